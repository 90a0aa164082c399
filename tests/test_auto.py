"""The error-controlled integrators in the loop (issue 36 item 5): ``method = "auto"`` and the named ones.

What the loop promises beside the formulas (tests/test_integrators.py): it lands on every instant the
run must not step over, picks the stiff method for the stiff thesis case, runs a case that a fixed step
cannot, stops below its minimum step with a reason that names the tolerances, and keeps the metric stream
at every accepted step.  Each shipped case's auto twin is held to its fixed-step run in
tests/test_auto_twins.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case
from ftcreport.control import TrackingController, TwoLinkKinematic
from ftcreport.model import Chain
from ftcreport.references import FlatReference, unicycle
from ftcreport.runner import run_scheme
from ftcreport.sim import Plant, SimSettings, simulate

CASES = Path(__file__).resolve().parents[1] / "cases"


def _case(name: str, **sim):
    case = load_case(CASES / f"{name}.toml")
    return case.model_copy(update={"simulation": case.simulation.model_copy(update=sim)})


def _run(name: str, scheme: str, **sim):
    return run_scheme(_case(name, **sim), scheme)


def test_the_four_link_chain_that_stops_at_a_fixed_step_runs_with_auto():
    """Four non-uniform robots on the eight (cases/four_link_eight_step.toml), the adaptive law: RK4 at
    dt = 0.02 s stops step_unstable at 10.06 s (omega_1 jumps to 1.7e3 rad/s in one step); auto (DOPRI5
    picked: rho dt = 1.06) runs past it, shortening its steps where the loop needs them."""
    fixed, _ = _run("four_link_eight_step", "adaptive", duration=15.0)
    assert fixed.status == "step_unstable", fixed.reason
    assert fixed.t_end == pytest.approx(10.06)
    run, m = _run("four_link_eight_step", "adaptive", duration=15.0, method="auto")
    assert run.status == "ok", run.reason
    assert run.t_end == pytest.approx(15.0)
    g = m["integrator"]
    assert g["method"] == "dopri5" and g["requested"] == "auto"
    assert g["rejected"] > 0  # the controller did reject steps on the way
    h = np.diff(run.t_stream)
    assert h.max() <= 0.02 * (1 + 1e-12) and h.min() < 0.002  # the longest step, and far shorter ones


def test_the_stiff_thesis_case_picks_the_stiff_method():
    """Thesis 3.2.3 (two_link_switching, k4 = 3000): the loop's spectral radius is k4 (times RKC's safety
    1.2), so rho dt = 18 > 3 x 3.3: auto takes the Rosenbrock W-method ROS34PW2; a k_v = 5 chain stays explicit."""
    run, m = _run("two_link_switching", "switching", duration=1.0, method="auto")
    assert run.status == "ok", run.reason
    g = m["integrator"]
    assert g["method"] == "ros34pw2"
    assert g["spectral_radius"] == pytest.approx(1.2 * 3000.0, rel=0.05)
    _, m3 = _run("three_link_switching", "switching", duration=1.0, method="auto")
    assert m3["integrator"]["method"] == "dopri5"
    assert m3["integrator"]["spectral_radius"] * 0.01 < 3.3


def test_etd3ec_under_continuous_control_takes_its_block_at_every_trial():
    """Its block's eta columns are reused only under sampled control: under continuous control they hold the
    law's -k_v (k4 = 3000 here), a stiff diagonal whose staleness the estimate would not see (docs/ENGINE.md,
    etd3ec).  Named etd3ec on the motor case with the law running continuously: a block per trial."""
    run, m = _run("motors/two_link_switching_motors", "switching", duration=0.05, method="etd3ec", sample_time=None)
    assert run.status == "ok", run.reason
    g = m["integrator"]
    assert g["method"] == "etd3ec" and g["accepted"] > 10
    assert g["linear_blocks"] == g["accepted"] + g["rejected"]


def test_motors_under_sampled_control_pick_etd3():
    """The DC-motor cases (200 Hz control, held voltages): the currents' R_a / L_a = 2,267 /s makes the plant
    stiff at dt = 5 ms; between samples it is autonomous, so auto takes the exponential ETD3RK with its
    embedded ETD2 (etd3ec), every step lands on a sample instant, and a step costs 3 rate evaluations
    (f(x), two stages; etd2ec's step doubling took 7), and 2 more (the linear block's two difference columns)
    when its block is taken: at the first step, every JAC_REUSE accepted steps, and after a rejection (and
    when the torque coupling drifts by COUPLING_DRIFT: not within these 0.5 s)."""
    from ftcreport.fast.loop import JAC_REUSE

    run, m = _run("motors/two_link_switching_motors", "switching", duration=0.5, method="auto")
    assert run.status == "ok", run.reason
    g = m["integrator"]
    assert g["method"] == "etd3ec"
    # a rejected trial reuses f(x); the start: f(t0), 20 power iterations, the starting step's trial stage
    assert g["evaluations"] == 3 * g["accepted"] + 2 * g["rejected"] + 2 * g["linear_blocks"] + 1 + 20 + 1
    assert math.ceil(g["accepted"] / JAC_REUSE) <= g["linear_blocks"]
    assert g["linear_blocks"] <= math.ceil(g["accepted"] / JAC_REUSE) + g["rejected"] + 1
    samples = np.round(np.arange(0.0, 0.5 + 1e-12, 0.005), 12)
    t = run.t_stream
    # every sample instant is a step boundary (to round-off of t0 + j T_s)
    assert np.all(np.min(np.abs(t[None, :] - samples[:, None]), axis=1) < 1e-12)


def _pi_drive_at(rate: float | None, **sim):
    case = _case("motors/three_link_switching_pi", sample_time=None, **sim)  # continuous control
    return case.model_copy(update={"actuators": case.actuators.model_copy(update={"drive_rate": rate})})


def test_auto_on_continuous_control_with_a_sampled_pi_drive_picks_etd3():
    """The attack on the Rosenbrock pick: continuous control through a PI drive sampled at its own 200 Hz
    (three_link_switching_pi without its control sample) went to ros34pw2, 2.33M evaluations for 5 s (1.5e-3 m
    from a tight DOPRI5 reference, where DOPRI5 took 220k for 3.8e-5 m and etd3ec 22k for 3.5e-5 m; at rtol
    1e-8: ros34pw2 4.1M, etd3ec 59k, dopri5 198k).  The drive holds its voltage between its own samples, so
    the stiff currents are linear there, as under sampled control: auto takes etd3ec.  A continuous PI drive
    keeps ros34pw2, the cheapest there (14k evaluations, 1.0e-8 m; etd3ec 56k, dopri5 73k)."""
    run, m = run_scheme(_pi_drive_at(200.0, duration=1.0, method="auto"), "nominal")
    assert run.status == "ok", run.reason
    assert m["integrator"]["method"] == "etd3ec"
    explicit, me = run_scheme(_pi_drive_at(200.0, duration=1.0, method="dopri5"), "nominal")
    assert m["integrator"]["evaluations"] < 0.5 * me["integrator"]["evaluations"]
    # the same end to the two methods' tolerance (rtol 1e-6: measured 3.5e-5 m apart at 5 s, both from a tight run)
    assert np.max(np.abs(run.stream["q"][-1, :2] - explicit.stream["q"][-1, :2])) < 1e-4
    cont, mc = run_scheme(_pi_drive_at(None, duration=1.0, method="auto"), "nominal")
    assert cont.status == "ok" and mc["integrator"]["method"] == "ros34pw2", cont.reason


def test_a_tolerance_min_step_cannot_reach_is_named_with_the_step_it_asks_for():
    """The attack on the error control: ros34pw2 at rtol = 1e-12 on the motor plant stops at min_step (the
    error 1e9 times the tolerance), and the reason offered only 'a finite-time blow-up, or a discontinuity'.
    It now names the step the tolerance asks for at the method's error order and the two ways out."""
    run, _ = _run("motors/two_link_switching_motors", "nominal", duration=0.05, method="ros34pw2", rtol=1e-12,
                  atol=1e-14, min_step=1e-4)  # fmt: skip
    assert run.status == "diverged", run.reason
    words = (
        "rtol = 1e-12, atol = 1e-14 ask for steps near",
        "below min_step = 0.0001 s",
        "loosen rtol and atol or lower min_step",
        "or the rates change faster than any step resolves",
    )
    for w in words:
        assert w in run.reason, run.reason


def test_steps_land_on_faults_and_dwell_ends():
    """Fault times are step boundaries; after each switch at t_s (switching, T_min = 0.01 s) a step ends
    at t_s + T_min exactly, where the dwell lets the rule choose again."""
    run, _ = _run("three_link_switching", "switching", duration=30.0, method="auto", dt=0.05)
    assert run.status == "ok", run.reason
    t = run.t_stream
    case = _case("three_link_switching")
    for te in case.fault_schedule().times:
        if te < 30.0:
            assert np.min(np.abs(t - te)) == 0.0, te
    sel = run.stream["selected"][:, 0] if run.stream["selected"].ndim == 2 else run.stream["selected"]
    switches = np.flatnonzero(sel[1:] != sel[:-1]) + 1
    assert switches.size >= 2
    T_min = case.schemes.switching.T_min
    for k in switches:
        # the rule runs after the step that ends at t[k]; that step's end is the switch time
        assert np.min(np.abs(t - (t[k] + T_min))) < 1e-12 * max(1.0, t[k])


def test_below_min_step_the_run_stops_with_the_tolerances_named():
    """DOPRI5 on a k_v = 3000 loop needs steps below 3.3 / 3000 = 1.1 ms for stability; with min_step = 2 ms
    it cannot: the steps it is forced to take at min_step blow up, and the reason names rtol, atol, the
    minimum step and the forced steps."""
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.array([0.1, 0.05, 0.0, 0.0])
    settings = SimSettings(dt=0.005, duration=1.0, method="dopri5", min_step=0.002)
    run = simulate(Plant(chain), TrackingController(chain, kin, k_v=3000.0), q0, r0.eta_d, settings)
    assert run.status == "diverged", run.reason
    for words in ("rtol = 1e-06", "atol = 1e-08", "dopri5", "taken at min_step = 0.002 s with the error over"):
        assert words in run.reason
    assert run.t_end < 1.0 and run.meta["integrator"]["forced_steps"] >= 1
    # at the default min_step the same run completes, its steps below 1.1 ms
    ok = simulate(Plant(chain), TrackingController(chain, kin, k_v=3000.0), q0, r0.eta_d,
                  SimSettings(dt=0.005, duration=1.0, method="dopri5"))  # fmt: skip
    assert ok.status == "ok", ok.reason
    assert np.median(np.diff(ok.t_stream)) < 0.0011


def test_a_discontinuity_is_passed_at_the_minimum_step():
    """The adaptive law's projection freezes a weight at 0 or 1 (kernels.adaptive_law): its rate jumps inside
    a step and the error estimate is O(h x jump).  At the default atol the step falls to min_step = 1e-8 s
    at 0.0442 s and passes; at atol = 1e-12 (a weight at 0 is held to 1e-12) no step is short enough: the
    step at min_step is taken anyway, counted and reported, and the run goes on (measured: 11 such steps
    in 1 s, the first at 0.0093 s, among 529)."""
    from ftcreport.fast import auto_run, loop

    assert auto_run.FORCED_STREAK == loop.FORCED_STREAK
    run, m = _run("two_link_adaptive_eight", "adaptive", duration=1.0, method="auto")
    assert run.status == "ok", run.reason
    assert np.min(np.diff(run.t_stream)) == pytest.approx(1e-8, rel=1e-6)
    assert m["integrator"]["forced_steps"] == 0
    run, m = _run("two_link_adaptive_eight", "adaptive", duration=1.0, method="auto", atol=1e-12)
    assert run.status == "ok", run.reason
    g = m["integrator"]
    assert 1 <= g["forced_steps"] < 0.05 * g["accepted"]
    assert 0.0 < g["first_forced_at"] < 1.0


def test_the_stream_holds_every_accepted_step_and_the_log_every_kth():
    """The metric stream is the accepted steps (non-uniform t); the log every log_every-th and the last."""
    run, m = _run("two_link_adaptive_eight", "adaptive", duration=5.0, method="auto", log_every=3)
    assert run.status == "ok", run.reason
    t = run.t_stream
    assert t.size == m["integrator"]["accepted"] + 1 == m["metric_samples"]
    assert np.all(np.diff(t) > 0) and t[0] == 0.0 and t[-1] == pytest.approx(5.0, abs=1e-12)
    assert np.ptp(np.diff(t)) > 0  # the steps are not equal
    expect = np.unique(np.append(t[::3], t[-1]))
    np.testing.assert_array_equal(run.t, expect)
    np.testing.assert_array_equal(run["q"], run.stream["q"][np.searchsorted(t, expect)])


def _adaptive_eight_auto(tmp_path: Path, **sim) -> Path:
    """cases/two_link_adaptive_eight.toml over its first second (no fault yet), method = "auto"; its
    thresholds, claims and requirements (stated for 60 s) left out."""
    import tomllib

    import tomli_w

    data = tomllib.loads((CASES / "two_link_adaptive_eight.toml").read_text())
    for k in ("faults", "thresholds", "claims", "requirements"):
        data.pop(k, None)
    data["simulation"] |= {"duration": 1.0, "method": "auto", **sim}
    p = tmp_path / "eight_auto.toml"
    p.write_text(tomli_w.dumps(data))
    return p


def test_run_says_how_many_steps_were_forced_at_min_step(tmp_path):
    """Steps taken at min_step with the error over the tolerance do not stop the run (docs/ENGINE.md), but
    the accuracy asked for was not met there: ``run`` says how many in one line, and only when there were
    some (at atol = 1e-12 the adaptive law's projection forces some in the first second; at the default
    atol none)."""
    import json

    from typer.testing import CliRunner

    from ftcreport.cli import app

    runner = CliRunner()
    case = _adaptive_eight_auto(tmp_path, atol=1e-12)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(case), "--scheme", "adaptive", "--out", str(out), "--no-report"])
    assert res.exit_code == 0, res.output
    g = json.loads((out / "eight_auto" / "adaptive" / "metrics.json").read_text())["integrator"]
    assert g["forced_steps"] >= 1
    lines = [ln for ln in res.stderr.splitlines() if "min_step" in ln]
    assert len(lines) == 1, res.stderr
    for words in (str(case), "simulation.min_step", "adaptive", f"{g['forced_steps']} step(s)", "1e-08 s",
                  "atol = 1e-12", f"t = {g['first_forced_at']:.6g} s"):  # fmt: skip
        assert words in lines[0], (words, lines[0])
    res = runner.invoke(app, ["run", str(_adaptive_eight_auto(tmp_path)), "--scheme", "adaptive", "--out",
                              str(out), "--no-report"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "min_step" not in res.output


def test_rtol_and_atol_of_a_fixed_step_case_set_its_stop_recheck():
    """rtol and atol are not unused with a fixed step: a stop that persists at dt/4 is checked again by the
    method's error-controlled twin at the case's rtol and atol (fast.recheck), so they are accepted and the
    fields' descriptions say so.  RK4 on a k_v = 3000 loop at dt = 5 ms (and 1.25 ms) blows up; DOPRI5
    passes the instant, its shortest step set by the tolerances."""
    from ftcreport.cases.tables import Simulation

    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.array([0.1, 0.05, 0.0, 0.0])
    shortest = {}
    for rtol, atol in ((1e-6, 1e-8), (1e-3, 1e-5)):
        settings = SimSettings(dt=0.005, duration=1.0, method="rk4", rtol=rtol, atol=atol)
        run = simulate(Plant(chain), TrackingController(chain, kin, k_v=3000.0), q0, r0.eta_d, settings)
        assert run.status == "step_unstable", run.reason
        assert f"dopri5 at rtol = {rtol:g}, atol = {atol:g}" in run.reason
        controlled = run.meta["integrator"]["recheck"]["controlled"]
        assert controlled["status"] == "ok"
        shortest[rtol] = controlled["min_step_taken"]
    assert shortest[1e-3] > 2 * shortest[1e-6]  # the looser tolerance takes longer steps
    for name in ("rtol", "atol", "min_step"):
        assert "re-check" in Simulation.model_fields[name].description, name
    Simulation(dt=0.01, duration=1.0, method="rk4", rtol=1e-3, atol=1e-5)  # accepted
