"""Monte Carlo campaigns (issue 10): Dask LocalCluster = in-process, kill and resume, the report's numbers."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest
import tomli_w

from ftcreport.campaign import (
    draw_variant,
    read_table,
    run_campaign,
    sample_seed,
    summarize,
    wilson_interval,
    write_table,
)
from ftcreport.cases import parse_case
from ftcreport.errors import CaseError, FtcError
from ftcreport.report.campaign import render_campaign

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
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in read_table(path)]


def test_seeds_and_draws_are_reproducible(base):
    assert sample_seed(7, 3) == sample_seed(7, 3)
    assert len({sample_seed(7, i) for i in range(1000)}) == 1000
    a, b = draw_variant(base, sample_seed(7, 3)), draw_variant(base, sample_seed(7, 3))
    assert a.model_dump() == b.model_dump()
    c = draw_variant(base, sample_seed(7, 4))
    assert c.model_dump() != a.model_dump()
    for i in range(50):
        v = draw_variant(base, sample_seed(1, i))
        assert 1 <= len(v.faults) <= 2
        assert all(2.0 <= f.time <= 5.0 and 0.0 <= f.sigma <= 0.5 for f in v.faults)
        assert len({f.wheel for f in v.faults}) == len(v.faults)


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
        time.sleep(0.2)
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
    assert json.loads((tmp_path / "summary.json").read_text())["schemes"]["oracle"]["successes"] == 3


def test_wilson_interval_edges():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(10 / (10 + 1.959963984540054**2), rel=1e-12)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and math.isclose(hi, 1 - wilson_interval(10, 10)[0], rel_tol=1e-12)
