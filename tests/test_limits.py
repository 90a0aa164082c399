"""Stability limits of the sampled loop (issue 37 item 3): closed forms, and the motor case by simulation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import harness

from ftcreport.analysis.closed_loop import Faults, SchemeLoop
from ftcreport.analysis.limits import MARGINAL_Z, gain_family, largest_gain, largest_sample_time, sampled_radius
from ftcreport.cases import load_case
from ftcreport.runner import build

ROOT = Path(__file__).resolve().parents[1]


def _harness_loop(case, built, k: float) -> SchemeLoop:
    """The harness's VELOCITY law (computed torque on a constant velocity command, tests/data) on the
    case's ideal plant, commanding rest: u = (Mbar1^-1 Bbar)^+ [-k eta + Mbar1^-1 (Mbar2 eta + Cbar)]."""
    h = harness()
    ctrl = h.controller(built.chain, h.VELOCITY, k=k, c0=(0.0, 0.0))
    return SchemeLoop(case, "harness", built, controller=ctrl)


def _at_rest(loop: SchemeLoop):
    """The velocity loop's blocks at rest (eta = 0: the plant's Coriolis and Mbar2 terms vanish)."""
    fz = Faults.healthy(loop.plant.nw, False)
    q0 = loop.ctrl.kin.reference.at(0.0).q_d
    return loop.blocks(loop.point(0.0, fz, q=q0, eta=np.zeros(2))).velocity_loop()


@pytest.fixture(scope="module")
def ideal():
    case = load_case(ROOT / "cases" / "two_link_switching.toml")
    return case, build(case)


@pytest.mark.parametrize("k", [5.0, 20.0, 300.0, 3000.0])
def test_ideal_velocity_loop_sample_time_limit_is_two_over_k(ideal, k):
    """Held torque on the ideal plant at rest: eta_e(j+1) = (1 - k T) eta_e(j), so T_max = 2 / k exactly."""
    case, built = ideal
    blk = _at_rest(_harness_loop(case, built, k))
    res = largest_sample_time(lambda T: sampled_radius(blk, T, 0), guess=1.0 / k)
    assert res["value"] == pytest.approx(2.0 / k, rel=1e-6)
    # one sample of measurement delay: z^2 - z + k T = 0, stable iff k T < 1.  At the boundary the pair
    # has |z| = sqrt(k T), so the search's marginal band (|z| up to 1 + MARGINAL_Z counts as marginal,
    # not lost) moves the limit by 2 MARGINAL_Z relative, against MARGINAL_Z with |z| = k T - 1 above
    res = largest_sample_time(lambda T: sampled_radius(blk, T, 1), guess=1.0 / k)
    assert res["value"] == pytest.approx((1.0 + MARGINAL_Z) ** 2 / k, rel=1e-8)
    assert res["value"] == pytest.approx(1.0 / k, rel=2.5 * MARGINAL_Z)


@pytest.mark.parametrize("T", [0.001, 0.005, 0.02])
def test_ideal_velocity_loop_gain_limit_is_two_over_T(ideal, T):
    """At sample time T the largest stable velocity gain is 2 / T, found from the case's gain upwards or downwards."""
    case, built = ideal
    fam = gain_family(lambda k: _at_rest(_harness_loop(case, built, k)), 5.0)
    for start in (5.0, 20.0 / T):  # stable start (search up) and unstable start (search down)
        res = largest_gain(lambda k: sampled_radius(fam(k), T, 0) - 1.0, start)
        assert res["value"] == pytest.approx(2.0 / T, rel=1e-6)


def test_full_loop_limit_is_the_velocity_loops_on_the_moving_reference(ideal):
    """The thesis 3.2.3 case (k4 = 3000): the whole loop, kinematic law and the moving reference included,
    loses stability at 0.664 ms, within 0.4 % of 2 / k_v = 0.667 ms (the study's "about 0.67 ms")."""
    case, built = ideal
    loop = SchemeLoop(case, "nominal", built)
    blk = loop.blocks(loop.point(0.0, Faults.healthy(4, False)))
    res = largest_sample_time(lambda T: sampled_radius(blk, T, 0), guess=2.0 / 3000.0)
    assert res["value"] == pytest.approx(2.0 / 3000.0, rel=4e-3)
    assert res["value"] == pytest.approx(6.6436e-4, rel=1e-3)


def _motor_case():
    return load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")


def test_motor_case_limits_reproduce_the_independent_study():
    """k4 = 3000 with the cases/motors motors and the static-inversion driver: T_max about 1.3 ms (1.371 here),
    and at T_s = 5 ms the largest stable k4 about 500-550 (559 here, 2 % above the study's range)."""
    from ftcreport.analysis.phases import analyze_scheme

    case = _motor_case()
    res = analyze_scheme(case, "nominal", build(case), margins=False)
    assert res["limits"]["sample_time_max"] == pytest.approx(1.371e-3, rel=2e-3)
    assert res["limits"]["k_v_max"] == pytest.approx(559.3, rel=2e-3)
    # the case's own gain is beyond it: every phase's sampled loop is unstable (it chatters at 48 V)
    assert all(p["stability"] == "unstable" and p["spectral_radius"] > 9 for p in res["phases"])


def _verdict(case, scheme: str, which: str, value: float, samples: int, fast: bool = False) -> dict:
    """The engine's loop at ``value`` of ``which`` as ftcreport.analysis.confirm reads it: two runs NUDGE
    apart, their difference (its sample-rate part when ``fast``) and the command's chatter."""
    from ftcreport.analysis.confirm import NUDGE, classify, variant
    from ftcreport.runner import run_scheme

    v = variant(case, scheme, which, value, samples)
    run, _ = run_scheme(v, scheme)
    other, _ = run_scheme(variant(case, scheme, which, value, samples, NUDGE), scheme)
    return classify(run, other, v.simulation.sample_time, fast)


def _grows(case, scheme: str, which: str, value: float) -> bool:
    """Whether the engine's loop at ``value`` is not bounded (:func:`_verdict`, 600 samples, fast)."""
    return _verdict(case, scheme, which, value, 600, fast=True)["outcome"] != "bounded"


@pytest.mark.parametrize(("which", "predicted", "lo", "hi"), [("sample_time_max", 1.371e-3, 1e-3, 2e-3),
                                                               ("k_v_max", 559.3, 400.0, 800.0)])  # fmt: skip
def test_motor_case_limits_match_a_bisection_by_simulation(which, predicted, lo, hi):
    """Bisection on the engine's runs (healthy plant, 600 samples near the reference) to 2 %: the simulated
    limit is within 5 % of the predicted one."""
    case = _motor_case()
    assert not _grows(case, "nominal", which, lo) and _grows(case, "nominal", which, hi)
    while hi / lo > 1.02:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if _grows(case, "nominal", which, mid) else (mid, hi)
    simulated = math.sqrt(lo * hi)
    assert simulated == pytest.approx(predicted, rel=0.05)


def test_sample_time_variant_integrates_the_plant_at_the_case_step_or_finer():
    """A confirmation's sample-time variant keeps the case's steps per sample where its dt fits (1.37 ms:
    one ETD2 step, as the case at 5 ms) and otherwise takes the case's dt or finer (204 ms: 41 steps of
    4.98 ms): one step per sample of 204 ms on the two-link circle grew the slow kinematic pair by 1.0019
    per sample, where 16 and 64 steps agree on 0.9987-0.9991 (a stable loop called a limit cycle)."""
    from ftcreport.analysis.confirm import variant

    case = load_case(ROOT / "cases" / "motors" / "two_link_active_motors.toml")
    for T, steps in ((1.371e-3, 1), (0.2041, 41)):
        s = variant(case, "nominal", "sample_time_max", T, 200).simulation
        assert s.sample_time == T and s.dt == pytest.approx(T / steps, rel=1e-12) and s.dt <= case.simulation.dt


def test_slow_kinematic_limit_on_the_circle_is_confirmed_by_the_engine():
    """two_link_active_motors (circle, omega = 0.5 rad/s, k_v = 20): the sample-time limit is the slow
    kinematic pair's (|z| = 1.0012 at 1.1x, time constant ~ 3 min), predicted at 236 ms.  The engine's runs
    (two runs NUDGE apart, read as ftcreport.analysis.confirm reads them, 1500 samples) are bounded at 0.9x
    (growth 0.9995 per sample) and grow at 1.1x (1.0012).  Before, the plant's ZOH frozen in world
    coordinates put the limit at 292 ms, and one ETD2 step per sample made the runs diverge at 0.9x of it."""
    from ftcreport.analysis.phases import analyze_scheme

    case = load_case(ROOT / "cases" / "motors" / "two_link_active_motors.toml")
    limit = analyze_scheme(case, "nominal", build(case), margins=False)["limits"]["sample_time_max"]
    assert limit == pytest.approx(0.2363, rel=2e-3)
    out = {f: _verdict(case, "nominal", "sample_time_max", f * limit, 1500) for f in (0.9, 1.1)}
    assert out[0.9]["outcome"] == "bounded" and out[0.9]["rho"] < 1.0
    assert out[1.1]["outcome"] == "limit cycle" and out[1.1]["rho"] > 1.0


def test_switching_banks_filters_set_the_sample_time_limit_and_the_engine_agrees():
    """two_link_active_motors's switching: the bank's reconstruction filters (c' = -gamma c + ..., gamma =
    10 1/s) reach no torque while the selection holds, so the loop's poles leave them out; a sampled
    controller steps them by forward Euler (z = 1 - gamma T), and the run is bounded only if they are
    stable: the limit is 2 / gamma = 200 ms exactly (the marginal band 1e-6 above it), not the
    tracking loop's 236 ms.  Before, the analysis predicted 236 ms and the engine's run at 0.9x of it
    overflowed its filters.  The engine agrees: bounded at 180 ms, the filters run away at 220 ms while
    q and eta stay on the reference."""
    from ftcreport.analysis.confirm import confirm_limit
    from ftcreport.analysis.phases import analyze_scheme

    case = load_case(ROOT / "cases" / "motors" / "two_link_active_motors.toml")
    res = analyze_scheme(case, "switching", build(case), margins=False)
    assert res["limits"]["sample_time_max"] == pytest.approx(2.0 / 10.0, rel=2e-6)
    assert res["crossing"]["sample_time_max"][0] == pytest.approx(1.0 - 10.0 * 1.1 * 0.2, rel=1e-5)
    first = res["phases"][0]
    assert first["internal_modes"]["spectral_radius"] == pytest.approx(1.0 - 1.0 * 0.005, rel=1e-9)  # slowest filter
    assert first["stability"] == "stable"
    z = complex(*res["crossing"]["sample_time_max"])
    assert res["crossing_internal"] == {"sample_time_max": True, "k_v_max": False}
    conf = confirm_limit(case, "switching", "sample_time_max", res["limits"]["sample_time_max"], z, "s", True)
    below, above = conf["runs"]
    assert below["outcome"] == "bounded" and above["outcome"] == "diverged"
    assert "scheme's own states" in above["note"] and conf["agrees"] is True


def test_periodic_loop_limit_is_the_product_over_the_reference_period_and_the_engine_agrees():
    """three_link_switching_pi's nominal on the sinusoid (period 2 pi / 0.2 = 31.4 s): the loop varies
    along the reference, and its sample-time limit is Floquet's, the growth per sample of the sampled
    loop's product over one period (24 frozen instants): 715.0 ms.  The worst frozen instant of the
    first phase alone said 737.6 ms, and the engine's runs at 0.9x of that (664 ms) were read as a limit
    cycle.  The engine agrees with the product to 1 %: bounded at 0.99x, it leaves the reference at
    1.01x, where the worst frozen instant still predicts a stable loop."""
    from ftcreport.analysis.phases import analyze_scheme, reference_period

    case = load_case(ROOT / "cases" / "motors" / "three_link_switching_pi.toml")
    built = build(case)
    assert reference_period(built) == pytest.approx(2.0 * math.pi / 0.2, rel=1e-12)
    res = analyze_scheme(case, "nominal", built, margins=False)
    limit = res["limits"]["sample_time_max"]
    assert limit == pytest.approx(0.7150, rel=1e-3)
    note = res["limit_notes"]["limits.sample_time_max"]
    assert "worst frozen instant of the first phase alone gives 737.6 ms" in note
    out = {f: _verdict(case, "nominal", "sample_time_max", f * limit, 400) for f in (0.99, 1.01)}
    assert out[0.99]["outcome"] == "bounded", out[0.99]
    assert out[1.01]["outcome"] != "bounded", out[1.01]


def test_the_scheme_states_are_read_only_where_the_crossing_mode_is_one_of_them():
    """classify's reading of the scheme's own states (xc), on two made-up pairs of runs whose q and eta
    settle (the nudge's difference decays 0.95 per sample): a filter state whose difference grows 1.2 per
    sample is called diverged when the analysis says the crossing mode is such a state, and the plant's
    verdict (bounded) stands otherwise; a state at round-off (1e-22, whose difference wanders) and an
    integral cost still taking up the nudge (its difference grows 300-fold over a short run, as
    three_link_switching_pi's switching at 0.9x of its k_v limit) are never read as a runaway."""
    from types import SimpleNamespace

    from ftcreport.analysis.confirm import classify

    T, k = 0.1, 200
    t = np.arange(k) * T
    decay = 1e-6 * 0.95 ** np.arange(k)

    def pair(xc_a, xc_b):
        def run(dq, xc):
            q = np.zeros((k, 3))
            q[:, 0] = dq
            stream = {"q": q, "eta": np.zeros((k, 2)), "u": np.ones((k, 2))}
            return SimpleNamespace(status="ok", t_stream=t, stream=stream, signals={"xc": xc}, t=t)

        return run(np.zeros(k), xc_a), run(decay, xc_b)

    base = np.ones((k, 1))
    growing = np.hstack((base, (1e-8 * 1.2 ** np.arange(k))[:, None]))
    a, b = pair(np.hstack((base, np.zeros((k, 1)))), growing)
    assert classify(a, b, T, internal=True)["outcome"] == "diverged"
    assert classify(a, b, T, internal=False)["outcome"] == "bounded"
    rng = np.random.default_rng(1)
    noise = np.hstack((base, 1e-22 * rng.standard_normal((k, 1))))
    integral = np.hstack((base, (1e-9 * np.arange(k) ** 1.5)[:, None]))
    a, b = pair(np.hstack((base, np.zeros((k, 1)))), noise)
    assert classify(a, b, T, internal=True)["outcome"] == "bounded"
    a, b = pair(np.hstack((base, np.zeros((k, 1)))), integral)
    assert classify(a, b, T, internal=False)["outcome"] == "bounded"


@pytest.mark.parametrize("rate", [0.1445, 3.0e-3, 50.0])
def test_a_loop_unstable_in_continuous_time_has_no_sample_time_limit(rate):
    """Round-3 audit: three_link_eight_faults' active scheme, whose continuous loop has a pole at +0.1445 1/s,
    got sample_time_max = 6.92e-6 s = 1e-6 / 0.1445: the search's first point, T = 1e-6 s, read
    |z| = e^(0.1445 T) = 1 + 1.4e-7 as inside the marginal band 1e-6 of the unit circle.  Unstable as T -> 0 is
    decided by the growth rate ln|z| / T (the continuous real part), against the continuous band."""
    res = largest_sample_time(lambda T: math.exp(rate * T), guess=2.0 / 20.0)  # a fastest pole of 20 1/s
    assert res["value"] is None
    assert "unstable in continuous time" in res["note"]
    # a marginal pole (2e-7 1/s against a fastest of 20 1/s, the Farza observer's unseen directions) is not
    res = largest_sample_time(lambda T: max(math.exp(2e-7 * T), abs(1.0 - 20.0 * T)), guess=2.0 / 20.0)
    assert res["value"] == pytest.approx(0.1, rel=1e-6)


def test_the_gain_limit_is_found_far_below_a_huge_case_gain():
    """Round-3 audit: with k_v = 9e5 the search stopped at k_v / 1e4 = 90 1/s and gave null ("unstable at every
    gain down to 90"), where the loop is stable below 87.47 1/s (README: null means no finite limit)."""
    res = largest_gain(lambda k: k - 87.47, 9.0e5)
    assert res["value"] == pytest.approx(87.47, rel=1e-6)
    res = largest_gain(lambda k: 1.0, 9.0e5)  # unstable at every gain: null, and the note says how far down
    assert res["value"] is None and "unstable at every gain down to" in res["note"]


def test_boundary_modes_tell_a_plant_integrator_from_an_unseen_estimate():
    """The modes on the boundary and which of them hold a plant perturbation in the plant
    (limits.boundary_modes): an open plant integrator (q' = eta, no feedback) does; an estimate the plant
    does not drive (it only feeds the plant), or one the plant drives but that feeds nothing back, does not:
    a plant perturbation dies out in the plant in both."""
    from ftcreport.analysis.limits import boundary_modes

    open_plant = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -2.0]])  # plant q, eta; a filter
    assert boundary_modes(open_plant, 2, False) == {"count": 1, "in_plant": 1, "largest": 0.0}
    feeds = np.array([[-1.0, 0.0, 0.0], [0.0, -3.0, 0.5], [0.0, 0.0, 0.0]])  # the estimate feeds eta only
    assert boundary_modes(feeds, 2, False) == {"count": 1, "in_plant": 0, "largest": None}
    driven = np.array([[-1.0, 0.0, 0.0], [0.0, -3.0, 0.0], [0.0, 1.0, 0.0]])  # eta drives it, it feeds nothing
    assert boundary_modes(driven, 2, False) == {"count": 1, "in_plant": 0, "largest": None}
    loop = np.array([[-1.0, 0.0, 0.0], [0.0, -3.0, 0.5], [0.0, 1.0, -1.0 / 6.0]])  # both ways: a zero mode
    modes = boundary_modes(loop, 2, False)
    assert modes["count"] == 1 and modes["in_plant"] == 1 and abs(modes["largest"]) < 1e-12
    T = 0.01  # the same in discrete time: z = 1 on the boundary, the plant's row a forward-Euler step
    assert boundary_modes(np.eye(3) + T * open_plant, 2, True)["in_plant"] == 1
    assert boundary_modes(np.eye(3) + T * feeds, 2, True)["in_plant"] == 0
    stable = np.array([[-1.0, 1.0], [0.0, -2.0]])
    assert boundary_modes(stable, 2, False) == {"count": 0, "in_plant": 0, "largest": None}


def test_a_loop_marginal_at_the_case_setting_has_no_limits_not_stable_everywhere(tmp_path):
    """The attack on analyze: with [plant] saturation = 1e-9 N m every phase is marginal (the law has no
    authority: the plant's integrators sit on the boundary), yet the limits read 'stable at every sample
    time up to 10 s' and 'every gain up to 1e+07'.  Now they are null of kind 'marginal', and say why."""
    import tomllib

    import tomli_w

    from ftcreport.analysis import analyze_case
    from ftcreport.analysis.summary import text_summary

    data = tomllib.loads((ROOT / "cases" / "two_link_active.toml").read_text())
    data["plant"]["saturation"] = 1e-9
    data["schemes"]["run"] = ["nominal", "active"]
    data["schemes"] = {
        k: v for k, v in data["schemes"].items() if not isinstance(v, dict) or k in ["nominal", "active"]
    }
    data.pop("thresholds", None)
    data.pop("claims", None)
    path = tmp_path / "saturated.toml"
    path.write_text(tomli_w.dumps(data))
    res = analyze_case(load_case(path), margins=False)
    for scheme in ("nominal", "active"):
        assert {p["stability"] for p in res["phases"][scheme]} == {"marginal"}
        assert res["limits"][scheme] == {"sample_time_max": None, "k_v_max": None}
        assert res["limit_kinds"][scheme]["limits.sample_time_max"] == "marginal"
        assert res["limit_kinds"][scheme]["limits.k_v_max"] == "marginal"
        note = res["limit_notes"][scheme]["limits.k_v_max"]
        assert "marginal, not stable" in note and "move the plant" in note
    text = "\n".join(text_summary(res))
    assert "stable at every sample time" not in text and "stable at every gain up to" not in text
    assert "no stable range (the loop is marginal)" in text


def test_the_unscented_filters_unseen_estimates_keep_its_gain_limit(tmp_path):
    """The UKF's phases are marginal by structure (estimates the measurements do not see, ERRATA P3: their
    modes do not move the plant), and its loop tracks: its k_v limit stays a limit (two_link_active:
    197.74 1/s, the value the analysis gave before boundary_modes existed)."""
    import tomllib

    import tomli_w

    from ftcreport.analysis import analyze_case

    data = tomllib.loads((ROOT / "cases" / "two_link_active.toml").read_text())
    data["schemes"]["run"] = ["active_ukf"]
    tables = data["schemes"].items()
    data["schemes"] = {k: v for k, v in tables if not isinstance(v, dict) or k in ["active_ukf"]}
    data.pop("thresholds", None)
    data.pop("claims", None)
    path = tmp_path / "ukf_only.toml"
    path.write_text(tomli_w.dumps(data))
    res = analyze_case(load_case(path), margins=False)
    assert {p["stability"] for p in res["phases"]["active_ukf"]} == {"marginal"}
    assert res["limit_kinds"]["active_ukf"]["limits.k_v_max"] == "limit"
    assert res["limits"]["active_ukf"]["k_v_max"] == pytest.approx(197.741, rel=1e-5)


def test_a_stiff_loop_is_stable_where_its_poles_are_resolved(tmp_path):
    """The attack on analyze: at k_v = 1e6 every phase read 'marginal' with max Re -0.155 1/s, because the
    marginal band was 1e-6 of the fastest pole (1e6 1/s: a band of 1 1/s).  Each pole is now held to its own
    resolution (limits.pole_bands: 1e-9 kappa |A|, 0.02 1/s for this pole): stable, and the sample-time
    limit is the ideal velocity loop's 2 / k_v (module limits: T_max = 2 / k_v)."""
    import tomllib

    import tomli_w

    from ftcreport.analysis import analyze_case

    data = tomllib.loads((ROOT / "cases" / "two_link_switching.toml").read_text())
    data["schemes"] = {"run": ["nominal"], "nominal": {"k_v": 1e6}}
    data.pop("thresholds", None)
    data.pop("claims", None)
    path = tmp_path / "stiff.toml"
    path.write_text(tomli_w.dumps(data))
    res = analyze_case(load_case(path), margins=False)
    for phase in res["phases"]["nominal"]:
        assert phase["stability"] == "stable"
        assert phase["max_real_part"] == pytest.approx(-0.1552, abs=2e-4)
    assert res["limits"]["nominal"]["sample_time_max"] == pytest.approx(2e-6, rel=1e-3)
    assert res["limit_kinds"]["nominal"]["limits.k_v_max"] == "unbounded"


def test_stability_holds_each_continuous_pole_to_its_own_resolution():
    """limits.stability with the loop's matrix: the fastest pole's band (1e-6 of 1e6 1/s = 1 1/s) called a
    pole at -0.155 1/s marginal; its resolution is 1e-9 kappa |A| = 1e-3 1/s (kappa = 1, diagonal)."""
    from ftcreport.analysis.limits import pole_bands, stability

    A = np.diag([-1e6, -0.155])
    poles = np.linalg.eigvals(A)
    assert stability(-0.155, poles, False) == "marginal"  # the band alone
    assert stability(-0.155, poles, False, A) == "stable"
    _, bands = pole_bands(A, 1.0)
    assert np.allclose(sorted(bands), [1e-3, 1e-3], rtol=1e-12)
    Z = np.diag([-1e6, -1e-9])  # a structural zero perturbed by the differences' error: still marginal
    assert stability(-1e-9, np.linalg.eigvals(Z), False, Z) == "marginal"
    assert stability(-0.155, poles, False, A, internal=-1e-7) == "marginal"  # a left-out mode on the boundary
    assert stability(2.0, np.array([2.0, -1e6]), False, np.diag([2.0, -1e6])) == "unstable"  # beyond the band


def test_the_gain_search_ends_at_the_largest_gain_a_case_file_accepts():
    """K_MAX is the bound of every k_v field (schemes.fields.Gain): 'stable up to K_MAX' never claims a gain
    no case can set (it was 1e7, 10x past the tables' 1e6), and a plug-in whose table takes the same range
    gets the same words as a built-in scheme, not 'beyond the scheme's range'."""
    from pydantic import ValidationError

    from ftcreport.analysis.limits import K_MAX
    from ftcreport.cases.scheme_tables import PluginTable

    assert PluginTable(k_v=K_MAX).k_v == K_MAX
    with pytest.raises(ValidationError):
        PluginTable(k_v=K_MAX * (1.0 + 1e-12))


def test_the_gain_search_stays_within_the_gains_the_scheme_accepts():
    """The walk from the case's gain by factors of 2 finds the interval of gains the scheme accepts (its edge
    by bisection) and searches inside it: the limit inside it as before, even when the first refused walk
    point lies past it (a table's lt = 150, the loop unstable from 142.5: the attack's lt150 case, which said
    'no limit'); stable up to the edge, kind beyond_range; unstable down to it, kind unstable; a refused
    point with an accepted one past it (a pack that refuses only 2 k_v) is a hole, not an end."""
    from ftcreport.analysis.limits import gain_domain

    below = lambda lim: lambda k: None if k < lim else f"k_v must be below {lim:g}"  # noqa: E731
    seen: list[float] = []

    def margin(limit):
        return lambda k: (seen.append(k), k - limit)[1]

    dom = gain_domain(below(150.0), 20.0)
    assert dom["top"] == pytest.approx(150.0, rel=2e-6) and dom["top"] < 150.0 and dom["why_top"]
    res = largest_gain(margin(142.5), 20.0, dom)
    assert res["kind"] == "limit" and res["value"] == pytest.approx(142.5, rel=1e-8)
    assert all(k <= dom["top"] for k in seen)
    res = largest_gain(margin(1e3), 20.0, dom)
    assert res["kind"] == "beyond_range" and res["value"] is None
    assert (
        "from the case's 20 up to 150 1/s, the largest the scheme accepts (above it: k_v must be below 150)"
        in (res["note"])
    )
    above = gain_domain(lambda k: "too small" if k < 5.0 else None, 20.0)
    assert above["bottom"] == pytest.approx(5.0, rel=2e-6) and "top" not in above
    res = largest_gain(lambda k: 1.0, 20.0, above)
    assert (
        res["kind"] == "unstable"
        and "down to 5 1/s, the smallest the scheme accepts (below it: too small)" in (res["note"])
    )
    hole = gain_domain(lambda k: "not 40" if k == 40.0 else None, 20.0)
    assert hole == {"hole": "the scheme refuses k_v = 40 1/s (not 40) but accepts 80 1/s"}
    assert gain_domain(lambda k: None, 20.0) == {}  # nothing refused: the search's own ends


@pytest.mark.parametrize(
    "name",
    ["two_link_active.toml", "three_link_adaptive.toml", "motors/two_link_active_motors.toml",
     "motors/three_link_switching_pi.toml", "three_link_circle_faults.toml"],
)  # fmt: skip
def test_every_built_in_law_is_affine_in_its_velocity_gain(name):
    """phases.scheme_limits does not check a built-in law's line through k_v and 2 k_v at k_v / 2 (the law is
    affine in k_v by construction at the operating point: limits.gain_family): here every built-in scheme of
    ideal, motor (static driver, sampled), PI-drive, adaptive and chained cases passes that check, at the
    first phase's instants, so the check moved from every analysis to this test."""
    from ftcreport.analysis.phases import _blocks_at_gain, case_frames, fault_phases, instants
    from ftcreport.cases import configured_schemes

    case = load_case(ROOT / "cases" / name)
    built = build(case)
    psis = case_frames(case, built)
    fz = Faults.healthy(built.chain.n_wheels, built.plant.motors is not None)
    T = case.simulation.sample_time
    checked = 0
    for scheme in configured_schemes(case):
        loop = SchemeLoop(case, scheme, built)
        period = T if T is not None else (case.simulation.dt if loop.has_disc else None)
        for t in instants(case, *fault_phases(case)[0]):
            base = loop.blocks(loop.point(t, fz, psis.get(t), None, None, period), period)

            def at(k, t=t, base=base, scheme=scheme, period=period, k_v=loop.k_v):
                if k == k_v:
                    return base
                return _blocks_at_gain(case, scheme, built, fz, psis.get(t), t, k, period, base)

            assert gain_family(at, loop.k_v) is not at, (name, scheme, t)  # the line passed the check at k_v / 2
            checked += 1
    assert checked >= 6
