"""The analysis in words: the lines ``ftcreport analyze`` prints (pure).

:func:`text_summary` reads the dict of :func:`ftcreport.analysis.analyze_case`.  The verdict's sentences
citing the analysis (:func:`analysis_sentences`, :func:`verdict_sentence`) are the comparison's, in
:mod:`ftcreport.evaluation.verdict_analysis` (evaluation is below analysis); their names still import
from here.
"""

from __future__ import annotations

from ..evaluation.verdict_analysis import (
    MAX_SENTENCES,
    analysis_sentences,
    measure_text,
    phase_measure,
    verdict_sentence,
)
from .limits import limit_words

__all__ = ["MAX_SENTENCES", "analysis_sentences", "fmt_limit", "measure_text", "pattern_text", "text_summary"]
__all__ += ["healthy_words", "horizon_words", "unstable_faulty"]
__all__ += ["split_text", "verdict_sentence"]


def pattern_text(p) -> str:
    """A pattern as its wheel effectivenesses: '1 0 1 0.5' (None: '-')."""
    if p is None:
        return "-"
    return " ".join(f"{v:g}" for v in p)


def fmt_limit(value, unit: str, kind: str | None = None) -> str:
    """A limit, or what its null means (``limit_kinds``, :func:`ftcreport.analysis.limits.limit_words`)."""
    return limit_words(value, kind, unit)


def _limit(table: dict, kinds: dict, where: str, key: str, unit: str) -> str:
    """One limit of a scheme's table as the summary writes it, a null one by its kind: 'none up to 10 s
    (stable throughout)' is not 'none (unstable throughout)', 'none (the loop is marginal, not stable)' nor
    'not computed'."""
    return fmt_limit(table.get(key), unit, kinds.get(f"{where}.{key}"))


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
    if res.get("horizon"):
        lines.append(f"  {horizon_words(res['horizon'])}")
    for scheme, lim in res.get("limits", {}).items():
        vl = res.get("velocity_loop", {}).get(scheme, {})
        kinds = res.get("limit_kinds", {}).get(scheme, {})
        lines.append(
            f"  {scheme} (healthy pattern): largest stable sample time "
            f"{_limit(lim, kinds, 'limits', 'sample_time_max', 's')}, "
            f"largest stable k_v {_limit(lim, kinds, 'limits', 'k_v_max', '1/s')} (velocity loop alone: "
            f"{_limit(vl, kinds, 'velocity_loop', 'sample_time_max', 's')}, "
            f"{_limit(vl, kinds, 'velocity_loop', 'k_v_max', '1/s')})"
        )
        # limit / the case's setting, as on the case page (report.analysis_figs.limit_rows): "margin factors",
        # not "margins", which the phases' lines below use for the gain and phase margins (GM, PM)
        factors = []
        if res.get("sample_time") and lim.get("sample_time_max"):
            T = res["sample_time"]
            factors.append(f"T_s max / T_s {T * 1e3:g} ms = {lim['sample_time_max'] / T:.3g}")
        k_v = res.get("k_v", {}).get(scheme)
        if k_v and lim.get("k_v_max"):
            factors.append(f"k_v max / k_v {k_v:g} 1/s = {lim['k_v_max'] / k_v:.3g}")
        if factors:
            lines.append(f"      margin factors (limit / case value): {', '.join(factors)} (a factor above 1 is "
                         "room the case keeps; below 1 the case's own setting is beyond the limit)")  # fmt: skip
        for key, note in res.get("limit_notes", {}).get(scheme, {}).items():
            if key == "caveat":
                lines.append(f"      every limit: {note}")
                continue
            where, _, which = key.rpartition(".")
            lines.append(f"      {which}{' (velocity loop alone)' if where == 'velocity_loop' else ''}: {note}")
        for which, c in res.get("confirmation", {}).get(scheme, {}).items():
            lines.append(f"      {which}: {c['sentence']}")
        if faulty := unstable_faulty(res.get("phases", {}).get(scheme, [])):
            lines.append(f"      {healthy_words(faulty)}")
    for scheme, phases in res.get("phases", {}).items():
        lines.append(f"  {scheme}, per fault phase:")
        for p in phases:
            lines.append(
                f"    {p['t_start']:g}-{p['t_end']:g} s: true {pattern_text(p['pattern_true'])}, applied "
                f"{pattern_text(p.get('pattern_applied'))} ({p.get('applied_from', '-')}); {phase_measure(p)}, "
                f"{p.get('stability')}{_in_parentheses(split_text(p.get('frozen_disagree')))}{_worst_margin(p.get('margins'))}"
                + (f": {p.get('note')}" if p.get("stability") == "not computed" and p.get("note") else "")
            )
    for scheme, why in res.get("not_analyzed", {}).items():
        lines.append(f"  {scheme}: not analysed: {why}")
    worst = [r for r in res.get("controllability", []) if r["compensable_rule"]][-3:]
    if worst:
        of = res.get("classic_model", "")
        of = f", of {of.split(':')[0]}" if of.startswith("the ideal plant") else ""
        lines.append(f"  least well conditioned compensable patterns (Gramian min eigenvalue{of}):")
        for r in worst:
            lines.append(f"    {r['pattern']}: {r['gramian_min_eig']:.3g}")
    return lines


def unstable_faulty(phases: list[dict]) -> str:
    """The fault phases (a wheel's sigma not 1, friction, a motor fault) a scheme's loop is unstable in, '35-70 s,
    ...', or ''."""

    def faulty(p: dict) -> bool:
        return (
            any(v != 1 for v in p.get("pattern_true") or ())
            or any(p.get("friction_true") or ())
            or bool(p.get("motor_faults"))
        )

    bad = [p for p in phases if p.get("stability") == "unstable" and faulty(p)]
    return ", ".join(f"{p['t_start']:g}-{p['t_end']:g} s" for p in bad)


def healthy_words(faulty: str) -> str:
    """'the limits are the healthy loop's: its faulty phase(s) 30-60 s are unstable at the case's own setting'."""
    return f"the limits are the healthy loop's: its faulty phase(s) {faulty} are unstable at the case's own setting"


def horizon_words(h: dict) -> str:
    """'analysed up to t = 0.9708 s of 5 s: infeasible reference at t = 0.9708 s ...; a run stops there at the
    latest ...' (analysis.case.analysed_horizon)."""
    return (
        f"analysed up to t = {h['t_end']:.4g} s of {h['duration']:g} s: {h['reason']}; a run stops there at the "
        "latest (status error), and the fault phases after it are not analysed"
    )


def split_text(split: dict | None) -> str:
    """Where a phase's frozen instants disagree ("frozen instants disagree: unstable at 10 s, stable at 3.333,
    16.67 s"), or "" (the text summary and the page)."""
    if not split:
        return ""
    at = lambda ts: ", ".join(f"{t:.4g}" for t in ts)  # noqa: E731
    unstable, stable = at(split["unstable_at"]), at(split["stable_at"])
    return f"frozen instants disagree: unstable at {unstable} s, stable at {stable} s"


def _in_parentheses(text: str) -> str:
    return f" ({text})" if text else ""
