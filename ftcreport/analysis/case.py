r"""The analysis of a case, as the ``analyze`` command and the case page show it (pure: no I/O).

:func:`analyze_case` gathers the case-wide analyses of :mod:`.classic` (the two-link error poles,
frozen-time and Floquet poles of the chained form, controllability per pattern, the healthy law's
velocity loop, the observer) and, for every scheme the case runs, :func:`.phases.analyze_scheme`:
per fault phase the true and applied pattern, the poles, stability and margins of the loop as it
runs (continuous or sampled), the scheme's stability limits and, for a case with sampled control or
motors, their confirmation by simulation (:mod:`.confirm`).  The keys are documented in README,
"Linearized analysis (`ftcreport analyze`)".
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import FtcError
from .classic import classic_analyses
from .closed_loop import Plant
from .confirm import confirm_limit, needs_confirmation
from .phases import analyze_scheme, case_frames, failure_words

__all__ = ["analysed_horizon", "analyze_case", "classic_model"]


def analysed_horizon(case, built) -> dict | None:
    """Where the reference turns infeasible before the case's end (``FlatReference.first_infeasible``, the
    instant ``cases validate`` warns of; a run stops at its first step past it), else None: ``{"t_end",
    "duration", "reason", "case"}``, ``t_end`` the last instant found feasible before it (50 us before at most,
    so that no frozen instant lands in between), ``case`` the case cut there (its faults from it on left out),
    which the analysis then covers.  Infeasible before the run's first step ends (t <= dt: no run takes a
    step, ``cases validate`` refuses it too): the ReferenceError, saying so."""
    from ..runner import reference_stop

    found = reference_stop(case, built)  # ReferenceError when no run takes a step
    if found is None:
        return None
    _, exc, t = found
    duration = float(case.simulation.duration)
    sim = case.simulation.model_copy(update={"duration": t})
    cut = case.model_copy(update={"simulation": sim, "faults": [f for f in case.faults if f.time < t]})
    return {"t_end": t, "duration": duration, "reason": str(exc), "case": cut}


def classic_model(case) -> str:
    """Which loop the case-wide analyses of :mod:`.classic` describe (``closed_loop_poles``, ``pole_tables``,
    ``predicted_decay_rate``, ``chained``, ``frozen_time``, ``controllability``, ``nominal_velocity_loop``,
    ``observer``), in words: they model torque inputs in continuous time, so on a case that samples its
    control, delays its measurements or has motors they are of the ideal plant, not of the loop the case
    runs (that one is in ``phases`` and ``limits``)."""
    sim = case.simulation
    left = [
        what
        for what, here in (
            ("sampling", sim.sample_time is not None),
            ("measurement delay", bool(sim.measurement_delay)),
            ("motors", case.actuators is not None),
        )
        if here
    ]
    if not left:
        return "the case's own loop (continuous time, torque inputs)"
    return (
        f"the ideal plant in continuous time (torque inputs, without the case's {', '.join(left)}): not the loop "
        "the case runs, which 'phases' and 'limits' analyse"
    )


def analyze_case(case, runs: dict | None = None, margins: bool = True, limits: bool = True,
                 confirm: bool = False, progress=None) -> dict:  # fmt: skip
    """Every analysis of one validated case, as plain data (README, "Linearized analysis").

    Parameters
    ----------
    case : ftcreport.cases.Case
    runs : dict, optional
        ``{scheme: stored time series}`` (``store.load_timeseries``): the states each scheme held and
        the model switching selected, phase by phase.  Without them the schemes' converged states.
    margins, limits : bool
        Compute the loop-at-a-time margins, and the stability limits.
    confirm : bool
        Confirm each limit by two short simulations (only for a case with sampled control or motors).
    progress : callable, optional
        Called with a line of text as each scheme is done.
    """
    from ..cases import configured_schemes
    from ..runner import build

    t0 = time.perf_counter()
    built = build(case)
    horizon = analysed_horizon(case, built)
    if horizon is not None:  # the part of the run the reference allows: every run stops where it turns infeasible
        case = horizon["case"]
        built = build(case)
    out = classic_analyses(case)
    out["classic_model"] = classic_model(case)
    out["horizon"] = None if horizon is None else {k: v for k, v in horizon.items() if k != "case"}
    out["sampled"] = case.simulation.sample_time is not None
    out["sample_time"] = case.simulation.sample_time
    out["measurement_delay"] = int(case.simulation.measurement_delay)
    plant = Plant(built)
    out["actuator_input"] = plant.input_name  # torque, voltage (static driver) or current target (PI drive)
    out["drive"] = _drive_words(built.plant)
    out["time_varying"] = None
    out["phases"], out["limits"], out["velocity_loop"], out["limit_notes"] = {}, {}, {}, {}
    out["limit_kinds"] = {}
    out["confirmation"] = {}
    out["not_analyzed"] = {}
    out["k_v"] = {}
    psis = case_frames(case, built)
    for scheme in configured_schemes(case):
        t1 = time.perf_counter()
        try:
            res = analyze_scheme(case, scheme, built, (runs or {}).get(scheme), margins, limits, psis)
        except (FtcError, ValueError, np.linalg.LinAlgError) as exc:
            out["not_analyzed"][scheme] = failure_words(exc, scheme)
            continue
        out["phases"][scheme] = res["phases"]
        out["k_v"][scheme] = res["k_v"]
        if limits:
            out["limits"][scheme] = res["limits"]
            out["velocity_loop"][scheme] = res["velocity_loop"]
            out["limit_notes"][scheme] = {k: v for k, v in res["limit_notes"].items() if v}
            out["limit_kinds"][scheme] = res["limit_kinds"]
            out.setdefault("_curves", {})[scheme] = res.get("_curves")
            if confirm and needs_confirmation(case):
                out["confirmation"][scheme] = _confirm(case, scheme, res)
        if progress is not None:
            progress(f"{scheme}: {time.perf_counter() - t1:.1f} s")
    from .phases import time_varying

    out["time_varying"] = time_varying(case)
    out["analysis_time"] = time.perf_counter() - t0
    return out


def _confirm(case, scheme: str, res: dict) -> dict:
    """Both limits of one scheme confirmed by simulation (:mod:`.confirm`); a null limit is skipped."""
    out = {}
    units = {"sample_time_max": "s", "k_v_max": "1/s"}
    for which, unit in units.items():
        limit = res["limits"].get(which)
        if limit is None:
            continue
        z = res.get("crossing", {}).get(which)
        internal = bool(res.get("crossing_internal", {}).get(which, False))
        out[which] = confirm_limit(case, scheme, which, limit, None if z is None else complex(*z), unit, internal)
    return out


def _drive_words(plant) -> str | None:
    """How the analysed loop's drive is modelled, in words for the page (None without motors)."""
    if plant.motors is None:
        return None
    drives = plant.drive or []
    first = drives[0] if isinstance(drives, list | tuple) and drives else drives
    if not drives or getattr(first, "driver", "static") == "static":
        return "the static driver (voltage from the drive's model of the motor)"
    each = [d.current_bandwidth for d in drives] if isinstance(drives, list | tuple) else [first.current_bandwidth]
    if len(set(each)) == 1:
        at = f"{each[0]:g} Hz"
    else:  # the robots' own, leader first (the leader's alone misstated the others': 5000 Hz for 0.5 Hz)
        at = f"{', '.join(f'{b:g}' for b in each)} Hz (robots {', '.join(str(i + 1) for i in range(len(each)))})"
    words = f"a PI current loop at {at} (its integral parts are states of the loop)"
    if first.drive_rate:
        words += f", sampled at {first.drive_rate:g} Hz in the run and analysed as continuous"
    return words
