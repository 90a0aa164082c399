"""The linearized analysis's batched evaluations (issue 37 item 9): the same numbers as one call at a time.

``SchemeLoop._rows_at`` and ``_discrete_rows`` evaluate a scheme's compiled law (the loop's ``law_rows``,
``discrete_rows``) at many points in one call; ``central_rows`` and ``directional_rows`` difference them.
Each must give exactly (bit for bit) what the single calls (``_rows``, ``discrete``, ``central_columns``, a
central difference along a direction) give: the analysis's poles and limits were unchanged by the batching
on every shipped case, and these tests hold it there.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import plugin_case

from ftcreport.analysis import closed_loop
from ftcreport.analysis.closed_loop import Faults, SchemeLoop, central_columns, central_rows, directional_rows
from ftcreport.cases import load_case
from ftcreport.errors import ModelError
from ftcreport.model.motor_compiled import F_MODE, MODE_OPEN, healthy_faults
from ftcreport.runner import build

ROOT = Path(__file__).resolve().parents[1]


def _loop(name: str, scheme: str) -> SchemeLoop:
    case = load_case(ROOT / "cases" / name)
    return SchemeLoop(case, scheme, build(case))


def _points(loop: SchemeLoop, pt, rng: np.random.Generator, m: int = 7):
    """m points about pt: the measurement, the true state and the linearized scheme states each moved."""
    ny = loop.n_q + 2
    Y = pt.xp[:ny] + 1e-3 * rng.standard_normal((m, ny))
    XP = pt.xp + 1e-3 * rng.standard_normal((m, pt.xp.size))
    XC = np.repeat(pt.xc[None, :], m, axis=0)
    lin = np.array(loop.linearized, dtype=int)
    if lin.size:
        XC[:, lin] += 1e-4 * rng.standard_normal((m, lin.size))
    return XP, Y, XC


@pytest.mark.parametrize(
    ("name", "scheme", "t"),
    [
        ("three_link_switching.toml", "nominal", 3.0),
        ("three_link_switching.toml", "switching", 17.0),
        ("three_link_adaptive.toml", "adaptive", 12.0),
        ("two_link_active.toml", "active", 5.0),
        ("two_link_active.toml", "active_ukf", 5.0),
        ("motors/two_link_active_motors.toml", "oracle", 5.0),
        ("motors/three_link_switching_pi.toml", "switching", 5.0),
    ],
)
def test_rows_at_are_the_single_calls_bit_for_bit(name, scheme, t, rng):
    """The law at m points in one compiled call equals the law called at each point (np.array_equal), with
    every input per row or one row for all, rates on or off; on motor cases the drive's signal per row."""
    loop = _loop(name, scheme)
    nw = loop.plant.nw
    fz = Faults.healthy(nw, loop.plant.motors is not None)
    pt = loop.point(t, fz, psi=None)
    XP, Y, XC = _points(loop, pt, rng)
    for rates in (True, False):
        for xp_rows, y_rows, xc_rows in ((XP, Y, XC), (XP[:1], Y, XC[:1]), (XP[:1], Y[:1], XC)):
            got = loop._rows_at(t, xp_rows, y_rows, xc_rows, fz, rates=rates)
            m = max(len(xp_rows), len(y_rows), len(xc_rows))
            want = np.array([
                loop._rows(t, xp_rows[min(r, len(xp_rows) - 1)], y_rows[min(r, len(y_rows) - 1)],
                           xc_rows[min(r, len(xc_rows) - 1)], fz, rates=rates)
                for r in range(m)
            ])  # fmt: skip
            assert got.shape == want.shape and np.array_equal(got, want), (scheme, rates)
    assert np.array_equal(loop.point(t, fz, psi=None).xc, pt.xc)  # the point's state left as it was


def test_rows_at_with_a_faulty_motor_reads_each_rows_true_state(rng):
    """With an open winding the oracle is told the faults the chain sees at each row's wheel speeds: the
    batch reads every row's true state as the single call does (the Gx columns)."""
    loop = _loop("motors/two_link_active_motors.toml", "oracle")
    motor = healthy_faults(loop.plant.nw)
    motor[0, F_MODE] = MODE_OPEN
    fz = Faults(np.ones(loop.plant.nw), np.zeros(loop.plant.nw), motor)
    pt = loop.point(5.0, fz, psi=None)
    XP, _Y, _XC = _points(loop, pt, rng)
    y1, xc1 = pt.xp[None, : loop.n_q + 2], pt.xc[None, :]
    got = loop._rows_at(5.0, XP, y1, xc1, fz)
    want = np.array([loop._rows(5.0, xp, y1[0], xc1[0], fz) for xp in XP])
    assert np.array_equal(got, want)
    assert np.ptp(got[:, : loop.plant.nw], axis=0).max() > 0.0  # the rows do differ: the true state is read


def test_discrete_rows_are_the_single_updates_bit_for_bit(rng):
    """The UKF scheme's update at m points in one call equals ``discrete`` at each (the filter step and law)."""
    loop = _loop("two_link_active.toml", "active_ukf")
    fz = Faults.healthy(loop.plant.nw, False)
    pt = loop.point(5.0, fz, psi=None, period=loop.case.simulation.dt)
    _XP, Y, XC = _points(loop, pt, rng)
    nq = loop.n_q
    got = loop._discrete_rows(5.0, Y, XC)
    want = np.array([loop.discrete(5.0, y[:nq], y[nq:], xc) for y, xc in zip(Y, XC, strict=True)])
    assert np.array_equal(got, want)
    one_y = np.array([loop.discrete(5.0, Y[0, :nq], Y[0, nq:], xc) for xc in XC])
    assert np.array_equal(loop._discrete_rows(5.0, Y[:1], XC), one_y)


def test_central_rows_and_directional_rows_are_the_single_differences(monkeypatch, rng):
    """central_rows gives central_columns' numbers, in one batch and in many (BATCH_ENTRIES made small);
    directional_rows the central difference along each direction, a zero direction giving zeros."""
    A = rng.standard_normal((5, 9))

    def f(x):
        return np.concatenate((np.sin(A @ x), [math.exp(x[0]) * x[3]]))

    def rows(X):
        return np.array([f(x) for x in X])

    x0 = rng.standard_normal(9) * 3.0
    want = central_columns(f, x0)
    assert np.array_equal(central_rows(rows, x0), want)
    assert np.array_equal(central_rows(rows, x0, columns=[7, 2]), central_columns(f, x0, columns=[7, 2]))
    monkeypatch.setattr(closed_loop, "BATCH_ENTRIES", 20)  # 1 column per batch of 2 rows of 9
    assert np.array_equal(central_rows(rows, x0), want)
    V = rng.standard_normal((9, 3))
    V[:, 1] = 0.0
    norm = math.sqrt(float(np.sum(x0 * x0)))
    got = directional_rows(rows, x0, V)
    for k in (0, 2):
        v = V[:, k]
        h = 1e-6 * max(1.0, norm) / math.sqrt(float(np.sum(v * v)))
        assert np.array_equal(got[:, k], (f(x0 + h * v) - f(x0 - h * v)) / (2.0 * h))
    assert not np.any(got[:, 1])
    J = central_columns(f, x0)  # and both are the Jacobian, to the differences' truncation
    assert np.abs(got[:, 0] - J @ V[:, 0]).max() < 1e-6 * np.abs(J @ V[:, 0]).max()


def test_a_plugin_law_that_raises_in_a_batch_is_named_as_in_one_call(tmp_path):
    """A plug-in law that raises at one of the batch's points stops the batch with the reason a single call
    gives (the plug-in's file and line, the exception): the row's inputs are the ones recorded."""

    def edit(src: str) -> str:
        old = "    w, s = terms.w, terms.eta_e"
        assert old in src
        return src.replace(old, "    if step.q[0] > 1e3:\n        raise ValueError('q far off')\n" + old, 1)

    path = plugin_case(tmp_path, "batch_raiser", edit, duration=2.0)
    case = load_case(path)
    loop = SchemeLoop(case, "batch_raiser", build(case))
    fz = Faults.healthy(loop.plant.nw, False)
    pt = loop.point(1.0, fz, psi=None)
    Y = np.repeat(pt.xp[None, : loop.n_q + 2], 3, axis=0)
    Y[2, 0] = 2e3  # the third point raises
    with pytest.raises(ModelError) as single:
        loop._rows(1.0, pt.xp, Y[2], pt.xc, fz)
    with pytest.raises(ModelError) as batch:
        loop._rows_at(1.0, pt.xp[None, :], Y, pt.xc[None, :], fz)
    assert str(batch.value) == str(single.value)
    assert "q far off" in str(batch.value) and "batch_raiser.py" in str(batch.value)


def test_the_rates_range_keeps_every_direction_above_its_floor(rng):
    """closed_loop._range: G = D R up to the singular values below RANGE_FLOOR of the largest, so K_c G is
    K_c D R (the parameter block's W from 2 rank law evaluations): a rank-2 matrix with noise at 1e-9 of it
    (the six-robot adaptive law's rates: 1, 1.3e-2, then 1e-8) gives rank 2, a direction at 1e-5 is kept."""
    from ftcreport.analysis.closed_loop import RANGE_FLOOR, _range

    U = np.linalg.qr(rng.standard_normal((500, 10)))[0]
    V = np.linalg.qr(rng.standard_normal((10, 10)))[0]
    for s, rank in (([1.0, 1.3e-2] + [1e-9] * 8, 2), ([1.0, 1.3e-2, 1e-5] + [1e-10] * 7, 3)):
        G = U @ np.diag(s) @ V.T
        D, R = _range(G)
        assert D.shape == (500, rank) and R.shape == (rank, 10)
        assert np.abs(D @ R - G).max() < 10 * RANGE_FLOOR * np.abs(G).max()
        assert np.abs(D @ R - G).max() < 1e-8  # what is dropped is the noise, not a direction
    assert _range(np.zeros((5, 3)))[0].shape == (5, 0)


def test_the_ideal_plants_columns_are_its_single_rates_bit_for_bit():
    """The ideal plant's Jacobians in its state and its input from one compiled call for all their points
    (model.compiled.plant_rhs_rows) equal central_columns of Plant.rates called point by point, on a faulty
    phase (sigma, ubar, the torque limit)."""
    loop = _loop("three_link_switching.toml", "nominal")
    nw = loop.plant.nw
    fz = Faults(np.linspace(0.3, 1.0, nw), np.linspace(-0.2, 0.1, nw), np.zeros((0, 4)))
    pt = loop.point(4.0, fz, psi=None)
    a = pt.a + 0.5
    want = central_columns(lambda x: loop.plant.rates(x, a, fz), pt.xp)
    assert np.array_equal(loop.plant._state_columns(pt.xp, a, fz), want)
    want_a = central_columns(lambda v: loop.plant.rates(pt.xp, v, fz), a)
    assert np.array_equal(loop.plant._input_columns(pt.xp, a, fz), want_a)
