"""The compiled UKF step (ftcreport.observers.ukf_compiled) against filterpy's (tests/ukf_reference.py, the reference).

Tolerances.  Both run the same equations in the same order; they differ in the
order of the sums (loops here, BLAS there), in round-off only.  Along 300 steps
the differences are amplified by the filter itself: the estimate of q is ~1e4
of its posterior standard deviation sd (q ~ 1 m, sd ~ 1e-4 m) and the parameter
directions are weakly observable (they forget slowly).  The reference fed a 1-ulp perturbation
of its state at every step drifts from itself by as much as the compiled step
does (measured on these six runs, 3 seeds of the perturbation: x up to 2.3e-10
sd, P up to 3.7e-12 sd_i sd_j; the compiled step: 2.8e-10 and 5.0e-12, both
largest for n = 3 with rho and ubar).  So x is compared componentwise in units
of its sd, |dx_i| <= 1e-9 sd_i, and P in units of sd_i sd_j, |dP_ij| <= 2e-11
sd_i sd_j (margins 3.6 and 4).  In absolute terms: |dx| <= 3.4e-12, |dP| <=
2.1e-14; one step from the same state: |dx| <= 6.9e-13, |dP| <= 1.9e-16.  Real
differences are far larger: without filterpy's redraw of the sigma points after
the prediction x moves by 1.5e-3 sd, and Q off by 1e-6 (relative) by 7e-7 sd.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.linalg import LinAlgError
from ukf_reference import FilterpyUKF

from ftcreport.fast import kernels as F
from ftcreport.model import Chain
from ftcreport.observers import UKFEstimator
from ftcreport.observers.ukf_compiled import (
    UKF_NONFINITE,
    UKF_OK,
    UKF_PREDICTED_NOT_PD,
    UKF_PRIOR_NOT_PD,
    merwe_weights,
    ukf_message,
    ukf_params,
    ukf_step,
)

STEPS = 300
X_TOL_SD = 1e-9  # |dx_i| / sd_i (see the module docstring)
P_TOL_SD = 2e-11  # |dP_ij| / (sd_i sd_j)


def _truth(pc: F.Chain, n: int, h: float, rng: np.random.Generator, sub: int = 10):
    """True plant (RK4, h / sub) driven forward with a weave; a gain and a friction fault at 45 % of the run.

    Returns the held controls u_k (over [t_k, t_k+1]) and the noisy measurements y_k = q(t_k) + v_k
    (1 mm / 1 mrad, as cases/three_link_active.toml).
    """
    nw, N = 2 * n, n + 2
    q, eta = np.zeros(N), np.zeros(2)
    rho, ubar = np.ones(nw), np.zeros(nw)
    us, ys = [], [q + 1e-3 * rng.standard_normal(N)]
    weave = np.array([1.0, -1.0] * n)
    for k in range(STEPS):
        t = k * h
        if k >= 0.45 * STEPS:
            rho[1], ubar[2] = 0.6, 0.3  # 1l loses 40 % of its gain, 2r gets 0.3 N m of friction
        # speed loop toward 0.5 m/s plus a +-0.4 N m differential weave [N m]
        u = 1.0 * (0.5 - eta[0]) + 0.4 * np.sin(1.3 * t + np.arange(nw)) * weave
        tau = rho * u + ubar  # (2.102)
        dt = h / sub
        for _ in range(sub):
            a1, b1 = F.plant_rhs(pc, q, eta, tau)
            a2, b2 = F.plant_rhs(pc, q + 0.5 * dt * a1, eta + 0.5 * dt * b1, tau)
            a3, b3 = F.plant_rhs(pc, q + 0.5 * dt * a2, eta + 0.5 * dt * b2, tau)
            a4, b4 = F.plant_rhs(pc, q + dt * a3, eta + dt * b3, tau)
            q = q + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            eta = eta + dt / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
        us.append(u)
        ys.append(q + 1e-3 * rng.standard_normal(N))
    return np.array(us), np.array(ys)


@pytest.mark.parametrize("estimate", [("rho",), ("ubar",), ("rho", "ubar")])
@pytest.mark.parametrize(("n", "h"), [(2, 0.01), (3, 0.02)])  # the sampling periods of the *_active cases
def test_compiled_step_equals_filterpy_along_300_steps(n, h, estimate):
    chain = Chain.uniform(n)  # the thesis robot
    pc = F.Chain(*chain.params)
    us, ys = _truth(pc, n, h, np.random.default_rng(n))
    assert np.ptp(ys[:, 0]) > 0.5  # the chain moves (x over the run [m])
    est = UKFEstimator(chain, meas_std=1e-3, estimate=estimate)
    ref = FilterpyUKF(est)
    params = ukf_params(est)
    s_ref = est.initial_state(ys[0])
    s = s_ref.copy()
    worst_x = worst_P = 0.0
    for k in range(STEPS):
        s_ref = ref.step(s_ref, us[k], ys[k + 1], h)
        s, status = ukf_step(pc, params, s, us[k], ys[k + 1], h)
        assert status == UKF_OK
        x_ref, P_ref = est.unpack(s_ref)
        x, P = est.unpack(s)
        sd = np.sqrt(np.diag(P_ref))
        worst_x = max(worst_x, float(np.max(np.abs(x - x_ref) / sd)))
        worst_P = max(worst_P, float(np.max(np.abs(P - P_ref) / np.outer(sd, sd))))
        np.testing.assert_array_equal(P, P.T)  # symmetrised as the reference's step
    assert worst_x <= X_TOL_SD
    assert worst_P <= P_TOL_SD


WEIGHT_CASES = [(10, 0.5, 2.0, -7.0), (19, 0.5, 2.0, -16.0), (6, 1.0, 0.0, 0.5)]  # nx = 10, 19: kappa = 3 - nx


@pytest.mark.parametrize(("n", "alpha", "beta", "kappa"), WEIGHT_CASES)
def test_weights_are_filterpys_bitwise(n, alpha, beta, kappa):
    from filterpy.kalman import MerweScaledSigmaPoints

    ref = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    Wm, Wc, c = merwe_weights(n, alpha, beta, kappa)
    np.testing.assert_array_equal(Wm, ref.Wm)
    np.testing.assert_array_equal(Wc, ref.Wc)
    assert c == alpha**2 * (n + kappa) - n + n  # filterpy's (lambda_ + n)


def _setup(n: int = 2):
    chain = Chain.uniform(n)
    est = UKFEstimator(chain, meas_std=1e-3)
    s = est.initial_state(np.zeros(chain.n_q))
    return est, F.Chain(*chain.params), ukf_params(est), s, np.full(chain.n_wheels, 0.5), np.zeros(chain.n_q)


def test_non_positive_definite_P_gives_the_status_not_an_exception():
    est, pc, params, s, u, y = _setup()
    x, P = est.unpack(s)
    P = P.copy()
    P[-1, -1] = -1e-3  # one negative variance
    bad = est.pack(x, P)
    with pytest.raises(LinAlgError):  # the reference raises (scipy's cholesky)
        FilterpyUKF(est).step(bad, u, y, 0.01)
    out, status = ukf_step(pc, params, bad, u, y, 0.01)
    assert status == UKF_PRIOR_NOT_PD
    np.testing.assert_array_equal(out, bad)  # the state is returned unchanged
    assert "not positive definite" in ukf_message(status)


def test_predicted_covariance_not_positive_definite():
    _est, pc, params, s, u, y = _setup()
    # Q = -10 I h swamps the propagated spread: the predicted P has negative variances
    out, status = ukf_step(pc, params._replace(Qc=-10.0 * np.eye(params.nx)), s, u, y, 0.01)
    assert status == UKF_PREDICTED_NOT_PD
    np.testing.assert_array_equal(out, s)


def test_non_finite_state_gives_the_status():
    _est, pc, params, s, u, y = _setup()
    bad = s.copy()
    bad[0] = np.nan
    out, status = ukf_step(pc, params, bad, u, y, 0.01)
    assert status == UKF_NONFINITE
    assert np.isnan(out[0])
    assert ukf_message(status) and ukf_message(UKF_OK) == ""


@pytest.mark.parametrize("estimate", [("rho",), ("ubar",), ("rho", "ubar")])
@pytest.mark.parametrize("n", [2, 3])
def test_sigma_propagation_is_midpoint_sigmas_bitwise(n, estimate):
    """_propagate shares the first stage among the parameter-direction points: same numbers, bit for bit."""
    from ftcreport.observers.ukf_compiled import _propagate, _sigma_points

    chain = Chain.uniform(n)
    pc = F.Chain(*chain.params)
    est = UKFEstimator(chain, meas_std=1e-3, estimate=estimate)
    params = ukf_params(est)
    rng = np.random.default_rng(7)
    x = est.unpack(est.initial_state(rng.normal(scale=0.3, size=chain.n_q), rng.normal(size=2)))[0]
    x[chain.n_q + 2 :] += rng.normal(scale=0.2, size=est.nx - chain.n_q - 2)
    A = rng.normal(size=(est.nx, est.nx))
    P = 0.01 * A @ A.T + 0.01 * np.eye(est.nx)
    X = np.empty((2 * est.nx + 1, est.nx))
    assert _sigma_points(x, P, params.c, np.empty_like(P), np.empty_like(P), X) == 0
    u = rng.normal(size=chain.n_wheels)
    Xf = np.empty_like(X)
    _propagate(pc, X, u, 0.02, params.est_rho, params.est_ubar, Xf)
    np.testing.assert_array_equal(Xf, F.midpoint_sigmas(pc, X, u, 0.02, params.est_rho, params.est_ubar))


def test_factorisations_match_lapack():
    """Cholesky (upper) and the LU inverse against scipy / numpy: round-off of a 19 x 19 SPD matrix."""
    import scipy.linalg

    from ftcreport.observers.ukf_compiled import _cholesky_upper, _lu_inverse

    rng = np.random.default_rng(3)
    A = rng.normal(size=(19, 19))
    P = A @ A.T + 0.1 * np.eye(19)  # condition number 670
    U = np.empty_like(P)
    assert _cholesky_upper(P, U) == 0
    # backward-stable factorisations: entries agree to cond * eps = 1.5e-13 of the largest (measured 2e-15)
    np.testing.assert_allclose(U, scipy.linalg.cholesky(P), rtol=0, atol=1.5e-13 * np.abs(U).max())
    S = P[:5, :5] + np.diag(rng.uniform(0.1, 1.0, 5))
    SI = np.empty_like(S)
    assert _lu_inverse(S, SI)
    np.testing.assert_allclose(SI, np.linalg.inv(S), rtol=0, atol=1.5e-13 * np.abs(SI).max())  # measured 2e-16
    # non-positive-definite: the failing pivot (1-based), as LAPACK's info
    P[4, 4] = -1.0
    assert _cholesky_upper(P, U) == 5
    assert not _lu_inverse(np.array([[1.0, 2.0], [2.0, 4.0]]), np.empty((2, 2)))  # singular: zero pivot


@pytest.mark.parametrize("estimate", [("rho",), ("ubar",), ("rho", "ubar")])
@pytest.mark.parametrize(("n", "h"), [(2, 0.01), (3, 0.02)])
def test_step_jacobian_is_the_steps_derivative(n, h, estimate):
    """ukf_step_jacobian (P held) against central differences of the compiled step itself, Richardson-extrapolated.

    The state is the filter's after 200 steps of a run (a full P, an innovation of 4-10 mm at the next
    measurement, so the gain's derivative times the innovation counts).  Reference: ``(4 D(H/2) - D(H)) / 3``
    with D the central differences of ukf_step at relative step H = 1e-3 (truncation O(H^4)); its own error,
    the spread between H = 1e-3 and 2e-3, is at most 4e-11 of the largest entry, and the derivative agrees
    to 2.7e-11 (measured on these six).  Plain central differences at 1e-6, what the analysis used before,
    are off by up to 1.1e-8 (the sigma points' weights, Wm_0 = -18 to -24 against 0.67 for the others,
    amplify the step's round-off); the tolerance, 1e-9, lies between.
    """
    from ftcreport.analysis.closed_loop import central_columns
    from ftcreport.observers.ukf_compiled import ukf_step_jacobian

    chain = Chain.uniform(n)
    pc = F.Chain(*chain.params)
    us, ys = _truth(pc, n, h, np.random.default_rng(n))
    est = UKFEstimator(chain, meas_std=1e-3, estimate=estimate)
    params = ukf_params(est)
    s = est.initial_state(ys[0])
    for k in range(200):
        s, status = ukf_step(pc, params, s, us[k], ys[k + 1], h)
    u, y = us[200], ys[201]
    nx, nw = est.nx, chain.n_wheels
    assert np.abs(y - s[: chain.n_q]).max() > 1e-3  # an innovation: dK r is part of the derivative

    def step(z):
        ss = s.copy()
        ss[:nx] = z[:nx]
        out, status = ukf_step(pc, params, ss, z[nx : nx + nw].copy(), z[nx + nw :].copy(), h)
        assert status == UKF_OK
        return out[:nx]

    z0 = np.concatenate((s[:nx], u, y))
    ref = (4.0 * central_columns(step, z0, step=5e-4) - central_columns(step, z0, step=1e-3)) / 3.0
    J, status = ukf_step_jacobian(pc, params, s, u, y, h, 1e-6)
    assert status == UKF_OK
    assert J.shape == (nx, nx + nw + chain.n_q)
    assert np.abs(J - ref).max() <= 1e-9 * np.abs(ref).max()
    bad = s.copy()
    bad[nx + nx * nx - 1] = -1.0  # a negative variance: the status of ukf_step, J zero
    J, status = ukf_step_jacobian(pc, params, bad, u, y, h, 1e-6)
    assert status == UKF_PRIOR_NOT_PD and not np.any(J)
