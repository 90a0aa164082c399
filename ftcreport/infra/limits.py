"""Stated limits: safe case names and the memory budget of one run (no I/O).

Case names
    A case name becomes a directory under ``--out`` and the title of an HTML page.
    It must match ``[A-Za-z0-9][A-Za-z0-9_.-]{0,63}`` (so it cannot hold a path
    separator, start with a dot, contain ``..`` as a component, a NUL byte or
    markup), must not be one of the generated names (:data:`RESERVED_NAMES`,
    compared without case), and within one batch names must differ in more than
    letter case (case-insensitive file systems would merge them).

Memory budget
    A run preallocates its time grid and its logs.  :func:`run_memory_bytes`
    estimates both from ``duration``, ``dt``, ``log_every``, the number of robots
    and the scheme's model bank (switching and adaptive keep state per failure
    pattern: 3 * 4^(n-1) - 2 of them with ``patterns = "all"``).  A run whose
    estimate exceeds :data:`MEMORY_BUDGET_BYTES`, or whose step count exceeds
    :data:`MAX_STEPS`, is refused before it starts with a message naming the
    fields and the limit.
"""

from __future__ import annotations

import math

from .names import NAME_PATTERN

__all__ = [
    "GENERATED_NAMES",
    "MAX_STEPS",
    "MEMORY_BUDGET_BYTES",
    "NAME_PATTERN",
    "RESERVED_NAMES",
    "budget_problem",
    "n_models",
    "name_collisions",
    "name_problem",
    "run_memory_bytes",
]

#: Every file and folder an ftcreport command writes at the top of an output directory (``reports/``),
#: with who writes it: the one list of them.  A case is a folder there too, so none of these may be a
#: case's name (tests/test_trust.py checks that a batch, check --junit and export write nothing else).
GENERATED_NAMES: dict[str, str] = {
    "index.html": "the index page (batch, run, report)",
    "manifest.json": "the batch's provenance (batch)",
    "metrics.parquet": "every run's metrics, one row per phase (batch, export)",
    "junit.xml": "the usual place of check --junit",
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


def run_memory_bytes(
    n: int, duration: float, dt: float, log_every: int, scheme: str = "", models: int | None = None
) -> tuple[int, int, int]:
    """Estimated (bytes, steps, logged samples) of one run.

    Logged values per sample: q, q_d, q_meas (n + 2 each), eta, eta_c, eta_d, z
    (2 each), u, tau, sigma, ubar and the estimates (2n each, 8 arrays), plus what the
    scheme keeps beyond them (its ``Scheme.budget``: a model bank's states, costs and
    weights per sample, and the bank itself; the switching and adaptive schemes').
    """
    steps = math.ceil(duration / dt)
    samples = steps // max(int(log_every), 1) + 2
    wheels = 2 * n
    width = 3 * (n + 2) + 8 + 8 * wheels + 16
    N = n_models(n) if models is None else models
    extra, bank = _bank(n, scheme, N)
    return steps * _BYTES_PER_STEP + samples * (width + extra) * 8 + bank, steps, samples


def _bank(n: int, scheme: str, N: int) -> tuple[int, int]:
    """(values logged per sample, bytes) a scheme keeps beyond the common ones (``Scheme.budget``), or (0, 0)."""
    hook = _budget_hook(scheme)
    return (0, 0) if hook is None else hook(n, N)


def _budget_hook(scheme: str):
    from ..schemes import every

    sc = every().get(scheme)
    return None if sc is None else sc.budget


def budget_problem(
    n: int, duration: float, dt: float, log_every: int, scheme: str = "", models: int | None = None
) -> tuple[str, str] | None:
    """(fields, reason) when a run exceeds :data:`MAX_STEPS` or :data:`MEMORY_BUDGET_BYTES`, else None."""
    if not (math.isfinite(duration) and math.isfinite(dt) and dt > 0 and duration > 0):
        return None  # range errors are reported by the field validators
    steps = math.ceil(duration / dt)
    if steps > MAX_STEPS:
        return (
            "simulation.dt",
            f"duration / dt = {duration:g} / {dt:g} = {steps:.3g} steps exceeds the limit of {MAX_STEPS:.0e} "
            f"steps per run; use dt >= {duration / MAX_STEPS:.3g} s or a shorter duration",
        )
    need, steps, samples = run_memory_bytes(n, duration, dt, log_every, scheme, models)
    if need > MEMORY_BUDGET_BYTES:
        N = n_models(n) if models is None else models
        banked = _budget_hook(scheme) is not None
        why = f" with {N} models (3 * 4^(n-1) - 2 = {n_models(n)} for n = {n})" if banked else ""
        field = "robots.n" if banked and 4 * _bank(n, scheme, N)[1] > MEMORY_BUDGET_BYTES else "simulation.log_every"
        return (
            field,
            f"the {scheme + ' ' if scheme else ''}run needs about {need / 2**20:.0f} MiB ({samples} logged samples "
            f"of {steps} steps{why}), "
            f"over the memory budget of {MEMORY_BUDGET_BYTES / 2**20:.0f} MiB; raise simulation.log_every, "
            "shorten simulation.duration or list fewer patterns",
        )
    return None
