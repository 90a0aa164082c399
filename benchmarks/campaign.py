"""Campaign throughput, measured (not asserted): samples per minute in-process and on 2 local Dask workers.

    nice python benchmarks/campaign.py [--samples 40] [--quick] [--json FILE]

The case is the example campaign (cases/two_link_campaign.toml: two links, 30 s, nominal + switching +
oracle per sample).  Target (issue 22): at least 80 % of (cores) / (compiled run time per sample).

1. Per-sample cost, in this process, split into: drawing and validating the variant (pydantic),
   building the objects (chain, reference, plant), building the controllers, the compiled closed loops
   (``simulate``; the "compiled run time per sample" of the target) and the metrics (Python, on the
   logged arrays).
2. The whole campaign in-process (``run_campaign(in_process=True)``): adds the sample files, the table
   rewrites (CSV + Parquet, every 2 s) and the manifest.
3. The whole campaign on a LocalCluster of 2 worker processes (``run_campaign(workers=2)``), and
   separately the fixed costs of that path: cluster start, the version check, the warm-up plugin.

Overhead = everything but the compiled loops: the Python per-sample work of step 1 (the largest part),
the client's files, and on the cluster the fixed start-up (amortized over the campaign), serialization
and the scheduler round trips.  The machine's load average is printed: on a shared machine the numbers
are lower bounds.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftcreport.cases import parse_case  # noqa: E402
from ftcreport.runner import build, make_controller, run_metrics  # noqa: E402
from ftcreport.sim import simulate  # noqa: E402
from ftcreport.studies.campaign import draw_variant, run_campaign, sample_seeds  # noqa: E402

SCHEMES = ["nominal", "switching", "oracle"]


def per_sample_costs(base, samples: int, seed: int) -> dict:
    """Mean seconds per sample of each stage (in this process, kernels warm)."""
    stages = dict.fromkeys(("draw", "build", "controllers", "compiled_runs", "metrics"), 0.0)
    for i in range(samples):
        t0 = time.perf_counter()
        variant = draw_variant(base, sample_seeds(seed, i))
        t1 = time.perf_counter()
        built = build(variant)
        t2 = time.perf_counter()
        stages["draw"] += t1 - t0
        stages["build"] += t2 - t1
        for s in SCHEMES:
            ta = time.perf_counter()
            ctrl = make_controller(built, s)
            tb = time.perf_counter()
            run = simulate(built.plant, ctrl, built.q0, built.eta0, built.settings)
            tc = time.perf_counter()
            run_metrics(variant, s, run, built, ctrl)
            td = time.perf_counter()
            stages["controllers"] += tb - ta
            stages["compiled_runs"] += tc - tb
            stages["metrics"] += td - tc
            assert run.meta.get("engine") == "compiled", s
    return {k: v / samples for k, v in stages.items()}


def cluster_fixed_costs(workers: int) -> dict:
    """Seconds to start a LocalCluster, check versions and register the warm-up plugin."""
    from dask.distributed import Client, LocalCluster

    from ftcreport.studies.cluster import WarmUp, check_versions

    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None)  # fmt: skip
    client = Client(cluster)
    t1 = time.perf_counter()
    check_versions(client)
    t2 = time.perf_counter()
    client.register_plugin(WarmUp(), name=WarmUp.name)
    t3 = time.perf_counter()
    client.close()
    cluster.close()
    return {"start": t1 - t0, "version_check": t2 - t1, "warm_up_plugin": t3 - t2}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=40, help="samples per campaign run")
    ap.add_argument("--quick", action="store_true", help="8 samples of a 10 s run")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    samples = args.samples
    if args.quick:
        samples = 8
        data["simulation"]["duration"] = 10.0
        data["campaign"]["fault_time"] = [2.0, 8.0]
    base = parse_case(data, "two_link_campaign")
    cores = os.cpu_count() or 1
    load0 = os.getloadavg()
    from ftcreport.sim import warm_up

    warm_up()
    costs = per_sample_costs(base, max(4, samples // 4), seed=100)
    per_sample = sum(costs.values())
    target = 0.8 * cores / costs["compiled_runs"] * 60.0
    out: dict = {
        "case": "two_link_campaign",
        "schemes": SCHEMES,
        "samples": samples,
        "duration_s": data["simulation"]["duration"],
        "cores": cores,
        "per_sample_s": costs | {"total": per_sample},
        "target_samples_per_min": target,
        "runs": {},
    }
    print(f"cores {cores}, load average before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}")
    print("per sample (3 schemes), seconds: " + ", ".join(f"{k} {v:.4f}" for k, v in costs.items()))
    print(f"  total {per_sample:.4f}; compiled share {costs['compiled_runs'] / per_sample:.0%}")
    print(f"target: 0.8 x {cores} cores / {costs['compiled_runs']:.4f} s = {target:.0f} samples/min")
    for label, kw in (("in-process", {"in_process": True}), ("LocalCluster, 2 workers", {"workers": 2})):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            res = run_campaign(base, samples, Path(d), seed=1, schemes=SCHEMES, show_progress=False, **kw)
            wall = time.perf_counter() - t0
        rate = 60.0 * len(res.completed) / wall
        out["runs"][label] = {"wall_s": wall, "samples_per_min": rate, "fraction_of_target": rate / target}
        print(f"{label:24s} {wall:7.1f} s  {rate:7.1f} samples/min  ({rate / target:.0%} of target)")
    fixed = cluster_fixed_costs(2)
    out["cluster_fixed_s"] = fixed
    print("LocalCluster fixed costs, seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in fixed.items()))
    # where the wall time goes beyond the samples' own cost
    w_in = out["runs"]["in-process"]["wall_s"]
    w_2 = out["runs"]["LocalCluster, 2 workers"]["wall_s"]
    rest_in = w_in - samples * per_sample
    rest_2 = w_2 - sum(fixed.values()) - samples * per_sample / min(2, cores)
    out["overhead_s"] = {"in_process_files_and_tables": rest_in, "cluster_scheduling_and_rest": rest_2}
    print(
        f"in-process: {samples} x {per_sample:.3f} s of samples, {rest_in:.1f} s else (sample files with fsync, "
        f"CSV + Parquet rewrites, manifest, imports); 2 workers: {sum(fixed.values()):.1f} s start-up, "
        f"{rest_2:.1f} s else (scheduling, serialization, worker imports, load from the other engineers)"
    )
    ideal_inproc = 60.0 / per_sample
    ideal_2 = min(2, cores) * ideal_inproc
    print(
        f"bounds from the per-sample cost: in-process {ideal_inproc:.1f}/min, 2 workers {ideal_2:.1f}/min; "
        f"the Python part ({per_sample - costs['compiled_runs']:.4f} s/sample) is the main overhead"
    )
    load1 = os.getloadavg()
    out["load_average"] = {"before": load0, "after": load1}
    print(f"load average after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
