"""Case files: every file in cases/ validates; malformed cases give one clear error."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from ftcreport.cases import load_case, parse_case
from ftcreport.errors import CaseError
from ftcreport.runner import build

CASES = Path(__file__).resolve().parents[1] / "cases"
ALL = sorted(CASES.glob("*.toml"))


@pytest.mark.parametrize("path", ALL, ids=[p.stem for p in ALL])
def test_every_case_validates_and_builds(path):
    case = load_case(path)
    assert case.name == path.stem
    built = build(case)
    built.reference.check(case.simulation.duration, dt=0.5)
    assert built.q0.shape == (case.robots.n + 2,)


def _base() -> dict:
    return tomllib.loads((CASES / "three_link_switching.toml").read_text())


@pytest.mark.parametrize(
    ("mutate", "where", "why"),
    [
        (lambda c: c["faults"][2].update(wheel="4r"), "faults[2].wheel", "'4r' is not a wheel of a 3-robot chain"),
        (lambda c: c["robots"].update(m=-3.0), "robots.m", "must be > 0, got -3.0"),
        (lambda c: c["robots"].update(r=[0.15, 0.0, 0.15]), "robots.r[1]", "must be > 0"),
        (lambda c: c["robots"].update(colour="red"), "robots.colour", "unknown field"),
        (lambda c: c["faults"].reverse(), "faults", "sorted by time"),
        (lambda c: c["simulation"].update(dt="fast"), "simulation.dt", "valid number"),
        (lambda c: c["faults"][0].update(sigma=1.5), "faults[0].sigma", "must be <= 1, got 1.5"),
        (lambda c: c["robots"].update(d=[1.0]), "robots.d", "1 link lengths given, a 3-robot chain needs 2"),
        (lambda c: c["faults"][-1].update(time=500.0), "faults[9].time", "before the end"),
        (lambda c: c["kinematic"].update(kind="two_link"), "kinematic.kind", "needs 2 robots"),
        (
            lambda c: c["schemes"]["switching"].update(patterns=[["1r", "1l"]]),
            "schemes.switching.patterns[0]",
            "uncompensable",
        ),
        (lambda c: c["schemes"].update(run=[]), "schemes", "no scheme"),
        (lambda c: c["schemes"].update(run=["nominal"]), "schemes.switching", "not listed in schemes.run"),
        (lambda c: c["schemes"].update(run=["nominal", "magic"]), "schemes.run[1]", "unknown scheme 'magic'"),
        (lambda c: c.pop("reference"), "reference", "Field required"),
        (lambda c: c.update(expected_status_of={"adaptiv": ["ok"]}), "expected_status_of.adaptiv", "'adaptive'"),
    ],
)
def test_malformed_cases_name_file_field_and_reason(mutate, where, why):
    data = _base()
    mutate(data)
    with pytest.raises(CaseError) as info:
        parse_case(data, "cases/x.toml")
    msg = str(info.value)
    assert msg.startswith(f"cases/x.toml: {where}: "), msg
    assert why in msg, msg
    assert "\n" not in msg


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(CaseError, match="cannot read"):
        load_case(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[robots\nn = 2")
    with pytest.raises(CaseError, match=r"bad\.toml: not valid TOML"):
        load_case(bad)


# ------------------------------------------------------------------ every family by default (issue 21)
def test_every_shipped_case_runs_every_family_or_says_why():
    from ftcreport.families import FAMILIES, not_applicable

    for path in ALL:
        case = load_case(path)
        missing = not_applicable(case)
        for s in FAMILIES:
            assert (getattr(case.schemes, s) is not None) != (s in missing), (path.stem, s)
        # a family is left out only for a stated physical reason, never silently
        for s, why in missing.items():
            assert "k_v" in why and ("unstable" in why or "diverges" in why), (path.stem, s, why)
    assert set(not_applicable(load_case(CASES / "two_link_switching.toml"))) == {"active", "active_ukf"}


def test_default_tables_follow_the_case_and_the_thesis():
    data = _base()  # three links (chained form), nominal/switching/oracle with k_v = 2 and five models
    case = parse_case(data, "x.toml")
    assert case.schemes.adaptive.k_v == 2.0 and case.schemes.adaptive.gamma == 1.0
    assert case.schemes.adaptive.patterns == case.schemes.switching.patterns  # the same model bank
    assert case.schemes.active.Theta == 0.9 and case.schemes.active.k_v == 2.0  # Table 4.2 (chained form)
    assert case.schemes.active_ukf.k_v == 2.0
    two = tomllib.loads((CASES / "two_link_intermittent.toml").read_text())
    two["schemes"] = {"k_v": 7.0}
    c2 = parse_case(two, "y.toml")
    assert c2.schemes.nominal.k_v == c2.schemes.oracle.k_v == 7.0
    assert c2.schemes.active.Theta == 1.6  # Table 4.1 (two links)
    assert c2.schemes.switching.patterns == "all" and c2.schemes.switching.gamma == 10.0
    two["schemes"] = {}
    assert parse_case(two, "z.toml").schemes.nominal.k_v == 10.0  # thesis 3.3.2.3 (k4 = 10)
    two["schemes"] = {"run": ["nominal", "oracle"], "oracle": {"k_v": 4.0}}
    c3 = parse_case(two, "w.toml")
    assert c3.schemes.nominal.k_v == 4.0 and c3.schemes.switching is None and c3.schemes.active_ukf is None
    two["schemes"] = {"run": ["adaptive_frozen"]}
    assert parse_case(two, "v.toml").schemes.adaptive_frozen.k_v == 10.0  # listed: the adaptive defaults
    # parsing the dump of a filled case gives the same case (the batch's workers re-parse it)
    assert parse_case(c3.model_dump(mode="json"), "w.toml") == c3


def test_expected_status_per_scheme():
    data = _base()
    data["expected_status_of"] = {"adaptive": ["ok", "step_unstable"]}
    case = parse_case(data, "x.toml")
    assert case.expected_for("adaptive") == {"ok", "step_unstable"}
    assert case.expected_for("switching") == {"ok"}  # the case-wide expected_status elsewhere
