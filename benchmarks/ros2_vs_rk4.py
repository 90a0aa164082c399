"""Measure the stiff thesis case (two_link_switching, k4 = 3000) with ROS2 at 5 ms against RK4 at 0.5 ms.

Full length (140 s), every scheme of the case, logged every 10 ms on both grids (the same instants).
Prints per scheme and phase the largest and final position error of each method and their largest
difference, as JSON.  The numbers quoted in ``cases/two_link_switching.toml`` come from this script::

    nice python benchmarks/ros2_vs_rk4.py [--schemes nominal,switching,oracle] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ftcreport.cases import load_case
from ftcreport.evaluation.metrics import tracking_errors
from ftcreport.runner import build, make_controller
from ftcreport.sim import SimSettings, simulate

CASE = Path(__file__).resolve().parents[1] / "cases" / "two_link_switching.toml"


def run(scheme: str, method: str, dt: float, log_dt: float = 0.01):
    case = load_case(CASE)
    built = build(case)
    s = built.settings
    settings = SimSettings(
        dt=dt, duration=s.duration, method=method, log_every=round(log_dt / dt), singularity_margin=s.singularity_margin
    )
    t0 = time.perf_counter()
    r = simulate(built.plant, make_controller(built, scheme), built.q0, built.eta0, settings)
    wall = time.perf_counter() - t0
    pos, _ = tracking_errors(r["q"], r["q_d"])
    return r, pos, wall, built.faults.phases(s.duration)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--schemes", default="nominal,switching,oracle")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    out = {}
    for scheme in args.schemes.split(","):
        res = {}
        for method, dt in (("rk4", 5e-4), ("ros2", 5e-3)):
            r, pos, wall, phases = run(scheme, method, dt)
            res[method] = (r, pos, wall)
        (ra, pa, wa), (rb, pb, wb) = res["rk4"], res["ros2"]
        if ra.t.shape != rb.t.shape or not np.allclose(ra.t, rb.t):
            raise SystemExit("the two logs are not on the same instants")
        rows = []
        for a, b in phases:
            m = (ra.t >= a) & (ra.t <= b)
            rows.append(
                {
                    "phase": [a, b],
                    "rk4_max": float(pa[m].max()),
                    "ros2_max": float(pb[m].max()),
                    "rk4_final": float(pa[m][-1]),
                    "ros2_final": float(pb[m][-1]),
                    "max_abs_difference": float(np.abs(pa[m] - pb[m]).max()),
                }
            )
        out[scheme] = {
            "status": [ra.status, rb.status],
            "rk4_final": float(pa[-1]),
            "ros2_final": float(pb[-1]),
            "max_abs_difference": float(np.abs(pa - pb).max()),
            "max_abs_difference_after_1s": float(np.abs(pa - pb)[ra.t >= 1.0].max()),
            "wall_s": [wa, wb],
            "phases": rows,
        }
        print(json.dumps({scheme: out[scheme]}, indent=1), flush=True)
    if args.out:
        from ftcreport.storage.store import write_atomic

        write_atomic(Path(args.out), json.dumps(out, indent=1).encode())


if __name__ == "__main__":
    main()
