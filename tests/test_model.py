"""The n-link model against invariants, the explicit thesis matrices and sympy."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_chain, random_q
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcreport.errors import ModelError
from ftcreport.model import Chain


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 6), seed=st.integers(0, 2**32 - 1))
def test_orthogonal_complement(n, seed):
    """S(q)^T A(q)^T = 0 (2.65) at random states, n = 2..6."""
    rng = np.random.default_rng(seed)
    chain = random_chain(rng, n)
    q = random_q(rng, n, max_art=np.radians(85))
    S, A = chain.S(q), chain.A(q)
    assert S.shape == (n + 2, 2) and A.shape == (n, n + 2)
    # entries of S grow like prod sec(phi); relative to their scale this is round-off
    scale = np.abs(S).max() * np.abs(A).max()
    np.testing.assert_allclose(S.T @ A.T, 0.0, atol=1e-13 * scale)
    # and A has full row rank, so S spans exactly its null space
    assert np.linalg.matrix_rank(A) == n


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_M_symmetric_positive_definite(rng, n):
    for _ in range(20):
        chain = random_chain(rng, n)
        q = random_q(rng, n, max_art=np.radians(89))
        M = chain.M(q)
        np.testing.assert_allclose(M, M.T, atol=1e-12)
        assert np.linalg.eigvalsh(M).min() > 0
        Mbar1 = chain.reduced(q, rng.normal(size=2))[0]
        np.testing.assert_allclose(Mbar1, Mbar1.T, atol=1e-9 * np.abs(Mbar1).max())
        assert np.linalg.eigvalsh(Mbar1).min() > 0


def test_positions_geometry(rng):
    """|P_i P_(i+1)| = d_i, P_i moves along U_i, C_i = P_i + a_i U_i (ERRATA E5)."""
    n = 4
    chain = random_chain(rng, n)
    q = random_q(rng, n)
    eta = rng.normal(size=2)
    P, Cm = chain.positions(q)
    np.testing.assert_allclose(P[-1], q[:2])
    np.testing.assert_allclose(np.linalg.norm(P[:-1] - P[1:], axis=1), chain.d, rtol=1e-12)
    th = chain.headings(q)
    U = np.column_stack((np.cos(th), np.sin(th)))
    np.testing.assert_allclose(Cm, P + np.asarray(chain.a)[:, None] * U, atol=1e-12)
    # no side slip: velocity of every P_i (finite difference) is along U_i
    h = 1e-6
    qd = chain.S(q) @ eta
    Pd = (chain.positions(q + h * qd)[0] - chain.positions(q - h * qd)[0]) / (2 * h)
    side = Pd[:, 0] * np.sin(th) - Pd[:, 1] * np.cos(th)
    np.testing.assert_allclose(side, 0.0, atol=1e-8)


def test_Sdot_matches_finite_difference(rng):
    for n in (2, 3, 5):
        chain = random_chain(rng, n)
        q, eta = random_q(rng, n), rng.normal(size=2)
        h = 1e-6
        qd = chain.S(q) @ eta
        fd = (chain.S(q + h * qd) - chain.S(q - h * qd)) / (2 * h)
        np.testing.assert_allclose(chain.Sdot(q, eta), fd, atol=1e-8)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_reduced_model_is_the_projection_of_the_full_matrices(rng, n):
    """The compiled reduced model (2.70)-(2.74) equals S^T M S, S^T M Sdot, S^T C(q, S eta), S^T B
    built from the numpy derivation M (D.5), C (D.9), B (C.8); etadot solves (2.70).

    Both sides evaluate the same products in a different order (loops vs BLAS), so they agree
    to round-off relative to the largest entry (1e-12; entries reach ~1e3 near 80 deg).
    """
    for _ in range(20):
        chain = random_chain(rng, n)
        q = random_q(rng, n, max_art=np.radians(80))
        eta, tau = rng.normal(size=2), rng.normal(size=2 * n)
        S, Sdot = chain.S(q), chain.Sdot(q, eta)
        M = chain.M(q)
        want = (S.T @ M @ S, S.T @ M @ Sdot, S.T @ chain.C(q, S @ eta), S.T @ chain.B(q))
        for got, ref in zip(chain.reduced(q, eta), want, strict=True):
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
        qdot, etadot = chain.dynamics(q, eta, tau)
        np.testing.assert_allclose(qdot, S @ eta, rtol=0, atol=1e-13 * np.abs(S).max())
        lhs = want[0] @ etadot + want[1] @ eta + want[2]
        np.testing.assert_allclose(lhs, want[3] @ tau, rtol=0, atol=1e-10 * max(1.0, np.abs(lhs).max()))


def test_C_is_Mdot_qdot_minus_dTdq(rng):
    """C(q, qdot) = Mdot qdot - dT/dq (D.9), by central differences of M."""
    for n in (2, 3, 5):
        chain = random_chain(rng, n)
        q, qdot = random_q(rng, n), rng.normal(size=n + 2)
        h = 1e-6
        Mdot = (chain.M(q + h * qdot) - chain.M(q - h * qdot)) / (2 * h)
        dTdq = np.array(
            [(qdot @ chain.M(q + h * e) @ qdot - qdot @ chain.M(q - h * e) @ qdot) / (4 * h) for e in np.eye(n + 2)]
        )
        np.testing.assert_allclose(chain.C(q, qdot), Mdot @ qdot - dTdq, atol=1e-6)


def test_wheel_speeds_from_kinematics(rng):
    """Bbar^T eta are the wheel speeds (v_i +/- b_i omega_i)/r_i computed from the geometry."""
    n = 3
    chain = random_chain(rng, n)
    q, eta = random_q(rng, n), rng.normal(size=2)
    h = 1e-6
    qd = chain.S(q) @ eta
    P0, P1 = chain.positions(q - h * qd)[0], chain.positions(q + h * qd)[0]
    th = chain.headings(q)
    v = np.einsum("ij,ij->i", (P1 - P0) / (2 * h), np.column_stack((np.cos(th), np.sin(th))))
    om = (chain.headings(q + h * qd) - chain.headings(q - h * qd)) / (2 * h)
    b, r = np.asarray(chain.b), np.asarray(chain.r)
    expect = np.empty(2 * n)
    expect[0::2] = (v + b * om) / r
    expect[1::2] = (v - b * om) / r
    np.testing.assert_allclose(chain.wheel_speeds(q, eta), expect, atol=1e-7)


# ----------------------------------------------------------------- explicit two-link model, ERRATA E1-E4
def _two_link_explicit(a1, a2, b1, b2, r1, r2, m1, m2, I1, I2, d, q, qdot):
    _, _, th2, th1 = q
    _, _, th2d, th1d = qdot
    s1, c1, s2, c2 = np.sin(th1), np.cos(th1), np.sin(th2), np.cos(th2)
    k2 = a2 * m2 + d * m1
    M = np.array(
        [
            [m1 + m2, 0, -k2 * s2, -a1 * m1 * s1],  # E1: m1 + m2, M14 = -a1 m1 sin th1
            [0, m1 + m2, k2 * c2, a1 * m1 * c1],
            [-k2 * s2, k2 * c2, m2 * a2**2 + m1 * d**2 + I2, a1 * d * m1 * np.cos(th1 - th2)],
            [-a1 * m1 * s1, a1 * m1 * c1, a1 * d * m1 * np.cos(th1 - th2), m1 * a1**2 + I1],
        ]
    )
    C = np.array(
        [
            -a1 * m1 * th1d**2 * c1 - k2 * th2d**2 * c2,
            -a1 * m1 * th1d**2 * s1 - k2 * th2d**2 * s2,  # E2: sin(theta2)
            -a1 * d * m1 * th1d**2 * np.sin(th1 - th2),
            a1 * d * m1 * th2d**2 * np.sin(th1 - th2),
        ]
    )
    sp = d * np.sin(th1 - th2)
    B = np.array(
        [
            [c1 / r1, c1 / r1, c2 / r2, c2 / r2],
            [s1 / r1, s1 / r1, s2 / r2, s2 / r2],  # E3: sin in row 2
            [sp / r1, sp / r1, b2 / r2, -b2 / r2],  # E3: /r1
            [b1 / r1, -b1 / r1, 0, 0],
        ]
    )
    phi = th1 - th2
    tp = np.tan(phi)
    Mbar1 = np.diag([m1 + m2 + (I2 + a2**2 * m2 + d**2 * m1) * tp**2 / d**2, I1 + a1**2 * m1])  # E4
    Bbar = np.array(
        [
            [1 / (r1 * np.cos(phi)), 1 / (r1 * np.cos(phi)), (1 + b2 * tp / d) / r2, (1 - b2 * tp / d) / r2],
            [b1 / r1, -b1 / r1, 0, 0],
        ]
    )
    return M, C, B, Mbar1, Bbar


def test_generic_equals_explicit_two_link(rng):
    """Generic n = 2 model == the corrected explicit matrices of ERRATA E1-E4 to 1e-9."""
    for _ in range(50):
        chain = random_chain(rng, 2)
        q = random_q(rng, 2, max_art=np.radians(80))
        eta = rng.normal(size=2)
        qdot = chain.S(q) @ eta
        a1, a2 = chain.a
        b1, b2 = chain.b
        r1, r2 = chain.r
        m1, m2 = chain.m
        I1, I2 = chain.I
        (d,) = chain.d
        M, C, B, Mbar1, Bbar = _two_link_explicit(a1, a2, b1, b2, r1, r2, m1, m2, I1, I2, d, q, qdot)
        np.testing.assert_allclose(chain.M(q), M, atol=1e-9)
        np.testing.assert_allclose(chain.C(q, qdot), C, atol=1e-9)
        np.testing.assert_allclose(chain.B(q), B, atol=1e-9)
        Mb1, _, _, Bb = chain.reduced(q, eta)
        np.testing.assert_allclose(Mb1, Mbar1, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(Bb, Bbar, rtol=1e-9, atol=1e-9)


def test_generic_equals_explicit_three_link(rng):
    """n = 3 against the thesis's (2.54) with the corrections of ERRATA E5b."""
    for _ in range(30):
        chain = random_chain(rng, 3)
        q = random_q(rng, 3)
        qdot = rng.normal(size=5)
        a1, a2, a3 = chain.a
        b1, b2, b3 = chain.b
        r1, r2, r3 = chain.r
        m1, m2, m3 = chain.m
        I1, I2, I3 = chain.I
        d1, d2 = chain.d
        _, _, th3, th2, th1 = q
        _, _, w3, w2, w1 = qdot
        h3, h2, h1 = (m1 + m2) * d2 + a3 * m3, d1 * m1 + a2 * m2, a1 * m1
        M = np.array(
            [
                [m1 + m2 + m3, 0, -h3 * np.sin(th3), -h2 * np.sin(th2), -h1 * np.sin(th1)],
                [0, m1 + m2 + m3, h3 * np.cos(th3), h2 * np.cos(th2), h1 * np.cos(th1)],
                [0, 0, (m1 + m2) * d2**2 + m3 * a3**2 + I3, h2 * d2 * np.cos(th2 - th3), h1 * d2 * np.cos(th1 - th3)],
                [0, 0, 0, m1 * d1**2 + m2 * a2**2 + I2, a1 * m1 * d1 * np.cos(th1 - th2)],
                [0, 0, 0, 0, m1 * a1**2 + I1],
            ]
        )
        M = np.triu(M) + np.triu(M, 1).T
        C = np.array(
            [
                -(a1 * m1 * w1**2 * np.cos(th1) + h2 * w2**2 * np.cos(th2) + h3 * w3**2 * np.cos(th3)),
                -(a1 * m1 * w1**2 * np.sin(th1) + h2 * w2**2 * np.sin(th2) + h3 * w3**2 * np.sin(th3)),
                -d2 * (a1 * m1 * w1**2 * np.sin(th1 - th3) + h2 * w2**2 * np.sin(th2 - th3)),
                -a1 * d1 * m1 * w1**2 * np.sin(th1 - th2) + h2 * d2 * w3**2 * np.sin(th2 - th3),
                a1 * m1 * (d1 * w2**2 * np.sin(th1 - th2) + d2 * w3**2 * np.sin(th1 - th3)),
            ]
        )
        B = np.zeros((5, 6))
        for i, (th, r) in enumerate(((th1, r1), (th2, r2), (th3, r3))):
            B[0, 2 * i : 2 * i + 2] = np.cos(th) / r
            B[1, 2 * i : 2 * i + 2] = np.sin(th) / r
        B[2, 0:2] = d2 * np.sin(th1 - th3) / r1
        B[2, 2:4] = d2 * np.sin(th2 - th3) / r2
        B[2, 4:6] = [b3 / r3, -b3 / r3]  # E5b: B(3,6) = -b3/r3
        B[3, 0:2] = d1 * np.sin(th1 - th2) / r1  # E5b
        B[3, 2:4] = [b2 / r2, -b2 / r2]  # E5b: B(4,3) = +b2/r2
        B[4, 0:2] = [b1 / r1, -b1 / r1]
        np.testing.assert_allclose(chain.M(q), M, atol=1e-9)
        np.testing.assert_allclose(chain.C(q, qdot), C, atol=1e-9)
        np.testing.assert_allclose(chain.B(q), B, atol=1e-9)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_against_symbolic_lagrangian(n):
    """An independent sympy derivation (kinetic energy, virtual work) for n = 2..4."""
    sp = pytest.importorskip("sympy")
    rng = np.random.default_rng(100 + n)
    chain = random_chain(rng, n)
    th = sp.symbols(f"th1:{n + 1}")  # robot order
    thd = sp.symbols(f"w1:{n + 1}")
    x, y, xd, yd = sp.symbols("x y xd yd")
    q = [x, y, *th[::-1]]
    qd = [xd, yd, *thd[::-1]]
    P = [None] * n
    P[n - 1] = sp.Matrix([x, y])
    for i in range(n - 2, -1, -1):
        P[i] = P[i + 1] + chain.d[i] * sp.Matrix([sp.cos(th[i + 1]), sp.sin(th[i + 1])])
    Cm = [P[i] + chain.a[i] * sp.Matrix([sp.cos(th[i]), sp.sin(th[i])]) for i in range(n)]
    qdv = sp.Matrix(qd)
    T = 0
    for i in range(n):
        v = Cm[i].jacobian(q) * qdv
        T += sp.Rational(1, 2) * chain.m[i] * (v.T * v)[0] + sp.Rational(1, 2) * chain.I[i] * thd[i] ** 2
    Msym = sp.hessian(T, qd)
    dTdq = sp.Matrix([sp.diff(T, qi) for qi in q])
    Mdot = Msym.applyfunc(lambda e: sum(sp.diff(e, qi) * qdi for qi, qdi in zip(q, qd, strict=True)))
    Csym = Mdot * qdv - dTdq
    # virtual work: forces at P_i along U_i, moments on theta_i
    taus = sp.symbols(f"tau0:{2 * n}")
    Q = sp.zeros(n + 2, 1)
    for i in range(n):
        tr, tl = taus[2 * i], taus[2 * i + 1]
        F = (tr + tl) / chain.r[i] * sp.Matrix([sp.cos(th[i]), sp.sin(th[i])])
        Q += P[i].jacobian(q).T * F
        Q += sp.Matrix([sp.diff(th[i], qi) for qi in q]) * chain.b[i] * (tr - tl) / chain.r[i]
    Bsym = Q.jacobian(taus)
    fM = sp.lambdify([q], Msym, "numpy")
    fC = sp.lambdify([q, qd], Csym, "numpy")
    fB = sp.lambdify([q], Bsym, "numpy")
    for _ in range(5):
        qv = random_q(rng, n)
        qdv_ = rng.normal(size=n + 2)
        np.testing.assert_allclose(chain.M(qv), np.array(fM(qv), dtype=float), atol=1e-9)
        np.testing.assert_allclose(chain.C(qv, qdv_), np.array(fC(qv, qdv_), dtype=float).ravel(), atol=1e-9)
        np.testing.assert_allclose(chain.B(qv), np.array(fB(qv), dtype=float), atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"m": [30.0, -1.0]}, "m[1]"),
        ({"r": [0.0, 0.15]}, "r[0]"),
        ({"d": [1.0, 2.0]}, "d"),
        ({"I": [1.0, -2.0]}, "I[1]"),
        ({"b": [0.7, float("nan")]}, "b"),
    ],
)
def test_impossible_parameters_are_named(kwargs, field):
    base = {"a": [0.3, 0.3], "b": [0.75, 0.75], "r": [0.15, 0.15], "m": [30.0, 30.0], "I": [15.6, 15.6], "d": [1.0]}
    base.update(kwargs)
    with pytest.raises(ModelError, match=field.replace("[", r"\[").replace("]", r"\]")):
        Chain(**base)


def test_single_robot_refused():
    with pytest.raises(ModelError, match="at least 2 robots"):
        Chain(a=[0.3], b=[0.7], r=[0.1], m=[1.0], I=[1.0], d=[])
