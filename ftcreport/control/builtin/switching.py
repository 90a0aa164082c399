r"""The switching scheme: multiple models and a switching mechanism (thesis 3.2, 3.3.1, (3.42)-(3.48)).

Its face is :class:`ftcreport.control.switching.SwitchingController` (the model bank, the superposed
filters' layout, the walk's tables); its law and switching rule are ``control.passive_law``'s
behind the passive dispatcher.  The applied model and the costs are computed from the logged
state (:func:`_derived`), not logged by the law.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import StrictBool

from ...schemes.api import Scheme
from ...schemes.fields import FieldError, Gain, Gain0, Strict, doc_field, number
from ...schemes.registry import register_built_in
from .nominal import K_V

__all__ = ["PATTERNS", "SCHEME", "SwitchingScheme", "check_patterns", "patterns_of"]

PATTERNS = (
    '"all" (every compensable pattern) or a list of the wheels each model assumes failed, '
    'e.g. [[], ["1r"], ["1r", "2l"]]'
)


class SwitchingScheme(Strict):
    """Multiple models and switching (thesis 3.2, 3.3.1)."""

    k_v: Gain = doc_field(..., K_V, "1/s")
    gamma: Gain = doc_field(10.0, "pole of the reconstruction filters", "1/s")
    T_min: number(0.0, 1e3) = doc_field(0.01, "waiting time between switches", "s")
    c_inst: Gain0 = doc_field(1.0, "weight of the instantaneous cost", "1")
    c_int: Gain0 = doc_field(0.0, "weight of the integral cost", "1")
    forgetting: Gain = doc_field(1.0, "forgetting rate of the integral cost", "1/s")
    hysteresis: Gain0 = doc_field(
        1e-10,
        "cost margin a new model must win by (costs within 1e-9 relative of the smallest are ties, "
        "resolved to the lowest pattern index)",
        "(m/s)^2",
    )
    patterns: Literal["all"] | list[list[str]] = doc_field("all", PATTERNS, "-")
    rotor_inertia: StrictBool = doc_field(
        True,
        "with [actuators]: the bank's filters and the law model the chain with the motors' rotor inertia "
        "eta_g N^2 J_m on each wheel axis (false: the chain alone, as the thesis; the bank then mistakes the "
        "missing inertia for lost torque and identifies failed wheels that work)",
        "-",
    )


def check_patterns(name: str, table, case) -> None:
    """The table's patterns on the case's chain: wheels of the chain, each once, each model once, compensable."""
    from ...errors import FtcError
    from ...model import pattern_is_compensable, wheel_index

    if table.patterns == "all":
        return
    n = case.robots.n
    if not table.patterns:
        raise FieldError(
            f"schemes.{name}.patterns",
            'no pattern: the scheme needs at least one model (e.g. [[]], the healthy one) or "all"',
        )
    seen: dict[tuple[int, ...], int] = {}
    for i, failed in enumerate(table.patterns):
        pat = [1] * (2 * n)
        for w in failed:
            try:
                k = wheel_index(w, n)
            except FtcError as exc:
                raise FieldError(f"schemes.{name}.patterns[{i}]", str(exc)) from None
            if pat[k] == 0:
                raise FieldError(f"schemes.{name}.patterns[{i}]", f"wheel {w!r} is listed twice")
            pat[k] = 0
        first = seen.setdefault(tuple(pat), i)
        if first != i:
            raise FieldError(
                f"schemes.{name}.patterns[{i}]", f"{failed} is the model of patterns[{first}] again (each model once)"
            )
        if not pattern_is_compensable(pat):
            raise FieldError(
                f"schemes.{name}.patterns[{i}]",
                f"{failed} is uncompensable: rank(Bbar sigma) < 2 (a leader wheel and two wheels must work)",
            )


def patterns_of(table, chain) -> list[tuple[int, ...]] | None:
    """The 0/1 patterns of a table's ``patterns`` on ``chain`` (None: every compensable pattern)."""
    from ...model import wheel_index

    if table is None or table.patterns == "all":
        return None
    out = []
    for failed in table.patterns:
        pat = [1] * chain.n_wheels
        for w in failed:
            pat[wheel_index(w, chain.n)] = 0
        out.append(tuple(pat))
    return out


def models(table) -> int | None:
    """How many models a table lists (None: every compensable pattern)."""
    pats = getattr(table, "patterns", "all")
    return None if pats == "all" else len(pats)


def _controller(scheme: Scheme, ctx):
    from ...model.actuators import rotor_inertia_wheels
    from ..switching import SwitchingController

    table = ctx.params if ctx.params is not None else SwitchingScheme(k_v=ctx.k_v)
    # the bank's filters know the motors' rotors (issue 36 item 3): eta_g N^2 J_m on each wheel axis
    motors = ctx.case.motor_params() if ctx.case is not None and table.rotor_inertia else None
    return SwitchingController(
        ctx.chain,
        ctx.kin,
        ctx.k_v,
        patterns=patterns_of(table, ctx.chain),
        u_limit=ctx.saturation,
        rotor_inertia=None if motors is None else rotor_inertia_wheels(motors),
        **table.model_dump(include={"gamma", "T_min", "c_inst", "c_int", "forgetting", "hysteresis"}),
    )


def _derived(ctrl, xc: np.ndarray, meas: np.ndarray, costs: bool) -> dict[str, np.ndarray]:
    """The applied model and, for the saved log, the costs (3.46) at the logged states (switching_costs)."""
    P = ctrl.packed()
    out = {"selected": np.round(xc[:, P.sel]).astype(float)}
    if costs:  # no metric reads them: the metric stream does not compute them at every step
        from ...jit.refs import to_ref
        from ..switching_compiled import switching_costs_rows

        nq = ctrl.chain.n_q
        eta = np.ascontiguousarray(meas[:, nq : nq + 2], dtype=float)
        J = switching_costs_rows(to_ref(P), eta, np.ascontiguousarray(xc, dtype=float), ctrl.log_costs)
        if ctrl.log_costs:
            out["cost"] = J
        else:
            out["cost_selected"], out["cost_best"] = J[:, 0].copy(), J[:, 1].copy()
    return out


def _derived_names(ctrl) -> tuple[str, ...]:
    return ("selected", "cost") if ctrl.log_costs else ("selected", "cost_selected", "cost_best")


def _metrics(case, name, t, S, built, ctrl, run) -> dict:
    """Detection of the true pattern by the applied model (ftcreport.evaluation.metrics.switching_metrics)."""
    from ...evaluation.metrics import switching_metrics

    out = switching_metrics(t, S["selected"], ctrl.patterns, S["sigma"], list(built.faults.times))
    out["patterns"] = ctrl.patterns.astype(int).tolist()
    return out


def _defaults(case, k_v: float) -> SwitchingScheme:
    """The thesis's gamma = 10, T_min = 0.01 s (3.2.3); the adaptive table's patterns if it narrows them."""
    adaptive = getattr(case.schemes, "adaptive", None)
    return SwitchingScheme(k_v=k_v, gamma=10.0, T_min=0.01, patterns="all" if adaptive is None else adaptive.patterns)


def _budget(n: int, N: int) -> tuple[int, int]:
    """(values logged per sample, bank bytes): 2 + 4n superposed filters, (2n + 1)(2n + 2) / 2 integral states
    whatever the bank (control/switching.py), selected and last switch, N costs up to MAX_LOGGED_COSTS models
    (2 above); the (N, 2n) pattern array, the list of tuples it is built from (about 64 + 8 * 2n bytes per
    model) and the walk's tables (9 * 2^(2n) bytes)."""
    from ..switching import MAX_LOGGED_COSTS

    wheels = 2 * n
    width = 2 + 2 * wheels + (wheels + 1) * (wheels + 2) // 2 + 2 + (N if N <= MAX_LOGGED_COSTS else 2)
    return width, N * wheels * 8 + N * (64 + 8 * wheels) + 9 * 2**wheels


SCHEME = register_built_in(
    Scheme(
        "switching",
        law="ftcreport.control.passive_law:passive_law",
        discrete="ftcreport.control.passive_law:passive_discrete",
        params=SwitchingScheme,
        controller=_controller,
        derived=_derived,
        derived_names=_derived_names,
        family="multiple models",
        description="one law per failure pattern, switched by the cost of reconstructed velocities",
        reference="thesis 3.2 and 3.3.1, (3.42)-(3.48)",
        label="switching",
        summary="multiple models + switching",
        color="#1f77b4",
        metrics=_metrics,
        default_run=True,
        defaults=_defaults,
        validate=lambda table, case: check_patterns("switching", table, case),
        budget=_budget,
    ),
    20,
)
