"""Interruption and concurrency (issue 23), through real processes.

* A batch killed with SIGINT or SIGKILL at a random moment (its whole process group,
  workers included, as Ctrl-C or a kill of the job does), then re-run, ends with every
  run complete, metrics identical to an uninterrupted batch (``wall_time``, ``compile_time`` aside) and no
  truncated or temporary file left.
* Two batches started at once on the same ``--out``: the output directory's lock lets
  one run; the other fails at once with a message naming the holder (exit 2).  The
  same for two campaigns on one ``--out`` and for ``report`` while a batch writes.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ftcreport.cases import SCHEME_NAMES, load_case
from ftcreport.families import FAMILIES

CASES = Path(__file__).resolve().parents[1] / "cases"
pytestmark = pytest.mark.slow
CLI = [sys.executable, "-m", "ftcreport.cli"]


@pytest.fixture(scope="module")
def small_cases(tmp_path_factory):
    """Two two-link cases, three schemes each, 4 s long: a six-run batch."""
    d = tmp_path_factory.mktemp("cases")
    out = []
    for name in ("two_link_uncompensable", "two_link_intermittent"):
        data = tomllib.loads((CASES / f"{name}.toml").read_text())
        data.pop("thresholds", None)
        p = d / f"{name}.toml"
        p.write_text(tomli_w.dumps(data))
        out.append(str(p))
    return out


def _batch(cases, out, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "batch", *cases, "--out", str(out), "--duration", "4", "--jobs", "2", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: signals reach the workers too
        **kw,
    )


@pytest.fixture(scope="module")
def reference(small_cases, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    p = _batch(small_cases, out)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 0, err
    return out


def _snapshot(out: Path) -> dict:
    """Every run's metrics (wall time aside) and time series; asserts nothing is truncated."""
    snap = {}
    for m in sorted(out.glob("*/*/metrics.json")):
        d = m.parent
        metrics = json.loads(m.read_text())
        metrics.pop("wall_time", None)
        metrics.pop("compile_time", None)  # times, not results
        assert (d / "key").read_text().strip(), d
        with np.load(d / "timeseries.npz") as z:
            series = {k: z[k].copy() for k in z.files}
        snap[f"{d.parent.name}/{d.name}"] = (metrics, series)
    for page in [out / "index.html", *out.glob("*/index.html")]:
        assert page.read_text().rstrip().endswith("</html>"), page
    leftovers = [p for p in out.rglob("*") if p.name.endswith(".partial")]
    assert not leftovers, leftovers
    return snap


def _assert_same(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b) and len(a) == 2 * len(FAMILIES)  # two cases, every family (issue 21)
    for k in a:
        assert a[k][0] == b[k][0], k  # every metric identical (the engine is deterministic)
        assert sorted(a[k][1]) == sorted(b[k][1]), k
        for s in a[k][1]:
            np.testing.assert_array_equal(a[k][1][s], b[k][1][s], err_msg=f"{k}: {s}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_killed_batch_resumes_to_identical_results(small_cases, reference, tmp_path, sig):
    out = tmp_path / "o"
    rng = random.Random()
    when = rng.uniform(2.0, 12.0)  # the reference batch takes 10-25 s on the CI machine
    p = _batch(small_cases, out)
    time.sleep(when)
    if p.poll() is None:
        os.killpg(p.pid, sig)
    _, err = p.communicate(timeout=120)
    print(f"{signal.Signals(sig).name} at {when:.2f} s: exit {p.returncode}")
    assert "Traceback" not in err, err
    if sig == signal.SIGINT and p.returncode != 0:
        assert p.returncode == 130 and "interrupted" in err, (p.returncode, err)
    again = _batch(small_cases, out)
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    _assert_same(_snapshot(out), _snapshot(reference))


def test_two_batches_at_once_one_runs_one_is_refused(small_cases, reference, tmp_path):
    out = tmp_path / "o"
    a, b = _batch(small_cases, out), _batch(small_cases, out)
    ra, rb = a.communicate(timeout=600), b.communicate(timeout=600)
    codes = sorted([a.returncode, b.returncode])
    assert codes == [0, 2], (codes, ra[1], rb[1])
    refused = ra[1] if a.returncode == 2 else rb[1]
    assert "in use by ftcreport batch (pid" in refused and "Traceback" not in refused
    assert refused.strip().count("\n") == 0
    _assert_same(_snapshot(out), _snapshot(reference))


def test_report_while_a_batch_writes_is_refused(small_cases, tmp_path):
    out = tmp_path / "o"
    p = _batch(small_cases, out)
    lock = out / ".ftcreport.lock"
    t0 = time.time()
    while not (lock.exists() and lock.read_text()) and time.time() - t0 < 60:
        time.sleep(0.05)
    rep = subprocess.run([*CLI, "report", "--out", str(out)], capture_output=True, text=True, timeout=120)
    p.communicate(timeout=600)
    assert p.returncode == 0
    assert rep.returncode == 2 and "in use by ftcreport batch" in rep.stderr and "Traceback" not in rep.stderr
    after = subprocess.run([*CLI, "report", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert after.returncode == 0, after.stderr


def test_two_campaigns_at_once_one_runs_one_is_refused(tmp_path):
    out = tmp_path / "camp"
    args = [*CLI, "campaign", str(CASES / "two_link_campaign.toml"), "-n", "3", "--in-process", "-q"]
    a = subprocess.Popen([*args, "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    b = subprocess.Popen([*args, "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ra, rb = a.communicate(timeout=600), b.communicate(timeout=600)
    codes = sorted([a.returncode, b.returncode])
    assert codes == [0, 2], (codes, ra, rb)
    refused = ra[1] if a.returncode == 2 else rb[1]
    assert "in use by ftcreport campaign (pid" in refused
    rows = (out / "results.csv").read_text().strip().splitlines()
    case = load_case(CASES / "two_link_campaign.toml")
    schemes = [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None]  # every family (issue 21)
    assert len(rows) == 1 + 3 * len(schemes)  # header + every sample x scheme, once
