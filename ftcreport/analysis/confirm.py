r"""Each predicted stability limit confirmed by short simulations, at 0.9x and 1.1x of it.

Issue 37 item 6.  For a scheme's ``sample_time_max`` and ``k_v_max`` (:mod:`.limits`, healthy
pattern), the case is run by the engine (``runner.run_scheme``) with the healthy plant (no fault
events), starting 1 um off the reference (:data:`START`), with that setting at 0.9 and 1.1 times
the limit and everything else as the case has it (plant, motors, drive, saturation, delay, noise,
integrator).  A sample-time variant keeps the case's number of steps per sample (one ETD2 step per
sample for the motor cases).

What is measured: the limit is a linearization's, a statement about small deviations from the
loop's own trajectory.  So each setting is run twice, the second run started :data:`NUDGE` (1e-8 m)
further off, and the verdict reads how the difference of the two runs' states at the samples
evolves: the variational response of the loop as the engine runs it, whichever mode crosses (the
velocity loop at the Nyquist frequency, or a slow kinematic mode at large sample times), and
unaffected by the error a moving reference leaves under a hold:

* ``diverged``: a run stopped (diverged, step_unstable, singular);
* ``limit cycle``: both completed, but the difference did not die out: its RMS over the last third
  of the run is at least :data:`DECAYED` times that over the first third (it stays, or it grows
  until the drive saturates and the loop chatters); or, for a mode crossing at more than a sixth of
  the sampling frequency, the command chatters from sample to sample (:func:`_chatter`: two runs
  locked on the same saturated cycle differ little);
* ``bounded``: both completed and the difference decayed below a tenth.

How long: the analysis predicts the spectral radius rho at 1.1x the limit, so the mode that crosses
grows by 10^4 in ``ln(1e4) / ln(rho)`` samples; the runs last that many samples (at least
:data:`MIN_SAMPLES`, at most :data:`MAX_SAMPLES`).  The prediction sets only the duration.
Prediction and simulation agree when 0.9x is bounded and 1.1x is not; anything else is reported as
a contradiction, with both numbers (never hidden).  When run: ``ftcreport analyze`` runs them for
a case with sampled control or motors unless ``--no-confirm``; a case page runs them when it is
rendered (batch renders a page only when its inputs changed).  They are not cached with the runs:
they cost a fraction of a second each warm, and a page is not re-rendered without a reason.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from ..errors import FtcError

__all__ = ["MAX_SAMPLES", "MIN_SAMPLES", "NUDGE", "START", "classify", "confirm_limit", "needs_confirmation"]

MIN_SAMPLES = 200
MAX_SAMPLES = 5_000
GROWTH = 1e4
#: the runs start this close to the reference: a linearization's limit is local, so its confirmation
#: starts where the linearization holds (with the case's own start, a large first error saturates the
#: drive and tests the region of attraction instead); the offset excites every mode
START = {"x": 1e-6, "y": 1e-6, "heading_offset_deg": 1e-4}
#: the second run's extra offset in x [m]: far below anything nonlinear, far above round-off (1e-15 m)
NUDGE = 1e-8
DECAYED = 0.1
#: a fast crossing also counts as a limit cycle when the command chatters (:func:`_chatter`) above this
CHATTER = 0.5
FACTORS = (0.9, 1.1)


def needs_confirmation(case) -> bool:
    """A case with sampled control or motors: its limits are confirmed by simulation (issue 37 item 6)."""
    return case.simulation.sample_time is not None or case.actuators is not None


def variant(case, scheme: str, which: str, value: float, samples: int, nudge: float = 0.0):
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
    start = case.initial.model_copy(
        update={"mode": "offset", "headings_deg": None, "eta": None, **START, "x": START["x"] + nudge}
    )
    return case.model_copy(update={"simulation": sim, "faults": [], "campaign": None, "initial": start})


def _states_at_samples(run, period: float) -> np.ndarray:
    """[q, eta] at each sample instant (the first stream row of each sample)."""
    t = np.asarray(run.t_stream if run.stream else run.t)
    sig = run.stream or run.signals
    first = np.unique(np.round(t / period), return_index=True)[1]
    return np.concatenate((np.asarray(sig["q"])[first], np.asarray(sig["eta"])[first]), axis=1)


def classify(run, other, period: float, fast: bool = False) -> dict:
    """The verdict on a pair of runs started NUDGE apart (module docstring): ``{"outcome", "growth", ...}``.

    ``fast``: the crossing mode oscillates at more than a sixth of the sampling frequency; then the
    difference's second difference is measured, which keeps that mode (a factor 1 to 4) and cuts the
    slow ones by (omega T)^2 (the kinematic modes, tens of seconds, would not decay within the run).
    """
    for r in (run, other):
        if r.status != "ok":
            return {"outcome": "diverged", "status": r.status, "t_end": r.t_end, "reason": r.reason}
    a, b = _states_at_samples(run, period), _states_at_samples(other, period)
    k = min(len(a), len(b))
    if k < 12:
        return {"outcome": "bounded", "status": "ok", "growth": 0.0, "note": "too few samples to judge"}
    d = a[:k] - b[:k]
    d[:, 2 : d.shape[1] - 2] = (d[:, 2 : d.shape[1] - 2] + np.pi) % (2.0 * np.pi) - np.pi  # headings
    if fast:
        d = d[2:] - 2.0 * d[1:-1] + d[:-2]
        k = len(d)
    dist = np.sqrt(np.sum(d * d, axis=1))
    third = k // 3
    early = float(np.sqrt(np.mean(dist[:third] ** 2)))
    late = float(np.sqrt(np.mean(dist[-third:] ** 2)))
    growth = late / early if early > 0 else (0.0 if late == 0 else math.inf)
    chatter = _chatter(run, period)
    bounded = growth < DECAYED and not (fast and chatter > CHATTER)
    return {"outcome": "bounded" if bounded else "limit cycle", "status": "ok", "growth": growth, "chatter": chatter}


def _chatter(run, period: float) -> float:
    """RMS of the command's second difference at the samples over RMS of the command, last third of the run.

    A sample-rate oscillation (the drive's limit cycle when the velocity loop is unstable) gives 1 to 4;
    a smooth command (omega T)^2, 1e-4 for 2 rad/s at 5 ms.  Two runs locked on the same saturated
    cycle differ little, so the difference alone would call it bounded.
    """
    t = np.asarray(run.t_stream if run.stream else run.t)
    u = np.asarray((run.stream or run.signals)["u"])
    us = u[np.unique(np.round(t / period), return_index=True)[1]]
    tail = us[2 * len(us) // 3 :]
    if len(tail) < 4:
        return 0.0
    d2 = tail[2:] - 2.0 * tail[1:-1] + tail[:-2]
    scale = float(np.sqrt(np.mean(tail**2)))
    return float(np.sqrt(np.mean(d2**2))) / scale if scale > 0 else 0.0


def confirm_limit(case, scheme: str, which: str, limit: float, crossing: complex | None, unit: str) -> dict:
    """Simulations at 0.9x and 1.1x of one limit: the runs' outcomes and whether they agree with it.

    ``crossing``: the predicted dominant pole z at 1.1x (its modulus sets the duration, its angle the
    measure: :func:`classify`; None: MIN_SAMPLES, the raw difference).
    """
    from ..runner import run_scheme

    rho = abs(crossing) if crossing is not None else 0.0
    need = math.ceil(math.log(GROWTH) / math.log(rho)) if rho > 1.0 else MIN_SAMPLES
    samples = int(min(MAX_SAMPLES, max(MIN_SAMPLES, need)))
    fast = crossing is not None and abs(cmath.phase(crossing)) > math.pi / 3
    measure = "second difference" if fast else "difference"
    out = {"limit": limit, "unit": unit, "samples": samples, "measure": measure, "runs": []}
    if need > MAX_SAMPLES:
        out["note"] = (
            f"the crossing mode is slow (|z| = {rho:.6g} at 1.1x: {need} samples to grow 10^4-fold); "
            f"run for {MAX_SAMPLES} samples"
        )
    for f in FACTORS:
        value = f * limit
        try:
            v = variant(case, scheme, which, value, samples)
            run, _m = run_scheme(v, scheme)
            other, _m = run_scheme(variant(case, scheme, which, value, samples, NUDGE), scheme)
            period = v.simulation.sample_time or v.simulation.dt
            if "error" in (run.status, other.status):
                res = {"outcome": "error", "reason": run.reason or other.reason}
            else:
                res = classify(run, other, period, fast)
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
