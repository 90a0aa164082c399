"""Honest stop reasons (issue 18 item 2, issue 36 item 4): a label that blames the step is one a smaller
step removes.

Three detectors (ftcreport.sim's docstring) stop a fixed-step run: a trial stage that leaves the domain,
a new state that jumps past a check in one step, and a sustained geometric growth of the applied torque.
The engine then runs the interval again at dt/4 (fast.recheck._recheck): ``step_unstable`` when the finer
run passes the stop (or stops later), ``singular`` when it also stops no later in a law's singular set,
``diverged`` when the blow-up persists.  The torque laws of the growth tests are the GEOMETRIC and
EXPLODING harnesses (tests/data/harness_scheme.py).
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


def _two_link(k_v: float, dt: float, duration: float = 5.0, saturation=None, offset=(0.1, 0.05, 0.0, 0.0)):
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.array(offset)
    ctrl = TrackingController(chain, kin, k_v=k_v)
    return simulate(Plant(chain, saturation=saturation), ctrl, q0, r0.eta_d, SimSettings(dt=dt, duration=duration))


# The velocity loop of the computed-torque law has the eigenvalue -k_v; RK4 is stable on the real axis
# for lambda dt > -2.79. k_v = 225 at dt = 0.02 s (lambda dt = -4.5, |R| = 8.5 per step) jumps past the
# speed bound in one step; k_v = 160 (lambda dt = -3.2, |R| = 1.8 per step) grows more slowly than the
# growth detector's e per step and reaches the speed bound. At dt/4 (lambda dt = -1.1 and -0.8) both are
# stable: the re-check passes the stop, so both are step_unstable, with dt named.
@pytest.mark.parametrize(("k_v", "words"), [(225.0, "blew up (velocity jumped"), (160.0, "velocity")])
def test_large_dt_names_the_step(k_v, words):
    run = _two_link(k_v, 0.02)
    assert run.status == "step_unstable", run.reason
    assert words in run.reason
    assert "dt = 0.02 s" in run.reason
    assert "at dt/4 = 0.005 s the same run passes this instant" in run.reason
    assert "singular" not in run.reason
    assert np.all(np.isfinite(run["q"])) and run.t.size >= 2  # the log up to the stop is kept
    recheck = run.meta["integrator"]["recheck"]
    assert recheck["status"] == "ok" and recheck["dt"] == 0.005


def test_a_step_unstable_stop_runs_at_a_quarter_of_the_step():
    """The label's promise (36 item 4): the case that stops step_unstable at dt runs through at dt/4."""
    assert _two_link(225.0, 0.02).status == "step_unstable"
    run = _two_link(225.0, 0.005)
    assert run.status == "ok", run.reason
    assert run.t_end == pytest.approx(5.0)


def test_the_same_loop_at_a_resolved_step_is_ok():
    # lambda dt = -225 * 0.002 = -0.45: resolved; the run completes and tracks
    run = _two_link(225.0, 0.002, duration=2.0)
    assert run.status == "ok", run.reason


# A saturation-limited two-link chain (every |u| <= 1 N m) started 57 deg off its heading cannot turn fast
# enough: its heading error e_theta grows to the two-link law's singular set, |e_theta| = 90 deg (the law
# refuses |cos e_theta| < 1e-3, ERRATA P4), at 13.08 s. An RK4 trial stage gets there first from an
# accepted state at 89.9 deg: before issue 36 this was reported step_unstable, at the same time at dt/2.
@pytest.mark.parametrize("dt", [0.01, 0.005])
def test_the_heading_singularity_is_singular_at_every_step(dt):
    run = _two_link(5.0, dt, duration=30.0, saturation=1.0, offset=(0.0, 0.0, 1.0, 1.0))
    assert run.status == "singular", run.reason
    assert "heading error e_theta of robot 2 = -89.9 deg" in run.reason
    assert "the two-link law's singular set (90 deg, ERRATA P4)" in run.reason
    assert "reached by a trial stage" in run.reason and "the law's own singular set, not the step" in run.reason
    assert run.t_end == pytest.approx(13.08, abs=0.01)  # the same stop at dt and dt/2
    # the accepted chain really is at the set's edge: the heading error of the last logged step
    e_theta = np.degrees(np.abs(np.angle(np.exp(1j * (run["q"][-1, 2] - run["q_d"][-1, 2])))))
    assert e_theta > 85.0


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
    # (> 1 N m): the stop comes at step 3 exactly, t = 0.03 s.  The harness's torque grows 3x per 0.01 s of
    # time whatever the step: at dt/4 it grows as fast (27x over the same 3 steps of dt), a fast mode of
    # the loop itself that the finer step resolves: diverged, not step_unstable.
    assert abs(GROWTH_FACTOR - np.e) < 1e-15 and GROWTH_STEPS == 3 and GROWTH_TOTAL == 20.0
    run = _run_geometric(_geometric(3.0, 0.01, 0.1))
    assert run.status == "diverged", run.reason
    assert run.t_end == pytest.approx(0.03, abs=1e-12)
    assert "grew more than 2.72x per step for 3 steps" in run.reason
    assert "at dt/4 = 0.0025 s the torque grows as fast (27x" in run.reason
    # 2.5x per step (lambda dt = 0.92: still resolved) never counts; the speed bound ends it, at dt/4 too
    slow = _run_geometric(_geometric(2.5, 0.01, 0.1), duration=1.0)
    assert slow.status == "diverged" and "dt = 0.01 s" in slow.reason
    assert "the blow-up persists" in slow.reason
    # a single jump of the torque (a fault with friction on a coasting chain) is one step of growth, not three
    jump = _run_geometric(_geometric(1.0, 0.01, 1e-6, k_jump=5), duration=0.2)
    assert jump.status == "ok", jump.reason


def test_a_slow_blow_up_that_persists_is_diverged():
    """x' = 50 x drives every wheel (the EXPLODING harness): e^(50 t) is resolved at dt = 0.01 s (1.65x per
    step) and reaches the speed bound at the same time at dt/4: the loop's own divergence."""
    chain = Chain.uniform(2, d=1.7)
    ctrl = H.controller(chain, H.EXPLODING, rate=50.0)
    run = _run_geometric(ctrl, duration=2.0)
    assert run.status == "diverged", run.reason
    assert "velocity" in run.reason and "the blow-up persists" in run.reason
    assert "the loop's own divergence" in run.reason
    fine = run.meta["integrator"]["recheck"]
    assert fine["status"] == "diverged" and abs(fine["t_end"] - run.t_end) <= 0.02


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
    assert "at dt/4 = 0.005 s the same run passes this instant" in run.reason
    # the logged chain is far from the singular set: the stop is the step's, not the geometry's
    assert metrics["singularity_margin_min"] > np.radians(45.0)
