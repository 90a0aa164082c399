"""Passive FTC 2: multi-design integration adaptive controller, thesis 3.3.2.3."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case
from ftcreport.control.adaptive import AdaptiveController
from ftcreport.control.interface_compiled import engine_terms
from ftcreport.control.kinematic import TwoLinkKinematic
from ftcreport.errors import ModelError
from ftcreport.fast import kernels as F
from ftcreport.fast.engine import compiled_spec, law_buffers, loop_for
from ftcreport.model import Chain
from ftcreport.references import FlatReference, eight
from ftcreport.runner import build, make_controller, run_scheme

CASES = Path(__file__).resolve().parents[1] / "cases"


@pytest.fixture(scope="module")
def eight_case():
    case = load_case(CASES / "two_link_adaptive_eight.toml")
    built = build(case)
    return {"case": case, **{s: run_scheme(case, s, built) for s in ("adaptive", "adaptive_frozen")}}


def test_pattern_laws_realise_the_bracket():
    """The compiled adaptive law (control.passive_law.adaptive_law, run by the loop's first_law) with the
    weights of model k alone (chi_(k) = 1): u = u_(k), Mbar1^-1 Bbar sigma_(k) u_(k) = w - Mbar1^-1 Bbar uhat_f
    (3.121), nothing to assumed-failed wheels."""
    built = build(load_case(CASES / "three_link_adaptive.toml"))
    ctrl = make_controller(built, "adaptive")
    spec = compiled_spec(ctrl)
    loop = loop_for(spec.law, spec.disc, motors=False, sampled=False, terms=spec.terms)
    rng = np.random.default_rng(3)
    n, nw = built.chain.n, built.chain.n_wheels
    q = built.q0 + rng.normal(scale=0.02, size=built.q0.shape)
    eta = np.array([0.4, 0.1])
    xc0 = ctrl.initial_state(0.0, q, eta)
    uf = rng.normal(scale=0.2, size=nw)
    xc0[ctrl._uf] = uf
    none, info = np.zeros(0), np.zeros(4)
    nk = ctrl.kin.n_states
    w, MB, _g, _e = engine_terms(spec.kin, spec.ref, F.new_cache(n), spec.chain, 0.0, q, eta, xc0[:nk], ctrl.k_v, info)
    assert info[0] == 0
    for k, sigma in enumerate(ctrl.patterns):
        xc = xc0.copy()
        chi = np.zeros((ctrl.N, nw))
        chi[k] = 1.0
        xc[ctrl._chi] = chi.ravel()
        u = loop.first_law((spec.P, law_buffers(spec)), spec.kin, spec.ref, spec.chain, 0.0, q, eta, xc,
                           np.ones(nw), np.zeros(nw), info, none)  # fmt: skip
        assert info[0] == 0
        # the bracket to round-off (values of O(1-10), 2 x 2 solves)
        np.testing.assert_allclose(MB @ (sigma * u), w - MB @ uf, rtol=0, atol=1e-10 * max(1.0, np.abs(w).max()))
        assert np.all(u[sigma == 0] == 0)


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
