r"""Compiled (numba) chained-form coordinates xi = phi(q) and T_alpha (Theorem 2.1) for any n.

Face: :mod:`ftcreport.model.chained`; tests/chained_reference.py derives the same maps with sympy.
Computed numerically: xi_(k-1) is the derivative of xi_k with respect to x along g1 / cos(theta_n), so
``xi_(m-j) = j! y_j`` where ``y_j`` are the Taylor coefficients in s = x of y along the flow
``dtheta_(i+1)/ds = sec(theta_n) w_(i+1) tan(phi_i) / d_i``, ``dy/ds = tan(theta_n)`` (theta_1
constant: g1 does not move it), by Taylor-mode differentiation (one coefficient at a time).  Then
``T21 = cos(theta_n) (n+1)! y_(n+1)`` and, because xi_2 depends on theta_1 only through the newest
coefficient of each robot in turn,
``T22 = sec^2(theta_n) sec^(n-1)(theta_n) prod_(i=1)^(n-1) w_(i+1) sec^2(phi_i) / d_i``.
Both agree with the sympy derivation to round-off (tested for n = 2..6).
"""

from __future__ import annotations

import math

from ..jit.compiling import jit
from ..jit.packed import _wrap


# =========================================================================== chained form
@jit
def chained_xi_T(th, d, work, ang):
    """xi_2..xi_(m-1) into ang, and (T21, T22), at headings th (robot order); see the module doc.

    ``work``: at least (9 n, n + 2) scratch (every jet below lives in it).
    """
    n = th.shape[0]
    K = n + 1
    nl = n - 1
    work[:] = 0.0
    TH = work[0:n]
    W = work[n : 2 * n]
    P1 = work[2 * n : 3 * n]
    RHS = work[3 * n : 4 * n]
    o = 4 * n
    PHI = work[o : o + nl]
    SP = work[o + nl : o + 2 * nl]
    CP = work[o + 2 * nl : o + 3 * nl]
    SEC = work[o + 3 * nl : o + 4 * nl]
    TAN = work[o + 4 * nl : o + 5 * nl]
    o += 5 * nl
    Y = work[o]
    STN = work[o + 1]
    CTN = work[o + 2]
    SECN = work[o + 3]
    TANN = work[o + 4]
    for k in range(n):
        TH[k, 0] = th[k]
    W[n - 1, 0] = 1.0
    last = n - 1
    for j in range(K):
        # coefficient j of every intermediate (Taylor-mode recurrences)
        for l in range(nl):
            PHI[l, j] = TH[l, j] - TH[l + 1, j]
            if j == 0:
                SP[l, 0] = math.sin(PHI[l, 0])
                CP[l, 0] = math.cos(PHI[l, 0])
            else:
                a = 0.0
                b = 0.0
                for i in range(1, j + 1):
                    a += i * PHI[l, i] * CP[l, j - i]
                    b += i * PHI[l, i] * SP[l, j - i]
                SP[l, j] = a / j
                CP[l, j] = -b / j
            s = 1.0 if j == 0 else 0.0
            for i in range(1, j + 1):
                s -= CP[l, i] * SEC[l, j - i]
            SEC[l, j] = s / CP[l, 0]
            s = 0.0
            for i in range(j + 1):
                s += SP[l, i] * SEC[l, j - i]
            TAN[l, j] = s
        if j == 0:
            STN[0] = math.sin(TH[last, 0])
            CTN[0] = math.cos(TH[last, 0])
        else:
            a = 0.0
            b = 0.0
            for i in range(1, j + 1):
                a += i * TH[last, i] * CTN[j - i]
                b += i * TH[last, i] * STN[j - i]
            STN[j] = a / j
            CTN[j] = -b / j
        s = 1.0 if j == 0 else 0.0
        for i in range(1, j + 1):
            s -= CTN[i] * SECN[j - i]
        SECN[j] = s / CTN[0]
        s = 0.0
        for i in range(j + 1):
            s += STN[i] * SECN[j - i]
        TANN[j] = s
        for k in range(n - 2, -1, -1):  # w_k = w_(k+1) sec(phi_k)
            s = 0.0
            for i in range(j + 1):
                s += W[k + 1, i] * SEC[k, j - i]
            W[k, j] = s
        for k in range(1, n):  # dtheta_k/ds = sec(theta_n) w_k tan(phi_(k-1)) / d_(k-1)
            s = 0.0
            for i in range(j + 1):
                s += SECN[i] * W[k, j - i]
            P1[k, j] = s
            s = 0.0
            for i in range(j + 1):
                s += P1[k, i] * TAN[k - 1, j - i]
            RHS[k, j] = s / d[k - 1]
            TH[k, j + 1] = RHS[k, j] / (j + 1)
        Y[j + 1] = TANN[j] / (j + 1)
    m = n + 2  # xi_2..xi_(m-1): xi_(m-jj) = jj! y_jj
    fact = 1.0
    for jj in range(1, n + 1):
        fact *= jj
        ang[m - jj - 2] = fact * Y[jj]
    T21 = CTN[0] * fact * (n + 1) * Y[n + 1]
    secn = SECN[0]
    T22 = secn * secn * secn ** (n - 1)
    for l in range(nl):
        T22 *= W[l + 1, 0] * SEC[l, 0] * SEC[l, 0] / d[l]
    return T21, T22


@jit
def to_frame(q, psi, out):
    """q in the frame rotated by psi, into out: theta_n wrapped in the frame, every other heading keeps its
    (wrapped) articulation angle to its follower (the re-anchoring of control/kinematic.py, beyond the thesis)."""
    c, s = math.cos(psi), math.sin(psi)
    out[0] = c * q[0] + s * q[1]
    out[1] = -s * q[0] + c * q[1]
    out[2] = _wrap(q[2] - psi)
    acc = out[2]
    for k in range(3, q.shape[0]):
        acc = acc + _wrap(q[k] - q[k - 1])
        out[k] = acc
    return out


@jit
def xi_T(qf, d, work, xi, T):
    """Chained coordinates xi = phi(q) (m,) and T_alpha (2, 2) at q (in its frame), into xi and T.

    Theorem 2.1 for any n (the module doc; ERRATA E5e-E5g: the printed (2.94), (2.99), (3.98) are wrong,
    this is checked against the sympy derivation of tests/chained_reference.py).  alpha = T_alpha eta (3.98).
    """
    n = qf.shape[0] - 2
    m = n + 2
    T21, T22 = chained_xi_T(qf[m - 1 : 1 : -1], d, work, xi[1 : m - 1])  # headings in robot order (a view)
    # xi_1 = x, xi_m = y;  T_alpha = [[cos theta_n, 0], [T21, T22]]
    xi[0] = qf[0]
    xi[m - 1] = qf[1]
    T[0, 0] = math.cos(qf[2])  # theta_n, the last robot
    T[0, 1] = 0.0
    T[1, 0] = T21
    T[1, 1] = T22
