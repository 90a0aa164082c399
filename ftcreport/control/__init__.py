"""Controllers: the built-in schemes' laws, read by the compiled engine (ftcreport.fast.engine.compiled_spec)."""

from .kinematic import ChainedBackstepping, KinematicOutput, TwoLinkKinematic
from .tracking import TrackingController

__all__ = [
    "ChainedBackstepping",
    "KinematicOutput",
    "TrackingController",
    "TwoLinkKinematic",
]
