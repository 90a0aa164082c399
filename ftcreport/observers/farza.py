r"""Nonlinear adaptive observer of Farza et al. (2009) for n linked robots.

Thesis chapter 4, (4.4)-(4.11) with ERRATA E15 (signs) and E16 (parentheses).
State ``x = [q, qdot]`` (2N, N = n + 2), output ``y = q``, unknown parameters
``rho_bar = [rho (2n gains), ubar (2n frictions)]`` (a subset may be chosen)::

    x' = A x + phi(u, x, rho_bar),  A = [[0, I], [0, 0]],  C = [I, 0]
    phi_2 = S Mbar1^-1 (-Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar)) + Sdot eta,  eta = S^+ qdot   (E16)

phi is linear in rho_bar: d phi / d rho_bar = [0; S Mbar1^-1 Bbar [diag(u), I]] (exact).
Observer, with ytilde = y - C xhat (E15)::

    xhat'   = A xhat + phi(u, xhat, rhohat) + Theta Delta^-1 (S_o^-1 + Y P Y^T) C^T K(ytilde)
    rhohat' = Theta P Y^T C^T K(ytilde)
    Y'      = Theta (A - S_o^-1 C^T C) Y + Delta d phi / d rho_bar
    P'      = Theta P (I - P / p_max) - Theta P Y^T C^T C Y P              (guard, see below)

with S_o = [[I, -I], [-I, 2I]] (the solution of (4.9)), Delta = diag(I, I / Theta),
K(e) = k1 tanh(k0 e), Y(0) = 0, P(0) = p0 I.

P guard (ERRATA P3).  The printed P' = Theta P - Theta P Y^T C^T C Y P grows like
exp(Theta t) in directions the regressor does not excite (individual gains and
frictions are not identifiable in steady tracking: the regressor has rank <= 2 per
instant).  The term -Theta P^2 / p_max bounds P at p_max in those directions and
leaves it essentially unchanged where excitation keeps P << p_max; the trade-off
is a slower parameter convergence (smaller adaptation gain) when p_max is small.
``p_max = None`` reproduces the printed law.

The observer's equations exist once, in the compiled kernels
(``observers.farza_compiled.farza_derivative`` and ``farza_estimates``); :class:`FarzaObserver`
checks and holds the tuning, lays out the state, packs the tuple the kernels take
(``packed()``, ``jit.packed.Obs``) and calls them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..errors import ModelError
from ..model.chain import Chain
from ..model.faults import wheel_names

__all__ = ["Estimate", "FarzaObserver", "estimate_flags", "parameter_names"]


class Estimate(NamedTuple):
    """What an estimator provides the active controller at one instant.

    ``rho`` and ``ubar`` are per wheel (2n,); where a parameter is not estimated
    it holds its nominal value (gain 1, friction 0).
    """

    q: np.ndarray
    eta: np.ndarray
    rho: np.ndarray
    ubar: np.ndarray


def estimate_flags(estimate: Sequence[str]) -> tuple[bool, bool]:
    """(est_rho, est_ubar) of an estimator's ``estimate`` (any of ``"rho"``, ``"ubar"``, not none)."""
    unknown = set(estimate) - {"rho", "ubar"}
    if unknown or not estimate:
        raise ModelError(f"estimate: choose among 'rho', 'ubar', got {list(estimate)}")
    return "rho" in estimate, "ubar" in estimate


def parameter_names(n: int, est_rho: bool, est_ubar: bool) -> list[str]:
    """Names of an estimator's parameters for n robots, gains first: e.g. ``rho_1r``, ``ubar_2l``."""
    wheels = wheel_names(n)
    return [f"rho_{w}" for w in wheels if est_rho] + [f"ubar_{w}" for w in wheels if est_ubar]


class FarzaObserver:
    """Adaptive observer of q, qdot and the actuator parameters from measured q.

    Parameters
    ----------
    chain : Chain
        The observer's model.
    Theta : float
        High-gain tuning parameter (> 0).
    k0, k1 : float
        K(e) = k1 tanh(k0 e) (thesis k0 = k1 = 1, ERRATA E17).
    p0 : float
        P(0) = p0 I (thesis 0.1).
    p_max : float, optional
        Bound of P in unexcited directions (guard); None: the printed law.
    estimate : sequence of str
        Which parameters to estimate: any of ``"rho"`` (2n gains), ``"ubar"`` (2n frictions).
    printed_signs : bool
        Use the signs of (4.11) as printed (diverges, kept for the ERRATA E15 test).
    q_hat0 : str
        Initial estimate of q: ``"measured"`` (default) starts at the first measurement,
        q_hat(0) = q(0); ``"zero"`` is the thesis's choice (4.2.4: x(0) = 0, so
        q_hat(0) = 0).  qdot_hat(0) = 0 either way (only q is measured).  With
        ``"zero"`` the output error starts at q(0) and the observer's transient is
        longer (K = k1 tanh(k0 e) saturates while |e| is large).
    """

    def __init__(
        self,
        chain: Chain,
        Theta: float,
        k0: float = 1.0,
        k1: float = 1.0,
        p0: float = 0.1,
        p_max: float | None = 1e3,
        estimate: Sequence[str] = ("rho", "ubar"),
        printed_signs: bool = False,
        q_hat0: str = "measured",
    ) -> None:
        if not Theta > 0:
            raise ModelError(f"Theta: must be > 0, got {Theta}")
        if not (k0 > 0 and k1 > 0 and p0 > 0):
            raise ModelError("k0, k1 and p0 must be > 0")
        if p_max is not None and not p_max > 0:
            raise ModelError(f"p_max: must be > 0 (or None), got {p_max}")
        if q_hat0 not in ("measured", "zero"):
            raise ModelError(f"q_hat0: must be 'measured' or 'zero', got {q_hat0!r}")
        self.q_hat0 = q_hat0
        self.est_rho, self.est_ubar = estimate_flags(estimate)
        self.chain = chain
        self.N = chain.n_q
        self.nw = chain.n_wheels
        self.Theta, self.k0, self.k1, self.p0, self.p_max = float(Theta), float(k0), float(k1), float(p0), p_max
        self.p = self.nw * (int(self.est_rho) + int(self.est_ubar))
        self.sign = -1.0 if printed_signs else 1.0
        N, p = self.N, self.p
        self._x = slice(0, 2 * N)
        self._rho = slice(2 * N, 2 * N + p)
        self._Y = slice(self._rho.stop, self._rho.stop + 2 * N * p)
        self._P = slice(self._Y.stop, self._Y.stop + p * p)
        self.n_states = self._P.stop
        I = np.eye(N)
        Z = np.zeros((N, N))
        self.A = np.block([[Z, I], [Z, Z]])
        self.Soinv = np.block([[2 * I, I], [I, I]])  # inverse of S_o = [[I, -I], [-I, 2I]]
        self.AY = self.Theta * (self.A - self.Soinv[:, :N] @ np.eye(N, 2 * N))  # Theta (A - S_o^-1 C^T C)
        self._obs = None  # the kernels' tuple, built on first use

    # ------------------------------------------------------------------ parameters
    def split(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(xhat, rhohat, Y, P) from the observer state."""
        return s[self._x], s[self._rho], s[self._Y].reshape(2 * self.N, self.p), s[self._P].reshape(self.p, self.p)

    def initial_state(self, q0: np.ndarray, qdot0: np.ndarray | None = None) -> np.ndarray:
        """Observer state at t = 0: q_hat(0) per ``q_hat0``, qdot_hat(0) = qdot0 (default 0),
        the parameters at their nominal values (gain 1, friction 0), Y(0) = 0, P(0) = p0 I."""
        s = np.zeros(self.n_states)
        if self.q_hat0 == "measured":
            s[: self.N] = q0
        if qdot0 is not None:
            s[self.N : 2 * self.N] = qdot0
        rho0 = []
        if self.est_rho:
            rho0.append(np.ones(self.nw))
        if self.est_ubar:
            rho0.append(np.zeros(self.nw))
        s[self._rho] = np.concatenate(rho0)
        s[self._P] = (self.p0 * np.eye(self.p)).ravel()
        return s

    def packed(self, tau: float | None = None, est0: int = 0, filt0: int = 0):
        """The observer as the compiled kernels take it (``jit.packed.Obs``).

        ``tau``, ``est0`` and ``filt0`` are the active controller's: its estimate filter's time
        constant (None: unfiltered), where the observer's and the filter's states start in its state.
        """
        from ..jit.packed import Obs

        return Obs(
            self.Theta, self.k0, self.k1, math.nan if self.p_max is None else float(self.p_max), int(self.est_rho),
            int(self.est_ubar), self.p, self.sign, math.nan if tau is None else float(tau),
            np.ascontiguousarray(self.AY), np.ascontiguousarray(self.Soinv), int(est0), self.n_states, int(filt0),
        )  # fmt: skip

    def _O(self):
        if self._obs is None:
            self._obs = self.packed()
        return self._obs

    # ------------------------------------------------------------------ dynamics
    def derivative(self, u: np.ndarray, y: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Observer state derivative, (n_states,), for measured q = y and applied control u: the compiled
        ``farza_derivative``, (4.4)-(4.11) with E15, E16 and the P guard."""
        from .farza_compiled import farza_derivative

        v = (np.ascontiguousarray(x, dtype=float) for x in (u, y, s))
        return farza_derivative(self._O(), self.chain.packed(), *v)

    # ------------------------------------------------------------------ estimator interface
    discrete_time = False  # integrated with the plant (continuous observer)
    scheme = "active"  # the registered scheme an active controller on it is (ftcreport.schemes)

    def parameter_names(self) -> list[str]:
        """Names of the estimated parameters, e.g. ``rho_1r``, ``ubar_2l``."""
        return parameter_names(self.chain.n, self.est_rho, self.est_ubar)
