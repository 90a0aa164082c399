"""The plug-in copy of the nominal law in the round-2 form (13 positionals), run through the deprecated adapter.

For tests/test_scheme_check.py: a round-2 scheme file keeps working (with a DeprecationWarning).

(3.35) with every wheel healthy: u = (MB diag(1))^+ w; it logs u_0 as its own signal.
"""

from typing import NamedTuple

import numpy as np

from ftcreport import schemes
from ftcreport.schemes import Scheme, register

matched_terms = schemes.matched_terms
law_for_pattern = schemes.law_for_pattern


class P(NamedTuple):
    k_v: float
    sigma: np.ndarray
    ksig: int


@schemes.jit
def law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig):
    dx = np.zeros(xc.shape[0])
    w, MB, _g, _e = matched_terms(Kp, R, C, pc, t, q, eta, xc, P.k_v, info, sig)
    if info[0] != 0:
        return np.zeros(2 * pc.n), dx
    u = law_for_pattern(MB, w, P.sigma)
    if sig.shape[0] > 0:
        sig[P.ksig] = u[0]
    return u, dx


register(
    Scheme(
        "round2_copy_nominal",
        law,
        lambda ctx: P(ctx.k_v, np.ones(ctx.chain.n_wheels), ctx.n_kin_signals),
        signals={"u0": 1},
        family="baseline",
        description="a copy of the nominal law (test)",
        reference="thesis (3.35)",
    )
)
