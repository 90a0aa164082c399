"""CLI: help, version, real commands, and honest 'not built yet' commands."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from ftcreport import __version__
from ftcreport.cases import known_schemes
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
    ("args", "why"),
    [
        (["campaign", "x.toml"], "x.toml: cannot read"),
        (["campaign", "cases/two_link_active.toml", "--in-process"], "no [campaign] table"),
    ],
)
def test_campaign_errors_exit_2_in_one_line(args, why, tmp_path):
    res = runner.invoke(app, [*args, "--out", str(tmp_path / "c")])
    assert res.exit_code == 2
    assert why in res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_cases_new_writes_a_valid_template(tmp_path):
    res = runner.invoke(app, ["cases", "new", "mine", "--dir", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "mine.toml").exists()
    again = runner.invoke(app, ["cases", "new", "mine", "--dir", str(tmp_path)])
    assert again.exit_code == 2 and "not overwritten" in again.output
    ok = runner.invoke(app, ["cases", "validate", str(tmp_path)])
    assert ok.exit_code == 0 and "ok" in ok.output


def test_report_without_results_is_one_line(tmp_path):
    res = runner.invoke(app, ["report", "--out", str(tmp_path / "nothing")])
    assert res.exit_code == 2 and "no stored results" in res.output


def test_report_says_what_it_renders_when_piped_and_its_help_what_it_runs(tmp_path):
    """Session 12's new user: `report` (piped) printed nothing for 40-60 s while its help said "no simulation",
    yet a motor page re-runs the analysis's short confirmation simulations.  It now says what it renders, as
    `batch` does, and its help says what runs."""
    out = tmp_path / "r"
    case = Path(__file__).resolve().parents[1] / "cases" / "two_link_sliding_mode.toml"
    res = runner.invoke(app, ["run", str(case), "--scheme", "nominal", "--duration", "2", "--out", str(out)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["report", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "rendering 1 case page(s)" in res.stderr
    assert "no simulation)" not in runner.invoke(app, ["report", "--help"]).output


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


@pytest.mark.parametrize(
    ("value", "words"),
    [("100", "100 s is not before --duration (2 s)"), ("2", "2 s is not before --duration (2 s)"),
     ("nan", "must be a finite time at or after 0 s"), ("-1", "must be a finite time at or after 0 s")],
)  # fmt: skip
def test_demo_fault_time_outside_the_run_is_refused_naming_it(value, words):
    """Session 13's attack: ``demo --duration 2 --fault-time 100`` ran, printed "wheel 2l lost at 100.0 s" and
    the "before" error twice at 2 s (exit 0); ``--fault-time nan`` failed naming "event 0" of a schedule the
    user never wrote.  The fault must be at or after 0 s and before the end, named as --fault-time."""
    res = runner.invoke(app, ["demo", "--robots", "2", "--duration", "2", "--fault-time", value])
    assert res.exit_code == 2, res.output
    assert f"--fault-time: {words}" in res.output and "Traceback" not in res.output, res.output


def test_run_command_writes_results(tmp_path):
    import json

    from ftcreport.storage.store import load_timeseries

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


def test_analyze_json_gives_closed_loop_poles():
    import json

    case = Path(__file__).resolve().parents[1] / "cases" / "two_link_adaptive_circle.toml"
    res = runner.invoke(app, ["analyze", str(case), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.output)
    poles = data["closed_loop_poles"]["adaptive"]
    assert len(poles) == 6 and all(re < 0 for re, _ in poles)
    kin = sorted(complex(r["re"], r["im"]).real for r in data["kinematic_poles"])
    assert kin[0] == pytest.approx(-1.93, abs=0.01)
    assert sum(r["rank"] == 2 for r in data["controllability"]) == 10


def test_cases_validate_lists_every_error_of_a_file(tmp_path):
    """Audit item 2: each field in error on its own line, not the first with '(and 3 more)'."""
    text = (Path(__file__).resolve().parents[1] / "cases" / "two_link_switching.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(
        text.replace("[robots]\n", '[robots]\ncolour = "red"\n', 1)
        .replace('kind = "unicycle"', 'kind = "unicycel"', 1)
        .replace("\ndt = 0.005", "\ndt = -0.005", 1)
    )
    assert bad.read_text().count("unicycel") == 1 and "\ndt = -0.005" in bad.read_text()
    res = runner.invoke(app, ["cases", "validate", str(bad)])
    assert res.exit_code == 2
    assert res.output.splitlines() == [
        f"ftcreport: error: {bad}: robots.colour: unknown field",
        f"ftcreport: error: {bad}: simulation.dt: must be > 0, got -0.005",
        f"ftcreport: error: {bad}: reference.kind: got 'unicycel'; expected one of 'unicycle', 'circle', 'eight', "
        "'line', 'sinusoid' (did you mean 'unicycle'?)",
    ], res.output


def test_cases_validate_caps_the_errors_of_a_file(tmp_path):
    """60 unknown keys: the first 50 lines, then the count of the rest."""
    text = (Path(__file__).resolve().parents[1] / "cases" / "two_link_switching.toml").read_text()
    extra = "".join(f"junk{i:02d} = 1\n" for i in range(60))
    bad = tmp_path / "many.toml"
    bad.write_text(text.replace("[robots]\n", "[robots]\n" + extra, 1))
    res = runner.invoke(app, ["cases", "validate", str(bad)])
    lines = res.output.splitlines()
    assert res.exit_code == 2 and len(lines) == 51, res.output
    assert lines[0] == f"ftcreport: error: {bad}: robots.junk00: unknown field"
    assert lines[49] == f"ftcreport: error: {bad}: robots.junk49: unknown field"
    assert lines[50] == f"ftcreport: error: {bad}: and 10 more error(s)"


KNOWN = "nominal, switching, adaptive, adaptive_frozen, active, active_ukf, oracle"  # ftcreport.schemes.BUILT_IN


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (
            ["run", "cases/two_link_switching.toml", "--scheme", "swiching"],
            "--scheme: got 'swiching'; known schemes: {known}; did you mean 'switching'?",
        ),
        (
            ["run", "cases/two_link_switching.toml", "--scheme", "xyzzy"],
            "--scheme: got 'xyzzy'; known schemes: {known}",
        ),
        (
            ["campaign", "cases/two_link_campaign.toml", "--schemes", "nominal,swiching", "--in-process"],
            "--schemes: got 'swiching'; known schemes: {known}; did you mean 'switching'?",
        ),
        (
            ["coverage", "cases/two_link_campaign.toml", "--schemes", "oracel", "--in-process"],
            "--schemes: got 'oracel'; known schemes: {known}; did you mean 'oracle'?",
        ),
        (
            ["fdi", "cases/two_link_campaign.toml", "--schemes", "activ", "--in-process"],
            "--schemes: got 'activ'; known schemes: {known}; did you mean 'active'?",
        ),
    ],
)
def test_a_mistyped_scheme_option_is_blamed_on_the_option(args, expected, tmp_path):
    """Audit item 4: not 'cases/x.toml: schemes.swiching: not configured in this case'."""
    res = runner.invoke(app, [*args, "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    # the registry at the time of the call: a test's plug-in scheme may be registered in this process
    known = ", ".join(known_schemes())
    assert known.startswith(KNOWN)  # the built-in ones first, in their order
    assert res.output == f"ftcreport: error: {expected.format(known=known)}\n"
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_a_scheme_the_case_does_not_run_says_why(tmp_path):
    res = runner.invoke(app, ["run", "cases/two_link_switching.toml", "--scheme", "active", "--out", str(tmp_path)])
    assert res.exit_code == 2
    line = res.output.strip()
    assert line.startswith(
        "ftcreport: error: --scheme: 'active' is not run on case 'two_link_switching' "
        "(this command runs nominal, switching, adaptive, oracle): the active law closes its k_v = 3000 1/s"
    ), line
    assert "\n" not in line


# ------------------------------------------------------------------ interrupts (audit item 5)
def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_an_interrupt_before_any_run_finished_says_nothing_was_stored(tmp_path, monkeypatch):
    import ftcreport.runner

    monkeypatch.setattr(ftcreport.runner, "run_scheme", _interrupt)  # Ctrl-C during the first scheme
    res = runner.invoke(app, ["run", "cases/two_link_switching.toml", "--out", str(tmp_path), "--no-report", "-q"])
    assert res.exit_code == 130
    assert res.output == "ftcreport: error: interrupted before any run finished; nothing was stored\n"


@pytest.mark.parametrize(
    ("stored", "said"),
    [
        (0, "interrupted before any run finished; nothing was stored"),
        (1, "interrupted; 1 finished run is stored, re-run the same command to resume"),
        (3, "interrupted; 3 finished runs are stored, re-run the same command to resume"),
    ],
)
def test_an_interrupted_batch_says_how_many_runs_it_stored(tmp_path, monkeypatch, stored, said):
    import ftcreport.studies.batch

    def execute(todo, out, jobs, show_progress, res, expected, finish):
        assert len(todo) == 4  # the case's four schemes, none cached
        res.stored = stored  # as _collect counts the runs whose worker stored them
        raise KeyboardInterrupt

    monkeypatch.setattr(ftcreport.studies.batch, "_execute", execute)
    case = "cases/two_link_switching.toml"
    res = runner.invoke(app, ["batch", case, "--out", str(tmp_path), "--duration", "0.2", "-q"])
    assert res.exit_code == 130
    assert res.output == f"ftcreport: error: {said}\n"


def test_a_command_that_stores_nothing_says_only_interrupted(tmp_path, monkeypatch):
    import ftcreport.report.render

    (tmp_path / "o").mkdir()
    monkeypatch.setattr(ftcreport.report.render, "render_all", _interrupt)
    res = runner.invoke(app, ["report", "--out", str(tmp_path / "o")])
    assert res.exit_code == 130 and res.output == "ftcreport: error: interrupted\n"


def test_an_interrupted_campaign_counts_its_samples(tmp_path, monkeypatch):
    import ftcreport.studies.cluster

    monkeypatch.setattr(ftcreport.studies.cluster, "execute", _interrupt)
    args = ["campaign", "cases/two_link_campaign.toml", "-n", "2", "--in-process", "--out", str(tmp_path / "c"), "-q"]
    res = runner.invoke(app, args)
    assert res.exit_code == 130
    assert res.output == "ftcreport: error: interrupted before any sample finished; nothing was stored\n"


# ------------------------------------------------------------------ help text (audit item 6)
def _commands():
    """(command path, click command) of every command of the CLI, groups included."""
    import typer.main

    def walk(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, [*path, name])

    return list(walk(typer.main.get_command(app), []))


COMMANDS = [(p, c) for p, c in _commands() if not hasattr(c, "commands")]


@pytest.mark.parametrize(("path", "cmd"), COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_every_command_has_an_example_that_parses(path, cmd):
    """The README says `ftcreport COMMAND --help` gives an example: it names files that exist, options that do."""
    import shlex

    root = Path(__file__).resolve().parents[1]
    res = runner.invoke(app, [*path, "--help"])
    assert res.exit_code == 0
    examples = [ln.strip().removeprefix("Example: ") for ln in res.output.splitlines() if "Example: " in ln]
    assert len(examples) == 1, res.output
    argv = shlex.split(examples[0].split(" > ")[0])  # without a shell redirection
    assert argv[: 1 + len(path)] == ["ftcreport", *path], argv
    args = argv[1 + len(path) :]
    cmd.make_context(" ".join(argv[: 1 + len(path)]), list(args))  # options and arguments parse
    for a in args:
        if a.endswith((".toml", "/")) and not a.startswith("reports"):  # inputs (reports/ is output)
            assert (root / a).exists(), (examples[0], a)


def test_help_keeps_units_and_table_names():
    """Typer renders help as rich markup, where '[s]' is a style tag: every bracket of a help text is shown."""
    import re

    for path, cmd in _commands():
        shown = " ".join(runner.invoke(app, [*path, "--help"]).output.replace("│", " ").split())
        for text in [cmd.help or "", *(getattr(p, "help", None) or "" for p in cmd.params)]:
            for bracket in re.findall(r"\\?(\[[^\]]*\])", text):
                assert " ".join(bracket.split()) in shown, (path, bracket)


def test_help_shows_no_doubled_percent():
    """Click does not %-format help texts: '1 %%' was printed as written (run --verify-dt)."""
    for path, cmd in _commands():
        shown = runner.invoke(app, [*path, "--help"]).output
        assert "%%" not in shown, (path, [ln for ln in shown.splitlines() if "%%" in ln])
        for text in [cmd.help or "", *(getattr(p, "help", None) or "" for p in cmd.params)]:
            assert "%%" not in text, (path, text)


ROOT = Path(__file__).resolve().parents[1]


def test_cases_validate_without_a_path_descends_into_cases(monkeypatch):
    """Issue 35 item 8: 'cases validate' with no path was an error, and a directory was not searched
    below its top level (cases/motors was left out)."""
    monkeypatch.chdir(ROOT)
    res = runner.invoke(app, ["cases", "validate"])
    assert res.exit_code == 0, res.output
    checked = {line.split()[-1] for line in res.output.splitlines() if line.startswith("ok")}
    expected = {str(p.relative_to(ROOT)) for p in (ROOT / "cases").rglob("*.toml")}
    assert checked == expected and any("cases/motors/" in p for p in checked)


@pytest.mark.parametrize("command", [[], ["batch"], ["run"], ["cases", "validate"], ["coverage"], ["report"]])
def test_help_shows_flags_without_a_type(command):
    """Issue 35 item 8: typer printed every flag as '--force <bool>'."""
    res = runner.invoke(app, [*command, "--help"], terminal_width=120)
    assert res.exit_code == 0, res.output
    assert "<bool>" not in res.output
    assert "--help" in res.output


def test_progress_bars_are_named_after_their_command(monkeypatch):
    """Issue 35 item 8: coverage and FDI progress bars said 'campaign'."""
    import io

    import rich.progress
    from rich.console import Console

    from ftcreport import campaign

    shown = {}

    class Captured(rich.progress.Progress):
        def __init__(self, *columns, **kw):
            self.buf = io.StringIO()
            super().__init__(*columns, **kw | {"console": Console(file=self.buf, width=150, force_terminal=True)})

        def stop(self):
            super().stop()
            shown[self.kind] = self.buf.getvalue()

    monkeypatch.setattr(rich.progress, "Progress", Captured)
    for kind, unit in (("coverage", "fault onsets/min"), ("fdi", "traces/min"), ("campaign", "samples/min")):
        Captured.kind = kind
        with campaign._progress(True, 4, kind) as bar:
            bar(3, 1)
        assert kind in shown[kind] and unit in shown[kind] and "4/4" in shown[kind], shown[kind]
        if kind != "campaign":
            assert "campaign" not in shown[kind]


def test_the_run_table_reads_wall_time_per_simulated_second_without_compiling():
    """The terminal's wall/sim-s, like the case page's schemes table, leaves out compiling (or loading)
    the engine's loop: a first run that spent 9 s of its 10 s compiling 10 s of simulated time shows 0.100."""
    from ftcreport.cli import _table

    row = {"scheme": "nominal", "status": "ok", "phases": [], "wall_time": 10.0, "compile_time": 9.0,
           "t_end": 10.0, "duration": 10.0}  # fmt: skip
    assert _table([row]).splitlines()[-1].split()[-1] == "0.100"
    assert _table([row | {"compile_time": None}]).splitlines()[-1].split()[-1] == "1.000"


def test_analyze_reads_a_batchs_stored_runs_and_refuses_a_directory_that_is_not_one(tmp_path):
    """Round-3 audit: ``analyze CASE --results DIR`` exited 3 on every input (an ImportError: the cache-key
    reader it called had been replaced by store.check_run).  A batch's current runs give switching's applied
    model per phase ("run (...)"); a run of another case content is not used, and says so; a directory that
    holds no results is refused with exit 2, naming it."""
    import json
    import tomllib

    import tomli_w

    raw = tomllib.loads((Path(__file__).resolve().parents[1] / "cases" / "two_link_switching.toml").read_text())
    raw["faults"] = raw["faults"][:1]  # its first fault (20 s) in a 25 s run
    raw["simulation"]["duration"] = 25.0
    raw.pop("claims", None)
    case = tmp_path / "two_link_switching.toml"
    case.write_text(tomli_w.dumps(raw))
    out = tmp_path / "results"
    res = runner.invoke(app, ["batch", str(case), "--out", str(out), "-q"])
    assert res.exit_code in (0, 1), res.output  # 1: a claim of the full-length case may not hold in 25 s
    res = runner.invoke(app, ["analyze", str(case), "--json", "--no-confirm", "--results", str(out)])
    assert res.exit_code == 0, res.output
    phases = json.loads(res.stdout)["phases"]["switching"]
    assert all(p["applied_from"].startswith("run (") for p in phases), [p["applied_from"] for p in phases]

    raw["simulation"]["duration"] = 24.0  # another content: not its runs
    case.write_text(tomli_w.dumps(raw))
    res = runner.invoke(app, ["analyze", str(case), "--json", "--no-confirm", "--results", str(out)])
    assert res.exit_code == 0, res.output
    phases = json.loads(res.stdout)["phases"]["switching"]
    assert not any(p["applied_from"].startswith("run (") for p in phases)
    assert "not current" in res.stderr and "switching" in res.stderr

    for bad in (tmp_path / "nowhere", case):
        res = runner.invoke(app, ["analyze", str(case), "--no-confirm", "--results", str(bad)])
        assert res.exit_code == 2, res.output
        assert str(bad.name) in res.output and "Traceback" not in res.output
