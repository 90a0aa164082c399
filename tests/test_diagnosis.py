"""Diagnosis scored against the truth (issue 18): hand-made estimate traces through detect + match_events.

Each trace is an estimate that leaves its nominal value at a fault and settles (after a short
exponential transient) at a chosen value; the detector declares it after the dwell, and the
scoring compares the declared value, wheel and kind with the true change within its phase.
"""

from __future__ import annotations

import numpy as np
import pytest

from ftcreport.evaluation.diagnosis import detect, match_events, phase_combined_effect, true_events
from ftcreport.model import Chain, FaultEvent, FaultSchedule

grid = np.arange(0.0, 60.0, 0.05)
NAMES2 = ["rho_1r", "rho_1l", "rho_2r", "rho_2l", "ubar_1r", "ubar_1l", "ubar_2r", "ubar_2l"]


def _settle(t0: float, start: float, value: float, tc: float = 0.5) -> np.ndarray:
    """start before t0, then start -> value with time constant tc."""
    x = np.full_like(grid, start)
    k = grid >= t0
    x[k] = value + (start - value) * np.exp(-(grid[k] - t0) / tc)
    return x


def _traces(**cols) -> np.ndarray:
    """(K, 8) estimates: nominal everywhere except the given columns."""
    X = np.column_stack([np.ones_like(grid)] * 4 + [np.zeros_like(grid)] * 4)
    for name, x in cols.items():
        X[:, NAMES2.index(name)] = x
    return X


def _score(sched: FaultSchedule, X: np.ndarray, **kw):
    decl = detect(grid, X, NAMES2, gain_band=0.1, friction_band=0.2, dwell=2.0)
    return match_events(decl, true_events(sched, NAMES2), float(grid[-1]), boundaries=list(sched.times), **kw)


def test_right_value_is_a_detection_with_its_delay():
    sched = FaultSchedule(2, [FaultEvent(10.0, "1l", sigma=0.3)])
    res = _score(sched, _traces(rho_1l=_settle(10.0, 1.0, 0.32)))
    (ev,) = res["events"]
    assert ev["outcome"] == "detected" and ev["detected"]
    # declared when the last 2 s (the dwell) stay within band/4 = 0.025 of their mean: the transient
    # 0.68 exp(-(t - 10)/0.5) spans less than that from ~11.5 s on, so about 3.5 s after the fault
    assert 3.0 < ev["delay"] < 4.5
    # the declared value is the window mean: 0.32 plus the window's share of the transient tail (< 0.025)
    assert 0.02 < ev["estimate_error"] < 0.02 + 0.025
    assert res["false_alarms"] == [] and res["corrections"] == []


def test_wrong_value_is_a_wrong_estimate_not_a_detection():
    """Table 4.2's rho_3r case in miniature: true 0.1, estimate settles at 0.51 (the mean of the robot's wheels)."""
    sched = FaultSchedule(2, [FaultEvent(10.0, "2r", sigma=0.1)])
    res = _score(sched, _traces(rho_2r=_settle(10.0, 1.0, 0.51)))
    (ev,) = res["events"]
    assert ev["outcome"] == "wrong_estimate" and not ev["detected"]
    assert ev["delay"] is None
    assert ev["estimate"] == pytest.approx(0.51, abs=0.01)
    assert ev["estimate_error"] == pytest.approx(0.41, abs=0.01)
    assert res["declarations"][0]["verdict"] == "wrong_estimate"
    assert res["false_alarms"] == []  # attributed to the event, not a false alarm
    # a wide enough tolerance accepts it: the tolerance is what decides
    wide = _score(sched, _traces(rho_2r=_settle(10.0, 1.0, 0.51)), gain_tol=0.5)
    assert wide["events"][0]["outcome"] == "detected"


def test_wrong_wheel_is_a_wrong_isolation_and_a_false_alarm():
    """1l fails; the estimate of 2l moves instead (and settles at the right value for 1l)."""
    sched = FaultSchedule(2, [FaultEvent(10.0, "1l", sigma=0.0)])
    res = _score(sched, _traces(rho_2l=_settle(10.0, 1.0, 0.0)))
    (ev,) = res["events"]
    assert ev["outcome"] == "wrong_isolation"
    assert ev["declared_elsewhere"] == ["rho_2l"]
    assert len(res["false_alarms"]) == 1 and res["false_alarms"][0]["parameter"] == "rho_2l"
    # the right wheel but the wrong kind (a friction declared for a gain loss) is also a wrong isolation
    res = _score(sched, _traces(ubar_1l=_settle(10.0, 0.0, -1.0)))
    assert res["events"][0]["outcome"] == "wrong_isolation"
    assert res["events"][0]["declared_elsewhere"] == ["ubar_1l"]


def test_recovery_needs_the_recovered_value():
    """A gain lost at 10 s recovers to 1.0 at 30 s: an estimate of -0.15 after 30 s is not a detection."""
    sched = FaultSchedule(2, [FaultEvent(10.0, "1r", sigma=0.0), FaultEvent(30.0, "1r", sigma=1.0)])
    wrong = _settle(10.0, 1.0, 0.0)
    wrong[grid >= 30.0] = _settle(30.0, 0.0, -0.15)[grid >= 30.0]
    res = _score(sched, _traces(rho_1r=wrong))
    loss, back = res["events"]
    assert loss["outcome"] == "detected"
    assert back["time"] == 30.0 and back["value"] == 1.0
    assert back["outcome"] == "wrong_estimate" and back["estimate"] == pytest.approx(-0.15, abs=0.01)
    right = _settle(10.0, 1.0, 0.0)
    right[grid >= 30.0] = _settle(30.0, 0.0, 1.02)[grid >= 30.0]
    res = _score(sched, _traces(rho_1r=right))
    assert [e["outcome"] for e in res["events"]] == ["detected", "detected"]
    assert 0.0 < res["events"][1]["delay"] < 5.0


def test_missed_within_its_phase_even_if_declared_after_the_next_event():
    """1l fails at 10 s, 2r at 20 s; the 1l estimate settles only at ~25 s: missed, no 15 s delay."""
    sched = FaultSchedule(2, [FaultEvent(10.0, "1l", sigma=0.0), FaultEvent(20.0, "2r", sigma=0.5)])
    slow = _settle(10.0, 1.0, 0.0, tc=4.0)  # within 0.025 of 0 only after ~14.8 s of transient
    res = _score(sched, _traces(rho_1l=slow, rho_2r=_settle(20.0, 1.0, 0.5)))
    first, second = res["events"]
    assert first["parameter"] == "rho_1l" and first["phase_end"] == 20.0
    assert first["outcome"] == "missed" and first["delay"] is None
    assert second["outcome"] == "detected" and second["delay"] < 5.0
    # the late 1l declaration brings the diagnosis to the truth: a correction, not a false alarm
    verdicts = {d["parameter"]: (d["verdict"], d["t_declared"]) for d in res["declarations"]}
    assert set(verdicts) == {"rho_1l", "rho_2r"}
    assert verdicts["rho_2r"][0] == "correct"
    assert verdicts["rho_1l"][0] == "correction" and verdicts["rho_1l"][1] > 20.0
    assert res["false_alarms"] == []


def test_nothing_declared_is_missed_and_nothing_changed_is_a_false_alarm():
    sched = FaultSchedule(2, [FaultEvent(30.0, "2l", ubar=-1.0, sigma=1.0)])
    res = _score(sched, _traces(rho_1r=_settle(5.0, 1.0, 0.6)))  # a change declared before any fault
    (ev,) = res["events"]
    assert ev["kind"] == "friction" and ev["outcome"] == "missed"
    assert len(res["false_alarms"]) == 1 and len(res["early_declarations"]) == 1


def test_combined_effect_is_exact_when_the_individual_parameters_are_not():
    """Two wheels with identical input columns: swapping their gains leaves the combined effect exact (P3)."""
    K = grid.size
    MB = np.zeros((K, 2, 4))
    MB[:, 0, 0] = MB[:, 0, 1] = 0.2  # wheels 0 and 1 act identically
    MB[:, 1, 2] = 0.3
    u = np.ones((K, 4))
    rho_true = np.tile([1.0, 0.0, 1.0, 1.0], (K, 1))
    rho_hat = np.tile([0.5, 0.5, 1.0, 1.0], (K, 1))  # each wrong by 0.5, their sum right
    from ftcreport.evaluation.diagnosis import combined_effect

    ce_t = combined_effect(MB, u, rho_true, np.zeros((K, 4)))
    ce_h = combined_effect(MB, u, rho_hat, np.zeros((K, 4)))
    (ph,) = phase_combined_effect(grid, ce_h, ce_t, rho_hat, rho_true, ["a", "b", "c", "d"], [(0.0, 60.0)], 2.0)
    assert ph["combined_effect_error_rms"] == pytest.approx(0.0, abs=1e-15)
    assert ph["combined_effect_rms"] == pytest.approx(np.hypot(0.2, 0.3), rel=1e-12)
    assert ph["parameter_errors"] == {"a": 0.5, "b": 0.5, "c": 0.0, "d": 0.0}


def test_observer_initial_estimate_is_configurable():
    """q_hat(0) = q(0) by default; the thesis's q_hat(0) = 0 (4.2.4) through the case field q_hat0."""
    from pathlib import Path

    from ftcreport.cases import load_case
    from ftcreport.observers import FarzaObserver
    from ftcreport.runner import build, make_controller

    chain = Chain.uniform(2)
    q0 = np.array([0.0, 1.0, 0.2, 0.1])
    measured = FarzaObserver(chain, 1.6).initial_state(q0)
    zero = FarzaObserver(chain, 1.6, q_hat0="zero").initial_state(q0)
    np.testing.assert_array_equal(measured[:4], q0)
    np.testing.assert_array_equal(zero[:4], np.zeros(4))
    np.testing.assert_array_equal(zero[4:], measured[4:])  # velocities, parameters, Y and P alike
    with pytest.raises(Exception, match="q_hat0"):
        FarzaObserver(chain, 1.6, q_hat0="first")
    case = load_case(Path(__file__).resolve().parents[1] / "cases" / "two_link_active.toml")
    assert case.schemes.active.q_hat0 == "measured"
    active = case.schemes.active.model_copy(update={"q_hat0": "zero"})
    case = case.model_copy(update={"schemes": case.schemes.model_copy(update={"active": active})})
    built = build(case)
    ctrl = make_controller(built, "active")
    xc = ctrl.initial_state(0.0, built.q0, built.eta0)
    assert xc[ctrl._est][:4].tolist() == [0.0, 0.0, 0.0, 0.0]  # q_hat(0), the observer's first states


def test_input_matrices_solve_the_reduced_model_at_every_row():
    """The compiled rows equal Mbar1^-1 Bbar from the model's own face, solved by LAPACK, per row.

    Tolerance 1e-14 absolute on entries of order 0.3: the closed-form 2 x 2 inverse and LU differ
    only in round-off (a few ulps of the entries times cond(Mbar1), which is below 10 here).
    """
    from ftcreport.evaluation.diagnosis import input_matrices
    from ftcreport.model import kernels as K

    chain = Chain.uniform(3, d=[0.5, 0.7])
    rng = np.random.default_rng(3)
    q = np.zeros((40, chain.n_q))
    q[:, :2] = rng.normal(0.0, 2.0, (40, 2))
    q[:, 2:] = rng.normal(0.0, 0.4, (40, chain.n_q - 2))  # articulations well inside +-90 deg
    got = input_matrices(chain, q)
    assert got.shape == (40, 2, chain.n_wheels)
    for k in range(q.shape[0]):
        Mbar1, _, _, Bbar = K.reduced(chain.params, q[k], np.zeros(2))
        np.testing.assert_allclose(got[k], np.linalg.solve(Mbar1, Bbar), rtol=0, atol=1e-14)
