"""FDI evaluation page: ROC, delay against false alarms, isolation, both detectors (HTML at the edge)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt

from . import plots
from .render import figure, write_page

__all__ = ["render_fdi"]


def _curves(res: dict) -> list[tuple[str, list[dict]]]:
    out = []
    for dwell in sorted({p["dwell"] for p in res["estimate"]}):
        out.append((f"estimate, dwell {dwell:g} s", [p for p in res["estimate"] if p["dwell"] == dwell]))
    for drift in sorted({p["drift"] for p in res["residual"]}):
        out.append((f"CUSUM residual, drift {drift:g}", [p for p in res["residual"] if p["drift"] == drift]))
    return out


def _svg(res: dict, y: str, ylabel: str) -> str:
    fig, ax = plt.subplots(figsize=(6.4, 2.8))
    for i, (label, pts) in enumerate(_curves(res)):
        pts = [p for p in pts if p["far_per_hour"] is not None and p[y] is not None]
        pts.sort(key=lambda p: p["far_per_hour"])
        ls = "-" if label.startswith("estimate") else "--"
        ax.plot([p["far_per_hour"] + 1e-1 for p in pts], [p[y] for p in pts], ls, marker="o", ms=3, label=label,
                color=f"C{i}")  # fmt: skip
    ax.set_xscale("log")
    ax.set_xlabel("false alarms per hour of fault-free time (+0.1 to show 0)")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=6)
    return plots._svg(fig)


def render_fdi(out: Path) -> Path:
    """Write ``index.html`` of an FDI directory from its ``fdi.json``."""
    out = Path(out)
    result = json.loads((out / "fdi.json").read_text())
    figures = []
    for s, res in result["schemes_results"].items():
        if not res["n_samples"]:
            continue
        roc = _svg(res, "pd", "detection probability")
        figures.append(figure(f"{s}-roc", f"{s}: ROC, detection probability against false alarms per hour.", svg=roc))
        delay = _svg(res, "mean_delay", "mean detection delay [s]")
        figures.append(figure(f"{s}-delay", f"{s}: mean detection delay against false alarms per hour.", svg=delay))
    return write_page(out / "index.html", "fdi.html", "../../", result=result, figures=figures)
