"""Passive FTC 2: multi-design integration adaptive controller, thesis 3.3.2.3."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case
from ftcreport.control.adaptive import AdaptiveController, pattern_laws
from ftcreport.control.kinematic import TwoLinkKinematic
from ftcreport.errors import ModelError
from ftcreport.model import Chain
from ftcreport.references import FlatReference, eight
from ftcreport.runner import build, run_scheme

CASES = Path(__file__).resolve().parents[1] / "cases"


@pytest.fixture(scope="module")
def eight_case():
    case = load_case(CASES / "two_link_adaptive_eight.toml")
    built = build(case)
    return {"case": case, **{s: run_scheme(case, s, built) for s in ("adaptive", "adaptive_frozen")}}


def test_pattern_laws_realise_the_bracket():
    """Every u_(k) satisfies Mbar1^-1 Bbar sigma_(k) u_(k) = w and sends nothing to assumed-failed wheels."""
    rng = np.random.default_rng(3)
    chain = Chain.uniform(3)
    pats = np.array(chain.compensable_patterns(), dtype=float)
    MB = rng.normal(size=(2, 6))
    w = rng.normal(size=2)
    U = pattern_laws(MB, pats, w)
    np.testing.assert_allclose(np.einsum("ij,kj->ki", MB, pats * U), np.tile(w, (len(pats), 1)), atol=1e-10)
    assert np.all(U[pats == 0] == 0)


@pytest.mark.slow
def test_eight_case_tracks_in_every_phase(eight_case):
    run, m = eight_case["adaptive"]
    assert m["status"] == "ok", m["reason"]
    for p in m["phases"][1:]:  # every phase after 10 s
        assert p["position_error_max"] < 0.03, p
    assert m["position_error_final"] < 0.01
    chi = run["chi_hat"]
    assert chi.min() >= 0.0 and chi.max() <= 1.0  # every weight at every logged step (ERRATA E14)
    assert chi.max() == 1.0 and chi.min() == 0.0  # the projection is active, not vacuous


@pytest.mark.slow
def test_adaptation_buys_a_tenfold_smaller_phase3_error(eight_case):
    _, ma = eight_case["adaptive"]
    _, mf = eight_case["adaptive_frozen"]
    assert mf["status"] == "ok"
    assert mf["phases"][2]["position_error_max"] >= 10 * ma["phases"][2]["position_error_max"]
    np.testing.assert_allclose(mf["friction_estimate_final"], 0.0)  # frozen means frozen


@pytest.mark.slow
def test_halving_dt_changes_per_phase_metrics_by_under_one_percent(eight_case):
    case = eight_case["case"]
    sim = case.simulation
    half = case.model_copy(
        update={"simulation": sim.model_copy(update={"dt": sim.dt / 2, "log_every": 2 * sim.log_every})}
    )
    _, mh = run_scheme(half, "adaptive")
    _, m = eight_case["adaptive"]
    for p, ph in zip(m["phases"], mh["phases"], strict=True):
        for key in ("position_error_max", "position_error_final"):
            assert ph[key] == pytest.approx(p[key], rel=0.01), (p["start"], key)


@pytest.mark.slow
def test_circle_converges_slowly_phase_after_phase():
    """ERRATA P1: the circle gains give a ~40 s time constant; the error still decreases every phase."""
    case = load_case(CASES / "two_link_adaptive_circle.toml")
    run, m = run_scheme(case, "adaptive")
    assert m["status"] == "ok"
    maxima = [p["position_error_max"] for p in m["phases"]]
    assert all(b < a for a, b in itertools.pairwise(maxima)), maxima
    assert maxima[-1] < 0.5 * maxima[0]
    for name in ("q", "eta", "tau", "chi_hat", "uf_hat"):
        assert np.all(np.isfinite(run[name])), name
    assert np.abs(run["tau"]).max() < 200.0
    assert np.abs(run["uf_hat"]).max() < 10.0


def test_bad_settings_refused():
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(eight(), chain.d)
    kin = TwoLinkKinematic(1.7, ref, 10, 10, 2)
    with pytest.raises(ModelError, match="chi0"):
        AdaptiveController(chain, kin, 10.0, chi0=np.full((10, 4), 1.5))
    with pytest.raises(ModelError, match="Gamma_f"):
        AdaptiveController(chain, kin, 10.0, Gamma_f=-1.0)
