"""Thesis claims as data (issue 18): schema, pure evaluation, check and JUnit gating, case pages."""

from __future__ import annotations

import tomllib
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from ftcreport.cases import load_case, parse_case
from ftcreport.cli import app
from ftcreport.errors import CaseError
from ftcreport.evaluation.claims import evaluate_claim, evaluate_claims, model_sequence
from ftcreport.model import Chain
from ftcreport.report.junit import junit_xml
from ftcreport.report.plots import robot_velocities
from ftcreport.studies.check import claim_item

CASES = Path(__file__).resolve().parents[1] / "cases"
THESIS = sorted(p for p in CASES.glob("*.toml") if load_case(p).description.startswith("Thesis"))
runner = CliRunner()

OK = {"status": "ok"}


def _claim(**kw) -> dict:
    return {"id": "c", "source": "3.2.3, Fig. 3.4", "words": "w", "expect": "reproduced"} | kw


def test_bound_claims_reproduced_or_not_with_the_number_in_the_reason():
    m = {"switching": OK | {"position_error_final": 3.0e-7}}
    r = evaluate_claim("x", _claim(scheme="switching", metric="position_error_final", max=1e-3), m)
    assert (r.outcome, r.ok) == ("reproduced", True)
    assert "3e-07" in r.reason and "<= 0.001" in r.reason
    r = evaluate_claim("x", _claim(scheme="switching", metric="position_error_final", min=1e-3), m)
    assert (r.outcome, r.ok) == ("not reproduced", False)
    assert "requires >= 0.001" in r.reason


def test_dict_metric_compares_its_largest_selected_entry():
    errs = {"rho_1r": 0.003, "rho_1l": 0.004, "rho_3r": 0.24, "rho_3l": 0.33}
    m = {"active": OK | {"fault_estimation_errors_final": errs}}
    rear = _claim(scheme="active", metric="fault_estimation_errors_final", keys=["rho_3r", "rho_3l"], max=0.1)
    r = evaluate_claim("x", rear | {"expect": "not reproduced"}, m)
    assert r.outcome == "not reproduced" and r.ok and "[rho_3l]" in r.measured
    lead = _claim(scheme="active", metric="fault_estimation_errors_final", keys=["rho_1r", "rho_1l"], max=0.1)
    assert evaluate_claim("x", lead, m).outcome == "reproduced"
    dotted = _claim(scheme="active", metric="fault_estimation_errors_final.rho_3r", max=0.1)
    assert "0.24" in evaluate_claim("x", dotted, m).reason


def test_sequence_claim_merges_repeats_and_is_one_based():
    assert model_sequence([(0.0, 0), (20.0, 4), (20.01, 4), (20.03, 1), (50.0, 2)]) == [1, 5, 2, 3]
    m = {"switching": OK | {"switch_sequence": [[0.0, 0], [20.0, 2], [20.1, 1], [50.0, 2]], "switch_count": 3}}
    r = evaluate_claim("x", _claim(scheme="switching", metric="switch_sequence", sequence=[1, 3, 2, 3]), m)
    assert r.outcome == "reproduced"
    r = evaluate_claim("x", _claim(scheme="switching", metric="switch_sequence", sequence=[1, 2, 3]), m)
    assert r.outcome == "not reproduced" and "1 -> 3 -> 2 -> 3" in r.reason


def test_ratio_not_applicable_and_not_evaluated():
    m = {"nominal": OK | {"position_error_final": 1.8e-7}, "switching": OK | {"position_error_final": 3.0e-7}}
    ratio = _claim(scheme="nominal", metric="position_error_final", relative_to="switching", min=10.0)
    r = evaluate_claim("x", ratio, m)
    assert r.outcome == "not reproduced" and "= 0.6" in r.measured
    na = _claim(not_applicable="by construction.", expect="not applicable")
    assert evaluate_claim("x", na, {}).outcome == "not applicable"
    missing = _claim(scheme="oracle", metric="position_error_final", max=1.0)
    assert evaluate_claim("x", missing, m).outcome == "not evaluated"
    stopped = {"oracle": {"status": "singular", "reason": "articulation angle"}}
    r = evaluate_claim("x", missing, stopped)
    assert r.outcome == "not evaluated" and not r.ok and "singular" in r.reason


@pytest.mark.parametrize(
    ("claim", "msg"),
    [
        (_claim(), "give scheme and metric"),
        (_claim(scheme="nominal", metric="m"), "either a bound"),
        (_claim(scheme="nominal", metric="m", max=1.0, sequence=[1]), "either a bound"),
        (_claim(scheme="wizard", metric="m", max=1.0), "unknown scheme"),
        (_claim(not_applicable="why"), "must expect 'not applicable'"),
        (_claim(scheme="oracle", metric="m", max=1.0), r"not in \[schemes\] run"),
    ],
)
def test_bad_claims_are_refused_with_the_field(claim, msg):
    data = tomllib.loads((CASES / "two_link_switching.toml").read_text())
    del data["schemes"]["oracle"]
    data["schemes"]["run"] = [s for s in data["schemes"] if s != "oracle"]  # every family runs unless narrowed
    data["claims"] = [claim]
    with pytest.raises(CaseError, match=msg) as info:
        parse_case(data, "x.toml")
    assert "claims[0]" in str(info.value)


def test_every_thesis_case_states_claims_with_an_expected_outcome():
    assert len(THESIS) == 7
    for path in THESIS:
        case = load_case(path)
        assert case.claims, path.name
        for c in case.claims:
            assert c.source and c.words and c.expect in ("reproduced", "not reproduced", "not applicable")
    # the four claims issue 18 names are there, with the outcome we measure
    by_id = {(p.stem, c.id): c for p in THESIS for c in load_case(p).claims}
    assert by_id[("two_link_switching", "switching_sequence")].expect == "not reproduced"
    assert by_id[("two_link_switching", "single_law_insufficient")].expect == "not reproduced"
    assert by_id[("two_link_adaptive_eight", "asymptotic_tracking")].expect == "not reproduced"
    assert by_id[("three_link_active", "rear_gain_estimates")].expect == "not reproduced"


def test_claims_do_not_change_the_cache_key():
    from ftcreport.cases import case_hash

    case = load_case(CASES / "two_link_switching.toml")
    assert case_hash(case, "v") == case_hash(case.model_copy(update={"claims": []}), "v")


def test_junit_has_one_testcase_per_claim_failing_on_a_changed_outcome():
    m = {"oracle": OK | {"position_error_final": 0.5}}
    res = evaluate_claims(
        "x",
        [
            _claim(id="holds", scheme="oracle", metric="position_error_final", max=1.0),
            _claim(id="changed", scheme="oracle", metric="position_error_final", max=0.1),
        ],
        m,
    )
    root = ET.fromstring(junit_xml([claim_item(c) for c in res]))
    assert root.get("tests") == "2" and root.get("failures") == "1"
    failing = [tc for tc in root.iter("testcase") if tc.find("failure") is not None]
    assert [(tc.get("classname"), tc.get("name")) for tc in failing] == [("x.claims", "changed")]
    assert "not reproduced (expected reproduced)" in failing[0].find("failure").get("message")


def test_check_gates_on_claims(tmp_path):
    """A 2 s run: one claim with its expected outcome, one whose outcome differs: exit 1, named."""
    src = tmp_path / "t.toml"
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["simulation"]["duration"] = 2.0
    data["faults"] = []
    data["schemes"] = {"oracle": data["schemes"]["oracle"]}
    data["claims"] = [
        _claim(id="bounded", scheme="oracle", metric="position_error_final", max=10.0),
        _claim(id="too_strict", scheme="oracle", metric="torque_peak", max=1e-9),
    ]
    src.write_text(tomli_w.dumps(data))
    junit = tmp_path / "junit.xml"
    res = runner.invoke(app, ["check", str(src), "--out", str(tmp_path / "r"), "--junit", str(junit), "-q"])
    assert res.exit_code == 1, res.output
    assert "claim too_strict" in res.output and "claim bounded" not in res.output
    assert "1/2 thesis claims have their expected outcome" in res.output
    data["claims"][1]["expect"] = "not reproduced"
    src.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["check", str(src), "--out", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r" / "t" / "index.html").read_text()
    assert 'id="thesis-claim"' in page and 'id="claim-bounded"' in page and 'id="claim-too_strict"' in page


def test_robot_velocities_follow_the_link_kinematics():
    """Two links: v_2 = eta[0], omega_1 = eta[1], v_1 = v_2 / cos(phi), omega_2 = v_2 tan(phi) / d (2.33)."""
    chain = Chain.uniform(2, d=1.7)
    rng = np.random.default_rng(0)
    q = np.column_stack((rng.normal(size=(20, 2)), rng.uniform(-1.2, 1.2, size=(20, 2))))
    eta = rng.normal(size=(20, 2))
    v, w = robot_velocities(chain, q, eta)
    phi = q[:, 3] - q[:, 2]  # theta_1 - theta_2
    np.testing.assert_allclose(v[:, 1], eta[:, 0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(w[:, 0], eta[:, 1], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(v[:, 0], eta[:, 0] / np.cos(phi), rtol=1e-12)
    np.testing.assert_allclose(w[:, 1], eta[:, 0] * np.tan(phi) / 1.7, rtol=1e-12, atol=1e-14)
