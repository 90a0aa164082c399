"""The error-controlled integrators (fast.integrators) on problems with known solutions (issue 36 item 5).

The loop (fast.loop.run_auto) evaluates the rates and calls these functions for the algebra; here a
small driver does the same on test equations, so each formula's order, each error estimate's order and
the step-size control are checked against exact solutions.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ftcreport.fast import integrators as I


# --------------------------------------------------------------------------- a driver as the loop's
def _linear_step(method, f, J, ft, t, x, f0, h):
    """One ROS2 (W = J, with f_t) or ETD2 (L = J) step, as fast.loop._linear_step."""
    zero = np.zeros(x.size)
    if method == "ros2ec":
        k1, DF, small, dinv = I.ros2_first(J, zero, f0, ft, h, 0)
        k2 = I.ros2_second(DF, small, dinv, k1, f(t + h, x + h * k1), ft, h, 0)
        return x + 1.5 * h * k1 + 0.5 * h * k2
    a, P2, p2 = I.etd2_first(J, zero, x, f0, h, 0)
    return I.etd2_second(J, zero, x, a, f0, f(t + h, a), P2, p2, h, 0)


def _attempt(method, f, jac, t, x, h):
    """(x+, err, rate evaluations) of one trial step, as fast.loop._attempt does it (f_t by a difference)."""
    f0 = f(t, x)
    if method == "dopri5":
        K = np.zeros((7, x.size))
        K[0] = f0
        for s in range(1, 7):
            K[s] = f(t + I.DP_C[s] * h, I.erk_stage_point(x, K, s, h, I.DP_A))
        xn, err = I.erk_solution(x, K, h, I.DP_B, I.DP_E)
        return xn, err, 7
    if method == "ros34pw2":  # as fast.loop._rosw_attempt, W = jac (any W: a W-method), f_t by a difference
        dt = 1e-7 * max(1.0, abs(t))
        return (*_rosw(f, jac(t, x), (f(t + dt, x) - f0) / dt, t, x, f0, h), 4)
    J = jac(t, x)
    if method == "etd3ec":  # ETD3RK and its embedded ETD2, as fast.loop._etd3_attempt
        zero = np.zeros(x.size)
        Q1, Q2, q1, q2, P1, P2, P3, p1, p2, p3 = I.etd3_phis(J, zero, h)
        a = I.etd3_half(Q1, q1, x, f0, h, 0)
        b, Da = I.etd3_end(J, zero, x, a, f0, f(t + 0.5 * h, a), P1, p1, h, 0)
        xn, err, Db = I.etd3_solution(J, zero, x, b, f0, f(t + h, b), Da, P1, P2, P3, p1, p2, p3, h, 0)
        # the midpoint (the metric stream's torques) is ETD2's continuous extension through b
        np.testing.assert_allclose(I.etd3_mid(x, f0, Db, Q1, Q2, q1, q2, h, 0), I.etd2_dense(
            J, zero, x, b, f0, f(t + h, b), h, 0.5, 0), rtol=1e-13, atol=1e-15)  # fmt: skip
        return xn, err, 3
    dt = 1e-7 * max(1.0, abs(t))
    ft = (f(t + dt, x) - f0) / dt if method == "ros2ec" else np.zeros(x.size)
    # step doubling: once and as two halves with the same linear part; err = (two halves - once) / 3
    one = _linear_step(method, f, J, ft, t, x, f0, h)
    mid = _linear_step(method, f, J, ft, t, x, f0, 0.5 * h)
    two = _linear_step(method, f, J, ft, t + 0.5 * h, mid, f(t + 0.5 * h, mid), 0.5 * h)
    return two, (two - one) / 3.0, 5


def _rosw(f, W, ft, t, x, f0, h):
    """(x+, err) of one ROS34PW2 step with the matrix W and the time derivative ft (fast.integrators)."""
    zero = np.zeros(x.size)
    DF, small, dinv = I.w_factor(W, zero, I.ROSW_GAMMA * h, 0)
    K = np.zeros((4, x.size))
    for i in range(4):
        fi = f0 if i == 0 else f(t + I.ROSW_C[i] * h, I.rosw_stage_point(x, K, i))
        K[i] = I.rosw_stage(W, zero, DF, small, dinv, K, i, fi, ft, h, 0)
    return I.rosw_solution(x, K)


def _integrate(method, f, jac, x0, t0, t1, rtol, atol, h_max=np.inf):
    """Error-controlled integration from t0 to t1 (the loop's controller); returns (x, accepted, rejected)."""
    k_err, beta = (5.0, 0.04) if method == "dopri5" else (3.0, 0.0)
    x, t = np.array(x0, dtype=float), t0
    f0 = f(t, x)
    h0 = I.first_guess(x, f0, rtol, atol)
    order = {"dopri5": 5.0, "ros34pw2": 3.0}.get(method, 2.0)
    h = min(I.starting_step(x, f0, f(t + h0, x + h0 * f0), h0, order, rtol, atol), h_max)
    r_prev, acc, rej = 0.0, 0, 0
    while t < t1:
        rejected = False
        while True:
            h = min(h, h_max, t1 - t)
            xn, err, _ = _attempt(method, f, jac, t, x, h)
            r = I.error_ratio(err, x, xn, rtol, atol)
            if r <= 1.0:
                break
            rej += 1
            rejected = True
            h *= I.step_factor(r, r_prev, k_err, beta, True)
        t += h
        x = xn
        acc += 1
        h *= I.step_factor(r, r_prev, k_err, beta, rejected)
        r_prev = max(r, 1e-4)
    return x, acc, rej


# --------------------------------------------------------------------------- test equations
def _oscillator(t, x):  # x'' = -x: x = (cos t, -sin t)
    return np.array([x[1], -x[0]])


def _oscillator_jac(t, x):
    return np.array([[0.0, 1.0], [-1.0, 0.0]])


LAM = -1e4


def _prothero(t, x):  # Prothero-Robinson: y' = lambda (y - cos t) - sin t, y = cos t; stiff for lambda = -1e4
    return np.array([LAM * (x[0] - math.cos(t)) - math.sin(t)])


def _prothero_jac(t, x):
    return np.array([[LAM]])


def _step_errors(method, h):
    """(|global error| of one step, |its error estimate|) on the oscillator from (1, 0) at h."""
    x0 = np.array([1.0, 0.0])
    xn, err, _ = _attempt(method, _oscillator, _oscillator_jac, 0.0, x0, h)
    exact = np.array([math.cos(h), -math.sin(h)])
    return float(np.max(np.abs(xn - exact))), float(np.max(np.abs(err)))


@pytest.mark.parametrize(("method", "order", "est_order"), [("dopri5", 5, 4), ("ros2ec", 2, 2)])
def test_local_error_and_its_estimate_have_the_method_orders(method, order, est_order):
    """Halving h divides the local error by 2^(p+1) (p the order) and the estimate by 2^(q+1): DOPRI5's
    embedded fourth order (q = 4); step doubling's (x_hh - x_h) / 3 of a second-order method (q = 2),
    which also estimates the error itself (within 5 % at h = 0.025).  (ETD2 is exact on the oscillator:
    its orders are checked on a nonlinear problem below.)"""
    e1, est1 = _step_errors(method, 0.05)
    e2, est2 = _step_errors(method, 0.025)
    assert math.log2(e1 / e2) == pytest.approx(order + 1, abs=0.1)
    assert math.log2(est1 / est2) == pytest.approx(est_order + 1, abs=0.1)
    if method != "dopri5":
        assert est2 == pytest.approx(e2, rel=0.05)


def test_etd2ec_is_exact_on_a_linear_problem_and_its_estimate_vanishes():
    """ETD2 with L the exact Jacobian integrates an affine system exactly: the step and its halves
    agree, so the estimate is round-off (the currents' transients of the motor cases)."""
    A = np.array([[-3000.0, 50.0], [0.0, -2.0]])
    b = np.array([1.0, 0.5])
    f = lambda t, x: A @ x + b  # noqa: E731
    x0 = np.array([1.0, -1.0])
    h = 0.05
    xn, err, _ = _attempt("etd2ec", f, lambda t, x: A, 0.0, x0, h)
    from scipy.linalg import expm

    aug = np.zeros((3, 3))
    aug[:2, :2] = A
    aug[:2, 2] = b
    exact = (expm(h * aug) @ np.append(x0, 1.0))[:2]
    np.testing.assert_allclose(xn, exact, rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(err)) < 1e-13


def test_etd2ec_is_second_order_on_a_nonlinear_problem():
    """Where N(x) = f(x) - L x is not constant, ETD2's local error is O(h^3), and so is its estimate."""

    def f(t, x):
        return np.array([-x[0] + 0.5 * math.sin(x[1]), -2.0 * x[1] + x[0] ** 2])

    L = lambda t, x: np.array([[-1.0, 0.0], [0.0, -2.0]])  # noqa: E731  (the linear part only)
    x0 = np.array([1.0, 0.5])
    ref, _, _ = _integrate("dopri5", f, None, x0, 0.0, 0.1, 1e-13, 1e-15)
    ref2, _, _ = _integrate("dopri5", f, None, x0, 0.0, 0.05, 1e-13, 1e-15)
    x1, est1, _ = _attempt("etd2ec", f, L, 0.0, x0, 0.1)
    x2, est2, _ = _attempt("etd2ec", f, L, 0.0, x0, 0.05)
    e1, e2 = np.max(np.abs(x1 - ref)), np.max(np.abs(x2 - ref2))
    assert math.log2(e1 / e2) == pytest.approx(3.0, abs=0.2)
    # step doubling's estimate follows the error (O(h^3)) and is close to it
    assert math.log2(np.max(np.abs(est1)) / np.max(np.abs(est2))) == pytest.approx(3.0, abs=0.2)
    assert np.max(np.abs(est2)) == pytest.approx(e2, rel=0.2)


def test_the_phi_functions_match_the_augmented_exponential():
    """phi_1, phi_2, phi_3 of fast.expo (scaling and modified squaring, phi_3's doubling) against scipy's expm
    of the augmented matrix [[Z, I, 0, 0], [0, 0, I, 0], [0, 0, 0, I], 0] (Saad 1992), whose first block
    row is [e^Z, phi_1, phi_2, phi_3]; measured 2e-16 to 2.2e-15 relative over these scales."""
    from scipy.linalg import expm

    from ftcreport.fast.expo import phi12, phi123, phi123_scalar

    rng = np.random.default_rng(1)
    for scale in (1e-3, 1.0, 15.0, 300.0):
        Z = scale * (rng.normal(size=(6, 6)) - 3.0 * np.eye(6))
        aug = np.zeros((24, 24))
        aug[:6, :6] = Z
        for i in range(3):
            aug[6 * i : 6 * i + 6, 6 * i + 6 : 6 * i + 12] = np.eye(6)
        E = expm(aug)
        Q1, Q2, *full = phi123(Z)
        for k, got in enumerate(full, start=1):
            want = E[:6, 6 * k : 6 * k + 6]
            assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want)), (scale, k)
        for got, want in zip((Q1, Q2), phi12(0.5 * Z), strict=True):  # the values at Z / 2
            assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want)), scale
    for z in (-1e-9, 1e-3, -0.199, 0.2, -3.0, -1e4, 2.5):
        exact = [(math.expm1(z) / z), (math.expm1(z) - z) / z**2]
        exact.append((exact[1] - 0.5) / z)  # phi_3 = (phi_2 - 1/2) / z
        p = phi123_scalar(z)
        if abs(z) >= 0.2:  # the closed forms, where they do not cancel
            np.testing.assert_allclose(p, exact, rtol=1e-13)
        else:  # the series against the closed forms' own round-off (1e-16 / |z|^k)
            np.testing.assert_allclose(p, exact, rtol=2e-16 / abs(z) ** 3 + 1e-14)


def test_etd3ec_is_third_order_and_its_estimate_second_order_on_a_nonlinear_problem():
    """ETD3RK's local error is O(h^4) (measured ratio 2^3.9 per halving); its estimate, the embedded ETD2's
    error, O(h^3) (2^2.9), and larger than the solution's error (local extrapolation, as DOPRI5)."""

    def f(t, x):
        return np.array([-x[0] + 0.5 * math.sin(x[1]), -2.0 * x[1] + x[0] ** 2])

    L = lambda t, x: np.array([[-1.0, 0.0], [0.0, -2.0]])  # noqa: E731
    x0 = np.array([1.0, 0.5])
    errs, ests = [], []
    for h in (0.1, 0.05, 0.025):
        ref, _, _ = _integrate("dopri5", f, None, x0, 0.0, h, 1e-13, 1e-15)
        xn, est, ev = _attempt("etd3ec", f, L, 0.0, x0, h)
        errs.append(np.max(np.abs(xn - ref)))
        ests.append(np.max(np.abs(est)))
    assert ev == 3  # f(x) and the two stages (the loop adds the block's two difference columns)
    for (e1, e2), (s1, s2) in zip(itertools.pairwise(errs), itertools.pairwise(ests), strict=True):
        assert math.log2(e1 / e2) == pytest.approx(4.0, abs=0.25)
        assert math.log2(s1 / s2) == pytest.approx(3.0, abs=0.25)
    assert all(s > 10 * e for s, e in zip(ests, errs, strict=True))


def test_etd3ec_on_a_stale_linear_block_keeps_an_estimate_that_bounds_its_error():
    """The loop takes etd3ec's block columns in eta again only every JAC_REUSE steps (fast.loop._etd3_attempt):
    between, L is stale.  On a motor-like pair (wheel speed and a stiff current, R / L_a = 3750 /s, from its
    quasi-static current) with the speed's column 20 % off (the back-EMF coupling included), the estimate is
    the exact block's to 2 % and stays above the solution's error by 100x or more at every h (measured
    229-1052x): a stale block cannot pass a step the estimate would refuse.  The solution's order falls from
    4.8 towards 2.5 as h shrinks (the stale stiff coupling is in N), which the O(h^3) estimate covers."""
    R, La, kb, km, b, c, Jm, v = 0.3, 8e-5, 0.03, 0.03, 1e-4, 0.02, 5e-3, 12.0

    def f(t, x):
        w, i = x
        return np.array([(km * i - b * w - c * math.sin(w)) / Jm, (v - R * i - kb * w) / La])

    def jac(t, x):
        w, _ = x
        return np.array([[(-b - c * math.cos(w)) / Jm, km / Jm], [-kb / La, -R / La]])

    x0 = np.array([5.0, (v - kb * 5.0) / R])
    exact = jac(0.0, x0)
    stale = exact.copy()
    stale[:, 0] *= 1.2
    for h in (0.004, 0.002, 0.001, 0.0005):
        ref, _, _ = _integrate("dopri5", f, None, x0, 0.0, h, 1e-13, 1e-15)
        xn, est, _ = _attempt("etd3ec", f, lambda t, x: stale, 0.0, x0, h)
        _, est_exact, _ = _attempt("etd3ec", f, lambda t, x: exact, 0.0, x0, h)
        scale = 1.0 + np.abs(ref)
        err, bound = np.max(np.abs(xn - ref) / scale), np.max(np.abs(est) / scale)
        assert bound == pytest.approx(np.max(np.abs(est_exact) / scale), rel=0.02)
        assert bound > 100.0 * err, (h, err, bound)


def test_etd3ec_is_exact_on_an_affine_problem_and_quiet_on_a_settled_stiff_one():
    """With L the Jacobian of an affine f, D = 0: the step is the exact flow and the estimate round-off.  On
    Prothero-Robinson (lambda = -1e4, y = cos t) at h = 0.2, 2000 / |lambda|, the estimate is 9e-6 and the
    solution's error 1.4e-7: the embedded ETD2 with its stage at t + h/2 would have estimated 9e-3,
    O(h^2) whatever the stiffness, and held the step far below what the solution needs."""
    A = np.array([[-3000.0, 50.0], [0.0, -2.0]])
    b = np.array([1.0, 0.5])
    x0 = np.array([1.0, -1.0])
    h = 0.05
    xn, err, _ = _attempt("etd3ec", lambda t, x: A @ x + b, lambda t, x: A, 0.0, x0, h)
    from scipy.linalg import expm

    aug = np.zeros((3, 3))
    aug[:2, :2] = A
    aug[:2, 2] = b
    np.testing.assert_allclose(xn, (expm(h * aug) @ np.append(x0, 1.0))[:2], rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(err)) < 1e-13
    t0 = 0.3
    xn, err, _ = _attempt("etd3ec", _prothero, _prothero_jac, t0, np.array([math.cos(t0)]), 0.2)
    assert abs(xn[0] - math.cos(t0 + 0.2)) < 1e-6  # measured 1.4e-7
    assert abs(err[0]) < 1e-4  # measured 9.2e-6


def _nonautonomous(t, x):
    """A nonlinear, non-autonomous pair (the rates read t, as a law reads its reference)."""
    return np.array([x[1] * math.cos(t) + 0.3 * x[0] ** 2, -math.sin(x[0]) - 0.5 * x[1] + t * x[0] * x[1]])


def _nonautonomous_jac(t, x):
    return np.array([[0.6 * x[0], math.cos(t)], [-math.cos(x[0]) + t * x[1], -0.5 + t * x[0]]])


@pytest.mark.parametrize("which", ["jacobian", "random", "zero"])
def test_ros34pw2_is_third_order_for_any_w_and_its_estimate_second_order(which):
    """ROS34PW2 is a W-method: its local error is O(h^4) and its embedded solution's O(h^3) whatever the
    matrix W (Rang & Angermann 2005): with the exact Jacobian, a random matrix, and W = 0 (then an explicit
    Runge-Kutta method).  That is what lets the loop's W hold only the plant's columns (the controller's
    states are treated explicitly) and makes its order independent of the accuracy of the difference
    columns.  Measured per halving of h from 0.1: 2^3.97-2^4.13 (solution), 2^2.99-2^3.11 (estimate)."""
    from scipy.integrate import solve_ivp

    t0, x0 = 0.3, np.array([0.4, -0.7])
    W = {"jacobian": _nonautonomous_jac(t0, x0), "random": np.random.default_rng(1).standard_normal((2, 2)),
         "zero": np.zeros((2, 2))}[which]  # fmt: skip
    f0 = _nonautonomous(t0, x0)
    ft = np.array([-x0[1] * math.sin(t0), x0[0] * x0[1]])  # d f / d t at (t0, x0), exact
    errs, ests = [], []
    for h in (0.1, 0.05, 0.025, 0.0125):
        exact = solve_ivp(_nonautonomous, (t0, t0 + h), x0, method="DOP853", rtol=1e-13, atol=1e-15).y[:, -1]
        xn, err = _rosw(_nonautonomous, W, ft, t0, x0, f0, h)
        errs.append(np.max(np.abs(xn - exact)))
        ests.append(np.max(np.abs(xn - err - exact)))  # the embedded solution x+ - err
    for (e1, e2), (s1, s2) in zip(itertools.pairwise(errs), itertools.pairwise(ests), strict=True):
        assert math.log2(e1 / e2) == pytest.approx(4.0, abs=0.2)
        assert math.log2(s1 / s2) == pytest.approx(3.0, abs=0.2)


def test_ros34pw2_is_l_stable_and_stiffly_accurate():
    """With W the Jacobian, on y' = lambda y: R(z) = 1 + z b^T (I - z B)^-1 1, B = alpha + gamma (its diagonal
    gamma).  |R| <= 1 on the imaginary axis and in the left half-plane (A-stable), R(z) -> 0 as z -> -infinity
    (L-stable: a settled stiff velocity loop stays settled at any step), and b is the last row of B (stiffly
    accurate: the solution is the last stage's point).  The embedded solution is A-stable with R(-inf) = -0.478:
    the estimate does not vanish on a stiff mode that is not settled."""
    B = I.ROSW_ALPHA + I.ROSW_GAMMA_IJ + I.ROSW_GAMMA * np.eye(4)

    def R(z, b=I.ROSW_B):
        return 1.0 + z * b @ np.linalg.solve(np.eye(4) - z * B, np.ones(4))

    assert abs(R(-1e8)) < 1e-7
    assert R(-1e8, I.ROSW_BHAT) == pytest.approx(-0.4783, abs=1e-3)
    assert max(abs(R(1j * y)) for y in np.logspace(-3, 6, 500)) <= 1.0 + 1e-12
    grid = [complex(-x, y) for x in np.logspace(-3, 5, 40) for y in np.linspace(-1e4, 1e4, 41)]
    assert max(abs(R(z)) for z in grid) <= 1.0
    np.testing.assert_allclose(I.ROSW_B, B[3], rtol=0, atol=1e-15)
    np.testing.assert_allclose(I.ROSW_C, [0.0, 0.87173304301691801, 0.73157995778885238, 1.0], atol=1e-15)


def test_ros34pw2_takes_long_steps_on_a_stiff_problem_and_meets_its_tolerance():
    """Prothero-Robinson with lambda = -1e4 over 10 s: stability does not hold the step (L-stable), accuracy does;
    third order takes fewer steps than ros2ec's second order at the same tolerance (measured 175 against 1,974 at
    rtol 1e-6, 43 against 197 at 1e-4), and the error follows the tolerance (2.7e-10 and 1.6e-7)."""
    x, acc, _ = _integrate("ros34pw2", _prothero, _prothero_jac, [1.0], 0.0, 10.0, 1e-6, 1e-8)
    assert abs(x[0] - math.cos(10.0)) < 1e-5
    _, acc_ros2, _ = _integrate("ros2ec", _prothero, _prothero_jac, [1.0], 0.0, 10.0, 1e-6, 1e-8)
    assert acc < 0.5 * acc_ros2
    x4, acc4, _ = _integrate("ros34pw2", _prothero, _prothero_jac, [1.0], 0.0, 10.0, 1e-4, 1e-6)
    assert abs(x4[0] - math.cos(10.0)) < 1e-3
    assert acc4 < acc


@pytest.mark.parametrize("rtol", [1e-4, 1e-6, 1e-8, 1e-10])
def test_dopri5_meets_its_tolerance_on_the_oscillator(rtol):
    """Over 10 periods the global error follows the tolerance: at most 50 rtol (errors add over ~100 steps
    with the safety factor 0.9 and rtol of |x| <= 1), and it falls with it."""
    x, acc, _ = _integrate("dopri5", _oscillator, None, [1.0, 0.0], 0.0, 20 * math.pi, rtol, rtol * 1e-2)
    err = np.max(np.abs(x - np.array([1.0, 0.0])))
    assert err < 50 * rtol
    assert err > 1e-3 * rtol  # not a fixed tiny step: the control really uses the tolerance
    # steps grow as rtol^(-1/5): from 1e-4 to 1e-10, 10^(6/5) = 16x more steps, within a factor 2
    if rtol == 1e-10:
        _, acc4, _ = _integrate("dopri5", _oscillator, None, [1.0, 0.0], 0.0, 20 * math.pi, 1e-4, 1e-6)
        assert 8.0 < acc / acc4 < 32.0


def test_rejections_and_recovery_at_a_fast_transient():
    """y' = -50 (y - sin t) + cos t from y(0) = 1: a 0.02 s transient, then y = sin t.  The controller
    rejects steps there (the starting step is tuned on f(0)), then grows them: far fewer steps than a
    fixed step resolving the transient over the whole interval would take."""
    f = lambda t, x: np.array([-50.0 * (x[0] - math.sin(t)) + math.cos(t)])  # noqa: E731
    x, acc, rej = _integrate("dopri5", f, None, [1.0], 0.0, 10.0, 1e-8, 1e-10)
    assert rej >= 1
    exact = math.sin(10.0) + math.exp(-500.0)
    assert abs(x[0] - exact) < 1e-7
    # explicit: stability holds h below 3.3 / 50 = 0.066 s, so >= 150 steps; far fewer than a 1e-3 grid
    assert 150 < acc < 2000


def test_ros2ec_takes_long_steps_on_a_stiff_problem():
    """Prothero-Robinson with lambda = -1e4: an explicit method needs h < 3.3e-4 (30,000 steps over 10 s);
    ROS2 (L-stable) follows y = cos t at steps set by accuracy alone, and meets the tolerance.  Without the f_t
    term of fast.integrators.ros2_first the stiff component's error is O(h) and an estimate of it held the step
    near 1 / |lambda|."""
    x, acc, _ = _integrate("ros2ec", _prothero, _prothero_jac, [1.0], 0.0, 10.0, 1e-6, 1e-8)
    assert abs(x[0] - math.cos(10.0)) < 1e-5
    assert acc < 3000  # 1974 measured
    x4, acc4, _ = _integrate("ros2ec", _prothero, _prothero_jac, [1.0], 0.0, 10.0, 1e-4, 1e-6)
    assert abs(x4[0] - math.cos(10.0)) < 1e-3
    assert 4.0 < acc / acc4 < 16.0  # 10x more steps at a 100x tighter tolerance (197 measured at 1e-4)
    # the same with DOPRI5 is held by stability: at least 10 / 3.3e-4 steps
    _, acc_dp, _ = _integrate("dopri5", _prothero, None, [1.0], 0.0, 1.0, 1e-6, 1e-8)
    assert acc_dp > 1.0 / (3.4 / abs(LAM))


def test_dopri5_real_stability_boundary():
    """R(z) = 1 + z b^T (I - z A)^-1 1 reaches |R| = 1 at z = -3.3 on the negative real axis
    (fast.loop.DOPRI5_REAL_BOUND, auto's stiffness test)."""
    from ftcreport.fast.loop import DOPRI5_REAL_BOUND

    A = I.DP_A[:6, :6]
    b = I.DP_B[:6]

    def R(z):
        return 1.0 + z * b @ np.linalg.solve(np.eye(6) - z * A, np.ones(6))

    zs = np.linspace(-4.0, -0.01, 4000)
    bound = -zs[np.flatnonzero(np.abs([R(z) for z in zs]) <= 1.0)[0]]
    assert bound == pytest.approx(3.31, abs=0.01)
    assert bound >= DOPRI5_REAL_BOUND


def test_step_factor_is_the_controllers():
    """0.9 r^(-1/k) (elementary), limited to [0.2, 5], at most 1 after a rejection; PI with beta."""
    assert I.step_factor(1.0, 1.0, 5.0, 0.0, False) == pytest.approx(0.9)
    assert I.step_factor(1e-3, 1.0, 5.0, 0.0, False) == pytest.approx(0.9 * 1e3**0.2)
    assert I.step_factor(1e-12, 1.0, 5.0, 0.0, False) == 5.0
    assert I.step_factor(1e-12, 1.0, 5.0, 0.0, True) == 1.0
    assert I.step_factor(1e12, 1.0, 5.0, 0.0, False) == 0.2
    assert I.step_factor(0.0, 1.0, 5.0, 0.0, False) == 5.0
    assert I.step_factor(math.nan, 1.0, 5.0, 0.0, False) == 0.2
    # PI: alpha = 1/5 - 0.75 beta, times r_prev^beta
    assert I.step_factor(0.5, 0.25, 5.0, 0.04, False) == pytest.approx(0.9 * 0.5 ** -(0.2 - 0.03) * 0.25**0.04)


def test_error_ratio_is_the_max_norm_and_rejects_nan():
    x = np.array([1.0, 100.0, 0.0])
    xn = np.array([1.0, 100.0, 0.0])
    err = np.array([1e-6, 1e-4, 0.0])
    # scales: 1e-8 + 1e-6 * 1, 1e-8 + 1e-6 * 100, 1e-8: ratios 0.990, 0.9999, 0; the largest
    assert I.error_ratio(err, x, xn, 1e-6, 1e-8) == pytest.approx(1e-4 / (1e-8 + 1e-4), rel=1e-14)
    assert math.isnan(I.error_ratio(np.array([math.nan, 0.0, 0.0]), x, xn, 1e-6, 1e-8))
