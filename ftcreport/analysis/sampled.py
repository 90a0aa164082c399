r"""The loop in discrete time, as a sampled controller runs it: ZOH, delay, held command (pure: no I/O).

With ``simulation.sample_time = T`` the engine (``fast.loop.sample``) runs the controller at
``t_j = j T``: the scheme's states take a forward-Euler step of the rates held since the last sample,
its discrete update runs, then the law on the measurement taken ``d`` samples before
(``simulation.measurement_delay``); the command (with motors: the driver's voltages, computed at the
sample from the measured wheel speeds) is held until the next sample while the plant runs on.
Linearized about a frozen operating point (:class:`~ftcreport.analysis.closed_loop.Blocks`), with
``y = [q, eta] = C x_p``::

    x_p(j+1)  = Phi x_p(j) + Gamma a(j)                          (ZOH of the plant: exact for a held a)
    b_1(j+1)  = C x_p(j),  b_k(j+1) = b_(k-1)(j)                 (the delay line, d blocks of y)
    yhat(j)   = b_d(j)  (d > 0),   C x_p(j)  (d = 0)
    c(j)      = Dc c^-(j) + Dy yhat(j)                           (the discrete update, identity if none)
    a(j)      = Gx_a x_p(j) + Gy_a yhat(j) + Gc_a c(j)
    c^-(j+1)  = c(j) + T (Gx_c x_p(j) + Gy_c yhat(j) + Gc_c c(j)) (forward Euler, as the engine)

``[Phi, Gamma] = [I, 0] expm([[A_p, B_p], [0, 0]] T)`` is the ZOH of the plant with a held, taken in
the frame turning with the reference (:func:`plant_zoh`: ``A_p = Fx - omega J``, the plant's part of
:meth:`Blocks.co_moving`).  On a moving reference the plant's Jacobian in world coordinates turns with
the reference within the sample (the direction of travel, d(S(q) eta)/d theta); in the turning frame
it is constant on a constant-curvature reference, so this ZOH is exact there.  Freezing the world-frame
Jacobian over the sample and turning its result by -omega T afterwards (the model before
2026-11-27) is not: it errs by about omega T |A_p| T / 2 in Phi, and on the two-link circle
(omega = 0.5 rad/s) it put the slow kinematic pair's crossing at 292 ms where the engine's runs,
converged in their step, cross between 204 and 262 ms (now 236 ms; tests/test_sampled_loop.py).
``control.sample_system(ss(A_p, B_p, I, 0), T, 'zoh')`` computes exactly this (scipy's
``cont2discrete``, the same matrix exponential).  :func:`zoh` gets it instead from the engine's own
phi function, ``Phi = I + A T phi_1(A T)``, ``Gamma = T phi_1(A T) B`` (``fast.expo.phi12``, the
function the ETD2 integrator steps a held voltage with), for speed: the limits' searches need about
a hundred discretizations per scheme, and scipy's expm (through its threaded BLAS) took 21 ms for a
10 x 10 matrix on the shared 2-core machine against 20 us; tests/test_sampled_loop.py checks the two
against each other to 1e-12 and against scipy's ``expm`` of the augmented matrix of an independent
derivation.  What python-control cannot do for us is the rest: its ``feedback`` of two sampled
systems assumes the controller's output acts in the same sample it reads its input, with the
controller's states discretized like the plant's; here the command is computed from the (delayed)
measurement and held, the scheme's states advance by forward Euler, and with motors the voltage the
driver holds contains the back-EMF compensation of the measured speed at the sample
(``k_b N omega_w(t_j)``) while the true back-EMF moves within the sample.  That last term is what
makes the motor loop's limit differ from the ideal plant's: the held voltage drives a current that
the growing back-EMF and the winding's own L_a / R_a shape within the sample, which the ZOH of the
[eta, i_a] block captures exactly.  So the closed loop is assembled here from the sampled plant and the controller's
Jacobians, and tests/test_sampled_loop.py checks the motor plant's ZOH against an independent
derivation to 1e-10.
"""

from __future__ import annotations

import math

import numpy as np

from .blocks import Blocks

__all__ = ["closed_loop_matrix", "open_loop_at_input", "parts", "plant_zoh", "spectral_radius", "zoh"]


def zoh(A: np.ndarray, B: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma): the exact discretization of x' = A x + B a with a held over T (module docstring).

    ``Phi = e^(A T) = I + A T phi_1(A T)``, ``Gamma = T phi_1(A T) B``, phi_1 from ``fast.expo.phi12``.
    """
    from ..fast.expo import phi12

    n = A.shape[0]
    if n == 0:
        return np.zeros((0, 0)), np.zeros((0, B.shape[1]))
    P1 = phi12(np.ascontiguousarray(A * float(T)))[0]
    return np.eye(n) + (A * float(T)) @ P1, float(T) * (P1 @ B)


def plant_zoh(blk: Blocks, T: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma) of the plant over one sample in the frame turning with the reference (module docstring):
    the ZOH of ``Fx - omega J`` (:meth:`Blocks.plant_co_moving`); the plain :func:`zoh` when it does not turn."""
    return zoh(blk.plant_co_moving(), blk.Fa, T)


def closed_loop_matrix(blk: Blocks, T: float, delay: int = 0, plant: tuple | None = None) -> np.ndarray:
    r"""The sampled loop's matrix M: ``z(j+1) = M z(j)``, ``z = [x_p, b_1..b_d, c^-]`` (module docstring).

    ``plant``: (Phi, Gamma) when already computed for this T (:func:`plant_zoh`).
    """
    M0, Bz, Ka = parts(blk, T, delay, plant)
    return M0 + Bz @ Ka


def parts(blk: Blocks, T: float, delay: int = 0, plant: tuple | None = None):
    """(M0, B, K) of the sampled loop: ``M = M0 + B K`` with ``a(j) = K z(j)`` the held actuator signals.

    M0 is the loop with every actuator input open (the plant's free motion, the delay line, the
    controller's own states); B the held inputs' columns (Gamma in the plant's rows).
    """
    Phi, Gam = plant_zoh(blk, T) if plant is None else plant
    mp, ny, na, nc = blk.Fx.shape[0], blk.Gy.shape[1], blk.na, blk.nc
    nb = delay * ny
    nz = mp + nb + nc
    Cy = np.eye(ny, mp)
    Sy = np.zeros((ny, nz))  # yhat = Sy z
    if delay:
        Sy[:, mp + nb - ny : mp + nb] = np.eye(ny)
    else:
        Sy[:, :mp] = Cy
    Sx = np.eye(mp, nz)
    Sc = np.zeros((nc, nz))
    Sc[:, mp + nb :] = np.eye(nc)
    c_of_z = blk.Dc @ Sc + blk.Dy @ Sy  # c(j) after the discrete update
    Ka = blk.Gx[:na] @ Sx + blk.Gy[:na] @ Sy + blk.Gc[:na] @ c_of_z  # a(j) = Ka z(j)
    M0 = np.zeros((nz, nz))
    M0[:mp, :mp] = Phi
    if delay:
        M0[mp : mp + ny, :mp] = Cy
        for k in range(1, delay):
            M0[mp + k * ny : mp + (k + 1) * ny, mp + (k - 1) * ny : mp + k * ny] = np.eye(ny)
    rates = blk.Gx[na:] @ Sx + blk.Gy[na:] @ Sy + blk.Gc[na:] @ c_of_z
    M0[mp + nb :, :] = c_of_z + T * rates
    Bz = np.zeros((nz, na))
    Bz[:mp] = Gam
    _turn(M0, Bz, blk, T, delay)
    return M0, Bz, Ka


def _turn(M0: np.ndarray, Bz: np.ndarray, blk: Blocks, T: float, delay: int) -> None:
    """The co-moving frame in discrete time: the held parts' world-frame vectors turned by -omega T.

    The continuous loop subtracts omega J (:meth:`Blocks.co_moving`); over a sample the frame turning
    with the reference turns by omega T.  The plant's rows are already in the new frame (its ZOH is
    taken in the turning frame, :func:`plant_zoh`); what the sample only copies or steps by forward
    Euler in the world frame (the delay line's copies of P_n, an observer's estimates) is rotated by
    R(-omega T).
    """
    if blk.omega == 0.0 or not blk.frame:
        return
    mp, ny = blk.Fx.shape[0], blk.Gy.shape[1]
    nb = delay * ny
    pairs = []
    for i, j in blk.frame:
        if i < mp:
            if i < ny and j < ny:
                pairs += [(mp + k * ny + i, mp + k * ny + j) for k in range(delay)]
        else:
            pairs.append((i + nb, j + nb))
    c, s = math.cos(blk.omega * T), math.sin(blk.omega * T)
    for i, j in pairs:
        for X in (M0, Bz):
            ri, rj = X[i].copy(), X[j].copy()
            X[i] = c * ri + s * rj
            X[j] = -s * ri + c * rj


def open_loop_at_input(blk: Blocks, T: float, delay: int, j: int, plant=None):
    """(A, B, C) of the loop broken at actuator input j, discrete: ``L_j(z) = -C (zI - A)^-1 B``.

    Every other input stays closed; the controller's own use of its command (the switching bank's
    filters read u) is unchanged: only the plant receives the injected signal.
    """
    M0, Bz, Ka = parts(blk, T, delay, plant)
    Bj, Kj = Bz[:, j : j + 1], Ka[j : j + 1]
    return M0 + Bz @ Ka - Bj @ Kj, Bj, Kj


def spectral_radius(M: np.ndarray) -> float:
    """max |z| over the eigenvalues of M (0 for an empty matrix)."""
    if M.size == 0:
        return 0.0
    return float(np.abs(np.linalg.eigvals(M)).max())
