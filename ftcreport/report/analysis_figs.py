"""The case page's "Linearized analysis" section: its data and its figures (``templates/_analysis.html``).

:func:`analysis_section` runs :func:`ftcreport.analysis.analyze_case` with the case's stored runs (the
states each scheme held, the model switching selected) and, for a case with sampled control or motors,
the confirmation of each stability limit by simulation; then it builds what the template shows:

* the limits per scheme beside the case's own sample time and gain, as margin factors, with the
  simulations' outcomes (a contradiction is shown as one);
* a table of the phases per scheme (applied against true pattern, spectral radius or slowest pole,
  stability, the worst actuator loop's margins);
* figures, interactive (plotly specs as in :mod:`.interactive`) with a static SVG beside each (shown
  when plotly.js cannot run, and in print): the pole map per scheme with the phases in colour
  (z-plane with the unit circle for a sampled loop), the spectral radius (or the largest real part)
  against the sample time and against k_v with the case's point and the limit marked, and the Bode
  plot of the loop with the least stability margin in each phase, margins marked;
* the case-wide analyses that were on the page before (two-link error poles, chained-form loci and
  Floquet rate, observer, controllability), and their figures.
"""

from __future__ import annotations

import json
import math

import numpy as np

from ..analysis.limits import limit_words
from ..analysis.summary import healthy_words, horizon_words, measure_text, split_text, unstable_faulty
from ..errors import FtcError
from . import plots

__all__ = ["analysis_section", "bode_fig", "limit_rows", "phase_rows", "pole_map_fig", "sweep_figs"]

PHASE_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#7f7f7f")


def analysis_section(case, names, series: dict, events: list[float]) -> dict | None:
    """The dict ``templates/_analysis.html`` renders, or None when nothing could be analysed.

    ``names``: the wheels' names; ``series``: the stored runs by scheme (``store.load_timeseries``);
    ``events``: the fault times.  An analysis that fails says why on the page instead of breaking it.
    """
    from ..analysis import analyze_case
    from ..analysis.confirm import needs_confirmation

    runs = {s: ts for s, ts in (series or {}).items() if ts is not None and ts.get("t") is not None}
    try:
        res = analyze_case(case, runs=runs, confirm=needs_confirmation(case))
    except (FtcError, ValueError, np.linalg.LinAlgError) as exc:
        return {"error": f"the linearized analysis failed: {exc}"}
    rows = res.get("controllability") or []
    pick = rows[:4] + rows[-4:] if len(rows) > 8 else rows
    res["ctrb_rows"] = [
        {**r, "failed": ", ".join(w for w, p in zip(names, r["pattern"], strict=True) if p == 0) or "none"}
        for r in pick
    ]
    if res.get("pole_tables"):
        res["pole_groups"] = group_tables(res["pole_tables"])
    res["limit_rows"] = limit_rows(res)
    if res.get("horizon"):  # the part of the run the reference allows (analysis.case.analysed_horizon)
        words = horizon_words(res["horizon"])
        res["horizon_text"] = words[:1].upper() + words[1:] + "."
    res["phase_rows"] = phase_rows(res)
    figs = []
    if res.get("phases"):
        figs.append(pole_map_fig(res))
        figs.extend([*sweep_figs(res, "T"), *sweep_figs(res, "k")])
        bode = bode_fig(res)
        if bode is not None:
            figs.append(bode)
    figs.extend(_classic_figures(res, series, events, case.simulation.duration))
    res["figures"] = figs
    return res


# ----------------------------------------------------------------------------------------------- tables
def _factor(limit, value) -> float | None:
    return limit / value if limit is not None and value else None


def limit_rows(res: dict) -> list[dict]:
    """One row per scheme: the limits, the case's values, the margin factors and the confirmations."""
    T = res.get("sample_time")
    out = []
    for scheme, lim in res.get("limits", {}).items():
        k_v = res.get("k_v", {}).get(scheme)
        vl = res.get("velocity_loop", {}).get(scheme, {})
        conf = res.get("confirmation", {}).get(scheme, {})
        kinds = res.get("limit_kinds", {}).get(scheme, {})
        words = lambda v, k, unit, kinds=kinds: limit_words(v, kinds.get(k), unit)  # noqa: E731  a null by its kind
        faulty = unstable_faulty(res.get("phases", {}).get(scheme, []))
        healthy = [healthy_words(faulty)] if faulty else []
        out.append(
            {
                "scheme": scheme,
                "T_max": lim.get("sample_time_max"),
                "T_text": words(lim.get("sample_time_max"), "limits.sample_time_max", "s"),
                "k_text": words(lim.get("k_v_max"), "limits.k_v_max", "1/s"),
                "vl_T_text": words(vl.get("sample_time_max"), "velocity_loop.sample_time_max", "s"),
                "vl_k_text": words(vl.get("k_v_max"), "velocity_loop.k_v_max", "1/s"),
                "T_factor": _factor(lim.get("sample_time_max"), T),
                "k_v": k_v,
                "k_max": lim.get("k_v_max"),
                "k_factor": _factor(lim.get("k_v_max"), k_v),
                # a limit a simulation contradicts gives no margin to rely on (the page marks it)
                "T_contradicted": (conf.get("sample_time_max") or {}).get("agrees") is False,
                "k_contradicted": (conf.get("k_v_max") or {}).get("agrees") is False,
                "vl_T_max": vl.get("sample_time_max"),
                "vl_k_max": vl.get("k_v_max"),
                "notes": _limit_notes(res.get("limit_notes", {}).get(scheme, {})) + healthy,
                "confirm": [{"which": w, **c} for w, c in conf.items()],
            }
        )
    return out


_LIMIT_NAMES = {"limits.sample_time_max": "T_s max", "limits.k_v_max": "k_v max",
                "velocity_loop.sample_time_max": "velocity loop alone, T_s max",
                "velocity_loop.k_v_max": "velocity loop alone, k_v max", "caveat": "every limit"}  # fmt: skip


def _limit_notes(notes: dict) -> list[str]:
    """Each note named by the limit it is about ("velocity loop alone, T_s max: stable at every sample time
    up to 10 s"), one line for the limits a note is the same for."""
    by_text: dict[str, list[str]] = {}
    for key, text in notes.items():
        if text:
            by_text.setdefault(text, []).append(_LIMIT_NAMES.get(key, key))
    return [f"{' and '.join(names)}: {text}" for text, names in by_text.items()]


def phase_rows(res: dict) -> list[dict]:
    """One row per fault phase, one cell per scheme (the phases are the same for every scheme)."""
    schemes = list(res.get("phases", {}))
    if not schemes:
        return []
    first = res["phases"][schemes[0]]
    rows = []
    for i, p0 in enumerate(first):
        cells = []
        for s in schemes:
            ph = res["phases"][s]
            p = ph[i] if i < len(ph) else None
            if p is None:
                cells.append(None)
                continue
            m = p.get("margins") or {}
            loops = [r for r in m.get("loops", []) if r.get("stability_margin") is not None]
            worst = min(loops, key=lambda r: r["stability_margin"]) if loops else None
            measure = p.get("spectral_radius", p.get("max_real_part"))
            cells.append(
                {
                    "applied": _pattern(p.get("pattern_applied")),
                    "differs": p.get("pattern_applied") is not None
                    and [round(v, 6) for v in p["pattern_applied"]] != [round(v, 6) for v in p["pattern_true"]],
                    "from": p.get("applied_from"),
                    "measure": measure,
                    "measure_text": measure_text(measure, bool(p.get("discrete"))),
                    "discrete": p.get("discrete"),
                    "stability": p.get("stability"),
                    "split": split_text(p.get("frozen_disagree")),
                    "worst": worst,
                    "margin_note": m.get("note"),
                    "internal": _internal_text(p.get("internal_modes"), bool(p.get("discrete"))),
                }
            )
        rows.append(
            {
                "span": f"{p0['t_start']:g}-{p0['t_end']:g}",
                "true": _pattern(p0["pattern_true"]),
                "friction": any(abs(v) > 0 for v in p0.get("friction_true", [])),
                "motor": p0.get("motor_faults"),
                "cells": cells,
            }
        )
    return rows


def _internal_text(internal: dict | None, discrete: bool) -> str | None:
    """'25 states outside the loop: rho 0.995' for a phase's left-out states that move (None when none do)."""
    if not internal:
        return None
    value = internal.get("spectral_radius", internal.get("max_real_part"))
    name = "rho" if discrete else "max Re"
    return f"{internal['modes']} state(s) outside the loop: {name} {measure_text(value, discrete)}"


def _pattern(p) -> str | None:
    """A pattern's effectivenesses, 3 significant digits each: '1 0 0.999 1'."""
    return None if p is None else " ".join(f"{v:.3g}" for v in p)


def group_tables(tables: dict) -> list[dict]:
    """Identical pole tables (to 4 significant digits) once, labelled with every scheme they cover."""
    groups: list[dict] = []
    for scheme, rows in tables.items():
        key = json.dumps([{k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in r.items()} for r in rows])
        for g in groups:
            if g["key"] == key:
                g["schemes"].append(scheme)
                break
        else:
            groups.append({"key": key, "schemes": [scheme], "rows": rows})
    return groups


# ----------------------------------------------------------------------------------------------- figures
def _figure(fig_id: str, caption: str, plotly: dict, svg: str) -> dict:
    return {"id": fig_id, "caption": caption, "plotly": plotly, "svg": svg}


def _menu(labels: list[str], groups: list[list[int]], n_traces: int, views: list[dict] | None = None) -> list[dict]:
    """A dropdown that shows one group of traces (one scheme) at a time, with its own layout (``views``)."""
    buttons = []
    for k, (label, idx) in enumerate(zip(labels, groups, strict=True)):
        vis = [i in idx for i in range(n_traces)]
        args: list[dict] = [{"visible": vis}]
        if views is not None:
            args.append(views[k])
        buttons.append({"label": label, "method": "update", "args": args})
    return [{"buttons": buttons, "x": 0.0, "xanchor": "left", "y": 1.18, "yanchor": "top", "showactive": True}]


def _r(v: float, digits: int = 5) -> float | None:
    return float(f"{v:.{digits}g}") if v is not None and math.isfinite(v) else None


def _scheme_discrete(res: dict, scheme: str) -> bool:
    """Whether a scheme's loop was analysed in discrete time (its phases say; the case's sampling else)."""
    phases = res["phases"].get(scheme) or []
    if phases and "discrete" in phases[0]:
        return bool(phases[0]["discrete"])
    return bool(res.get("sampled"))


def _plane(discrete: bool, poles) -> dict:
    """The axes and stability boundary of one scheme's view: the z-plane with the unit circle, or the s-plane
    with the imaginary axis (its slower half of the poles in view, where the phases differ)."""
    if discrete:
        shapes = [{"type": "circle", "xref": "x", "yref": "y", "x0": -1, "y0": -1, "x1": 1, "y1": 1,
                   "line": {"color": "black", "width": 1, "dash": "dot"}}]  # fmt: skip
        return {"xaxis.title.text": "Re z", "yaxis.title.text": "Im z", "shapes": shapes,
                "xaxis.autorange": True, "yaxis.scaleanchor": "x", "yaxis.scaleratio": 1}  # fmt: skip
    shapes = [{"type": "line", "xref": "x", "yref": "paper", "x0": 0, "x1": 0, "y0": 0, "y1": 1,
               "line": {"color": "black", "width": 1, "dash": "dot"}}]  # fmt: skip
    view = {"xaxis.title.text": "Re s [1/s]", "yaxis.title.text": "Im s [1/s]", "shapes": shapes,
            "xaxis.autorange": True, "yaxis.scaleanchor": None}  # fmt: skip
    re = np.abs([a for a, _b in poles])
    if re.size:
        x = 3.0 * float(np.percentile(re, 50))
        view |= {"xaxis.autorange": False, "xaxis.range": [-x, 0.15 * x]}
    return view


def pole_map_fig(res: dict) -> dict:
    """Poles of every phase's loop, one scheme at a time (dropdown), the phases in colour; each scheme on its
    own plane (z for a loop analysed in discrete time, s otherwise: the UKF's filter is sampled where the
    other schemes of the case are continuous)."""
    traces, groups, labels, views = [], [], [], []
    for scheme, phases in res["phases"].items():
        idx = []
        for i, p in enumerate(phases):
            poles = np.array([complex(a, b) for a, b in p.get("poles", [])])
            if poles.size == 0:
                continue
            rows = p.get("pole_table") or []
            text = [
                f"{scheme}, {p['t_start']:g}-{p['t_end']:g} s: damping {_r(r['damping'], 3)}, "
                f"time constant {_r(r['time_constant'], 3)} s"
                for r in rows
            ]
            idx.append(len(traces))
            traces.append(
                {
                    "type": "scatter",
                    "mode": "markers",
                    "x": [_r(z.real) for z in poles],
                    "y": [_r(z.imag) for z in poles],
                    "name": f"{p['t_start']:g}-{p['t_end']:g} s ({p.get('stability')})",
                    "marker": {"symbol": "x", "size": 9, "color": PHASE_COLORS[i % len(PHASE_COLORS)]},
                    "text": text if len(text) == poles.size else None,
                    "visible": not groups,
                }
            )
        groups.append(idx)
        labels.append(scheme)
        views.append(_plane(_scheme_discrete(res, scheme), [pl for p in phases for pl in p.get("poles", [])]))
    planes = {_scheme_discrete(res, s) for s in labels} or {bool(res.get("sampled"))}
    first = views[0] if views else _plane(bool(res.get("sampled")), [])
    layout = {
        "height": 420,
        "margin": {"l": 60, "r": 20, "t": 60, "b": 50},
        "xaxis": {"title": {"text": first["xaxis.title.text"]}, "zeroline": True},
        "yaxis": {"title": {"text": first["yaxis.title.text"]}, "zeroline": True},
        "shapes": first["shapes"],
        "updatemenus": _menu(labels, groups, len(traces), views),
        "legend": {"orientation": "h", "y": -0.2},
    }
    if first.get("yaxis.scaleanchor"):
        layout["yaxis"] |= {"scaleanchor": "x", "scaleratio": 1}
    if "xaxis.range" in first:
        layout["xaxis"]["range"] = first["xaxis.range"]
    where = " or ".join(
        w for d, w in ((True, "z-plane, unit circle dotted"), (False, "s-plane, imaginary axis dotted")) if d in planes
    )
    if len(planes) > 1:
        where += ": each scheme on its own, z for a loop analysed in discrete time"
    cap = (
        f"Closed-loop poles of each fault phase ({where}; at the phase's worst frozen instant), one scheme at a time "
        "(menu); hover for damping and time constant"
        + ("; an s-plane view shows the slower half of the poles, double-click for all." if False in planes else ".")
    )
    if res.get("time_varying"):
        cap += " The loop is time-varying here: frozen-instant poles are evidence, not proof."
    return _figure("analysis-poles", cap, {"data": traces, "layout": layout}, _pole_map_svg(res))


def _pole_map_svg(res: dict) -> str:
    import matplotlib.pyplot as plt

    schemes = [s for s, p in res["phases"].items() if p]
    cols = min(3, len(schemes))
    rows = math.ceil(len(schemes) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.3 * cols, 2.8 * rows), squeeze=False)
    for ax, scheme in zip(axes.flat, schemes, strict=False):
        for i, p in enumerate(res["phases"][scheme]):
            poles = np.array([complex(a, b) for a, b in p.get("poles", [])])
            if poles.size:
                ax.plot(poles.real, poles.imag, "x", color=PHASE_COLORS[i % len(PHASE_COLORS)], ms=5,
                        label=f"{p['t_start']:g}-{p['t_end']:g} s")  # fmt: skip
        if _scheme_discrete(res, scheme):
            th = np.linspace(0, 2 * np.pi, 200)
            ax.plot(np.cos(th), np.sin(th), "k:", lw=0.8)
            ax.set_aspect("equal", adjustable="datalim")
        else:
            ax.axvline(0.0, color="k", lw=0.8, ls=":")
            ax.set_xscale("symlog", linthresh=0.1)
        ax.set_title(scheme)
    for ax in list(axes.flat)[len(schemes) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=6)
    return plots._svg(fig)


def sweep_figs(res: dict, which: str) -> list[dict]:
    """Spectral radius (or largest real part) against the sample time or k_v, per scheme, the case marked:
    one figure per measure, so that a sampled loop's spectral radius (stable below 1) and a continuous
    loop's largest real part (stable below 0) never share an axis or a boundary."""
    curves = res.get("_curves") or {}
    kinds: dict[str, list[str]] = {}
    for scheme, c in curves.items():
        if c and which in c:
            key = "rho_T" if which == "T" else ("rho_k" if "rho_k" in c else "max_re_k")
            kinds.setdefault(key, []).append(scheme)
    figs = []
    for key, schemes in sorted(kinds.items(), key=lambda kv: kv[0] != "rho_k"):
        fig_id = f"analysis-sweep-{which}" + ("" if not figs else "-continuous")
        f = _sweep_fig(res, which, key, schemes, fig_id, mixed=len(kinds) > 1)
        if f is not None:
            figs.append(f)
    return figs


def _sweep_fig(res: dict, which: str, key: str, schemes: list[str], fig_id: str, mixed: bool) -> dict | None:
    """:func:`sweep_figs`' figure of one measure (``key``: rho_T, rho_k or max_re_k) for ``schemes``."""
    curves = res.get("_curves") or {}
    T_case = res.get("sample_time")
    traces, marks = [], []
    ylabel = {"rho_T": "spectral radius", "rho_k": "spectral radius", "max_re_k": "largest real part [1/s]"}[key]
    for i, (scheme, c) in enumerate(curves.items()):
        if scheme not in schemes:
            continue
        x = np.asarray(c[which], dtype=float)
        y = np.asarray(c[key], dtype=float)
        color = plots.SCHEME_COLORS.get(scheme, PHASE_COLORS[i % len(PHASE_COLORS)])
        traces.append({"type": "scatter", "mode": "lines", "x": [_r(v) for v in x * (1e3 if which == "T" else 1)],
                       "y": [_r(v) for v in y], "name": scheme, "line": {"color": color}})  # fmt: skip
        lim = res["limits"].get(scheme, {}).get("sample_time_max" if which == "T" else "k_v_max")
        if lim is not None:
            marks.append((scheme, lim * (1e3 if which == "T" else 1), color))
        own = T_case if which == "T" else res.get("k_v", {}).get(scheme)
        if own and x.size > 1 and x[0] <= own <= x[-1] and np.all(x > 0):
            at = float(np.interp(math.log(own), np.log(x), y))  # the curve at the case's own setting
            shown = own * (1e3 if which == "T" else 1)
            traces.append({"type": "scatter", "mode": "markers", "x": [_r(shown)], "y": [_r(at)],
                           "name": f"{scheme}: the case", "showlegend": False,
                           "marker": {"symbol": "circle-open", "size": 12, "color": color, "line": {"width": 2}},
                           "hovertext": f"{scheme}: the case's {'T_s' if which == 'T' else 'k_v'} {shown:.4g}, "
                                        f"{ylabel} {at:.4g}"})  # fmt: skip
    if not traces:
        return None
    edge = 0.0 if key == "max_re_k" else 1.0
    shapes = [{"type": "line", "xref": "paper", "yref": "y", "x0": 0, "x1": 1, "y0": edge, "y1": edge,
               "line": {"color": "black", "width": 1, "dash": "dot"}}]  # fmt: skip
    case_x = None
    if which == "T" and T_case:
        case_x = T_case * 1e3
    elif which == "k":
        ks = {v for sc, v in res.get("k_v", {}).items() if sc in schemes}
        case_x = next(iter(ks)) if len(ks) == 1 else None
    if case_x is not None:
        shapes.append({"type": "line", "xref": "x", "yref": "paper", "x0": case_x, "x1": case_x, "y0": 0, "y1": 1,
                       "line": {"color": "gray", "width": 2}})  # fmt: skip
    for scheme, x, color in marks:
        traces.append({"type": "scatter", "mode": "markers", "x": [_r(x)], "y": [edge], "name": f"{scheme} limit",
                       "marker": {"symbol": "diamond", "size": 10, "color": color}, "showlegend": False,
                       "hovertext": f"{scheme}: limit {x:.4g}"})  # fmt: skip
    xtitle = "sample time T [ms]" if which == "T" else "velocity gain k_v [1/s]"
    layout = {
        "height": 360,
        "margin": {"l": 60, "r": 20, "t": 30, "b": 50},
        "xaxis": {"title": {"text": xtitle}, "type": "log"},
        "yaxis": {"title": {"text": ylabel}, "type": "log" if edge == 1.0 else "linear"},
        "shapes": shapes,
        "legend": {"orientation": "h", "y": -0.25},
    }
    where = f"at the case's sample time {T_case * 1e3:g} ms" if T_case else "in continuous time"
    if which == "T":
        cap = ("Spectral radius of each scheme's sampled loop (healthy pattern, the case's gains) against the "
               "sample time; dotted: 1, grey line and open circles: the case's sample time, diamonds: the "
               "limits.")  # fmt: skip
    else:
        if mixed and key == "rho_k":  # a discrete filter in a continuous case: its own period
            periods = {(res["phases"].get(sc) or [{}])[0].get("sample_time") for sc in schemes} - {None}
            where = f"at its period {min(periods) * 1e3:g} ms" if len(periods) == 1 else "in discrete time"
        cap = (f"{ylabel.capitalize()} of each scheme's loop against its velocity gain k_v {where}; dotted: the "
               f"stability boundary ({edge:g}), grey line and open circles: the case's gain, diamonds: the "
               "limits.")  # fmt: skip
        if mixed:
            cap += (" The schemes analysed in discrete time (spectral radius) and in continuous time (largest real "
                    "part) are in separate figures.")  # fmt: skip
    spec = {"data": traces, "layout": layout}
    return _figure(fig_id, cap, spec, _sweep_svg(traces, shapes, layout))


def _sweep_svg(traces, shapes, layout) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 2.8))
    for tr in traces:
        if tr["mode"] == "lines":
            ax.plot(tr["x"], tr["y"], color=tr["line"]["color"], label=tr["name"])
        elif tr["marker"]["symbol"] == "circle-open":
            ax.plot(tr["x"], tr["y"], "o", mfc="none", color=tr["marker"]["color"], ms=7)
        else:
            ax.plot(tr["x"], tr["y"], "D", color=tr["marker"]["color"], ms=5)
    for s in shapes:
        if s["xref"] == "paper":
            ax.axhline(s["y0"], color="k", ls=":", lw=0.8)
        else:
            ax.axvline(s["x0"], color="0.5", lw=1.5)
    ax.set_xscale("log")
    if layout["yaxis"]["type"] == "log":
        ax.set_yscale("log")
    ax.set_xlabel(layout["xaxis"]["title"]["text"])
    ax.set_ylabel(layout["yaxis"]["title"]["text"])
    ax.legend(fontsize=6)
    return plots._svg(fig)


def bode_fig(res: dict) -> dict | None:
    """Bode plot of the loop with the least stability margin in each phase, one scheme at a time."""
    traces, groups, labels = [], [], []
    for scheme, phases in res["phases"].items():
        idx = []
        for i, p in enumerate(phases):
            b = (p.get("margins") or {}).get("_bode")
            if not b:
                continue
            color = PHASE_COLORS[i % len(PHASE_COLORS)]
            name = f"{p['t_start']:g}-{p['t_end']:g} s, input {b['input']}"
            idx += [len(traces), len(traces) + 1]
            traces.append({"type": "scatter", "mode": "lines", "x": [_r(w) for w in b["omega"]],
                           "y": [_r(v, 4) for v in b["mag_db"]], "name": name, "line": {"color": color},
                           "legendgroup": name, "visible": not groups})  # fmt: skip
            traces.append({"type": "scatter", "mode": "lines", "x": [_r(w) for w in b["omega"]],
                           "y": [_r(v, 4) for v in b["phase_deg"]], "name": name, "line": {"color": color},
                           "legendgroup": name, "showlegend": False, "xaxis": "x2", "yaxis": "y2",
                           "visible": not groups})  # fmt: skip
            for key, axis, text in (("gain_crossover", "x", "PM"), ("phase_crossover", "x2", "GM")):
                w = b.get(key)
                if w:
                    val = b.get("phase_margin_deg") if text == "PM" else b.get("gain_margin_db")
                    idx.append(len(traces))
                    # the phase crossover on the curve as drawn: its phase is wrapped, +180 deg where it wraps
                    y = 0.0 if text == "PM" else _phase_at(b["omega"], b["phase_deg"], w)
                    traces.append({"type": "scatter", "mode": "markers", "x": [_r(w)], "y": [_r(y, 4)],
                                   "xaxis": axis, "yaxis": "y" if axis == "x" else "y2", "showlegend": False,
                                   "marker": {"symbol": "circle-open", "size": 11, "color": color},
                                   "hovertext": f"{text} {val:.3g}" if val is not None else text,
                                   "visible": not groups})  # fmt: skip
        if idx:
            groups.append(idx)
            labels.append(scheme)
    if not traces:
        return None
    discrete = bool(res.get("sampled"))
    layout = {
        "height": 520,
        "margin": {"l": 60, "r": 20, "t": 60, "b": 50},
        "grid": {"rows": 2, "columns": 1, "pattern": "independent"},
        "xaxis": {"type": "log", "matches": "x2"},
        "yaxis": {"title": {"text": "|L| [dB]"}},
        "xaxis2": {"type": "log", "title": {"text": "frequency [rad/s]"}},
        "yaxis2": {"title": {"text": "phase of L [deg]"}},
        "shapes": [_hline("y", 0.0), _hline("y2", -180.0)],
        "updatemenus": _menu(labels, groups, len(traces)),
        "legend": {"orientation": "h", "y": -0.15},
    }
    upto = ", sampled: up to the Nyquist frequency" if discrete else ""
    cap = (
        "Bode plot of L = -K (sI - A)^-1 B broken at the actuator input with the least stability margin, per fault "
        f"phase ({res.get('actuator_input', 'torque')} inputs{upto}); circles: the gain crossover (phase margin read "
        "at 0 dB) and the phase crossover (gain margin read where the phase crosses -180 deg, drawn on the curve: "
        "+180 deg where the phase is wrapped)."
    )
    return _figure("analysis-bode", cap, {"data": traces, "layout": layout}, _bode_svg(res))


def _phase_at(omega, phase_deg, w: float) -> float:
    """The phase curve's own value at frequency ``w`` (log-frequency interpolation), as wrapped: at a wrap
    between two samples (a jump over 180 deg) the nearer sample's value, not a point inside the jump."""
    x, y = np.log(np.asarray(omega, dtype=float)), np.asarray(phase_deg, dtype=float)
    lw = math.log(w)
    if x.size < 2:
        return float(y[0])
    j = int(np.clip(np.searchsorted(x, lw), 1, x.size - 1))
    if abs(y[j] - y[j - 1]) > 180.0:
        return float(y[j] if abs(x[j] - lw) < abs(lw - x[j - 1]) else y[j - 1])
    return float(np.interp(lw, x, y))


def _hline(yref: str, y: float) -> dict:
    return {"type": "line", "xref": "paper", "yref": yref, "x0": 0, "x1": 1, "y0": y, "y1": y,
            "line": {"color": "black", "width": 1, "dash": "dot"}}  # fmt: skip


def _bode_svg(res: dict) -> str:
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6.5, 4.2), sharex=True)
    has = lambda ph: any((p.get("margins") or {}).get("_bode") for p in ph)  # noqa: E731
    scheme = next((s for s, ph in res["phases"].items() if has(ph)), None)
    for i, p in enumerate(res["phases"].get(scheme, [])):
        b = (p.get("margins") or {}).get("_bode")
        if not b:
            continue
        c = PHASE_COLORS[i % len(PHASE_COLORS)]
        a1.semilogx(b["omega"], b["mag_db"], color=c, label=f"{p['t_start']:g}-{p['t_end']:g} s ({b['input']})")
        a2.semilogx(b["omega"], b["phase_deg"], color=c)
    a1.axhline(0, color="k", ls=":", lw=0.8)
    a2.axhline(-180, color="k", ls=":", lw=0.8)
    a1.set_ylabel("|L| [dB]")
    a2.set_ylabel("phase [deg]")
    a2.set_xlabel("frequency [rad/s]")
    a1.set_title(f"{scheme}: the loop with the least stability margin per phase", fontsize=8)
    a1.legend(fontsize=6)
    return plots._svg(fig)


def _classic_figures(res: dict, series: dict, events: list[float], duration: float) -> list[dict]:
    """The case-wide analyses' figures: frozen-time or chained-form pole loci, the predicted decay."""
    figs = []
    ft = res.get("frozen_time")
    if ft:
        step = max(1, len(ft["times"]) // 60)
        loci = list(zip(ft["times"][::step], ft["poles"][::step], strict=True))
        figs.append({"id": "pole-loci", "svg": plots.pole_loci_svg(loci, "t [s]"),
                     "caption": "Frozen-time poles of the closed-loop error dynamics along the reference, healthy "
                     "wheels (red line: imaginary axis)."})  # fmt: skip
    ch = res.get("chained")
    if ch:
        first = next(iter(ch.values()))
        loci = [(f["phi_deg"], f["poles"]) for f in first["frozen"]]
        figs.append({"id": "pole-loci", "svg": plots.pole_loci_svg(loci, "theta_nd - psi [deg]"),
                     "caption": "Frozen poles of the chained-form loop over one re-anchoring period; the Floquet "
                     f"rate of the period is {first['floquet_rate']:.4g} 1/s."})  # fmt: skip
    rate = res.get("predicted_decay_rate")
    if rate and series:
        scheme = "nominal" if "nominal" in series else next(iter(series))
        t_end = min([duration, *[t for t in events if t > 0]])
        fit = plots.fitted_decay_rate(series[scheme], t_end)
        res["fitted_decay"] = None
        if fit is not None:
            fitted, ta, tb, decays = fit
            # one phrase for the caption and the text below the tables: the same window, the same value
            words = (
                f"fitted rate {fitted:.3g} 1/s over {ta:.3g}-{tb:.3g} s"
                if decays
                else f"over {ta:.3g}-{tb:.3g} s the error does not decay here (limit cycle or offset): no rate fitted"
            )
            res["fitted_decay"] = {"scheme": scheme, "rate": fitted if decays else None, "from": ta, "to": tb,
                                   "decays": decays, "words": words}  # fmt: skip
            cap = (
                f"Predicted envelope (rate {rate:.3g} 1/s) against the simulated error of the {scheme} run before "
                f"the first fault ({words})."
            )
            figs.append({"id": "decay", "svg": plots.decay_svg(series[scheme], rate, (ta, tb), scheme), "caption": cap})
    if res.get("sampled") or res.get("actuator_input", "torque") != "torque":
        for f in figs:  # these are of the laws on the ideal plant, not of the loop the tables above analyse
            f["caption"] += (" Of the ideal plant in continuous time (the case-wide analyses below), not this case's "
                             "loop with its sampling and motors: that one is analysed above.")  # fmt: skip
    return figs
