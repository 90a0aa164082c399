r"""Simulation engine: plant and controller integrated together.

The plant is the reduced dynamics (2.70) of a :class:`~ftcreport.model.Chain`
with the actuator fault model (2.102) and optional torque saturation::

    qdot   = S(q) eta
    etadot = Mbar1^-1 (Bbar tau - Mbar2 eta - Cbar),   tau = sigma sat(u) + ubar

A controller (any object following :class:`Controller`) has its own
continuous state ``xc``; plant and controller state are stepped together by
fixed-step classical RK4 (``method="rk4"``, the default) or by the two-stage
Rosenbrock W-method ROS2 (``method="ros2"``) for stiff velocity loops.

ROS2 (Verwer, Spee, Blom, Hundsdorfer 1999), with gamma = 1 + 1/sqrt(2)::

    (I - gamma h A) k1 = f(t, y)
    (I - gamma h A) k2 = f(t + h, y + h k1) - 2 k1
    y+ = y + 3/2 h k1 + 1/2 h k2

is second order for any matrix A (a W-method) and L-stable when A is the
Jacobian.  Here A holds only the columns of the plant velocities eta (forward
differences, 2 extra evaluations per step): the stiffness of these closed
loops is the velocity-error gain (k4 = 3000 in thesis 3.2.3 gives an eigenvalue
-3000, ERRATA E12f, so RK4 needs dt < 0.93 ms), and it lives in those columns.
A controller may add the exact diagonal of the Jacobian of its own linear
states (``stiff_diagonal``, e.g. -gamma for reconstruction filters); with it a
matched reconstruction error obeys the W-method recursion of e' = -gamma e and
stays exactly zero, as it does under RK4.  Solving with A = F E^T + diag(a)
is a 2 x 2 solve (Woodbury).  The fast transient of
the velocity loop is then damped rather than resolved: tracking errors agree
with fine-step RK4 (tested), first-instant torque peaks do not (they last
~1/k4 s).  With DC motors, ``method="etd2"`` (compiled engine
only, :func:`ftcreport.fast.loop._etd2`) is the exponential ETD2RK of Cox & Matthews (2002): exact
on the linear [eta, i_a] block, so a current's transient after a held-voltage step is integrated
whole over a step of one control sample, where ROS2 only damps it.

Fault events land exactly on step boundaries: the time grid is ``t0 + k dt``
with every event time inserted (the step before an event is shortened), and
sigma, ubar are held over each step at their value at its start, so the fault
model is exact.  After each step the controller's
discrete hook runs (switching logic and the like).

A run that approaches a singular configuration (an articulation angle
within ``singularity_margin`` of 90 deg, ERRATA P4, or a controller singular at
the accepted state) stops with status ``"singular"``; a non-finite or
out-of-bounds state stops with ``"diverged"``.  A step that blows up stops with
``"step_unstable"`` and a reason naming ``dt``, never as a singularity: either a
trial stage of the integrator left the domain (a controller singularity, a
non-finite value) while the accepted state at the step's start is regular, or
the new state fails a check that the accepted state was far from (a speed or
position bound crossed from within ``JUMP_FRACTION`` of it, the singular set
reached from ``JUMP_MARGINS`` margins away: a change no resolved step makes), or
the applied torque grew geometrically from accepted step to accepted step
(max_j |tau_j| more than ``GROWTH_FACTOR`` = e times larger than at the step
before, ``GROWTH_STEPS`` = 3 steps in a row, ``GROWTH_TOTAL`` = 20 times larger
overall, ending above ``GROWTH_FLOOR`` = 1 N m).  Growth by e per step is a rate
of 1 / dt: a mode with lambda dt > 1 is not resolved by the step (RK4's local
error on it is about (lambda dt)^5 / 120 per step, 1 % at lambda dt = 1 and
growing fast), so either the integrator is unstable there or the run is not
converged in dt.  A fault that makes the torque jump is one step of growth, not
three.  A slower blow-up ends as ``"diverged"`` at the speed or position bound,
with ``dt`` named in the reason: a resolved exponential growth, such as
e^(50 t) at dt = 0.01 s (1.65x per step), is divergence, not a step problem.
The log up to that point is kept and the reason is
recorded; a NaN is never returned silently.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .errors import (
    DivergenceError,
    FtcError,
    ModelError,
    SingularityError,
    articulation_reason,
    bound_reason,
    nonfinite_reason,
    step_growth_reason,
    trial_stage_reason,
    with_step,
)
from .model import kernels as K
from .model.chain import Chain
from .model.faults import FaultSchedule
from .runs import (
    GROWTH_FACTOR,
    GROWTH_FLOOR,
    GROWTH_STEPS,
    GROWTH_TOTAL,
    JUMP_FRACTION,
    JUMP_MARGINS,
    REDUCED_SIGNALS,
    STATUS_DIVERGED,
    STATUS_ERROR,
    STATUS_OK,
    STATUS_SINGULAR,
    STATUS_STEP_UNSTABLE,
    STREAM_SIGNALS,
    Run,
    step_jump_words,
    stream_of,
)

__all__ = [
    "REDUCED_SIGNALS",
    "STREAM_SIGNALS",
    "Controller",
    "Plant",
    "Run",
    "SimSettings",
    "simulate",
    "stream_of",
    "time_grid",
]

_NUMERIC_ERRORS = (DivergenceError, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError)


@runtime_checkable
class Controller(Protocol):
    """What the engine needs of a controller.

    Attributes
    ----------
    n_states : int
        Length of the controller's continuous state ``xc`` (may be 0).
    signal_names : tuple of str
        Names of the signals :meth:`signals` returns, logged at log instants.
    """

    n_states: int
    signal_names: tuple[str, ...]

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """Controller state at the start of the run, (n_states,)."""
        ...

    def evaluate(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Control signal u (2n,) and controller state derivative (n_states,)."""
        ...

    def discrete(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """Discrete update after each step (e.g. switching); return xc (possibly unchanged)."""
        ...

    def signals(self, t: float, q: np.ndarray, eta: np.ndarray, xc: np.ndarray) -> dict[str, np.ndarray]:
        """Named signals to log at this instant (keys are :attr:`signal_names`)."""
        ...


@dataclass(frozen=True)
class SimSettings:
    """Settings of one simulation run.

    Attributes
    ----------
    dt : float
        Nominal RK4 step [s].
    duration : float
        Simulated time [s].
    t0 : float
        Start time [s].
    log_every : int
        Log one step in ``log_every`` (decimation); the last step is always logged.
    singularity_margin : float
        Stop when an articulation angle comes within this many rad of 90 deg.
    max_speed : float
        Stop (diverged) when |v_n| or |omega_1| exceeds this [m/s, rad/s].
    max_position : float
        Stop (diverged) when |x| or |y| exceeds this [m].
    method : str
        ``"rk4"`` (classical, fixed step), ``"ros2"`` (Rosenbrock W-method, stiff-capable) or
        ``"etd2"`` (exponential ETD2RK, exact on the linear [eta, i_a] block: the motor cases at
        one step per control sample; compiled engine only, fast.loop._etd2).
    sample_time : float or None
        Sampled (digital) control: the controller runs every ``sample_time`` [s], a whole number
        of steps, its command held in between (zero-order hold) and its own state advanced by a
        forward-Euler step per sample; the plant integrates at ``dt``.  None: continuous-time
        control (the law evaluated at every stage of the step).
    measurement_delay : int
        Sampled control only: the controller sees the measurements taken this many samples before
        (the first sample's until there is one that old).
    """

    dt: float
    duration: float
    t0: float = 0.0
    log_every: int = 1
    singularity_margin: float = math.radians(2.0)
    max_speed: float = 1e3
    max_position: float = 1e6
    method: str = "rk4"
    sample_time: float | None = None
    measurement_delay: int = 0

    def __post_init__(self) -> None:
        if self.method not in ("rk4", "ros2", "etd2"):
            raise ModelError(f"method: must be 'rk4', 'ros2' or 'etd2', got {self.method!r}")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ModelError(f"dt: must be a positive number of seconds, got {self.dt}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ModelError(f"duration: must be a positive number of seconds, got {self.duration}")
        if self.dt > self.duration:
            raise ModelError(f"dt: {self.dt} s is longer than the duration {self.duration} s")
        if int(self.log_every) < 1:
            raise ModelError(f"log_every: must be >= 1, got {self.log_every}")
        if not 0 <= self.singularity_margin < math.pi / 2:
            raise ModelError(f"singularity_margin: must be in [0, pi/2) rad, got {self.singularity_margin}")
        if int(self.measurement_delay) != self.measurement_delay or self.measurement_delay < 0:
            raise ModelError(f"measurement_delay: must be a whole number of samples >= 0, got {self.measurement_delay}")
        if self.measurement_delay and self.sample_time is None:
            raise ModelError(f"measurement_delay: {self.measurement_delay} samples needs sampled control (sample_time)")
        if self.sample_time is not None:
            ratio = self.sample_time / self.dt
            if not (math.isfinite(ratio) and ratio >= 1 - 1e-9 and abs(ratio - round(ratio)) <= 1e-9 * ratio):
                raise ModelError(
                    f"sample_time: {self.sample_time} s is not a whole number of steps dt = {self.dt} s "
                    "(the plant integrates at dt between the controller's samples)"
                )


class Plant:
    """True chain, fault schedule and actuator saturation.

    Parameters
    ----------
    chain : Chain
        The true physical parameters (the controller may hold different ones).
    faults : FaultSchedule, optional
        Actuator faults; healthy wheels when omitted.
    saturation : float, optional
        Symmetric limit on every wheel's control signal |u_j| [N m], applied
        before the fault model: tau = sigma sat(u) + ubar.
    noise_q : (n + 2,) array_like, optional
        Standard deviations of the measurement noise on q [m, m, rad, ...]: the
        controller sees q + noise, drawn once per step (a sampled sensor held
        over the step), seeded.
    noise_eta : (2,) array_like, optional
        Standard deviations of the noise on the measured eta [m/s, rad/s].
    seed : int
        Seed of the noise generator (runs are reproducible).
    motors : MotorParams or sequence of MotorParams, optional
        A DC motor per wheel (one set per robot, leader first), thesis (2.26)-(2.29): the command
        becomes armature voltages (the driver's static inversion, ftcreport.fast.motor) and the
        wheel torque follows the currents.  None: the ideal torque plant (tau = command).
    """

    def __init__(
        self,
        chain: Chain,
        faults: FaultSchedule | None = None,
        saturation: float | None = None,
        noise_q=None,
        noise_eta=None,
        seed: int = 0,
        motors=None,
    ):
        self.chain = chain
        self.motors = motors
        self.faults = faults if faults is not None else FaultSchedule(chain.n)
        if self.faults.n != chain.n:
            raise ModelError(f"faults: schedule is for {self.faults.n} robots, chain has {chain.n}")
        if saturation is not None and not (math.isfinite(saturation) and saturation > 0):
            raise ModelError(f"saturation: must be a positive torque [N m], got {saturation}")
        self.saturation = saturation
        nq = np.zeros(chain.n_q) if noise_q is None else np.broadcast_to(np.asarray(noise_q, float), (chain.n_q,))
        ne = np.zeros(2) if noise_eta is None else np.broadcast_to(np.asarray(noise_eta, float), (2,))
        if np.any(nq < 0) or np.any(ne < 0) or not (np.all(np.isfinite(nq)) and np.all(np.isfinite(ne))):
            raise ModelError("noise: standard deviations must be finite and >= 0")
        self.noise_std = np.concatenate((nq, ne))
        self.noisy = bool(np.any(self.noise_std > 0))
        self.seed = int(seed)

    def draw_noise(self, rng: np.random.Generator) -> np.ndarray:
        """Measurement noise of one step, (n + 4,) = [q noise, eta noise]."""
        if not self.noisy:
            return np.zeros_like(self.noise_std)
        return rng.standard_normal(self.noise_std.shape[0]) * self.noise_std

    def torque(self, u: np.ndarray, sigma: np.ndarray, ubar: np.ndarray) -> np.ndarray:
        """Applied torque tau = sigma sat(u) + ubar (2.102)."""
        if self.saturation is not None:
            u = np.clip(u, -self.saturation, self.saturation)
        return sigma * u + ubar

    def rhs(self, t: float, x: np.ndarray, u: np.ndarray, params: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Plant state derivative in python-control order ``f(t, x, u, params)``.

        ``x = [q, eta]``, ``params = (sigma, ubar)``.
        """
        nq = self.chain.n_q
        tau = self.torque(u, *params)
        qdot, etadot = K.eta_dot(self.chain.params, x[:nq], x[nq:], tau)
        return np.concatenate((qdot, etadot))


def time_grid(t0: float, duration: float, dt: float, breakpoints=()) -> np.ndarray:
    """Step boundaries ``t0 + k dt`` with every breakpoint inside inserted exactly.

    Grid points closer than ``1e-6 dt`` to a breakpoint are replaced by it, so a
    fault at t = 20 s starts a step at exactly 20.0 whatever dt is.
    """
    t_end = t0 + duration
    n = math.floor(duration / dt + 1e-9)
    grid = t0 + dt * np.arange(n + 1)
    if t_end - grid[-1] > 1e-6 * dt:
        grid = np.append(grid, t_end)
    else:
        grid[-1] = t_end
    bps = np.array([b for b in breakpoints if t0 < b < t_end], dtype=float)
    if bps.size:
        close = np.min(np.abs(grid[:, None] - bps[None, :]), axis=1) < 1e-6 * dt
        grid = np.union1d(grid[~close], bps)
    return grid


def simulate(
    plant: Plant,
    controller: Controller,
    q0: np.ndarray,
    eta0: np.ndarray,
    settings: SimSettings,
    progress: Callable[[float], None] | None = None,
    engine: str = "auto",
) -> Run:
    """Integrate plant and controller with fixed-step RK4 or ROS2.

    Parameters
    ----------
    plant : Plant
    controller : Controller
    q0 : (n + 2,) array_like
        Initial configuration ``[x, y, theta_n, ..., theta_1]``.
    eta0 : (2,) array_like
        Initial ``[v_n, omega_1]``.
    settings : SimSettings
    progress : callable, optional
        Called with the simulated time now and then (every ~1 % of the run).
    engine : str
        ``"python"``: the loop below (the reference implementation);
        ``"compiled"``: the same loop in machine code (:mod:`ftcreport.fast`),
        for the controllers it knows; ``"auto"`` (default): compiled when the
        controller has a compiled counterpart, else Python.

    Returns
    -------
    Run
        Always returned; ``run.status`` says whether it completed.
    """
    chain = plant.chain
    p = chain.params
    nq, nw, nc = chain.n_q, chain.n_wheels, int(controller.n_states)
    q0 = np.asarray(q0, dtype=float)
    eta0 = np.asarray(eta0, dtype=float)
    if q0.shape != (nq,):
        raise ModelError(f"q0: expected {nq} values [x, y, theta_n..theta_1], got shape {q0.shape}")
    if eta0.shape != (2,):
        raise ModelError(f"eta0: expected 2 values [v_n, omega_1], got shape {eta0.shape}")

    grid = time_grid(settings.t0, settings.duration, settings.dt, plant.faults.times)
    n_steps = grid.shape[0] - 1
    every = int(settings.log_every)
    log_idx = np.unique(np.append(np.arange(0, n_steps + 1, every), n_steps))
    n_log = log_idx.shape[0]
    is_logged = np.zeros(n_steps + 1, dtype=bool)
    is_logged[log_idx] = True
    if engine not in ("auto", "python", "compiled"):
        raise ModelError(f"engine: must be 'auto', 'python' or 'compiled', got {engine!r}")
    if engine != "python":
        from .fast.engine import compiled_spec, simulate_compiled

        spec = compiled_spec(controller)
        if spec is not None:
            run = simulate_compiled(spec, plant, q0, eta0, settings, grid, log_idx, progress)
            run.meta["fault_schedule"] = _fault_records(plant)
            return run
        if engine == "compiled":
            raise ModelError(f"engine: {type(controller).__name__} has no compiled counterpart")
    if plant.motors is not None:
        raise ModelError(
            f"actuators: the DC-motor plant runs on the compiled engine; {type(controller).__name__} "
            f"{'has no compiled counterpart' if engine != 'python' else 'was asked to run in the Python loop'}"
        )
    if settings.method == "etd2":
        raise ModelError(
            f"method: 'etd2' runs on the compiled engine; {type(controller).__name__} "
            f"{'has no compiled counterpart' if engine != 'python' else 'was asked to run in the Python loop'}"
        )
    if settings.sample_time is not None:
        raise ModelError(
            f"sample_time: sampled control runs on the compiled engine; {type(controller).__name__} "
            f"{'has no compiled counterpart' if engine != 'python' else 'was asked to run in the Python loop'}"
        )

    xc0 = np.asarray(controller.initial_state(grid[0], q0, eta0), dtype=float).reshape(nc)
    x = np.concatenate((q0, eta0, xc0))

    names = tuple(controller.signal_names)
    first = controller.signals(grid[0], q0, eta0, xc0)
    logs: dict[str, np.ndarray] = {
        "q": np.full((n_log, nq), np.nan),
        "eta": np.full((n_log, 2), np.nan),
        "u": np.full((n_log, nw), np.nan),
        "tau": np.full((n_log, nw), np.nan),
        "sigma": np.full((n_log, nw), np.nan),
        "ubar": np.full((n_log, nw), np.nan),
        "xc": np.full((n_log, nc), np.nan),
    }
    for name in names:
        logs[name] = np.full((n_log, *np.shape(first[name])), np.nan)
    t_log = np.full(n_log, np.nan)

    def deriv(t: float, xs: np.ndarray, hold: tuple):
        sigma, ubar, nz = hold
        q, eta, xc = xs[:nq], xs[nq : nq + 2], xs[nq + 2 :]
        u, xcdot = controller.evaluate(t, q + nz[:nq], eta + nz[nq:], xc)
        tau = plant.torque(u, sigma, ubar)
        qdot, etadot = K.eta_dot(p, q, eta, tau)
        return np.concatenate((qdot, etadot, xcdot)), u, tau

    if settings.method == "rk4":
        step = _step_rk4
    else:
        diag = np.zeros(nq + 2 + nc)
        stiff = getattr(controller, "stiff_diagonal", None)
        if stiff is not None:
            diag[nq + 2 :] = np.asarray(stiff, dtype=float)
        step = _make_ros2(nq, diag)
    observe = getattr(controller, "observe_faults", None)  # the oracle is told the true faults
    rng = np.random.default_rng(plant.seed)
    if plant.noisy:
        logs["q_meas"] = np.full((n_log, nq), np.nan)
    status, reason = STATUS_OK, ""
    stream: dict[str, np.ndarray] = {}  # the metric stream: every accepted step
    t_stream = np.full(n_steps + 1, np.nan)
    si = 0
    g_prev, g_start, streak = 0.0, 0.0, 0  # step-growth detector
    li = 0
    k = 0
    t = grid[0]
    report_every = max(1, n_steps // 100)
    wall0 = _time.perf_counter()
    with np.errstate(all="ignore"):
        for k in range(n_steps + 1):
            t = grid[k]
            sigma, ubar = plant.faults.at(t)
            nz = plant.draw_noise(rng)
            hold = (sigma, ubar, nz)
            if observe is not None:
                observe(sigma, ubar)
            try:
                if not np.all(np.isfinite(x)):
                    raise DivergenceError(nonfinite_reason("state", t))
                _check_state(chain, x, settings)
                k1, u, tau = deriv(t, x, hold)
                if not (np.all(np.isfinite(k1)) and np.all(np.isfinite(u))):
                    raise DivergenceError(nonfinite_reason("control or derivative", t))
            except SingularityError as exc:
                status, reason = STATUS_SINGULAR, str(exc)
                break
            except (DivergenceError, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError) as exc:
                status, reason = STATUS_DIVERGED, with_step(str(exc), settings.dt, settings.method)
                break
            except FtcError as exc:
                status, reason = STATUS_ERROR, str(exc)
                break
            g = float(np.max(np.abs(tau))) if tau.size else 0.0
            if g_prev > 0.0 and g > GROWTH_FACTOR * g_prev:
                if streak == 0:
                    g_start = g_prev
                streak += 1
            else:
                streak = 0
            g_prev = g
            if streak >= GROWTH_STEPS and g > GROWTH_FLOOR and g > GROWTH_TOTAL * g_start:
                status = STATUS_STEP_UNSTABLE
                reason = step_growth_reason(t, g_start, g, streak, GROWTH_FACTOR, settings.dt, settings.method)
                break
            q, eta, xc = x[:nq], x[nq : nq + 2], x[nq + 2 :]
            row = {"q": q, "eta": eta, "u": u, "tau": tau, "sigma": sigma, "ubar": ubar, "xc": xc}
            if plant.noisy:
                row["q_meas"] = q + nz[:nq]
            sig = controller.signals(t, q + nz[:nq], eta + nz[nq:], xc)
            row |= {name: sig[name] for name in names}
            srow = stream_of({name: np.asarray(v, dtype=float)[None] for name, v in row.items()})
            if not stream:
                stream = {name: np.full((n_steps + 1, *v.shape[1:]), np.nan) for name, v in srow.items()}
            for name, v in srow.items():
                stream[name][si] = v[0]
            t_stream[si] = t
            si += 1
            if is_logged[k]:
                t_log[li] = t
                for name in logs:
                    logs[name][li] = row[name]
                li += 1
            if k == n_steps:
                break
            h = grid[k + 1] - t
            try:
                xn = step(deriv, t, x, h, k1, hold)
            except (SingularityError, *_NUMERIC_ERRORS) as e:
                # a trial stage left the domain; the accepted state x passed every check above
                status = STATUS_STEP_UNSTABLE
                reason = trial_stage_reason(t, str(e), settings.dt, settings.method)
                break
            except FtcError as exc:
                status, reason = STATUS_ERROR, str(exc)
                t = grid[k + 1]
                break
            jump = _step_jump(chain, x, xn, settings)
            if jump[0]:
                status = STATUS_STEP_UNSTABLE
                reason = trial_stage_reason(t, step_jump_words(*jump), settings.dt, settings.method, stage=False)
                break
            try:
                x = np.asarray(
                    controller.discrete(grid[k + 1], xn[:nq] + nz[:nq], xn[nq : nq + 2] + nz[nq:], xn[nq + 2 :]),
                    dtype=float,
                )
                x = np.concatenate((xn[: nq + 2], x)) if nc else xn
            except SingularityError as exc:
                status, reason = STATUS_SINGULAR, str(exc)
                t = grid[k + 1]
                break
            except (DivergenceError, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError) as exc:
                status, reason = STATUS_DIVERGED, with_step(str(exc), settings.dt, settings.method)
                t = grid[k + 1]
                break
            except FtcError as exc:
                status, reason = STATUS_ERROR, str(exc)
                t = grid[k + 1]
                break
            if progress is not None and k % report_every == 0:
                progress(float(grid[k + 1]))
    wall = _time.perf_counter() - wall0
    if progress is not None:
        progress(float(t))
    for name in logs:
        logs[name] = logs[name][:li]
    stream = {name: v[:si] for name, v in stream.items()}
    return Run(
        t=t_log[:li],
        signals=logs,
        status=status,
        reason=reason,
        t_end=float(t),
        steps=int(k),
        wall_time=wall,
        meta={
            "dt": settings.dt,
            "duration": settings.duration,
            "log_every": every,
            "fault_schedule": _fault_records(plant),
        },
        t_stream=t_stream[:si],
        stream=stream,
    )


def _fault_records(plant: Plant) -> list[dict]:
    """The plant's fault events as plain records (run metadata: exports and notebook views).

    A motor event (issue 19) also carries its ``motor`` kind and ``value``.
    """
    out = []
    for e in plant.faults.events:
        rec = {"time": float(e.time), "wheel": str(e.wheel), "sigma": float(e.sigma), "ubar": float(e.ubar)}
        if e.motor is not None:
            rec |= {"motor": str(e.motor), "value": None if e.value is None else float(e.value)}
        out.append(rec)
    return out


def _step_rk4(deriv, t, x, h, k1, hold):
    """One classical RK4 step (k1 = f(t, x) already evaluated)."""
    k2 = deriv(t + 0.5 * h, x + 0.5 * h * k1, hold)[0]
    k3 = deriv(t + 0.5 * h, x + 0.5 * h * k2, hold)[0]
    k4 = deriv(t + h, x + h * k3, hold)[0]
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


_ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


def _make_ros2(nq: int, diag: np.ndarray):
    """ROS2 step with A = F E^T + diag(diag), F the eta columns of the Jacobian."""
    cols = [nq, nq + 1]

    def step(deriv, t, x, h, f0, hold):
        # F = df/d(eta), forward differences
        F = np.empty((x.shape[0], 2))
        for j, c in enumerate(cols):
            delta = 1e-7 * max(1.0, abs(x[c]))
            xp = x.copy()
            xp[c] += delta
            F[:, j] = (deriv(t, xp, hold)[0] - f0) / delta
        gh = _ROS2_GAMMA * h
        # W = Dm - gh F E^T with Dm = I - gh diag(a):
        # W^-1 r = Dm^-1 r + gh Dm^-1 F (I_2 - gh E^T Dm^-1 F)^-1 E^T Dm^-1 r
        dinv = 1.0 / (1.0 - gh * diag)
        DF = dinv[:, None] * F
        small = np.eye(2) - gh * DF[cols, :]

        def solve(r):
            rd = dinv * r
            return rd + gh * (DF @ np.linalg.solve(small, rd[cols]))

        k1 = solve(f0)
        k2 = solve(deriv(t + h, x + h * k1, hold)[0] - 2.0 * k1)
        return x + 1.5 * h * k1 + 0.5 * h * k2

    return step


def _step_jump(chain: Chain, x: np.ndarray, xn: np.ndarray, settings: SimSettings) -> tuple[int, float, float]:
    """(kind, before, after) when the step x -> xn is a numerical blow-up, else (0, 0, 0).

    The new state is non-finite (kind 1), or fails a check of :func:`_check_state`
    that the accepted state x was far from: speed (2) or position (3) beyond its
    bound from within ``JUMP_FRACTION`` of it (a growth of more than 10x in one
    step), or an articulation angle (4) within the margin of 90 deg from more
    than ``JUMP_MARGINS`` margins away.  ``before``/``after``: the checked value.
    The compiled engine's ``_step_jump`` kernel returns the same triple.
    """
    nq = chain.n_q
    if not np.all(np.isfinite(xn)):
        return 1, 0.0, 0.0
    e0, e1 = float(np.max(np.abs(x[nq : nq + 2]))), float(np.max(np.abs(xn[nq : nq + 2])))
    if e1 > settings.max_speed and e0 < JUMP_FRACTION * settings.max_speed:
        return 2, e0, e1
    p0, p1 = float(np.max(np.abs(x[:2]))), float(np.max(np.abs(xn[:2])))
    if p1 > settings.max_position and p0 < JUMP_FRACTION * settings.max_position:
        return 3, p0, p1
    if chain.n > 1:
        c0 = float(np.min(np.abs(K.articulation_cos(chain.params, x[:nq]))))
        c1 = float(np.min(np.abs(K.articulation_cos(chain.params, xn[:nq]))))
        if c1 <= math.sin(settings.singularity_margin) and c0 > math.sin(JUMP_MARGINS * settings.singularity_margin):
            return 4, math.degrees(math.acos(min(1.0, c0))), math.degrees(math.acos(min(1.0, c1)))
    return 0, 0.0, 0.0


def _check_state(chain: Chain, x: np.ndarray, settings: SimSettings) -> None:
    """Raise SingularityError / DivergenceError for a state that must stop the run."""
    nq = chain.n_q
    q, eta = x[:nq], x[nq : nq + 2]
    c = np.abs(K.articulation_cos(chain.params, q))
    limit = math.sin(settings.singularity_margin)
    if np.any(c <= limit):
        i = int(np.argmin(c))
        ang = math.degrees(math.acos(min(1.0, c[i])))
        raise SingularityError(articulation_reason(i, ang, settings.singularity_margin))
    if np.any(np.abs(eta) > settings.max_speed):
        raise DivergenceError(bound_reason("velocity", eta.tolist(), settings.max_speed))
    if np.any(np.abs(q[:2]) > settings.max_position):
        raise DivergenceError(bound_reason("position", q[:2].tolist(), settings.max_position, " m"))


def demo_chain(n: int):
    """(chain, kinematic controller, q0) of the thesis robot on a 5 m circle at 0.5 m/s: the two-link
    law for n = 2, the chained law for n >= 3 (warm-up and benchmarks)."""
    from .control.kinematic import ChainedBackstepping, TwoLinkKinematic
    from .model import Chain
    from .references import FlatReference, circle

    chain = Chain.uniform(n)
    ref = FlatReference(circle(5.0, 0.5), chain.d)
    if n == 2:
        kin = TwoLinkKinematic(chain.d[0], ref, 1.0, 1.0, 1.0)
    else:
        kin = ChainedBackstepping(chain.d, ref, [0.3] * n, 1.0, 1.0, 5.0)
    return chain, kin, ref.at(0.0).q_d


def warm_up() -> float:
    """Compile (or load from the cache) every kernel on a tiny run; returns the seconds it took."""
    from .control.switching import SwitchingController
    from .control.tracking import TrackingController

    t0 = _time.perf_counter()
    for n in (2, 3):
        chain, kin, q0 = demo_chain(n)
        for ctrl in (TrackingController(chain, kin, 5.0), SwitchingController(chain, kin, 5.0)):
            for method in ("rk4", "ros2"):
                simulate(Plant(chain), ctrl, q0, np.array([0.5, 0.0]), SimSettings(0.01, 0.03, method=method))
    return _time.perf_counter() - t0
