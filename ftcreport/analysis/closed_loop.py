r"""One scheme's closed loop, linearized through the scheme interface (pure: no I/O).

The loop a case runs is the plant (the chain, its actuators and the drive), the kinematic law, and the
scheme's compiled law with its own states.  This module evaluates each part as the engine does, at an
operating point on the reference, and differentiates it by central differences:

* the plant, ``x_p' = f_p(x_p, a)`` with ``x_p = [q, eta, i_a]`` (thesis (2.70); with ``[actuators]``
  the motors (2.26)-(2.29) with ERRATA E19, ``model.motor_compiled.motor_plant_rhs``) and ``a`` the signal the
  controller holds at the actuator inputs: the torque command ``u`` on the ideal plant, the driver's
  armature voltage with motors (:class:`Plant`);
* the controller, ``(a, c') = g(x_p, y, c)``: the scheme's law (``law(P, Kp, R, C, pc, t, q, eta, xc,
  sig_true, ubar_true, info, sig)``, the scheme API of ``ftcreport.schemes``) at the measurement
  ``y = [q, eta]``, then the command faults (2.101)-(2.102), the torque limit and the driver; ``c``
  the scheme's states that are linearized (:class:`SchemeLoop`);
* where the scheme has a smooth discrete update (the UKF's step and the law it holds), that map too.

The laws are nonlinear in q (the kinematic laws (3.27)-(3.29), (3.67)-(3.106)) and reach the
numbers only through the compiled kernels, so the Jacobians are central differences of the compiled
functions (error O(h^2) for a relative step h = 1e-6: about 1e-12 of each entry, far below what a
pole or a limit needs; ``tests/test_linear_loop.py`` checks them against the model's analytic
Jacobians and the sympy Lagrangian).  The same code linearizes a plug-in scheme, which is known only
through that interface.  One exception, for cost: the UKF scheme's filter step enters its update through
its derivative (:meth:`SchemeLoop._ukf_map`, ``observers.ukf_compiled.ukf_step_jacobian``), not
through differences of the whole step (112 filter steps per frozen instant for six robots).

Operating point (a frozen instant t of a fault phase): the plant on the reference,
``q = q_d(t), eta = eta_d(t)``, the motors' currents quasi-static for the command held there; the
kinematic frame as the controller holds it at t (:func:`frames`); the scheme's own states at what
they hold in that phase: the states of its run at t when a run exists, else the converged values of
the built-in schemes (:func:`operating_state`: switching's applied model, the adaptive weights on
the design of the applied pattern, the observers' estimates at the truth) and a plug-in's initial
state.

States that cannot matter to the tracking are left out, exactly: the kinematic frame and switching's
selected index and dwell timer are held (they change by jumps, not by rates), the UKF's covariance is
held at its value (the filter linearized with its gain frozen, the usual linearization of a Kalman
filter), and every state that the plant can neither excite nor see is dropped by
:func:`relevant_states` (the Farza observer's sensitivity matrix Y and gain P at zero estimation
error, the adaptive law's weight combinations that leave the torque unchanged): its modes are
decoupled, so the poles that remain are exactly those of the loop that reaches the plant.  Their
own block is kept apart (``Blocks.internal``) and counts for stability: the run stays bounded only if
it is stable too (the switching bank's filters, stepped by forward Euler in a sampled loop).  The
adaptive weights (N designs x 2n wheels, 7,670 states for five robots) enter only through the
torque and have no dynamics of their own at zero error; :func:`_parameter_block` replaces them by
their image in the torque space (at most 2n states), exactly.
"""

from __future__ import annotations

import copy
import math
import weakref
from dataclasses import dataclass

import numpy as np

from ..errors import ModelError
from .blocks import Blocks

__all__ = [
    "Blocks",
    "Faults",
    "Plant",
    "Point",
    "SchemeLoop",
    "central_columns",
    "frames",
    "operating_state",
    "relevant_states",
]

_EMPTY = np.zeros(0)
#: relative step of the central differences: truncation ~h^2 = 1e-12, round-off ~eps/h = 2e-10 of |f|
STEP = 1e-6
#: the adaptive weights are put at least this far inside [0, 1] (:func:`_inside`), far beyond STEP
WEIGHT_INSIDE = 1e-3
#: the plant's Jacobians by the built plant they belong to, then by the exact content of their arguments
#: (:meth:`Plant.state_columns`): every scheme of a case, and its loops at other gains, share them
_PLANT_JACOBIANS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class Faults:
    """The faults of one phase: command faults (2.101)-(2.102) and the motors' fault table.

    sigma, ubar : (2n,) ndarrays, wheel order 1r, 1l, 2r, ...; motor : (2n, 4) ndarray (rows
    ``[k_m scale, R_a scale, mode, v_stuck]``, ``model.motor_compiled``) or an empty (0, 4) array without motors.
    """

    sigma: np.ndarray
    ubar: np.ndarray
    motor: np.ndarray

    @classmethod
    def healthy(cls, nw: int, motors: bool) -> Faults:
        from ..model.motor_compiled import healthy_faults

        return cls(np.ones(nw), np.zeros(nw), healthy_faults(nw) if motors else np.zeros((0, 4)))


def central_columns(f, x0: np.ndarray, columns=None, step: float = STEP) -> np.ndarray:
    """Columns of the Jacobian of f at x0 by central differences, (len(f(x0)), len(columns)).

    Column j: ``(f(x0 + h e_j) - f(x0 - h e_j)) / (2 h)`` with ``h = step max(1, |x0_j|)``.  A function
    that does not read x_j gives exactly 0 (the same evaluation twice): :func:`relevant_states` relies on it.
    The result is Fortran-ordered, each column written once in place (a column is contiguous: on the
    adaptive law's 36,864 rows, stacking and then reading them along a column cost more than the law).
    :func:`central_rows` with f evaluated one point at a time.
    """
    # the same points and operations as central_rows, f called on each row in turn
    return central_rows(lambda X: np.array([np.asarray(f(x), dtype=float) for x in X]), x0, columns, step)


#: entries of a batch of evaluation points (:func:`central_rows`): 8 MB, ~28 rows of six robots' adaptive weights
BATCH_ENTRIES = 1 << 20


def central_rows(f_rows, x0: np.ndarray, columns=None, step: float = STEP) -> np.ndarray:
    """:func:`central_columns` with f evaluated a batch of points at a time: ``f_rows(X)`` is f at each row
    of X, an (m, len(f)) array (:meth:`SchemeLoop._rows_at`: one compiled call for the batch).

    The points are those of :func:`central_columns`, in its order (``x0 + h e_j``, then ``x0 - h e_j``,
    column by column), in batches of at most :data:`BATCH_ENTRIES` entries; each column is computed by
    the same operations, so the two give the same numbers bit for bit (``tests/test_batched_law.py``).
    """
    x0 = np.asarray(x0, dtype=float)
    cols = list(range(x0.size) if columns is None else columns)
    if not cols:
        return np.zeros((np.asarray(f_rows(x0[None, :])).shape[1], 0))
    per = max(1, BATCH_ENTRIES // max(1, 2 * x0.size))  # columns per batch
    out = None
    for s in range(0, len(cols), per):
        block = cols[s : s + per]
        hs = np.array([step * max(1.0, abs(x0[j])) for j in block])
        X = np.repeat(x0[None, :], 2 * len(block), axis=0)
        for k, j in enumerate(block):
            X[2 * k, j] += hs[k]
            X[2 * k + 1, j] -= hs[k]
        F = np.asarray(f_rows(X), dtype=float)
        if out is None:
            out = np.empty((F.shape[1], len(cols)), order="F")
        for k in range(len(block)):  # into out's contiguous column, no temporary (36,864 rows for six robots)
            col = out[:, s + k]
            np.subtract(F[2 * k], F[2 * k + 1], out=col)
            col /= 2.0 * hs[k]
    return out


def directional_rows(f_rows, x0: np.ndarray, V: np.ndarray, step: float = STEP,
                     x0_norm: float | None = None, embed=None) -> np.ndarray:  # fmt: skip
    """``J(x0) V``: a central difference along each column v of V (h scaled to v and x0; ``x0_norm``: |x0|
    if known), f evaluated in one batch (``f_rows`` as in :func:`central_rows`).

    The norms are sums of squares, not ``np.linalg.norm``: on a vector of 36,840 adaptive weights that
    calls the threaded BLAS, 27 ms a call on the loaded 2-core machine against 0.1 ms.  ``embed``
    ``(z, at, held)``: x is the part ``z[at]`` of a longer vector z (a scheme's state), and f_rows takes
    rows of z, each written once with ``z[held]`` and the varied x at ``at``.
    """
    x0 = np.asarray(x0, dtype=float)
    if x0_norm is None:
        x0_norm = math.sqrt(float(np.sum(x0 * x0)))
    hs = []
    for k in range(V.shape[1]):
        nv = math.sqrt(float(np.sum(V[:, k] * V[:, k])))
        hs.append(step * max(1.0, x0_norm) / nv if nv != 0.0 else 0.0)
    along = [k for k, h in enumerate(hs) if h != 0.0]
    if not along:
        return np.zeros((np.asarray(f_rows(x0[None, :])).shape[1], V.shape[1]))
    # the points written in place (20 rows of 36,852 weights for six robots), in z when embedded
    z, at, held = embed if embed is not None else (x0, slice(0, x0.size), np.zeros(0, dtype=int))
    X = np.empty((2 * len(along), z.size))
    X[:, held] = z[held]
    hv = np.empty(x0.size)
    for r, k in enumerate(along):
        np.multiply(hs[k], V[:, k], out=hv)
        if isinstance(at, slice):  # a view: written directly
            np.add(x0, hv, out=X[2 * r, at])
            np.subtract(x0, hv, out=X[2 * r + 1, at])
        else:
            X[2 * r, at] = x0 + hv
            X[2 * r + 1, at] = x0 - hv
    F = np.asarray(f_rows(X), dtype=float)
    out = np.zeros((F.shape[1], V.shape[1]))
    for r, k in enumerate(along):
        np.subtract(F[2 * r], F[2 * r + 1], out=out[:, k])
        out[:, k] /= 2.0 * hs[k]
    return out


# ----------------------------------------------------------------------------------------------- plant
class Plant:
    r"""The plant as the controller's samples see it: x_p' = f_p(x_p, a) (pure).

    ``x_p = [q (n + 2), eta (2), motor states]``: with ``[actuators]`` the currents i_a (2n) and, for a
    PI drive, its integral parts z (2n) after them (model.drive_compiled).  ``a`` is what the controller holds at
    the actuator inputs: on the ideal plant the torque command u (the plant applies
    ``tau = sigma sat(u) + ubar``, (2.101)-(2.102)); with the static driver its armature voltage; with
    a PI drive its current target i*, the drive being a continuous part of the plant
    (``model.drive_compiled.pi_voltage``: v_a = sat(K_p (i* - i_a) + z + c_ff k_b N omega), z' = K_i (i* - i_a)).
    The drive's own model of the motor (``[actuators.drive_model]``) turns the command into ``a``
    (:meth:`command`).  A PI drive at its own rate (``drive_rate``) is analysed as the continuous PI:
    its period is a fraction of the controller's (the case rejects a rate that is not a whole number
    of steps), and the page says so.  This is the one place that says how the drive enters the loop.
    """

    def __init__(self, built) -> None:
        from ..fast import kernels as F
        from ..model.kernels import kernel_ref

        self.chain = built.plant.chain  # the plant's chain (a mismatch case differs from the model's)
        self.n_q = self.chain.n_q
        self.nw = self.chain.n_wheels
        self.saturation = built.plant.saturation
        self._F = F
        self._pref = kernel_ref(self.chain.params)
        self.motors = self.drive = None
        self.pi = False  # a PI current loop (its integral parts are plant states)
        self.nm = 0
        self.input_name, self.input_unit = "torque", "N m"
        if built.plant.motors is not None:
            from ..model.actuators import pack, pack_drive
            from ..model.drive_compiled import DRIVER_STATIC

            self.motors = pack(built.plant.motors, self.chain.n)
            self.drive = pack_drive(getattr(built.plant, "drive", None), built.plant.motors, self.chain.n)
            self.pi = self.drive.kind != DRIVER_STATIC
            self.nm = self.nw * (2 if self.pi else 1)
            self.input_name, self.input_unit = ("current target", "A") if self.pi else ("voltage", "V")
        self.n_states = self.n_q + 2 + self.nm
        # the schemes of a case hold the same plant state and, often, the same signal at an instant (the
        # healthy phase's matched command): its Jacobians once per content, for every scheme and gain
        self._jacobians = _PLANT_JACOBIANS.setdefault(built.plant, {})

    def clip(self, u: np.ndarray) -> np.ndarray:
        return u if self.saturation is None else np.clip(u, -self.saturation, self.saturation)

    def wheel_speeds(self, pref, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """Bbar(q)^T eta (virtual work) with the chain ``pref`` (a kernel ref)."""
        return self._F.reduced(pref, q, eta)[3].T @ eta

    def true_faults(self, xp: np.ndarray, fz: Faults) -> tuple[np.ndarray, np.ndarray]:
        """(sigma, ubar) the chain sees: the command faults with the motors' equivalents at xp's wheel speeds."""
        if self.motors is None:
            return fz.sigma, fz.ubar
        from ..model.motor_compiled import fault_equivalent

        nq = self.n_q
        sm, um = fault_equivalent(self.motors, fz.motor, self.wheel_speeds(self._pref, xp[:nq], xp[nq : nq + 2]))
        return sm * fz.sigma, sm * fz.ubar + um

    def command(self, u: np.ndarray, omega_meas: np.ndarray, fz: Faults) -> np.ndarray:
        """The held actuator signal for the law's command u: u itself, or what the drive makes of it.

        The drive's current target at the measured wheel speeds (``model.drive_compiled.current_target``, with
        the drive's model), fed the command after the command faults and the limit; the static
        driver's voltage of it (``model.drive_compiled.static_voltage``), or the target itself for a PI drive.
        """
        if self.motors is None:
            return u
        from ..model.drive_compiled import current_target, static_voltage

        i_star = current_target(self.drive, fz.sigma * self.clip(u) + fz.ubar, omega_meas)
        return i_star if self.pi else static_voltage(self.drive, i_star, omega_meas, fz.motor)

    def rates(self, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        """f_p(x_p, a): [S(q) eta, etadot (2.70), i_a' (2.28), z' of a PI drive] with a held."""
        nq, nw = self.n_q, self.nw
        q, eta = xp[:nq], xp[nq : nq + 2]
        if self.motors is None:
            qdot, etadot = self._F.plant_rhs(self._pref, q, eta, fz.sigma * self.clip(a) + fz.ubar)
            return np.concatenate((qdot, etadot))
        from ..model.motor_compiled import motor_plant_rhs

        xm = xp[nq + 2 :]
        if not self.pi:
            qdot, etadot, idot, _tau = motor_plant_rhs(self._pref, self.motors, q, eta, xm, a, fz.motor)
            return np.concatenate((qdot, etadot, idot))
        from ..model.drive_compiled import pi_voltage

        omega = self.wheel_speeds(self._pref, q, eta)  # read by the PI only with back-EMF feedforward
        v, zdot = pi_voltage(self.drive, a, xm[:nw], xm[nw:], omega, fz.motor)
        qdot, etadot, idot, _tau = motor_plant_rhs(self._pref, self.motors, q, eta, xm[:nw], v, fz.motor)
        return np.concatenate((qdot, etadot, idot, zdot))

    def _rates_rows(self, X: np.ndarray, TAU: np.ndarray) -> np.ndarray:
        """:meth:`rates` of the ideal plant at each row of X and of the torques TAU (one row serves every row;
        ``model.compiled.plant_rhs_rows``)."""
        X, TAU = np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(TAU, dtype=float)
        out = np.empty((max(X.shape[0], TAU.shape[0]), X.shape[1]))
        self._F.plant_rhs_rows(self._pref, X, TAU, out)
        return out

    def operating_currents(self, q: np.ndarray, eta: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        """The motor states at the operating point: the currents quasi-static for the held voltages a
        (L_a di/dt = 0), or a PI drive's steady state for the held target a (``drive_compiled.pi_steady_states``)."""
        if self.motors is None:
            return _EMPTY
        omega = self.wheel_speeds(self._pref, q, eta)
        if self.pi:
            from ..model.drive_compiled import pi_steady_states

            return pi_steady_states(self.motors, self.drive, a, omega, fz.motor)[: self.nm]
        from ..model.motor_compiled import quasi_static_current

        return quasi_static_current(self.motors, a, omega, fz.motor)

    def input_columns(self, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        """d f_p / d a, (n_states, 2n): the currents' rows are exact (1/L_a on working windings)."""
        return self._once("a", self._input_columns, xp, a, fz)

    def state_columns(self, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        """d f_p / d x_p: central differences in q and eta, the currents' columns exact (affine in i_a)."""
        return self._once("x", self._state_columns, xp, a, fz)

    def _once(self, which: str, jacobian, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        """``jacobian(xp, a, fz)`` computed once per exact content of its arguments (a copy each call)."""
        arrays = (xp, a, fz.sigma, fz.ubar, fz.motor)
        key = (which, *((v.dtype.str, v.shape, v.tobytes()) for v in map(np.asarray, arrays)))
        if key not in self._jacobians:
            self._jacobians[key] = jacobian(xp, a, fz)
        return self._jacobians[key].copy()

    def _input_columns(self, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        if self.motors is None:  # the torques of the held commands, each point's in one compiled call
            return central_rows(lambda A: self._rates_rows(xp[None, :], fz.sigma * self.clip(A) + fz.ubar), a)
        if self.pi:  # a PI: K_p / L_a and K_i off its limits, central differences
            return central_columns(lambda v: self.rates(xp, v, fz), a)
        from ..model.motor_compiled import winding_voltage

        B = np.zeros((self.n_states, self.nw))
        # the winding sees the driver's voltage except when open, shorted or stuck (model.motor_compiled)
        passes = winding_voltage(self.motors, np.ones(self.nw), fz.motor) == 1.0
        B[self.n_q + 2 :, :] = np.diag(np.where(passes, 1.0 / self.motors.L_a, 0.0))
        return B

    def _state_columns(self, xp: np.ndarray, a: np.ndarray, fz: Faults) -> np.ndarray:
        nq = self.n_q
        f = lambda x: self.rates(x, a, fz)  # noqa: E731
        if self.motors is None:  # the ideal plant: its points in one compiled call, the same numbers
            tau = np.ascontiguousarray(fz.sigma * self.clip(a) + fz.ubar, dtype=float)
            return central_rows(lambda X: self._rates_rows(X, tau[None, :]), xp)
        if self.pi:  # a PI: affine in i_a and z off its limits
            return central_columns(f, xp)
        from ..model.motor_compiled import current_jacobian

        J = np.zeros((self.n_states, self.n_states))
        J[:, : nq + 2] = central_columns(f, xp, range(nq + 2))
        J[nq:, nq + 2 :] = current_jacobian(self._pref, self.motors, xp[:nq], xp[nq : nq + 2], fz.motor)
        return J


# ----------------------------------------------------------------------------------------------- points
@dataclass
class Point:
    """An operating point: time, the phase's faults, the plant state, the controller state, the held signal."""

    t: float
    faults: Faults
    xp: np.ndarray
    xc: np.ndarray
    a: np.ndarray
    applied: list | None = None  # the pattern the law assumes here (None: not a pattern-based law)
    omega: float = 0.0  # the reference's turning rate at t (theta_n's), for the co-moving frame


# ----------------------------------------------------------------------------------------------- scheme
class SchemeLoop:
    """One scheme of a case as the engine runs it, evaluated from Python through the scheme interface.

    Parameters
    ----------
    case : ftcreport.cases.Case
    scheme : str
        A built-in or registered scheme the case runs.
    built : ftcreport.runner.Built, optional
        The case's built objects (shared between the schemes of a case).
    k_v : float, optional
        Another velocity gain than the case's (the stability limits vary it).
    controller : optional
        A controller built elsewhere (a registered scheme's ``SchemeController`` outside any case table)
        to run on the case's plant instead of the case's ``scheme``.
    """

    def __init__(self, case, scheme: str, built=None, k_v: float | None = None, controller=None) -> None:
        from ..fast import kernels as F
        from ..fast.engine import compiled_spec, law_buffers, loop_for
        from ..jit.refs import to_ref
        from ..runner import build, make_controller

        built = built if built is not None else build(case)
        if k_v is not None:
            built = copy.copy(built)
            built.case = with_k_v(case, scheme, k_v)
        self.case = case
        self.scheme = scheme
        self.built = built
        self.ctrl = make_controller(built, scheme) if controller is None else controller
        self.k_v = float(self.ctrl.k_v)
        spec = compiled_spec(self.ctrl)
        if spec is None:
            raise ModelError(f"scheme {scheme}: no compiled law to linearize")
        self.spec = spec
        # the law through its loop's entry points, as the engine and 'schemes check' call it (the
        # scheme interface: the loop builds the step, the terms and the law's buffers); the case's own
        # variant of the loop, so that a batch's compiled cache serves it
        self._loop = loop_for(
            spec.law, spec.disc, motors=case.actuators is not None,
            sampled=case.simulation.sample_time is not None, terms=spec.terms,
        )  # fmt: skip
        self._bufs = law_buffers(spec)
        self._kin, self._ref, self._pc = to_ref(spec.kin), to_ref(spec.ref), to_ref(spec.chain)
        self._cache = to_ref(F.new_cache(self.ctrl.chain.n))
        self.plant = Plant(built)
        self.n_q = self.plant.n_q
        self.nk = int(self.ctrl.kin.n_states)
        self.held, self.has_disc = _layout(self.ctrl, self.nk)
        keep = np.ones(int(self.ctrl.n_states), dtype=bool)
        keep[np.fromiter(self.held, dtype=int, count=len(self.held))] = False
        lin = self._lin_index = np.flatnonzero(keep)
        self.linearized = lin.tolist()
        # the linearized states as a slice when contiguous (the adaptive weights, 36,852 for six robots:
        # a view and a copy where an index array gathers and scatters them at every evaluation)
        contiguous = lin.size > 0 and np.array_equal(lin, np.arange(lin[0], lin[0] + lin.size))
        self._lin: slice | np.ndarray = slice(int(lin[0]), int(lin[0]) + lin.size) if contiguous else lin
        # the same states in the law's buffer of the own states' rates (after the nk kinematic states, held)
        nk = self.nk
        self._own = slice(self._lin.start - nk, self._lin.stop - nk) if contiguous else lin - nk
        self._held_index = np.array(sorted(self.held), dtype=int)
        # every own state linearized (the adaptive weights): the law's rates are the rows' own, uncopied
        self._own_all = contiguous and self._own == slice(0, int(self.ctrl.n_states) - nk)
        self._linearized_at: dict[tuple, Blocks] = {}  # :meth:`blocks` by the content of its arguments
        self._ukf_law = _ukf_law(self.ctrl)  # the UKF scheme's compiled parameters (:meth:`_ukf_map`), or None

    # ------------------------------------------------------------------------------------------ calls
    def law(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray, st, ut) -> tuple[np.ndarray, np.ndarray]:
        """(u, xc') of the scheme's compiled law at the measured (q, eta) (the scheme API's call)."""
        u = self._command(t, q, eta, xc, st, ut)
        # the scheme's own states' rates (the law's out.dx); the kinematic controller's states have none
        return u, np.concatenate((np.zeros(self.nk), self._bufs[2][: int(self.ctrl.n_states) - self.nk]))

    def _command(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray, st, ut) -> np.ndarray:
        """The law's u at (t, q, eta); its own states' rates are left in the law buffers (``_bufs[2]``)."""
        info = np.zeros(4)
        spec, bufs = self.spec, self._bufs
        u = self._loop.first_law(
            (spec.P, bufs), spec.kin, spec.ref, spec.chain, float(t), np.ascontiguousarray(q, dtype=float),
            np.ascontiguousarray(eta, dtype=float), np.ascontiguousarray(xc, dtype=float),
            np.ascontiguousarray(st, dtype=float), np.ascontiguousarray(ut, dtype=float), info, _EMPTY,
        )  # fmt: skip
        if info[0] != 0:
            raise ModelError(self._stopped("law", t, info))
        return np.asarray(u, dtype=float)

    def _whose(self, role: str = "law") -> str:
        """``file:line: `` of a plug-in scheme's law (or another of its hooks: where to look), empty for a
        built-in scheme."""
        from ..schemes import get
        from ..schemes.registry import _where, is_built_in

        sc = get(self.scheme)
        fn = getattr(sc, role, None) or sc.law
        return "" if is_built_in(sc) or isinstance(fn, str) else f"{_where(fn)}: "

    def _finite(self, pt: Point, **jacobians: np.ndarray) -> None:
        """Raise ModelError naming the first Jacobian that holds an inf or a NaN (a law whose output
        overflows within the central differences' step, a plant driven out of its domain)."""
        words = {"Fx": "the plant's Jacobian against its state", "Fa": "the plant's Jacobian against its input",
                 "Gy": "the law's Jacobian against the measurement", "Gx": "the law's Jacobian against the true state",
                 "Gc": "the law's Jacobian against the scheme's states"}  # fmt: skip
        for name, J in jacobians.items():
            if J is None or not J.size:
                continue
            big = float(np.abs(pt.a).max(initial=0.0))
            top = max(float(J.max()), -float(J.min()))  # NaN when J holds one (no |J| copy: 36,864 rows)
            if not math.isfinite(top):
                raise ModelError(
                    f"{self._whose()}scheme {self.scheme}: at t = {pt.t:g} s {words[name]} ({name}) is not finite: "
                    f"the loop's outputs overflow or leave their domain within a central difference's step of the "
                    f"operating point (largest |{self.plant.input_name}| there {big:.3g})"
                )
            if top > _OVERFLOW:
                raise ModelError(
                    f"{self._whose()}scheme {self.scheme}: at t = {pt.t:g} s {words[name]} ({name}) reaches "
                    f"{top:.3g}: the closed loop's matrices would overflow (a product of two such entries), so its "
                    f"poles mean nothing (largest |{self.plant.input_name}| at the operating point {big:.3g})"
                )

    def _stopped(self, what: str, t: float, info: np.ndarray) -> str:
        """Why the scheme's law or discrete update stopped at t: a plug-in's that raised (E_LAW_RAISED: the
        loop caught it; run again in Python, it is named with its line, as a run's reason names it)."""
        from ..fast.stops import law_nonfinite_reason, law_raised_reason, law_signal_reason
        from ..jit.packed import E_LAW_NONFINITE, E_LAW_RAISED, E_LAW_SIGNAL, E_LAW_WRITE
        from ..schemes.controller import write_reason

        code = int(info[0])
        if code == E_LAW_RAISED:
            return law_raised_reason(self.spec, info, self._bufs)
        # the run's own words for the engine's stops (fast.stops), the plug-in's law file first
        if code == E_LAW_NONFINITE:
            return self._whose() + law_nonfinite_reason(self.spec, int(info[2]), float(info[3]), float(info[1]))
        if code == E_LAW_SIGNAL:
            return self._whose() + law_signal_reason(self.spec, int(info[2]), float(info[3]), float(info[1]))
        if code == E_LAW_WRITE:
            return self._whose() + write_reason(self.ctrl, int(info[1]), float(info[2]))
        return f"scheme {self.scheme}: the {what} stops at t = {t:g} s (error code {code})"

    def discrete(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """The scheme's discrete update at t (a copy of xc updated)."""
        out = np.array(xc, dtype=float)
        info = np.zeros(4)
        q, eta = np.asarray(q, dtype=float), np.asarray(eta, dtype=float)
        spec = self.spec
        self._loop.first_discrete((spec.P, self._bufs), spec.kin, spec.ref, spec.chain, float(t), q, eta, out, info)
        if info[0] != 0:
            raise ModelError(self._stopped("discrete update", t, info))
        return out

    def controller(self, t: float, xp: np.ndarray, y: np.ndarray, xc: np.ndarray, fz: Faults):
        """(a, xc') at the true plant state xp, the measurement y = [q, eta] and the controller state xc."""
        nq = self.n_q
        st, ut = self.plant.true_faults(xp, fz)  # only an oracle reads them
        u, dx = self.law(t, y[:nq], y[nq : nq + 2], xc, st, ut)
        return self._actuator(u, y, fz), dx

    def _rows(self, t: float, xp: np.ndarray, y: np.ndarray, xc: np.ndarray, fz: Faults, rates: bool = True):
        """``[a, xc'[linearized]]`` as :meth:`controller` gives them, or a alone (``rates`` False), without
        copying the rates of the other states (the adaptive weights: 36,852 for six robots)."""
        nq = self.n_q
        st, ut = self.plant.true_faults(xp, fz)
        a = self._actuator(self._command(t, y[:nq], y[nq : nq + 2], xc, st, ut), y, fz)
        return np.concatenate((a, self._bufs[2][self._own])) if rates else a

    def _rows_at(self, t: float, XP: np.ndarray, Y: np.ndarray, XC: np.ndarray, fz: Faults,
                 rates: bool = True) -> np.ndarray:  # fmt: skip
        """:meth:`_rows` at each row of (XP, Y, XC), (m, len): the law evaluated for all of them in one
        compiled call (the loop's ``law_rows``), the same numbers as :meth:`_rows` row by row.  An
        argument of one row serves every row."""
        nq = self.n_q
        XP, Y, XC = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (XP, Y, XC))
        m = max(XP.shape[0], Y.shape[0], XC.shape[0])
        if self.plant.motors is None:
            ST, UT = fz.sigma[None, :], fz.ubar[None, :]
        else:  # the faults the chain sees depend on its wheel speeds (an oracle reads them)
            pairs = [self.plant.true_faults(xp, fz) for xp in XP]
            ST, UT = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
        ST, UT = np.ascontiguousarray(ST, dtype=float), np.ascontiguousarray(UT, dtype=float)
        nw, n_own = self.plant.nw, int(self.ctrl.n_states) - self.nk
        OUT = np.empty((m, nw + (n_own if rates else 0)))  # [u, the own states' rates] per row
        info = np.zeros(4)
        spec = self.spec
        self._loop.law_rows(
            (spec.P, self._bufs), spec.kin, spec.ref, spec.chain, float(t), np.ascontiguousarray(Y[:, :nq]),
            np.ascontiguousarray(Y[:, nq : nq + 2]), XC, ST, UT, info, OUT,
        )  # fmt: skip
        if info[0] != 0:
            raise ModelError(self._stopped("law", t, info))
        if self.plant.motors is not None:  # the drive's signal for each command, at its row's measurement
            for r in range(m):
                OUT[r, :nw] = self._actuator(OUT[r, :nw], Y[min(r, Y.shape[0] - 1)], fz)
        if not rates or self._own_all:
            return OUT
        return np.hstack((OUT[:, :nw], OUT[:, nw:][:, self._own]))

    def _discrete_rows(self, t: float, Y: np.ndarray, XC: np.ndarray) -> np.ndarray:
        """:meth:`discrete` at each row of (Y, XC) (one row of Y serves every row): the updated copies,
        from one compiled call (the loop's ``discrete_rows``)."""
        nq = self.n_q
        Y = np.ascontiguousarray(np.atleast_2d(Y), dtype=float)
        out = np.array(np.atleast_2d(XC), dtype=float, order="C")
        info = np.zeros(4)
        spec = self.spec
        self._loop.discrete_rows(
            (spec.P, self._bufs), spec.kin, spec.ref, spec.chain, float(t), np.ascontiguousarray(Y[:, :nq]),
            np.ascontiguousarray(Y[:, nq : nq + 2]), out, info,
        )  # fmt: skip
        if info[0] != 0:
            raise ModelError(self._stopped("discrete update", t, info))
        return out

    def _actuator(self, u: np.ndarray, y: np.ndarray, fz: Faults) -> np.ndarray:
        """The held actuator signal for the law's u at the measurement y (:meth:`Plant.command`)."""
        omega = None
        if self.plant.motors is not None:
            nq = self.n_q
            omega = self.plant.wheel_speeds(self._pc, y[:nq], y[nq : nq + 2])  # the driver's: the model's Bbar
        return self.plant.command(u, omega, fz)

    # ------------------------------------------------------------------------------------------ points
    def point(self, t: float, faults: Faults, psi: float | None = None, applied=None, run_xc=None,
              period: float | None = None, q=None, eta=None) -> Point:  # fmt: skip
        """The operating point at t on the reference (module docstring); ``period``: a sampled scheme's T.

        ``q``, ``eta``: another plant state than the reference's (a loop at rest, in the tests).
        """
        r = self.ctrl.kin.reference.at(float(t))
        q = np.asarray(r.q_d if q is None else q, dtype=float)
        eta = np.asarray(r.eta_d if eta is None else eta, dtype=float)
        xc, applied = operating_state(self, t, q, eta, faults, psi, applied, run_xc, period)
        if not np.all(np.isfinite(xc)):
            bad = int(np.count_nonzero(~np.isfinite(xc)))
            src = "its initial_state" + (" or its run" if run_xc is not None else "")
            raise ModelError(
                f"{self._whose('initial_state')}scheme {self.scheme}: its state at the operating point "
                f"(t = {t:g} s) is not finite ({bad} of {xc.size} entries: {src}): nothing to linearize about"
            )
        xp = np.concatenate((q, eta, np.zeros(self.plant.nm)))
        a, dx = self.controller(t, xp, xp[: self.n_q + 2], xc, faults)
        if not np.all(np.isfinite(dx)):
            bad = [int(i) for i in np.flatnonzero(~np.isfinite(dx)) if i >= self.nk]
            raise ModelError(
                f"{self._whose()}scheme {self.scheme}: its law's state rates at the operating point (t = {t:g} s) "
                f"are not finite (out.dx{[i - self.nk for i in bad]}): nothing to linearize about"
            )
        if not np.all(np.isfinite(a)):
            raise ModelError(
                f"{self._whose()}scheme {self.scheme}: its law's command at the operating point (t = {t:g} s) is "
                f"not finite ({self.plant.input_name} {np.array2string(a, precision=3)}): nothing to linearize about"
            )
        xp[self.n_q + 2 :] = self.plant.operating_currents(q, eta, a, faults)
        omega = float((self.ctrl.chain.S(q) @ eta)[2])  # theta_n's rate: P_n's direction of motion turns at it
        return Point(float(t), faults, xp, xc, a, applied, omega)

    # ------------------------------------------------------------------------------------------ Jacobians
    def blocks(self, pt: Point, period: float | None = None, basis: np.ndarray | None = None) -> Blocks:
        """The loop's Jacobians at ``pt`` (``period``: the sample time a discrete update is linearized for;
        ``basis``: a parameter block's basis to use, from :attr:`Blocks.basis` of the same point).

        Each point once: the same time, faults, plant and controller states, held signal, turning rate,
        period and basis (their exact bytes) give the blocks already computed, as a copy (the limits are
        searched at the first phase's worst instant, which with the healthy pattern and no run is that
        phase's point itself).
        """
        key = _point_key(pt, period, basis)
        if key not in self._linearized_at:
            self._linearized_at[key] = self._blocks(pt, period, basis)
        return copy.copy(self._linearized_at[key])

    def _blocks(self, pt: Point, period: float | None, basis: np.ndarray | None) -> Blocks:
        """:meth:`blocks` computed."""
        ny = self.n_q + 2
        fz, t = pt.faults, pt.t
        Fx = self.plant.state_columns(pt.xp, pt.a, fz)
        Fa = self.plant.input_columns(pt.xp, pt.a, fz)
        na = pt.a.size
        y0 = pt.xp[:ny].copy()
        lin = self._lin_index
        at = self._lin  # the same states, for indexing

        xp1, y1, xc1 = pt.xp[None, :], y0[None, :], pt.xc[None, :]

        held_at = self._held_index

        def with_c(C):  # the controller states with their linearized entries the rows of C (one pass)
            XC = np.empty((C.shape[0], pt.xc.size))
            XC[:, held_at] = pt.xc[held_at]
            XC[:, at] = C
            return XC

        # [a, c'] at batches of points (:meth:`_rows_at`): the measurement, the true state or the scheme's states varied
        Gy = central_rows(lambda Y: self._rows_at(t, xp1, Y, xc1, fz), y0)
        self._finite(pt, Fx=Fx, Fa=Fa, Gy=Gy)
        motor_faults = self.plant.motors is not None and fz.motor.size and np.any(fz.motor != _healthy_row())
        Gx = None  # zero unless the motors are faulty (then the controller reads the true plant state)
        if motor_faults:  # the oracle is told the faults the chain sees, which depend on the wheel speeds
            Gx = central_rows(lambda X: self._rows_at(t, X, y1, xc1, fz), pt.xp)
            if not np.any(Gx):
                Gx = None
        c0 = pt.xc[at]
        g_c = lambda C: self._rows_at(t, xp1, y1, with_c(C), fz)  # noqa: E731
        g_z = lambda XC: self._rows_at(t, xp1, y1, XC, fz)  # noqa: E731  (rows of the whole state)
        disc = None
        if self.has_disc:
            if period is None:
                raise ModelError(f"scheme {self.scheme}: its discrete update needs a sample time to be linearized")
            disc = self._discrete_map(pt, period, at)
        elif lin.size and Gx is None:
            torque = lambda XC: self._rows_at(t, xp1, y1, XC, fz, rates=False)  # noqa: E731
            block = _parameter_block(g_z, c0, Gy, na, basis, torque, embed=(pt.xc, at, held_at))
            if block is not None:
                Gy_r, Gc_r, U = block
                self._finite(pt, Gy=Gy_r, Gc=Gc_r)
                rank = Gc_r.shape[1]
                return Blocks(
                    Fx, Fa, np.zeros((na + rank, Fx.shape[0])), Gy_r, Gc_r, np.eye(rank), np.zeros((rank, ny)), na,
                    dropped=int(lin.size - rank), parameter_block=int(lin.size), omega=pt.omega, frame=[(0, 1)],
                    basis=U,
                )  # fmt: skip
        Gc = central_rows(g_c, c0)
        self._finite(pt, Gx=Gx, Gc=Gc)
        if Gx is None:
            Gx = np.zeros((na + lin.size, self.plant.n_states))
        if disc is None:
            Dc, Dy = np.eye(lin.size), np.zeros((lin.size, ny))
        else:
            Dc, Dy = disc
        keep = relevant_states(Gx, Gy, Gc, Dc, Dy, na)
        out = np.setdiff1d(np.arange(lin.size), keep)  # left out: their own block decides internal stability
        sel = np.concatenate((np.arange(na), na + keep))
        kept = [int(lin[k]) for k in keep]
        where = {i: Fx.shape[0] + k for k, i in enumerate(kept)}
        frame = [(0, 1)] + [(where[i], where[j]) for i, j in _world_pairs(self.ctrl) if i in where and j in where]
        return Blocks(
            Fx, Fa, Gx[sel], Gy[sel], Gc[np.ix_(sel, keep)], Dc[np.ix_(keep, keep)], Dy[keep], na,
            kept=kept, dropped=int(lin.size - keep.size), omega=pt.omega, frame=frame,
            internal=Gc[na:][np.ix_(out, out)], internal_map=None if disc is None else Dc[np.ix_(out, out)],
        )  # fmt: skip

    def _discrete_map(self, pt: Point, period: float, lin: slice | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Dc, Dy): the Jacobian of the discrete update c <- d(c, y) at pt for samples ``period`` apart.

        The UKF scheme's through its filter step's derivative (:meth:`_ukf_map`); any other by central
        differences of the update.
        """
        ny = self.n_q + 2
        xc0 = pt.xc.copy()
        y0 = pt.xp[:ny].copy()
        if self._ukf_law is not None and float(pt.t) - xc0[self.ctrl._t.start] > 0.0:
            return self._ukf_map(pt, lin)

        def d(Y, C):  # the update at rows of (Y, C), C the linearized states
            XC = np.repeat(xc0[None, :], max(Y.shape[0], C.shape[0]), axis=0)
            XC[:, lin] = C
            return self._discrete_rows(pt.t, Y, XC)[:, lin]

        Dc = central_rows(lambda C: d(y0[None, :], C), xc0[lin])
        Dy = central_rows(lambda Y: d(Y, xc0[lin][None, :]), y0)
        return Dc, Dy

    def _ukf_map(self, pt: Point, lin: slice | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""(Dc, Dy) of the UKF scheme's update ``c+ = L(E(c, y), y)``: the filter step by its derivative.

        The update (``control.active_law.ukf_discrete``) is the filter's step on the estimate x with the
        held command u and the measured q, ``x+ = s(x, u, q)`` (E: c with x replaced by x+), then the law
        (4.14) on the new estimates (L: the same compiled update called with no time elapsed since its
        sample computes the law alone; it overwrites the held command and leaves x+ as it is).  The central
        difference of the whole update along column j, ``(L(E(c + h e_j)) - L(E(c - h e_j))) / 2 h``, is
        taken with E to first order, ``E(c +- h e_j) = E(c) +- h E_c e_j`` (E_c from
        :func:`~ftcreport.observers.ukf_compiled.ukf_step_jacobian`, the filter's derivative with its
        covariance held): L is differenced along the direction the step gives the perturbation, with
        the same h, and the rows of x+ are E_c's own.  So the law sees what it saw when the whole update
        was differenced, to O(h^2) (the clips of the law sit on the estimates: sigma_hat = clip(rho, 0,
        1) with rho at the truth, 1 or 0; across such a kink a difference depends on where its two points
        fall, and these fall where they fell), and the step costs one filter step and its derivative
        instead of 2 (nx + 2n + N + 2) filter steps (112 for six robots, 0.25 ms each).
        tests/test_linear_loop.py compares the two.
        """
        from ..observers.ukf_compiled import ukf_message, ukf_step_jacobian

        ctrl, law = self.ctrl, self._ukf_law
        nq, ny = self.n_q, self.n_q + 2
        nx, nw = int(law.ukf.nx), self.plant.nw
        t = float(pt.t)
        xc0 = pt.xc.copy()
        y0 = pt.xp[:ny].copy()
        est, held = ctrl._est, ctrl._u
        h = t - xc0[ctrl._t.start]  # as ukf_discrete computes it
        s = xc0[est.start : est.start + nx * (nx + 1)]
        J, status = ukf_step_jacobian(law.pf, law.ukf, s, xc0[held].copy(), y0[:nq].copy(), h, STEP)
        if status:
            raise ModelError(f"scheme {self.scheme}: {ukf_message(int(status))} (its step's derivative at t = {t:g} s)")
        xc1 = self.discrete(t, y0[:nq], y0[nq:], xc0)  # the step and the law; at xc1 no time has elapsed
        where = {int(i): k for k, i in enumerate(self.linearized)}
        rows = np.array([where[est.start + i] for i in range(nx)])
        cols = np.concatenate((rows, [where[i] for i in range(held.start, held.stop)]))
        n = len(self.linearized)
        Ec = np.eye(n)  # dE / dc and dE / dy: the step's derivative in x's rows, the identity elsewhere
        Ec[rows] = 0.0
        Ec[np.ix_(rows, cols)] = J[:, : nx + nw]
        Ey = np.zeros((n, ny))
        Ey[rows, :nq] = J[:, nx + nw :]
        c0, c1 = xc0[lin], xc1[lin]
        # the law's central differences along (v, w), the step's image of a perturbation: every point's
        # law in one compiled call (:meth:`_discrete_rows`), the columns of Dc and then of Dy
        zero = np.zeros(ny)
        dirs = [(Ec[:, j], zero, STEP * max(1.0, abs(c0[j]))) for j in range(n)]
        dirs += [(Ey[:, k], np.eye(ny)[k], STEP * max(1.0, abs(y0[k]))) for k in range(ny)]
        C = np.array([c1 + s * h * v for v, _w, h in dirs for s in (1.0, -1.0)])
        Y = np.array([y0 + s * h * w for _v, w, h in dirs for s in (1.0, -1.0)])
        XC = np.repeat(xc1[None, :], C.shape[0], axis=0)
        XC[:, lin] = C
        out = self._discrete_rows(t, Y, XC)[:, lin]
        D = np.column_stack([(out[2 * k] - out[2 * k + 1]) / (2.0 * h) for k, (_v, _w, h) in enumerate(dirs)])
        Dc, Dy = D[:, :n], D[:, n:]
        Dc[rows], Dy[rows] = Ec[rows], Ey[rows]  # x+ is the step's: its derivative, not its difference
        return Dc, Dy


#: a Jacobian entry beyond this makes the loop's matrix products overflow (1e150^2 = 1e300, near float's
#: 1.8e308): no physical loop's gain comes near it
_OVERFLOW = 1e150


def _point_key(pt: Point, period: float | None, basis: np.ndarray | None) -> tuple:
    """Everything :meth:`SchemeLoop.blocks` reads of its arguments, exactly (arrays by dtype, shape and bytes)."""
    arrays = (pt.xp, pt.xc, pt.a, pt.faults.sigma, pt.faults.ubar, pt.faults.motor)
    if basis is not None:
        arrays += (basis,)
    exact = tuple((a.dtype.str, a.shape, a.tobytes()) for a in map(np.asarray, arrays))
    return (float(pt.t), float(pt.omega), None if period is None else float(period), basis is None, exact)


def _healthy_row() -> np.ndarray:
    return np.array([1.0, 1.0, 0.0, 0.0])


def with_k_v(case, scheme: str, k_v: float):
    """The case with ``scheme``'s velocity gain set to k_v (a built-in table's or a plug-in's ``k_v``)."""
    cfg = getattr(case.schemes, scheme, None)
    if cfg is None:
        raise ModelError(f"scheme {scheme} is not configured in case {case.name}")
    if "k_v" not in type(cfg).model_fields:
        raise ModelError(f"scheme {scheme}: its parameters have no k_v to vary")
    new = cfg.model_copy(update={"k_v": float(k_v)})
    return case.model_copy(update={"schemes": case.schemes.model_copy(update={scheme: new})})


# ----------------------------------------------------------------------------------------------- layouts
def _layout(ctrl, nk: int) -> tuple[set[int], bool]:
    """(held, has_disc): the controller states held at the operating point, and whether the scheme's
    discrete update is a smooth map to linearize (the UKF's step and law) rather than a decision.

    Held: the kinematic frame (re-anchored by jumps), switching's selected model and dwell timer, the
    UKF's covariance and its last sample time, the Farza observer's sensitivity Y and gain P (4.4)-(4.11):
    at zero estimation error they multiply the innovation, zero, so they are decoupled exactly (their
    values still set the observer's gains).  A plug-in's discrete update (switches, projections, README
    "Write your own scheme") is held too: only its law's rates are linearized.
    """
    from ..control.active import ActiveController
    from ..control.switching import SwitchingController
    from ..observers.ukf import UKFEstimator

    held = set(range(nk))
    disc = False
    if isinstance(ctrl, SwitchingController):
        held |= {ctrl._sel, ctrl._tsw}
    elif isinstance(ctrl, ActiveController) and isinstance(ctrl.est, UKFEstimator):
        o = ctrl.est
        start = ctrl._est.start
        held |= set(range(start + o.nx, start + o.n_states))  # the covariance
        held |= set(range(ctrl._t.start, ctrl._t.stop))
        disc = True
    elif isinstance(ctrl, ActiveController):  # the Farza observer
        o, start = ctrl.est, ctrl._est.start
        held |= set(range(start + o._Y.start, start + o._P.stop))
    return held, disc


def _ukf_law(ctrl):
    """The UKF scheme's ``UkfLaw`` (observers.ukf_compiled: the filter's model and constants), None for any
    other scheme."""
    from ..control.active import ActiveController
    from ..observers.ukf import UKFEstimator

    if isinstance(ctrl, ActiveController) and isinstance(ctrl.est, UKFEstimator) and ctrl.discrete_time:
        return ctrl.P.ukf
    return None


def _world_pairs(ctrl) -> list[tuple[int, int]]:
    """Index pairs of xc holding world-frame vectors: an observer's estimate of P_n and of its velocity.

    A plug-in scheme's layout is unknown: none (its estimates, if any, are linearized in the world frame).
    """
    from ..control.active import ActiveController
    from ..observers.ukf import UKFEstimator

    if not isinstance(ctrl, ActiveController):
        return []
    e = ctrl._est.start
    if isinstance(ctrl.est, UKFEstimator):
        return [(e, e + 1)]
    N = ctrl.est.N
    return [(e, e + 1), (e + N, e + N + 1)]


def frames(kin, times, step: float = 0.01) -> dict[float, float]:
    """The chained law's frame psi at each of ``times`` as the controller holds it along the reference.

    psi starts at theta_nd(0) and re-anchors to theta_nd when |theta_nd - psi| exceeds the band
    (``kin_discrete``): stepped along the reference at ``step`` (the case's dt, at least 0.01 s: the
    engine re-anchors after every step; the band is 45 deg and the references turn a few degrees per
    0.01 s at most).  Empty for the two-link law (no frame).
    """
    if kin.n_states == 0:
        return {}
    ts = sorted(float(t) for t in times)
    xc = np.asarray(kin.initial_state(0.0, kin.reference.at(0.0).q_d), dtype=float)
    walk, ends, t = [], [], 0.0
    for target in ts:  # the steps up to each instant, the instant itself last
        walk += [np.arange(t, target, step)[1:] if target > t else np.zeros(0), np.array([target])]
        ends.append(sum(w.size for w in walk) - 1)
        t = target
    steps = np.concatenate(walk) if walk else np.zeros(0)
    if hasattr(kin, "discrete_along"):  # one compiled walk: 4,000 steps of 0.03 ms from Python for 80 s
        psi = kin.discrete_along(steps, xc)
    else:
        psi = np.empty(steps.size)
        for k, s in enumerate(steps):
            xc = kin.discrete(float(s), None, xc)
            psi[k] = xc[0]
    return {target: float(psi[e]) for target, e in zip(ts, ends, strict=True)}


def operating_state(loop: SchemeLoop, t: float, q, eta, fz: Faults, psi=None, applied=None, run_xc=None,
                    period=None) -> tuple[np.ndarray, list | None]:  # fmt: skip
    """The controller state at the operating point, and the pattern the law applies there.

    With ``run_xc`` (the run's logged controller state at t) the scheme's own states are the run's,
    except the estimates of the plant's state, which are put on the plant's (zero estimation error:
    the linearization is about the reference).  Without a run: switching applies ``applied`` (the
    model its run selected, else the model of the true pattern, else the nearest bank model), the
    adaptive weights sit on that design with the friction estimate at the true friction, the
    observers' estimates at the truth (q, eta, gains, frictions), their gains at their initial value.
    Returns the state and the applied pattern (None for a law that does not apply one).
    """
    from ..control.active import ActiveController
    from ..control.adaptive import AdaptiveController
    from ..control.baselines import OracleController
    from ..control.switching import SwitchingController
    from ..control.tracking import TrackingController

    ctrl = loop.ctrl
    nk = loop.nk
    sigma_t, ubar_t = loop.plant.true_faults(np.concatenate((q, eta, np.zeros(loop.plant.nm))), fz)
    xc = np.asarray(ctrl.initial_state(t, q, eta), dtype=float).copy()
    if run_xc is not None and len(run_xc) == xc.size and np.all(np.isfinite(run_xc)):
        xc[nk:] = run_xc[nk:]
    if nk:
        xc[:nk] = psi if psi is not None else np.asarray(ctrl.kin.initial_state(t, q), dtype=float)
    own = run_xc is not None
    pattern = None
    if isinstance(ctrl, SwitchingController):
        if applied is None:
            applied = nearest_model(ctrl.patterns, sigma_t)
        xc[ctrl._sel] = float(applied)
        xc[ctrl._tsw] = t - 1e9
        pattern = [float(v) for v in ctrl.patterns[int(applied)]]
    elif isinstance(ctrl, AdaptiveController):
        if not own:
            k = nearest_model(ctrl.patterns, sigma_t)
            chi = np.zeros((ctrl.N, ctrl.chain.n_wheels))
            chi[k] = 1.0
            xc[ctrl._chi] = chi.ravel()
            xc[ctrl._uf] = ubar_t
        pattern = [float(v) for v in ctrl.patterns[int(np.argmax(xc[ctrl._chi].reshape(ctrl.N, -1).sum(axis=1)))]]
        xc[ctrl._chi] = _inside(xc[ctrl._chi].reshape(ctrl.N, -1)).ravel()
    elif isinstance(ctrl, ActiveController):
        xc, pattern = _observer_point(loop, ctrl, t, q, eta, sigma_t, ubar_t, xc, own, period)
    elif isinstance(ctrl, OracleController):
        pattern = [float(v) for v in sigma_t]
    elif isinstance(ctrl, TrackingController):
        pattern = [float(v) for v in ctrl.sigma]
    return xc, pattern


def _observer_point(loop, ctrl, t, q, eta, sigma_t, ubar_t, xc, own: bool, period) -> tuple[np.ndarray, list]:
    """An active scheme's state: its estimates of q and eta on the plant's, its parameter estimates at
    the truth (or the run's), its estimate filters converged.

    The UKF scheme runs at the samples: its state before the update at t is the previous sample's,
    so its estimates sit on the reference at ``t - T`` and its held command is the law's there (its
    update run with no time elapsed computes just the law); the update at t then predicts over T
    and meets the measurement at t with (almost) no innovation.
    """
    from ..observers.ukf import UKFEstimator

    o = ctrl.est
    nw = ctrl.chain.n_wheels
    est = xc[ctrl._est].copy()
    params = np.concatenate(([sigma_t] if o.est_rho else []) + ([ubar_t] if o.est_ubar else [])) if o.p else _EMPTY
    if isinstance(o, UKFEstimator):
        T = loop.case.simulation.dt if period is None else period
        r = ctrl.kin.reference.at(float(t) - T)
        q_prev, eta_prev = np.asarray(r.q_d, dtype=float), np.asarray(r.eta_d, dtype=float)
        x = est[: o.nx]
        x[: o.N] = q_prev
        x[o.N : o.N + 2] = eta_prev
        if not own:
            x[o.N + 2 :] = params
        est[: o.nx] = x
        xc[ctrl._est] = est
        xc[ctrl._t] = t - T  # no time elapsed: the update computes the law on these estimates only
        xc[ctrl._u] = loop.discrete(t - T, q_prev, eta_prev, xc)[ctrl._u]
    else:
        N = o.N
        est[:N] = q
        est[N : 2 * N] = ctrl.chain.S(q) @ eta
        if not own:
            est[o._rho] = params
        xc[ctrl._est] = est
    if ctrl.tau is not None and not own:
        xc[ctrl._filt] = np.concatenate((sigma_t, ubar_t))
    rho = xc[ctrl._filt][:nw] if ctrl.tau is not None else (sigma_t if not o.est_rho else _rho_of(o, xc[ctrl._est]))
    return xc, [float(v) for v in np.clip(rho, 0.0, 1.0)]


def _rho_of(o, est: np.ndarray) -> np.ndarray:
    from ..observers.ukf import UKFEstimator

    if isinstance(o, UKFEstimator):
        return est[o.N + 2 : o.N + 2 + o.nw]
    return est[o._rho][: o.nw]


def _inside(chi: np.ndarray) -> np.ndarray:
    """Adaptive weights (designs x wheels) moved inside [0, 1], each wheel's sum kept.

    The projection of (3.117) freezes a weight at 0 or 1 that is pushed outwards: at a bound the law
    is one-sided, and a central difference would average its two sides.  The interior side is the
    linearization, so every weight is put ``delta = min(1e-3, 0.1 / N)`` inside (N designs; far beyond
    the differences' step) and the largest weight of each wheel gives up what the others gained: a
    wheel's weights keep their sum, so the torque of a matched mixture is unchanged.
    """
    N = chi.shape[0]
    delta = min(WEIGHT_INSIDE, 0.1 / max(N, 1))
    out = np.clip(chi, delta, 1.0 - delta)
    top = np.argmax(chi, axis=0)
    cols = np.arange(chi.shape[1])
    out[top, cols] -= out.sum(axis=0) - chi.sum(axis=0)
    return np.clip(out, delta, 1.0 - delta)


def nearest_model(patterns: np.ndarray, sigma: np.ndarray) -> int:
    """The bank model closest to the effectiveness sigma (least squares; the lowest index on a tie)."""
    d = np.sum((np.asarray(patterns, dtype=float) - np.asarray(sigma, dtype=float)[None, :]) ** 2, axis=1)
    return int(np.flatnonzero(d <= d.min() * (1 + 1e-12) + 1e-15)[0])


# ----------------------------------------------------------------------------------------------- reduction
def relevant_states(Gx, Gy, Gc, Dc, Dy, na: int) -> np.ndarray:
    """The scheme states (indices into c) that both reach the plant and are reached by it.

    Directed graph on the states: an edge j -> i where a Jacobian entry says i's rate (or update)
    reads j.  A state the plant cannot reach (no path from q, eta, i_a) stays at its operating value
    whatever the plant does; one that cannot reach the plant (no path to a) changes nothing the plant
    sees.  Either way A is block-triangular with that state in a diagonal block of its own, so the
    loop's poles are exactly those of the remaining states; the rest (the Farza observer's Y and P
    at zero estimation error, a frozen weight) are modes the tracking error cannot see.
    """
    nc = Gc.shape[1]
    if nc == 0:
        return np.zeros(0, dtype=int)
    dep = (Gc[na:] != 0) | (Dc != np.eye(nc))  # dep[i, j]: state i reads state j
    from_plant = np.any(Gy[na:] != 0, axis=1) | np.any(Gx[na:] != 0, axis=1) | np.any(Dy != 0, axis=1)
    to_plant = np.any(Gc[:na] != 0, axis=0)
    reached = _closure(dep, from_plant)  # i reached if it reads a reached state
    reaches = _closure(dep.T, to_plant)  # j reaches if a state that reaches reads it
    return np.flatnonzero(reached & reaches)


def _closure(dep: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """States reachable from ``seed`` along ``dep[i, j]`` (i reads j): i joins when it reads a member."""
    member = seed.copy()
    while True:
        new = member | np.any(dep[:, member], axis=1)
        if np.array_equal(new, member):
            return member
        member = new


def _parameter_block(g, c0: np.ndarray, Gy: np.ndarray, na: int, basis: np.ndarray | None = None, torque=None,
                     embed=None):  # fmt: skip
    r"""Scheme states without dynamics of their own, replaced by the part of their image the loop reaches.

    When the states c have ``dc'/dc = 0`` at the point and reach the plant only through a (the
    adaptive weights and friction estimate of (3.113)-(3.120) at zero error: their rates are
    proportional to eta_e), the loop sees them only through ``z = K_c c`` (``K_c = da/dc``), and
    ``z' = K_c c' = W y`` with ``W = K_c G_cy``.  z moves only within range(W): with U an orthonormal
    basis of it, ``xi = U^T z`` carries every pole the plant can excite and see, exactly::

        xi' = U^T W y,        a = G_ay y + U xi

    The other modes are constant: weight combinations that leave the torque unchanged, and torque
    offsets the adaptation never moves (both block-triangular, eigenvalue 0, outside the loop).  The
    check that the rates do not read the states probes two random directions.  Costs O(ny) law
    evaluations instead of O(len(c)) (7,670 weights for five robots): W is differenced along a basis of
    range(G_cy), which the rates' dependence on y through eta_e makes 2-dimensional for the adaptive law.
    ``g(C)`` returns [a, c'] at the point's measurement for each row of C (a batch:
    :func:`directional_rows`), ``torque(C)`` its a columns alone (default: from g), ``Gy`` its Jacobian in
    y (a rows first); ``embed``: as :func:`directional_rows`' (then g and torque take rows of the whole
    state).  Returns (Gy, Gc) of [a, xi] and the basis U (``basis``: use this one, e.g. the same loop's
    at another gain), or None when the states have dynamics of their own (then each is differentiated).
    """
    V = _probes(c0.size)
    norm = math.sqrt(float(np.sum(c0 * c0)))  # every direction below differentiates at c0
    outs = directional_rows(g, c0, V, x0_norm=norm, embed=embed)
    scale = max(1.0, float(np.abs(outs[:na]).max()))
    if np.abs(outs[na:]).max() > 1e-7 * scale:
        return None  # the states' rates read the states: differentiate them all
    # W = K_c G_cy: the torque's rate along each measurement direction.  K_c is differenced along a basis
    # of range(G_cy) only, G_cy = D R (:func:`_range`): the rates read y through few combinations (the
    # adaptive law's through eta_e: 2, against ny = n + 4 columns), so 2 rank law evaluations, not 2 ny
    torque = (lambda C: g(C)[:, :na]) if torque is None else torque
    D, R = _range(Gy[na:])
    W = directional_rows(torque, c0, D, x0_norm=norm, embed=embed) @ R
    if basis is None:
        U, s, _ = np.linalg.svd(W, full_matrices=False)
        # directions below 1e-6 of the largest are the differences' error (~1e-9 here), not dynamics
        rank = int(np.sum(s > 1e-6 * max(float(s.max()) if s.size else 0.0, 1e-300)))
        basis = U[:, :rank]
    rank = basis.shape[1]
    return np.vstack((Gy[:na], basis.T @ W)), np.vstack((basis, np.zeros((rank, rank)))), basis


#: directions of a rate Jacobian below this fraction of its largest singular value are the central
#: differences' noise (1e-8 on the six-robot adaptive law, whose next one is 1.3e-2), not a direction it reads
RANGE_FLOOR = 1e-6


def _range(G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D, R) with ``G = D R`` up to the singular values of G below :data:`RANGE_FLOOR` of its largest:
    ``D = G V`` and ``R = V^T``, V the eigenvectors of ``G^T G`` (ny x ny) above the floor squared.

    The Gram matrix instead of an SVD of G itself: 0.4 ms against 2.5 ms on the adaptive law's 36,852 rows
    (its eigenvalues carry an error of eps times the largest, 1e-16, far below the floor's 1e-12).
    """
    if not G.size:
        return np.zeros((G.shape[0], 0)), np.zeros((0, G.shape[1]))
    lam, V = np.linalg.eigh(G.T @ G)
    V = V[:, lam > RANGE_FLOOR**2 * max(float(lam.max()), 1e-300)]
    return G @ V, V.T


_PROBES: dict[int, np.ndarray] = {}


def _probes(size: int, probes: int = 2) -> np.ndarray:
    """:func:`_parameter_block`'s random unit directions (seed 0), drawn once per size (36,852 weights: 2 ms).

    Two: a rate that reads the states shows in either, unless orthogonal to both.
    """
    if size not in _PROBES:
        V = np.random.default_rng(0).standard_normal((size, probes))
        V /= np.sqrt(np.sum(V * V, axis=0))
        V.flags.writeable = False
        _PROBES[size] = V
    return _PROBES[size]
