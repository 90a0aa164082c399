"""What a case page says of the checks around its runs: the step check and the items not judged.

``run --verify-dt`` stores ``verify_dt`` in each run's ``metrics.json`` (ftcreport.runner.dt_sensitivity);
:func:`step_checks` turns it into words for the schemes table.  ``run --scheme`` judges only the
thresholds and claims that read the schemes it ran (README, exit codes); :func:`ran_here` and
:func:`not_judged` let the page say the same instead of failing an item whose scheme was not run.
"""

from __future__ import annotations

from collections.abc import Iterable

from ..evaluation.metrics import METRICS
from ..runner import step_change_over

__all__ = ["not_judged", "ran_here", "step_checks"]


def step_checks(runs: list[dict]) -> list[dict]:
    """The ``run --verify-dt`` result of each run that has one, in words.

    Returns one dict per such run: ``scheme``, ``converged``, ``empty``, ``refined`` (what was
    refined: "dt = 0.01 s vs 0.005 s"), ``moved`` (one phrase per metric whose change is over the
    tolerance, largest first, or, when converged, the largest change) and ``text`` (the sentence).
    """
    out = []
    for m in runs:
        v = m.get("verify_dt")
        if not isinstance(v, dict):
            continue
        rows = v.get("metrics") or {}
        rtol, atol = v.get("rtol", 0.01), v.get("atol", 1e-6)
        over = [k for k, r in rows.items() if step_change_over(r, rtol, atol)]
        by_size = sorted(rows, key=lambda k: -_rel(rows[k]))
        moved = [_moved(k, rows[k]) for k in sorted(over, key=lambda k: -_rel(rows[k]))]
        converged, empty = bool(v.get("converged")), bool(v.get("empty"))
        status = v.get("status", "")
        a, _, b = str(status).partition(" / ")
        tol = f"{rtol:.0%} (+{atol:g} absolute)"
        if empty:
            text = (
                f"step check ({v.get('refined')}): EMPTY: the refined run is bit-identical on every headline "
                "metric, so it tested nothing (run exits 1)"
            )
        elif converged:
            big = f"; the largest change: {_moved(by_size[0], rows[by_size[0]])}" if by_size else ""
            text = f"step check ({v.get('refined')}): converged, every headline metric within {tol}{big}"
        else:
            parts = list(moved)
            if a != b:
                parts.insert(0, f"the status changes from {a} to {b}")
            text = f"step check ({v.get('refined')}): NOT converged (run exits 1): {'; '.join(parts)} (tolerance {tol})"
        out.append({"scheme": m["scheme"], "converged": converged, "empty": empty, "moved": moved, "text": text})
    return out


def ran_here(manifest: dict | None) -> set[str] | None:
    """The schemes of the ``ftcreport run`` that wrote the case's manifest; None for a batch or check
    (every scheme of the case was to run, and an item whose scheme has no run fails)."""
    settings = (manifest or {}).get("settings") or {}
    schemes = settings.get("schemes")
    if settings.get("command") != "run" or not isinstance(schemes, list):
        return None
    return {str(s) for s in schemes}


def not_judged(schemes: Iterable[str], ran: set[str] | None) -> str | None:
    """Why an item reading ``schemes`` is not judged on this page ("not judged (needs nominal, not run
    here)"), or None when it is judged: ``run --scheme`` judges only items on the schemes it ran."""
    if ran is None:
        return None
    missing = [s for s in dict.fromkeys(schemes) if s not in ran]
    if not missing:
        return None
    return f"not judged (needs {', '.join(missing)}, not run here)"


def _rel(r: dict) -> float:
    rel = r.get("rel_change")
    return float("inf") if rel is None else float(rel)


def _moved(key: str, r: dict) -> str:
    """ "energy 12.3 -> 16 J (+30.1% at the refined step)": a metric as run, refined, and the change."""
    unit = METRICS[key].unit if key in METRICS else ""
    unit = "" if unit in ("", "1", "-") else f" {unit}"
    a, b = r.get("dt"), r.get("dt_half")
    if a is None or b is None:
        return f"{key} {_num(a)} -> {_num(b)}{unit} (null in one run)"
    a, b = float(a), float(b)
    if a == 0.0:
        return f"{key} {_num(a)} -> {_num(b)}{unit} (change {abs(b - a):.3g}{unit})"
    # the change relative to the value as run: what the run's own number is off by
    return f"{key} {_num(a)} -> {_num(b)}{unit} ({(b - a) / abs(a):+.1%} at the refined step)"


def _num(x) -> str:
    return "null" if x is None else f"{float(x):.4g}"
