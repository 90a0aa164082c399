"""Fault model (2.101-2.102), schedules and the redundancy condition (2.103)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from conftest import random_chain, random_q
from hypothesis import given
from hypothesis import strategies as st

from ftcreport.errors import FaultError
from ftcreport.model import (
    Chain,
    FaultEvent,
    FaultSchedule,
    compensable_patterns,
    is_compensable_at,
    wheel_index,
    wheel_names,
)


def test_remark_2_1_two_links():
    """n = 2: healthy, any one failure, any two failures except both on robot 1 (Remark 2.1)."""
    pats = set(compensable_patterns(2))
    expected = {(1, 1, 1, 1)}
    expected |= {tuple(0 if i == j else 1 for i in range(4)) for j in range(4)}
    expected |= {
        tuple(0 if i in pair else 1 for i in range(4)) for pair in itertools.combinations(range(4), 2) if pair != (0, 1)
    }
    assert pats == expected
    assert len(pats) == 10


@pytest.mark.parametrize(("n", "count"), [(2, 10), (3, 46), (4, 190), (5, 766)])
def test_pattern_count_rule(n, count):
    """3 * 2^(2n-2) - 2 compensable patterns (ERRATA E5d; n = 3: 46, cf. Remark 3.6)."""
    pats = compensable_patterns(n)
    assert len(pats) == count == 3 * 2 ** (2 * n - 2) - 2
    assert pats[0] == (1,) * (2 * n)
    assert len(set(pats)) == count


@pytest.mark.parametrize("n", [2, 3])
def test_rule_equals_numerical_rank(rng, n):
    """At generic random poses rank(Bbar sigma) = 2 exactly for the patterns of the rule."""
    rule = set(compensable_patterns(n))
    for _ in range(5):
        chain = random_chain(rng, n)
        q = random_q(rng, n)
        for pat in itertools.product((1, 0), repeat=2 * n):
            assert chain.is_compensable_at(pat, q) == (pat in rule), pat
    # Remark 3.6: for n = 3 any four failed wheels may still be compensable, five never
    assert any(sum(p) == 2 for p in compensable_patterns(3))
    assert all(sum(p) >= 2 for p in compensable_patterns(3))


def test_pose_dependent_rank_drop():
    """ERRATA E5d: only 1r and 2r working, rank drops at tan(phi) = -d/b2 (-66.2 deg)."""
    chain = Chain.uniform(2, d=1.7)
    phi = np.arctan(-1.7 / 0.75)
    assert np.degrees(phi) == pytest.approx(-66.2, abs=0.05)
    pat = (1, 0, 1, 0)
    q_bad = chain.q_from_headings(0.0, 0.0, [phi, 0.0])
    q_ok = chain.q_from_headings(0.0, 0.0, [phi + 0.2, 0.0])
    Bbar = chain.S(q_bad).T @ chain.B(q_bad)
    assert not is_compensable_at(Bbar, pat, tol=1e-9)
    assert chain.is_compensable_at(pat, q_ok)


@given(robot=st.integers(1, 9), side=st.sampled_from("rlRL"), n=st.integers(2, 9))
def test_wheel_index_roundtrip(robot, side, n):
    name = f"{robot}{side}"
    if robot <= n:
        j = wheel_index(name, n)
        assert wheel_names(n)[j] == name.lower()
    else:
        with pytest.raises(FaultError, match=f"not a wheel of a {n}-robot chain"):
            wheel_index(name, n)


@pytest.mark.parametrize("bad", ["4r", "1x", "", "r1", "0l"])
def test_bad_wheel_names(bad):
    with pytest.raises(FaultError):
        wheel_index(bad, 3)


def test_schedule_piecewise_constant_and_intermittent():
    sched = FaultSchedule(
        2,
        [
            FaultEvent(30.0, "2l", sigma=1.0, ubar=0.0),  # recovers (given out of order)
            FaultEvent(10.0, "2l", sigma=0.0, ubar=-2.0),
            FaultEvent(10.0, "1r", sigma=0.5),
        ],
    )
    np.testing.assert_array_equal(sched.times, [10.0, 30.0])
    np.testing.assert_array_equal(sched.sigma(9.999), [1, 1, 1, 1])
    np.testing.assert_array_equal(sched.sigma(10.0), [0.5, 1, 1, 0])  # right-continuous
    np.testing.assert_array_equal(sched.ubar(10.0), [0, 0, 0, -2.0])
    np.testing.assert_array_equal(sched.sigma(30.0), [0.5, 1, 1, 1])
    np.testing.assert_array_equal(sched.ubar(31.0), [0, 0, 0, 0])
    assert sched.pattern(20.0) == (1, 1, 1, 0)
    assert sched.phases(40.0) == [(0.0, 10.0), (10.0, 30.0), (30.0, 40.0)]
    u = np.array([1.0, 2.0, 3.0, 4.0])
    sigma, ubar = sched.at(15.0)
    np.testing.assert_allclose(sigma * u + ubar, [0.5, 2.0, 3.0, -2.0])  # tau = sigma u + ubar (2.102)


def test_schedule_refuses_bad_events():
    with pytest.raises(FaultError, match="sigma must be in"):
        FaultSchedule(2, [FaultEvent(1.0, "1r", sigma=1.5)])
    with pytest.raises(FaultError, match="time must be finite"):
        FaultSchedule(2, [FaultEvent(-1.0, "1r")])
    with pytest.raises(FaultError, match="'3r' is not a wheel of a 2-robot chain"):
        FaultSchedule(2, [FaultEvent(1.0, "3r")])
    with pytest.raises(FaultError, match="same wheel at the same time"):
        FaultSchedule(2, [FaultEvent(1.0, "1r"), FaultEvent(1.0, "1r", sigma=0.5)])


def test_uncompensable_intervals_named():
    sched = FaultSchedule(2, [FaultEvent(5.0, "1r"), FaultEvent(8.0, "1l"), FaultEvent(12.0, "1l", sigma=1.0)])
    bad = sched.uncompensable_intervals(20.0)
    assert bad == [(8.0, 12.0, (0, 0, 1, 1))]
