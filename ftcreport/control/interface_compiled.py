r"""The compiled side of the scheme interface: the matched terms, the kinematic signals, the guards.

The loop (ftcreport/fast/loop.py) takes the kinematic controller's part of every law from here
(:func:`fast.engine.loop_for` binds these names in each generated loop module): the matched terms
at the measured state (:func:`engine_terms`), the kinematic law alone for the logged signals
(:func:`kinematic_eval`, :func:`kinematic_signals`), its discrete update and cache.  A law asks for
the terms at another velocity with :func:`terms_at` (or another model, :func:`terms_with`).

``step.kin`` is ``(Kp, R, C, xk, fresh)``: the kinematic law's parameters, the reference, the
per-step cache (jit.packed.Cache), the kinematic controller's states and a one-value flag set
when the law evaluated the kinematic law itself (its signals are then the ones logged).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.core.extending import intrinsic
from numba.core.imputils import impl_ret_borrowed

from ..jit.compiling import jit
from ..jit.packed import KIN_CHAINED, new_cache
from ..model.compiled import reduced
from ..schemes.api import GUARD, Terms
from .kinematic_compiled import _reanchor_time, eta_c_and_dot, kin_discrete
from .tracking_compiled import law_terms, matched_terms

__all__ = [
    "engine_terms",
    "guards_intact",
    "kinematic_discrete",
    "kinematic_eval",
    "kinematic_event_time",
    "kinematic_events",
    "kinematic_signals",
    "legacy_matched_terms",
    "legacy_no_discrete",
    "new_kinematic_cache",
    "no_discrete",
    "no_law",
    "readonly",
    "terms_at",
    "terms_with",
]

kinematic_discrete = kin_discrete  # the chained law's re-anchoring after each step
new_kinematic_cache = new_cache
legacy_matched_terms = matched_terms  # the round-2 law's helper (kinematic signals into its sig)
kinematic_event_time = _reanchor_time  # when in (t_a, t_b] the chained law's frame must re-anchor (t_b: not)


@jit
def kinematic_events(Kp):
    """Whether the kinematic law has events an error-controlled step must land on (the chained law's
    re-anchoring: :func:`kinematic_event_time`)."""
    return Kp.kind == KIN_CHAINED


@intrinsic
def readonly(typingctx, arr):
    """``arr`` typed read-only (no copy): a law that writes its state fails to compile, at that line."""
    if not isinstance(arr, types.Array):
        return None
    sig = arr.copy(readonly=True)(arr)

    def codegen(context, builder, signature, args):
        return impl_ret_borrowed(context, builder, signature.return_type, args[0])

    return sig, codegen


@jit
def engine_terms(Kp, R, C, pc, t, q, eta, xk, k_v, info):
    """The matched terms (3.35)-(3.37) at the measured (q, eta): the kinematic law, then ``law_terms``.

    The reduced matrices stay in C for the plant when it shares the controller's model (fast.loop).
    """
    Mbar1, Mbar2, Cbar, Bbar, S_, _Sd = reduced(pc, q, eta)
    kin, ecd = eta_c_and_dot(Kp, R, C, S_, t, q, eta, xk, info)
    if info[0] != 0:
        z = np.zeros(2)
        return Terms(z, np.zeros((2, 2 * pc.n)), z, z)
    C.M1[:] = Mbar1
    C.M2[:] = Mbar2
    C.Cb[:] = Cbar
    C.Bb[:] = Bbar
    C.Sm[:] = S_
    C.f[3] = 1.0
    eta_e = eta - kin[0]
    w, MB, g = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, kin[1], kin[2], ecd, k_v)
    return Terms(w, MB, g, eta_e)


@jit
def _terms(Kp, R, C, pc, t, q, eta, xk, k_v, info):
    """The matched terms at (q, eta) with the model pc, leaving C's shared plant matrices alone."""
    Mbar1, Mbar2, Cbar, Bbar, S_, _Sd = reduced(pc, q, eta)
    kin, ecd = eta_c_and_dot(Kp, R, C, S_, t, q, eta, xk, info)
    if info[0] != 0:
        z = np.zeros(2)
        return Terms(z, np.zeros((2, 2 * pc.n)), z, z)
    eta_e = eta - kin[0]
    w, MB, g = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, kin[1], kin[2], ecd, k_v)
    return Terms(w, MB, g, eta_e)


@jit
def terms_at(step, eta, k_v):
    """The matched terms at the measured q and another velocity ``eta`` (e.g. an estimate), gain ``k_v``.

    The kinematic law runs at (step.t, step.q) with etadot_c along S(q) eta (ERRATA P5); on a
    singular configuration ``step.info[0]`` is set (return at once).  Its signals are the ones logged.
    """
    Kp, R, C, xk, fresh = step.kin
    fresh[0] = 1.0
    return _terms(Kp, R, C, step.model, step.t, step.q, eta, xk, k_v, step.info)


@jit
def terms_with(step, model, eta, k_v):
    """:func:`terms_at` with another chain model (an estimator's own, e.g. the UKF's)."""
    Kp, R, C, xk, fresh = step.kin
    fresh[0] = 1.0
    return _terms(Kp, R, C, model, step.t, step.q, eta, xk, k_v, step.info)


@jit
def kinematic_eval(Kp, R, C, pc, t, q, eta, xk, info):
    """The kinematic law at the measured state (for its logged signals only; C holds the result)."""
    S_ = reduced(pc, q, eta)[4]
    eta_c_and_dot(Kp, R, C, S_, t, q, eta, xk, info)


@jit
def kinematic_signals(sig, Kp, C):
    """eta_c, eta_c_dot, z, q_d, eta_d of C's last kinematic evaluation into ``sig``; returns their count.

    etadot_c is the central difference of rows 1 and 2 (t +/- h) that ``eta_c_and_dot`` returned.
    """
    z = C.KZ[0]
    q_d = C.QD[0]
    h = Kp.h
    sig[0:2] = C.KEC[0]
    sig[2] = (C.KEC[1, 0] - C.KEC[2, 0]) / (2.0 * h)
    sig[3] = (C.KEC[1, 1] - C.KEC[2, 1]) / (2.0 * h)
    k = 4
    sig[k : k + z.shape[0]] = z
    k += z.shape[0]
    sig[k : k + q_d.shape[0]] = q_d
    k += q_d.shape[0]
    sig[k : k + 2] = C.ED[0]
    return k + 2


@njit(nogil=True, error_model="numpy")  # not cached: it takes any scheme's P (a plug-in's types too)
def no_discrete(P, step, x):
    """The discrete update of a scheme that has none."""
    return


@njit(nogil=True, error_model="numpy")
def legacy_no_discrete(P, Kp, R, C, t, q, eta, xc, info):
    """The round-2 form's discrete update of a scheme that has none (the adapter's)."""
    return


@njit(nogil=True, error_model="numpy")
def no_law(P, step, terms, x, out):
    """A law that commands nothing (the loop template's placeholder; never run)."""
    return


@jit
def guards_intact(buf, n):
    """Whether the guard cells after the first ``n`` values of ``buf`` still hold :data:`GUARD`."""
    ok = True
    for i in range(n, buf.shape[0]):
        ok = ok and buf[i] == GUARD
    return ok
