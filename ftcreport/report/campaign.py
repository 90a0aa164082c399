"""Campaign report: success rates with Wilson intervals, distributions, worst patterns (HTML at the edge)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np

from ..campaign import summarize
from ..store import _jsonable, write_atomic
from . import plots
from .render import figure, write_page

__all__ = ["render_campaign"]


def _rates_svg(summary: dict) -> str:
    names = list(summary["schemes"])
    fig, ax = plt.subplots(figsize=(6.4, 2.4))
    for i, s in enumerate(names):
        e = summary["schemes"][s]
        rate = e["rate"] or 0.0
        ax.bar(i, rate, color=plots.SCHEME_COLORS.get(s, "0.5"))
        ax.errorbar(i, rate, yerr=[[rate - e["wilson_low"]], [e["wilson_high"] - rate]], color="k", capsize=4)
    ax.set_xticks(range(len(names)), names)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate (95 % Wilson)")
    return plots._svg(fig)


def _hist_svg(summary: dict, key: str, label: str, log: bool) -> str:
    fig, ax = plt.subplots(figsize=(6.4, 2.4))
    data = [np.asarray(e[key], dtype=float) for e in summary["schemes"].values()]
    data = [d[np.isfinite(d)] for d in data]
    allv = np.concatenate(data) if data else np.zeros(0)
    if allv.size:
        lo, hi = allv.min(), allv.max()
        if log:
            lo = max(lo, 1e-9)
            bins = np.logspace(np.log10(lo), np.log10(max(hi, lo * 10)), 30)
            ax.set_xscale("log")
        else:
            bins = np.linspace(lo, max(hi, lo + 1e-9), 30)
        for s, d in zip(summary["schemes"], data, strict=True):
            if d.size:
                ax.hist(d, bins=bins, histtype="step", lw=1.2, color=plots.SCHEME_COLORS.get(s, "0.5"), label=s)
        ax.legend(fontsize=6)
    ax.set_xlabel(label)
    ax.set_ylabel("samples")
    return plots._svg(fig)


def render_campaign(out: Path, rows: list[dict]) -> Path:
    """Write ``summary.json`` and ``index.html`` of a campaign directory from its table rows."""
    out = Path(out)
    summary = summarize(rows)
    meta_path = out / "campaign.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    write_atomic(out / "summary.json", json.dumps(_jsonable(summary), indent=1).encode())
    figures = []
    if rows:
        figures = [
            figure("rates", "Success rate per scheme with 95 % Wilson intervals.", svg=_rates_svg(summary)),
            figure(
                "max-error",
                "Distribution of the maximum position error per sample.",
                svg=_hist_svg(summary, "max_errors", "max position error [m]", True),
            ),
            figure(
                "recovery",
                "Distribution of the recovery time (samples that never recover are counted in the table).",
                svg=_hist_svg(summary, "recovery_times", "recovery time max [s]", False),
            ),
        ]
    return write_page(
        out / "index.html",
        "campaign.html",
        "../../",
        name=meta.get("case", out.name),
        seed=meta.get("seed"),
        success=(meta.get("base", {}).get("campaign") or {}).get("success", {}),
        summary=summary,
        figures=figures,
    )
