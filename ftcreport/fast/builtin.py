r"""The built-in schemes behind one law, so that they share one compiled loop.

numba compiles the closed loop (fast/loop.py) once per law it is bound to, and each compile links
every kernel the law reaches: about 20-40 s apiece on the 2-core machine.  Binding the six built-in
laws one by one made a cold batch compile six loops in each worker process.  Here they sit behind
one dispatcher with one parameter type, :class:`Builtin` (the law's own parameters in their slot,
placeholders in the others), so a process compiles one loop for all of them.  Each law stays one
kernel (fast/kernels.py, fast/ukf.py); this module only chooses.  Plug-in schemes
(ftcreport.schemes) keep a loop of their own, compiled when a case first runs them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import kernels as F
from .kernels import jit
from .ukf import Ukf, UkfLaw, active_ukf_discrete, active_ukf_law

__all__ = ["LAW_ACTIVE_UKF", "Builtin", "builtin", "builtin_discrete", "builtin_law"]

LAW_ACTIVE_UKF = 5  # after kernels.LAW_TRACKING .. LAW_ACTIVE


class Builtin(NamedTuple):
    """A built-in scheme's parameters: ``kind`` (kernels.LAW_*, LAW_ACTIVE_UKF) and its slot filled."""

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


def builtin(kind: int, law: F.Law, chain: F.Chain, obs: F.Obs | None = None, ukf: UkfLaw | None = None) -> Builtin:
    """Pack a built-in scheme (placeholders where its slot is not used)."""
    return Builtin(int(kind), law, _no_obs() if obs is None else obs, _no_ukf(law, chain) if ukf is None else ukf)


@jit
def builtin_law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig):
    """The law of the built-in scheme ``P.kind`` (the scheme API's signature)."""
    k = P.kind
    if k == F.LAW_TRACKING:
        return F.tracking_law(P.law, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_ORACLE:
        return F.oracle_law(P.law, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_SWITCHING:
        return F.switching_law(P.law, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_ADAPTIVE:
        return F.adaptive_law(P.law, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    if k == F.LAW_ACTIVE:
        return F.active_law((P.law, P.obs), Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)
    return active_ukf_law(P.ukf, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig)


@jit
def builtin_discrete(P, Kp, R, C, t, q, eta, xc, info):
    """The discrete update of the built-in scheme ``P.kind`` (switching rule, weight clip, UKF step)."""
    k = P.kind
    if k == F.LAW_SWITCHING:
        F.switching_discrete(P.law, Kp, R, C, t, q, eta, xc, info)
    elif k == F.LAW_ADAPTIVE:
        F.adaptive_discrete(P.law, Kp, R, C, t, q, eta, xc, info)
    elif k == LAW_ACTIVE_UKF:
        active_ukf_discrete(P.ukf, Kp, R, C, t, q, eta, xc, info)
