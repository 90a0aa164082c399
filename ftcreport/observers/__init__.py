"""State and fault estimators (pure): Farza et al. (2009) adaptive observer, augmented UKF.

The UKF module is imported on first use: it pulls filterpy and with it
scipy.stats (about 65 MB resident), which a run without the UKF never needs.
"""

from typing import TYPE_CHECKING

from .farza import Estimate, FarzaObserver

if TYPE_CHECKING:
    from .ukf import UKFEstimator

__all__ = ["Estimate", "FarzaObserver", "UKFEstimator"]


def __getattr__(name: str):
    if name == "UKFEstimator":
        from .ukf import UKFEstimator

        return UKFEstimator
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
