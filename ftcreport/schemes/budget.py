"""A run's step count and memory against the limits of :mod:`ftcreport.infra.limits`, with each scheme's own
share (its ``Scheme.budget``: a model bank's states, costs and weights per sample, and the bank itself).

It reads the registry, so it lives with the schemes, not with the limits (which know no scheme).
"""

from __future__ import annotations

import math

from ..infra.limits import _BYTES_PER_STEP, MAX_STEPS, MEMORY_BUDGET_BYTES, n_models

__all__ = ["budget_problem", "run_memory_bytes"]


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
    from .registry import every

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
