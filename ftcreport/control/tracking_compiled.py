r"""Compiled (numba) dynamic tracking law: its terms (3.35-3.37), the right inverse for a fault pattern, the
matched terms the schemes' laws share.

Face: :mod:`ftcreport.control.tracking` (``law_terms``, ``law_for_pattern``, ``TrackingController``).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import _inv2, _mv, _solve2
from ..model.compiled import reduced
from .kinematic_compiled import eta_c_and_dot


@jit
def law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, T, f_eta, eta_c_dot, k_v):
    """(w, MB = Mbar1^-1 Bbar, g) of the dynamic law (3.35)/(3.107), with ERRATA E8 (T_alpha^T f_eta).

    The pattern-independent part: u_(k) = (MB sigma_(k))^+ w (law_for_pattern) gives
    eta_e' = -k_v eta_e - T_alpha^T f_eta when sigma_(k) is the true pattern.
    """
    Minv = _inv2(Mbar1)
    # g = -Mbar1^-1 (Mbar2 eta + Cbar)   (the free dynamics)
    g = -_mv(Minv, _mv(Mbar2, eta) + Cbar)
    # w = -k_v eta_e - T_alpha^T f_eta + Mbar1^-1 (Mbar2 eta + Cbar) + etadot_c
    w = -k_v * eta_e - _mv(T.T, f_eta) - g + eta_c_dot
    nw = Bbar.shape[1]
    MB = np.empty((2, nw))
    for j in range(nw):
        MB[0, j] = Minv[0, 0] * Bbar[0, j] + Minv[0, 1] * Bbar[1, j]
        MB[1, j] = Minv[1, 0] * Bbar[0, j] + Minv[1, 1] * Bbar[1, j]
    return w, MB, g


@jit
def _gram(MB, sigma):
    """A A^T for A = MB diag(sigma)."""
    G = np.zeros((2, 2))
    for j in range(MB.shape[1]):
        s2 = sigma[j] * sigma[j]
        G[0, 0] += MB[0, j] * MB[0, j] * s2
        G[0, 1] += MB[0, j] * MB[1, j] * s2
        G[1, 1] += MB[1, j] * MB[1, j] * s2
    G[1, 0] = G[0, 1]
    return G


@jit
def _right_inverse(MB, sigma, AAt, w):
    """A^T (A A^T)^-1 w for A = MB diag(sigma)."""
    y = _solve2(AAt, w)
    nw = MB.shape[1]
    u = np.empty(nw)
    for j in range(nw):
        u[j] = sigma[j] * (MB[0, j] * y[0] + MB[1, j] * y[1])
    return u


@jit
def law_for_pattern(MB, w, sigma):
    """u_(k) = (MB diag(sigma_(k)))^+ w, thesis (3.35)/(3.107), minimum-norm A^+ = A^T (A A^T)^-1.

    Least squares (pinv) when cond(A A^T) > 1e12: a pattern with rank < 2 (ERRATA E5d), e.g. the
    oracle facing an uncompensable fault.
    """
    AAt = _gram(MB, sigma)
    tr = 0.5 * (AAt[0, 0] + AAt[1, 1])
    det = AAt[0, 0] * AAt[1, 1] - AAt[0, 1] * AAt[1, 0]
    lmax = tr + math.sqrt(max(tr * tr - det, 0.0))
    if not det / lmax > lmax * 1e-12:  # cond(A A^T) = lmax / lmin, lmin = det / lmax
        nw = MB.shape[1]
        A = np.empty((2, nw))
        for j in range(nw):
            A[0, j] = MB[0, j] * sigma[j]
            A[1, j] = MB[1, j] * sigma[j]
        return np.linalg.pinv(A, rcond=1e-9) @ w
    # u = A^T (A A^T)^-1 w
    return _right_inverse(MB, sigma, AAt, w)


# =========================================================================== the closed loop
@jit
def _kin_signals(sig, kin, ecd, C):
    """eta_c, eta_c_dot, z, q_d, eta_d into sig; returns the next free index."""
    z = kin[3]
    q_d = C.QD[0]
    sig[0:2] = kin[0]
    sig[2:4] = ecd
    k = 4
    sig[k : k + z.shape[0]] = z
    k += z.shape[0]
    sig[k : k + q_d.shape[0]] = q_d
    k += q_d.shape[0]
    sig[k : k + 2] = C.ED[0]
    return k + 2


# =========================================================================== the schemes' building blocks
# The schemes' laws are ftcreport/control/*_law.py (the scheme API's contract, ftcreport.schemes.api); here
# the kernels they share: the matched terms (matched_terms, the round-2 plug-in API's), the switching
# bank's filters and rule, the active laws' estimate filters and signals.


@jit
def matched_terms(Kp, R, C, pc, t, q, eta, xc, k_v, info, sig):
    """The kinematic law and the matched dynamic law's terms at (q, eta): (w, MB, g, eta_e).

    eta_c and etadot_c come from the kinematic controller, (3.29) or (3.67)-(3.106); w, MB and g
    are those of (3.37) (``law_terms``): Mbar1 etadot_c + Mbar2 eta + Cbar - k_v Mbar1 eta_e - T^T f
    = MB tau.  ``sig`` gets eta_c, etadot_c, z, q_d, eta_d when it is not empty.  The reduced
    matrices are left in C, for the plant to reuse when it shares the controller's model.
    """
    Mbar1, Mbar2, Cbar, Bbar, S_, _Sd = reduced(pc, q, eta)
    kin, ecd = eta_c_and_dot(Kp, R, C, S_, t, q, eta, xc[: Kp.nk], info)
    if info[0] != 0:
        z = np.zeros(2)
        return z, np.zeros((2, 2 * pc.n)), z, z
    if sig.shape[0] > 0:
        _kin_signals(sig, kin, ecd, C)
    C.M1[:] = Mbar1
    C.M2[:] = Mbar2
    C.Cb[:] = Cbar
    C.Bb[:] = Bbar
    C.Sm[:] = S_
    C.f[3] = 1.0
    eta_e = eta - kin[0]
    w, MB, g = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, kin[1], kin[2], ecd, k_v)
    return w, MB, g, eta_e
