"""The sensor's own clock (``[plant.noise] sample_time``): the noise a run sees does not depend on its step.

Before, the engine drew one sample of sensor noise per integration step: refining dt drew a new noise
realisation, so ``run --verify-dt`` on a noisy case (three_link_active) compared two different noises, and
benchmarks/accuracy.py found no equal-accuracy line for it (RK4 at dt/2 and dt/4 landed 6.5e-5 and 1.35e-4 m
from the run at dt).  Now draw j holds on [t0 + j T, t0 + (j + 1) T) for the sensor's period T (default the
case's dt, so the shipped numbers do not move), whatever the step.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case, parse_case
from ftcreport.errors import CaseError
from ftcreport.runner import halve_dt, run_scheme

CASES = Path(__file__).resolve().parents[1] / "cases"


def _active(duration: float = 5.0, **sim):
    case = load_case(CASES / "three_link_active.toml")
    return case.model_copy(update={"simulation": case.simulation.model_copy(update={"duration": duration, **sim})})


def _with_period(case, T: float | None):
    noise = case.plant.noise.model_copy(update={"sample_time": T})
    return case.model_copy(update={"plant": case.plant.model_copy(update={"noise": noise})})


def _xy_at(run, t: float) -> np.ndarray:
    i = int(np.searchsorted(run.t_stream, t - 1e-9))
    assert abs(run.t_stream[i] - t) < 1e-9
    return run.stream["q"][i, :2]


def test_the_default_period_is_dt_and_moves_no_number():
    """sample_time = dt written out gives the run of the case as shipped, bit for bit."""
    case = _active(2.0)
    a, ma = run_scheme(case, "nominal")
    b, mb = run_scheme(_with_period(case, case.simulation.dt), "nominal")
    assert np.array_equal(a.stream["q"], b.stream["q"]) and np.array_equal(a.stream["u"], b.stream["u"])
    assert ma["position_error_max"] == mb["position_error_max"]


def test_refining_the_step_keeps_the_draws_and_converges_at_the_method_order():
    """halve_dt (``run --verify-dt``) keeps the sensor on its clock: the measurement noise at the instants both
    runs share is the same, and RK4's differences dt -> dt/2 -> dt/4 shrink by 2^4 (measured 6.0e-10 and
    3.6e-11 m: 16.6x).  Before, they were 6.5e-5 and 1.35e-4 m: the difference of two noise realisations."""
    case = _active(5.0, log_every=1)
    runs = [run_scheme(c, "nominal")[0] for c in (case, halve_dt(case), halve_dt(halve_dt(case)))]
    xs = [_xy_at(r, 5.0) for r in runs]
    d1, d2 = np.max(np.abs(xs[0] - xs[1])), np.max(np.abs(xs[1] - xs[2]))
    assert d1 < 1e-8
    assert 10.0 < d1 / d2 < 25.0
    # the noise itself: q_meas - q at every instant of the coarse run, read from the finer run's log
    coarse, fine = runs[0], runs[1]
    j = np.searchsorted(fine.t, coarse.t - 1e-12)
    np.testing.assert_allclose(fine.t[j], coarse.t, atol=1e-12)
    n_coarse = coarse.signals["q_meas"] - coarse.signals["q"]
    n_fine = fine.signals["q_meas"][j] - fine.signals["q"][j]
    np.testing.assert_allclose(n_fine, n_coarse, rtol=0, atol=1e-15)


def test_a_slower_sensor_holds_each_draw_over_its_period():
    """sample_time = 4 dt: the noise changes only at the sensor's ticks, every fourth step."""
    case = _with_period(_active(1.0, log_every=1), 0.08)
    run, _ = run_scheme(case, "nominal")
    noise = run.signals["q_meas"] - run.signals["q"]
    changes = np.flatnonzero(np.any(np.abs(np.diff(noise, axis=0)) > 1e-9, axis=1)) + 1  # draws of 1e-3, not round-off
    np.testing.assert_allclose(run.t[changes], 0.08 * np.arange(1, changes.size + 1), atol=1e-9)
    assert changes.size == 12  # ticks at 0.08 ... 0.96 s in a 1 s run


def test_an_error_controlled_run_lands_on_every_tick_and_agrees_with_the_fixed_step():
    """dopri5 with its longest step 10 dt lands on every draw (0.02 s) and ends where RK4 at dt/4 ends, within the
    tolerance's reach (measured 3e-12 m at rtol 1e-9)."""
    case = _with_period(_active(2.0), 0.02)
    fine, _ = run_scheme(halve_dt(halve_dt(case)), "nominal")
    sim = case.simulation.model_copy(update={"method": "dopri5", "dt": 0.2, "rtol": 1e-9, "atol": 1e-11})
    auto = case.model_copy(update={"simulation": sim})
    run, _ = run_scheme(auto, "nominal")
    ticks = 0.02 * np.arange(1, 100)
    assert np.all(np.min(np.abs(run.t_stream[:, None] - ticks[None, :]), axis=0) < 1e-9)
    assert np.max(np.abs(_xy_at(run, 2.0) - _xy_at(fine, 2.0))) < 1e-9


def _raw() -> dict:
    return tomllib.loads((CASES / "three_link_active.toml").read_text())


@pytest.mark.parametrize(
    ("noise", "sim", "why"),
    [
        ({"sample_time": 0.03}, {}, "0.03 s is not a whole number of steps dt = 0.02 s"),
        ({"sample_time": 0.01}, {}, "0.01 s is not a whole number of steps dt = 0.02 s"),
        ({"sample_time": 500.0}, {}, "longer than the run (400 s)"),
        ({"sample_time": -1.0}, {}, "must be >= 1e-09, got -1.0"),
        ({"sample_time": 1e-7}, {"method": "auto"}, "exceeds the limit"),
    ],
)
def test_a_sensor_clock_the_step_cannot_hold_is_refused_naming_the_field(noise, sim, why):
    raw = _raw()
    raw["plant"]["noise"].update(noise)
    raw["simulation"].update(sim)
    with pytest.raises(CaseError) as info:
        parse_case(raw, "cases/x.toml")
    assert "cases/x.toml: plant.noise.sample_time: " in str(info.value)
    assert why in str(info.value)


def test_a_sensor_clock_over_the_step_limit_advises_on_the_sensors_period():
    """The attack on the sensor clock: a refusal renamed to plant.noise.sample_time still said 'use dt >= ...',
    advice on a field that does not bind (an error-controlled run lands on every tick whatever dt)."""
    raw = _raw()
    raw["plant"]["noise"]["sample_time"] = 1e-7
    raw["simulation"]["method"] = "auto"
    with pytest.raises(CaseError) as info:
        parse_case(raw, "cases/x.toml")
    text = str(info.value)
    assert "plant.noise.sample_time: " in text and "use plant.noise.sample_time >= 4e-05 s" in text, text
    assert "use dt" not in text and "duration / sample_time = 400 / 1e-07" in text, text


def test_a_noiseless_sensor_clock_binds_no_step_unless_a_discrete_time_filter_reads_it():
    """The attack on the sensor clock: a noiseless case was budgeted with the sensor's ticks under auto (1e-7 s:
    refused), though the run lands on them only to read a draw or to run the UKF's update.  Without noise the
    schemes without a discrete-time filter run; the UKF still reads the sensor's clock and is refused."""
    raw = _raw()
    raw["plant"]["noise"] = {"sample_time": 1e-7}
    raw["simulation"]["method"] = "auto"
    ukf = raw["schemes"].pop("active_ukf")
    raw["schemes"]["run"] = ["nominal", "active", "oracle"]
    assert parse_case(raw, "cases/x.toml").plant.noise.sample_time == 1e-7
    raw["schemes"] |= {"active_ukf": ukf, "run": ["nominal", "active", "active_ukf", "oracle"]}
    with pytest.raises(CaseError) as info:
        parse_case(raw, "cases/x.toml")
    assert "plant.noise.sample_time: " in str(info.value) and "active_ukf" in str(info.value)


def test_an_error_controlled_method_accepts_any_period():
    raw = _raw()
    raw["plant"]["noise"]["sample_time"] = 0.03
    raw["simulation"]["method"] = "auto"
    assert parse_case(raw, "cases/x.toml").plant.noise.sample_time == 0.03


@pytest.mark.parametrize(
    ("name", "digest"),
    [("three_link_active", "bfda24c18c3b9209"), ("five_link_cascade", "bb9bba4183e6dd91"),
     ("motors/two_link_active_motors", "404e114d5f4827a7")],
)  # fmt: skip
def test_a_case_without_a_sensor_period_keeps_its_content_hash(name, digest):
    """The attack on the sensor clock (session 14): 'sample_time: null' joined every case's content hash, so every
    stored run became another content.  Left out when unset, as the other later fields are (the digests are
    those of the code before the field, with the version string 'pinned'); set, it is content."""
    from ftcreport.cases.files import case_hash

    case = load_case(CASES / f"{name}.toml")
    assert case_hash(case, "pinned") == digest
    assert case_hash(_with_period(case, case.simulation.dt), "pinned") != digest


def test_a_sample_time_confirmation_runs_with_a_sensor_period_written_out():
    """The attack on the sensor clock: analysis.confirm.variant sets dt = T / steps for the sample-time limit's
    runs and kept a written sensor period the new dt does not divide (even one equal to the case's dt, the
    default): every confirmation ended 'error' and no limit was confirmed.  The variant's sensor is on its
    default clock (its dt), which the sampled law reads once a sample."""
    from ftcreport.analysis.confirm import variant

    case = load_case(CASES / "motors" / "two_link_switching_motors.toml")
    noise = case.plant.noise.model_copy(update={"position": 1e-3, "sample_time": case.simulation.dt})
    case = case.model_copy(update={"plant": case.plant.model_copy(update={"noise": noise})})
    v = variant(case, "nominal", "sample_time_max", 0.9 * 1.371e-3, 200)
    assert v.plant.noise.sample_time is None and v.plant.noise.position == 1e-3
    run, m = run_scheme(v, "nominal")
    assert m["status"] == "ok", run.reason


def test_the_ukf_updates_on_the_sensors_clock_so_refining_the_step_keeps_its_filter():
    """The attack on the sensor clock: halve_dt kept the noise's draws but halved dt, which was also the UKF's
    period (it updated at every fixed step, and on an error-controlled run's dt ticks): 'run --verify-dt' on the
    shipped three_link_active called active_ukf not converged (torque_peak 2.26 %), and RK4's dt -> dt/2 -> dt/4
    differences fell 3.2x (9.4e-5, 2.9e-5 m).  The filter now updates when a measurement arrives, on the sensor's
    ticks: measured 1.5e-11 and 1.0e-12 m (15x, RK4's order), torque_peak equal to 1e-10."""
    case = _active(5.0, log_every=1)
    case = case.model_copy(update={"faults": [f for f in case.faults if f.time < 5.0]})
    runs = [run_scheme(c, "active_ukf") for c in (case, halve_dt(case), halve_dt(halve_dt(case)))]
    xs = [r.stream["q"][-1, :2] for r, _ in runs]
    d1, d2 = np.max(np.abs(xs[0] - xs[1])), np.max(np.abs(xs[1] - xs[2]))
    assert d1 < 1e-9 and 10.0 < d1 / d2 < 25.0, (d1, d2)
    peaks = [m["torque_peak"] for _, m in runs]
    assert max(peaks) - min(peaks) < 1e-8 * max(peaks)


def test_a_fixed_and_an_error_controlled_ukf_update_at_the_same_ticks():
    """With a sensor slower than the step (0.04 s, dt = 0.02 s) the fixed step's filter updates every other step
    and the error-controlled run's on the same ticks: the two runs agree to their integration error (measured
    1.3e-11 m); the filter at 0.02 s is another filter (1.3e-4 m away)."""
    case = _with_period(_active(2.0), 0.04)
    case = case.model_copy(update={"faults": [f for f in case.faults if f.time < 2.0]})
    fixed, _ = run_scheme(case, "active_ukf")
    sim = case.simulation.model_copy(update={"method": "dopri5", "rtol": 1e-10, "atol": 1e-12})
    auto, _ = run_scheme(case.model_copy(update={"simulation": sim}), "active_ukf")
    assert np.max(np.abs(_xy_at(fixed, 2.0) - _xy_at(auto, 2.0))) < 1e-8
    every, _ = run_scheme(_with_period(case, 0.02), "active_ukf")  # the filter at dt: another filter
    assert np.max(np.abs(_xy_at(fixed, 2.0) - _xy_at(every, 2.0))) > 1e-7


def test_the_stops_recheck_refines_the_step_not_the_ukfs_clock():
    """CI's check of the shipped two_link_adaptive_circle: after the UKF moved to the sensor's clock, the stop's
    re-check at dt/4 (fast.recheck._recheck) still ran its filter through run_steps' default ticks, which it
    passed the coarse settings, by accident of an argument left out.  The re-check now says it: the filter updates
    on the coarse run's ticks (the sensor's 5 ms), as 'run --verify-dt' keeps them.  At dt/4 with that filter the
    torque grows as fast as at dt (measured 330x over the detector's 3 steps of dt, against 20 for e-fold a
    step) and the rk4 step then jumps into the articulation singularity, where dopri5 stops too: the loop's own
    fast mode, ``diverged``, as the case now expects; with the filter at dt/4 the finer run reached the set
    slower (``singular``)."""
    case = load_case(CASES / "two_link_adaptive_circle.toml")
    case = case.model_copy(update={"simulation": case.simulation.model_copy(update={"duration": 42.0})})
    run, m = run_scheme(case, "active_ukf")
    fine = run.meta["integrator"]["recheck"]
    assert m["status"] == "diverged" and m["status"] in case.expected_status_of["active_ukf"], run.reason
    assert fine["dt"] == 0.00125 and fine["growth"] > 2.72**3 * 5, fine
    assert abs(fine["t_end"] - 40.87) < 0.01, fine


def test_the_case_page_says_the_filter_updates_on_the_sensors_clock():
    """The page's idealizations name the UKF's clock beside the control's timing: a 0.04 s sensor, 0.04 s."""
    from ftcreport.report.plant import _idealizations

    def timing(case) -> str:
        return next(r["includes"] for r in _idealizations(case) if r["aspect"] == "control timing")

    assert "active_ukf: a discrete-time filter, updated once a measurement (every 0.02 s)" in timing(_active())
    assert "every 0.04 s" in timing(_with_period(_active(), 0.04))
    sampled = _active(sample_time=0.04)
    assert "active_ukf: a discrete-time filter, updated at each sample" in timing(sampled)
    case = _active()
    no_ukf = case.model_copy(update={"schemes": case.schemes.model_copy(update={"active_ukf": None})})
    assert "discrete-time filter" not in timing(no_ukf)


def test_the_pages_provenance_says_what_the_stops_recheck_found_not_its_detectors_label():
    """Seen on the batch page of two_link_adaptive_circle: the provenance read 'its stop re-checked at dt =
    0.00125 s: step_unstable' beside a run labelled diverged (the fine run's own detector, not the verdict), as
    if the step were to blame.  It now says what the re-check found: where it stopped again and how fast the
    torque grew there, or that it passed."""
    from ftcreport.runner import integrator_words

    g = {"method": "rk4", "dt": 0.005, "steps": 8174}
    stopped = g | {"recheck": {"dt": 0.00125, "status": "step_unstable", "t_end": 40.87125, "growth": 330.04}}
    words = integrator_words({"integrator": stopped})
    assert "step_unstable" not in words, words
    assert "re-checked at dt = 0.00125 s: it stops again at t = 40.8713 s, max |tau| 330x over the" in words, words
    passed = g | {"recheck": {"dt": 0.00125, "status": "ok", "t_end": 41.0, "growth": None}}
    assert "re-checked at dt = 0.00125 s: it runs past the stop" in integrator_words({"integrator": passed})
