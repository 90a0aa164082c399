r"""The oracle: (3.35) told the true sigma and ubar at every instant, the bound every FTC scheme is read against.

Its face is :class:`ftcreport.control.baselines.OracleController`; its law is
``schemes.laws.passive.oracle_law`` behind the passive dispatcher.
"""

from __future__ import annotations

from ..fields import Gain, Strict, doc_field
from .api import Scheme
from .nominal import K_V
from .registry import register_built_in

__all__ = ["SCHEME", "OracleScheme"]


class OracleScheme(Strict):
    """The law told the true sigma and ubar at every instant."""

    k_v: Gain = doc_field(..., K_V, "1/s")


def _controller(scheme: Scheme, ctx):
    from ..control.baselines import OracleController

    return OracleController(ctx.chain, ctx.kin, ctx.k_v)


SCHEME = register_built_in(
    Scheme(
        "oracle",
        law="ftcreport.schemes.laws.passive:passive_law",
        discrete="ftcreport.schemes.laws.passive:passive_discrete",
        params=OracleScheme,
        controller=_controller,
        family="bound",
        description="(3.35) told the true sigma and ubar at every instant",
        reference="thesis (3.35) with the true pattern",
        label="the oracle",
        summary="told the true faults",
        color="#2ca02c",
        default_run=True,
        defaults=lambda case, k_v: OracleScheme(k_v=k_v),
    ),
    90,
)
