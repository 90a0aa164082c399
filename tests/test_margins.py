"""Loop-at-a-time and disk margins (issue 37 item 4) against python-control's own functions."""

from __future__ import annotations

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
