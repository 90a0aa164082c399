r"""Compiled (numba) step of the augmented-state UKF of observers/ukf.py.

:func:`ukf_step` does what the filterpy reference step (``tests/ukf_reference.py``)
does through filterpy (``UnscentedKalmanFilter.predict`` then ``update`` with
``MerweScaledSigmaPoints``), in the same order of operations, so the two agree
to round-off (tests/test_ukf_compiled.py).  The Python estimator stays the
reference implementation.

Filter state: x = [q (N = n + 2), eta (2), rho (2n, when estimated), ubar (2n,
when estimated)], nx entries, carried with its covariance P as the flat array
``s = [x, P.ravel()]`` (row-major), the layout of ``UKFEstimator.pack``.

Scaled sigma points and weights (S. J. Julier, "The scaled unscented
transformation", ACC 2002; E. A. Wan and R. van der Merwe, "The unscented
Kalman filter for nonlinear estimation", AS-SPCC 2000, the UKF algorithm;
R. van der Merwe, "Sigma-point Kalman filters for probabilistic inference in
dynamic state-space models", PhD thesis, OGI/OHSU 2004), with
``lambda = alpha^2 (nx + kappa) - nx`` and ``c = lambda + nx``::

    U = chol(c P)               upper triangular, U^T U = c P
    X_0 = x,  X_k = x + U[k-1],  X_(nx+k) = x - U[k-1]        k = 1..nx (rows of U)
    Wm_0 = lambda / c,  Wc_0 = lambda / c + 1 - alpha^2 + beta,  Wm_k = Wc_k = 1 / (2 c)

One step over the sample h with the control u held:

* predict: ``X_k <- f(X_k)``, f one midpoint (RK2) step of the process model
  ``q' = S(q) eta``, ``Mbar1 eta' = -Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar)``
  (thesis (2.63), (2.70) with the fault model (2.102)), rho' = ubar' = 0: the
  numbers of control.active_compiled.midpoint_sigmas, the kernel the reference UKF in tests/ calls,
  bit for bit (:func:`_propagate` shares the first stage among the points
  that differ from X_0 in the parameters only);
  ``x = sum Wm_k X_k``, ``P = sum Wc_k (X_k - x)(X_k - x)^T + Qc h``;
* sigma points redrawn from the predicted (x, P), as filterpy's ``predict``
  does (filterpy 2.0.0, UKF.py: ``self.sigmas_f = self.points_fn.sigma_points(self.x,
  self.P)`` after the transform): the update sees X_k of the predicted P, not
  the propagated points (the difference is ~1e-3 posterior standard deviations);
* update with y = q + v, measurement model ``Z_k = X_k[:N]``::

      zp = sum Wm_k Z_k,   S = sum Wc_k (Z_k - zp)(Z_k - zp)^T + R
      Pxz = sum Wc_k (X_k - x)(Z_k - zp)^T,   K = Pxz S^-1
      x <- x + K (y - zp),   P <- P - K (S K^T)

  S^-1 is formed by LU with partial pivoting (numpy's ``inv``, which filterpy
  calls, is LAPACK gesv on the identity: the same factorisation);
* ``P <- (P + P^T) / 2`` (the reference step).

Cholesky reads the upper triangle of c P, as LAPACK potrf (scipy's
``cholesky``) does.  Sums run in index order; BLAS may sum in another order,
hence the round-off differences.

Failures do not raise: :func:`ukf_step` returns a status (``UKF_*`` below, 0 =
none) and then the unchanged input state; :func:`ukf_message` turns the status
into the message for the user.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..jit import packed as P
from ..jit.compiling import jit
from ..jit.packed import _inv2
from ..model.compiled import reduced

if TYPE_CHECKING:
    from .ukf import UKFEstimator

__all__ = [
    "UKF_NONFINITE",
    "UKF_OK",
    "UKF_PREDICTED_NOT_PD",
    "UKF_PRIOR_NOT_PD",
    "UKF_S_SINGULAR",
    "Ukf",
    "merwe_weights",
    "ukf_message",
    "ukf_params",
    "ukf_step",
    "ukf_step_jacobian",
]

# status of ukf_step
from ..jit.packed import (
    UKF_NONFINITE,
    UKF_OK,
    UKF_PREDICTED_NOT_PD,
    UKF_PRIOR_NOT_PD,
    UKF_S_SINGULAR,
    ukf_message,
)


class Ukf(NamedTuple):
    """What :func:`ukf_step` needs of a UKFEstimator (numba-typed)."""

    nx: int  # augmented state size N + 2 + p
    N: int  # n + 2: measured q
    est_rho: bool  # gains in the state (after eta)
    est_ubar: bool  # frictions in the state (after the gains)
    Qc: np.ndarray  # (nx, nx) process-noise intensities [per second]; Q = Qc h
    R: np.ndarray  # (N, N) measurement covariance
    Wm: np.ndarray  # (2 nx + 1,) mean weights
    Wc: np.ndarray  # (2 nx + 1,) covariance weights
    c: float  # lambda + nx: sigma points from chol(c P)


def merwe_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[np.ndarray, np.ndarray, float]:
    r"""Scaled sigma-point weights (Wm, Wc) and c = lambda + n (Wan & van der Merwe 2000).

    ``lambda = alpha^2 (n + kappa) - n``; ``Wm_0 = lambda / c``,
    ``Wc_0 = Wm_0 + 1 - alpha^2 + beta``, the 2n others ``1 / (2 c)``.
    Computed with the same operations as filterpy (tested: bitwise equal).
    """
    lam = alpha**2 * (n + kappa) - n
    c = lam + n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1 - alpha**2 + beta)
    return Wm, Wc, float(c)


def ukf_params(est: UKFEstimator) -> Ukf:
    """The :class:`Ukf` of a UKFEstimator (its sigma-point parameters, Qc and R).

    :func:`ukf_step`'s model is ``jit.packed.Chain(*est.chain.params)``: the
    filter's chain, which is not the plant's in the model-mismatch cases.
    """
    pts = est.points
    Wm, Wc, c = merwe_weights(est.nx, pts.alpha, pts.beta, pts.kappa)
    return Ukf(
        int(est.nx),
        int(est.N),
        bool(est.est_rho),
        bool(est.est_ubar),
        np.ascontiguousarray(est.Qc, dtype=float),
        np.ascontiguousarray(est.R, dtype=float),
        Wm,
        Wc,
        c,
    )


# =========================================================================== kernels
@jit
def _cholesky_upper(A, U):
    """U upper triangular with U^T U = A, from A's upper triangle (LAPACK potf2, uplo = 'U').

    Returns 0, or j + 1 when the j-th (0-based) pivot is not positive (or NaN):
    A is not positive definite.  The lower triangle of U is zeroed.
    """
    n = A.shape[0]
    for j in range(n):
        for i in range(j):
            U[j, i] = 0.0
        # U_jj = sqrt(A_jj - sum_(k<j) U_kj^2)
        d = A[j, j]
        for k in range(j):
            d -= U[k, j] * U[k, j]
        if not d > 0.0:
            return j + 1
        d = math.sqrt(d)
        U[j, j] = d
        # U_ji = (A_ji - sum_(k<j) U_kj U_ki) / U_jj,  i > j
        for i in range(j + 1, n):
            v = A[j, i]
            for k in range(j):
                v -= U[k, j] * U[k, i]
            U[j, i] = v / d
    return 0


@jit
def _sigma_points(x, P, c, work, U, X):
    """Merwe's scaled sigma points of (x, P) into X (2 nx + 1, nx); returns the Cholesky status."""
    nx = x.shape[0]
    for i in range(nx):
        for j in range(nx):
            work[i, j] = c * P[i, j]
    info = _cholesky_upper(work, U)
    if info:
        return info
    for j in range(nx):
        X[0, j] = x[j]
    for k in range(nx):
        for j in range(nx):
            X[k + 1, j] = x[j] + U[k, j]
            X[nx + k + 1, j] = x[j] - U[k, j]
    return 0


@jit
def _unscented_transform(X, Wm, Wc, noise, mean, cov, dev):
    """mean = sum Wm_k X_k;  cov = sum Wc_k (X_k - mean)(X_k - mean)^T + noise;  dev = X - mean."""
    m, n = X.shape
    for j in range(n):
        v = 0.0
        for k in range(m):
            v += Wm[k] * X[k, j]
        mean[j] = v
    for k in range(m):
        for j in range(n):
            dev[k, j] = X[k, j] - mean[j]
    for i in range(n):
        for j in range(n):
            v = 0.0
            for k in range(m):
                v += dev[k, i] * (Wc[k] * dev[k, j])
            cov[i, j] = v + noise[i, j]


@jit
def _lu_inverse(A, Ainv):
    """A^-1 by LU with partial pivoting (LAPACK getrf + getrs on I); False when a pivot is zero."""
    n = A.shape[0]
    LU = A.copy()
    perm = np.arange(n)
    for j in range(n):
        p = j
        for i in range(j + 1, n):
            if abs(LU[i, j]) > abs(LU[p, j]):
                p = i
        if LU[p, j] == 0.0 or not math.isfinite(LU[p, j]):
            return False
        if p != j:
            for k in range(n):
                LU[j, k], LU[p, k] = LU[p, k], LU[j, k]
            perm[j], perm[p] = perm[p], perm[j]
        for i in range(j + 1, n):
            LU[i, j] /= LU[j, j]
            for k in range(j + 1, n):
                LU[i, k] -= LU[i, j] * LU[j, k]
    # columns of P I, then L z = e, U x = z
    for col in range(n):
        for i in range(n):
            v = 1.0 if perm[i] == col else 0.0
            for k in range(i):
                v -= LU[i, k] * Ainv[k, col]
            Ainv[i, col] = v
        for i in range(n - 1, -1, -1):
            v = Ainv[i, col]
            for k in range(i + 1, n):
                v -= LU[i, k] * Ainv[k, col]
            Ainv[i, col] = v / LU[i, i]
    return True


@jit
def _rhs(Mbar1, Mbar2, Cbar, Bbar, S, eta, tau, qd, ed):
    """model.compiled.plant_rhs from the model terms into qd, ed, with its operations in its order (no allocation).

    ``qd = S eta`` (2.63);  ``Mbar1 ed = Bbar tau - Mbar2 eta - Cbar`` (2.70), solved in closed form.
    """
    for i in range(S.shape[0]):
        acc = 0.0
        for j in range(2):
            acc += S[i, j] * eta[j]
        qd[i] = acc
    # r = Bbar tau - Mbar2 eta - Cbar, then Cramer's rule as jit.packed._solve2
    r0 = _rhs_row(Mbar2, Cbar, Bbar, eta, tau, 0)
    r1 = _rhs_row(Mbar2, Cbar, Bbar, eta, tau, 1)
    det = Mbar1[0, 0] * Mbar1[1, 1] - Mbar1[0, 1] * Mbar1[1, 0]
    ed[0] = (Mbar1[1, 1] * r0 - Mbar1[0, 1] * r1) / det
    ed[1] = (Mbar1[0, 0] * r1 - Mbar1[1, 0] * r0) / det


@jit
def _rhs_row(Mbar2, Cbar, Bbar, eta, tau, i):
    """Row i of Bbar tau - Mbar2 eta - Cbar, each product summed from 0 as jit.packed._mv."""
    bt = 0.0
    for j in range(tau.shape[0]):
        bt += Bbar[i, j] * tau[j]
    me = 0.0
    for j in range(2):
        me += Mbar2[i, j] * eta[j]
    return bt - me - Cbar[i]


@jit
def _propagate(pc, X, u, h, est_rho, est_ubar, Xf):
    """``control.active_compiled.midpoint_sigmas(pc, X, u, h, est_rho, est_ubar)`` into Xf, bitwise, with fewer
    model evaluations.

    One midpoint step of (2.63), (2.70), (2.102) per sigma point, u held::

        tau = diag(rho) u + ubar,   (qd1, ed1) = f(q, eta),   (qd2, ed2) = f(q + h/2 qd1, eta + h/2 ed1)
        q <- q + h qd2,   eta <- eta + h ed2,   rho, ubar unchanged

    The sigma points along the parameter directions (rows N + 2.. of the
    triangular factor) keep sigma 0's (q, eta) exactly, so the first stage's
    model terms (kernels.reduced: Mbar1, Mbar2, Cbar, Bbar, S) are evaluated
    once for all of them; ``f`` is then formed as model.compiled.plant_rhs forms it
    (:func:`_rhs`, the same operations without allocating).  Tested bitwise
    against control.active_compiled.midpoint_sigmas.
    """
    m = X.shape[0]
    N = pc.n + 2
    nw = 2 * pc.n
    tau = np.empty(nw)
    qm = np.empty(N)
    em = np.empty(2)
    qd1 = np.empty(N)
    qd2 = np.empty(N)
    ed1 = np.empty(2)
    ed2 = np.empty(2)
    terms0 = reduced(pc, X[0, :N], X[0, N : N + 2])
    half = 0.5 * h
    for i in range(m):
        x = X[i]
        q = x[:N]
        eta = x[N : N + 2]
        k = N + 2
        for j in range(nw):
            rho = 1.0
            if est_rho:
                rho = x[k + j]
            ubar = 0.0
            if est_ubar:
                ubar = x[k + (nw if est_rho else 0) + j]
            # tau = rho u + ubar   (2.102)
            tau[j] = rho * u[j] + ubar
        same = True
        for j in range(N + 2):
            if x[j] != X[0, j]:
                same = False
                break
        if same:
            Mbar1, Mbar2, Cbar, Bbar, S, _Sd = terms0
        else:
            Mbar1, Mbar2, Cbar, Bbar, S, _Sd = reduced(pc, q, eta)
        _rhs(Mbar1, Mbar2, Cbar, Bbar, S, eta, tau, qd1, ed1)
        for j in range(N):
            qm[j] = q[j] + half * qd1[j]
        for j in range(2):
            em[j] = eta[j] + half * ed1[j]
        Mbar1, Mbar2, Cbar, Bbar, S, _Sd = reduced(pc, qm, em)
        _rhs(Mbar1, Mbar2, Cbar, Bbar, S, em, tau, qd2, ed2)
        for j in range(N):
            Xf[i, j] = q[j] + h * qd2[j]
        for j in range(2):
            Xf[i, N + j] = eta[j] + h * ed2[j]
        for j in range(N + 2, x.shape[0]):
            Xf[i, j] = x[j]


@jit
def _all_finite(a):
    return np.isfinite(a).all()


@jit
def ukf_step(pc, U, s, u, y, h):
    r"""One UKF step over h: predict with u held, update with y = q (the reference UKF of tests/ukf_reference.py).

    Parameters
    ----------
    pc : jit.packed.Chain
        The filter's model (``jit.packed.Chain(*chain.params)``).
    U : Ukf
        Filter constants (:func:`ukf_params`).
    s : (nx + nx * nx,) ndarray
        ``[x, P.ravel()]`` at the previous sample.
    u : (2n,) ndarray
        Control applied over the sample (held), wheel order 1r, 1l, 2r, ...
    y : (N,) ndarray
        Measured q at the end of the sample.
    h : float
        Sample length [s] (> 0); Q = Qc h.

    Returns
    -------
    s_new : (nx + nx * nx,) ndarray
        ``[x, P.ravel()]`` after the update, P symmetrised; the input s (a copy)
        when the status is not UKF_OK.
    status : int
        UKF_OK (0); UKF_NONFINITE (1): x or P of the input, of the prediction or
        of the result is not finite; UKF_PRIOR_NOT_PD (2): the input P is not
        positive definite; UKF_PREDICTED_NOT_PD (3): the predicted P is not;
        UKF_S_SINGULAR (4): S has a zero pivot.  :func:`ukf_message` gives the text.
    """
    nx = U.nx
    N = U.N
    m = 2 * nx + 1
    x = s[:nx].copy()
    P = s[nx:].copy().reshape(nx, nx)
    if not (_all_finite(x) and _all_finite(P)):
        return s.copy(), UKF_NONFINITE
    work = np.empty((nx, nx))
    Uc = np.empty((nx, nx))
    X = np.empty((m, nx))
    dev = np.empty((m, nx))

    # ---- predict: sigma points of (x, P), each through one midpoint step of (2.63), (2.70), (2.102)
    if _sigma_points(x, P, U.c, work, Uc, X):
        return s.copy(), UKF_PRIOR_NOT_PD
    Xf = np.empty((m, nx))
    _propagate(pc, X, u, h, U.est_rho, U.est_ubar, Xf)
    # x = sum Wm_k X_k;  P = sum Wc_k (X_k - x)(X_k - x)^T + Qc h
    Q = U.Qc * h
    _unscented_transform(Xf, U.Wm, U.Wc, Q, x, P, dev)
    if not (_all_finite(x) and _all_finite(P)):
        return s.copy(), UKF_NONFINITE
    # filterpy's predict redraws the sigma points from the predicted (x, P)
    if _sigma_points(x, P, U.c, work, Uc, X):
        return s.copy(), UKF_PREDICTED_NOT_PD

    # ---- update with y = q + v: Z_k = X_k[:N]
    Z = np.ascontiguousarray(X[:, :N])
    zp = np.empty(N)
    S = np.empty((N, N))
    dz = np.empty((m, N))
    # zp = sum Wm_k Z_k;  S = sum Wc_k (Z_k - zp)(Z_k - zp)^T + R
    _unscented_transform(Z, U.Wm, U.Wc, U.R, zp, S, dz)
    SI = np.empty((N, N))
    if not _lu_inverse(S, SI):
        return s.copy(), UKF_S_SINGULAR
    # Pxz = sum_k Wc_k (X_k - x)(Z_k - zp)^T, accumulated point by point as filterpy's cross_variance
    Pxz = np.zeros((nx, N))
    for k in range(m):
        w = U.Wc[k]
        for i in range(nx):
            di = X[k, i] - x[i]
            for j in range(N):
                Pxz[i, j] += w * (di * dz[k, j])
    # K = Pxz S^-1
    Kg = np.zeros((nx, N))
    for i in range(nx):
        for j in range(N):
            v = 0.0
            for k in range(N):
                v += Pxz[i, k] * SI[k, j]
            Kg[i, j] = v
    # x <- x + K (y - zp)
    r = np.empty(N)
    for j in range(N):
        r[j] = y[j] - zp[j]
    for i in range(nx):
        v = 0.0
        for j in range(N):
            v += Kg[i, j] * r[j]
        x[i] += v
    # P <- P - K (S K^T)
    SKt = np.empty((N, nx))
    for i in range(N):
        for j in range(nx):
            v = 0.0
            for k in range(N):
                v += S[i, k] * Kg[j, k]
            SKt[i, j] = v
    for i in range(nx):
        for j in range(nx):
            v = 0.0
            for k in range(N):
                v += Kg[i, k] * SKt[k, j]
            work[i, j] = P[i, j] - v
    # P <- (P + P^T) / 2
    out = np.empty(nx + nx * nx)
    out[:nx] = x
    for i in range(nx):
        for j in range(nx):
            out[nx + i * nx + j] = 0.5 * (work[i, j] + work[j, i])
    if not _all_finite(out):
        return s.copy(), UKF_NONFINITE
    return out, UKF_OK


# =========================================================================== its derivative (the linearized analysis)
@jit
def _model_columns(pc, q, eta, tau, rel, A, z, qd, ed, fp):
    """``A = d f / d [q, eta]`` of the process model ``f = (S eta, Mbar1^-1 (Bbar tau - Mbar2 eta - Cbar))`` at
    tau held, by central differences (relative step ``rel``, as ``analysis.closed_loop.central_columns``).

    Columns 0 and 1 (the position of P_n) are exactly 0 and not differenced: the model's terms read q only
    through the headings (``model.compiled.s_column`` reads ``q[2:]``: the chain's dynamics do not depend
    on where it is).  ``z``, ``qd``, ``ed``, ``fp``: work arrays (N + 2, N, 2, N + 2).
    """
    N = q.shape[0]
    for i in range(N + 2):
        for j in range(N + 2):
            A[i, j] = 0.0
    for j in range(2, N + 2):
        for i in range(N):
            z[i] = q[i]
        z[N] = eta[0]
        z[N + 1] = eta[1]
        x0 = z[j]
        hj = rel * max(1.0, abs(x0))
        z[j] = x0 + hj
        Mbar1, Mbar2, Cbar, Bbar, S, _Sd = reduced(pc, z[:N], z[N:])
        _rhs(Mbar1, Mbar2, Cbar, Bbar, S, z[N:], tau, qd, ed)
        for i in range(N):
            fp[i] = qd[i]
        fp[N] = ed[0]
        fp[N + 1] = ed[1]
        z[j] = x0 - hj
        Mbar1, Mbar2, Cbar, Bbar, S, _Sd = reduced(pc, z[:N], z[N:])
        _rhs(Mbar1, Mbar2, Cbar, Bbar, S, z[N:], tau, qd, ed)
        for i in range(N):
            A[i, j] = (fp[i] - qd[i]) / (2.0 * hj)
        A[N, j] = (fp[N] - ed[0]) / (2.0 * hj)
        A[N + 1, j] = (fp[N + 1] - ed[1]) / (2.0 * hj)


@jit
def _torque_columns(Mbar1, Bbar, u, rho, U, nx, BT):
    """``BT = d f / d tau  d tau / d [x, u]`` (N + 2, nx + 2n): how the wheels' torques ``tau = diag(rho) u + ubar``
    (2.102) move the model, exactly (``d eta' / d tau = Mbar1^-1 Bbar``, (2.70); q' does not read tau)."""
    N = U.N
    nw = u.shape[0]
    Minv = _inv2(Mbar1)
    for i in range(BT.shape[0]):
        for c in range(BT.shape[1]):
            BT[i, c] = 0.0
    for j in range(nw):
        b0 = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
        b1 = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
        k = N + 2
        if U.est_rho:
            BT[N, k + j] = b0 * u[j]
            BT[N + 1, k + j] = b1 * u[j]
            k += nw
        if U.est_ubar:
            BT[N, k + j] = b0
            BT[N + 1, k + j] = b1
        BT[N, nx + j] = b0 * rho[j]
        BT[N + 1, nx + j] = b1 * rho[j]


@jit
def ukf_step_jacobian(pc, U, s, u, y, h, rel):
    r"""The derivative of :func:`ukf_step`'s estimate x+ in (x, u, y) with the covariance P held: (J, status).

    What the linearized analysis needs of the UKF scheme's discrete update (analysis.closed_loop: the
    filter linearized with P frozen, the usual linearization of a Kalman filter).  It replaces central
    differences of the whole step (2 (nx + 2n + N) steps) by the derivative of each propagated sigma
    point, and is exact in exact arithmetic for the following reason.  With P held the sigma points are
    ``X_k = x + d_k`` with offsets d_k = +-rows of chol(c P) that do not move, so ``dX_k / dx = I``.  The
    step then computes (module docstring)::

        Xf_k = F(X_k, u)   (one midpoint step),   x^- = sum Wm_k Xf_k,
        P^- = sum Wc_k e_k e_k^T + Qc h,   e_k = Xf_k - x^-

    and updates from sigma points redrawn from (x^-, P^-).  Their statistics are exactly x^- and P^-
    (``sum Wm_k = 1``, the +-d_k cancel, ``sum Wc_k d_k d_k^T = P^-``), so in exact arithmetic ``zp = H x^-``,
    ``S = H P^- H^T + R``, ``Pxz = P^- H^T`` (H = [I_N, 0], y = q + v) and the update is the linear Kalman
    update with the predicted covariance: ``x+ = x^- + K r``, ``K = P^- H^T S^-1``, ``r = y - H x^-``; the
    redraw's Cholesky factor has no derivative to take.  Differentiating, with ``w = S^-1 r``::

        dx+ = (I - K H) (dx^- + dP^- H^T w) + K dy,   dx^- = sum Wm_k dXf_k,
        dP^- H^T w = sum Wc_k [de_k (H e_k . w) + e_k (H de_k . w)],   de_k = dXf_k - dx^-

    (dK r = dP^- H^T w - K H dP^- H^T w; the innovation r is small but not zero at the analysis's
    operating point, so the term is kept).  Only ``dXf_k / d[x, u]`` is left: the midpoint step
    ``Xm = X + h/2 f(X)``, ``Xf = X + h f(Xm)`` (q, eta; the parameters are carried) by the chain rule,
    ``dXm = E + h/2 (A(X) E + BT(X))``, ``dXf = E + h (A(Xm) dXm + BT(Xm))`` with E = [I, 0] the (q, eta)
    rows, ``A = df / d[q, eta]`` the model's Jacobian at each sigma point by central differences
    (:func:`_model_columns`, step ``rel``) and ``BT`` the torques' columns, exact (:func:`_torque_columns`).
    The sigma points along the parameter directions keep X_0's (q, eta): their first-stage model terms
    are X_0's, differenced once (as :func:`_propagate` shares them).

    Parameters
    ----------
    pc, U, s, u, y, h
        As :func:`ukf_step`.
    rel : float
        Relative step of the model's central differences (``analysis.closed_loop.STEP``).

    Returns
    -------
    J : (nx, nx + 2n + N) ndarray
        ``[d x+ / d x, d x+ / d u, d x+ / d y]``.
    status : int
        UKF_OK, or the status :func:`ukf_step` gives for the same input when its prior covariance is not
        positive definite (UKF_PRIOR_NOT_PD), a value is not finite (UKF_NONFINITE) or S is singular
        (UKF_S_SINGULAR); J is then zero.
    """
    nx = U.nx
    N = U.N
    nw = u.shape[0]
    m = 2 * nx + 1
    nq = N + 2  # the propagated rows (q, eta)
    nin = nx + nw
    J = np.zeros((nx, nin + N))
    x = s[:nx].copy()
    P = s[nx:].copy().reshape(nx, nx)
    if not (_all_finite(x) and _all_finite(P)):
        return J, UKF_NONFINITE
    work = np.empty((nx, nx))
    Uc = np.empty((nx, nx))
    X = np.empty((m, nx))
    if _sigma_points(x, P, U.c, work, Uc, X):
        return J, UKF_PRIOR_NOT_PD
    Xf = np.empty((m, nx))
    _propagate(pc, X, u, h, U.est_rho, U.est_ubar, Xf)
    xm = np.empty(nx)
    Pm = np.empty((nx, nx))
    dev = np.empty((m, nx))
    _unscented_transform(Xf, U.Wm, U.Wc, U.Qc * h, xm, Pm, dev)
    if not (_all_finite(xm) and _all_finite(Pm)):
        return J, UKF_NONFINITE
    # the Kalman update with the predicted covariance: S = H P^- H^T + R, K = P^- H^T S^-1, w = S^-1 r
    S = np.empty((N, N))
    for i in range(N):
        for j in range(N):
            S[i, j] = Pm[i, j] + U.R[i, j]
    SI = np.empty((N, N))
    if not _lu_inverse(S, SI):
        return J, UKF_S_SINGULAR
    K = np.zeros((nx, N))
    for i in range(nx):
        for j in range(N):
            v = 0.0
            for k in range(N):
                v += Pm[i, k] * SI[k, j]
            K[i, j] = v
    w = np.zeros(N)
    for i in range(N):
        v = 0.0
        for j in range(N):
            v += SI[i, j] * (y[j] - xm[j])
        w[i] = v

    # dXf_k / d[x, u] in the (q, eta) rows, sigma point by sigma point
    D = np.zeros((m, nq, nin))
    A = np.empty((nq, nq))
    BT = np.empty((nq, nin))
    G = np.empty((nq, nin))
    A0 = np.empty((nq, nq))
    z = np.empty(nq)
    fp = np.empty(nq)
    qd = np.empty(N)
    ed = np.empty(2)
    qm = np.empty(N)
    em = np.empty(2)
    tau = np.empty(nw)
    rho = np.empty(nw)
    terms0 = reduced(pc, X[0, :N], X[0, N:nq])
    # X_0's first-stage columns at tau held, as f(z, tau) = f0(z) + G(z) tau: the (q, eta) differences of the
    # model terms at X_0 +- h e_j, kept for the points that share X_0's (q, eta)
    Zs = np.empty((2 * nq, nq))
    M1s = np.empty((2 * nq, 2, 2))
    M2s = np.empty((2 * nq, 2, 2))
    Cs = np.empty((2 * nq, 2))
    Bs = np.empty((2 * nq, 2, nw))
    Ss = np.empty((2 * nq, N, 2))
    hs = np.zeros(nq)
    for j in range(2, nq):
        x0 = X[0, j]
        hj = rel * max(1.0, abs(x0))
        hs[j] = hj
        for side in range(2):
            r = 2 * j + side
            for i in range(nq):
                Zs[r, i] = X[0, i]
            Zs[r, j] = x0 + hj if side == 0 else x0 - hj
            Mbar1, Mbar2, Cbar, Bbar, Sm, _Sd = reduced(pc, Zs[r, :N], Zs[r, N:])
            M1s[r] = Mbar1
            M2s[r] = Mbar2
            Cs[r] = Cbar
            Bs[r] = Bbar
            Ss[r] = Sm
    half = 0.5 * h
    for k in range(m):
        xk = X[k]
        kk = N + 2
        for j in range(nw):
            rj = 1.0
            if U.est_rho:
                rj = xk[kk + j]
            ub = 0.0
            if U.est_ubar:
                ub = xk[kk + (nw if U.est_rho else 0) + j]
            rho[j] = rj
            tau[j] = rj * u[j] + ub  # (2.102)
        same = True
        for j in range(nq):
            if xk[j] != X[0, j]:
                same = False
                break
        # first stage at X_k: f, its (q, eta) columns A0 and its torque columns BT
        if same:
            Mbar1, Mbar2, Cbar, Bbar, Sm, _Sd = terms0
            for i in range(nq):
                A0[i, 0] = 0.0
                A0[i, 1] = 0.0
            for j in range(2, nq):
                r = 2 * j
                _rhs(M1s[r], M2s[r], Cs[r], Bs[r], Ss[r], Zs[r, N:], tau, qd, ed)
                for i in range(N):
                    fp[i] = qd[i]
                fp[N] = ed[0]
                fp[N + 1] = ed[1]
                _rhs(M1s[r + 1], M2s[r + 1], Cs[r + 1], Bs[r + 1], Ss[r + 1], Zs[r + 1, N:], tau, qd, ed)
                for i in range(N):
                    A0[i, j] = (fp[i] - qd[i]) / (2.0 * hs[j])
                A0[N, j] = (fp[N] - ed[0]) / (2.0 * hs[j])
                A0[N + 1, j] = (fp[N + 1] - ed[1]) / (2.0 * hs[j])
        else:
            Mbar1, Mbar2, Cbar, Bbar, Sm, _Sd = reduced(pc, xk[:N], xk[N:nq])
            _model_columns(pc, xk[:N], xk[N:nq], tau, rel, A0, z, qd, ed, fp)
        _torque_columns(Mbar1, Bbar, u, rho, U, nx, BT)
        _rhs(Mbar1, Mbar2, Cbar, Bbar, Sm, xk[N:nq], tau, qd, ed)
        for j in range(N):
            qm[j] = xk[j] + half * qd[j]
        for j in range(2):
            em[j] = xk[N + j] + half * ed[j]
        # dXm = E + h/2 (A0 E + BT)
        for i in range(nq):
            for c in range(nin):
                v = BT[i, c]
                if c < nq:
                    v += A0[i, c]
                G[i, c] = half * v
            G[i, i] += 1.0
        # second stage at Xm: dXf = E + h (A dXm + BT)
        Mbar1, Mbar2, Cbar, Bbar, Sm, _Sd = reduced(pc, qm, em)
        _torque_columns(Mbar1, Bbar, u, rho, U, nx, BT)
        _model_columns(pc, qm, em, tau, rel, A, z, qd, ed, fp)
        for i in range(nq):
            for c in range(nin):
                v = BT[i, c]
                for j in range(2, nq):
                    v += A[i, j] * G[j, c]
                D[k, i, c] = h * v
            D[k, i, i] += 1.0

    # dx^- = sum Wm_k dXf_k (the parameters are carried: identity)
    dxm = np.zeros((nx, nin))
    for k in range(m):
        wk = U.Wm[k]
        for i in range(nq):
            for c in range(nin):
                dxm[i, c] += wk * D[k, i, c]
    for i in range(nq, nx):
        dxm[i, i] = 1.0
    # Z = dx^- + dP^- H^T w: de_k is zero in the parameter rows (both carried)
    Zm = dxm.copy()
    b = np.empty(nin)
    for k in range(m):
        wk = U.Wc[k]
        a = 0.0
        for j in range(N):
            a += dev[k, j] * w[j]
        for c in range(nin):
            v = 0.0
            for i in range(N):
                v += w[i] * (D[k, i, c] - dxm[i, c])
            b[c] = v
        for i in range(nq):
            for c in range(nin):
                Zm[i, c] += wk * a * (D[k, i, c] - dxm[i, c])
        for i in range(nx):
            e = wk * dev[k, i]
            for c in range(nin):
                Zm[i, c] += e * b[c]
    # J = [(I - K H) Z, K]
    for i in range(nx):
        for c in range(nin):
            v = Zm[i, c]
            for j in range(N):
                v -= K[i, j] * Zm[j, c]
            J[i, c] = v
        for j in range(N):
            J[i, nin + j] = K[i, j]
    if not _all_finite(J):
        return np.zeros((nx, nin + N)), UKF_NONFINITE
    return J, UKF_OK


# =========================================================================== the active scheme on the UKF
class UkfLaw(NamedTuple):
    """Active FTC on the UKF's estimates: what its law and discrete update need (the scheme's P)."""

    law: P.Law  # k_v, u_limit
    ukf: Ukf
    pf: P.Chain  # the filter's (and the law's) chain model
    est0: int  # the filter's flat [x, P] in xc
    filt0: int  # the estimates' filters (tau), 2 nw
    tau: float  # nan: unfiltered
    u0: int  # the held control, nw
    t0: int  # the last sample time


@jit
def _ukf_estimates(L, xc, nw):
    """(q_hat, eta_hat, rho_hat, ubar_hat) of the filter state (rho 1, ubar 0 where not estimated)."""
    N = L.ukf.N
    x = xc[L.est0 : L.est0 + L.ukf.nx]
    rho = np.ones(nw)
    ubar = np.zeros(nw)
    k = N + 2
    if L.ukf.est_rho:
        rho = x[k : k + nw].copy()
        k += nw
    if L.ukf.est_ubar:
        ubar = x[k : k + nw].copy()
    return x[:N].copy(), x[N : N + 2].copy(), rho, ubar


@jit
def _ukf_used(L, xc, nw, rho_e, ubar_e):
    """(sigma_hat, ubar_hat) the law uses: filtered when tau is set, ubar clipped to the limit, sigma to [0, 1]."""
    rho, ubar = rho_e, ubar_e
    if not math.isnan(L.tau):
        rho = xc[L.filt0 : L.filt0 + nw].copy()
        ubar = xc[L.filt0 + nw : L.filt0 + 2 * nw].copy()
    if not math.isnan(L.law.u_limit):
        ubar = P._clip(ubar, -L.law.u_limit, L.law.u_limit)
    return P._clip(rho, 0.0, 1.0), ubar
