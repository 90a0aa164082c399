r"""Simulation: plant and controller integrated together, on the compiled engine.

The plant is the reduced dynamics (2.70) of a :class:`~ftcreport.model.Chain`
with the actuator fault model (2.102) and optional torque saturation::

    qdot   = S(q) eta
    etadot = Mbar1^-1 (Bbar tau - Mbar2 eta - Cbar),   tau = sigma sat(u) + ubar

:func:`simulate` runs the closed loop on the compiled engine
(:func:`ftcreport.fast.simulate.simulate_compiled` over the loop template ``ftcreport/fast/loop.py``)
for a controller built by the package (:func:`ftcreport.runner.make_controller`, the classes of
:mod:`ftcreport.control`) or a registered scheme (:mod:`ftcreport.schemes`).  There is no second
loop in Python (issue 17: each equation exists once): a new law is written as a scheme (README,
"Write your own scheme").  The controller's continuous state ``xc`` is stepped with the plant's.

Integrators (:attr:`SimSettings.method`; the error-controlled ones, ``"auto"``, ``"dopri5"``,
``"ros2ec"``, ``"etd2ec"``, ``"etd3ec"``, ``"ros34pw2"``, are in :mod:`ftcreport.fast.integrators`): fixed-step
classical RK4 (``"rk4"``, the default), or
the two-stage Rosenbrock W-method ROS2 (``"ros2"``, Verwer, Spee, Blom, Hundsdorfer 1999) for
stiff velocity loops, with gamma = 1 + 1/sqrt(2)::

    (I - gamma h A) k1 = f(t, y)
    (I - gamma h A) k2 = f(t + h, y + h k1) - 2 k1
    y+ = y + 3/2 h k1 + 1/2 h k2

second order for any matrix A (a W-method) and L-stable when A is the Jacobian.  Here A holds only
the columns of the plant velocities eta (forward differences): the stiffness of these closed
loops is the velocity-error gain (k4 = 3000 in thesis 3.2.3 gives an eigenvalue -3000, ERRATA
E12f, so RK4 needs dt < 0.93 ms), and it lives in those columns.  A controller may add the exact
diagonal of the Jacobian of its own linear states (``stiff_diagonal``, e.g. -gamma for
reconstruction filters); with it a matched reconstruction error obeys the W-method recursion of
e' = -gamma e and stays exactly zero, as it does under RK4.  The fast transient of the velocity
loop is then damped rather than resolved: tracking errors agree with fine-step RK4 (tested),
first-instant torque peaks do not (they last ~1/k4 s).  With DC motors, ``method="etd2"``
(:func:`ftcreport.fast.loop._etd2`) is the exponential ETD2RK of Cox & Matthews (2002): exact on
the linear [eta, i_a] block, so a current's transient after a held-voltage step is integrated
whole over a step of one control sample, where ROS2 only damps it.

Fault events land exactly on step boundaries: the fixed-step grid is ``t0 + k dt``
with every event time inserted (:func:`time_grid`; the step before an event is shortened),
and an error-controlled step is clipped to land on every fault time, control sample,
tick of the noise/UKF clock and switching dwell end (fast.loop.run_auto); sigma, ubar
are held over each step at their value at its start, so the fault model is exact.
After each step the controller's discrete update runs (switching logic and the like).

A run that approaches a singular configuration (an articulation angle
within ``singularity_margin`` of 90 deg, ERRATA P4, or a controller singular at
the accepted state) stops with status ``"singular"``; a non-finite or
out-of-bounds state stops with ``"diverged"``.  Three detectors stop a
fixed-step run whose step blows up: a trial stage of the integrator left the
domain (a controller singularity, a non-finite value) while the accepted state
at the step's start is regular; the new state fails a check that the accepted
state was far from (a speed or position bound crossed from within
``JUMP_FRACTION`` of it, the singular set reached from ``JUMP_MARGINS`` margins
away: a change no resolved step makes); or the applied torque grew
geometrically from accepted step to accepted step (max_j |tau_j| more than
``GROWTH_FACTOR`` = e times larger than at the step before, ``GROWTH_STEPS`` = 3
steps in a row, ``GROWTH_TOTAL`` = 20 times larger overall, ending above
``GROWTH_FLOOR`` = 1 N m; the constants are in :mod:`ftcreport.runs`): growth by
e per step is a rate of 1 / dt, a mode with lambda dt > 1 that the step does not
resolve.  Such a stop, and a divergence at a bound, is labelled by what a
smaller step does to it (issue 36 item 4, :func:`ftcreport.fast.recheck._relabel`):
the interval is run again from a checkpoint before it with the method's
error-controlled twin, and the stop is ``"step_unstable"`` only if that run
passes it or stops later; ``"singular"`` if it also stops, no later, with the
state in a law's singular set (named in the reason); ``"diverged"`` if the
blow-up persists (a resolved exponential growth, such as e^(50 t) at dt = 0.01 s,
1.65x per step, is divergence, not a step problem).  An error-controlled run is
never ``"step_unstable"``: a trial stage that leaves the domain is a rejected
step, and a step below ``min_step`` stops the run with the tolerances named.
The log up to that point is kept and the reason is
recorded; a NaN is never returned silently.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import ModelError
from .model.chain import Chain
from .model.faults import FaultSchedule
from .runs import AUTO_METHODS, METHODS, REDUCED_SIGNALS, STREAM_SIGNALS, Run, stream_of

__all__ = [
    "REDUCED_SIGNALS",
    "STREAM_SIGNALS",
    "Plant",
    "Run",
    "SimSettings",
    "simulate",
    "stream_of",
    "time_grid",
]


#: defaults of the error-controlled methods (cases.Simulation's say why)
RTOL, ATOL, MIN_STEP = 1e-6, 1e-8, 1e-8


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
        Fixed step: ``"rk4"`` (classical), ``"ros2"`` (Rosenbrock W-method, stiff-capable) or
        ``"etd2"`` (exponential ETD2RK, exact on the linear [eta, i_a] block: the motor cases at
        one step per control sample, fast.loop._etd2).  Error-controlled (fast.integrators):
        ``"dopri5"`` (Dormand-Prince 5(4), non-stiff), ``"ros2ec"`` (ROS2, stiff loops), ``"etd2ec"``
        (ETD2, motors under sampled control), both with step doubling's estimate, ``"etd3ec"`` (ETD3RK
        with an embedded ETD2, motors under sampled control), ``"ros34pw2"`` (the Rosenbrock W-method
        ROS34PW2 of Rang & Angermann 2005: third order, an embedded second order, L-stable; stiff loops),
        or ``"auto"``: dopri5, ros34pw2 or etd3ec picked at t0 from the loop's spectral radius
        (fast.loop.run_auto).  With these ``dt``
        is the longest step, and the clock of the sensor noise and of a discrete-time filter (the
        UKF): steps land on its multiples when the plant is noisy or the scheme has one.
    rtol, atol : float
        Error-controlled methods: a step is accepted when every state's local error estimate is at
        most atol + rtol |x_i| (fast.integrators.error_ratio).
    min_step : float
        Error-controlled methods: the run stops (with the reason) when the step falls below it [s].
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
    rtol: float = RTOL
    atol: float = ATOL
    min_step: float = MIN_STEP

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ModelError(f"method: must be one of {', '.join(map(repr, METHODS))}, got {self.method!r}")
        for name in ("rtol", "atol", "min_step"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ModelError(f"{name}: must be a positive number, got {v}")
        if self.min_step >= self.dt and self.method in AUTO_METHODS:
            raise ModelError(f"min_step: {self.min_step} s is not below the longest step dt = {self.dt} s")
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
        if self.sample_time is not None and self.method not in AUTO_METHODS:  # error-controlled: steps land on samples
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
        controller sees q + noise, drawn once per sensor sample (``noise_period``)
        and held in between, seeded.
    noise_eta : (2,) array_like, optional
        Standard deviations of the noise on the measured eta [m/s, rad/s].
    seed : int
        Seed of the noise generator (runs are reproducible).
    noise_period : float, optional
        The sensor's sample period [s]: draw j holds on [t0 + j T, t0 + (j + 1) T), whatever the
        integration step (a fixed step must divide it; an error-controlled one lands on every tick).
        None: the run's ``dt``.
    motors : MotorParams or sequence of MotorParams, optional
        A DC motor per wheel (one set per robot, leader first), thesis (2.26)-(2.29): the command
        becomes armature voltages (the driver's static inversion, ftcreport.model.motor_compiled) and the
        wheel torque follows the currents.  None: the ideal torque plant (tau = command).
    drive : DriveParams or sequence of DriveParams, optional
        The motors' drives (ftcreport.model.actuators.DriveParams: the static inversion or a PI
        current loop, and the drive's model of the motor); None: the static driver with the plant's
        own model of every motor.
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
        drive=None,
        noise_period: float | None = None,
    ):
        self.chain = chain
        self.motors = motors
        self.drive = drive
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
        if noise_period is not None and not (math.isfinite(noise_period) and noise_period > 0):
            raise ModelError(f"noise_period: must be a positive time [s], got {noise_period}")
        self.noise_period = None if noise_period is None else float(noise_period)


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
    controller,
    q0: np.ndarray,
    eta0: np.ndarray,
    settings: SimSettings,
    progress: Callable[[float], None] | None = None,
    engine: str = "compiled",
) -> Run:
    """Integrate plant and controller on the compiled engine (RK4, ROS2 or ETD2).

    Parameters
    ----------
    plant : Plant
    controller
        A controller with a compiled counterpart: one :func:`ftcreport.runner.make_controller`
        builds (the classes of :mod:`ftcreport.control` on a :class:`~ftcreport.references.FlatReference`)
        or a registered scheme's :class:`ftcreport.schemes.SchemeController`.
    q0 : (n + 2,) array_like
        Initial configuration ``[x, y, theta_n, ..., theta_1]``.
    eta0 : (2,) array_like
        Initial ``[v_n, omega_1]``.
    settings : SimSettings
    progress : callable, optional
        Called with the simulated time now and then (every ~1 % of the run).
    engine : str
        ``"compiled"`` (default) or its old alias ``"auto"``: the only engine.  The Python loop
        (``"python"``) was removed (issue 17: each equation exists once).

    Returns
    -------
    Run
        Always returned; ``run.status`` says whether it completed.

    Raises
    ------
    ModelError
        Bad initial state, ``engine="python"``, or a controller without a compiled counterpart
        (write it as a scheme: :mod:`ftcreport.schemes`).
    """
    from .fast.engine import compiled_spec
    from .fast.simulate import simulate_compiled

    nq = plant.chain.n_q
    q0 = np.asarray(q0, dtype=float)
    eta0 = np.asarray(eta0, dtype=float)
    if q0.shape != (nq,):
        raise ModelError(f"q0: expected {nq} values [x, y, theta_n..theta_1], got shape {q0.shape}")
    if eta0.shape != (2,):
        raise ModelError(f"eta0: expected 2 values [v_n, omega_1], got shape {eta0.shape}")
    if engine not in ("auto", "compiled"):
        why = "; the Python loop was removed (issue 17)" if engine == "python" else ""
        raise ModelError(f"engine: must be 'compiled' (or 'auto'), got {engine!r}{why}")
    spec = compiled_spec(controller)
    if spec is None:
        raise ModelError(
            f"controller: {type(controller).__name__} has no compiled counterpart; a new law runs as a scheme "
            "(ftcreport.schemes, README 'Write your own scheme')"
        )
    T = plant.noise_period
    if T is not None and settings.method not in AUTO_METHODS:
        ratio = T / settings.dt
        if not (ratio >= 1 - 1e-9 and abs(ratio - round(ratio)) <= 1e-9 * ratio):
            raise ModelError(
                f"noise_period: {T:g} s is not a whole number of steps dt = {settings.dt:g} s (a fixed step holds "
                "one draw; an error-controlled method lands on every draw)"
            )
    if settings.method in AUTO_METHODS:  # error-controlled: the steps are the controller's (no grid)
        run = simulate_compiled(spec, plant, q0, eta0, settings, None, None, progress)
    else:
        grid = time_grid(settings.t0, settings.duration, settings.dt, plant.faults.times)
        n_steps = grid.shape[0] - 1
        log_idx = np.unique(np.append(np.arange(0, n_steps + 1, int(settings.log_every)), n_steps))
        run = simulate_compiled(spec, plant, q0, eta0, settings, grid, log_idx, progress)
    run.meta["fault_schedule"] = _fault_records(plant)
    return run


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


def demo_chain(n: int):
    """(chain, kinematic controller, q0) of the thesis robot (1 m links) on a 5 m circle at 0.5 m/s: the
    two-link law for n = 2, the chained law for n >= 3 (``ftcreport demo``, warm-up and benchmarks)."""
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
