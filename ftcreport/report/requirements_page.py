"""The case page's requirements section (issue 35 item 11), rendered by ``templates/_requirements.html``.

:func:`requirements_section` builds a row per requirement x scheme (its windows' outcomes, the first
window that does not hold with its first violation, the extreme value) and, per requirement, a figure
(:func:`requirement_figure`) of its signal per scheme with every window shaded, the bound drawn over
each window and each scheme's first violation marked: its time and value come from every integration
step (ftcreport.evaluation.requirements, stored in metrics.json), the curves from the logged samples
(min-max decimated, :func:`ftcreport.report.interactive.decimate`).  Figures are plotly specs drawn like
the page's other figures (``div.plotly-fig`` with its JSON spec beside it).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..evaluation.requirements import SIGNALS, applies_to, signal_label, signal_values
from ..model import wheel_index
from . import interactive
from .plots import SCHEME_COLORS

__all__ = ["requirement_figure", "requirements_section"]

_LOG_SIGNALS = ("position_error", "heading_error", "torque_abs")
_WINDOW_FILL = "rgba(30,90,200,0.09)"
_BOUND_LINE = {"color": "rgba(176,0,32,0.85)", "width": 1.5, "dash": "dash"}


def _get(obj: Any, key: str, default: Any = None) -> Any:
    return obj.get(key, default) if isinstance(obj, dict) else getattr(obj, key, default)


def _finite(values) -> list[float]:
    return [float(v) for v in values if isinstance(v, int | float) and math.isfinite(v)]


def requirement_figure(
    req: Any, records: dict[str, list[dict]], series: dict[str, dict], wheels: list[str]
) -> dict | None:
    """The figure of one requirement: its signal per scheme (logged), windows shaded, bounds, first violations.

    ``records``: scheme -> the stored window records of this requirement; ``series``: scheme -> logged run.
    """
    sig, robot, wheel = _get(req, "signal"), _get(req, "robot"), _get(req, "wheel")
    unit = SIGNALS[sig][0]
    col = None if wheel is None else wheel_index(wheel, len(wheels) // 2)
    lo_b, hi_b = _get(req, "min"), _get(req, "max")
    log = sig in _LOG_SIGNALS and (lo_b is None or lo_b > 0) and (hi_b is None or hi_b > 0)
    data, inside, every = [], [], []
    wins = next((r for r in records.values() if r), [])
    for scheme, recs in records.items():
        ts = series.get(scheme)
        if ts is None or "q" not in ts or (sig.startswith("torque") and "tau" not in ts):
            continue
        y = signal_values(sig, ts, robot, col)
        t = np.asarray(ts["t"], float)
        for w in wins:
            if w.get("start") is not None and w.get("end") is not None:
                m = (t >= w["start"]) & (t <= w["end"])
                inside += _finite(y[m])
        every += _finite(y)
        tt, yy = interactive.decimate(t, np.maximum(y, 1e-12) if log else y)
        c = SCHEME_COLORS.get(scheme)
        hover = f"%{{y:.4g}} {unit}"
        data.append(interactive._trace(tt, interactive._r(yy, 6), scheme, hover, line={"color": c, "width": 1.2}))
        first = [r["first_violation"] for r in recs if r.get("first_violation")]
        if first:
            data.append(
                {
                    "x": [f["time"] for f in first],
                    "y": [f["value"] for f in first],
                    "name": f"{scheme}: first violation",
                    "type": "scatter",
                    "mode": "markers",
                    "marker": {"symbol": "x-thin-open", "size": 13, "color": c or "#b00020", "line": {"width": 2.5}},
                    "hovertemplate": f"{scheme}: first violation at %{{x:.6g}} s: %{{y:.4g}} {unit}<extra></extra>",
                }
            )
            inside += [f["value"] for f in first]
    if not data:
        return None
    shapes = []
    for w in wins:
        if w.get("start") is None or w.get("end") is None or w["start"] >= w["end"]:
            continue
        span = {"xref": "x", "x0": w["start"], "x1": w["end"]}
        shapes.append({"type": "rect", **span, "yref": "paper", "y0": 0, "y1": 1, "fillcolor": _WINDOW_FILL,
                       "line": {"width": 0}, "layer": "below"})  # fmt: skip
        for b in (lo_b, hi_b):
            if b is not None:
                shapes.append({"type": "line", **span, "yref": "y", "y0": b, "y1": b, "line": _BOUND_LINE})
    bounds = [b for b in (lo_b, hi_b) if b is not None]
    vals = _finite((inside or every) + bounds)  # the windows' samples set the scale (all of them if none)
    empty = [w for w in wins if w.get("outcome") == "not evaluated"]
    notes = []
    if empty and len(empty) == len(wins):
        notes.append({"text": f"not evaluated: {empty[0].get('reason', '')}", "xref": "paper", "yref": "paper",
                      "x": 0.5, "y": 0.95, "showarrow": False, "font": {"color": "#555", "size": 12}})  # fmt: skip
    yaxis: dict[str, Any] = {"title": {"text": f"{_label(req)} [{unit}]"}}
    if log:
        pos = [v for v in vals if v > 0] or [1e-12]
        yaxis |= {"type": "log", "range": [math.log10(min(pos)) - 0.3, math.log10(max(pos)) + 0.3]}
    elif vals:
        lo, hi = min(vals), max(vals)
        pad = 0.1 * (hi - lo) or 0.1 * max(abs(hi), 1e-9)
        yaxis["range"] = [lo - pad, hi + pad]
    t_end = max(float(np.asarray(series[s]["t"])[-1]) for s in records if s in series)
    layout = {
        "title": {
            "text": f"requirement {_get(req, 'id')}: {_label(req)} {wins[0].get('bound', '') if wins else ''}",
            "font": {"size": 13},
        },
        "height": 340,
        "margin": {"l": 60, "r": 20, "t": 40, "b": 40},
        "hovermode": "closest",
        "xaxis": {"title": {"text": "t [s]"}, "range": [0, t_end]},
        "yaxis": yaxis,
        "shapes": shapes,
        "annotations": notes,
        "legend": {"orientation": "h", "y": -0.2},
    }
    return {"data": data, "layout": layout}


def _label(req: Any) -> str:
    return signal_label(req)


def requirements_section(case, runs: list[dict], series: dict[str, dict]) -> dict | None:
    """What the case page's requirements section shows (None when the case states none).

    ``groups``: one per requirement x scheme, its windows' outcomes summed up (the first window that
    does not hold named, with its first violation) and each window's row kept for a folded list;
    ``figures``: one per requirement (:func:`requirement_figure`).
    """
    from ..model.faults import wheel_names

    reqs = list(case.requirements)
    if not reqs:
        return None
    by_scheme = {m["scheme"]: m for m in runs}
    groups, figures = [], []
    wheels = list(wheel_names(case.robots.n))
    for req in reqs:
        records: dict[str, list[dict]] = {}
        for scheme, m in by_scheme.items():
            if not applies_to(req, scheme):
                continue
            recs = [r for r in (m.get("requirements") or []) if r.get("id") == req.id]
            records[scheme] = recs
            if not recs:
                why = f"no result stored (run {m.get('status')}: {m.get('reason') or 'no reason given'})"
                recs = [{"window_label": "-", "outcome": "not evaluated", "reason": why}]
            groups.append(_group(req, scheme, recs))
        spec = requirement_figure(req, records, series, wheels) if series else None
        if spec is not None:
            cap = (
                f"Requirement {req.id}: {_label(req)} per scheme; shaded: its windows; dashed: the bound over each "
                "window; x: each scheme's first violation (time and value from every integration step; the curves "
                "are the logged samples)."
            )
            figures.append({"id": f"req-{req.id}", "plotly": spec, "caption": cap})
    held = sum(g["held"] for g in groups)
    return {"groups": groups, "figures": figures, "held": held, "total": sum(g["total"] for g in groups)}


def _group(req, scheme: str, recs: list[dict]) -> dict:
    """One requirement x scheme: its windows, how many hold, the first that does not, the extreme value."""
    windows = [
        {
            "window": r.get("window_label", "-"),
            "outcome": r.get("outcome", "not evaluated"),
            "reason": r.get("reason", ""),
        }
        for r in recs
    ]
    bad = next((r for r in recs if r.get("outcome") != "holds"), None)
    outcome = "violated" if any(r.get("outcome") == "violated" for r in recs) else (bad or recs[0]).get("outcome")
    key = "value_max" if req.max is not None else "value_min"
    vals = [r for r in recs if r.get(key) is not None]
    pick = max if req.max is not None else min
    extreme = pick(vals, key=lambda r: r[key]) if vals else None
    return {
        "id": req.id,
        "description": req.description,
        "scheme": scheme,
        "signal": recs[0].get("label") or _label(req),
        "bound": recs[0].get("bound", ""),
        "unit": recs[0].get("unit", ""),
        "held": sum(r.get("outcome") == "holds" for r in recs),
        "total": len(recs),
        "outcome": outcome,
        "bad": None if bad is None else {"window": bad.get("window_label"), "reason": bad.get("reason", "")},
        "first": None if bad is None else bad.get("first_violation"),
        "extreme": None if extreme is None else {"value": extreme[key], "time": extreme["t_" + key]},
        "windows": windows,
    }


# ------------------------------------------------------------------------------------- baseline
