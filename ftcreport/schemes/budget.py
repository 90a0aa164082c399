"""A run's step count and memory against the limits of :mod:`ftcreport.infra.limits`, with each scheme's own
share (its ``Scheme.budget``: a model bank's states, costs and weights per sample, and the bank itself).

It reads the registry, so it lives with the schemes, not with the limits (which know no scheme).
"""

from __future__ import annotations

import math

import numpy as np

from ..infra.limits import _BYTES_PER_STEP, MAX_STEPS, MEMORY_BUDGET_BYTES, n_models

__all__ = ["budget_problem", "own_memory_problem", "run_memory_bytes"]


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
    N = n_models(n) if models is None else models
    extra, bank = _bank(n, scheme, N)
    return steps * _BYTES_PER_STEP + samples * (_width(n) + extra) * 8 + bank, steps, samples


def _width(n: int) -> int:
    """Values every run logs per sample (:func:`run_memory_bytes`), the scheme's own left out."""
    wheels = 2 * n
    return 3 * (n + 2) + 8 + 8 * wheels + 16


def _bank(n: int, scheme: str, N: int) -> tuple[int, int]:
    """(values logged per sample, bytes) a scheme keeps beyond the common ones (``Scheme.budget``), or (0, 0);
    a plug-in's budget that raises or returns anything else is named (:func:`.controller.hook`)."""
    from .hooks import hook

    sc = _budgeted(scheme)
    return (0, 0) if sc is None else hook(sc, "budget", sc.budget, n, N, convert=_counts)


def _counts(value) -> tuple[int, int]:
    """A ``budget`` hook's result: (values logged per sample, bytes), two whole numbers >= 0."""
    from .hooks import ResultError, one_line

    ok = isinstance(value, tuple | list) and len(value) == 2
    if not ok or not all(isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 0 for v in value):
        raise ResultError(f"returned {one_line(repr(value))[:80]}, not (values logged per sample, bytes) >= 0")
    return int(value[0]), int(value[1])


def _budgeted(scheme: str):
    """The registered scheme of that name when it declares a budget, else None."""
    from .registry import every

    sc = every().get(scheme)
    return None if sc is None or sc.budget is None else sc


#: the field that sets a run's step, its symbol in the reason and the name the advice uses
STEP_DT = ("simulation.dt", "dt", "dt")
#: ... where an error-controlled run lands on the sensor's ticks, shorter than dt
STEP_SENSOR = ("plant.noise.sample_time", "sample_time", "plant.noise.sample_time")


def budget_problem(
    n: int,
    duration: float,
    dt: float,
    log_every: int,
    scheme: str = "",
    models: int | None = None,
    step: tuple[str, str, str] = STEP_DT,
) -> tuple[str, str] | None:
    """(fields, reason) when a run exceeds :data:`MAX_STEPS` or :data:`MEMORY_BUDGET_BYTES`, else None.  ``dt``
    is the run's step, set by ``step`` (:data:`STEP_DT`, or :data:`STEP_SENSOR`): the field a too-short step is
    blamed on, its symbol and the name the advice gives."""
    if not (math.isfinite(duration) and math.isfinite(dt) and dt > 0 and duration > 0):
        return None  # range errors are reported by the field validators
    field, symbol, advice = step
    steps = math.ceil(duration / dt)
    if steps > MAX_STEPS:
        return (
            field,
            f"duration / {symbol} = {duration:g} / {dt:g} = {steps:.3g} steps exceeds the limit of {MAX_STEPS:.0e} "
            f"steps per run; use {advice} >= {duration / MAX_STEPS:.3g} s or a shorter duration",
        )
    need, steps, samples = run_memory_bytes(n, duration, dt, log_every, scheme, models)
    if need > MEMORY_BUDGET_BYTES:
        return _memory_problem(n, duration, dt, scheme, models, need, steps, samples, field)
    return None


def _memory_problem(
    n: int,
    duration: float,
    dt: float,
    scheme: str,
    models: int | None,
    need: int,
    steps: int,
    samples: int,
    step_field: str = STEP_DT[0],
) -> tuple[str, str]:
    """(field, reason) of a run over the memory budget: the part of the estimate that dominates (the time
    grid, the logged time series, or the scheme's model bank) and what brings it within the budget."""
    N = n_models(n) if models is None else models
    from .registry import is_built_in

    banked = _budgeted(scheme) is not None
    extra, bank = _bank(n, scheme, N)
    per_sample = (_width(n) + extra) * 8
    grid = steps * _BYTES_PER_STEP
    series = samples * per_sample
    why = f" with {N} models (3 * 4^(n-1) - 2 = {n_models(n)} for n = {n})" if banked else ""
    head = (
        f"the {scheme + ' ' if scheme else ''}run needs about {_mib(need)} MiB ({samples} logged samples of {steps} "
        f"steps{why}), over the memory budget of {_mib(MEMORY_BUDGET_BYTES)} MiB"
    )
    fewer = (
        f"list fewer patterns in [schemes.{scheme}] patterns, leave {scheme} out of [schemes] run (list the schemes "
        f"to run there, without {scheme}, and drop [schemes.{scheme}]), or use fewer robots"
    )
    if banked and not is_built_in(_budgeted(scheme)):  # a plug-in's own budget hook: no patterns field to name
        from .hooks import hook_where

        where = hook_where(_budgeted(scheme), _budgeted(scheme).budget)
        fewer = (
            f"its budget hook ({where.rstrip(': ')}) declares {extra} values per sample and {_mib(bank)} MiB; "
            f"leave {scheme} out of [schemes] run, or use fewer robots"
        )
    if banked and bank >= max(grid, series):
        return (
            "robots.n",
            f"{head}: the {scheme} scheme's model bank (its table of {N} patterns and the tables built from it) alone "
            f"needs about {_mib(bank)} MiB, whatever the duration and logging; {fewer}",
        )
    room = MEMORY_BUDGET_BYTES - grid - bank  # what the log may take
    if series >= grid and room >= 2 * per_sample:  # the log dominates and fewer samples fit
        every = math.ceil(steps / max(room // per_sample - 2, 1))
        while every > 1 and _fits(n, duration, dt, every - 1, scheme, models):  # the estimate's own rounding
            every -= 1
        while not _fits(n, duration, dt, every, scheme, models):
            every += 1
        return (
            "simulation.log_every",
            f"{head}: the logged time series take about {_mib(series)} MiB; raise simulation.log_every to at least "
            f"{every}, or shorten simulation.duration",
        )
    if series >= grid:  # even two logged samples (the first and the last) are over: the width is the scheme's
        return (
            "robots.n",
            f"{head}: each logged sample holds {per_sample // 8} values ({extra} of them the {scheme} scheme's, for "
            f"its {N} models), so no logging interval brings it within the budget; {fewer}",
        )
    return (
        step_field,
        f"{head}: the time grid of {steps} steps takes about {_mib(grid)} MiB; raise {step_field} or shorten "
        "simulation.duration",
    )


#: the fewest rows a run's chunk buffers hold (fast.auto_run: at least 64; fast.simulate: 1 % of the steps)
_MIN_CHUNK_ROWS = 64


def own_memory_problem(scheme: str, n_own: int, widths: dict[str, int], case) -> str | None:
    """Why a plug-in's own states and signals do not fit a run of ``case`` in the memory budget, else None.

    A run logs them with every saved sample (``simulation.log_every``) and holds them in its chunk buffers
    (1 % of the steps, at least 64 rows), beside what :func:`run_memory_bytes` counts; checked when the scheme
    is bound to the case, before any array of that size is made (``signals = {"K": 10**11}``: the run failed
    with out of memory, naming neither the scheme nor the signal).
    """
    s = case.simulation
    common, steps, samples = run_memory_bytes(case.robots.n, s.duration, s.dt, s.log_every, scheme)
    width = n_own + sum(widths.values())
    rows = samples + max(_MIN_CHUNK_ROWS, steps // 100 + 1)
    need = common + rows * width * 8
    if need <= MEMORY_BUDGET_BYTES:
        return None
    wide = sorted(widths.items(), key=lambda kv: -kv[1])[:3]
    parts = ", ".join([f"n_states: {n_own:.3g}", *(f"signal {k}: {v:.3g}" for k, v in wide)])
    fewest = common + (2 + _MIN_CHUNK_ROWS) * width * 8  # two saved samples, the smallest chunk
    fix = (
        "declare fewer states or narrower signals"
        if fewest > MEMORY_BUDGET_BYTES
        else "raise simulation.log_every or shorten simulation.duration, or declare fewer states or narrower signals"
    )
    return (
        f"scheme {scheme}: its own states and signals are {width:.3g} values per logged row ({parts}); a run of "
        f"{samples} saved samples and {rows - samples} buffered steps needs about {_mib(need)} MiB, over the memory "
        f"budget of {_mib(MEMORY_BUDGET_BYTES)} MiB: {fix}"
    )


def _fits(n: int, duration: float, dt: float, log_every: int, scheme: str, models: int | None) -> bool:
    return run_memory_bytes(n, duration, dt, log_every, scheme, models)[0] <= MEMORY_BUDGET_BYTES


def _mib(b: float) -> str:
    return f"{b / 2**20:.0f}"
