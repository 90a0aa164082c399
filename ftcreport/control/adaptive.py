r"""Passive FTC 2: multi-design integration with adaptive weights and friction estimate.

Thesis section 3.3.2 (3.114-3.127), ERRATA E8, E13, E14, P1, P2.

Per failure pattern sigma_(k) a dynamic law with the friction estimate (3.121, E8)::

    u_(k) = (Mbar1^-1 Bbar sigma_(k))^+ [ -k_v eta_e - T_alpha^T f_eta + Mbar1^-1 (Mbar2 eta + Cbar)
                                          - Mbar1^-1 Bbar uhat_f + etadot_c ]

and the applied signal is their per-wheel weighted sum (3.118)::

    u_j = sum_k chihat_(k)j u_(k)j

Adaptive laws, from the Lyapunov function (3.129) (checked term by term)::

    uhat_f' = Gamma_f (Mbar1^-1 Bbar)^T eta_e                          (3.124 with E13)
    chihat_(k)j' = p_kj + f_kj,   p_kj = -gamma u_(k)j eta_e^T (Mbar1^-1 Bbar)_(:, j)   (3.125)

with the projection of E14 keeping every weight in [0, 1]: f = -p (update frozen)
when chihat is at 0 and p < 0 or at 1 and p > 0, else f = 0.  A fixed-step
integrator can step over the boundary within a step by O(h p); after every step
the weights are put back into [0, 1] (the discrete counterpart of the projection).

The weights and the friction estimate are control variables, not a diagnosis
(ERRATA P2): they drift even without faults and do not identify the pattern.
``adapt=False`` freezes them at their initial values (what adaptation buys).

State: ``[kinematic state, chihat (N x 2n, row-major), uhat_f (2n)]``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ModelError
from ..model.chain import Chain
from ..model.faults import model_patterns
from ..schemes.controller import SchemeController
from .kinematic import ChainedBackstepping, TwoLinkKinematic

__all__ = ["AdaptiveController"]


class AdaptiveController(SchemeController):
    """Multi-design integration adaptive FTC for any n with either kinematic controller: the adaptive scheme's face
    (``adaptive_frozen`` with ``adapt=False``).

    Parameters
    ----------
    chain : Chain
    kinematic : TwoLinkKinematic or ChainedBackstepping
    k_v : float
        Velocity-error gain (thesis k4 / c6).
    patterns : sequence of 0/1 sequences, optional
        The failure patterns; default every compensable pattern of the chain.
    gamma : float
        Adaptation gain of every weight chihat_(k)j (thesis gamma_kj).
    Gamma_f : float or (2n, 2n) array
        Adaptation gain matrix of the friction estimate.
    chi0 : (N, 2n) array, optional
        Initial weights; default the thesis's chihat_(1)(0) = I (first pattern), others 0.
    uf0 : (2n,) array, optional
        Initial friction estimate [N m] (default 0).
    adapt : bool
        False freezes weights and friction estimate at their initial values.
    """

    def __init__(
        self,
        chain: Chain,
        kinematic: TwoLinkKinematic | ChainedBackstepping,
        k_v: float,
        patterns: Sequence[Sequence[float]] | None = None,
        gamma: float = 1.0,
        Gamma_f: float | np.ndarray = 1.0,
        chi0: np.ndarray | None = None,
        uf0: np.ndarray | None = None,
        adapt: bool = True,
    ) -> None:
        pats = model_patterns(chain.n, patterns)
        if not gamma > 0:
            raise ModelError(f"gamma: adaptation gain must be > 0, got {gamma}")
        nw = chain.n_wheels
        G = np.asarray(Gamma_f, dtype=float)
        G = G * np.eye(nw) if G.ndim == 0 else G
        if G.shape != (nw, nw) or np.any(np.linalg.eigvalsh(0.5 * (G + G.T)) <= 0):
            raise ModelError(f"Gamma_f: must be a positive scalar or a ({nw}, {nw}) positive definite matrix")
        from ..schemes import get

        self._bind(get("adaptive" if adapt else "adaptive_frozen"), chain, kinematic, k_v)
        self.patterns = np.array(pats, dtype=float)
        self.N = self.patterns.shape[0]
        self.gamma = float(gamma)
        self.Gamma_f = G
        if chi0 is None:
            chi0 = np.zeros((self.N, nw))
            chi0[0] = 1.0
        chi0 = np.asarray(chi0, dtype=float)
        if chi0.shape != (self.N, nw) or np.any(chi0 < 0) or np.any(chi0 > 1):
            raise ModelError(f"chi0: expected ({self.N}, {nw}) weights inside [0, 1] (ERRATA E14)")
        self.chi0 = chi0
        self.uf0 = np.zeros(nw) if uf0 is None else np.asarray(uf0, dtype=float)
        self.adapt = bool(adapt)
        nk = kinematic.n_states
        self._kin = slice(0, nk)
        self._chi = slice(nk, nk + self.N * nw)
        self._uf = slice(self._chi.stop, self._chi.stop + nw)
        self.n_own = self._uf.stop - nk
        self.widths = {}
        self._P = None
        self._finish()

    @property
    def P(self):
        """The compiled law's parameters (jit.packed.Law; offsets in the scheme's own states)."""
        if self._P is None:
            from ..jit.packed import LAW_ADAPTIVE, law_params

            nk = self.kin.n_states
            self._P = law_params(
                LAW_ADAPTIVE, self.k_v, self.chain.n_wheels, self.n_states,
                patterns=np.ascontiguousarray(self.patterns, dtype=float), gamma=self.gamma,
                chi0=self._chi.start - nk, uf0=self._uf.start - nk,
                Gamma_f=np.ascontiguousarray(self.Gamma_f, dtype=float), adapt=int(self.adapt),
            )  # fmt: skip
        return self._P

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        xc = np.zeros(self.n_states)
        xc[self._kin] = self.kin.initial_state(t, q)
        xc[self._chi] = self.chi0.ravel()
        xc[self._uf] = self.uf0
        return xc
