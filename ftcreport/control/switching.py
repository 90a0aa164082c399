r"""Passive FTC 1: multiple dynamic controllers and a switching mechanism.

Thesis sections 3.2.2.2-3.2.2.3 and 3.3.1 (3.33-3.48, 3.107), ERRATA E8, E12f, E12g.

* One dynamic law per failure pattern sigma_(k) (3.35)/(3.107), all sharing the
  kinematic controller; only the selected one is applied.
* Reconstruction filters, one per model, as controller state (3.42)::

      etahat_(k) = gamma/(s+gamma)[eta] + 1/(s+gamma)[-Mbar1^-1 (Mbar2 eta + Cbar)]
                   + 1/(s+gamma)[Mbar1^-1 Bbar sigma_(k) u]

  i.e. ``etahat_(k)' = -gamma etahat_(k) + gamma eta - Mbar1^-1 (Mbar2 eta + Cbar)
  + Mbar1^-1 Bbar sigma_(k) u`` with the applied u, started at etahat_(k)(0) = eta(0)
  (ERRATA E12g).  The matched model then reconstructs exactly: its error obeys
  e' = -gamma e + Mbar1^-1 Bbar (sigma - sigma_(k)) u = -gamma e.
* Costs (3.46), with the optional forgetting integral of Narendra & Balakrishnan
  (1994): ``J_(k) = c_inst |etatilde_(k)|^2 + c_int int_0^t exp(-lambda (t - s)) |etatilde_(k)(s)|^2 ds``;
  the integral is one more state per model, ``I' = -lambda I + |etatilde|^2``.
  The thesis uses c_inst = 1, c_int = 0.
* Switching (3.47)-(3.48), after every integration step: the argmin of J is
  applied if at least T_min has passed since the last switch.  Hysteresis
  (ours, ERRATA E12g): a candidate replaces the applied model only if its cost is
  lower by more than ``hysteresis`` (absolute).  The laws of models that differ
  only in wheels the applied law sends no torque to reconstruct identically, so
  their costs tie at round-off level; without the margin argmin + T_min chatters
  among them.  Ties resolve to the lowest index: patterns are ordered healthy
  first, then by number of assumed failures.  A tie is a cost within
  ``TIE_RTOL`` (relative) of the smallest: round-off (about 1e-13 here) must not
  decide between models that are equivalent, or the run depends on the order of
  floating-point operations (the two engines, another BLAS) from the first such
  tie on.

The controller's state is ``[kinematic state, etahat (N x 2), I (N, if c_int > 0),
selected index, time of the last switch]``; the last two are discrete (zero
derivative, changed only by :meth:`discrete`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ModelError
from ..model import kernels as K
from ..model.chain import Chain
from ..model.faults import model_patterns
from .kinematic import ChainedBackstepping, TwoLinkKinematic
from .tracking import TrackingController, kinematic_signals, law_for_pattern, law_terms

__all__ = ["TIE_RTOL", "SwitchingController"]

TIE_RTOL = 1e-9  # switching costs this close (relative) to the smallest are ties


class SwitchingController:
    """Multiple-model switching FTC for any n with either kinematic controller.

    Parameters
    ----------
    chain : Chain
        The controller's model.
    kinematic : TwoLinkKinematic or ChainedBackstepping
    k_v : float
        Velocity-error gain of every dynamic law (thesis k4 / c6).
    patterns : sequence of 0/1 sequences, optional
        The failure patterns sigma_(k) (1 = wheel works); default: every
        compensable pattern of the chain.
    gamma : float
        Pole of the reconstruction filters 1/(s + gamma) [1/s].
    T_min : float
        Waiting time between two switches [s].
    c_inst, c_int, forgetting : float
        Cost weights and forgetting rate lambda [1/s] of the integral term.
    hysteresis : float
        Absolute cost margin [(m/s)^2] a candidate must win by.
    u_limit : float, optional
        Saturation of the plant's actuators, if known: the filters use the
        saturated signal.
    initial_model : int
        Index of the model applied at the start (0: the first pattern).
    """

    def __init__(
        self,
        chain: Chain,
        kinematic: TwoLinkKinematic | ChainedBackstepping,
        k_v: float,
        patterns: Sequence[Sequence[float]] | None = None,
        gamma: float = 10.0,
        T_min: float = 0.01,
        c_inst: float = 1.0,
        c_int: float = 0.0,
        forgetting: float = 1.0,
        hysteresis: float = 1e-10,
        u_limit: float | None = None,
        initial_model: int = 0,
    ) -> None:
        pats = model_patterns(chain.n, patterns)
        for name, val in (("gamma", gamma), ("forgetting", forgetting)):
            if not val > 0:
                raise ModelError(f"{name}: must be > 0, got {val}")
        if T_min < 0 or c_inst < 0 or c_int < 0 or hysteresis < 0:
            raise ModelError("T_min, c_inst, c_int and hysteresis must be >= 0")
        self.chain = chain
        self.kin = kinematic
        self.tracking = TrackingController(chain, kinematic, k_v)
        self.k_v = float(k_v)
        self.patterns = np.array(pats, dtype=float)  # (N, 2n)
        self.N = self.patterns.shape[0]
        self.gamma, self.T_min = float(gamma), float(T_min)
        self.c_inst, self.c_int, self.forgetting = float(c_inst), float(c_int), float(forgetting)
        self.hysteresis = float(hysteresis)
        self.u_limit = u_limit
        if not 0 <= int(initial_model) < self.N:
            raise ModelError(f"initial_model: {initial_model} is not a model index (0..{self.N - 1})")
        self.initial_model = int(initial_model)
        nk = kinematic.n_states
        N = self.N
        self._kin = slice(0, nk)
        self._hat = slice(nk, nk + 2 * N)
        self._int = slice(nk + 2 * N, nk + 2 * N + (N if self.c_int > 0 else 0))
        self._sel = self._int.stop
        self._tsw = self._sel + 1
        self.n_states = self._tsw + 1
        # exact diagonal Jacobian of the linear filter / integral states (used by ROS2)
        self.stiff_diagonal = np.zeros(self.n_states)
        self.stiff_diagonal[self._hat] = -self.gamma
        self.stiff_diagonal[self._int] = -self.forgetting
        self.signal_names = ("eta_c", "z", "q_d", "eta_d", "selected", "cost")

    # ------------------------------------------------------------------ helpers
    def selected(self, xc: np.ndarray) -> int:
        """Index of the applied model."""
        return round(float(xc[self._sel]))

    def costs(self, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """J_(k) for every model, (N,)."""
        err = eta[None, :] - xc[self._hat].reshape(self.N, 2)
        J = self.c_inst * np.einsum("ij,ij->i", err, err)
        if self.c_int > 0:
            J = J + self.c_int * xc[self._int]
        return J

    # ------------------------------------------------------------------ Controller protocol
    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        xc = np.zeros(self.n_states)
        xc[self._kin] = self.kin.initial_state(t, q)
        xc[self._hat] = np.tile(eta, self.N)  # etahat_(k)(0) = eta(0), ERRATA E12g
        xc[self._sel] = float(self.initial_model)
        xc[self._tsw] = -1e9  # "long ago" (finite: the engine rejects non-finite states)
        return xc

    def evaluate(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray):
        kin, eta_c_dot = self.tracking.eta_c_and_dot(t, q, eta, xc[self._kin])
        Mbar1, Mbar2, Cbar, Bbar = K.reduced(self.chain.params, q, eta)
        terms = law_terms(Mbar1, Mbar2, Cbar, Bbar, eta, eta - kin.eta_c, kin, eta_c_dot, self.k_v)
        u = law_for_pattern(terms, self.patterns[self.selected(xc)])
        u_app = u if self.u_limit is None else np.clip(u, -self.u_limit, self.u_limit)
        dx = np.zeros(self.n_states)
        hat = xc[self._hat].reshape(self.N, 2)
        # etahat_(k)' = -gamma etahat + gamma eta + g + Mbar1^-1 Bbar sigma_(k) u   (3.42)
        drive = (self.patterns * u_app[None, :]) @ terms.MB.T  # (N, 2)
        dx[self._hat] = (-self.gamma * hat + self.gamma * eta[None, :] + terms.g[None, :] + drive).ravel()
        if self.c_int > 0:
            err = eta[None, :] - hat
            dx[self._int] = -self.forgetting * xc[self._int] + np.einsum("ij,ij->i", err, err)
        return u, dx

    def discrete(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        xc = xc.copy()
        xc[self._kin] = self.kin.discrete(t, q, xc[self._kin])
        J = self.costs(eta, xc)
        cur = self.selected(xc)
        lim = J.min() * (1.0 + TIE_RTOL)
        ties = np.flatnonzero(np.less_equal(J, lim))  # (3.47), ties -> lowest index
        cand = int(ties[0]) if ties.size else int(np.argmin(J))
        if cand != cur and t - xc[self._tsw] >= self.T_min - 1e-12 and J[cand] < J[cur] - self.hysteresis:
            xc[self._sel] = cand
            xc[self._tsw] = t
        return xc

    def signals(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> dict[str, np.ndarray]:
        return kinematic_signals(self.kin, t, q, xc[self._kin]) | {
            "selected": np.array(self.selected(xc), dtype=float),
            "cost": self.costs(eta, xc),
        }
