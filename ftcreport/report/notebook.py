"""Notebook views (``_repr_html_``): a summary table and one small inline SVG figure.

:func:`run_html` shows a :class:`~ftcreport.sim.Run`; :func:`case_html` a case's stored results
(:class:`ftcreport.storage.results.CaseResults`).  Both are self-contained HTML (escaped text, inline SVG).
"""

from __future__ import annotations

import html
import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from ..sim import Run
    from ..storage.results import CaseResults

__all__ = ["case_html", "error_figure", "run_html"]

_STYLE = (
    "<style>.ftc-nb table{border-collapse:collapse;font-size:12px}"
    ".ftc-nb td,.ftc-nb th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:right}"
    ".ftc-nb td.l,.ftc-nb th.l{text-align:left}.ftc-nb svg{max-width:480px;height:auto}</style>"
)


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return str(x)
    if isinstance(x, int | np.integer):
        return str(int(x))
    if isinstance(x, float | np.floating):
        return "-" if not math.isfinite(float(x)) else f"{float(x):.4g}"
    return html.escape(str(x))


def _position_error(signals: dict[str, np.ndarray]) -> np.ndarray | None:
    if "q" not in signals or "q_d" not in signals:
        return None
    q, qd = np.asarray(signals["q"]), np.asarray(signals["q_d"])
    return np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])


def error_figure(series: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]], events: list[float]) -> str:
    """Small SVG: position error of P_n against time per label (log scale), or the path when there is
    no reference; fault events as dotted lines.  ``series``: label -> (t, signals)."""
    from . import plots

    fig, ax = plots.plt.subplots(figsize=(4.6, 1.8))
    drawn = False
    for label, (t, sig) in series.items():
        err = _position_error(sig)
        color = plots.SCHEME_COLORS.get(label)
        if err is not None and t.size > 1:
            ax.semilogy(t, np.maximum(err, 1e-12), lw=1.0, label=label, color=color)
            ax.set_xlabel("t [s]")
            ax.set_ylabel("position error [m]")
            drawn = True
        elif "q" in sig and t.size > 1:
            ax.plot(sig["q"][:, 0], sig["q"][:, 1], lw=1.0, label=label, color=color)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            drawn = True
    if not drawn:
        plots.plt.close(fig)
        return ""
    if ax.get_xlabel() == "t [s]":
        for t_ev in events:
            ax.axvline(t_ev, color="k", lw=0.6, ls=":")
    if len(series) > 1:
        ax.legend(fontsize=6, ncol=min(4, len(series)), loc="best")
    return plots._svg(fig)


def _table(rows: list[tuple[str, Any]]) -> str:
    body = "".join(f"<tr><th class='l'>{html.escape(k)}</th><td class='l'>{_fmt(v)}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def run_html(run: Run) -> str:
    """Summary (case, scheme, status, engine, times, errors, signals) and the error figure of one run."""
    meta = run.meta
    err = _position_error(run.signals)
    rows: list[tuple[str, Any]] = []
    if meta.get("case"):
        rows.append(("case / scheme", f"{meta.get('case')} / {meta.get('scheme', '?')}"))
    rows += [
        ("status", run.status + (f": {run.reason}" if run.reason else "")),
        ("simulated", f"{run.t_end:g} s, {run.t.size} logged instants" + (f", {run.steps} steps" if run.steps else "")),
        ("engine", meta.get("engine", "python")),
        ("wall time [s]", run.wall_time),
    ]
    if err is not None and err.size:
        rows += [("position error max [m]", float(np.max(err))), ("position error final [m]", float(err[-1]))]
    faults = meta.get("fault_schedule") or []
    if faults:
        rows.append(
            (
                "faults",
                "; ".join(f"{f['time']:g} s {f['wheel']} sigma {f['sigma']:g} ubar {f['ubar']:g}" for f in faults),
            )
        )
    rows.append(("signals", ", ".join(f"{k} {tuple(v.shape)}" for k, v in run.signals.items())))
    label = meta.get("scheme") or "run"
    svg = error_figure({label: (np.asarray(run.t), run.signals)}, [f["time"] for f in faults])
    return f"<div class='ftc-nb'>{_STYLE}{_table(rows)}{svg}</div>"


_COLUMNS = (
    ("scheme", "scheme"),
    ("status", "status"),
    ("engine", "engine"),
    ("position_error_final", "final error [m]"),
    ("position_error_max", "max error [m]"),
    ("recovery_time_max", "recovery max [s]"),
    ("torque_peak", "peak torque [N m]"),
    ("switching_match_fraction", "match"),
    ("wall_time", "wall [s]"),
)


def case_html(res: CaseResults) -> str:
    """The scheme comparison table of a case and the position errors of every scheme in one figure."""
    head = "".join(f"<th>{html.escape(label)}</th>" for _, label in _COLUMNS)
    body = []
    for m in res.metrics_by_scheme().values():
        cells = "".join(
            f"<td{' class=l' if k in ('scheme', 'status', 'engine') else ''}>{_fmt(m.get(k))}</td>" for k, _ in _COLUMNS
        )
        body.append(f"<tr>{cells}</tr>")
    series = {}
    for s in res.schemes:
        run = res.run(s)
        if run is not None and run.t.size > 1:
            series[s] = (np.asarray(run.t), run.signals)
    faults = res.fault_schedule()
    svg = error_figure(series, [f["time"] for f in faults]) if series else ""
    title = f"<p><b>{html.escape(res.name)}</b> ({len(series)} stored run(s) in {html.escape(str(res.root))})</p>"
    return f"<div class='ftc-nb'>{_STYLE}{title}<table><tr>{head}</tr>{''.join(body)}</table>{svg}</div>"
