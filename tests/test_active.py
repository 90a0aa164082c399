"""Active FTC (issue 6): Farza observer + (4.14) on thesis Tables 4.1 and 4.2, the UKF, diagnosis.

Table 4.1 (cases/two_link_active.toml, ERRATA E18): two links, circle v_d = omega_d = 0.5 from
(0, 0, 0), the chain starting 1 m off at rest, 5 N m saturation, RK4 at 10 ms for 70 s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import harness

from ftcreport.cases import load_case, with_duration
from ftcreport.control.active import ActiveController
from ftcreport.evaluation.diagnosis import Declaration, detect, match_events, true_events
from ftcreport.model import Chain, FaultEvent, FaultSchedule
from ftcreport.observers import FarzaObserver, UKFEstimator
from ftcreport.runner import build, make_controller, run_scheme
from ftcreport.sim import Plant, SimSettings, simulate

CASES = "cases"


def _at(run, t):
    return int(np.argmin(np.abs(run.t - t)))


def _window_max(run, a, b):
    k = (run.t >= a) & (run.t <= b)
    return float(np.hypot(*(run["q"][k, :2] - run["q_d"][k, :2]).T).max())


@pytest.fixture(scope="module")
def table41():
    case = load_case(f"{CASES}/two_link_active.toml")
    return case, run_scheme(case, "active")


@pytest.fixture(scope="module")
def table41_ukf():
    case = load_case(f"{CASES}/two_link_active.toml")
    return case, run_scheme(case, "active_ukf")


# ---------------------------------------------------------------------- Table 4.1, Farza
def test_printed_signs_diverge_on_table41():
    """ERRATA E15 on the thesis case: the printed signs of (4.11) make the loop blow up."""
    case = with_duration(load_case(f"{CASES}/two_link_active.toml"), 20.0)
    built = build(case)
    good = make_controller(built, "active")
    obs = FarzaObserver(built.chain, 1.6, p_max=1e10, printed_signs=True)
    bad = ActiveController(built.chain, built.kinematic(), 20.0, obs, u_limit=5.0)
    run = simulate(built.plant, bad, built.q0, built.eta0, built.settings)
    est_err = np.abs(run["q_hat"] - run["q"]).max(axis=1) if run.t.size else np.array([np.inf])
    assert run.status != "ok" or est_err.max() > 1.0
    assert good.est.sign == 1.0


@pytest.mark.slow
def test_table41_state_estimation(table41):
    _, (run, m) = table41
    assert run.ok
    assert m["state_estimation_max_after_5s_q"] < 0.05
    assert m["state_estimation_max_after_5s_eta"] < 0.3


@pytest.mark.slow
def test_table41_gains_and_frictions_identified(table41):
    """Every gain and friction within 0.02 at 35 s and 70 s, within 0.05 from 60 s (25 s after the change)."""
    _, (run, _) = table41
    est = np.hstack((run["rho_hat"], run["ubar_hat"]))
    truth_before = np.array([1, 1, 1, 0.5, 0, 0, 0, 0])
    truth_after = np.array([1, 0, 0.8, 0.5, -0.5, 0, 0, 0])
    k35 = int(np.searchsorted(run.t, 35.0)) - 1  # last sample before the change
    np.testing.assert_allclose(est[k35], truth_before, atol=0.02)
    np.testing.assert_allclose(est[-1], truth_after, atol=0.02)
    late = run.t >= 60.0
    assert np.abs(est[late] - truth_after).max() < 0.05


@pytest.mark.slow
def test_table41_tracking(table41):
    _, (run, _) = table41
    assert _window_max(run, 35.0, 45.0) < 0.5
    assert _window_max(run, 60.0, 70.0) < 0.15


@pytest.mark.slow
def test_table41_detection_and_isolation(table41):
    """Every fault event detected on its wheel and type, with a delay; no false or early declaration."""
    _, (_, m) = table41
    events = m["detection_events"]
    got = {(e["parameter"], e["time"]) for e in events}
    assert got == {("rho_2l", 0.0), ("rho_1l", 35.0), ("rho_2r", 35.0), ("ubar_1r", 35.0)}
    for e in events:
        assert e["detected"], e
        assert 0.0 < e["delay"] < 30.0
        assert e["estimate_error"] < 0.05
        assert e["kind"] == ("friction" if e["parameter"].startswith("ubar") else "gain")
    assert m["false_alarms"] == 0
    assert m["early_declarations"] == 0
    assert m["detection_delay_max"] == pytest.approx(max(e["delay"] for e in events))


@pytest.mark.slow
def test_guard_bounds_p_on_table41(table41):
    _, (run, m) = table41
    assert m["P_max"] <= 1e10 * (1 + 1e-6)
    assert np.all(np.isfinite(run["rho_hat"])) and np.all(np.isfinite(run["P_max"]))


# ---------------------------------------------------------------------- Table 4.1, UKF
@pytest.mark.slow
def test_ukf_table41(table41_ukf):
    """The UKF estimates the state far better than the Farza observer and follows the excited loss of 1l.

    1l was driven before 35 s, so its loss is seen at once: within 0.05 of 0 five seconds after.
    The other changes of the case are not individually identifiable by the UKF (ERRATA P3); the
    combined effect is (its RMS error is 5 % of the signal's).
    """
    _, (run, m) = table41_ukf
    assert run.ok
    assert m["state_estimation_max_after_5s_q"] < 1e-3
    assert m["state_estimation_max_after_5s_eta"] < 0.02
    k40 = _at(run, 40.0)
    assert abs(run["rho_hat"][k40, 1]) < 0.05
    assert m["combined_effect_error_rms"] < 0.1 * m["combined_effect_rms"]
    assert _window_max(run, 35.0, 45.0) < 0.5
    assert _window_max(run, 60.0, 70.0) < 0.15


@pytest.mark.slow
def test_ukf_gains_of_excited_wheels_within_5s():
    """Noiseless, every wheel driven by varying commands: each gain within 0.05 five seconds after each change."""
    chain = Chain.uniform(2, d=1.0)
    ukf = UKFEstimator(chain, meas_std=1e-4, eta_noise=1e-6, rho_noise=0.5, rho_std0=0.5, estimate=("rho",))
    faults = FaultSchedule(2, [FaultEvent(10.0, "2l", sigma=0.5), FaultEvent(20.0, "1r", sigma=0.3)])
    # a velocity loop on the true eta with varying commands, eta_c = (0.5 + 0.4 sin 1.7t, 0.8 sin 1.3t), sampled
    # at every step; the UKF runs at the samples on the held u (tests/data/harness_scheme.py, UKF)
    H = harness()
    ctrl = H.controller(chain, H.UKF, c0=(0.5, 0.0), amp=(0.4, 0.8), om=(1.7, 1.3), estimator=ukf)
    settings = SimSettings(dt=0.01, duration=30.0, log_every=10)
    run = simulate(Plant(chain, faults), ctrl, np.zeros(4), np.zeros(2), settings)
    assert run.ok, run.reason
    nk = ctrl.kin.n_states
    for t_check, truth in ((15.0, [1, 1, 1, 0.5]), (25.0, [0.3, 1, 1, 0.5]), (29.9, [0.3, 1, 1, 0.5])):
        k = _at(run, t_check)
        rho = ukf.estimates(run["xc"][k, nk : nk + ukf.n_states], run["q"][k]).rho
        np.testing.assert_allclose(rho, truth, atol=0.05)


# ---------------------------------------------------------------------- Table 4.2
@pytest.mark.slow
def test_table42_noisy_run_stays_finite_and_tracks():
    """400 s, 1 mm / 1 mrad noise per sample, the case's guard (p_max = 1e3): finite, tracking holds."""
    case = load_case(f"{CASES}/three_link_active.toml")
    assert case.plant.noise.position == 1e-3 and case.plant.noise.heading == 1e-3
    run, m = run_scheme(case, "active")
    assert run.ok and run.t_end == pytest.approx(400.0)
    for key in ("q_hat", "eta_hat", "rho_hat", "P_max"):
        assert np.all(np.isfinite(run[key])), key
    assert float(run["P_max"].max()) <= 1e3 * (1 + 1e-6)
    assert _window_max(run, 220.0, 400.0) < 0.05  # after 1r's change
    assert m["position_error_final"] < 0.01
    # the identifiable gains: 1r (0.8 after 220 s, through the 30 s filter) and 1l (0.3)
    assert abs(run["rho_hat"][-1, 0] - 0.8) < 0.05
    assert abs(run["rho_hat"][-1, 1] - 0.3) < 0.05


# ---------------------------------------------------------------------- diagnosis logic
def test_detect_steady_new_value_and_ignores_swings():
    t = np.arange(0.0, 60.0, 0.1)
    x = np.ones_like(t)
    x[t >= 20] = 0.5 + 0.8 * np.exp(-(t[t >= 20] - 20)) * np.sin(3 * (t[t >= 20] - 20))  # swing, then 0.5
    swing = np.ones_like(t)
    k = (t >= 30) & (t < 31.5)
    swing[k] = 0.6  # steady for 1.5 s only: shorter than the dwell
    d = detect(t, np.column_stack((x, swing)), ["rho_1r", "rho_2l"], gain_band=0.1, dwell=2.0)
    assert len(d) == 1
    assert d[0].parameter == "rho_1r" and d[0].kind == "gain" and d[0].wheel == "1r"
    assert 22.0 < d[0].t_declared < 26.0
    assert d[0].value == pytest.approx(0.5, abs=0.02)


def test_match_events_counts_false_and_early():
    sched = FaultSchedule(2, [FaultEvent(10.0, "1l", sigma=0.0), FaultEvent(10.0, "2r", ubar=-1.0)])
    names = ["rho_1r", "rho_1l", "rho_2r", "rho_2l", "ubar_1r", "ubar_1l", "ubar_2r", "ubar_2l"]
    ev = true_events(sched, names)
    # the 2r event sets sigma = 0 (default) and ubar = -1: a gain and a friction change
    assert {(e["parameter"], e["time"]) for e in ev} == {("rho_1l", 10.0), ("rho_2r", 10.0), ("ubar_2r", 10.0)}
    decl = [
        Declaration("rho_1l", "1l", "gain", 10.5, 12.0, 0.01, 1.0),
        Declaration("rho_2l", "2l", "gain", 4.0, 6.0, 0.7, 1.0),  # before any fault on 2l
        Declaration("ubar_2r", "2r", "friction", 10.2, 13.0, -0.95, 0.0),
    ]
    res = match_events(decl, ev, 30.0)
    det = {e["parameter"]: e for e in res["events"]}
    assert det["rho_1l"]["delay"] == pytest.approx(2.0)
    assert not det["rho_2r"]["detected"]
    assert det["ubar_2r"]["estimate_error"] == pytest.approx(0.05)
    assert len(res["false_alarms"]) == 1 and len(res["early_declarations"]) == 1


def test_active_controller_settings_are_checked():
    chain = Chain.uniform(2)
    case = load_case(f"{CASES}/two_link_active.toml")
    kin = build(case).kinematic()
    obs = FarzaObserver(chain, 1.0)
    with pytest.raises(Exception, match="tau"):
        ActiveController(chain, kin, 5.0, obs, tau=0.0)
    with pytest.raises(Exception, match="u_limit"):
        ActiveController(chain, kin, 5.0, obs, u_limit=-1.0)
    assert math.isfinite(ActiveController(chain, kin, 5.0, obs, tau=30.0).n_states)
