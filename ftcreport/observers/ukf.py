r"""Augmented-state unscented Kalman filter (filterpy) estimating [q, eta, rho, ubar] from measured q.

The alternative to the Farza observer (issue 6), with the same interface
(:meth:`UKFEstimator.estimates`, :meth:`UKFEstimator.parameter_names`).  It is a
discrete-time filter run at the control sampling instants:

* process model over one sample of length h, the applied control u held (ZOH)::

      q' = S(q) eta,   Mbar1 eta' = -Mbar2 eta - Cbar + Bbar (diag(rho) u + ubar)   (2.70), (2.102)
      rho' = w_rho,    ubar' = w_ubar                                               (random walks)

  integrated with one midpoint (RK2) step per sigma point;
* measurement ``y = q + v`` (only q is measured, thesis chapter 4).

Process noise is given as continuous-time intensities (per second) and scaled
by h, so the filter's tuning does not depend on the sampling period.  The
random-walk intensity of the parameters sets the trade-off between tracking a
fault change quickly and the estimates' variance under sensor noise; it plays
the role of the Farza observer's Theta and P guard.

The filter's state (x, P) is carried in a flat array so the controller's state
remains the whole truth (restartable, logged).  The step exists once, compiled
(:func:`ftcreport.observers.ukf_compiled.ukf_step`, Merwe scaled sigma points with filterpy's
order of operations); :class:`UKFEstimator` checks and holds the tuning (Qc, R,
P(0), the sigma-point parameters) and lays out the state.  The filterpy filter
the compiled step is tested against is tests/ukf_reference.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..errors import ModelError
from ..model.chain import Chain
from .farza import Estimate, estimate_flags, parameter_names

__all__ = ["SigmaPoints", "UKFEstimator"]


class SigmaPoints(NamedTuple):
    """Merwe scaled sigma points' parameters (Wan & van der Merwe 2000); ukf_compiled.merwe_weights: the weights."""

    alpha: float
    beta: float
    kappa: float


class UKFEstimator:
    """Unscented Kalman filter on the augmented state [q, eta, rho, ubar].

    Parameters
    ----------
    chain : Chain
        The filter's model.
    meas_std : float or (n + 2,) array
        Standard deviation of the measured q [m, m, rad, ...] (R).
    q_noise, eta_noise : float
        Process-noise intensities of q [m^2/s] and eta [(m/s)^2/s] (model error).
    rho_noise, ubar_noise : float
        Random-walk intensities of the gains [1/s] and frictions [(N m)^2/s].
    rho_std0, ubar_std0, eta_std0 : float
        Initial standard deviations (P(0) diagonal) of gains, frictions [N m], eta.
    estimate : sequence of str
        Any of ``"rho"``, ``"ubar"`` (as the Farza observer).
    alpha, beta, kappa : float
        Merwe scaled sigma points (kappa = 3 - dim when None).
    """

    discrete_time = True
    scheme = "active_ukf"  # the registered scheme an active controller on it is (ftcreport.schemes)

    def __init__(
        self,
        chain: Chain,
        meas_std: float | Sequence[float] = 1e-3,
        q_noise: float = 1e-8,
        eta_noise: float = 1e-4,
        rho_noise: float = 1e-2,
        ubar_noise: float = 1e-2,
        rho_std0: float = 0.3,
        ubar_std0: float = 0.5,
        eta_std0: float = 0.5,
        estimate: Sequence[str] = ("rho", "ubar"),
        alpha: float = 0.5,
        beta: float = 2.0,
        kappa: float | None = None,
    ) -> None:
        self.est_rho, self.est_ubar = estimate_flags(estimate)
        R = np.broadcast_to(np.asarray(meas_std, dtype=float), (chain.n_q,))
        values = [q_noise, eta_noise, rho_noise, ubar_noise, rho_std0, ubar_std0, eta_std0]
        if np.any(R <= 0) or min(values) < 0 or not np.all(np.isfinite(values)):
            raise ModelError("UKF: meas_std must be > 0 and the noise intensities >= 0")
        self.chain = chain
        self.N = chain.n_q
        self.nw = chain.n_wheels
        self.p = self.nw * (int(self.est_rho) + int(self.est_ubar))
        self.nx = self.N + 2 + self.p
        self.n_states = self.nx + self.nx * self.nx
        N, nw = self.N, self.nw
        qc = [q_noise] * N + [eta_noise] * 2
        pc = [rho_noise] * (nw if self.est_rho else 0) + [ubar_noise] * (nw if self.est_ubar else 0)
        self.Qc = np.diag(qc + pc)
        p0 = [1e-6] * N + [eta_std0**2] * 2
        p0 += [rho_std0**2] * (nw if self.est_rho else 0) + [ubar_std0**2] * (nw if self.est_ubar else 0)
        self.P0 = np.diag(p0)
        self.points = SigmaPoints(alpha, beta, (3.0 - self.nx) if kappa is None else kappa)
        self.R = np.diag(R**2)  # measurement covariance

    def _split_params(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nw, k = self.nw, self.N + 2
        rho = x[k : k + nw] if self.est_rho else np.ones(nw)
        k += nw if self.est_rho else 0
        ubar = x[k : k + nw] if self.est_ubar else np.zeros(nw)
        return rho, ubar

    # ------------------------------------------------------------------ state
    def parameter_names(self) -> list[str]:
        """Names of the estimated parameters, e.g. ``rho_1r``, ``ubar_2l``."""
        return parameter_names(self.chain.n, self.est_rho, self.est_ubar)

    def pack(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        return np.concatenate((x, P.ravel()))

    def unpack(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return s[: self.nx], s[self.nx :].reshape(self.nx, self.nx)

    def initial_state(self, q0: np.ndarray, eta0: np.ndarray | None = None) -> np.ndarray:
        """x(0) = [q0, eta0 (default 0), healthy parameters], P(0) = diag of the initial deviations."""
        x = np.zeros(self.nx)
        x[: self.N] = q0
        if eta0 is not None:
            x[self.N : self.N + 2] = eta0
        if self.est_rho:
            x[self.N + 2 : self.N + 2 + self.nw] = 1.0
        return self.pack(x, self.P0.copy())

    def estimates(self, s: np.ndarray, y: np.ndarray) -> Estimate:
        x, _ = self.unpack(s)
        rho, ubar = self._split_params(x)
        return Estimate(x[: self.N], x[self.N : self.N + 2], rho.copy(), ubar.copy())
