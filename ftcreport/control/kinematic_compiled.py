r"""Compiled (numba) kinematic laws: the chained-form backstepping (3.67-3.104) and the two-link law (3.8-3.29).

Faces: :class:`ftcreport.control.kinematic.ChainedBackstepping` and
:class:`~ftcreport.control.kinematic.TwoLinkKinematic`.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import (  # noqa: F401 - for the face (kinematic.py)
    E_CHAINED_ART,
    E_CHAINED_THN,
    E_KAPPA,
    E_REF_ART,
    E_REF_SPEED,
    E_TWO_LINK_ETH,
    E_TWO_LINK_PHI,
    KIN_CHAINED,
    KIN_TWO_LINK,
    Kin,
    _wrap,
    new_cache,
)
from ..model.chained_compiled import to_frame, xi_T
from ..references.compiled import ref_side


@jit
def _chained_law(Kp, R, C, ir, q, psi, info):
    """Recursive backstepping on the chained form into row ir of the cache: eta_c, T_alpha, f_eta, Z.

    Thesis (3.67)-(3.106) generalized to any n (derivation in control/kinematic.py's module doc), with
    ERRATA E12a ((3.95), hence 3.103), E12b ((3.102)), E12c ((3.105)) and E12d (gains c_j on every virtual
    control, in L); length scale mu and frame psi beyond the thesis.  Refuses |theta_n| or an articulation
    angle near 90 deg in the frame (E_CHAINED_*) and kappa - Delta_1 near 0 (E_KAPPA).
    """
    eta_d = C.ED[ir]
    qf = to_frame(q, psi, C.WQ)
    n = Kp.n
    m = n + 2
    p = m - 1
    eta_c, T, f_eta, Z = C.KEC[ir], C.KT[ir], C.KF[ir], C.KZ[ir]
    # check_domain
    if abs(math.cos(qf[2])) <= Kp.singular_tol:
        info[0] = E_CHAINED_THN
        info[1] = math.degrees(qf[2])
        return
    worst = 2.0
    iw = 0
    for i in range(n - 1):  # robot order i, i+1: q index m-1-i, m-2-i
        c = math.cos(qf[m - 1 - i] - qf[m - 2 - i])
        if c < worst:
            worst = c
            iw = i
    if n > 1 and worst <= Kp.singular_tol:
        info[0] = E_CHAINED_ART
        info[1] = iw
        info[2] = math.degrees(qf[m - 1 - iw] - qf[m - 2 - iw])
        return
    xi = C.WXI
    xi_T(qf, R.d, C.WJ, xi, T)
    xi_d, T_d = C.XID[ir], C.TD[ir]
    # alpha_d = T_alpha(q_d) eta_d
    a1d = T_d[0, 0] * eta_d[0] + T_d[0, 1] * eta_d[1]
    a2d = T_d[1, 0] * eta_d[0] + T_d[1, 1] * eta_d[1]
    e0 = xi[0] - xi_d[0]
    for j in range(1, m - 1):  # Z_j = xi_e,(m+1-j) - xi_(m-j) xi_e,1
        Z[j - 1] = (xi[m - j] - xi_d[m - j]) - xi[m - j - 1] * e0
    Z[m - 2] = xi[1] - xi_d[1]
    Z[m - 1] = e0
    mu = Kp.mu
    Zh, Zbar, LtZ = C.WV[0], C.WV[1], C.WV[2]
    for j in range(p):
        # Zhat_j = mu^-(j-1) Z_j
        Zh[j] = Z[j] * Kp.Dscale[j]
    z = Z[m - 1]
    lnz = 0.0
    for j in range(p):
        lnz += Kp.LN_last[j] * Zh[j]
        acc = 0.0
        for i in range(j + 1):  # L is lower triangular
            acc += Kp.L[j, i] * Zh[i]
        # Zbar = L Zhat
        Zbar[j] = acc
    # alpha_2c = alpha_2d + mu^(p-1) [-c_a2 Zbar_p - mu alpha_1d (Zbar_(p-1) + row_p N Zhat)]   (3.102, E12b)
    a2c = a2d + mu ** (p - 1) * (-Kp.c_alpha2 * Zbar[p - 1] - mu * a1d * (Zbar[p - 2] + lnz))
    for i in range(p):
        acc = 0.0
        for j in range(i, p):
            acc += Kp.L[j, i] * Zbar[j]
        # rho (L^T Zbar)_i mu^-(i-1)
        LtZ[i] = Kp.rho * acc * Kp.Dscale[i]
    # Delta_1 = sum_(j<=p-2) rho (L^T Zbar)_j mu^-(j-1) xi_(m-1-j),  Gamma = rho (L^T Zbar)_(p-1) mu^-(p-2)  (3.93)
    delta1 = 0.0
    for j in range(1, p - 1):
        delta1 += LtZ[j - 1] * xi[m - 2 - j]
    gam = LtZ[p - 2]
    kd = Kp.kappa - delta1
    if abs(kd) < Kp.singular_tol * Kp.kappa:
        info[0] = E_KAPPA
        info[1] = kd
        return
    # alpha_1c = alpha_1d + (kappa - Delta_1)^-1 (-c_z z + Gamma alpha_2c)   (3.103, E12a)
    a1c = a1d + (-Kp.c_xi1 * z + gam * a2c) / kd
    det = T[0, 0] * T[1, 1] - T[0, 1] * T[1, 0]  # eta_c = T^-1 alpha_c
    eta_c[0] = (T[1, 1] * a1c - T[0, 1] * a2c) / det
    eta_c[1] = (T[0, 0] * a2c - T[1, 0] * a1c) / det
    # f_eta = [z (kappa - Delta_1), rho mu^-(p-1) Zbar_p - z Gamma]   (3.105, E12c)
    f_eta[0] = z * kd
    f_eta[1] = Kp.rho * Kp.Dscale[p - 1] * Zbar[p - 1] - z * gam


@jit
def _two_link_law(Kp, C, ir, q, info):
    """Two-link diffeomorphism controller into row ir of the cache: eta_c, T_alpha, f_eta, z.

    Thesis (3.8)-(3.29) and Appendices F, G with ERRATA E6 (z4), E7 (z3'), E9 (alpha_2c), E10 (T_alpha,
    f_alpha of Appendix G once E6 is applied), E11a (alpha_1).  Refuses cos e_theta or cos phi below 1e-3.
    """
    q_d = C.QD[ir]
    vd, wd, vdd, wdd = C.SC[ir, 0], C.SC[ir, 1], C.SC[ir, 2], C.SC[ir, 3]
    d = Kp.d2
    thd = q_d[2]
    ct, st = math.cos(thd), math.sin(thd)
    exw, eyw = q[0] - q_d[0], q[1] - q_d[1]
    # e = T_e (q - q_d)   (3.8)-(3.10)
    ex = ct * exw + st * eyw
    ey = -st * exw + ct * eyw
    eth = _wrap(q[2] - thd)
    c, s = math.cos(eth), math.sin(eth)
    phi = q[3] - q[2]
    cphi = math.cos(phi)
    eta_c, T, f_eta, z = C.KEC[ir], C.KT[ir], C.KF[ir], C.KZ[ir]
    if abs(c) < 1e-3:
        info[0] = E_TWO_LINK_ETH
        info[1] = math.degrees(eth)
        return
    if abs(cphi) < 1e-3:
        info[0] = E_TWO_LINK_PHI
        info[1] = math.degrees(phi)
        return
    tphi = math.tan(phi)
    sec2 = 1.0 / cphi**2
    # z1 = e_x, z2 = e_y, z3 = tan e_theta, z4 = tan(phi) / (d c^3) - omega_d / (v_d c^2) + e_y   (3.14-3.17, E6)
    z[0] = ex
    z[1] = ey
    z[2] = s / c
    z[3] = tphi / (d * c**3) - wd / (vd * c**2) + ey
    # alpha_1 = v_2 cos e_theta - v_d (E11a);  alpha_2 = z4' = T21 v_2 + T22 omega_1 + f2 (Appendix G, E6, E10)
    T21 = -sec2 * tphi / (d**2 * c**3) + 3.0 * tphi**2 * s / (d**2 * c**4) - 2.0 * wd * s * tphi / (d * vd * c**3) + s
    T22 = sec2 / (d * c**3)
    f2 = (
        -3.0 * tphi * s * wd / (d * c**4)
        - (wdd * vd - wd * vdd) / (vd**2 * c**2)
        + 2.0 * wd**2 * s / (vd * c**3)
        - wd * ex
    )
    T[0, 0] = c
    T[0, 1] = 0.0
    T[1, 0] = T21
    T[1, 1] = T22
    # f_alpha = [-v_d, f2]   (3.29, Appendix G with E10)
    C.KA[ir, 0] = -vd
    C.KA[ir, 1] = f2
    z1, z3, z4 = z[0], z[2], z[3]
    # g = z1 + z3 (z4 + (omega_d / v_d)(1 + z3^2));  alpha_c = [-k1 g, -k2 v_d z3 - k3 z4]   (3.27)-(3.28), E9
    g = z1 + z3 * (z4 + (wd / vd) * (1.0 + z3**2))
    r0 = -Kp.k1 * g - C.KA[ir, 0]
    r1 = -Kp.k2 * vd * z3 - Kp.k3 * z4 - C.KA[ir, 1]
    det = T[0, 0] * T[1, 1] - T[0, 1] * T[1, 0]  # eta_c = T^-1 (alpha_c - f_alpha)   (3.29)
    eta_c[0] = (T[1, 1] * r0 - T[0, 1] * r1) / det
    eta_c[1] = (T[0, 0] * r1 - T[1, 0] * r0) / det
    # f_eta = [g, z4 / k2] (the Lyapunov cross term the dynamic law cancels, E8)
    f_eta[0] = g
    f_eta[1] = z4 / Kp.k2


@jit
def kin_law(Kp, R, C, ir, q, xk, info):
    """The kinematic law into row ir of the cache (ir: 0 at t, 1 at t + h, 2 at t - h)."""
    if Kp.kind == KIN_TWO_LINK:
        _two_link_law(Kp, C, ir, q, info)
    else:
        _chained_law(Kp, R, C, ir, q, xk[0], info)


@jit
def eta_c_and_dot(Kp, R, C, S, t, q, eta, xk, info):
    """TrackingController.eta_c_and_dot: law at t and the central difference along (S(q) eta, 1) (ERRATA P5).

    Returns ``((eta_c, T_alpha, f_eta, z), etadot_c)``; the first four are views of
    cache row 0, valid until the next evaluation.
    """
    kin = (C.KEC[0], C.KT[0], C.KF[0], C.KZ[0])
    ecd = np.zeros(2)
    ref_side(Kp, R, C, t, xk[0] if Kp.nk > 0 else 0.0, info)
    if info[0] != 0:
        return kin, ecd
    h = Kp.h
    # one call site with a run-time row index: a literal 0, 1, 2 would make numba compile three copies
    for ir in range(3):
        if ir == 0:
            C.WP[:] = q
        else:
            sgn = 1.0 if ir == 1 else -1.0
            for i in range(q.shape[0]):
                C.WP[i] = q[i] + sgn * h * (S[i, 0] * eta[0] + S[i, 1] * eta[1])
        kin_law(Kp, R, C, ir, C.WP, xk, info)
        if info[0] != 0:
            return kin, ecd
    ecd[0] = (C.KEC[1, 0] - C.KEC[2, 0]) / (2.0 * h)
    ecd[1] = (C.KEC[1, 1] - C.KEC[2, 1]) / (2.0 * h)
    return kin, ecd


@jit
def kin_discrete(Kp, R, C, t, xc, info):
    """After each step, the chained law's re-anchoring: psi jumps to theta_d when it leaves the band."""
    if Kp.kind == KIN_CHAINED:
        ref_side(Kp, R, C, t, xc[0], info)
        if info[0] != 0:
            return
        thd = C.QD[0, 2]
        if abs(_wrap(thd - xc[0])) > Kp.band:
            xc[0] = thd


@jit
def kin_discrete_along(Kp, R, C, times, xc, info):
    """:func:`kin_discrete` after each of ``times`` in turn, from ``xc``: the frame psi after each (one call for
    a walk along the reference that took one call per step).  On an error the walk stops with ``info``
    set, the rest of the returned psi NaN."""
    out = np.full(times.shape[0], np.nan)
    x = xc.copy()
    for k in range(times.shape[0]):
        kin_discrete(Kp, R, C, times[k], x, info)
        if info[0] != 0:
            return out
        out[k] = x[0]
    return out


@jit
def _reanchor_time(Kp, R, C, t_a, t_b, psi, info):
    """When in (t_a, t_b] the chained law's frame psi must re-anchor (kin_discrete: once the
    reference heading theta_d(t) leaves psi +/- band): t_b if it need not, else the first instant found
    by bisection on theta_d (a function of t alone: an event known from the reference), to 1e-12 s
    relative, on the side where it must (so that the discrete update there re-anchors)."""
    if Kp.kind != KIN_CHAINED:
        return t_b
    ref_side(Kp, R, C, t_b, psi, info)
    if info[0] != 0 or abs(_wrap(C.QD[0, 2] - psi)) <= Kp.band:
        info[:] = 0.0
        return t_b
    a, b = t_a, t_b
    for _ in range(80):
        if b - a <= 1e-12 * max(1.0, abs(b)):
            break
        m = 0.5 * (a + b)
        ref_side(Kp, R, C, m, psi, info)
        if info[0] != 0:
            info[:] = 0.0
            return t_b
        if abs(_wrap(C.QD[0, 2] - psi)) > Kp.band:
            b = m
        else:
            a = m
    return b
