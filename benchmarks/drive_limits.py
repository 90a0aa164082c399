"""Where the sampled velocity loop breaks, with the static drive and with a PI current loop (issue 36 item 1).

The thesis case 3.2.3 (two_link_switching, k4 = 3000) with the datasheet motors on every wheel and
the law sampled at T_s, the nominal scheme over its first seconds (no fault: the healthy loop).  Two
bisections per drive:

* ``T_s`` at k4 = 3000: the largest sample time at which the loop settles;
* ``k4`` at T_s = 5 ms (the motor cases' 200 Hz): the largest velocity gain at which it settles.

A run "settles" when the sample-to-sample change of the velocity error eta - eta_c (the
Nyquist-frequency oscillation of a sampled loop past its limit, bounded by the 48 V supply) has
fallen below 1e-5 m/s over the last quarter of the run.  A settled loop's change sits at the smooth
motion's 1e-9 m/s, a limit cycle's at 1e-3 .. 0.3 m/s: four decades of margin either side.  Within a
few percent below the limit the oscillation decays too slowly to settle within the run: such a run
counts as not settling, so the limits found are those of a loop that settles within ``--duration``
(conservative; ``--check`` re-runs each bracket twice as long to show how much).

Drives: ``static`` (the shipped cases' driver: the voltage of the sample held), ``pi`` (a continuous
PI current loop of 1 kHz bandwidth, gains by pole-zero cancellation), ``pi_ff`` (the same with back-EMF
feedforward).  Each run is ETD2 at one step per sample (the motor cases' integration), or with
``--rk4`` RK4 at a step of at most T_s / 10 and 0.1 ms (the reference: RK4 is stable on the PI's 0.16 ms
loop below 0.33 ms); ``--check`` re-runs the two points that bracket each limit with the other
integrator and with the same one over twice the time.

    nice python benchmarks/drive_limits.py [--duration 8] [--out docs/drive_limits.json] [--check]
"""

from __future__ import annotations

import argparse
import json
import math
import time
import tomllib
from pathlib import Path

import numpy as np

from ftcreport.cases import parse_case
from ftcreport.runner import run_scheme

ROOT = Path(__file__).resolve().parents[1]
CASE = "two_link_switching"  # thesis 3.2.3: k4 = 3000, the first fault at 20 s
DRIVES = {
    "static": {},
    "pi": {"driver": "pi", "current_bandwidth": 1000.0},
    "pi_ff": {"driver": "pi", "current_bandwidth": 1000.0, "back_emf_feedforward": True},
}
SETTLED = 1e-5  # m/s: the sample-to-sample velocity-error change of a settled loop (~1e-9; cycles 1e-3 .. 0.3)


def _case(T_s: float, k_v: float, drive: dict, duration: float, method: str, sub: int):
    raw = tomllib.loads((ROOT / "cases" / f"{CASE}.toml").read_text())
    for key in ("thresholds", "claims", "campaign"):
        raw.pop(key, None)
    raw["faults"] = []
    raw["schemes"] = {"nominal": {"k_v": k_v}, "run": ["nominal"]}
    raw["simulation"].update(dt=T_s / sub, duration=duration, method=method, log_every=sub, sample_time=T_s)
    raw["actuators"] = dict(drive)
    return parse_case(raw, "drive_limits")


def classify(T_s: float, k_v: float, drive: dict, duration: float, rk4: bool = False) -> dict:
    """One run: ``settles`` and the late / earlier sample-to-sample velocity-error changes [m/s]."""
    method, sub = ("rk4", max(10, math.ceil(T_s / 1e-4 - 1e-9))) if rk4 else ("etd2", 1)
    t0 = time.perf_counter()
    run, _m = run_scheme(_case(T_s, k_v, drive, duration, method, sub), "nominal")
    out = {"T_s": T_s, "k_v": k_v, "method": method, "dt": T_s / sub, "status": run.status}
    out["wall_s"] = round(time.perf_counter() - t0, 2)
    if run.status != "ok":
        return out | {"settles": False}
    t = run.t[1:]
    d = np.diff(run.signals["eta"] - run.signals["eta_c"], axis=0)

    def rms(lo: float, hi: float) -> float:
        keep = (t >= lo * duration) & (t < hi * duration)
        return float(np.sqrt(np.mean(d[keep] ** 2)))

    late = rms(0.75, 1.0)
    return out | {"change_late": late, "change_before": rms(0.5, 0.75), "settles": late < SETTLED}


def bisect(settles, lo: float, hi: float, rel: float = 0.01) -> tuple[float, float, list[dict]]:
    """(last settling value, first cycling value, the runs) between lo (settles) and hi (cycles)."""
    runs = [settles(lo), settles(hi)]
    if not runs[0]["settles"] or runs[1]["settles"]:
        raise RuntimeError(f"the bracket [{lo}, {hi}] does not bracket the limit: {runs}")
    while hi - lo > rel * lo:
        mid = 0.5 * (lo + hi)
        r = settles(mid)
        runs.append(r)
        if r["settles"]:
            lo = mid
        else:
            hi = mid
        word = "settles" if r["settles"] else "limit cycle"
        print(f"  {mid:.6g}: {word} ({r.get('change_late', 0):.2e} m/s)", flush=True)
    return lo, hi, runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=8.0, help="simulated time per run [s] (before the first fault)")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON result here")
    ap.add_argument("--rk4", action="store_true", help="integrate with RK4 at <= T_s / 10 and 0.1 ms (the reference)")
    ap.add_argument("--check", action="store_true", help="re-run each bracket with the other integrator and 2x longer")
    args = ap.parse_args()
    T, rk4 = args.duration, args.rk4
    result: dict = {"case": CASE, "duration": T, "settled": SETTLED, "rk4": rk4, "drives": {}}
    for name, drive in DRIVES.items():
        print(f"{name}: T_s at k4 = 3000", flush=True)
        ts_lo, ts_hi, ts_runs = bisect(lambda T_s, d=drive: classify(T_s, 3000.0, d, T, rk4), 0.5e-3, 2.5e-3)
        print(f"{name}: k4 at T_s = 5 ms", flush=True)
        k_lo, k_hi, k_runs = bisect(lambda k, d=drive: classify(5e-3, k, d, T, rk4), 100.0, 1500.0)
        row = {"T_s_limit_ms": [ts_lo * 1e3, ts_hi * 1e3], "k4_limit": [k_lo, k_hi], "runs": ts_runs + k_runs}
        if args.check:
            brackets = [(x, 3000.0) for x in (ts_lo, ts_hi)] + [(5e-3, k) for k in (k_lo, k_hi)]
            row["other_integrator"] = [classify(a, b, drive, T, not rk4) for a, b in brackets]
            row["twice_as_long"] = [classify(a, b, drive, 2 * T, rk4) for a, b in brackets]
        result["drives"][name] = row
        print(f"{name}: T_s limit {ts_lo * 1e3:.3f}-{ts_hi * 1e3:.3f} ms at k4 = 3000; k4 limit {k_lo:.0f}-{k_hi:.0f} "
              "at T_s = 5 ms", flush=True)  # fmt: skip
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))
    print("\n| drive | T_s limit at k4 = 3000 [ms] | k4 limit at T_s = 5 ms |\n|---|---|---|")
    for name, row in result["drives"].items():
        a, b = row["T_s_limit_ms"]
        c, d = row["k4_limit"]
        print(f"| {name} | {a:.3f} - {b:.3f} | {c:.0f} - {d:.0f} |")


if __name__ == "__main__":
    main()
