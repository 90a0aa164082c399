"""Every scheme's closed loop linearized through the scheme interface (issue 37 item 1)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ftcreport.analysis import closed_loop_jacobian, two_link_error_jacobian
from ftcreport.analysis.closed_loop import Faults, SchemeLoop, central_columns
from ftcreport.analysis.phases import analyze_scheme
from ftcreport.cases import load_case, with_duration
from ftcreport.control.builtin.switching import patterns_of
from ftcreport.runner import build, run_scheme

ROOT = Path(__file__).resolve().parents[1]


def _case(name: str):
    case = load_case(ROOT / "cases" / name)
    return case, build(case)


def _rel(a, b) -> float:
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / max(np.abs(np.asarray(b)).max(), 1e-300))


def test_poles_equal_the_two_link_error_dynamics_exactly():
    """Thesis 3.2.3 (k4 = 3000, v_d = 0.5, omega_d = 0.1): the loop in q, eta in the frame turning with the
    reference has the analytic error Jacobian's poles (two_link_error_jacobian, tested against
    control.linearize and the simulated decay); in the world frame they would be off by ~omega_d."""
    case, built = _case("two_link_switching.toml")
    k = case.kinematic
    want = np.sort_complex(np.linalg.eigvals(two_link_error_jacobian(1.7, 0.5, 0.1, k.k1, k.k2, k.k3, 3000.0)))
    for scheme in ("nominal", "switching", "oracle", "adaptive"):
        loop = SchemeLoop(case, scheme, built)
        blk = loop.blocks(loop.point(7.0, Faults.healthy(4, False)))
        got = np.linalg.eigvals(blk.continuous())
        for w in want:  # the adaptive loop has its two slow adaptation poles besides
            assert np.min(np.abs(got - w)) < 1e-6 * max(abs(w), 1.0), (scheme, w)
        blk.omega = 0.0
        world = np.linalg.eigvals(blk.continuous())
        assert max(np.min(np.abs(world - w)) for w in want) > 0.005  # the frame matters


def test_block_jacobian_equals_the_older_face_and_central_differences():
    """The nominal loop's A (world frame) against analysis.closed_loop_jacobian (TrackingController.evaluate
    and model.kernels.eta_dot, another path to the same loop) and against central differences of the loop's
    rate function composed here, on a chained case (three links, the sinusoid) at two instants.  To 1e-5 of
    the largest entry: the kinematic law's etadot_c is itself a central difference (ERRATA P5), so the loop
    is smooth only down to that difference's step (measured: 1e-12 at t = 3 s, 1.6e-6 at 17 s)."""
    case, built = _case("three_link_switching.toml")
    loop = SchemeLoop(case, "nominal", built)
    fz = Faults.healthy(6, False)
    for t in (3.0, 17.0):
        pt = loop.point(t, fz, psi=built.reference.at(t).theta_d)
        blk = loop.blocks(pt)
        blk.omega = 0.0
        A = blk.continuous()
        nq = loop.n_q
        old = closed_loop_jacobian(built.chain, loop.ctrl, t, pt.xp[:nq], pt.xp[nq:], pt.xc)
        assert _rel(A, old) < 1e-5

        def F(x, t=t, nq=nq, pt=pt):
            a, _ = loop.controller(t, x, x[: nq + 2], pt.xc, fz)
            return loop.plant.rates(x, a, fz)

        assert _rel(A, central_columns(F, pt.xp)) < 1e-5


def test_plant_jacobian_against_the_sympy_model():
    """d(qdot, etadot)/d(q, eta, tau) of the reduced model (2.70) from an independent sympy derivation
    (kinetic energy, virtual work, S from the kinematics), against the plant's central differences, two links."""
    sp = pytest.importorskip("sympy")
    case, built = _case("two_link_intermittent.toml")
    chain = built.plant.chain
    n = 2
    th = sp.symbols("th1:3")
    x, y = sp.symbols("x y")
    v, w = sp.symbols("v w")
    taus = sp.symbols("tau0:4")
    q = [x, y, th[1], th[0]]
    # qdot = S eta: P_2 moves along theta_2 at v; theta_2' = v tan(theta_1 - theta_2) / d (2.63); theta_1' = w
    S = sp.Matrix([[sp.cos(th[1]), 0], [sp.sin(th[1]), 0], [sp.tan(th[0] - th[1]) / chain.d[0], 0], [0, 1]])
    eta = sp.Matrix([v, w])
    qd = S * eta
    P = [None, sp.Matrix([x, y])]
    P[0] = P[1] + chain.d[0] * sp.Matrix([sp.cos(th[1]), sp.sin(th[1])])
    Cm = [P[i] + chain.a[i] * sp.Matrix([sp.cos(th[i]), sp.sin(th[i])]) for i in range(n)]
    qs = sp.symbols("qd0:4")
    qv = sp.Matrix(qs)
    T = 0
    for i in range(n):
        vel = Cm[i].jacobian(q) * qv
        thd = qs[3] if i == 0 else qs[2]
        T += sp.Rational(1, 2) * chain.m[i] * (vel.T * vel)[0] + sp.Rational(1, 2) * chain.I[i] * thd**2
    M = sp.hessian(T, qs)
    dTdq = sp.Matrix([sp.diff(T, qi) for qi in q])
    Mdot = M.applyfunc(lambda e: sum(sp.diff(e, qi) * qdi for qi, qdi in zip(q, qs, strict=True)))
    Cv = (Mdot * qv - dTdq).subs(dict(zip(qs, qd, strict=True)))
    Q = sp.zeros(4, 1)
    for i in range(n):
        tr, tl = taus[2 * i], taus[2 * i + 1]
        Q += P[i].jacobian(q).T * (tr + tl) / chain.r[i] * sp.Matrix([sp.cos(th[i]), sp.sin(th[i])])
        Q += sp.Matrix([sp.diff(th[i], qi) for qi in q]) * chain.b[i] * (tr - tl) / chain.r[i]
    Mq = M.subs(dict(zip(qs, qd, strict=True)))
    Sdot = S.applyfunc(lambda e: sum(sp.diff(e, qi) * qdi for qi, qdi in zip(q, qd, strict=True)))
    # S^T (M (S etadot + Sdot eta) + C) = S^T B tau
    etadot = (S.T * Mq * S).LUsolve(S.T * Q - S.T * Mq * Sdot * eta - S.T * Cv)
    f = sp.Matrix([*qd, *etadot])
    vars_ = [*q, v, w, *taus]
    J = sp.lambdify([vars_], f.jacobian(vars_), "numpy")
    plant = SchemeLoop(case, "nominal", built).plant
    fz = Faults.healthy(4, False)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q0 = np.array([*rng.normal(size=2), rng.uniform(-0.5, 0.5), 0.0])
        q0[3] = q0[2] + rng.uniform(-0.6, 0.6)
        e0 = rng.normal(size=2) * [0.5, 0.3]
        tau = rng.normal(size=4)
        xp = np.concatenate((q0, e0))
        want = np.array(J(np.concatenate((q0, e0, tau))), dtype=float)
        assert _rel(plant.state_columns(xp, tau, fz), want[:, :6]) < 1e-7
        assert _rel(plant.input_columns(xp, tau, fz), want[:, 6:]) < 1e-7


def test_motor_plant_current_columns_are_the_central_differences():
    """The currents' exact columns (model.motor_compiled.current_jacobian) equal central differences of the rates."""
    case, built = _case("motors/two_link_active_motors.toml")
    loop = SchemeLoop(case, "nominal", built)
    fz = Faults.healthy(4, True)
    pt = loop.point(5.0, fz)
    J = loop.plant.state_columns(pt.xp, pt.a, fz)
    fd = central_columns(lambda x: loop.plant.rates(x, pt.a, fz), pt.xp)
    assert _rel(J[:, 6:], fd[:, 6:]) < 1e-8
    assert _rel(J, fd) < 1e-7


def test_a_fault_the_healthy_law_cannot_compensate(tmp_path):
    """1r lost and 1l at 5 % (k_v = 5): the healthy law still asks robot 1's turn of its weak wheel and its
    loop is unstable in that phase; the oracle, told the truth, is stable; before the fault both are."""
    data = tomllib.loads((ROOT / "cases" / "two_link_intermittent.toml").read_text())
    data.pop("thresholds", None)
    data["faults"] = [{"time": 10.0, "wheel": "1r"}, {"time": 10.0, "wheel": "1l", "sigma": 0.05}]
    del data["schemes"]["switching"]
    data["schemes"]["run"] = ["nominal", "oracle"]
    path = tmp_path / "weak_leader.toml"
    path.write_text(tomli_w.dumps(data))
    case = load_case(path)
    built = build(case)
    nom = analyze_scheme(case, "nominal", built, margins=False, limits=False)["phases"]
    ora = analyze_scheme(case, "oracle", built, margins=False, limits=False)["phases"]
    assert [p["stability"] for p in nom] == ["stable", "unstable"]
    assert nom[1]["max_real_part"] > 0.01 and nom[1]["pattern_applied"] == [1.0] * 4
    assert [p["stability"] for p in ora] == ["stable", "stable"] and ora[1]["max_real_part"] < -0.15
    assert ora[1]["pattern_applied"] == [0.0, 0.05, 1.0, 1.0]


def test_switching_applies_the_model_its_run_selected():
    """Thesis 3.2.3 over 60 s: in every phase the applied pattern is the bank model the run held longest."""
    case = with_duration(load_case(ROOT / "cases" / "two_link_switching.toml"), 60.0)
    built = build(case)
    run, _ = run_scheme(case, "switching", built)
    series = {"t": run.t, **run.signals}
    res = analyze_scheme(case, "switching", built, run=series, margins=False, limits=False)
    pats = np.array(patterns_of(case.schemes.switching, built.chain), dtype=float)
    t, sel = np.asarray(run.t), np.round(np.asarray(run.signals["selected"])).astype(int).ravel()
    for p in res["phases"]:
        mask = (t >= p["t_start"]) & (t < p["t_end"])
        vals, counts = np.unique(sel[mask], return_counts=True)
        assert p["pattern_applied"] == [float(v) for v in pats[vals[np.argmax(counts)]]]
        assert p["applied_from"].startswith("run")
    # after the first fault the run finds the true pattern: applied equals true in the later phases
    assert all(p["pattern_applied"] == p["pattern_true"] for p in res["phases"][1:])


def test_the_parameter_block_keeps_every_pole_the_plant_sees():
    """The adaptive weights (24 here) replaced by their image in the torque space (4 or fewer states): the
    reduced loop's poles are the full loop's nonzero poles (the full Jacobian differenced state by state)."""
    case, built = _case("two_link_adaptive_circle.toml")
    loop = SchemeLoop(case, "adaptive", built)
    fz = Faults.healthy(4, False)
    pt = loop.point(4.0, fz)
    blk = loop.blocks(pt)
    assert blk.parameter_block == len(loop.linearized) and blk.nc <= 4
    reduced = np.linalg.eigvals(blk.continuous())
    lin = np.array(loop.linearized)
    nx = loop.plant.n_states

    def F(z):
        xc = pt.xc.copy()
        xc[lin] = z[nx:]
        a, dx = loop.controller(pt.t, z[:nx], z[: loop.n_q + 2], xc, fz)
        return np.concatenate((loop.plant.rates(z[:nx], a, fz), dx[lin]))

    full = central_columns(F, np.concatenate((pt.xp, pt.xc[lin])))
    blk.omega = 0.0
    world = np.linalg.eigvals(blk.continuous())
    ev = np.linalg.eigvals(full)
    scale = np.abs(ev).max()
    nonzero = ev[np.abs(ev) > 1e-7 * scale]
    assert len(nonzero) == len(world[np.abs(world) > 1e-7 * scale])
    for v in nonzero:
        assert np.min(np.abs(world - v)) < 1e-6 * scale
    assert np.all(reduced.real < 0)


def _same_blocks(a, b) -> bool:
    names = ("Fx", "Fa", "Gx", "Gy", "Gc", "Dc", "Dy")
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names) and (a.na, a.kept, a.dropped, a.omega) == (
        b.na, b.kept, b.dropped, b.omega)  # fmt: skip


def test_blocks_are_served_again_only_for_the_same_point():
    """SchemeLoop.blocks keeps what it computed by the exact content of its point: the same point gives the
    numbers a fresh loop computes, as a copy; another instant, other faults or another controller state
    (two schemes' points differ there) are linearized anew and give other numbers."""
    case, built = _case("two_link_adaptive_circle.toml")
    loop = SchemeLoop(case, "adaptive", built)
    healthy = Faults.healthy(4, False)
    faulty = Faults(np.array([1.0, 1.0, 0.0, 1.0]), np.zeros(4), np.zeros((0, 4)))
    pt = loop.point(4.0, healthy)
    first = loop.blocks(pt)
    first.omega = 123.0  # a caller's change to its copy does not reach the next caller
    again = loop.blocks(loop.point(4.0, healthy))
    fresh = SchemeLoop(case, "adaptive", built).blocks(pt)
    assert _same_blocks(again, fresh) and again.omega != 123.0
    for other in (loop.point(5.0, healthy), loop.point(4.0, faulty)):
        assert not _same_blocks(loop.blocks(other), fresh)
    moved = loop.point(4.0, healthy)
    moved.xc = moved.xc.copy()
    moved.xc[loop.linearized[0]] += 1e-3  # other weights: another point
    assert not np.array_equal(loop.blocks(moved).Gy, fresh.Gy)
    nominal = SchemeLoop(case, "nominal", built)  # another scheme's loop keeps its own
    assert not _same_blocks(nominal.blocks(nominal.point(4.0, healthy)), fresh)


@pytest.mark.parametrize("scheme", ["adaptive", "active", "switching"])
def test_the_limits_case_gain_is_the_loop_at_its_point(scheme):
    """The gain family's blocks at the case's own k_v are the loop already linearized at that point
    (phases.scheme_limits uses them instead of linearizing a copy of the case with the same gain)."""
    from ftcreport.analysis.phases import _blocks_at_gain

    case, built = _case("two_link_active.toml")
    loop = SchemeLoop(case, scheme, built)
    fz = Faults.healthy(built.chain.n_wheels, False)
    base = loop.blocks(loop.point(2.0, fz))
    again = _blocks_at_gain(case, scheme, built, fz, None, 2.0, loop.k_v, None, base)
    assert _same_blocks(again, base)
    assert not _same_blocks(_blocks_at_gain(case, scheme, built, fz, None, 2.0, 2.0 * loop.k_v, None, base), base)


def test_the_ukf_update_through_its_steps_derivative_is_its_central_differences():
    """The UKF scheme's discrete update linearized through the filter step's derivative (SchemeLoop._ukf_map)
    against central differences of the whole compiled update (the analysis's method before 2026-12-02), at
    healthy and faulty points of two_link_active and three_link_active: every row within 2e-6 of the row's
    largest entry.  Measured: 3.7e-7 at most, which is the whole update's differences' own error (against
    differences of the filter step Richardson-extrapolated, tests/test_ukf_compiled.py, they are off by up
    to 3e-7 of a row: the step's round-off over 2 h = 2e-6, amplified by the sigma points' weights), and the
    law's (the clips of sigma_hat sit on the estimates at the truth: both difference the law at the same
    points to O(h^2))."""
    for name in ("two_link_active.toml", "three_link_active.toml"):
        case, built = _case(name)
        loop = SchemeLoop(case, "active_ukf", built)
        assert loop._ukf_law is not None
        nw, T = built.chain.n_wheels, case.simulation.dt
        lost = Faults(np.r_[1.0, 0.0, np.ones(nw - 2)], np.r_[0.0, 0.0, 0.3, np.zeros(nw - 3)], np.zeros((0, 4)))
        for fz in (Faults.healthy(nw, False), lost):
            for t in (2.0, 7.3):
                pt = loop.point(t, fz, period=T)
                Dc, Dy = loop._discrete_map(pt, T, loop._lin)
                law, loop._ukf_law = loop._ukf_law, None  # the whole update's central differences
                Dc0, Dy0 = loop._discrete_map(pt, T, loop._lin)
                loop._ukf_law = law
                new, old = np.hstack((Dc, Dy)), np.hstack((Dc0, Dy0))
                assert np.all(np.abs(new - old).max(axis=1) <= 2e-6 * np.abs(old).max(axis=1)), (name, t)


def test_the_frames_walk_is_the_kinematic_laws_own_steps():
    """closed_loop.frames walks the chained law's frame along the reference in one compiled call
    (ChainedBackstepping.discrete_along): the same psi, bit for bit, as its discrete update called step by
    step from Python (what frames did before 2026-12-02), at instants out of order and repeated."""
    from ftcreport.analysis.closed_loop import frames

    _, built = _case("five_link_cascade.toml")
    kin = built.kinematic()
    times = [7.5, 2.5, 40.0, 7.5, 63.3]
    got = frames(kin, times, step=0.02)
    xc = np.asarray(kin.initial_state(0.0, kin.reference.at(0.0).q_d), dtype=float)
    want, t = {}, 0.0
    for target in sorted(times):
        for s in [*(np.arange(t, target, 0.02)[1:] if target > t else []), target]:
            xc = kin.discrete(float(s), None, xc)
        t = target
        want[target] = float(xc[0])
    assert got == want
    assert len(set(want.values())) > 2  # the frame re-anchors between them
