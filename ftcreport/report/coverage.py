"""Coverage page: per-scheme fault tables and heatmaps beside the redundancy rule's prediction (HTML edge)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np

from ..model import wheel_names
from . import plots
from .render import figure, write_page

__all__ = ["coverage_grids", "render_coverage"]


def coverage_grids(summary: dict, n: int) -> dict:
    """The maps as arrays: ``single`` (wheels x columns) and ``pairs`` (wheels x wheels).

    Per scheme the fraction of onsets recovered (NaN where not run); ``predicted`` is 1 where
    the rule (2.103) says compensable, 0 where not.  Columns: loss, sigma=..., friction.
    """
    wheels = list(wheel_names(n))
    first = next(iter(summary["schemes"].values()), {"faults": {}})["faults"]
    cols = []
    for e in first.values():
        if e["kind"] != "pair" and e["column"] not in cols:
            cols.append(e["column"])
    cols.sort(key=lambda c: (c != "loss", c == "friction", c))
    out: dict = {"wheels": wheels, "columns": cols, "single": {}, "pairs": {}}
    pred_s = np.full((len(wheels), len(cols)), np.nan)
    pred_p = np.full((len(wheels), len(wheels)), np.nan)
    for s, entry in summary["schemes"].items():
        g = np.full((len(wheels), len(cols)), np.nan)
        p = np.full((len(wheels), len(wheels)), np.nan)
        for e in entry["faults"].values():
            ws = e["wheels"].split("+")
            if e["kind"] == "pair":
                i, j = sorted(wheels.index(w) for w in ws)
                p[i, j] = p[j, i] = e["recovered_fraction"]
                pred_p[i, j] = pred_p[j, i] = float(e["predicted_compensable"])
            else:
                i, c = wheels.index(ws[0]), cols.index(e["column"])
                g[i, c] = e["recovered_fraction"]
                pred_s[i, c] = float(e["predicted_compensable"])
        out["single"][s], out["pairs"][s] = g, p
    out["predicted_single"], out["predicted_pairs"] = pred_s, pred_p
    return out


def _heat(ax, grid, pred, xlabels, ylabels, title) -> None:
    cmap = plt.get_cmap("RdYlGn").with_extremes(bad="#eeeeee")
    rows, cols = grid.shape
    im = ax.imshow(
        np.ma.masked_invalid(grid),
        vmin=0.0,
        vmax=1.0,
        cmap=cmap,
        aspect="auto",
        origin="upper",
        interpolation="nearest",
        extent=(-0.5, cols - 0.5, rows - 0.5, -0.5),
    )
    ax.grid(False)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            if np.isfinite(pred[i, j]) and pred[i, j] == 0.0:
                ax.text(j, i, "X", ha="center", va="center", fontsize=11, fontweight="bold", color="k")
            elif np.isfinite(grid[i, j]):
                ax.text(j, i, f"{grid[i, j]:.2g}", ha="center", va="center", fontsize=6, color="k")
    ax.set_xticks(range(len(xlabels)), xlabels, fontsize=6, rotation=30)
    ax.set_yticks(range(len(ylabels)), ylabels, fontsize=7)
    ax.set_title(title, fontsize=8)
    return im


def _map_svg(grids: dict, key: str, xlabels: list[str]) -> str:
    schemes = list(grids[key])
    pred = grids[f"predicted_{key}"]
    fig, axes = plt.subplots(1, len(schemes) + 1, figsize=(1.6 + 1.7 * (len(schemes) + 1), 2.4), squeeze=False)
    _heat(axes[0, 0], pred, pred, xlabels, grids["wheels"], "predicted (2.103)")
    im = None
    for ax, s in zip(axes[0, 1:], schemes, strict=True):
        im = _heat(ax, grids[key][s], pred, xlabels, grids["wheels"], f"simulated: {s}")
        ax.set_yticklabels([])
    if im is not None:
        fig.colorbar(im, ax=axes[0, :].tolist(), shrink=0.8, label="onsets recovered")
    return plots._svg(fig)


def render_coverage(out: Path) -> Path:
    """Write ``index.html`` of a coverage directory from its ``summary.json`` and ``coverage.json``."""
    out = Path(out)
    meta = json.loads((out / "coverage.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    grids = coverage_grids(summary, int(meta["n"]))
    figures = []
    if grids["columns"]:
        figures.append(
            figure(
                "single",
                "Single-wheel faults (wheels x fault kinds): the rule's prediction (green compensable, "
                "X uncompensable) beside the fraction of onset times each scheme recovered from.",
                svg=_map_svg(grids, "single", grids["columns"]),
            )
        )
    if any(np.isfinite(g).any() for g in grids["pairs"].values()):
        figures.append(
            figure(
                "pairs",
                "Pairs of wheel losses (wheel x wheel): prediction and fraction of onsets recovered.",
                svg=_map_svg(grids, "pairs", grids["wheels"]),
            )
        )
    return write_page(
        out / "index.html",
        "coverage.html",
        "../../",
        meta=meta,
        summary=summary,
        figures=figures,
    )
