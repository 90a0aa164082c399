r"""The phi functions of exponential integrators, for the ETD2 step of fast.loop.

phi_1(z) = (e^z - 1) / z and phi_2(z) = (e^z - 1 - z) / z^2, for a matrix Z = h J
(Hochbruck & Ostermann, "Exponential integrators", Acta Numerica 19, 2010, (2.10)).  Both come
from one matrix exponential of an augmented matrix (Saad 1992; Al-Mohy & Higham 2011, (2.11))::

    exp([[Z, I, 0],      [[e^Z, phi_1(Z), phi_2(Z)],
         [0, 0, I],   =   [0,   I,        I       ],
         [0, 0, 0]])      [0,   0,        I       ]]

The exponential is scaling and squaring with the diagonal [7/7] Pade approximant (Higham,
"The scaling and squaring method for the matrix exponential revisited", SIAM J. Matrix Anal.
Appl. 26, 2005): the matrix is scaled by 2^-s until its 1-norm is at most theta_7 = 0.9504, where
the approximant's backward error is below the unit round-off (Higham's Table 2.3), then squared s
times.
"""

from __future__ import annotations

import math

import numpy as np

from .kernels import jit

#: theta_7 of Higham (2005), Table 2.3: ||A||_1 <= theta_7 keeps the [7/7] backward error below 2^-53
THETA_7 = 0.9504178996162932
#: the [7/7] Pade coefficients b_0..b_7 (Higham 2005, (2.2)): (2m - j)! m! / ((2m)! j! (m - j)!) scaled
PADE_7 = (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0)


@jit
def expm(A):
    """e^A of a square matrix by scaling and squaring with the [7/7] Pade approximant (Higham 2005)."""
    n = A.shape[0]
    norm = 0.0
    for j in range(n):  # the 1-norm: the largest column sum
        acc = 0.0
        for i in range(n):
            acc += abs(A[i, j])
        norm = max(norm, acc)
    s = 0
    if norm > THETA_7:
        s = math.ceil(math.log2(norm / THETA_7))
    X = A * (0.5**s)
    b = PADE_7
    eye = np.eye(n)
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    # U = X (b7 X^6 + b5 X^4 + b3 X^2 + b1 I), V = b6 X^6 + b4 X^4 + b2 X^2 + b0 I
    U = X @ (b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
    V = b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * eye
    # r_77(X) = (V - U)^-1 (V + U)
    E = np.ascontiguousarray(np.linalg.solve(V - U, V + U))
    for _ in range(s):
        E = E @ E
    return E


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
def phi12(Z):
    """(phi_1(Z), phi_2(Z)) of a square matrix Z, from one exponential of the augmented matrix above.

    Computed on the balanced D^-1 Z D (:func:`balance`): phi_k(D^-1 Z D) = D^-1 phi_k(Z) D, and
    the augmented matrix keeps its identity blocks under the same scaling.
    """
    m = Z.shape[0]
    d = balance(Z)
    A = np.zeros((3 * m, 3 * m))
    for i in range(m):
        for j in range(m):
            A[i, j] = Z[i, j] * d[j] / d[i]
    for i in range(m):
        A[i, m + i] = 1.0
        A[m + i, 2 * m + i] = 1.0
    E = expm(A)
    P1 = np.empty((m, m))
    P2 = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            P1[i, j] = E[i, m + j] * d[i] / d[j]
            P2[i, j] = E[i, 2 * m + j] * d[i] / d[j]
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
