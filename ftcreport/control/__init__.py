"""Controllers: objects with explicit internal state (see ftcreport.sim.Controller)."""

from .velocity import VelocityController, constant_command

__all__ = ["VelocityController", "constant_command"]
