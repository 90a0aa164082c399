"""Simulation engine: exact fault timing, singular and divergent stops, tracking."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcreport.control import VelocityController, constant_command
from ftcreport.errors import ModelError
from ftcreport.model import Chain, FaultEvent, FaultSchedule
from ftcreport.sim import Plant, SimSettings, simulate, time_grid


def test_time_grid_inserts_events_exactly():
    grid = time_grid(0.0, 30.0, 0.03, [20.0, 7.0001])
    assert 20.0 in grid and 7.0001 in grid
    assert grid[0] == 0.0 and grid[-1] == 30.0
    assert np.all(np.diff(grid) > 0) and np.diff(grid).max() <= 0.03 + 1e-12
    # a grid point that already is the event is not duplicated
    g2 = time_grid(0.0, 30.0, 0.01, [20.0])
    assert np.sum(np.isclose(g2, 20.0, atol=1e-6)) == 1


@pytest.mark.parametrize("dt", [0.01, 0.03, 0.007])
def test_fault_changes_torque_at_exactly_20s(dt):
    chain = Chain.uniform(2, d=1.7)
    faults = FaultSchedule(2, [FaultEvent(20.0, "2l", sigma=0.0, ubar=-1.5)])
    ctrl = VelocityController(chain, constant_command(0.5, 0.1), k=5.0)
    run = simulate(Plant(chain, faults), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=dt, duration=21.0))
    assert run.ok, run.reason
    i = int(np.flatnonzero(run.t == 20.0)[0])  # the instant exists exactly
    assert run["tau"][i - 1, 3] != pytest.approx(-1.5, abs=1e-3)
    assert run["tau"][i, 3] == -1.5  # sigma * u + ubar with sigma = 0
    assert run["sigma"][i - 1, 3] == 1.0 and run["sigma"][i, 3] == 0.0
    # the other wheels keep sigma u
    np.testing.assert_allclose(run["tau"][i, :3], run["u"][i, :3])


def test_nominal_tracks_constant_velocity_healthy():
    """Matched model, healthy wheels: e' = -k e, so |e(t)| = |e(0)| exp(-k t)."""
    for n in (2, 3, 5):
        chain = Chain.uniform(n, d=1.0)
        k = 4.0
        ctrl = VelocityController(chain, constant_command(0.5, 0.1), k=k)
        run = simulate(Plant(chain), ctrl, np.zeros(chain.n_q), np.zeros(2), SimSettings(dt=0.01, duration=8.0))
        assert run.ok
        err = np.linalg.norm(run["eta"] - np.array([0.5, 0.1]), axis=1)
        expected = np.linalg.norm([0.5, 0.1]) * np.exp(-k * run.t)
        # RK4 at dt = 0.01 with k dt = 0.04: relative error of exp(-k t) far below 1e-6
        np.testing.assert_allclose(err, expected, rtol=1e-6, atol=1e-12)
        assert err[-1] < 1e-6


def test_singular_run_stops_with_reason_and_keeps_log():
    chain = Chain.uniform(3, d=1.0)
    ctrl = VelocityController(chain, constant_command(0.1, 1.0), k=5.0)
    run = simulate(Plant(chain), ctrl, np.zeros(5), np.zeros(2), SimSettings(dt=0.01, duration=30.0))
    assert run.status == "singular"
    assert "articulation angle" in run.reason and "90 deg" in run.reason
    assert 0 < run.t_end < 30.0
    assert run.t.shape[0] > 10 and np.all(np.isfinite(run["q"]))
    margins = [chain.singularity_margin(q) for q in run["q"]]
    assert min(margins) >= math.radians(2.0)
    assert margins[-1] < math.radians(5.0)


class _Exploding:
    """A controller that commands ever larger torques (to force divergence)."""

    n_states = 1
    signal_names = ()

    def initial_state(self, t, q, eta):
        return np.array([1.0])

    def evaluate(self, t, q, eta, xc):
        return np.full(4, xc[0]), np.array([50.0 * xc[0]])

    def discrete(self, t, q, eta, xc):
        return xc

    def signals(self, t, q, eta, xc):
        return {}


def test_divergence_stops_with_reason():
    chain = Chain.uniform(2)
    run = simulate(Plant(chain), _Exploding(), np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=10.0))
    assert run.status == "diverged"
    assert run.reason
    assert run.t_end < 10.0
    assert np.all(np.isfinite(run["q"])) and np.all(np.isfinite(run["eta"]))


def test_saturation_limits_commanded_torque():
    chain = Chain.uniform(2)
    ctrl = VelocityController(chain, constant_command(2.0, 0.0), k=20.0)
    run = simulate(Plant(chain, saturation=5.0), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.0))
    assert np.abs(run["u"]).max() > 5.0
    assert np.abs(run["tau"]).max() <= 5.0 + 1e-12


def test_decimated_logging_keeps_last_point():
    chain = Chain.uniform(2)
    ctrl = VelocityController(chain, constant_command(0.5, 0.0))
    run = simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.005, log_every=10))
    assert run.t[-1] == pytest.approx(1.005)
    assert np.allclose(np.diff(run.t[:-1]), 0.1)


@pytest.mark.parametrize(
    ("kwargs", "msg"),
    [
        ({"dt": 0.0, "duration": 1.0}, "dt"),
        ({"dt": 0.1, "duration": -1.0}, "duration"),
        ({"dt": 2.0, "duration": 1.0}, "dt"),
    ],
)
def test_bad_settings(kwargs, msg):
    with pytest.raises(ModelError, match=msg):
        SimSettings(**kwargs)


def test_bad_initial_state_shape():
    chain = Chain.uniform(3)
    ctrl = VelocityController(chain, constant_command(0.5, 0.0))
    with pytest.raises(ModelError, match="q0"):
        simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.0))
