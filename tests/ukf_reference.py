"""The filterpy UKF step: the reference the compiled step (ftcreport.observers.ukf_compiled.ukf_step) is tested against.

It was ``UKFEstimator.step`` while the Python loop ran the filter; the package now runs only the
compiled step, so filterpy's lives here (tests/test_ukf_compiled.py, benchmarks/ukf_step.py).
Same filter as :class:`ftcreport.observers.UKFEstimator` describes: Merwe scaled sigma points,
process model one midpoint step per sigma point with u held (the compiled
``fast.kernels.midpoint_sigmas``, all points in one call), Q = Qc h, measurement y = q,
P symmetrised after the update.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from ftcreport.fast import kernels as F
from ftcreport.observers import UKFEstimator


class _BatchUKF(UnscentedKalmanFilter):
    """filterpy's UKF with the process model applied to all sigma points in one call."""

    batch_fx = None

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        if fx is not None or self.batch_fx is None:
            return super().compute_process_sigmas(dt, fx, **fx_args)
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f[:] = self.batch_fx(sigmas, dt, **fx_args)
        return None


class FilterpyUKF:
    """filterpy's predict/update on the state layout and tuning of a :class:`UKFEstimator`."""

    def __init__(self, est: UKFEstimator) -> None:
        self.est = est
        self._pc = F.Chain(*est.chain.params)
        pts = est.points
        points = MerweScaledSigmaPoints(est.nx, alpha=pts.alpha, beta=pts.beta, kappa=pts.kappa)
        self._ukf = _BatchUKF(dim_x=est.nx, dim_z=est.N, dt=0.01, fx=self._fx, hx=self._hx, points=points)
        self._ukf.batch_fx = self._fx_batch
        self._ukf.R = est.R

    def _fx_batch(self, sigmas: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        est = self.est
        u = np.asarray(u, float)
        return F.midpoint_sigmas(self._pc, np.ascontiguousarray(sigmas), u, float(dt), est.est_rho, est.est_ubar)

    def _fx(self, x: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        return self._fx_batch(x[None, :], dt, u)[0]

    def _hx(self, x: np.ndarray) -> np.ndarray:
        return x[: self.est.N]

    def step(self, s: np.ndarray, u: np.ndarray, y: np.ndarray, h: float) -> np.ndarray:
        """Predict over h with u held, then update with the measurement y = q."""
        ukf = self._ukf
        ukf.x, ukf.P = self.est.unpack(s)
        ukf.x = ukf.x.copy()
        ukf.P = ukf.P.copy()
        ukf.Q = self.est.Qc * h
        ukf.predict(dt=h, u=np.asarray(u, dtype=float))
        ukf.update(np.asarray(y, dtype=float))
        P = 0.5 * (ukf.P + ukf.P.T)
        return self.est.pack(ukf.x, P)
