"""The baseline page's stamp: which stored runs ``OUT/baseline.html`` compared, and whether they still are.

Apart from :mod:`.baseline_page`, which renders the page, so that the index (:mod:`.render`) reads the stamp
without importing the page's renderer (which imports it: a cycle).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["PAGE", "STAMP", "compared_runs", "stale_reason"]

#: the baseline page under OUT, and beside it the seals of the runs it compared (:func:`stale_reason`)
PAGE = "baseline.html"
STAMP = "baseline.html.stamp"


def _seal(out: Path, case: str, scheme: str) -> str | None:
    """The seal (SHA-256) of the run record stored in ``OUT/<case>/<scheme>``, None when there is none."""
    from ..storage.store import RECORD, read_json

    rec = read_json(Path(out) / case / scheme / RECORD)
    seal = rec.get("sha256") if isinstance(rec, dict) else None
    return seal if isinstance(seal, str) else None


def compared_runs(out: Path, comparisons: list) -> dict[str, str | None]:
    """``{"case/scheme": seal}`` of every run the comparisons cover (:func:`_seal`; None: no run stored)."""
    return {f"{c.case}/{sc.scheme}": _seal(out, c.case, sc.scheme) for c in comparisons for sc in c.schemes}


def stale_reason(out: Path) -> str | None:
    """Why ``OUT/baseline.html`` is not a comparison of the results now stored in OUT (None: it is).

    The rule: the page belongs to the current results while every run it compared is still the run
    stored in OUT, i.e. the seal of each run's record (``record.json``'s SHA-256, over the run's cache key
    and the SHA-256 of its metrics and time series) equals the one the page's renderer kept in :data:`STAMP`
    when it wrote the page (:func:`~ftcreport.report.baseline_page.render_baseline`).  A run made again
    with another result (a changed case, code or library) has another seal; a run made again identically
    keeps it, and the page still says the same.  Runs added since (other cases) leave it current: the page
    names the cases it compared.  A page without a readable stamp (written by an ftcreport before stamps,
    or the stamp removed) cannot be tied to any runs: stale.  A stale page is not deleted (it is the
    reader's file, e.g. a comparison kept to read); the index names it, unlinked, and says to run
    ``check --baseline`` again.
    """
    from ..storage.store import read_json

    out = Path(out)
    stamp = read_json(out / STAMP)
    runs = stamp.get("runs") if isinstance(stamp, dict) else None
    if not isinstance(runs, dict):
        return f"no {STAMP} beside it names the runs it compared"
    for run, seal in runs.items():
        case, _, scheme = str(run).partition("/")
        now = _seal(out, case, scheme)
        if now != seal:
            return f"{case} / {scheme} " + ("is no longer stored" if now is None else "was made again since")
    return None
