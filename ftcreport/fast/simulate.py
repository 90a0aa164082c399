"""A compiled run from its start to its status: the chunked fixed-step loop, then the stop's re-check."""

from __future__ import annotations

import time as _time
from typing import TYPE_CHECKING

import numpy as np

from ..jit.packed import AT_STATE
from .auto_run import _simulate_auto
from .engine import (
    _FIRST_CALLS,
    _READY,
    _collect,
    _compile_time,
    _finish,
    _Loop,
    _timing_mark,
    disc_ticks,
    n_noise_ticks,
    noise_ticks,
)
from .integrators import METHOD_CODES
from .recheck import _controlled_recheck, _keep_checkpoints, _recheck, _relabel
from .stops import _stop

if TYPE_CHECKING:
    from .engine import Spec


def simulate_compiled(spec: Spec, plant, q0, eta0, settings, grid, log_idx, progress=None):
    """sim.simulate on the compiled kernels; returns a :class:`~ftcreport.sim.Run`.

    ``grid`` (the step boundaries) and ``log_idx`` (the logged steps) for a fixed-step method; both
    None for an error-controlled one (``SimSettings.method`` in fast.integrators.AUTO_METHODS).
    """
    if grid is None:
        return _simulate_auto(spec, plant, q0, eta0, settings, progress)
    from ..runs import Run

    n_steps = grid.shape[0] - 1
    is_logged = np.zeros(n_steps + 1, dtype=np.bool_)
    is_logged[log_idx] = True
    times = np.array(sorted(set(float(v) for v in plant.faults.times)), dtype=float)
    seg = np.searchsorted(times, grid, side="right")
    firsts = np.unique(seg, return_index=True)[1]
    fidx = np.searchsorted(np.unique(seg), seg).astype(np.int64)
    compile0 = _FIRST_CALLS[0]  # compile_time below
    L = _Loop(spec, plant, q0, eta0, settings, grid[firsts], n_noise_ticks(plant, settings))
    if plant.noisy:  # each step holds the draw of the sensor's tick it starts in (its clock divides dt's grid)
        ticks = np.minimum(noise_ticks(plant, settings, float(grid[0]), grid), L.noise.shape[0] - 1)
        L.step_noise = np.ascontiguousarray(L.noise[ticks])
    steps_new = L.loop.run_steps not in _READY
    nq = L.nq
    # The kernels log every step of a chunk (about 1 % of the run) into chunk buffers; after each chunk
    # the light signals go to the full-rate metric stream and every signal of the logged steps
    # (log_every) to the saved log, so the heavy ones (xc, switching costs, weights) are never held
    # at full rate.
    chunk = max(1, n_steps // 100)
    L.buffers(chunk + 1)
    every_step = np.ones(n_steps + 1, dtype=np.bool_)
    disc_on = disc_ticks(spec, plant, settings, grid)  # the UKF's update on the sensor's ticks
    method = METHOD_CODES[settings.method]
    stream: dict[str, np.ndarray] = {}  # preallocated for every step on the first chunk
    log_parts: list[list[np.ndarray]] = []
    si = 0
    k = 0
    status, reason = "ok", ""
    t_end = float(grid[0])
    checkpoints: list[tuple[int, tuple]] = []  # (step, carried state) at chunk starts: the re-check's restarts
    recheck = None
    wall0 = _time.perf_counter()
    first_s, chunks = 0.0, 0  # the first chunk's call (with the loop's compile or load when it is new here)
    if L.info[0] != 0:  # the first command failed (at t0, before any step)
        status, reason, t_end = _stop(L.info, AT_STATE, t_end, t_end, settings, spec.ref, spec, L.P[1])
    with np.errstate(all="ignore"):
        while status == "ok":
            k1 = min(k + chunk - 1, n_steps)
            if k == 0:
                _timing_mark("loop_call")
            checkpoints = _keep_checkpoints(checkpoints, k, L)
            k_last, li, where = L.steps(grid, fidx, L.step_noise, method, k, k1, every_step, disc_on)
            if k == 0:
                _timing_mark("first_chunk")
                first_s = _time.perf_counter() - wall0
            chunks += 1
            if li:
                keep = is_logged[k : k + li]
                si = _collect(spec, plant, nq, li, keep, L.bufs, stream, si, n_steps + 1, log_parts)
            if L.info[0] != 0:
                status, reason, t_end = _stop(
                    L.info,
                    where,
                    float(grid[k_last]),
                    float(grid[min(k_last + 1, n_steps)]),
                    settings,
                    spec.ref,
                    spec,
                    L.P[1],
                )
                if status in ("step_unstable", "diverged"):  # does a smaller step remove the stop? (36 item 4)
                    code = int(L.info[0])
                    recheck = _recheck(L, grid, fidx, checkpoints, k_last)
                    if recheck["status"] not in ("ok", "singular"):  # it persists at dt/4: a second opinion
                        recheck["controlled"] = _controlled_recheck(L, grid, checkpoints, k_last, recheck["k_to"])
                    status, reason = _relabel(code, where, reason, recheck, settings, t_end)
                k = k_last
                break
            k = k_last
            t_end = float(grid[k])
            if k >= n_steps:
                break
            if progress is not None:
                progress(float(grid[k + 1]))
            k += 1
    wall = _time.perf_counter() - wall0
    meta = {"integrator": {"method": settings.method, "dt": settings.dt, "steps": int(k)}}
    if recheck is not None:  # what the run at dt/4 found (plain values: run metadata)
        meta["integrator"]["recheck"] = recheck
    meta["compile_time"] = _compile_time(compile0, wall, first_s, chunks, steps_new)
    return _finish(Run, spec, plant, settings, nq, stream, si, log_parts, status, reason, t_end, int(k), wall, meta,
                   progress)  # fmt: skip
