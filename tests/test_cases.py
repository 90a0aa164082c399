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
        (lambda c: c.update(schemes={}), "schemes", "no scheme"),
        (lambda c: c.pop("reference"), "reference", "Field required"),
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
