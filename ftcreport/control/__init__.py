"""Controllers: objects with explicit internal state (see ftcreport.sim.Controller)."""

from .kinematic import ChainedBackstepping, KinematicOutput, TwoLinkKinematic
from .tracking import TrackingController, dynamic_law
from .velocity import VelocityController, constant_command

__all__ = [
    "ChainedBackstepping",
    "KinematicOutput",
    "TrackingController",
    "TwoLinkKinematic",
    "VelocityController",
    "constant_command",
    "dynamic_law",
]
