r"""Kinematic and dynamic model of n physically linked 2WD robots.

Thesis chapter 2, sections 2.4.1-2.4.3 and Appendices A-D, with the
corrections of ERRATA E1-E5d.  The arithmetic lives in the compiled kernels
(:mod:`ftcreport.fast.kernels`, through the faces of :mod:`ftcreport.model.kernels`);
:class:`Chain` validates the parameters, precomputes the constant arrays once,
and exposes the stable API::

    chain = Chain(a=[...], b=[...], r=[...], m=[...], I=[...], d=[...])
    chain.S(q); chain.A(q); chain.M(q); chain.C(q, qdot); chain.B(q)
    Mbar1, Mbar2, Cbar, Bbar = chain.reduced(q, eta)
    chain.compensable_patterns()

State conventions: ``q = [x, y, theta_n, ..., theta_1]``, ``eta = [v_n, omega_1]``,
wheels ``1r, 1l, 2r, 2l, ...``; robot 1 (the leader) first in every per-robot
parameter list; ``d[i] = |P_(i+1) P_(i+2)|`` (0-based), i.e. the thesis's d_1..d_(n-1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import ModelError
from . import kernels as K
from .faults import compensable_patterns, is_compensable_at, wheel_names

__all__ = ["THESIS_ROBOT", "Chain"]

#: Per-robot parameters used throughout the thesis (section 3.2.3, from its ref. [34]).
THESIS_ROBOT = {"a": 0.3, "b": 0.75, "r": 0.15, "m": 30.0, "I": 15.625}


def _vector(name: str, values, length: int, *, positive: bool, nonneg: bool = False) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{name}: not a list of numbers ({exc})") from None
    if arr.ndim != 1 or arr.shape[0] != length:
        raise ModelError(f"{name}: expected {length} values, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{name}: values must be finite, got {arr.tolist()}")
    if positive and np.any(arr <= 0):
        bad = int(np.flatnonzero(arr <= 0)[0])
        raise ModelError(f"{name}[{bad}]: must be > 0, got {arr[bad]}")
    if nonneg and np.any(arr < 0):
        bad = int(np.flatnonzero(arr < 0)[0])
        raise ModelError(f"{name}[{bad}]: must be >= 0, got {arr[bad]}")
    return arr


@dataclass(frozen=True, eq=False)
class Chain:
    r"""n >= 2 two-wheel-drive robots linked in a chain.

    Parameters
    ----------
    a : (n,) sequence of float
        Signed distance from the axle midpoint P_i to the centre of mass C_i
        along the heading [m].
    b : (n,) sequence of float
        Half the distance between the two driven wheels [m], > 0.
    r : (n,) sequence of float
        Wheel radius [m], > 0.
    m : (n,) sequence of float
        Mass [kg], > 0.
    I : (n,) sequence of float
        Yaw moment of inertia about C_i [kg m^2], >= 0.
    d : (n - 1,) sequence of float
        Link lengths, ``d[i] = |P_(i+1) P_(i+2)|`` for 0-based i [m], > 0.

    All per-robot lists are leader (robot 1) first.
    """

    a: Sequence[float]
    b: Sequence[float]
    r: Sequence[float]
    m: Sequence[float]
    I: Sequence[float]
    d: Sequence[float]
    params: K.ChainParams = field(init=False, repr=False)  # the kernels' Chain tuple (K.make_params)

    def __post_init__(self) -> None:
        try:
            n = len(self.a)
        except TypeError:
            raise ModelError("a: expected a list of per-robot values") from None
        if n < 2:
            raise ModelError(f"a: a chain needs at least 2 robots, got {n}")
        vals = {
            "a": _vector("a", self.a, n, positive=False),
            "b": _vector("b", self.b, n, positive=True),
            "r": _vector("r", self.r, n, positive=True),
            "m": _vector("m", self.m, n, positive=True),
            "I": _vector("I", self.I, n, positive=False, nonneg=True),
            "d": _vector("d", self.d, n - 1, positive=True),
        }
        for key, arr in vals.items():
            object.__setattr__(self, key, tuple(arr.tolist()))
        object.__setattr__(self, "params", K.make_params(**vals))

    def packed(self):
        """The chain as the compiled kernels take it (``jit.packed.Chain``; built once)."""
        return self.params

    # ------------------------------------------------------------------ build
    @classmethod
    def uniform(cls, n: int, d: float | Sequence[float] = 1.0, **robot: float) -> Chain:
        """n identical robots (thesis values unless overridden) and link length(s) d."""
        if not isinstance(n, int | np.integer) or n < 2:
            raise ModelError(f"n: a chain needs an integer number of robots >= 2, got {n!r}")
        par = {**THESIS_ROBOT, **robot}
        dd = [float(d)] * (n - 1) if np.isscalar(d) else list(d)
        return cls(**{k: [float(v)] * n for k, v in par.items()}, d=dd)

    # -------------------------------------------------------------- geometry
    @property
    def n(self) -> int:
        """Number of robots."""
        return self.params.n

    @property
    def n_q(self) -> int:
        """Length of q, n + 2."""
        return self.params.n + 2

    @property
    def n_wheels(self) -> int:
        """Number of driven wheels, 2 n."""
        return 2 * self.params.n

    @property
    def wheels(self) -> tuple[str, ...]:
        """Wheel names in torque order: ``('1r', '1l', '2r', ...)``."""
        return wheel_names(self.n)

    def q_from_headings(self, x: float, y: float, headings_robot_order: Sequence[float]) -> np.ndarray:
        """Build q from P_n = (x, y) and headings ``[theta_1, ..., theta_n]``."""
        th = np.asarray(headings_robot_order, dtype=float)
        if th.shape != (self.n,):
            raise ModelError(f"headings: expected {self.n} values, got {th.shape}")
        return np.concatenate(([x, y], th[::-1]))

    def headings(self, q: np.ndarray) -> np.ndarray:
        """``[theta_1, ..., theta_n]`` (robot order) from q."""
        return np.asarray(q, dtype=float)[:1:-1].copy()

    def positions(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Axle midpoints P_i and centres of mass C_i, each (n, 2), robot 1 first."""
        return K.positions(self.params, np.asarray(q, dtype=float))

    # ------------------------------------------------------------ kinematics
    def S(self, q: np.ndarray) -> np.ndarray:
        """S(q), (n + 2, 2): qdot = S(q) eta, thesis (2.63)-(2.64)."""
        return K.S_matrix(self.params, np.asarray(q, dtype=float))

    def Sdot(self, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """dS/dt along qdot = S(q) eta, (n + 2, 2)."""
        return K.S_and_Sdot(self.params, np.asarray(q, dtype=float), np.asarray(eta, dtype=float))[1]

    def A(self, q: np.ndarray) -> np.ndarray:
        """Constraint matrix A(q), (n, n + 2): A(q) qdot = 0, thesis (2.61)-(2.62)."""
        return K.A_matrix(self.params, np.asarray(q, dtype=float))

    # --------------------------------------------------------------- dynamics
    def M(self, q: np.ndarray) -> np.ndarray:
        """Inertia matrix M(q), (n + 2, n + 2), Appendix D (D.5), ERRATA E5a."""
        return K.M_matrix(self.params, np.asarray(q, dtype=float))

    def C(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """Centripetal/Coriolis vector C(q, qdot) = Mdot qdot - dT/dq, (n + 2,), (D.9)."""
        return K.C_vector(self.params, np.asarray(q, dtype=float), np.asarray(qdot, dtype=float))

    def B(self, q: np.ndarray) -> np.ndarray:
        """Input matrix B(q), (n + 2, 2 n), wheels 1r, 1l, ..., Appendix C (C.8)."""
        return K.B_matrix(self.params, np.asarray(q, dtype=float))

    def reduced(self, q: np.ndarray, eta: np.ndarray):
        """``(Mbar1, Mbar2, Cbar, Bbar)`` of the reduced model, thesis (2.70)-(2.74)."""
        return K.reduced(self.params, np.asarray(q, dtype=float), np.asarray(eta, dtype=float))

    def dynamics(self, q: np.ndarray, eta: np.ndarray, tau: np.ndarray):
        """``(qdot, etadot)`` of the reduced model under wheel torques tau (2n,)."""
        return K.eta_dot(
            self.params, np.asarray(q, dtype=float), np.asarray(eta, dtype=float), np.asarray(tau, dtype=float)
        )

    def kinetic_energy(self, q: np.ndarray, eta: np.ndarray) -> float:
        """T = 1/2 qdot^T M qdot with qdot = S eta (equals 1/2 eta^T Mbar1 eta)."""
        qdot = self.S(q) @ np.asarray(eta, dtype=float)
        return 0.5 * float(qdot @ self.M(q) @ qdot)

    def wheel_speeds(self, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """Wheel angular velocities (2n,), wheel order; tau . wheel_speeds is the input power."""
        return K.wheel_speeds(self.params, np.asarray(q, dtype=float), np.asarray(eta, dtype=float))

    # ------------------------------------------------------------ redundancy
    def compensable_patterns(self) -> list[tuple[int, ...]]:
        """All 0/1 failure patterns satisfying rank(Bbar sigma) = 2 generically.

        See :func:`ftcreport.model.faults.compensable_patterns` for the rule.
        """
        return compensable_patterns(self.n)

    def is_compensable_at(self, sigma: Sequence[float], q: np.ndarray, tol: float = 1e-9) -> bool:
        """Numerical check of rank(Bbar(q) diag(sigma)) = 2 at one pose (2.103)."""
        Bbar = self.S(q).T @ self.B(q)
        return is_compensable_at(Bbar, sigma, tol)
