"""Test harnesses as one plug-in scheme on the compiled loop (issue 17: there is no Python loop).

The tests of the engine itself (exact fault timing, stops, saturation, noise, logging) and of the
observers under excitation drive the plant with laws that ignore the kinematic controller.  They
were Python ``Controller`` objects run by the Python loop; here they are one scheme, ``harness``,
whose ``P.mode`` chooses the law (one law: numba compiles one loop for all of them):

- ``VELOCITY``: healthy computed torque on a velocity command
  eta_c(t) = c0 + amp sin(om t) (elementwise), the healthy instance of (3.35)::

      etadot_des = etadot_c - k (eta - eta_c)
      u = (Mbar1^-1 Bbar)^+ [etadot_des + Mbar1^-1 (Mbar2 eta + Cbar)]

  (= Bbar^+ (Mbar1 etadot_des + Mbar2 eta + Cbar): both matrices have the same row space), so with
  a matched model and healthy wheels the velocity error obeys e' = -k e exactly.  eta_c is logged
  as the signal ``eta_cmd``.
- ``EXPLODING``: one state x, x' = rate x, every wheel commanded u_j = x (a blow-up like e^(rate t)).
- ``GEOMETRIC``: u = g (1, -1, 1, -1, ...) with g = start factor^k at step k = round(t / dt), or
  with ``k_jump`` >= 0 a single jump g = start (1e6 from step k_jump on).
- ``FARZA``: the velocity law on the true eta with Farza's observer (fast.kernels.farza_derivative)
  integrated alongside as the scheme's state, fed the applied u and the measured q.
- ``UKF``: the velocity law sampled at every step (held over the step) with the compiled UKF
  (observers.ukf_compiled.ukf_step) run at the samples on the held u; state ``[UKF state, held u, last sample]``.

:func:`controller` builds the ``SchemeController``.  The scheme declares ``terms="none"``: the engine
never evaluates the kinematic controller for these laws (a circle reference keeps its re-anchoring
harmless), and the kinematic signals are not logged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ftcreport import schemes
from ftcreport.control import ChainedBackstepping, TwoLinkKinematic
from ftcreport.control.active_law import _no_obs
from ftcreport.fast import kernels as F
from ftcreport.observers.ukf_compiled import UKF_OK, Ukf, ukf_params, ukf_step
from ftcreport.references import FlatReference, circle
from ftcreport.schemes import Scheme, SchemeController, register

VELOCITY, EXPLODING, GEOMETRIC, FARZA, UKF = range(5)

law_for_pattern = schemes.law_for_pattern
reduced = schemes.reduced


class P(NamedTuple):
    mode: int
    k: float
    c0: np.ndarray  # (2,)
    amp: np.ndarray  # (2,)
    om: np.ndarray  # (2,)
    rate: float
    start: float
    factor: float
    dt: float
    k_jump: int
    healthy: np.ndarray  # (2n,) ones
    obs: Any  # fast.kernels.Obs (FARZA) or a placeholder
    ukf: Any  # observers.ukf_compiled.Ukf (UKF) or a placeholder
    ch: Any  # the controller's fast.kernels.Chain (the discrete update has no pc)
    ns: int  # the estimator's states (FARZA, UKF)


@schemes.jit
def velocity_u(P, pc, t, q, eta):
    """The VELOCITY law's u and eta_c at (t, q, eta) (module docstring)."""
    Mbar1, Mbar2, Cbar, Bbar, _S, _Sd = reduced(pc, q, eta)
    eta_c = np.empty(2)
    w = np.empty(2)
    for i in range(2):
        # eta_c = c0 + amp sin(om t), etadot_des = amp om cos(om t) - k (eta - eta_c)
        eta_c[i] = P.c0[i] + P.amp[i] * math.sin(P.om[i] * t)
        w[i] = P.amp[i] * P.om[i] * math.cos(P.om[i] * t) - P.k * (eta[i] - eta_c[i])
    # w = etadot_des + Mbar1^-1 (Mbar2 eta + Cbar), MB = Mbar1^-1 Bbar
    w += np.linalg.solve(Mbar1, Mbar2 @ eta + Cbar)
    MB = np.linalg.solve(Mbar1, Bbar)
    return law_for_pattern(MB, w, P.healthy), eta_c


@schemes.jit
def law(P, step, terms, x, out):
    nw = out.u.shape[0]
    if P.mode == EXPLODING:
        out.dx[0] = P.rate * x[0]
        out.u[:] = x[0]
        return
    if P.mode == GEOMETRIC:
        k = math.floor(step.t / P.dt + 0.5)
        g = P.start * P.factor**k
        if P.k_jump >= 0:  # one jump instead
            g = P.start * (1e6 if k >= P.k_jump else 1.0)
        for j in range(nw):
            out.u[j] = g if j % 2 == 0 else -g
        return
    if P.mode == UKF:
        out.u[:] = x[P.ns : P.ns + nw]
        return
    u, eta_c = velocity_u(P, step.model, step.t, step.q, step.eta)
    out.u[:] = u
    out.sig[0] = eta_c[0]
    out.sig[1] = eta_c[1]
    if P.mode == FARZA:
        out.dx[0 : P.ns] = F.farza_derivative(P.obs, step.model, u, step.q, x[0 : P.ns])


@schemes.jit
def discrete(P, step, x):
    if P.mode != UKF:
        return
    nw = 2 * P.ch.n
    t = step.t
    h = t - x[P.ns + nw]
    if h > 0.0:
        s_new, status = ukf_step(P.ch, P.ukf, x[0 : P.ns], x[P.ns : P.ns + nw], step.q, h)
        if status != UKF_OK:
            step.info[0] = F.E_UKF
            step.info[1] = status
            step.info[2] = t
            return
        x[0 : P.ns] = s_new
    x[P.ns : P.ns + nw] = velocity_u(P, P.ch, t, step.q, step.eta)[0]
    x[P.ns + nw] = t


@dataclass(frozen=True)
class Params:
    """What :func:`controller` was given (the scheme's ``ctx.params``)."""

    mode: int
    k: float = 5.0
    c0: tuple = (0.5, 0.1)
    amp: tuple = (0.0, 0.0)
    om: tuple = (0.0, 0.0)
    rate: float = 0.0
    start: float = 0.0
    factor: float = 1.0
    dt: float = 0.01
    k_jump: int = -1
    estimator: Any = None  # FarzaObserver (FARZA) or UKFEstimator (UKF)


def _no_ukf() -> Ukf:
    z1, z2 = np.zeros(1), np.zeros((1, 1))
    return Ukf(1, 1, False, False, z2, z2, z1, z1, 1.0)


def _pack(ctx) -> P:
    p: Params = ctx.params
    est = p.estimator
    obs = est.packed() if p.mode == FARZA else _no_obs()
    ukf = ukf_params(est) if p.mode == UKF else _no_ukf()
    ns = est.n_states if est is not None else 0
    arr = lambda v: np.ascontiguousarray(v, dtype=float)  # noqa: E731
    return P(
        p.mode, float(p.k), arr(p.c0), arr(p.amp), arr(p.om), float(p.rate), float(p.start), float(p.factor),
        float(p.dt), int(p.k_jump), np.ones(ctx.chain.n_wheels), obs, ukf, ctx.chain.params, int(ns),
    )  # fmt: skip


def _n_states(ctx) -> int:
    p: Params = ctx.params
    if p.mode == EXPLODING:
        return 1
    if p.mode == FARZA:
        return p.estimator.n_states
    if p.mode == UKF:
        return p.estimator.n_states + ctx.chain.n_wheels + 1
    return 0


def _initial_state(ctx, q0, eta0) -> np.ndarray:
    p: Params = ctx.params
    if p.mode == EXPLODING:
        return np.array([1.0])
    if p.mode == FARZA:
        return p.estimator.initial_state(q0)  # only q is measured: qdot_hat(0) = 0
    if p.mode == UKF:
        u0 = velocity_u(_pack(ctx), ctx.chain.params, 0.0, np.ascontiguousarray(q0, dtype=float), eta0)[0]
        return np.concatenate((p.estimator.initial_state(q0), u0, [0.0]))
    return np.zeros(0)


SCHEME = register(
    Scheme(
        "harness",
        law,
        _pack,
        n_states=_n_states,
        initial_state=_initial_state,
        discrete=discrete,
        signals={"eta_cmd": 2},
        terms="none",
        family="test",
        description="the engine's and the observers' test harnesses (tests/data/harness_scheme.py)",
    )
)


def controller(chain, mode: int, **kw) -> SchemeController:
    """The harness in ``mode`` on ``chain`` (keywords: the fields of :class:`Params`)."""
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    if chain.n == 2:
        kin = TwoLinkKinematic(chain.d[0], ref, 1.0, 1.0, 1.0)
    else:
        kin = ChainedBackstepping(chain.d, ref, [0.3] * chain.n, 1.0, 1.0, 5.0)
    return SchemeController(SCHEME, chain, kin, kw.get("k", 5.0), Params(mode, **kw))
