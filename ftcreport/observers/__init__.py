"""State and fault estimators (pure): Farza et al. (2009) adaptive observer, augmented UKF."""

from .farza import Estimate, FarzaObserver
from .ukf import UKFEstimator

__all__ = ["Estimate", "FarzaObserver", "UKFEstimator"]
