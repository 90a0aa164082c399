"""Wall time of one UKF step: compiled (ftcreport.observers.ukf_compiled) against filterpy (tests/ukf_reference.py).

    python benchmarks/ukf_step.py [--n 2,3] [--steps 2000] [--repeats 5] [--json FILE]

For each chain size n (thesis robot, gains and frictions estimated: the largest
state, nx = 5 n + 4) runs both steps along the same measured sequence (the
filter's own q plus 1 mm noise, a slowly varying u) and prints the median over
repeats of the wall (and CPU) seconds per step, the speed-up, and the implied wall seconds per
simulated second at each sampling period the cases use: the estimator runs once
per simulation step, h = dt (cases/*.toml: 5, 10, 20 ms).  The compile time
of the first compiled call (numba cache warm or cold) is reported separately.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the filterpy reference

from ukf_reference import FilterpyUKF  # noqa: E402

from ftcreport.fast import kernels as F  # noqa: E402
from ftcreport.model import Chain  # noqa: E402
from ftcreport.observers import UKFEstimator  # noqa: E402
from ftcreport.observers.ukf_compiled import ukf_params, ukf_step  # noqa: E402

DTS = (0.005, 0.01, 0.02)  # the simulation steps of cases/*.toml
H = 0.01  # the step used for timing (the cost does not depend on h)


def _inputs(n: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(n)
    t = H * np.arange(steps)
    u = 0.5 + 0.4 * np.sin(1.3 * t[:, None] + np.arange(2 * n))
    noise = 1e-3 * rng.standard_normal((steps, n + 2))
    return u, noise


def _run(step, s: np.ndarray, u: np.ndarray, noise: np.ndarray, N: int) -> tuple[float, float]:
    """(wall, CPU) seconds per step: the machine may be shared, the thread's CPU time is not."""
    t0, c0 = time.perf_counter(), time.thread_time()
    for k in range(u.shape[0]):
        s = step(s, u[k], s[:N] + noise[k])
    return (time.perf_counter() - t0) / u.shape[0], (time.thread_time() - c0) / u.shape[0]


def measure(n: int, steps: int, repeats: int) -> dict:
    chain = Chain.uniform(n)
    est = UKFEstimator(chain, meas_std=1e-3)
    pc = F.Chain(*chain.params)
    params = ukf_params(est)
    s0 = est.initial_state(np.zeros(chain.n_q))
    u, noise = _inputs(n, steps)

    def compiled(s, uk, yk):
        out, status = ukf_step(pc, params, s, uk, yk, H)
        if status:
            raise SystemExit(f"status {status}")
        return out

    t0 = time.perf_counter()
    compiled(s0, u[0], s0[: est.N])
    first = time.perf_counter() - t0
    short = max(steps // 10, 50)  # filterpy: fewer steps (it is slower), same sequence
    fast = [_run(compiled, s0, u, noise, est.N) for _ in range(repeats)]
    ref_step = FilterpyUKF(est).step
    ref = [_run(lambda s, uk, yk: ref_step(s, uk, yk, H), s0, u[:short], noise[:short], est.N) for _ in range(repeats)]
    t_fast, t_ref = statistics.median(t for t, _ in fast), statistics.median(t for t, _ in ref)
    c_fast, c_ref = statistics.median(c for _, c in fast), statistics.median(c for _, c in ref)
    return {
        "n": n,
        "nx": est.nx,
        "first_call_s": first,
        "compiled_s_per_step": t_fast,
        "filterpy_s_per_step": t_ref,
        "compiled_cpu_s_per_step": c_fast,
        "filterpy_cpu_s_per_step": c_ref,
        "speedup": t_ref / t_fast,
        "s_per_simulated_s": {
            f"dt={dt:g}": {"compiled": t_fast / dt, "filterpy": t_ref / dt, "compiled_cpu": c_fast / dt} for dt in DTS
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", default="2,3")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = [measure(int(n), args.steps, args.repeats) for n in args.n.split(",")]
    for r in rows:
        per = ", ".join(
            f"{k}: {v['compiled']:.4f} [CPU {v['compiled_cpu']:.4f}] ({v['filterpy']:.3f})"
            for k, v in r["s_per_simulated_s"].items()
        )
        print(
            f"n = {r['n']} (nx = {r['nx']}): compiled {1e6 * r['compiled_s_per_step']:.1f} us/step, "
            f"filterpy {1e6 * r['filterpy_s_per_step']:.0f} us/step, x{r['speedup']:.0f} (CPU: "
            f"{1e6 * r['compiled_cpu_s_per_step']:.1f} and {1e6 * r['filterpy_cpu_s_per_step']:.0f} us/step); "
            f"s per simulated s, compiled [CPU] (filterpy): {per}; first call {r['first_call_s']:.2f} s"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
