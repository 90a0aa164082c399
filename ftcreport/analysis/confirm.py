r"""Each predicted stability limit confirmed by short simulations, at 0.9x and 1.1x of it.

Issue 37 item 6.  For a scheme's ``sample_time_max`` and ``k_v_max`` (:mod:`.limits`, healthy
pattern), the case is run by the engine (``runner.run_scheme``) with the healthy plant (no fault
events), starting 1 um off the reference (:data:`START`), with that setting at 0.9 and 1.1 times
the limit and everything else as the case has it (plant, motors, drive, saturation, delay, noise,
integrator).  A sample-time variant integrates the plant at the case's step or finer: it keeps the
case's number of steps per sample, or takes as many as the case's dt fits in the new sample time
(:func:`variant`).  The step is the plant's, not the controller's: one ETD2 step per sample is
exact for the motors' currents under a held voltage but only second order on the kinematics, and at
a sample time of 0.2 s on the two-link circle (0.1 rad of heading per step) its error alone moved
the slow kinematic pair's growth per sample from 0.99905 (converged: 16 and 64 steps per sample
agree) to 1.0019, a limit cycle in a stable loop.

What is measured: the limit is a linearization's, a statement about small deviations from the
loop's own trajectory.  So each setting is run twice, the second run started :data:`NUDGE` (1e-6 m)
further off, and the verdict reads how the difference of the two runs' states at the samples
evolves: the variational response of the loop as the engine runs it, whichever mode crosses (the
velocity loop at the Nyquist frequency, or a slow kinematic mode at large sample times), and
unaffected by the error a moving reference leaves under a hold:

* ``diverged``: a run stopped (diverged, step_unstable, singular), or the difference of the scheme's own
  states ran away while q and eta did not show it (:func:`_scheme_states_grow`: a mode the torque
  does not read, which the analysis counts for stability, ``Blocks.internal``);
* ``limit cycle``: both completed, but the difference does not decay: it grew 10^4-fold, or it did
  not fall a hundredfold and its growth per sample fitted over the run's second half (``rho``, the
  simulation's own spectral radius of the crossing mode) is at least 1; or, for a mode crossing at
  more than a sixth of the sampling frequency, the command keeps chattering from sample to sample
  (:func:`_chatter`: two runs locked on the same saturated cycle differ little);
* ``bounded``: both completed and the difference decays.

How long: the analysis predicts the spectral radius rho at 1.1x the limit, so the mode that crosses
grows by 10^4 in ``ln(1e4) / ln(rho)`` samples; the runs last that many samples (at least
:data:`MIN_SAMPLES`, at most :data:`MAX_SAMPLES`).  The prediction sets only the duration.
Prediction and simulation agree when 0.9x is bounded and 1.1x is not; anything else is reported as
a contradiction, with both numbers (never hidden).  When run: ``ftcreport analyze`` runs them for
a case with sampled control or motors unless ``--no-confirm``; a case page runs them when it is
rendered (batch renders a page only when its inputs changed).  They are not cached with the runs:
they cost a fraction of a second each warm at a fast limit, but a slow kinematic limit at a large
sample time takes its 5,000 samples at the case's step (two_link_active_motors, 236 ms at 5 ms: 43-52
steps per sample: 107 s for the case's analysis with its 22 confirmations, 2026-11-27), and a page is
not re-rendered without a reason.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from ..errors import FtcError

__all__ = [
    "MAX_SAMPLES",
    "MIN_SAMPLES",
    "NUDGE",
    "START",
    "classify",
    "confirm_limit",
    "needs_confirmation",
    "sampled_steps",
]

MIN_SAMPLES = 200
MAX_SAMPLES = 5_000
GROWTH = 1e4
#: the runs start this close to the reference: a linearization's limit is local, so its confirmation
#: starts where the linearization holds (with the case's own start, a large first error saturates the
#: drive and tests the region of attraction instead); the offset excites every mode
START = {"x": 1e-6, "y": 1e-6, "heading_offset_deg": 1e-4}
#: the second run's extra offset in x [m]: far below anything nonlinear, and four decades above the floor
#: of two nearby runs' difference (about 1e-10 m: on three_link_switching_pi at 664 ms a nudge of 1e-8 m
#: decayed to that floor, whose wander over the run's second half was then fitted as a growth of 1.03 per
#: sample, a "limit cycle" in a loop whose deviation had fallen a hundredfold; 1e-6 m decays 10^4-fold)
NUDGE = 1e-6
LINEAR = 1e4
#: a deviation down to this fraction of its start has decayed, whatever slope its remainder has
DECAYED = 1e-2
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
    steps = 1 if T is None else round(T / s.dt)  # per sample (log_every counts steps)
    if which == "sample_time_max":
        steps = sampled_steps(s, float(value))
        T = float(value)
        data |= {"sample_time": T, "dt": T / steps}
        if case.plant.noise.sample_time is not None:  # a sensor period the new step need not divide: the
            # default clock (dt), which the sampled law reads once a sample, as it reads the sensor at its samples
            noise = case.plant.noise.model_copy(update={"sample_time": None})
            case = case.model_copy(update={"plant": case.plant.model_copy(update={"noise": noise})})
    else:
        case = with_k_v(case, scheme, value)
    period = T if T is not None else s.dt
    duration = samples * period
    data |= {"duration": duration, "log_every": steps * max(1, round(samples / 2000))}
    if data["sample_time"] is not None and data["measurement_delay"] * data["sample_time"] >= duration:
        data["duration"] = duration = (data["measurement_delay"] + samples) * data["sample_time"]
    sim = Simulation.model_validate(data)
    start = case.initial.model_copy(
        update={"mode": "offset", "headings_deg": None, "eta": None, **START, "x": START["x"] + nudge}
    )
    return case.model_copy(update={"simulation": sim, "faults": [], "campaign": None, "initial": start})


def sampled_steps(sim, T: float) -> int:
    """Integration steps per sample of a variant at sample time T: the case's own number, or more when
    the case's dt fits more often into T (the plant is never integrated coarser than the case does)."""
    own = 1 if sim.sample_time is None else round(sim.sample_time / sim.dt)
    return max(own, math.ceil(T / sim.dt * (1.0 - 1e-9)))


def _sample_rows(t: np.ndarray, period: float) -> np.ndarray:
    """The index of each sample instant's row: the first row of each sample, i.e. at t_j itself (a row
    a hair below t_j by round-off counts as t_j)."""
    return np.unique(np.floor(t / period + 1e-6), return_index=True)[1]


def _states_at_samples(run, period: float) -> np.ndarray:
    """[q, eta] at each sample instant (the first stream row of each sample)."""
    t = np.asarray(run.t_stream if run.stream else run.t)
    sig = run.stream or run.signals
    first = _sample_rows(t, period)
    return np.concatenate((np.asarray(sig["q"])[first], np.asarray(sig["eta"])[first]), axis=1)


def classify(run, other, period: float, fast: bool = False, internal: bool = False) -> dict:
    """The verdict on a pair of runs started NUDGE apart (module docstring): ``{"outcome", "rho", ...}``.

    ``rho``: the deviation's growth per sample, exp of the slope of its logarithm fitted over the
    second half of the run (while it stays below LINEAR, a 10^4-fold growth: beyond, it has left the
    linear range and the loop is called unstable at once).  ``fast``: the crossing mode oscillates at
    more than a sixth of the sampling frequency; then the deviation's second difference is read,
    which keeps that mode (a factor 1 to 4) and cuts the slow kinematic ones by (omega T)^2.
    ``internal``: the crossing mode is one of the scheme's states that reach no actuator (the analysis's
    left-out states, ``Blocks.internal``); then, where q and eta settle, the scheme's own states are read
    (:func:`_scheme_states_grow`).  Only then: over a short run an integral cost or a filter still taking
    up the nudge grows too, which is no instability.
    """
    for r in (run, other):
        if r.status != "ok":
            return {"outcome": "diverged", "status": r.status, "t_end": r.t_end, "reason": r.reason}
    verdict = _plant_verdict(run, other, period, fast)
    if internal and verdict["outcome"] == "bounded":  # q and eta settle: do the scheme's own states?
        grown = _scheme_states_grow(run, other)
        if grown is not None:
            return {"outcome": "diverged", "status": "ok", "rho": None, "note": grown}
    return verdict


def _plant_verdict(run, other, period: float, fast: bool) -> dict:
    """:func:`classify` on the plant's states [q, eta] at the samples (both runs completed)."""
    a, b = _states_at_samples(run, period), _states_at_samples(other, period)
    k = min(len(a), len(b))
    d = a[:k] - b[:k]
    d[:, 2 : d.shape[1] - 2] = (d[:, 2 : d.shape[1] - 2] + np.pi) % (2.0 * np.pi) - np.pi  # headings
    if fast:
        d = d[2:] - 2.0 * d[1:-1] + d[:-2]
    dist = np.sqrt(np.sum(d * d, axis=1))
    if len(dist) < 12 or not np.all(np.isfinite(dist)) or dist[0] <= 0.0:
        return {"outcome": "bounded", "status": "ok", "rho": None, "note": "too few samples to judge"}
    chatter = _chatter(run, period)
    if dist.max() > LINEAR * max(dist[: max(2, len(dist) // 20)].max(), 1e-300):
        return {"outcome": "limit cycle", "status": "ok", "rho": None, "chatter": chatter,
                "note": "the deviation grew 10^4-fold"}  # fmt: skip
    start = dist[: max(2, len(dist) // 20)].max()
    if dist[-len(dist) // 10 :].max() < DECAYED * start and not (fast and chatter > CHATTER):
        # a hundredfold down: what is left is round-off or the slow modes' trace in the differences
        return {"outcome": "bounded", "status": "ok", "rho": None, "chatter": chatter,
                "note": "the deviation decayed a hundredfold"}  # fmt: skip
    half = np.arange(len(dist) // 2, len(dist))
    keep = half[dist[half] > 0.0]
    slope = float(np.polyfit(keep, np.log(dist[keep]), 1)[0]) if keep.size > 4 else 0.0
    rho = math.exp(slope)
    bounded = rho < 1.0 and not (fast and chatter > CHATTER)
    return {"outcome": "bounded" if bounded else "limit cycle", "status": "ok", "rho": rho, "chatter": chatter}


def _scheme_states_grow(run, other) -> str | None:
    """Why the scheme's own states (``xc``, as logged) run away, or None.

    A mode of the scheme's states that the torque does not read (the switching bank's filters, stepped
    by forward Euler: unstable beyond gamma T = 2) leaves q and eta alone until it overflows; the
    analysis counts it (``Blocks.internal``), so its confirmation must see it.  Read on the difference
    of the two runs, each state relative to its own largest magnitude in the run (units differ; a
    difference at round-off stays at round-off): it runs away when its last tenth is above a hundred
    times its value at the middle of the run, still growing and above 1e-4 of the states' own size
    (the nudge amplified a hundredfold), or when it is no longer finite.  A transient as the nudge
    reaches the scheme's states is over by the middle of a stable run.
    """
    xa, xb = run.signals.get("xc"), other.signals.get("xc")
    if xa is None or xb is None:
        return None
    k = min(len(xa), len(xb))
    if k < 20:
        return None
    with np.errstate(invalid="ignore", over="ignore"):
        a, b = np.asarray(xa[:k], dtype=float), np.asarray(xb[:k], dtype=float)
        d = a - b
        if not np.all(np.isfinite(d)):
            return "the scheme's own states overflowed"
        scale = np.maximum(np.abs(a).max(axis=0), np.abs(b).max(axis=0))
        cols = scale > 1e-12 * scale.max(initial=0.0)  # a state that stays at round-off is not read
        if not np.any(cols):
            return None
        dist = np.abs(d[:, cols] / scale[cols]).max(axis=1)
    mid, tail = dist[k // 2], dist[-max(2, k // 10) :]
    if tail.max() > max(100.0 * mid, 1e-4) and tail[-1] >= tail[0]:
        growth = tail.max() / max(mid, 1e-300)
        return f"the scheme's own states ran away (their difference {growth:.3g}-fold over the second half)"
    return None


def _chatter(run, period: float) -> float:
    """How much the command chatters and keeps chattering: over the last third of the run, the RMS of its
    second difference at the samples over its RMS, when that part has not decayed from the middle third
    (by 10 % at most); 0 when it dies out.

    A sample-rate oscillation (the drive's limit cycle when the velocity loop is unstable) gives 1 to 4
    and stays; a smooth command gives (omega T)^2, 1e-4 for 2 rad/s at 5 ms; a stable loop near its
    limit rings at the sample rate but the ringing decays.  Two runs locked on the same saturated cycle
    differ little, so their difference alone would call it bounded.
    """
    t = np.asarray(run.t_stream if run.stream else run.t)
    u = np.asarray((run.stream or run.signals)["u"])
    us = u[_sample_rows(t, period)]
    n = len(us) // 3
    if n < 4:
        return 0.0

    def part(x):
        d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
        return float(np.sqrt(np.mean(d2**2))), float(np.sqrt(np.mean(x**2)))

    mid, _ = part(us[n : 2 * n])
    late, scale = part(us[2 * n :])
    if scale == 0.0 or late < 0.9 * mid:
        return 0.0
    return late / scale


def confirm_limit(case, scheme: str, which: str, limit: float, crossing: complex | None, unit: str,
                  internal: bool = False) -> dict:  # fmt: skip
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
                res = classify(run, other, period, fast, internal)
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
