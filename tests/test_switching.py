"""Passive FTC 1: switching controller, baselines, thesis cases 3.2.3 and 3.3.1.4."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case
from ftcreport.control.baselines import OracleController
from ftcreport.control.kinematic import TwoLinkKinematic
from ftcreport.control.switching import SwitchingController
from ftcreport.errors import UncompensableError
from ftcreport.evaluation.metrics import tracking_errors
from ftcreport.model import Chain, FaultEvent, FaultSchedule
from ftcreport.references import FlatReference, unicycle
from ftcreport.runner import build, run_scheme
from ftcreport.sim import Plant, SimSettings, simulate

CASES = Path(__file__).resolve().parents[1] / "cases"


@pytest.fixture(scope="module")
def two_link():
    """The thesis 3.2.3 case run with switching and nominal (shared by several tests)."""
    case = load_case(CASES / "two_link_switching.toml")
    built = build(case)
    out = {"case": case}
    for scheme in ("switching", "nominal"):
        out[scheme] = run_scheme(case, scheme, built)
    return out


@pytest.fixture(scope="module")
def three_link():
    case = load_case(CASES / "three_link_switching.toml")
    built = build(case)
    return {"case": case, **{s: run_scheme(case, s, built) for s in ("switching", "nominal", "oracle")}}


# ------------------------------------------------------------------ thesis 3.2.3
@pytest.mark.slow
def test_two_link_thesis_case_switching(two_link):
    run, m = two_link["switching"]
    assert m["status"] == "ok", m["reason"]
    pos, _ = tracking_errors(run["q"], run["q_d"])
    for t_fault in (20.0, 50.0, 80.0, 110.0):
        end = t_fault + 30.0
        after = (run.t >= t_fault + 10.0) & (run.t < end)
        assert pos[after].max() < 0.01, t_fault
    assert m["position_error_final"] < 1e-6
    assert m["switching_match_fraction"] >= 0.99
    assert 0.0 <= m["switching_exact_match_fraction"] <= m["switching_match_fraction"]
    needing = [d for d in m["detection_delays"] if d["needs_switch"]]
    assert len(needing) >= 3  # 20 s, 50 s and 110 s need a switch (80 s: the applied model stays valid)
    for d in needing:
        assert d["delay"] is not None and d["delay"] <= 0.2, d


@pytest.mark.slow
def test_nominal_is_measurably_worse(two_link):
    """Without FTC the post-fault errors are larger (the velocity loop's high gain hides much of it)."""
    _, ms = two_link["switching"]
    _, mn = two_link["nominal"]
    assert mn["status"] == "ok"
    # phases 3 (1r + 2l lost) and 4 (2l lost): max error after the fault
    for k in (2, 3):
        assert mn["phases"][k]["position_error_max"] > 1.4 * ms["phases"][k]["position_error_max"], k
    assert mn["phases"][3]["position_error_max"] > 10 * ms["phases"][3]["position_error_max"]


@pytest.mark.slow
def test_ros2_matches_fine_rk4_on_the_stiff_case():
    """The stiff thesis loop (k4 = 3000): ROS2 at 5 ms vs RK4 at 0.5 ms over the first 4 s."""
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    from ftcreport.control.tracking import TrackingController

    errs = {}
    for method, dt in (("rk4", 5e-4), ("ros2", 5e-3)):
        ctrl = TrackingController(chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), k_v=3000.0)
        run = simulate(
            Plant(chain),
            ctrl,
            np.array([0.3, -0.2, 0, 0]),
            np.zeros(2),
            SimSettings(dt=dt, duration=4.0, method=method, log_every=int(0.1 / dt)),
        )
        assert run.ok
        errs[method] = tracking_errors(run["q"], run["q_d"])[0]
    np.testing.assert_allclose(errs["ros2"], errs["rk4"], rtol=1e-3, atol=1e-6)


# ------------------------------------------------------------------ reconstruction
def _healthy_two_link(selected: int):
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, 10, 2, 0.5)
    ctrl = SwitchingController(chain, kin, k_v=5.0, T_min=1e9, initial_model=selected)
    run = simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=10.0))
    return ctrl, run


@pytest.mark.parametrize("method", ["rk4", "ros2"])
def test_matched_reconstruction_is_exact_whichever_model_is_applied(method):
    """Healthy wheels, filters from etahat(0) = eta(0): the healthy model's error stays ~0,
    also when a model assuming 1l failed is applied (T_min forbids switching)."""
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    for applied in (0, 3):  # healthy; '1l failed'
        ctrl = SwitchingController(
            chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), k_v=5.0, T_min=1e9, initial_model=applied
        )
        run = simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=10.0, method=method))
        assert run.ok
        J = run["cost"]
        assert np.all(run["selected"] == applied)
        # the healthy model (0) reconstructs exactly: (m/s)^2 at round-off level
        assert J[:, 0].max() < 1e-20
        # the applied model too (it sends no torque where it differs from the truth)
        assert J[:, applied].max() < 1e-20
        # a model assuming 1r failed while 1r is driven does not
        assert J[-1, 4] > 1e-8


def test_matched_error_decays_at_gamma_after_a_fault():
    """After the fault the now-matched model's error obeys e' = -gamma e: J ~ exp(-2 gamma t)."""
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    gamma = 4.0
    ctrl = SwitchingController(chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), k_v=5.0, gamma=gamma)
    faults = FaultSchedule(2, [FaultEvent(5.0, "2r")])
    run = simulate(Plant(chain, faults), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.005, duration=7.0))
    j = ctrl.patterns.tolist().index([1, 1, 0, 1])
    m = (run.t >= 5.0) & (run.t <= 6.5)
    J = run["cost"][m, j]
    assert J[0] > 1e-12  # the filter had drifted before the fault
    rate = -np.polyfit(run.t[m] - 5.0, np.log(J), 1)[0]
    assert rate == pytest.approx(2 * gamma, rel=1e-4)


def test_uncompensable_model_list_refused():
    chain = Chain.uniform(2)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    with pytest.raises(UncompensableError, match="rank"):
        SwitchingController(chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), 5.0, patterns=[(0, 0, 1, 1)])


def test_oracle_tracks_exactly_through_faults_with_friction():
    """The oracle cancels sigma and ubar: no transient at all at the fault (upper bound)."""
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    faults = FaultSchedule(2, [FaultEvent(3.0, "1r", 0.0, -2.0), FaultEvent(6.0, "2l", 0.5, 1.0)])
    ctrl = OracleController(chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), k_v=5.0)
    r0 = ref.at(0.0)
    run = simulate(Plant(chain, faults), ctrl, r0.q_d, r0.eta_d, SimSettings(dt=0.01, duration=9.0))
    assert run.ok
    pos, head = tracking_errors(run["q"], run["q_d"])
    assert pos.max() < 1e-9 and head.max() < 1e-9


# ------------------------------------------------------------------ thesis 3.3.1.4
@pytest.mark.slow
def test_three_link_thesis_case(three_link):
    run, m = three_link["switching"]
    assert m["status"] == "ok", m["reason"]
    e = np.abs(run["q"] - run["q_d"])
    k60 = int(np.searchsorted(run.t, 60.0)) - 1  # just before the 60 s event
    assert e[k60].max() < 1e-3
    assert m["switching_match_fraction"] >= 0.99


@pytest.mark.slow
def test_three_link_nominal_and_oracle_bracket_switching(three_link):
    _, ms = three_link["switching"]
    _, mn = three_link["nominal"]
    _, mo = three_link["oracle"]
    after = slice(1, None)
    worst = {k: max(p["position_error_max"] for p in m["phases"][after]) for k, m in (("s", ms), ("n", mn), ("o", mo))}
    assert worst["o"] <= worst["s"] * 1.01 + 1e-9
    assert worst["n"] > worst["s"]


# ------------------------------------------------------------------ uncompensable case
@pytest.mark.slow
def test_uncompensable_case_warns_and_records_loss():
    case = load_case(CASES / "two_link_uncompensable.toml")
    warnings = case.warnings()
    assert len(warnings) == 1
    assert "faults[1]" in warnings[0] and "t = 30 s" in warnings[0] and "robot 1" in warnings[0]
    for scheme in ("switching", "oracle"):
        _, m = run_scheme(case, scheme)
        assert m["status"] in ("ok", "singular", "diverged")  # completed or stopped with a reason
        assert m["phases"][1]["position_error_max"] < 0.01  # 1r alone is compensable
        assert m["phases"][2]["position_error_max"] > 0.5  # tracking lost after 30 s, and recorded
        assert m["phases"][2]["recovery_time"] is None
