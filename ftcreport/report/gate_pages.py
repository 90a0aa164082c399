"""The gate's page parts (issue 35 items 10, 11): the case page's requirements section and the baseline page.

* :func:`requirements_section` builds what ``templates/_requirements.html`` shows: a row per
  requirement x scheme x window (outcome, first violation, worst value) and, per requirement, a
  figure of its signal per scheme with every window shaded, the bound drawn over each window and
  the first violation of each scheme marked (time and value from every step, ftcreport.requirements);
* :func:`render_baseline` writes ``OUT/baseline.html`` (``templates/baseline.html``): per case and
  scheme the comparison with the baseline (ftcreport.baseline), which fields of the case changed
  since it was saved, the metrics beyond tolerance, and for each signal outside its band a figure
  overlaying the baseline's band and the new signal.

Figures are plotly specs drawn like the other figures of the pages (``div.plotly-fig`` with a JSON
spec beside it); the signal curves are min-max decimated (:func:`ftcreport.report.interactive.decimate`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..model import wheel_index
from ..requirements import SIGNALS, applies_to, signal_values
from . import interactive
from .plots import SCHEME_COLORS

__all__ = ["MAX_BASELINE_FIGURES", "render_baseline", "requirement_figure", "requirements_section"]

MAX_BASELINE_FIGURES = 40  # per baseline page; the table lists every difference
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
    from ..requirements import signal_label

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
def _zoom(mid: np.ndarray, out: np.ndarray, e: np.ndarray) -> list[float]:
    """An x-range around the intervals outside the band (at least 10 intervals wide)."""
    k = np.flatnonzero(out)
    if k.size == 0:
        return [float(e[0]), float(e[-1])]
    a, b = float(e[k[0]]), float(e[k[-1] + 1])
    pad = max(5 * float(e[1] - e[0]), 0.1 * (b - a))
    return [max(float(e[0]), a - pad), min(float(e[-1]), b + pad)]


def _yrange(xr: list[float], mid: np.ndarray, *ys: np.ndarray) -> list[float] | None:
    m = (mid >= xr[0]) & (mid <= xr[1])
    vals = np.concatenate([np.asarray(y, float)[m] for y in ys]) if m.any() else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return None
    lo, hi = float(vals.min()), float(vals.max())
    pad = 0.08 * (hi - lo) or 0.1 * max(abs(hi), 1e-12)
    return [lo - pad, hi + pad]


def _band_figure(case: str, scheme: str, sig: str, unit: str, drawn: dict, new_t, new_y) -> dict:
    """Two panels, as the Simulation Data Inspector's comparison: above, the baseline's tolerance band
    (shaded), its envelope and the new run, the intervals outside the band circled; below, the
    difference new - baseline per interval (of the maxima and of the minima) against the tolerance.
    The x-axis opens on the intervals that differ (double-click: the whole run)."""
    e = np.asarray(drawn["edges"], float)
    mid = 0.5 * (e[:-1] + e[1:])
    x = interactive._r(mid, 6)
    with np.errstate(invalid="ignore"):
        above = drawn["new_hi"] > drawn["upper"]
        below = drawn["new_lo"] < drawn["lower"]
    out = above | below
    grey = "rgba(90,90,90,0.9)"

    def line(y, name, **kw) -> dict:
        return {"x": x, "y": interactive._r(y, 6), "name": name, "type": "scatter", "mode": "lines", **kw}

    data = [
        line(drawn["upper"], "band", line={"width": 0}, legendgroup="band", showlegend=False, hoverinfo="skip"),
        line(drawn["lower"], "baseline's tolerance band", line={"width": 0}, fill="tonexty",
             fillcolor="rgba(120,120,120,0.25)", legendgroup="band", hoverinfo="skip"),
        line(drawn["base_hi"], "baseline (max and min per interval)", line={"color": grey, "width": 1},
             legendgroup="base", hovertemplate=f"baseline max %{{y:.4g}} {unit}<extra></extra>"),
        line(drawn["base_lo"], "baseline min", line={"color": grey, "width": 1}, legendgroup="base",
             showlegend=False, hovertemplate=f"baseline min %{{y:.4g}} {unit}<extra></extra>"),
    ]  # fmt: skip
    color = SCHEME_COLORS.get(scheme, "#1f77b4")
    if new_y is not None:
        t, y = interactive.decimate(np.asarray(new_t, float), new_y)
        data.append(interactive._trace(t, interactive._r(y, 6), "new run", f"new %{{y:.4g}} {unit}",
                                       line={"color": color, "width": 1.3}))  # fmt: skip
    k = np.flatnonzero(out)
    data.append(
        {
            "x": interactive._r(mid[k], 6),
            "y": interactive._r(np.where(above[k], drawn["new_hi"][k], drawn["new_lo"][k]), 6),
            "name": "outside the band",
            "type": "scatter",
            "mode": "markers",
            "marker": {"symbol": "circle-open", "size": 9, "color": "#b00020", "line": {"width": 2}},
            "hovertemplate": f"outside: %{{y:.4g}} {unit} at %{{x:.4g}} s<extra></extra>",
        }
    )
    d_hi, d_lo = drawn["new_hi"] - drawn["base_hi"], drawn["new_lo"] - drawn["base_lo"]
    tol_hi, tol_lo = drawn["upper"] - drawn["base_hi"], drawn["lower"] - drawn["base_lo"]
    below_axis = {"xaxis": "x", "yaxis": "y2"}
    data += [
        line(d_hi, "new - baseline (maxima)", line={"color": color, "width": 1.2}, **below_axis,
             hovertemplate=f"difference of the maxima %{{y:.3g}} {unit}<extra></extra>"),
        line(d_lo, "new - baseline (minima)", line={"color": color, "width": 1.2, "dash": "dot"}, **below_axis,
             hovertemplate=f"difference of the minima %{{y:.3g}} {unit}<extra></extra>"),
        line(tol_hi, "tolerance", line={"color": "#b00020", "width": 1, "dash": "dash"}, **below_axis,
             legendgroup="tol", hovertemplate=f"tolerance +%{{y:.3g}} {unit}<extra></extra>"),
        line(tol_lo, "-tolerance", line={"color": "#b00020", "width": 1, "dash": "dash"}, **below_axis,
             legendgroup="tol", showlegend=False, hovertemplate=f"tolerance %{{y:.3g}} {unit}<extra></extra>"),
    ]  # fmt: skip
    xr = _zoom(mid, out, e)
    top = _yrange(xr, mid, drawn["upper"], drawn["lower"], drawn["new_hi"], drawn["new_lo"])
    bottom = _yrange(xr, mid, d_hi, d_lo, tol_hi, tol_lo)
    layout = {
        "title": {"text": f"{case} / {scheme} / {sig}: against the baseline", "font": {"size": 13}},
        "height": 460,
        "margin": {"l": 70, "r": 20, "t": 40, "b": 40},
        "hovermode": "closest",
        "xaxis": {"title": {"text": "t [s]"}, "range": xr, "anchor": "y2"},
        "yaxis": {"title": {"text": f"{sig} [{unit}]"}, "domain": [0.42, 1], **({"range": top} if top else {})},
        "yaxis2": {
            "title": {"text": f"difference [{unit}]"},
            "domain": [0, 0.32],
            **({"range": bottom} if bottom else {}),
        },
        "legend": {"orientation": "h", "y": -0.16},
    }
    return {"data": data, "layout": layout}


def render_baseline(out: Path, dest: Path, comparisons: list) -> Path:
    """Write ``OUT/baseline.html``: every case x scheme against the baseline in ``dest``."""
    from ..baseline import key_signals
    from ..model.faults import wheel_names
    from ..store import load_timeseries, read_json
    from .render import write_page

    out = Path(out)
    rows, cases, figures = [], [], []
    for cmp in comparisons:
        entry = {"case": cmp.case, "missing": cmp.missing, "changed": cmp.changed, "schemes": []}
        for sc in cmp.schemes:
            status = "missing" if sc.missing else ("pass" if sc.ok else "FAIL")
            changes = [d for d in sc.metrics if not d.ok]
            entry["schemes"].append(
                {
                    "scheme": sc.scheme,
                    "status": status,
                    "missing": sc.missing,
                    "run_status": sc.status,
                    "metrics": [
                        {"metric": d.metric, "old": d.old, "new": d.new, "delta": d.delta, "tol": d.tol, "ok": d.ok}
                        for d in sc.metrics
                    ],
                    "changes": len(changes) + len(sc.signals) + int(sc.status[0] != sc.status[1]),
                    "signals": [d.line() for d in sc.signals],
                    "signals_compared": sc.signals_compared,
                }
            )
            rows.append((cmp.case, sc.scheme, status))
            if not sc.drawn:
                continue
            ts = load_timeseries(out, cmp.case, sc.scheme)
            n = (read_json(out / cmp.case / "case.json") or {}).get("n")
            new = key_signals(ts, list(wheel_names(int(n)))) if ts is not None and n else {}
            for sig, drawn in sc.drawn.items():
                if len(figures) >= MAX_BASELINE_FIGURES:
                    break
                unit = next((d.unit for d in sc.signals if d.signal == sig), "")
                spec = _band_figure(
                    cmp.case, sc.scheme, sig, unit, drawn, ts["t"] if sig in new else None, new.get(sig)
                )
                figures.append(
                    {
                        "id": f"bl-{len(figures)}",
                        "plotly": spec,
                        "caption": f"{cmp.case} / {sc.scheme} / {sig}: the baseline's tolerance band (grey: "
                        "max(abs_tol, rel_tol |baseline|) around its minimum and maximum per interval, widened by the "
                        "time tolerances), the baseline's envelope (grey lines), the new run (colour) and the "
                        "intervals where it leaves the band (red circles).",
                    }
                )
        cases.append(entry)
    n_diff = sum(len(s.drawn) for c in comparisons for s in c.schemes)
    index = read_json(Path(dest) / "baseline.json") or {}
    interactive.ensure_plotly(out)
    return write_page(
        out / "baseline.html",
        "baseline.html",
        "",
        dest=str(dest),
        saved=index.get("cases", {}),
        cases=cases,
        figures=figures,
        n_pass=sum(r[2] == "pass" for r in rows),
        n_total=len(rows),
        n_diff=n_diff,
        max_figures=MAX_BASELINE_FIGURES,
        plotly_src=interactive.ASSET,
    )
