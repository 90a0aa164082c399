r"""Fault diagnosis from estimated gains and frictions: detection, isolation, estimation (pure).

An estimator (Farza observer, UKF) gives rho_hat_j(t) and ubar_hat_j(t) per
wheel.  After a fault change its estimates swing (ERRATA P3: individual
parameters are weakly identifiable, the transient can leave [0, 1] by far),
so "the estimate left a band" alone isolates the wrong wheels.  A change is
therefore declared when an estimate has **settled at a new value**:

* over the last ``dwell`` seconds the estimate stayed within ``settle_band``
  of its window mean (it is steady), and
* that mean differs from the parameter's reference value by more than
  ``band`` (it is a new value).

The reference starts at the nominal value (gain 1, friction 0) and becomes
the declared value after each declaration.  A declaration names the
parameter, hence the wheel (isolation) and the type (gain loss or friction),
its time, the onset (when the estimate last left the reference band), and
the estimated value (the window mean).

:func:`match_events` scores the declarations against the true fault schedule
(issue 18).  The run is cut into phases at the schedule's event times; a true
change of parameter j at t_e is judged only within its phase [t_e, t_next)
(the next event of the schedule, or the end of the run), so a delay never
runs past the next event.  Each true change gets one outcome:

* ``detected``: a declaration on j (the right wheel and the right kind) in the
  phase whose value is within the tolerance of the true new value (``gain_tol``
  for gains, ``friction_tol`` [N m] for frictions); the delay is to the first
  such declaration;
* ``wrong_estimate``: declarations on j in the phase, none within the tolerance
  (the estimate reported is the last of them);
* ``wrong_isolation``: nothing declared on j in the phase, but a change was
  declared on a parameter that did not change in it (another wheel, or the
  other kind on the same wheel);
* ``missed``: nothing declared in the phase that could stand for it.

Only ``detected`` counts as a detection: ``missed_detections`` counts every
other outcome (a fault not correctly diagnosed within its phase is missed), and
``wrong_estimates``, ``wrong_isolations`` break it down.  Each declaration is
classified as well: ``correct`` or ``wrong_estimate`` (on a parameter that
changed in its phase), ``correction`` (on a parameter that did not change, at
its true value within tolerance, after the previous declaration on it was
wrong: the diagnosis recovers the truth late), or a false alarm (any other
declaration on a parameter that did not change in its phase; ``early`` are
those on a wheel before its first fault).

The combined effect Mbar1^-1 Bbar (diag(rho) u + ubar), the acceleration the
actuators produce, is what is identifiable at each instant (P3);
:func:`combined_effect` evaluates it for estimated and true parameters, and
:func:`diagnosis_metrics` reports its error per phase beside the individual
parameters' errors.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..model.chain import Chain
from ..model.faults import FaultSchedule, wheel_names
from .metrics import time_mean

__all__ = [
    "Declaration",
    "combined_effect",
    "detect",
    "diagnosis_metrics",
    "input_matrices",
    "match_events",
    "phase_combined_effect",
    "true_events",
]


@dataclass(frozen=True)
class Declaration:
    """One declared change of one parameter."""

    parameter: str  # e.g. "rho_1l", "ubar_1r"
    wheel: str
    kind: str  # "gain" or "friction"
    t_onset: float  # [s] the estimate left the reference band
    t_declared: float  # [s]
    value: float  # estimated new value
    reference: float  # value it changed from


def _kind(name: str) -> tuple[str, str]:
    prefix, wheel = name.split("_", 1)
    return ("gain" if prefix == "rho" else "friction"), wheel


def detect(
    t: np.ndarray,
    estimates: np.ndarray,
    names: list[str],
    gain_band: float = 0.1,
    friction_band: float = 0.2,
    dwell: float = 2.0,
    settle_band: float | None = None,
) -> list[Declaration]:
    """Declarations from logged estimates (K, p) with parameter names (``rho_*``, ``ubar_*``).

    ``settle_band`` defaults to a quarter of the parameter's band.
    """
    t = np.asarray(t, dtype=float)
    X = np.asarray(estimates, dtype=float)
    out: list[Declaration] = []
    for j, name in enumerate(names):
        kind, wheel = _kind(name)
        band = gain_band if kind == "gain" else friction_band
        steady = band / 4.0 if settle_band is None else settle_band
        ref = 1.0 if kind == "gain" else 0.0
        x = X[:, j]
        onset = None
        start = 0  # index of the window start
        for k in range(t.size):
            if not np.isfinite(x[k]):
                break
            if abs(x[k] - ref) > band:
                if onset is None:
                    onset = t[k]
            else:
                onset = None
            while t[k] - t[start] > dwell:
                start += 1
            if onset is None or t[k] - t[0] < dwell or t[start] < onset:
                continue
            w = x[start : k + 1]
            mean = float(time_mean(t[start : k + 1], w))
            if float(np.max(np.abs(w - mean))) <= steady and abs(mean - ref) > band:
                out.append(Declaration(name, wheel, kind, float(onset), float(t[k]), mean, ref))
                ref = mean
                onset = None
    out.sort(key=lambda d: (d.t_declared, d.parameter))
    return out


def true_events(schedule: FaultSchedule, names: list[str]) -> list[dict]:
    """True parameter changes of the schedule (including events at t = 0) for the estimated parameters."""
    wheels = wheel_names(schedule.n)
    out = []
    times = sorted({0.0, *schedule.times})
    prev_sigma, prev_ubar = np.ones(len(wheels)), np.zeros(len(wheels))
    for te in times:
        sigma, ubar = schedule.at(te)
        for i, w in enumerate(wheels):
            if f"rho_{w}" in names and sigma[i] != prev_sigma[i]:
                out.append({"parameter": f"rho_{w}", "wheel": w, "kind": "gain", "time": te, "value": float(sigma[i])})
            if f"ubar_{w}" in names and ubar[i] != prev_ubar[i]:
                out.append(
                    {"parameter": f"ubar_{w}", "wheel": w, "kind": "friction", "time": te, "value": float(ubar[i])}
                )
        prev_sigma, prev_ubar = sigma, ubar
    return out


def _phase_end(t: float, boundaries: list[float], t_end: float) -> float:
    """The first boundary after t (the end of t's phase), or t_end."""
    later = [b for b in boundaries if b > t]
    return min(later) if later else t_end


def _within(kind: str, value: float, truth: float, gain_tol: float, friction_tol: float) -> bool:
    return abs(value - truth) <= (gain_tol if kind == "gain" else friction_tol)


def match_events(
    declarations: list[Declaration],
    events: list[dict],
    t_end: float,
    gain_tol: float = 0.1,
    friction_tol: float = 0.2,
    boundaries: list[float] | None = None,
) -> dict:
    """Score declarations against the true changes (see the module docstring).

    Parameters
    ----------
    declarations : list of Declaration
        From :func:`detect`.
    events : list of dict
        True changes from :func:`true_events`.
    t_end : float
        End of the run [s] (end of the last phase).
    gain_tol, friction_tol : float
        A declared value within this of the true new value is right [1, N m].
    boundaries : list of float, optional
        Phase boundaries: the schedule's event times (default: the times in ``events``).
        Pass every event time of the schedule, including events on parameters that are
        not estimated: they end a phase all the same.

    Returns
    -------
    dict
        ``events`` (one row per true change: ``outcome``, ``detected``, ``delay``,
        ``t_declared``, ``estimate``, ``estimate_error``, ``phase_end``, ``tolerance``,
        ``declared_elsewhere``), ``declarations`` (each with its ``verdict``),
        ``false_alarms``, ``early_declarations``, ``corrections``.
    """
    bounds = sorted({float(e["time"]) for e in events} if boundaries is None else {float(b) for b in boundaries})
    changed: dict[tuple[str, float], dict] = {}  # (parameter, phase start) -> event
    for ev in events:
        changed[(ev["parameter"], float(ev["time"]))] = ev

    def phase_start(t: float) -> float:
        earlier = [b for b in bounds if b <= t]
        return max(earlier) if earlier else 0.0

    def truth_at(param: str, t: float) -> float:
        """True value of a parameter at t (nominal before its first change)."""
        val = 1.0 if param.startswith("rho_") else 0.0
        for ev in sorted(events, key=lambda e: e["time"]):
            if ev["parameter"] == param and ev["time"] <= t:
                val = float(ev["value"])
        return val

    verdicts: list[str] = []
    standing: dict[str, float] = {}  # the diagnosed value of each parameter (last declaration)
    for d in declarations:
        start = phase_start(d.t_declared)
        truth = truth_at(d.parameter, d.t_declared)
        right = _within(d.kind, d.value, truth, gain_tol, friction_tol)
        before = standing.get(d.parameter, 1.0 if d.kind == "gain" else 0.0)
        if (d.parameter, start) in changed:
            verdicts.append("correct" if right else "wrong_estimate")
        elif right and not _within(d.kind, before, truth, gain_tol, friction_tol):
            verdicts.append("correction")
        else:
            verdicts.append("false_alarm")
        standing[d.parameter] = d.value

    def in_phase(t: float, start: float, end: float) -> bool:
        return start <= t and (t < end or (end >= t_end and t <= t_end))

    matched = []
    for ev in events:
        te = float(ev["time"])
        end = _phase_end(te, bounds, t_end)
        mine = [
            i for i, d in enumerate(declarations) if d.parameter == ev["parameter"] and in_phase(d.t_declared, te, end)
        ]
        elsewhere = sorted(
            {
                declarations[i].parameter
                for i, d in enumerate(declarations)
                if verdicts[i] == "false_alarm" and in_phase(d.t_declared, te, end)
            }
        )
        tol = gain_tol if ev["kind"] == "gain" else friction_tol
        row = dict(ev) | {"phase_end": end, "tolerance": tol, "declared_elsewhere": elsewhere}
        right = [i for i in mine if verdicts[i] == "correct"]
        if right:
            d = declarations[right[0]]
            row |= {"outcome": "detected", "detected": True, "delay": d.t_declared - te, "t_declared": d.t_declared}
        elif mine:
            d = declarations[mine[-1]]
            row |= {"outcome": "wrong_estimate", "detected": False, "delay": None, "t_declared": d.t_declared}
        else:
            d = None
            outcome = "wrong_isolation" if elsewhere else "missed"
            row |= {"outcome": outcome, "detected": False, "delay": None, "t_declared": None}
        row["estimate"] = None if d is None else d.value
        row["estimate_error"] = None if d is None else abs(d.value - float(ev["value"]))
        matched.append(row)
    first_fault: dict[str, float] = {}
    for ev in sorted(events, key=lambda e: e["time"]):
        first_fault.setdefault(ev["wheel"], ev["time"])
    decl = [asdict(d) | {"verdict": v} for d, v in zip(declarations, verdicts, strict=True)]
    false = [x for x in decl if x["verdict"] == "false_alarm"]
    early = [f for f in false if f["t_declared"] < first_fault.get(f["wheel"], np.inf)]
    corrections = [x for x in decl if x["verdict"] == "correction"]
    return {
        "events": matched,
        "declarations": decl,
        "false_alarms": false,
        "early_declarations": early,
        "corrections": corrections,
    }


def input_matrices(chain: Chain, q: np.ndarray) -> np.ndarray:
    """Mbar1^-1 Bbar at each logged configuration, (K, 2, 2n) (both depend on q only).

    One compiled call (``model.compiled.input_matrices_rows``): a per-row call from Python would
    load and emit the model kernel ``reduced`` in every process that computes it (issue 20 item 7).
    """
    from ..model.kernels import input_matrices_rows

    return input_matrices_rows(chain.params, q)


def combined_effect(MB: np.ndarray, u: np.ndarray, rho: np.ndarray, ubar: np.ndarray) -> np.ndarray:
    """Mbar1^-1 Bbar (diag(rho) u + ubar) at each logged instant, (K, 2): what the actuators accelerate.

    ``MB`` from :func:`input_matrices`.
    """
    return np.einsum("kij,kj->ki", MB, rho * u + ubar)


def phase_combined_effect(
    t: np.ndarray,
    ce_hat: np.ndarray,
    ce_true: np.ndarray,
    est: np.ndarray,
    truth: np.ndarray,
    names: list[str],
    phases: list[tuple[float, float]],
    window: float,
) -> list[dict]:
    """Per phase: the combined effect's error and the individual parameters' errors at its end.

    Over the last ``window`` seconds of each phase (at most the phase): RMS of
    |ce_hat - ce_true| (2-norm per instant) and of |ce_true|, and each
    parameter's |estimate - truth| at the last sample of the phase (ERRATA P3:
    the first is identifiable, the others need not be).
    """
    out = []
    for start, end in phases:
        last = end >= t[-1]
        inside = (t >= start) & ((t <= end) if last else (t < end))
        if not np.any(inside):
            continue
        tail = inside & (t >= max(start, t[inside][-1] - window))
        err = np.linalg.norm(ce_hat[tail] - ce_true[tail], axis=1)
        size = np.linalg.norm(ce_true[tail], axis=1)
        k = int(np.flatnonzero(inside)[-1])
        e_rms = float(np.sqrt(time_mean(t[tail], err**2)))
        s_rms = float(np.sqrt(time_mean(t[tail], size**2)))
        out.append(
            {
                "start": float(start),
                "end": float(end),
                "combined_effect_error_rms": e_rms,
                "combined_effect_rms": s_rms,
                "combined_effect_relative_error": e_rms / s_rms if s_rms > 0 else None,
                "parameter_errors": dict(zip(names, np.abs(est[k] - truth[k]).tolist(), strict=True)),
            }
        )
    return out


def diagnosis_metrics(
    chain: Chain,
    schedule: FaultSchedule,
    names: list[str],
    t: np.ndarray,
    signals: dict[str, np.ndarray],
    u_limit: float | None,
    gain_band: float,
    friction_band: float,
    dwell: float,
    t_end: float,
    settle_band: float | None = None,
    gain_tol: float = 0.1,
    friction_tol: float = 0.2,
) -> dict:
    """Metrics of an active run: state and fault estimation, detection and isolation.

    Diagnosis counts (see the module docstring): ``correct_detections``,
    ``missed_detections`` (true changes not correctly diagnosed within their
    phase: ``wrong_estimates`` + ``wrong_isolations`` + nothing declared),
    ``detection_delay_max`` (largest delay of a correct detection, ``None`` when
    one is missed; never beyond the next event), ``false_alarms``,
    ``early_declarations``, ``corrections``.  Per phase, ``diagnosis_phases``
    gives the combined effect's error beside every parameter's error;
    ``combined_effect_relative_error_final`` is its last phase's relative error.
    """
    q, eta = signals["q"], signals["eta"]
    out: dict = {}
    after = t >= min(5.0, t[-1])
    ta = t[after]  # means over time (metrics.time_mean): each sample weighs the step it starts
    out["state_estimation_rms_q"] = float(np.sqrt(np.mean(time_mean(ta, (signals["q_hat"][after] - q[after]) ** 2))))
    out["state_estimation_rms_eta"] = float(
        np.sqrt(np.mean(time_mean(ta, (signals["eta_hat"][after] - eta[after]) ** 2)))
    )
    out["state_estimation_rms"] = out["state_estimation_rms_eta"]
    out["state_estimation_max_after_5s_q"] = float(np.max(np.abs(signals["q_hat"][after] - q[after])))
    out["state_estimation_max_after_5s_eta"] = float(np.max(np.abs(signals["eta_hat"][after] - eta[after])))
    # the combined effect first, so that its (K, 2, 2n) matrices are freed before the estimates are
    # gathered (the peak memory of a long run's metrics: issue 20 item 7)
    u_applied = signals["u"] if u_limit is None else np.clip(signals["u"], -u_limit, u_limit)
    MB = input_matrices(chain, q)
    ce_hat = combined_effect(MB, u_applied, signals["rho_hat"], signals["ubar_hat"])
    ce_true = combined_effect(MB, u_applied, signals["sigma"], signals["ubar"])
    del MB, u_applied
    out["combined_effect_error_rms"] = float(np.sqrt(np.mean(time_mean(ta, (ce_hat[after] - ce_true[after]) ** 2))))
    out["combined_effect_rms"] = float(np.sqrt(np.mean(time_mean(ta, ce_true[after] ** 2))))
    all_names = [f"rho_{w}" for w in wheel_names(chain.n)] + [f"ubar_{w}" for w in wheel_names(chain.n)]
    cols = [all_names.index(n) for n in names]
    # the estimated parameters' columns only, each gathered once (K, len(names))
    est = np.hstack([signals["rho_hat"], signals["ubar_hat"]])[:, cols]
    truth = np.hstack([signals["sigma"], signals["ubar"]])[:, cols]
    err_final = np.abs(est[-1] - truth[-1])
    out["fault_estimation_error_final"] = float(err_final.max())
    out["fault_estimation_errors_final"] = dict(zip(names, err_final.tolist(), strict=True))
    phases = schedule.phases(float(t[-1]))
    out["diagnosis_phases"] = phase_combined_effect(t, ce_hat, ce_true, est, truth, names, phases, dwell)
    last = out["diagnosis_phases"][-1] if out["diagnosis_phases"] else {}
    out["combined_effect_relative_error_final"] = last.get("combined_effect_relative_error")
    decl = detect(t, est, names, gain_band, friction_band, dwell, settle_band)
    res = match_events(
        decl, true_events(schedule, names), t_end, gain_tol, friction_tol, boundaries=list(schedule.times)
    )
    events = res["events"]
    for row in events:  # the combined effect of the event's phase, beside the parameter's estimate
        ph = next((p for p in out["diagnosis_phases"] if p["start"] == row["time"]), None)
        row["combined_effect_relative_error"] = None if ph is None else ph["combined_effect_relative_error"]
    delays = [e["delay"] for e in events if e["outcome"] == "detected"]
    out["detection_events"] = events
    out["detections"] = res["declarations"]
    out["diagnosis_tolerances"] = {"gain": gain_tol, "friction": friction_tol}
    out["correct_detections"] = len(delays)
    out["missed_detections"] = sum(e["outcome"] != "detected" for e in events)
    out["wrong_estimates"] = sum(e["outcome"] == "wrong_estimate" for e in events)
    out["wrong_isolations"] = sum(e["outcome"] == "wrong_isolation" for e in events)
    out["detection_delay_max"] = float(max(delays)) if delays and not out["missed_detections"] else None
    out["false_alarms"] = len(res["false_alarms"])
    out["early_declarations"] = len(res["early_declarations"])
    out["corrections"] = len(res["corrections"])
    out["estimate_caveat"] = (
        "individual gains and frictions are weakly identifiable in steady tracking (ERRATA P3); "
        "the combined effect Mbar1^-1 Bbar (diag(rho) u + ubar) is what the measurements determine"
    )
    return out
