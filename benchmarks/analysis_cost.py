"""What the linearized analysis costs against the simulation, and how it grows with n (issue 37 item 9).

A chain of n robots on the five-link case's circle and faults (cases/five_link_cascade.toml with
``robots.n = n``: one wheel lost every 15 s, from the last robot forward), every family run on it
(nominal, switching, adaptive, active, active_ukf, oracle: the case's default), 80 s at dt = 0.02:

* the simulation: the wall time of every scheme's run (``runner.run_scheme``), warm (each scheme run
  once before, so nothing is compiled while timed);
* the analysis: ``analysis.analyze_case`` (every scheme in every phase, margins, limits; no
  simulation to confirm: the case is neither sampled nor motorised), warm likewise;
* per scheme (``phases.analyze_scheme`` timed around its call; ``case_wide`` the rest: the classic
  analyses and the chained law's frames), the analysis's wall time against n = 2..6, and the exponent
  of a power law fitted to it.

Item 9's target: the six-robot case's analysis under 10 % of its simulation time.  Measurements only;
nothing is asserted.

    nice python benchmarks/analysis_cost.py [--n 2,3,4,5,6] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import time
import tomllib
from pathlib import Path

import numpy as np

from ftcreport.analysis import analyze_case
from ftcreport.analysis import case as case_module
from ftcreport.cases import configured_schemes, parse_case
from ftcreport.runner import build, run_scheme

ROOT = Path(__file__).resolve().parents[1]


def chain_case(n: int):
    """cases/five_link_cascade.toml with n robots (faults on the wheels that exist), every family."""
    raw = tomllib.loads((ROOT / "cases" / "five_link_cascade.toml").read_text())
    for key in ("thresholds", "claims", "campaign"):
        raw.pop(key, None)
    raw["robots"]["n"] = n
    raw["robots"]["d"] = 1.0
    # one wheel lost every 15 s from the last robot forward, as the five-link case
    wheels = [f"{n - i}{'lr'[i % 2]}" for i in range(min(4, n))]
    raw["faults"] = [{"time": 15.0 * (i + 1), "wheel": w} for i, w in enumerate(wheels)]
    return parse_case(raw, f"chain_{n}")


def simulate_all(case) -> dict[str, float]:
    built = build(case)
    out = {}
    for s in configured_schemes(case):
        t0 = time.perf_counter()
        run_scheme(case, s, built)
        out[s] = time.perf_counter() - t0
    return out


def analyse(case) -> tuple[float, dict[str, float]]:
    """The analysis's wall time, and per scheme that of ``phases.analyze_scheme`` (timed around the call
    ``analyze_case`` makes: the progress lines give 0.1 s, too coarse for the small cases' fit); the
    case-wide part (the classic analyses, the chained law's frames) is the rest, ``case_wide``."""
    per: dict[str, float] = {}
    inner = case_module.analyze_scheme

    def timed(case, scheme, *args, **kwargs):
        t1 = time.perf_counter()
        try:
            return inner(case, scheme, *args, **kwargs)
        finally:
            per[scheme] = time.perf_counter() - t1

    case_module.analyze_scheme = timed
    try:
        t0 = time.perf_counter()
        analyze_case(case)
        total = time.perf_counter() - t0
    finally:
        case_module.analyze_scheme = inner
    per["case_wide"] = total - sum(per.values())
    return total, per


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", default="2,3,4,5,6", help="robot counts (the last is the target's case)")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()
    ns = [int(v) for v in args.n.split(",")]
    rows = []
    for n in ns:
        case = chain_case(n)
        simulate_all(case)  # warm: every scheme's loop compiled or loaded
        analyse(case)  # warm: every law's Python entry loaded
        sim = simulate_all(case)
        total, per = analyse(case)
        rows.append({"n": n, "simulation_s": sum(sim.values()), "simulation": sim, "analysis_s": total})
        rows[-1]["analysis"] = per
        print(f"n = {n}: simulation {sum(sim.values()):.1f} s ({', '.join(f'{k} {v:.1f}' for k, v in sim.items())}); "
              f"analysis {total:.2f} s ({', '.join(f'{k} {v:.2f}' for k, v in per.items())}); "
              f"ratio {total / sum(sim.values()):.3f}", flush=True)  # fmt: skip
    fits = {}
    if len(rows) > 1:
        for s in rows[-1]["analysis"]:
            x = np.log([r["n"] for r in rows if s in r["analysis"]])
            y = np.log([max(r["analysis"][s], 1e-3) for r in rows if s in r["analysis"]])
            fits[s] = float(np.polyfit(x, y, 1)[0]) if len(x) > 1 else math.nan
        x, y = np.log([r["n"] for r in rows]), np.log([r["analysis_s"] for r in rows])
        fits["total"] = float(np.polyfit(x, y, 1)[0])
        print("growth exponent (time ~ n^p): " + ", ".join(f"{k} {v:.2f}" for k, v in fits.items()))
    last = rows[-1]
    ratio = last["analysis_s"] / last["simulation_s"]
    print(f"target (n = {last['n']}): analysis / simulation = {ratio:.3f} (limit 0.1)")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "growth_exponent": fits}, indent=2))


if __name__ == "__main__":
    main()
