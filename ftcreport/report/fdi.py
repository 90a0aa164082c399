"""FDI evaluation page: one ROC per detector with its recommended operating point, delay against false
alarms, isolation; the sweep tables folded (HTML at the edge)."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt

from . import plots
from .render import figure, index_root, write_page

__all__ = ["FAR_BUDGET", "operating_point", "render_fdi"]

#: The false-alarm budget of the recommended operating point [false alarms per hour of fault-free time].
FAR_BUDGET = 1.0
DETECTORS = {
    "estimate": ("estimate-based", "dwell", "dwell {:g} s", ("threshold", "dwell")),
    "residual": ("CUSUM residual", "drift", "drift {:g}", ("h", "drift")),
}
RULE = (
    f"the setting with the highest detection probability among those with at most {FAR_BUDGET:g} false alarm per "
    "hour of fault-free time (ties: the shorter mean delay); when none is within the budget, the fewest false alarms"
)


def operating_point(points: list[dict]) -> dict | None:
    """The recommended setting of a detector's sweep (:data:`RULE`), or None when no point has a
    detection probability and a false-alarm rate."""
    pts = [p for p in points if p.get("pd") is not None and p.get("far_per_hour") is not None]
    if not pts:
        return None
    delay = lambda p: p["mean_delay"] if p.get("mean_delay") is not None else float("inf")  # noqa: E731
    within = [p for p in pts if p["far_per_hour"] <= FAR_BUDGET]
    if within:
        return min(within, key=lambda p: (-p["pd"], delay(p)))
    return min(pts, key=lambda p: (p["far_per_hour"], -p["pd"], delay(p)))


def _roc_svg(points: list[dict], detector: str, best: dict | None, n: int) -> str:
    """One detector's ROC: a line per value of its second parameter (dwell or drift) through the swept
    first one, the false-alarm axis linear below 0.1 per hour (symlog: 0 is on it), the budget dashed,
    the recommended point starred."""
    label, group, fmt, _keys = DETECTORS[detector]
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    for i, g in enumerate(sorted({p[group] for p in points})):
        pts = sorted(
            (p for p in points if p[group] == g and p["far_per_hour"] is not None and p["pd"] is not None),
            key=lambda p: (p["far_per_hour"], p["pd"]),
        )
        if pts:
            ax.plot(
                [p["far_per_hour"] for p in pts],
                [p["pd"] for p in pts],
                "-o",
                ms=3.5,
                lw=1.1,
                color=f"C{i}",
                label=fmt.format(g),
            )
    ax.axvline(FAR_BUDGET, color="0.4", ls="--", lw=0.8)
    if best is not None:
        ax.plot([best["far_per_hour"]], [best["pd"]], "*", ms=14, color="#b00020", label="recommended", zorder=5)
    ax.set_xscale("symlog", linthresh=0.1)
    ax.set_xlim(left=-0.02)
    ax.set_ylim(-0.03, 1.05)
    ax.set_xlabel("false alarms per hour of fault-free time (linear below 0.1; dashed: the budget)")
    ax.set_ylabel("detection probability")
    ax.set_title(f"{label} detector, {n} samples", fontsize=8)
    ax.legend(fontsize=6, loc="lower right")
    return plots._svg(fig)


def _delay_svg(res: dict) -> str:
    """Mean detection delay against false alarms, both detectors."""
    fig, ax = plt.subplots(figsize=(6.4, 2.6))
    i = 0
    for det, (label, group, fmt, _keys) in DETECTORS.items():
        for g in sorted({p[group] for p in res[det]}):
            pts = sorted(
                (
                    p
                    for p in res[det]
                    if p[group] == g and p["far_per_hour"] is not None and p["mean_delay"] is not None
                ),
                key=lambda p: p["far_per_hour"],
            )
            if pts:
                ax.plot(
                    [p["far_per_hour"] for p in pts],
                    [p["mean_delay"] for p in pts],
                    "-o" if det == "estimate" else "--s",
                    ms=3,
                    color=f"C{i}",
                    label=f"{label}, {fmt.format(g)}",
                )
            i += 1
    ax.set_xscale("symlog", linthresh=0.1)
    ax.set_xlabel("false alarms per hour of fault-free time (linear below 0.1)")
    ax.set_ylabel("mean detection delay [s]")
    ax.legend(fontsize=6)
    return plots._svg(fig)


def render_fdi(out: Path) -> Path:
    """Write ``index.html`` of an FDI directory from its ``fdi.json``."""
    out = Path(out)
    result = json.loads((out / "fdi.json").read_text())
    figures, recommended = [], []
    for s, res in result["schemes_results"].items():
        if not res["n_samples"]:
            continue
        for det, (label, _group, _fmt, keys) in DETECTORS.items():
            best = operating_point(res[det])
            if best is not None:
                setting = ", ".join(f"{k} = {best[k]:g}" for k in keys)
                recommended.append({"scheme": s, "detector": label, "setting": setting, **best})
            roc = _roc_svg(res[det], det, best, res["n_samples"])
            figures.append(
                figure(
                    f"{s}-roc-{det}",
                    f"{s}, {label} detector: ROC (detection probability against false alarms per hour); "
                    f"star: the recommended operating point ({RULE}).",
                    svg=roc,
                )
            )
        figures.append(
            figure(f"{s}-delay", f"{s}: mean detection delay against false alarms per hour.", svg=_delay_svg(res))
        )
    return write_page(
        out / "index.html",
        "fdi.html",
        index_root(out),
        result=result,
        figures=figures,
        recommended=recommended,
        rule=RULE,
    )
