r"""Statistics that say whether a difference between two schemes is real (pure; scipy.stats).

Every scheme of a campaign runs on the same samples, so comparisons are *paired*:

* success (a 0/1 outcome per sample): the exact McNemar test.  Only the discordant
  samples carry information: b = A succeeds and B fails, c = A fails and B succeeds.
  Under "no difference" b ~ Binomial(b + c, 1/2); the two-sided exact p-value is
  ``scipy.stats.binomtest(b, b + c, 0.5).pvalue``.
* a continuous metric (error, recovery time): the per-sample difference A - B and a
  bootstrap confidence interval of its mean (``scipy.stats.bootstrap``, percentile
  method, a fixed generator so that a report is reproducible).  The difference is
  called significant when the interval excludes 0, and only on at least
  :func:`min_pairs` pairs: with n pairs all of one sign the percentile interval
  excludes 0, which under no difference happens with probability 2^(1 - n) (0.5 at
  n = 2), so below the n at which even a unanimous sign passes the exact two-sided
  sign test at the comparison's level there is no verdict ("too few paired samples").
* a success rate alone: the Wilson score interval
  (``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``).

The significance level is per comparison (no correction for the number of
comparisons on a page; the page says so).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

__all__ = ["bootstrap_mean_ci", "compare_metric", "compare_success", "mcnemar_exact", "min_pairs", "wilson_interval"]


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy); (0, 1) when n = 0."""
    if n == 0:
        return 0.0, 1.0
    ci = stats.binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    lo = 0.0 if successes == 0 else max(0.0, float(ci.low))  # exact ends (round-off would leave 1 - 1e-16)
    hi = 1.0 if successes == n else min(1.0, float(ci.high))
    return lo, hi


def mcnemar_exact(a: Sequence[bool], b: Sequence[bool]) -> dict:
    """Exact McNemar test on paired outcomes ``a[i]``, ``b[i]`` (True = success).

    Returns ``{"n", "a_only", "b_only", "p"}``: the pairs, the discordant counts
    (A succeeds and B fails, and the reverse) and the two-sided exact p-value (1 when
    there is no discordant pair).
    """
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"paired outcomes differ in length: {a.size} and {b.size}")
    a_only = int(np.sum(a & ~b))
    b_only = int(np.sum(~a & b))
    k = a_only + b_only
    p = 1.0 if k == 0 else float(stats.binomtest(a_only, k, 0.5).pvalue)
    return {"n": int(a.size), "a_only": a_only, "b_only": b_only, "p": p}


def min_pairs(confidence: float = 0.95) -> int:
    """The fewest pairs on which a paired comparison at ``confidence`` can give a verdict: the smallest n with
    2^(1 - n) <= 1 - confidence (6 at 95 %).

    Why: 2^(1 - n) is the exact two-sided sign test's p-value for n differences all of one sign, the
    strongest evidence n pairs can hold; a bootstrap (percentile) interval excludes 0 whenever the signs
    agree, so on fewer pairs it would call a difference significant that the data cannot support."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence}")
    n = 1
    while 2.0 ** (1 - n) > 1.0 - confidence:
        n += 1
    return n


def bootstrap_mean_ci(d: Sequence[float], confidence: float = 0.95, n_resamples: int = 9999, seed: int = 0) -> dict:
    """Bootstrap (percentile) confidence interval of the mean of ``d``; a fixed generator (reproducible).

    Returns ``{"n", "mean", "low", "high"}``; ``low``/``high`` are None for fewer than 2 values,
    and equal the mean when all values are equal.
    """
    d = np.asarray(d, dtype=float)
    d = d[np.isfinite(d)]
    out = {"n": int(d.size), "mean": float(d.mean()) if d.size else None, "low": None, "high": None}
    if d.size < 2:
        return out
    if np.all(d == d[0]):
        out["low"] = out["high"] = float(d[0])
        return out
    res = stats.bootstrap(
        (d,),
        np.mean,
        confidence_level=confidence,
        n_resamples=n_resamples,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    out["low"], out["high"] = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return out


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def _p(p: float) -> str:
    return "p < 0.0001" if p < 1e-4 else f"p = {p:.2g}"


def _verdict(name_a: str, name_b: str, metric: str, test: str, result: dict, sig: bool, text: str) -> dict:
    """The record of a paired comparison: the two schemes, the metric, the test, its numbers and its sentence."""
    return {"a": name_a, "b": name_b, "metric": metric, "test": test, **result, "significant": sig, "text": text}


def compare_success(name_a: str, name_b: str, a: Sequence[bool], b: Sequence[bool], alpha: float = 0.05) -> dict:
    """Paired comparison of success (exact McNemar) with the sentence the report prints."""
    t = mcnemar_exact(a, b)
    sig = t["p"] < alpha
    if sig:
        win, lose = (name_a, name_b) if t["a_only"] > t["b_only"] else (name_b, name_a)
        hi, lo = max(t["a_only"], t["b_only"]), min(t["a_only"], t["b_only"])
        text = (
            f"{win} beats {lose} on success (exact McNemar {_p(t['p'])}; "
            f"{hi} samples only {win} succeeds, {lo} only {lose}, of {t['n']})"
        )
    else:
        text = (
            f"{name_a} vs {name_b} on success: no significant difference (exact McNemar {_p(t['p'])}; "
            f"{t['a_only']} vs {t['b_only']} discordant samples of {t['n']})"
        )
    return _verdict(name_a, name_b, "success", "mcnemar_exact", t, sig, text)


def compare_metric(
    name_a: str,
    name_b: str,
    metric: str,
    a: Sequence[float | None],
    b: Sequence[float | None],
    unit: str = "",
    confidence: float = 0.95,
) -> dict:
    """Paired comparison of a lower-is-better metric: bootstrap CI of mean(A - B) on the pairs where both exist.

    No verdict (``judged`` False, not significant) on fewer than :func:`min_pairs` pairs, whatever the
    interval: the record keeps ``n``, ``mean`` and ``min_pairs``, and no interval (on so few pairs it is
    little more than the range of the differences)."""
    pairs = [
        (float(x), float(y))
        for x, y in zip(a, b, strict=True)
        if x is not None and y is not None and math.isfinite(float(x)) and math.isfinite(float(y))
    ]
    d = [x - y for x, y in pairs]
    need = min_pairs(confidence)
    judged = len(d) >= need
    ci = bootstrap_mean_ci(d, confidence) if judged else {"n": len(d), "mean": float(np.mean(d)) if d else None}
    ci = {"low": None, "high": None} | ci | {"judged": judged, "min_pairs": need}
    sig = judged and (ci["low"] > 0 or ci["high"] < 0)
    u = f" {unit}" if unit else ""
    level = f"{100 * confidence:.0f} %"
    if not judged:
        text = f"{name_a} vs {name_b} on {metric}: too few paired samples ({ci['n']}; a verdict needs {need})"
        if ci["mean"] is not None:
            text += f", mean difference {_fmt(ci['mean'])}{u} ({name_a} - {name_b})"
    else:
        span = f"mean difference {_fmt(ci['mean'])}{u}, {level} CI [{_fmt(ci['low'])}, {_fmt(ci['high'])}]"
        why = f"({name_a} - {name_b}: {span}; bootstrap, {ci['n']} pairs)"
        if sig:
            win, lose = (name_a, name_b) if ci["high"] < 0 else (name_b, name_a)
            text = f"{win} beats {lose} on {metric} {why}"
        else:
            text = f"{name_a} vs {name_b} on {metric}: no significant difference {why}"
    return _verdict(name_a, name_b, metric, "bootstrap_mean_difference", ci, sig, text)
