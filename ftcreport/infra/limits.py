"""Stated limits: safe case names and the memory budget of one run (no I/O).

Case names
    A case name becomes a directory under ``--out`` and the title of an HTML page.
    It must match ``[A-Za-z0-9][A-Za-z0-9_.-]{0,63}`` (so it cannot hold a path
    separator, start with a dot, contain ``..`` as a component, a NUL byte or
    markup), must not be one of the generated names (:data:`RESERVED_NAMES`,
    compared without case), and within one batch names must differ in more than
    letter case (case-insensitive file systems would merge them).

Memory budget
    A run preallocates its time grid and its logs.  ``schemes.budget.run_memory_bytes``
    estimates both from ``duration``, ``dt``, ``log_every``, the number of robots
    and the scheme's model bank (switching and adaptive keep state per failure
    pattern: 3 * 4^(n-1) - 2 of them with ``patterns = "all"``).  A run whose
    estimate exceeds :data:`MEMORY_BUDGET_BYTES`, or whose step count exceeds
    :data:`MAX_STEPS`, is refused before it starts with a message naming the
    fields and the limit.
"""

from __future__ import annotations

import os

from ..errors import FtcError
from .names import NAME_PATTERN

__all__ = [
    "GENERATED_NAMES",
    "MAX_STEPS",
    "MEMORY_BUDGET_BYTES",
    "NAME_PATTERN",
    "RESERVED_NAMES",
    "n_models",
    "name_collisions",
    "name_problem",
    "worker_count",
]

#: Every file and folder an ftcreport command writes at the top of an output directory (``reports/``),
#: with who writes it: the one list of them.  A case is a folder there too, so none of these may be a
#: case's name (tests/test_trust.py checks that a batch, check --junit and export write nothing else).
GENERATED_NAMES: dict[str, str] = {
    "index.html": "the index page (batch, run, report)",
    "manifest.json": "the batch's provenance (batch)",
    "metrics.parquet": "every run's metrics, one row per phase (batch, export)",
    "metrics.parquet.stamp": "the table's hash and its inputs' digest: redone when either differs (batch, export)",
    "junit.xml": "the usual place of check --junit",
    "baseline.html": "the comparison with a baseline (check --baseline)",
    "baseline.html.stamp": "the seals of the runs baseline.html compares: linked from the index while they hold",
    "assets": "files the pages share",
    "campaigns": "campaign's pages and tables (reports/campaigns/<case>)",
    "coverage": "coverage's pages and tables (reports/coverage/<case>)",
    "fdi": "fdi's pages and results (reports/fdi/<case>)",
    ".ftcreport.lock": "the output directory's lock",
    ".ftcreport.kind": "which command's results the output directory holds",
}
#: names the output directory uses itself (compared lower-case); ``index`` too, the pages' link name
RESERVED_NAMES = frozenset({"index", *GENERATED_NAMES})

#: largest number of integration steps of one run (time grid and per-step bookkeeping)
MAX_STEPS = 10_000_000
#: memory a run may preallocate for its grid, logs and model bank
MEMORY_BUDGET_BYTES = 1 << 30  # 1 GiB
_BYTES_PER_STEP = 40  # time grid, step flags and their temporaries


def name_problem(name: object) -> str | None:
    """Why ``name`` is not a safe case name, or None when it is."""
    if not isinstance(name, str):
        return f"must be a string, got {type(name).__name__}"
    shown = repr(name) if len(name) <= 40 else repr(name[:40]) + f"... ({len(name)} characters)"
    if not NAME_PATTERN.fullmatch(name):
        if len(name) > 64:
            return f"{shown} is longer than 64 characters"
        return f"{shown} must start with a letter or digit and hold only ASCII letters, digits, '_', '.', '-'"
    if name.lower() in RESERVED_NAMES or name.lower().endswith(".html"):
        names = ", ".join(sorted(n for n in RESERVED_NAMES if not n.startswith(".")))
        return f"{shown} is a name the report uses itself ({names}, *.html)"
    return None


def name_collisions(names: list[str]) -> dict[int, int]:
    """Index of each name that repeats an earlier one (ignoring letter case) -> index of that earlier one."""
    first: dict[str, int] = {}
    out = {}
    for i, n in enumerate(names):
        k = n.lower()
        if k in first:
            out[i] = first[k]
        else:
            first[k] = i
    return out


def n_models(n: int) -> int:
    """Compensable 0/1 failure patterns of an n-robot chain: 3 * 4^(n-1) - 2."""
    return 3 * 4 ** (n - 1) - 2


def worker_count(
    jobs: int | None, runs: int, option: str = "--jobs", noun: str = "runs to simulate"
) -> tuple[int, str | None]:
    """Worker processes for ``runs`` tasks: ``jobs`` (default: the cores), at most the number of tasks and the
    cores this process may use; and why it was capped below the ``jobs`` asked for (None when it was not,
    or when ``jobs`` was not given).  ``option`` (``--jobs``, ``--workers``) and ``noun`` name them in the
    message: a number below 1 is refused (FtcError)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    if jobs is not None and jobs < 1:
        raise FtcError(f"{option}: must be at least 1, got {jobs}")
    want = cores if jobs is None else jobs
    n = max(1, min(want, cores, runs))
    if jobs is None or n == jobs:
        return n, None
    why = f"the number of {noun}" if runs < cores else f"the cores this process may use ({cores})"
    return n, why
