"""Golden-run comparison: every case x scheme, full length, compiled engine against the Python engine.

    python benchmarks/golden.py [--jobs 2] [--json FILE] [--schemes S ...] [CASE ...]

For each run prints the largest difference of the plant state (q, eta) over the
whole run, of the applied torque, and of the tracking metrics the thresholds use
(final and RMS position error).  tests/test_fast.py asserts the same comparison on
short windows in CI; this script is the full-length proof (several minutes: the
Python engine is the slow side).
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftcreport.cases import SCHEME_NAMES, load_case  # noqa: E402
from ftcreport.fast.engine import compiled_spec  # noqa: E402
from ftcreport.runner import build, make_controller, run_metrics  # noqa: E402
from ftcreport.sim import simulate  # noqa: E402

METRICS = ("position_error_final", "position_error_rms")


def compare(path: str, scheme: str) -> dict:
    case = load_case(path)
    runs, metrics = {}, {}
    for engine in ("python", "compiled"):
        built = build(case)
        ctrl = make_controller(built, scheme)
        run = simulate(built.plant, ctrl, built.q0, built.eta0, built.settings, engine=engine)
        runs[engine] = run
        metrics[engine] = run_metrics(case, scheme, run, built, ctrl)
    py, fast = runs["python"], runs["compiled"]
    out = {"case": case.name, "scheme": scheme, "status": [py.status, fast.status], "steps": [py.steps, fast.steps]}
    k = min(py.t.size, fast.t.size)
    for name in ("q", "eta", "tau"):
        out[f"max_diff_{name}"] = float(np.max(np.abs(py[name][:k] - fast[name][:k]))) if k else 0.0
    for m in METRICS:
        a, b = metrics["python"].get(m), metrics["compiled"].get(m)
        out[m] = [a, b]
    out["wall_s"] = [py.wall_time, fast.wall_time]
    return out


def _steps(path: str) -> float:
    sim = load_case(path).simulation
    return sim.duration / sim.dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--schemes", nargs="+", choices=SCHEME_NAMES, help="only these schemes (default: all)")
    args = ap.parse_args()
    paths = args.cases or sorted((ROOT / "cases").glob("*.toml"))
    jobs = []
    for p in paths:
        case = load_case(p)
        built = build(case)
        for scheme in args.schemes or SCHEME_NAMES:
            if getattr(case.schemes, scheme) is not None and compiled_spec(make_controller(built, scheme)):
                jobs.append((str(p), scheme))
    # longest runs first (steps), each line printed as soon as it is known
    jobs.sort(key=lambda j: -_steps(j[0]))
    head = f"{'case':28s} {'scheme':16s} {'max|dq|':>9s} {'max|deta|':>9s} {'max|dtau|':>9s}"
    print(head + "  final position error, Python / compiled [m]", flush=True)
    results = []
    with ProcessPoolExecutor(args.jobs) as ex:
        futures = [ex.submit(compare, p, s) for p, s in jobs]
        for fut in as_completed(futures):
            r = fut.result()
            results.append(r)
            a, b = r["position_error_final"]
            fin = f"{a:.6g} / {b:.6g}" if a is not None and b is not None else "-"
            flag = "" if r["status"][0] == r["status"][1] else f"  status {r['status']}"
            print(
                f"{r['case']:28s} {r['scheme']:16s} {r['max_diff_q']:9.2e} {r['max_diff_eta']:9.2e} "
                f"{r['max_diff_tau']:9.2e}  {fin}{flag}",
                flush=True,
            )
            if args.json:  # rewritten atomically after every run: an interrupted comparison keeps what it has
                tmp = args.json.with_suffix(".tmp")
                tmp.write_text(json.dumps(results, indent=2))
                tmp.replace(args.json)


if __name__ == "__main__":
    main()
