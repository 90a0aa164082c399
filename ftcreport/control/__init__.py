"""Controllers: the built-in schemes' laws, read by the compiled engine (ftcreport.fast.engine.compiled_spec)."""

from .kinematic import ChainedBackstepping, KinematicOutput, TwoLinkKinematic
from .tracking import TrackingController, dynamic_law

__all__ = [
    "ChainedBackstepping",
    "KinematicOutput",
    "TrackingController",
    "TwoLinkKinematic",
    "dynamic_law",
]
