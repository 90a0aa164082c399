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

import contextlib
import io
import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FtcError
from .sim import Run

__all__ = [
    "OutputBusyError",
    "cached_key",
    "clean_partial",
    "load_metrics",
    "load_timeseries",
    "output_lock",
    "read_json",
    "save_run",
    "stored_metrics",
    "write_atomic",
    "write_json",
]

TMP_SUFFIX = ".partial"  # a temporary file of write_atomic; only a killed process leaves one behind
LOCK_NAME = ".ftcreport.lock"


def write_atomic(path: Path, data: bytes) -> None:
    """Write bytes to ``path`` atomically (temporary file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # what open() would give, not mkstemp's 0600
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


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
    (d / "key").unlink(missing_ok=True)  # the directory is incomplete until the new key is written
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


def stored_schemes(out: Path, case_name: str) -> list[str]:
    """The schemes with a stored run of a case (built-in ones first, then plug-in ones by name)."""
    from .cases import ordered_schemes

    d = Path(out) / case_name
    found = sorted(p.parent.name for p in d.glob("*/metrics.json")) if d.is_dir() else []
    return ordered_schemes(found)


def read_json(path: Path) -> Any:
    """The content of a JSON file, or None when it is missing, unreadable or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def load_metrics(out: Path, case_name: str, scheme: str) -> dict | None:
    return read_json(Path(out) / case_name / scheme / "metrics.json")


def stored_metrics(out: Path, case_name: str) -> dict[str, dict]:
    """``{scheme: metrics.json content}`` of the case's stored runs, in scheme order (plug-ins last)."""
    runs = {s: load_metrics(out, case_name, s) for s in stored_schemes(out, case_name)}
    return {s: m for s, m in runs.items() if m is not None}


def load_timeseries(out: Path, case_name: str, scheme: str) -> dict[str, np.ndarray] | None:
    try:
        with np.load(Path(out) / case_name / scheme / "timeseries.npz") as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError):
        return None


# ------------------------------------------------------------------ one writer per output directory
class OutputBusyError(FtcError):
    """Another ftcreport process is writing to the same output directory."""

    exit_code = 2


_held: dict[str, list] = {}  # resolved directory -> [open lock file, depth] (re-entrant in one process)


@contextlib.contextmanager
def output_lock(out: Path, command: str):
    """Hold the exclusive lock of an output directory (``<out>/.ftcreport.lock``, ``flock``).

    Two processes never write to the same directory at once: the second one fails at
    once with :class:`OutputBusyError` naming the holder.  The kernel drops the lock when
    its holder exits, however it exits (SIGKILL included), so no stale lock remains.
    Re-entrant within one process (``batch`` renders the report under its own lock).
    """
    import fcntl

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    key = str(out.resolve())
    if key in _held:
        _held[key][1] += 1
        try:
            yield
        finally:
            _held[key][1] -= 1
        return
    path = out / LOCK_NAME
    fh = open(path, "a+")  # noqa: SIM115 - held open for the lock's lifetime
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        # the holder writes its name just after it takes the lock: wait a moment for it
        holder = ""
        for _ in range(50):
            fh.seek(0)
            holder = fh.read().strip()
            if holder:
                break
            time.sleep(0.01)
        holder = holder or "another process"
        fh.close()
        raise OutputBusyError(
            f"{out}: --out: in use by {holder}; wait for it to finish or choose another --out "
            "(one ftcreport process writes to an output directory at a time)"
        ) from None
    try:
        fh.seek(0)
        fh.truncate()
        fh.write(f"ftcreport {command} (pid {os.getpid()})")
        fh.flush()
        _held[key] = [fh, 1]
        clean_partial(out)
        yield
    finally:
        _held.pop(key, None)
        with contextlib.suppress(OSError):
            fh.seek(0)
            fh.truncate()
        fh.close()  # releases the flock


def clean_partial(out: Path) -> int:
    """Remove the temporary files a killed writer left (call with the lock held); returns how many."""
    n = 0
    for root, dirs, files in os.walk(out):
        # a nested output directory (reports/campaigns/<case>) has its own lock and writer: not ours
        dirs[:] = [d for d in dirs if not (Path(root) / d / LOCK_NAME).exists()]
        for f in files:
            if f.startswith(".") and f.endswith(TMP_SUFFIX):
                with contextlib.suppress(OSError):
                    (Path(root) / f).unlink()
                    n += 1
    return n
