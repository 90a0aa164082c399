r"""Each predicted stability limit confirmed by two short simulations, at 0.9x and 1.1x of it.

Issue 37 item 6.  For a scheme's ``sample_time_max`` and ``k_v_max`` (:mod:`.limits`, healthy
pattern), the case is run by the engine (``runner.run_scheme``) with the healthy plant (no fault
events), starting 1 mm and 0.05 deg off the reference (:data:`START`), and that setting at 0.9
and 1.1 times the limit, everything else as the case has it (plant, motors, drive, saturation,
delay, integrator).  A sample-time variant keeps the
case's number of steps per sample (one ETD2 step per sample for the motor cases).

How long: the analysis predicts the spectral radius rho at 1.1x the limit, so the mode that crosses
grows by 10^4 in ``ln(1e4) / ln(rho)`` samples; the simulation runs that many samples (at least
:data:`MIN_SAMPLES`, at most :data:`MAX_SAMPLES`): long enough for a growth of 10^4 to show, no longer.
The prediction only sets the duration; the verdict reads the simulation alone:

* ``diverged``: the run stopped (diverged, step_unstable, singular);
* ``limit cycle``: it completed, but the sample-to-sample part of its command did not die out: the
  RMS of the second difference of u at the samples over the last third of the run is at least
  :data:`DECAYED` times that over the first third (it stays, or it grows until the drive saturates;
  a smooth command has only ~(omega T)^2 |u| there);
* ``bounded``: it completed and that part decayed below a tenth.

Prediction and simulation agree when 0.9x is bounded and 1.1x is not; anything else is reported as
a contradiction, with both numbers (never hidden).  When run: ``ftcreport analyze`` runs them for
a case with sampled control or motors unless ``--no-confirm``; a case page runs them when it is
rendered (batch renders a page only when its inputs changed).  They are not cached with the runs:
they cost a fraction of a second each warm, and a page is not re-rendered without a reason.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import FtcError

__all__ = ["MAX_SAMPLES", "MIN_SAMPLES", "classify", "confirm_limit", "needs_confirmation"]

MIN_SAMPLES = 200
MAX_SAMPLES = 20_000
GROWTH = 1e4
#: the runs start this close to the reference: a linearization's limit is local, so its confirmation
#: starts where the linearization holds (with the case's own start, a large first error saturates the
#: drive and tests the region of attraction instead); the offset excites every mode
START = {"x": 1e-6, "y": 1e-6, "heading_offset_deg": 1e-4}
DECAYED = 0.1
FACTORS = (0.9, 1.1)


def needs_confirmation(case) -> bool:
    """A case with sampled control or motors: its limits are confirmed by simulation (issue 37 item 6)."""
    return case.simulation.sample_time is not None or case.actuators is not None


def variant(case, scheme: str, which: str, value: float, samples: int):
    """The case with ``which`` (sample_time_max or k_v_max) set to ``value``, no faults, a short run."""
    from ..cases import Simulation
    from .closed_loop import with_k_v

    s = case.simulation
    data = s.model_dump()
    T = s.sample_time
    if which == "sample_time_max":
        steps = 1 if T is None else round(T / s.dt)
        T = float(value)
        data |= {"sample_time": T, "dt": T / steps}
    else:
        case = with_k_v(case, scheme, value)
    period = T if T is not None else s.dt
    duration = samples * period
    data |= {"duration": duration, "log_every": max(1, round(duration / period / 2000))}
    if data["sample_time"] is not None and data["measurement_delay"] * data["sample_time"] >= duration:
        data["duration"] = duration = (data["measurement_delay"] + samples) * data["sample_time"]
    sim = Simulation.model_validate(data)
    start = case.initial.model_copy(update={"mode": "offset", "headings_deg": None, "eta": None, **START})
    return case.model_copy(update={"simulation": sim, "faults": [], "campaign": None, "initial": start})


def classify(run, period: float) -> dict:
    """The verdict on one short run (module docstring): ``{"outcome", "status", "growth", ...}``."""
    if run.status != "ok":
        return {"outcome": "diverged", "status": run.status, "t_end": run.t_end, "reason": run.reason}
    t = np.asarray(run.t_stream if run.stream else run.t)
    u = np.asarray((run.stream or run.signals)["u"])
    first = np.unique(np.round(t / period), return_index=True)[1]  # the command at each sample
    us = u[first]
    if len(us) < 12:
        return {"outcome": "bounded", "status": run.status, "growth": 0.0, "note": "too few samples to judge"}
    # the sample-to-sample part of the command: second differences (a smooth motion has ~(omega T)^2 there)
    d2 = np.linalg.norm(us[2:] - 2.0 * us[1:-1] + us[:-2], axis=1)
    third = len(d2) // 3
    early, late = float(np.sqrt(np.mean(d2[:third] ** 2))), float(np.sqrt(np.mean(d2[-third:] ** 2)))
    growth = late / early if early > 0 else 0.0
    peak = float(np.abs(us).max())
    return {
        "outcome": "bounded" if growth < DECAYED else "limit cycle",
        "status": run.status,
        "growth": growth,
        "command_peak": peak,
    }


def confirm_limit(case, scheme: str, which: str, limit: float, rho_above: float | None, unit: str) -> dict:
    """Simulations at 0.9x and 1.1x of one limit: the runs' outcomes and whether they agree with it.

    ``rho_above``: the predicted spectral radius at 1.1x (sets the duration; None: MIN_SAMPLES).
    """
    from ..runner import run_scheme

    if rho_above is not None and rho_above > 1.0:
        samples = int(min(MAX_SAMPLES, max(MIN_SAMPLES, math.ceil(math.log(GROWTH) / math.log(rho_above)))))
    else:
        samples = MIN_SAMPLES
    out = {"limit": limit, "unit": unit, "samples": samples, "runs": []}
    for f in FACTORS:
        value = f * limit
        try:
            v = variant(case, scheme, which, value, samples)
            run, _m = run_scheme(v, scheme)
            period = v.simulation.sample_time or v.simulation.dt
            res = classify(run, period) if run.status != "error" else {"outcome": "error", "reason": run.reason}
            res["duration"] = v.simulation.duration
        except FtcError as exc:
            res = {"outcome": "error", "reason": str(exc)}
        out["runs"].append({"factor": f, "value": value, **res})
    below, above = (r["outcome"] for r in out["runs"])
    if "error" in (below, above):
        out["agrees"] = None
    else:
        out["agrees"] = below == "bounded" and above != "bounded"
    out["sentence"] = sentence(which, out)
    return out


def sentence(which: str, res: dict) -> str:
    """'predicted 1.37 ms; at 1.23 ms bounded, at 1.51 ms limit cycle' (and a contradiction said so)."""
    def show(v: float) -> str:
        return f"{v * 1e3:.3g} ms" if res["unit"] == "s" else f"{v:.4g} {res['unit']}"

    parts = [f"at {show(r['value'])} {r['outcome']}" for r in res["runs"]]
    text = f"predicted {show(res['limit'])}; " + ", ".join(parts)
    if res["agrees"] is False:
        text += ": the simulation contradicts the prediction"
    return text
