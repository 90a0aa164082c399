r"""Compiled (numba) closed loop: the single implementation of the model, references and laws.

The reduced model, the reference jets, both kinematic laws, the dynamic law's
terms and the Farza observer exist here only.  The public classes are thin
faces over these functions: ``model.Chain`` (and ``model.kernels``),
``references.FlatReference``/``TrigPath``, ``control.kinematic.TwoLinkKinematic``/
``ChainedBackstepping``, ``control.tracking.law_terms``/``law_for_pattern`` and
``observers.farza.FarzaObserver`` hold and validate the parameters, pack them
into the NamedTuples below (``Chain``, ``Ref``, ``Kin``, ``Obs``; their
``packed()`` methods) and call these functions from Python.  Each function
cites its thesis equation and erratum (docs/ERRATA.md); the formula stands as
a comment above the line that computes it.  What checks them is independent:
the numpy derivation of M, C, A, B (model/kernels.py), the sympy chained form (tests/chained_reference.py),
the thesis's explicit matrices, invariants (S^T A^T = 0, power balance) and
closed-form references (tests).  Nothing here does I/O.

Differences of method (not of equations):

* The chained-form coordinates xi = phi(q) and T_alpha (Theorem 2.1;
  tests/chained_reference.py derives them with sympy) are computed numerically: xi_(k-1) is the
  derivative of xi_k with respect to x along g1 / cos(theta_n), so
  ``xi_(m-j) = j! y_j`` where ``y_j`` are the Taylor coefficients in s = x of y
  along the flow ``dtheta_(i+1)/ds = sec(theta_n) w_(i+1) tan(phi_i) / d_i``,
  ``dy/ds = tan(theta_n)`` (theta_1 constant: g1 does not move it).  Those are
  computed by Taylor-mode differentiation (one coefficient at a time).  Then
  ``T21 = cos(theta_n) (n+1)! y_(n+1)`` and, because xi_2 depends on theta_1 only
  through the newest coefficient of each robot in turn,
  ``T22 = sec^2(theta_n) sec^(n-1)(theta_n) prod_(i=1)^(n-1) w_(i+1) sec^2(phi_i) / d_i``.
  Both agree with the sympy derivation to round-off (tested for n = 2..6).
* 2 x 2 systems are solved in closed form, small products by loops: results
  differ from numpy/LAPACK in the last bits only.

Errors are reported through ``info`` (a float array): ``info[0]`` is a code
(``E_*`` below, 0 = none) and ``info[1:4]`` its numbers; the engine turns them
into the messages of ftcreport.errors.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .compiling import jit  # numba's njit through ftcreport's compiler: cache=True, nogil, error_model="numpy"

TIE_RTOL = 1e-9  # control.switching.TIE_RTOL (tests/test_fast.py checks they agree)

# error codes (info[0])
E_STATE_SINGULAR = 1  # info: link index i (0-based), angle [deg]
E_NONFINITE_STATE = 2
E_NONFINITE_DERIV = 3
E_SPEED = 4
E_POSITION = 5
E_TWO_LINK_ETH = 6  # info: e_theta [deg]
E_TWO_LINK_PHI = 7  # info: phi [deg]
E_CHAINED_THN = 8  # info: theta_n in frame [deg]
E_CHAINED_ART = 9  # info: link index, angle [deg]
E_KAPPA = 10  # info: kappa - Delta_1
E_REF_SPEED = 11  # info: t, robot (1-based), speed
E_REF_ART = 12  # info: t, link index, angle [deg]
E_STEP_GROWTH = 13  # info: t, max |tau| at the streak start, max |tau| now [N m]
E_UKF = 15  # info: the UKF step's status (fast.ukf.UKF_*), t
E_STEP_JUMP = 14  # info: kind, before, after (_step_jump: non-finite new state or a check failed in one step)
E_LAW_WRITE = 16  # info: the buffer a scheme wrote past (0 u, 1 dx, 2 sig, 3 its state in the discrete update), t
E_MIN_STEP = 17  # info: t, the step that fell below the minimum (error-controlled methods, fast.loop.run_auto)

# where run_steps stopped (its 4th return value)
AT_STATE = 0  # at the accepted state of step k (checks, the law at the step start, growth)
AT_TRIAL = 1  # in a trial stage of step k (RK4 k2..k4, ROS2's Jacobian and second stage)
AT_DISCRETE = 2  # in the discrete update at the end of step k

LAW_TRACKING = 0
LAW_ORACLE = 1
LAW_SWITCHING = 2
LAW_ADAPTIVE = 3
LAW_ACTIVE = 4

KIN_TWO_LINK = 0
KIN_CHAINED = 1


class Chain(NamedTuple):
    """Constant arrays of a chain, built once by model.kernels.make_params (``Chain.params``, ``ChainParams``).

    Arrays indexed ``[robot]`` are in robot order (index 0 = robot 1).
    """

    n: int
    a: np.ndarray  # (n,) P_i -> C_i [m], signed along the heading
    b: np.ndarray  # (n,) half axle length [m]
    r: np.ndarray  # (n,) wheel radius [m]
    m: np.ndarray  # (n,) mass [kg]
    I: np.ndarray  # (n,) yaw inertia about C_i [kg m^2]
    d: np.ndarray  # (n-1,) link lengths d_i = |P_i P_(i+1)| [m] (ERRATA E5c)
    m_total: float  # sum of the masses [kg]
    h: np.ndarray  # (n,) first moments h_k = sum_i m_i L[i, k] (D.5)
    G: np.ndarray  # (n, n) G = L^T diag(m) L (D.5)
    D: np.ndarray  # (n, n) D[i, k] lever arm of P_i on theta_k (C.2-C.8)


class Ref(NamedTuple):
    """A FlatReference on a TrigPath (references.py)."""

    n: int
    x0: float
    y0: float
    vx: float
    vy: float
    xterms: np.ndarray  # (k, 3): amplitude, frequency, phase
    yterms: np.ndarray
    rot: float
    ox: float
    oy: float
    d: np.ndarray
    order: int
    max_art: float
    min_speed: float


class Kin(NamedTuple):
    """Kinematic controller: two-link (3.8-3.29) or chained backstepping (3.67-3.106)."""

    kind: int
    n: int
    d2: float
    k1: float
    k2: float
    k3: float
    c_alpha2: float
    c_xi1: float
    kappa: float
    band: float
    mu: float
    singular_tol: float
    L: np.ndarray  # (p, p)
    LN_last: np.ndarray  # (p,)
    Dscale: np.ndarray  # (p,)
    rho: float
    h: float  # step of the etadot_c central difference
    nk: int  # kinematic states (0 or 1)


class Law(NamedTuple):
    """Dynamic law and its state layout (tracking, oracle, switching, adaptive, active)."""

    kind: int
    k_v: float
    sigma: np.ndarray  # (nw,) tracking pattern
    patterns: np.ndarray  # (N, nw)
    gamma: float
    T_min: float
    c_inst: float
    c_int: float
    forgetting: float
    hysteresis: float
    u_limit: float  # nan: none
    hat0: int  # switching: the superposed filters h, z_1 .. z_2n (switching_rates)
    int0: int  # switching: the integral matrix M's upper triangle (n_int values; 0: no integral cost)
    n_int: int
    sel: int
    tsw: int
    chi0: int
    uf0: int
    Gamma_f: np.ndarray  # (nw, nw)
    adapt: int
    n_states: int
    codes: np.ndarray  # (2^nw,) int64: bank index of the 0/1 pattern sum_j sigma_j 2^j, -1 if absent; (0,): no walk
    trie: np.ndarray  # (2^(nw+1),) uint8: 1 where a bank pattern has the prefix (wheels 0..d-1) of node 2^d + code;
    # trie[0] = 1: the bank is monotone (switching._walk)
    Jw: np.ndarray  # (nw,) switching: the rotors' inertia on the wheel axes the bank's filters model; (0,): none


def law_params(kind: int, k_v: float, nw: int, n_states: int, **kw) -> Law:
    """A ``Law`` with the fields a law does not use at neutral values (numba compiles one type)."""
    base = dict(
        kind=kind, k_v=k_v, sigma=np.ones(nw), patterns=np.zeros((0, nw)), gamma=0.0, T_min=0.0,
        c_inst=0.0, c_int=0.0, forgetting=0.0, hysteresis=0.0, u_limit=math.nan, hat0=0, int0=0, n_int=0, sel=0,
        tsw=0, chi0=0, uf0=0, Gamma_f=np.zeros((nw, nw)), adapt=0, n_states=n_states,
        codes=np.zeros(0, dtype=np.int64), trie=np.zeros(0, dtype=np.uint8), Jw=np.zeros(0),
    )  # fmt: skip
    base.update(kw)
    return Law(**base)


class Obs(NamedTuple):
    """Farza observer (observers/farza.py) and the active law's filters (control/active.py)."""

    Theta: float
    k0: float
    k1: float
    p_max: float  # nan: the printed law
    est_rho: int
    est_ubar: int
    p: int
    sign: float
    tau: float  # nan: unfiltered
    AY: np.ndarray  # (2N, 2N)
    Soinv: np.ndarray  # (2N, 2N)
    est0: int
    est_n: int
    filt0: int


class Cache(NamedTuple):
    """The reference side of the kinematic law at t, t + h, t - h (rows 0, 1, 2), memoized.

    ``f = [t, psi, valid]``; rows hold q_d, eta_d, eta_d_dot, (v_d, omega_d, v_d_dot,
    omega_d_dot) and, for the chained law, xi_d and T_d in the frame psi.  The RK4
    stages k2, k3 and k4, the discrete update and the next k1 ask for the same
    instants (the Python reference memoizes them the same way).
    """

    f: np.ndarray  # (3,)
    QD: np.ndarray  # (3, N)
    ED: np.ndarray  # (3, 2)
    EDD: np.ndarray  # (3, 2)
    SC: np.ndarray  # (3, 4)
    XID: np.ndarray  # (3, m)
    TD: np.ndarray  # (3, 2, 2)
    # the controller's Mbar1, Mbar2, Cbar, Bbar, S at the measured (q, eta) of the last evaluation:
    # without noise and with the plant's parameters they are the plant's (f[3] = 1: valid)
    M1: np.ndarray  # (2, 2)
    M2: np.ndarray  # (2, 2)
    Cb: np.ndarray  # (2,)
    Bb: np.ndarray  # (2, 2n)
    Sm: np.ndarray  # (N, 2)
    # the kinematic law's outputs at rows 0 (t), 1 (t + h), 2 (t - h), and its work space
    KEC: np.ndarray  # (3, 2) eta_c
    KT: np.ndarray  # (3, 2, 2) T_alpha
    KF: np.ndarray  # (3, 2) f_eta
    KZ: np.ndarray  # (3, m) error coordinates
    KA: np.ndarray  # (3, 2) f_alpha of alpha = T_alpha eta + f_alpha (two-link law; the chained law's is 0, 3.98)
    WJ: np.ndarray  # jets of chained_xi_T
    WQ: np.ndarray  # (N,) q in the frame
    WP: np.ndarray  # (N,) q +/- h qdot
    WXI: np.ndarray  # (m,) xi
    WV: np.ndarray  # (3, m) Zhat, Zbar, L^T Zbar
    WR: np.ndarray  # (n + 4, max(n, 3)) ref_point's work space


@jit
def new_cache(n):
    N = n + 2
    return Cache(
        np.zeros(4), np.zeros((3, N)), np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 4)), np.zeros((3, N)),
        np.zeros((3, 2, 2)), np.zeros((2, 2)), np.zeros((2, 2)), np.zeros(2), np.zeros((2, 2 * n)), np.zeros((N, 2)),
        np.zeros((3, 2)), np.zeros((3, 2, 2)), np.zeros((3, 2)), np.zeros((3, N)), np.zeros((3, 2)),
        np.zeros((9 * n, n + 2)), np.zeros(N), np.zeros(N), np.zeros(N), np.zeros((3, N)), np.zeros((n + 4, max(n, 3))),
    )  # fmt: skip


# =========================================================================== helpers
@jit
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@jit
def _solve2(A, b):
    """x with A x = b for a 2 x 2 A (closed form)."""
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    x = np.empty(2)
    x[0] = (A[1, 1] * b[0] - A[0, 1] * b[1]) / det
    x[1] = (A[0, 0] * b[1] - A[1, 0] * b[0]) / det
    return x


@jit
def _inv2(A):
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out = np.empty((2, 2))
    out[0, 0] = A[1, 1] / det
    out[0, 1] = -A[0, 1] / det
    out[1, 0] = -A[1, 0] / det
    out[1, 1] = A[0, 0] / det
    return out


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


# =========================================================================== references (references.py)
@jit
def path_jets(R, t):
    """Normalized Taylor coefficients (f^(k)(t) / k!) of x_d, y_d at t (references.TrigPath).

    x = x0 + vx t + sum_j a_j sin(w_j t + ph_j) in the path frame, likewise y, then rotated by R.rot
    and translated by (R.ox, R.oy).  The thesis's references (3.5-3.7, the eight of 3.3.2.3 with
    ERRATA E11) are such paths.
    """
    K1 = R.order + 1
    X = np.zeros(K1)
    Y = np.zeros(K1)
    X[0] = R.x0 + R.vx * t
    Y[0] = R.y0 + R.vy * t
    if K1 > 1:
        X[1] += R.vx
        Y[1] += R.vy
    for which in range(2):
        terms = R.xterms if which == 0 else R.yterms
        arr = X if which == 0 else Y
        for j in range(terms.shape[0]):
            amp, w, ph = terms[j, 0], terms[j, 1], terms[j, 2]
            fact = 1.0
            for k in range(K1):
                if k > 0:
                    fact *= k
                # d^k/dt^k A sin(w t + ph) = A w^k sin(w t + ph + k pi / 2)
                arr[k] += amp * w**k * math.sin(w * t + ph + k * np.pi / 2) / fact
    c, s = math.cos(R.rot), math.sin(R.rot)
    # world = origin + R(rot) (x, y)
    Xw = c * X - s * Y
    Yw = s * X + c * Y
    Xw[0] += R.ox
    Yw[0] += R.oy
    return Xw, Yw


@jit
def _conv(a, b, k):
    """Coefficient k of the product of two jets."""
    acc = 0.0
    for i in range(k + 1):
        acc += a[i] * b[k - i]
    return acc


@jit
def ref_jets(R, t, info):
    """Jets of every heading (rows, robot order) and of v_n at t: the flat outputs (3.59)-(3.66) for any n.

    From P_n's path: theta_nd = atan2(ydot_d, xdot_d), v_nd = xdot_d cos theta_nd + ydot_d sin theta_nd,
    P_(i)d = P_(i+1)d + d_i U_(i+1)d (ERRATA E5, E5c), theta_id the direction of Pdot_(i)d; each robot
    loses one order of the jet.  Refuses speeds below R.min_speed (info E_REF_SPEED).
    """
    X0, Y0 = path_jets(R, t)
    n = R.n
    K1 = R.order + 1
    TH = np.zeros((n, K1))
    LEN = np.zeros(n, dtype=np.int64)
    V = np.zeros(K1)
    wk = np.zeros((11, K1))  # one allocation for the work jets
    X, Y, Xd, Yd, Xdd, Ydd, num, den, s, c = wk[0], wk[1], wk[2], wk[3], wk[4], wk[5], wk[6], wk[7], wk[8], wk[9]
    w = wk[10]
    X[:] = X0
    Y[:] = Y0
    L = K1
    for i in range(n - 1, -1, -1):
        for k in range(L - 1):
            Xd[k] = X[k + 1] * (k + 1)
            Yd[k] = Y[k + 1] * (k + 1)
        speed = math.hypot(Xd[0], Yd[0])
        if speed < R.min_speed:
            info[0] = E_REF_SPEED
            info[1] = t
            info[2] = i + 1
            info[3] = speed
            return X0, Y0, TH, LEN, V
        m = L - 2
        for k in range(m):
            Xdd[k] = Xd[k + 1] * (k + 1)
            Ydd[k] = Yd[k + 1] * (k + 1)
        for k in range(m):
            # thetadot = (xdot yddot - ydot xddot) / (xdot^2 + ydot^2)
            num[k] = _conv(Xd, Ydd, k) - _conv(Yd, Xdd, k)
            den[k] = _conv(Xd, Xd, k) + _conv(Yd, Yd, k)
        th = TH[i]
        th[0] = math.atan2(Yd[0], Xd[0])
        for k in range(m):  # thetadot = num / den (jet quotient), integrated
            acc = num[k]
            for j in range(1, k + 1):
                acc -= den[j] * w[k - j]
            w[k] = acc / den[0]
            th[k + 1] = w[k] / (k + 1)
        LEN[i] = m + 1
        s[0] = math.sin(th[0])
        c[0] = math.cos(th[0])
        # jets of sin and cos: k s_k = sum_j j th_j c_(k-j), k c_k = -sum_j j th_j s_(k-j)
        for k in range(1, m + 1):
            a = 0.0
            b = 0.0
            for j in range(1, k + 1):
                a += j * th[j] * c[k - j]
                b += j * th[j] * s[k - j]
            s[k] = a / k
            c[k] = -b / k
        if i == n - 1:
            for k in range(m + 1):
                # v_n = xdot cos theta_n + ydot sin theta_n
                V[k] = _conv(Xd, c, k) + _conv(Yd, s, k)
        if i > 0:
            L = m + 1
            for k in range(L):
                # P_i = P_(i+1) + d_i (cos theta_(i+1), sin theta_(i+1))
                X[k] = X[k] + R.d[i - 1] * c[k]
                Y[k] = Y[k] + R.d[i - 1] * s[k]
    return X0, Y0, TH, LEN, V


@jit
def _shift3(a, length, delta, out):
    """First 3 normalized Taylor coefficients at t0 + delta of the jet a at t0, into out."""
    for i in range(3):
        s = 0.0
        for j in range(i, length):
            # b_i = sum_(j >= i) C(j, i) a_j delta^(j - i)
            comb = 1.0 if i == 0 else (float(j) if i == 1 else 0.5 * j * (j - 1))  # C(j, i), i <= 2
            s += comb * a[j] * delta ** (j - i)
        out[i] = s


@jit
def ref_point(R, jets, t, delta, info, q_d, eta_d, eta_d_dot, sc, work):
    """The reference state at t0 + delta from the jets at t0: q_d, eta_d, eta_d_dot and sc = (v_d, omega_d,
    v_d_dot, omega_d_dot) of robot n (the two-link scheme's unicycle, 3.5-3.7).  Headings are unwrapped along
    the chain; an articulation angle beyond R.max_art is refused (info E_REF_ART).
    After the call ``work[:n, :3]`` holds the first three coefficients of every heading (thetadot_id in column 1).

    ``work``: (n + 4, max(n, 3)) scratch (no allocation: this runs for three instants per new t).
    """
    X0, Y0, TH, LEN, V = jets
    n = R.n
    K1 = R.order + 1
    N = n + 2
    th3 = work[:n, :3]
    X, Y, v, th = work[n, :3], work[n + 1, :3], work[n + 2, :3], work[n + 3, :n]
    if delta != 0.0:
        _shift3(X0, K1, delta, X)
        _shift3(Y0, K1, delta, Y)
        _shift3(V, LEN[n - 1], delta, v)
        for i in range(n):
            _shift3(TH[i], LEN[i], delta, th3[i])
    else:
        X[:] = X0[:3]
        Y[:] = Y0[:3]
        v[:] = V[:3]
        for i in range(n):
            th3[i] = TH[i, :3]
    for i in range(n):
        th[i] = th3[i, 0]
    for i in range(n - 2, -1, -1):
        th[i] = th[i + 1] + _wrap(th[i] - th[i + 1])
    worst = -1.0
    iw = 0
    for i in range(n - 1):
        a = abs(th[i] - th[i + 1])
        if a > worst:
            worst = a
            iw = i
    if n > 1 and worst > R.max_art:
        info[0] = E_REF_ART
        info[1] = t
        info[2] = iw
        info[3] = math.degrees(th[iw] - th[iw + 1])
        return
    # q_d = [x_d, y_d, theta_nd, ..., theta_1d] (2.60), eta_d = [v_nd, omega_1d], etadot_d = [vdot_nd, 2 th_1,2]
    q_d[0] = X[0]
    q_d[1] = Y[0]
    for k in range(n):
        q_d[N - 1 - k] = th[k]
    eta_d[0] = v[0]
    eta_d[1] = th3[0, 1]
    eta_d_dot[0] = v[1]
    eta_d_dot[1] = 2.0 * th3[0, 2]
    sc[0] = v[0]
    sc[1] = th3[n - 1, 1]
    sc[2] = v[1]
    sc[3] = 2.0 * th3[n - 1, 2]


@jit
def ref_side(Kp, R, C, t, psi, info):
    """Fill the cache for instant t and frame psi (a no-op when it already holds them)."""
    if C.f[2] == 1.0 and C.f[0] == t and C.f[1] == psi:
        return
    C.f[2] = 0.0
    jets = ref_jets(R, t, info)
    if info[0] != 0:
        return
    h = Kp.h
    for i in range(3):
        ti = t if i == 0 else (t + h if i == 1 else t - h)
        ref_point(R, jets, ti, ti - t, info, C.QD[i], C.ED[i], C.EDD[i], C.SC[i], C.WR)
        if info[0] != 0:
            return
        if Kp.kind == KIN_CHAINED:
            xi_T(to_frame(C.QD[i], psi, C.WQ), R.d, C.WJ, C.XID[i], C.TD[i])
    C.f[0] = t
    C.f[1] = psi
    C.f[2] = 1.0


# =========================================================================== chained form
@jit
def chained_xi_T(th, d, work, ang):
    """xi_2..xi_(m-1) into ang, and (T21, T22), at headings th (robot order); see the module doc.

    ``work``: at least (9 n, n + 2) scratch (every jet below lives in it).
    """
    n = th.shape[0]
    K = n + 1
    nl = n - 1
    work[:] = 0.0
    TH = work[0:n]
    W = work[n : 2 * n]
    P1 = work[2 * n : 3 * n]
    RHS = work[3 * n : 4 * n]
    o = 4 * n
    PHI = work[o : o + nl]
    SP = work[o + nl : o + 2 * nl]
    CP = work[o + 2 * nl : o + 3 * nl]
    SEC = work[o + 3 * nl : o + 4 * nl]
    TAN = work[o + 4 * nl : o + 5 * nl]
    o += 5 * nl
    Y = work[o]
    STN = work[o + 1]
    CTN = work[o + 2]
    SECN = work[o + 3]
    TANN = work[o + 4]
    for k in range(n):
        TH[k, 0] = th[k]
    W[n - 1, 0] = 1.0
    last = n - 1
    for j in range(K):
        # coefficient j of every intermediate (Taylor-mode recurrences)
        for l in range(nl):
            PHI[l, j] = TH[l, j] - TH[l + 1, j]
            if j == 0:
                SP[l, 0] = math.sin(PHI[l, 0])
                CP[l, 0] = math.cos(PHI[l, 0])
            else:
                a = 0.0
                b = 0.0
                for i in range(1, j + 1):
                    a += i * PHI[l, i] * CP[l, j - i]
                    b += i * PHI[l, i] * SP[l, j - i]
                SP[l, j] = a / j
                CP[l, j] = -b / j
            s = 1.0 if j == 0 else 0.0
            for i in range(1, j + 1):
                s -= CP[l, i] * SEC[l, j - i]
            SEC[l, j] = s / CP[l, 0]
            s = 0.0
            for i in range(j + 1):
                s += SP[l, i] * SEC[l, j - i]
            TAN[l, j] = s
        if j == 0:
            STN[0] = math.sin(TH[last, 0])
            CTN[0] = math.cos(TH[last, 0])
        else:
            a = 0.0
            b = 0.0
            for i in range(1, j + 1):
                a += i * TH[last, i] * CTN[j - i]
                b += i * TH[last, i] * STN[j - i]
            STN[j] = a / j
            CTN[j] = -b / j
        s = 1.0 if j == 0 else 0.0
        for i in range(1, j + 1):
            s -= CTN[i] * SECN[j - i]
        SECN[j] = s / CTN[0]
        s = 0.0
        for i in range(j + 1):
            s += STN[i] * SECN[j - i]
        TANN[j] = s
        for k in range(n - 2, -1, -1):  # w_k = w_(k+1) sec(phi_k)
            s = 0.0
            for i in range(j + 1):
                s += W[k + 1, i] * SEC[k, j - i]
            W[k, j] = s
        for k in range(1, n):  # dtheta_k/ds = sec(theta_n) w_k tan(phi_(k-1)) / d_(k-1)
            s = 0.0
            for i in range(j + 1):
                s += SECN[i] * W[k, j - i]
            P1[k, j] = s
            s = 0.0
            for i in range(j + 1):
                s += P1[k, i] * TAN[k - 1, j - i]
            RHS[k, j] = s / d[k - 1]
            TH[k, j + 1] = RHS[k, j] / (j + 1)
        Y[j + 1] = TANN[j] / (j + 1)
    m = n + 2  # xi_2..xi_(m-1): xi_(m-jj) = jj! y_jj
    fact = 1.0
    for jj in range(1, n + 1):
        fact *= jj
        ang[m - jj - 2] = fact * Y[jj]
    T21 = CTN[0] * fact * (n + 1) * Y[n + 1]
    secn = SECN[0]
    T22 = secn * secn * secn ** (n - 1)
    for l in range(nl):
        T22 *= W[l + 1, 0] * SEC[l, 0] * SEC[l, 0] / d[l]
    return T21, T22


@jit
def to_frame(q, psi, out):
    """q in the frame rotated by psi, into out: theta_n wrapped in the frame, every other heading keeps its
    (wrapped) articulation angle to its follower (the re-anchoring of control/kinematic.py, beyond the thesis)."""
    c, s = math.cos(psi), math.sin(psi)
    out[0] = c * q[0] + s * q[1]
    out[1] = -s * q[0] + c * q[1]
    out[2] = _wrap(q[2] - psi)
    acc = out[2]
    for k in range(3, q.shape[0]):
        acc = acc + _wrap(q[k] - q[k - 1])
        out[k] = acc
    return out


@jit
def xi_T(qf, d, work, xi, T):
    """Chained coordinates xi = phi(q) (m,) and T_alpha (2, 2) at q (in its frame), into xi and T.

    Theorem 2.1 for any n (the module doc; ERRATA E5e-E5g: the printed (2.94), (2.99), (3.98) are wrong,
    this is checked against the sympy derivation of tests/chained_reference.py).  alpha = T_alpha eta (3.98).
    """
    n = qf.shape[0] - 2
    m = n + 2
    T21, T22 = chained_xi_T(qf[m - 1 : 1 : -1], d, work, xi[1 : m - 1])  # headings in robot order (a view)
    # xi_1 = x, xi_m = y;  T_alpha = [[cos theta_n, 0], [T21, T22]]
    xi[0] = qf[0]
    xi[m - 1] = qf[1]
    T[0, 0] = math.cos(qf[2])  # theta_n, the last robot
    T[0, 1] = 0.0
    T[1, 0] = T21
    T[1, 1] = T22


@jit
def _chained_law(Kp, R, C, ir, q, psi, info):
    """Recursive backstepping on the chained form into row ir of the cache: eta_c, T_alpha, f_eta, Z.

    Thesis (3.67)-(3.106) generalized to any n (derivation in control/kinematic.py's module doc), with
    ERRATA E12a ((3.95), hence 3.103), E12b ((3.102)), E12c ((3.105)) and E12d (gains c_j on every virtual
    control, in L); length scale mu and frame psi beyond the thesis.  Refuses |theta_n| or an articulation
    angle near 90 deg in the frame (E_CHAINED_*) and kappa - Delta_1 near 0 (E_KAPPA).
    """
    eta_d = C.ED[ir]
    qf = to_frame(q, psi, C.WQ)
    n = Kp.n
    m = n + 2
    p = m - 1
    eta_c, T, f_eta, Z = C.KEC[ir], C.KT[ir], C.KF[ir], C.KZ[ir]
    # check_domain
    if abs(math.cos(qf[2])) <= Kp.singular_tol:
        info[0] = E_CHAINED_THN
        info[1] = math.degrees(qf[2])
        return
    worst = 2.0
    iw = 0
    for i in range(n - 1):  # robot order i, i+1: q index m-1-i, m-2-i
        c = math.cos(qf[m - 1 - i] - qf[m - 2 - i])
        if c < worst:
            worst = c
            iw = i
    if n > 1 and worst <= Kp.singular_tol:
        info[0] = E_CHAINED_ART
        info[1] = iw
        info[2] = math.degrees(qf[m - 1 - iw] - qf[m - 2 - iw])
        return
    xi = C.WXI
    xi_T(qf, R.d, C.WJ, xi, T)
    xi_d, T_d = C.XID[ir], C.TD[ir]
    # alpha_d = T_alpha(q_d) eta_d
    a1d = T_d[0, 0] * eta_d[0] + T_d[0, 1] * eta_d[1]
    a2d = T_d[1, 0] * eta_d[0] + T_d[1, 1] * eta_d[1]
    e0 = xi[0] - xi_d[0]
    for j in range(1, m - 1):  # Z_j = xi_e,(m+1-j) - xi_(m-j) xi_e,1
        Z[j - 1] = (xi[m - j] - xi_d[m - j]) - xi[m - j - 1] * e0
    Z[m - 2] = xi[1] - xi_d[1]
    Z[m - 1] = e0
    mu = Kp.mu
    Zh, Zbar, LtZ = C.WV[0], C.WV[1], C.WV[2]
    for j in range(p):
        # Zhat_j = mu^-(j-1) Z_j
        Zh[j] = Z[j] * Kp.Dscale[j]
    z = Z[m - 1]
    lnz = 0.0
    for j in range(p):
        lnz += Kp.LN_last[j] * Zh[j]
        acc = 0.0
        for i in range(j + 1):  # L is lower triangular
            acc += Kp.L[j, i] * Zh[i]
        # Zbar = L Zhat
        Zbar[j] = acc
    # alpha_2c = alpha_2d + mu^(p-1) [-c_a2 Zbar_p - mu alpha_1d (Zbar_(p-1) + row_p N Zhat)]   (3.102, E12b)
    a2c = a2d + mu ** (p - 1) * (-Kp.c_alpha2 * Zbar[p - 1] - mu * a1d * (Zbar[p - 2] + lnz))
    for i in range(p):
        acc = 0.0
        for j in range(i, p):
            acc += Kp.L[j, i] * Zbar[j]
        # rho (L^T Zbar)_i mu^-(i-1)
        LtZ[i] = Kp.rho * acc * Kp.Dscale[i]
    # Delta_1 = sum_(j<=p-2) rho (L^T Zbar)_j mu^-(j-1) xi_(m-1-j),  Gamma = rho (L^T Zbar)_(p-1) mu^-(p-2)  (3.93)
    delta1 = 0.0
    for j in range(1, p - 1):
        delta1 += LtZ[j - 1] * xi[m - 2 - j]
    gam = LtZ[p - 2]
    kd = Kp.kappa - delta1
    if abs(kd) < Kp.singular_tol * Kp.kappa:
        info[0] = E_KAPPA
        info[1] = kd
        return
    # alpha_1c = alpha_1d + (kappa - Delta_1)^-1 (-c_z z + Gamma alpha_2c)   (3.103, E12a)
    a1c = a1d + (-Kp.c_xi1 * z + gam * a2c) / kd
    det = T[0, 0] * T[1, 1] - T[0, 1] * T[1, 0]  # eta_c = T^-1 alpha_c
    eta_c[0] = (T[1, 1] * a1c - T[0, 1] * a2c) / det
    eta_c[1] = (T[0, 0] * a2c - T[1, 0] * a1c) / det
    # f_eta = [z (kappa - Delta_1), rho mu^-(p-1) Zbar_p - z Gamma]   (3.105, E12c)
    f_eta[0] = z * kd
    f_eta[1] = Kp.rho * Kp.Dscale[p - 1] * Zbar[p - 1] - z * gam


@jit
def _two_link_law(Kp, C, ir, q, info):
    """Two-link diffeomorphism controller into row ir of the cache: eta_c, T_alpha, f_eta, z.

    Thesis (3.8)-(3.29) and Appendices F, G with ERRATA E6 (z4), E7 (z3'), E9 (alpha_2c), E10 (T_alpha,
    f_alpha of Appendix G once E6 is applied), E11a (alpha_1).  Refuses cos e_theta or cos phi below 1e-3.
    """
    q_d = C.QD[ir]
    vd, wd, vdd, wdd = C.SC[ir, 0], C.SC[ir, 1], C.SC[ir, 2], C.SC[ir, 3]
    d = Kp.d2
    thd = q_d[2]
    ct, st = math.cos(thd), math.sin(thd)
    exw, eyw = q[0] - q_d[0], q[1] - q_d[1]
    # e = T_e (q - q_d)   (3.8)-(3.10)
    ex = ct * exw + st * eyw
    ey = -st * exw + ct * eyw
    eth = _wrap(q[2] - thd)
    c, s = math.cos(eth), math.sin(eth)
    phi = q[3] - q[2]
    cphi = math.cos(phi)
    eta_c, T, f_eta, z = C.KEC[ir], C.KT[ir], C.KF[ir], C.KZ[ir]
    if abs(c) < 1e-3:
        info[0] = E_TWO_LINK_ETH
        info[1] = math.degrees(eth)
        return
    if abs(cphi) < 1e-3:
        info[0] = E_TWO_LINK_PHI
        info[1] = math.degrees(phi)
        return
    tphi = math.tan(phi)
    sec2 = 1.0 / cphi**2
    # z1 = e_x, z2 = e_y, z3 = tan e_theta, z4 = tan(phi) / (d c^3) - omega_d / (v_d c^2) + e_y   (3.14-3.17, E6)
    z[0] = ex
    z[1] = ey
    z[2] = s / c
    z[3] = tphi / (d * c**3) - wd / (vd * c**2) + ey
    # alpha_1 = v_2 cos e_theta - v_d (E11a);  alpha_2 = z4' = T21 v_2 + T22 omega_1 + f2 (Appendix G, E6, E10)
    T21 = -sec2 * tphi / (d**2 * c**3) + 3.0 * tphi**2 * s / (d**2 * c**4) - 2.0 * wd * s * tphi / (d * vd * c**3) + s
    T22 = sec2 / (d * c**3)
    f2 = (
        -3.0 * tphi * s * wd / (d * c**4)
        - (wdd * vd - wd * vdd) / (vd**2 * c**2)
        + 2.0 * wd**2 * s / (vd * c**3)
        - wd * ex
    )
    T[0, 0] = c
    T[0, 1] = 0.0
    T[1, 0] = T21
    T[1, 1] = T22
    # f_alpha = [-v_d, f2]   (3.29, Appendix G with E10)
    C.KA[ir, 0] = -vd
    C.KA[ir, 1] = f2
    z1, z3, z4 = z[0], z[2], z[3]
    # g = z1 + z3 (z4 + (omega_d / v_d)(1 + z3^2));  alpha_c = [-k1 g, -k2 v_d z3 - k3 z4]   (3.27)-(3.28), E9
    g = z1 + z3 * (z4 + (wd / vd) * (1.0 + z3**2))
    r0 = -Kp.k1 * g - C.KA[ir, 0]
    r1 = -Kp.k2 * vd * z3 - Kp.k3 * z4 - C.KA[ir, 1]
    det = T[0, 0] * T[1, 1] - T[0, 1] * T[1, 0]  # eta_c = T^-1 (alpha_c - f_alpha)   (3.29)
    eta_c[0] = (T[1, 1] * r0 - T[0, 1] * r1) / det
    eta_c[1] = (T[0, 0] * r1 - T[1, 0] * r0) / det
    # f_eta = [g, z4 / k2] (the Lyapunov cross term the dynamic law cancels, E8)
    f_eta[0] = g
    f_eta[1] = z4 / Kp.k2


@jit
def kin_law(Kp, R, C, ir, q, xk, info):
    """The kinematic law into row ir of the cache (ir: 0 at t, 1 at t + h, 2 at t - h)."""
    if Kp.kind == KIN_TWO_LINK:
        _two_link_law(Kp, C, ir, q, info)
    else:
        _chained_law(Kp, R, C, ir, q, xk[0], info)


@jit
def eta_c_and_dot(Kp, R, C, S, t, q, eta, xk, info):
    """TrackingController.eta_c_and_dot: law at t and the central difference along (S(q) eta, 1) (ERRATA P5).

    Returns ``((eta_c, T_alpha, f_eta, z), etadot_c)``; the first four are views of
    cache row 0, valid until the next evaluation.
    """
    kin = (C.KEC[0], C.KT[0], C.KF[0], C.KZ[0])
    ecd = np.zeros(2)
    ref_side(Kp, R, C, t, xk[0] if Kp.nk > 0 else 0.0, info)
    if info[0] != 0:
        return kin, ecd
    h = Kp.h
    # one call site with a run-time row index: a literal 0, 1, 2 would make numba compile three copies
    for ir in range(3):
        if ir == 0:
            C.WP[:] = q
        else:
            sgn = 1.0 if ir == 1 else -1.0
            for i in range(q.shape[0]):
                C.WP[i] = q[i] + sgn * h * (S[i, 0] * eta[0] + S[i, 1] * eta[1])
        kin_law(Kp, R, C, ir, C.WP, xk, info)
        if info[0] != 0:
            return kin, ecd
    ecd[0] = (C.KEC[1, 0] - C.KEC[2, 0]) / (2.0 * h)
    ecd[1] = (C.KEC[1, 1] - C.KEC[2, 1]) / (2.0 * h)
    return kin, ecd


# =========================================================================== dynamic laws (control/tracking.py)
@jit
def _mv(A, x):
    """A x for a small dense A (no BLAS call)."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * x[j]
        out[i] = acc
    return out


@jit
def law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, T, f_eta, eta_c_dot, k_v):
    """(w, MB = Mbar1^-1 Bbar, g) of the dynamic law (3.35)/(3.107), with ERRATA E8 (T_alpha^T f_eta).

    The pattern-independent part: u_(k) = (MB sigma_(k))^+ w (law_for_pattern) gives
    eta_e' = -k_v eta_e - T_alpha^T f_eta when sigma_(k) is the true pattern.
    """
    Minv = _inv2(Mbar1)
    # g = -Mbar1^-1 (Mbar2 eta + Cbar)   (the free dynamics)
    g = -_mv(Minv, _mv(Mbar2, eta) + Cbar)
    # w = -k_v eta_e - T_alpha^T f_eta + Mbar1^-1 (Mbar2 eta + Cbar) + etadot_c
    w = -k_v * eta_e - _mv(T.T, f_eta) - g + eta_c_dot
    nw = Bbar.shape[1]
    MB = np.empty((2, nw))
    for j in range(nw):
        MB[0, j] = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
        MB[1, j] = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
    return w, MB, g


@jit
def _gram(MB, sigma):
    """A A^T for A = MB diag(sigma)."""
    G = np.zeros((2, 2))
    for j in range(MB.shape[1]):
        s2 = sigma[j] * sigma[j]
        G[0, 0] += MB[0, j] * MB[0, j] * s2
        G[0, 1] += MB[0, j] * MB[1, j] * s2
        G[1, 1] += MB[1, j] * MB[1, j] * s2
    G[1, 0] = G[0, 1]
    return G


@jit
def _right_inverse(MB, sigma, AAt, w):
    """A^T (A A^T)^-1 w for A = MB diag(sigma)."""
    y = _solve2(AAt, w)
    nw = MB.shape[1]
    u = np.empty(nw)
    for j in range(nw):
        u[j] = sigma[j] * (MB[0, j] * y[0] + MB[1, j] * y[1])
    return u


@jit
def law_for_pattern(MB, w, sigma):
    """u_(k) = (MB diag(sigma_(k)))^+ w, thesis (3.35)/(3.107), minimum-norm A^+ = A^T (A A^T)^-1.

    Least squares (pinv) when cond(A A^T) > 1e12: a pattern with rank < 2 (ERRATA E5d), e.g. the
    oracle facing an uncompensable fault.
    """
    AAt = _gram(MB, sigma)
    tr = 0.5 * (AAt[0, 0] + AAt[1, 1])
    det = AAt[0, 0] * AAt[1, 1] - AAt[0, 1] * AAt[1, 0]
    lmax = tr + math.sqrt(max(tr * tr - det, 0.0))
    if not det / lmax > lmax * 1e-12:  # cond(A A^T) = lmax / lmin, lmin = det / lmax
        nw = MB.shape[1]
        A = np.empty((2, nw))
        for j in range(nw):
            A[0, j] = MB[0, j] * sigma[j]
            A[1, j] = MB[1, j] * sigma[j]
        return np.linalg.pinv(A, rcond=1e-9) @ w
    # u = A^T (A A^T)^-1 w
    return _right_inverse(MB, sigma, AAt, w)


@jit
def _clip(x, lo, hi):
    return np.minimum(np.maximum(x, lo), hi)


# =========================================================================== Farza observer (observers/farza.py)
@jit
def farza_estimates(O, pc, s, y, nw):
    """(q_hat, eta_hat, rho, ubar) from the observer state (thesis 4.2.3.2); nominal values where not estimated."""
    N = pc.n + 2
    S = s_matrix(pc, y)
    # eta_hat = S(y)^+ qdot_hat = (S^T S)^-1 S^T qdot_hat
    eta = _solve2(S.T @ S, S.T @ s[N : 2 * N])
    rho = np.ones(nw)
    ubar = np.zeros(nw)
    k = 2 * N
    if O.est_rho:
        rho = s[k : k + nw].copy()
        k += nw
    if O.est_ubar:
        ubar = s[k : k + nw].copy()
    return s[:N].copy(), eta, rho, ubar


@jit
def farza_derivative(O, pc, u, y, s):
    """Observer state derivative (4.4)-(4.11) with ERRATA E15 (signs), E16 (phi_2) and the P guard (P3).

    The equations of observers/farza.py's module doc, grouped for small dense loops:
    (S_o^-1 + Y P Y^T) C^T K = S_o^-1 C^T K + Y (P v) with v = (C Y)^T K, and
    P Y^T C^T C Y P = W^T W with W = C Y P.  eta = S^+ qdot by the normal equations.
    """
    N = pc.n + 2
    nw = 2 * pc.n
    P_ = O.p
    Th = O.Theta
    o_rho = 2 * N
    o_Y = o_rho + P_
    o_P = o_Y + 2 * N * P_
    Y = s[o_Y:o_P].reshape((2 * N, P_))
    P = s[o_P : o_P + P_ * P_].reshape((P_, P_))
    rho = np.ones(nw)
    ubar = np.zeros(nw)
    k = 0
    if O.est_rho:
        rho = s[o_rho : o_rho + nw]
        k = nw
    if O.est_ubar:
        ubar = s[o_rho + k : o_rho + k + nw]
    q = s[:N]
    qdot = s[N : 2 * N]
    S0 = s_matrix(pc, q)
    eta = _solve2(S0.T @ S0, _mv(S0.T, qdot))  # S^+ qdot (S has full column rank)
    Mbar1, Mbar2, Cbar, Bbar, S, Sdot = reduced(pc, q, eta)
    Minv = _inv2(Mbar1)
    MB = np.empty((2, nw))
    for j in range(nw):
        MB[0, j] = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
        MB[1, j] = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
    tq = rho * u + ubar
    # Mbar1^-1 (-Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar))   (E16)
    acc = -_mv(Minv, _mv(Mbar2, eta) + Cbar) + _mv(MB, tq)
    ds = np.empty(s.shape[0])
    # correction terms
    Kt = np.empty(N)
    for i in range(N):
        # K(ytilde) = k1 tanh(k0 (y - C xhat))   (E15: ytilde = y - C xhat)
        Kt[i] = O.k1 * math.tanh(O.k0 * (y[i] - s[i]))
    v = np.zeros(P_)  # (C Y)^T K
    for a in range(P_):
        acc_v = 0.0
        for i in range(N):
            acc_v += Y[i, a] * Kt[i]
        v[a] = acc_v
    Pv = _mv(P, v)
    YPv = _mv(Y, Pv)
    SoK = _mv(O.Soinv[:, :N], Kt)
    sgn = O.sign * Th
    # xhat' = A xhat + phi + Theta Delta^-1 (S_o^-1 + Y P Y^T) C^T K, Delta^-1 = diag(I, Theta I)   (E15)
    for i in range(N):
        ds[i] = s[N + i] + sgn * (SoK[i] + YPv[i])
        # phi_2 = S acc + Sdot eta
        ds[N + i] = S[i, 0] * acc[0] + S[i, 1] * acc[1] + Sdot[i, 0] * eta[0] + Sdot[i, 1] * eta[1]
        ds[N + i] += sgn * Th * (SoK[N + i] + YPv[N + i])
    for a in range(P_):
        # rhohat' = Theta P Y^T C^T K   (E15)
        ds[o_rho + a] = sgn * Pv[a]
    # Y' = Theta (A - S_o^-1 C^T C) Y + Delta dphi/drho_bar, with dphi_2/drho_bar = S MB [diag(u), I]
    AY = O.AY
    dY = ds[o_Y:o_P].reshape((2 * N, P_))
    for i in range(2 * N):
        for a in range(P_):
            dY[i, a] = 0.0
        for kk in range(2 * N):
            c = AY[i, kk]
            if c != 0.0:
                for a in range(P_):
                    dY[i, a] += c * Y[kk, a]
    for i in range(N):
        for j in range(nw):
            smb = S[i, 0] * MB[0, j] + S[i, 1] * MB[1, j]
            c0 = 0
            if O.est_rho:
                dY[N + i, j] += smb * u[j] / Th
                c0 = nw
            if O.est_ubar:
                dY[N + i, c0 + j] += smb / Th
    # P' = Theta P - Theta W^T W - Theta P P / p_max,  W = C Y P
    W = np.zeros((N, P_))
    for i in range(N):
        for b in range(P_):
            acc_w = 0.0
            for a in range(P_):
                acc_w += Y[i, a] * P[a, b]
            W[i, b] = acc_w
    dP = ds[o_P : o_P + P_ * P_].reshape((P_, P_))
    guard = not math.isnan(O.p_max)
    for a in range(P_):
        for b in range(P_):
            acc_p = 0.0
            for i in range(N):
                acc_p += W[i, a] * W[i, b]
            val = Th * P[a, b] - Th * acc_p
            if guard:
                acc_pp = 0.0
                for c in range(P_):
                    acc_pp += P[a, c] * P[c, b]
                val -= Th * acc_pp / O.p_max
            dP[a, b] = val
    return ds


# =========================================================================== the closed loop
@jit
def _kin_signals(sig, kin, ecd, C):
    """eta_c, eta_c_dot, z, q_d, eta_d into sig; returns the next free index."""
    z = kin[3]
    q_d = C.QD[0]
    sig[0:2] = kin[0]
    sig[2:4] = ecd
    k = 4
    sig[k : k + z.shape[0]] = z
    k += z.shape[0]
    sig[k : k + q_d.shape[0]] = q_d
    k += q_d.shape[0]
    sig[k : k + 2] = C.ED[0]
    return k + 2


@jit
def kin_discrete(Kp, R, C, t, xc, info):
    """After each step, the chained law's re-anchoring: psi jumps to theta_d when it leaves the band."""
    if Kp.kind == KIN_CHAINED:
        ref_side(Kp, R, C, t, xc[0], info)
        if info[0] != 0:
            return
        thd = C.QD[0, 2]
        if abs(_wrap(thd - xc[0])) > Kp.band:
            xc[0] = thd


# =========================================================================== the schemes' building blocks
# The schemes' laws are ftcreport/schemes/laws (the scheme API's contract, ftcreport.schemes.api); here
# the kernels they share: the matched terms (matched_terms, the round-2 plug-in API's), the switching
# bank's filters and rule, the active laws' estimate filters and signals.


@jit
def matched_terms(Kp, R, C, pc, t, q, eta, xc, k_v, info, sig):
    """The kinematic law and the matched dynamic law's terms at (q, eta): (w, MB, g, eta_e).

    eta_c and etadot_c come from the kinematic controller, (3.29) or (3.67)-(3.106); w, MB and g
    are those of (3.37) (``law_terms``): Mbar1 etadot_c + Mbar2 eta + Cbar - k_v Mbar1 eta_e - T^T f
    = MB tau.  ``sig`` gets eta_c, etadot_c, z, q_d, eta_d when it is not empty.  The reduced
    matrices are left in C, for the plant to reuse when it shares the controller's model.
    """
    Mbar1, Mbar2, Cbar, Bbar, S_, _Sd = reduced(pc, q, eta)
    kin, ecd = eta_c_and_dot(Kp, R, C, S_, t, q, eta, xc[: Kp.nk], info)
    if info[0] != 0:
        z = np.zeros(2)
        return z, np.zeros((2, 2 * pc.n)), z, z
    if sig.shape[0] > 0:
        _kin_signals(sig, kin, ecd, C)
    C.M1[:] = Mbar1
    C.M2[:] = Mbar2
    C.Cb[:] = Cbar
    C.Bb[:] = Bbar
    C.Sm[:] = S_
    C.f[3] = 1.0
    eta_e = eta - kin[0]
    w, MB, g = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, kin[1], kin[2], ecd, k_v)
    return w, MB, g, eta_e


@jit
def _tri(a, b, D):
    """Index of M[a, b] (a <= b) in the packed upper triangle of a symmetric (D, D) matrix, row by row."""
    return a * D - (a * (a - 1)) // 2 + (b - a)


@jit
def switching_rates(Lw, MB, u, g, eta, xc, dx):
    r"""The model bank's filters (3.42) and cost integrals, by superposition, into dx.

    The filters are linear in sigma_(k), so every model's estimate is that of the healthy model
    minus one filter per wheel: ``etahat_(k) = h - sum_j f_kj z_j``, f_k = 1 - sigma_(k) (the failure
    indicator), with h(0) = eta(0), z_j(0) = 0 and the applied (saturated) torque u::

        h'   = -gamma h + gamma eta + g + MB u
        z_j' = -gamma z_j + MB[:, j] u_j

    so the error (3.43) is ``etatilde_(k) = eta - etahat_(k) = A (1, f_k)`` with A = [eta - h, z_1 .. z_2n]
    (2 x (2n + 1)).  The integral cost of every model follows from one symmetric matrix,
    ``int_(k) = (1, f_k)^T M (1, f_k)``, ``M' = -forgetting M + A^T A`` (Narendra & Balakrishnan 1994;
    control/switching.py).  Both are linear ODEs, so RK4 integrates them exactly as it would the
    per-model states (equal to round-off).  State layout: ``xc[hat0 : hat0 + 2]`` = h, then z_j
    (2 each, wheel order 1r, 1l, 2r, ...); ``xc[int0 : int0 + n_int]`` = M's upper triangle row by row
    (``_tri``), present when c_int > 0.
    """
    nw = u.shape[0]
    u_app = u if math.isnan(Lw.u_limit) else _clip(u, -Lw.u_limit, Lw.u_limit)
    gm = Lw.gamma
    i0 = Lw.hat0
    d0 = 0.0
    d1 = 0.0
    for j in range(nw):
        # z_j' = -gamma z_j + MB[:, j] u_j
        dx[i0 + 2 + 2 * j] = -gm * xc[i0 + 2 + 2 * j] + MB[0, j] * u_app[j]
        dx[i0 + 3 + 2 * j] = -gm * xc[i0 + 3 + 2 * j] + MB[1, j] * u_app[j]
        d0 += u_app[j] * MB[0, j]
        d1 += u_app[j] * MB[1, j]
    # h' = -gamma h + gamma eta + g + MB u   (3.42) for sigma = 1
    dx[i0] = -gm * xc[i0] + gm * eta[0] + g[0] + d0
    dx[i0 + 1] = -gm * xc[i0 + 1] + gm * eta[1] + g[1] + d1
    if Lw.n_int > 0:
        D = nw + 1
        A = np.empty((2, D))
        A[0, 0] = eta[0] - xc[i0]
        A[1, 0] = eta[1] - xc[i0 + 1]
        for j in range(nw):
            A[0, j + 1] = xc[i0 + 2 + 2 * j]
            A[1, j + 1] = xc[i0 + 3 + 2 * j]
        for a in range(D):
            for b in range(a, D):
                m = Lw.int0 + _tri(a, b, D)
                # M' = -forgetting M + A^T A
                dx[m] = -Lw.forgetting * xc[m] + (A[0, a] * A[0, b] + A[1, a] * A[1, b])


@jit
def _model_cost(Lw, xc, e10, e11, s):
    r"""J_(k) = c_inst |etatilde_(k)|^2 + c_int int_(k) of one pattern ``s`` (3.46), from the superposed states.

    etatilde_(k) = (eta - h) + sum_j f_j z_j and int_(k) = M_00 + sum_j f_j (2 c_j + f_j M_jj),
    c_j = M_0j + sum_(i<j) f_i M_ij, f = 1 - s, summed in wheel order, skipping f_j = 0: for a 0/1
    pattern the same operations, in the same order, as the walk (``_walk``), so both give the same bits.
    """
    nw = s.shape[0]
    i0 = Lw.hat0
    e0 = e10
    e1 = e11
    for j in range(nw):
        f = 1.0 - s[j]
        if f != 0.0:
            # etatilde += f_j z_j
            e0 += f * xc[i0 + 2 + 2 * j]
            e1 += f * xc[i0 + 3 + 2 * j]
    J = Lw.c_inst * (e0 * e0 + e1 * e1)
    if Lw.n_int > 0:
        D = nw + 1
        m0 = Lw.int0
        acc = xc[m0]
        for j in range(nw):
            fj = 1.0 - s[j]
            if fj != 0.0:
                c = xc[m0 + _tri(np.int64(0), j + 1, D)]  # not a literal 0: one compile of _tri
                for i in range(j):
                    fi = 1.0 - s[i]
                    if fi != 0.0:
                        c += fi * xc[m0 + _tri(i + 1, j + 1, D)]
                # int += f_j (2 c_j + f_j M_jj)
                acc += fj * (2.0 * c + fj * xc[m0 + _tri(j + 1, j + 1, D)])
        J = J + Lw.c_int * acc
    return J


@jit
def switching_costs(Lw, eta, xc):
    """J_(k) (3.46) of every model of the bank, (N,) (``_model_cost`` per pattern)."""
    Nm = Lw.patterns.shape[0]
    J = np.empty(Nm)
    e10 = eta[0] - xc[Lw.hat0]
    e11 = eta[1] - xc[Lw.hat0 + 1]
    for k in range(Nm):
        J[k] = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
    return J


@jit
def switching_costs_rows(Lw, ETA, XC, every):
    """(K, N) costs of every model at K logged states (every = 1), or (K, 2) [J_selected, min_k J_k] (0)."""
    K = XC.shape[0]
    out = np.empty((K, Lw.patterns.shape[0] if every else 2))
    for r in range(K):
        if every:
            out[r] = switching_costs(Lw, ETA[r], XC[r])
        else:
            e10 = ETA[r, 0] - XC[r, Lw.hat0]
            e11 = ETA[r, 1] - XC[r, Lw.hat0 + 1]
            Jc = _model_cost(Lw, XC[r], e10, e11, Lw.patterns[round(XC[r, Lw.sel])])
            out[r, 0] = Jc
            out[r, 1] = _best_cost(Lw, XC[r], e10, e11, Jc)[0]
    return out


@jit
def _walk(Lw, xc, e10, e11, mode, lim):
    r"""Depth-first walk over the 0/1 patterns wheel by wheel: the least J (mode 0, lim = a known cost)
    or the lowest bank index with J <= lim (mode 1).

    Wheel j's branch adds f_j = 1 - sigma_j: etatilde += z_j and int += 2 c_j + M_jj, with
    c_i += M_ji for the wheels i > j still open (the rank-one update of ``_model_cost``'s sums, O(2n)
    per node).  Branches without a bank pattern (``Lw.trie``) are skipped, and so are those whose lower
    bound exceeds lim: every leaf below a node at depth d has, for any unit vector w,
    |etatilde| >= w . etatilde = w . etatilde_node + sum_(i >= d) f_i w . z_i
    >= w . etatilde_node + sum_(i >= d) min(0, w . z_i); with w along etatilde_node (above the last
    three wheels; nearer the leaves the cheaper |etatilde_node| - sum_(i >= d) |z_i|).  For the
    integral, M is positive semidefinite, so v^T M v >= (y^T M v)^2 / (y^T M y) for y = the node's
    (1, f) (Cauchy-Schwarz), and y^T M v >= y^T M y + sum_(i >= d) min(0, (M y)_i).  The bounds are
    lowered by far more than the round-off of the leaf costs (1e-12 relative on etatilde,
    1e-10 D^2 trace(M) on the integral, 1e-9 on the comparison), so no pattern that could be the
    minimum or a tie is skipped.
    The branch that brings etatilde nearer 0 is walked first (a low cost early prunes more; the
    order does not change the result).  In a monotone bank (``trie[0] = 1``: a pattern with one more
    working wheel is in the bank, at a lower index, e.g. every compensable pattern) the branch
    f_d = 1 of a wheel whose filter and integrals are exactly 0 (never driven) is skipped: its costs
    are those of f_d = 0, bit for bit, at higher indices (at t = 0 every model ties).  Returns
    (least J, True if a NaN cost was met) in mode 0, (index, False) in mode 1.
    """
    nw = Lw.patterns.shape[1]
    D = nw + 1
    i0 = Lw.hat0
    use_int = Lw.n_int > 0
    Z = np.empty((nw, 2))  # local copies: the walk reads plain arrays of its own
    for j in range(nw):
        Z[j, 0] = xc[i0 + 2 + 2 * j]
        Z[j, 1] = xc[i0 + 3 + 2 * j]
    M = np.zeros((D, D)) if use_int else np.zeros((1, 1))
    if use_int:
        for a in range(D):
            for b in range(a, D):
                M[a, b] = xc[Lw.int0 + _tri(a, b, D)]
                M[b, a] = M[a, b]
    return _walk_core(
        Lw.codes, Lw.trie, Z, M, use_int, Lw.c_inst, Lw.c_int, e10, e11, mode, lim
    )  # fmt: skip


@jit
def _walk_core(codes, trie, Z, M, use_int, c_inst, c_int, e10, e11, mode, lim):
    """``_walk`` on plain arrays: Z (2n, 2) the wheels' filters, M (2n + 1, 2n + 1) the integrals."""
    nw = Z.shape[0]
    D = nw + 1
    R = np.zeros(nw + 1)  # R[d] = sum_(i >= d) |z_i|
    for j in range(nw - 1, -1, -1):
        R[j] = R[j + 1] + math.sqrt(Z[j, 0] ** 2 + Z[j, 1] ** 2)
    slack = 0.0  # the int part's round-off and M's departure from PSD (far above either)
    if use_int:
        tr = 0.0
        for a in range(D):
            tr += abs(M[a, a])
        slack = c_int * 1e-10 * D * D * tr
    E = np.empty((nw + 1, 2))
    ACC = np.zeros(nw + 1)
    CV = np.zeros((nw + 1, nw)) if use_int else np.zeros((1, 1))
    CODE = np.zeros(nw + 1, dtype=np.int64)
    BR = np.zeros(nw + 1, dtype=np.int64)
    FIRST = np.zeros(nw + 1, dtype=np.int64)  # the f_d walked first at depth d
    SAME = np.zeros(nw, dtype=np.bool_)  # f_d = 1 gives f_d = 0's costs at a higher index: skipped
    if trie[0] == 1:
        for j in range(nw):
            zero = Z[j, 0] == 0.0 and Z[j, 1] == 0.0
            if use_int:
                for a in range(D):
                    zero = zero and M[a, j + 1] == 0.0
            SAME[j] = zero
    E[0, 0] = e10
    E[0, 1] = e11
    if use_int:
        ACC[0] = M[0, 0]
        for j in range(nw):
            CV[0, j] = M[0, j + 1]
    best = lim
    nan = False
    found = -1
    d = 0
    while d >= 0:
        if d == nw:
            k = codes[CODE[d]]
            if k >= 0:
                cost = c_inst * (E[d, 0] * E[d, 0] + E[d, 1] * E[d, 1])
                if use_int:
                    cost = cost + c_int * ACC[d]
                if mode == 0:
                    if cost < best:
                        best = cost
                    elif math.isnan(cost):
                        nan = True
                elif cost <= lim and (found < 0 or k < found):
                    found = k
            d -= 1
            continue
        if BR[d] == 0:
            a0 = E[d, 0] + Z[d, 0]
            a1 = E[d, 1] + Z[d, 1]
            FIRST[d] = 1 if a0 * a0 + a1 * a1 < E[d, 0] * E[d, 0] + E[d, 1] * E[d, 1] else 0
        elif BR[d] == 2:
            d -= 1
            continue
        b = FIRST[d] if BR[d] == 0 else 1 - FIRST[d]  # f_d of this branch
        BR[d] += 1
        if b == 1 and SAME[d]:
            continue
        code = CODE[d] | ((1 - b) << d)  # bit d = sigma_d
        if trie[(1 << (d + 1)) + code] == 0:
            continue
        c = d + 1
        if b == 0:  # wheel d works: f_d = 0
            E[c, 0] = E[d, 0]
            E[c, 1] = E[d, 1]
            if use_int:
                ACC[c] = ACC[d]
                for i in range(c, nw):
                    CV[c, i] = CV[d, i]
        else:  # wheel d failed: f_d = 1
            E[c, 0] = E[d, 0] + Z[d, 0]
            E[c, 1] = E[d, 1] + Z[d, 1]
            if use_int:
                ACC[c] = ACC[d] + (2.0 * CV[d, d] + M[d + 1, d + 1])
                for i in range(c, nw):
                    CV[c, i] = CV[d, i] + M[d + 1, i + 1]
        # lower bound of J below this node: c_inst (inst. bound) + c_int (integral bound) - slack
        ib = 0.0
        if use_int and ACC[c] > 0.0:
            # int = v^T M v >= (y^T M v)^2 / (y^T M y) with y = this node's (1, f) (Cauchy-Schwarz),
            # y^T M v >= int_node + sum_(i >= c) min(0, c_i) = L
            L = ACC[c]
            for i in range(c, nw):
                if CV[c, i] < 0.0:
                    L += CV[c, i]
            if L > 0.0:
                ib = c_int * (L * L / ACC[c])
        r = math.sqrt(E[c, 0] * E[c, 0] + E[c, 1] * E[c, 1])
        gap = r - R[c] - 1e-12 * (r + R[c])
        bound = c_inst * gap * gap if gap > 0.0 else 0.0
        if (bound + ib - slack) * (1.0 - 1e-9) > best:
            continue
        if nw - c >= 3 and r > 0.0:
            # w = etatilde_node / |etatilde_node|: |etatilde| >= r + sum_(i >= c) min(0, w . z_i)
            w0 = E[c, 0] / r
            w1 = E[c, 1] / r
            acc = r
            for i in range(c, nw):
                p = w0 * Z[i, 0] + w1 * Z[i, 1]
                if p < 0.0:
                    acc += p
            gap = acc - 1e-12 * (r + R[c])
            bound = c_inst * gap * gap if gap > 0.0 else 0.0
            if (bound + ib - slack) * (1.0 - 1e-9) > best:
                continue
        CODE[c] = code
        BR[c] = 0
        d = c
    if mode == 0:
        return best, nan
    return float(found), False


@jit
def _good_cost(Lw, xc, e10, e11):
    """The cost of a good bank pattern, the walk's first upper bound: wheel by wheel the branch of lower
    partial cost (the wheels after it assumed working), then single-wheel changes while one lowers J.

    A cost of a pattern of the bank, computed by ``_model_cost`` (the walk's bits): only a bound, the
    walk still finds the least cost.  Without it a poor applied model (during the dwell time or
    behind the hysteresis) leaves the walk a poor bound and many more nodes to visit.
    """
    nw = Lw.patterns.shape[1]
    i0 = Lw.hat0
    s = np.ones(nw)
    code = 0
    e0 = e10
    e1 = e11
    for d in range(nw):
        a0 = e0 + xc[i0 + 2 + 2 * d]
        a1 = e1 + xc[i0 + 3 + 2 * d]
        keep = Lw.trie[(1 << (d + 1)) + (code | (1 << d))] == 1  # wheel d working is in the bank
        fail = Lw.trie[(1 << (d + 1)) + code] == 1
        if fail and (not keep or a0 * a0 + a1 * a1 < e0 * e0 + e1 * e1):
            s[d] = 0.0
            e0 = a0
            e1 = a1
        else:
            code |= 1 << d
    best = _model_cost(Lw, xc, e10, e11, s)
    for _ in range(nw):
        moved = False
        for j in range(nw):
            c2 = code ^ (1 << j)
            k = Lw.codes[c2]
            if k >= 0:
                Jn = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
                if Jn < best:
                    best = Jn
                    code = c2
                    moved = True
        if not moved:
            break
    return best


@jit
def _best_cost(Lw, xc, e10, e11, Jc):
    """min_k J_(k) over the bank (``_walk`` for a 0/1 bank with its table, else every pattern), and NaN seen."""
    if Lw.codes.shape[0] > 0:
        Jg = _good_cost(Lw, xc, e10, e11)
        lim = Jc if not math.isnan(Jc) else np.inf
        # np.int64: a literal mode would compile _walk and _walk_core once per mode (issue 20 item 1)
        return _walk(Lw, xc, e10, e11, np.int64(0), Jg if Jg < lim else lim)
    best = np.inf
    nan = False
    for k in range(Lw.patterns.shape[0]):
        cost = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
        if cost < best:
            best = cost
        elif math.isnan(cost):
            nan = True
    return best, nan


@jit
def switching_select(Lw, t, eta, xc):
    r"""The switching rule (3.47)-(3.48): the model of least cost J_k (3.46), with dwell time and hysteresis.

    J_k = c_inst |eta - etahat_k|^2 + c_int int_k (``_model_cost``); ties within TIE_RTOL of the least
    cost go to the lowest index.  The selection changes only after T_min since the last switch and
    when it lowers J by the hysteresis.  The least cost and the tied candidates are found by
    ``_walk`` for a 0/1 bank (no per-model work: it skips the subtrees that cannot win), by
    evaluating every pattern otherwise; the same bits either way.  A NaN cost anywhere keeps the
    applied model (as argmin + the comparisons of the exhaustive rule do).
    """
    if t - xc[Lw.tsw] < Lw.T_min - 1e-12:
        return
    cur = round(xc[Lw.sel])
    e10 = eta[0] - xc[Lw.hat0]
    e11 = eta[1] - xc[Lw.hat0 + 1]
    Jc = _model_cost(Lw, xc, e10, e11, Lw.patterns[cur])
    m, nan = _best_cost(Lw, xc, e10, e11, Jc)
    if nan or math.isnan(Jc):
        return
    lim = m * (1.0 + TIE_RTOL)  # ties (round-off) -> lowest index
    if lim < m:
        lim = m  # a negative least cost (round-off of the integral): exact ties only, as argmin
    if Lw.codes.shape[0] > 0:
        cand = round(_walk(Lw, xc, e10, e11, np.int64(1), lim)[0])
        Jn = _model_cost(Lw, xc, e10, e11, Lw.patterns[cand])
    else:
        cand = -1
        Jn = np.inf
        for k in range(Lw.patterns.shape[0]):
            cost = _model_cost(Lw, xc, e10, e11, Lw.patterns[k])
            if cost <= lim:
                cand = k
                Jn = cost
                break
    if cand >= 0 and cand != cur and Jn < Jc - Lw.hysteresis:
        xc[Lw.sel] = cand
        xc[Lw.tsw] = t


@jit
def rotor_filter_terms(pc, q, eta, Jw):
    r"""(MB, g) of the bank's filters (3.42) for a chain whose wheels carry rotors of inertia Jw (issue 36 item 3).

    With a DC motor on each wheel the rotor's inertia eta_g N^2 J_m turns with the wheel (ERRATA E19,
    fast.motor.motor_plant_rhs): (Mbar1 + Bbar Jw Bbar^T) etadot = Bbar (tau - Jw Bbardot^T eta) -
    Mbar2 eta - Cbar, so etadot = g + MB tau with MB = A^-1 Bbar, g = -A^-1 (Mbar2 eta + Cbar +
    Bbar Jw Bbardot^T eta), A = Mbar1 + Bbar Jw Bbar^T.  The law's own (3.37) keeps the chain's model.
    """
    Mbar1, Mbar2, Cbar, Bbar, S, Sd = reduced(pc, q, eta)
    Bbd = bbar_rate(pc, q, eta, S, Sd)
    A = rotor_mass(Mbar1, Bbar, Jw)
    nw = Bbar.shape[1]
    r = _mv(Mbar2, eta) + Cbar
    for j in range(nw):
        # + Bbar_j Jw_j (Bbardot^T eta)_j
        wd = Jw[j] * (Bbd[0, j] * eta[0] + Bbd[1, j] * eta[1])
        r[0] += Bbar[0, j] * wd
        r[1] += Bbar[1, j] * wd
    g = -_solve2(A, r)
    MB = np.empty((2, nw))
    col = np.empty(2)
    for j in range(nw):
        col[0] = Bbar[0, j]
        col[1] = Bbar[1, j]
        MB[:, j] = _solve2(A, col)
    return MB, g


@jit
def estimate_filters(dx, xc, filt0, tau, rho_e, ubar_e):
    """The estimates' first-order filters of the active laws (thesis 4.2.4: tau xdot = x_est - x), into dx.

    ``xc[filt0 : filt0 + nw]`` filters the gains, the next nw the frictions; tau nan: no filters.
    """
    if math.isnan(tau):
        return
    nw = rho_e.shape[0]
    for j in range(nw):
        dx[filt0 + j] = (rho_e[j] - xc[filt0 + j]) / tau
        dx[filt0 + nw + j] = (ubar_e[j] - xc[filt0 + nw + j]) / tau


@jit
def active_signals(sig, k, qh, eh, rho_e, ubar_e, sigma_used, ubar_used):
    """The active laws' logged signals after the kinematic ones (from index k): q_hat, eta_hat,
    rho_hat, ubar_hat, sigma_used, ubar_used (fast.engine splits them by these widths)."""
    N, nw = qh.shape[0], rho_e.shape[0]
    sig[k : k + N] = qh
    sig[k + N : k + N + 2] = eh
    k += N + 2
    sig[k : k + nw] = rho_e
    sig[k + nw : k + 2 * nw] = ubar_e
    sig[k + 2 * nw : k + 3 * nw] = sigma_used
    sig[k + 3 * nw : k + 4 * nw] = ubar_used


@jit
def _check_state(pp, x, nq, lim, max_speed, max_position, info):
    n = pp.n
    worst = 2.0
    iw = 0
    for i in range(n - 1):
        c = abs(math.cos(x[nq - 1 - i] - x[nq - 2 - i]))
        if c < worst:
            worst = c
            iw = i
    if n > 1 and worst <= lim:
        info[0] = E_STATE_SINGULAR
        info[1] = iw
        info[2] = math.degrees(math.acos(min(1.0, worst)))
        return
    if abs(x[nq]) > max_speed or abs(x[nq + 1]) > max_speed:
        info[0] = E_SPEED
        info[1] = x[nq]
        info[2] = x[nq + 1]
        return
    if abs(x[0]) > max_position or abs(x[1]) > max_position:
        info[0] = E_POSITION
        info[1] = x[0]
        info[2] = x[1]


@jit
def _min_art_cos(pp, x, nq):
    worst = 2.0
    for i in range(pp.n - 1):
        worst = min(worst, abs(math.cos(x[nq - 1 - i] - x[nq - 2 - i])))
    return worst


@jit
def _step_jump(pp, x, xn, nq, lim, max_speed, max_position, frac, lim_far, info):
    """A step's blow-up (ftcreport.sim's docstring): kind (0 = none) with before/after in info[2:4]."""
    for i in range(xn.shape[0]):
        if not math.isfinite(xn[i]):
            return 1
    e0 = max(abs(x[nq]), abs(x[nq + 1]))
    e1 = max(abs(xn[nq]), abs(xn[nq + 1]))
    if e1 > max_speed and e0 < frac * max_speed:
        info[2] = e0
        info[3] = e1
        return 2
    p0 = max(abs(x[0]), abs(x[1]))
    p1 = max(abs(xn[0]), abs(xn[1]))
    if p1 > max_position and p0 < frac * max_position:
        info[2] = p0
        info[3] = p1
        return 3
    if pp.n > 1:
        c0 = _min_art_cos(pp, x, nq)
        c1 = _min_art_cos(pp, xn, nq)
        if c1 <= lim and c0 > lim_far:
            info[2] = math.degrees(math.acos(min(1.0, c0)))
            info[3] = math.degrees(math.acos(min(1.0, c1)))
            return 4
    return 0


# =========================================================================== the Python UKF's model; the active law
@jit
def midpoint_sigmas(pc, sigmas, u, dt, est_rho, est_ubar):
    """The reference UKF's process model (tests/ukf_reference.py) at every sigma point: a midpoint step, u held."""
    N = pc.n + 2
    nw = 2 * pc.n
    out = sigmas.copy()
    for i in range(sigmas.shape[0]):
        x = sigmas[i]
        rho = np.ones(nw)
        ubar = np.zeros(nw)
        k = N + 2
        if est_rho:
            rho = x[k : k + nw]
            k += nw
        if est_ubar:
            ubar = x[k : k + nw]
        tau = rho * u + ubar
        q = x[:N]
        eta = x[N : N + 2]
        qd1, ed1 = plant_rhs(pc, q, eta, tau)
        qd2, ed2 = plant_rhs(pc, q + 0.5 * dt * qd1, eta + 0.5 * dt * ed1, tau)
        out[i, :N] = q + dt * qd2
        out[i, N : N + 2] = eta + dt * ed2
    return out
