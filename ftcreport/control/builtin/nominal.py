r"""The nominal scheme: the matched law (3.35) assuming healthy wheels, no fault tolerance (the baseline).

Its face is :class:`ftcreport.control.tracking.TrackingController`; its law is
``control.passive_law.nominal_law`` behind the passive dispatcher (one loop for the passive schemes).
:func:`matched_law_scheme` builds it and the oracle (control/builtin/oracle.py), which differ only in their face
and their words.
"""

from __future__ import annotations

import importlib

from ...schemes.api import Scheme
from ...schemes.fields import Gain, Strict, doc_field
from ...schemes.registry import register_built_in

__all__ = ["K_V", "SCHEME", "NominalScheme", "matched_law_scheme"]

K_V = "velocity-error gain of the dynamic law (the thesis's k4 or c6)"


class NominalScheme(Strict):
    """The law assuming healthy wheels (no FTC)."""

    k_v: Gain = doc_field(..., K_V, "1/s")


def matched_law_scheme(name: str, face: str, params: type[Strict], **words) -> Scheme:
    """A scheme of the matched law (3.35) behind the passive dispatcher, its only parameter k_v.

    ``face``: ``"module:Class"`` of its Python face, built as ``Class(chain, kin, k_v)``; ``words``: the
    rest of :class:`~ftcreport.schemes.api.Scheme`'s fields (family, description, reference, label,
    summary, color, default_run).
    """
    module, cls = face.split(":")

    def controller(scheme: Scheme, ctx):
        face_cls = getattr(importlib.import_module(module, __package__), cls)
        return face_cls(ctx.chain, ctx.kin, ctx.k_v)

    return Scheme(
        name,
        law="ftcreport.control.passive_law:passive_law",
        discrete="ftcreport.control.passive_law:passive_discrete",
        params=params,
        controller=controller,
        defaults=lambda case, k_v: params(k_v=k_v),
        **words,
    )


SCHEME = register_built_in(
    matched_law_scheme(
        "nominal",
        "..tracking:TrackingController",
        NominalScheme,
        family="baseline",
        description="the matched law (3.35) assuming healthy wheels: no FTC",
        reference="thesis 3.2.2, (3.35)",
        label="nominal (no FTC)",
        summary="no FTC",
        color="#d62728",
        default_run=True,
    ),
    10,
)
