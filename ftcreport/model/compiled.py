r"""Compiled (numba) kernels of the n-link chain model: S(q), M, C, B, the reduced model, the plant's rhs.

The single implementation of the model the simulation evaluates (thesis 2.60-2.74, Appendices C and D,
ERRATA E5); :mod:`ftcreport.model.kernels` and :class:`ftcreport.model.Chain` are its readable faces,
and the numpy derivation there checks it (S^T A^T = 0, Mbar1 = S^T M S, power balance).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import (
    Chain,  # noqa: F401 - the face (model/kernels.py) reads its twin only
    _inv2,
    _mv,
    _solve2,
)


# =========================================================================== model (model/kernels.py)
@jit
def s_column(p, q):
    """(theta robot order, col = thetadot / v_n, tan phi, sec phi, w), thesis (2.64) with ERRATA E5, E5c.

    v_(i+1) = v_n w_(i+1), w_(i+1) = prod_(j=i+1)^(n-1) sec(phi_j), and
    thetadot_(i+1) = v_(i+1) tan(phi_i) / d_i, phi_i = theta_i - theta_(i+1) (one pinned link, 2.33).
    """
    n = p.n
    N = n + 2
    th = np.empty(n)
    for k in range(n):
        th[k] = q[N - 1 - k]
    tphi = np.empty(max(n - 1, 0))
    sphi = np.empty(max(n - 1, 0))
    for i in range(n - 1):
        # phi_i = theta_i - theta_(i+1)
        ph = th[i] - th[i + 1]
        tphi[i] = math.tan(ph)
        sphi[i] = 1.0 / math.cos(ph)
    w = np.ones(n)
    for i in range(n - 2, -1, -1):
        # w_i = w_(i+1) sec(phi_i)   (v_i = v_n w_i)
        w[i] = w[i + 1] * sphi[i]
    col = np.zeros(n)
    for i in range(1, n):
        # thetadot_(i+1) / v_n = w_(i+1) tan(phi_i) / d_i
        col[i] = tphi[i - 1] * w[i] / p.d[i - 1]
    return th, col, tphi, sphi, w


@jit
def s_matrix(p, q):
    """S(q), qdot = S(q) eta, thesis (2.63)-(2.64): columns [d q / d v_n, d q / d omega_1]."""
    n = p.n
    N = n + 2
    th, col, _t, _s, _w = s_column(p, q)
    S = np.zeros((N, 2))
    # xdot = v_n cos theta_n, ydot = v_n sin theta_n
    S[0, 0] = math.cos(th[n - 1])
    S[1, 0] = math.sin(th[n - 1])
    for k in range(n):
        S[N - 1 - k, 0] = col[k]
    # thetadot_1 = omega_1
    S[N - 1, 1] = 1.0
    return S


@jit
def _mass(p, th, sth, cth):
    """Inertia matrix M(q) (D.5) with E5a; th, sth, cth: headings (robot order) and their sin, cos."""
    n = p.n
    N = n + 2
    M = np.zeros((N, N))
    M[0, 0] = p.m_total
    M[1, 1] = p.m_total
    for k in range(n):
        ik = N - 1 - k
        # M_xy,k = h_k U_k^perp,  M_kl = G_kl cos(theta_k - theta_l) + I_k delta_kl   (D.5, E5a)
        M[0, ik] = -p.h[k] * sth[k]
        M[ik, 0] = M[0, ik]
        M[1, ik] = p.h[k] * cth[k]
        M[ik, 1] = M[1, ik]
        for l in range(n):
            M[ik, N - 1 - l] = p.G[k, l] * math.cos(th[k] - th[l])
        M[ik, ik] += p.I[k]
    return M


@jit
def _coriolis(p, th, sth, cth, thdot):
    """Centripetal/Coriolis vector C(q, qdot) = Mdot qdot - dT/dq (D.9); thdot: heading rates, robot order."""
    n = p.n
    N = n + 2
    C = np.zeros(N)
    # C_xy = -sum_k h_k thetadot_k^2 U_k,  C_l = sum_k G_lk thetadot_k^2 sin(theta_l - theta_k)
    for k in range(n):
        t2 = thdot[k] * thdot[k]
        C[0] -= p.h[k] * t2 * cth[k]
        C[1] -= p.h[k] * t2 * sth[k]
    for l in range(n):
        s = 0.0
        for k in range(n):
            s += p.G[l, k] * math.sin(th[l] - th[k]) * thdot[k] * thdot[k]
        C[N - 1 - l] = s
    return C


@jit
def input_matrix(p, th, sth, cth):
    """Input matrix B(q) (C.8) with E3, by virtual work; th, sth, cth as for ``_mass``."""
    n = p.n
    N = n + 2
    B = np.zeros((N, 2 * n))
    # B (C.8), E3: columns 2i (ir), 2i+1 (il) = (1/r_i) [U_i; D[i, k] sin(theta_i - theta_k) +/- b_i delta_ik]
    for i in range(n):
        ri = p.r[i]
        for j in (2 * i, 2 * i + 1):
            B[0, j] = cth[i] / ri
            B[1, j] = sth[i] / ri
            for k in range(n):
                B[N - 1 - k, j] = p.D[i, k] * math.sin(th[i] - th[k]) / ri
        B[N - 1 - i, 2 * i] += p.b[i] / ri
        B[N - 1 - i, 2 * i + 1] -= p.b[i] / ri
    return B


@jit
def input_matrix_and_rate(p, q, thdot):
    """B(q) of (C.8) and its time derivative along headings moving at thdot (robot order)."""
    n = p.n
    N = n + 2
    nw = 2 * n
    th = np.empty(n)
    sth = np.empty(n)
    cth = np.empty(n)
    for k in range(n):
        th[k] = q[N - 1 - k]
        sth[k] = math.sin(th[k])
        cth[k] = math.cos(th[k])
    Bd = np.zeros((N, nw))
    for i in range(n):
        ri = p.r[i]
        for j in (2 * i, 2 * i + 1):
            # d/dt of B's columns (C.8): U_i' = thetadot_i U_i^perp, d/dt sin(theta_i - theta_k)
            Bd[0, j] = -sth[i] * thdot[i] / ri
            Bd[1, j] = cth[i] * thdot[i] / ri
            for k in range(n):
                Bd[N - 1 - k, j] = p.D[i, k] * math.cos(th[i] - th[k]) * (thdot[i] - thdot[k]) / ri
    return input_matrix(p, th, sth, cth), Bd


@jit
def bbar_rate(p, q, eta, S, Sd):
    """Bbardot = Sdot^T B + S^T Bdot along qdot = S eta, given S and Sdot of ``kernels.reduced``."""
    n = p.n
    _th, col, _t, _s, _w = s_column(p, q)
    thdot = col * eta[0]
    thdot[0] = eta[1]
    B, Bd = input_matrix_and_rate(p, q, thdot)
    nw = 2 * n
    Bbd = np.zeros((2, nw))
    for a in range(2):
        for j in range(nw):
            acc = 0.0
            for i in range(n + 2):
                acc += Sd[i, a] * B[i, j] + S[i, a] * Bd[i, j]
            Bbd[a, j] = acc
    return Bbd


@jit
def rotor_mass(Mbar1, Bbar, Jw):
    """Mbar1 + Bbar diag(Jw) Bbar^T: the reduced inertia with the rotors on the wheel axes, (2, 2)."""
    A = Mbar1.copy()
    for j in range(Bbar.shape[1]):
        for a in range(2):
            for b in range(2):
                A[a, b] += Jw[j] * Bbar[a, j] * Bbar[b, j]
    return A


@jit
def mass_and_coriolis(p, q, qdot):
    """(M(q), C(q, qdot)) of (D.5), (D.9) for any qdot (not only S(q) eta): model.kernels' faces."""
    n = p.n
    th = np.empty(n)
    thdot = np.empty(n)
    sth = np.empty(n)
    cth = np.empty(n)
    for k in range(n):
        # q = [x, y, theta_n, ..., theta_1]: robot k (0-based) at q[n + 1 - k]
        th[k] = q[n + 1 - k]
        thdot[k] = qdot[n + 1 - k]
        sth[k] = math.sin(th[k])
        cth[k] = math.cos(th[k])
    return _mass(p, th, sth, cth), _coriolis(p, th, sth, cth, thdot)


@jit
def reduced(p, q, eta):
    """(Mbar1, Mbar2, Cbar, Bbar, S, Sdot) of (2.70)-(2.74), M by (D.5), C by (D.9), B by (C.8).

    ERRATA E1-E5b (the printed matrices are wrong or garbled; this is the generic derivation
    of model/kernels.py, E5a inertia slots), E4 (the two-link reduced model it reproduces).
    Mbar1 = S^T M S, Mbar2 = S^T M Sdot, Cbar = S^T C(q, S eta), Bbar = S^T B; Sdot analytic:
    d/dt tan(phi_i) = sec^2(phi_i) phidot_i, d/dt w_(i+1) = w_(i+1) sum_(j > i) tan(phi_j) phidot_j.
    """
    n = p.n
    N = n + 2
    nw = 2 * n
    th, col, tphi, sphi, w = s_column(p, q)
    thdot = col * eta[0]
    thdot[0] = eta[1]
    S = np.zeros((N, 2))
    Sd = np.zeros((N, 2))
    cn, sn = math.cos(th[n - 1]), math.sin(th[n - 1])
    S[0, 0], S[1, 0] = cn, sn
    Sd[0, 0] = -sn * thdot[n - 1]
    Sd[1, 0] = cn * thdot[n - 1]
    # wdot[i] = w[i] sum_(j >= i) tan(phi_j) phidot_j
    acc = 0.0
    wdot = np.zeros(n)
    for i in range(n - 2, -1, -1):
        acc += tphi[i] * (thdot[i] - thdot[i + 1])
        wdot[i] = w[i] * acc
    for k in range(n):
        S[N - 1 - k, 0] = col[k]
        if k >= 1:
            # d/dt (w_k tan(phi_(k-1)) / d_(k-1)) = (sec^2 phi phidot w + tan phi wdot) / d
            phidot = thdot[k - 1] - thdot[k]
            Sd[N - 1 - k, 0] = (sphi[k - 1] ** 2 * phidot * w[k] + tphi[k - 1] * wdot[k]) / p.d[k - 1]
    S[N - 1, 1] = 1.0
    sth = np.empty(n)
    cth = np.empty(n)
    for k in range(n):
        sth[k] = math.sin(th[k])
        cth[k] = math.cos(th[k])
    M = _mass(p, th, sth, cth)
    C = _coriolis(p, th, sth, cth, thdot)  # at qdot = S eta
    B = input_matrix(p, th, sth, cth)
    # S^T (.) with S = [s0, e_(N-1)] and Sdot = [sd0, 0]
    Ms0 = np.zeros(N)
    Msd0 = np.zeros(N)
    for i in range(N):
        for j in range(N):
            Ms0[i] += M[i, j] * S[j, 0]
            Msd0[i] += M[i, j] * Sd[j, 0]
    Mbar1 = np.zeros((2, 2))
    Mbar2 = np.zeros((2, 2))
    Cbar = np.zeros(2)
    Bbar = np.zeros((2, nw))
    for i in range(N):
        Mbar1[0, 0] += S[i, 0] * Ms0[i]
        Mbar1[0, 1] += S[i, 0] * M[i, N - 1]
        Mbar2[0, 0] += S[i, 0] * Msd0[i]
        Cbar[0] += S[i, 0] * C[i]
        for j in range(nw):
            Bbar[0, j] += S[i, 0] * B[i, j]
    Mbar1[1, 0] = Ms0[N - 1]
    Mbar1[1, 1] = M[N - 1, N - 1]
    Mbar2[1, 0] = Msd0[N - 1]
    Cbar[1] = C[N - 1]
    for j in range(nw):
        Bbar[1, j] = B[N - 1, j]
    return Mbar1, Mbar2, Cbar, Bbar, S, Sd


@jit
def wheel_speeds_rows(p, Q, ETA):
    """Wheel angular velocities Bbar(q)^T eta at every row (wheel order); model.kernels.wheel_speeds."""
    nw = 2 * p.n
    out = np.empty((Q.shape[0], nw))
    for k in range(Q.shape[0]):
        Bbar = reduced(p, Q[k], ETA[k])[3]
        for j in range(nw):
            # omega_wheel = Bbar^T eta (virtual work: tau . omega is the power into the chain)
            out[k, j] = Bbar[0, j] * ETA[k, 0] + Bbar[1, j] * ETA[k, 1]
    return out


@jit
def input_matrices_rows(p, Q):
    """Mbar1(q)^-1 Bbar(q) at every row, (K, 2, 2n): what a unit wheel torque accelerates (2.70).

    Both matrices depend on q only (eta = 0 here); diagnosis.input_matrices.
    """
    nw = 2 * p.n
    out = np.empty((Q.shape[0], 2, nw))
    eta0 = np.zeros(2)
    for k in range(Q.shape[0]):
        Mbar1, _M2, _C, Bbar, _S, _Sd = reduced(p, Q[k], eta0)
        Minv = _inv2(Mbar1)
        for j in range(nw):
            # column j of Mbar1^-1 Bbar
            out[k, 0, j] = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
            out[k, 1, j] = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
    return out


@jit
def plant_rhs(p, q, eta, tau):
    """qdot = S eta and etadot of the reduced model (2.70): Mbar1 etadot + Mbar2 eta + Cbar = Bbar tau."""
    Mbar1, Mbar2, Cbar, Bbar, S, _Sd = reduced(p, q, eta)
    # etadot = Mbar1^-1 (Bbar tau - Mbar2 eta - Cbar)
    rhs = _mv(Bbar, tau) - _mv(Mbar2, eta) - Cbar
    return _mv(S, eta), _solve2(Mbar1, rhs)


@jit
def plant_rhs_rows(p, X, TAU, out):
    """:func:`plant_rhs` at each row r of ``[q, eta]`` X and torques TAU (an input of one row serves every
    row), ``out[r] = [qdot, etadot]`` (the linearized analysis's central differences of the plant: one call
    for all their points)."""
    nq = X.shape[1] - 2
    for r in range(out.shape[0]):
        x = X[r if X.shape[0] > 1 else 0]
        qd, ed = plant_rhs(p, x[:nq], x[nq:], TAU[r if TAU.shape[0] > 1 else 0])
        out[r, :nq] = qd
        out[r, nq:] = ed
