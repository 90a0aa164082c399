"""The baseline page (issue 35 item 10): ``OUT/baseline.html`` from ``templates/baseline.html``.

:func:`render_baseline` shows every case x scheme against the baseline (ftcreport.studies.baseline): which
fields of the case changed since it was saved, the metrics with their deltas and tolerances, and for
each signal outside its band a figure as the Simulation Data Inspector draws a comparison: the
baseline's tolerance band, its envelope and the new run above, their difference against the
tolerance below, opening on the intervals that differ.

The index links the page only while it compares the runs stored in OUT (:func:`stale_reason`): it records
their seals beside it, in :data:`STAMP`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import interactive
from .baseline_stamp import PAGE, STAMP, compared_runs
from .plots import SCHEME_COLORS
from .render import write_page

__all__ = ["MAX_BASELINE_FIGURES", "render_baseline"]


MAX_BASELINE_FIGURES = 40  # per baseline page; the tables name every difference
#: signals drawn on a log axis when their positive values span more than LOG_DECADES decades
LOG_FAMILIES = ("position_error", "heading_error")
LOG_DECADES = 2.0


def _zoom(mid: np.ndarray, out: np.ndarray, e: np.ndarray) -> list[float]:
    """An x-range around the intervals outside the band (at least 10 intervals wide)."""
    k = np.flatnonzero(out)
    if k.size == 0:
        return [float(e[0]), float(e[-1])]
    a, b = float(e[k[0]]), float(e[k[-1] + 1])
    pad = max(5 * float(e[1] - e[0]), 0.1 * (b - a))
    return [max(float(e[0]), a - pad), min(float(e[-1]), b + pad)]


def _shown(xr: list[float], mid: np.ndarray, scale_from: float | None, *ys: np.ndarray) -> np.ndarray:
    """The intervals that set an axis: those in the x-range from ``scale_from`` on, so the start-up
    transient is drawn but does not set the axis; all in the x-range when none is after it or the values
    of ``ys`` there are all one value (a failed wheel's zero torque)."""
    m = (mid >= xr[0]) & (mid <= xr[1])
    if scale_from is None:
        return m
    later = m & (mid >= scale_from)
    vals = _values(later, ys)
    return later if vals.size and np.ptp(vals) > 0 else m


def _values(m: np.ndarray, ys) -> np.ndarray:
    vals = np.concatenate([np.asarray(y, float)[m] for y in ys]) if m.any() else np.zeros(0)
    return vals[np.isfinite(vals)]


def _yrange(m: np.ndarray, *ys: np.ndarray) -> list[float] | None:
    vals = _values(m, ys)
    if vals.size == 0:
        return None
    lo, hi = float(vals.min()), float(vals.max())
    pad = 0.08 * (hi - lo) or 0.1 * max(abs(hi), 1e-12)
    return [lo - pad, hi + pad]


def _log_range(m: np.ndarray, *ys: np.ndarray) -> list[float] | None:
    """A log axis's range (log10 units) over the positive values, or None when they span under
    :data:`LOG_DECADES` decades (a linear axis reads them better)."""
    vals = _values(m, ys)
    vals = vals[vals > 0]
    if vals.size == 0:
        return None
    a, b = np.log10(vals.min()), np.log10(vals.max())
    if b - a < LOG_DECADES:
        return None
    pad = 0.04 * (b - a)
    return [float(a - pad), float(b + pad)]


def _band_figure(
    case: str, scheme: str, sig: str, unit: str, drawn: dict, new_t, new_y, scale_from: float | None = None
) -> dict:
    """Two panels, as the Simulation Data Inspector's comparison: above, the baseline's tolerance band
    (shaded), its envelope and the new run, the intervals outside the band circled; below, the
    difference new - baseline per interval (of the maxima and of the minima) against the tolerance.
    The x-axis opens on the intervals that differ (double-click: the whole run).  The y-axes take their
    scale from ``scale_from`` on (past the start-up transient, which is drawn and may run off the axis), as
    the case page's figures; an error whose values span decades (:data:`LOG_FAMILIES`) is on a
    log axis over the whole x-range instead."""
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
    tops = (drawn["upper"], drawn["lower"], drawn["new_hi"], drawn["new_lo"])
    log = _log_range(_shown(xr, mid, None), *tops) if sig.split("[", 1)[0] in LOG_FAMILIES else None
    top = log or _yrange(_shown(xr, mid, scale_from, *tops), *tops)
    bottoms = (d_hi, d_lo, tol_hi, tol_lo)
    bottom = _yrange(_shown(xr, mid, scale_from, *bottoms), *bottoms)
    layout = {
        "title": {"text": f"{case} / {scheme} / {sig}: against the baseline", "font": {"size": 13}},
        "height": 460,
        "margin": {"l": 70, "r": 20, "t": 40, "b": 40},
        "hovermode": "closest",
        "xaxis": {"title": {"text": "t [s]"}, "range": xr, "anchor": "y2"},
        "yaxis": {
            "title": {"text": f"{sig} [{unit}]" + (" (log)" if log else "")},
            "domain": [0.42, 1],
            "type": "log" if log else "linear",
            **({"range": top} if top else {}),
        },
        "yaxis2": {
            "title": {"text": f"difference [{unit}]"},
            "domain": [0, 0.32],
            **({"range": bottom} if bottom else {}),
        },
        "legend": {"orientation": "h", "y": -0.16},
    }
    return {"data": data, "layout": layout}


def _scale_from(ts) -> float | None:
    """Where a run's overlays take their y-scale from: 1 s after its start, past the start-up transient (the
    case page's figures scale from the first fault, but an overlay's x-range opens on the intervals that
    differ, which may end soon after a fault: a failed wheel's zero torque would set the axis)."""
    t = None if ts is None else np.asarray(ts.get("t"), float)
    return None if t is None or t.size < 2 else float(t[0]) + 1.0


def render_baseline(out: Path, dest: Path, comparisons: list) -> Path:
    """Write ``OUT/baseline.html``: every case x scheme against the baseline in ``dest``, and beside it
    :data:`STAMP`, the seals of the runs it compares (:func:`stale_reason`)."""
    from ..model.faults import wheel_names
    from ..storage.store import load_timeseries, read_json, write_atomic
    from ..studies.baseline import key_signals

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
            rec = read_json(out / cmp.case / "case.json") or {}
            n = rec.get("n")
            scale_from = _scale_from(ts)
            new = key_signals(ts, list(wheel_names(int(n)))) if ts is not None and n else {}
            for sig, drawn in sc.drawn.items():
                if len(figures) >= MAX_BASELINE_FIGURES:
                    break
                unit = next((d.unit for d in sc.signals if d.signal == sig), "")
                spec = _band_figure(
                    cmp.case, sc.scheme, sig, unit, drawn, ts["t"] if sig in new else None, new.get(sig), scale_from
                )
                figures.append(
                    {
                        "id": f"bl-{len(figures)}",
                        "plotly": spec,
                        "caption": f"{cmp.case} / {sc.scheme} / {sig}: the baseline's tolerance band (grey: "
                        "max(abs_tol, rel_tol |baseline|) around its minimum and maximum per interval, widened by the "
                        "time tolerances), the baseline's envelope (grey lines), the new run (colour) and the "
                        "intervals where it leaves the band (red circles). "
                        + (
                            f"The axes take their scale from t = {scale_from:g} s on: the start-up transient before "
                            "it is drawn but may run off the axis; "
                            if scale_from is not None
                            else ""
                        )
                        + "an error spanning decades is on a log axis.",
                    }
                )
        cases.append(entry)
    n_diff = sum(len(s.drawn) for c in comparisons for s in c.schemes)
    index = read_json(Path(dest) / "baseline.json") or {}
    (out / STAMP).unlink(missing_ok=True)  # no stamp of earlier runs beside a page being rewritten
    page = write_page(
        out / PAGE,
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
        plotly_inline=interactive.inline_plotly() if figures else None,
    )
    stamp = {"dest": str(dest), "runs": compared_runs(out, comparisons)}
    write_atomic(out / STAMP, json.dumps(stamp, indent=1, sort_keys=True).encode())
    return page
