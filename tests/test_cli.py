"""CLI: help, version, real commands, and honest 'not built yet' commands."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from ftcreport import __version__
from ftcreport.cli import app

runner = CliRunner()


def test_help_lists_design_commands():
    res = runner.invoke(app, ["--help"])
    assert res.exit_code == 0
    for cmd in ("batch", "run", "check", "analyze", "campaign", "report", "cases"):
        assert cmd in res.output


def test_version():
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0
    assert __version__ in res.output


@pytest.mark.parametrize(
    "args",
    [
        ["batch", "cases"],
        ["report"],
        ["check"],
        ["analyze", "x.toml"],
        ["campaign", "x.toml"],
        ["cases", "validate", "cases"],
        ["cases", "new", "foo"],
    ],
)
def test_unbuilt_commands_exit_2_without_traceback(args):
    res = runner.invoke(app, args)
    assert res.exit_code == 2
    assert "not built yet" in res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_patterns_command():
    res = runner.invoke(app, ["patterns", "3"])
    assert res.exit_code == 0
    assert "46 of 64 patterns are compensable" in res.output


def test_patterns_bad_input_is_one_line():
    res = runner.invoke(app, ["patterns", "1"])
    assert res.exit_code == 2
    assert res.output.strip().count("\n") == 0
    assert "at least 2 robots" in res.output


def test_demo_runs_and_reports():
    res = runner.invoke(app, ["demo", "--robots", "2", "--duration", "4", "--fault-time", "2"])
    assert res.exit_code == 0, res.output
    assert "status: ok" in res.output
    assert "singularity margin min" in res.output


def test_demo_bad_parameter_is_one_line():
    res = runner.invoke(app, ["demo", "--dt", "-1"])
    assert res.exit_code == 2
    assert "dt" in res.output and "Traceback" not in res.output


def test_run_command_writes_results(tmp_path):
    import json

    from ftcreport.store import load_timeseries

    case = Path(__file__).resolve().parents[1] / "cases" / "two_link_uncompensable.toml"
    res = runner.invoke(app, ["run", str(case), "--out", str(tmp_path), "--duration", "3", "--scheme", "oracle"])
    assert res.exit_code == 0, res.output
    assert "oracle" in res.output and "Traceback" not in res.output
    m = json.loads((tmp_path / "two_link_uncompensable" / "oracle" / "metrics.json").read_text())
    assert m["status"] == "ok" and m["scheme"] == "oracle" and m["duration"] == 3.0
    assert m["position_error_final"] < 1e-6
    ts = load_timeseries(tmp_path, "two_link_uncompensable", "oracle")
    assert ts["t"][-1] == pytest.approx(3.0) and ts["q"].shape[1] == 4


def test_run_bad_case_is_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[robots]\nn = 1\n")
    res = runner.invoke(app, ["run", str(bad)])
    assert res.exit_code == 2
    assert "bad.toml" in res.output and "Traceback" not in res.output
    assert res.output.strip().count("\n") == 0
