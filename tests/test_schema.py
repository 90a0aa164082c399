"""One schema for case files: JSON Schema from the models, generated README tables, editor config, did-you-mean."""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
import tomllib
from pathlib import Path

import jsonschema
import pytest
from typer.testing import CliRunner

from ftcreport.cases import case_schema, did_you_mean, parse_case
from ftcreport.cases.schema_doc import schema_json, update_readme
from ftcreport.cli import app
from ftcreport.errors import CaseError

ROOT = Path(__file__).resolve().parents[1]
CASES = sorted((ROOT / "cases").glob("*.toml"))
VALIDATOR = jsonschema.Draft202012Validator(case_schema())


def _walk(schema: dict, defs: dict, path: str = ""):
    """(path, property schema) of every property of every table, through $refs."""
    for name, prop in schema.get("properties", {}).items():
        yield f"{path}{name}", prop
    for name, sub in defs.items():
        if name != "__root__":
            for name2, prop in sub.get("properties", {}).items():
                yield f"{name}.{name2}", prop


def _numeric(s: dict) -> list[dict]:
    if s.get("type") in ("number", "integer"):
        return [s]
    out = []
    for key in ("anyOf", "prefixItems"):
        for sub in s.get(key, []):
            out += _numeric(sub)
    for key in ("items", "additionalProperties"):
        if isinstance(s.get(key), dict):
            out += _numeric(s[key])
    return out


def test_every_field_has_description_unit_and_numeric_range():
    schema = case_schema()
    props = list(_walk(schema, schema["$defs"]))
    assert len(props) > 120  # every table's fields, not just the top level
    for where, prop in props:
        assert prop.get("description"), f"{where}: no description"
        assert prop.get("unit"), f"{where}: no unit"
        for num in _numeric(prop):
            lo = "minimum" in num or "exclusiveMinimum" in num
            hi = "maximum" in num or "exclusiveMaximum" in num
            assert lo and hi, f"{where}: numeric without a documented range: {num}"


@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_schema_validates_every_shipped_case(path):
    errors = list(VALIDATOR.iter_errors(tomllib.loads(path.read_text())))
    assert errors == [], [e.message for e in errors]


def _base() -> dict:
    return tomllib.loads((ROOT / "cases" / "three_link_switching.toml").read_text())


MALFORMED = [
    ("unknown key", lambda c: c["schemes"]["switching"].update(kp_v=3.0)),
    ("unknown table", lambda c: c.update(robot={"n": 2})),
    ("sigma above 1", lambda c: c["faults"][0].update(sigma=1.5)),
    ("one robot", lambda c: c["robots"].update(n=1)),
    ("negative step", lambda c: c["simulation"].update(dt=-0.01)),
    ("step as text", lambda c: c["simulation"].update(dt="fast")),
    ("unknown reference", lambda c: c["reference"].update(kind="spiral")),
    ("missing kinematic", lambda c: c.pop("kinematic")),
    ("mass zero in a list", lambda c: c["robots"].update(m=[30.0, 0.0, 30.0])),
    ("band at 90 deg", lambda c: c["kinematic"].update(band_deg=90.0)),
    ("negative seed", lambda c: c.update(plant={"noise": {"seed": -1}})),
    ("log_every zero", lambda c: c["simulation"].update(log_every=0)),
    ("method unknown", lambda c: c["simulation"].update(method="euler")),
    ("huge speed", lambda c: c["reference"].update(speed=1e9)),
]


@pytest.mark.parametrize(("why", "mutate"), MALFORMED, ids=[m[0] for m in MALFORMED])
def test_schema_and_models_reject_malformed_cases(why, mutate):
    data = _base()
    assert list(VALIDATOR.iter_errors(data)) == []
    bad = copy.deepcopy(data)
    mutate(bad)
    assert list(VALIDATOR.iter_errors(bad)), f"schema accepts: {why}"
    with pytest.raises(CaseError):  # the models agree with the schema they generate
        parse_case(bad, "cases/x.toml")


def test_readme_tables_and_schema_file_match_the_models():
    readme = ROOT / "cases" / "README.md"
    text = readme.read_text()
    assert text.count("<!-- schema:") >= 19
    assert update_readme(text) == text, "cases/README.md drifted: run python -m ftcreport.cases.schema_doc"
    stored = (ROOT / "cases" / "case.schema.json").read_text()
    assert stored == schema_json(), "cases/case.schema.json drifted: run python -m ftcreport.cases.schema_doc"


def test_drift_is_detected():
    text = (ROOT / "cases" / "README.md").read_text()
    edited = text.replace("| wheel radius |", "| radius of the wheel |", 1)
    assert edited != text
    assert update_readme(edited) == text  # regenerating restores the model's wording


def test_did_you_mean():
    data = _base()
    data["schemes"]["switching"]["kp_v"] = data["schemes"]["switching"].pop("k_v")
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    assert str(info.value).startswith("cases/x.toml: schemes.switching.kp_v: unknown field (did you mean 'k_v'?)")
    assert did_you_mean("duraton", ["dt", "duration", "method"]) == " (did you mean 'duration'?)"
    assert did_you_mean("zzz", ["dt", "duration"]) == ""
    data = _base()
    data["robot"] = data.pop("robots")
    with pytest.raises(CaseError, match=r"x.toml: robot: unknown field \(did you mean 'robots'\?\)"):
        parse_case(data, "cases/x.toml")


def test_cli_prints_the_schema_and_the_tables():
    runner = CliRunner()
    res = runner.invoke(app, ["cases", "schema"])
    assert res.exit_code == 0
    assert json.loads(res.output) == case_schema()
    res = runner.invoke(app, ["cases", "schema", "--markdown"])
    assert res.exit_code == 0
    assert "### [schemes.switching]" in res.output and "| `k_v` | float | (0, 1e6] | 1/s | required |" in res.output


@pytest.mark.skipif(shutil.which("taplo") is None, reason="taplo (test extra) not installed")
def test_taplo_config_validates_cases(tmp_path):
    ok = subprocess.run(["taplo", "check", *map(str, CASES)], cwd=ROOT, capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    # the shipped config in a copy of the layout, with a misspelt key (cases/ itself is left alone)
    (tmp_path / "cases").mkdir()
    shutil.copy(ROOT / ".taplo.toml", tmp_path / ".taplo.toml")
    shutil.copy(ROOT / "cases" / "case.schema.json", tmp_path / "cases" / "case.schema.json")
    text = (ROOT / "cases" / "two_link_switching.toml").read_text()
    (tmp_path / "cases" / "good.toml").write_text(text)
    (tmp_path / "cases" / "bad.toml").write_text(text.replace("k_v = 3000.0", "kp_v = 3000.0", 1))
    good = subprocess.run(["taplo", "check", "cases/good.toml"], cwd=tmp_path, capture_output=True, text=True)
    assert good.returncode == 0, good.stderr
    res = subprocess.run(["taplo", "check", "cases/bad.toml"], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode != 0
    assert "kp_v" in res.stderr


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (
            lambda c: c["schemes"].update(switchng={"k_v": 1.0}),
            "schemes.switchng: unknown field (did you mean 'switching'?)",
        ),
        (
            lambda c: c["simulation"].update(duraton=10.0),
            "simulation.duraton: unknown field (did you mean 'duration'?)",
        ),
        (
            lambda c: c.update(thresholds={"switching": {"position_error_final": {"mx": 1.0}}}),
            "thresholds.switching.position_error_final.mx: unknown field (did you mean 'max'?)",
        ),
        (
            lambda c: c.update(thresholds={"switchng": {"a": {"max": 1.0}}}),
            "thresholds.switchng: unknown scheme 'switchng' (did you mean 'switching'?)",
        ),
        (lambda c: c["faults"][1].update(sigm=0.5), "faults[1].sigm: unknown field (did you mean 'sigma'?)"),
        (lambda c: c["robots"].update(colour="red"), "robots.colour: unknown field"),
    ],
)
def test_did_you_mean_at_every_depth(mutate, expected):
    data = _base()
    mutate(data)
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    assert str(info.value).startswith(f"cases/x.toml: {expected}"), str(info.value)
    if "did you mean" not in expected:
        assert "did you mean" not in str(info.value)
