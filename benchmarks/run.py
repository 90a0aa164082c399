"""Speed and memory of the simulation core, measured (not asserted).

    python benchmarks/run.py [--quick] [--json FILE]

Prints, per scheme and chain size: wall seconds per simulated second (median of
repeats), model evaluations per second, peak memory of the run (tracemalloc), and
the same two-link closed loop run through python-control's
``input_output_response`` (what a python-control user would write), side by side.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftcreport.cases import load_case, with_duration  # noqa: E402
from ftcreport.control.kinematic import TwoLinkKinematic  # noqa: E402
from ftcreport.control.tracking import TrackingController  # noqa: E402
from ftcreport.model import Chain  # noqa: E402
from ftcreport.model import kernels as K  # noqa: E402
from ftcreport.references import FlatReference, unicycle  # noqa: E402
from ftcreport.runner import build, run_scheme  # noqa: E402

CASES = ROOT / "cases"
SCENARIOS = [
    # (label, case file, scheme, simulated seconds)
    ("two-link switching (3.2.3, ROS2 5 ms)", "two_link_switching.toml", "switching", 20.0),
    ("two-link nominal (3.2.3, ROS2 5 ms)", "two_link_switching.toml", "nominal", 20.0),
    ("two-link adaptive (3.3.2.3 eight, RK4 5 ms)", "two_link_adaptive_eight.toml", "adaptive", 10.0),
    ("three-link switching (3.3.1.4, RK4 10 ms)", "three_link_switching.toml", "switching", 20.0),
    ("three-link adaptive (3.3.2.3, RK4 10 ms)", "three_link_adaptive.toml", "adaptive", 20.0),
    ("five-link switching, 766 models (RK4 20 ms)", "five_link_cascade.toml", "switching", 20.0),
    ("two-link active Farza (Table 4.1, RK4 10 ms)", "two_link_active.toml", "active", 20.0),
    ("two-link active UKF (Table 4.1, 10 ms samples)", "two_link_active.toml", "active_ukf", 20.0),
    ("three-link active Farza (Table 4.2, RK4 20 ms)", "three_link_active.toml", "active", 40.0),
]


def model_evals_per_second(n: int, count: int = 2000) -> float:
    chain = Chain.uniform(n)
    p = chain.params
    q = chain.q_from_headings(0.0, 0.0, np.linspace(0.3, 0.0, n))
    eta = np.array([0.5, 0.1])
    tau = np.ones(2 * n)
    t0 = time.perf_counter()
    for _ in range(count):
        K.eta_dot(p, q, eta, tau)
    return count / (time.perf_counter() - t0)


def scenario(case_file: str, scheme: str, seconds: float, repeats: int) -> dict:
    """Median wall time of untraced runs; peak memory from one extra run under tracemalloc
    (tracemalloc slows Python several-fold, so it never overlaps a timed run)."""
    case = with_duration(load_case(CASES / case_file), seconds)
    walls = []
    for _ in range(repeats):
        built = build(case)
        t0 = time.perf_counter()
        run, m = run_scheme(case, scheme, built)
        walls.append(time.perf_counter() - t0)
        assert m["status"] == "ok", m["reason"]
    built = build(case)
    tracemalloc.start()
    run_scheme(case, scheme, built)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"wall_per_sim_s": statistics.median(walls) / seconds, "peak_mb": peak / 2**20, "steps": run.steps}


def peak_rss_400s() -> dict:
    """Peak resident memory of the 400 s Table 4.2 active run (decimated logging), in a fresh process."""
    import subprocess

    code = (
        "import resource, sys; sys.path.insert(0, {!r})\n"
        "from ftcreport.cases import load_case\n"
        "from ftcreport.runner import run_scheme\n"
        "run, m = run_scheme(load_case({!r}), 'active')\n"
        "print(m['status'], run.t.size, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
    ).format(str(ROOT), str(CASES / "three_link_active.toml"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    return {"status": out[0], "logged_samples": int(out[1]), "peak_rss_mb": int(out[2]) / 1024}


def batch_times() -> dict:
    """`ftcreport batch cases/` cold (empty output directory) and warm (everything cached)."""
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "ftcreport.cli", "batch", str(CASES), "--out", d, "--quiet"]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=False, capture_output=True)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run(cmd, check=False, capture_output=True)
        warm = time.perf_counter() - t0
    return {"cold_s": cold, "warm_s": warm}


def io_response_comparison(seconds: float) -> dict:
    """The two-link healthy closed loop: our engine vs control.input_output_response (RK45)."""
    import control

    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    ctrl = TrackingController(chain, TwoLinkKinematic(1.7, ref, 10, 2, 0.5), k_v=5.0)
    q0, eta0 = np.array([0.3, -0.2, 0.0, 0.0]), np.zeros(2)

    def upd(t, x, u, params):
        q, eta = x[:4], x[4:]
        uu, _ = ctrl.evaluate(t, q, eta, np.zeros(0))
        qd, ed = K.eta_dot(chain.params, q, eta, uu)
        return np.concatenate((qd, ed))

    sys_cl = control.nlsys(upd, None, states=6, inputs=0, outputs=6)
    T = np.linspace(0, seconds, int(seconds / 0.01) + 1)
    t0 = time.perf_counter()
    # default solve_ivp (RK45, rtol 1e-3): what a python-control user gets without tuning
    res = control.input_output_response(sys_cl, T, 0, np.concatenate((q0, eta0)))
    wall_ct = time.perf_counter() - t0
    from ftcreport.sim import Plant, SimSettings, simulate

    t0 = time.perf_counter()
    run = simulate(Plant(chain), ctrl, q0, eta0, SimSettings(dt=0.01, duration=seconds))
    wall_us = time.perf_counter() - t0
    diff = float(np.abs(res.states[:2, -1] - run["q"][-1, :2]).max())
    return {
        "ours_wall_per_sim_s": wall_us / seconds,
        "python_control_wall_per_sim_s": wall_ct / seconds,
        "ratio": wall_ct / wall_us,
        "final_position_difference_m": diff,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats, shorter runs")
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("--no-batch", action="store_true", help="skip the cold/warm batch and the 400 s memory run")
    args = ap.parse_args()
    repeats = 1 if args.quick else 3
    scale = 0.25 if args.quick else 1.0
    out: dict = {"model_evals_per_second": {}, "scenarios": {}}
    for n in (2, 3, 5):
        out["model_evals_per_second"][n] = model_evals_per_second(n, 500 if args.quick else 2000)
        print(f"model eta_dot, n = {n}: {out['model_evals_per_second'][n]:,.0f} evaluations/s")
    for label, case_file, scheme, seconds in SCENARIOS:
        r = scenario(case_file, scheme, seconds * scale, repeats)
        out["scenarios"][label] = r
        print(f"{label:48s} {r['wall_per_sim_s']:.3f} s per simulated s, peak {r['peak_mb']:.1f} MB")
    cmp_ = io_response_comparison(10.0 * scale)
    out["input_output_response"] = cmp_
    print(
        f"two-link healthy loop: ours {cmp_['ours_wall_per_sim_s']:.3f} s/s, python-control "
        f"input_output_response {cmp_['python_control_wall_per_sim_s']:.3f} s/s (ratio {cmp_['ratio']:.2f}); "
        f"final positions differ by {cmp_['final_position_difference_m']:.1e} m"
    )
    if not args.no_batch:
        mem = peak_rss_400s()
        out["memory_400s"] = mem
        print(
            f"400 s Table 4.2 active run: peak RSS {mem['peak_rss_mb']:.0f} MB "
            f"({mem['logged_samples']} logged samples, every 10th step)"
        )
        bt = batch_times()
        out["batch"] = bt
        print(f"ftcreport batch cases/: cold {bt['cold_s']:.0f} s, warm {bt['warm_s']:.1f} s")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
