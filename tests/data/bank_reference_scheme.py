"""The per-model switching bank as a plug-in scheme: the reference of tests/test_switching_bank.py.

The bank as it was before the superposition (issue 20 item 5): one reconstruction filter (3.42) and
one forgetting cost integral per model, integrated separately, and the exhaustive rule
(3.46)-(3.47): every cost, the lowest index within TIE_RTOL of the least one, the dwell time T_min,
the hysteresis.  It shares with the package only what is not under test: the kinematic law and the
matched law's terms (``matched_terms``, ``law_for_pattern``).  State after the kinematic one:
``[etahat_1 .. etahat_N (2 each), I_1 .. I_N, selected, time of the last switch]``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ftcreport import schemes
from ftcreport.control.switching import TIE_RTOL
from ftcreport.model import compensable_patterns
from ftcreport.schemes import Scheme, SchemeController, register

law_for_pattern = schemes.law_for_pattern


class P(NamedTuple):
    patterns: np.ndarray  # (N, 2n)
    gamma: float
    T_min: float
    c_inst: float
    c_int: float
    forgetting: float
    hysteresis: float
    tie: float


@schemes.jit
def law(P, step, terms, x, out):
    MB, g, eta = terms.MB, terms.g, step.eta
    N, nw = P.patterns.shape
    hat, integ, sel = 0, 2 * N, 3 * N
    u = law_for_pattern(MB, terms.w, P.patterns[round(x[sel])])
    out.u[:] = u
    for k in range(N):
        e2 = 0.0
        for i in range(2):
            # etahat_k' = -gamma etahat_k + gamma eta + g + MB diag(sigma_k) u
            rate = -P.gamma * x[hat + 2 * k + i] + P.gamma * eta[i] + g[i]
            for j in range(nw):
                rate += MB[i, j] * P.patterns[k, j] * u[j]
            out.dx[hat + 2 * k + i] = rate
            e2 += (eta[i] - x[hat + 2 * k + i]) ** 2
        # I_k' = -lambda I_k + |eta - etahat_k|^2
        out.dx[integ + k] = -P.forgetting * x[integ + k] + e2


@schemes.jit
def costs(P, eta, x):
    """J_k = c_inst |eta - etahat_k|^2 + c_int I_k, (3.46)."""
    N = P.patterns.shape[0]
    J = np.empty(N)
    for k in range(N):
        e0 = eta[0] - x[2 * k]
        e1 = eta[1] - x[2 * k + 1]
        J[k] = P.c_inst * (e0 * e0 + e1 * e1) + P.c_int * x[2 * N + k]
    return J


@schemes.jit
def discrete(P, step, x):
    N = P.patterns.shape[0]
    t = step.t
    sel, tsw = 3 * N, 3 * N + 1
    J = costs(P, step.eta, x)
    cur = round(x[sel])
    least = J.min()
    cand = int(np.argmin(J))
    for k in range(N):  # the lowest index within TIE_RTOL of the least cost
        if J[k] <= least * (1.0 + P.tie):
            cand = k
            break
    if cand != cur and t - x[tsw] >= P.T_min - 1e-12 and J[cand] < J[cur] - P.hysteresis:
        x[sel] = cand
        x[tsw] = t


def _pack(ctx) -> P:
    c = ctx.params
    pats = np.array(compensable_patterns(ctx.chain.n), dtype=float)
    return P(pats, 10.0, 0.01, 1.0, float(c), 1.0, 1e-10, TIE_RTOL)


def _n_states(ctx) -> int:
    return 3 * len(compensable_patterns(ctx.chain.n)) + 2


def _initial_state(ctx, q0, eta0) -> np.ndarray:
    N = len(compensable_patterns(ctx.chain.n))
    # etahat_k(0) = eta(0) (ERRATA E12g), I_k(0) = 0, model 0 applied, the last switch "long ago"
    return np.concatenate((np.tile(eta0, N), np.zeros(N), [0.0, -1e9]))


SCHEME = register(
    Scheme(
        "bank_reference",
        law,
        _pack,
        n_states=_n_states,
        initial_state=_initial_state,
        discrete=discrete,
        family="test",
        description="the per-model switching bank (tests/test_switching_bank.py)",
    )
)


def controller(chain, kin, k_v: float, c_int: float) -> SchemeController:
    """The per-model bank with every compensable pattern, gamma 10, T_min 0.01, c_inst 1, forgetting 1."""
    return SchemeController(SCHEME, chain, kin, k_v, c_int)
