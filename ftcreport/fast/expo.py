r"""The phi functions of exponential integrators, for the ETD2 step of fast.loop.

phi_1(z) = (e^z - 1) / z and phi_2(z) = (e^z - 1 - z) / z^2, for a matrix Z = h J (Hochbruck &
Ostermann, "Exponential integrators", Acta Numerica 19, 2010, (2.10)), by scaling and modified
squaring (Skaflestad & Wright, "The scaling and modified squaring method for matrix functions
related to the exponential", Appl. Numer. Math. 59, 2009):

1. balance Z by a diagonal similarity of powers of 2 (:func:`balance`; phi_k(D^-1 Z D) =
   D^-1 phi_k(Z) D);
2. scale X = Z / 2^s until ||X||_1 <= 1/2;
3. phi_2(X) by its Taylor series sum_j X^j / (j + 2)! (Horner, 14 terms: the remainder is below
   (1/2)^15 / 16! = 1.5e-18 relative), then phi_1 = I + X phi_2 and e^X = I + X phi_1;
4. s doublings, each from the identities of the scalar functions (they hold for commuting
   matrices, and functions of one matrix commute)::

       e^(2X) = e^X e^X,  phi_1(2X) = (e^X + I) phi_1(X) / 2,  phi_2(2X) = (phi_1(X)^2 + 2 phi_2(X)) / 4

Three m x m products per doubling, where the augmented-matrix exponential (Saad 1992) costs one
product of size 3m: 9x the work.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit

#: terms of phi_2's Taylor series at ||X||_1 <= 1/2 (remainder (1/2)^15 / 16! < 1e-17)
TAYLOR_TERMS = 14


@jit
def balance(Z):
    """d (powers of 2) with D^-1 Z D, D = diag(d), balanced: each off-diagonal row and column sum alike.

    The Parlett-Reinsch iteration (LAPACK's gebal; James, Langou & Lowery, "On matrix balancing
    and eigenvector computation", 2014, Algorithm 2) in the 1-norm, at most 30 sweeps.  Powers of
    2 scale without round-off.  Z of the motor block mixes amperes and metres per second, so its
    entries span ten decades; balanced, its norm is set by its stiff diagonal.
    """
    m = Z.shape[0]
    B = Z.copy()
    d = np.ones(m)
    for _ in range(30):
        done = True
        for i in range(m):
            c = 0.0
            r = 0.0
            for k in range(m):
                if k != i:
                    c += abs(B[k, i])
                    r += abs(B[i, k])
            if c == 0.0 or r == 0.0:
                continue
            total = c + r
            f = 1.0
            while c < 0.5 * r:
                c *= 2.0
                r *= 0.5
                f *= 2.0
            while c >= 2.0 * r:
                c *= 0.5
                r *= 2.0
                f *= 0.5
            if c + r < 0.95 * total:
                done = False
                d[i] *= f
                for k in range(m):
                    B[k, i] *= f
                    B[i, k] /= f
        if done:
            break
    return d


@jit
def _mm(A, B):
    """A B of small square matrices (plain loops: no BLAS call for a 6 x 6)."""
    m = A.shape[0]
    C = np.zeros((m, m))
    for i in range(m):
        for k in range(m):
            a = A[i, k]
            if a != 0.0:
                for j in range(m):
                    C[i, j] += a * B[k, j]
    return C


@jit
def _scaled(Z, at_least):
    """(d, X, s): Z balanced (D^-1 Z D, D = diag(d): :func:`balance`) and scaled by 2^-s, s the fewest halvings
    (at least ``at_least``) that bring its 1-norm to 1/2 or below."""
    m = Z.shape[0]
    d = balance(Z)
    X = np.empty((m, m))
    norm = 0.0
    for j in range(m):
        col = 0.0
        for i in range(m):
            X[i, j] = Z[i, j] * d[j] / d[i]
            col += abs(X[i, j])
        norm = max(norm, col)
    s = at_least
    if norm > 0.5 * 2.0**at_least:
        s = math.ceil(math.log2(norm / 0.5))
    X *= 0.5**s
    return d, X, s


@jit
def phi12(Z):
    """(phi_1(Z), phi_2(Z)) of a square matrix Z (module docstring: balance, scale, Taylor, double)."""
    m = Z.shape[0]
    d, X, s = _scaled(Z, 0)
    eye = np.eye(m)
    # phi_2(X) = sum_j X^j / (j + 2)!, by Horner from the highest term
    P2 = eye / math.gamma(TAYLOR_TERMS + 2.0)
    for j in range(TAYLOR_TERMS - 1, -1, -1):
        P2 = _mm(X, P2) + eye / math.gamma(j + 3.0)
    P1 = eye + _mm(X, P2)  # phi_1 = I + X phi_2
    E = eye + _mm(X, P1)  # e^X = I + X phi_1
    for _ in range(s):
        P2 = 0.25 * (_mm(P1, P1) + 2.0 * P2)  # phi_2(2X) = (phi_1(X)^2 + 2 phi_2(X)) / 4
        P1 = 0.5 * _mm(E + eye, P1)  # phi_1(2X) = (e^X + I) phi_1(X) / 2
        E = _mm(E, E)  # e^(2X) = (e^X)^2
    for i in range(m):
        for j in range(m):
            P1[i, j] *= d[i] / d[j]
            P2[i, j] *= d[i] / d[j]
    return P1, P2


@jit
def phi12_scalar(z):
    """(phi_1(z), phi_2(z)) of a scalar; Taylor series near 0, where the closed forms cancel."""
    if abs(z) < 1e-3:
        # phi_1 = 1 + z/2 + z^2/6 + z^3/24 + ..., phi_2 = 1/2 + z/6 + z^2/24 + z^3/120 + ...
        # (truncation below |z|^4 / 100 < 1e-14)
        return 1.0 + z * (0.5 + z * (1.0 / 6.0 + z / 24.0)), 0.5 + z * (1.0 / 6.0 + z * (1.0 / 24.0 + z / 120.0))
    e = math.expm1(z)
    return e / z, (e - z) / (z * z)


@jit
def phi123(Z):
    """(phi_1(Z/2), phi_2(Z/2), phi_1(Z), phi_2(Z), phi_3(Z)) of a square matrix Z, phi_3(z) = (e^z - 1 - z -
    z^2/2) / z^3: as :func:`phi12` (the same balancing and Taylor length: phi_3's remainder is below (1/2)^15 /
    17!), scaled by at least one halving, so that the values at Z/2 are those before the last doubling
    (ETD3RK's stage at t + h/2 needs them), with phi_3's doubling (Skaflestad & Wright 2009, (2.6))::

        phi_3(2X) = (e^X phi_3(X) + phi_1(X) / 2 + phi_2(X) + phi_3(X)) / 8
    """
    m = Z.shape[0]
    d, X, s = _scaled(Z, 1)
    eye = np.eye(m)
    # phi_3(X) = sum_j X^j / (j + 3)!, by Horner from the highest term
    P3 = eye / math.gamma(TAYLOR_TERMS + 3.0)
    for j in range(TAYLOR_TERMS - 1, -1, -1):
        P3 = _mm(X, P3) + eye / math.gamma(j + 4.0)
    P2 = 0.5 * eye + _mm(X, P3)  # phi_2 = I/2 + X phi_3
    P1 = eye + _mm(X, P2)
    E = eye + _mm(X, P1)
    Q1 = P1
    Q2 = P2
    for k in range(s):
        if k == s - 1:
            Q1 = P1.copy()
            Q2 = P2.copy()
        P3 = 0.125 * (_mm(E, P3) + 0.5 * P1 + P2 + P3)
        P2 = 0.25 * (_mm(P1, P1) + 2.0 * P2)
        P1 = 0.5 * _mm(E + eye, P1)
        E = _mm(E, E)
    for i in range(m):
        for j in range(m):
            f = d[i] / d[j]
            Q1[i, j] *= f
            Q2[i, j] *= f
            P1[i, j] *= f
            P2[i, j] *= f
            P3[i, j] *= f
    return Q1, Q2, P1, P2, P3


@jit
def phi123_scalar(z):
    """(phi_1(z), phi_2(z), phi_3(z)) of a scalar; Taylor series for |z| < 0.2, where phi_3's closed form
    cancels (its round-off there up to 1e-16 / |z|^3), the closed forms beyond (at most 1.3e-14)."""
    if abs(z) < 0.2:
        # phi_k(z) = sum_j z^j / (j + k)!: 10 terms, remainder below 0.2^10 / 10! < 3e-14 of phi_1's
        p1, p2, p3 = 0.0, 0.0, 0.0
        for j in range(12, -1, -1):
            p1 = p1 * z + 1.0 / math.gamma(j + 2.0)
            p2 = p2 * z + 1.0 / math.gamma(j + 3.0)
            p3 = p3 * z + 1.0 / math.gamma(j + 4.0)
        return p1, p2, p3
    e = math.expm1(z)
    return e / z, (e - z) / (z * z), (e - z - 0.5 * z * z) / (z * z * z)
