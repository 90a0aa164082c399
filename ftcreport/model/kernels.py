r"""Array kernels of the n-link 2WD chain model (the simulation hot path).

Every function takes plain ``numpy`` arrays and a ``ChainParams`` tuple of
constant arrays computed once per chain (:func:`make_params`; it is the compiled
kernels' ``jit.packed.Chain``, whose fields are documented there), and
returns new arrays.

What the simulation evaluates -- S and Sdot, the reduced model, the plant's
right-hand side, the wheel speeds, the input matrix B(q), the inertia matrix M(q)
and the vector C(q, qdot) -- exists once, in the compiled kernels
(:mod:`ftcreport.fast.kernels`: ``reduced`` builds M and C with ``_mass`` and
``_coriolis``, which ``mass_and_coriolis`` also serves to Python;
:mod:`ftcreport.model.motor_compiled`); the functions of that name here are faces over
them.  A(q) exists only here (the engine never needs it).  The tests check them
against the thesis's explicit matrices and a sympy Lagrangian, and the reduced
model against them (S^T A^T = 0, Mbar1 = S^T M S, Bbar = S^T B, power balance).

Conventions (used everywhere in ftcreport)
------------------------------------------
* Robots are numbered 1..n, robot 1 is the leader.  Arrays "in robot order"
  have index 0 for robot 1.
* ``q = [x, y, theta_n, theta_(n-1), ..., theta_1]`` (thesis 2.60), where
  ``(x, y)`` is P_n, the axle midpoint of the last robot.
* ``eta = [v_n, omega_1]``: linear velocity of robot n, angular velocity of
  robot 1 (thesis 2.63).
* Wheels and torques in the order ``1r, 1l, 2r, 2l, ..., nr, nl`` (2.102).
* ``d_i = |P_i P_(i+1)|``, i = 1..n-1 (ERRATA E5c); the link is rigid with
  the follower i+1 and pinned at the leader's axle P_i:
  ``P_i = P_(i+1) + d_i (cos theta_(i+1), sin theta_(i+1))`` (ERRATA E5).
* ``C_i = P_i + a_i (cos theta_i, sin theta_i)`` is the centre of mass.

Structure used by the derivation
--------------------------------
Every point of interest is ``(x, y) + sum_k L_k U_k`` with
``U_k = (cos theta_k, sin theta_k)`` and constant lever arms ``L_k``.  For the
centre of mass of robot i, ``L[i, k] = d_(k-1) [k > i] + a_i [k = i]``, so
its Jacobian (Appendix D, D.3) is ``[I_2, L[i, k] U_k^perp]`` and the kinetic
energy (D.2, D.4) gives (D.5, with ERRATA E5a for the inertia slots)::

    M_xy,xy = (sum_i m_i) I_2
    M_xy,k  = h_k U_k^perp,                       h = L^T m
    M_k,l   = G_kl cos(theta_k - theta_l) + I_k delta_kl,   G = L^T diag(m) L

and ``C = Mdot qdot - dT/dq`` (D.9) collapses to::

    C_xy = -sum_k h_k thetadot_k^2 U_k
    C_l  =  sum_k G_lk thetadot_k^2 sin(theta_l - theta_k)

The input matrix follows from virtual work (Appendix C, C.2-C.8): the force
``(tau_ir + tau_il) U_i / r_i`` acts at P_i, whose lever arms are
``D[i, k] = d_(k-1) [k > i]``, and the moment ``b_i (tau_ir - tau_il) / r_i``
acts on theta_i.  Both forms are checked against a symbolic Lagrangian
derivation and the explicit two- and three-link matrices in the tests.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..jit.packed import Chain as ChainParams

__all__ = [
    "A_matrix",
    "B_matrix",
    "C_vector",
    "ChainParams",
    "M_matrix",
    "S_and_Sdot",
    "S_matrix",
    "axle_midpoints",
    "eta_dot",
    "input_matrices_rows",
    "kernel_ref",
    "make_params",
    "packed",
    "positions",
    "reduced",
    "wheel_speeds",
    "wrap",
]


def _fast():
    """The compiled twin of this module (numba is loaded on first use, not with the package)."""
    from . import compiled

    return compiled


def __getattr__(name: str):
    # ChainParams is the kernels' Chain tuple (one type for numba), reached lazily: numba loads on first use
    if name == "ChainParams":
        return _fast().Chain
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def make_params(a, b, r, m, I, d):
    """Precompute the constant arrays of a chain (no validation here), as the kernels' ``Chain`` tuple."""
    a, b, r, m, I = (np.ascontiguousarray(v, dtype=float).copy() for v in (a, b, r, m, I))
    d = np.ascontiguousarray(d, dtype=float).reshape(-1).copy()
    n = a.shape[0]
    # D[i, k] = d_(k-1) for k > i (0-based: D[i, k] = d[k - 1] for k > i)
    D = np.zeros((n, n))
    for i in range(n):
        for k in range(i + 1, n):
            D[i, k] = d[k - 1]
    L = D + np.diag(a)
    h = L.T @ m
    G = L.T @ (m[:, None] * L)
    return _fast().Chain(int(n), a, b, r, m, I, d, float(m.sum()), h, G, D)


def packed(p):
    """p as the kernels' ``Chain`` tuple (p itself when :func:`make_params` built it)."""
    F = _fast()
    if type(p) is F.Chain:
        return p
    return F.Chain(
        int(p.n),
        *(np.ascontiguousarray(v, dtype=float) for v in (p.a, p.b, p.r, p.m, p.I)),
        np.ascontiguousarray(p.d, dtype=float).reshape(-1),
        float(p.m_total),
        *(np.ascontiguousarray(v, dtype=float) for v in (p.h, p.G, p.D)),
    )


def kernel_ref(p):
    """p as the loop passes it to the kernels (``jit.refs.to_ref`` of :func:`packed`).

    A kernel called from Python with it is compiled for the loop's argument types, so the loop's
    compile and the faces' calls share one compile (docs/ENGINE.md, "Compile time (session 9)").
    """
    from ..jit.refs import to_ref

    return to_ref(packed(p))


def _vec(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


def S_matrix(p: ChainParams, q: np.ndarray) -> np.ndarray:
    r"""Kinematic matrix S(q), qdot = S(q) eta, thesis (2.63)-(2.64): the compiled ``s_matrix``.

    Returns
    -------
    S : (n + 2, 2) ndarray
    """
    return _fast().s_matrix(kernel_ref(p), _vec(q))


def S_and_Sdot(p: ChainParams, q: np.ndarray, eta: np.ndarray):
    r"""S(q) and its time derivative along qdot = S(q) eta: the compiled ``reduced`` (its last two outputs).

    Returns
    -------
    S, Sdot : (n + 2, 2) ndarrays
    """
    return _fast().reduced(kernel_ref(p), _vec(q), _vec(eta))[4:]


def A_matrix(p: ChainParams, q: np.ndarray) -> np.ndarray:
    r"""Constraint matrix A(q), A(q) qdot = 0, thesis (2.61)-(2.62).

    Row j (j = 0..n-1) is the no-side-slip constraint of robot n - j
    (robot n first, as in 2.62): the velocity of P_i has no component along
    U_i^perp, i.e. ``xdot sin th_i - ydot cos th_i - sum_k D[i,k] cos(th_i - th_k) thdot_k = 0``.

    Returns
    -------
    A : (n, n + 2) ndarray
    """
    n = p.n
    th = q[:1:-1]
    A = np.zeros((n, n + 2))
    for row in range(n):
        i = n - 1 - row
        A[row, 0] = np.sin(th[i])
        A[row, 1] = -np.cos(th[i])
        # columns of theta_k in q: index 2 + (n - 1 - k) for 0-based k
        A[row, 2:] = (-p.D[i] * np.cos(th[i] - th))[::-1]
    return A


def M_matrix(p: ChainParams, q: np.ndarray) -> np.ndarray:
    r"""Inertia matrix M(q) from kinetic energy, Appendix D (D.5) with E5a.

    Returns
    -------
    M : (n + 2, n + 2) ndarray, symmetric positive definite
    """
    q = _vec(q)
    return _fast().mass_and_coriolis(kernel_ref(p), q, np.zeros_like(q))[0]


def C_vector(p: ChainParams, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    r"""Centripetal/Coriolis vector C(q, qdot) = Mdot qdot - dT/dq, (D.9).

    Returns
    -------
    C : (n + 2,) ndarray
    """
    return _fast().mass_and_coriolis(kernel_ref(p), _vec(q), _vec(qdot))[1]


def B_matrix(p: ChainParams, q: np.ndarray) -> np.ndarray:
    r"""Input matrix B(q) by virtual work, Appendix C (C.2)-(C.8), ERRATA E3 (``model.compiled.input_matrix_and_rate``).

    Column ``2i`` (wheel ir) is ``(1/r_i) [U_i; D[i,k] sin(th_i - th_k) + b_i delta_ik]``,
    column ``2i+1`` (wheel il) the same with ``-b_i``.

    Returns
    -------
    B : (n + 2, 2 n) ndarray, columns in wheel order 1r, 1l, ..., nr, nl
    """
    # the rate Bdot along headings at rest (thdot = 0) is not used
    return _fast().input_matrix_and_rate(kernel_ref(p), _vec(q), np.zeros(p.n))[0]


def reduced(p: ChainParams, q: np.ndarray, eta: np.ndarray):
    r"""Reduced dynamics matrices, thesis (2.70)-(2.74): the compiled ``reduced``.

    ``Mbar1 etadot + Mbar2 eta + Cbar = Bbar tau`` with
    Mbar1 = S^T M S, Mbar2 = S^T M Sdot, Cbar = S^T C(q, S eta), Bbar = S^T B.
    The full M, C, B above are the independent check (tests/test_model.py).

    Returns
    -------
    Mbar1 : (2, 2), Mbar2 : (2, 2), Cbar : (2,), Bbar : (2, 2 n) ndarrays
    """
    return _fast().reduced(kernel_ref(p), _vec(q), _vec(eta))[:4]


def eta_dot(p: ChainParams, q: np.ndarray, eta: np.ndarray, tau: np.ndarray):
    r"""Forward dynamics of the reduced model (2.70), qdot and etadot: the compiled ``plant_rhs``.

    Returns
    -------
    qdot : (n + 2,), etadot : (2,) ndarrays
    """
    return _fast().plant_rhs(kernel_ref(p), _vec(q), _vec(eta), _vec(tau))


def positions(p: ChainParams, q: np.ndarray):
    """Axle midpoints P_i and centres of mass C_i, robot order.

    Returns
    -------
    P, Cm : (n, 2) ndarrays, row 0 = robot 1
    """
    th = q[:1:-1]
    P = axle_midpoints(q, p.d)
    Cm = P + p.a[:, None] * np.column_stack((np.cos(th), np.sin(th)))
    return P, Cm


def axle_midpoints(q: np.ndarray, d) -> np.ndarray:
    """Axle midpoints P_i, (n, 2), row 0 = robot 1, from q and the link lengths d (n - 1)."""
    n = q.shape[0] - 2
    th = q[:1:-1]
    P = np.empty((n, 2))
    P[n - 1] = q[0], q[1]
    for i in range(n - 2, -1, -1):
        # P_i = P_(i+1) + d_i U_(i+1)
        P[i, 0] = P[i + 1, 0] + d[i] * np.cos(th[i + 1])
        P[i, 1] = P[i + 1, 1] + d[i] * np.sin(th[i + 1])
    return P


def wheel_speeds(p: ChainParams, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
    r"""Wheel angular velocities in wheel order, ``Bbar^T eta = B^T S eta``: the compiled ``wheel_speeds_rows``.

    By virtual work the power delivered by the torques is ``tau . wheel_speeds``:
    omega_ir = (v_i + b_i omega_i) / r_i, omega_il = (v_i - b_i omega_i) / r_i.
    """
    return _fast().wheel_speeds_rows(kernel_ref(p), _vec(q)[None, :], _vec(eta)[None, :])[0]


def input_matrices_rows(p: ChainParams, Q: np.ndarray) -> np.ndarray:
    """Mbar1(q)^-1 Bbar(q), (K, 2, 2n), at K configurations: one compiled call (no per-row Python)."""
    Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, int(p.n) + 2)  # [x_n, y_n, theta_n, ..., theta_1]
    return _fast().input_matrices_rows(kernel_ref(p), Q)  # a ref: the loop's compile of reduced


def wrap(a):
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
