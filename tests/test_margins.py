"""Loop-at-a-time and disk margins (issue 37 item 4) against python-control's own functions."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import control
import numpy as np
import pytest

from ftcreport.analysis.closed_loop import Faults, SchemeLoop
from ftcreport.analysis.margins import crossover_margins, disk_margin_siso, frequency_grid, loop_margins, loop_systems
from ftcreport.cases import load_case
from ftcreport.runner import build

ROOT = Path(__file__).resolve().parents[1]

LOOPS = [
    control.tf([2], [1, 1, 0]),
    control.tf([30], [1, 3, 3, 1]),
    control.tf([1, 2], [1, 3, 3, 1, 0.1]),
    control.sample_system(control.tf([30], [1, 3, 3, 1]), 0.05),
    control.sample_system(control.tf([4], [1, 2, 0]), 0.1),
]


@pytest.mark.parametrize("L", LOOPS)
def test_crossover_margins_equal_python_controls(L):
    """Gain margin, phase margin, stability margin and the crossover frequencies as control.stability_margins
    gives them (its exact polynomial method on these low-order loops), to 1e-6."""
    L = control.ss(L)
    T = L.dt if L.isdtime(strict=True) else None
    om = frequency_grid(L.poles(), T)
    mine = crossover_margins(L, om, control.frequency_response(L, om).complex.ravel())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = control.stability_margins(L)
    for a, b in zip(mine, theirs, strict=True):
        if np.isfinite(b):
            assert a == pytest.approx(float(b), rel=1e-6)
        else:
            assert not np.isfinite(a) or b is None


@pytest.mark.parametrize("L", LOOPS)
def test_disk_margin_of_one_loop_equals_python_controls(L):
    """The closed form of the balanced disk margin against control.disk_margins on the same grid."""
    if not hasattr(control, "disk_margins"):
        pytest.skip("python-control < 0.10.2 has no disk_margins")
    om = frequency_grid(control.ss(L).poles(), L.dt if L.isdtime(strict=True) else None)
    mine = disk_margin_siso(control.frequency_response(L, om).complex.ravel())
    dm, dgm, dpm = control.disk_margins(L, om)
    assert mine["disk_margin"] == pytest.approx(float(dm), rel=1e-9)
    assert mine["disk_phase_margin_deg"] == pytest.approx(float(dpm), rel=1e-9)
    if np.isfinite(dgm):
        assert mine["disk_gain_margin_db"] == pytest.approx(float(dgm), rel=1e-9)


def test_motor_case_gain_margins_are_where_a_larger_gain_loses_stability():
    """On the sampled motor loop at 1 ms (stable: its limit is 1.37 ms) each actuator loop's gain margin is
    the factor on that loop's gain at which the sampled loop's spectral radius reaches 1 (the definition,
    by Brent's method on the closed loop), to 1e-7; its phase and stability margins are those of L on a
    dense grid (200,000 points up to the Nyquist frequency).  (control.stability_margins' polynomial
    method reports a gain margin of 1.10 and phase margins of 9.1 and 27.6 deg here, at crossings the
    dense grid does not have: angle(-L) is 0.08 rad at its 1854 rad/s; these polynomials are ill-conditioned.)"""
    from scipy.optimize import brentq

    from ftcreport.analysis.sampled import open_loop_at_input

    case = load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")
    built = build(case)
    loop = SchemeLoop(case, "nominal", built)
    blk = loop.blocks(loop.point(3.0, Faults.healthy(4, True)))
    T = 1e-3
    res = loop_margins(blk, T, 0, built.chain.wheels, "V")
    assert res["input"] == "voltage" and len(res["loops"]) == 4
    for j, (row, L) in enumerate(zip(res["loops"], loop_systems(blk, T), strict=True)):
        A, B, K = open_loop_at_input(blk, T, 0, j)
        rho = lambda k, A=A, B=B, K=K: float(np.abs(np.linalg.eigvals(A + k * B @ K)).max()) - 1.0  # noqa: E731
        assert rho(1.0) < 0 < rho(row["gain_margin"] * 1.001)
        assert row["gain_margin"] == pytest.approx(brentq(rho, 1.0, row["gain_margin"] * 1.001), rel=1e-7)
        om = np.linspace(1e-3, np.pi / T, 200_000)
        Ljw = control.frequency_response(L, om).complex.ravel()
        cross = np.flatnonzero(np.diff(np.sign(np.abs(Ljw) - 1.0)))
        pms = np.remainder(np.degrees(np.angle(Ljw[cross])), 360.0) - 180.0
        assert row["phase_margin_deg"] == pytest.approx(pms[np.argmin(np.abs(pms))], abs=0.01)
        assert row["stability_margin"] == pytest.approx(np.abs(1.0 + Ljw).min(), rel=1e-6)
    # near its sample-time limit the loop keeps little gain: 1.20 to 1.91 over the four wheels
    assert [round(r["gain_margin"], 2) for r in res["loops"]] == [1.2, 1.21, 1.5, 1.91]


def test_margins_are_not_given_for_an_unstable_loop():
    """two_link_switching_motors at its own 5 ms: every phase unstable, margins replaced by the reason."""
    from ftcreport.analysis.phases import analyze_scheme

    case = load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")
    res = analyze_scheme(case, "oracle", build(case), limits=False)
    for p in res["phases"]:
        assert "loops" not in p["margins"] and "unstable" in p["margins"]["note"]


PAIRS = [("two_link_active.toml", "active"), ("three_link_switching.toml", "switching")]


@pytest.mark.parametrize(("name", "scheme"), PAIRS)
def test_all_loops_from_one_eigendecomposition_equal_python_controls_responses(name, scheme):
    """margins.Loops (Sherman-Morrison on the closed loop's eigendecomposition) against python-control's
    frequency response of each loop broken alone, to 1e-10 (the eigenvectors are well conditioned here)."""
    from ftcreport.analysis.margins import Loops

    case = load_case(ROOT / "cases" / name)
    built = build(case)
    loop = SchemeLoop(case, scheme, built)
    blk = loop.blocks(loop.point(3.0, Faults.healthy(built.chain.n_wheels, False)))
    lp = Loops(blk, None)
    assert not lp.exact
    for j, L in enumerate(loop_systems(blk, None)):
        om = frequency_grid(L.poles(), None)
        want = control.frequency_response(L, om).complex.ravel()
        assert np.abs(lp.response(j, om) - want).max() < 1e-10 * np.abs(want).max()


def test_a_loop_evaluated_on_its_own_pole_is_infinite_not_a_crash():
    """CI on a Zen 5 machine: two_link_switching's page stopped with "complex division by zero" in the
    crossover search: the scalar L_j = -t / (1 + t) met 1 + t = 0 exactly, a pole of L_j on the axis (the
    array path divides under errstate and gives inf).  Both now give an infinite gain there."""
    import math

    from ftcreport.analysis.margins import Loops

    w0 = 2.0
    lp = Loops.__new__(Loops)
    lp.exact, lp.T = False, None
    lp.lam = np.array([0.0 + 0.0j])
    lp.W = np.array([[1.0 + 0.0j]])
    lp.KV = np.array([[-1j * w0]])  # t(j w0) = -j w0 / (j w0 - 0) = -1 exactly
    assert math.isinf(abs(lp.at(0)(w0)))
    assert math.isinf(abs(lp.response(0, [w0])[0]))
    assert abs(lp.at(0)(1.0) - lp.response(0, [1.0])[0]) < 1e-12  # elsewhere the same value


def test_the_frequency_grid_ignores_poles_at_round_off_from_the_origin():
    """A pole at round-off distance from s = 0 (or z = 1) is a constant mode, not a frequency: the grid starts a
    decade below the slowest pole that is not (two_link_intermittent's adaptive loop in its last phase had a
    mode at 1e-16 1/s, its grid started at 1e-17 rad/s and reported a gain margin of 5.6e-15 there)."""
    poles = np.array([-10.0, -1.0 + 2.0j, -1.0 - 2.0j, -0.05, 1.0e-16, -3.0e-17])
    grid = frequency_grid(poles, None)
    assert grid[0] == pytest.approx(0.005) and grid[-1] == pytest.approx(100.0)
    T = 0.01
    z = np.exp(poles * T)
    z[4] = 1.0 + 2e-16
    sampled = frequency_grid(z, T)
    assert sampled[0] == pytest.approx(0.005, rel=1e-6) and sampled[-1] == math.pi / T
    slow = np.array([-2300.0, -1.4e-3])  # a slow adaptation beside a fast motor (6e-7 of it) is kept
    assert frequency_grid(slow, None)[0] == pytest.approx(1.4e-4)


def _resonant_blocks(zeta: float = 0.01):
    """A two-input loop with a lightly damped mode (zeta, 1 rad/s) and a slow one, as Blocks with no scheme
    states: x' = A0 x + B a, a = K x (Blocks.continuous: Fx + Fa Gy C)."""
    from ftcreport.analysis.blocks import Blocks

    A0 = np.array([[0.0, 1.0, 0.0], [-1.0, -2.0 * zeta, 0.3], [0.0, 0.0, -0.05]])
    B = np.array([[0.0, 0.0], [1.0, 0.2], [0.1, 1.0]])
    K = np.array([[-0.02, -0.03, 0.0], [0.0, -0.01, -0.2]])  # a = K x (y = x: ny = 3, no scheme states)
    return Blocks(A0, B, np.zeros((2, 3)), K, np.zeros((2, 0)), np.zeros((0, 0)), np.zeros((0, 3)), 2)


def test_disk_margins_do_not_depend_on_the_grid():
    """The disk margin is the least over all frequencies: its peak refined off the grid, one loop at a time
    and for every input at once, equals the least on 20,000 frequencies (6,000 for the MIMO loop, ab13md's)
    to 1e-5, where the 200-point grid alone overstates it (a resonance of Q = 50 falls between its points)."""
    blk = _resonant_blocks()
    res = loop_margins(blk, None, 0, ["1r", "1l"], "N m")
    A = blk.continuous()
    Bf, Kf = blk.feedback()
    for j, row in enumerate(res["loops"]):
        Lj = control.ss(A - Bf[:, [j]] @ Kf[[j]], Bf[:, [j]], -Kf[[j]], np.zeros((1, 1)))
        w = np.geomspace(1e-3, 1e3, 20000)
        dense = disk_margin_siso(control.frequency_response(Lj, w).complex.ravel())["disk_margin"]
        grid = frequency_grid(np.linalg.eigvals(A - Bf[:, [j]] @ Kf[[j]]), None)
        coarse = disk_margin_siso(control.frequency_response(Lj, grid).complex.ravel())["disk_margin"]
        assert row["disk_margin"] == pytest.approx(dense, rel=1e-5), j
        assert coarse > row["disk_margin"] * (1 + 1e-4)  # the grid alone would have overstated it
    if not hasattr(control, "disk_margins"):
        return
    Lm = control.ss(A - Bf @ Kf, Bf, -Kf, np.zeros((2, 2)))  # every input broken (margins.mimo_loop)
    w = np.geomspace(1e-3, 1e3, 6000)
    dense = float(np.min(control.disk_margins(Lm, w, returnall=True)[0]))
    assert res["all_inputs"]["disk_margin"] == pytest.approx(dense, rel=1e-5)


def test_the_grids_hold_the_closed_loops_lightly_damped_modes():
    """A mode damped at 0.002 makes a dip narrower than any grid's spacing: resonant_frequencies puts its
    natural frequency on the grids, so the MIMO disk margin is the least of a grid 20 times as fine near it."""
    from ftcreport.analysis.margins import resonant_frequencies

    blk = _resonant_blocks(zeta=0.002)
    A = blk.continuous()
    wn = resonant_frequencies(A, None)
    assert wn.size == 1 and 0.8 < wn[0] < 1.25  # the 1 rad/s mode, moved a little by the feedback
    T = 0.05  # and in discrete time: the same mode from ln z / T
    Ad = np.asarray(control.c2d(control.ss(A, np.zeros((3, 1)), np.eye(3), 0), T).A)
    assert resonant_frequencies(Ad, T) == pytest.approx(wn, rel=1e-9)
    if not hasattr(control, "disk_margins"):
        return
    res = loop_margins(blk, None, 0, ["1r", "1l"], "N m")
    Bf, Kf = blk.feedback()
    Lm = control.ss(A - Bf @ Kf, Bf, -Kf, np.zeros((2, 2)))
    w = np.unique(np.concatenate((np.geomspace(1e-3, 1e3, 400), np.geomspace(0.9 * wn[0], 1.1 * wn[0], 4000))))
    dense = float(np.min(control.disk_margins(Lm, w, returnall=True)[0]))
    assert res["all_inputs"]["disk_margin"] == pytest.approx(dense, rel=1e-4)


def test_the_mimo_disk_margin_finds_the_dip_beside_a_lightly_damped_mode():
    """two_link_adaptive_circle's adaptive loop in its first phase: its MIMO disk margin dips to 1.37 at 0.744
    rad/s, beside its mode of 0.752 rad/s (damping 0.06); the 24-point grid and the loops' worst frequencies
    alone gave 1.60.  With the mode's frequency on the grid it is the least of 600 frequencies around it."""
    if not hasattr(control, "disk_margins"):
        pytest.skip("python-control < 0.10.2 has no disk_margins")
    from ftcreport.analysis.margins import mimo_loop
    from ftcreport.analysis.phases import fault_phases, instants

    case = load_case(ROOT / "cases" / "two_link_adaptive_circle.toml")
    loop = SchemeLoop(case, "adaptive", build(case))
    t = instants(case, *fault_phases(case)[0])[0]
    blk = loop.blocks(loop.point(t, Faults.healthy(loop.plant.nw, False), None))
    got = loop_margins(blk, None, 0, loop.ctrl.chain.wheels, "N m")["all_inputs"]["disk_margin"]
    w = np.geomspace(0.6, 0.9, 600)
    dense = float(np.min(control.disk_margins(mimo_loop(blk, None, 0), w, returnall=True)[0]))
    assert dense < 1.45  # the dip is there
    assert got == pytest.approx(dense, rel=1e-4)
