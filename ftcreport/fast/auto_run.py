"""Error-controlled runs (``method = "auto"``, ``dopri5``, ``ros2ec``, ``etd2ec``, ``etd3ec``): ``run_auto``."""

from __future__ import annotations

import math
import time as _time
from typing import TYPE_CHECKING

import numpy as np

from ..jit.packed import (
    AT_STATE,
    AT_TRIAL,
    E_LAW_NONFINITE,
    E_LAW_RAISED,
    E_LAW_SIGNAL,
    E_LAW_WRITE,
    E_MIN_STEP,
    E_STEP_JUMP,
)
from .engine import (
    _FIRST_CALLS,
    _READY,
    NAN,
    _collect,
    _compile_time,
    _finish,
    _Loop,
    _timing_mark,
    n_noise_ticks,
    noise_clock,
)
from .stops import _how, _in_singular_set, _message, _stop, law_nonfinite_reason, law_raised_reason, law_signal_reason

if TYPE_CHECKING:
    from .engine import Spec


# --------------------------------------------------------------------------- error-controlled runs
#: the opt codes of fast.loop.run_auto's method (-1: auto picks at t0)
_AUTO_CODES = {"auto": -1, "dopri5": 3, "ros2ec": 4, "etd2ec": 5, "etd3ec": 6, "ros34pw2": 7}
_CODE_NAMES = {3: "dopri5", 4: "ros2ec", 5: "etd2ec", 6: "etd3ec", 7: "ros34pw2"}


def _dwell(controller) -> tuple[int, float]:
    """(slot of the last switch's time in xc, T_min) of a switching scheme's dwell, or (-1, 0): its end is
    known from the controller's state, so a step lands on it (switching_select changes the model only
    once t - xc[tsw] >= T_min)."""
    slot = getattr(controller, "_tsw", None)
    T_min = getattr(controller, "T_min", None)
    if slot is None or T_min is None or float(T_min) <= 0.0:
        return -1, 0.0
    return int(slot), float(T_min)


def _simulate_auto(spec: Spec, plant, q0, eta0, settings, progress=None):
    """An error-controlled run (fast.loop.run_auto): chunks by time (1 % of the run, for the progress
    callback), each logged at every accepted step into buffers that the stream and the decimated log
    (every ``log_every``-th accepted step, and the last) take from, as for the fixed steps."""
    from ..infra.limits import MAX_STEPS, MEMORY_BUDGET_BYTES
    from ..runs import Run

    t0, duration = float(settings.t0), float(settings.duration)
    t_end = t0 + duration
    times = np.array(sorted(set(float(v) for v in plant.faults.times)), dtype=float)
    events = times[(times > t0) & (times < t_end)]
    period = noise_clock(plant, settings)  # the sensor's clock: its draws (noisy), the UKF's updates
    clock = period if plant.noisy else NAN
    compile0 = _FIRST_CALLS[0]  # compile_time below
    L = _Loop(spec, plant, q0, eta0, settings, np.concatenate(([t0], events)), n_noise_ticks(plant, settings))
    steps_new = L.loop.run_auto not in _READY
    nq = L.nq
    # the chunk buffers: about 4x the steps of 1 % of the run at the longest step, at most 32 MB
    row_bytes = 8 * (L.nc + spec.n_sig + 5 * L.nw + 2 * (L.nq + 2) + L.nm + 1)
    rows = max(64, min(math.ceil(duration / settings.dt / 100) * 4 + 8, (32 << 20) // row_bytes))
    L.buffers(rows)
    opt, ctl = _auto_arrays(spec, settings, t0, t_end, t0, clock, _AUTO_CODES[settings.method], L.nm, period)
    stream: dict[str, np.ndarray] = {}
    log_parts: list[list[np.ndarray]] = []
    si = 0
    status, reason = "ok", ""
    t_now = t0
    every = int(settings.log_every)
    cap = None
    wall0 = _time.perf_counter()
    first_s, calls = 0.0, 0  # the first chunk's call (with the loop's compile or load when it is new here)
    if L.info[0] != 0:
        status, reason, _ = _stop(L.info, AT_STATE, t0, t0, settings, spec.ref, spec, L.P[1])
    chunk = 0
    with np.errstate(all="ignore"):
        while status == "ok":
            opt[5] = t0 + duration * min(1.0, (chunk + 1) / 100.0)  # this chunk's end (O_TCHUNK)
            if si == 0:
                _timing_mark("loop_call")
            li, where = L.auto_steps(events, L.fsig, L.fubar, L.fmot, L.noise, opt, ctl, rows)
            if si == 0:
                _timing_mark("first_chunk")
            if calls == 0:
                first_s = _time.perf_counter() - wall0
            calls += 1
            done = L.info[0] == 0 and li > 0 and L.lt[li - 1] >= t_end
            if li:
                keep = (np.arange(si, si + li) % every) == 0
                if done:
                    keep[-1] = True  # the last step is always logged
                si = _collect(spec, plant, nq, li, keep, L.bufs, stream, si, None, log_parts)
                t_now = float(L.lt[li - 1])
            if L.info[0] != 0:
                status, reason = _auto_stop(L, int(where), ctl, settings, spec)
                t_now = float(ctl[0])
                break
            if done:
                break
            if cap is None and stream:  # the stream's rows within the memory budget (ftcreport.infra.limits)
                width = sum(v[0].size for v in stream.values())
                cap = min(MAX_STEPS, MEMORY_BUDGET_BYTES // (8 * width))
            if cap is not None and si > cap:
                status = "error"
                reason = (
                    f"at t = {t_now:.6g} s the error-controlled run has taken {si} steps, the limit of "
                    f"ftcreport.infra.limits (MAX_STEPS, or its metric stream over MEMORY_BUDGET_BYTES; mean step "
                    f"{(t_now - t0) / si:.3g} s): loosen simulation.rtol/atol, or name a stiff method "
                    "(ros34pw2, etd3ec)"
                )
                break
            if float(ctl[0]) >= opt[5]:
                chunk += 1
                if progress is not None:
                    progress(float(ctl[0]))
    wall = _time.perf_counter() - wall0
    used = _CODE_NAMES.get(int(ctl[8]), settings.method)
    meta = {
        "integrator": {
            "method": used,
            "requested": settings.method,
            "rtol": settings.rtol,
            "atol": settings.atol,
            "max_step": settings.dt,
            "min_step": settings.min_step,
            "accepted": int(ctl[3]),
            "rejected": int(ctl[4]),
            "evaluations": int(ctl[5]),
            "spectral_radius": None if math.isnan(ctl[9]) else float(ctl[9]),
            # steps taken at min_step with the error over the tolerance (a discontinuity: fast.loop.run_auto)
            "forced_steps": int(ctl[15]),
            "first_forced_at": float(ctl[16]) if ctl[15] else None,
            # etd3ec: how often its linear block's difference columns were taken (fast.loop._etd3_attempt)
            "linear_blocks": int(ctl[19]),
        },
        "compile_time": _compile_time(compile0, wall, first_s, calls, steps_new),
    }
    return _finish(Run, spec, plant, settings, nq, stream, si, log_parts, status, reason, t_now, int(ctl[3]), wall,
                   meta, progress)  # fmt: skip


def _auto_arrays(
    spec: Spec, settings, t_start: float, t_end: float, t0: float, clock: float, method: int, nm: int, disc_clock: float
):
    """fast.loop.run_auto's ``opt`` (settings) and ``ctl`` (state) for a run from t_start to t_end (the
    sensor's draws on ``clock`` (nan: no noise) and a discrete-time filter's updates (the UKF) on ``disc_clock``
    (the sensor's period, noise or not) ticking from t0;
    ``method`` -1: auto picks; ``nm`` the motor states)."""
    slot, T_min = _dwell(spec.controller)
    opt = np.array(
        [
            settings.rtol, settings.atol, settings.dt, settings.min_step, t_end, t_start, clock, t0, float(slot),
            T_min, float(method), disc_clock if spec.start else 0.0,
        ]
    )  # fmt: skip
    # fast.loop's C_ entries, then etd3ec's linear block (fast.loop.C_JAGE, C_JTAKEN, C_JCOLS: (2 + nm) squared)
    ctl = np.zeros(20 + (2 + nm) ** 2)
    ctl[0] = t_start  # t
    ctl[18] = -1.0  # etd3ec's linear block: not taken yet
    ctl[7] = -math.inf  # the chained frame's next re-anchoring: none located yet
    ctl[8] = -1.0  # the method: not chosen yet
    ctl[9] = NAN  # the spectral radius: not estimated (a named method)
    return opt, ctl


#: fast.loop.FORCED_STREAK (tests/test_auto.py checks they agree)
FORCED_STREAK = 100


def _auto_stop(L: _Loop, where: int, ctl: np.ndarray, settings, spec: Spec) -> tuple[str, str]:
    """(status, reason) of an error-controlled run's stop (:func:`_auto_cause`), with the steps forced at
    min_step named when there were some."""
    status, reason = _auto_cause(L, where, ctl, settings, spec)
    if ctl[15]:
        reason += (
            f"; {int(ctl[15])} step(s) were taken at min_step = {settings.min_step:g} s with the error over the "
            f"tolerance, the first at t = {ctl[16]:.6g} s"
        )
    return status, reason


def _auto_cause(L: _Loop, where: int, ctl: np.ndarray, settings, spec: Spec) -> tuple[str, str]:
    """(status, reason) of an error-controlled run's stop.  No ``step_unstable``: the step is the
    controller's, so a stop at an accepted state is the loop's (singular, diverged, error); below the
    minimum step the label follows the last rejection's cause (a singular set: ``singular``; the
    error estimate, a non-finite or jumping state: ``diverged``)."""
    from ..errors import min_step_reason

    info = L.info
    used = _CODE_NAMES.get(int(ctl[8]), settings.method)
    how = _how(settings, used)
    t = float(ctl[0])
    if int(info[0]) == E_LAW_RAISED:  # a plug-in's law raised (numba's boundscheck, ...)
        return "error", law_raised_reason(spec, info, L.P[1])
    if int(info[0]) == E_LAW_WRITE:  # the scheme wrote past its buffers (the loop's guard cells)
        from ..schemes.controller import write_reason

        return "error", write_reason(spec.controller, int(info[1]), float(info[2]))
    if int(info[0]) == E_LAW_NONFINITE:  # the law's command, from a finite state
        return "error", law_nonfinite_reason(spec, int(info[2]), float(info[3]), float(info[1]))
    if int(info[0]) == E_LAW_SIGNAL:  # a plug-in's logged signal, from a finite state
        return "error", law_signal_reason(spec, int(info[2]), float(info[3]), float(info[1]))
    if int(info[0]) != E_MIN_STEP:
        status, reason = _message(info, t, settings, spec.ref, how)
        if status == "step_unstable":  # a stop of the fixed-step detectors' kind: the error control followed it
            status = "diverged"
        return status, reason
    cause = ctl[10:14]
    code = int(cause[0])
    if code == 0:
        ratio = float(cause[1])
        order = 5.0 if used == "dopri5" else 3.0  # the embedded error's order in h (fast.loop.run_auto: k_err)
        asks = settings.min_step * ratio ** (-1.0 / order) if ratio > 1.0 else settings.min_step
        why = (
            f"the local error stayed {ratio:.3g} times the tolerance for {FORCED_STREAK} steps in a row at "
            f"min_step: either rtol = {settings.rtol:g}, atol = {settings.atol:g} ask for steps near {asks:.2g} s "
            f"(the error ~ h^{order:.0f}), below min_step = {settings.min_step:g} s (loosen rtol and atol or lower "
            "min_step), or the rates change faster than any step resolves (a finite-time blow-up, or a "
            "discontinuity crossed at every step)"
        )
        return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    if code == E_STEP_JUMP:
        from ..runs import step_jump_words

        why = f"every shorter step blew up ({step_jump_words(int(cause[1]), float(cause[2]), float(cause[3]))})"
        return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    status, words = _message(cause, t, settings, spec.ref, how)
    why = f"every shorter step's trial stage left the domain ({words})"
    if _in_singular_set(cause, AT_TRIAL, L.x, t, settings, spec):  # the state is at the set's edge
        return "singular", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    if status == "error":  # the reference's own infeasibility (E_REF_*)
        return "error", words
    return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)
