"""Coverage page: per-scheme fault tables and maps (HTML tables, colored) beside the redundancy rule's
prediction (HTML edge)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np

from ..model import wheel_names
from ..studies.coverage import DEFAULT_CRITERIA, recovery_bound
from .render import index_root, write_page

__all__ = ["coverage_grids", "kinds_text", "map_tables", "render_coverage"]


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


def kinds_text(meta: dict) -> str:
    """The kinds of fault the coverage ran, in words, each with its settings (``coverage.json``'s ``kinds``,
    ``sigmas``, ``friction``): only the kinds run are named (``--kinds loss,pair`` has no sigma)."""
    kinds = list(meta.get("kinds") or [])
    words = {
        "loss": "single-wheel losses",
        "pair": "pairs of losses",
        "partial": f"partial losses (sigma in {', '.join(f'{x:g}' for x in meta.get('sigmas') or [])})",
        "friction": f"a friction of ubar = {meta.get('friction', 0):g} N m per wheel",
    }
    parts = [words.get(k, k) for k in kinds]
    if len(parts) < 2:
        return parts[0] if parts else "no fault"
    return ", ".join(parts[:-1]) + " and " + parts[-1]


def _cell_color(x: float) -> str:
    """Background of a map cell: red (0) through yellow to green (1) (matplotlib's RdYlGn), grey if not run."""
    if not np.isfinite(x):
        return "#eeeeee"
    r, g, b, _ = plt.get_cmap("RdYlGn")(0.15 + 0.7 * float(x))
    return f"rgb({int(255 * r)},{int(255 * g)},{int(255 * b)})"


def map_tables(grids: dict, key: str, xlabels: list[str]) -> list[dict]:
    """The maps as HTML tables (numbers at the text's size): the rule's prediction, then one per scheme.

    Each table: ``title`` and ``rows`` of (wheel, cells); a cell has ``text`` (the fraction of onsets
    recovered, or X where the rule says uncompensable, with the fraction beside it), ``color`` and
    ``title`` (hover text).
    """
    pred = grids[f"predicted_{key}"]
    tables = []
    for name, grid in [("predicted (2.103)", pred), *[(f"simulated: {s}", g) for s, g in grids[key].items()]]:
        rows = []
        for i, w in enumerate(grids["wheels"]):
            cells = []
            for j, c in enumerate(xlabels):
                x, p = grid[i, j], pred[i, j]
                fault = f"{w} {c}" if key == "single" else f"{w}+{c}"
                if not np.isfinite(p):
                    cells.append({"text": "", "color": "#f7f7f7", "title": ""})
                    continue
                if grid is pred:
                    text, title = ("ok", f"{fault}: compensable") if p == 1.0 else ("X", f"{fault}: uncompensable")
                    color = _cell_color(1.0 if p == 1.0 else 0.0)
                else:
                    frac = "-" if not np.isfinite(x) else f"{x:.2g}"
                    text = frac if p == 1.0 else f"X {frac}"
                    title = f"{fault}: {frac} of the onsets recovered" + (
                        "" if p == 1.0 else " (uncompensable by the rule)"
                    )
                    color = _cell_color(x)
                cells.append({"text": text, "color": color, "title": title})
            rows.append({"wheel": w, "cells": cells})
        tables.append({"title": name, "columns": xlabels, "rows": rows})
    return tables


def criteria_text(criteria: dict) -> str:
    """The success criteria in one line: 'position_error_final <= 0.05' (what "recovered" means on the page)."""
    bits = []
    for m, b in criteria.items():
        if (b or {}).get("min") is not None:
            bits.append(f"{m} \u2265 {b['min']:g}")
        if (b or {}).get("max") is not None:
            bits.append(f"{m} \u2264 {b['max']:g}")
    return ", ".join(bits) or "none"


def render_coverage(out: Path) -> Path:
    """Write ``index.html`` of a coverage directory from its ``summary.json`` and ``coverage.json``.

    "Recovered" here is the case's success criteria (its ``[campaign] success``, else
    :data:`~ftcreport.studies.coverage.DEFAULT_CRITERIA`); a campaign page's "never recovered" is the case's
    ``recovery_band`` instead.  The page names the criteria, where they come from and the other meaning
    wherever it uses the word (``criteria_words``, ``criteria_from``, ``band``)."""
    out = Path(out)
    meta = json.loads((out / "coverage.json").read_text())
    base = meta.get("base") or {}
    stated = (base.get("campaign") or {}).get("success")
    criteria = stated or DEFAULT_CRITERIA
    words = criteria_text(criteria)
    summary = json.loads((out / "summary.json").read_text())
    grids = coverage_grids(summary, int(meta["n"]))
    maps = []
    if grids["columns"]:
        maps.append(
            {
                "id": "single",
                "caption": "Single-wheel faults (wheels x fault kinds): the rule's prediction (X uncompensable) beside "
                f"the fraction of onset times each scheme recovered from (met {words}; green 1, red 0; hover a "
                "cell: its fault).",
                "tables": map_tables(grids, "single", grids["columns"]),
            }
        )
    if any(np.isfinite(g).any() for g in grids["pairs"].values()):
        maps.append(
            {
                "id": "pairs",
                "caption": "Pairs of wheel losses (wheel x wheel): prediction and fraction of onsets recovered "
                f"(met {words}).",
                "tables": map_tables(grids, "pairs", grids["wheels"]),
            }
        )
    band = base.get("recovery_band", 0.01)
    bound = recovery_bound(criteria, band)
    return write_page(
        out / "index.html",
        "coverage.html",
        index_root(out),
        meta=meta,
        kinds=kinds_text(meta),
        summary=summary,
        maps=maps,
        criteria=criteria,
        criteria_words=words,
        criteria_from="the case's [campaign] success" if stated else "the default (the case has no [campaign] success)",
        band=band,
        bound=bound,
    )
