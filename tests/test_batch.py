"""batch, check, report: the product's edges."""

from __future__ import annotations

import json
import re
import shutil
import tomllib
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from ftcreport.cli import app
from ftcreport.studies.batch import run_batch

CASES = Path(__file__).resolve().parents[1] / "cases"
runner = CliRunner()


@pytest.fixture(scope="module")
def batch_dir(tmp_path_factory):
    """Every case of cases/ through every scheme at a 2 s duration override."""
    out = tmp_path_factory.mktemp("reports")
    res = run_batch([CASES], out, jobs=2, duration=2.0, show_progress=False)
    return out, res


def test_every_case_runs_through_every_scheme(batch_dir):
    from ftcreport.evaluation.families import FAMILIES

    out, res = batch_dir
    names = {p.stem for p in CASES.glob("*.toml")}
    assert set(res.cases) == names and not res.case_errors
    assert not res.failed_runs, res.failed_runs
    for name in names:
        rec = json.loads((out / name / "case.json").read_text())
        # every family ran, or the record says in one line why it cannot apply (issue 21)
        assert set(FAMILIES) <= set(rec["schemes"]) | set(rec["not_run"]), name
        assert all(len(why) > 20 and "\n" not in why for why in rec["not_run"].values()), rec["not_run"]
        for s in rec["schemes"]:
            m = json.loads((out / name / s / "metrics.json").read_text())
            assert m["status"] == "ok" and m["duration"] == 2.0
            for key in (
                "position_error_max",
                "position_error_rms",
                "position_error_final",
                "heading_error_max",
                "heading_error_final",
                "recovery_time_max",
                "torque_peak",
                "torque_rms",
                "saturation_fraction",
                "singularity_margin_min",
                "wall_time",
                "phases",
            ):
                assert key in m, (name, s, key)
    assert (out / "index.html").exists()
    assert all((out / n / "index.html").exists() for n in names)


def test_every_run_writes_exactly_the_metrics_validation_knows(batch_dir):
    """ftcreport.evaluation.metrics.METRICS is the list case validation checks threshold and claim names against
    (issue 34 item 12): a run of every scheme writes exactly its entries beside its identity."""
    from ftcreport.cases import load_case
    from ftcreport.evaluation.metrics import metrics_of
    from ftcreport.runner import _identity

    out, _ = batch_dir
    seen = set()
    for rec in sorted(out.glob("*/case.json")):
        case = load_case(CASES / f"{rec.parent.name}.toml")
        for s in json.loads(rec.read_text())["schemes"]:
            m = json.loads((out / rec.parent.name / s / "metrics.json").read_text())
            written = set(m) - set(_identity(case, s)) - {"status", "reason", "engine", "null_reasons"}
            optional = {"verify_dt"} | ({"requirements"} - set(m))  # run --verify-dt; cases with [[requirements]]
            assert written == set(metrics_of(s)) - optional, (rec.parent.name, s, written ^ set(metrics_of(s)))
            seen.add(s)
    assert {"nominal", "oracle", "switching", "adaptive", "adaptive_frozen", "active", "active_ukf"} <= seen


def test_rerun_simulates_nothing(batch_dir):
    out, first = batch_dir
    page = out / "two_link_uncompensable" / "index.html"
    before = page.stat().st_mtime_ns
    again = run_batch([CASES], out, jobs=2, duration=2.0, show_progress=False)
    assert again.simulated == []
    assert sorted(again.cached) == sorted(first.simulated)
    assert page.stat().st_mtime_ns == before  # a warm batch does not re-render an unchanged page
    forced = run_batch(
        [CASES / "two_link_uncompensable.toml"], out, jobs=1, duration=2.0, force=True, show_progress=False
    )
    assert len(forced.simulated) == 6  # every family (issue 21)
    assert page.stat().st_mtime_ns > before  # new runs: the page is rendered again


def test_changed_case_is_resimulated(tmp_path):
    src = tmp_path / "c.toml"
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["schemes"]["run"] = ["nominal", "switching", "oracle"]  # narrowed: three runs
    src.write_text(tomli_w.dumps(data))
    out = tmp_path / "r"
    assert len(run_batch([src], out, jobs=1, duration=1.0, show_progress=False).simulated) == 3
    data["schemes"]["oracle"]["k_v"] = 6.0
    src.write_text(tomli_w.dumps(data))
    res = run_batch([src], out, jobs=1, duration=1.0, show_progress=False)
    assert len(res.simulated) == 3  # the key hashes the whole case content


def test_broken_case_does_not_stop_the_batch(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    shutil.copy(CASES / "two_link_uncompensable.toml", cases / "good.toml")
    (cases / "broken.toml").write_text('[robots]\nn = 3\nd = 1.0\n[reference]\nkind = "circle"\n')
    out = tmp_path / "reports"
    res = runner.invoke(app, ["batch", str(cases), "--out", str(out), "--duration", "1", "--jobs", "1", "-q"])
    assert res.exit_code == 2  # a refused case file is bad input; the others ran
    assert "broken.toml" in res.output and "Traceback" not in res.output
    assert (out / "good" / "index.html").exists()
    assert json.loads((out / "good" / "oracle" / "metrics.json").read_text())["status"] == "ok"
    rec = json.loads((out / "broken" / "case.json").read_text())
    assert rec["status"] == "error" and "broken.toml" in rec["error"]
    index = (out / "index.html").read_text()
    assert "broken" in index and "good" in index


def test_check_fails_on_an_impossible_threshold(tmp_path):
    src = tmp_path / "t.toml"
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["simulation"]["duration"] = 2.0
    data["faults"] = []
    data["thresholds"] = {
        "oracle": {"position_error_final": {"max": 1e-3}, "torque_peak": {"max": 1e-9}},
    }
    src.write_text(tomli_w.dumps(data))
    junit = tmp_path / "junit.xml"
    out = tmp_path / "r"
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--junit", str(junit), "-q"])
    assert res.exit_code == 1, res.output
    assert "FAIL" in res.output and "torque_peak" in res.output
    root = ET.parse(junit).getroot()
    runs = [tc for tc in root.iter("testcase") if tc.get("name") == "status"]  # one per run (issue 34)
    assert root.get("failures") == "1" and root.get("tests") == str(2 + len(runs)) and len(runs) >= 2
    failing = [tc for tc in root.iter("testcase") if tc.find("failure") is not None]
    assert [tc.get("name") for tc in failing] == ["torque_peak"]
    assert "expected <= 1e-09" in failing[0].find("failure").get("message")


def test_check_passes_and_exit_2_on_bad_case(tmp_path):
    src = tmp_path / "ok.toml"
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["simulation"]["duration"] = 2.0
    data["faults"] = [f for f in data["faults"] if f["time"] < 2.0]
    data["thresholds"] = {"oracle": {"position_error_final": {"max": 1e-6}}}
    src.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["check", str(src), "--out", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 0, res.output
    assert "1/1 thresholds hold" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[robots]\nn = 2\n")
    res = runner.invoke(app, ["check", str(bad), "--out", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 2


def test_report_rerenders_from_stored_results(batch_dir):
    out, _ = batch_dir
    page = out / "two_link_switching" / "index.html"
    page.unlink()
    res = runner.invoke(app, ["report", "--out", str(out)])
    assert res.exit_code == 0
    html = page.read_text()
    assert "No faults." in html  # the 2 s override drops the events at 20 s and later
    # no repeated content: the four schemes share the matched law, so their pole table appears once
    poles = html[html.index('id="poles"') : html.index("</table>", html.index('id="poles"'))]
    assert poles.count("nominal, switching, adaptive, oracle") == 6  # six poles (z1..z4, eta_e), each row once
    assert all(f">{s}<" not in poles for s in ("nominal", "switching", "adaptive", "oracle"))
    for marker in (
        'id="schemes"',
        'id="phases"',
        'id="fig-paths"',
        'id="fig-errors"',
        'id="fig-torques"',
        'id="fig-switching"',
        'id="fig-articulation"',
        'id="controllability"',
        'id="poles"',  # a two-link case on a constant-velocity reference: linearized poles shown
        'id="verdict"',
        'id="replay"',
        'class="not-run"',  # active and active_ukf cannot apply at k_v = 3000: one line each says why
        "<svg",
        "Provenance",
    ):
        assert marker in html, marker


# ------------------------------------------------------------------ fuzzed malformed cases
BASE = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
_paths = [
    ("robots", "n"),
    ("robots", "m"),
    ("robots", "d"),
    ("reference", "kind"),
    ("reference", "radius"),
    ("simulation", "dt"),
    ("simulation", "duration"),
    ("kinematic", "kind"),
    ("kinematic", "k1"),
    ("schemes", "oracle"),
]
_bad_values = st.one_of(
    st.just(-1.0),
    st.just(0),
    st.just("x"),
    st.just([]),
    st.just({"q": 1}),
    st.just(True),
    st.text(max_size=5),
    st.floats(max_value=-1e-9, allow_nan=False),
    st.just(1e9),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(_paths), value=_bad_values, extra=st.booleans())
def test_fuzzed_bad_cases_give_one_clear_error(tmp_path, where, value, extra):
    data = json.loads(json.dumps(BASE))
    table, key = where
    data[table][key] = value
    if extra:
        data["robots"]["colour"] = "red"
    path = tmp_path / "fz.toml"
    path.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["cases", "validate", str(path)])
    if res.exit_code == 0:  # some values happen to be valid (e.g. a big radius)
        assert "ok" in res.output
        return
    assert res.exit_code == 2
    lines = [ln for ln in res.output.splitlines() if ln.startswith("ftcreport: error:")]
    # one line per field in error (a table given for a value can hold several), each 'file: field: reason'
    assert lines and len(set(lines)) == len(lines), res.output
    assert all(re.match(rf"ftcreport: error: {re.escape(str(path))}: \S+: \S", ln) for ln in lines), res.output
    assert "Traceback" not in res.output
    assert not extra or f"ftcreport: error: {path}: robots.colour: unknown field" in lines


@pytest.mark.parametrize(
    "text",
    ["", "not toml at all [", "[robots]\nn = 2\n", '[[faults]]\ntime = "soon"\n', "robots = 3\n"],
)
def test_garbage_files_give_one_line_per_error_and_exit_2(tmp_path, text):
    path = tmp_path / "g.toml"
    path.write_text(text)
    res = runner.invoke(app, ["cases", "validate", str(path)])
    assert res.exit_code == 2
    lines = res.output.splitlines()
    assert lines and all(ln.startswith(f"ftcreport: error: {path}: ") for ln in lines), res.output
    assert len(set(lines)) == len(lines) and "Traceback" not in res.output


def test_expected_status_keeps_a_designed_loss_from_failing_the_batch(tmp_path):
    """A case built to lose tracking declares it; without the declaration the same run fails the batch."""
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["faults"] = [{"time": 1.0, "wheel": "1r"}, {"time": 2.0, "wheel": "1l"}]
    data["simulation"]["duration"] = 30.0
    data["schemes"] = {"run": ["oracle"], "oracle": {"k_v": 5.0}}
    outcomes = {}
    for expected in (["ok"], ["ok", "singular", "diverged"]):
        data["expected_status"] = expected
        src = tmp_path / f"loss{len(expected)}.toml"
        src.write_text(tomli_w.dumps(data))
        res = run_batch([src], tmp_path / "r", jobs=1, show_progress=False)
        m = json.loads((tmp_path / "r" / src.stem / "oracle" / "metrics.json").read_text())
        assert m["status"] in ("singular", "diverged"), m["status"]
        outcomes[len(expected)] = len(res.failed_runs)
    assert outcomes == {1: 1, 3: 0}
    # issue 35 item 5: the index counts the stop the case expects apart from the one it does not
    html = (tmp_path / "r" / "index.html").read_text()
    counts = html[html.index('id="counts"') : html.index("</p>", html.index('id="counts"'))]
    assert "1 stopped as their case expects" in counts and "1 stopped or failed unexpectedly" in counts
    assert "(expected)" in html  # the matrix marks the expected stop


def test_manifests_merge_across_batches_and_the_index_links_every_page(tmp_path):
    """Issue 35 items 5 and 8: a second batch into the same --out overwrote manifest.json with its own
    cases while the index showed every case; other pages under --out (campaign, coverage, FDI) were not
    linked."""
    data = tomllib.loads((CASES / "two_link_uncompensable.toml").read_text())
    data["schemes"] = {"run": ["oracle"], "oracle": data["schemes"]["oracle"]}
    out = tmp_path / "r"
    for name in ("first", "second"):
        (tmp_path / f"{name}.toml").write_text(tomli_w.dumps(data))
        run_batch([tmp_path / f"{name}.toml"], out, jobs=1, duration=1.0, show_progress=False, render=False)
    man = json.loads((out / "manifest.json").read_text())
    assert set(man["cases"]) == {"first", "second"}
    assert sorted(r["case"] for r in man["runs"]) == ["first", "second"]
    assert [b["cases"] for b in man["batches"]] == [["first"], ["second"]]
    # the first case again: its entry is replaced, nothing doubles
    run_batch([tmp_path / "first.toml"], out, jobs=1, duration=1.0, show_progress=False, render=False)
    man = json.loads((out / "manifest.json").read_text())
    assert sorted(r["case"] for r in man["runs"]) == ["first", "second"]
    assert [b["cases"] for b in man["batches"]] == [["second"], ["first"]]
    # a page another command wrote under --out is found and linked from the index
    other = out / "campaigns" / "x"
    other.mkdir(parents=True)
    (other / "index.html").write_text("<html><head><title>ftcreport campaign: x</title></head></html>")
    from ftcreport.report.render import render_index

    html = render_index(out).read_text()
    assert '<a href="campaigns/x/index.html">campaign: x</a>' in html and 'id="batches"' in html


def test_every_thesis_case_page_has_its_claims_section(batch_dir):
    """Issue 18: each thesis case's page shows a 'Thesis claim' block with one row per claim of its file."""
    from ftcreport.cases import load_case

    out, _ = batch_dir
    thesis = [p for p in CASES.glob("*.toml") if load_case(p).description.startswith("Thesis")]
    assert len(thesis) == 7
    for path in thesis:
        html = (out / path.stem / "index.html").read_text()
        assert 'id="thesis-claim"' in html, path.stem
        for c in load_case(path).claims:
            assert f'id="claim-{c.id}"' in html, (path.stem, c.id)
    # the thesis figures of the active schemes (Figs 4.5-4.9, 4.14-4.18)
    html = (out / "two_link_active" / "index.html").read_text()
    for fig in ("velocities", "active-control", "active-path", "active_ukf-control", "active_ukf-path"):
        assert f'id="fig-{fig}"' in html, fig


def test_a_cold_batch_starts_every_loop_in_the_first_wave():
    # issue 20 item 3: the workers compile distinct loops side by side (control/*_law.py' two dispatchers,
    # each plug-in's, each motor/sampled variant) before any loop's second run
    from ftcreport.cases import configured_schemes, load_case
    from ftcreport.studies.batch import _compile_first, _loop_of

    cases = [load_case(CASES / f"{n}.toml") for n in ("two_link_active", "two_link_sliding_mode")]
    cases.append(load_case(CASES / "motors" / "two_link_active_motors.toml"))
    todo = [(c, "", s, "") for c in cases for s in configured_schemes(c)]
    ordered = _compile_first(todo)
    assert sorted(map(id, ordered)) == sorted(map(id, todo))  # a reordering, nothing lost
    keys = [_loop_of(c, s) for c, _, s, _ in ordered]
    distinct = list(dict.fromkeys(keys))
    assert keys[: len(distinct)] == distinct  # every distinct loop once, before any repeat
    laws = {k[0][0] for k in distinct}  # each loop by its law (the registry's "module:function")
    assert {
        "ftcreport.control.passive_law:passive_law",
        "ftcreport.control.active_law:active_law",
        "ftcreport_plugin_sliding_mode:law",
    } == laws
    assert any(k[1] for k in distinct)  # the motor case's loops are a variant of their own
    rest = [(c.name, s) for c, _, s, _ in ordered[len(distinct) :]]
    assert rest == [(c.name, s) for c, _, s, _ in todo if (c.name, s) in set(rest)]  # the rest keeps its order


def test_batch_reports_its_workers_peak_memory(tmp_path):
    """The workers' peak resident memory reaches the CLI line, the batch manifest and the index page.

    Bounds: a worker imports numpy and numba and runs compiled code (``import numba`` alone is about
    100 MB resident here), so a real reading is above 50 MB; a 0.2 s two-link run cannot need 4 GB.
    A KiB/bytes/MB mix-up would be off by 1024x and fall outside.  (Not a memory target: that is
    measured by benchmarks/run.py.)
    """
    out = tmp_path / "out"
    case = CASES / "two_link_switching.toml"
    res = runner.invoke(app, ["batch", str(case), "--out", str(out), "--duration", "0.2", "--jobs", "1", "--quiet"])
    assert res.exit_code == 0, res.output
    line = next(x for x in res.output.splitlines() if "worker peak memory" in x)
    printed = float(line.split("worker peak memory ")[1].split(" MB")[0])
    memory = json.loads((out / "manifest.json").read_text())["memory"]
    peak = memory["worker_peak_rss_mb"]
    assert 50.0 < peak < 4096.0
    assert abs(printed - peak) <= 0.5  # printed rounded to the MB
    assert memory["workers"] == 1 and memory["runs_measured"] >= 1
    runs = json.loads((out / "manifest.json").read_text())["runs"]
    per_run = [r.get("worker_peak_rss_mb") for r in runs]
    assert all(p is not None and 50.0 < p <= peak for p in per_run)  # one worker: its peak so far, at most the max
    assert f"{peak:.0f} MB" in (out / "index.html").read_text()
    # a warm batch starts no worker: nothing measured, and the line says nothing about memory
    again = runner.invoke(app, ["batch", str(case), "--out", str(out), "--duration", "0.2", "--jobs", "1", "--quiet"])
    assert again.exit_code == 0 and "worker peak memory" not in again.output
    assert json.loads((out / "manifest.json").read_text())["memory"]["worker_peak_rss_mb"] is None


def test_peak_rss_is_this_process_high_water_mark_in_mb():
    import resource

    from ftcreport.studies.batch import peak_rss_mb

    peak = peak_rss_mb()
    # ru_maxrss (KiB on Linux) also counts what the process had before its exec, so it is at least VmHWM
    assert 20.0 < peak <= resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 + 1.0


# ------------------------------------------------------------------ the progress display (audit item 1)
def _terminal(height: int = 24):
    import io

    from rich.console import Console

    return Console(file=io.StringIO(), force_terminal=True, width=100, height=height, color_system=None)


def _screen(display, height: int = 24) -> list[str]:
    """One frame of the display as the terminal shows it."""
    con = _terminal(height)
    con.print(display)
    return con.file.getvalue().rstrip("\n").splitlines()


def _runs(display, n: int) -> None:
    for i in range(n):
        display.durations[(f"case{i // 4}", f"s{i % 4}")] = 20.0  # every run 20 s of simulated time


def test_the_display_is_one_overall_bar_and_the_active_runs():
    from ftcreport.studies.display import BatchDisplay

    d = BatchDisplay.make(98, True, _terminal())
    _runs(d, 98)
    d.advanced("case0", "s0", 0.0)  # started (compiling)
    d.advanced("case0", "s1", 5.0)
    d.advanced("case0", "s0", 10.0)
    d.finished("case0", "s0")
    d.advanced("case0", "s0", 20.0)  # a report that arrives after the run's result: ignored
    d.advanced("case0", "s2", 1.0)
    lines = _screen(d)
    assert len(lines) == 3, lines  # the overall bar and the two active runs; no line for the 96 others
    assert lines[0].startswith("batch ") and " 1/98 runs " in lines[0] and " ETA " in lines[0], lines[0]
    assert lines[1].startswith("  case0 / s1 ") and lines[1].endswith(" 25 % of 20 s"), lines[1]
    assert lines[2].startswith("  case0 / s2 ") and lines[2].endswith("  5 % of 20 s"), lines[2]
    # the bar counts the finished run and the active ones' fractions: 1 + 5/20 + 1/20
    assert d.overall.tasks[0].completed == pytest.approx(1.30, abs=1e-12)


def test_the_display_fits_a_24_row_terminal():
    from ftcreport.studies.display import BatchDisplay

    d = BatchDisplay.make(98, True, _terminal())
    _runs(d, 98)
    for i in range(40):  # 40 workers busy at once
        d.advanced(f"case{i // 4}", f"s{i % 4}", 2.0)
    lines = _screen(d)
    assert len(lines) == 21, lines  # overall, 19 runs, the count of the others: 24 rows less 3
    assert lines[-1] == "  ... and 21 more running"
    assert " 0/98 runs " in lines[0]


def test_no_display_off_a_terminal_or_when_quiet():
    import io

    from rich.console import Console

    from ftcreport.studies.display import BatchDisplay

    assert BatchDisplay.make(4, True, Console(file=io.StringIO())).live is None  # piped stderr, a CI log
    assert BatchDisplay.make(4, False, _terminal()).live is None  # --quiet
    d = BatchDisplay.make(4, True, None)  # pytest's stderr is no terminal
    assert d.live is None
    with d:
        d.advanced("c", "s", 0.0)
        d.finished("c", "s")


def test_a_piped_batch_prints_no_bars(tmp_path):
    out = tmp_path / "o"
    case = CASES / "two_link_switching.toml"
    res = runner.invoke(app, ["batch", str(case), "--out", str(out), "--duration", "0.2", "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert "━" not in res.output and "two_link_switching / " not in res.output, res.output
    # --duration's warning (it drops the case's faults), stderr's one notice, the summary: nothing of the display
    lines = [ln for ln in res.output.splitlines() if not ln.startswith("ftcreport: warning: ")]
    assert "--duration 0.2: drops faults[0]" in res.output
    assert len(lines) == 2 and lines[0].startswith("rendering 1 case page(s)"), res.output
    assert lines[1].startswith("1 case(s): 4 run(s) simulated, 0 cached, 0 failed"), res.output


def test_batch_workers_leave_ctrl_c_to_the_batch_process():
    """Ctrl-C reaches the whole process group: a worker still importing printed a KeyboardInterrupt
    traceback.  The workers ignore SIGINT (the batch process terminates them); its own handler stays."""
    import multiprocessing as mp
    import signal

    from ftcreport.studies.batch import _Pool

    before = signal.getsignal(signal.SIGINT)
    with _Pool(max_workers=1, mp_context=mp.get_context("spawn")) as pool:
        assert pool.submit(signal.getsignal, signal.SIGINT).result(timeout=120) == signal.SIG_IGN
    assert signal.getsignal(signal.SIGINT) is before


def test_index_of_a_fault_free_case_shows_fault_metrics_not_applicable(tmp_path):
    """W3 (newuser12): the index of a batch of two_link_campaign (no [[faults]]) gave every scheme
    "wins: max error after faults 1 / 1" and "wins: worst recovery time 1 / 1", and named winners of
    "max error after faults" while its matrix showed "-" for it.  Without a fault these metrics do not
    apply: the scoreboard, the winners and the matrix all say n/a with the reason, and nobody wins them."""
    data = tomllib.loads((CASES / "two_link_campaign.toml").read_text())
    assert "faults" not in data
    data["schemes"]["run"] = ["nominal", "switching", "oracle"]
    data.pop("campaign", None)
    (tmp_path / "calm.toml").write_text(tomli_w.dumps(data))
    out = tmp_path / "r"
    run_batch([tmp_path / "calm.toml"], out, jobs=1, duration=15.0, show_progress=False, render=False)
    from ftcreport.report.render import render_index

    html = render_index(out).read_text()
    board = html[html.index('id="scoreboard"') : html.index("</table>", html.index('id="scoreboard"'))]
    rows = {r.split("</td>")[0]: r for r in board.split('<tr><td class="l">')[1:]}
    for s in ("nominal", "switching"):
        cells = [re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", rows[s])]
        # HEADLINE's order: after faults, final error, recovery, peak torque after the fault, energy...
        assert cells[0] == cells[2] == cells[3] == "n/a (no fault)", (s, cells)
        assert cells[1] in ("0 / 1", "1 / 1"), (s, cells)  # the final error is still contested
    winners = html[html.index('id="cases"') : html.index("</table>", html.index('id="cases"'))]
    cells = re.findall(r'<td class="l">(.*?)</td>', winners)
    na = '<span class="muted" title="not applicable: no fault in the run">n/a (no fault)</span>'
    # case, then the seven metrics in HEADLINE's order, then the verdict
    assert cells[1] == cells[3] == cells[4] == na, cells  # detection delay: no active scheme ran
    assert "nominal" not in cells[1] and "never leave" not in cells[8]
    assert cells[8].startswith("With no fault in the run, the fault-response metrics do not apply; ")
    matrix = html[html.index('id="matrix"') :]
    assert matrix.count(na) == 3  # max after faults of nominal, switching and the oracle


def test_a_directory_s_subdirectories_are_named_not_silently_skipped(tmp_path):
    """``batch DIR`` reads DIR's own case files; case files in its subdirectories (cases/motors/ beside
    cases/) are not run, and the batch says so, naming them and how to run them (session 12's new user:
    ``batch mycases`` left ``mycases/motors/`` out without a word)."""
    from ftcreport.studies.batch import discover

    (tmp_path / "motors" / "deep").mkdir(parents=True)
    for rel in ("a.toml", "motors/b.toml", "motors/c.toml", "motors/deep/d.toml"):
        (tmp_path / rel).write_text("")
    (tmp_path / "empty").mkdir()
    notes: list[str] = []
    found = discover([tmp_path], on_note=notes.append)
    assert found == [tmp_path / "a.toml"]
    assert len(notes) == 1, notes
    assert "3 case files in subdirectories" in notes[0]
    assert "motors/: 2" in notes[0] and "motors/deep/: 1" in notes[0]
    assert "empty" not in notes[0]
    notes.clear()
    assert discover([tmp_path / "motors" / "deep"], on_note=notes.append) == [tmp_path / "motors/deep/d.toml"]
    assert notes == []  # nothing below it


_SMALL = """description = "small"
[robots]
n = 2
d = 1.0
[reference]
kind = "circle"
radius = 5.0
speed = 0.5
[initial]
x = 0.2
[[faults]]
time = 1.0
wheel = "1l"
[kinematic]
kind = "two_link"
k1 = 10.0
k2 = 2.0
k3 = 0.5
[schemes]
run = ["nominal", "oracle"]
[schemes.nominal]
k_v = 5.0
[schemes.oracle]
k_v = 5.0
[simulation]
dt = 0.01
duration = 2.0
log_every = 5
[thresholds.oracle]
position_error_final = { max = 0.5 }
"""


def _index_counts(html: str) -> str:
    """The index's headline counts (its ``#counts`` paragraph) as text, whitespace collapsed."""
    start = html.index('id="counts"')
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", html[start : html.index("</p>", start)]))


def test_the_index_leaves_out_the_old_runs_of_a_case_whose_file_the_last_batch_rejected(tmp_path):
    """Attack 13 break 04: after a batch of two cases, one case file made invalid (k_v = -5) and batched
    again (exit 2), the index still read "2 case(s), 4 run(s): 4 completed ...; thresholds: 2 hold", with
    the rejected case's old "ok 1/1 thresholds" badge and a winners row.  Its stored runs are of an earlier
    version of the file: the headline, thresholds and winners leave them out, its rows say so, and they
    stay stored and reachable from its page."""
    cases = tmp_path / "cases"
    cases.mkdir()
    for name in ("alpha", "beta"):
        (cases / f"{name}.toml").write_text(_SMALL)
    out = tmp_path / "rep"
    args = ["batch", str(cases), "--out", str(out), "--jobs", "1", "-q"]
    assert runner.invoke(app, args).exit_code == 0
    (cases / "alpha.toml").write_text(_SMALL.replace("k_v = 5.0", "k_v = -5.0"))
    res = runner.invoke(app, args)
    assert res.exit_code == 2 and "alpha.toml" in res.output, res.output
    html = (out / "index.html").read_text()
    counts = _index_counts(html)
    assert "2 run(s): 2 completed" in counts and "thresholds: 1 hold" in counts, counts
    assert "1 case file(s) rejected by the last batch" in counts and "2 stored run(s) of earlier" in counts, counts
    stale = "case file rejected by the last batch that read it: its stored runs are from an earlier version of the file"
    winners = html[html.index('id="cases"') : html.index("</table>", html.index('id="cases"'))]
    alpha = next(r for r in winners.split("<tr>") if 'href="alpha/index.html"' in r)
    assert stale in alpha and "nominal" not in alpha and "oracle" not in alpha, alpha
    matrix = html[html.index('id="matrix"') :]
    row = next(r for r in matrix.split("<tr>") if 'href="alpha/index.html"' in r)
    assert "thresholds" not in row and stale in row and row.count(">stale<") == 2, row
    board = html[html.index('id="scoreboard"') : html.index("</table>", html.index('id="scoreboard"'))]
    assert "<td>1</td>" in board and "<td>2</td>" not in board  # runs per scheme: beta's only
    # never deleted: the old runs are stored and linked from the case's page
    assert (out / "alpha" / "oracle" / "metrics.json").is_file()
    page = (out / "alpha" / "index.html").read_text()
    assert stale in page and 'href="oracle/metrics.json"' in page and 'href="nominal/timeseries.npz"' in page


def test_a_rejected_case_file_marks_the_runs_it_stored_under_its_name_field_stale(tmp_path):
    """A case file with a ``name`` field stores its runs under that name; rejected, its record goes under the
    file's stem: the runs under its name stayed counted on the index as current.  The rejection is recorded
    under every case stored from that file, so those runs are stale too."""
    cases = tmp_path / "cases"
    cases.mkdir()
    (cases / "alpha.toml").write_text('name = "foo"\n' + _SMALL)
    (cases / "beta.toml").write_text(_SMALL)
    out = tmp_path / "rep"
    args = ["batch", str(cases), "--out", str(out), "--jobs", "1", "-q"]
    assert runner.invoke(app, args).exit_code == 0
    assert (out / "foo" / "oracle" / "metrics.json").is_file()
    (cases / "alpha.toml").write_text('name = "foo"\n' + _SMALL.replace("k_v = 5.0", "k_v = -5.0"))
    assert runner.invoke(app, args).exit_code == 2
    for name in ("alpha", "foo"):
        rec = json.loads((out / name / "case.json").read_text())
        assert rec["status"] == "error" and "alpha.toml" in rec["error"], (name, rec)
    html = (out / "index.html").read_text()
    counts = _index_counts(html)
    assert "2 run(s): 2 completed" in counts and "thresholds: 1 hold" in counts, counts
    assert "1 case file(s) rejected" in counts and "(2 stored run(s)" in counts, counts  # one file, two records
    assert (out / "foo" / "oracle" / "metrics.json").is_file()  # kept: linked from foo's page
    assert 'href="oracle/metrics.json"' in (out / "foo" / "index.html").read_text()
    # accepted again: its runs are current again (re-run only if the file changed)
    (cases / "alpha.toml").write_text('name = "foo"\n' + _SMALL)
    assert runner.invoke(app, args).exit_code == 0
    assert json.loads((out / "foo" / "case.json").read_text())["status"] == "ok"


def test_the_winners_table_says_why_a_detector_metric_has_no_winner(tmp_path):
    """Session 13's page review: in "Winners per case", a case run without a fault detector (nominal and the
    oracle only) read a bare "n/a" under the detection delay and the false alarms, as if something had failed;
    it now says that no detector ran there."""
    case = tmp_path / "small.toml"
    case.write_text(_SMALL)
    out = tmp_path / "rep"
    assert runner.invoke(app, ["batch", str(case), "--out", str(out), "--jobs", "1", "-q"]).exit_code == 0
    html = (out / "index.html").read_text()
    winners = html[html.index('id="cases"') : html.index("</table>", html.index('id="cases"'))]
    row = next(r for r in winners.split("<tr>") if 'href="small/index.html"' in r)
    assert row.count(">n/a: no detector run</span>") == 2, row
    assert ">n/a</span>" not in row, row


def test_metrics_parquet_marks_the_runs_of_a_rejected_case_file_stale(tmp_path):
    """Session 13's left-alone list: after a case file is rejected, metrics.parquet (and export's copy) still
    listed its earlier runs with nothing to tell them from current ones, though the index leaves them out.
    Its ``stale`` column is True on exactly those rows (the record's status is error), False elsewhere."""
    import pandas as pd

    cases = tmp_path / "cases"
    cases.mkdir()
    for name in ("alpha", "beta"):
        (cases / f"{name}.toml").write_text(_SMALL)
    out = tmp_path / "rep"
    args = ["batch", str(cases), "--out", str(out), "--jobs", "1", "-q"]
    assert runner.invoke(app, args).exit_code == 0
    df = pd.read_parquet(out / "metrics.parquet")
    assert not df["stale"].any()
    (cases / "alpha.toml").write_text(_SMALL.replace("k_v = 5.0", "k_v = -5.0"))
    assert runner.invoke(app, args).exit_code == 2
    df = pd.read_parquet(out / "metrics.parquet")
    assert set(df.loc[df["stale"], "case"]) == {"alpha"} and set(df.loc[~df["stale"], "case"]) == {"beta"}
    assert sorted(df.loc[df["stale"], "scheme"].unique()) == ["nominal", "oracle"]
    assert runner.invoke(app, ["export", "--out", str(out), "--dest", str(tmp_path / "ex")]).exit_code == 0
    ex = pd.read_parquet(tmp_path / "ex" / "metrics.parquet")
    assert set(ex.loc[ex["stale"], "case"]) == {"alpha"}
