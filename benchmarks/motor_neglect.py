"""Where the thesis's neglect of the motor dynamics stops holding (issue 19 item 4).

The thesis designs its laws for a plant whose wheel torque is the command (section 2.3.3 models
the DC motors, the controllers neglect them).  A motor turns the command into torque through its
current, which lags by the electrical time constant tau_e = L_a / R_a.  This script sweeps tau_e
(L_a scaled, R_a kept) with continuous-time control and a supply that never saturates
(V_max = 1e5 V), so that only the lag differs from the ideal plant, for two velocity gains:

* k4 = 3000 (two_link_switching, thesis 3.2.3; ROS2 at dt = 1 ms, 0.25 ms below tau_e = 1 ms);
* k_v = 10 (two_link_adaptive_eight, thesis 3.3.2.3; RK4, dt = tau_e / 4 capped at 1 ms).

For each point it reports the largest position error after the first fault and the final
error, against the ideal plant at the same step, and their ratio.  The limit is the largest
tau_e whose error after the fault stays within 10 % of the ideal plant's.  A linear reading:
the velocity loop x' = -k (x - x_c) with a first-order lag tau_e has the poles of
tau_e s^2 + s + k, damping 1 / (2 sqrt(k tau_e)); the lag matters once k tau_e is near 1.

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
TAU_E_MS = (0.0, 0.05, 0.1, 0.2, 0.44, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)  # 0: the ideal plant
SETUPS = {
    "k4 = 3000": ("two_link_switching", "switching", "ros2"),
    "k_v = 10": ("two_link_adaptive_eight", "adaptive", "rk4"),
}


def _case(name: str, scheme: str, method: str, tau_e_ms: float, duration: float, dt: float | None = None):
    raw = tomllib.loads((ROOT / "cases" / f"{name}.toml").read_text())
    for key in ("thresholds", "claims", "campaign"):
        raw.pop(key, None)
    raw["schemes"]["run"] = [k for k in raw["schemes"] if isinstance(raw["schemes"][k], dict)]
    duration = min(duration, raw["simulation"]["duration"])
    raw["faults"] = [f for f in raw.get("faults", []) if f["time"] < duration]
    if dt is None:
        dt = 1e-3 if method == "ros2" or tau_e_ms == 0 else min(1e-3, tau_e_ms * 1e-3 / 4)
    raw["simulation"].update(dt=dt, duration=duration, method=method, log_every=1)
    if tau_e_ms > 0:
        raw["actuators"] = {"L_a": MAXON_RE65.R_a * tau_e_ms * 1e-3, "V_max": 1e5}
    return parse_case(raw, f"{name}_tau{tau_e_ms:g}")


def _errors(metrics: dict) -> tuple[float | None, float | None]:
    after = [p["position_error_max"] for p in metrics.get("phases", [])[1:] if p.get("position_error_max") is not None]
    return (max(after) if after else None), metrics.get("position_error_final")


def sweep(duration: float) -> dict:
    out = {}
    for label, (name, scheme, method) in SETUPS.items():
        rows = []
        for tau in TAU_E_MS:
            case = _case(name, scheme, method, tau, duration)
            t0 = time.perf_counter()
            _, m = run_scheme(case, scheme)
            after, final = _errors(m)
            rows.append(
                {
                    "tau_e_ms": tau,
                    "dt": case.simulation.dt,
                    "status": m["status"],
                    "error_after_fault": after,
                    "error_final": final,
                    "torque_peak": m.get("torque_peak"),
                    "wall_s": round(time.perf_counter() - t0, 1),
                }
            )
            print(label, rows[-1], flush=True)
        ideal = rows[0]["error_after_fault"]
        for r in rows:
            r["ratio"] = None if r["error_after_fault"] is None or not ideal else r["error_after_fault"] / ideal
        good = [r["tau_e_ms"] for r in rows[1:] if r["status"] == "ok" and r["ratio"] is not None and r["ratio"] < 1.1]
        bad = [r["tau_e_ms"] for r in rows[1:] if r["tau_e_ms"] not in good]
        first_bad = min(bad) if bad else None
        limit = max((g for g in good if first_bad is None or g < first_bad), default=None)
        out[label] = {"case": name, "scheme": scheme, "method": method, "rows": rows, "limit_ms": limit}
        out[label]["first_degraded_ms"] = first_bad
    return out


def svg(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, res in result.items():
        rows = [r for r in res["rows"][1:] if r["ratio"] is not None]
        ax.loglog([r["tau_e_ms"] for r in rows], [r["ratio"] for r in rows], "o-", label=f"{label} ({res['case']})")
    ax.axhline(1.1, color="grey", ls=":", lw=1)
    ax.axvline(MAXON_RE65.L_a / MAXON_RE65.R_a * 1e3, color="k", ls="--", lw=1, label="maxon RE 65 (0.44 ms)")
    ax.set_xlabel("electrical time constant L_a / R_a [ms]")
    ax.set_ylabel("max error after fault / ideal plant")
    ax.legend(fontsize=8)
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
    for label, res in result.items():
        print(f"{label}: error within 10 % of the ideal plant up to L_a/R_a = {res['limit_ms']} ms", end="")
        print(f", degraded from {res['first_degraded_ms']} ms")


if __name__ == "__main__":
    main()
