"""The loop's Jacobians at one operating point and the matrices built from them (pure: numpy only).

Split from :mod:`.closed_loop` (which computes them from a case's scheme) so that the numeric part of
the analysis (:mod:`.sampled`, :mod:`.limits`, :mod:`.margins`) imports no case, runner or engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Blocks"]


@dataclass
class Blocks:
    r"""The loop's Jacobians at one point (see the module docstring for the names).

    Fx, Fa : plant, d f_p / d x_p and d f_p / d a.  Gx, Gy, Gc : the controller's outputs
    ``[a, c']`` against the true plant state (the oracle's true faults only), the measurement
    ``y = [q, eta]`` and its linearized states c; ``na`` rows of a first.  Dc, Dy : the discrete
    update ``c <- Dc c + Dy y`` at each sample (identity and 0 when the scheme has none to linearize).
    ``kept`` : the indices of xc that c holds; ``dropped`` : how many scheme states were left out as
    decoupled (:func:`relevant_states`), ``parameter_block`` : the size of the block replaced by its
    image in the actuator space (:func:`_parameter_block`), 0 if none.

    ``basis``: the parameter block's orthonormal basis in the actuator space (to linearize the same
    loop at another gain in the same coordinates).

    ``internal`` and ``internal_map``: the left-out states' own Jacobians, their rates against
    themselves (``Gc_c`` restricted to them) and their discrete update (``Dc`` restricted; None for the
    identity).  Left out because the plant cannot reach them or they cannot reach the plant, they sit
    in a diagonal block of their own: the loop's poles do not contain theirs, but the whole loop is
    bounded only if they are stable too (internal stability).  A sampled controller steps them by
    forward Euler, so a stable filter ``c' = -gamma c + ...`` (the switching bank's) is unstable
    beyond ``gamma T = 2`` whatever the tracking does (:meth:`internal_measure`).

    ``omega`` and ``frame``: the reference's turning rate and the index pairs (in ``[x_p, c]``) of the
    vectors written in the world frame (the position of P_n, an observer's estimate of it and of its
    velocity).  The loop is linearized about a moving reference; in world coordinates the frozen
    Jacobian misses the turning of the reference's frame, and its eigenvalues are off by about omega
    (0.013 1/s on the slowest pole of two_link_switching, omega = 0.1 rad/s).  In the frame turning
    with the reference, ``e = R(theta_d)^T dx``, ``e' = (R^T A R - omega J) e`` (J the 90 deg rotation): on
    a constant-curvature reference the error dynamics are then autonomous and these are their exact
    poles (equal to the two-link error Jacobian's, :func:`~ftcreport.analysis.classic.two_link_error_jacobian`,
    tests/test_linear_loop.py); on any other reference they are the frozen poles in that frame.
    """

    Fx: np.ndarray
    Fa: np.ndarray
    Gx: np.ndarray
    Gy: np.ndarray
    Gc: np.ndarray
    Dc: np.ndarray
    Dy: np.ndarray
    na: int
    kept: list = field(default_factory=list)
    dropped: int = 0
    parameter_block: int = 0
    omega: float = 0.0
    frame: list = field(default_factory=list)
    basis: np.ndarray | None = None
    internal: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    internal_map: np.ndarray | None = None
    _internal_eig: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def nc(self) -> int:
        return self.Gc.shape[1]

    def continuous(self) -> np.ndarray:
        r"""A of ``x' = A x``, x = [x_p, c], for control at every instant (y = [q, eta] = C x_p)::

        A = [[Fx + Fa (Gx_a + Gy_a C), Fa Gc_a],
             [Gx_c + Gy_c C,           Gc_c  ]]
        """
        mp, ny, na = self.Fx.shape[0], self.Gy.shape[1], self.na
        Cy = np.eye(ny, mp)
        Ka = self.Gx[:na] + self.Gy[:na] @ Cy
        top = np.hstack((self.Fx + self.Fa @ Ka, self.Fa @ self.Gc[:na]))
        bottom = np.hstack((self.Gx[na:] + self.Gy[na:] @ Cy, self.Gc[na:]))
        return self.co_moving(np.vstack((top, bottom)))

    def co_moving(self, A: np.ndarray) -> np.ndarray:
        """A - omega J on the world-frame vectors: the Jacobian in the frame turning with the reference."""
        A = A.copy()
        for i, j in self.frame:
            A[i, j] += self.omega  # (-omega J)[0, 1] = +omega
            A[j, i] -= self.omega
        return A

    def plant_co_moving(self) -> np.ndarray:
        """Fx - omega J on the plant's world-frame vectors: the plant alone in the frame turning with the
        reference (what the plant's ZOH over a sample is taken of, :func:`~ftcreport.analysis.sampled.plant_zoh`)."""
        mp = self.Fx.shape[0]
        A = self.Fx.copy()
        for i, j in self.frame:
            if i < mp and j < mp:
                A[i, j] += self.omega
                A[j, i] -= self.omega
        return A

    def velocity_loop(self) -> Blocks:
        """The inner loop alone: the same blocks with the configuration q held (its rows and columns out).

        What is left is eta (and the currents and the drive with motors) with the scheme's states: the
        loop the velocity gain and the sample time act on.  The outer (kinematic) loop's coupling through
        q is cut, so on the ideal plant at rest, under the matched law, its sampled limit is exactly
        T = 2 / k_v (:mod:`ftcreport.analysis.limits`).
        """
        mp, nq = self.Fx.shape[0], self.Gy.shape[1] - 2
        keep = np.arange(nq, mp)
        frame = [(i - nq, j - nq) for i, j in self.frame if i >= mp]
        return Blocks(
            self.Fx[np.ix_(keep, keep)], self.Fa[keep], self.Gx[:, keep], self.Gy[:, nq:], self.Gc, self.Dc,
            self.Dy[:, nq:], self.na, self.kept, self.dropped, self.parameter_block, self.omega, frame,
            internal=self.internal, internal_map=self.internal_map,
        )  # fmt: skip

    def internal_modes(self, T: float | None = None) -> np.ndarray:
        """The left-out states' own modes that move: eigenvalues of ``internal`` (continuous, T None) or of
        their sampled map ``(I + T internal) internal_map`` (forward Euler, then the discrete update, as
        :func:`~ftcreport.analysis.sampled.parts` steps them).

        States that do not move at the point (a weight combination the torque does not see, an estimate
        the measurement does not reach: zero rates) are constants, not modes: an eigenvalue within 1e-12
        (relative) of 0 (continuous) or of 1 (discrete) is left out, so that they do not make every loop
        marginal.
        """
        G = self.internal
        if not G.size:
            return np.zeros(0, dtype=complex)
        if T is not None and self.internal_map is not None:
            ev = np.linalg.eigvals((np.eye(len(G)) + float(T) * G) @ self.internal_map)
            return ev[np.abs(ev - 1.0) > 1e-12]
        if self._internal_eig is None:
            lam = np.linalg.eigvals(G)
            self._internal_eig = lam[np.abs(lam) > 1e-12 * max(1.0, float(np.abs(lam).max(initial=0.0)))]
        lam = self._internal_eig
        return lam if T is None else 1.0 + float(T) * lam

    def internal_measure(self, T: float | None = None) -> float:
        """The left-out states' largest |z| over a sample of T, or their largest real part (T None);
        0 and -inf when none of them moves."""
        ev = self.internal_modes(T)
        if not ev.size:
            return 0.0 if T is not None else -np.inf
        return float(np.abs(ev).max()) if T is not None else float(ev.real.max())

    def feedback(self) -> tuple[np.ndarray, np.ndarray]:
        """(B, K) with ``A = A_0 + B K`` and ``a = K x``: the actuator inputs, for margins (continuous)."""
        mp, ny, na, nc = self.Fx.shape[0], self.Gy.shape[1], self.na, self.nc
        B = np.vstack((self.Fa, np.zeros((nc, na))))
        K = np.hstack((self.Gx[:na] + self.Gy[:na] @ np.eye(ny, mp), self.Gc[:na]))
        return B, K
