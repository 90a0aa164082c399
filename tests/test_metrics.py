"""Metric definitions on hand-made data, and energy against the work-energy theorem."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import harness

from ftcreport.evaluation.metrics import phase_metrics, recovery_time, switching_metrics, torque_metrics
from ftcreport.model import Chain
from ftcreport.sim import Plant, SimSettings, simulate


def test_recovery_time_is_entry_into_the_band_for_good():
    t = np.linspace(0, 10, 101)
    e = np.where(t < 3, 1.0, 0.001)
    e[50] = 0.5  # an excursion at t = 5 s
    assert recovery_time(t, e, 0.0, 10.0, 0.01) == pytest.approx(5.1)
    assert recovery_time(t, e, 6.0, 10.0, 0.01) == 0.0
    assert recovery_time(t, np.ones_like(t), 0.0, 10.0, 0.01) is None


def test_phase_metrics_split_at_events():
    t = np.linspace(0, 4, 401)
    e = np.abs(np.sin(t))
    ph = phase_metrics(t, e, [(0.0, 2.0), (2.0, 4.0)], band=0.5)
    assert ph[0]["position_error_max"] == pytest.approx(1.0, abs=1e-4)
    assert ph[1]["position_error_final"] == pytest.approx(abs(np.sin(4.0)))
    # IAE of |sin| over the phase samples [0, 1.99] is 1 - cos 1.99 (the event sample starts phase 2)
    assert ph[0]["position_error_iae"] == pytest.approx(1 - np.cos(1.99), rel=1e-4)


def test_switching_metrics_exact_effective_and_delays():
    t = np.arange(0.0, 10.0, 1.0)
    patterns = np.array([[1, 1, 1, 1], [0, 1, 1, 1], [0, 1, 1, 0]])
    sigma = np.ones((10, 4))
    sigma[3:, 0] = 0.0  # 1r fails at 3 s
    sel = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, 2])  # right at 4 s; a superset (1r + 2l) from 6 s
    m = switching_metrics(t, sel, patterns, sigma, [3.0])
    assert m["switch_count"] == 2
    assert m["switching_exact_match_fraction"] == pytest.approx(5 / 10)  # 0-2 healthy, 4-5 exact
    assert m["switching_match_fraction"] == pytest.approx(9 / 10)  # + superset 6-9; 3 s wrong
    assert m["detection_delays"] == [{"time": 3.0, "needs_switch": True, "delay": 1.0}]
    assert m["switch_sequence"] == [(0.0, 0), (4.0, 1), (6.0, 2)]


def test_switching_delay_stops_at_the_next_fault():
    """A match reached only after the next fault is not the first fault's detection (issue 18)."""
    t = np.arange(0.0, 30.0, 1.0)
    patterns = np.array([[1, 1, 1, 1], [0, 1, 1, 1], [0, 1, 1, 0]])
    sigma = np.ones((30, 4))
    sigma[5:, 0] = 0.0  # 1r fails at 5 s
    sigma[10:, 3] = 0.0  # 2l fails at 10 s as well
    sel = np.zeros(30, dtype=int)
    sel[22:] = 2  # the right model (1r + 2l) from 22 s only: 17 s after the first fault
    m = switching_metrics(t, sel, patterns, sigma, [10.0, 5.0])
    assert m["detection_delays"] == [
        {"time": 5.0, "needs_switch": True, "delay": None},  # not 17 s: the 10 s fault came first
        {"time": 10.0, "needs_switch": True, "delay": 12.0},
    ]
    assert m["switching_missed_detections"] == 1
    assert m["detection_delay_max"] is None


def test_energy_bounds_the_kinetic_energy_gained():
    """From rest, no friction: int tau.omega dt = T(end) exactly, so energy >= T(end)."""
    chain = Chain.uniform(2)
    ctrl = harness().controller(chain, harness().VELOCITY, c0=(0.5, 0.2), k=3.0)  # healthy computed torque
    run = simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.005, duration=3.0))
    omega = np.array([chain.wheel_speeds(q, e) for q, e in zip(run["q"], run["eta"], strict=True)])
    m = torque_metrics(run["tau"], run["u"], None, run.t, omega)
    T_end = chain.kinetic_energy(run["q"][-1], run["eta"][-1])
    signed = np.sum(0.5 * (np.sum(run["tau"] * omega, 1)[1:] + np.sum(run["tau"] * omega, 1)[:-1]) * np.diff(run.t))
    assert signed == pytest.approx(T_end, rel=1e-4)
    assert m["energy"] >= T_end * (1 - 1e-4)


def test_means_over_time_weigh_samples_by_their_time():
    """Error-controlled runs have unequal steps (issue 36): a mean over time must not count a stretch of
    short steps (a transient) more than its time.  RMS values are trapezoids; fractions of what is held
    over each step weigh each sample by the step it starts."""
    from ftcreport.evaluation.metrics import time_mean

    rng = np.random.default_rng(7)
    t = np.concatenate(([0.0], np.cumsum(rng.uniform(1e-4, 0.2, 400))))  # unequal steps, up to 2000x apart
    x = np.sin(t) ** 2
    exact = (t[-1] / 2 - np.sin(2 * t[-1]) / 4) / t[-1]  # the mean of sin^2 over [0, T]
    assert abs(time_mean(t, x) - exact) < 1e-3  # trapezoid: O(h^2)
    assert abs(np.mean(x) - exact) > 1e-2  # the mean of the samples is not the mean over time
    # a flag held over each step (set on the steps from t = 20 s on): exact by the steps it starts
    held = (t >= 20.0).astype(float)
    start = t[np.searchsorted(t, 20.0)]
    assert time_mean(t, held, "step") == pytest.approx(
        (t[-1] - start + (t[-1] - t[-2])) / (t[-1] - t[0] + t[-1] - t[-2])
    )
    # on equal steps the step rule is the mean of the samples
    u = np.arange(11) * 0.1
    np.testing.assert_allclose(time_mean(u, np.arange(11.0) ** 2, "step"), np.mean(np.arange(11.0) ** 2), rtol=1e-14)


def test_a_fault_at_t0_makes_the_first_phase_a_fault_phase():
    """The round-3 case audit: a fault at t = 0 was read as "no fault" (phases[1:] were the fault phases),
    so a run that never settled passed `recovery_time_max <= 1` with 0 and the page said "With no fault
    in the run"."""
    from ftcreport.evaluation.compare import _extract
    from ftcreport.evaluation.metrics import fault_phases, tracking_metrics

    t = np.linspace(0.0, 2.0, 201)
    q = np.zeros((t.size, 4))
    q_d = np.zeros((t.size, 4))
    q[:, 1] = 0.028  # never within the 0.01 m band
    m = tracking_metrics(t, q, q_d, [(0.0, 2.0)], 0.01, fault_times=[0.0])
    assert m["phases"][0]["fault"] is True
    assert m["recovery_time_max"] is None  # never settles: a threshold on it fails
    assert _extract("after_fault_error_max", m) == (pytest.approx(0.028), "")
    # a fault at t = 0 and another at 1 s: both phases are fault phases
    m2 = tracking_metrics(t, q, q_d, [(0.0, 1.0), (1.0, 2.0)], 0.01, fault_times=[0.0, 1.0])
    assert [p["fault"] for p in m2["phases"]] == [True, True]
    # no fault at t = 0: the first phase is the healthy one, as before
    m3 = tracking_metrics(t, q, q_d, [(0.0, 1.0), (1.0, 2.0)], 0.01, fault_times=[1.0])
    assert [p["fault"] for p in m3["phases"]] == [False, True]
    assert len(fault_phases(m3["phases"])) == 1
    # results stored before the key existed: the phases after the first, as they were read then
    old = [{k: v for k, v in p.items() if k != "fault"} for p in m3["phases"]]
    assert fault_phases(old) == old[1:]


def test_a_threshold_on_a_null_metric_fails_with_the_runs_reason():
    """A null recovery_time_max (a fault phase never recovers) fails its bound with why it is null, not
    "metric absent", which read as a typo in the threshold's name."""
    from ftcreport.studies.check import evaluate

    why = "some phase that starts with a fault never recovers (see phases[*].recovery_time)"
    m = {"status": "ok", "recovery_time_max": None, "null_reasons": {"recovery_time_max": why}}
    (r,) = evaluate("c", {"nominal": {"recovery_time_max": {"max": 1.0}}}, {"nominal": m})
    assert not r.ok
    assert r.reason == f"null: {why}"
    (r,) = evaluate("c", {"nominal": {"recovery_tme_max": {"max": 1.0}}}, {"nominal": m})
    assert not r.ok and r.reason == "metric absent"


def _inside_steps(t, y0, B, C, T, s):
    """A + C s + B exp(-s/T) inside each step (A = y0 - B), at offsets s of the step starting at t."""
    return (y0 - B) + C * s + B * np.exp(-s / T)


@pytest.mark.parametrize("T", [0.44e-3, 20e-3, 1.0])  # fast inside a 5 ms step; slow; the quadratic branch
def test_step_integrals_are_exact_on_the_fitted_shape(T):
    """The motor cases' torque inside a held-voltage step is a constant, a drift and the currents'
    transient (benchmarks/torque_metric_dt.py --fit); given its start, midpoint and end the integrals of
    tau^2 and |tau omega| are exact to the 16-point Gauss-Legendre quadrature (measured 2e-11 at
    T = 0.44 ms, 6e-11 at 20 ms; asserted to 1e-7, the reference's own trapezoid on 200,001 points being
    about 1e-10); a step in which the power changes sign has a kink the nodes do not resolve, to 1e-3 of
    that step's work.  The trapezoid misses the fast transient by several % of a step's integral."""
    from ftcreport.evaluation.metrics import step_integrals

    rng = np.random.default_rng(1)
    h, K, nw = 0.005, 12, 3
    t = np.arange(K + 1) * h
    sign = rng.choice([-1.0, 1.0], (K, nw))  # each step's power keeps its sign (a kink is not resolved)
    y0 = sign * rng.uniform(2, 4, (K, nw))
    B = rng.uniform(-1, 1, (K, nw))
    C = rng.uniform(-50, 50, (K, nw))  # |C h| <= 0.25
    om = rng.uniform(0.5, 3, (K + 1, nw))
    tau = np.zeros((K + 1, nw))
    tau[:-1] = y0
    tau_mid = np.full((K + 1, nw), np.nan)
    tau_mid[:-1] = _inside_steps(0, y0, B, C, T, h / 2)
    end = _inside_steps(0, y0, B, C, T, h)
    # each step's end is the next start: build the stream so, one step at a time (its own integrals)
    sq_exact, pw_exact = np.zeros(nw), 0.0
    fine = np.linspace(0.0, h, 200001)
    for k in range(K):
        x = _inside_steps(0, y0[k], B[k], C[k], T, fine[:, None])
        w = om[k] + (om[k + 1] - om[k]) * fine[:, None] / h
        sq_exact += np.trapezoid(x * x, fine, axis=0)
        pw_exact += np.trapezoid(np.sum(np.abs(x * w), axis=1), fine)
        one = np.stack([y0[k], end[k]])
        sq, pw = step_integrals(t[k : k + 2], one, om[k : k + 2], np.stack([tau_mid[k], tau_mid[-1]]), T)
        np.testing.assert_allclose(sq, np.trapezoid(x * x, fine, axis=0), rtol=1e-7)
        assert pw == pytest.approx(np.trapezoid(np.sum(np.abs(x * w), axis=1), fine), rel=1e-7)
    # without the midpoint: the trapezoid (what every method without an interpolant keeps); it misses a fast
    # transient that the fit integrates exactly (step 0 of each wheel)
    x = _inside_steps(0, y0[0], B[0], C[0], T, fine[:, None])
    exact0 = np.trapezoid(x * x, fine, axis=0)
    sq_t, _ = step_integrals(t[:2], np.stack([y0[0], end[0]]), om[:2], None, T)
    np.testing.assert_allclose(sq_t, 0.5 * h * (y0[0] ** 2 + end[0] ** 2))
    if h > T:
        assert np.max(np.abs(sq_t / exact0 - 1.0)) > 1e-3


def test_a_held_torque_is_integrated_as_held():
    """Sampled control without motors holds the command over each step: h tau_k^2, not the trapezoid."""
    from ftcreport.evaluation.metrics import step_integrals

    t = np.array([0.0, 0.01, 0.02, 0.03])
    tau = np.array([[1.0], [3.0], [-2.0], [5.0]])
    om = np.array([[1.0], [1.0], [-1.0], [-1.0]])
    sq, pw = step_integrals(t, tau, om, held=True)
    assert sq[0] == pytest.approx(0.01 * (1 + 9 + 4))
    assert pw == pytest.approx(0.01 * (1 * 1 + 3 * 0.5 * (1 + 1) + 2 * 1))


def test_a_threshold_on_a_table_entry_reads_that_entry():
    """``metric.key`` (an entry of a table metric) is accepted by the case's validation, as for a claim; check
    read the dotted name as a metric of its own and failed it as "metric absent" whatever the run held."""
    from ftcreport.cases.case import metric_problem
    from ftcreport.studies.check import evaluate

    name = "fault_estimation_errors_final.rho"
    assert metric_problem("active", name) is None  # the case file may state it
    m = {"status": "ok", "fault_estimation_errors_final": {"rho": 0.02, "ubar": 0.3}}
    (r,) = evaluate("c", {"active": {name: {"max": 0.05}}}, {"active": m})
    assert r.ok and r.actual == 0.02, r
    (r,) = evaluate("c", {"active": {name: {"max": 0.01}}}, {"active": m})
    assert not r.ok and r.actual == 0.02 and r.reason == "0.02 > max 0.01"
    (r,) = evaluate("c", {"active": {"fault_estimation_errors_final.ubar": {"max": 1.0}}}, {"active": m})
    assert r.ok and r.actual == 0.3
    # an entry the run does not hold is absent, named with its key
    (r,) = evaluate("c", {"active": {"fault_estimation_errors_final.tau": {"max": 1.0}}}, {"active": m})
    assert not r.ok and r.reason == "metric absent"
