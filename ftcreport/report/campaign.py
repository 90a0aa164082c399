"""Campaign report: success rates with Wilson intervals, distributions, worst patterns, a page per
failing sample (HTML at the edge).

The page (``<campaign>/index.html``) shows the rates, the paired comparisons as one matrix per metric
(a cell: who wins, with the p-value or the confidence interval on hover), the distributions as ECDFs
(every scheme visible, none hidden behind another's bars), and the failing samples, each linked to
its own page.  A sample's page is an ordinary case page (replay, figures, verdict) of the sample's
variant, re-simulated from its seeds (:func:`render_sample`): the worst :data:`WORST_K` failing
samples are rendered with the campaign, any other on demand (``ftcreport sample DIR INDEX``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np

from ..errors import FtcError
from ..evaluation.compare import BOUND
from ..storage.store import _jsonable, read_json, write_atomic
from ..studies.campaign import COMPARED_METRICS, PAGES, completed, summarize
from . import plots
from .render import figure, index_root, write_page

__all__ = [
    "PAGES",
    "WORST_K",
    "check_sample_content",
    "check_sample_index",
    "coincide_note",
    "coinciding",
    "comparison_matrices",
    "failing_samples",
    "render_campaign",
    "render_sample",
]

WORST_K = 3  # failing samples whose page the campaign renders (the others: ``ftcreport sample``)
LINESTYLES = ("-", "--", "-.", ":")
#: hollow markers, largest first, for schemes whose ECDF lines coincide (drawn concentric, all visible)
MARKERS = (("o", 10.0), ("s", 7.0), ("^", 5.0), ("D", 3.5), ("v", 2.5))
#: two schemes' ECDFs coincide when their sorted samples agree within this relative tolerance (on the
#: figure's log scale 2 % is under a line's width)
COINCIDE_RTOL = 0.02


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


def _samples(e: dict, key: str, log: bool) -> np.ndarray:
    d = np.sort(np.asarray(e[key], dtype=float))
    return d[np.isfinite(d) & ((d > 0) if log else True)]


def coinciding(summary: dict, key: str, log: bool = False) -> list[list[str]]:
    """Groups of two or more schemes whose ECDFs of ``key`` coincide: as many samples with a value, and
    the sorted values equal within :data:`COINCIDE_RTOL` (the lines would be drawn over each other)."""
    groups: list[list[str]] = []
    for s, e in summary["schemes"].items():
        d = _samples(e, key, log)
        if not d.size:
            continue
        for g in groups:
            ref = _samples(summary["schemes"][g[0]], key, log)
            same_n = ref.size == d.size == len(summary["schemes"][g[0]][key]) == len(e[key])
            if same_n and np.allclose(d, ref, rtol=COINCIDE_RTOL, atol=0.0):
                g.append(s)
                break
        else:
            groups.append([s])
    return [g for g in groups if len(g) > 1]


def _names(xs: list[str]) -> str:
    return xs[0] if len(xs) == 1 else ", ".join(xs[:-1]) + " and " + xs[-1]


def coincide_note(summary: dict, rows: list[dict], key: str, log: bool, what: str) -> str:
    """The caption's sentence on the schemes whose ECDF lines coincide (:func:`coinciding`), and the metric
    that separates them: the final error, when its medians differ beyond the tolerance ("" if none do)."""
    out = []
    for g in coinciding(summary, key, log):
        text = (
            f" {_names(g)} coincide (the same {what} within {100 * COINCIDE_RTOL:g} % on every sample); "
            "their lines carry hollow markers of decreasing size"
        )
        fin = {}
        for s in g:
            v = [r.get("position_error_final") for r in rows if r.get("scheme") == s and completed(r)]
            v = [float(x) for x in v if isinstance(x, int | float) and math.isfinite(x)]
            if v:
                fin[s] = float(np.median(v))
        if len(fin) == len(g) and max(fin.values()) > (1 + COINCIDE_RTOL) * min(fin.values()):
            medians = ", ".join(f"{s} {v:.3g} m" for s, v in fin.items())
            text += f"; the final error separates them (medians {medians}; see its matrix above)"
        out.append(text + ".")
    return "".join(out)


def _ecdf_svg(summary: dict, key: str, label: str, log: bool, never: str | None = None) -> str:
    """Empirical CDFs of a per-sample value, one step line per scheme (its own line style and width); the
    schemes whose lines coincide (:func:`coinciding`) carry concentric hollow markers and say so in the
    legend.  The fraction of a scheme's completed runs without a value (e.g. never recovered) is where its line
    ends below 1; the runs that stopped early are no sample of the distribution (their metrics cover a
    truncated horizon: :func:`ftcreport.studies.campaign.completed`), so they are counted in the legend, not
    in the fraction."""
    fig, ax = plt.subplots(figsize=(6.4, 2.8))
    same = {s: g for g in coinciding(summary, key, log) for s in g}
    for i, (s, e) in enumerate(summary["schemes"].items()):
        d = _samples(e, key, log)
        n = max(int(e.get("completed", e.get("n")) or 0), d.size, 1)
        if not d.size:
            continue
        y = np.arange(1, d.size + 1) / n
        style: dict = {}
        stops = sum((e.get("stopped") or {}).values())
        tail = f"; {stops} stopped" if stops else ""
        label_s = f"{s} ({d.size}/{n}{tail})"
        if s in same:
            j = same[s].index(s)
            style = {"marker": MARKERS[j % len(MARKERS)][0], "ms": MARKERS[j % len(MARKERS)][1], "mfc": "none"}
            label_s = f"{s} ({d.size}/{n}{tail}; coincides with {_names([x for x in same[s] if x != s])})"
        ax.step(
            np.r_[d[0], d],
            np.r_[0.0, y],
            where="post",
            lw=2.2 - 0.4 * (i % 4),
            ls=LINESTYLES[i % len(LINESTYLES)],
            color=plots.SCHEME_COLORS.get(s, f"C{i}"),
            label=label_s,
            **style,
        )
    if log and ax.lines:
        ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(label)
    ax.set_ylabel("fraction of samples <= x")
    if ax.lines:
        ax.legend(fontsize=6, loc="lower right", title=never, title_fontsize=6)
    else:
        ax.text(0.5, 0.5, "no sample has a value", ha="center", va="center", transform=ax.transAxes)
    return plots._svg(fig)


def comparison_matrices(summary: dict) -> list[dict]:
    """The paired comparisons as one scheme x scheme matrix per metric.

    A cell (row A, column B): ``A`` when A beats B significantly, ``B`` when B beats A, ``n.s.``
    otherwise, ``not judged`` for a metric on fewer pairs than a verdict needs
    (:func:`ftcreport.evaluation.stats.min_pairs`), with the numbers (McNemar's p, or the mean difference
    and its 95 % CI) in ``title`` for hover and ``short`` in the cell; ``cls`` colors it (win, loss, ns,
    nj: not judged).
    """
    comps = summary.get("comparisons") or []
    schemes = list(summary["schemes"])
    out = []
    for metric in ("success", *COMPARED_METRICS):
        mine = [c for c in comps if c["metric"] == metric]
        if not mine:
            continue
        cells: dict[tuple[str, str], dict] = {}
        for c in mine:
            for a, b, flip in ((c["a"], c["b"], False), (c["b"], c["a"], True)):
                cells[(a, b)] = _cell(c, flip)
        rows = [{"scheme": a, "cells": [cells.get((a, b)) for b in schemes]} for a in schemes]
        unit = COMPARED_METRICS.get(metric, "")
        out.append({"metric": metric, "unit": unit, "schemes": schemes, "rows": rows})
    return out


def _cell(c: dict, flip: bool) -> dict:
    """One matrix cell of comparison ``c`` seen from its row's scheme (``flip``: the row is c's b)."""
    row, col = (c["b"], c["a"]) if flip else (c["a"], c["b"])
    if c["metric"] == "success":
        mine, theirs = (c["b_only"], c["a_only"]) if flip else (c["a_only"], c["b_only"])
        short = f"{mine}:{theirs}, p {c['p']:.2g}"
        row_wins = mine > theirs
    else:
        sign = -1.0 if flip else 1.0
        if not c.get("judged", c.get("low") is not None):  # too few pairs: the mean shown, no verdict
            pairs = f"{c.get('n', 0)} pair{'' if c.get('n') == 1 else 's'}"
            short = pairs if c.get("mean") is None else f"{sign * c['mean']:+.2g} ({pairs})"
            return {"text": "not judged", "cls": "nj", "short": short, "title": c["text"]}
        mean, lo, hi = sign * c["mean"], *sorted((sign * c["low"], sign * c["high"]))
        short = f"{mean:+.2g} [{lo:+.2g}, {hi:+.2g}]"
        row_wins = hi < 0  # lower is better: the row's value is smaller
    if not c["significant"]:
        return {"text": "n.s.", "cls": "ns", "short": short, "title": c["text"]}
    win = row if row_wins else col
    return {"text": f"{win} better", "cls": "win" if row_wins else "loss", "short": short, "title": c["text"]}


def failing_samples(rows: list[dict]) -> list[dict]:
    """Samples where some scheme other than the oracle did not succeed, worst first: most schemes
    failing, then the largest final position error (the success criterion's metric; the whole run's
    maximum is the initial offset's on most samples).  Each: ``sample``, ``faulted_wheels``, ``failed``
    (the schemes), ``max_error`` (the largest final error over the schemes), ``errors`` per scheme and
    ``stopped``: the ``status`` and ``t_end`` of each failed scheme whose run stopped early.  A stopped run
    has no final error (None): its error at the stop is no final error of the horizon
    (:func:`ftcreport.studies.campaign.completed`)."""
    by: dict[int, list[dict]] = {}
    for r in rows:
        by.setdefault(int(r["sample"]), []).append(r)
    out = []
    for i, rs in by.items():
        failed = [r["scheme"] for r in rs if not r.get("success") and r["scheme"] != BOUND]
        if not failed:
            continue
        errs = {r["scheme"]: r.get("position_error_final") if completed(r) else None for r in rs}
        stopped = {
            r["scheme"]: {"status": r.get("status"), "t_end": r.get("t_end")}
            for r in rs
            if r["scheme"] in failed and not completed(r)
        }
        finite = [v for v in errs.values() if isinstance(v, int | float) and math.isfinite(v)]
        out.append(
            {
                "sample": i,
                "faulted_wheels": rs[0].get("faulted_wheels", "?"),
                "failed": failed,
                "max_error": max(finite) if finite else math.inf,
                "errors": errs,
                "stopped": stopped,
            }
        )
    out.sort(key=lambda e: (-len(e["failed"]), -e["max_error"]))
    return out


def sample_name(index: int) -> str:
    return f"sample-{int(index):05d}"


def check_sample_index(out: Path, index: int) -> int:
    """``index`` when the campaign in ``out`` ran that sample, else FtcError naming the range it ran.

    The range is the campaign's ``--samples`` (``manifest.json``'s settings, rewritten by a resumed
    campaign), or, without a manifest, the samples stored under ``samples/``.  A page for an index
    outside it would show a variant the campaign never drew (exit 2, as any bad argument).
    """
    out = Path(out)
    index = int(index)
    settings = (read_json(out / "manifest.json") or {}).get("settings") if (out / "manifest.json").is_file() else None
    n = settings.get("samples") if isinstance(settings, dict) else None
    if not isinstance(n, int) or isinstance(n, bool) or n < 0:
        stored = [int(p.stem) for p in (out / "samples").glob("*.json") if p.stem.isdigit()]
        n = max(stored) + 1 if stored else 0
    if not 0 <= index < n:
        ran = f"samples 0 to {n - 1}" if n else "no sample"
        if index >= n and (out / "samples" / f"{index:08d}.json").is_file():  # a larger run's, not reported
            ran += (
                f" (sample {index} is stored from a run with more samples: 'campaign --samples {index + 1}' reports it)"
            )
        raise FtcError(f"sample {index}: not a sample of the campaign in {out}, which ran {ran}")
    return index


def check_sample_content(out: Path, meta: dict, base) -> None:
    """FtcError (exit 2) when another ftcreport version computed the campaign (``campaign.json``'s ``version``),
    other code of the package or other numeric libraries (its ``code`` and ``versions``, when recorded), or
    when ``base``, the campaign's base case parsed now, hashes otherwise than the campaign recorded
    (``campaign.json``'s ``case_hash``): a scheme file changed since (named, from the files' own hashes the
    campaign recorded), or what the package makes of the case.  A sample re-simulated from it would not be
    the campaign's sample, as ``campaign`` refuses to resume from another base case content."""
    from .. import __version__
    from ..cases import plugin_digests
    from ..studies.campaign import case_content_hash, identity

    version = meta.get("version")
    if version is not None and version != __version__:  # the case may read alike, the code that runs it does not
        raise FtcError(
            f"{Path(out) / 'campaign.json'}: the campaign was computed by ftcreport {version}, this is {__version__}: "
            "a sample re-simulated now need not be the campaign's; re-run the campaign with --force"
        )
    made, here = {k: meta.get(k) for k in ("code", "versions")}, identity()
    if made["code"] is not None and made["code"] != here["code"]:  # a source file of the package changed since
        raise FtcError(
            f"{Path(out) / 'campaign.json'}: the campaign was computed by other code of ftcreport {version} (code "
            f"digest {made['code']}, now {here['code']}): a sample re-simulated now need not be the campaign's; "
            "re-run the campaign with --force"
        )
    if isinstance(made["versions"], dict) and made["versions"] != here["versions"]:
        was = made["versions"]
        moved = [f"{k} {was.get(k)}, now {v}" for k, v in here["versions"].items() if was.get(k) != v]
        raise FtcError(
            f"{Path(out) / 'campaign.json'}: the campaign was computed with {'; '.join(moved) or 'other libraries'}: "
            "a sample re-simulated now need not be the campaign's; re-run the campaign with --force"
        )
    recorded = meta.get("case_hash")
    now = case_content_hash(base)
    if recorded is None or now == recorded:
        return
    was, files = meta.get("plugin_files"), plugin_digests(base)
    changed = [p for p, h in files.items() if h != was.get(p)] if isinstance(was, dict) else list(files)
    where = ", ".join(changed) if changed else str(Path(out) / "campaign.json")
    what = "changed" if changed else "reads otherwise (another ftcreport version?)"
    raise FtcError(
        f"{where}: {what} since the campaign in {out} ran (base case content hash {now}, the campaign's "
        f"{recorded}): its samples would not be the campaign's; restore it, or re-run the campaign with --force"
    )


def render_sample(out: Path, index: int) -> Path:
    """Re-simulate sample ``index`` of the campaign in ``out`` and write its page, a case page (verdict,
    replay, figures) at ``<out>/sample_pages/sample-NNNNN/index.html``; returns its path.

    The sample's variant is drawn again from the campaign's seed (``ftcreport.studies.campaign.sample_seeds``),
    so its runs are the campaign's; its results are stored beside the page like a batch's.
    """
    from ..cases import _toml_value, parse_case
    from ..runner import run_scheme
    from ..storage.store import save_run
    from ..studies.batch import record_case, run_key
    from ..studies.campaign import draw_variant, sample_seeds
    from .render import render_case

    out = Path(out)
    meta = read_json(out / "campaign.json")
    if not isinstance(meta, dict) or "base" not in meta:
        raise FtcError(f"{out}: not a campaign directory (no campaign.json); run 'ftcreport campaign' first")
    base = parse_case(meta["base"], f"{out / 'campaign.json'}: base")
    check_sample_content(out, meta, base)
    index = check_sample_index(out, index)
    variant = draw_variant(base, sample_seeds(int(meta["seed"]), index))
    name = sample_name(index)
    variant = variant.model_copy(
        update={"name": name, "description": f"{base.name}, campaign sample {index}: {variant.description}"}
    )
    root = out / PAGES
    data = _drop_none(json.loads(variant.model_dump_json()))
    data.pop("campaign", None)
    text = f"# {base.name}: sample {index} of the campaign in {out} (seed {meta['seed']}), as drawn\n" + "".join(
        f"{k} = {_toml_value(v)}\n" for k, v in data.items()
    )
    src = root / f"{name}.toml"
    write_atomic(src, text.encode())
    variant = parse_case(data, str(src))
    record_case(root, variant, src)
    for s in meta.get("schemes") or []:
        run, m = run_scheme(variant, s)
        save_run(root, name, s, run, m, run_key(variant, s))
    page = render_case(root, name, root="../../", nav=f"campaign {base.name}")
    if page is None:  # pragma: no cover - record_case wrote the record above
        raise FtcError(f"{root / name}: the sample's record is missing")
    return page


def _drop_none(v):
    """A dict without its None values (TOML has no null), recursively."""
    if isinstance(v, dict):
        return {k: _drop_none(x) for k, x in v.items() if x is not None}
    if isinstance(v, list):
        return [_drop_none(x) for x in v]
    return v


def render_campaign(out: Path, rows: list[dict], worst: int = WORST_K) -> Path:
    """Write ``summary.json`` and ``index.html`` of a campaign directory from its table rows, and the
    pages of the ``worst`` failing samples not rendered yet (when the directory holds ``campaign.json``)."""
    out = Path(out)
    summary = summarize(rows)
    meta_path = out / "campaign.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    write_atomic(out / "summary.json", json.dumps(_jsonable(summary), indent=1).encode())
    failing = failing_samples(rows)
    if meta.get("base") and worst > 0:
        for e in failing[:worst]:
            if not (out / PAGES / sample_name(e["sample"]) / "index.html").exists():
                render_sample(out, e["sample"])
    for e in failing:
        page = out / PAGES / sample_name(e["sample"]) / "index.html"
        e["href"] = page.relative_to(out).as_posix() if page.exists() else None
    band = (meta.get("base") or {}).get("recovery_band")
    into_band = f"into the {band:g} m recovery band" if isinstance(band, int | float) else "into the recovery band"
    figures = []
    if rows:
        figures = [
            figure("rates", "Success rate per scheme with 95 % Wilson intervals.", svg=_rates_svg(summary)),
            figure(
                "max-error",
                "Empirical CDF of the maximum position error per sample over the whole run, the initial offset "
                "included (log scale): the fraction of the runs that completed at or below each value, one "
                "line per scheme (further left is better; the runs that stopped early are left out)."
                + coincide_note(summary, rows, "max_errors", True, "max errors"),
                svg=_ecdf_svg(summary, "max_errors", "max position error [m]", True),
            ),
            figure(
                "recovery",
                "Empirical CDF of the recovery time (defined under the rates table) over the runs that "
                f"completed: a scheme's line ends at the fraction of them that recovered {into_band} (legend: "
                "recovered / completed runs, and the runs that stopped early, which are left out)."
                + coincide_note(summary, rows, "recovery_times", False, "recovery times"),
                svg=_ecdf_svg(summary, "recovery_times", "recovery time max [s]", False, "recovered / completed"),
            ),
        ]
    return write_page(
        out / "index.html",
        "campaign.html",
        index_root(out),
        name=meta.get("case", out.name),
        seed=meta.get("seed"),
        success=(meta.get("base", {}).get("campaign") or {}).get("success", {}),
        summary=summary,
        figures=figures,
        matrices=comparison_matrices(summary),
        failing=failing,
        schemes=list(summary["schemes"]),
        out_dir=str(out),
        worst=worst,
        band=band,
    )
