"""What every domain's compiled kernels share: the packed parameter tuples, the error codes, small helpers.

The faces pack their parameters into these NamedTuples (``Chain``, ``Ref``, ``Kin``, ``Law``, ``Obs``:
their ``packed()`` methods) and the engine hands them to the kernels.  Errors are reported through
``info`` (a float array): ``info[0]`` is a code (``E_*`` below, 0 = none) and ``info[1:4]`` its
numbers; the engine turns them into the messages of ftcreport.errors.  2 x 2 systems are solved in
closed form, small products by loops: results differ from numpy/LAPACK in the last bits only.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .compiling import jit

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
E_UKF = 15  # info: the UKF step's status (UKF_* below), t
E_STEP_JUMP = 14  # info: kind, before, after (_step_jump: non-finite new state or a check failed in one step)
E_LAW_WRITE = 16  # info: the buffer a scheme wrote past (0 u, 1 dx, 2 sig, 3 its state in the discrete update), t
E_LAW_NONFINITE = 18  # info: t, the wheel index, the value (a law's command not finite from finite inputs)
E_LAW_SIGNAL = 19  # info: t, the signal index, the value (a plug-in's logged signal not finite from finite inputs)
E_LAW_RAISED = 20  # info: 0 the law, 1 the discrete update, t (a plug-in's raised: an index out of bounds, ...)
E_MIN_STEP = 17  # info: t, the step that fell below the minimum (error-controlled methods, fast.loop.run_auto)

#: the UKF step's statuses (observers/ukf_compiled.py's ``ukf_step``; E_UKF's info carries one)
UKF_OK = 0
UKF_NONFINITE = 1  # x or P (input, predicted or updated) has a non-finite entry
UKF_PRIOR_NOT_PD = 2  # the input P is not positive definite (Cholesky of c P fails)
UKF_PREDICTED_NOT_PD = 3  # the predicted P is not positive definite (the redraw before the update)
UKF_S_SINGULAR = 4  # the innovation covariance S is singular (zero pivot)

_MESSAGES = {
    UKF_NONFINITE: "the UKF's state or covariance became non-finite",
    UKF_PRIOR_NOT_PD: "the UKF's covariance P is not positive definite (Cholesky of (lambda + n) P failed)",
    UKF_PREDICTED_NOT_PD: "the UKF's predicted covariance is not positive definite (Cholesky failed)",
    UKF_S_SINGULAR: "the UKF's innovation covariance S is singular",
}


def ukf_message(status: int) -> str:
    """The user's message for a status of the UKF step ("" for UKF_OK)."""
    return _MESSAGES.get(int(status), "") if status else ""


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
    """A FlatReference on a TrigPath (references/__init__.py)."""

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
def _clip(x, lo, hi):
    return np.minimum(np.maximum(x, lo), hi)


@jit
def _tri(a, b, D):
    """Index of M[a, b] (a <= b) in the packed upper triangle of a symmetric (D, D) matrix, row by row."""
    return a * D - (a * (a - 1)) // 2 + (b - a)
