"""Result storage at the edge: atomic files, one directory per case and scheme.

Layout under the output directory (``reports/`` by default)::

    <case>/<scheme>/metrics.json      the metrics (ftcreport.metrics names), status and reason
    <case>/<scheme>/timeseries.npz    t, q, q_d, eta, u, tau, sigma, ubar and the controller's signals
    <case>/<scheme>/key               the cache key (hash of case content + package version)

Every file is written to a temporary name in the same directory and renamed
into place (``os.replace``), so a reader never sees a half-written file and an
interrupted run loses nothing already stored.
"""

from __future__ import annotations

import io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .sim import Run

__all__ = ["cached_key", "load_metrics", "load_timeseries", "save_run", "write_atomic", "write_json"]


def write_atomic(path: Path, data: bytes) -> None:
    """Write bytes to ``path`` atomically (temporary file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: Path, obj: Any) -> None:
    """Atomic JSON (NaN and inf written as null)."""
    write_atomic(path, (json.dumps(_jsonable(obj), indent=2, sort_keys=False) + "\n").encode())


def save_run(out: Path, case_name: str, scheme: str, run: Run, metrics: dict, key: str) -> Path:
    """Store one run; the key file is written last so a complete directory has it."""
    d = Path(out) / case_name / scheme
    buf = io.BytesIO()
    arrays = {"t": run.t, **{k: v for k, v in run.signals.items()}}
    np.savez_compressed(buf, **arrays)
    write_atomic(d / "timeseries.npz", buf.getvalue())
    write_json(d / "metrics.json", metrics)
    write_atomic(d / "key", key.encode())
    return d


def cached_key(out: Path, case_name: str, scheme: str) -> str | None:
    """The cache key of a stored run, or None when absent or incomplete."""
    d = Path(out) / case_name / scheme
    try:
        key = (d / "key").read_text().strip()
    except OSError:
        return None
    if not (d / "metrics.json").exists() or not (d / "timeseries.npz").exists():
        return None
    return key


def load_metrics(out: Path, case_name: str, scheme: str) -> dict | None:
    try:
        return json.loads((Path(out) / case_name / scheme / "metrics.json").read_text())
    except (OSError, ValueError):
        return None


def load_timeseries(out: Path, case_name: str, scheme: str) -> dict[str, np.ndarray] | None:
    try:
        with np.load(Path(out) / case_name / scheme / "timeseries.npz") as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError):
        return None
