"""Baselines (issue 35 item 10): tolerances as Simulink Test's, the compact signals, save then check.

The end-to-end runs are two_link_switching cut to 25 s (its first fault at 20 s), switching alone.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from ftcreport.cases import parse_case
from ftcreport.cli import app
from ftcreport.errors import CaseError
from ftcreport.studies.baseline import band, compare_metric, compare_signal, edges_for, envelope, field_diff

CASES = Path(__file__).resolve().parents[1] / "cases"
runner = CliRunner()


# ---------------------------------------------------------------------------------------- pure
def test_metric_tolerance_is_the_larger_of_absolute_and_relative():
    assert compare_metric("m", 100.0, 100.09, rel_tol=1e-3, abs_tol=1e-9).ok  # 0.09 <= 0.1
    d = compare_metric("m", 100.0, 100.11, rel_tol=1e-3, abs_tol=1e-9)
    assert not d.ok and d.tol == pytest.approx(0.1) and d.delta == pytest.approx(0.11)
    assert compare_metric("m", 1e-7, 5e-7, rel_tol=1e-3, abs_tol=1e-6).ok  # near zero the absolute floor decides
    assert not compare_metric("m", 1e-7, 5e-7, rel_tol=1e-3, abs_tol=1e-9).ok
    assert compare_metric("m", None, None, 1e-3, 1e-9).ok
    null = compare_metric("recovery_time_max", 3.2, None, 1e-3, 1e-9)
    assert not null.ok and null.line() == "recovery_time_max: baseline 3.2, new null (no numeric delta)"
    line = compare_metric("position_error_final", 3.0e-7, 4.2e-7, 1e-3, 1e-9).line()
    assert line == "position_error_final: baseline 3e-07 m, new 4.2e-07 m, delta +1.2e-07 m (+40 %); tolerance 1e-09 m"


def test_the_envelope_keeps_a_one_sample_spike():
    t = np.linspace(0.0, 100.0, 100_001)
    y = np.sin(t)
    y[31_415] = 50.0  # one sample of 100,001
    e = edges_for(t)
    lo, hi = envelope(t, y, e)
    assert e.size == 501 and np.nanmax(hi) == 50.0 and np.nanmin(lo) == pytest.approx(-1.0, abs=1e-6)
    assert np.nanmax(np.interp(np.linspace(0, 100, 500), t, y)) < 2  # a 500-point grid misses it


def test_a_signal_shifted_in_time_passes_only_with_a_time_tolerance():
    """A step at 10 s in the baseline, at 10.5 s in the new run: outside the band unless lagging_tol >= 0.5 s;
    the same step earlier (9.5 s) needs leading_tol, as Simulink's leading and lagging tolerances."""
    t = np.linspace(0.0, 20.0, 20_001)
    base = (t >= 10.0).astype(float)
    e = edges_for(t, 400)  # 0.05 s intervals
    lo, hi = envelope(t, base, e)
    late, early = (t >= 10.5).astype(float), (t >= 9.5).astype(float)
    delta, _ = compare_signal("s", "1", e, lo, hi, t, late, 1e-3, 1e-9)
    assert (
        delta is not None
        and delta.first_time == pytest.approx(10.0)
        and delta.excess == pytest.approx(0.999)  # 1 less the 0.1 % tolerance
    )
    assert compare_signal("s", "1", e, lo, hi, t, late, 1e-3, 1e-9, lag=0.5)[0] is None
    assert compare_signal("s", "1", e, lo, hi, t, late, 1e-3, 1e-9, lead=0.5)[0] is not None  # the wrong side
    assert compare_signal("s", "1", e, lo, hi, t, early, 1e-3, 1e-9, lead=0.5)[0] is None
    assert compare_signal("s", "1", e, lo, hi, t, early, 1e-3, 1e-9, lag=0.5)[0] is not None
    assert compare_signal("s", "1", e, lo, hi, t, base * 1.0009, 1e-3, 1e-9)[0] is None  # within 0.1 %
    assert compare_signal("s", "1", e, lo, hi, t, base * 1.0011, 1e-3, 1e-9)[0] is not None
    L, U = band(lo, hi, e, 0.0, 0.1)
    assert np.all(U - hi == pytest.approx(0.1)) and np.all(lo - L == pytest.approx(0.1))


def test_the_overlays_are_not_scaled_by_the_start_up():
    """Issue 35 item 2: on baseline.html the torque overlays' axis was set by the 4,320 N m start-up spike (so
    everything after it was a flat line), and the position-error overlays were linear with red circles over
    differences too small to see.  Now, as on the case page, the axes take their scale from the samples after
    the first fault (the start-up drawn, not setting the axis), and an error spanning decades is on a log
    scale."""
    from ftcreport.report.baseline_page import _band_figure

    t = np.linspace(0.0, 40.0, 40_001)
    e = edges_for(t, 400)
    tau = np.where(t < 0.05, 4320.0, 3.0 * np.sin(5 * t))  # the start-up spike, then +-3 N m
    lo, hi = envelope(t, tau, e)
    delta, drawn = compare_signal("torque[1r]", "N m", e, lo, hi, t, tau * 1.01, 1e-3, 1e-3)
    assert delta is not None
    fig = _band_figure("c", "nominal", "torque[1r]", "N m", drawn, t, tau * 1.01, scale_from=20.0)
    lay = fig["layout"]
    assert lay["yaxis"].get("type", "linear") == "linear"
    top_lo, top_hi = lay["yaxis"]["range"]
    assert -3.6 < top_lo < -2.9 and 2.9 < top_hi < 3.6, "the axis is the torque after the fault's, not 4,320"
    d_lo, d_hi = lay["yaxis2"]["range"]
    assert -0.1 < d_lo < 0 < d_hi < 0.1  # the difference after the fault (1 % of 3 N m), not 43 N m
    assert max(v for tr in fig["data"] if tr.get("yaxis") != "y2" for v in tr["y"] if v is not None) >= 4320
    # a wheel lost at 20 s: its zero torque after the fault does not set the axis (the page scales from 1 s)
    lost = np.where(t < 20.0, tau, 0.0)
    lo, hi = envelope(t, lost, e)
    _, drawn = compare_signal("torque[1r]", "N m", e, lo, hi, t, lost * 1.01, 1e-3, 1e-3)
    top_lo, top_hi = _band_figure("c", "n", "torque[1r]", "N m", drawn, t, lost, scale_from=1.0)["layout"]["yaxis"][
        "range"
    ]
    assert -3.6 < top_lo < -2.9 and 2.9 < top_hi < 3.6
    # an error decaying over 6 decades: a log axis (plotly ranges in log10 units) that shows the whole run
    err = 0.08 * np.exp(-t / 2.5) + 1e-9
    lo, hi = envelope(t, err, e)
    _, drawn = compare_signal("position_error", "m", e, lo, hi, t, err * 1.05, 1e-3, 1e-12)
    fig = _band_figure("c", "nominal", "position_error", "m", drawn, t, err * 1.05, scale_from=20.0)
    assert fig["layout"]["yaxis"]["type"] == "log"
    a, b = fig["layout"]["yaxis"]["range"]
    assert a < -7.5 and b > np.log10(0.05)


def test_field_diff_names_each_changed_field():
    old = {"schemes": {"switching": {"k_v": 3000.0, "gamma": 10.0}}, "faults": [{"time": 20.0}], "plugins": {}}
    new = {
        "schemes": {"switching": {"k_v": 2000.0, "gamma": 10.0}},
        "faults": [{"time": 25.0}],
        "plugins": {"x.py": "ab"},
    }
    assert field_diff(old, new) == [
        "schemes.switching.k_v: 3000.0 -> 2000.0",
        "faults[0].time: 20.0 -> 25.0",
        'plugins.x.py: added ("ab")',
    ]


def test_baseline_tables_are_validated():
    data = tomllib.loads((CASES / "two_link_switching.toml").read_text())
    for table, words in (
        ({"metrics": {"torque_pek": {"rel_tol": 0.1}}}, "baseline.metrics.torque_pek: not a scalar metric of "
         "metrics.json (did you mean 'torque_peak'?)"),
        ({"signals": {"torques": {"abs_tol": 1.0}}}, "baseline.signals.torques: not a baseline signal (did you mean "
         "'torque'?)"),
        ({"rel_tol": -1.0}, "baseline.rel_tol: must be >= 0, got -1.0"),
        ({"lead_tol": 0.1}, "baseline.lead_tol: unknown field (did you mean 'leading_tol'?)"),
    ):  # fmt: skip
        with pytest.raises(CaseError) as exc:
            parse_case(data | {"baseline": table}, "x.toml")
        assert words in str(exc.value), str(exc.value)


# ---------------------------------------------------------------------------------- save, check
def _write(path: Path, k_v: float = 3000.0, baseline: dict | None = None) -> None:
    data = tomllib.loads((CASES / "two_link_switching.toml").read_text())
    data["name"] = "bl"
    data["faults"] = data["faults"][:1]
    data["simulation"]["duration"] = 25.0
    data["schemes"] = {"run": ["switching"], "switching": data["schemes"]["switching"] | {"k_v": k_v}}
    data["claims"], data["thresholds"], data["requirements"] = [], {}, []
    if baseline is not None:
        data["baseline"] = baseline
    path.write_text(tomli_w.dumps(data))


def test_save_then_check_passes_and_a_changed_gain_fails_naming_metric_delta_and_field(tmp_path):
    src, out, dest, junit = tmp_path / "bl.toml", tmp_path / "r", tmp_path / "base", tmp_path / "junit.xml"
    _write(src)
    res = runner.invoke(app, ["baseline", "save", str(src), "--out", str(out), "--dest", str(dest), "-q"])
    assert res.exit_code == 0, res.output
    saved = json.loads((dest / "bl" / "baseline.json").read_text())
    assert saved["case_fields"]["schemes"]["switching"]["k_v"] == 3000.0 and saved["case_text"] == src.read_text()
    assert saved["ftcreport"]["git"] is None or len(saved["ftcreport"]["git"]["revision"]) == 40
    assert saved["case_hash"] and saved["schemes"]["switching"]["key"] and saved["versions"]["numpy"]
    assert saved["schemes"]["switching"]["signals"] == [
        "position_error", "heading_error[1]", "heading_error[2]", "torque[1r]", "torque[1l]", "torque[2r]", "torque[2l]"
    ]  # fmt: skip

    # the unchanged tree passes
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(dest), "--junit", str(junit)])
    assert res.exit_code == 0, res.output
    assert "1/1 runs match the baseline" in res.output
    tc = next(t for t in ET.fromstring(junit.read_bytes()).iter("testcase") if t.get("name") == "baseline")
    assert tc.get("classname") == "bl.switching" and tc.find("failure") is None
    assert "within tolerance of the baseline" in tc.find("system-out").text

    # one gain changed: fails, one line per change with baseline, new and delta, and the field that changed
    old_peak = saved["schemes"]["switching"]["metrics"]["torque_peak"]
    _write(src, k_v=2000.0)
    res = runner.invoke(
        app, ["check", str(src), "--out", str(out), "--baseline", str(dest), "--junit", str(junit), "-q"]
    )
    assert res.exit_code == 1, res.output
    new_peak = json.loads((out / "bl" / "switching" / "metrics.json").read_text())["torque_peak"]
    assert new_peak < 0.9 * old_peak  # the start-up spike scales with k_v
    d = new_peak - old_peak
    line = (
        f"FAIL  bl / switching / torque_peak: baseline {old_peak:.6g} N m, new {new_peak:.6g} N m, delta {d:+.4g} N m "
        f"({100 * d / old_peak:+.3g} %); tolerance {1e-3 * old_peak:.3g} N m"
    )
    assert line in res.output.splitlines(), res.output
    assert (
        "FAIL  bl / switching: inputs changed since the baseline (1 field(s)): schemes.switching.k_v: 3000.0 -> 2000.0"
        in res.output.splitlines()
    )
    assert "0/1 runs match the baseline" in res.output
    failure = next(t for t in ET.fromstring(junit.read_bytes()).iter("testcase") if t.get("name") == "baseline")
    msg = failure.find("failure").get("message")
    assert f"torque_peak: baseline {old_peak:.6g} N m, new {new_peak:.6g} N m, delta {d:+.4g} N m" in msg
    assert "schemes.switching.k_v: 3000.0 -> 2000.0" in msg
    page = (out / "baseline.html").read_text()
    assert "<code>schemes.switching.k_v: 3000.0 -&gt; 2000.0</code>" in page
    assert 'data-metric="torque_peak"' in page and 'id="plot-bl-0-spec"' in page  # a signal's overlay

    # tolerances of the case as it is now: wide enough, the same change passes (and still says what changed)
    wide = {"rel_tol": 1.0, "abs_tol": 1e3}
    _write(src, k_v=2000.0, baseline=wide)
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(dest)])
    assert res.exit_code == 0, res.output
    assert "inputs changed since the baseline (2 field(s))" in res.output  # k_v and the [baseline] table


def test_the_index_links_the_baseline_page_only_while_it_compares_the_stored_runs(tmp_path):
    """A baseline.html left by an earlier `check --baseline` stayed linked from the index after a later batch
    re-ran its runs (the page compared runs no longer stored), and the first check's index did not link the
    page it wrote (rendered before it).  The index links it while every run it compared is still the stored
    one (the run record's seal), and otherwise names it as written for earlier results, without a link."""
    import re

    src, out, dest = tmp_path / "bl.toml", tmp_path / "r", tmp_path / "base"
    _write(src)
    res = runner.invoke(app, ["baseline", "save", str(src), "--out", str(out), "--dest", str(dest), "-q"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(dest), "-q"])
    assert res.exit_code == 0, res.output
    pages = (out / "index.html").read_text().split('id="other-pages"', 1)
    assert len(pages) == 2 and 'href="baseline.html"' in pages[1], "the index does not link the baseline page"

    _write(src, k_v=2000.0)  # another run of the case: the page compared the one before it
    res = runner.invoke(app, ["batch", str(src), "--out", str(out), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert (out / "baseline.html").exists()  # the page stays (a reader's file), unlinked
    index = (out / "index.html").read_text()
    assert 'href="baseline.html"' not in index
    row = index.split('id="other-pages"', 1)[1].split("</table>", 1)[0]
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", row))
    assert "baseline.html" in text and "written for earlier results" in text, text


def test_a_missing_baseline_fails_and_a_missing_directory_is_bad_input(tmp_path):
    src, out = tmp_path / "bl.toml", tmp_path / "r"
    _write(src)
    other = tmp_path / "other"
    other.mkdir()
    (other / "baseline.json").write_text(json.dumps({"format": 1, "cases": {"x": {}}}))
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(other), "-q"])
    assert res.exit_code == 1, res.output
    assert f"FAIL  bl / switching / baseline missing: no baseline of case 'bl' in {other} (it holds: x)" in res.output
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(tmp_path / "nowhere"), "-q"])
    assert res.exit_code == 2
    assert "--baseline: no baseline here" in res.output


def test_the_compared_metrics_are_names_a_case_may_tune():
    from ftcreport.cases import BASELINE_METRIC_NAMES
    from ftcreport.studies.baseline import COMPARED_METRICS

    assert set(COMPARED_METRICS) <= set(BASELINE_METRIC_NAMES)


def _saved_short_baseline(tmp_path: Path) -> tuple[Path, Path, Path]:
    """(case file, results, baseline directory): the baseline case shortened to 2 s, its baseline saved."""
    src, out, dest = tmp_path / "bl.toml", tmp_path / "r", tmp_path / "base"
    _write(src)
    data = tomllib.loads(src.read_text())
    data["simulation"]["duration"], data["faults"][0]["time"] = 2.0, 1.0
    src.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["baseline", "save", str(src), "--out", str(out), "--dest", str(dest), "-q"])
    assert res.exit_code == 0, res.output
    return src, out, dest


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda r: r["schemes"].update(switching="x"), "schemes.switching is not a table"),
        (lambda r: r["schemes"]["switching"].update(metrics=None), "schemes.switching.metrics is not a table"),
        (lambda r: r["schemes"]["switching"].update(signals=None), "schemes.switching.signals is not a list of names"),
        (lambda r: r.update(case_fields=[1]), "case_fields is not a table"),
    ],
)
def test_a_hand_edited_baseline_fails_naming_the_file_and_the_field(tmp_path, damage, words):
    """The round-3 gate attack: a baseline.json edited by hand (a scheme's table replaced by a string, its
    metrics or signals by null) crashed `check` (exit 3, AttributeError/TypeError)."""
    src, out, dest = _saved_short_baseline(tmp_path)
    path = dest / "bl" / "baseline.json"
    rec = json.loads(path.read_text())
    damage(rec)
    path.write_text(json.dumps(rec))
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(dest), "-q"])
    assert res.exit_code == 1, res.output
    assert "a bug" not in res.output and "Traceback" not in res.output
    assert f"{path}: damaged: {words}" in res.output, res.output


def test_a_baseline_whose_signal_band_is_gone_fails_naming_it(tmp_path):
    """The review: a signal listed in baseline.json whose band signals.npz lacks (both files edited, its
    hash updated) raised KeyError in the comparison."""
    import hashlib
    import io

    import numpy as np

    src, out, dest = _saved_short_baseline(tmp_path)
    npz, path = dest / "bl" / "signals.npz", dest / "bl" / "baseline.json"
    with np.load(npz) as z:
        kept = {k: z[k] for k in z.files if k != "switching|torque[1r]|lo"}
    buf = io.BytesIO()
    np.savez(buf, **kept)
    npz.write_bytes(buf.getvalue())
    rec = json.loads(path.read_text())
    rec["signals_sha256"] = hashlib.sha256(buf.getvalue()).hexdigest()
    path.write_text(json.dumps(rec))
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--baseline", str(dest), "-q"])
    assert res.exit_code == 1, res.output
    assert "a bug" not in res.output
    assert f"{path}: damaged: schemes.switching.signals names 'torque[1r]', which {npz} has no band of" in res.output


def test_a_baseline_case_whose_file_left_the_checked_directory_fails_and_a_subset_is_noted(tmp_path):
    """The round-3 attack: with two cases saved from a directory and one file then deleted, `check DIR
    --baseline B` said "1/1 runs match the baseline" (exit 0) without a word of the other: a scheme missing
    from a case failed, a whole case missing passed.  A baseline case whose file lay in a directory (or was a
    file) this check reads, and is not checked now, fails; one outside the inputs (a check of a subset) is
    named in a note and does not fail."""
    cases, out, dest = tmp_path / "cases", tmp_path / "r", tmp_path / "base"
    cases.mkdir()
    for name in ("a", "b"):
        _write(cases / f"{name}.toml")
        data = tomllib.loads((cases / f"{name}.toml").read_text())
        data["name"] = name
        data["simulation"]["duration"], data["faults"][0]["time"] = 2.0, 1.0
        (cases / f"{name}.toml").write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["baseline", "save", str(cases), "--out", str(out), "--dest", str(dest), "-q"])
    assert res.exit_code == 0, res.output
    # a subset: only a.toml is checked; b is outside the inputs, named but not failed
    res = runner.invoke(app, ["check", str(cases / "a.toml"), "--out", str(out), "--baseline", str(dest)])
    assert res.exit_code == 0, res.output
    assert "1 case of the baseline not among this check's inputs (not compared): b" in res.output
    (cases / "b.toml").unlink()
    res = runner.invoke(app, ["check", str(cases), "--out", str(out), "--baseline", str(dest)])
    assert res.exit_code == 1, res.output
    assert f"b / baseline missing: b is in the baseline (its file {cases / 'b.toml'}) but not checked now" in res.output


def test_a_dest_that_is_the_results_directory_or_inside_it_is_refused_naming_dest(tmp_path):
    """Session 13's attack: ``baseline save --dest rep --out rep`` wrote baseline.json, <case>/baseline.json and
    signals.npz into the results tree (exit 0: the re-entrant lock skipped the directory's kind check), and
    ``--dest rep/<case>/<scheme>`` (baseline or export) wrote into a stored run's folder.  Both are refused
    before anything runs or is written, naming --dest; a results directory given as --dest with another --out
    is refused naming --dest too (it named --out), also before the batch runs."""
    src, out, _ = _saved_short_baseline(tmp_path)
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if ".ftcreport.lock" not in p.name)
    for bad in (out, out / "bl" / "switching", out / "bl"):
        res = runner.invoke(app, ["baseline", "save", str(src), "--out", str(out), "--dest", str(bad), "-q"])
        assert res.exit_code == 2, (bad, res.output)
        assert f"{bad}: --dest: is " in res.output and "--out" in res.output, res.output
        res = runner.invoke(app, ["export", "--out", str(out), "--dest", str(bad)])
        assert res.exit_code == 2, (bad, res.output)
        assert f"{bad}: --dest: " in res.output, res.output
    after = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if ".ftcreport.lock" not in p.name)
    assert after == before
    other = tmp_path / "r2"
    res = runner.invoke(app, ["baseline", "save", str(src), "--out", str(other), "--dest", str(out), "-q"])
    assert res.exit_code == 2 and f"{out}: --dest: holds the results of another kind" in res.output, res.output
    assert not other.exists()  # refused before the batch ran
