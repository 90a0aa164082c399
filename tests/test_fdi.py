"""FDI evaluation (issue 22): detectors and ROC against known answers, and a small run on campaign samples."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import norm

from ftcreport.cases import parse_case
from ftcreport.report.fdi import render_fdi
from ftcreport.studies.fdi import cusum_state, roc, run_fdi, score, threshold_state

ROOT = Path(__file__).resolve().parents[1]
DT, K, K0 = 0.1, 200, 100  # 20 s segments, the step at 10 s


def _segments(mu: float, n: int = 200, seed: int = 5) -> list[dict]:
    """A step of ``mu`` standard deviations at 10 s in unit Gaussian noise, ``n`` segments."""
    rng = np.random.default_rng(seed)
    t = np.arange(K) * DT
    out = []
    for _ in range(n):
        x = rng.normal(size=K)
        x[K0:] += mu
        out.append({"t": t, "x": x, "t_fault": t[K0]})
    return out


def _threshold(seg, setting):
    c, m = setting
    return threshold_state(seg["x"], c, m)[:, 0]


def test_roc_of_a_step_in_gaussian_noise():
    segs = _segments(6.0)
    for c, m in ((2.0, 1), (1.0, 3)):
        p = 2.0 * (1.0 - norm.cdf(c))  # P(|x| > c) per sample
        # rising edges of "m samples in a row over c" in the 100 fault-free samples: the first possible
        # one (index m-1) has probability p^m, each later one (1 - p) p^m
        per_segment = p**m + (K0 - m) * (1.0 - p) * p**m
        expected_far = 3600.0 * per_segment / (K0 * DT)
        (pt,) = roc(segs, _threshold, [(c, m)])
        # Monte Carlo: about 870 and 430 alarms in all; 4 standard deviations (counts ~ Poisson) < 15 %, 20 %
        assert pt["far_per_hour"] == pytest.approx(expected_far, rel=0.15 if m == 1 else 0.2)
        # a 6-sigma step crosses c at once (P(miss) per sample < 1e-4): detected after m - 1 samples, less
        # when the samples just before the step were over c already: for m = 3 the delay is 2, 1 or 0
        # samples with probabilities 1 - p, p (1 - p), p^2, so E = dt (2 - p - p^2); for m = 1 it is 0
        assert pt["pd"] == 1.0
        expected_delay = 0.0 if m == 1 else DT * (2.0 - p - p**2)
        assert pt["mean_delay"] == pytest.approx(expected_delay, abs=0.015)  # SD of the mean ~0.005 s
    # the ROC of a 1.5-sigma step: detection probability falls as the threshold rises, and within the
    # 10 s after the step a 1-sample detector almost surely fires (P(miss) = P(|x| < c)^100)
    segs = _segments(1.5, n=100)
    pts = roc(segs, _threshold, [(c, 1) for c in (1.0, 2.0, 3.0, 4.0, 6.0)])
    pds = [q["pd"] for q in pts]
    assert pds == sorted(pds, reverse=True)
    q_miss = norm.cdf(4.0 - 1.5) - norm.cdf(-4.0 - 1.5)
    assert pts[3]["pd"] == pytest.approx(1.0 - q_miss**100, abs=0.05)
    assert pts[4]["pd"] < 0.1 and pts[4]["far_per_hour"] == 0.0


def test_cusum_on_a_noise_free_step_by_hand():
    z = np.zeros(50)
    z[20:] = 1.0  # step of 1 at index 20; drift 0.25: S grows by 0.75 per sample
    st = cusum_state(z, drift=0.25, h=2.0)
    # S = 0.75 j after j samples: over h = 2 at j = 3 (2.25), i.e. index 22; reset, again at 25, 28, ...
    assert np.nonzero(st)[0][:3].tolist() == [22, 25, 28]
    t = np.arange(50) * 0.1
    sc = score(t, st, t_fault=2.0)
    assert sc["detected"] and sc["delay"] == pytest.approx(0.2) and sc["false_alarms"] == 0
    assert sc["free_time"] == pytest.approx(2.0)
    # nothing below the drift: no alarm ever
    assert not cusum_state(np.full(50, 0.25), 0.25, 0.1).any()


def test_score_counts_false_alarms_before_the_fault_only():
    t = np.arange(10.0)
    st = np.array([0, 1, 1, 0, 1, 0, 0, 1, 1, 1], dtype=bool)
    sc = score(t, st, t_fault=6.0, skip=0.0)
    assert sc["false_alarms"] == 2 and sc["delay"] == 1.0 and sc["first"] == 7
    # the start-up is skipped; a state already on when the window opens counts once
    assert score(t, st, t_fault=6.0, skip=2.0)["false_alarms"] == 2
    assert score(t, st, t_fault=6.0, skip=3.0)["false_alarms"] == 1


def _active_campaign() -> dict:
    data = tomllib.loads((ROOT / "cases" / "two_link_campaign.toml").read_text())
    data["schemes"]["active"] = {"k_v": 5.0, "Theta": 1.6, "p_max": 1e10}
    data["simulation"]["duration"] = 12.0
    data["campaign"] |= {"fault_time": [5.0, 8.0], "sigma": [0.3, 0.6], "friction_probability": 0.0}
    data["campaign"] |= {"noise_position": [1e-4, 5e-4], "noise_heading": [1e-4, 5e-4]}
    return data


def test_fdi_on_noisy_campaign_samples(tmp_path, monkeypatch):
    base = parse_case(_active_campaign(), "fdi_short")
    sweep = {"thresholds": (0.1, 10.0), "dwells": (1.0,), "cusum_h": (5.0, 1e9), "cusum_drift": (1.0,)}
    res = run_fdi(base, 3, tmp_path, seed=2, in_process=True, show_progress=False, sweep=sweep)
    r = res["schemes_results"]["active"]
    assert not res["failed"] and r["n_samples"] + r["diverged_or_stopped"] == 3 and r["n_samples"] >= 1
    assert res["calibration"] == [2.0, 5.0]
    est = {p["threshold"]: p for p in r["estimate"]}
    # a threshold no estimate reaches: nothing detected, no false alarm.  At 0.1 the gains' estimates
    # see the losses of 0.4-0.7 they can identify (sample 2's loss of 2l stays unseen in its 6 s: the
    # individual gains are weakly identifiable, ERRATA P3), and never move by 0.1 before the fault
    assert est[10.0]["pd"] == 0.0 and est[10.0]["far_per_hour"] == 0.0
    assert est[0.1]["pd"] >= 2 / 3 and est[0.1]["far_per_hour"] == 0.0 and 0.0 <= est[0.1]["isolation"] <= 1.0
    cus = {p["h"]: p for p in r["residual"]}
    assert cus[1e9]["pd"] == 0.0 and cus[1e9]["far_per_hour"] == 0.0 and cus[5.0]["pd"] > 0.0
    for p in r["estimate"] + r["residual"]:
        assert p["mean_delay"] is None or 0.0 <= p["mean_delay"] <= 7.0
    html = render_fdi(tmp_path).read_text()
    assert "CUSUM" in html and "<svg" in html
    # one ROC per detector, each with its recommended point; the sweep tables folded
    assert 'id="fig-active-roc-estimate"' in html and 'id="fig-active-roc-residual"' in html
    assert 'id="recommended"' in html and "at most 1 false alarm per hour" in html
    assert html.count("<details>") == 2 * len(res["schemes_results"]) and '<table id="active-estimate">' in html
    # resumable: a second run recomputes nothing and gives the same sweep
    again = run_fdi(base, 3, tmp_path, seed=2, in_process=True, show_progress=False, sweep=sweep)
    assert json.dumps(again["schemes_results"]) == json.dumps(res["schemes_results"])
    assert not math.isnan(json.loads((tmp_path / "fdi.json").read_text())["schemes_results"]["active"]["skip"])
    # traces another code of the package computed are stale, as a campaign's samples (the version alone was not)
    from ftcreport.errors import FtcError
    from ftcreport.storage import code_digest

    monkeypatch.setattr(code_digest, "DIGEST", "0123456789abcdef")
    with pytest.raises(FtcError, match=r"00000000.json: was computed by other code"):
        run_fdi(base, 3, tmp_path, seed=2, in_process=True, show_progress=False, sweep=sweep)


def test_recommended_operating_point_rule():
    """Issue 35 item 7: the highest detection probability within 1 false alarm per hour (ties: the shorter
    delay); when no setting is within the budget, the fewest false alarms."""
    from ftcreport.report.fdi import FAR_BUDGET, operating_point

    pts = [
        {"pd": 0.99, "far_per_hour": 12.0, "mean_delay": 0.5},
        {"pd": 0.80, "far_per_hour": 1.0, "mean_delay": 2.0},
        {"pd": 0.80, "far_per_hour": 0.0, "mean_delay": 1.5},
        {"pd": 0.60, "far_per_hour": 0.0, "mean_delay": 0.9},
        {"pd": None, "far_per_hour": 0.0, "mean_delay": None},
    ]
    assert FAR_BUDGET == 1.0
    assert operating_point(pts) == pts[2]  # 0.8 within the budget twice: the shorter delay
    over = [{"pd": 1.0, "far_per_hour": 5.0, "mean_delay": 1.0}, {"pd": 0.5, "far_per_hour": 2.0, "mean_delay": 3.0}]
    assert operating_point(over) == over[1]
    assert operating_point([{"pd": None, "far_per_hour": None}]) is None
