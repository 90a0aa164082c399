"""Thresholds of a case against the metrics of its runs (pure).

A case's ``[thresholds.<scheme>]`` table maps metric names (those of
``metrics.json``) to ``{min, max}``.  A run that did not complete fails every
threshold of its scheme (a metric of a stopped run is not comparable); a metric
absent from the run fails with that reason.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ThresholdResult", "evaluate"]


@dataclass(frozen=True)
class ThresholdResult:
    """One threshold of one scheme of one case."""

    case: str
    scheme: str
    metric: str
    min: float | None
    max: float | None
    actual: float | None
    ok: bool
    reason: str


def evaluate(case_name: str, thresholds: dict, metrics_by_scheme: dict[str, dict | None]) -> list[ThresholdResult]:
    """Compare every threshold with the stored metrics.

    Parameters
    ----------
    thresholds : dict
        ``{scheme: {metric: bound}}`` with bound having ``min``/``max`` attributes or keys.
    metrics_by_scheme : dict
        ``{scheme: metrics dict or None (not run)}``.
    """
    out = []
    for scheme, bounds in thresholds.items():
        m = metrics_by_scheme.get(scheme)
        for metric, bound in bounds.items():
            lo = bound.get("min") if isinstance(bound, dict) else bound.min
            hi = bound.get("max") if isinstance(bound, dict) else bound.max
            if m is None:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, "scheme not run"))
                continue
            if m.get("status") != "ok":
                why = f"run {m.get('status')}: {m.get('reason', '')}".strip()
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, why))
                continue
            val = m.get(metric)
            if not isinstance(val, int | float) or isinstance(val, bool):
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, "metric absent"))
                continue
            val = float(val)
            if lo is not None and val < lo:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, False, f"{val:.6g} < min {lo:g}"))
            elif hi is not None and val > hi:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, False, f"{val:.6g} > max {hi:g}"))
            else:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, True, ""))
    return out
