"""Accuracy against cost: each shipped case's fixed step against the error-controlled integrators (issue 36).

For every case in cases/ and cases/motors/ (first fault + 5 s, at most 30 s of it) and one scheme (``--scheme``,
default nominal: a continuous law, so that the reference is a solution of an ODE; a hybrid rule such as the
switching logic runs at the steps' ends, and its instants are part of what is compared):

* a reference: the case's method's error-controlled twin (dopri5 for rk4, ros2ec for ros2, etd2ec for etd2)
  at rtol = 1e-10, atol = 1e-12, its longest step the case's dt; its resolution is its difference from the
  same twin at rtol = 1e-11, atol = 1e-13 (1e-12 m on the chains: a fixed step's error below twice it is not
  resolved, and no comparison is drawn from it);
* the case as shipped (fixed step dt);
* ``auto`` at rtol = 1e-2 ... 1e-10 (atol = rtol / 100), its longest step ``--max-step-factor`` x dt.

Accuracy: the largest |x, y| error of P_n against the reference at the fault instants and the end (every run
lands on them); cost: rate evaluations of the closed loop (the loop's own count; 4 per step for RK4, ROS2 and
ETD2) and the loop's warm wall time (the least of ``--repeats``).  For each case the cheapest ``auto`` whose
error is at most the fixed step's is named, with its cost relative to the fixed step.  With ``--refine 2,4`` the
fixed step also runs at dt/2 and dt/4 (the fixed method's own accuracy-cost line), and each ``auto`` row gets the
fixed step's evaluations at that row's error (log-log interpolation between the refinements that bracket it; none
outside them): the comparison at equal accuracy where the fixed step is not at the shipped dt.  Writes JSON::

    nice python benchmarks/accuracy.py [--json FILE] [--scheme nominal] [--max-step-factor 10] [--refine 2,4] [CASE ...]
"""

from __future__ import annotations

import argparse
import glob
import itertools
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from ftcreport.cases import configured_schemes, load_case
from ftcreport.runner import run_scheme

ROOT = Path(__file__).resolve().parents[1]
TWIN = {"rk4": "dopri5", "ros2": "ros2ec", "etd2": "etd2ec"}
RTOLS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)


def _run(case, scheme: str, repeats: int, **sim):
    case = case.model_copy(update={"simulation": case.simulation.model_copy(update=sim)})
    best = None
    for _ in range(repeats):
        run, metrics = run_scheme(case, scheme)
        if best is None or run.wall_time < best[0].wall_time:
            best = (run, metrics)
    return best


def _error(run, ref, instants) -> float:
    """max |(x, y) - (x, y)_ref| over the instants (both runs have a step boundary at each), or nan."""
    worst = 0.0
    for t in instants:
        i, j = np.searchsorted(run.t_stream, t - 1e-9), np.searchsorted(ref.t_stream, t - 1e-9)
        if i >= run.t_stream.size or j >= ref.t_stream.size:
            return math.nan
        if abs(run.t_stream[i] - t) > 1e-9 or abs(ref.t_stream[j] - t) > 1e-9:
            return math.nan
        worst = max(worst, float(np.max(np.abs(run.stream["q"][i, :2] - ref.stream["q"][j, :2]))))
    return worst


def _row(label: str, run, metrics) -> dict:
    g = run.meta["integrator"]
    evals = g.get("evaluations", 4 * g.get("steps", 0))  # the fixed methods: 4 evaluations per step
    return {"run": label, "status": run.status, "method": g["method"], "steps": int(run.steps),
            "evaluations": int(evals), "loop_wall_s": round(float(run.wall_time), 5)}  # fmt: skip


def _fixed_cost_at(line: list[dict], error: float) -> float | None:
    """The fixed step's evaluations at ``error``: log-log interpolation between the two refinements whose errors
    bracket it (the fixed method's own accuracy-cost line), or None outside the measured range (no extrapolation)."""
    pts = sorted((math.log(r["error_m"]), math.log(r["evaluations"])) for r in line)
    if not pts or not math.isfinite(error) or error <= 0:
        return None
    le = math.log(error)
    for (e0, c0), (e1, c1) in itertools.pairwise(pts):
        if e0 <= le <= e1 and e1 > e0:
            return math.exp(c0 + (c1 - c0) * (le - e0) / (e1 - e0))
    return None


def measure(
    path: Path, scheme_wanted: str, factor: float, repeats: int, refine: tuple[int, ...] = (), rtols=RTOLS
) -> dict:
    case = load_case(path)
    schemes = configured_schemes(case)
    scheme = scheme_wanted if scheme_wanted in schemes else schemes[0]
    times = sorted(float(t) for t in case.fault_schedule().times)
    duration = min(case.simulation.duration, (times[0] + 5.0) if times else 10.0, 30.0)
    case = case.model_copy(update={"simulation": case.simulation.model_copy(update={"duration": duration})})
    sim = case.simulation
    noise = case.plant.noise
    if noise.sample_time is None:  # the sensor's clock pinned at the shipped dt: every run sees the same draws
        plant = case.plant.model_copy(update={"noise": noise.model_copy(update={"sample_time": sim.dt})})
        case = case.model_copy(update={"plant": plant})
    instants = [t for t in times if t < duration] + [duration]
    ref, _ = _run(case, scheme, 1, method=TWIN[sim.method], rtol=1e-10, atol=1e-12, min_step=1e-12)
    tighter, _ = _run(case, scheme, 1, method=TWIN[sim.method], rtol=1e-11, atol=1e-13, min_step=1e-12)
    resolution = _error(ref, tighter, instants)
    rows = []
    fixed, fm = _run(case, scheme, repeats)
    rows.append(_row(f"{sim.method} dt = {sim.dt:g}", fixed, fm) | {"error_m": _error(fixed, ref, instants)})
    finer = []  # the fixed step refined: the fixed method's own accuracy-cost line
    for k in refine:
        run, m = _run(case, scheme, repeats, dt=sim.dt / k)
        finer.append(_row(f"{sim.method} dt = {sim.dt / k:g}", run, m) | {"error_m": _error(run, ref, instants)})
    for rtol in rtols:
        run, m = _run(case, scheme, repeats, method="auto", rtol=rtol, atol=rtol / 100, dt=sim.dt * factor)
        rows.append(_row(f"auto rtol = {rtol:g}", run, m) | {"rtol": rtol, "error_m": _error(run, ref, instants)})
    target = rows[0]["error_m"]
    resolved = target > 2.0 * resolution
    ok = [r for r in rows[1:] if r["status"] == "ok" and r["error_m"] <= target] if resolved else []
    best = min(ok, key=lambda r: r["evaluations"]) if ok else None
    line = [r for r in [rows[0], *finer] if r["status"] == "ok" and r["error_m"] > 0]
    for r in rows[1:]:
        r["fixed_evaluations_at_this_error"] = _fixed_cost_at(line, r["error_m"]) if r["status"] == "ok" else None
    return {
        "case": str(path.relative_to(ROOT)),
        "scheme": scheme,
        "duration_s": duration,
        "dt": sim.dt,
        "max_step": sim.dt * factor,
        "reference": {
            "method": TWIN[sim.method],
            "status": ref.status,
            "steps": int(ref.steps),
            "resolution_m": resolution,
            "fixed_error_resolved": bool(resolved),
        },
        "rows": rows,
        "fixed_refined": finer,
        "cheapest_auto_as_accurate": None
        if best is None
        else {
            "run": best["run"],
            "method": best["method"],
            "evaluations_ratio": best["evaluations"] / rows[0]["evaluations"],
            "wall_ratio": best["loop_wall_s"] / rows[0]["loop_wall_s"],
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="*", help="case files (default: every shipped case)")
    ap.add_argument("--scheme", default="nominal")
    ap.add_argument("--max-step-factor", type=float, default=10.0, help="auto's longest step, times the case's dt")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path)
    tols = ",".join(f"{r:g}" for r in RTOLS)
    ap.add_argument("--rtols", default=tols, help="auto's tolerances (default: 1e-2 ... 1e-10)")
    ap.add_argument("--refine", default="", help="also the fixed step at dt/k for these k (e.g. 2,4): its cost line")
    args = ap.parse_args()
    shipped = glob.glob(str(ROOT / "cases" / "*.toml")) + glob.glob(str(ROOT / "cases" / "motors" / "*.toml"))
    files = [Path(f).resolve() for f in args.cases] or sorted(Path(f) for f in shipped)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": platform.processor() or platform.machine(), "cases": []}
    for f in files:
        refine = tuple(int(k) for k in args.refine.split(",") if k)
        rtols = tuple(float(r) for r in args.rtols.split(",") if r)
        res = measure(f, args.scheme, args.max_step_factor, args.repeats, refine, rtols)
        out["cases"].append(res)
        best = res["cheapest_auto_as_accurate"]
        fixed = res["rows"][0]
        print(
            f"{res['case']} ({res['scheme']}, {res['duration_s']:g} s): {fixed['run']} error {fixed['error_m']:.2g} m, "
            f"{fixed['evaluations']} evaluations; "
            + (f"not resolved (the reference's resolution: {res['reference']['resolution_m']:.2g} m)"
               if not res["reference"]["fixed_error_resolved"]
               else "no auto as accurate" if best is None else f"{best['run']} ({best['method']}): "
               f"{best['evaluations_ratio']:.2f}x the evaluations, {best['wall_ratio']:.2f}x the wall time"),
            flush=True,
        )  # fmt: skip
        if args.json:
            args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
