"""CI (issue 38 item 2): runs are bit-identical with ftcreport's compile-time acceleration on and off.

Runs every scheme of a few cases (the passive loop, the active loop, the motor variant) for a short
time in a fresh process per mode (the two side by side), each mode with its own empty cache
directory (``FTCREPORT_CACHE``), once with the acceleration (the default) and once with
``FTCREPORT_FAST_COMPILE=0`` (numba's own pipeline), and compares every logged array and every
metric bit for bit.  Prints one line per run and exits 1 on the first difference.

    python .ci/bit_identical.py [--duration 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = ("two_link_switching.toml", "two_link_active.toml", "motors/two_link_switching_motors.toml")

RUN = """
import json, sys
import numpy as np
from ftcreport.cases import configured_schemes, load_case, with_duration
from ftcreport.jit import compiling
from ftcreport.runner import run_scheme

out = {"accelerated": compiling.accelerated(), "runs": []}
for path in sys.argv[3:]:
    case = with_duration(load_case(path), float(sys.argv[2]))
    for scheme in configured_schemes(case):
        run, metrics = run_scheme(case, scheme)
        name = f"{case.name}.{scheme}"
        arrays = {"t": run.t} | {k: np.asarray(v) for k, v in run.signals.items()}
        np.savez(f"{sys.argv[1]}/{name}.npz", **arrays)
        times = ("wall_time", "compile_time")  # how long, not what: never compared
        numbers = {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and k not in times}
        out["runs"].append({"name": name, "status": metrics["status"], "metrics": numbers})
print(json.dumps(out))
"""


def _start(folder: Path, duration: float, **env: str) -> tuple[subprocess.Popen, float]:
    """One mode's run in a fresh process with its own empty cache, started (the two modes side by side:
    CI's machine has two cores, and each mode is one process)."""
    folder.mkdir()
    environ = dict(os.environ, FTCREPORT_CACHE=str(folder / "cache"), **env)
    cases = [str(ROOT / "cases" / c) for c in CASES]
    argv = [sys.executable, "-c", RUN, str(folder), str(duration), *cases]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environ)
    return proc, time.perf_counter()


def _finish(started: tuple[subprocess.Popen, float], what: str) -> dict:
    proc, t0 = started
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"bit_identical: the run failed ({what}):\n{stderr}")
    out = json.loads(stdout.splitlines()[-1])
    out["wall"] = wall
    return out


def _same(u, v) -> bool:
    """Equal numbers, NaN equal to NaN (a metric over an empty phase)."""
    return u == v or (isinstance(u, float) and isinstance(v, float) and u != u and v != v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds per run")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        started_on = _start(Path(d) / "on", args.duration)
        started_off = _start(Path(d) / "off", args.duration, FTCREPORT_FAST_COMPILE="0")
        on = _finish(started_on, "accelerated")
        off = _finish(started_off, "FTCREPORT_FAST_COMPILE=0")
        if not on["accelerated"] or off["accelerated"]:
            print(f"bit_identical: expected accelerated on/off, got {on['accelerated']}/{off['accelerated']}")
            return 1
        failed = 0
        for a, b in zip(on["runs"], off["runs"], strict=True):
            x, y = np.load(Path(d) / "on" / f"{a['name']}.npz"), np.load(Path(d) / "off" / f"{b['name']}.npz")
            diff = [k for k in x.files if k not in y.files or not np.array_equal(x[k], y[k], equal_nan=True)]
            diff += [k for k in y.files if k not in x.files]
            diff += [f"metric {k}" for k in a["metrics"] if not _same(a["metrics"][k], b["metrics"].get(k))]
            if a["status"] != b["status"]:
                diff.append(f"status {a['status']} / {b['status']}")
            verdict = "bit-identical" if not diff else "DIFFERENT: " + ", ".join(diff)
            print(f"{a['name']} ({a['status']}, {len(x.files)} arrays, {len(a['metrics'])} metrics): {verdict}")
            failed += bool(diff)
        print(f"accelerated {on['wall']:.0f} s, numba's own pipeline {off['wall']:.0f} s (cold, wall, side by side)")
        return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
