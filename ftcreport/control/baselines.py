r"""Baselines every FTC scheme is reported between.

* ``nominal``: the kinematic controller and the dynamic law (3.35) assuming
  healthy wheels, no fault tolerance (:func:`nominal`).
* ``oracle``: the same laws told the true effectiveness sigma(t) and friction
  ubar(t) at every instant (:class:`OracleController`)::

      u = (Mbar1^-1 Bbar sigma)^+ [w - Mbar1^-1 Bbar ubar]

  so that Mbar1^-1 Bbar (sigma u + ubar) = w exactly whenever sigma is
  compensable; for an uncompensable sigma it applies the least-squares
  pseudo-inverse (the best any law can do without the lost direction).

The engine hands the oracle's law the faults it holds over each step, so the
oracle sees exactly what the plant applies, including at event instants.
"""

from __future__ import annotations

from ..model.chain import Chain
from .kinematic import ChainedBackstepping, TwoLinkKinematic
from .tracking import TrackingController

__all__ = ["OracleController", "nominal"]


def nominal(chain: Chain, kinematic: TwoLinkKinematic | ChainedBackstepping, k_v: float) -> TrackingController:
    """The no-FTC baseline: healthy pattern, no friction compensation."""
    return TrackingController(chain, kinematic, k_v)


class OracleController(TrackingController):
    """Dynamic law with the true sigma and ubar (upper bound of every FTC scheme): the oracle scheme's face.

    Its law is the compiled ``control.passive_law.oracle_law``, told the faults the plant applies at
    every stage of every step."""

    scheme_name = "oracle"
