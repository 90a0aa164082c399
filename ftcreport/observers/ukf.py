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
remains the whole truth (restartable, logged); the filterpy object is only a
workspace.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import ModelError
from ..model import kernels as K
from ..model.chain import Chain
from ..model.faults import wheel_names
from .farza import Estimate

__all__ = ["UKFEstimator"]


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
        unknown = set(estimate) - {"rho", "ubar"}
        if unknown or not estimate:
            raise ModelError(f"estimate: choose among 'rho', 'ubar', got {list(estimate)}")
        R = np.broadcast_to(np.asarray(meas_std, dtype=float), (chain.n_q,))
        values = [q_noise, eta_noise, rho_noise, ubar_noise, rho_std0, ubar_std0, eta_std0]
        if np.any(R <= 0) or min(values) < 0 or not np.all(np.isfinite(values)):
            raise ModelError("UKF: meas_std must be > 0 and the noise intensities >= 0")
        self.chain = chain
        self._fast_chain = None
        self.N = chain.n_q
        self.nw = chain.n_wheels
        self.est_rho = "rho" in estimate
        self.est_ubar = "ubar" in estimate
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
        # filterpy (and the scipy.stats it pulls, ~65 MB) only where a UKF is built: the compiled
        # engine runs its own step (fast/ukf.py); this object is the reference of tests/test_ukf_compiled.py
        from filterpy.kalman import MerweScaledSigmaPoints

        points = MerweScaledSigmaPoints(
            self.nx, alpha=alpha, beta=beta, kappa=(3.0 - self.nx) if kappa is None else kappa
        )
        self.points = points  # alpha, beta, kappa and the weights Wm, Wc (fast/ukf.py reads them)
        self.R = np.diag(R**2)  # measurement covariance
        self._ukf = _batch_ukf_class()(dim_x=self.nx, dim_z=N, dt=0.01, fx=self._fx, hx=self._hx, points=points)
        self._ukf.batch_fx = self._fx_batch
        self._ukf.R = self.R

    # ------------------------------------------------------------------ model
    def _split_params(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nw, k = self.nw, self.N + 2
        rho = x[k : k + nw] if self.est_rho else np.ones(nw)
        k += nw if self.est_rho else 0
        ubar = x[k : k + nw] if self.est_ubar else np.zeros(nw)
        return rho, ubar

    def _fx(self, x: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        """One midpoint step of the process model with u held."""
        p, N = self.chain.params, self.N
        rho, ubar = self._split_params(x)
        tau = rho * u + ubar
        q, eta = x[:N], x[N : N + 2]
        qd1, ed1 = K.eta_dot(p, q, eta, tau)
        qd2, ed2 = K.eta_dot(p, q + 0.5 * dt * qd1, eta + 0.5 * dt * ed1, tau)
        out = x.copy()
        out[:N] = q + dt * qd2
        out[N : N + 2] = eta + dt * ed2
        return out

    def _fx_batch(self, sigmas: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        """_fx on every sigma point at once, by the compiled kernel (same midpoint step)."""
        from ..fast import kernels as F

        if self._fast_chain is None:
            self._fast_chain = F.Chain(*self.chain.params)
        return F.midpoint_sigmas(
            self._fast_chain, np.ascontiguousarray(sigmas), np.asarray(u, float), float(dt), self.est_rho, self.est_ubar
        )

    def _hx(self, x: np.ndarray) -> np.ndarray:
        return x[: self.N]

    # ------------------------------------------------------------------ state
    def parameter_names(self) -> list[str]:
        wheels = wheel_names(self.chain.n)
        return [f"rho_{w}" for w in wheels if self.est_rho] + [f"ubar_{w}" for w in wheels if self.est_ubar]

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

    def step(self, s: np.ndarray, u: np.ndarray, y: np.ndarray, h: float) -> np.ndarray:
        """Predict over h with u held, then update with the measurement y = q."""
        ukf = self._ukf
        ukf.x, ukf.P = self.unpack(s)
        ukf.x = ukf.x.copy()
        ukf.P = ukf.P.copy()
        ukf.Q = self.Qc * h
        ukf.predict(dt=h, u=np.asarray(u, dtype=float))
        ukf.update(np.asarray(y, dtype=float))
        P = 0.5 * (ukf.P + ukf.P.T)
        return self.pack(ukf.x, P)

    def estimates(self, s: np.ndarray, y: np.ndarray) -> Estimate:
        x, _ = self.unpack(s)
        rho, ubar = self._split_params(x)
        return Estimate(x[: self.N], x[self.N : self.N + 2], rho.copy(), ubar.copy())


_BatchUKF = None


def _batch_ukf_class():
    """filterpy's UKF with the process model applied to all sigma points in one call (built on first use)."""
    global _BatchUKF
    if _BatchUKF is not None:
        return _BatchUKF
    from filterpy.kalman import UnscentedKalmanFilter

    class BatchUKF(UnscentedKalmanFilter):
        """filterpy's UKF with the process model applied to all sigma points in one call."""

        batch_fx = None

        def compute_process_sigmas(self, dt, fx=None, **fx_args):
            if fx is not None or self.batch_fx is None:
                return super().compute_process_sigmas(dt, fx, **fx_args)
            sigmas = self.points_fn.sigma_points(self.x, self.P)
            self.sigmas_f[:] = self.batch_fx(sigmas, dt, **fx_args)
            return None

    _BatchUKF = BatchUKF
    return BatchUKF
