"""Linearized analyses: error dynamics of the two-link closed loop, controllability per pattern."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import control
import numpy as np
import pytest
import tomli_w

from ftcreport.analysis import (
    _TwoLinkError,
    kinematic_error_matrix,
    pattern_controllability,
    pole_table,
    two_link_error_jacobian,
    two_link_error_system,
)
from ftcreport.control.tracking import TrackingController
from ftcreport.model import Chain
from ftcreport.sim import Plant, SimSettings, simulate

CIRCLE = {"d": 1.7, "v_d": 0.5, "omega_d": 0.5, "k1": 1.0, "k2": 1.0, "k3": 0.2, "k_v": 20.0}


def test_predicts_errata_p1():
    """Circle gains of 3.3.2.3: kinematic error poles -1.93, -0.22, -0.025 +/- 0.786j."""
    A = kinematic_error_matrix(0.5, 0.5, 1.0, 1.0, 0.2)
    poles = sorted(np.linalg.eigvals(A), key=lambda p: (p.real, p.imag))
    expected = sorted([-1.93, -0.22, -0.025 + 0.786j, -0.025 - 0.786j], key=lambda p: (p.real, p.imag))
    np.testing.assert_allclose(poles, expected, atol=5e-3)
    assert all(p.real < 0 for p in poles)


def test_control_linearize_equals_analytic_jacobian():
    """control.linearize (forward differences, eps 1e-6) of the nlsys built on the project's controller."""
    sys = two_link_error_system(**CIRCLE)
    lin = control.linearize(sys, np.zeros(6), [])
    np.testing.assert_allclose(lin.A, two_link_error_jacobian(**CIRCLE), atol=2e-5)


def test_linearization_equals_fd_jacobian_of_the_simulated_closed_loop():
    """The engine's closed loop (plant + TrackingController), in error coordinates, to 1e-5."""
    p = CIRCLE
    err = _TwoLinkError(p["d"], p["v_d"], p["omega_d"], p["k1"], p["k2"], p["k3"], p["k_v"])
    chain = Chain.uniform(2, d=p["d"])
    ctrl = TrackingController(chain, err.kin, k_v=p["k_v"])
    xc = np.zeros(0)

    def eps_of(t, q, eta):
        out = err.kin.law(t, q, xc)
        z = err.kin.zcoords(q, err.ref.at(t))
        return np.concatenate((z, eta - out.eta_c))

    def eps_dot(e):
        q = err.q_from_z(e[:4])
        eta = e[4:] + err.kin.law(0.0, q, xc).eta_c
        u, _ = ctrl.evaluate(0.0, q, eta, xc)
        qdot, etadot = chain.dynamics(q, eta, u)  # the simulated closed loop's right-hand side
        h = 1e-5
        return (eps_of(h, q + h * qdot, eta + h * etadot) - eps_of(-h, q - h * qdot, eta - h * etadot)) / (2 * h)

    delta = 1e-4
    J = np.column_stack([(eps_dot(delta * e) - eps_dot(-delta * e)) / (2 * delta) for e in np.eye(6)])
    np.testing.assert_allclose(J, two_link_error_jacobian(**p), atol=1e-5 * np.abs(J).max())


@pytest.mark.slow
def test_predicted_rate_matches_simulated_decay_on_the_circle():
    """Slowest pole of the 6-state linearization vs the fitted envelope decay of a simulated run (10 %)."""
    p = CIRCLE
    A = two_link_error_jacobian(**p)
    rate = -pole_table(A)[0]["re"]
    err = _TwoLinkError(p["d"], p["v_d"], p["omega_d"], p["k1"], p["k2"], p["k3"], p["k_v"])
    chain = Chain.uniform(2, d=p["d"])
    q0 = err.q_from_z(np.array([0.02, -0.02, 0.01, 0.0]))
    eta0 = err.kin.law(0.0, q0, np.zeros(0)).eta_c
    run = simulate(
        Plant(chain),
        TrackingController(chain, err.kin, p["k_v"]),
        q0,
        eta0,
        SimSettings(dt=0.02, duration=160.0, log_every=5),
    )
    assert run.ok
    e = np.hypot(run["q"][:, 0] - run["q_d"][:, 0], run["q"][:, 1] - run["q_d"][:, 1])
    # envelope: local maxima of the oscillating error after the fast modes have died out
    k = np.flatnonzero((e[1:-1] > e[:-2]) & (e[1:-1] >= e[2:])) + 1
    k = k[run.t[k] > 30.0]
    fitted = -np.polyfit(run.t[k], np.log(e[k]), 1)[0]
    assert fitted == pytest.approx(rate, rel=0.10)


@pytest.mark.parametrize("n", [2, 3])
def test_controllability_rank_is_the_redundancy_rule(n):
    chain = Chain.uniform(n, d=1.2)
    q = chain.q_from_headings(0.0, 0.0, np.radians([25.0, 10.0, 0.0][:n]))
    rows = pattern_controllability(chain, q, np.array([0.5, 0.1]), k_v=5.0)
    assert len(rows) == 2 ** (2 * n)
    for r in rows:
        assert (r["rank"] == 2) == r["compensable_rule"], r
        assert (r["gramian_min_eig"] > 1e-9) == r["compensable_rule"], r
    # ranking: the healthy pattern is the best conditioned, uncompensable ones come last
    assert rows[0]["pattern"] == [1] * (2 * n)
    assert all(not r["compensable_rule"] for r in rows[-(2 ** (2 * n) - (3 * 2 ** (2 * n - 2) - 2)) :])


def test_gramian_closed_form_equals_python_control():
    """W = B B^T / (2 k_v) for A = -k_v I is python-control's Lyapunov solution: smallest eigenvalues
    agree to 1e-12 relative (round-off of slycot's Schur solve on a 2 x 2 problem)."""
    chain = Chain.uniform(3, d=1.2)
    q = chain.q_from_headings(0.0, 0.0, np.radians([25.0, 10.0, 0.0]))
    k_v = 7.0
    rows = pattern_controllability(chain, q, np.array([0.5, 0.1]), k_v=k_v)
    Mbar1, _, _, Bbar = chain.reduced(q, np.array([0.5, 0.1]))
    MB = np.linalg.solve(Mbar1, Bbar)
    for r in rows[:12]:
        B = MB * np.asarray(r["pattern"], dtype=float)[None, :]
        W = control.gram(control.ss(-k_v * np.eye(2), B, np.eye(2), 0), "c")
        want = max(float(np.linalg.eigvalsh(0.5 * (W + W.T)).min()), 0.0)
        assert r["gramian_min_eig"] == pytest.approx(want, rel=1e-12, abs=1e-15), r


def test_an_absurd_velocity_gain_is_named_not_a_crash():
    """k_v = 1e-308 made slycot raise inside control.gram while the page rendered (exit 3)."""
    from ftcreport.errors import ModelError

    chain = Chain.uniform(2, d=1.2)
    q = chain.q_from_headings(0.0, 0.0, np.radians([10.0, 0.0]))
    rows = pattern_controllability(chain, q, np.array([0.5, 0.1]), k_v=1e-308)  # huge but finite: exact
    assert all(math.isfinite(r["gramian_min_eig"]) for r in rows)
    # 1e-320 is subnormal: printed as stored, 9.99989e-321
    with pytest.raises(ModelError, match=r"k_v = 9.99989e-321 1/s: the controllability Gramian .* overflows"):
        pattern_controllability(chain, q, np.array([0.5, 0.1]), k_v=1e-320)


def test_pole_table_fields():
    rows = pole_table(np.diag([-2.0, -0.5]))
    assert [r["re"] for r in rows] == [-0.5, -2.0]
    assert rows[0]["time_constant"] == pytest.approx(2.0) and rows[0]["damping"] == pytest.approx(1.0)
    assert math.isinf(pole_table(np.diag([0.0]))[0]["time_constant"])


def test_frozen_time_poles_along_the_eight():
    """Frozen-time poles along the thesis's eight with its gains: computed, and equal to the
    constant-reference poles where the eight is momentarily straight (t = 0: zero curvature)."""
    from ftcreport.analysis import frozen_time_poles
    from ftcreport.references import FlatReference, eight

    ref = FlatReference(eight(), [1.7])
    res = frozen_time_poles(ref, 1.7, 10.0, 10.0, 2.0, 10.0, duration=60.0, samples=61)
    assert len(res["worst_real_part"]) == 61 and 0.0 <= res["positive_fraction"] <= 1.0
    r0 = ref.at(0.0)
    p0 = np.linalg.eigvals(two_link_error_jacobian(1.7, r0.v_d, r0.omega_d, 10.0, 10.0, 2.0, 10.0))
    assert res["worst_real_part"][0] == pytest.approx(p0.real.max())
    assert res["worst"] < 0  # the eight's gains keep every frozen-time pole in the left half plane


@pytest.mark.parametrize("n", [2, 3])
def test_healthy_law_velocity_loop_is_stable_exactly_for_compensable_patterns(n):
    """G = W_a W^-1 has real eigenvalues >= 0, positive iff the true pattern is compensable."""
    from ftcreport.analysis import velocity_loop
    from ftcreport.model import pattern_is_compensable

    chain = Chain.uniform(n, d=1.3)
    q = chain.q_from_headings(0.0, 0.0, np.radians([20.0, 5.0, 0.0][:n]))
    rows = velocity_loop(chain, q, np.array([0.5, 0.1]), 5.0, np.ones(2 * n))
    for r in rows:
        assert r["stable"] == pattern_is_compensable(r["pattern"]), r
        if r["stable"]:
            assert 0 < r["lambda_min"] <= 1 + 1e-9
            assert math.isinf(r["gain_margin"]) and r["phase_margin_deg"] == pytest.approx(90.0)
    healthy = next(r for r in rows if all(r["pattern"]))
    assert healthy["lambda_min"] == pytest.approx(1.0)
    # a switching law for '1r failed' on a plant that also lost 1l: the common working set is not compensable
    law = np.ones(2 * n)
    law[0] = 0
    rows_k = velocity_loop(chain, q, np.array([0.5, 0.1]), 5.0, law)
    lost_1l = next(r for r in rows_k if r["pattern"] == [1, 0] + [1] * (2 * n - 2))
    assert not lost_1l["stable"]


# ---------------------------------------------------------------------- observer (issue 8, item 5)
def test_farza_error_poles_scale_with_theta():
    """The high-gain error pairs are Theta (-k +/- sqrt(k^2 - k)): proportional to Theta."""
    from ftcreport.analysis import farza_error_poles

    for k0, k1 in ((1.0, 1.0), (2.0, 1.5)):
        base = farza_error_poles(1.0, 4, k0, k1)
        k = k0 * k1
        expect = np.sort_complex(np.array([-k + np.sqrt(complex(k * k - k)), -k - np.sqrt(complex(k * k - k))] * 4))
        np.testing.assert_allclose(base, expect, atol=1e-6)  # a double root is exact only to ~sqrt(eps)
        for th in (0.5, 1.6, 3.0, 10.0):
            np.testing.assert_allclose(farza_error_poles(th, 4, k0, k1), th * base, rtol=1e-6, atol=1e-6 * th)


def test_full_observer_poles_approach_the_high_gain_ones():
    """With the model Jacobian included, slowest rate / Theta -> 1 as Theta grows (and the model dominates at 0.5)."""
    from ftcreport.analysis import farza_linearized_poles, healthy_torque
    from ftcreport.observers import FarzaObserver

    chain = Chain.uniform(2, d=1.0)
    q = np.array([0.0, 0.0, 0.2, -0.1])
    eta = np.array([0.5, 0.3])
    u = healthy_torque(chain.params, q, eta, np.array([0.1, -0.2]))
    ratios = []
    for th in (2.0, 8.0, 32.0):
        poles = farza_linearized_poles(FarzaObserver(chain, th), q, chain.S(q) @ eta, u)
        ratios.append(-poles.real.max() / th)
    assert abs(ratios[-1] - 1.0) < 0.05
    assert abs(ratios[2] - 1.0) < abs(ratios[0] - 1.0)


def test_measured_q_observability_ranks():
    """State observable from q; with the 4n parameters only two more directions (ERRATA P3), n = 2, 3."""
    from ftcreport.analysis import healthy_torque, observability

    for n in (2, 3):
        chain = Chain.uniform(n, d=1.0)
        q = np.concatenate(([0.0, 0.0], np.linspace(0.1, -0.1, n)))
        eta = np.array([0.5, 0.2])
        u = healthy_torque(chain.params, q, eta, np.array([0.1, 0.1]))
        ob = observability(chain, q, eta, u)
        assert ob["state_rank"] == n + 4
        assert ob["augmented_dim"] == n + 4 + 4 * n
        assert ob["augmented_rank"] == n + 6


# ---------------------------------------------------------------------- chained form on a circle (item 1)
@pytest.mark.slow
def test_chained_circle_floquet_rate_predicts_simulated_decay():
    """n = 3 chained form on a 5 m circle: the Floquet rate of the re-anchoring period matches the fitted
    decay of a healthy simulation within 10 %, and the Jacobian equals python-control's linearize."""
    from ftcreport.analysis import chained_circle_analysis, closed_loop_jacobian
    from ftcreport.control.kinematic import ChainedBackstepping
    from ftcreport.model import kernels as K
    from ftcreport.references import FlatReference, circle
    from ftcreport.sim import Plant, SimSettings, simulate

    n = 3
    chain = Chain.uniform(n, d=1.0)
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    kin = ChainedBackstepping(chain.d, ref, [0.3] * n, 2.0, 2.0, 5.0)
    res = chained_circle_analysis(chain, kin, 5.0, 0.1)
    rate = res["floquet_rate"]
    assert rate > 0
    # frozen poles at phi = 0 are all stable; the frozen loci move toward the axis as phi grows
    assert res["frozen"][0]["poles"][0][0] < 0
    assert res["frozen"][-1]["poles"][0][0] > res["frozen"][0]["poles"][0][0]

    ctrl = TrackingController(chain, kin, 5.0)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.array([0.05, -0.03, 0.02, 0.02, 0.02])
    run = simulate(Plant(chain), ctrl, q0, r0.eta_d, SimSettings(dt=0.02, duration=45.0, log_every=5))
    d = run["q"] - run["q_d"]
    d[:, 2:] = np.angle(np.exp(1j * d[:, 2:]))
    e = np.linalg.norm(d, axis=1)
    k = (run.t >= 5.0) & (run.t <= 40.0)
    fitted = -np.polyfit(run.t[k], np.log(e[k]), 1)[0]
    assert abs(fitted - rate) / rate < 0.10, (fitted, rate)

    t = 3.0
    r = ref.at(t)
    xc = kin.initial_state(0.0, r0.q_d)
    N = chain.n_q

    def upd(_t, x, _u, _params):
        u, _ = ctrl.evaluate(t, x[:N], x[N:], xc)
        qd, ed = K.eta_dot(chain.params, x[:N], x[N:], u)
        return np.concatenate((qd, ed))

    sys = control.nlsys(upd, None, states=N + 2, inputs=0, outputs=N + 2)
    x0 = np.concatenate((r.q_d, r.eta_d))
    A_pc = control.linearize(sys, x0, np.zeros(0)).A
    A = closed_loop_jacobian(chain, ctrl, t, r.q_d, r.eta_d, xc)
    np.testing.assert_allclose(A, A_pc, atol=1e-5 * max(1.0, np.abs(A).max()))


def test_chained_frozen_time_poles_on_the_sinusoid():
    """Three links on the thesis sinusoid (3.3.1.4): frozen-time poles stable all along (worst about -0.14)."""
    from ftcreport.analysis import analyze_case
    from ftcreport.cases import load_case

    a = analyze_case(load_case(Path(__file__).resolve().parents[1] / "cases" / "three_link_switching.toml"))
    ft = a["frozen_time"]
    assert ft["positive_fraction"] == 0.0
    assert -0.2 < ft["worst"] < -0.05
    assert len(ft["poles"][0]) == 3 + 4  # n + 4 error states


def test_fault_patterns_enumeration_scales():
    """Every pattern up to 8 wheels; beyond, healthy + single + double losses (issue 20 item 6)."""
    import itertools

    from ftcreport.analysis import default_max_failed, fault_patterns

    assert sorted(fault_patterns(6)) == sorted(itertools.product((1, 0), repeat=6))
    assert default_max_failed(8) is None and default_max_failed(10) == 2
    for n in (5, 12):
        pats = fault_patterns(2 * n, 2)
        assert len(pats) == 1 + 2 * n + math.comb(2 * n, 2) == len(set(pats))
        assert pats[0] == (1,) * (2 * n)
        assert all(sum(1 - v for v in p) <= 2 for p in pats)


def test_twelve_robot_analysis_enumerates_what_the_page_shows(tmp_path):
    """A 12-robot case (the schema's largest) analyses 301 patterns, not 2^24; counts by the rule of (2.103)."""
    from ftcreport.analysis import analyze_case
    from ftcreport.cases import load_case

    text = (Path(__file__).resolve().parents[1] / "cases" / "three_link_circle_faults.toml").read_text()
    text = text.replace("n = 3", "n = 12", 1).replace("radius = 5.0", "radius = 30.0", 1)
    data = tomllib.loads(text)
    for s in list(data["schemes"]):
        if s != "nominal":
            del data["schemes"][s]
    # 3 * 4^11 switching models are over the memory budget (ftcreport.infra.limits): the analysis needs no run
    data["schemes"]["run"] = ["nominal", "oracle"]
    data["thresholds"] = {k: v for k, v in data.get("thresholds", {}).items() if k in data["schemes"]["run"]}
    path = tmp_path / "twelve.toml"
    path.write_text(tomli_w.dumps(data))
    res = analyze_case(load_case(path))
    assert res["patterns_enumerated"] == {
        "max_failed": 2,
        "count": 301,
        "total": 2**24,
        "compensable_total": 3 * 2**22 - 2,
    }
    assert len(res["controllability"]) == 301
    # the healthy law keeps every compensable enumerated pattern stable and no other (see velocity_loop)
    vl = res["nominal_velocity_loop"]
    assert vl["stable_patterns"] == vl["compensable_patterns"]


def test_chained_circle_frozen_poles_are_each_instants_own():
    """chained_circle_analysis computes each instant's Jacobian once (the RK4 steps share their ends): every
    frozen instant's poles are still those of the Jacobian at that instant, computed afresh."""
    from ftcreport.analysis import chained_circle_analysis, closed_loop_jacobian
    from ftcreport.control.kinematic import ChainedBackstepping
    from ftcreport.references import FlatReference, circle

    chain = Chain.uniform(2, d=1.0)
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    kin = ChainedBackstepping(chain.d, ref, [0.3] * 2, 2.0, 2.0, 5.0)
    res = chained_circle_analysis(chain, kin, 5.0, 0.1, steps=6)
    ctrl = TrackingController(chain, kin, 5.0)
    xc = kin.initial_state(0.0, ref.at(0.0).q_d)
    poles = []
    for t in np.linspace(0.0, res["period"], 7):
        r = ref.at(float(t))
        ev = np.linalg.eigvals(closed_loop_jacobian(chain, ctrl, float(t), r.q_d, r.eta_d, xc))
        poles.append(ev[np.argsort(-ev.real)])
    for row, ev in zip(res["frozen"], poles, strict=True):
        assert np.allclose(np.array(row["poles"]), np.column_stack((ev.real, ev.imag)), rtol=1e-12, atol=1e-12)
    assert not np.allclose(poles[0], poles[-1])  # the instants differ: one shared entry would show


def test_compensable_patterns_are_computed_once_and_handed_out_as_new_lists():
    from ftcreport.model.faults import compensable_patterns, model_patterns, pattern_is_compensable

    first = compensable_patterns(3)
    first.clear()  # a caller's list is its own
    pats = compensable_patterns(3)
    assert len(pats) == 3 * 2**4 - 2 and pats[0] == (1,) * 6 and all(map(pattern_is_compensable, pats))
    assert model_patterns(3) == pats and model_patterns(2) == compensable_patterns(2)


def test_chained_circle_interpolated_monodromy_agrees_with_jacobians(monkeypatch):
    """The Floquet rate from A(t)'s Chebyshev interpolant (16 Jacobians) agrees with RK4 on 60 steps of
    Jacobians (121, the former method) within that method's own error (4e-5 on the six-robot circle)."""
    from ftcreport.analysis import chained_circle_analysis, classic
    from ftcreport.control.kinematic import ChainedBackstepping
    from ftcreport.references import FlatReference, circle

    chain = Chain.uniform(4, d=1.0)
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    kin = ChainedBackstepping(chain.d, ref, [0.3] * 4, 2.0, 2.0, 5.0)
    fitted = chained_circle_analysis(chain, kin, 5.0, 0.1)
    monkeypatch.setattr(classic, "CIRCLE_FIT", -1.0)  # every interpolant rejected: RK4 on the Jacobians
    direct = chained_circle_analysis(chain, kin, 5.0, 0.1)
    assert fitted["frozen"] == direct["frozen"]
    assert abs(fitted["floquet_rate"] - direct["floquet_rate"]) < 5e-5 * abs(direct["floquet_rate"])
    np.testing.assert_allclose(
        fitted["multipliers"], direct["multipliers"], atol=2e-4 * abs(complex(*direct["multipliers"][0]))
    )


def test_a_phase_whose_frozen_instants_disagree_is_inconclusive_not_unstable():
    """Round-3 audit: four_link_eight_step's healthy phase (0-20 s) was "unstable" for nominal and the oracle,
    max Re +11.57 1/s at the frozen instant t = 10 s, where the instants at 3.3 and 16.7 s are stable, and
    every run tracks (nominal ends at 5.5e-6 m); every limit then read "unstable in continuous time".  Frozen
    instants that disagree decide nothing about a time-varying loop: the phase is "inconclusive" (stable null),
    says which instants are which, gets no margins, and the limits taken at its worst instant say they are
    frozen evidence only."""
    from ftcreport.analysis.phases import analyze_scheme, case_frames
    from ftcreport.cases import load_case
    from ftcreport.runner import build

    case = load_case(Path(__file__).resolve().parents[1] / "cases" / "four_link_eight_step.toml")
    built = build(case)
    res = analyze_scheme(case, "nominal", built, psis=case_frames(case, built))
    first = res["phases"][0]
    assert first["stability"] == "inconclusive" and first["stable"] is None
    assert first["frozen_disagree"]["unstable_at"] == [10.0]
    assert first["frozen_disagree"]["stable_at"] == pytest.approx([10.0 / 3.0, 50.0 / 3.0])
    assert first["max_real_part"] > 1.0  # the worst frozen instant's, still reported
    assert "stable loop only" in first["margins"]["note"]
    assert all(p["stability"] == "stable" and p["frozen_disagree"] is None for p in res["phases"][1:])
    caveat = res["limit_notes"]["caveat"]
    assert caveat.startswith("frozen evidence only, taken at the instant t = 10 s of the first phase")


def test_an_inconclusive_phase_supports_no_claim_of_stability_in_the_verdict():
    """The verdict neither says a scheme's loop is unstable in a phase whose frozen instants disagree, nor that
    the healthy law's loop 'stays stable in every fault phase' when one of them is inconclusive."""
    from ftcreport.evaluation.verdict_analysis import verdict_sentence

    def phase(t0, t1, stability, measure):
        return {"t_start": t0, "t_end": t1, "stability": stability, "max_real_part": measure, "discrete": False}

    analysis = {"phases": {"nominal": [phase(0, 20, "inconclusive", 11.57), phase(20, 40, "stable", -0.21)]}}
    assert verdict_sentence("nominal", analysis, "nominal wins") is None
    assert verdict_sentence("nominal", analysis, "loses") is None
    analysis["phases"]["nominal"][0] = phase(0, 20, "stable", -0.3)
    assert verdict_sentence("nominal", analysis, "nominal wins").startswith("The analysis agrees")
