"""The verdict's sentences citing the linearized analysis (issue 37 item 7; pure).

:func:`analysis_sentences` is what the comparison's verdict (:mod:`ftcreport.evaluation.compare`) says of
the analysis where a scheme loses or chatters, or nominal wins; :func:`verdict_sentence` is its one
sentence for a scheme.  Both read the dict of :func:`ftcreport.analysis.analyze_case`.  The analysis's
terminal lines (:mod:`ftcreport.analysis.summary`) write a phase's measure with the same words
(:func:`measure_text`, :func:`phase_measure`).
"""

from __future__ import annotations

import math

__all__ = [
    "MAX_SENTENCES",
    "SLOW_GROWTH",
    "analysis_sentences",
    "every_loop_unstable",
    "growth",
    "limit_words",
    "measure_text",
    "phase_measure",
    "verdict_sentence",
]

#: at most this many sentences of the analysis in a verdict
MAX_SENTENCES = 3


def measure_text(v: float | None, discrete: bool) -> str:
    """A spectral radius or a largest real part as text, its distance from the boundary kept: a radius of
    1.00003 reads "1 + 3e-05", not "1" beside "unstable"."""
    if v is None:
        return "-"
    edge = 1.0 if discrete else 0.0
    d = v - edge
    if discrete and d != 0.0 and abs(d) < 1e-3:
        return f"1 {'+' if d > 0 else '-'} {abs(d):.2g}"
    return f"{v:.4g}"


def phase_measure(p: dict, up_to: bool = False) -> str:
    """A fault phase's measure: its spectral radius (sampled loop) or its largest real part; ``up_to``: the
    largest of several phases' ("spectral radius up to 10.66")."""
    more = " up to" if up_to else ""
    if p.get("discrete"):
        return f"spectral radius{more} {measure_text(p.get('spectral_radius'), True)}"
    v = p.get("max_real_part")
    return "max Re -" if v is None else f"max Re{more} {v:.4g} 1/s"


def verdict_sentence(scheme: str, analysis: dict, why: str, limit: str | None = None) -> str | None:
    """One sentence citing the analysis for ``scheme`` in a verdict (issue 37 item 7), or None.

    ``why``: "loses" (ranked below the winners), "chatters" (its loop is predicted unstable in some
    phase, yet its run completed) or "nominal wins" (the healthy law's loop stays stable under the
    faults).  The sentence names the phase, the spectral radius or the slowest pole, and the limit when
    the case's setting is beyond it.  ``limit``: what bounds the wheels' inputs in the case, in words
    ("the drive's voltage limit", "the saturation at 50 N m"), or None for ideal torques: only a case
    with a limit is said to chatter at it.
    """
    phases = (analysis or {}).get("phases", {}).get(scheme)
    if not phases:
        return None
    done = [p for p in phases if p.get("stability") in ("stable", "marginal", "unstable")]
    if not done:
        return None
    # a phase whose frozen instants disagree supports no claim of "stable in every phase"
    unsure = any(p.get("stability") == "inconclusive" for p in phases)
    lim = (analysis.get("limits") or {}).get(scheme, {})
    bad = [p for p in done if p["stability"] != "stable"]
    span = lambda p: f"{p['t_start']:g}-{p['t_end']:g} s"  # noqa: E731
    if why == "nominal wins":
        if bad or unsure:
            return None
        slow = max(done, key=lambda p: p.get("max_real_part", p.get("spectral_radius", -math.inf)) or -math.inf)
        return (
            f"The analysis agrees: the healthy law's loop stays stable in every fault phase (slowest at "
            f"{span(slow)}, {phase_measure(slow)}), so the faults only cost it the torque it cannot redistribute."
        )
    if bad:
        p = max(bad, key=lambda p: p.get("spectral_radius") or p.get("max_real_part") or 0.0)
        every = len(done) > 1 and all(q["stability"] == p["stability"] for q in done)
        # in every phase: the largest measure, not which phase has it (the schemes of one verdict that differ
        # only in that read as one sentence; round-off picked the phase when the radii agree to the digits shown)
        where = "in every fault phase (" if every else f"in the phase {span(p)} ("
        text = f"The analysis predicts {scheme}'s loop {p['stability']} {where}{phase_measure(p, every)}"
        T, tmax = analysis.get("sample_time"), lim.get("sample_time_max")
        if p.get("discrete") and T and tmax and tmax < T:
            text += f"; its sample time {T * 1e3:g} ms is beyond its limit {tmax * 1e3:.3g} ms"
        kmax = lim.get("k_v_max")
        k_v = analysis.get("k_v", {}).get(scheme)
        if kmax and k_v and k_v > kmax:
            text += f"; k_v = {k_v:g} 1/s is beyond its largest stable {kmax:.3g} 1/s"
        return text + ")" + (_completed(limit, p, analysis) if why == "chatters" else ".")
    if why == "loses" and not unsure:
        slow = max(done, key=lambda p: p.get("spectral_radius") or p.get("max_real_part") or -math.inf)
        return (
            f"Its loop is stable in every phase (slowest at {span(slow)}, {phase_measure(slow)}): {scheme} loses on "
            "what it applies, not on stability."
        )
    return None


#: a predicted growth below this factor over its phase is "too slow to show in the run" (less than doubling)
SLOW_GROWTH = 2.0


def growth(p: dict, T: float | None) -> tuple[float, float] | None:
    """(the factor by which the phase's unstable mode grows over the phase, its e-folding time [s]) from the
    spectral radius rho per sample T (rate ln(rho) / T) or the largest real part; None when not growing."""
    if p.get("discrete"):
        rho = p.get("spectral_radius")
        if not rho or rho <= 1.0 or not T:
            return None
        rate = math.log(rho) / T
    else:
        rate = p.get("max_real_part")
        if rate is None or rate <= 0.0:
            return None
    span = max(float(p["t_end"]) - float(p["t_start"]), 0.0)
    return math.exp(min(rate * span, 700.0)), 1.0 / rate


def _seconds(v: float) -> str:
    return f"{v:,.0f}" if v >= 1000 else f"{v:.3g}"


def _completed(limit: str | None, p: dict, analysis: dict) -> str:
    """Why a loop predicted unstable completed its run, true of the case at hand: a sampled loop with a
    limit chatters at it, a continuous one is held by it.  With ideal torques nothing bounds the wheels, so
    the sentence gives the predicted growth over the phase and its e-folding time (session 12's new user:
    "the case applies ideal torques" explained nothing): below SLOW_GROWTH it is too slow to show in the
    run; above it the run and the frozen linearization disagree, which the sentence says."""
    discrete = bool(p.get("discrete"))
    if limit is not None:
        if discrete:
            return f": the wheels chatter at {limit}."
        return f": its run completed, the wheels' inputs held by {limit}."
    g = growth(p, (p.get("sample_time") or analysis.get("sample_time")) if discrete else None)
    if g is None:
        return ": its run completed all the same (ideal torques: no drive limit or saturation bounds it)."
    factor, efold = g
    span = float(p["t_end"]) - float(p["t_start"])
    by = f"a factor {factor:.3g} over the phase's {span:g} s (e-folding in {_seconds(efold)} s)"
    if factor < SLOW_GROWTH:
        return f": its predicted growth is slow, {by}, too little to show in the run."
    caveat = (
        "frozen-instant poles are evidence, not proof, on this time-varying loop"
        if analysis.get("time_varying")
        else "the linearization and the run disagree here"
    )
    return f": its run completed all the same, though the linearization grows by {by}; {caveat}."


def limit_words(case) -> str | None:
    """What bounds the wheels' inputs of a case, in words for :func:`verdict_sentence`, or None."""
    if getattr(case, "actuators", None) is not None:
        return "the drive's voltage limit"
    sat = getattr(getattr(case, "plant", None), "saturation", None)
    return None if sat is None else f"the saturation at {sat:g} N m"


def every_loop_unstable(analysis: dict, schemes: list[str]) -> bool:
    """Whether the analysis predicts each of ``schemes``' loops unstable in some fault phase (a scheme it did not
    analyse counts as not predicted unstable)."""
    phases = (analysis or {}).get("phases") or {}
    return all(any(p.get("stability") == "unstable" for p in phases.get(s) or []) for s in schemes)


def analysis_sentences(
    analysis: dict, ranking: list[str], winners: list[str], stopped: list[str], limit: str | None = None
) -> list[str]:
    """The verdict's sentences citing the analysis (issue 37 item 7), at most :data:`MAX_SENTENCES`.

    ``ranking``: the schemes ranked on the largest error after the faults, best first; ``winners`` its
    winners; ``stopped``: the schemes whose run did not complete.  In this order: a scheme whose loop the
    analysis predicts unstable in a phase (it "chatters" when its run completed: a sampled loop beyond
    its limit runs on at the drive's limit, where the case has one), nominal among the winners with its
    loop stable in every phase, and the last-ranked FTC scheme (it "loses") when its loop is stable.
    ``limit``: what bounds the wheels' inputs (:func:`limit_words`), None for ideal torques.
    """
    if not analysis or not analysis.get("phases"):
        return []
    out: list[str] = []
    cited: set[str] = set()
    same: dict[str, list[str]] = {}  # one sentence for the schemes the analysis says the same of
    for scheme in [*ranking, *stopped]:
        phases = analysis["phases"].get(scheme) or []
        if scheme in cited or not any(p.get("stability") == "unstable" for p in phases):
            continue
        why = "loses" if scheme in stopped else "chatters"
        line = verdict_sentence(scheme, analysis, why, limit)
        if line:
            same.setdefault(line.replace(f"predicts {scheme}'s loop ", "predicts {who} "), []).append(scheme)
            cited.add(scheme)
    for template, schemes in same.items():
        who = f"{schemes[0]}'s loop"
        if len(schemes) > 1:
            who = f"the loops of {', '.join(schemes[:-1])} and {schemes[-1]}"
            template = template.replace("its sample time", "the case's sample time")
            template = template.replace("beyond its", "beyond their")
        out.append(template.replace("{who}", who))
    if "nominal" in winners and "nominal" not in cited:
        line = verdict_sentence("nominal", analysis, "nominal wins")
        if line:
            out.append(line)
            cited.add("nominal")
    contestants = [s for s in ranking if s not in ("nominal", "oracle")]
    if contestants and contestants[-1] not in cited and contestants[-1] not in winners:
        line = verdict_sentence(contestants[-1], analysis, "loses")
        if line:
            out.append(line)
    return out[:MAX_SENTENCES]
