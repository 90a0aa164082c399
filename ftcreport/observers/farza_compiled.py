r"""Compiled (numba) Farza adaptive observer (Farza et al. 2009; thesis 4.2): estimates and derivative.

Face: :class:`ftcreport.observers.farza.FarzaObserver`.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import _inv2, _mv, _solve2
from ..model.compiled import reduced, s_matrix


# =========================================================================== Farza observer (observers/farza.py)
@jit
def farza_estimates(O, pc, s, y, nw):
    """(q_hat, eta_hat, rho, ubar) from the observer state (thesis 4.2.3.2); nominal values where not estimated."""
    N = pc.n + 2
    S = s_matrix(pc, y)
    # eta_hat = S(y)^+ qdot_hat = (S^T S)^-1 S^T qdot_hat
    eta = _solve2(S.T @ S, S.T @ s[N : 2 * N])
    rho = np.ones(nw)
    ubar = np.zeros(nw)
    k = 2 * N
    if O.est_rho:
        rho = s[k : k + nw].copy()
        k += nw
    if O.est_ubar:
        ubar = s[k : k + nw].copy()
    return s[:N].copy(), eta, rho, ubar


@jit
def farza_derivative(O, pc, u, y, s):
    """Observer state derivative (4.4)-(4.11) with ERRATA E15 (signs), E16 (phi_2) and the P guard (P3).

    The equations of observers/farza.py's module doc, grouped for small dense loops:
    (S_o^-1 + Y P Y^T) C^T K = S_o^-1 C^T K + Y (P v) with v = (C Y)^T K, and
    P Y^T C^T C Y P = W^T W with W = C Y P.  eta = S^+ qdot by the normal equations.
    """
    N = pc.n + 2
    nw = 2 * pc.n
    P_ = O.p
    Th = O.Theta
    o_rho = 2 * N
    o_Y = o_rho + P_
    o_P = o_Y + 2 * N * P_
    Y = s[o_Y:o_P].reshape((2 * N, P_))
    P = s[o_P : o_P + P_ * P_].reshape((P_, P_))
    rho = np.ones(nw)
    ubar = np.zeros(nw)
    k = 0
    if O.est_rho:
        rho = s[o_rho : o_rho + nw]
        k = nw
    if O.est_ubar:
        ubar = s[o_rho + k : o_rho + k + nw]
    q = s[:N]
    qdot = s[N : 2 * N]
    S0 = s_matrix(pc, q)
    eta = _solve2(S0.T @ S0, _mv(S0.T, qdot))  # S^+ qdot (S has full column rank)
    Mbar1, Mbar2, Cbar, Bbar, S, Sdot = reduced(pc, q, eta)
    Minv = _inv2(Mbar1)
    MB = np.empty((2, nw))
    for j in range(nw):
        MB[0, j] = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
        MB[1, j] = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
    tq = rho * u + ubar
    # Mbar1^-1 (-Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar))   (E16)
    acc = -_mv(Minv, _mv(Mbar2, eta) + Cbar) + _mv(MB, tq)
    ds = np.empty(s.shape[0])
    # correction terms
    Kt = np.empty(N)
    for i in range(N):
        # K(ytilde) = k1 tanh(k0 (y - C xhat))   (E15: ytilde = y - C xhat)
        Kt[i] = O.k1 * math.tanh(O.k0 * (y[i] - s[i]))
    v = np.zeros(P_)  # (C Y)^T K
    for a in range(P_):
        acc_v = 0.0
        for i in range(N):
            acc_v += Y[i, a] * Kt[i]
        v[a] = acc_v
    Pv = _mv(P, v)
    YPv = _mv(Y, Pv)
    SoK = _mv(O.Soinv[:, :N], Kt)
    sgn = O.sign * Th
    # xhat' = A xhat + phi + Theta Delta^-1 (S_o^-1 + Y P Y^T) C^T K, Delta^-1 = diag(I, Theta I)   (E15)
    for i in range(N):
        ds[i] = s[N + i] + sgn * (SoK[i] + YPv[i])
        # phi_2 = S acc + Sdot eta
        ds[N + i] = S[i, 0] * acc[0] + S[i, 1] * acc[1] + Sdot[i, 0] * eta[0] + Sdot[i, 1] * eta[1]
        ds[N + i] += sgn * Th * (SoK[N + i] + YPv[N + i])
    for a in range(P_):
        # rhohat' = Theta P Y^T C^T K   (E15)
        ds[o_rho + a] = sgn * Pv[a]
    # Y' = Theta (A - S_o^-1 C^T C) Y + Delta dphi/drho_bar, with dphi_2/drho_bar = S MB [diag(u), I]
    AY = O.AY
    dY = ds[o_Y:o_P].reshape((2 * N, P_))
    for i in range(2 * N):
        for a in range(P_):
            dY[i, a] = 0.0
        for kk in range(2 * N):
            c = AY[i, kk]
            if c != 0.0:
                for a in range(P_):
                    dY[i, a] += c * Y[kk, a]
    for i in range(N):
        for j in range(nw):
            smb = S[i, 0] * MB[0, j] + S[i, 1] * MB[1, j]
            c0 = 0
            if O.est_rho:
                dY[N + i, j] += smb * u[j] / Th
                c0 = nw
            if O.est_ubar:
                dY[N + i, c0 + j] += smb / Th
    # P' = Theta P - Theta W^T W - Theta P P / p_max,  W = C Y P
    W = np.zeros((N, P_))
    for i in range(N):
        for b in range(P_):
            acc_w = 0.0
            for a in range(P_):
                acc_w += Y[i, a] * P[a, b]
            W[i, b] = acc_w
    dP = ds[o_P : o_P + P_ * P_].reshape((P_, P_))
    guard = not math.isnan(O.p_max)
    for a in range(P_):
        for b in range(P_):
            acc_p = 0.0
            for i in range(N):
                acc_p += W[i, a] * W[i, b]
            val = Th * P[a, b] - Th * acc_p
            if guard:
                acc_pp = 0.0
                for c in range(P_):
                    acc_pp += P[a, c] * P[c, b]
                val -= Th * acc_pp / O.p_max
            dP[a, b] = val
    return ds
