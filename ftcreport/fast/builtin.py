r"""The built-in schemes behind two laws, so that they share two compiled loops.

numba compiles the closed loop (fast/loop.py) once per law it is bound to, and each compile links
every kernel the law reaches.  Binding the six built-in laws one by one made a cold batch compile
six loops (each with its own copy of the model, the reference and the kinematic law); one loop for
all six made the first run of any scheme compile all six laws, the UKF's included.  Here they sit
in two groups, each behind one dispatcher over one parameter type:

- :func:`passive_law`: nominal (tracking), oracle, switching and adaptive, over their ``Law``
  (``P.kind`` chooses); they share the matched law;
- :func:`active_any_law`: the active schemes, Farza's observer or the UKF, over :class:`Active`
  (the scheme's slot filled, a placeholder in the other); they share the estimate filters.

A cold batch compiles the two loops in parallel (ftcreport.batch starts one run of each first), and
a first run of a passive scheme compiles only the first.  Each law stays one kernel
(fast/kernels.py, fast/ukf.py); this module only chooses.  Plug-in schemes (ftcreport.schemes) keep
a loop of their own, compiled when a case first runs them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import kernels as F
from .kernels import jit
from .ukf import Ukf, UkfLaw, active_ukf_discrete, active_ukf_law

__all__ = ["LAW_ACTIVE_UKF", "Active", "active", "active_any_discrete", "active_any_law", "passive_discrete"]
__all__ += ["passive_law"]

LAW_ACTIVE_UKF = 5  # after kernels.LAW_TRACKING .. LAW_ACTIVE


class Active(NamedTuple):
    """An active scheme's parameters: ``kind`` (kernels.LAW_ACTIVE or LAW_ACTIVE_UKF) and its slot filled."""

    kind: int
    law: F.Law
    obs: F.Obs
    ukf: UkfLaw


def _no_obs() -> F.Obs:
    z = np.zeros((1, 1))
    return F.Obs(1.0, 1.0, 1.0, math.nan, 0, 0, 0, 1.0, math.nan, z, z, 0, 0, 0)


def _no_ukf(law: F.Law, chain: F.Chain) -> UkfLaw:
    z1, z2 = np.zeros(1), np.zeros((1, 1))
    return UkfLaw(law, Ukf(1, 1, False, False, z2, z2, z1, z1, 1.0), chain, 0, 0, math.nan, 0, 0)


def active(law: F.Law, chain: F.Chain, obs: F.Obs | None = None, ukf: UkfLaw | None = None) -> Active:
    """Pack an active scheme: Farza's observer (``obs``) or the UKF (``ukf``), a placeholder in the other."""
    kind = F.LAW_ACTIVE if ukf is None else LAW_ACTIVE_UKF
    return Active(kind, law, _no_obs() if obs is None else obs, _no_ukf(law, chain) if ukf is None else ukf)


@jit
def passive_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig):
    """The law of the passive (or baseline) scheme ``P.kind`` (the scheme API's signature)."""
    k = P.kind
    if k == F.LAW_TRACKING:
        return F.tracking_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_ORACLE:
        return F.oracle_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_SWITCHING:
        return F.switching_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    return F.adaptive_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)


@jit
def passive_discrete(P, Kp, R, C, t, q, eta, xc, info):
    """The discrete update of the passive scheme ``P.kind`` (switching rule, weight clip)."""
    k = P.kind
    if k == F.LAW_SWITCHING:
        F.switching_discrete(P, Kp, R, C, t, q, eta, xc, info)
    elif k == F.LAW_ADAPTIVE:
        F.adaptive_discrete(P, Kp, R, C, t, q, eta, xc, info)


@jit
def active_any_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig):
    """The law of the active scheme ``P.kind``: on Farza's observer's estimates or the UKF's."""
    if P.kind == F.LAW_ACTIVE:
        return F.active_law((P.law, P.obs), Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    return active_ukf_law(P.ukf, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)


@jit
def active_any_discrete(P, Kp, R, C, t, q, eta, xc, info):
    """The discrete update of the active scheme ``P.kind`` (the UKF's step; none for Farza's observer)."""
    if P.kind == LAW_ACTIVE_UKF:
        active_ukf_discrete(P.ukf, Kp, R, C, t, q, eta, xc, info)
