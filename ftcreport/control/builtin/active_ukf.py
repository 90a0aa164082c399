r"""The active UKF scheme: an augmented-state unscented Kalman filter of q, eta, the gains and frictions and
the law (4.14) on its estimates, both at the samples, the command held in between.

Its face is :class:`ftcreport.control.active.ActiveController` over a
:class:`ftcreport.observers.UKFEstimator`; its law and discrete update (the filter's step) are
``control.active_law``'s behind the active dispatcher.
"""

from __future__ import annotations

from typing import Literal

from ...schemes.api import Scheme
from ...schemes.fields import Gain, Gain0, Strict, doc_field, number
from ...schemes.registry import register_built_in
from .active import ESTIMATE, TAU, Diagnosis, derived, metrics
from .nominal import K_V

__all__ = ["SAMPLED_LIMIT", "SCHEME", "ActiveUKFScheme"]

SAMPLED_LIMIT = 2.0  # k_v dt at which the held (sampled) velocity loop loses stability


class ActiveUKFScheme(Strict):
    """Active FTC with the augmented-state unscented Kalman filter (filterpy); runs at the samples."""

    k_v: Gain = doc_field(..., K_V, "1/s")
    meas_std: number(None, 1e3, gt=0) = doc_field(1e-3, "measurement standard deviation (R of the filter)", "m, rad")
    eta_noise: Gain0 = doc_field(1e-4, "process noise intensity of the velocities", "(m/s)^2/s")
    rho_noise: Gain0 = doc_field(1e-2, "random-walk intensity of the gains", "1/s")
    ubar_noise: Gain0 = doc_field(1e-2, "random-walk intensity of the frictions", "(N m)^2/s")
    rho_std0: Gain = doc_field(0.3, "initial standard deviation of the gains", "1")
    ubar_std0: Gain = doc_field(0.5, "initial standard deviation of the frictions", "N m")
    estimate: list[Literal["rho", "ubar"]] = doc_field(["rho", "ubar"], ESTIMATE, "-")
    tau: Gain | None = doc_field(None, TAU, "s")
    diagnosis: Diagnosis = doc_field(Diagnosis(), "fault detection settings ([...diagnosis])", "-")


def _controller(scheme: Scheme, ctx):
    from ...observers import UKFEstimator
    from ..active import ActiveController

    cfg = ctx.params if ctx.params is not None else ActiveUKFScheme(k_v=ctx.k_v)
    noise = cfg.model_dump(include={"meas_std", "eta_noise", "rho_noise", "ubar_noise", "rho_std0", "ubar_std0"})
    ukf = UKFEstimator(ctx.chain, estimate=tuple(dict.fromkeys(cfg.estimate)), **noise)
    return ActiveController(ctx.chain, ctx.kin, ctx.k_v, ukf, u_limit=ctx.saturation, tau=cfg.tau)


def _not_applicable(case, k_v: float) -> str | None:
    """The UKF holds its control over each step of length dt: e_(k+1) = (1 - k_v dt) e_k is unstable at k_v dt >= 2."""
    kdt = k_v * case.simulation.dt
    if kdt >= SAMPLED_LIMIT:
        return (
            f"the UKF holds its control over each {case.simulation.dt:g} s sample; with k_v = {k_v:g} the "
            f"sampled velocity loop has k_v dt = {kdt:.3g} >= 2 and is unstable"
        )
    return None


def _defaults(case, k_v: float) -> ActiveUKFScheme:
    """The schema's defaults; the filter's R from the plant's sensor noise when it has one."""
    nz = case.plant.noise
    std = max(nz.position, nz.heading)
    return ActiveUKFScheme(k_v=k_v, **({"meas_std": std} if std > 0 else {}))


def _cost(case) -> float:
    """The UKF's step propagates 2 (n + 2 + 4n) + 1 sigma points: about 4x the other schemes' step for n = 2
    (measured: 0.017 against 0.004 s per simulated second)."""
    n = case.robots.n
    return (2 * (n + 2 + 4 * n) + 1) / 6.0


SCHEME = register_built_in(
    Scheme(
        "active_ukf",
        law="ftcreport.control.active_law:active_law",
        discrete="ftcreport.control.active_law:active_discrete",
        params=ActiveUKFScheme,
        terms="own",
        start=True,  # the filter's first step and the first command at t0
        controller=_controller,
        derived=derived,
        derived_names=("P_max", "param_std"),
        family="active",
        description="augmented-state unscented Kalman filter + (4.14), both at the samples (the law held in between)",
        reference="Julier & Uhlmann 1997; thesis (4.14)",
        label="active (UKF)",
        summary="UKF + (4.14)",
        color="#17becf",
        metrics=metrics,
        default_run=True,
        defaults=_defaults,
        not_applicable=_not_applicable,
        cost=_cost,
    ),
    50,
)
