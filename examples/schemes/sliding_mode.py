r"""A passive sliding-mode FTC law with a boundary layer: the worked example of the scheme API.

Written only against the public API (:mod:`ftcreport.schemes`); ``README.md`` ("Write your own
scheme") walks through it.  List this file in a case's ``plugins`` and give it a table::

    plugins = ["../examples/schemes/sliding_mode.py"]
    [schemes.sliding_mode]
    k_v = 20.0      # the linear velocity-error gain (the thesis's k4)
    k0 = 1.0        # constant part of the switching gain      [m/s^2, rad/s^2]
    k_w = 0.6       # part proportional to |w|                  [1]
    phi = 0.02      # boundary-layer width                      [m/s, rad/s]

Derivation
----------
The thesis's matched dynamics (3.33)-(3.37): with the velocity error ``eta_e = eta - eta_c``
and the reduced model (2.70),

    eta_e' = g + MB tau - eta_c',    g = -Mbar1^-1 (Mbar2 eta + Cbar),    MB = Mbar1^-1 Bbar,

and the faults enter as ``tau = Sigma u + ubar`` (2.101)-(2.102), ``Sigma = diag(sigma)``.  The
nominal law (3.35) with every wheel healthy is ``u = MB^+ w``, ``w = -k_v eta_e - T^T f_eta - g +
eta_c'`` (the engine hands the law these terms: ``terms.w``, ``terms.MB``, ``terms.g``,
``terms.eta_e``).  Here the sliding variable is the velocity
error itself, ``s = eta_e`` (relative degree one in u; Slotine and Li, *Applied Nonlinear Control*,
Prentice Hall 1991, ch. 7; Utkin, *Sliding Modes in Control and Optimization*, Springer 1992), and

    u = MB^+ (w - K sat(s / phi)),    sat(x) = x if |x| <= 1 else x / |x|   (a vector saturation),
    K = k0 + k_w |w|.

With ``A = MB Sigma MB^+`` the closed loop is

    s' = -k_v s - T^T f_eta - A K sat(s / phi) + d,    d = (A - I) w + MB ubar,

so the faults are a matched uncertainty ``d`` (it enters where the control does; Alwi and
Edwards, "Fault tolerant control using sliding modes with on-line control allocation",
Automatica 44(7), 2008, treat actuator faults the same way).  With the thesis's V2 = V1 +
s^T s / 2 (3.36), the cross term f_eta^T T s cancels as in (3.37) and

    V2' <= V1'' - k_v |s|^2 - K lambda |s| + |s| |d|     outside the layer (|s| > phi),

where ``lambda = lambda_min((A + A^T)/2)``.  Hence, **if lambda > 0 and** ``lambda K >= |d| +
kappa`` for some kappa > 0, i.e. ``lambda k_w >= ||A - I||`` and ``lambda k0 >= ||MB|| |ubar| +
kappa``, ``s`` reaches the layer ``|s| <= phi`` in finite time and stays in it; inside it the
loop is linear with gain ``k_v + lambda K / phi``, so the velocity error is ultimately bounded by
``phi`` and the kinematic errors of (3.27)-(3.28) by a class-K function of phi (uniform ultimate
boundedness, not asymptotic tracking: the price of the boundary layer, which removes chattering).

Which wheels must work: ``A`` has rank 2 only if ``MB Sigma`` does, the thesis's compensability
condition (a leader wheel and at least two wheels working, rank(Bbar sigma) = 2).  That is
necessary, not sufficient: ``lambda > 0`` holds for every sigma with ``(1 - min sigma) cond(MB) <
1``, i.e. for partial losses of effectiveness, but a wheel lost completely (sigma = 0) can make
``A``'s symmetric part indefinite; then this passive law has no guarantee and the active or
switching schemes, which identify sigma, are the right tools.  The law does not read the true
faults (``step.sigma_true``, ``step.ubar_true``): it is passive, one fixed law for every fault.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ftcreport import schemes
from ftcreport.schemes import Scheme, SchemeContext, register

jit = schemes.jit  # numba's njit with ftcreport's options (cache=True, nogil, error_model="numpy")
law_for_pattern = schemes.law_for_pattern


# 1. Parameters: the case's [schemes.sliding_mode] table (every field with its unit and range).
class SlidingModeParams(BaseModel):
    """[schemes.sliding_mode]: the sliding-mode law's gains."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    k_v: float | None = Field(
        None,
        gt=0,
        le=1e6,
        description="linear velocity-error gain (default: the case's)",
        json_schema_extra={"unit": "1/s"},
    )
    k0: float = Field(
        1.0,
        ge=0,
        le=1e6,
        description="constant part of the switching gain K",
        json_schema_extra={"unit": "m/s^2, rad/s^2"},
    )
    k_w: float = Field(
        0.6,
        ge=0,
        le=1e3,
        description="part of K proportional to |w| (bounds (A - I) w)",
        json_schema_extra={"unit": "1"},
    )
    phi: float = Field(
        0.02, gt=0, le=1e3, description="boundary-layer width on |eta_e|", json_schema_extra={"unit": "m/s, rad/s"}
    )


# 2. Pack: what the compiled law reads (numbers and arrays in a NamedTuple; never pass this
#    tuple to an ftcreport kernel compiled with cache=True, see README "the numba rule").
class P(NamedTuple):
    k0: float
    k_w: float
    phi: float
    healthy: np.ndarray  # sigma = 1 for every wheel: the law inverts the healthy MB


def pack(ctx: SchemeContext) -> P:
    p = ctx.params if ctx.params is not None else SlidingModeParams()
    return P(p.k0, p.k_w, p.phi, np.ones(ctx.chain.n_wheels))


# 3. The law: the engine hands it the matched terms at the measured state (its k_v: the table's);
#    it writes the torques, its states' rates (none here: n_states is 0) and its signals.
@jit
def law(P, step, terms, x, out):
    w, s = terms.w, terms.eta_e  # the sliding variable s is the velocity error
    # K = k0 + k_w |w|: bounds |d| = |(A - I) w + MB ubar| (see the module docstring)
    K = P.k0 + P.k_w * math.sqrt(w[0] * w[0] + w[1] * w[1])
    # K sat(s / phi) = K s / max(|s|, phi): linear inside the boundary layer, K s/|s| outside
    gain = K / max(math.sqrt(s[0] * s[0] + s[1] * s[1]), P.phi)
    v = np.empty(2)
    v[0] = w[0] - gain * s[0]
    v[1] = w[1] - gain * s[1]
    # u = MB^+ (w - K sat(s / phi))
    out.u[:] = law_for_pattern(terms.MB, v, P.healthy)
    # 4. Signals: the sliding variable s = eta_e and the switching gain K, in the order declared below
    out.sig[0] = s[0]
    out.sig[1] = s[1]
    out.sig[2] = K


# 5. Register: from now on a case may name it in [schemes.sliding_mode] and schemes.run.
register(
    Scheme(
        name="sliding_mode",
        law=law,
        pack=pack,
        params=SlidingModeParams,
        signals={"s": 2, "K": 1},
        family="passive",
        description="sliding mode on the velocity error with a boundary layer: u = MB^+ (w - K sat(eta_e/phi)), "
        "K = k0 + k_w |w|; passive (one law for every fault)",
        reference="Slotine & Li, Applied Nonlinear Control (1991) ch. 7; Utkin (1992); Alwi & Edwards, "
        "Automatica 44(7) 2008",
    )
)
