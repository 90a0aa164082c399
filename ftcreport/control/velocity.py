r"""Nominal computed-torque velocity controller (healthy wheels, no FTC).

Tracks a velocity command eta_c(t) = [v_nc, omega_1c] with the reduced model
(2.70) assuming every wheel healthy (sigma = I, ubar = 0)::

    etadot_des = etadot_c - k (eta - eta_c)
    u = Bbar^+ (Mbar1 etadot_des + Mbar2 eta + Cbar)

Bbar^+ = Bbar^T (Bbar Bbar^T)^-1 is the minimum-norm right inverse; it equals
(Mbar1^-1 Bbar)^+ Mbar1 because both matrices have the same row space, so this
is the healthy instance of the thesis's dynamic law (3.35).  With a matched
model and healthy wheels the velocity error obeys e' = -k e exactly.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import ModelError
from ..model import kernels as K
from ..model.chain import Chain

__all__ = ["VelocityController", "constant_command", "healthy_torque"]

Command = Callable[[float], tuple[np.ndarray, np.ndarray]]


def constant_command(v_n: float, omega_1: float) -> Command:
    """eta_c(t) = [v_n, omega_1], etadot_c = 0."""
    eta_c = np.array([float(v_n), float(omega_1)])
    zero = np.zeros(2)

    def command(t: float) -> tuple[np.ndarray, np.ndarray]:
        return eta_c, zero

    return command


def healthy_torque(p: K.ChainParams, q: np.ndarray, eta: np.ndarray, etadot_des: np.ndarray) -> np.ndarray:
    """Minimum-norm torques realising etadot_des with healthy wheels, (2n,)."""
    Mbar1, Mbar2, Cbar, Bbar = K.reduced(p, q, eta)
    w = Mbar1 @ etadot_des + Mbar2 @ eta + Cbar
    # u = Bbar^T (Bbar Bbar^T)^-1 w
    return Bbar.T @ np.linalg.solve(Bbar @ Bbar.T, w)


class VelocityController:
    """Computed-torque tracking of a velocity command (no internal state).

    Parameters
    ----------
    chain : Chain
        The controller's model of the chain (may differ from the plant's).
    command : callable
        ``command(t) -> (eta_c (2,), etadot_c (2,))``.
    k : float
        Velocity-error gain [1/s], > 0.
    """

    n_states = 0
    signal_names = ("eta_c",)

    def __init__(self, chain: Chain, command: Command, k: float = 5.0) -> None:
        if not k > 0:
            raise ModelError(f"k: velocity gain must be > 0, got {k}")
        self.chain = chain
        self.command = command
        self.k = float(k)
        self._empty = np.zeros(0)

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        return self._empty

    def evaluate(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray):
        eta_c, etadot_c = self.command(t)
        # etadot_des = etadot_c - k (eta - eta_c)
        etadot_des = etadot_c - self.k * (eta - eta_c)
        return healthy_torque(self.chain.params, q, eta, etadot_des), self._empty

    def discrete(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        return xc

    def signals(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> dict[str, np.ndarray]:
        return {"eta_c": self.command(t)[0]}
