r"""The oracle: (3.35) told the true sigma and ubar at every instant, the bound every FTC scheme is read against.

Its face is :class:`ftcreport.control.baselines.OracleController`; its law is
``control.passive_law.oracle_law`` behind the passive dispatcher.
"""

from __future__ import annotations

from ...schemes.fields import Gain, Strict, doc_field
from ...schemes.registry import register_built_in
from .nominal import K_V, matched_law_scheme

__all__ = ["SCHEME", "OracleScheme"]


class OracleScheme(Strict):
    """The law told the true sigma and ubar at every instant."""

    k_v: Gain = doc_field(..., K_V, "1/s")


SCHEME = register_built_in(
    matched_law_scheme(
        "oracle",
        "..baselines:OracleController",
        OracleScheme,
        family="bound",
        description="(3.35) told the true sigma and ubar at every instant",
        reference="thesis (3.35) with the true pattern",
        label="the oracle",
        summary="told the true faults",
        color="#2ca02c",
        default_run=True,
    ),
    90,
)
