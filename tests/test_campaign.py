"""Monte Carlo campaigns (issues 10, 22): Dask LocalCluster and a real scheduler = in-process, kill and
resume, shared-scheduler isolation, seeds, versions, the report's numbers."""

from __future__ import annotations

import contextlib
import json
import math
import operator
import os
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w

from ftcreport import __version__
from ftcreport.cases import parse_case
from ftcreport.errors import CaseError, FtcError
from ftcreport.report.campaign import render_campaign
from ftcreport.studies.campaign import (
    campaign_hash,
    case_content_hash,
    draw_variant,
    read_table,
    run_campaign,
    run_sample,
    sample_seeds,
    summarize,
    task_key,
    wilson_interval,
    write_table,
)
from ftcreport.studies.cluster import check_versions

ROOT = Path(__file__).resolve().parents[1]
SCHEMES = ["nominal", "oracle"]


def _base_data() -> dict:
    """The example campaign, shortened to 8 s (faults in 2-5 s) so that 20 samples take seconds."""
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    data["simulation"]["duration"] = 8.0
    data["campaign"]["fault_time"] = [2.0, 5.0]
    return data


@pytest.fixture(scope="module")
def base():
    return parse_case(_base_data(), "two_link_campaign_short")


def _metric_rows(path: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("wall_time", "compile_time")} for r in read_table(path)]


def test_seeds_and_draws_are_reproducible(base):
    assert sample_seeds(7, 3) == sample_seeds(7, 3)
    assert len({sample_seeds(7, i).draw for i in range(1000)}) == 1000
    a, b = draw_variant(base, sample_seeds(7, 3)), draw_variant(base, sample_seeds(7, 3))
    assert a.model_dump() == b.model_dump()
    c = draw_variant(base, sample_seeds(7, 4))
    assert c.model_dump() != a.model_dump()
    assert a.plant.noise.seed == sample_seeds(7, 3).noise
    for i in range(50):
        v = draw_variant(base, sample_seeds(1, i))
        assert 1 <= len(v.faults) <= 2
        assert all(2.0 <= f.time <= 5.0 and 0.0 <= f.sigma <= 0.5 for f in v.faults)
        assert len({f.wheel for f in v.faults}) == len(v.faults)


def test_noise_and_draw_streams_differ_for_every_seed():
    """The old rule seeded the noise with seed % 2**31 and the draws with seed: the same stream for half
    of all (32-bit) seeds.  Now two SeedSequence children: different seeds and different first numbers."""
    for campaign_seed in range(40):
        for i in range(25):
            s = sample_seeds(campaign_seed, i)
            assert 0 <= s.draw < 2**63 and 0 <= s.noise < 2**63
            assert s.draw != s.noise
            d = np.random.default_rng(s.draw).random(4)
            n = np.random.default_rng(s.noise).random(4)
            assert not np.any(d == n)
    # seeds use 63 bits: far more than 2**32 values are reachable
    assert max(sample_seeds(0, i).draw for i in range(200)) > 2**40
    with pytest.raises(FtcError, match="--seed: must be >= 0"):
        sample_seeds(-1, 0)


def test_identical_seeds_give_identical_samples(base):
    a = run_sample(base.model_dump_json(), 2, 9, ["oracle"])
    b = run_sample(base.model_dump_json(), 2, 9, ["oracle"])
    for rec in (a, b):
        for r in rec["rows"]:
            r.pop("wall_time")
            r.pop("compile_time")  # the first run in this process compiled or loaded the loop
    assert a == b
    assert a["version"] == __version__ and a["campaign"] == campaign_hash(base, ["oracle"], 9)
    assert a["rows"][0]["noise_seed"] == sample_seeds(9, 2).noise


def test_task_keys_depend_on_case_schemes_seed_and_version(base):
    other = parse_case(_base_data() | {"description": "another campaign"}, "other")
    h = campaign_hash(base, SCHEMES, 0)
    assert h == campaign_hash(parse_case(_base_data(), "again"), SCHEMES, 0)
    variants = {
        h,
        campaign_hash(other, SCHEMES, 0),
        campaign_hash(base, ["oracle"], 0),
        campaign_hash(base, SCHEMES, 1),
        campaign_hash(base, SCHEMES, 0, version="0.0.0"),
    }
    assert len(variants) == 5
    assert task_key("campaign", h, 3) != task_key("campaign", h, 4)
    assert task_key("campaign", h, 0) != task_key("campaign", campaign_hash(other, SCHEMES, 0), 0)


def _record_path(out: Path, i: int) -> Path:
    return out / "samples" / f"{i:08d}.json"


def test_resume_refuses_another_version_or_case_content(base, tmp_path):
    run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    p = _record_path(tmp_path, 1)
    rec = json.loads(p.read_text())
    p.write_text(json.dumps(rec | {"version": "0.0.1"}))
    with pytest.raises(FtcError, match=r"00000001.json: was computed by ftcreport 0.0.1, this is "):
        run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    p.write_text(json.dumps(rec | {"case_hash": "0" * 16}))
    with pytest.raises(FtcError, match="another base case content"):
        run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    p.write_text(json.dumps({k: v for k, v in rec.items() if k != "version"}))
    with pytest.raises(FtcError, match="records no package version"):
        run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    res = run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False, force=True)
    assert (res.rerun_stale, res.skipped, res.completed) == (1, 1, [1])
    again = json.loads(p.read_text())
    assert again["version"] == __version__
    assert again["rows"][0]["position_error_final"] == rec["rows"][0]["position_error_final"]
    # the campaign directory itself records its version
    meta = tmp_path / "campaign.json"
    meta.write_text(json.dumps(json.loads(meta.read_text()) | {"version": "0.0.1"}))
    with pytest.raises(FtcError, match=r"campaign started by ftcreport 0\.0\.1"):
        run_campaign(base, 2, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["kind"] == "campaign" and man["seeds"]["campaign"] == 1
    assert man["seeds"]["samples"]["1"]["noise"] == sample_seeds(1, 1).noise
    assert man["dependencies"]["numpy"] == np.__version__ and man["dependencies"]["pyarrow"] is not None
    assert man["cases"] == {base.name: case_content_hash(base)} and man["platform"]["cores"] >= 1
    assert man["campaign"] == campaign_hash(base, ["oracle"], 1) and "git" in man["ftcreport"]


class _FakeClient:
    def __init__(self, worker_version, worker_code=None):
        self.worker_version = worker_version
        self.worker_code = worker_code

    def get_versions(self, check, packages):
        mine = {"python": "3.11.7", **{p: "1.0" for p in packages}}
        theirs = dict(mine, ftcreport=self.worker_version)
        return {"client": {"packages": mine}, "workers": {"tcp://10.0.0.2:4000": {"packages": theirs}}}

    def run(self, func):  # Client.run: the function on every worker, {address: result}
        return {"tcp://10.0.0.2:4000": func() if self.worker_code is None else self.worker_code}


def test_worker_versions_are_checked():
    assert check_versions(_FakeClient("1.0"))["tcp://10.0.0.2:4000"]["ftcreport"] == "1.0"
    with pytest.raises(FtcError, match=r"worker tcp://10.0.0.2:4000: versions differ .*ftcreport 0.9 \(client: 1.0\)"):
        check_versions(_FakeClient("0.9"))
    with pytest.raises(FtcError, match="ftcreport missing"):
        check_versions(_FakeClient(None))


def test_worker_code_is_checked():
    """A worker with the same package version but other code (an edited checkout on a --scheduler's
    machine) would compute samples that the records label with this process's code digest."""
    from ftcreport.storage.code_digest import code_digest

    assert check_versions(_FakeClient("1.0"))["tcp://10.0.0.2:4000"]["code"] == code_digest()
    with pytest.raises(FtcError, match=r"worker tcp://10.0.0.2:4000: its ftcreport code differs .*0123456789abcdef"):
        check_versions(_FakeClient("1.0", worker_code="0123456789abcdef"))


@pytest.mark.slow
def test_local_cluster_equals_in_process(base, tmp_path):
    """20 samples on a LocalCluster with 2 workers give the same table as in-process (metrics to 1e-12)."""
    a = run_campaign(base, 20, tmp_path / "inproc", seed=11, schemes=SCHEMES, in_process=True, show_progress=False)
    b = run_campaign(base, 20, tmp_path / "dask", seed=11, schemes=SCHEMES, workers=2, show_progress=False)
    assert not a.failed and not b.failed
    ra, rb = _metric_rows(a.table), _metric_rows(b.table)
    assert len(ra) == len(rb) == 40
    for x, y in zip(ra, rb, strict=True):
        assert x.keys() == y.keys()
        for k in x:
            if isinstance(x[k], float) and isinstance(y[k], float):
                assert y[k] == pytest.approx(x[k], rel=1e-12, abs=1e-12), k
            else:
                assert x[k] == y[k], k
    assert [r["sample"] for r in ra] == sorted(r["sample"] for r in ra)
    # some samples fail under the nominal law: the table carries real outcomes
    assert 0 < sum(r["success"] for r in ra if r["scheme"] == "nominal") <= 20


@pytest.mark.slow
def test_killed_campaign_resumes_to_exactly_n_unique_samples(tmp_path):
    case = tmp_path / "short.toml"
    case.write_text(tomli_w.dumps(_base_data()))
    out = tmp_path / "camp"
    cmd = [sys.executable, "-m", "ftcreport.cli", "campaign", str(case), "-n", "12", "--seed", "5", "--quiet"]
    cmd += ["--workers", "2", "--schemes", "nominal,oracle", "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=tmp_path, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and len(list((out / "samples").glob("*.json"))) < 3:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)  # the client, the cluster and its workers, mid-campaign
    proc.wait()
    before = len(list((out / "samples").glob("*.json")))
    assert 3 <= before < 12
    # the table on disk is complete and parseable whatever the moment of the kill
    rows = read_table(out / "results.csv")
    assert len(rows) % 2 == 0 and {r["scheme"] for r in rows} <= set(SCHEMES)
    base = parse_case(_base_data(), str(case))
    res = run_campaign(base, 12, out, seed=5, schemes=SCHEMES, in_process=True, show_progress=False)
    assert res.skipped == before and len(res.completed) == 12 - before
    rows = read_table(out / "results.csv")
    assert len(rows) == 24
    assert sorted({r["sample"] for r in rows}) == list(range(12))
    assert len({(r["sample"], r["scheme"]) for r in rows}) == 24
    # a resumed sample equals a fresh run of it
    fresh = run_campaign(base, 12, tmp_path / "fresh", seed=5, schemes=SCHEMES, in_process=True, show_progress=False)
    assert _metric_rows(fresh.table) == _metric_rows(out / "results.csv")


def test_resume_refuses_another_campaign(base, tmp_path):
    run_campaign(base, 1, tmp_path, seed=1, schemes=["oracle"], in_process=True, show_progress=False)
    with pytest.raises(FtcError, match="another seed"):
        run_campaign(base, 1, tmp_path, seed=2, schemes=["oracle"], in_process=True, show_progress=False)


def test_campaign_needs_a_campaign_table():
    data = _base_data()
    data.pop("campaign")
    with pytest.raises(CaseError, match=r"no \[campaign\] table"):
        run_campaign(parse_case(data, "x"), 1, Path("unused"), in_process=True, show_progress=False)
    data = _base_data()
    data["campaign"]["fault_time"] = [2.0, 9.0]
    with pytest.raises(CaseError, match=r"campaign.fault_time: upper bound"):
        parse_case(data, "x.toml")


# ---------------------------------------------------------------------- report from a hand-made table
def _row(sample, scheme, success, wheels, err, rec):
    return {
        "sample": sample,
        "scheme": scheme,
        "seed": 100 + sample,
        "status": "ok",
        "success": success,
        "faulted_wheels": wheels,
        "failed_wheels": "none",
        "compensable": True,
        "n_faults": 1,
        "position_error_max": err,
        "recovery_time_max": rec,
    }


def test_report_rates_come_from_the_table(tmp_path):
    rows = [
        _row(0, "nominal", True, "1r", 0.1, 2.0),
        _row(1, "nominal", False, "2l", 0.9, None),
        _row(2, "nominal", False, "2l", 0.8, None),
        _row(3, "nominal", True, "1r", 0.2, 3.0),
        _row(0, "oracle", True, "1r", 0.05, 1.0),
        _row(1, "oracle", True, "2l", 0.06, 1.5),
        _row(2, "oracle", False, "2l", 0.7, None),
        _row(3, "oracle", True, "1r", 0.04, 1.0),
    ]
    records = {}
    for r in rows:
        records.setdefault(r["sample"], {"sample": r["sample"], "rows": []})["rows"].append(r)
    write_table(tmp_path, records.values())
    table = read_table(tmp_path / "results.csv")
    assert len(table) == 8
    # the Parquet table beside it: the same rows with typed columns (missing stays missing)
    pq = pd.read_parquet(tmp_path / "results.parquet")
    assert list(pq.columns) == list(table[0].keys()) and len(pq) == 8
    assert str(pq["sample"].dtype) == "Int64" and str(pq["success"].dtype) == "boolean"
    assert pq["position_error_max"].dtype == np.float64 and str(pq["faulted_wheels"].dtype).startswith("string")
    assert pq["recovery_time_max"].isna().sum() == 3 and pq["recovery_time_max"].sum() == pytest.approx(8.5)
    assert pq["success"].tolist() == [r["success"] for r in table]
    nominal_1 = next(r for r in table if r["sample"] == 1 and r["scheme"] == "nominal")
    assert nominal_1["recovery_time_max"] is None and nominal_1["success"] is False
    s = summarize(table)
    nom, ora = s["schemes"]["nominal"], s["schemes"]["oracle"]
    assert (nom["successes"], nom["n"], nom["rate"]) == (2, 4, 0.5)
    assert ora["rate"] == 0.75
    # Wilson 95 %, by hand: p = 0.5, n = 4, z = 1.96: centre 0.5, half 0.3500 (to 4 digits)
    assert nom["wilson_low"] == pytest.approx(0.1500, abs=1e-4)
    assert nom["wilson_high"] == pytest.approx(0.8500, abs=1e-4)
    assert nom["worst_patterns"][0] == {"faulted_wheels": "2l", "failures": 2, "samples": 2}
    assert ora["vs_nominal"] == {"samples": 4, "better": 1, "worse": 0}
    assert nom["vs_oracle"] == {"samples": 4, "better": 0, "worse": 1}
    assert nom["recovery_never"] == 2 and sorted(nom["recovery_times"]) == [2.0, 3.0]
    (tmp_path / "campaign.json").write_text(json.dumps({"case": "hand", "seed": 0, "base": {}}))
    page = render_campaign(tmp_path, table)
    html = page.read_text()
    assert "0.500" in html and "[0.150, 0.850]" in html and "<svg" in html
    # paired comparison: 0 samples only nominal succeeds, 1 only oracle: McNemar p = 1 (by hand)
    mc = next(c for c in s["comparisons"] if c["metric"] == "success")
    assert (mc["a"], mc["b"], mc["a_only"], mc["b_only"], mc["p"]) == ("nominal", "oracle", 0, 1, 1.0)
    assert "nominal vs oracle on success: no significant difference (exact McNemar p = 1;" in html
    rc = next(c for c in s["comparisons"] if c["metric"] == "recovery_time_max")
    assert rc["n"] == 2 and rc["mean"] == pytest.approx(((2.0 - 1.0) + (3.0 - 1.0)) / 2)  # samples 0 and 3
    assert json.loads((tmp_path / "summary.json").read_text())["schemes"]["oracle"]["successes"] == 3


def _stopped_rows() -> list[dict]:
    """Two schemes on 8 samples (the newuser12 W1 campaign, made by hand): adaptive recovers 1 s sooner than
    active on every sample, except that adaptive's run of sample 6 stopped at 0.1 s (step_unstable, before
    its faults) with the truncated run's metrics in its row (final error 0.2418 m, recovery time 0 s), and
    active's run of sample 3 diverged at 12 s (with a recovery time 1.0 s and a final error 5 m)."""
    rows = []
    for i in range(8):
        wheels = "1r+2l" if i >= 6 else "1r"
        act = _row(i, "active", True, wheels, 0.30, 2.0 + 0.5 * i) | {"position_error_final": 0.01, "t_end": 20.0}
        ada = _row(i, "adaptive", True, wheels, 0.25, 1.0 + 0.5 * i) | {"position_error_final": 0.005, "t_end": 20.0}
        if i == 3:
            act |= {"status": "diverged", "success": False, "t_end": 12.0, "position_error_final": 5.0}
            act |= {"recovery_time_max": 1.0, "position_error_max": 9.0}
        if i == 6:
            ada |= {"status": "step_unstable", "success": False, "t_end": 0.1, "position_error_final": 0.2418}
            ada |= {"recovery_time_max": 0.0, "position_error_max": 0.2418}
        rows += [act, ada]
    return rows


def test_a_run_stopped_early_enters_no_distribution_or_comparison(tmp_path):
    """newuser12 W1: adaptive's run of sample 6 stopped at 0.1 s (step_unstable), yet its truncated metrics
    counted it as recovered in 0 s in the recovery CDF and in the paired recovery-time comparison, and its
    fault pattern was charged with an integrator failure; the page never said step_unstable.  A run whose
    status is not ok now counts as a failure and nowhere else: it is counted by status per scheme, shown
    with its status and t_end among the failing samples, and charged to its fault pattern only when the
    loop stopped it (diverged, singular), not the step (step_unstable) or the program (error)."""
    from ftcreport.report.campaign import failing_samples

    rows = _stopped_rows()
    s = summarize(rows)
    ada, act = s["schemes"]["adaptive"], s["schemes"]["active"]
    # still failures in the success rate: 7 of 8 each
    assert (ada["successes"], ada["n"], act["successes"], act["n"]) == (7, 8, 7, 8)
    assert ada["stopped"] == {"step_unstable": 1} and act["stopped"] == {"diverged": 1}
    assert ada["completed"] == act["completed"] == 7
    # the distributions hold the 7 completed runs: no 0 s recovery, no truncated max error
    assert sorted(ada["recovery_times"]) == [1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.5]
    assert sorted(act["recovery_times"]) == [2.0, 2.5, 3.0, 4.0, 4.5, 5.0, 5.5]
    assert ada["recovery_never"] == act["recovery_never"] == 0
    assert ada["max_errors"] == [0.25] * 7 and act["max_errors"] == [0.30] * 7
    # the paired comparisons treat the stopped runs as missing: samples 3 and 6 drop out of every metric,
    # leaving 6 pairs whose recovery differences are all exactly -1 s (with them: 8 pairs, mean -1.125 s)
    by = {c["metric"]: c for c in s["comparisons"] if {c["a"], c["b"]} == {"adaptive", "active"}}
    rec = by["recovery_time_max"]
    assert (rec["a"], rec["n"]) == ("adaptive", 6)
    assert rec["mean"] == pytest.approx(-1.0, abs=1e-12) and rec["low"] == rec["high"] == pytest.approx(-1.0)
    assert by["position_error_final"]["n"] == by["position_error_max"]["n"] == 6
    assert by["position_error_final"]["mean"] == pytest.approx(0.005 - 0.01, abs=1e-12)
    # worst patterns: active's divergence is the loop's and charged to 1r (1 of its 6 samples); adaptive's
    # numerical stop is not charged to 1r+2l, where it has no other failure
    assert act["worst_patterns"] == [{"faulted_wheels": "1r", "failures": 1, "samples": 6}]
    assert ada["worst_patterns"] == []
    # failing samples: the failed scheme's status and t_end, no final error from a truncated run
    fail = {e["sample"]: e for e in failing_samples(rows)}
    assert sorted(fail) == [3, 6]
    assert fail[6]["stopped"] == {"adaptive": {"status": "step_unstable", "t_end": 0.1}}
    assert fail[6]["errors"]["adaptive"] is None and fail[6]["max_error"] == pytest.approx(0.01)
    assert fail[3]["stopped"] == {"active": {"status": "diverged", "t_end": 12.0}}
    # the page says it
    html = _render_hand(tmp_path, rows)
    rates = html.split('id="rates"', 1)[1].split("</table>", 1)[0]
    ada_row = rates.split('<td class="l">adaptive</td>', 1)[1].split("</tr>", 1)[0]
    assert "1 (step_unstable 1)" in ada_row
    table = html.split('id="failing-samples"', 1)[1].split("</table>", 1)[0]
    assert "step_unstable at 0.1 s" in table and "diverged at 12 s" in table and "0.242" not in table
    assert "adaptive (7/7; 1 stopped)" in html.split('id="fig-recovery"', 1)[1]


def _render_hand(out: Path, rows: list[dict]) -> str:
    """The campaign page of hand-made rows (their table written as a campaign writes it), as HTML."""
    records: dict = {}
    for r in rows:
        records.setdefault(r["sample"], {"sample": r["sample"], "rows": []})["rows"].append(r)
    write_table(out, records.values())
    (out / "campaign.json").write_text(json.dumps({"case": "hand", "seed": 0, "base": {}}))
    return render_campaign(out, read_table(out / "results.csv")).read_text()


def test_the_campaign_page_says_which_band_recovered_means_where_it_uses_the_word(tmp_path):
    """'Recovered' has two definitions: on a campaign page a run settles in the case's recovery_band (0.01 m),
    on a coverage page it meets the success criteria (a final error within 0.05 m).  The campaign page defined
    its own in one paragraph, but the rates table's 'never recovered', the paired comparisons and the recovery
    figure used the word bare.  Each now names the band and where it comes from, and the definition says what a
    coverage page means by the word instead.  The numbers are unchanged."""
    import re

    rows = [_row(i, s, True, "1r", 0.1, 1.0 + i) for i in range(3) for s in ("nominal", "switching", "oracle")]
    records: dict = {}
    for r in rows:
        records.setdefault(r["sample"], {"sample": r["sample"], "rows": []})["rows"].append(r)
    write_table(tmp_path, records.values())
    base = {"recovery_band": 0.01, "campaign": {"success": {"position_error_final": {"min": None, "max": 0.05}}}}
    (tmp_path / "campaign.json").write_text(json.dumps({"case": "hand", "seed": 0, "base": base}))
    html = render_campaign(tmp_path, read_table(tmp_path / "results.csv")).read_text()
    text = lambda h: re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", h))  # noqa: E731
    head = html.split('id="rates"', 1)[1].split("</thead>", 1)[0]
    (th,) = [c for c in re.findall(r"<th[^>]*>.*?</th>", head, re.S) if "never recovered" in c]
    assert "0.01 m" in text(th) and "recovery_band" in th, th  # the band on the column, its source in its title
    definition = text(html.split('id="recovery-definition"', 1)[1].split("</p>", 1)[0])
    assert "recovery_band" in definition and "0.01 m" in definition, definition
    assert "coverage page" in definition and "success" in definition, definition
    paired = text(html.split("Is the difference real?", 1)[1].split("</p>", 1)[0])
    assert "both recovered into the 0.01 m band" in paired, paired
    fig = text(html.split('id="fig-recovery"', 1)[1].split("</figcaption>", 1)[0])
    assert "recovered into the 0.01 m recovery band" in fig, fig


def test_a_comparison_on_too_few_pairs_is_shown_as_not_judged(tmp_path):
    """newuser12 W2: a matrix cell on 2 pairs was coloured as a win.  On 3 pairs whose recovery differences are
    all -1 s (adaptive recovers 1 s sooner; the old rule: a CI [-1, -1], 'adaptive better'), the cell now says
    not judged, and the page says how many pairs a verdict needs (6 at 95 %: 2^(1 - 6) <= 0.05)."""
    from ftcreport.report.campaign import comparison_matrices

    rows = [r for r in _stopped_rows() if r["sample"] < 3]
    s = summarize(rows)
    assert s["min_pairs"] == 6
    (mx,) = [m for m in comparison_matrices(s) if m["metric"] == "recovery_time_max"]
    (row,) = [r for r in mx["rows"] if r["scheme"] == "adaptive"]
    cell = row["cells"][mx["schemes"].index("active")]
    assert (cell["text"], cell["cls"]) == ("not judged", "nj")
    assert cell["short"] == "-1 (3 pairs)"  # the mean difference adaptive - active, as exact as the rows
    html = _render_hand(tmp_path, rows)
    matrix = html.split('id="matrix-recovery_time_max"', 1)[1].split("</table>", 1)[0]
    assert 'class="nj"' in matrix and "better" not in matrix
    assert "adaptive vs active on recovery_time_max: too few paired samples (3; a verdict needs 6)" in html
    assert "at least 6 pairs" in html


def _hand_campaign(out: Path) -> Path:
    """A campaign page from a hand-made table: switching and oracle have the same max errors on every sample
    (the initial offset sets them), their final errors differ 100-fold; nominal has its own max errors."""
    rows = []
    for i, (err, nom) in enumerate([(0.05, 0.3), (0.25, 0.4), (0.3, 1.5)]):
        for s, e, fin in (("nominal", nom, 0.2), ("switching", err, 1e-3), ("oracle", err * (1 + 1e-4), 1e-5)):
            rows.append(_row(i, s, True, "1r", e, 1.0) | {"position_error_final": fin})
    records = {}
    for r in rows:
        records.setdefault(r["sample"], {"sample": r["sample"], "rows": []})["rows"].append(r)
    write_table(out, records.values())
    (out / "campaign.json").write_text(json.dumps({"case": "hand", "seed": 0, "base": {}}))
    return render_campaign(out, read_table(out / "results.csv"))


def test_coinciding_ecdf_lines_are_told_apart(tmp_path):
    """Issue 35 item 7: in the max-error ECDF the schemes' lines coincided and the oracle's, drawn last, hid
    the others.  Coinciding lines now carry markers of their own (concentric, hollow) and the caption names
    them and the metric that separates them."""
    html = _hand_campaign(tmp_path).read_text()
    fig = html.split('id="fig-max-error"', 1)[1].split("</figure>", 1)[0]
    caption = fig.split("<figcaption>", 1)[1]
    assert "switching and oracle coincide" in caption
    assert "the final error separates them (medians switching 0.001 m, oracle 1e-05 m;" in caption
    assert "nominal" not in caption
    svg = fig.split("<svg", 1)[1]
    assert "switching (3/3; coincides with oracle)" in svg and "oracle (3/3; coincides with switching)" in svg
    assert "nominal (3/3)" in svg


def test_campaign_links_only_to_an_index_that_exists(tmp_path):
    """Issue 35 item 7: the campaign page linked 'all cases' to ../../index.html, broken under a custom --out;
    it links the index only where one exists."""
    alone = tmp_path / "alone"
    alone.mkdir()
    assert "../../index.html" not in _hand_campaign(alone).read_text()
    nested = tmp_path / "reports" / "campaigns" / "hand"
    nested.mkdir(parents=True)
    (tmp_path / "reports" / "index.html").write_text("<html></html>")
    assert '<a href="../../index.html">all cases</a>' in _hand_campaign(nested).read_text()


def test_wilson_interval_edges():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(10 / (10 + 1.959963984540054**2), rel=1e-12)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and math.isclose(hi, 1 - wilson_interval(10, 10)[0], rel_tol=1e-12)


# ---------------------------------------------------------------------- a real cluster: dask scheduler + 2 workers
WORKER_FLAGS = ("--no-nanny", "--no-dashboard", "--death-timeout", "60")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scheduler():
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 (random free port), killed at teardown."""
    from distributed import Client

    dask = str(Path(sys.executable).parent / "dask")
    addr = f"tcp://127.0.0.1:{_free_port()}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "start_new_session": True}
    procs = [
        subprocess.Popen(
            [dask, "scheduler", "--host", "127.0.0.1", "--port", addr.rsplit(":", 1)[1], "--no-dashboard"], **quiet
        )
    ]
    try:
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [dask, "worker", addr, "--host", "127.0.0.1", "--nthreads", "1", *WORKER_FLAGS],
                    **quiet,
                )
            )
        with Client(addr, timeout=60) as c:
            c.wait_for_workers(2, timeout=120)
        yield addr
    finally:
        for p in procs:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=30)


def test_old_key_rule_collides_and_the_new_one_does_not(scheduler, base):
    """Two clients, two different functions under one key: the scheduler hands the second client the
    first one's result.  The old key ``sample-{seed}-{i}`` was one key for two campaigns on seed 0."""
    from distributed import Client

    with Client(scheduler, timeout=30) as a, Client(scheduler, timeout=30) as b:
        old = "sample-0-0"  # the old rule for two campaigns on the default seed
        fa = a.submit(operator.add, 2, 3, key=old)
        assert fa.result(timeout=60) == 5
        fb = b.submit(operator.mul, 2, 3, key=old)
        assert fb.result(timeout=60) == 5  # the wrong answer, silently: 2 * 3 = 6
        other = parse_case(_base_data() | {"description": "another campaign"}, "other")
        ka = task_key("campaign", campaign_hash(base, SCHEMES, 0), 0)
        kb = task_key("campaign", campaign_hash(other, SCHEMES, 0), 0)
        ga = a.submit(operator.add, 2, 3, key=ka)
        gb = b.submit(operator.mul, 2, 3, key=kb)
        assert (ga.result(timeout=60), gb.result(timeout=60)) == (5, 6)


def _cli(case: Path, out: Path, n: int, scheduler: str, schemes: str) -> list[str]:
    cmd = [sys.executable, "-m", "ftcreport.cli", "campaign", str(case), "-n", str(n), "--quiet"]
    return [*cmd, "--scheduler", scheduler, "--schemes", schemes, "--out", str(out)]


def test_two_campaigns_on_one_scheduler_do_not_mix(scheduler, tmp_path):
    """Two different campaigns, both on the default seed 0, at the same time from two client processes."""
    da = _base_data()
    db = _base_data()
    db["campaign"]["sigma"] = [0.6, 0.9]  # another campaign: other gains, another scheme list
    db["campaign"]["faults"] = [2, 2]
    procs = []
    for name, data, schemes in (("a", da, "nominal,oracle"), ("b", db, "oracle,nominal")):
        (tmp_path / f"{name}.toml").write_text(tomli_w.dumps(data))
        cmd = _cli(tmp_path / f"{name}.toml", tmp_path / name, 4, scheduler, schemes)
        procs.append(subprocess.Popen(cmd, cwd=tmp_path))
    assert [p.wait(timeout=300) for p in procs] == [0, 0]
    for name, data, schemes in (("a", da, SCHEMES), ("b", db, ["oracle", "nominal"])):
        ref = run_campaign(
            parse_case(data, name), 4, tmp_path / f"{name}-ref", schemes=schemes, in_process=True, show_progress=False
        )
        assert _metric_rows(tmp_path / name / "results.csv") == _metric_rows(ref.table), name
        h = campaign_hash(parse_case(data, name), schemes, 0)
        assert {json.loads(p.read_text())["campaign"] for p in (tmp_path / name / "samples").glob("*.json")} == {h}
    rows_b = read_table(tmp_path / "b" / "results.csv")
    assert all(r["n_faults"] == 2 for r in rows_b)  # b's own draws, not a's (1 or 2 faults)
    man = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert len(man["workers"]) == 2 and all(v["ftcreport"] == __version__ for v in man["workers"].values())
    # the warm-up plugin ran once on each worker (the kernels loaded before any sample)
    from distributed import Client

    with Client(scheduler, timeout=30) as c:
        secs = c.run(lambda dask_worker: getattr(dask_worker.plugins.get("ftcreport-warm-up"), "seconds", None))
    assert len(secs) == 2 and all(isinstance(v, float) and v > 0 for v in secs.values())


def test_killed_campaign_resumes_on_a_real_scheduler(scheduler, tmp_path):
    """The client killed mid-way (the workers stay); resumed on the same scheduler to exactly N samples."""
    data = _base_data()
    data["simulation"]["duration"] = 6.0
    case = tmp_path / "short.toml"
    case.write_text(tomli_w.dumps(data))
    out, n = tmp_path / "camp", 30
    proc = subprocess.Popen(_cli(case, out, n, scheduler, "oracle"), cwd=tmp_path, start_new_session=True)
    deadline = time.time() + 240
    while time.time() < deadline and len(list((out / "samples").glob("*.json"))) < 3 and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = len(list((out / "samples").glob("*.json")))
    assert 3 <= before < n
    base = parse_case(data, str(case))
    res = run_campaign(base, n, out, schemes=["oracle"], scheduler=scheduler, show_progress=False)
    assert res.skipped == before and len(res.completed) == n - before and not res.failed
    rows = read_table(out / "results.csv")
    assert sorted(r["sample"] for r in rows) == list(range(n))
    fresh = run_campaign(base, n, tmp_path / "fresh", schemes=["oracle"], in_process=True, show_progress=False)
    assert _metric_rows(fresh.table) == _metric_rows(out / "results.csv")


def test_coverage_runs_on_the_real_scheduler(scheduler, tmp_path):
    """The coverage map takes the same Dask path: equal to in-process, keys from its own hash."""
    from ftcreport.studies.coverage import run_coverage

    data = _base_data()
    data["simulation"]["duration"] = 6.0
    data["campaign"]["fault_time"] = [1.0, 4.0]
    base = parse_case(data, "cov")
    kw = {"schemes": ["oracle"], "kinds": ("loss",), "times": [3.0], "show_progress": False}
    a = run_coverage(base, tmp_path / "dask", scheduler=scheduler, **kw)
    b = run_coverage(base, tmp_path / "inproc", in_process=True, **kw)
    assert len(a.completed) == 4 and not a.failed and len(a.workers) == 2
    ra = read_table(a.table)
    assert ra == read_table(b.table) and all(r["recovered"] for r in ra)


@pytest.fixture(scope="module")
def failing_campaign(tmp_path_factory):
    """3 samples with a success bound no run meets (final error <= 1 nm): every sample fails, so the
    campaign's page has failing samples to link; the worst one's page is rendered with it."""
    data = _base_data()
    data["campaign"]["success"] = {"position_error_final": {"max": 1e-9}}
    base = parse_case(data, "two_link_campaign_strict")
    out = tmp_path_factory.mktemp("campaign_pages")
    res = run_campaign(base, 3, out, seed=5, schemes=SCHEMES, in_process=True, show_progress=False)
    assert not res.failed
    page = render_campaign(out, read_table(res.table), worst=1)
    return out, page


def test_the_worst_failing_sample_has_its_page_with_the_campaigns_runs(failing_campaign):
    """Issue 35 item 7: a failing sample opens from the campaign's table; its page is a case page of the
    sample's variant, re-simulated from its seeds, so its metrics are the campaign's (to round-off)."""
    from ftcreport.report.campaign import failing_samples, render_sample, sample_name

    out, page = failing_campaign
    rows = read_table(out / "results.csv")
    failing = failing_samples(rows)
    assert len(failing) == 3 and all(e["failed"] == ["nominal"] for e in failing)  # the oracle is not judged
    worst = failing[0]["sample"]
    assert failing[0]["max_error"] == max(e["max_error"] for e in failing)
    html = page.read_text()
    href = f'href="sample_pages/{sample_name(worst)}/index.html"'
    assert href in html, "the failing-samples table links the rendered sample"
    others = [e["sample"] for e in failing[1:]]
    assert all(f"ftcreport sample {out} {i}" in html for i in others)  # the command that renders the rest
    sample_page = out / "sample_pages" / sample_name(worst) / "index.html"
    shtml = sample_page.read_text()
    for marker in ('id="verdict"', 'id="replay"', 'id="fig-errors"', 'id="fig-torques"', 'href="../../index.html"'):
        assert marker in shtml, marker
    for s in SCHEMES:
        mine = json.loads((out / "sample_pages" / sample_name(worst) / s / "metrics.json").read_text())
        row = next(r for r in rows if r["sample"] == worst and r["scheme"] == s)
        for k in ("position_error_final", "position_error_max", "torque_peak"):
            assert mine[k] == pytest.approx(row[k], rel=1e-9, abs=1e-12), (s, k)
    # on demand: another sample's page
    again = render_sample(out, others[0])
    assert again.exists() and again.parent.name == sample_name(others[0])
    with pytest.raises(FtcError, match="not a campaign directory"):
        render_sample(out / "sample_pages", 0)


@pytest.mark.parametrize("indices", [["3"], ["99"], ["1", "99"]])
def test_sample_refuses_an_index_the_campaign_never_ran(failing_campaign, indices):
    """Issue 34 audit: ``sample DIR 99`` rendered a page (exit 0) for a sample the 3-sample campaign never
    ran; now exit 2 naming the range, before any page is rendered."""
    from typer.testing import CliRunner

    from ftcreport.cli import app
    from ftcreport.report.campaign import sample_name

    out, _ = failing_campaign
    before = sorted(p.name for p in (out / "sample_pages").iterdir())
    res = CliRunner().invoke(app, ["sample", str(out), *indices])
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    bad = indices[-1]
    assert f"sample {bad}: " in line and "samples 0 to 2" in line and str(out) in line, line
    assert sorted(p.name for p in (out / "sample_pages").iterdir()) == before  # nothing rendered
    assert not (out / "sample_pages" / sample_name(int(bad))).exists()


def test_pairwise_comparisons_are_a_matrix_and_distributions_ecdfs(failing_campaign):
    from ftcreport.report.campaign import comparison_matrices

    out, page = failing_campaign
    summary = json.loads((out / "summary.json").read_text())
    mats = comparison_matrices(summary)
    assert [m["metric"] for m in mats] == ["success", "position_error_final", "position_error_max", "recovery_time_max"]
    success = mats[0]
    assert success["schemes"] == SCHEMES
    (row_nominal,) = [r for r in success["rows"] if r["scheme"] == "nominal"]
    diag, vs_oracle = row_nominal["cells"]
    assert diag is None and vs_oracle["text"] == "n.s."  # both fail every sample: no discordant pair
    fin = mats[1]
    (row_nominal,) = [r for r in fin["rows"] if r["scheme"] == "nominal"]
    (row_oracle,) = [r for r in fin["rows"] if r["scheme"] == "oracle"]
    # the same comparison seen from both sides: one sentence, opposite mean differences; on 3 pairs no verdict
    # (a metric verdict needs min_pairs = 6 at 95 %; newuser12 W2)
    a, b = row_nominal["cells"][1], row_oracle["cells"][0]
    assert a["cls"] == b["cls"] == "nj" and a["title"] == b["title"] and "(3 pairs)" in a["short"]
    mean_a, mean_b = (float(c["short"].split()[0]) for c in (a, b))
    assert mean_a == pytest.approx(-mean_b)
    html = page.read_text()
    assert 'id="matrix-success"' in html and 'id="matrix-position_error_final"' in html
    assert "Empirical CDF" in html and "fraction of samples" in html


# ---------------------------------------------------------------------- the adversarial tester's breaks
@pytest.mark.parametrize(
    ("success", "field", "reason"),
    [
        ({"position_eror_final": {"max": 0.05}}, "position_eror_final", "unknown metric (did you mean 'position_error"),
        ({"engine": {"max": 1}}, "engine", "unknown metric (a nominal run writes t_end, "),
        ({"phases": {"max": 1}}, "phases", "'phases' is not a number (a record)"),
        ({"chi_hat_min": {"min": 0.1}}, "chi_hat_min", "'chi_hat_min' is not a metric of the nominal scheme"),
        ({"position_error_final": {}}, "position_error_final", "give min, max or both"),
    ],
)
def test_a_success_bound_on_no_numeric_metric_is_refused_at_validation(tmp_path, success, field, reason):
    """A misspelt metric validated and then failed every sample; a non-numeric one crashed every sample
    (TypeError); one that a scheme of the case never writes failed that scheme's every sample.  Now refused
    by 'cases validate' as [thresholds] are: the file, the field, the reason."""
    from typer.testing import CliRunner

    from ftcreport.cli import app

    data = _base_data()
    data["campaign"]["success"] = success
    case = tmp_path / "typo.toml"
    case.write_text(tomli_w.dumps(data))
    res = CliRunner().invoke(app, ["cases", "validate", str(case)])
    assert res.exit_code == 2, res.output
    assert f"{case}: campaign.success.{field}: {reason}" in res.stderr, res.stderr
    with pytest.raises(CaseError, match=rf"campaign\.success\.{field}: "):
        parse_case(data, "typo.toml")


def test_a_success_bound_reads_an_entry_of_a_table_metric():
    """Validation accepts ``metric.key`` (an entry of a table metric, as [thresholds] do): the verdict reads it."""
    from ftcreport.studies.campaign import _success

    m = {"status": "ok", "fault_estimation_errors_final": {"1r": 0.01, "1l": 0.3}}
    assert _success(m, {"fault_estimation_errors_final.1r": {"max": 0.05}})
    assert not _success(m, {"fault_estimation_errors_final.1l": {"max": 0.05}})
    assert not _success(m, {"fault_estimation_errors_final.2r": {"max": 0.05}})  # absent: not a success


@pytest.mark.parametrize(
    ("schemes", "reason"),
    [
        ("nominal,nominal", "--schemes: 'nominal' is named twice"),
        ("oracle, nominal ,oracle", "--schemes: 'oracle' is named twice"),
        (",", "--schemes: names no scheme"),
        ("", "--schemes: names no scheme"),
    ],
)
def test_campaign_refuses_a_repeated_or_empty_scheme_list(tmp_path, schemes, reason):
    """``--schemes nominal,nominal`` ran nominal twice per sample (its Wilson interval on twice the samples);
    ``--schemes ,`` ran nothing and exited 0.  Now bad input: exit 2, one line, no output directory."""
    from typer.testing import CliRunner

    from ftcreport.cli import app

    out = tmp_path / "out"
    case = str(ROOT / "cases" / "two_link_campaign.toml")
    res = CliRunner().invoke(
        app, ["campaign", case, "-n", "1", "--in-process", "-q", "--out", str(out), "--schemes", schemes]
    )
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    assert reason in line, line
    assert not out.exists()


def _strict_case(path: Path, x: float) -> Path:
    """The short campaign base with a success bound no run meets (every sample fails, so the campaign renders
    its failing samples' pages) and the initial offset ``x``; written to ``path``."""
    data = _base_data()
    data["campaign"]["success"] = {"position_error_final": {"max": 1e-9}}
    data["initial"]["x"] = x
    path.write_text(tomli_w.dumps(data))
    return path


def test_force_with_another_case_content_leaves_no_stale_sample_page(tmp_path):
    """``campaign --force`` with a changed case into the same --out kept the sample pages rendered from the
    earlier content, and the new page linked them as current.  Now every linked page is the new content's."""
    from typer.testing import CliRunner

    from ftcreport.cli import app
    from ftcreport.report.campaign import sample_name

    out = tmp_path / "out"
    args = ["-n", "2", "--in-process", "-q", "--schemes", "nominal", "--out", str(out)]
    first = CliRunner().invoke(app, ["campaign", str(_strict_case(tmp_path / "c.toml", 0.2)), *args])
    assert first.exit_code == 0, first.output
    pages = out / "sample_pages"
    old = {i: (pages / sample_name(i) / "nominal" / "metrics.json").read_text() for i in (0, 1)}
    again = CliRunner().invoke(app, ["campaign", str(_strict_case(tmp_path / "c.toml", 0.5)), *args, "--force"])
    assert again.exit_code == 0, again.output
    rows = read_table(out / "results.csv")
    html = (out / "index.html").read_text()
    for i in (0, 1):
        assert f'href="sample_pages/{sample_name(i)}/index.html"' in html
        page = json.loads((pages / sample_name(i) / "nominal" / "metrics.json").read_text())
        assert page != json.loads(old[i])
        (row,) = [r for r in rows if r["sample"] == i]
        assert page["position_error_final"] == pytest.approx(row["position_error_final"], rel=1e-9, abs=1e-12)


def test_sample_refuses_a_changed_scheme_file(tmp_path):
    """``sample OUT K`` re-simulated sample K with the scheme files on disk now, silently, where ``campaign``
    refuses to resume from another base case content.  Now it refuses too (exit 2), naming the changed file."""
    from typer.testing import CliRunner

    from ftcreport.cli import app
    from ftcreport.report.campaign import sample_name

    plugin = tmp_path / "campaign_copy_scheme.py"
    plugin.write_text(
        (ROOT / "tests" / "data" / "copy_nominal_scheme.py").read_text().replace("copy_nominal", "campaign_copy")
    )
    data = _base_data()
    data["plugins"] = [str(plugin)]
    data["schemes"]["campaign_copy"] = {}
    base = parse_case(data, "two_link_campaign_plugin")
    out = tmp_path / "out"
    run_campaign(base, 2, out, seed=3, schemes=["campaign_copy"], in_process=True, show_progress=False)
    ok = CliRunner().invoke(app, ["sample", str(out), "0"])
    assert ok.exit_code == 0, ok.output  # the content it ran: rendered
    plugin.write_text(plugin.read_text() + "\n# the law changed since the campaign ran\n")
    res = CliRunner().invoke(app, ["sample", str(out), "1"])
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    assert line.startswith(f"ftcreport: error: {plugin}: changed since the campaign in {out} ran"), line
    assert not (out / "sample_pages" / sample_name(1)).exists()


def test_resume_with_fewer_samples_reports_the_first_n_and_keeps_the_rest(tmp_path):
    """A resume with a smaller --samples reported every stored sample (summary: 3 samples) while ``sample OUT 2``
    refused ("ran samples 0 to 1").  Now the table, summary and page are the first n, as a fresh campaign of n;
    the samples beyond stay stored (a larger --samples later reuses them) and the CLI says so."""
    from typer.testing import CliRunner

    from ftcreport.cli import app
    from ftcreport.report.campaign import check_sample_index

    case = tmp_path / "c.toml"
    case.write_text(tomli_w.dumps(_base_data()))
    out = tmp_path / "out"
    args = ["campaign", str(case), "--in-process", "-q", "--schemes", "nominal", "--seed", "4", "--out", str(out)]
    first = CliRunner().invoke(app, [*args, "-n", "3"])
    assert first.exit_code == 0, first.output
    fewer = CliRunner().invoke(app, [*args, "-n", "2"])
    assert fewer.exit_code == 0, fewer.output
    assert "0 samples run, 2 already done" in fewer.stdout and "1 stored sample beyond --samples 2" in fewer.stdout
    assert sorted({r["sample"] for r in read_table(out / "results.csv")}) == [0, 1]
    assert set(pd.read_parquet(out / "results.parquet")["sample"]) == {0, 1}
    assert json.loads((out / "summary.json").read_text())["n_samples"] == 2
    assert sorted(json.loads((out / "manifest.json").read_text())["seeds"]["samples"]) == ["0", "1"]
    assert _record_path(out, 2).exists()  # kept: not lost, not shown
    assert check_sample_index(out, 1) == 1
    with pytest.raises(FtcError, match=r"ran samples 0 to 1 \(sample 2 is stored from a run with more samples"):
        check_sample_index(out, 2)
    more = CliRunner().invoke(app, [*args, "-n", "3"])
    assert more.exit_code == 0, more.output
    assert "0 samples run, 3 already done" in more.stdout
    assert sorted({r["sample"] for r in read_table(out / "results.csv")}) == [0, 1, 2]


def test_nothing_left_to_run_starts_no_cluster(base, tmp_path, monkeypatch, capsys):
    """All samples stored: before, a re-run started a LocalCluster anyway and printed "--workers 2: capped
    at 1 (the number of samples to run)" with 0 to run.  Now it reports from what is stored."""
    import dask.distributed

    out = tmp_path / "c"
    run_campaign(base, 2, out, schemes=["nominal"], in_process=True, show_progress=False)
    capsys.readouterr()

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started with nothing to run")

    monkeypatch.setattr(dask.distributed, "LocalCluster", no_cluster)
    monkeypatch.setattr(dask.distributed, "Client", no_cluster)
    res = run_campaign(base, 2, out, schemes=["nominal"], workers=2, show_progress=False)
    assert (res.skipped, res.completed, res.failed) == (2, [], {})
    assert "capped" not in capsys.readouterr().err
    assert len(read_table(res.table)) == 2


def test_an_interrupt_counts_the_samples_stored_before_this_run(base, tmp_path, monkeypatch):
    """The interrupt message counts what is stored, not only what this run finished: before, a re-run
    stopped with every sample stored said "interrupted before any sample finished; nothing was stored"."""
    from ftcreport.errors import interrupted_message
    from ftcreport.infra.lifetime import Interrupted
    from ftcreport.studies import campaign as mod

    out = tmp_path / "c"
    run_campaign(base, 2, out, schemes=["nominal"], in_process=True, show_progress=False)

    def stop(_):
        raise Interrupted(signal.SIGINT)

    with pytest.raises(KeyboardInterrupt) as got:  # one more sample finishes, then the signal
        run_campaign(base, 4, out, schemes=["nominal"], in_process=True, show_progress=False, on_sample=stop)
    resume = "; 3 finished samples are stored, re-run the same command to resume"
    assert interrupted_message(got.value) == "interrupted" + resume

    def stop_table(*a, **k):
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(mod, "write_table", stop_table)  # stopped before any sample runs: the 3 stored count
    with pytest.raises(KeyboardInterrupt) as got:
        run_campaign(base, 3, out, schemes=["nominal"], in_process=True, show_progress=False)
    assert interrupted_message(got.value) == "interrupted by SIGTERM" + resume


def _kept_base_fault_case(tmp_path: Path, fault_time: list[float]) -> Path:
    """The example campaign keeping a base fault on wheel 1r at 10 s, drawing one fault on 1r only."""
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    data["faults"] = [{"time": 10.0, "wheel": "1r", "sigma": 0.5}]
    data["campaign"] |= {"keep_base_faults": True, "wheels": ["1r"], "fault_time": fault_time, "faults": [1, 1]}
    path = tmp_path / "kept.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_a_drawn_fault_that_must_coincide_with_a_kept_one_is_refused_at_validation(tmp_path):
    """keep_base_faults with a base fault on 1r at 10 s, wheels ["1r"], fault_time [10, 10]: before, it
    validated and every sample failed with "a second event on wheel 1r at t = 10.0"."""
    from ftcreport.cases import load_case

    path = _kept_base_fault_case(tmp_path, [10.0, 10.0])
    with pytest.raises(CaseError) as got:
        load_case(path)
    msg = str(got.value)
    assert str(path) in msg and "campaign.fault_time" in msg, msg
    assert "1r" in msg and "keep_base_faults" in msg and "faults[0]" in msg, msg


def test_a_drawn_fault_never_coincides_with_a_kept_one(tmp_path):
    """A range where half the drawn times (to the ms) land on the kept fault's 10 s: the draw takes another
    time instead of making a variant that cannot run (before: CaseError, "a second event on wheel 1r")."""
    from ftcreport.cases import load_case

    base = load_case(_kept_base_fault_case(tmp_path, [9.999, 10.001]))
    times = []
    for i in range(30):
        v = draw_variant(base, sample_seeds(0, i))
        on_1r = sorted(f.time for f in v.faults if f.wheel == "1r")
        assert len(on_1r) == 2 and on_1r[0] != on_1r[1], on_1r
        times += on_1r
    assert {9.999, 10.001} <= set(times)


def test_sample_refuses_a_campaign_another_package_version_computed(failing_campaign, tmp_path):
    """``sample`` re-simulates a sample with the code installed now; a campaign another ftcreport version
    computed (its case content unchanged) got a page whose numbers need not be the campaign's table's, where
    ``campaign`` refuses to resume such records.  Now it refuses (exit 2), naming both versions."""
    import shutil

    from typer.testing import CliRunner

    from ftcreport import __version__
    from ftcreport.cli import app

    src, _ = failing_campaign
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    meta = json.loads((out / "campaign.json").read_text())
    assert meta["version"] == __version__
    meta["version"] = "0.0.1"
    (out / "campaign.json").write_text(json.dumps(meta))
    before = sorted(p.name for p in (out / "sample_pages").iterdir())
    res = CliRunner().invoke(app, ["sample", str(out), "2"])
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    assert f"{out / 'campaign.json'}: " in line and "0.0.1" in line and __version__ in line, line
    assert "--force" in line, line
    assert sorted(p.name for p in (out / "sample_pages").iterdir()) == before  # nothing rendered


def _without_times(rec: dict) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("wall_time", "compile_time")} for r in rec["rows"]]


@pytest.fixture(scope="module")
def stored_pair(base, tmp_path_factory):
    """A campaign of 2 samples (nominal), kept pristine: a test copies it and damages the copy."""
    out = tmp_path_factory.mktemp("stored_pair") / "out"
    res = run_campaign(base, 2, out, seed=2, schemes=["nominal"], in_process=True, show_progress=False)
    assert not res.failed
    return out


def _damaged_copy(stored_pair: Path, tmp_path: Path, damage) -> tuple[Path, dict]:
    """A copy of ``stored_pair`` whose sample 1 is ``damage``d (the file rewritten as an editor would); its
    record as it was."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(stored_pair, out)
    p = _record_path(out, 1)
    rec = json.loads(p.read_text())
    d = json.loads(p.read_text())
    damage(d)
    p.write_text(json.dumps(d))
    return out, rec


@pytest.mark.parametrize(
    ("damage", "field"),
    [
        (lambda d: d.pop("rows"), "rows: missing"),
        (lambda d: d.__setitem__("rows", 5), "rows: the number 5, not a list"),
        (lambda d: d.__setitem__("rows", [5]), "rows[0]: the number 5, not a table"),
        (lambda d: d.__setitem__("rows", []), "rows: empty"),
        (lambda d: d["rows"][0].pop("success"), "rows[0].success: missing"),
        (lambda d: d["rows"][0].__setitem__("success", "no"), "rows[0].success: the text 'no', not a boolean"),
        (lambda d: d["rows"][0].__setitem__("position_error_final", "abc"), "rows[0].position_error_final: the text"),
        (lambda d: d.__setitem__("sample", "1"), "sample: the text '1', not an integer"),
        (lambda d: [d.update(sample=0), *(r.update(sample=0) for r in d["rows"])], "sample: 0, the file's name says 1"),
    ],
)
def test_a_malformed_sample_record_is_not_done_and_runs_again(base, stored_pair, tmp_path, capsys, damage, field):
    """A sample file with a damaged "rows" (missing, not a list, a list of numbers) made the re-run crash as a
    bug (exit 3, KeyError: 'rows' / TypeError), and an ill-typed field ("success": "no") was taken as it was
    (counted as a success, the parquet's typed columns turned to text).  A malformed record is not a result:
    it counts as not done, runs again, and one line on stderr names the file and the field."""
    out, rec = _damaged_copy(stored_pair, tmp_path, damage)
    capsys.readouterr()
    res = run_campaign(base, 2, out, seed=2, schemes=["nominal"], in_process=True, show_progress=False)
    assert (res.skipped, res.completed, res.failed, res.rerun_stale) == (1, [1], {}, 0)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ftcreport: note: {_record_path(out, 1)}: {field}"), lines[0]
    assert "runs again" in lines[0], lines[0]
    assert _without_times(json.loads(_record_path(out, 1).read_text())) == _without_times(rec)
    table = pd.read_parquet(out / "results.parquet")
    assert str(table["success"].dtype) == "boolean" and str(table["position_error_final"].dtype) == "float64"


def _flip_success(d: dict) -> None:
    for r in d["rows"]:
        r["success"] = not r["success"]
        r["position_error_final"] = 0.001


def test_a_sample_record_edited_by_hand_is_not_a_result(base, stored_pair, tmp_path, capsys):
    """A stored sample whose success flag and final error were edited by hand (the file well formed) was taken
    as it was: the table and summary counted it.  Every sample record is sealed with the SHA-256 of its content;
    one whose seal does not match is not a result: it runs again, and a note on stderr names the file."""
    out, rec = _damaged_copy(stored_pair, tmp_path, _flip_success)
    assert isinstance(rec.get("sha256"), str) and len(rec["sha256"]) == 64
    want = summarize(read_table(stored_pair / "results.csv"))["schemes"]["nominal"]["successes"]
    capsys.readouterr()
    res = run_campaign(base, 2, out, seed=2, schemes=["nominal"], in_process=True, show_progress=False)
    assert (res.skipped, res.completed, res.failed, res.rerun_stale) == (1, [1], {}, 0)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ftcreport: note: {_record_path(out, 1)}: hash mismatch"), lines[0]
    assert _without_times(json.loads(_record_path(out, 1).read_text())) == _without_times(rec)
    assert summarize(read_table(res.table))["schemes"]["nominal"]["successes"] == want


def test_an_unsealed_sample_record_is_refused_and_force_runs_it_again(base, stored_pair, tmp_path):
    """A record without a seal (written before records were sealed, or its seal removed to pass an edit off
    as such a record) is never taken as a result: like a record of another version it is refused, and
    --force runs it again."""
    out, rec = _damaged_copy(stored_pair, tmp_path, lambda d: [d.pop("sha256", None), _flip_success(d)])
    with pytest.raises(FtcError, match=r"00000001.json: carries no seal \(sha256\)"):
        run_campaign(base, 2, out, seed=2, schemes=["nominal"], in_process=True, show_progress=False)
    res = run_campaign(base, 2, out, seed=2, schemes=["nominal"], in_process=True, show_progress=False, force=True)
    assert (res.skipped, res.completed, res.rerun_stale) == (1, [1], 1)
    assert _without_times(json.loads(_record_path(out, 1).read_text())) == _without_times(rec)


def test_resume_refuses_samples_another_code_or_numeric_library_computed(base, stored_pair, tmp_path, monkeypatch):
    """Resume keyed a stored sample on the package version only: after a change of the package's code (a fixed
    success rule, a metric) or of a numeric library, every stored sample was served as current, unlike the
    case-result cache (batch.run_key: code digest and numeric versions).  Now such samples are refused as
    stale, naming what changed, and --force runs them again."""
    import shutil

    from ftcreport.storage import code_digest, manifest

    out = tmp_path / "out"
    shutil.copytree(stored_pair, out)
    run = dict(base=base, samples=2, out=out, seed=2, schemes=["nominal"], in_process=True, show_progress=False)
    real = code_digest.code_digest()
    monkeypatch.setattr(code_digest, "DIGEST", "0123456789abcdef")  # a source file of the package changed
    with pytest.raises(FtcError, match=rf"00000000.json: was computed by other code .*{real}.*0123456789abcdef"):
        run_campaign(**run)
    monkeypatch.setattr(code_digest, "DIGEST", real)
    versions = manifest.numeric_versions()
    monkeypatch.setattr(manifest, "numeric_versions", lambda: versions | {"numpy": "0.0.1"})
    with pytest.raises(FtcError, match=rf"00000000.json: was computed with numpy {versions['numpy']}, now 0.0.1"):
        run_campaign(**run)
    res = run_campaign(**run, force=True)
    assert (res.rerun_stale, sorted(res.completed)) == (2, [0, 1])
    assert json.loads(_record_path(out, 0).read_text())["versions"]["numpy"] == "0.0.1"
    monkeypatch.undo()
    with pytest.raises(FtcError, match=r"was computed with numpy 0.0.1, now "):
        run_campaign(**run)


def test_sample_refuses_a_campaign_another_code_computed(failing_campaign, tmp_path, monkeypatch):
    """``sample`` re-simulates a sample with the code installed now; after a change of the package's code the
    page need not show the campaign's sample, where ``campaign`` refuses to resume.  Now it refuses too."""
    import shutil

    from typer.testing import CliRunner

    from ftcreport.cli import app
    from ftcreport.storage import code_digest

    src, _ = failing_campaign
    out = tmp_path / "copy"
    shutil.copytree(src, out)
    before = sorted(p.name for p in (out / "sample_pages").iterdir())
    monkeypatch.setattr(code_digest, "DIGEST", "0123456789abcdef")
    res = CliRunner().invoke(app, ["sample", str(out), "2"])
    assert res.exit_code == 2, res.output
    (line,) = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    assert f"{out / 'campaign.json'}: " in line and "other code" in line and "0123456789abcdef" in line, line
    assert sorted(p.name for p in (out / "sample_pages").iterdir()) == before  # nothing rendered


def test_sample_renders_the_campaign_page_from_the_sealed_records_not_an_edited_table(tmp_path):
    """``sample OUT K`` re-rendered the campaign's page and summary from ``results.csv`` as it found it: an
    edited table (every nominal run a success, a smaller final error) reached summary.json and the page.
    The table is a view of the sealed sample records; the page is now rendered from those (and the table
    rewritten from them)."""
    from typer.testing import CliRunner

    from ftcreport.cli import app

    case = tmp_path / "c.toml"
    data = _base_data()
    data["campaign"]["success"] = {"position_error_final": {"max": 1e-9}}  # no run meets it: all fail
    case.write_text(tomli_w.dumps(data))
    out = tmp_path / "out"
    args = ["campaign", str(case), "--in-process", "-q", "--schemes", "nominal", "--seed", "2", "--out", str(out)]
    first = CliRunner().invoke(app, [*args, "-n", "2"])
    assert first.exit_code == 0, first.output
    honest = json.loads((out / "summary.json").read_text())["schemes"]["nominal"]
    assert honest["successes"] == 0
    table = (out / "results.csv").read_text()
    lines = table.splitlines()
    cols = lines[0].split(",")
    at = cols.index("success")
    edited = [lines[0]] + [",".join("True" if j == at else c for j, c in enumerate(ln.split(","))) for ln in lines[1:]]
    (out / "results.csv").write_text("\n".join(edited) + "\n")
    res = CliRunner().invoke(app, ["sample", str(out), "0"])
    assert res.exit_code == 0, res.output
    assert json.loads((out / "summary.json").read_text())["schemes"]["nominal"]["successes"] == 0
    assert (out / "results.csv").read_text() == table  # the view rewritten from the records


def test_a_stopped_run_s_metrics_are_not_in_the_table(tmp_path):
    """A run that stopped early has metrics over [0, t_end] only: in results.csv and .parquet they would read as
    the run's (a mean over the column mixes 12 s of a diverging run with 60 s runs), so its metric cells are
    empty there; what it is and where it stopped (status, reason, t_end, the sample's columns) stay, and the
    sealed sample records keep every number (session 12's left-alone list)."""
    ok = _row(0, "nominal", True, "1r", 0.1, 2.0) | {"t_end": 60.0, "energy": 5.0, "reason": ""}
    stopped = _row(0, "oracle", False, "1r", 0.02, 1.0) | {
        "status": "diverged", "t_end": 12.5, "energy": 1.5, "reason": "the speed bound", "dt": 0.01,
    }  # fmt: skip
    record = {"sample": 0, "rows": [ok, dict(stopped)]}
    write_table(tmp_path, [record])
    table = {r["scheme"]: r for r in read_table(tmp_path / "results.csv")}
    assert table["nominal"]["position_error_max"] == 0.1 and table["nominal"]["energy"] == 5.0
    row = table["oracle"]
    assert row["position_error_max"] is None and row["recovery_time_max"] is None and row["energy"] is None
    assert (row["status"], row["t_end"], row["reason"], row["dt"]) == ("diverged", 12.5, "the speed bound", 0.01)
    assert (row["success"], row["faulted_wheels"], row["sample"]) == (False, "1r", 0)
    pq = pd.read_parquet(tmp_path / "results.parquet").set_index("scheme")
    assert pd.isna(pq.loc["oracle", "energy"]) and pq.loc["nominal", "energy"] == 5.0
    assert record["rows"][1]["energy"] == 1.5  # the record is not changed
