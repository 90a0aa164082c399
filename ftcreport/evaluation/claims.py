r"""Thesis claims checked against the runs of a case (pure).

A case file lists the thesis's claims about its simulation as ``[[claims]]``
tables (``cases/README.md``): the thesis's words with their figure or table,
the metric and the comparison that decide them, and the outcome we expect
(``expect``).  :func:`evaluate_claims` turns each into a :class:`ClaimResult`:

* ``reproduced``: the measured value satisfies the comparison;
* ``not reproduced``: it does not (the reason says by how much);
* ``not applicable``: the claim carries ``not_applicable`` (the reason why it
  cannot be checked by this simulation);
* ``not evaluated``: the scheme did not run, stopped early, or lacks the metric.

Comparisons, on the metrics of ``scheme`` (``metrics.json`` names):

* a bound ``min`` / ``max`` on ``metric``; a dotted name reads into a dict
  (``fault_estimation_errors_final.rho_2r``); a dict or list of numbers is
  compared through its largest entry, restricted to ``keys`` when given;
* ``relative_to = "<scheme>"``: the bound applies to the ratio of the metric
  of ``scheme`` to the same metric of that scheme;
* ``sequence``: the applied switching models (``switch_sequence``, 1-based as
  in the thesis, consecutive repeats merged) must equal the list.

``ftcreport check`` passes a claim when its outcome equals ``expect``: a claim we
do not reproduce is recorded as such (``expect = "not reproduced"``) and keeps CI
green, and a change of outcome either way fails the check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["OUTCOMES", "ClaimResult", "bound_text", "evaluate_claim", "evaluate_claims", "model_sequence"]

OUTCOMES = ("reproduced", "not reproduced", "not applicable", "not evaluated")


@dataclass(frozen=True)
class ClaimResult:
    """One claim of one case, evaluated."""

    case: str
    id: str
    source: str
    words: str
    scheme: str | None
    metric: str | None
    measured: str  # what we measured, as shown on the page
    outcome: str  # one of OUTCOMES
    reason: str  # one sentence
    expect: str
    note: str
    ok: bool  # outcome == expect


def _get(c, key: str):
    return c.get(key) if isinstance(c, dict) else getattr(c, key, None)


def model_sequence(switch_sequence: list) -> list[int]:
    """Applied models, 1-based, consecutive repeats merged, from ``[(t, index), ...]``."""
    out: list[int] = []
    for _, idx in switch_sequence:
        k = int(idx) + 1
        if not out or out[-1] != k:
            out.append(k)
    return out


def _arrow(seq: list[int], limit: int = 12) -> str:
    s = " -> ".join(map(str, seq[:limit]))
    return s + (f" -> ... ({len(seq)} in all)" if len(seq) > limit else "")


def _value(metrics: dict, metric: str, keys: list[str] | None) -> tuple[float | None, str]:
    """The number a bound compares (largest entry of a dict/list) and a label of where it came from."""
    val = metrics
    for part in metric.split("."):
        val = val.get(part) if isinstance(val, dict) else None
    where = ""
    if isinstance(val, dict):
        items = {k: v for k, v in val.items() if keys is None or k in keys}
        items = {k: v for k, v in items.items() if isinstance(v, int | float) and not isinstance(v, bool)}
        if not items:
            return None, ""
        where = max(items, key=lambda k: items[k])
        val = items[where]
    elif isinstance(val, list):
        nums = [v for v in val if isinstance(v, int | float) and not isinstance(v, bool)]
        val = max(nums) if nums else None
    if not isinstance(val, int | float) or isinstance(val, bool) or not math.isfinite(val):
        return None, ""
    return float(val), where


def bound_text(lo, hi) -> str:
    """The bounds in words: ``>= lo and <= hi`` (a missing bound left out)."""
    parts = [f">= {lo:g}" if lo is not None else "", f"<= {hi:g}" if hi is not None else ""]
    return " and ".join(p for p in parts if p)


def evaluate_claim(case_name: str, claim, metrics_by_scheme: dict[str, dict | None]) -> ClaimResult:
    """Evaluate one claim (a ``cases.Claim`` or its dict) against the stored metrics."""
    base = {k: _get(claim, k) for k in ("id", "source", "words", "scheme", "metric", "expect")}
    base.update(case=case_name, note=_get(claim, "note") or "")
    expect, scheme, metric = base["expect"], base["scheme"], base["metric"]

    def result(outcome: str, reason: str, measured: str = "-") -> ClaimResult:
        return ClaimResult(**base, measured=measured, outcome=outcome, reason=reason, ok=outcome == expect)

    na = _get(claim, "not_applicable")
    if na:
        return result("not applicable", na)
    m = metrics_by_scheme.get(scheme)
    if m is None:
        return result("not evaluated", f"the {scheme} scheme was not run.")
    if m.get("status") != "ok":
        return result("not evaluated", f"the {scheme} run stopped ({m.get('status')}: {m.get('reason', '')}).")
    seq = _get(claim, "sequence")
    if seq is not None:
        got = model_sequence(m.get(metric) or [])
        if not got:
            return result("not evaluated", f"{scheme} has no {metric}.")
        more = " (first 100 switches only)" if m.get("switch_sequence_truncated") else ""
        measured = f"{_arrow(got)}; {m.get('switch_count', len(got) - 1)} switches"
        if got == list(seq):
            return result("reproduced", f"the applied models follow {_arrow(list(seq))}{more}.", measured)
        return result(
            "not reproduced",
            f"the applied models go {_arrow(got)}{more}, not {_arrow(list(seq))}.",
            measured,
        )
    keys = _get(claim, "keys")
    val, where = _value(m, metric, keys)
    if val is None:
        return result("not evaluated", f"{scheme} has no numeric {metric}.")
    lo, hi = _get(claim, "min"), _get(claim, "max")
    label = f"{metric}[{where}]" if where else metric
    other = _get(claim, "relative_to")
    if other is not None:
        mo = metrics_by_scheme.get(other)
        if mo is None or mo.get("status") != "ok":
            return result("not evaluated", f"the {other} scheme was not run or stopped.")
        ref, _ = _value(mo, metric, keys)
        if ref is None or ref == 0.0:
            return result("not evaluated", f"{other} has no nonzero {metric} to compare with.")
        measured = f"{scheme} {val:.3g} / {other} {ref:.3g} = {val / ref:.3g}"
        label = f"the ratio of {scheme}'s {metric} to {other}'s"
        val = val / ref
    else:
        measured = f"{label} = {val:.3g}"
        label = f"{scheme}'s {label}"
    want = bound_text(lo, hi)
    if (lo is None or val >= lo) and (hi is None or val <= hi):
        return result("reproduced", f"{label} is {val:.3g}, {want} as the claim requires.", measured)
    return result("not reproduced", f"{label} is {val:.3g}; the claim requires {want}.", measured)


def evaluate_claims(case_name: str, claims, metrics_by_scheme: dict[str, dict | None]) -> list[ClaimResult]:
    """Every claim of a case, in file order."""
    return [evaluate_claim(case_name, c, metrics_by_scheme) for c in claims or []]
