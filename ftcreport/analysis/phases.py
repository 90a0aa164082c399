r"""Every scheme in every fault phase: poles, stability, margins and limits of the loop as it runs (pure).

For each scheme of a case and each phase of its fault schedule (between two events), the closed
loop is linearized (:mod:`.closed_loop`) at frozen instants of the phase, with the phase's true
faults and the pattern the scheme applies there:

* nominal applies the healthy law to the faulty plant; the oracle the truth;
* switching the model its run selected longest in the phase, or without a run the model of the true
  pattern (the one its cost selects once the filters have converged; the nearest bank model when the
  true pattern is not in the bank);
* adaptive its weights (the run's, else on the design of the true pattern), the active schemes their
  estimates (the run's parameter estimates, else the truth); a plug-in its run's states, else its
  initial state.

On a constant-curvature reference with the two-link law, or a straight line, the loop in the frame
turning with the reference is autonomous: one instant per phase gives its exact poles.  Elsewhere the
loop is time-varying and three instants per phase are taken; frozen-time eigenvalues are evidence,
not proof (a time-varying loop can be unstable with every frozen pole stable, and the converse).

Where the controller is sampled (``simulation.sample_time``, and the UKF scheme, whose filter and
law run at the samples or at every step), the loop is analysed in discrete time (:mod:`.sampled`):
z-plane poles and the spectral radius; elsewhere s-plane poles and the largest real part.
"""

from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import FtcError, ModelError
from .closed_loop import Blocks, Faults, SchemeLoop, frames
from .limits import (
    MARGINAL_Z,
    boundary_modes,
    continuous_margin,
    dominant_pole,
    fastest_pole,
    gain_domain,
    gain_family,
    largest_gain,
    largest_sample_time,
    periodic_growth,
    sampled_radius,
)
from .limits import stability as limits_stability
from .margins import loop_margins
from .sampled import closed_loop_matrix

__all__ = ["RunStates", "analyze_scheme", "fault_phases", "instants", "pole_rows", "reference_period", "time_varying"]

#: frozen instants over one period of the reference for a periodic loop's sample-time limit
#: (:func:`~ftcreport.analysis.limits.periodic_growth`: 12, 24 and 48 agree to 1.5e-4 on the three-link sinusoid)
PERIODIC_INSTANTS = 24


def fault_phases(case) -> list[tuple[float, float]]:
    """The phases of the fault schedule: [0, first event), ..., [last event, duration]."""
    end = float(case.simulation.duration)
    events = sorted({float(f.time) for f in case.faults if 0.0 < f.time < end})
    edges = [0.0, *events, end]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def time_varying(case) -> bool:
    """Whether the loop is time-varying in the frame turning with the reference (several instants needed).

    The two-link law on a unicycle or circle reference (constant v_d, omega_d), and any law on a
    straight line, give an autonomous loop; the chained law's frame re-anchoring (every 45 deg) makes
    it periodic on a circle, and the eight and the sinusoid change speed and curvature.
    """
    kind = case.reference.kind
    if kind == "line":
        return False
    if kind == "unicycle" and float(case.reference.omega_d) == 0.0:
        return False
    return not (case.kinematic.kind == "two_link" and kind in ("unicycle", "circle"))


def reference_period(built) -> float | None:
    """The reference's period [s]: the smallest common period of its sine terms (a uniform velocity
    only translates the path, which no loop in the frame of the reference sees); None without one (a
    line, incommensurate frequencies up to a ratio of 16)."""
    path = built.reference.path
    ws = sorted({abs(w) for a, w, _ in (*path.x_terms, *path.y_terms) if a != 0.0 and w != 0.0})
    if not ws:
        return None
    for m in range(1, 17):
        if all(abs(w * m / ws[0] - round(w * m / ws[0])) < 1e-9 * max(1.0, w * m / ws[0]) for w in ws):
            return 2.0 * math.pi * m / ws[0]
    return None


def instants(case, t0: float, t1: float) -> list[float]:
    """The frozen instants of a phase: its middle, or three spread over it on a time-varying loop."""
    if not time_varying(case):
        return [0.5 * (t0 + t1)]
    return [t0 + (k + 0.5) / 3.0 * (t1 - t0) for k in range(3)]


#: where the applied pattern comes from without a run (with one: the run's states)
_ORIGIN = {
    "nominal": "the healthy law (no FTC)",
    "oracle": "the true faults",
    "adaptive": "weights on the design of the true pattern",
    "adaptive_frozen": "weights on the design of the true pattern",
    "active": "estimates at the truth",
    "active_ukf": "estimates at the truth",
}


def case_frames(case, built) -> dict[float, float]:
    """The chained law's frame at every frozen instant of the case (empty for the two-link law)."""
    times = [t for p in fault_phases(case) for t in instants(case, *p)]
    return frames(built.kinematic(), times, step=max(float(case.simulation.dt), 0.01))


def phase_faults(built, t: float) -> Faults:
    """The true faults at t: command faults (sigma, ubar) and the motor-fault table."""
    sigma, ubar = built.faults.at(float(t))
    motors = built.plant.motors is not None
    motor = np.asarray(built.faults.motor(float(t)), dtype=float) if motors else np.zeros((0, 4))
    return Faults(np.asarray(sigma, dtype=float).copy(), np.asarray(ubar, dtype=float).copy(), motor)


@dataclass
class RunStates:
    """A stored run's controller state and switching index, read at the analysis's instants.

    ``series``: the run's logged arrays (``t``, ``xc``, ``selected`` for switching), as
    ``store.load_timeseries`` gives them.  Only the part the run simulated is used.
    """

    series: dict

    def _t(self) -> np.ndarray:
        return np.asarray(self.series.get("t", np.zeros(0)), dtype=float)

    def xc_at(self, t: float) -> np.ndarray | None:
        """The logged controller state nearest t, None when the run did not reach t."""
        ts, xc = self._t(), self.series.get("xc")
        if xc is None or ts.size == 0 or t > ts[-1] + 1e-9 or t < ts[0] - 1e-9:
            return None
        return np.asarray(xc[int(np.argmin(np.abs(ts - t)))], dtype=float)

    def selected(self, t0: float, t1: float) -> tuple[int, float] | None:
        """The switching model applied longest in [t0, t1) and the fraction of the phase's samples it held."""
        ts, sel = self._t(), self.series.get("selected")
        if sel is None or ts.size == 0:
            return None
        mask = (ts >= t0) & (ts < t1)
        if not np.any(mask):
            return None
        vals, counts = np.unique(np.round(np.asarray(sel, dtype=float)[mask]).astype(int), return_counts=True)
        k = int(np.argmax(counts))
        return int(vals[k]), float(counts[k] / counts.sum())


def failure_words(exc: BaseException, scheme: str, t: float | None = None) -> str:
    """Why a linearization failed, for the page and --json: ftcreport's own message (it names the scheme and
    where), or numpy's or scipy's (a linear solve, an SVD on the loop's numbers) with the scheme and the time."""
    if isinstance(exc, FtcError):
        return str(exc)
    at = f" at t = {t:g} s" if t is not None else ""
    return f"scheme {scheme}: the linear algebra on its loop{at} failed on its numbers ({type(exc).__name__}: {exc})"


def pole_rows(poles: np.ndarray, T: float | None) -> list[dict]:
    """Poles with natural frequency, damping and time constant, slowest first (as ``control.damp``).

    A continuous pole s: ``wn = |s|``, ``damping = -Re(s) / |s|``, time constant ``-1 / Re(s)``; a
    discrete pole z (T given) through its continuous equivalent ``s = ln(z) / T``.
    """
    rows = []
    for p in np.asarray(poles, dtype=complex):
        with np.errstate(divide="ignore", invalid="ignore"):
            sp = complex(np.log(p) / T) if T else complex(p)
        wn = abs(sp)
        rows.append(
            {
                "re": float(p.real),
                "im": float(p.imag),
                "wn": float(wn) if math.isfinite(wn) else None,
                "damping": float(-sp.real / wn) if wn > 0 and math.isfinite(wn) else None,
                "time_constant": float(-1.0 / sp.real) if sp.real < 0 else None,
            }
        )
    key = (lambda r: -math.hypot(r["re"], r["im"])) if T else (lambda r: -r["re"])
    return sorted(rows, key=key)


def analyze_scheme(case, scheme: str, built, run: dict | None = None, margins: bool = True,
                   limits: bool = True, psis: dict | None = None) -> dict:  # fmt: skip
    """One scheme of a case: per phase the true and applied pattern, poles, stability, margins; its limits.

    ``run``: the scheme's stored run (``store.load_timeseries``), for the states it held and the model
    switching selected; ``psis``: the chained law's frame at the instants (:func:`case_frames`, shared
    by the schemes of a case).  Returns ``{"phases": [...], "limits": {...}, "velocity_loop": {...}, ...}``
    (the keys are documented in README, "Linearized analysis").
    """
    loop = SchemeLoop(case, scheme, built)
    sim = case.simulation
    T = sim.sample_time
    discrete = T is not None or loop.has_disc
    period = T if T is not None else (sim.dt if loop.has_disc else None)
    delay = int(sim.measurement_delay)
    states = RunStates(run) if run else None
    phases = fault_phases(case)
    times = {p: instants(case, *p) for p in phases}
    if psis is None:
        psis = case_frames(case, built)
    out_phases = []
    for t0, t1 in phases:
        fz = phase_faults(built, t0)
        applied, applied_from = None, _ORIGIN.get(scheme, "its initial state (no run)")
        if scheme == "switching":
            sel = states.selected(t0, t1) if states else None
            if sel is not None:
                applied, applied_from = sel[0], f"run ({100 * sel[1]:.0f} % of the phase)"
            else:
                applied_from = "true pattern (nearest bank model)"
        entry = {
            "t_start": t0,
            "t_end": t1,
            "pattern_true": [float(v) for v in fz.sigma],
            "friction_true": [float(v) for v in fz.ubar],
            "discrete": bool(discrete),
            "sample_time": period if discrete else None,
        }
        if fz.motor.size:
            entry["motor_faults"] = _motor_words(fz.motor, loop.ctrl.chain.wheels)
        rows = []
        for t in times[(t0, t1)]:
            run_xc = states.xc_at(t) if states else None
            try:
                pt = loop.point(t, fz, psis.get(t), applied, run_xc, period)
                blk = loop.blocks(pt, period)
            except (FtcError, ValueError, np.linalg.LinAlgError) as exc:
                rows.append({"t": t, "error": failure_words(exc, scheme, t)})
                continue
            if discrete:
                M = closed_loop_matrix(blk, period, delay)
                ev = np.linalg.eigvals(M) if M.size else np.zeros(0, dtype=complex)
                measure = float(np.abs(ev).max(initial=0.0))
            else:
                A = blk.continuous()
                ev = np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
                measure = float(ev.real.max(initial=-math.inf))
            # the left-out states' own modes: not poles of the loop the plant sees, but the run is bounded
            # only if they are stable too (Blocks.internal)
            inner = blk.internal_modes(period if discrete else None)
            internal = (float(np.abs(inner).max()) if discrete else float(inner.real.max())) if inner.size else None
            if internal is not None:
                measure = max(measure, internal)
            rows.append({"t": t, "measure": measure, "poles": ev, "blk": blk, "pt": pt, "run": run_xc is not None,
                         "internal": internal, "n_internal": int(inner.size)})  # fmt: skip
        good = [r for r in rows if "error" not in r]
        key = "spectral_radius" if discrete else "max_real_part"
        entry["instants"] = [
            {"t": r["t"], key: r.get("measure"), **({"error": r["error"]} if "error" in r else {})} for r in rows
        ]
        entry["frozen"] = len(rows) > 1
        if not good:  # no frozen instant linearized (a plug-in law that raises): the documented keys null
            entry |= {"pattern_applied": None, "applied_from": applied_from, "t_worst": None, "poles": [],
                      "pole_table": None, key: None, "internal_modes": None, "stable": None,
                      "stability": "not computed", "frozen_disagree": None, "states": None, "margins": None,
                      "note": rows[0]["error"] if rows else "no instant"}  # fmt: skip
            out_phases.append(entry)
            continue
        worst = max(good, key=lambda r: r["measure"])
        pt, blk = worst["pt"], worst["blk"]
        if worst["run"] and scheme not in ("nominal", "oracle", "switching"):
            applied_from = "its run's states"
        stability = _verdict(worst, discrete)
        # frozen instants that disagree (one stable, another unstable) decide nothing about a time-varying
        # loop: four_link_eight_step's healthy loop is frozen-unstable at 10 s (+11.6 1/s), stable at
        # 3.3 and 16.7 s, and every run tracks it
        each = {r["t"]: _verdict(r, discrete) for r in good}
        disagree = "stable" in each.values() and "unstable" in each.values()
        if disagree:
            stability = "inconclusive"
        entry |= {
            "pattern_applied": pt.applied,
            "applied_from": applied_from if pt.applied is not None else "the law applies no pattern",
            "t_worst": worst["t"],
            "poles": [[float(p.real), float(p.imag)] for p in worst["poles"]],
            "pole_table": pole_rows(worst["poles"], period if discrete else None),
            key: worst["measure"],
            "stable": None if disagree else stability == "stable",
            "stability": stability,
            "frozen_disagree": {
                "stable_at": [t for t, v in each.items() if v == "stable"],
                "unstable_at": [t for t, v in each.items() if v == "unstable"],
            }
            if disagree
            else None,
            "internal_modes": (
                {"modes": worst["n_internal"], key: worst["internal"]} if worst["internal"] is not None else None
            ),
            "states": {
                "plant": int(blk.Fx.shape[0]),
                "scheme": int(blk.nc),
                "left_out": int(blk.dropped),
                "parameter_block": int(blk.parameter_block),
                "delay_line": delay * (loop.n_q + 2) if discrete else 0,
            },
        }
        entry["margins"] = (
            loop_margins(
                blk, period if discrete else None, delay, loop.ctrl.chain.wheels, loop.plant.input_unit, not out_phases
            )
            if margins and stability == "stable"
            else {"note": f"the closed loop is {_words(stability)}: margins are defined for a stable loop only"}
            if margins
            else None
        )
        out_phases.append(entry)
    result = {"phases": out_phases, "discrete": bool(discrete), "sample_time": period, "k_v": loop.k_v}
    if limits:
        # at the first phase's worst frozen instant (the limits' searches cost tens of linearizations each)
        t_lim = out_phases[0]["t_worst"]
        if t_lim is None:  # a phase not computed: its first frozen instant (the limits say why they are null)
            t_lim = times[phases[0]][0]
        result |= scheme_limits(case, scheme, built, loop, [t_lim], psis, period, delay)
        split = out_phases[0].get("frozen_disagree")
        if split:  # the limits are those of one frozen instant that the phase's others contradict: say so
            others = ", ".join(f"{t:.4g}" for t in split["stable_at"])
            caveat = (f"frozen evidence only, taken at the instant t = {t_lim:.4g} s of the first phase, whose other "
                      f"frozen instants ({others} s) are stable")  # fmt: skip
            result["limit_notes"] = {"caveat": caveat, **result["limit_notes"]}
    return result


def scheme_limits(case, scheme, built, loop: SchemeLoop, ts, psis, period, delay) -> dict:
    """``limits`` and ``velocity_loop`` of one scheme: healthy pattern, the case's gains (module limits).

    The velocity loop alone (q held, :meth:`Blocks.velocity_loop`) is given for a law that measures
    eta; an active scheme sees the velocity only through its observer of q, so holding q opens its
    loop: its ``velocity_loop`` limits are null, and say so.
    """
    fz = Faults.healthy(built.chain.n_wheels, built.plant.motors is not None)
    out = {"limits": {}, "velocity_loop": {}, "limit_notes": {}, "limit_kinds": {}}
    kinds = out["limit_kinds"]
    try:
        blocks = [loop.blocks(loop.point(t, fz, psis.get(t), None, None, period), period) for t in ts]
    except (FtcError, ValueError, np.linalg.LinAlgError) as exc:
        for name in ("limits", "velocity_loop"):
            out[name] = {"sample_time_max": None, "k_v_max": None}
            why = f"not computed: {failure_words(exc, scheme, ts[0])}"
            out["limit_notes"] |= {f"{name}.{k}": why for k in out[name]}
            kinds |= {f"{name}.{k}": "not_computed" for k in out[name]}
        return out
    picks = {"limits": lambda b: b}
    if _law_reads_eta(loop, ts[0], fz, psis, period):
        picks["velocity_loop"] = Blocks.velocity_loop
    else:
        out["velocity_loop"] = {"sample_time_max": None, "k_v_max": None}
        why = "the law does not read eta (it estimates the velocity from q): without q there is no velocity loop"
        out["limit_notes"] |= {"velocity_loop.sample_time_max": why, "velocity_loop.k_v_max": why}
        kinds |= {"velocity_loop.sample_time_max": "not_applicable", "velocity_loop.k_v_max": "not_applicable"}
    # a loop marginal at the case's own setting with modes that move the plant has no stable range to bound:
    # its tracking error does not converge (a law saturated everywhere, a drive too slow to act), and a
    # "limit" where it turns unstable would be read as a stability limit that simulation then refutes
    for name, pick in list(picks.items()):
        own = pick(blocks[0])
        sampled = period is not None
        M = closed_loop_matrix(own, period, delay) if sampled else own.continuous()
        modes = boundary_modes(M, _n_plant(own, delay if sampled else 0), sampled)
        unstable = (sampled_radius(own, period, delay) - 1.0 - MARGINAL_Z if sampled
                    else continuous_margin(own)) > 0.0  # fmt: skip
        if modes["in_plant"] and not unstable:  # an unstable one: the searches say where it is stable
            del picks[name]
            at = f"T_s = {period * 1e3:g} ms" if sampled else "in continuous time"
            note = (
                f"no stable range: the loop at the case's own setting ({at}, k_v = {loop.k_v:g} 1/s) is marginal, "
                f"not stable: {_held_words(modes, sampled)}, so the tracking error does not converge and there is "
                "no stable range to bound"
            )
            out[name] = {"sample_time_max": None, "k_v_max": None}
            out["limit_notes"] |= {f"{name}.sample_time_max": note, f"{name}.k_v_max": note}
            kinds |= {f"{name}.sample_time_max": "marginal", f"{name}.k_v_max": "marginal"}
    periodic = _periodic_blocks(case, built, loop, fz, period) if "limits" in picks else None
    for name, pick in picks.items():
        if loop.has_disc:
            out[name]["sample_time_max"] = None
            out["limit_notes"][f"{name}.sample_time_max"] = (
                "not searched: the UKF's gain comes from its covariance, the run's (or the initial one) at its own "
                "period; at another sample time the filter would settle to another gain"
            )
            kinds[f"{name}.sample_time_max"] = "not_searched"
            continue
        guess = 2.0 / max(fastest_pole(pick(b)) for b in blocks)
        rho = lambda T, p=pick: max(sampled_radius(p(b), T, delay) for b in blocks)  # noqa: E731
        res = largest_sample_time(rho, guess)
        if name == "limits" and periodic is not None:
            res, rho = _periodic_limit(periodic, res, guess, delay)
        if res["value"] is not None:  # the range below the limit must be stable, not only marginal (below)
            T9 = 0.9 * res["value"]
            frozen = periodic[1] if name == "limits" and periodic is not None else blocks
            mats = [(closed_loop_matrix(pick(b), T9, delay), _n_plant(pick(b), delay)) for b in frozen]
            res = _unless_held(res, mats, True, f"T_s = {T9 * 1e3:.4g} ms", f"{res['value'] * 1e3:.4g} ms")
        out[name]["sample_time_max"] = res["value"]
        out["limit_notes"][f"{name}.sample_time_max"] = res["note"]
        kinds[f"{name}.sample_time_max"] = res["kind"]
        if name == "limits" and res["value"] is not None:
            T1 = 1.1 * res["value"]
            z = dominant_pole(blocks[0], T1, delay)
            inner = blocks[0].internal_measure(T1) >= abs(z)
            if periodic is not None:  # the frozen instants' dominant pole, at the period's growth per sample
                z = max((dominant_pole(b, T1, delay) for b in periodic[1]), key=abs)
                inner = max(b.internal_measure(T1) for b in periodic[1]) >= rho(T1)
                z = z / abs(z) * rho(T1) if abs(z) > 0.0 else z
            out["crossing"] = {"sample_time_max": [z.real, z.imag]}
            # whether the crossing mode is one of the left-out states' (the confirmation then reads them)
            out["crossing_internal"] = {"sample_time_max": bool(inner)}
        if name == "limits":
            grid = _grid(res["value"] or guess, period)
            out["_curves"] = {"T": grid.tolist(), "rho_T": [rho(T) for T in grid]}
    k_v = loop.k_v

    def at_gain(k: float, t: float, b: Blocks) -> Blocks:
        # at the case's own gain the loop is the one linearized there, b (tests/test_limits.py: the same numbers)
        return b if k == k_v else _blocks_at_gain(case, scheme, built, fz, psis.get(t), t, k, period, b)

    try:
        refuses = gain_refusal(case, scheme, built)
        domain = {} if refuses is None else gain_domain(refuses, k_v)  # the gains a plug-in accepts
        if "hole" in domain:
            raise ModelError(f"not searched: {domain['hole']}: its gains are not an interval")
        if refuses is not None and (refuses(2.0 * k_v) or refuses(0.5 * k_v)):  # no line through them: each gain
            fam = [lambda k, t=t, b=b: at_gain(k, t, b) for t, b in zip(ts, blocks, strict=True)]
        else:
            # a built-in law is affine in k_v by construction unless a limit clips its command (limits.gain_family)
            unclipped = built.plant.motors is None and built.plant.saturation is None
            checked = not (unclipped and _built_in(scheme))
            fam = [
                gain_family(lambda k, t=t, b=b: at_gain(k, t, b), k_v, checked) for t, b in zip(ts, blocks, strict=True)
            ]
    except ModelError as exc:  # a plug-in without a k_v field, or whose gains have a hole
        for name in picks:
            out[name]["k_v_max"] = None
            out["limit_notes"][f"{name}.k_v_max"] = str(exc)
            kinds[f"{name}.k_v_max"] = "not_searched"
        return out
    for name, pick in picks.items():
        if period is not None:
            radius = lambda k, p=pick: max(sampled_radius(p(f(k)), period, delay) for f in fam)  # noqa: E731
            margin = lambda k, r=radius: r(k) - 1.0 - MARGINAL_Z  # noqa: E731
        else:
            margin = lambda k, p=pick: max(continuous_margin(p(f(k))) for f in fam)  # noqa: E731
        res = largest_gain(margin, loop.k_v, domain)
        if res["value"] is not None:  # as the sample time's: the gains below the limit must be stable
            k9 = 0.9 * res["value"]
            loops = [pick(f(k9)) for f in fam]
            mats = [
                (closed_loop_matrix(b, period, delay) if period is not None else b.continuous(), _n_plant(b, delay))
                for b in loops
            ]
            res = _unless_held(res, mats, period is not None, f"k_v = {k9:.4g} 1/s", f"{res['value']:.4g} 1/s")
        out[name]["k_v_max"] = res["value"]
        out["limit_notes"][f"{name}.k_v_max"] = res["note"]
        kinds[f"{name}.k_v_max"] = res["kind"]
        if name == "limits":
            grid = _grid(res["value"] or k_v, k_v)
            lo, hi = domain.get("bottom", 0.0), domain.get("top", math.inf)
            grid = grid[(grid >= lo) & (grid <= hi)]  # only gains the scheme accepts
            key = "rho_k" if period is not None else "max_re_k"
            curve = radius if period is not None else margin
            out.setdefault("_curves", {}).update({"k": grid.tolist(), key: [curve(k) for k in grid]})
        if name == "limits" and res["value"] is not None and period is not None:
            b1 = fam[0](1.1 * res["value"])
            z = dominant_pole(b1, period, delay)
            out.setdefault("crossing", {})["k_v_max"] = [z.real, z.imag]
            out.setdefault("crossing_internal", {})["k_v_max"] = bool(b1.internal_measure(period) >= abs(z))
    return out


def _n_plant(blk: Blocks, delay: int) -> int:
    """The plant's states and the delay line's copies of them, first in the loop's matrix."""
    return blk.Fx.shape[0] + delay * blk.Gy.shape[1]


def _held_words(modes: dict, discrete: bool) -> str:
    """'3 of its modes sit on the stability boundary and move the plant (largest |z| - 1 -2.8e-07)'."""
    edge = "|z| - 1" if discrete else "Re"
    return (
        f"{modes['in_plant']} of its modes sit on the stability boundary and move the plant "
        f"(largest {edge} {modes['largest']:.3g})"
    )


def _unless_held(res: dict, mats, discrete: bool, at: str, limit: str) -> dict:
    """``res`` (a limit found), or null of kind marginal when the loop at 0.9x the limit is marginal with
    boundary modes that hold a plant perturbation in the plant (:func:`limits.boundary_modes`): then the
    search's "stable" side is only marginal, the tracking error does not converge below the limit, and the
    limit is only where it turns unstable (a drive saturated at I_max = 1e-6: a k_v limit of 638 1/s, and
    at 300 1/s every phase marginal; simulation at 0.9x and 1.1x diverged)."""
    for M, n_plant in mats:
        modes = boundary_modes(M, n_plant, discrete)
        if modes["in_plant"]:
            note = (
                f"no stable range: below the point where the loop turns unstable ({limit}) it is marginal, not "
                f"stable: at {at} {_held_words(modes, discrete)}, so the tracking error does not converge there"
            )
            return {"value": None, "kind": "marginal", "note": "; ".join(x for x in (res["note"], note) if x)}
    return res


def _periodic_blocks(case, built, loop: SchemeLoop, fz: Faults, period) -> tuple[float, list] | None:
    """(the reference's period, the loop's blocks at PERIODIC_INSTANTS instants over it) for a sampled or
    motorised case whose loop varies along a periodic reference, else None.

    Only there: its sample-time limit is confirmed by simulation, which sees the loop over whole periods;
    elsewhere the limit is what another sample time would do and stays the worst frozen instant's
    (evidence), which costs one linearization instead of 24 (issue 37 item 9's budget).
    """
    from .confirm import needs_confirmation

    if loop.has_disc or not time_varying(case) or not needs_confirmation(case):
        return None
    P = reference_period(built)
    if P is None:
        return None
    ts = [(k + 0.5) * P / PERIODIC_INSTANTS for k in range(PERIODIC_INSTANTS)]
    try:  # a period the reference does not complete (a horizon: analysis.case.analysed_horizon) has no product
        psis = frames(built.kinematic(), ts, step=max(float(case.simulation.dt), 0.01))
        return P, [loop.blocks(loop.point(t, fz, psis.get(t), None, None, period), period) for t in ts]
    except (FtcError, ValueError, np.linalg.LinAlgError):
        return None


def _periodic_limit(periodic: tuple[float, list], frozen: dict, guess: float, delay: int):
    """The sample-time limit over one period of the reference (:func:`periodic_growth`) and its growth
    function; the note gives the worst frozen instant's limit beside it."""
    P, blocks = periodic
    rho = lambda T: periodic_growth(blocks, T, delay, P)  # noqa: E731
    res = largest_sample_time(rho, guess)
    seen = f"{frozen['value'] * 1e3:.4g} ms" if frozen["value"] is not None else "none"
    note = (
        f"over one period of the reference ({P:.4g} s, {len(blocks)} instants: the growth per sample of the "
        f"sampled loop's product over it); the worst frozen instant of the first phase alone gives {seen}"
    )
    return {"value": res["value"], "kind": res["kind"], "note": "; ".join(x for x in (res["note"], note) if x)}, rho


def _law_reads_eta(loop: SchemeLoop, t: float, fz: Faults, psis: dict, period) -> bool:
    """Whether the scheme's law (not the driver, which reads the measured wheel speeds) reads eta."""
    pt = loop.point(t, fz, psis.get(t), None, None, period)
    nq = loop.n_q
    st, ut = loop.plant.true_faults(pt.xp, fz)
    q, eta = pt.xp[:nq], pt.xp[nq : nq + 2]
    u0 = loop.law(t, q, eta, pt.xc, st, ut)[0]
    return any(np.any(loop.law(t, q, eta + 1e-4 * e, pt.xc, st, ut)[0] != u0) for e in np.eye(2))


def _verdict(row: dict, discrete: bool) -> str:
    """A frozen instant's stability (:func:`limits.stability`), a continuous loop's poles held to their own
    resolution where the fastest pole's band would call them marginal."""
    A = None if discrete else row["blk"].continuous()
    return limits_stability(row["measure"], row["poles"], discrete, A, row.get("internal"))


def _words(stability: str) -> str:
    return "inconclusive (its frozen instants disagree)" if stability == "inconclusive" else stability


def _grid(limit: float, case_value: float | None, points: int = 48) -> np.ndarray:
    """A log grid for the figures: from a tenth of the smaller of the limit and the case's value to three
    times the larger."""
    lo = min(limit, case_value or limit)
    hi = max(limit, case_value or limit)
    return np.geomspace(lo / 10.0, hi * 3.0, points)


def gain_refusal(case, scheme: str, built):
    """For a plug-in scheme: ``refuses(k)``, why it does not accept velocity gain k (its table's range: the
    table validated with k; its ``validate`` hook on that table; its hooks bound with k: ``pack`` raising on
    it), else None; None for a built-in
    scheme (its law takes any gain > 0).  A plug-in whose table has no k_v: ModelError (nothing to vary).
    Each gain's answer is kept (the search and the figure's grid ask again)."""
    from pydantic import ValidationError

    from ..cases.case import scheme_validate
    from ..runner import make_controller
    from ..schemes import get
    from ..schemes.fields import FieldError
    from ..schemes.registry import is_built_in
    from .closed_loop import with_k_v

    if is_built_in(get(scheme)):
        return None
    with_k_v(case, scheme, 1.0)  # ModelError without a k_v field
    cfg = getattr(case.schemes, scheme)
    model, data = type(cfg), cfg.model_dump()
    try:
        model.model_validate(data)
        table_checks = True
    except ValidationError:  # a table that does not round-trip through its dump: its hooks alone tell
        table_checks = False
    answers: dict[float, str | None] = {}

    def refuses(k: float) -> str | None:
        if k not in answers:
            answers[k] = None
            try:
                if table_checks:
                    model.model_validate(data | {"k_v": float(k)})
                b = copy.copy(built)
                b.case = with_k_v(case, scheme, k)
                scheme_validate(scheme, getattr(b.case.schemes, scheme), b.case)
                make_controller(b, scheme, checked=False)
            except ValidationError as exc:
                answers[k] = f"its table: {' '.join(str(exc.errors()[0].get('msg', exc)).split())}"
            except FieldError as exc:  # its validate hook's refusal of the table
                answers[k] = f"its validate: {exc.loc}: {exc.msg}"
            except FtcError as exc:
                answers[k] = str(exc)
        return answers[k]

    return refuses


def _built_in(scheme: str) -> bool:
    """Whether ``scheme`` is one of ftcreport's own laws (schemes.registry)."""
    from ..schemes import get
    from ..schemes.registry import is_built_in

    return is_built_in(get(scheme))


def _blocks_at_gain(case, scheme, built, fz, psi, t, k, period, base: Blocks) -> Blocks:
    """The loop linearized with velocity gain k, in the coordinates of ``base`` (the same point's blocks)."""
    lp = SchemeLoop(case, scheme, built, k_v=k)
    return lp.blocks(lp.point(t, fz, psi, None, None, period), period, basis=base.basis)


_MODES = {1: "open", 2: "short", 3: "stuck"}


def _motor_words(table: np.ndarray, names) -> list[str]:
    """The motor faults of a table in words, wheel by wheel (healthy wheels left out)."""
    out = []
    for j, (km, ra, mode, vs) in enumerate(np.asarray(table, dtype=float)):
        bits = []
        if int(mode) in _MODES:
            bits.append(_MODES[int(mode)] + (f" at {vs:g} V" if int(mode) == 3 else ""))
        if km != 1.0:
            bits.append(f"k_m x{km:g}")
        if ra != 1.0:
            bits.append(f"R_a x{ra:g}")
        if bits:
            out.append(f"{names[j]}: " + ", ".join(bits))
    return out
