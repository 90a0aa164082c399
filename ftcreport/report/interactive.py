"""Interactive time-series figures (plotly.js figure specs as plain dicts; the page draws them).

Each function returns ``{"data": [...], "layout": {...}}`` ready for ``Plotly.newPlot``: tracking
errors, torques (a menu picks the scheme), the switching index against the true pattern, and the
estimates of the adaptive and active schemes against the truth.  Fault phases are shaded and the
events marked.  Series are decimated by keeping each bucket's minimum and maximum
(:func:`decimate`), so peaks survive and a page stays small; the page states the point budget.
plotly.js itself is one shared file (``reports/assets/plotly.min.js``, copied from the installed
``plotly`` package by :func:`ensure_plotly`), loaded by every page: nothing is fetched online.
"""

from __future__ import annotations

import itertools
import math
from importlib import resources
from pathlib import Path

import numpy as np

from ..control.kinematic import wrap
from ..store import write_atomic
from .plots import SCHEME_COLORS

__all__ = ["MAX_POINTS", "decimate", "ensure_plotly", "errors_fig", "estimates_fig", "switching_fig", "torques_fig"]

MAX_POINTS = 1500  # per trace, after decimation
ASSET = "assets/plotly.min.js"


def ensure_plotly(out: Path) -> Path:
    """Copy plotly.min.js from the installed package to ``out/assets`` (once; again if it changed)."""
    src = resources.files("plotly") / "package_data" / "plotly.min.js"
    data = src.read_bytes()
    dst = Path(out) / ASSET
    if not dst.exists() or dst.stat().st_size != len(data):
        write_atomic(dst, data)
    return dst


def decimate(t: np.ndarray, *ys: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, ...]:
    """Min-max decimation on a shared time axis: per bucket the samples where any series is at its
    minimum or maximum; at most about ``max_points`` samples, first and last kept."""
    t = np.asarray(t, float)
    if t.size <= max_points:
        return (t, *[np.asarray(y) for y in ys])
    nb = max(1, max_points // (2 * max(1, len(ys))))
    edges = np.linspace(0, t.size, nb + 1).astype(int)
    keep = {0, t.size - 1}
    for y in ys:
        y = np.asarray(y, float)
        if y.ndim == 1:
            y = y[:, None]
        for a, b in itertools.pairwise(edges):
            if b <= a:
                continue
            seg = y[a:b]
            finite = np.where(np.isfinite(seg), seg, 0.0)
            keep.update((a + finite.argmin(axis=0)).tolist())
            keep.update((a + finite.argmax(axis=0)).tolist())
    idx = np.array(sorted(keep))
    return (t[idx], *[np.asarray(y)[idx] for y in ys])


def _r(x: np.ndarray, digits: int = 4) -> list:
    """Round to significant digits for compact JSON (None for non-finite values)."""
    x = np.asarray(x, float)
    out = []
    for v in x.tolist():
        out.append(float(f"{v:.{digits}g}") if math.isfinite(v) else None)
    return out


def _phases(events: list[float], t_end: float) -> list[dict]:
    """Shaded fault phases (alternate phases after each event) and a dotted line per event."""
    shapes = []
    ev = sorted({float(e) for e in events if e > 0})
    for i, te in enumerate(ev):
        end = ev[i + 1] if i + 1 < len(ev) else t_end
        span = {"xref": "x", "yref": "paper", "x0": te, "y0": 0, "y1": 1}  # full height from the event on
        if i % 2 == 0:
            shade = {"fillcolor": "rgba(180,0,30,0.07)", "line": {"width": 0}, "layer": "below"}
            shapes.append({"type": "rect", **span, "x1": end, **shade})
        shapes.append(
            {"type": "line", **span, "x1": te, "line": {"color": "rgba(120,0,20,0.6)", "width": 1, "dash": "dot"}}
        )
    return shapes


def _layout(title: str, events: list[float], t_end: float, height: int = 360, **extra) -> dict:
    lay = {
        "title": {"text": title, "font": {"size": 13}},
        "height": height,
        "margin": {"l": 60, "r": 20, "t": 40, "b": 40},
        "hovermode": "x unified",
        "xaxis": {"title": {"text": "t [s]"}, "range": [0, t_end]},
        "shapes": _phases(events, t_end),
        "legend": {"orientation": "h", "y": -0.18},
    }
    lay.update(extra)
    return lay


def _trace(t: np.ndarray, y: list, name: str, hover: str, **extra) -> dict:
    """One line trace over time (``t`` rounded to 6 digits for compact JSON); ``extra``: its other keys."""
    return {"x": _r(t, 6), "y": y, "name": name, "type": "scatter", "mode": "lines", "hovertemplate": hover, **extra}


def _t_end(series: dict) -> float:
    return max(float(ts["t"][-1]) for ts in series.values())


def errors_fig(series: dict[str, dict], events: list[float]) -> dict:
    """Position error and largest heading error per scheme (log scale)."""
    data = []
    for scheme, ts in series.items():
        q, qd = ts["q"], ts["q_d"]
        pos = np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])
        head = np.abs(wrap(q[:, 2:] - qd[:, 2:])).max(axis=1)
        t, p, h = decimate(ts["t"], np.maximum(pos, 1e-12), np.maximum(head, 1e-9))
        c = SCHEME_COLORS.get(scheme)
        data.append(_trace(t, _r(p), scheme, "%{y:.3g} m", legendgroup=scheme, line={"color": c, "width": 1.3}))
        heading = {"legendgroup": scheme, "showlegend": False, "line": {"color": c, "width": 1.0}, "yaxis": "y2"}
        data.append(_trace(t, _r(h), scheme, "%{y:.3g} rad", **heading))
    lay = _layout(
        "tracking errors (shaded: fault phases; drag to zoom, double-click to reset)",
        events,
        _t_end(series),
        height=460,
        yaxis={"type": "log", "title": {"text": "position error [m]"}, "domain": [0.53, 1]},
        yaxis2={"type": "log", "title": {"text": "max heading error [rad]"}, "domain": [0, 0.45]},
    )
    return {"data": data, "layout": lay}


def torques_fig(series: dict[str, dict], wheels: list[str], events: list[float], main: str) -> dict:
    """Applied torques per wheel; a menu shows one scheme at a time (``main`` first)."""
    data, owner = [], []
    schemes = [s for s in series if "tau" in series[s]]
    for scheme in schemes:
        ts = series[scheme]
        tau = np.asarray(ts["tau"], float)
        t, *cols = decimate(
            ts["t"],
            *[tau[:, j] for j in range(tau.shape[1])],
            max_points=max(400, 4 * MAX_POINTS // max(1, len(wheels))),
        )
        for j, w in enumerate(wheels):
            data.append(_trace(t, _r(cols[j]), w, "%{y:.3g} N m", line={"width": 1}, visible=scheme == main))
            owner.append(scheme)
    buttons = [
        {
            "label": s,
            "method": "update",
            "args": [{"visible": [o == s for o in owner]}, {"title.text": f"applied wheel torques, {s}"}],
        }
        for s in schemes
    ]
    lay = _layout(
        f"applied wheel torques, {main}",
        events,
        _t_end(series),
        height=380,
        yaxis={"title": {"text": "tau [N m]"}},
        updatemenus=[
            {
                "buttons": buttons,
                "direction": "down",
                "x": 1.0,
                "xanchor": "right",
                "y": 1.18,
                "active": schemes.index(main) if main in schemes else 0,
            }
        ],
    )
    return {"data": data, "layout": lay}


def switching_fig(ts: dict, patterns: list[list[int]], events: list[float]) -> dict:
    """Applied model index against the index of the true pattern (-1 when it is not a model)."""
    pats = [tuple(p) for p in patterns]
    truth = np.array([pats.index(k) if (k := tuple((s >= 1.0).astype(int))) in pats else -1 for s in ts["sigma"]])
    t, sel, tr = decimate(ts["t"], np.asarray(ts["selected"], float), truth.astype(float))
    truth_line = {"shape": "hv", "color": "rgba(0,0,0,0.35)", "width": 4}  # wide and grey, under the model's
    model_line = {"shape": "hv", "color": SCHEME_COLORS["switching"], "width": 1.2}
    data = [
        _trace(t, tr.astype(int).tolist(), "true pattern", "true %{y}", line=truth_line),
        _trace(t, sel.astype(int).tolist(), "applied model", "model %{y}", line=model_line),
    ]
    lay = _layout(
        "switching: applied model against the true pattern (-1: the true pattern is not a model)",
        events,
        float(ts["t"][-1]),
        height=300,
        yaxis={"title": {"text": "model index"}},
    )
    return {"data": data, "layout": lay}


def estimates_fig(ts: dict, scheme: str, wheels: list[str], events: list[float], patterns=None) -> dict | None:
    """Estimates of one scheme against the truth (dashed).

    Active schemes: rho_hat and ubar_hat per wheel against sigma and ubar.  Adaptive schemes: the
    weights chihat_(k) (mean over the wheels each model drives) and uhat_f against ubar (control
    variables, not a diagnosis: ERRATA P2).
    """
    t_end = float(ts["t"][-1])
    data = []
    if "rho_hat" in ts:
        top, bottom = ("rho_hat", "sigma", "gain"), ("ubar_hat", "ubar", "friction [N m]")
    elif "chi_hat" in ts and patterns is not None:
        chi = np.asarray(ts["chi_hat"], float)
        pats = np.asarray(patterns, float)
        show = range(min(pats.shape[0], 12))
        w = [chi[:, k, pats[k] > 0].mean(axis=1) for k in show]
        t, *cols = decimate(ts["t"], *w)
        for k, c in zip(show, cols, strict=True):
            data.append(_trace(t, _r(c), f"model {k}", "%{y:.3g}", line={"width": 1}))
        top, bottom = None, ("uf_hat", "ubar", "friction [N m]")
    else:
        return None
    for key, true_key, _label in [x for x in (top, bottom) if x is not None]:
        if key not in ts:
            continue
        est, tru = np.asarray(ts[key], float), np.asarray(ts[true_key], float)
        axis = "y" if key == "rho_hat" else "y2"
        t, *cols = decimate(
            ts["t"], *[est[:, j] for j in range(est.shape[1])], *[tru[:, j] for j in range(est.shape[1])]
        )
        m = est.shape[1]
        for j, w in enumerate(wheels):
            color = f"hsl({int(360 * j / max(1, m))},65%,42%)"
            line = {"width": 1.1, "color": color}
            data.append(_trace(t, _r(cols[j]), f"{key} {w}", "%{y:.3g}", legendgroup=w, yaxis=axis, line=line))
            dashed = {"width": 1, "dash": "dash", "color": color}
            hidden = {"legendgroup": w, "showlegend": False, "yaxis": axis, "line": dashed}
            data.append(_trace(t, _r(cols[m + j]), f"true {w}", "true %{y:.3g}", **hidden))
    top_title = "gain estimate" if "rho_hat" in ts else "weight (mean over wheels)"
    lo_hi = [-0.5, 1.5] if "rho_hat" in ts else [-0.05, 1.05]
    fric = np.asarray(ts.get("ubar", np.zeros((1, 1))), float)
    f_lo, f_hi = float(np.nanmin(fric)) - 1.0, float(np.nanmax(fric)) + 1.0
    note = (
        "control variables of the adaptive law, not a diagnosis (ERRATA P2)"
        if "chi_hat" in ts
        else ("solid: estimate, dashed: truth; axes clipped, zoom out for the transients (ERRATA P3)")
    )
    lay = _layout(
        f"{scheme}: {note}",
        events,
        t_end,
        height=460,
        yaxis={"title": {"text": top_title}, "domain": [0.53, 1], "range": lo_hi},
        yaxis2={"title": {"text": "friction [N m]"}, "domain": [0, 0.45], "range": [f_lo, f_hi]},
    )
    return {"data": data, "layout": lay}
