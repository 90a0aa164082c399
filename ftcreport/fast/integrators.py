r"""The integrators of the compiled loop: their formulas, error estimates and step-size control.

The loop (fast/loop.py) owns the closed loop's rate function ``f(t, x)`` and the Jacobian columns
of its stiff block; the functions here never see a law or a plant.  They take the stage rates the
loop computed and return the next stage point, the new state and its local error estimate
(reverse communication, as in the Fortran ODE codes: the caller evaluates f, the integrator does
the algebra).  State order ``x = [q, eta, i_a, ..., xc]``: the stiff block is the ``m`` entries
from ``first``: eta, the motors' currents and whatever else the plant puts after them (``first`` =
nq: the fixed ROS2 and ETD2, and etd2ec), or the whole plant from q (``first`` = 0: ros2ec, whose W
needs the coupling of eta's rates to q, k_v d eta_c / dq: without it, as without f_t, a stiff velocity
loop lags its moving equilibrium by O(h), which the error estimate sees, and the step falls to 1 / k_v).

Fixed-step methods (``SimSettings.method``): RK4 (in the loop), ROS2 (:func:`ros2_first`,
:func:`ros2_second`) and ETD2 (:func:`etd2_first`, :func:`etd2_second`).

Error-controlled methods, each with an embedded estimate of its local error:

* ``dopri5``: Dormand & Prince (1980), "A family of embedded Runge-Kutta formulae", J. Comput.
  Appl. Math. 6, 19-26 (the coefficients of Hairer, Norsett & Wanner, "Solving ODEs I", 2nd ed.,
  Table II.5.2): seven stages, fifth-order solution, fourth-order embedded one; for non-stiff loops.
* ``ros2ec``: the two-stage Rosenbrock W-method ROS2 (Verwer, Spee, Blom & Hundsdorfer 1999, SIAM J.
  Sci. Comput. 20, 1456-1480) with W of the whole plant and the rates' time derivative: L-stable,
  second order for any W; for stiff non-autonomous loops.
* ``etd2ec``: ETD2RK (Cox & Matthews 2002), exact on the linear block: for the motors between samples
  (held voltages: the plant is autonomous there).

  Both estimate their error by step doubling (Richardson; Hairer, Norsett & Wanner I, II.4): the
  step once (x_h) and as two halves (x_hh) with the same linear part, err = (x_hh - x_h) / 3, the
  leading error of x_hh for a second-order method (O(h^3)); x_hh is the solution.  Their embedded
  first-order solutions (x + h k1; ETD1, the first stage a) are no good estimate here: O(h^2), and for
  a stiff component with a slowly moving equilibrium O(h) (the step falls to 1 / k_v), where the
  second-order solution is accurate (fast.loop._attempt).
* ``etd3ec``: ETD3RK (Cox & Matthews 2002) with an embedded ETD2 (:func:`etd3_solution`), on the same
  linear block as etd2ec: two stages (t + h/2, t + h) and the block's two difference columns, 5
  evaluations a step with f(x) against etd2ec's 7, third order where etd2ec is second; ``auto``'s
  choice for the motors under sampled control, where every step ends at a sample (the fixed ETD2
  takes one step per sample at 4 evaluations).

Step-size control (Hairer, Norsett & Wanner I, section II.4, and II, section IV.2):

* the error ratio is the max norm r = max_i |err_i| / (atol + rtol max(|x_i|, |x+_i|)) (the norm of
  MATLAB's ode45, Shampine & Reichelt 1997, "The MATLAB ODE Suite", SIAM J. Sci. Comput. 18: an
  RMS over thousands of slow controller states would dilute the plant's few errors); a step is
  accepted when r <= 1;
* the next step is h fac with fac = 0.9 r^-alpha r_prev^beta (Gustafsson's PI controller; beta = 0
  is the elementary controller 0.9 r^(-1/k), k the order of the error estimate plus one), fac
  limited to [0.2, 5] and to at most 1 right after a rejection;
* the first step from HNW I's starting-step algorithm (II.4, p. 169), in the same norm.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import _solve2
from ..runs import AUTO_METHODS
from .expo import phi12, phi12_scalar, phi123, phi123_scalar

__all__ = [
    "AUTO_METHODS",
    "DP_A",
    "DP_B",
    "DP_C",
    "DP_E",
    "METHOD_CODES",
    "ROS2_GAMMA",
    "ROSW_ALPHA",
    "ROSW_B",
    "ROSW_BHAT",
    "ROSW_C",
    "ROSW_GAMMA",
    "ROSW_GAMMA_IJ",
    "ROSW_GT",
    "erk_solution",
    "erk_stage_point",
    "error_ratio",
    "etd2_dense",
    "etd2_first",
    "etd2_second",
    "power_step",
    "ros2_first",
    "ros2_second",
    "rosw_solution",
    "rosw_stage",
    "rosw_stage_point",
    "solve_small",
    "starting_step",
    "step_factor",
    "w_apply",
    "w_factor",
    "w_solve",
]

#: the methods' codes in the loop (fast.loop.run_steps, run_auto)
METHOD_CODES = {"rk4": 0, "ros2": 1, "etd2": 2, "dopri5": 3, "ros2ec": 4, "etd2ec": 5, "etd3ec": 6, "ros34pw2": 7}

# Dormand-Prince 5(4): c_i, a_ij, the fifth-order weights b and e = b - bhat (bhat: the fourth order)
DP_C = np.array([0.0, 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0, 1.0, 1.0])
DP_A = np.array(
    [
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [1.0 / 5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
        [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
        [19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0, 0.0, 0.0],
        [9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0, 0.0],
        [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0],
    ]
)
DP_B = np.array([35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0, 0.0])
DP_E = np.array([71.0 / 57600.0, 0.0, -71.0 / 16695.0, 71.0 / 1920.0, -17253.0 / 339200.0, 22.0 / 525.0, -1.0 / 40.0])

ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)

#: step-size controller (HNW I, II.4): safety factor, largest and smallest change per step
SAFETY, FAC_MAX, FAC_MIN = 0.9, 5.0, 0.2


# --------------------------------------------------------------------------- explicit Runge-Kutta
@jit
def erk_stage_point(x, K, s, h, A):
    """x + h sum_j a_sj K_j: the point where stage s (0-based, s >= 1) is evaluated; K: (stages, nx)."""
    y = x.copy()
    for j in range(s):
        a = A[s, j]
        if a != 0.0:
            y += (h * a) * K[j]
    return y


@jit
def erk_solution(x, K, h, B, E):
    """(x+, err): x+ = x + h sum_j b_j K_j, err = h sum_j e_j K_j (the embedded pair's difference)."""
    xn = x.copy()
    err = np.zeros(x.shape[0])
    for j in range(B.shape[0]):
        if B[j] != 0.0:
            xn += (h * B[j]) * K[j]
        if E[j] != 0.0:
            err += (h * E[j]) * K[j]
    return xn, err


# --------------------------------------------------------------------------- step-size control
@jit
def error_ratio(err, x, xn, rtol, atol):
    """r = max_i |err_i| / (atol + rtol max(|x_i|, |x+_i|)): the step is accepted when r <= 1."""
    r = 0.0
    for i in range(err.shape[0]):
        sc = atol + rtol * max(abs(x[i]), abs(xn[i]))
        e = abs(err[i]) / sc
        if math.isnan(e):
            return e  # a NaN rejects the step
        r = max(r, e)
    return r


@jit
def step_factor(r, r_prev, k, beta, rejected):
    r"""The next step's factor fac = 0.9 r^-alpha r_prev^beta, alpha = 1/k - 0.75 beta, in [0.2, 5].

    ``k``: the order of the error estimate plus one (err = O(h^k)); ``beta``: Gustafsson's PI term
    (0.04 for DOPRI5 as in Hairer's code, 0 for the elementary controller); ``r_prev``: the last
    accepted step's ratio (at least 1e-4); ``rejected``: the step before was rejected (then fac <= 1).
    """
    hi = 1.0 if rejected else FAC_MAX
    if not r > 0.0:
        return hi if r == 0.0 else FAC_MIN  # an exact step grows; a NaN shrinks
    alpha = 1.0 / k - 0.75 * beta
    fac = SAFETY * r ** (-alpha) * max(r_prev, 1e-4) ** beta
    return min(hi, max(FAC_MIN, fac))


@jit
def _scaled_norm(v, x, rtol, atol):
    n = 0.0
    for i in range(v.shape[0]):
        n = max(n, abs(v[i]) / (atol + rtol * abs(x[i])))
    return n


@jit
def starting_step(x, f0, f1, h0, order, rtol, atol):
    """HNW I's starting step (II.4, p. 169): from f0 = f(t, x) and f1 = f(t + h0, x + h0 f0).

    h1 = (0.01 / max(||f0||, ||f1 - f0|| / h0))^(1 / (order + 1)) in the error's scaled max norm;
    returns min(100 h0, h1).  ``h0`` comes from :func:`first_guess`.
    """
    d1 = _scaled_norm(f0, x, rtol, atol)
    d2 = _scaled_norm(f1 - f0, x, rtol, atol) / h0
    big = max(d1, d2)
    h1 = max(1e-06, 0.001 * h0) if big <= 1e-15 else (0.01 / big) ** (1.0 / (order + 1.0))
    return min(100.0 * h0, h1)


@jit
def first_guess(x, f0, rtol, atol):
    """HNW's h0 = 0.01 ||x|| / ||f0|| (1e-6 when either is tiny), the probe step of :func:`starting_step`."""
    d0 = _scaled_norm(x, x, rtol, atol)
    d1 = _scaled_norm(f0, x, rtol, atol)
    if d0 < 1e-5 or d1 < 1e-5:
        return 1e-6
    return 0.01 * d0 / d1


@jit
def power_step(v, fv, f0, eps):
    r"""One step of the nonlinear power method for the spectral radius of df/dx (RKC's ``spcrad``:
    Sommeijer, Shampine & Verwer 1998, J. Comput. Appl. Math. 88, 315-326).

    ``v``: the current direction (unit 2-norm), ``fv`` = f(x + eps v), ``f0`` = f(x): J v ~ (fv - f0) /
    eps; returns (|J v|, the next unit direction).
    """
    w = (fv - f0) / eps
    n = math.sqrt(np.sum(w * w))
    if not n > 0.0:
        return 0.0, v
    return n, w / n


# --------------------------------------------------------------------------- linearly implicit (W-methods)
@jit
def solve_small(A, b):
    """A x = b for the W-method's small system: closed form for 2 x 2, else Gaussian elimination (partial pivoting)."""
    m = b.shape[0]
    if m == 2:
        return _solve2(A, b)
    M = A.copy()
    y = b.copy()
    for c in range(m):
        p = c
        for r in range(c + 1, m):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if p != c:
            for j in range(m):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            y[c], y[p] = y[p], y[c]
        for r in range(c + 1, m):
            f = M[r, c] / M[c, c]
            for j in range(c, m):
                M[r, j] -= f * M[c, j]
            y[r] -= f * y[c]
    out = np.empty(m)
    for c in range(m - 1, -1, -1):
        acc = y[c]
        for j in range(c + 1, m):
            acc -= M[c, j] * out[j]
        out[c] = acc / M[c, c]
    return out


@jit
def ros2_first(F, diag, f0, ft, h, first):
    r"""ROS2's first stage: k1 with (I - gamma h A) k1 = f(t, x) + gamma h f_t(t, x).

    ``ft``: the rates' explicit time derivative (zeros: the fixed-step ROS2 of the shipped cases,
    which leaves it out).  With it the method is consistent on non-autonomous stiff loops (the
    reference enters the law through t): the autonomous form with t as a state, t' = 1 (Verwer et
    al. 1999, (2.1)); without it a stiff component's error is O(h) and ``ros2ec``'s estimate sees it.
    ``first``: where the block of F's columns starts in x.

    A holds the ``m`` columns F (nx, m) of the stiff block (rows all of x, columns x[first : first + m])
    and the diagonal ``diag`` of the controller's linear filters; (I - gamma h A) is solved by
    Sherman-Morrison-Woodbury: with D = I - gamma h diag(diag), (D - gamma h F E^T)^-1 r =
    D^-1 r + gamma h D^-1 F (I - gamma h E^T D^-1 F)^-1 E^T D^-1 r, an m x m system.
    Returns (k1, D^-1 F, the m x m matrix, D^-1) for :func:`ros2_second`.
    """
    nx, m = F.shape
    gh = ROS2_GAMMA * h
    dinv = 1.0 / (1.0 - gh * diag)
    DF = np.empty((nx, m))
    for i in range(nx):
        for j in range(m):
            DF[i, j] = dinv[i] * F[i, j]
    small = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            small[i, j] = (1.0 if i == j else 0.0) - gh * DF[first + i, j]
    rd = dinv * (f0 + gh * ft)
    k1 = rd + gh * (DF @ solve_small(small, rd[first : first + m]))
    return k1, DF, small, dinv


@jit
def ros2_second(DF, small, dinv, k1, f2, ft, h, first):
    r"""ROS2's second stage, (I - gamma h A) k2 = f(t + h, x + h k1) - 2 k1 - gamma h f_t (``f2`` the rates
    there); returns k2.  The step: x+ = x + 3/2 h k1 + 1/2 h k2; the embedded first order x + h k1
    differs by h/2 (k1 + k2)."""
    m = small.shape[0]
    gh = ROS2_GAMMA * h
    rd = dinv * (f2 - 2.0 * k1 - gh * ft)
    return rd + gh * (DF @ solve_small(small, rd[first : first + m]))


# --------------------------------------------------------------------------- ROS34PW2 (Rosenbrock W, 3(2))
# Rang & Angermann (2005), "New Rosenbrock W-methods of order 3 for partial differential algebraic equations
# of index 1", BIT Numer. Math. 45, 761-787, Table 4.1 (ROS34PW2): four stages, third order for any W (a
# W-method), the embedded second-order solution from the same stages, L-stable (R(inf) = 0) and stiffly
# accurate (b = the last row of alpha + gamma).  In the formulation of Hairer & Wanner II, (IV.7.4), with
# the rates' time derivative f_t of the non-autonomous form:
#     (I - gamma h A) k_i = h f(t + alpha_i h, x + sum_j<i alpha_ij k_j) + h A sum_j<i gamma_ij k_j + gamma_i h^2 f_t,
#     x+ = x + sum_i b_i k_i,   err = sum_i (b_i - bhat_i) k_i  (O(h^3)),
# alpha_i = sum_j alpha_ij, gamma_i = gamma + sum_j<i gamma_ij.  tests/test_integrators.py checks the orders
# (3 and 2, with the exact Jacobian, a random W and W = 0), A- and L-stability and the stiff accuracy.
ROSW_GAMMA = 4.3586652150845900e-01
ROSW_ALPHA = np.array(
    [
        [0.0, 0.0, 0.0, 0.0],
        [8.7173304301691801e-01, 0.0, 0.0, 0.0],
        [8.4457060015369423e-01, -1.1299064236484185e-01, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ]
)
#: gamma_ij below the diagonal (the diagonal is ROSW_GAMMA)
ROSW_GAMMA_IJ = np.array(
    [
        [0.0, 0.0, 0.0, 0.0],
        [-8.7173304301691801e-01, 0.0, 0.0, 0.0],
        [-9.0338057013044082e-01, 5.4180672388095326e-02, 0.0, 0.0],
        [2.4212380706095346e-01, -1.2232505839045147e00, 5.4526025533510214e-01, 0.0],
    ]
)
ROSW_B = np.array([2.4212380706095346e-01, -1.2232505839045147e00, 1.5452602553351020e00, 4.3586652150845900e-01])
ROSW_BHAT = np.array([3.7810903145819369e-01, -9.6042292212423178e-02, 0.5, 2.1793326075422950e-01])
#: the stages' time offsets alpha_i and the coefficients gamma_i of f_t
ROSW_C = ROSW_ALPHA.sum(axis=1)
ROSW_GT = ROSW_GAMMA + ROSW_GAMMA_IJ.sum(axis=1)


@jit
def w_factor(F, diag, gh, first):
    r"""(I - gh A) for A = F E^T + diag(diag), ready for :func:`w_solve`: (D^-1 F, the m x m matrix, D^-1).

    F (nx, m): the columns of x[first : first + m]; D = I - gh diag(diag) (the controller's exact linear
    filters); Sherman-Morrison-Woodbury as in :func:`ros2_first`: the m x m matrix is I - gh E^T D^-1 F.
    """
    nx, m = F.shape
    dinv = 1.0 / (1.0 - gh * diag)
    DF = np.empty((nx, m))
    for i in range(nx):
        for j in range(m):
            DF[i, j] = dinv[i] * F[i, j]
    small = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            small[i, j] = (1.0 if i == j else 0.0) - gh * DF[first + i, j]
    return DF, small, dinv


@jit
def w_solve(DF, small, dinv, r, gh, first):
    r"""(I - gh A)^-1 r from :func:`w_factor`'s pieces: D^-1 r + gh D^-1 F (I - gh E^T D^-1 F)^-1 E^T D^-1 r."""
    m = small.shape[0]
    rd = dinv * r
    return rd + gh * (DF @ solve_small(small, rd[first : first + m]))


@jit
def w_apply(F, diag, v, first):
    """A v = F v[first : first + m] + diag * v."""
    m = F.shape[1]
    return F @ v[first : first + m] + diag * v


@jit
def rosw_stage_point(x, K, i):
    """x + sum_j<i alpha_ij k_j: where ROS34PW2's stage i (0-based) evaluates the rates (K: (4, nx))."""
    y = x.copy()
    for j in range(i):
        a = ROSW_ALPHA[i, j]
        if a != 0.0:
            y += a * K[j]
    return y


@jit
def rosw_stage(F, diag, DF, small, dinv, K, i, fi, ft, h, first):
    r"""ROS34PW2's k_i from the rates ``fi`` at its stage point (:func:`rosw_stage_point`):
    (I - gamma h A) k_i = h f_i + h A sum_j<i gamma_ij k_j + gamma_i h^2 f_t."""
    r = h * fi + (ROSW_GT[i] * h * h) * ft
    if i > 0:
        v = np.zeros(fi.shape[0])
        for j in range(i):
            v += ROSW_GAMMA_IJ[i, j] * K[j]
        r += h * w_apply(F, diag, v, first)
    return w_solve(DF, small, dinv, r, ROSW_GAMMA * h, first)


@jit
def rosw_solution(x, K):
    """(x+, err): x+ = x + sum_i b_i k_i, err = sum_i (b_i - bhat_i) k_i (the embedded second order's difference)."""
    xn = x.copy()
    err = np.zeros(x.shape[0])
    for i in range(4):
        xn += ROSW_B[i] * K[i]
        err += (ROSW_B[i] - ROSW_BHAT[i]) * K[i]
    return xn, err


# --------------------------------------------------------------------------- exponential (ETD2RK)
@jit
def etd2_first(J, diag, x, f0, h, nq):
    r"""ETD2RK's first stage a = x + h phi_1(hL) f(x) (the exponential Euler step, ETD1).

    L: the block J (m x m) on x[nq : nq + m] and the diagonal ``diag`` elsewhere (fast.loop._etd2).
    Returns (a, phi_2(hJ), phi_2(h diag)) for :func:`etd2_second`.
    """
    nx = x.shape[0]
    m = J.shape[0]
    P1, P2 = phi12(h * J)
    p1 = np.empty(nx)
    p2 = np.empty(nx)
    for i in range(nx):
        p1[i], p2[i] = phi12_scalar(h * diag[i])
    a = x + h * p1 * f0
    a[nq : nq + m] = x[nq : nq + m] + h * (P1 @ f0[nq : nq + m])
    return a, P2, p2


@jit
def etd2_dense(J, diag, x, a, f0, f1, h, theta, nq):
    r"""ETD2RK's continuous extension at t + theta h, the step's own interpolant (Hochbruck & Ostermann
    2010, sec. 2.3: N interpolated linearly between x and a)::

        x(s) = x + s phi_1(s L) f(x) + (s^2 / h) phi_2(s L) (f(a) - f(x) - L (a - x)),   s = theta h

    equal to :func:`etd2_second`'s x+ at theta = 1; exact on the linear part (the currents' transient
    after a held voltage step), second order in N.  The metric stream reads the torques at theta = 1/2
    (fast.loop.run_steps: each step's midpoint).
    """
    nx = x.shape[0]
    m = J.shape[0]
    s = theta * h
    g = f1 - f0 - diag * (a - x)
    g[nq : nq + m] = f1[nq : nq + m] - f0[nq : nq + m] - J @ (a[nq : nq + m] - x[nq : nq + m])
    P1, P2 = phi12(s * J)
    out = np.empty(nx)
    for i in range(nx):
        q1, q2 = phi12_scalar(s * diag[i])
        out[i] = x[i] + s * q1 * f0[i] + (s * s / h) * q2 * g[i]
    out[nq : nq + m] = x[nq : nq + m] + s * (P1 @ f0[nq : nq + m]) + (s * s / h) * (P2 @ g[nq : nq + m])
    return out


@jit
def etd2_second(J, diag, x, a, f0, f1, P2, p2, h, nq):
    r"""ETD2RK's step x+ = a + h phi_2(hL) (f(a) - f(x) - L (a - x)); ``f1`` = f(t + h, a)."""
    m = J.shape[0]
    g = f1 - f0 - diag * (a - x)
    g[nq : nq + m] = f1[nq : nq + m] - f0[nq : nq + m] - J @ (a[nq : nq + m] - x[nq : nq + m])
    xn = a + h * p2 * g
    xn[nq : nq + m] = a[nq : nq + m] + h * (P2 @ g[nq : nq + m])
    return xn


# --------------------------------------------------------------------------- ETD3RK with an embedded ETD2
@jit
def _block_apply(Pm, pv, v, nq):
    """phi(hL) v for L = the block J on v[nq : nq + m] and the diagonal elsewhere: Pm = phi(h J), pv = phi(h diag)."""
    m = Pm.shape[0]
    out = pv * v
    out[nq : nq + m] = Pm @ v[nq : nq + m]
    return out


@jit
def _residual(J, diag, x, y, fx, fy, nq):
    """D(y) = f(y) - f(x) - L (y - x): the nonlinear part's change from x to y."""
    m = J.shape[0]
    g = fy - fx - diag * (y - x)
    g[nq : nq + m] = fy[nq : nq + m] - fx[nq : nq + m] - J @ (y[nq : nq + m] - x[nq : nq + m])
    return g


@jit
def etd3_phis(J, diag, h):
    """The phi functions ETD3RK needs, of h L/2: (phi_1, phi_2) and of h L: (phi_1, phi_2, phi_3), each as a
    matrix of the block h J and a vector of h diag: ``(Q1, Q2, q1, q2, P1, P2, P3, p1, p2, p3)`` (one scaling
    and squaring gives both: fast.expo.phi123)."""
    nx = diag.shape[0]
    Q1, Q2, P1, P2, P3 = phi123(h * J)
    q1, q2 = np.empty(nx), np.empty(nx)
    p1, p2, p3 = np.empty(nx), np.empty(nx), np.empty(nx)
    for i in range(nx):
        q1[i], q2[i] = phi12_scalar(0.5 * h * diag[i])
        p1[i], p2[i], p3[i] = phi123_scalar(h * diag[i])
    return Q1, Q2, q1, q2, P1, P2, P3, p1, p2, p3


@jit
def etd3_half(Q1, q1, x, f0, h, nq):
    r"""ETD3RK's first stage, at t + h/2: a = x + (h/2) phi_1(hL/2) f(x) (exponential Euler over half the step)."""
    return x + 0.5 * h * _block_apply(Q1, q1, f0, nq)


@jit
def etd3_end(J, diag, x, a, f0, fa, P1, p1, h, nq):
    r"""ETD3RK's second stage, at t + h: b = x + h phi_1(hL) (f(x) + 2 D(a)); returns (b, D(a))."""
    Da = _residual(J, diag, x, a, f0, fa, nq)
    return x + h * _block_apply(P1, p1, f0 + 2.0 * Da, nq), Da


@jit
def etd3_mid(x, f0, Db, Q1, Q2, q1, q2, h, nq):
    r"""x(t + h/2) by ETD2's continuous extension through the stage b (:func:`etd2_dense` at theta = 1/2, its
    phi functions of hL/2 given): x + (h/2) phi_1(hL/2) f(x) + (h/4) phi_2(hL/2) D(b)."""
    return x + 0.5 * h * _block_apply(Q1, q1, f0, nq) + 0.25 * h * _block_apply(Q2, q2, Db, nq)


@jit
def etd3_solution(J, diag, x, b, f0, fb, Da, P1, P2, P3, p1, p2, p3, h, nq):
    r"""(x+, err, D(b)): ETD3RK's third-order solution and its difference from an embedded second-order one.

    ETD3RK (Cox & Matthews 2002, J. Comput. Phys. 176, (26); Hochbruck & Ostermann 2010, Acta Numerica 19,
    Table 5.5, weights b_1 = phi_1 - 3 phi_2 + 4 phi_3, b_2 = 4 phi_2 - 8 phi_3, b_3 = 4 phi_3 - phi_2 on
    the stages x, a (c = 1/2) and b (c = 1)), written with D(y) = f(y) - f(x) - L (y - x)::

        x+  = x + h phi_1 f(x) + h (4 phi_2 - 8 phi_3) D(a) + h (4 phi_3 - phi_2) D(b)
        x2+ = x + h phi_1 f(x) + h phi_2 D(b)          (ETD2RK with b as its stage at t + h)
        err = x+ - x2+ = h (2 phi_2 - 4 phi_3) (2 D(a) - D(b))

    x2+ is second order (b is accurate to O(h^3) itself), so err = O(h^3): the error of the second-order
    solution, an upper estimate of the third-order one's (local extrapolation, as DOPRI5).  Both are
    exact when f is affine and L its Jacobian (D = 0).  Unlike the embedded ETD2 with its stage at
    t + h/2 (x + h phi_1 f + 2 h phi_2 D(a)), whose error on a stiff component stays O(h^2) whatever the
    stiffness (9e-3 against 9e-6 on Prothero-Robinson, lambda = -1e4, h = 0.2), the weight
    2 phi_2 - 4 phi_3 vanishes as hL -> -infinity: a stiff component's settled part adds no error.
    """
    Db = _residual(J, diag, x, b, f0, fb, nq)
    base = x + h * _block_apply(P1, p1, f0, nq)
    xn = base + h * (_block_apply(P2, p2, 4.0 * Da - Db, nq) + _block_apply(P3, p3, 4.0 * Db - 8.0 * Da, nq))
    err = h * (_block_apply(P2, p2, 2.0 * (2.0 * Da - Db), nq) - _block_apply(P3, p3, 4.0 * (2.0 * Da - Db), nq))
    return xn, err, Db
