"""Simulation engine: exact fault timing, singular and divergent stops, tracking.

The laws that drive these runs are the test harnesses of tests/data/harness_scheme.py (a plug-in
scheme on the compiled loop): healthy computed torque on a constant velocity command, and a
blow-up.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import harness

from ftcreport.control import TrackingController, TwoLinkKinematic
from ftcreport.errors import ModelError
from ftcreport.evaluation.metrics import singularity_margin
from ftcreport.model import Chain, FaultEvent, FaultSchedule
from ftcreport.references import FlatReference, circle
from ftcreport.sim import Plant, SimSettings, simulate, time_grid

H = harness()


def _velocity(chain, eta_c, k=5.0):
    """Healthy computed torque on the constant command eta_c (harness VELOCITY: e' = -k e when matched)."""
    return H.controller(chain, H.VELOCITY, k=k, c0=eta_c)


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
    ctrl = _velocity(chain, (0.5, 0.1), k=5.0)
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
        ctrl = _velocity(chain, (0.5, 0.1), k=k)
        run = simulate(Plant(chain), ctrl, np.zeros(chain.n_q), np.zeros(2), SimSettings(dt=0.01, duration=8.0))
        assert run.ok
        err = np.linalg.norm(run["eta"] - np.array([0.5, 0.1]), axis=1)
        expected = np.linalg.norm([0.5, 0.1]) * np.exp(-k * run.t)
        # RK4 at dt = 0.01 with k dt = 0.04: relative error of exp(-k t) far below 1e-6
        np.testing.assert_allclose(err, expected, rtol=1e-6, atol=1e-12)
        assert err[-1] < 1e-6


def test_singular_run_stops_with_reason_and_keeps_log():
    chain = Chain.uniform(3, d=1.0)
    ctrl = _velocity(chain, (0.1, 1.0), k=5.0)
    run = simulate(Plant(chain), ctrl, np.zeros(5), np.zeros(2), SimSettings(dt=0.01, duration=30.0))
    assert run.status == "singular"
    assert "articulation angle" in run.reason and "90 deg" in run.reason
    assert 0 < run.t_end < 30.0
    assert run.t.shape[0] > 10 and np.all(np.isfinite(run["q"]))
    margins = [singularity_margin(q[None, :]) for q in run["q"]]  # per logged state
    assert min(margins) >= math.radians(2.0)
    assert margins[-1] < math.radians(5.0)


def test_divergence_stops_with_reason():
    chain = Chain.uniform(2)
    exploding = H.controller(chain, H.EXPLODING, rate=50.0)  # every wheel commanded x, x' = 50 x
    run = simulate(Plant(chain), exploding, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=10.0))
    # e^(50 t) at dt = 0.01 s grows 1.65x per step: a resolved divergence, not a step blow-up
    assert run.status == "diverged"
    assert "dt = 0.01 s" in run.reason
    assert run.t_end < 10.0
    assert np.all(np.isfinite(run["q"])) and np.all(np.isfinite(run["eta"]))


def test_saturation_limits_commanded_torque():
    chain = Chain.uniform(2)
    ctrl = _velocity(chain, (2.0, 0.0), k=20.0)
    run = simulate(Plant(chain, saturation=5.0), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.0))
    assert np.abs(run["u"]).max() > 5.0
    assert np.abs(run["tau"]).max() <= 5.0 + 1e-12


def test_decimated_logging_keeps_last_point():
    chain = Chain.uniform(2)
    ctrl = _velocity(chain, (0.5, 0.0))
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
    ctrl = _velocity(chain, (0.5, 0.0))
    with pytest.raises(ModelError, match="q0"):
        simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.0))


def test_sensor_noise_is_seeded_and_only_measured():
    """The controller sees q + noise (logged as q_meas); the plant integrates the truth; seeded."""
    chain = Chain.uniform(2)
    runs = []
    for seed in (1, 1, 2):
        ctrl = _velocity(chain, (0.5, 0.1), k=5.0)
        plant = Plant(chain, noise_q=[0.001, 0.001, 0.002, 0.002], noise_eta=[0.01, 0.0], seed=seed)
        runs.append(simulate(plant, ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=2.0)))
    a, b, c = runs
    np.testing.assert_array_equal(a["q"], b["q"])  # same seed, same run
    assert np.abs(a["q"] - c["q"]).max() > 0  # another seed differs
    resid = a["q_meas"] - a["q"]
    assert 0.0005 < resid[:, 0].std() < 0.0015 and 0.001 < resid[:, 2].std() < 0.003
    # the velocity noise reaches the controller: v_n tracking error is noisy, omega_1 is not
    assert np.abs(a["eta"][-50:, 0] - 0.5).max() > 1e-4


def test_plant_parameters_can_differ_from_the_controller_model():
    """Mismatch: a 20 % heavier plant under the nominal model's computed torque lags the command."""
    model = Chain.uniform(2)
    heavy = Chain.uniform(2, m=36.0)
    out = {}
    for name, plant_chain in (("matched", model), ("heavy", heavy)):
        ctrl = _velocity(model, (0.5, 0.1), k=2.0)
        run = simulate(Plant(plant_chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=1.0))
        out[name] = run["eta"][-1, 0]
    expected = 0.5 * (1 - np.exp(-2.0))
    assert out["matched"] == pytest.approx(expected, rel=1e-6)
    assert out["heavy"] < out["matched"] - 1e-3


def test_a_controller_without_a_compiled_counterpart_is_refused():
    """There is no Python loop (issue 17): a law is a scheme; the old engine="python" is a clear error."""

    class Mine:
        n_states = 0
        signal_names = ()

    chain = Chain.uniform(2)
    settings = SimSettings(dt=0.01, duration=0.1)
    with pytest.raises(ModelError, match="no compiled counterpart; a new law runs as a scheme"):
        simulate(Plant(chain), Mine(), np.zeros(4), np.zeros(2), settings)
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    ctrl = TrackingController(chain, TwoLinkKinematic(chain.d[0], ref, 1.0, 1.0, 1.0), 5.0)
    with pytest.raises(ModelError, match="the Python loop was removed"):
        simulate(Plant(chain), ctrl, ref.at(0.0).q_d, np.array([0.5, 0.0]), settings, engine="python")
