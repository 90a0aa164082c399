r"""Compiled (numba) references: the path's Taylor jets, the flat-output reference of every robot (3.59-3.66).

Face: :class:`ftcreport.references.FlatReference` and :class:`~ftcreport.references.TrigPath`, which
check feasibility through these kernels; the closed-form references of the tests check them.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import (
    E_REF_ART,
    E_REF_SPEED,
    KIN_CHAINED,
    Ref,  # noqa: F401 - the face (references/__init__.py) reads its twin only
    _wrap,
)
from ..model.chained_compiled import to_frame, xi_T


# ==================================================================== references (faces: references/__init__.py)
@jit
def path_jets(R, t):
    """Normalized Taylor coefficients (f^(k)(t) / k!) of x_d, y_d at t (references.TrigPath).

    x = x0 + vx t + sum_j a_j sin(w_j t + ph_j) in the path frame, likewise y, then rotated by R.rot
    and translated by (R.ox, R.oy).  The thesis's references (3.5-3.7, the eight of 3.3.2.3 with
    ERRATA E11) are such paths.
    """
    K1 = R.order + 1
    X = np.zeros(K1)
    Y = np.zeros(K1)
    X[0] = R.x0 + R.vx * t
    Y[0] = R.y0 + R.vy * t
    if K1 > 1:
        X[1] += R.vx
        Y[1] += R.vy
    for which in range(2):
        terms = R.xterms if which == 0 else R.yterms
        arr = X if which == 0 else Y
        for j in range(terms.shape[0]):
            amp, w, ph = terms[j, 0], terms[j, 1], terms[j, 2]
            fact = 1.0
            for k in range(K1):
                if k > 0:
                    fact *= k
                # d^k/dt^k A sin(w t + ph) = A w^k sin(w t + ph + k pi / 2)
                arr[k] += amp * w**k * math.sin(w * t + ph + k * np.pi / 2) / fact
    c, s = math.cos(R.rot), math.sin(R.rot)
    # world = origin + R(rot) (x, y)
    Xw = c * X - s * Y
    Yw = s * X + c * Y
    Xw[0] += R.ox
    Yw[0] += R.oy
    return Xw, Yw


@jit
def _conv(a, b, k):
    """Coefficient k of the product of two jets."""
    acc = 0.0
    for i in range(k + 1):
        acc += a[i] * b[k - i]
    return acc


@jit
def ref_jets(R, t, info):
    """Jets of every heading (rows, robot order) and of v_n at t: the flat outputs (3.59)-(3.66) for any n.

    From P_n's path: theta_nd = atan2(ydot_d, xdot_d), v_nd = xdot_d cos theta_nd + ydot_d sin theta_nd,
    P_(i)d = P_(i+1)d + d_i U_(i+1)d (ERRATA E5, E5c), theta_id the direction of Pdot_(i)d; each robot
    loses one order of the jet.  Refuses speeds below R.min_speed (info E_REF_SPEED).
    """
    X0, Y0 = path_jets(R, t)
    n = R.n
    K1 = R.order + 1
    TH = np.zeros((n, K1))
    LEN = np.zeros(n, dtype=np.int64)
    V = np.zeros(K1)
    wk = np.zeros((11, K1))  # one allocation for the work jets
    X, Y, Xd, Yd, Xdd, Ydd, num, den, s, c = wk[0], wk[1], wk[2], wk[3], wk[4], wk[5], wk[6], wk[7], wk[8], wk[9]
    w = wk[10]
    X[:] = X0
    Y[:] = Y0
    L = K1
    for i in range(n - 1, -1, -1):
        for k in range(L - 1):
            Xd[k] = X[k + 1] * (k + 1)
            Yd[k] = Y[k + 1] * (k + 1)
        speed = math.hypot(Xd[0], Yd[0])
        if speed < R.min_speed:
            info[0] = E_REF_SPEED
            info[1] = t
            info[2] = i + 1
            info[3] = speed
            return X0, Y0, TH, LEN, V
        m = L - 2
        for k in range(m):
            Xdd[k] = Xd[k + 1] * (k + 1)
            Ydd[k] = Yd[k + 1] * (k + 1)
        for k in range(m):
            # thetadot = (xdot yddot - ydot xddot) / (xdot^2 + ydot^2)
            num[k] = _conv(Xd, Ydd, k) - _conv(Yd, Xdd, k)
            den[k] = _conv(Xd, Xd, k) + _conv(Yd, Yd, k)
        th = TH[i]
        th[0] = math.atan2(Yd[0], Xd[0])
        for k in range(m):  # thetadot = num / den (jet quotient), integrated
            acc = num[k]
            for j in range(1, k + 1):
                acc -= den[j] * w[k - j]
            w[k] = acc / den[0]
            th[k + 1] = w[k] / (k + 1)
        LEN[i] = m + 1
        s[0] = math.sin(th[0])
        c[0] = math.cos(th[0])
        # jets of sin and cos: k s_k = sum_j j th_j c_(k-j), k c_k = -sum_j j th_j s_(k-j)
        for k in range(1, m + 1):
            a = 0.0
            b = 0.0
            for j in range(1, k + 1):
                a += j * th[j] * c[k - j]
                b += j * th[j] * s[k - j]
            s[k] = a / k
            c[k] = -b / k
        if i == n - 1:
            for k in range(m + 1):
                # v_n = xdot cos theta_n + ydot sin theta_n
                V[k] = _conv(Xd, c, k) + _conv(Yd, s, k)
        if i > 0:
            L = m + 1
            for k in range(L):
                # P_i = P_(i+1) + d_i (cos theta_(i+1), sin theta_(i+1))
                X[k] = X[k] + R.d[i - 1] * c[k]
                Y[k] = Y[k] + R.d[i - 1] * s[k]
    return X0, Y0, TH, LEN, V


@jit
def _shift3(a, length, delta, out):
    """First 3 normalized Taylor coefficients at t0 + delta of the jet a at t0, into out."""
    for i in range(3):
        s = 0.0
        for j in range(i, length):
            # b_i = sum_(j >= i) C(j, i) a_j delta^(j - i)
            comb = 1.0 if i == 0 else (float(j) if i == 1 else 0.5 * j * (j - 1))  # C(j, i), i <= 2
            s += comb * a[j] * delta ** (j - i)
        out[i] = s


@jit
def ref_point(R, jets, t, delta, info, q_d, eta_d, eta_d_dot, sc, work):
    """The reference state at t0 + delta from the jets at t0: q_d, eta_d, eta_d_dot and sc = (v_d, omega_d,
    v_d_dot, omega_d_dot) of robot n (the two-link scheme's unicycle, 3.5-3.7).  Headings are unwrapped along
    the chain; an articulation angle beyond R.max_art is refused (info E_REF_ART).
    After the call ``work[:n, :3]`` holds the first three coefficients of every heading (thetadot_id in column 1).

    ``work``: (n + 4, max(n, 3)) scratch (no allocation: this runs for three instants per new t).
    """
    X0, Y0, TH, LEN, V = jets
    n = R.n
    K1 = R.order + 1
    N = n + 2
    th3 = work[:n, :3]
    X, Y, v, th = work[n, :3], work[n + 1, :3], work[n + 2, :3], work[n + 3, :n]
    if delta != 0.0:
        _shift3(X0, K1, delta, X)
        _shift3(Y0, K1, delta, Y)
        _shift3(V, LEN[n - 1], delta, v)
        for i in range(n):
            _shift3(TH[i], LEN[i], delta, th3[i])
    else:
        X[:] = X0[:3]
        Y[:] = Y0[:3]
        v[:] = V[:3]
        for i in range(n):
            th3[i] = TH[i, :3]
    for i in range(n):
        th[i] = th3[i, 0]
    for i in range(n - 2, -1, -1):
        th[i] = th[i + 1] + _wrap(th[i] - th[i + 1])
    worst = -1.0
    iw = 0
    for i in range(n - 1):
        a = abs(th[i] - th[i + 1])
        if a > worst:
            worst = a
            iw = i
    if n > 1 and worst > R.max_art:
        info[0] = E_REF_ART
        info[1] = t
        info[2] = iw
        info[3] = math.degrees(th[iw] - th[iw + 1])
        return
    # q_d = [x_d, y_d, theta_nd, ..., theta_1d] (2.60), eta_d = [v_nd, omega_1d], etadot_d = [vdot_nd, 2 th_1,2]
    q_d[0] = X[0]
    q_d[1] = Y[0]
    for k in range(n):
        q_d[N - 1 - k] = th[k]
    eta_d[0] = v[0]
    eta_d[1] = th3[0, 1]
    eta_d_dot[0] = v[1]
    eta_d_dot[1] = 2.0 * th3[0, 2]
    sc[0] = v[0]
    sc[1] = th3[n - 1, 1]
    sc[2] = v[1]
    sc[3] = 2.0 * th3[n - 1, 2]


@jit
def ref_rows(R, ts, q_d, eta_d, ok):
    """:func:`ref_point` at each of the instants ``ts`` from its own jets (delta = 0, as a first call of
    ``FlatReference.at`` at that instant): rows of ``q_d`` (k, n + 2) and ``eta_d`` (k, 2); ``ok[i]`` False
    where the reference is infeasible at ts[i] (the row is left as it was)."""
    n = R.n
    info = np.zeros(4)
    eta_d_dot = np.empty(2)
    sc = np.empty(4)
    work = np.empty((n + 4, max(n, 3)))
    qi = np.empty(n + 2)
    ei = np.empty(2)
    for i in range(ts.shape[0]):
        info[:] = 0.0
        jets = ref_jets(R, ts[i], info)
        if info[0] != 0:
            ok[i] = False
            continue
        ref_point(R, jets, ts[i], 0.0, info, qi, ei, eta_d_dot, sc, work)
        if info[0] != 0:
            ok[i] = False
            continue
        ok[i] = True
        q_d[i] = qi
        eta_d[i] = ei


@jit
def ref_side(Kp, R, C, t, psi, info):
    """Fill the cache for instant t and frame psi (a no-op when it already holds them)."""
    if C.f[2] == 1.0 and C.f[0] == t and C.f[1] == psi:
        return
    C.f[2] = 0.0
    jets = ref_jets(R, t, info)
    if info[0] != 0:
        return
    h = Kp.h
    for i in range(3):
        ti = t if i == 0 else (t + h if i == 1 else t - h)
        ref_point(R, jets, ti, ti - t, info, C.QD[i], C.ED[i], C.EDD[i], C.SC[i], C.WR)
        if info[0] != 0:
            return
        if Kp.kind == KIN_CHAINED:
            xi_T(to_frame(C.QD[i], psi, C.WQ), R.d, C.WJ, C.XID[i], C.TD[i])
    C.f[0] = t
    C.f[1] = psi
    C.f[2] = 1.0
