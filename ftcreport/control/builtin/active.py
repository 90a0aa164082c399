r"""The active scheme: the Farza et al. (2009) adaptive observer of q, eta, the gains and frictions, and the
compensating law (4.14) on its estimates (thesis chapter 4).

Its face is :class:`ftcreport.control.active.ActiveController` over a
:class:`ftcreport.observers.FarzaObserver`; its law is ``control.active_law.farza_law`` behind the
active dispatcher (one loop with the UKF scheme).  The law asks for the matched terms at the
estimated velocity itself (``terms="own"``).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ...schemes.api import Scheme
from ...schemes.fields import Gain, Strict, doc_field, number
from ...schemes.registry import register_built_in
from .nominal import K_V

__all__ = ["ESTIMATE", "OBSERVER_RATIO", "SCHEME", "TAU", "THETA_THESIS", "ActiveScheme", "Diagnosis"]

ESTIMATE = 'what the estimator identifies: "rho" (gains) and/or "ubar" (frictions)'
TAU = "filter 1/(tau s + 1) on the estimates the law uses (none by default)"
THETA_THESIS = {"two_link": 1.6, "chained": 0.9}  # Table 4.1, Table 4.2
# k_v / Theta above which the default active scheme is not run: measured, 12.5 (Table 4.1) and 5.6 (Table 4.2)
# track, 1875 (3.2.3's k4 = 3000) diverges at once; the limit in between is not mapped
OBSERVER_RATIO = 100.0


class Diagnosis(Strict):
    """Fault detection on the estimated gains and frictions (ftcreport.evaluation.diagnosis)."""

    gain_band: Gain = doc_field(0.1, "a gain estimate beyond this from the last declared value is an excursion", "1")
    friction_band: Gain = doc_field(0.2, "the same for a friction estimate", "N m")
    dwell: Gain = doc_field(2.0, "an estimate steady this long at a new value is declared", "s")
    settle_band: Gain | None = doc_field(
        None, "steady: within this of its window mean (default: a quarter of the band)", "1 or N m"
    )
    gain_tolerance: Gain = doc_field(
        0.1, "a declared gain within this of the true new value is a correct detection", "1"
    )
    friction_tolerance: Gain = doc_field(
        0.2, "a declared friction within this of the true new value is a correct detection", "N m"
    )


class ActiveScheme(Strict):
    """Active FTC with the Farza et al. (2009) adaptive observer (thesis chapter 4); only q is measured."""

    k_v: Gain = doc_field(..., K_V, "1/s")
    Theta: number(None, 1e3, gt=0) = doc_field(1.6, "observer tuning parameter Theta", "1/s")
    k0: Gain = doc_field(1.0, "observer gain k0", "1")
    k1: Gain = doc_field(1.0, "observer gain k1", "1")
    p0: number(None, 1e12, gt=0) = doc_field(0.1, "P(0) = p0 I", "1")
    p_max: number(None, 1e15, gt=0) = doc_field(
        1e3, "P guard: bound of P (ERRATA P3; the printed law has none, P grows like exp(Theta t))", "1"
    )
    estimate: list[Literal["rho", "ubar"]] = doc_field(["rho", "ubar"], ESTIMATE, "-")
    tau: Gain | None = doc_field(None, TAU, "s")
    diagnosis: Diagnosis = doc_field(Diagnosis(), "fault detection settings ([...diagnosis])", "-")
    q_hat0: Literal["measured", "zero"] = doc_field(
        "measured", "observer's initial q estimate: the first measurement, or 0 as in the thesis (4.2.4)", "-"
    )


def _controller(scheme: Scheme, ctx):
    from ...observers import FarzaObserver
    from ..active import ActiveController

    cfg = ctx.params if ctx.params is not None else ActiveScheme(k_v=ctx.k_v)
    obs = FarzaObserver(
        ctx.chain,
        cfg.Theta,
        cfg.k0,
        cfg.k1,
        cfg.p0,
        cfg.p_max,
        estimate=tuple(dict.fromkeys(cfg.estimate)),
        q_hat0=cfg.q_hat0,
    )
    return ActiveController(ctx.chain, ctx.kin, ctx.k_v, obs, u_limit=ctx.saturation, tau=cfg.tau)


def derived(ctrl, xc: np.ndarray, meas: np.ndarray, costs: bool) -> dict[str, np.ndarray]:
    """P_max (the largest eigenvalue of the estimator's covariance) and param_std (the parameters' deviations)."""
    o = ctrl.est
    nk = ctrl.kin.n_states
    est = xc[:, ctrl._est.start - nk : ctrl._est.stop - nk]
    if o.discrete_time:  # the UKF: the filter's whole covariance after its mean; the parameters after q, eta
        P = est[:, o.nx :].reshape(-1, o.nx, o.nx)
        first = ctrl.chain.n_q + 2
    else:  # the Farza observer's parameter covariance
        P = est[:, o._P].reshape(-1, o.p, o.p)
        first = 0
    out = {"P_max": np.linalg.eigvalsh(P).max(axis=1) if len(P) else np.zeros(0)}
    out["param_std"] = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2)[:, first:], 0.0))
    return out


def metrics(case, name, t, S, built, ctrl, run) -> dict:
    """Fault diagnosis from the estimates (ftcreport.evaluation.diagnosis) and the estimator's final values."""
    from ...evaluation.diagnosis import diagnosis_metrics

    cfg = getattr(case.schemes, name)
    names = ctrl.est.parameter_names()
    d = cfg.diagnosis
    out: dict = {"estimated_parameters": names}
    out |= diagnosis_metrics(
        built.chain,
        built.faults,
        names,
        t,
        S,
        case.plant.saturation,
        d.gain_band,
        d.friction_band,
        d.dwell,
        run.t_end,
        d.settle_band,
        d.gain_tolerance,
        d.friction_tolerance,
    )
    out["P_max"] = float(np.max(S["P_max"]))
    out["rho_hat_final"] = S["rho_hat"][-1].tolist()
    out["ubar_hat_final"] = S["ubar_hat"][-1].tolist()
    return out


def _defaults(case, k_v: float) -> ActiveScheme:
    """Theta = 1.6 for the two-link controller (Table 4.1) and 0.9 for the chained form (Table 4.2), k0 = k1 = 1,
    P(0) = 0.1 I (4.2.4); P guard 1e3; gains and frictions estimated."""
    return ActiveScheme(k_v=k_v, Theta=THETA_THESIS[case.kinematic.kind], k0=1.0, k1=1.0, p0=0.1)


def _not_applicable(case, k_v: float) -> str | None:
    """The law closes a k_v-fast velocity loop on an observer of rate Theta: no default table when k_v / Theta > 100."""
    theta = THETA_THESIS[case.kinematic.kind]
    if k_v / theta > OBSERVER_RATIO:
        return (
            f"the active law closes its k_v = {k_v:g} 1/s velocity loop on the Farza observer's estimate, whose "
            f"rate is Theta = {theta:g} 1/s: a ratio of {k_v / theta:.0f} (> {OBSERVER_RATIO:g}); measured on this "
            "case, the loop diverges within 10 ms"
        )
    return None


SCHEME = register_built_in(
    Scheme(
        "active",
        law="ftcreport.control.active_law:active_law",
        discrete="ftcreport.control.active_law:active_discrete",
        params=ActiveScheme,
        terms="own",
        controller=_controller,
        derived=derived,
        derived_names=("P_max", "param_std"),
        family="active",
        description="Farza adaptive observer of q, eta, gains and frictions + the compensating law (4.14)",
        reference="thesis chapter 4; Farza et al. 2009",
        label="active (Farza)",
        summary="Farza observer + (4.14)",
        color="#ff7f0e",
        metrics=metrics,
        default_run=True,
        defaults=_defaults,
        not_applicable=_not_applicable,
    ),
    40,
)
