r"""Kinematic + dynamic tracking controller (no FTC): the nominal closed loop.

The dynamic law for a failure pattern sigma_(k), thesis (3.35)/(3.107) with E8::

    u_(k) = (Mbar1^-1 Bbar sigma_(k))^+ [ -k_v eta_e - T_alpha^T f_eta
                                           + Mbar1^-1 Mbar2 eta + Mbar1^-1 Cbar + etadot_c ]

with the minimum-norm right inverse A^+ = A^T (A A^T)^-1.  With sigma = sigma_(k)
the velocity error obeys ``eta_e' = -k_v eta_e - T_alpha^T f_eta`` and the total
Lyapunov function decreases.  :class:`TrackingController` applies it with the
healthy pattern (the ``nominal`` baseline); the FTC schemes' compiled laws use
the same kernels with other patterns.

The law lives once, in the compiled kernels (``control.tracking_compiled.law_terms`` and
``law_for_pattern``, which cite the equations and errata); the helpers here are
their faces, and :meth:`TrackingController.evaluate` is the compiled loop's law at
one state for the analyses (``analysis.closed_loop_jacobian``).

etadot_c is the derivative of eta_c(t, q, psi) along the closed loop (ERRATA P5):
the directional derivative in the direction (qdot = S(q) eta, 1), computed by the
kernels' ``eta_c_and_dot`` as a central difference of step h (truncation O(h^2),
about 1e-10 relative at h = 1e-5).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import ModelError
from ..model import kernels as K
from ..model.chain import Chain
from ..schemes.controller import KINEMATIC_SIGNALS, SchemeController
from .kinematic import ChainedBackstepping, KinematicOutput, TwoLinkKinematic

__all__ = [
    "LawTerms",
    "TrackingController",
    "law_for_pattern",
    "law_terms",
]


def _F():
    """The compiled twin of this module (numba is loaded on first use, not with the package)."""
    from . import tracking_compiled as compiled

    return compiled


class LawTerms(NamedTuple):
    """Pattern-independent pieces of the dynamic law at one instant.

    ``w`` is the desired closed-loop velocity-error derivative term
    ``-k_v eta_e - T_alpha^T f_eta + Mbar1^-1 (Mbar2 eta + Cbar) + etadot_c``,
    ``MB = Mbar1^-1 Bbar`` and ``g = -Mbar1^-1 (Mbar2 eta + Cbar)`` (free dynamics).
    """

    w: np.ndarray
    MB: np.ndarray
    g: np.ndarray


def _vec(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def law_terms(
    Mbar1: np.ndarray,
    Mbar2: np.ndarray,
    Cbar: np.ndarray,
    Bbar: np.ndarray,
    eta: np.ndarray,
    eta_e: np.ndarray,
    kin: KinematicOutput,
    eta_c_dot: np.ndarray,
    k_v: float,
) -> LawTerms:
    """The bracket of (3.35)/(3.107) with E8 and Mbar1^-1 Bbar, once for every pattern: the compiled ``law_terms``."""
    w, MB, g = _F().law_terms(
        *(_vec(v) for v in (Mbar1, Mbar2, Cbar, Bbar, eta, eta_e, kin.T_alpha, kin.f_eta, eta_c_dot)), float(k_v)
    )
    return LawTerms(w, MB, g)


def law_for_pattern(terms: LawTerms, sigma_k: np.ndarray, w_extra: np.ndarray | None = None) -> np.ndarray:
    r"""u_(k) = (Mbar1^-1 Bbar sigma_(k))^+ w, thesis (3.35)/(3.107): the compiled ``law_for_pattern``.

    ``w_extra`` is added to the bracket (e.g. ``-Mbar1^-1 Bbar ubar`` to cancel a known
    or estimated friction).  For a pattern with rank(A) < 2 the least-squares
    pseudo-inverse is used (the oracle facing an uncompensable fault).
    """
    w = terms.w if w_extra is None else terms.w + w_extra
    return _F().law_for_pattern(_vec(terms.MB), _vec(w), _vec(sigma_k))


class TrackingController(SchemeController):
    """Kinematic controller + dynamic law for one assumed pattern (nominal: healthy): the nominal scheme's face.

    Parameters
    ----------
    chain : Chain
        The controller's model (may differ from the plant's).
    kinematic : TwoLinkKinematic or ChainedBackstepping
    k_v : float
        Velocity-error gain of the dynamic law (thesis k4 or c6), > 0.
    sigma : sequence of float, optional
        Assumed effectiveness per wheel; healthy (all ones) by default.
    h : float
        Step of the directional central difference for etadot_c [s].
    """

    def __init__(
        self,
        chain: Chain,
        kinematic: TwoLinkKinematic | ChainedBackstepping,
        k_v: float,
        sigma=None,
        h: float = 1e-5,
    ) -> None:
        if not k_v > 0:
            raise ModelError(f"k_v: velocity gain must be > 0, got {k_v}")
        from ..schemes import get

        self._bind(get(self.scheme_name), chain, kinematic, k_v)
        self.sigma = np.ones(chain.n_wheels) if sigma is None else np.asarray(sigma, dtype=float)
        self.h = float(h)
        self.n_own = 0
        self.widths = {}
        self._P = None
        self._finish()

    scheme_name = "nominal"
    kinematic_signals = KINEMATIC_SIGNALS

    @property
    def P(self):
        """The compiled law's parameters (jit.packed.Law: the pattern the law assumes)."""
        if self._P is None:
            from ..jit.packed import LAW_ORACLE, LAW_TRACKING, law_params

            kind = LAW_ORACLE if self.scheme_name == "oracle" else LAW_TRACKING
            sigma = np.ascontiguousarray(self.sigma, dtype=float)
            self._P = law_params(kind, self.k_v, self.chain.n_wheels, self.n_states, sigma=sigma)
        return self._P

    # --------------------------------------------------------------- pieces
    def eta_c_and_dot(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray):
        """(KinematicOutput at t, etadot_c along qdot = S(q) eta): the compiled ``eta_c_and_dot``, the loop's."""
        return self.kin.law_and_rate(t, q, eta, xc, K.S_matrix(self.chain.params, q), self.h)

    # --------------------------------------------------------------- the analyses' law
    def evaluate(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray):
        kin, eta_c_dot = self.eta_c_and_dot(t, q, eta, xc)
        Mbar1, Mbar2, Cbar, Bbar = K.reduced(self.chain.params, q, eta)
        terms = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta - kin.eta_c, kin, eta_c_dot, self.k_v)
        return law_for_pattern(terms, self.sigma), np.zeros(self.n_states)
