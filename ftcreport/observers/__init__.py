"""State and fault estimators (pure): Farza et al. (2009) adaptive observer."""

from .farza import FarzaObserver

__all__ = ["FarzaObserver"]
