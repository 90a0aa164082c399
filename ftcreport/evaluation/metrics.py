r"""Metrics of a run (pure: arrays in, plain dicts out, SI units).

Names are stable: they are the keys of ``metrics.json`` and of the thresholds
``ftcreport check`` compares.  Definitions:

* position error: distance between P_n and its reference, ``|(x, y) - (x_d, y_d)|`` [m];
* heading error: ``max_i |wrap(theta_i - theta_id)|`` over every robot [rad];
* phases: the intervals between fault events (the schedule's event times);
  per phase ``start``, ``end``, ``fault`` (the phase starts with a fault event: the first phase
  too when a fault acts from t = 0), ``position_error_max``, ``position_error_rms``,
  ``position_error_final`` and ``recovery_time``: the time from the phase start
  until the position error enters the band and stays in it until the phase ends
  (``None`` if it never does);
* ``recovery_time_max``: the largest recovery time over the phases that start
  with a fault event (a fault at t = 0 included) (``None`` when one of them never recovers);
* ``position_error_iae`` (whole run and per phase): integral of the position
  error over time [m s] (trapezoid over every integration step);
* torques: ``torque_peak`` = max |tau| over wheels and time [N m] (start-up included),
  ``torque_peak_after_fault`` = the same from the first fault event on (``None`` without a
  fault: the start-up transient, e.g. k_v times the initial velocity error, does not decide it),
  ``torque_rms``
  = RMS over time of the per-wheel torques (largest wheel), ``saturation_fraction``
  = fraction of time with some |u_j| at the limit, ``energy`` = the motors'
  absolute mechanical work int sum_j |tau_j omega_j| dt [J] (over every step, as
  :func:`step_integrals` integrates a step: the trapezoid, a held torque, or the motors'
  transient fitted through the step's midpoint);
* ``singularity_margin_min``: the smallest distance of an articulation angle
  |theta_i - theta_(i+1)| from 90 deg over the run [rad];
* switching (ERRATA E12g): the true 0/1 pattern marks a wheel faulty when its
  sigma < 1; the applied model *exactly* matches when its pattern equals it, and
  *effectively* matches when it assumes a superset of the true faults (the
  models are compensable by construction, so the same torques reach the
  ground).  ``switching_match_fraction`` is the effective fraction,
  ``switching_exact_match_fraction`` the exact one, ``detection_delays`` per
  fault event the time until the applied model effectively matches (0 when the
  applied one already did: no switch needed), searched only until the next fault
  event (a match after it is not this event's detection: the delay is then
  ``None`` and counted in ``switching_missed_detections``), ``detection_delay_max``
  their max (``None`` when one is missed).

Every metric reads the run's metric stream (:attr:`ftcreport.sim.Run.stream`):
the state, torques and estimates at every accepted integration step, taken at
the start of the step (where the law is evaluated and the torque applied). So
``log_every`` changes what is saved, never a metric: extrema, counts and delays
are exact to the step, and integrals are trapezoids over the steps.  Means over
time are too (:func:`time_mean`; the error-controlled methods' steps are not
equal): RMS values by the trapezoid, and fractions of time of what is held over
each step (the applied model, saturation) by the steps they start.  The torque's
RMS and the energy follow what the torque does inside a step (:func:`step_integrals`:
held under sampled control, the currents' transient with motors).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..model.kernels import wrap

__all__ = [
    "HEADLINE_METRICS",
    "METRICS",
    "Metric",
    "fault_phases",
    "metrics_of",
    "phase_metrics",
    "recovery_time",
    "singularity_margin",
    "step_integrals",
    "switching_metrics",
    "time_mean",
    "time_weights",
    "torque_metrics",
    "tracking_errors",
    "tracking_metrics",
]


def tracking_errors(q: np.ndarray, q_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error of P_n (K,) [m] and heading errors (K, n) [rad], headings in q order."""
    pos = np.hypot(q[:, 0] - q_d[:, 0], q[:, 1] - q_d[:, 1])
    head = np.abs(wrap(q[:, 2:] - q_d[:, 2:]))
    return pos, head


def recovery_time(t: np.ndarray, err: np.ndarray, start: float, end: float, band: float) -> float | None:
    """Time from ``start`` until err enters [0, band] and stays there until ``end``."""
    m = (t >= start) & (t <= end)
    if not np.any(m):
        return None
    tt, ee = t[m], err[m]
    outside = np.flatnonzero(ee > band)
    if outside.size == 0:
        return 0.0
    last = outside[-1]
    if last == tt.size - 1:
        return None
    return float(tt[last + 1] - start)


def _iae(t: np.ndarray, e: np.ndarray) -> float:
    return float(np.sum(0.5 * (e[1:] + e[:-1]) * np.diff(t))) if e.size > 1 else 0.0


def time_weights(t: np.ndarray, rule: str = "trapezoid") -> np.ndarray:
    """Each sample's share of the time t[-1] - t[0] (K,).

    ``"trapezoid"``: half of each step on either side (second order for a signal that varies within
    the steps: positions, torques, estimates); ``"step"``: the whole step it starts, the last sample
    the step before it (exact for a signal held over each step: the applied model, a saturation flag).
    """
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return np.ones(t.size)
    h = np.diff(t)
    w = np.empty(t.size)
    if rule == "step":
        w[:-1] = h
        w[-1] = h[-1]
        return w
    w[:-1] = 0.5 * h
    w[-1] = 0.0
    w[1:] += 0.5 * h
    return w


def time_mean(t: np.ndarray, x: np.ndarray, rule: str = "trapezoid") -> np.ndarray | float:
    """Mean over time of x (K, ...) sampled at t (K,), each sample weighted by :func:`time_weights`.

    The error-controlled methods' steps are not equal: a stretch of short steps (a transient) counts by
    its time, not by its samples.  A single sample is its own mean.
    """
    x = np.asarray(x, dtype=float)
    w = time_weights(t, rule)
    total = w.sum()
    if not total > 0:
        return np.mean(x, axis=0)
    return np.tensordot(w, x, axes=(0, 0)) / total


def _rms(t: np.ndarray, x: np.ndarray) -> float:
    return float(np.sqrt(time_mean(t, np.square(x)))) if x.size else float("nan")


_PHASE_METRICS = (*(f"position_error_{k}" for k in ("max", "rms", "final", "iae")), "recovery_time")


def phase_metrics(
    t: np.ndarray,
    pos_err: np.ndarray,
    phases: Sequence[tuple[float, float]],
    band: float,
    fault_times: Sequence[float] | None = None,
) -> list[dict]:
    """Per-phase tracking metrics (see the module docstring).

    ``fault``: the phase starts with a fault event, the first phase too when a fault acts from t = 0
    (``fault_times`` None: every phase but the first, as the phases are cut at the events).
    """
    out = []
    for i, (start, end) in enumerate(phases):
        fault = i > 0 if fault_times is None else any(abs(float(ft) - start) <= 1e-12 for ft in fault_times)
        m = (t >= start) & (t < end) if end < t[-1] else (t >= start) & (t <= end)
        if not np.any(m):  # no logged sample in the phase: every metric unknown
            out.append({"start": start, "end": end, "fault": fault} | dict.fromkeys(_PHASE_METRICS))
            continue
        e = pos_err[m]
        out.append(
            {
                "start": float(start),
                "end": float(end),
                "fault": fault,
                "position_error_max": float(e.max()),
                "position_error_rms": _rms(t[m], e),
                "position_error_final": float(e[-1]),
                "position_error_iae": _iae(t[m], e),
                "recovery_time": recovery_time(t, pos_err, start, end, band),
            }
        )
    return out


def tracking_metrics(
    t: np.ndarray,
    q: np.ndarray,
    q_d: np.ndarray,
    phases: Sequence[tuple[float, float]],
    band: float,
    fault_times: Sequence[float] | None = None,
) -> dict:
    """Whole-run and per-phase tracking metrics (``fault_times``: the schedule's event times)."""
    pos, head = tracking_errors(q, q_d)
    hmax = head.max(axis=1)
    ph = phase_metrics(t, pos, phases, band, fault_times)
    rec = [p["recovery_time"] for p in fault_phases(ph)]  # phases that start with a fault event
    return {
        "position_error_max": float(pos.max()),
        "position_error_rms": _rms(t, pos),
        "position_error_final": float(pos[-1]),
        "position_error_iae": _iae(t, pos),
        "heading_error_max": float(hmax.max()),
        "heading_error_final": float(hmax[-1]),
        "recovery_time_max": (None if any(r is None for r in rec) else float(max(rec))) if rec else 0.0,
        "phases": ph,
    }


def fault_phases(phases: Sequence[Mapping]) -> list:
    """The phases that start with a fault event (a fault at t = 0 makes the first one).

    Results stored before phases carried ``fault``: every phase but the first, as they were read then.
    """
    phases = list(phases or [])
    if phases and all("fault" in p for p in phases):
        return [p for p in phases if p["fault"]]
    return phases[1:]


#: Gauss-Legendre nodes and weights on [0, 1] (8 points): each step's two pieces in :func:`step_integrals`
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


def step_integrals(
    t: np.ndarray, tau: np.ndarray, omega: np.ndarray, tau_mid: np.ndarray | None = None,
    fast: float | np.ndarray | None = None, held: bool = False,
) -> tuple[np.ndarray, float]:  # fmt: skip
    r"""Per wheel ``int tau^2 dt`` (nw,) and ``int sum_j |tau_j omega_j| dt`` over the steps of a stream.

    How each step [t_k, t_k+1] is integrated depends on what the torque does inside it:

    * ``held`` (sampled control, no motors): tau is the held command, constant over the step (the steps
      end at the samples): ``h tau_k^2`` and ``tau_k`` times the trapezoid of |omega|, exactly;
    * ``tau_mid`` (sampled control with motors: the torques at the step's midpoint, from the
      integrator's interpolant, fast.loop) and ``fast`` (the currents' time constant T per wheel, or one
      for all: L_a / R_a with the static drive, L_a / K_p with the PI's, runner.current_time_constants):
      after each held voltage step the currents settle within T, inside the step, where no row is.
      The torque is fitted through the step's start, midpoint and end as ``A + C s + B exp(-s / T)``
      (a constant, the drift, the transient; for h < T / 10, where the transient is no longer fast,
      the quadratic through the same points) and integrated on 8 Gauss-Legendre points over
      [0, min(h/2, 4T)] and 8 over the rest; omega linear in the step.  Measured against dt/32 on every
      motor case (benchmarks/torque_metric_dt.py --fit): 0.01-0.13 %, against 0.7-6.5 % for the trapezoid;
    * otherwise (and on a step without a midpoint row): the trapezoid.
    """
    t = np.asarray(t, dtype=float)
    K, nw = tau.shape
    if K < 2:
        return np.zeros(nw), 0.0
    h = np.diff(t)
    a, b = tau[:-1], tau[1:]
    wa, wb = np.abs(omega[:-1]), np.abs(omega[1:])
    if held:
        return np.sum(h[:, None] * a * a, axis=0), float(np.sum(h[:, None] * np.abs(a) * 0.5 * (wa + wb)))
    sq = 0.5 * h[:, None] * (a * a + b * b)
    pw = 0.5 * h * np.sum(np.abs(a * omega[:-1]) + np.abs(b * omega[1:]), axis=1)
    T = None if fast is None else np.broadcast_to(np.asarray(fast, dtype=float), (nw,))
    if tau_mid is None or T is None or not np.all(T > 0):
        return sq.sum(axis=0), float(pw.sum())
    m = np.asarray(tau_mid, dtype=float)[:-1]
    rows = np.flatnonzero(np.all(np.isfinite(m), axis=1) & (h > 0))
    for chunk in np.array_split(rows, max(1, rows.size // 8192)):
        if chunk.size == 0:
            continue
        hk = h[chunk][:, None]  # (k, 1)
        # the nodes: 8 on [0, c] and 8 on [c, h], c = min(h/2, 4T) (the transient lives in the first)
        c = np.minimum(0.5 * hk, 4.0 * T.max())
        s = np.concatenate((c * _GL_X, c + (hk - c) * _GL_X), axis=1)  # (k, 16)
        w = np.concatenate((c * _GL_W, (hk - c) * _GL_W), axis=1)
        x = _fitted(hk, a[chunk], m[chunk], b[chunk], s, T)  # (k, 16, nw)
        r = (s / hk)[:, :, None]
        om = omega[chunk][:, None, :] * (1.0 - r) + omega[chunk + 1][:, None, :] * r
        sq[chunk] = np.einsum("kj,kjw->kw", w, x * x)
        pw[chunk] = np.einsum("kj,kj->k", w, np.sum(np.abs(x * om), axis=2))
    return sq.sum(axis=0), float(pw.sum())


def _fitted(h: np.ndarray, y0: np.ndarray, y1: np.ndarray, y2: np.ndarray, s: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The torque inside each step at the offsets s (k, J): through y0, y1, y2 (k, nw) at 0, h/2, h; T (nw,)."""
    x = s / h  # (k, J)
    exp = (h >= 0.1 * T.max())[:, 0]  # every wheel's transient fast beside the step: the exponential basis
    # the quadratic through the three points (Lagrange on 0, 1/2, 1)
    l0 = (1 - x) * (1 - 2 * x)
    l1 = 4 * x * (1 - x)
    l2 = x * (2 * x - 1)
    out = l0[:, :, None] * y0[:, None, :] + l1[:, :, None] * y1[:, None, :] + l2[:, :, None] * y2[:, None, :]
    if np.any(exp):
        # A + C s + B e^{-s/T}: B from the second difference, which the linear part does not see
        hk = h[exp]  # (k, 1)
        e1, e2 = np.exp(-0.5 * hk / T), np.exp(-hk / T)  # (k, nw)
        d = (1.0 - 2.0 * e1 + e2)[:, None, :]  # e^{-s/T}'s second difference over 0, h/2, h (> 0)
        B = (y0[exp] - 2.0 * y1[exp] + y2[exp])[:, None, :] / d
        A = y0[exp][:, None, :] - B
        C = ((y2[exp] - y0[exp])[:, None, :] - B * (e2 - 1.0)[:, None, :]) / hk[:, :, None]
        se = s[exp][:, :, None]
        out[exp] = A + C * se + B * np.exp(-se / T)
    return out


def torque_metrics(
    tau: np.ndarray,
    u: np.ndarray,
    u_limit: float | None,
    t: np.ndarray | None = None,
    omega: np.ndarray | None = None,
    first_fault: float | None = None,
    tau_mid: np.ndarray | None = None,
    fast: float | None = None,
    held: bool = False,
) -> dict:
    """Peak and RMS torque, fraction of time at saturation, (given wheel speeds) energy, and (given the
    times and ``first_fault``) the peak from the first fault on.

    ``t`` (K,): the samples' instants, for the means over time (:func:`time_mean`); without it the
    samples weigh equally.  ``tau_mid``, ``fast``, ``held``: how the torque behaves inside each step
    (:func:`step_integrals`), for the RMS and the energy.
    """
    tt = np.arange(tau.shape[0], dtype=float) if t is None else t
    inside = held or (tau_mid is not None and fast is not None)  # else the trapezoid, as time_mean has it
    inside = inside and t is not None and omega is not None and tt.size > 1 and tt[-1] > tt[0]
    if inside:
        sq, work = step_integrals(tt, tau, omega, tau_mid, fast, held)
        rms_per_wheel = np.sqrt(sq / (tt[-1] - tt[0]))
    else:
        rms_per_wheel = np.sqrt(time_mean(tt, np.square(tau)))
    sat = 0.0
    if u_limit is not None:
        sat = float(time_mean(tt, np.any(np.abs(u) >= u_limit * (1 - 1e-12), axis=1), "step"))
    out = {
        "torque_peak": float(np.abs(tau).max()),
        "torque_rms": float(rms_per_wheel.max()),
        "saturation_fraction": sat,
    }
    if t is not None and omega is not None:
        out["energy"] = work if inside else _iae(t, np.sum(np.abs(tau * omega), axis=1))
    if t is not None:
        after = np.asarray(t) >= first_fault if first_fault is not None else np.zeros(len(tau), dtype=bool)
        out["torque_peak_after_fault"] = float(np.abs(tau[after]).max()) if np.any(after) else None
    return out


def singularity_margin(q: np.ndarray) -> float:
    """Smallest distance of an articulation angle from 90 deg over the run [rad]."""
    th = q[:, :1:-1]  # robot order
    c = np.abs(np.cos(th[:, :-1] - th[:, 1:]))
    return float(np.arcsin(np.clip(c.min(), 0.0, 1.0)))


def switching_metrics(
    t: np.ndarray,
    selected: np.ndarray,
    patterns: np.ndarray,
    sigma_true: np.ndarray,
    event_times: Sequence[float],
) -> dict:
    """Switch count, exact/effective match fractions and detection delays (ERRATA E12g).

    Parameters
    ----------
    selected : (K,) ndarray
        Index of the applied model at each logged instant.
    patterns : (N, 2n) ndarray
        The models' 0/1 patterns (1 = wheel assumed working).
    sigma_true : (K, 2n) ndarray
        True effectiveness at each logged instant.
    """
    sel = np.asarray(selected).astype(int)
    assumed_ok = patterns[sel] > 0.5  # (K, 2n)
    true_ok = sigma_true >= 1.0
    exact = np.all(assumed_ok == true_ok, axis=1)
    # effective: every wheel assumed working really works (assumed failures are a superset)
    effective = np.all(~assumed_ok | true_ok, axis=1)
    delays = []
    times = sorted(float(x) for x in event_times)
    for i, te in enumerate(times):
        k0 = int(np.searchsorted(t, te, side="left"))
        if k0 >= t.size:
            continue
        # the search ends at the next fault event: a match after it is not this event's detection
        k1 = int(np.searchsorted(t, times[i + 1], side="left")) if i + 1 < len(times) else t.size
        ok = np.flatnonzero(effective[k0:k1])
        if ok.size == 0:
            delays.append({"time": te, "needs_switch": True, "delay": None})
            continue
        first = k0 + int(ok[0])
        delays.append({"time": te, "needs_switch": bool(first > k0), "delay": float(t[first] - t[k0])})
    known = [d["delay"] for d in delays if d["delay"] is not None]
    return {
        "switching_missed_detections": len(delays) - len(known),
        "switch_count": int(np.sum(sel[1:] != sel[:-1])),
        "switching_match_fraction": float(time_mean(t, effective, "step")),  # the model is held over a step
        "switching_exact_match_fraction": float(time_mean(t, exact, "step")),
        "detection_delays": delays,
        "detection_delay_max": (None if len(known) < len(delays) else (max(known) if known else 0.0)),
        "switch_sequence": _sequence(t, sel)[:100],
        "switch_sequence_truncated": bool(len(_sequence(t, sel)) > 100),
    }


def _sequence(t: np.ndarray, sel: np.ndarray) -> list[tuple[float, int]]:
    """(time, model index) each time the applied model changes, starting at t[0]."""
    if sel.size == 0:
        return []
    idx = np.concatenate(([0], np.flatnonzero(sel[1:] != sel[:-1]) + 1))
    return [(float(t[i]), int(sel[i])) for i in idx]


# ---------------------------------------------------------------------- the names a run writes
@dataclass(frozen=True)
class Metric:
    """One entry of a run's ``metrics.json`` that thresholds and claims may name.

    ``kind``: ``number`` (a threshold or a claim bounds it), ``table`` (numbers by name: a claim reads
    one entry, ``name.key``, or the largest), ``list`` (numbers: a claim compares the largest),
    ``sequence`` (``(time, model)`` pairs: a claim's ``sequence``), ``record`` (shown, not compared).
    ``schemes``: the schemes whose runs write it (None: every scheme, plug-ins included).
    """

    kind: str
    unit: str
    schemes: tuple[str, ...] | None = None


_SWITCHING = ("switching",)
_ADAPTIVE = ("adaptive", "adaptive_frozen")
_ACTIVE = ("active", "active_ukf")

#: The headline scalars of a run, every scheme's (a subset of :data:`METRICS`): what ``run --verify-dt``
#: compares between dt and dt/2 (ftcreport.runner.dt_sensitivity) and, but for the after-fault peak,
#: what a baseline compares by default (ftcreport.studies.baseline.COMPARED_METRICS).
HEADLINE_METRICS: tuple[str, ...] = (
    "position_error_max",
    "position_error_rms",
    "position_error_final",
    "heading_error_max",
    "recovery_time_max",
    "torque_peak",
    "torque_peak_after_fault",
    "torque_rms",
    "energy",
)

#: Every entry a run writes beside its identity (case, scheme, settings, status, reason, engine): the
#: functions of this module, :func:`ftcreport.evaluation.diagnosis.diagnosis_metrics` and
#: :func:`ftcreport.runner.run_metrics` (tests/test_batch.py checks that a run of every scheme writes
#: exactly these).  Case validation checks the metric names of ``[thresholds.<scheme>]`` and
#: ``[[claims]]`` against it (``ftcreport.cases``).
METRICS: dict[str, Metric] = {
    "t_end": Metric("number", "s"),
    "metric_samples": Metric("number", "1"),
    "wall_time": Metric("number", "s"),
    "compile_time": Metric("number", "s"),
    "position_error_max": Metric("number", "m"),
    "position_error_rms": Metric("number", "m"),
    "position_error_final": Metric("number", "m"),
    "position_error_iae": Metric("number", "m s"),
    "heading_error_max": Metric("number", "rad"),
    "heading_error_final": Metric("number", "rad"),
    "recovery_time_max": Metric("number", "s"),
    "phases": Metric("record", "-"),
    "torque_peak": Metric("number", "N m"),
    "torque_peak_after_fault": Metric("number", "N m"),
    "torque_rms": Metric("number", "N m"),
    "saturation_fraction": Metric("number", "1"),
    "energy": Metric("number", "J"),
    "singularity_margin_min": Metric("number", "rad"),
    "verify_dt": Metric("record", "-"),  # run --verify-dt only
    "integrator": Metric("record", "-"),  # the method that ran (auto's pick), its steps, its stop's re-check
    "requirements": Metric("record", "-"),  # cases with [[requirements]] only: every window's outcome
    # switching (switching_metrics)
    "switching_missed_detections": Metric("number", "1", _SWITCHING),
    "switch_count": Metric("number", "1", _SWITCHING),
    "switching_match_fraction": Metric("number", "1", _SWITCHING),
    "switching_exact_match_fraction": Metric("number", "1", _SWITCHING),
    "detection_delays": Metric("record", "s", _SWITCHING),
    "detection_delay_max": Metric("number", "s", _SWITCHING + _ACTIVE),
    "switch_sequence": Metric("sequence", "s, 1", _SWITCHING),
    "switch_sequence_truncated": Metric("record", "-", _SWITCHING),
    "patterns": Metric("record", "-", _SWITCHING + _ADAPTIVE),
    # adaptive (runner.run_metrics)
    "chi_hat_min": Metric("number", "1", _ADAPTIVE),
    "chi_hat_max": Metric("number", "1", _ADAPTIVE),
    "chi_hat_final": Metric("list", "1", _ADAPTIVE),
    "friction_estimate_final": Metric("list", "N m", _ADAPTIVE),
    "friction_true_final": Metric("list", "N m", _ADAPTIVE),
    "friction_estimate_note": Metric("record", "-", _ADAPTIVE),
    # active (diagnosis.diagnosis_metrics and runner.run_metrics)
    "estimated_parameters": Metric("record", "-", _ACTIVE),
    "state_estimation_rms_q": Metric("number", "m, rad", _ACTIVE),
    "state_estimation_rms_eta": Metric("number", "m/s, rad/s", _ACTIVE),
    "state_estimation_rms": Metric("number", "m/s, rad/s", _ACTIVE),
    "state_estimation_max_after_5s_q": Metric("number", "m, rad", _ACTIVE),
    "state_estimation_max_after_5s_eta": Metric("number", "m/s, rad/s", _ACTIVE),
    "combined_effect_error_rms": Metric("number", "m/s^2, rad/s^2", _ACTIVE),
    "combined_effect_rms": Metric("number", "m/s^2, rad/s^2", _ACTIVE),
    "fault_estimation_error_final": Metric("number", "1 or N m", _ACTIVE),
    "fault_estimation_errors_final": Metric("table", "1 or N m", _ACTIVE),
    "diagnosis_phases": Metric("record", "-", _ACTIVE),
    "combined_effect_relative_error_final": Metric("number", "1", _ACTIVE),
    "detection_events": Metric("record", "-", _ACTIVE),
    "detections": Metric("record", "-", _ACTIVE),
    "diagnosis_tolerances": Metric("table", "1, N m", _ACTIVE),
    "correct_detections": Metric("number", "1", _ACTIVE),
    "missed_detections": Metric("number", "1", _ACTIVE),
    "wrong_estimates": Metric("number", "1", _ACTIVE),
    "wrong_isolations": Metric("number", "1", _ACTIVE),
    "false_alarms": Metric("number", "1", _ACTIVE),
    "early_declarations": Metric("number", "1", _ACTIVE),
    "corrections": Metric("number", "1", _ACTIVE),
    "estimate_caveat": Metric("record", "-", _ACTIVE),
    "P_max": Metric("number", "1", _ACTIVE),
    "rho_hat_final": Metric("list", "1", _ACTIVE),
    "ubar_hat_final": Metric("list", "N m", _ACTIVE),
}


def metrics_of(scheme: str) -> list[str]:
    """The names of :data:`METRICS` a run of ``scheme`` writes."""
    return [k for k, m in METRICS.items() if m.schemes is None or scheme in m.schemes]
