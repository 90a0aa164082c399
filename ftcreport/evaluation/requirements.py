r"""Time-windowed requirements on a signal (pure: arrays in, plain records out; issue 35 item 11).

A case states, in ``[[requirements]]`` tables (``cases/README.md``), bounds on a signal over
windows defined by events, for instance "the position error stays under 1 cm from 5 s after each
fault to the next fault"::

    [[requirements]]
    id = "settled_between_faults"
    signal = "position_error"
    scheme = "*"                    # every scheme the case runs, or one scheme's name
    start = { after_fault = 5.0 }   # a time [s], or N s after each fault event (one window per event)
    end = "next_fault"              # a time [s], "next_fault", "end" (of the run), or { after_fault = M }
    max = 0.01                      # min, max, or both (within the band [min, max])

**Signals** (:data:`SIGNALS`), computed at every accepted integration step (the metric stream
:attr:`ftcreport.sim.Run.stream`, as every metric of :mod:`ftcreport.evaluation.metrics`, so ``log_every``
changes nothing): ``position_error`` |P_n - P_nd| [m]; ``heading_error`` |wrap(theta_i - theta_id)|
[rad] of robot ``robot``, or the largest over the robots; ``torque`` the applied torque of wheel
``wheel`` [N m] (tau = sigma sat(u) + ubar, thesis 2.101); ``torque_abs`` its magnitude, or the
largest over the wheels; ``speed`` v_n [m/s] and ``turn_rate`` omega_1 [rad/s] (eta of 2.70).

**Windows.** The fault events are the distinct times of ``[[faults]]`` in the run (repairs
included: every event starts a phase, as in :meth:`ftcreport.model.FaultSchedule.phases`).
``start = T`` makes one window from T; ``start = { after_fault = N }`` one window per event te,
from te + N.  The window ends at ``end``: a time; ``"end"``, the end of the run (the case's
duration); ``"next_fault"``, the first event after the window's own event (after T for a timed
start), else the end of the run; ``{ after_fault = M }``, te + M (with an ``after_fault`` start).
A window holds the samples with start <= t <= end, except that a window ending at a fault event
leaves that event's sample out (its torque is already the faulty one: faults act from the start
of the step at their time, :mod:`ftcreport.sim`).  Edges are compared with a slack of 1 ns, so a
grid instant that round-off puts 1e-15 s before an edge still belongs to it.

**Outcomes** per window: ``holds`` (every sample within the bound), ``violated`` (the first
violation's time and value, and the worst sample, are recorded; a non-finite sample is a
violation) or ``not evaluated``: the window has no sample (it starts at or after its end, or after
the run's end: "empty window"), the run stopped before the window ended without a violation so
far, or there is no fault event to start an ``after_fault`` window.  ``ftcreport check`` fails
on ``violated`` and on ``not evaluated`` alike: a gate passes only what it has tested, and a
window that vanished because a fault moved or the run got shorter is a change the case's author
must see (cases/README.md, "Requirements").

:func:`evaluate_requirements` runs where the stream exists (:func:`ftcreport.runner.run_metrics`),
and the records are stored with the run's metrics (``metrics.json``, key ``requirements``);
:func:`ftcreport.studies.check.requirement_items` turns the stored records into gate items for ``check`` and JUnit.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "OUTCOMES",
    "SIGNALS",
    "Window",
    "bound_words",
    "evaluate_requirements",
    "signal_label",
    "signal_values",
    "windows",
]

#: signal name -> (unit, what it is); the case schema's choices (ftcreport.cases.Requirement.signal)
SIGNALS: dict[str, tuple[str, str]] = {
    "position_error": ("m", "distance of the last robot's axle midpoint P_n from its reference"),
    "heading_error": ("rad", "|wrap(theta_i - theta_id)| of robot `robot`, or the largest over the robots"),
    "torque": ("N m", "applied torque of wheel `wheel` (tau = sigma sat(u) + ubar)"),
    "torque_abs": ("N m", "|applied torque| of wheel `wheel`, or the largest over the wheels"),
    "speed": ("m/s", "forward speed v_n of the last robot"),
    "turn_rate": ("rad/s", "turn rate omega_1 of the leader"),
}
#: signals that take a robot (``robot``) and a wheel (``wheel``); required where marked True
SELECTORS: dict[str, tuple[str, bool]] = {
    "heading_error": ("robot", False),
    "torque": ("wheel", True),
    "torque_abs": ("wheel", False),
}
OUTCOMES = ("holds", "violated", "not evaluated")
EDGE_SLACK = 1e-9  # [s] a sample this close to a window edge is on it


@dataclass(frozen=True)
class Window:
    """One window of a requirement: [start, end] (``end`` left out when ``open_end``)."""

    start: float
    end: float
    open_end: bool
    event: float | None  # the fault event that opened it (after_fault starts), else None
    index: int  # 1-based among the requirement's windows

    @property
    def label(self) -> str:
        after = f"fault at {self.event:g} s: " if self.event is not None else ""
        return f"{after}{self.start:g}-{self.end:g} s"


def _get(obj: Any, key: str, default: Any = None) -> Any:
    if isinstance(obj, Mapping):
        return obj.get(key, default)
    return getattr(obj, key, default)


def _after(edge: Any) -> float | None:
    """N of an ``{ after_fault = N }`` edge, else None."""
    v = _get(edge, "after_fault") if not isinstance(edge, int | float | str) else None
    return None if v is None else float(v)


def signal_label(req: Any) -> str:
    """``position_error``, ``heading_error of robot 2``, ``torque of wheel 1r``, ``torque_abs (largest wheel)``."""
    sig = _get(req, "signal")
    robot, wheel = _get(req, "robot"), _get(req, "wheel")
    if robot is not None:
        return f"{sig} of robot {robot}"
    if wheel is not None:
        return f"{sig} of wheel {wheel}"
    if sig == "heading_error":
        return f"{sig} (largest robot)"
    if sig == "torque_abs":
        return f"{sig} (largest wheel)"
    return str(sig)


def bound_words(lo: float | None, hi: float | None, unit: str = "") -> str:
    """``<= 0.01 m``, ``>= 0.2 m/s``, ``within [-5, 5] N m``."""
    u = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        return f"within [{lo:g}, {hi:g}]{u}"
    return f"<= {hi:g}{u}" if hi is not None else f">= {lo:g}{u}"


def signal_values(
    signal: str, S: Mapping[str, np.ndarray], robot: int | None = None, wheel: int | None = None
) -> np.ndarray:
    """The signal at every row of ``S`` (the metric stream or a logged series: q, q_d, eta, tau).

    ``robot``: 1-based, leader first; ``wheel``: the index in the torque vector
    (:func:`ftcreport.model.wheel_index`).  q holds the headings last robot first (theta_n..theta_1).
    """
    if signal == "position_error":
        q, qd = S["q"], S["q_d"]
        return np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])
    if signal == "heading_error":
        from ..model.kernels import wrap

        head = np.abs(wrap(S["q"][:, 2:] - S["q_d"][:, 2:]))  # (K, n), last robot first
        n = head.shape[1]
        return head.max(axis=1) if robot is None else head[:, n - int(robot)]
    if signal in ("torque", "torque_abs"):
        tau = np.asarray(S["tau"], float)
        if wheel is not None:
            col = tau[:, int(wheel)]
            return col if signal == "torque" else np.abs(col)
        return np.abs(tau).max(axis=1)
    if signal == "speed":
        return np.asarray(S["eta"], float)[:, 0]
    if signal == "turn_rate":
        return np.asarray(S["eta"], float)[:, 1]
    raise ValueError(f"unknown signal {signal!r} (known: {', '.join(SIGNALS)})")


def windows(req: Any, events: Iterable[float], duration: float) -> list[Window]:
    """The windows of one requirement over a run of ``duration`` s with these fault event times."""
    ev = sorted({float(e) for e in events if 0.0 <= float(e) < duration})
    start, end = _get(req, "start", 0.0), _get(req, "end", "end")
    n_after = _after(start)
    opens: list[tuple[float, float | None]] = (
        [(te + n_after, te) for te in ev] if n_after is not None else [(float(start), None)]
    )
    out = []
    for k, (s, te) in enumerate(opens, start=1):
        anchor = te if te is not None else s
        m_after = _after(end)
        if m_after is not None:
            e, open_end = min(float(anchor) + m_after, float(duration)), False
        elif end == "end":
            e, open_end = float(duration), False
        elif end == "next_fault":
            later = [x for x in ev if x > anchor + EDGE_SLACK]
            e, open_end = (later[0], True) if later else (float(duration), False)
        else:
            e, open_end = float(end), False
        out.append(Window(float(s), float(e), open_end, te, k))
    return out


def _excess(v: np.ndarray, lo: float | None, hi: float | None) -> np.ndarray:
    """How far each value lies outside [lo, hi] (0 inside; inf for a non-finite value)."""
    ex = np.zeros(v.shape)
    if hi is not None:
        ex = np.maximum(ex, v - hi)
    if lo is not None:
        ex = np.maximum(ex, lo - v)
    return np.where(np.isfinite(v), ex, np.inf)


def _window_record(
    req: Any, w: Window, t: np.ndarray, y: np.ndarray, t_end: float, status: str, duration: float
) -> dict:
    """One window's outcome (the record stored in metrics.json)."""
    lo, hi = _get(req, "min"), _get(req, "max")
    unit = SIGNALS[_get(req, "signal")][0]
    rec: dict[str, Any] = {
        "id": _get(req, "id"),
        "signal": _get(req, "signal"),
        "label": signal_label(req),
        "unit": unit,
        "min": lo,
        "max": hi,
        "bound": bound_words(lo, hi, unit),
        "window": w.index,
        "window_label": w.label,
        "start": w.start,
        "end": w.end,
        "open_end": w.open_end,
        "event": w.event,
        "samples": 0,
    }

    def done(outcome: str, reason: str, **more) -> dict:
        return rec | more | {"outcome": outcome, "reason": reason}

    if w.start >= w.end - EDGE_SLACK:
        where = "the end of the run" if w.end >= duration - EDGE_SLACK else "its end"
        return done("not evaluated", f"empty window: it starts at {w.start:g} s, not before {where} ({w.end:g} s)")
    upper = t < w.end - EDGE_SLACK if w.open_end else t <= w.end + EDGE_SLACK
    mask = (t >= w.start - EDGE_SLACK) & upper
    idx = np.flatnonzero(mask)
    stopped = status != "ok" and t_end < w.end - EDGE_SLACK
    if idx.size == 0:
        if stopped:
            return done("not evaluated", f"the run stopped ({status}) at {t_end:g} s, before the window")
        return done("not evaluated", f"empty window: no integration step in {w.start:g}-{w.end:g} s")
    tw, yw = t[idx], y[idx]
    ex = _excess(yw, lo, hi)
    finite = np.isfinite(yw)
    extrema = {
        "samples": int(idx.size),
        "value_min": float(yw[finite].min()) if finite.any() else None,
        "value_max": float(yw[finite].max()) if finite.any() else None,
        "t_value_min": float(tw[finite][np.argmin(yw[finite])]) if finite.any() else None,
        "t_value_max": float(tw[finite][np.argmax(yw[finite])]) if finite.any() else None,
    }
    bad = np.flatnonzero(ex > 0)
    if bad.size:
        k0, kw = int(bad[0]), int(bad[np.argmax(ex[bad])])
        first = {"time": float(tw[k0]), "value": float(yw[k0])}
        worst = {"time": float(tw[kw]), "value": float(yw[kw]), "excess": float(ex[kw])}
        reason = (
            f"first violation at {first['time']:.6g} s: {first['value']:.4g} {unit}, not {rec['bound']}; "
            f"worst {worst['value']:.4g} {unit} at {worst['time']:.6g} s"
        )
        return done("violated", reason, first_violation=first, worst=worst, **extrema)
    if stopped:
        return done(
            "not evaluated",
            f"the run stopped ({status}) at {t_end:g} s, before the window's end ({w.end:g} s); "
            f"no violation in the {idx.size} step(s) before",
            **extrema,
        )
    side = "value_max" if hi is not None else "value_min"
    at = "t_value_max" if hi is not None else "t_value_min"
    reason = (
        f"holds over {idx.size} steps: {side.removeprefix('value_')} {extrema[side]:.4g} {unit} at {extrema[at]:.6g} s"
    )
    if lo is not None and hi is not None:
        reason = f"holds over {idx.size} steps: from {extrema['value_min']:.4g} to {extrema['value_max']:.4g} {unit}"
    return done("holds", reason, **extrema)


def applies_to(req: Any, scheme: str) -> bool:
    """Whether a requirement applies to a scheme (``scheme = "*"``: every scheme)."""
    s = _get(req, "scheme", "*")
    return s in ("*", scheme)


def evaluate_requirements(
    requirements: Sequence[Any],
    scheme: str,
    t: np.ndarray,
    S: Mapping[str, np.ndarray],
    events: Iterable[float],
    duration: float,
    t_end: float,
    status: str,
    wheel_index=None,
) -> list[dict]:
    """Every window of every requirement that applies to ``scheme``, in file order (records).

    ``t``, ``S``: the metric stream (every accepted step); ``events``: the run's fault event times;
    ``wheel_index(name) -> int``: the torque column of a wheel name (required for wheel selectors).
    """
    events = list(events)
    out: list[dict] = []
    t = np.asarray(t, float)
    cache: dict[tuple, np.ndarray] = {}
    for req in requirements:
        if not applies_to(req, scheme):
            continue
        sig, robot, wheel = _get(req, "signal"), _get(req, "robot"), _get(req, "wheel")
        wins = windows(req, events, duration)
        if not wins:
            rec = {
                "id": _get(req, "id"),
                "signal": sig,
                "label": signal_label(req),
                "unit": SIGNALS[sig][0],
                "min": _get(req, "min"),
                "max": _get(req, "max"),
                "bound": bound_words(_get(req, "min"), _get(req, "max"), SIGNALS[sig][0]),
                "window": 0,
                "window_label": "no window",
                "samples": 0,
                "outcome": "not evaluated",
                "reason": "no fault event in the run: the windows start after each fault event",
            }
            out.append(rec)
            continue
        key = (sig, robot, wheel)
        if key not in cache:
            col = None if wheel is None else (wheel_index(wheel) if wheel_index is not None else int(wheel))
            cache[key] = signal_values(sig, S, robot, col) if t.size else np.zeros(0)
        for w in wins:
            out.append(_window_record(req, w, t, cache[key], t_end, status, duration))
    return out


def summary_lines(case: str, metrics_by_scheme: Mapping[str, dict | None]) -> list[str]:
    """One line per requirement x scheme (``ftcreport run``): windows that hold, and the first that does not."""
    lines = []
    for scheme, m in metrics_by_scheme.items():
        recs = (m or {}).get("requirements") or []
        for rid in dict.fromkeys(r.get("id") for r in recs):
            mine = [r for r in recs if r.get("id") == rid]
            held = sum(r.get("outcome") == "holds" for r in mine)
            bad = next((r for r in mine if r.get("outcome") != "holds"), None)
            what = f"{mine[0].get('label')} {mine[0].get('bound')}"
            head = f"requirement {rid} / {scheme}: {what}: {held}/{len(mine)} window(s) hold"
            if bad is not None:
                head += f"; [{bad.get('window_label')}] {bad.get('outcome')}: {bad.get('reason')}"
            lines.append(head)
    return lines


def finite_or_none(x: Any) -> float | None:
    return float(x) if isinstance(x, int | float) and math.isfinite(x) else None
