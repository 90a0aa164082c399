"""Chained form for any n (Theorem 2.1): identity, inverse, thesis three-link formulas."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcreport.control.kinematic import ChainedBackstepping
from ftcreport.errors import SingularityError
from ftcreport.model import Chain
from ftcreport.model.chained import ChainedForm
from ftcreport.references import FlatReference, circle

LIM60 = np.radians(60)


def _q_in_domain(rng, n, lim=LIM60):
    """|theta_i| < lim and |theta_i - theta_(i+1)| < lim (rejection sampling)."""
    while True:
        th = rng.uniform(-lim, lim, n)
        if np.all(np.abs(np.diff(th)) < lim):
            return np.concatenate((rng.normal(size=2) * 3, th[::-1]))


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_chained_form_identity(n):
    """d/dt phi(q) along qdot = S eta: xi1' = a1, xi2' = a2, xi_k' = xi_(k-1) a1, to 1e-6 relative."""
    rng = np.random.default_rng(300 + n)
    chain = Chain.uniform(n, d=rng.uniform(0.7, 1.8, n - 1).tolist())
    cf = ChainedForm(chain.d)
    h = 1e-6
    for _ in range(30):
        q = _q_in_domain(rng, n)
        eta = rng.normal(size=2)
        xi, T = cf.xi(q), cf.T_alpha(q)
        alpha = T @ eta
        qd = chain.S(q) @ eta
        fd = (cf.xi(q + h * qd) - cf.xi(q - h * qd)) / (2 * h)
        expected = np.concatenate((alpha, xi[1:-1] * alpha[0]))
        np.testing.assert_allclose(fd, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


@settings(max_examples=80, deadline=None)
@given(n=st.integers(2, 5), seed=st.integers(0, 2**32 - 1))
def test_chained_inverse_roundtrip(n, seed):
    rng = np.random.default_rng(seed)
    cf = ChainedForm([1.0 + 0.1 * i for i in range(n - 1)])
    q = _q_in_domain(rng, n)
    np.testing.assert_allclose(cf.inverse(cf.xi(q)), q, rtol=0, atol=1e-10)


def test_three_link_against_corrected_thesis_formulas():
    """xi_2 of (2.94) with ERRATA E5f and T_alpha of (3.98) with E5g (beta1 corrected, beta2 as printed)."""
    rng = np.random.default_rng(5)
    d1, d2 = 1.3, 0.8
    cf = ChainedForm([d1, d2])
    for _ in range(50):
        q = _q_in_domain(rng, 3)
        _, _, th3, th2, th1 = q
        T1, T2, T3 = np.tan(th1 - th2), np.tan(th2 - th3), np.tan(th3)
        s1, s2, s3 = 1 / np.cos(th1 - th2), 1 / np.cos(th2 - th3), 1 / np.cos(th3)
        xi2 = T1 / (d1 * d2 * np.cos(th3) ** 4 * np.cos(th2 - th3) ** 3) + T2 / (d2**2 * np.cos(th3) ** 4) * (
            3 * T3 * T2 - s2**2
        )
        xi3 = T2 / (d2 * np.cos(th3) ** 3)
        beta1 = (
            T1 * s2**4 * s3**4 * (3 * T1 * T2 - s1**2) / (d1**2 * d2)
            - T1 * s2**3 * s3**4 * (5 * T2**2 - 10 * T2 * T3 + s2**2) / (d1 * d2**2)
            + T2
            * s3**4
            * (12 * T2**2 * T3**2 + 2 * T2**2 * s2**2 + 3 * T2**2 * s3**2 - 10 * T2 * T3 * s2**2 + s2**4)
            / d2**3
        )
        beta2 = s3**4 * s1**2 * s2**3 / (d1 * d2)
        xi = cf.xi(q)
        np.testing.assert_allclose(xi, [q[0], xi2, xi3, T3, q[1]], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(cf.T_alpha(q), [[np.cos(th3), 0], [beta1, beta2]], rtol=1e-9, atol=1e-12)


def test_domain_check():
    """The chained law refuses |theta_n| or an articulation angle at 90 deg (its frame psi = 0 here)."""
    ref = FlatReference(circle(8.0, 0.5), [1.0, 1.0])
    kin = ChainedBackstepping([1.0, 1.0], ref, [0.3] * 3, 2.0, 2.0, 5.0)
    with pytest.raises(SingularityError, match="theta_3"):
        kin.law(0.0, np.array([0, 0, np.pi / 2, np.pi / 2, np.pi / 2]), np.zeros(1))
    with pytest.raises(SingularityError, match="theta_1 - theta_2"):
        kin.law(0.0, np.array([0, 0, 0.0, 0.0, np.pi / 2]), np.zeros(1))
