"""Where the thesis's neglect of the motor dynamics stops holding (issue 19 item 4).

The thesis designs its laws for a plant whose wheel torque is the command (section 2.3.3 models
the DC motors, the controllers neglect them).  Three sweeps on two_link_switching (thesis 3.2.3,
switching scheme, k4 = 3000, 30 s: one fault at 20 s), each against the ideal torque plant, all
ROS2 at dt = 1 ms (the motor cases' step, checked there against 0.5 ms):

* ``lag``: the electrical time constant tau_e = L_a / R_a (L_a scaled, R_a kept) with
  continuous-time control and a supply that never saturates (V_max = 1e5 V): only the current's
  lag differs from the ideal plant.  Linear reading: the velocity loop x' = -k (x - x_c) behind a
  first-order lag has the poles of tau_e s^2 + s + k, damping 1 / (2 sqrt(k tau_e)): less damped,
  never unstable, in continuous time.
* ``lag_48V``: the same with the datasheet's 48 V supply (the driver saturates).
* ``k_v_sampled``: the velocity gain k_v with the default motors and the law sampled at
  T_s = 5 ms (the motor cases' setting), against the ideal plant with continuous control at the
  same k_v.  Linear reading: the sampled velocity loop x+ = (1 - k_v T_s) x is stable for
  k_v T_s < 2, with the sign of (1 - k_v T_s) flipping (ringing) above 1.

Each point: the largest position error after the first fault, the final error, their ratio to
the ideal plant's.  The limit: the smallest k_v from which on every run is lost or has twice the
ideal plant's error after the fault.

    nice python benchmarks/motor_neglect.py [--duration 30] [--out motor_neglect.json] [--svg docs/motor_neglect.svg]
"""

from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

from ftcreport.cases import parse_case
from ftcreport.model.actuators import MAXON_RE65
from ftcreport.runner import run_scheme

ROOT = Path(__file__).resolve().parents[1]
CASE = "two_link_switching"  # thesis 3.2.3, k4 = 3000; first fault at 20 s
SCHEME = "switching"
TAU_E_MS = (0.05, 0.2, 0.44, 2.0, 10.0, 50.0)
K_V = (3.0, 10.0, 30.0, 100.0, 200.0, 300.0, 400.0, 600.0, 1000.0, 3000.0)
T_S = 0.005


def _case(duration: float, k_v: float = 3000.0, actuators: dict | None = None, sample_time: float | None = None):
    raw = tomllib.loads((ROOT / "cases" / f"{CASE}.toml").read_text())
    for key in ("thresholds", "claims", "campaign"):
        raw.pop(key, None)
    raw["schemes"] = {SCHEME: raw["schemes"][SCHEME] | {"k_v": k_v}, "run": [SCHEME]}
    raw["faults"] = [f for f in raw.get("faults", []) if f["time"] < duration]
    # ROS2 at 1 ms: the method and step of the motor cases (checked there against 0.5 ms)
    raw["simulation"].update(dt=1e-3, duration=duration, method="ros2", log_every=100)
    if sample_time is not None:
        raw["simulation"]["sample_time"] = sample_time
    if actuators is not None:
        raw["actuators"] = actuators
    return parse_case(raw, CASE)


def _run(case) -> dict:
    t0 = time.perf_counter()
    _, m = run_scheme(case, SCHEME)
    after = [p["position_error_max"] for p in m.get("phases", [])[1:] if p.get("position_error_max") is not None]
    return {
        "status": m["status"],
        "error_after_fault": max(after) if after and m["status"] == "ok" else None,
        "error_final": m.get("position_error_final") if m["status"] == "ok" else None,
        "torque_peak": m.get("torque_peak"),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def _ratio(row: dict, ideal: dict) -> float | None:
    a, b = row["error_after_fault"], ideal["error_after_fault"]
    return None if a is None or not b else a / b


def sweep(duration: float) -> dict:
    """Three sweeps on two_link_switching (switching scheme), each against the ideal plant."""
    ideal = _run(_case(duration))
    out: dict = {"ideal_k4_3000": ideal}
    for label, vmax in (("lag", 1e5), ("lag_48V", None)):
        rows = []
        for tau in TAU_E_MS:
            act = {"L_a": MAXON_RE65.R_a * tau * 1e-3} | ({"V_max": vmax} if vmax else {})
            r = _run(_case(duration, actuators=act)) | {"tau_e_ms": tau}
            r["ratio"] = _ratio(r, ideal)
            rows.append(r)
            print(label, r, flush=True)
        out[label] = rows
    rows = []
    for k in K_V:
        base = _run(_case(duration, k_v=k))
        r = _run(_case(duration, k_v=k, actuators={}, sample_time=T_S)) | {"k_v": k, "k_v_T_s": k * T_S}
        r["ideal_error_after_fault"] = base["error_after_fault"]
        r["ratio"] = _ratio(r, base)
        rows.append(r)
        print("k_v", r, flush=True)
    out["k_v_sampled"] = rows
    out |= k_v_limit(rows)
    return out


def k_v_limit(rows: list[dict], broken: float = 2.0) -> dict:
    """The sampled loop's break: the smallest k_v from which on every run is lost (not ok) or has twice
    the ideal plant's error after the fault, and the largest k_v below it (``broken``: that factor)."""
    bad = [r["ratio"] is None or r["ratio"] > broken for r in rows]
    first = next((i for i in range(len(rows)) if all(bad[i:])), None)
    return {
        "k_v_first_broken": None if first is None else rows[first]["k_v"],
        "k_v_last_within": rows[first - 1]["k_v"] if first else (rows[-1]["k_v"] if first is None else None),
    }


def svg(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9.0, 3.6))
    for label, name in (("lag", "continuous control, no voltage limit"), ("lag_48V", "continuous control, 48 V")):
        rows = [r for r in result[label] if r["ratio"] is not None]
        a1.semilogx([r["tau_e_ms"] for r in rows], [r["ratio"] for r in rows], "o-", label=name)
    a1.axvline(MAXON_RE65.L_a / MAXON_RE65.R_a * 1e3, color="k", ls="--", lw=1, label="maxon RE 65: 0.44 ms")
    a1.set_xlabel("L_a / R_a [ms] (k4 = 3000)")
    a1.set_ylabel("max error after fault / ideal plant")
    a1.legend(fontsize=7)
    rows = result["k_v_sampled"]
    ok = [r for r in rows if r["ratio"] is not None]
    a2.loglog([r["k_v_T_s"] for r in ok], [r["ratio"] for r in ok], "o-", label="motors, T_s = 5 ms")
    a2.axvline(2.0, color="grey", ls=":", lw=1, label="k_v T_s = 2")
    a2.axhline(1.1, color="grey", ls="--", lw=1)
    a2.set_xlabel("k_v T_s (velocity gain x sample time)")
    a2.set_ylabel("max error after fault / ideal plant")
    a2.legend(fontsize=7)
    for ax in (a1, a2):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="svg")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=30.0, help="simulated time per run [s] (first fault: 20 s)")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON result here")
    ap.add_argument("--svg", type=Path, default=None, help="write the figure here")
    args = ap.parse_args()
    result = sweep(args.duration)
    text = json.dumps(result, indent=1)
    if args.out:
        args.out.write_text(text)
    if args.svg:
        svg(result, args.svg)
    print(f"k_v with motors and T_s = {T_S} s: lost or twice the ideal error from k_v = {result['k_v_first_broken']}")
    print(f"(the last k_v below: {result['k_v_last_within']})")


if __name__ == "__main__":
    main()
