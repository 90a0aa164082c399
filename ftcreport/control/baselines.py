r"""Baselines every FTC scheme is reported between.

* ``nominal``: the kinematic controller and the dynamic law (3.35) assuming
  healthy wheels, no fault tolerance (:func:`nominal`).
* ``oracle``: the same laws told the true effectiveness sigma(t) and friction
  ubar(t) at every instant (:class:`OracleController`)::

      u = (Mbar1^-1 Bbar sigma)^+ [w - Mbar1^-1 Bbar ubar]

  so that Mbar1^-1 Bbar (sigma u + ubar) = w exactly whenever sigma is
  compensable; for an uncompensable sigma it applies the least-squares
  pseudo-inverse (the best any law can do without the lost direction).

The engine tells the oracle the faults it holds over each step through
``observe_faults(sigma, ubar)``, so the oracle sees exactly what the plant
applies, including at event instants.
"""

from __future__ import annotations

import numpy as np

from ..model import kernels as K
from ..model.chain import Chain
from .kinematic import ChainedBackstepping, TwoLinkKinematic
from .tracking import TrackingController, law_for_pattern, law_terms

__all__ = ["OracleController", "nominal"]


def nominal(chain: Chain, kinematic: TwoLinkKinematic | ChainedBackstepping, k_v: float) -> TrackingController:
    """The no-FTC baseline: healthy pattern, no friction compensation."""
    return TrackingController(chain, kinematic, k_v)


class OracleController(TrackingController):
    """Dynamic law with the true sigma and ubar (upper bound of every FTC scheme)."""

    def __init__(self, chain: Chain, kinematic: TwoLinkKinematic | ChainedBackstepping, k_v: float) -> None:
        super().__init__(chain, kinematic, k_v)
        self._sigma = np.ones(chain.n_wheels)
        self._ubar = np.zeros(chain.n_wheels)

    def observe_faults(self, sigma: np.ndarray, ubar: np.ndarray) -> None:
        """Called by the engine at every step with the faults it applies."""
        self._sigma = sigma
        self._ubar = ubar

    def evaluate(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray):
        kin, eta_c_dot = self.eta_c_and_dot(t, q, eta, xc)
        Mbar1, Mbar2, Cbar, Bbar = K.reduced(self.chain.params, q, eta)
        terms = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta - kin.eta_c, kin, eta_c_dot, self.k_v)
        # u = (Mbar1^-1 Bbar sigma)^+ [w - Mbar1^-1 Bbar ubar]
        u = law_for_pattern(terms, self._sigma, -terms.MB @ self._ubar)
        return u, np.zeros(self.n_states)
