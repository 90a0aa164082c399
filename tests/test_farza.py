"""Farza et al. (2009) adaptive observer: ERRATA E15 signs, identification, the P guard (P3)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import harness

from ftcreport.errors import ModelError
from ftcreport.model import Chain, FaultEvent, FaultSchedule
from ftcreport.observers import FarzaObserver
from ftcreport.sim import Plant, SimSettings, simulate

H = harness()


def _signals(run, ctrl, obs) -> dict:
    """xhat, rhohat and the largest eigenvalue of P from the logged observer state."""
    parts = [obs.split(xc[ctrl.kin.n_states :]) for xc in run["xc"]]
    return {
        "xhat": np.array([x for x, _, _, _ in parts]),
        "rhohat": np.array([r for _, r, _, _ in parts]),
        "Pmax": np.array([np.linalg.eigvalsh(P).max() for _, _, _, P in parts]),
    }


def _run(p_max, printed=False, duration=20.0):
    chain = Chain.uniform(2, d=1.0)
    obs = FarzaObserver(chain, Theta=2.0, p_max=p_max, printed_signs=printed)
    faults = FaultSchedule(2, [FaultEvent(10.0, "2l", sigma=0.5)])
    # an excited velocity loop on the true eta, eta_c = (0.5 + 0.2 sin 0.7t, 0.3 sin 0.5t), the observer alongside
    ctrl = H.controller(chain, H.FARZA, c0=(0.5, 0.0), amp=(0.2, 0.3), om=(0.7, 0.5), estimator=obs)
    run = simulate(
        Plant(chain, faults), ctrl, np.zeros(4), np.zeros(2), SimSettings(dt=0.01, duration=duration, log_every=10)
    )
    sig = _signals(run, ctrl, obs)
    qdot = np.array([chain.S(q) @ e for q, e in zip(run["q"], run["eta"], strict=True)])
    err = np.abs(sig["xhat"] - np.hstack((run["q"], qdot))).max(axis=1)
    return run, sig, err


def test_printed_signs_diverge_corrected_signs_converge():
    """ERRATA E15: with the signs of (4.11) as printed the observer blows up; corrected it tracks."""
    bad, _, err_bad = _run(1e3, printed=True)
    assert bad.status == "diverged" or err_bad.max() > 1.0
    good, _, err_good = _run(1e3)
    assert good.ok
    k5 = int(np.searchsorted(good.t, 5.0))
    assert err_good[k5] < 1e-6


def test_gain_loss_is_identified_without_guard_and_p_blows_up():
    """Without the guard the 2l gain (0.5 after 10 s) is identified, but P grows like exp(Theta t) (P3)."""
    _, sig, _ = _run(None)
    rho = sig["rhohat"][-1][:4]
    np.testing.assert_allclose(rho, [1.0, 1.0, 1.0, 0.5], atol=0.02)
    assert float(sig["Pmax"].max()) > 1e6


def test_guard_bounds_p_at_the_cost_of_convergence_speed():
    _, sig, _ = _run(1e3)
    assert float(sig["Pmax"].max()) <= 1e3 * (1 + 1e-6)
    # the measured price: the gain estimate is still far from 0.5 ten seconds after the fault
    assert abs(sig["rhohat"][-1][3] - 0.5) > 0.2
    assert np.all(np.isfinite(sig["rhohat"]))


def test_bad_settings():
    chain = Chain.uniform(2)
    with pytest.raises(ModelError, match="Theta"):
        FarzaObserver(chain, Theta=0.0)
    with pytest.raises(ModelError, match="estimate"):
        FarzaObserver(chain, Theta=1.0, estimate=("mass",))
