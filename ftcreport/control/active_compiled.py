r"""Compiled (numba) parts of the active laws: the estimate filters 1/(tau s + 1), the signals, and the reference
UKF's process model.

Faces: :mod:`ftcreport.control.active`, :mod:`ftcreport.observers.ukf`.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit.compiling import jit
from ..model.compiled import plant_rhs


@jit
def estimate_filters(dx, xc, filt0, tau, rho_e, ubar_e):
    """The estimates' first-order filters of the active laws (thesis 4.2.4: tau xdot = x_est - x), into dx.

    ``xc[filt0 : filt0 + nw]`` filters the gains, the next nw the frictions; tau nan: no filters.
    """
    if math.isnan(tau):
        return
    nw = rho_e.shape[0]
    for j in range(nw):
        dx[filt0 + j] = (rho_e[j] - xc[filt0 + j]) / tau
        dx[filt0 + nw + j] = (ubar_e[j] - xc[filt0 + nw + j]) / tau


@jit
def active_signals(sig, k, qh, eh, rho_e, ubar_e, sigma_used, ubar_used):
    """The active laws' logged signals after the kinematic ones (from index k): q_hat, eta_hat,
    rho_hat, ubar_hat, sigma_used, ubar_used (fast.engine splits them by these widths)."""
    N, nw = qh.shape[0], rho_e.shape[0]
    sig[k : k + N] = qh
    sig[k + N : k + N + 2] = eh
    k += N + 2
    sig[k : k + nw] = rho_e
    sig[k + nw : k + 2 * nw] = ubar_e
    sig[k + 2 * nw : k + 3 * nw] = sigma_used
    sig[k + 3 * nw : k + 4 * nw] = ubar_used


# =========================================================================== the Python UKF's model; the active law
@jit
def midpoint_sigmas(pc, sigmas, u, dt, est_rho, est_ubar):
    """The reference UKF's process model (tests/ukf_reference.py) at every sigma point: a midpoint step, u held."""
    N = pc.n + 2
    nw = 2 * pc.n
    out = sigmas.copy()
    for i in range(sigmas.shape[0]):
        x = sigmas[i]
        rho = np.ones(nw)
        ubar = np.zeros(nw)
        k = N + 2
        if est_rho:
            rho = x[k : k + nw]
            k += nw
        if est_ubar:
            ubar = x[k : k + nw]
        tau = rho * u + ubar
        q = x[:N]
        eta = x[N : N + 2]
        qd1, ed1 = plant_rhs(pc, q, eta, tau)
        qd2, ed2 = plant_rhs(pc, q + 0.5 * dt * qd1, eta + 0.5 * dt * ed1, tau)
        out[i, :N] = q + dt * qd2
        out[i, N : N + 2] = eta + dt * ed2
    return out
