"""Interactive time-series figures (plotly.js figure specs as plain dicts; the page draws them).

Each function returns ``{"data": [...], "layout": {...}}`` ready for ``Plotly.newPlot``: tracking
errors, torques (a menu picks the scheme), the switching index against the true pattern, and the
estimates of the adaptive and active schemes against the truth.  Fault phases are shaded and the
events marked.  Series are decimated by keeping each bucket's minimum and maximum
(:func:`decimate`), so peaks survive and a page stays small; the page states the point budget.
plotly.js itself is inlined once per page, gzip-compressed and base64-encoded
(:func:`inline_plotly`: about 2.0 MB per page against 4.8 MB as text), so a page copied alone
works offline; nothing is fetched online.
"""

from __future__ import annotations

import base64
import functools
import gzip
import itertools
import math
from importlib import resources

import numpy as np

from ..control.kinematic import wrap
from . import plots
from .plots import SCHEME_COLORS

__all__ = [
    "MAX_POINTS",
    "band_fig",
    "decimate",
    "errors_fig",
    "estimates_fig",
    "inline_plotly",
    "motors_fig",
    "series_colors",
    "switching_fig",
    "torques_fig",
]

MAX_POINTS = 1500  # per trace, after decimation
#: colours for series that are not a scheme or whose scheme's colour is taken (tab10, then tab20b's darks)
PALETTE = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
    "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173",
)  # fmt: skip


def series_colors(names: list[str]) -> dict[str, str]:
    """One colour per series name, none repeated: a scheme's own colour (:data:`plots.SCHEME_COLORS`) for a
    scheme, or for the first series named after it (``switching (this case)``); the others the first colours
    of :data:`PALETTE` not taken (``switching (base)``), cycling only past 15 series."""
    out: dict[str, str] = {}
    for name in names:
        own = SCHEME_COLORS.get(name) or SCHEME_COLORS.get(name.split(" (", 1)[0])
        if own and own not in out.values():
            out[name] = own
    free = [c for c in PALETTE if c not in out.values() and c not in SCHEME_COLORS.values()]
    free += [c for c in PALETTE if c not in out.values() and c not in free]
    for i, name in enumerate(n for n in names if n not in out):
        out[name] = free[i % len(free)] if free else PALETTE[i % len(PALETTE)]
    return out


@functools.cache  # one compression per process: every page inlines the same bytes
def inline_plotly() -> dict:
    """plotly.min.js for inlining in a page: gzip-compressed and base64-encoded (the page inflates it
    with the browser's DecompressionStream), so a page copied alone still draws its figures.

    Returns ``{"b64", "raw_bytes", "inline_bytes", "version"}``: 4.8 MB of plotly.js become about
    2.0 MB in the page (against 4.8 MB inlined as text).
    """
    data = (resources.files("plotly") / "package_data" / "plotly.min.js").read_bytes()
    b64 = base64.b64encode(gzip.compress(data, compresslevel=9, mtime=0)).decode("ascii")
    head = data[:400].decode("utf-8", "replace")
    version = head.split("plotly.js v", 1)[1].split()[0] if "plotly.js v" in head else "?"
    return {"b64": b64, "raw_bytes": len(data), "inline_bytes": len(b64), "version": version}


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


def _phases(phases: list[dict], t_end: float) -> list[dict]:
    """Every fault phase shaded in its pattern's color (the first of each pattern in the legend, with
    its gains), a dotted line at each event; the same phases as the static figures (plots.fault_phases)."""
    shapes, seen = [], set()
    for p in phases:
        span = {"xref": "x", "yref": "paper", "x0": p["start"], "y0": 0, "y1": 1}
        if p["color"] is not None:
            first = p["color"] not in seen
            seen.add(p["color"])
            shade = {"fillcolor": p["color"], "opacity": 0.3, "line": {"width": 0}, "layer": "below"}
            legend = {"name": p["label"], "showlegend": first, "legendgroup": "phase " + p["color"]}
            shapes.append({"type": "rect", **span, "x1": min(p["end"], t_end), **shade, **legend})
        if p["start"] > 0:
            dot = {"color": "rgba(120,0,20,0.6)", "width": 1, "dash": "dot"}
            shapes.append({"type": "line", **span, "x1": p["start"], "line": dot})
    return shapes


def _layout(title: str, phases: list[dict], t_end: float, height: int = 360, **extra) -> dict:
    lay = {
        "title": {"text": title, "font": {"size": 13}},
        "height": height + 50,
        "margin": {"l": 60, "r": 20, "t": 40, "b": 100},
        "hovermode": "x unified",
        # automargin: the margin grows to hold the title below the tick labels (else plotly keeps the title
        # inside the fixed margin, and with the legend below it the title sat on the tick labels)
        "xaxis": {"title": {"text": "t [s]", "standoff": 6}, "automargin": True, "range": [0, t_end]},
        "shapes": _phases(phases, t_end),
        "legend": {"orientation": "h", "y": 0, "yref": "container", "yanchor": "bottom"},
    }
    lay.update(extra)
    return lay


def _trace(t: np.ndarray, y: list, name: str, hover: str, **extra) -> dict:
    """One line trace over time (``t`` rounded to 6 digits for compact JSON); ``extra``: its other keys."""
    return {"x": _r(t, 6), "y": y, "name": name, "type": "scatter", "mode": "lines", "hovertemplate": hover, **extra}


def _t_end(series: dict) -> float:
    return max(float(ts["t"][-1]) for ts in series.values())


def errors_fig(series: dict[str, dict], phases: list[dict]) -> dict:
    """Position error and largest heading error per series (log scale), each in its own colour
    (:func:`series_colors`)."""
    data = []
    colors = series_colors(list(series))
    scale: dict[str, list[np.ndarray]] = {"pos": [], "head": []}  # the samples the axes are scaled on
    for scheme, ts in series.items():
        q, qd = ts["q"], ts["q_d"]
        pos = np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])
        head = np.abs(wrap(q[:, 2:] - qd[:, 2:])).max(axis=1)
        after = ts["t"] >= float(ts["t"][0]) + 1.0  # a chain starting on its reference: ~0 at t0
        scale["pos"].append(pos[after])
        scale["head"].append(head[after])
        t, p, h = decimate(ts["t"], np.maximum(pos, 1e-12), np.maximum(head, 1e-9))
        c = colors[scheme]
        data.append(_trace(t, _r(p), scheme, "%{y:.3g} m", legendgroup=scheme, line={"color": c, "width": 1.3}))
        heading = {"legendgroup": scheme, "showlegend": False, "line": {"color": c, "width": 1.0}, "yaxis": "y2"}
        data.append(_trace(t, _r(h), scheme, "%{y:.3g} rad", **heading))
    lay = _layout(
        "tracking errors (shaded: fault phases; drag to zoom, double-click to reset)",
        phases,
        _t_end(series),
        height=460,
        yaxis={"type": "log", "title": {"text": "position error [m]"}, "domain": [0.53, 1]},
        yaxis2={"type": "log", "title": {"text": "max heading error [rad]"}, "domain": [0, 0.45]},
    )
    for axis, key, floor in (("yaxis", "pos", 1e-12), ("yaxis2", "head", 1e-9)):
        rng = _log_range(scale[key], floor)
        if rng is not None:
            lay[axis]["range"] = rng
    lay["xaxis"]["anchor"] = "y2"  # the time axis under the lower panel, not between the two
    return {"data": data, "layout": lay}


def _log_range(parts: list[np.ndarray], floor: float) -> list[float] | None:
    """A log axis's range [log10 lo, log10 hi] over the samples from 1 s after the start: their least and
    largest value (at least ``floor``) with a fifth of a decade of room; None without samples.  The error
    at t0 of a chain that starts on its reference (round-off) no longer sets the lower end."""
    v = np.concatenate([p for p in parts if p.size]) if any(p.size for p in parts) else np.zeros(0)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    lo, hi = max(float(v.min()), floor), max(float(v.max()), floor)
    return [round(math.log10(lo) - 0.15, 3), round(math.log10(hi) + 0.15, 3)]


def _window(t: np.ndarray, phases: list[dict], samples: int = 60) -> tuple[int, int]:
    """The zoom window of a band figure: ``samples`` logged samples from the first fault (or mid-run)."""
    events = [p["start"] for p in phases if p["start"] > 0]
    t0 = events[0] if events else float(t[t.size // 2])
    a = int(np.searchsorted(t, t0))
    a = max(0, min(a, t.size - samples))
    return a, min(t.size, a + samples)


def _scale_from(t: np.ndarray, phases: list[dict]) -> float:
    """Where a band figure's whole-run axis takes its scale from: the first fault (what the verdict
    ranks: the peak after it), or 1 s after the start without a fault (or a sample after it)."""
    events = [p["start"] for p in phases if p["start"] > 0 and p["start"] < t[-1]]
    return events[0] if events else float(t[0]) + 1.0


def band_fig(
    series: dict[str, dict],
    signals: dict[str, np.ndarray],
    rows: list[tuple[str, str, float | None]],
    wheels: list[str],
    phases: list[dict],
    main: str,
    title: str,
) -> dict:
    """Per-wheel signals of every scheme (a menu picks the scheme, ``main`` first), in three columns:
    the first second (the start-up transient at its own scale), the whole run (each bucket's min-max
    band and mean, so chatter reads as a band of its amplitude; the axis scaled on the samples from
    the first fault on, or from t = 1 s without one: :func:`_scale_from`), and a zoom of 60 logged
    samples from the first fault (every sample, the chatter's shape).

    ``signals``: ``{f"{scheme}/{row}": (K, nw) array}`` on each scheme's log times; ``rows``: (key,
    axis title, limit) per row of panels, the limit drawn at +-limit (None: none).
    """
    data, owner = [], []
    schemes = [s for s in series if all(f"{s}/{r[0]}" in signals for r in rows)]
    nrow = len(rows)
    gap = 0.1 / max(1, nrow - 1) if nrow > 1 else 0.0
    height = (1.0 - gap * (nrow - 1)) / nrow
    cols = ((0.0, 0.12), (0.22, 0.75), (0.82, 1.0))  # first second | whole run | zoom
    axes: dict = {}
    t_end = _t_end(series)
    for r in range(nrow):
        top = 1.0 - r * (height + gap)
        for c in range(3):
            k = 3 * r + c + 1
            axes[k] = {
                "x": f"x{'' if k == 1 else k}",
                "y": f"y{'' if k == 1 else k}",
                "dom": ((top - height, top), cols[c]),
            }
    lims: dict[int, list[float]] = {}
    for scheme in schemes:
        t = np.asarray(series[scheme]["t"], float)
        a, b = _window(t, phases)
        first = t <= t[0] + 1.0
        for r, (key, _label, _lim) in enumerate(rows):
            y = np.asarray(signals[f"{scheme}/{key}"], float)
            rng = plots.robust_range(t, y, start=_scale_from(t, phases))
            if rng is not None:
                old = lims.setdefault(3 * r + 2, list(rng))
                lims[3 * r + 2] = [min(old[0], rng[0]), max(old[1], rng[1])]
            for j, w in enumerate(wheels):
                color = f"hsl({int(360 * j / max(1, len(wheels)))},65%,42%)"
                vis = scheme == main
                show = r == 0
                ax1, ax2, ax3 = axes[3 * r + 1], axes[3 * r + 2], axes[3 * r + 3]
                common = {"legendgroup": w, "visible": vis}
                # the first second, every sample
                tf, yf = decimate(t[first], y[first, j], max_points=400)
                data.append(
                    _trace(
                        tf,
                        _r(yf),
                        w,
                        "%{y:.4g}",
                        xaxis=ax1["x"],
                        yaxis=ax1["y"],
                        showlegend=False,
                        line={"width": 1, "color": color},
                        **common,
                    )
                )
                # the whole run: min-max band and mean per bucket
                tc, lo, hi, mean = plots.buckets_of(t, y[:, j], 700)
                band = {"xaxis": ax2["x"], "yaxis": ax2["y"], "hoverinfo": "skip", "showlegend": False}
                data.append(_trace(tc, _r(lo), w, "", line={"width": 0, "color": color}, **band, **common))
                fill = {"fill": "tonexty", "fillcolor": color.replace("hsl", "hsla").replace(")", ",0.25)")}
                data.append(_trace(tc, _r(hi), w, "", line={"width": 0, "color": color}, **fill, **band, **common))
                data.append(
                    _trace(
                        tc,
                        _r(mean),
                        w,
                        f"{w} mean %{{y:.4g}}",
                        xaxis=ax2["x"],
                        yaxis=ax2["y"],
                        showlegend=show,
                        line={"width": 1.2, "color": color},
                        **common,
                    )
                )
                # the zoom: every logged sample of the window
                data.append(
                    _trace(
                        t[a:b],
                        _r(y[a:b, j]),
                        w,
                        "%{y:.4g}",
                        xaxis=ax3["x"],
                        yaxis=ax3["y"],
                        showlegend=False,
                        line={"width": 1, "color": color, "shape": "hv"},
                        mode="lines+markers",
                        marker={"size": 3},
                        **common,
                    )
                )
                owner += [scheme] * 5
    buttons = [
        {
            "label": s,
            "method": "update",
            "args": [{"visible": [o == s for o in owner]}, {"title.text": f"{title}, {s}"}],
        }
        for s in schemes
    ]
    t_main = series[main]["t"] if main in series else next(iter(series.values()))["t"]
    a, b = _window(np.asarray(t_main, float), phases)
    lay = {
        "title": {"text": f"{title}, {main}", "font": {"size": 13}},
        "height": 260 * nrow + 120,
        "margin": {"l": 60, "r": 20, "t": 50, "b": 90},
        "hovermode": "closest",
        "legend": {"orientation": "h", "y": 0, "yref": "container", "yanchor": "bottom"},
        "shapes": [],
        "annotations": [],
        "updatemenus": [
            {
                "buttons": buttons,
                "direction": "down",
                "x": 1.0,
                "xanchor": "right",
                "y": 1.0 + 40 / (260 * nrow + 120),
                "yanchor": "bottom",
                "active": schemes.index(main) if main in schemes else 0,
            }
        ],
    }
    for k, ax in axes.items():
        r, c = (k - 1) // 3, (k - 1) % 3
        (y0, y1), (x0, x1) = ax["dom"]
        xname = "xaxis" if k == 1 else f"xaxis{k}"
        yname = "yaxis" if k == 1 else f"yaxis{k}"
        xr = [0, 1.0] if c == 0 else ([0, t_end] if c == 1 else [float(t_main[a]), float(t_main[b - 1])])
        lay[xname] = {
            "domain": [x0, x1],
            "anchor": ax["y"],
            "range": xr,
            "title": {
                "text": ("t [s], first second" if c == 0 else "t [s]" if c == 1 else "t [s], zoom")
                if r == nrow - 1
                else ""
            },
        }
        lay[yname] = {"domain": [y0, y1], "anchor": ax["x"]}
        if c == 1:
            lay[yname]["title"] = {"text": rows[r][1]}
            if k in lims:
                lay[yname]["range"] = lims[k]
            shades = _phases(phases, t_end)
            lay["shapes"] += [
                {**s, "xref": ax["x"], "yref": f"{ax['y']} domain"} | ({"showlegend": False} if r else {})
                for s in shades
            ]
        lim = rows[r][2]
        if lim is not None:
            for sign in (1, -1):
                lay["shapes"].append(
                    {
                        "type": "line",
                        "xref": f"{ax['x']} domain",
                        "yref": ax["y"],
                        "x0": 0,
                        "x1": 1,
                        "y0": sign * lim,
                        "y1": sign * lim,
                        "line": {"color": "#b00020", "width": 1, "dash": "dash"},
                    }
                )
            if c == 1:
                lay["annotations"].append(
                    {
                        "xref": f"{ax['x']} domain",
                        "yref": ax["y"],
                        "x": 1,
                        "y": lim,
                        "xanchor": "right",
                        "yanchor": "bottom",
                        "showarrow": False,
                        "text": f"limit +-{lim:g}",
                        "font": {"size": 10, "color": "#b00020"},
                    }
                )
    return {"data": data, "layout": lay}


def torques_fig(series: dict[str, dict], wheels: list[str], phases: list[dict], main: str) -> dict:
    """Applied torques per wheel (:func:`band_fig`); a menu shows one scheme at a time (``main`` first)."""
    sig = {f"{s}/tau": np.asarray(ts["tau"], float) for s, ts in series.items() if "tau" in ts}
    return band_fig(series, sig, [("tau", "tau [N m]", None)], wheels, phases, main, "applied wheel torques")


def motors_fig(
    series: dict[str, dict],
    volts: dict[str, np.ndarray],
    wheels: list[str],
    phases: list[dict],
    main: str,
    v_max: float | None,
    i_max: float | None,
) -> dict:
    """Armature voltage (top) and current (bottom) per wheel with the driver's limits +-V_max and
    +-I_max dashed (:func:`band_fig`); ``volts``: the voltages per scheme on its log times."""
    sig = {}
    for s, ts in series.items():
        if "i_a" in ts and s in volts:
            sig[f"{s}/v"] = np.asarray(volts[s], float)
            sig[f"{s}/i"] = np.asarray(ts["i_a"], float)
    rows = [("v", "armature voltage [V]", v_max), ("i", "armature current [A]", i_max)]
    return band_fig(series, sig, rows, wheels, phases, main, "armature voltage and current")


def switching_fig(ts: dict, patterns: list[list[int]], phases: list[dict], scheme: str = "") -> dict:
    """Applied model index against the index of the true pattern (-1 when it is not a model)."""
    pats = [tuple(p) for p in patterns]
    truth = np.array([pats.index(k) if (k := tuple((s >= 1.0).astype(int))) in pats else -1 for s in ts["sigma"]])
    t, sel, tr = decimate(ts["t"], np.asarray(ts["selected"], float), truth.astype(float))
    truth_line = {"shape": "hv", "color": "rgba(0,0,0,0.35)", "width": 4}  # wide and grey, under the model's
    model_line = {"shape": "hv", "color": SCHEME_COLORS.get(scheme, "#1f77b4"), "width": 1.2}
    data = [
        _trace(t, tr.astype(int).tolist(), "true pattern", "true %{y}", line=truth_line),
        _trace(t, sel.astype(int).tolist(), "applied model", "model %{y}", line=model_line),
    ]
    lay = _layout(
        "switching: applied model against the true pattern (-1: the true pattern is not a model)",
        phases,
        float(ts["t"][-1]),
        height=300,
        yaxis={"title": {"text": "model index"}},
    )
    return {"data": data, "layout": lay}


def estimates_fig(ts: dict, scheme: str, wheels: list[str], phases: list[dict], patterns=None) -> dict | None:
    """Estimates of one scheme against the truth (dashed).

    Active schemes: rho_hat and ubar_hat per wheel against sigma and ubar.  Adaptive schemes: the
    weights chihat_(k) (mean over the wheels each model drives) and the friction estimate (logged as
    uf_hat) against ubar (control variables, not a diagnosis: ERRATA P2).  Either friction estimate is
    named ubar_hat in the figure, as in the README and the rest of the pages.
    """
    t_end = float(ts["t"][-1])
    data = []
    m = len(wheels)
    # a colour means one thing: a wheel (its estimates and truths) in both panels of the active figure
    wheel_colors = {w: f"hsl({int(360 * j / max(1, m))},65%,42%)" for j, w in enumerate(wheels)}
    if "rho_hat" in ts:
        top, bottom = ("rho_hat", "sigma", "gain"), ("ubar_hat", "ubar", "friction [N m]")
    elif "chi_hat" in ts and patterns is not None:
        chi = np.asarray(ts["chi_hat"], float)
        pats = np.asarray(patterns, float)
        show = range(min(pats.shape[0], 12))
        # the adaptive figure's two panels draw different quantities (a model's weight, a wheel's friction
        # estimate): every model and every wheel its own colour (plotly's default colours for the models
        # repeated the wheels' hues: model 3 and wheel 1r both red)
        colors = series_colors([f"model {k}" for k in show] + [f"wheel {w}" for w in wheels])
        wheel_colors = {w: colors[f"wheel {w}"] for w in wheels}
        w = [chi[:, k, pats[k] > 0].mean(axis=1) for k in show]
        t, *cols = decimate(ts["t"], *w)
        for k, c in zip(show, cols, strict=True):
            data.append(_trace(t, _r(c), f"model {k}", "%{y:.3g}", line={"width": 1, "color": colors[f"model {k}"]}))
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
            color = wheel_colors[w]
            line = {"width": 1.1, "color": color}
            name = f"{'ubar_hat' if key == 'uf_hat' else key} {w}"  # one name for the friction estimate
            data.append(_trace(t, _r(cols[j]), name, "%{y:.3g}", legendgroup=w, yaxis=axis, line=line))
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
        phases,
        t_end,
        height=460,
        yaxis={"title": {"text": top_title}, "domain": [0.53, 1], "range": lo_hi},
        yaxis2={"title": {"text": "friction [N m]"}, "domain": [0, 0.45], "range": [f_lo, f_hi]},
    )
    lay["xaxis"]["anchor"] = "y2"  # the time axis under the lower panel, not between the two
    return {"data": data, "layout": lay}
