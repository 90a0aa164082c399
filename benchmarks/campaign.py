"""Campaign throughput, measured (not asserted): samples per minute in-process and on a Dask LocalCluster.

    python benchmarks/campaign.py [--quick] [--json FILE]

Runs the example campaign (cases/two_link_campaign.toml: two links, nominal + switching + oracle per
sample) in-process, then on a LocalCluster with 1 and 2 worker processes, each into a fresh directory,
and prints samples per minute and the speed-up.  Scaling model: samples are independent and each costs
the same on average, so K workers give a speed-up of about K (bounded by the cores) minus the cluster
start-up (a few seconds, amortized over the campaign) and the per-sample table rewrite on the client.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftcreport.campaign import run_campaign  # noqa: E402
from ftcreport.cases import parse_case  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer and shorter samples")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    samples = 12
    if args.quick:
        samples = 4
        data["simulation"]["duration"] = 10.0
        data["campaign"]["fault_time"] = [2.0, 8.0]
    base = parse_case(data, "two_link_campaign")
    out: dict = {"samples": samples, "duration_s": data["simulation"]["duration"], "runs": {}}
    for label, kw in (
        ("in-process", {"in_process": True}),
        ("LocalCluster, 1 worker", {"workers": 1}),
        ("LocalCluster, 2 workers", {"workers": 2}),
    ):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            res = run_campaign(base, samples, Path(d), seed=1, show_progress=False, **kw)
            wall = time.perf_counter() - t0
        rate = 60.0 * len(res.completed) / wall
        out["runs"][label] = {"wall_s": wall, "samples_per_min": rate}
        print(f"{label:26s} {wall:7.1f} s  {rate:6.2f} samples/min")
    base_rate = out["runs"]["LocalCluster, 1 worker"]["samples_per_min"]
    for r in out["runs"].values():
        r["speedup_vs_1_worker"] = r["samples_per_min"] / base_rate
    print(f"speed-up 2 workers vs 1: {out['runs']['LocalCluster, 2 workers']['speedup_vs_1_worker']:.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
