"""The switching bank with motors (issue 36 item 3) and the case page's plant block (items 2, 6).

The finding: with DC motors the bank identified the healthy chain ~0 % of the time before the first
fault and 64 % over the run (three_link_switching_motors; 99.6 % without motors).  Its causes: the
filters (3.42) left out the rotors' inertia, the static drive's held voltage moves the torque
between samples, and the instantaneous cost keeps a model chosen on one moment of mismatch (the
wheels it leaves undriven cannot be tested).  The remedy: the filters model the rotors
(fast.kernels.rotor_filter_terms) and the motor cases use Narendra & Balakrishnan's forgetting cost.
Checked here: the filters' model is the motor plant's; the finding is reproduced with the old bank;
the motor cases identify within 5 points of the case without motors; the page shows it.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import random_chain, random_q

from ftcreport.cases import load_case, parse_case, resolve_overlay
from ftcreport.fast import kernels as K
from ftcreport.fast.engine import _chain
from ftcreport.model import motor_compiled as M
from ftcreport.model.actuators import MAXON_RE65, pack, rotor_inertia_wheels
from ftcreport.runner import run_scheme

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "cases" / "three_link_switching.toml"
STATIC = ROOT / "cases" / "motors" / "three_link_switching_motors.toml"
PI = ROOT / "cases" / "motors" / "three_link_switching_pi.toml"


@pytest.mark.parametrize("n", [2, 3])
def test_the_banks_filters_predict_with_the_motor_plants_inertia(n, rng):
    """rotor_filter_terms: g + MB tau is the motor plant's etadot for the wheel torques tau = eta_g N k_m i
    (b_m = 0), to round-off: the filters' model is (2.70) with the rotors on the wheel axes (E19)."""
    pc = _chain(random_chain(rng, n).params)
    motors = [dataclasses.replace(MAXON_RE65, N=20.0 * (1 + 0.1 * i), b_m=0.0) for i in range(n)]
    mo = pack(motors, n)
    Jw = rotor_inertia_wheels(motors)
    np.testing.assert_array_equal(Jw, M.rotor_inertia_wheel(mo))
    for _ in range(5):
        q = random_q(rng, n)
        eta = rng.normal(size=2)
        i = rng.normal(size=2 * n) * 10.0
        etadot = M.motor_plant_rhs(pc, mo, q, eta, i, np.zeros(2 * n), M.healthy_faults(2 * n))[1]
        MB, g = K.rotor_filter_terms(pc, q, eta, Jw)
        tau = mo.eta_g * mo.N * mo.k_m * i
        np.testing.assert_allclose(g + MB @ tau, etadot, rtol=1e-12, atol=1e-12 * np.abs(etadot).max())
        # and it is not the chain's own model: the rotors weigh
        Mbar1, _M2, _C, Bbar, _S, _Sd = K.reduced(pc, q, eta)
        assert np.abs(np.linalg.solve(Mbar1, Bbar) - MB).max() > 1e-3 * np.abs(MB).max()


def _switching(path: Path, **switching):
    """The switching run of a case (its other schemes dropped), with ``switching`` over its table."""
    raw = tomllib.loads(path.read_text())
    if "base_case" in raw:
        raw = resolve_overlay(path, raw)
    raw = copy.deepcopy(raw)
    for key in ("claims", "thresholds"):
        raw.pop(key, None)
    raw["schemes"] = {"switching": raw["schemes"]["switching"] | switching, "run": ["switching"]}
    run, m = run_scheme(parse_case(raw, path.stem), "switching")
    assert run.status == "ok", run.reason
    return run, m


def _exact_before(run, t_end: float) -> float:
    """Exact identification over [0, t_end) of a run whose true pattern is healthy there (model 0)."""
    keep = run.t < t_end
    return float(np.mean(np.round(run.signals["selected"][keep]) == 0))


def test_the_finding_reproduced_with_the_old_bank():
    """The bank as it was (no rotors in its filters, the thesis's instantaneous cost) on the static
    motor case: measured 0.3 % exact before the first fault (20 s) and 63.5 % over 100 s."""
    run, m = _switching(STATIC, rotor_inertia=False, c_int=0.0)
    assert _exact_before(run, 20.0) < 0.05
    assert m["switching_exact_match_fraction"] < 0.70


def test_motor_cases_identify_within_five_points_of_the_case_without_motors():
    """Exact identification, measured: 99.64 % without motors (thesis cost); 97.80 % with the static
    drive (c_int = 10, forgetting = 1) and 99.50 % with the PI drive (forgetting = 10): within the
    issue's 5 points, and 100 % of the healthy start in both."""
    _, base = _switching(BASE)
    ref = base["switching_exact_match_fraction"]
    assert ref > 0.99
    for path in (STATIC, PI):
        run, m = _switching(path)
        assert m["switching_exact_match_fraction"] >= ref - 0.05, (path.stem, m["switching_exact_match_fraction"])
        assert _exact_before(run, 20.0) == 1.0
    # the PI drive with the short memory: within half a point
    assert m["switching_exact_match_fraction"] >= ref - 0.005


def test_the_pi_case_needs_both_remedies():
    """On the PI case each part of the remedy alone is not enough: without the rotors in the filters
    (58.1 % measured with the thesis cost), with them but the instantaneous cost (83.6 %: one
    coincidental moment at 3.9 s switches to a superset model that then stays)."""
    _, no_rotors = _switching(PI, rotor_inertia=False, c_int=0.0)
    _, thesis_cost = _switching(PI, c_int=0.0)
    assert no_rotors["switching_exact_match_fraction"] < 0.7
    assert thesis_cost["switching_exact_match_fraction"] < 0.9


def test_a_motor_case_with_the_instantaneous_cost_is_warned_about():
    raw = resolve_overlay(STATIC, tomllib.loads(STATIC.read_text()))
    raw["schemes"]["switching"]["c_int"] = 0.0
    case = parse_case(raw, "warned")
    assert any(w.startswith("schemes.switching: with [actuators]") for w in case.warnings())
    assert not any("schemes.switching" in w for w in load_case(STATIC).warnings())
    assert not any("schemes.switching" in w for w in load_case(BASE).warnings())


def test_the_motor_case_page_shows_the_plant_and_the_identification(tmp_path):
    """A batch of the static motor case, the PI case and their base (to 25 s: the first fault at 20 s):
    every page has the idealizations; the motor pages what the drive assumes and the identification
    figure (applied model against the true pattern, the cost excesses) with the base's fraction."""
    from ftcreport.studies.batch import run_batch

    res = run_batch([BASE, STATIC, PI], tmp_path, jobs=2, duration=25.0, show_progress=False)
    assert not res.case_errors and not res.failed_runs, (res.case_errors, res.failed_runs)
    base_page = (tmp_path / "three_link_switching" / "index.html").read_text()
    assert 'id="idealizations"' in base_page and "ideal torque sources" in base_page
    assert 'id="drive-model"' not in base_page and 'id="fig-identification"' not in base_page
    for name, drive in (
        ("three_link_switching_motors", "static inversion"),
        ("three_link_switching_pi", "PI current loop"),
    ):
        page = (tmp_path / name / "index.html").read_text()
        assert 'id="idealizations"' in page and "a DC motor per wheel" in page
        assert 'id="drive-model"' in page and drive in page
        spec = re.search(r'<script type="application/json" id="plot-identification-spec">(.*?)</script>', page, re.S)
        assert spec is not None
        fig = json.loads(spec.group(1))
        names = [tr["name"] for tr in fig["data"]]
        assert names[:2] == ["true pattern", "applied model"] and "cost excess of the true model" in names
        true_idx = [y for y in fig["data"][0]["y"] if y is not None]
        assert min(true_idx) == 0 and max(true_idx) == 1  # healthy, then 1r failed at 20 s
        assert fig["layout"]["yaxis2"]["type"] == "log"
        m = re.search(r"without motors: ([0-9.]+) %", page)
        assert m is not None and math.isfinite(float(m.group(1)))
    pi = (tmp_path / "three_link_switching_pi" / "index.html").read_text()
    assert "K_p = 1.012 V/A" in pi and "back-EMF feedforward" in pi
