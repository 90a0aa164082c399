r"""The nominal scheme: the matched law (3.35) assuming healthy wheels, no fault tolerance (the baseline).

Its face is :class:`ftcreport.control.tracking.TrackingController`; its law is
``schemes.laws.passive.nominal_law`` behind the passive dispatcher (one loop for the passive schemes).
"""

from __future__ import annotations

from ..fields import Gain, Strict, doc_field
from .api import Scheme
from .registry import register_built_in

__all__ = ["K_V", "SCHEME", "NominalScheme"]

K_V = "velocity-error gain of the dynamic law (the thesis's k4 or c6)"


class NominalScheme(Strict):
    """The law assuming healthy wheels (no FTC)."""

    k_v: Gain = doc_field(..., K_V, "1/s")


def _controller(scheme: Scheme, ctx):
    from ..control.tracking import TrackingController

    return TrackingController(ctx.chain, ctx.kin, ctx.k_v)


SCHEME = register_built_in(
    Scheme(
        "nominal",
        law="ftcreport.schemes.laws.passive:passive_law",
        discrete="ftcreport.schemes.laws.passive:passive_discrete",
        params=NominalScheme,
        controller=_controller,
        family="baseline",
        description="the matched law (3.35) assuming healthy wheels: no FTC",
        reference="thesis 3.2.2, (3.35)",
        label="nominal (no FTC)",
        summary="no FTC",
        color="#d62728",
        default_run=True,
        defaults=lambda case, k_v: NominalScheme(k_v=k_v),
    ),
    10,
)
