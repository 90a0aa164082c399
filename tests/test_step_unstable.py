"""Honest stop reasons (issue 18 item 2): a step that blows up is ``step_unstable``, never ``singular``.

Three mechanisms (ftcreport.sim's docstring): a trial stage that leaves the domain, a new state
that jumps past a check in one step, and a sustained geometric growth of the applied torque.
The torque laws of the growth tests are the GEOMETRIC harness (tests/data/harness_scheme.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import harness

from ftcreport.cases import load_case
from ftcreport.control import TrackingController, TwoLinkKinematic
from ftcreport.model import Chain
from ftcreport.references import FlatReference, unicycle
from ftcreport.runner import run_scheme
from ftcreport.runs import GROWTH_FACTOR, GROWTH_STEPS, GROWTH_TOTAL
from ftcreport.sim import Plant, SimSettings, simulate

CASES = Path(__file__).resolve().parents[1] / "cases"


def _two_link(k_v: float, dt: float, duration: float = 5.0):
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.array([0.1, 0.05, 0.0, 0.0])
    ctrl = TrackingController(chain, kin, k_v=k_v)
    return simulate(Plant(chain), ctrl, q0, r0.eta_d, SimSettings(dt=dt, duration=duration))


# The velocity loop of the computed-torque law has the eigenvalue -k_v; RK4 is stable on the real axis
# for lambda dt > -2.79. k_v = 225 at dt = 0.02 s (lambda dt = -4.5, |R| = 8.5 per step) jumps past the
# speed bound in one step: step_unstable. k_v = 160 (lambda dt = -3.2, |R| = 1.8 per step) grows more
# slowly than the growth detector's e per step and ends at the speed bound: diverged, with dt named.
@pytest.mark.parametrize(
    ("k_v", "status", "words"),
    [(225.0, "step_unstable", "blew up (velocity jumped"), (160.0, "diverged", "velocity")],
)
def test_large_dt_names_the_step(k_v, status, words):
    run = _two_link(k_v, 0.02)
    assert run.status == status, run.reason
    assert words in run.reason
    assert "dt = 0.02 s" in run.reason
    assert "singular" not in run.reason
    assert np.all(np.isfinite(run["q"])) and run.t.size >= 2  # the log up to the stop is kept


def test_the_same_loop_at_a_resolved_step_is_ok():
    # lambda dt = -225 * 0.002 = -0.45: resolved; the run completes and tracks
    run = _two_link(225.0, 0.002, duration=2.0)
    assert run.status == "ok", run.reason


H = harness()


def _geometric(factor: float, dt: float, start: float, k_jump: int | None = None):
    """Torque start factor^k at step k of dt, alternating in sign over the wheels (k_jump: one jump of 1e6)."""
    chain = Chain.uniform(2, d=1.7)
    jump = -1 if k_jump is None else k_jump
    return H.controller(chain, H.GEOMETRIC, factor=factor, dt=dt, start=start, k_jump=jump)


def _run_geometric(ctrl, dt=0.01, duration=0.3):
    chain = Chain.uniform(2, d=1.7)
    q0 = chain.q_from_headings(0.0, 0.0, [0.0, 0.0])
    return simulate(Plant(chain), ctrl, q0, np.array([0.5, 0.0]), SimSettings(dt=dt, duration=duration))


def test_growth_detector_thresholds():
    # 3x per step from 0.1 N m: after 2 steps of growth 9x (< 20), after 3 steps 27x (> 20) and 2.7 N m
    # (> 1 N m): the stop comes at step 3 exactly, t = 0.03 s.
    assert abs(GROWTH_FACTOR - np.e) < 1e-15 and GROWTH_STEPS == 3 and GROWTH_TOTAL == 20.0
    run = _run_geometric(_geometric(3.0, 0.01, 0.1))
    assert run.status == "step_unstable", run.reason
    assert run.t_end == pytest.approx(0.03, abs=1e-12)
    assert "grew more than 2.72x per step for 3 steps" in run.reason
    # 2.5x per step (lambda dt = 0.92: still resolved) never counts; the speed bound ends it as divergence
    slow = _run_geometric(_geometric(2.5, 0.01, 0.1), duration=1.0)
    assert slow.status == "diverged" and "dt = 0.01 s" in slow.reason
    # a single jump of the torque (a fault with friction on a coasting chain) is one step of growth, not three
    jump = _run_geometric(_geometric(1.0, 0.01, 1e-6, k_jump=5), duration=0.2)
    assert jump.status == "ok", jump.reason


def test_four_link_audit_case_stops_honestly():
    """The audit's configuration: four non-uniform robots on the eight (scale 2), 3r with friction, then 2l.

    Nominal and oracle complete at dt = 0.02 s. The adaptive law blows up near t = 10 s; before this
    change such a run was reported as a chained-form singularity. It must now name the step.
    """
    case = load_case(CASES / "four_link_eight_step.toml")
    case = case.model_copy(update={"simulation": case.simulation.model_copy(update={"duration": 12.0})})
    run, metrics = run_scheme(case, "adaptive")
    assert run.status == "step_unstable", run.reason
    assert "dt = 0.02 s" in run.reason
    assert "singular" not in run.reason
    # the logged chain is far from the singular set: the stop is the step's, not the geometry's
    assert metrics["singularity_margin_min"] > np.radians(45.0)
