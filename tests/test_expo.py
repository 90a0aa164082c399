"""The phi functions of the ETD2 step (fast/expo.py) against scipy's matrix exponential.

The reference is scipy.linalg.expm (Al-Mohy & Higham 2009) of the augmented matrix
[[Z, I, 0], [0, 0, I], [0, 0, 0]], whose first block row is [e^Z, phi_1(Z), phi_2(Z)] (Saad 1992):
an independent route to what fast/expo.py gets by scaling and modified squaring.  Also: the scalar
closed forms on a diagonal matrix, balancing on a matrix scaled as the motor block is (amperes
against metres per second), and the scalar series at its switch-over point.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg as sl

from ftcreport.fast.expo import balance, phi12, phi12_scalar


def _phi_ref(Z):
    m = Z.shape[0]
    A = np.zeros((3 * m, 3 * m))
    A[:m, :m] = Z
    A[:m, m : 2 * m] = np.eye(m)
    A[m : 2 * m, 2 * m :] = np.eye(m)
    E = sl.expm(A)
    return E[:m, m : 2 * m], E[:m, 2 * m :]


@pytest.mark.parametrize("scale", [1e-3, 0.5, 3.0, 40.0, 400.0])
def test_phi12_matches_scipy_over_five_decades_of_norm(scale):
    rng = np.random.default_rng(7)
    A = rng.normal(size=(10, 10)) * scale / np.sqrt(10)
    A -= 2.0 * scale * np.eye(10)  # a stable matrix, as h J of a damped plant is
    P1, P2 = phi12(A)
    R1, R2 = _phi_ref(A)
    # measured <= 1.9e-15 relative up to ||A|| ~ 1000 (s = 11 doublings); 1e-12 leaves a margin of
    # 500 for other platforms' round-off without hiding a wrong doubling formula (that is O(1))
    assert np.abs(P1 - R1).max() <= 1e-12 * np.abs(R1).max()
    assert np.abs(P2 - R2).max() <= 1e-12 * np.abs(R2).max()


def test_phi_functions_of_a_diagonal_matrix_are_the_scalar_closed_forms():
    z = np.array([-11.0, -0.3, 0.0, 1e-5, 2.0])
    P1, P2 = phi12(np.diag(z))
    for k, zk in enumerate(z):
        e1 = 1.0 if zk == 0.0 else math.expm1(zk) / zk
        e2 = 0.5 if zk == 0.0 else (math.expm1(zk) - zk) / zk**2
        if abs(zk) < 1e-3:  # the closed form cancels there: phi_2 = 1/2 + z/6 + O(z^2)
            e2 = 0.5 + zk / 6.0
        assert P1[k, k] == pytest.approx(e1, rel=1e-13)
        assert P2[k, k] == pytest.approx(e2, rel=1e-10)
        assert phi12_scalar(zk)[0] == pytest.approx(e1, rel=1e-13)
        assert phi12_scalar(zk)[1] == pytest.approx(e2, rel=1e-10)
    assert np.count_nonzero(P1 - np.diag(np.diag(P1))) == 0  # no coupling appears


def test_scalar_series_and_closed_form_agree_at_the_switch_over():
    for z in (-1e-3, 1e-3):
        series = phi12_scalar(z * (1 - 1e-12))
        closed = phi12_scalar(z * (1 + 1e-12))
        # the closed form phi_2 = (e^z - 1 - z) / z^2 loses eps / z^2 * |z| ~ 1e-13 at |z| = 1e-3
        assert series[0] == pytest.approx(closed[0], rel=1e-14)
        assert series[1] == pytest.approx(closed[1], rel=1e-12)


def test_phi12_on_a_badly_scaled_motor_like_block():
    """eta rows against current columns: entries from 1e-2 to 1e5, the balanced result still matches."""
    rng = np.random.default_rng(3)
    m = 8
    Z = rng.normal(size=(m, m))
    Z[2:, :2] *= 500.0  # d i_dot / d eta: k_b N Bbar / L_a, large
    Z[:2, 2:] *= 0.01  # d etadot / d i: gear k_m over the mass, small
    Z[np.arange(2, m), np.arange(2, m)] = -11.0  # h R_a / L_a at h = 5 ms
    P1, P2 = phi12(Z)
    R1, R2 = _phi_ref(Z)
    assert np.abs(P1 - R1).max() <= 1e-12 * np.abs(R1).max()
    assert np.abs(P2 - R2).max() <= 1e-12 * np.abs(R2).max()
    d = balance(Z)
    assert np.all(np.log2(d) == np.round(np.log2(d)))  # powers of 2: scaling without round-off
    B = Z * d[None, :] / d[:, None]
    assert np.abs(B).sum(axis=0).max() < 0.2 * np.abs(Z).sum(axis=0).max()  # the norm fell
