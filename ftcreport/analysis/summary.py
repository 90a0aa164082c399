"""The analysis in words: the lines ``ftcreport analyze`` prints, and the verdict's sentence (pure).

:func:`text_summary` reads the dict of :func:`ftcreport.analysis.analyze_case`; :func:`verdict_sentence`
is the one sentence the comparison's verdict cites for a scheme (issue 37 item 7, called from
``ftcreport.evaluation.compare``).
"""

from __future__ import annotations

import math

__all__ = ["analysis_sentences", "fmt_limit", "pattern_text", "text_summary", "verdict_sentence"]

#: at most this many sentences of the analysis in a verdict
MAX_SENTENCES = 3


def pattern_text(p) -> str:
    """A pattern as its wheel effectivenesses: '1 0 1 0.5' (None: '-')."""
    if p is None:
        return "-"
    return " ".join(f"{v:g}" for v in p)


def fmt_limit(value, unit: str) -> str:
    if value is None:
        return "none"
    return f"{value * 1e3:.4g} ms" if unit == "s" else f"{value:.4g} 1/s"


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


def _measure(p: dict) -> str:
    if p.get("discrete"):
        return f"spectral radius {measure_text(p.get('spectral_radius'), True)}"
    v = p.get("max_real_part")
    return "max Re -" if v is None else f"max Re {v:.4g} 1/s"


def _worst_margin(m: dict | None) -> str:
    if not m or not m.get("loops"):
        return ""
    rows = [r for r in m["loops"] if r.get("stability_margin") is not None]
    if not rows:
        return ""
    r = min(rows, key=lambda r: r["stability_margin"])
    gm = "inf" if r.get("gain_margin_db") is None else f"{r['gain_margin_db']:.3g} dB"
    pm = "inf" if r.get("phase_margin_deg") is None else f"{r['phase_margin_deg']:.3g} deg"
    dm = "" if r.get("disk_margin") is None else f", disk {r['disk_margin']:.3g}"
    return f"; worst loop {r['input']}: GM {gm}, PM {pm}{dm}"


def text_summary(res: dict) -> list[str]:
    """The terminal lines of ``ftcreport analyze``."""
    lines = [f"{res['case']}: {res['n_robots']} robots, reference {res['reference_kind']}"]
    how = f"sampled at {res['sample_time'] * 1e3:g} ms (ZOH)" if res.get("sampled") else "continuous-time control"
    if res.get("measurement_delay"):
        how += f", measurements {res['measurement_delay']} sample(s) old"
    lines.append(f"  {how}; actuator inputs: {res.get('actuator_input', 'torque')}")
    if res.get("time_varying"):
        lines.append("  the loop is time-varying along this reference: frozen-instant poles are evidence, not proof")
    for scheme, lim in res.get("limits", {}).items():
        vl = res.get("velocity_loop", {}).get(scheme, {})
        lines.append(
            f"  {scheme}: largest stable sample time {fmt_limit(lim.get('sample_time_max'), 's')}, largest stable "
            f"k_v {fmt_limit(lim.get('k_v_max'), '1/s')} (velocity loop alone: "
            f"{fmt_limit(vl.get('sample_time_max'), 's')}, {fmt_limit(vl.get('k_v_max'), '1/s')})"
        )
        factors = []
        if res.get("sample_time") and lim.get("sample_time_max"):
            factors.append(f"T_s {res['sample_time'] * 1e3:g} ms = {res['sample_time'] / lim['sample_time_max']:.3g}x")
        k_v = res.get("k_v", {}).get(scheme)
        if k_v and lim.get("k_v_max"):
            factors.append(f"k_v {k_v:g} 1/s = {k_v / lim['k_v_max']:.3g}x")
        if factors:
            lines.append(f"      the case's own settings against these limits: {', '.join(factors)} (stable below 1x)")
        for key, note in res.get("limit_notes", {}).get(scheme, {}).items():
            where, _, which = key.rpartition(".")
            lines.append(f"      {which}{' (velocity loop alone)' if where == 'velocity_loop' else ''}: {note}")
        for which, c in res.get("confirmation", {}).get(scheme, {}).items():
            lines.append(f"      {which}: {c['sentence']}")
    for scheme, phases in res.get("phases", {}).items():
        lines.append(f"  {scheme}, per fault phase:")
        for p in phases:
            lines.append(
                f"    {p['t_start']:g}-{p['t_end']:g} s: true {pattern_text(p['pattern_true'])}, applied "
                f"{pattern_text(p.get('pattern_applied'))} ({p.get('applied_from', '-')}); {_measure(p)}, "
                f"{p.get('stability')}{_worst_margin(p.get('margins'))}"
            )
    for scheme, why in res.get("not_analyzed", {}).items():
        lines.append(f"  {scheme}: not analysed: {why}")
    worst = [r for r in res.get("controllability", []) if r["compensable_rule"]][-3:]
    if worst:
        lines.append("  least well conditioned compensable patterns (Gramian min eigenvalue):")
        for r in worst:
            lines.append(f"    {r['pattern']}: {r['gramian_min_eig']:.3g}")
    return lines


def verdict_sentence(scheme: str, analysis: dict, why: str) -> str | None:
    """One sentence citing the analysis for ``scheme`` in a verdict (issue 37 item 7), or None.

    ``why``: "loses" (ranked below the winners), "chatters" (its sampled loop is predicted unstable
    in some phase) or "nominal wins" (the healthy law's loop stays stable under the faults).  The
    sentence names the phase, the spectral radius or the slowest pole, and the limit when the case's
    setting is beyond it.
    """
    phases = (analysis or {}).get("phases", {}).get(scheme)
    if not phases:
        return None
    done = [p for p in phases if p.get("stability") in ("stable", "marginal", "unstable")]
    if not done:
        return None
    lim = (analysis.get("limits") or {}).get(scheme, {})
    bad = [p for p in done if p["stability"] != "stable"]
    span = lambda p: f"{p['t_start']:g}-{p['t_end']:g} s"  # noqa: E731
    if why == "nominal wins":
        if bad:
            return None
        slow = max(done, key=lambda p: p.get("max_real_part", p.get("spectral_radius", -math.inf)) or -math.inf)
        return (
            f"The analysis agrees: the healthy law's loop stays stable in every fault phase (slowest at "
            f"{span(slow)}, {_measure(slow)}), so the faults only cost it the torque it cannot redistribute."
        )
    if bad:
        p = max(bad, key=lambda p: p.get("spectral_radius") or p.get("max_real_part") or 0.0)
        every = len(done) > 1 and all(q["stability"] == p["stability"] for q in done)
        where = f"in every fault phase (worst {span(p)}, " if every else f"in the phase {span(p)} ("
        text = f"The analysis predicts {scheme}'s loop {p['stability']} {where}{_measure(p)}"
        T, tmax = analysis.get("sample_time"), lim.get("sample_time_max")
        if p.get("discrete") and T and tmax and tmax < T:
            text += f"; its sample time {T * 1e3:g} ms is beyond its limit {tmax * 1e3:.3g} ms"
        kmax = lim.get("k_v_max")
        k_v = analysis.get("k_v", {}).get(scheme)
        if kmax and k_v and k_v > kmax:
            text += f"; k_v = {k_v:g} 1/s is beyond its largest stable {kmax:.3g} 1/s"
        return text + ")" + (": the wheels chatter at the drive's limit." if why == "chatters" else ".")
    if why == "loses":
        slow = max(done, key=lambda p: p.get("spectral_radius") or p.get("max_real_part") or -math.inf)
        return (
            f"Its loop is stable in every phase (slowest at {span(slow)}, {_measure(slow)}): {scheme} loses on "
            "what it applies, not on stability."
        )
    return None


def analysis_sentences(analysis: dict, ranking: list[str], winners: list[str], stopped: list[str]) -> list[str]:
    """The verdict's sentences citing the analysis (issue 37 item 7), at most :data:`MAX_SENTENCES`.

    ``ranking``: the schemes ranked on the largest error after the faults, best first; ``winners`` its
    winners; ``stopped``: the schemes whose run did not complete.  In this order: a scheme whose loop the
    analysis predicts unstable in a phase (it "chatters" when its run completed: a sampled loop beyond
    its limit runs on at the drive's limit), nominal among the winners with its loop stable in every
    phase, and the last-ranked FTC scheme (it "loses") when its loop is stable.
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
        line = verdict_sentence(scheme, analysis, why)
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
