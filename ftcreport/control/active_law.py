r"""The active built-in schemes' laws, behind one dispatcher so that they share one compiled loop.

Active FTC (thesis chapter 4): an estimator of q, eta, the wheels' gains and frictions from the
measured q, and the law (4.14) on its estimates.  :func:`active_law` runs Farza's observer
(4.3)-(4.9), integrated with the plant, or the UKF (observers.ukf_compiled), run at the samples by the discrete
update with its command held in between; both over :class:`Active` (the scheme's slot filled, a
placeholder in the other), so the estimate filters and the law's terms are compiled once for both.
Their terms are at the estimated velocity, so they ask for them (``terms_at``): their scheme
declares ``terms="own"``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import E_UKF, LAW_ACTIVE, Chain, Law, Obs, _clip, _mv
from ..observers.farza_compiled import farza_derivative, farza_estimates
from ..observers.ukf_compiled import UKF_OK, Ukf, UkfLaw, _ukf_estimates, _ukf_used, ukf_step
from .active_compiled import active_signals, estimate_filters
from .interface_compiled import terms_at, terms_with
from .tracking_compiled import law_for_pattern

__all__ = ["LAW_ACTIVE_UKF", "Active", "active", "active_discrete", "active_law", "farza_law", "ukf_discrete"]
__all__ += ["ukf_law"]

LAW_ACTIVE_UKF = 5  # after jit.packed.LAW_TRACKING .. LAW_ACTIVE


class Active(NamedTuple):
    """An active scheme's parameters: ``kind`` (LAW_ACTIVE or LAW_ACTIVE_UKF) and its slot filled."""

    kind: int
    law: Law
    obs: Obs
    ukf: UkfLaw


def _no_obs() -> Obs:
    z = np.zeros((1, 1))
    return Obs(1.0, 1.0, 1.0, math.nan, 0, 0, 0, 1.0, math.nan, z, z, 0, 0, 0)


def _no_ukf(law: Law, chain: Chain) -> UkfLaw:
    z1, z2 = np.zeros(1), np.zeros((1, 1))
    return UkfLaw(law, Ukf(1, 1, False, False, z2, z2, z1, z1, 1.0), chain, 0, 0, math.nan, 0, 0)


def active(law: Law, chain: Chain, obs: Obs | None = None, ukf: UkfLaw | None = None) -> Active:
    """Pack an active scheme: Farza's observer (``obs``) or the UKF (``ukf``), a placeholder in the other."""
    kind = LAW_ACTIVE if ukf is None else LAW_ACTIVE_UKF
    return Active(kind, law, _no_obs() if obs is None else obs, _no_ukf(law, chain) if ukf is None else ukf)


@jit
def _command(T, sigma_hat, ubar_hat, u_limit):
    """(4.14): u = (MB diag(sigma_hat))^+ (w - MB ubar_hat) on the terms at the estimates, clipped to the limit."""
    u = law_for_pattern(T.MB, T.w - _mv(T.MB, ubar_hat), sigma_hat)
    if not math.isnan(u_limit):
        u = _clip(u, -u_limit, u_limit)
    return u


@jit
def farza_law(P, step, terms, x, out):
    """Active FTC (4.14) on the Farza observer's estimates (4.3)-(4.9); eta is not used (only q is)."""
    Lw, O = P.law, P.obs
    pc = step.model
    nw = 2 * pc.n
    s = x[O.est0 : O.est0 + O.est_n]
    qh, eh, rho_e, ubar_e = farza_estimates(O, pc, s, step.q, nw)
    rho, ubar = rho_e, ubar_e
    if not math.isnan(O.tau):
        rho = x[O.filt0 : O.filt0 + nw].copy()
        ubar = x[O.filt0 + nw : O.filt0 + 2 * nw].copy()
    if not math.isnan(Lw.u_limit):
        ubar = _clip(ubar, -Lw.u_limit, Lw.u_limit)
    sigma_hat = _clip(rho, 0.0, 1.0)
    # the matched terms at the measured q and the estimated velocity (etadot_c along S(q) eta_hat)
    T = terms_at(step, eh, Lw.k_v)
    if step.info[0] != 0:
        return
    u = _command(T, sigma_hat, ubar, Lw.u_limit)
    out.u[:] = u
    out.dx[O.est0 : O.est0 + O.est_n] = farza_derivative(O, pc, u, step.q, s)
    estimate_filters(out.dx, x, O.filt0, O.tau, rho_e, ubar_e)
    active_signals(out.sig, 0, qh, eh, rho_e, ubar_e, sigma_hat, ubar)


@jit
def ukf_law(P, step, terms, x, out):
    """Active FTC (4.14) on the UKF: the control computed at the last sample, held (ZOH) until the next.

    The filter and the law run at the samples (:func:`ukf_discrete`); between them the only
    continuous states are the estimates' first-order filters, tau xdot = x_est - x.
    """
    nw = out.u.shape[0]
    out.u[:] = x[P.u0 : P.u0 + nw]
    qh, eh, rho_e, ubar_e = _ukf_estimates(P, x, nw)
    estimate_filters(out.dx, x, P.filt0, P.tau, rho_e, ubar_e)
    sigma_hat, ubar_hat = _ukf_used(P, x, nw, rho_e, ubar_e)
    active_signals(out.sig, 0, qh, eh, rho_e, ubar_e, sigma_hat, ubar_hat)


@jit
def ukf_discrete(P, step, x):
    """At each sample: the UKF's predict + update over the time since the last sample with the held u,
    then the law (4.14) on the new estimates, held until the next sample."""
    nw = 2 * P.pf.n
    t = step.t
    h = t - x[P.t0]
    if h > 0.0:
        ns = P.ukf.nx * (P.ukf.nx + 1)
        s_new, status = ukf_step(P.pf, P.ukf, x[P.est0 : P.est0 + ns], x[P.u0 : P.u0 + nw], step.q, h)
        if status != UKF_OK:
            step.info[0] = E_UKF
            step.info[1] = status
            step.info[2] = t
            return
        x[P.est0 : P.est0 + ns] = s_new
    _qh, eh, rho_e, ubar_e = _ukf_estimates(P, x, nw)
    sigma_hat, ubar_hat = _ukf_used(P, x, nw, rho_e, ubar_e)
    T = terms_with(step, P.pf, eh, P.law.k_v)
    u = np.zeros(nw) if step.info[0] != 0 else _command(T, sigma_hat, ubar_hat, P.law.u_limit)
    x[P.u0 : P.u0 + nw] = u
    x[P.t0] = t


@jit
def active_law(P, step, terms, x, out):
    """The law of the active scheme ``P.kind``: on Farza's observer's estimates or the UKF's."""
    if P.kind == LAW_ACTIVE:
        farza_law(P, step, terms, x, out)
    else:
        ukf_law(P.ukf, step, terms, x, out)


@jit
def active_discrete(P, step, x):
    """The discrete update of the active scheme ``P.kind`` (the UKF's step; none for Farza's observer)."""
    if P.kind == LAW_ACTIVE_UKF:
        ukf_discrete(P.ukf, step, x)
