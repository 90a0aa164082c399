"""Fault-coverage maps (issue 22): the two-link oracle agrees with the redundancy rule (2.103)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ftcreport import __version__
from ftcreport.cases import parse_case
from ftcreport.errors import FtcError
from ftcreport.model import pattern_is_compensable
from ftcreport.report.coverage import coverage_grids, render_coverage
from ftcreport.studies.coverage import (
    CoverageFault,
    _curvature,
    fault_set,
    onset_times,
    predicted_compensable,
    run_coverage,
)

ROOT = Path(__file__).resolve().parents[1]


def _two_link(duration: float = 12.0) -> dict:
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    data["simulation"]["duration"] = duration
    data.pop("campaign")  # success: the default final position error <= 0.05 m (the campaign's own)
    return data


def test_fault_set_and_prediction_by_hand():
    fs = fault_set(2)
    assert len(fs) == 4 + 6 + 2 * 4 + 4  # losses, pairs C(4, 2), two partial gains, frictions
    assert len(fault_set(3)) == 6 + 15 + 12 + 6
    # n = 2: the only uncompensable single or pair is losing both leader wheels
    lost = [f.wheels for f in fs if not predicted_compensable(2, f)]
    assert lost == [("1r", "1l")]
    # n = 3: likewise, and the rule agrees with the model's own pattern test
    for f in fault_set(3, kinds=("pair",)):
        pattern = [0 if w in f.wheels else 1 for w in ("1r", "1l", "2r", "2l", "3r", "3l")]
        assert predicted_compensable(3, f) == pattern_is_compensable(pattern) == (f.wheels != ("1r", "1l"))
    # partial losses and frictions leave every wheel working
    assert predicted_compensable(2, CoverageFault("partial", ("1r",), 0.25))
    with pytest.raises(FtcError, match="--kinds: unknown"):
        fault_set(2, kinds=("melt",))
    with pytest.raises(FtcError, match="--sigmas"):
        fault_set(2, sigmas=(0.0,))


def test_onset_times_follow_the_curvature():
    # the unicycle reference has constant curvature: evenly spaced over 20-50 % of the run
    assert onset_times(parse_case(_two_link(12.0), "u")) == [2.4, 4.2, 6.0]
    data = _two_link(40.0)
    data["reference"] = {"kind": "eight", "scale": 4.0}
    data["kinematic"] = {"kind": "chained"}
    case = parse_case(data, "eight")
    times = onset_times(case, 3)
    path = case.reference.path()
    grid = np.linspace(8.0, 20.0, 201)
    k = np.array([_curvature(path, t) for t in grid])
    got = [_curvature(path, t) for t in times]
    # the smallest and the largest curvature of the window (to the grid's resolution and the 20 ms rounding)
    tol = 0.02 * np.ptp(k)
    assert min(got) == pytest.approx(k.min(), abs=tol) and max(got) == pytest.approx(k.max(), abs=tol)
    assert len(set(times)) == 3 and all(8.0 <= t <= 20.0 for t in times)


@pytest.fixture(scope="module")
def oracle_map(tmp_path_factory):
    out = tmp_path_factory.mktemp("coverage")
    base = parse_case(_two_link(), "two_link_campaign_short")
    res = run_coverage(base, out, schemes=["oracle"], kinds=("loss", "pair"), in_process=True, show_progress=False)
    return base, out, res


def test_oracle_coverage_agrees_with_the_redundancy_rule(oracle_map):
    _, out, res = oracle_map
    assert res.times == [2.4, 4.2, 6.0] and not res.failed
    assert len(res.completed) == (4 + 6) * 3
    summary = json.loads((out / "summary.json").read_text())
    faults = summary["schemes"]["oracle"]["faults"]
    for key, e in faults.items():
        if e["kind"] == "loss":  # every single loss is compensable and recovers at every onset
            assert e["predicted_compensable"] and e["recovered"] == [True] * 3, key
        if not e["predicted_compensable"]:  # marked, and lost at every onset
            assert e["recovered"] == [False] * 3, key
            assert min(e["final_error"]) > 0.05, key
    assert [k for k, e in faults.items() if not e["predicted_compensable"]] == ["pair 1r+1l"]
    o = summary["schemes"]["oracle"]
    assert (o["agree"], o["n_faults"], o["lost_but_compensable"], o["recovered_but_uncompensable"]) == (10, 10, [], [])
    # the map marks the uncompensable cell and shows the simulated outcome beside it
    g = coverage_grids(summary, 2)
    assert g["predicted_pairs"][0, 1] == 0.0 and g["pairs"]["oracle"][0, 1] == 0.0
    assert np.nansum(g["predicted_pairs"] == 0.0) == 2  # (1r, 1l) and its mirror
    assert np.all(g["single"]["oracle"][:, 0] == 1.0)
    html = render_coverage(out).read_text()
    assert "predicted (2.103)" in html and 'class="map"' in html and "pair 1r+1l" in html
    assert 'title="1r+1l: 0 of the onsets recovered (uncompensable by the rule)">X 0</td>' in html
    # one definition of recovery (issue 35 item 4): a run recovers when it completes and meets the success
    # bound, and its recovery time is the time into that bound, so "recovered" and "never" cannot coexist
    rows = [r for i in sorted((out / "items").glob("*.json")) for r in json.loads(i.read_text())["rows"]]
    assert all(r["recovery_bound"] == 0.05 for r in rows)
    for r in rows:
        assert r["recovered"] == (r["recovery_time"] is not None), r
        if r["recovered"]:
            assert 0.0 <= r["recovery_time"] <= 12.0 - r["onset"] and r["final_error"] <= 0.05
    for e in faults.values():
        assert (e["recovery_time_max"] is None) == (not any(e["recovered"]))
    assert 'id="recovery-definition"' in html and "enters 0.05 m and stays" in html
    man = json.loads((out / "manifest.json").read_text())
    assert man["kind"] == "coverage" and man["settings"]["times"] == [2.4, 4.2, 6.0]


def test_coverage_resumes_and_refuses_another_version(oracle_map):
    base, out, _ = oracle_map
    again = run_coverage(base, out, schemes=["oracle"], kinds=("loss", "pair"), in_process=True, show_progress=False)
    assert again.skipped == 30 and again.completed == []
    p = out / "items" / "000004.json"
    rec = json.loads(p.read_text())
    p.write_text(json.dumps(rec | {"version": "0.0.1"}))
    with pytest.raises(FtcError, match=r"000004.json: was computed by ftcreport 0\.0\.1"):
        run_coverage(base, out, schemes=["oracle"], kinds=("loss", "pair"), in_process=True, show_progress=False)
    p.write_text(json.dumps(rec))
    assert rec["version"] == __version__


def test_coverage_times_are_checked():
    base = parse_case(_two_link(), "x")
    with pytest.raises(FtcError, match=r"--times: onset times must lie in \[0, 12\)"):
        run_coverage(base, Path("unused"), times=[13.0], in_process=True, show_progress=False)


def test_coverage_cli_errors_are_one_line(tmp_path):
    from typer.testing import CliRunner

    from ftcreport.cli import app

    r = CliRunner().invoke(app, ["coverage", str(ROOT / "cases" / "two_link_campaign.toml"), "--times", "5,x"])
    assert r.exit_code == 2 and "--times: expected comma-separated numbers, got '5,x'" in r.output
    r = CliRunner().invoke(app, ["coverage", str(ROOT / "cases" / "two_link_campaign.toml"), "--kinds", "melt"])
    assert r.exit_code == 2 and "--kinds: unknown ['melt']" in r.output
    assert "Traceback" not in r.output


def _refused(out: Path, *args: str) -> str:
    """The one line a bad coverage option gives (exit 2), checked to leave no output directory behind; runs are
    confined to one scheme at one onset, so an option wrongly accepted costs seconds, not a map."""
    from typer.testing import CliRunner

    from ftcreport.cli import app

    case = str(ROOT / "cases" / "two_link_campaign.toml")
    fast = ["--times", "5", "--schemes", "nominal", "--in-process", "-q", "--out", str(out)]
    r = CliRunner().invoke(app, ["coverage", case, *fast, *args])  # the last --times wins
    assert r.exit_code == 2, (args, r.exit_code, r.output)
    assert len(r.output.strip().splitlines()) == 1 and r.output.startswith("ftcreport: error: "), r.output
    assert not out.exists(), f"{args}: {out} made before the option was refused"
    return r.output.strip()


def test_coverage_kinds_and_sigmas_that_name_nothing_are_refused(tmp_path):
    """--kinds "," (or "") ran a map of zero fault runs and exited 0, where campaign --schemes "," is refused;
    --sigmas "," silently dropped the partial losses --kinds asks for."""
    for kinds in (",", "", " , "):
        line = _refused(tmp_path / "k", "--kinds", kinds)
        assert "--kinds: names no fault kind; give one or more of loss, pair, partial, friction" in line
    line = _refused(tmp_path / "s", "--kinds", "partial", "--sigmas", ",")
    assert "--sigmas: names no gain for the partial losses; give one or more in (0, 1)" in line
    assert fault_set(2, sigmas=(), kinds=("loss",))  # no partial loss asked: no gain needed
    with pytest.raises(FtcError, match="--kinds: names no fault kind"):
        fault_set(2, kinds=())


def test_coverage_friction_is_a_finite_nonzero_torque_of_the_case_range(tmp_path):
    """--friction nan, inf or -1e300 was taken: every friction run failed as a CaseError (faults[0].ubar), kept
    in failed.json only, and the command exited 1 with nothing on stderr."""
    for value in ("nan", "inf", "-inf", "-1e300", "10000.5", "0"):
        line = _refused(tmp_path / "f", "--kinds", "friction", "--friction", value)
        assert "--friction: " in line and "[-10000, 10000] N m (a fault's ubar)" in line, line
    assert "a friction of 0 N m changes no wheel" in _refused(tmp_path / "f", "--kinds", "friction", "--friction", "0")
    assert "--friction: " in _refused(tmp_path / "f", "--kinds", "loss", "--friction", "nan")  # unused, still bad
    assert [f.ubar for f in fault_set(1, friction=-2.0, kinds=("friction",))] == [-2.0, -2.0]  # negative: allowed


def test_coverage_times_and_sigmas_refuse_nan_inf_and_negatives(tmp_path):
    """--times and --sigmas are refused out of range whatever the number (nan compares false to every bound)."""
    for value in ("nan", "inf", "-1", "-1e300"):
        assert "--times: onset times must lie in [0, 30) s" in _refused(tmp_path / "t", "--times", value)
        assert "--sigmas: partial losses need 0 < sigma < 1" in _refused(tmp_path / "s", "--sigmas", value)
    assert "--times: " in _refused(tmp_path / "t", "--times", ",")


def _coverage_dir(out: Path, kinds: list[str]) -> Path:
    """A coverage directory with its metadata and an empty summary (the page's header and links only)."""
    out.mkdir(parents=True, exist_ok=True)
    meta = {"case": "hand", "n": 2, "schemes": ["oracle"], "kinds": kinds, "sigmas": [0.25, 0.5]}
    meta |= {"friction": 0.5, "times": [2.4, 4.2], "base": {}}
    (out / "coverage.json").write_text(json.dumps(meta))
    (out / "summary.json").write_text(json.dumps({"schemes": {}}))
    return out


def test_the_header_lists_only_the_kinds_run(tmp_path):
    """Issue 35 item 7: with --kinds loss,pair the header still listed partial losses (sigma 0.25, 0.5) and a
    friction; it now names the kinds run, with their settings only where they were used."""
    html = render_coverage(_coverage_dir(tmp_path / "a", ["loss", "pair"])).read_text()
    head = html.split("<h1>", 1)[1].split('id="recovery-definition"', 1)[0]
    assert "single-wheel losses and pairs of losses" in head
    assert "sigma" not in head and "friction" not in head
    html = render_coverage(_coverage_dir(tmp_path / "b", ["partial", "friction"])).read_text()
    head = html.split("<h1>", 1)[1].split('id="recovery-definition"', 1)[0]
    assert "partial losses (sigma in 0.25, 0.5) and a friction of ubar = 0.5 N m per wheel" in head
    assert "pairs" not in head


def test_the_coverage_page_says_which_band_recovered_means_where_it_uses_the_word(tmp_path):
    """'Recovered' has two definitions: on a coverage page a run meets the success criteria (a final error within
    0.05 m), on a campaign page it settles in the case's tighter recovery_band (0.01 m).  The coverage page's
    columns 'onsets recovered' and 'recovered although uncompensable' and its maps used the word bare, and its
    definition did not say where the criteria come from.  The headers carry the criteria and their source, the
    definition names the source and what a campaign page means by the word instead.  Numbers unchanged."""
    import html as markup
    import re

    text = lambda h: markup.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", h)))  # noqa: E731
    out = _coverage_dir(tmp_path / "d", ["loss"])  # no [campaign] success in the case: the default criteria
    html = render_coverage(out).read_text()
    heads = re.findall(r"<th[^>]*>.*?</th>", html, re.S)
    for word in ("onsets recovered", "recovered although uncompensable"):
        (th,) = [h for h in heads if word in h]
        assert "position_error_final" in th and "0.05" in th and "the default" in th, th
    definition = text(html.split('id="recovery-definition"', 1)[1].split("</p>", 1)[0])
    assert "the default (the case has no [campaign] success)" in definition, definition
    assert "campaign page" in definition and "recovery_band, 0.01 m" in definition, definition
    meta = json.loads((out / "coverage.json").read_text())
    base = {"recovery_band": 0.02, "campaign": {"success": {"position_error_final": {"min": None, "max": 0.1}}}}
    (out / "coverage.json").write_text(json.dumps(meta | {"base": base}))
    html = render_coverage(out).read_text()
    definition = text(html.split('id="recovery-definition"', 1)[1].split("</p>", 1)[0])
    assert "the case's [campaign] success" in definition and "recovery_band, 0.02 m" in definition, definition


def test_coverage_links_only_to_an_index_that_exists(tmp_path):
    """Issue 35 item 7: 'all cases' pointed at ../../index.html, broken under a custom --out."""
    assert "../../index.html" not in render_coverage(_coverage_dir(tmp_path / "x", ["loss"])).read_text()
    nested = _coverage_dir(tmp_path / "reports" / "coverage" / "hand", ["loss"])
    (tmp_path / "reports" / "index.html").write_text("<html></html>")
    assert '<a href="../../index.html">all cases</a>' in render_coverage(nested).read_text()


def test_coverage_refuses_items_another_code_computed(oracle_map, monkeypatch):
    """Resume keyed a stored item on the package version only; a change of the package's code is stale too."""
    from ftcreport.storage import code_digest

    base, out, _ = oracle_map
    monkeypatch.setattr(code_digest, "DIGEST", "0123456789abcdef")
    with pytest.raises(FtcError, match=r"000000.json: was computed by other code"):
        run_coverage(base, out, schemes=["oracle"], kinds=("loss", "pair"), in_process=True, show_progress=False)
