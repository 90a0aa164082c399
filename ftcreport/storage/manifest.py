"""Provenance manifest: what produced a batch or a campaign.

One module for both (issues 22 and 24 share it). A manifest records the
package version, the git revision when the package runs from a checkout, the
versions of every runtime dependency, Python, the platform and CPU, and what
the caller adds: the engine per run, seeds, case content hashes.

Layout of ``manifest.json``::

    {"kind": "batch" | "campaign",
     "created": ISO 8601 UTC,
     "ftcreport": {"version": ..., "git": {"revision": ..., "dirty": bool} | null},
     "python": {"version": ..., "implementation": ...},
     "platform": {"system": ..., "release": ..., "machine": ..., "cpu": ..., "cores": int},
     "dependencies": {name: version | null},
     ... caller's keys (cases, runs, seeds, ...)}

This module reads the environment (``importlib.metadata``, ``git``, ``/proc``) and
writes one file; it sits with storage at the edge, never in the numeric core.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import os
import platform
import subprocess
import sys
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from .. import __version__

__all__ = [
    "NUMERIC_DEPENDENCIES",
    "RUNTIME_DEPENDENCIES",
    "build_manifest",
    "environment",
    "numeric_versions",
    "write_manifest",
]

#: Distributions whose versions the manifest records (runtime and optional export/report ones).
RUNTIME_DEPENDENCIES: tuple[str, ...] = (
    "numpy",
    "scipy",
    "control",
    "slycot",
    "numba",
    "llvmlite",
    "pydantic",
    "typer",
    "click",
    "rich",
    "jinja2",
    "matplotlib",
    "dask",
    "distributed",
    "cloudpickle",
    "pandas",
    "pyarrow",
    "xarray",
    "h5netcdf",
    "h5py",
    "plotly",
)
#: The distributions whose version can change a simulated number (part of result cache keys).
NUMERIC_DEPENDENCIES: tuple[str, ...] = ("numpy", "scipy", "numba", "llvmlite", "control", "slycot")


def _dist_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git() -> dict[str, Any] | None:
    """Revision of the checkout this package runs from, or None (installed copy, no git)."""
    root = Path(__file__).resolve().parents[2]  # ftcreport/storage/manifest.py -> the checkout
    if not (root / ".git").exists():
        return None
    try:
        rev = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return {"revision": rev, "dirty": bool(dirty)}


@functools.lru_cache(maxsize=1)
def environment() -> dict[str, Any]:
    """The process's environment: package, git, Python, platform, dependency versions (cached)."""
    return {
        "ftcreport": {"version": __version__, "git": _git()},
        "python": {"version": platform.python_version(), "implementation": sys.implementation.name},
        "platform": {
            "system": platform.system(),
            "release": platform.release(),
            "machine": platform.machine(),
            "cpu": _cpu(),
            "cores": os.cpu_count(),
        },
        "dependencies": {name: _dist_version(name) for name in RUNTIME_DEPENDENCIES},
    }


def numeric_versions() -> dict[str, str | None]:
    """Versions that can change a simulated number; a result cache key includes them."""
    deps = environment()["dependencies"]
    return {"ftcreport": __version__, **{k: deps.get(k) for k in NUMERIC_DEPENDENCIES}}


def build_manifest(kind: str, **fields: Any) -> dict[str, Any]:
    """A manifest of ``kind`` ("batch", "campaign", "coverage") with the caller's ``fields`` added.

    Typical fields: ``cases={name: content_hash}``, ``runs=[{case, scheme, engine, status}]``,
    ``seeds={...}``, ``settings={...}``.
    """
    created = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    return {"kind": kind, "created": created, **environment(), **fields}


def write_manifest(path: Path, manifest: Mapping[str, Any]) -> Path:
    """Write ``manifest`` as JSON to ``path`` atomically; returns the path."""
    from .store import write_atomic

    path = Path(path)
    write_atomic(path, (json.dumps(manifest, indent=2, sort_keys=False, default=str) + "\n").encode())
    return path
