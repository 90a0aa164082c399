"""Paired statistics between schemes (issue 22): McNemar, bootstrap and Wilson against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcreport.evaluation.stats import (
    bootstrap_mean_ci,
    compare_metric,
    compare_success,
    mcnemar_exact,
    wilson_interval,
)


def test_mcnemar_exact_by_hand():
    # 8 samples only A succeeds, 2 only B, 5 both, 3 neither: p = 2 * P(X <= 2), X ~ Bin(10, 1/2)
    a = [True] * 8 + [False] * 2 + [True] * 5 + [False] * 3
    b = [False] * 8 + [True] * 2 + [True] * 5 + [False] * 3
    t = mcnemar_exact(a, b)
    assert (t["n"], t["a_only"], t["b_only"]) == (18, 8, 2)
    assert t["p"] == pytest.approx(2 * (1 + 10 + 45) / 2**10, rel=1e-12)  # 0.109375
    # 10 against 0: p = 2 / 2**10
    assert mcnemar_exact([True] * 10, [False] * 10)["p"] == pytest.approx(2 / 1024, rel=1e-12)
    # symmetric, and no discordant pair: p = 1
    assert mcnemar_exact(b, a)["p"] == t["p"]
    assert mcnemar_exact([True, False], [True, False])["p"] == 1.0
    with pytest.raises(ValueError, match="differ in length"):
        mcnemar_exact([True], [True, False])


def test_mcnemar_sentences():
    c = compare_success("oracle", "nominal", [True] * 10, [False] * 10)
    assert c["significant"] and c["text"].startswith("oracle beats nominal on success (exact McNemar p = 0.002;")
    c = compare_success("oracle", "nominal", [True] * 8 + [False] * 2, [False] * 8 + [True] * 2)
    assert not c["significant"] and "no significant difference (exact McNemar p = 0.11" in c["text"]


def test_bootstrap_by_hand():
    # two values 0 and 1: resampled means are 0, 1/2, 1 with probabilities 1/4, 1/2, 1/4, so the
    # 2.5 % and 97.5 % percentiles are exactly 0 and 1
    ci = bootstrap_mean_ci([0.0, 1.0])
    assert (ci["n"], ci["mean"], ci["low"], ci["high"]) == (2, 0.5, 0.0, 1.0)
    # normal data: the percentile interval approaches mean +/- 1.96 s / sqrt(n) (s with ddof 0, the
    # bootstrap's plug-in); tolerance 5 % of the half width (Monte Carlo error of 9999 resamples ~1 %)
    d = np.random.default_rng(3).normal(0.3, 2.0, 400)
    ci = bootstrap_mean_ci(d)
    half = 1.959964 * d.std() / math.sqrt(d.size)
    assert ci["mean"] == pytest.approx(d.mean(), rel=1e-12)
    assert ci["low"] == pytest.approx(d.mean() - half, abs=0.05 * half)
    assert ci["high"] == pytest.approx(d.mean() + half, abs=0.05 * half)
    assert bootstrap_mean_ci(d) == ci  # fixed generator: reproducible
    # degenerate cases
    assert bootstrap_mean_ci([2.0, 2.0, 2.0])["low"] == 2.0
    assert bootstrap_mean_ci([1.0])["low"] is None


def test_compare_metric_pairs_and_sentence():
    a = [0.10, 0.20, None, 0.15, 0.12, 0.11, 0.13, 0.14]
    b = [0.50, 0.60, 0.40, 0.55, 0.52, 0.51, 0.53, float("nan")]
    c = compare_metric("switching", "nominal", "position_error_max", a, b, "m")
    assert c["n"] == 6  # the pairs where both values exist
    assert c["mean"] == pytest.approx(np.mean([-0.4, -0.4, -0.4, -0.4, -0.4, -0.4]), abs=1e-12)
    assert c["significant"] and c["text"].startswith("switching beats nominal on position_error_max")
    c = compare_metric("a", "b", "m", [1.0, 2.0, 3.0, 4.0], [2.0, 1.0, 4.0, 3.0])
    assert not c["significant"] and "no significant difference" in c["text"]


def test_wilson_is_scipys():
    # by hand: p = 0.5, n = 4, z = 1.96: centre 0.5, half 0.3500 (to 4 digits)
    lo, hi = wilson_interval(2, 4)
    assert lo == pytest.approx(0.1500, abs=1e-4) and hi == pytest.approx(0.8500, abs=1e-4)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(10 / (10 + 1.959963984540054**2), rel=1e-9)
