r"""The adaptive scheme and its ablation: multi-design integration with adaptive weights and a friction
estimate (thesis 3.3.2, (3.113)-(3.127)); ``adaptive_frozen`` holds the weights and the estimate at
their initial values (what adaptation buys).

Their face is :class:`ftcreport.control.adaptive.AdaptiveController`; the law and the weights' clip are
``control.passive_law``'s behind the passive dispatcher.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ...schemes.api import Scheme
from ...schemes.fields import Gain, Strict, doc_field
from ...schemes.registry import register_built_in
from .nominal import K_V
from .switching import PATTERNS, check_patterns, patterns_of

__all__ = ["FROZEN", "SCHEME", "AdaptiveScheme"]


class AdaptiveScheme(Strict):
    """Adaptive weights and friction estimate (thesis 3.3.2); weights start at 1 for the first pattern."""

    k_v: Gain = doc_field(..., K_V, "1/s")
    gamma: Gain = doc_field(1.0, "adaptation gain of every weight", "1")
    Gamma_f: Gain = doc_field(1.0, "friction estimate gain (times the identity)", "1")
    patterns: Literal["all"] | list[list[str]] = doc_field("all", PATTERNS, "-")


def _controller(adapt: bool):
    def build(scheme: Scheme, ctx):
        from ..adaptive import AdaptiveController

        table = ctx.params if ctx.params is not None else AdaptiveScheme(k_v=ctx.k_v)
        return AdaptiveController(
            ctx.chain,
            ctx.kin,
            ctx.k_v,
            patterns=patterns_of(table, ctx.chain),
            gamma=table.gamma,
            Gamma_f=table.Gamma_f,
            adapt=adapt,
        )

    return build


def _derived(ctrl, xc: np.ndarray, meas: np.ndarray, costs: bool) -> dict[str, np.ndarray]:
    """The weights (N, 2n) per row (a view of the logged state where numpy can) and the friction estimate."""
    P = ctrl.P
    nw = ctrl.chain.n_wheels
    chi = xc[:, P.chi0 : P.chi0 + ctrl.N * nw]
    return {"chi_hat": chi.reshape(len(xc), ctrl.N, nw), "uf_hat": xc[:, P.uf0 : P.uf0 + nw].copy()}


def _metrics(case, name, t, S, built, ctrl, run) -> dict:
    """The weights' range and final values, and the friction estimate (control variables, not a diagnosis:
    ERRATA P2)."""
    out: dict = {"patterns": ctrl.patterns.astype(int).tolist()}
    out["chi_hat_min"] = float(np.min(S["chi_hat_min"])) if "chi_hat_min" in S else float(run["chi_hat"].min())
    out["chi_hat_max"] = float(np.max(S["chi_hat_max"])) if "chi_hat_max" in S else float(run["chi_hat"].max())
    out["chi_hat_final"] = run["chi_hat"][-1].tolist()
    out["friction_estimate_final"] = S["uf_hat"][-1].tolist()
    out["friction_true_final"] = S["ubar"][-1].tolist()
    out["friction_estimate_note"] = "control variable of the adaptive law, not a fault diagnosis (ERRATA P2)"
    return out


def _patterns(case, other: str):
    cfg = getattr(case.schemes, other, None)
    return "all" if cfg is None else cfg.patterns


def _defaults(case, k_v: float) -> AdaptiveScheme:
    """The thesis's gamma = 1, Gamma_f = 1 (3.3.2.3); the switching table's patterns if it narrows them."""
    return AdaptiveScheme(k_v=k_v, gamma=1.0, Gamma_f=1.0, patterns=_patterns(case, "switching"))


def _frozen_defaults(case, k_v: float) -> AdaptiveScheme:
    """As adaptive's, with the adaptive table's patterns if it gives one (else the switching table's)."""
    other = "adaptive" if getattr(case.schemes, "adaptive", None) is not None else "switching"
    return AdaptiveScheme(k_v=k_v, gamma=1.0, Gamma_f=1.0, patterns=_patterns(case, other))


def _budget(n: int, N: int) -> tuple[int, int]:
    """(values logged per sample, bank bytes): 2n N weights, logged twice (state and chi_hat); a bank of
    about 8 values per model and wheel."""
    wheels = 2 * n
    return 2 * N * wheels, 8 * N * wheels * 8


_COMMON = dict(
    law="ftcreport.control.passive_law:passive_law",
    discrete="ftcreport.control.passive_law:passive_discrete",
    params=AdaptiveScheme,
    derived=_derived,
    derived_names=("chi_hat", "uf_hat"),
    reference="thesis 3.3.2",
    metrics=_metrics,
    budget=_budget,
)

SCHEME = register_built_in(
    Scheme(
        "adaptive",
        controller=_controller(True),
        family="adaptive",
        description="adaptive pattern weights and friction estimate",
        label="adaptive",
        summary="adaptive weights + friction estimate",
        color="#9467bd",
        default_run=True,
        defaults=_defaults,
        validate=lambda table, case: check_patterns("adaptive", table, case),
        **_COMMON,
    ),
    30,
)

FROZEN = register_built_in(
    Scheme(
        "adaptive_frozen",
        controller=_controller(False),
        family="ablation",
        description="the adaptive law with its weights and friction frozen",
        label="adaptive with frozen weights",
        summary="the adaptive law with weights and friction frozen",
        color="#8c564b",
        default_run=False,  # an ablation: run when the case names it
        defaults=_frozen_defaults,
        validate=lambda table, case: check_patterns("adaptive_frozen", table, case),
        **_COMMON,
    ),
    31,
)
