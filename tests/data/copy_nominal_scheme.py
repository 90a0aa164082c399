"""A plug-in copy of the built-in nominal law, written against the public scheme API only (tests/test_schemes.py).

(3.35) with every wheel healthy: u = (MB diag(1))^+ w; it logs u_0 as its own signal.
"""

from typing import NamedTuple

import numpy as np

from ftcreport import schemes
from ftcreport.schemes import Scheme, register

law_for_pattern = schemes.law_for_pattern


class P(NamedTuple):
    sigma: np.ndarray


@schemes.jit
def law(P, step, terms, x, out):
    out.u[:] = law_for_pattern(terms.MB, terms.w, P.sigma)
    out.sig[0] = out.u[0]


register(
    Scheme(
        "copy_nominal",
        law,
        lambda ctx: P(np.ones(ctx.chain.n_wheels)),
        signals={"u0": 1},
        family="baseline",
        description="a copy of the nominal law (test)",
        reference="thesis (3.35)",
    )
)
