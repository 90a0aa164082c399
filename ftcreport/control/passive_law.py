r"""The passive (and baseline) built-in schemes' laws, behind one dispatcher so that they share one loop.

numba compiles the closed loop (fast/loop.py) once per law it is bound to, and each compile links
every kernel the law reaches.  Binding the built-in laws one by one made a cold batch compile one
loop per scheme (each with its own copy of the model, the reference and the kinematic law); here
nominal (the tracking law), the oracle, switching and adaptive sit behind :func:`passive_law`,
over one parameter type (jit.packed.Law, ``P.kind`` chooses).  The active schemes have theirs
(:mod:`ftcreport.control.active_law`).  Each law is the scheme API's: ``law(P, step, terms, x, out)``
on the matched terms (3.35)-(3.37) the engine computed at the measured state.
"""

from __future__ import annotations

from ..jit.compiling import jit
from ..jit.packed import LAW_ADAPTIVE, LAW_ORACLE, LAW_SWITCHING, LAW_TRACKING, _mv
from .switching_compiled import rotor_filter_terms, switching_rates, switching_select
from .tracking_compiled import law_for_pattern

__all__ = [
    "adaptive_discrete",
    "adaptive_law",
    "nominal_law",
    "oracle_law",
    "passive_discrete",
    "passive_law",
    "switching_discrete",
    "switching_law",
]


@jit
def nominal_law(P, step, terms, x, out):
    """(3.37) for the fixed pattern ``P.sigma`` (the nominal scheme: every wheel healthy)."""
    out.u[:] = law_for_pattern(terms.MB, terms.w, P.sigma)


@jit
def oracle_law(P, step, terms, x, out):
    """(3.37) told the true faults: u = (MB diag(sigma))^+ (w - MB ubar)."""
    out.u[:] = law_for_pattern(terms.MB, terms.w - _mv(terms.MB, step.ubar_true), step.sigma_true)


@jit
def switching_law(P, step, terms, x, out):
    """(3.37) for the selected model's pattern, and the model bank's rates (control.switching_compiled.switching_rates).

    With ``P.Jw`` (the motors' rotor inertias) the bank's filters predict with the rotors
    (control.switching_compiled.rotor_filter_terms); the law itself uses the chain's model, as every scheme.
    """
    u = law_for_pattern(terms.MB, terms.w, P.patterns[round(x[P.sel])])
    out.u[:] = u
    if P.Jw.shape[0] > 0:  # the bank's filters model the motors' rotors (issue 36 item 3); the law keeps the chain's
        MB, g = rotor_filter_terms(step.model, step.q, step.eta, P.Jw)
        switching_rates(P, MB, u, g, step.eta, x, out.dx)
    else:
        switching_rates(P, terms.MB, u, terms.g, step.eta, x, out.dx)


@jit
def switching_discrete(P, step, x):
    """After each step: the switching rule (control.switching_compiled.switching_select)."""
    switching_select(P, step.t, step.eta, x)


@jit
def adaptive_law(P, step, terms, x, out):
    """Multi-design integration (3.113)-(3.120): u = sum_k chi_k o u_(k), projected weight and friction laws."""
    Lw = P
    u = out.u
    dx = out.dx
    nw = u.shape[0]
    MB = terms.MB
    eta_e = terms.eta_e
    Nm = Lw.patterns.shape[0]
    uf = x[Lw.uf0 : Lw.uf0 + nw]
    w2 = terms.w - _mv(MB, uf)
    c = _mv(MB.T, eta_e)
    for k in range(Nm):
        # u_(k) = A^T (A A^T)^-1 w2, A = MB diag(sigma_(k)), in scalars (no temporaries)
        g00 = 0.0
        g01 = 0.0
        g11 = 0.0
        for j in range(nw):
            s2 = Lw.patterns[k, j] * Lw.patterns[k, j]
            g00 += MB[0, j] * MB[0, j] * s2
            g01 += MB[0, j] * MB[1, j] * s2
            g11 += MB[1, j] * MB[1, j] * s2
        det = g00 * g11 - g01 * g01
        y0 = (g11 * w2[0] - g01 * w2[1]) / det
        y1 = (g00 * w2[1] - g01 * w2[0]) / det
        for j in range(nw):
            Ukj = Lw.patterns[k, j] * (MB[0, j] * y0 + MB[1, j] * y1)
            chi = x[Lw.chi0 + k * nw + j]
            u[j] += chi * Ukj
            if Lw.adapt:
                # chidot = Proj(-gamma U_kj (MB^T eta_e)_j): frozen at the bounds 0 and 1 when pushing out
                pk = -Lw.gamma * Ukj * c[j]
                frozen = (chi <= 0.0 and pk < 0.0) or (chi >= 1.0 and pk > 0.0)
                dx[Lw.chi0 + k * nw + j] = 0.0 if frozen else pk
    if Lw.adapt:
        # friction estimate: ufdot = Gamma_f MB^T eta_e
        dx[Lw.uf0 : Lw.uf0 + nw] = _mv(Lw.Gamma_f, _mv(MB.T, eta_e))


@jit
def adaptive_discrete(P, step, x):
    """After each step: the weights clipped to [0, 1] (the projection's bounds)."""
    nw = P.patterns.shape[1]
    for i in range(P.chi0, P.chi0 + P.patterns.shape[0] * nw):
        x[i] = min(max(x[i], 0.0), 1.0)


@jit
def passive_law(P, step, terms, x, out):
    """The law of the passive (or baseline) scheme ``P.kind``."""
    k = P.kind
    if k == LAW_TRACKING:
        nominal_law(P, step, terms, x, out)
    elif k == LAW_ORACLE:
        oracle_law(P, step, terms, x, out)
    elif k == LAW_SWITCHING:
        switching_law(P, step, terms, x, out)
    else:
        adaptive_law(P, step, terms, x, out)


@jit
def passive_discrete(P, step, x):
    """The discrete update of the passive scheme ``P.kind`` (switching rule, weight clip)."""
    k = P.kind
    if k == LAW_SWITCHING:
        switching_discrete(P, step, x)
    elif k == LAW_ADAPTIVE:
        adaptive_discrete(P, step, x)
