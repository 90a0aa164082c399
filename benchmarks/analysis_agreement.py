"""Whether two versions of the analysis compute the same numbers on every shipped case (issue 37 item 9).

``--save FILE`` writes every number ``analysis.analyze_case(load_case(path), confirm=False)`` gives for
cases/*.toml and cases/motors/*.toml (poles, spectral radii or largest real parts at every instant,
internal modes, margins, limits and their curves, the case-wide analyses), flattened to
``{case: {path: array}}``; ``--compare OLD NEW`` prints, per case, the largest relative change and
where.  A relative change is taken against the largest magnitude of the same array (a pole list's
change against its largest pole), so that a zero imaginary part does not read as an infinite change.

    python benchmarks/analysis_agreement.py --save old.pkl      # on the old code
    python benchmarks/analysis_agreement.py --save new.pkl      # on the new
    python benchmarks/analysis_agreement.py --compare old.pkl new.pkl
"""

from __future__ import annotations

import argparse
import math
import pickle
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: keys that are no result of the analysis (wall time)
SKIP = {"analysis_time"}


def flatten(obj, path: str = "", out: dict | None = None) -> dict[str, np.ndarray]:
    """Every number in a nested result, as ``{path: float array}`` (lists of numbers become one array)."""
    out = {} if out is None else out
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k not in SKIP:
                flatten(v, f"{path}/{k}", out)
    elif isinstance(obj, list | tuple | np.ndarray):
        arr = np.asarray(obj) if not isinstance(obj, np.ndarray) else obj
        if arr.dtype.kind in "fciub" and arr.size:
            out[path] = np.asarray(arr, dtype=complex).ravel()
        else:
            for i, v in enumerate(obj):
                flatten(v, f"{path}[{i}]", out)
    elif isinstance(obj, bool | int | float | complex | np.number) and obj is not None:
        out[path] = np.asarray([obj], dtype=complex)
    return out


def save(file: Path) -> None:
    from ftcreport.analysis import analyze_case
    from ftcreport.cases import load_case

    res = {}
    for path in sorted([*ROOT.glob("cases/*.toml"), *ROOT.glob("cases/motors/*.toml")]):
        t0 = time.perf_counter()
        res[path.stem] = flatten(analyze_case(load_case(path), confirm=False))
        print(f"{path.stem}: {len(res[path.stem])} arrays, {time.perf_counter() - t0:.1f} s", flush=True)
    file.write_bytes(pickle.dumps(res))


def compare(old_file: Path, new_file: Path) -> float:
    """Print each case's largest relative change (and where); return the largest over all cases."""
    old, new = pickle.loads(old_file.read_bytes()), pickle.loads(new_file.read_bytes())
    worst_all = 0.0
    for case in sorted(set(old) | set(new)):
        a, b = old.get(case, {}), new.get(case, {})
        if set(a) != set(b):
            print(f"{case}: keys differ: {sorted(set(a) ^ set(b))[:5]}")
        worst, where = 0.0, ""
        for key in sorted(set(a) & set(b)):
            x, y = a[key], b[key]
            if x.shape != y.shape:
                worst, where = math.inf, f"{key} shape {x.shape} -> {y.shape}"
                break
            fin = np.isfinite(x) & np.isfinite(y)
            if np.any(np.isfinite(x) != np.isfinite(y)):
                worst, where = math.inf, f"{key} finite {x} -> {y}"
                break
            scale = float(np.abs(x[fin]).max(initial=0.0))
            rel = float(np.abs(x[fin] - y[fin]).max(initial=0.0)) / scale if scale > 0 else 0.0
            if rel > worst:
                worst, where = rel, key
        print(f"{case}: largest relative change {worst:.2e} at {where}")
        worst_all = max(worst_all, worst)
    print(f"largest over the cases: {worst_all:.2e}")
    return worst_all


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", type=Path)
    ap.add_argument("--compare", type=Path, nargs=2)
    args = ap.parse_args()
    if args.save:
        save(args.save)
    if args.compare:
        compare(*args.compare)


if __name__ == "__main__":
    main()
