"""The case file's physical tables: robots, reference, initial state, faults, actuators, simulation, plant."""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import StrictBool, model_validator

from ..model.actuators import DRIVE_MODEL_FIELDS, MAXON_RE65, DriveParams, MotorParams
from ..model.chain import THESIS_ROBOT
from ..model.faults import MOTOR_KINDS
from ..runs import AUTO_METHODS
from ..schemes.fields import (
    Angle,
    Coord,
    Factor,
    Inertia,
    Int,
    Length,
    Mass,
    Rate,
    Signed,
    Speed,
    Std,
    Time,
    Torque,
    Unit,
    _f,
    _FieldError,
    _num,
    _Strict,
    refuse_unused,
)


class Robots(_Strict):
    """Per-robot parameters: a scalar applies to every robot, a list is leader first."""

    n: Int = _f(..., "number of robots (robot 1 is the leader)", "1", ge=2, le=12)
    a: Signed | list[Signed] = _f(
        THESIS_ROBOT["a"], "signed distance from the axle midpoint P_i to the centre of mass C_i", "m"
    )
    b: Length | list[Length] = _f(THESIS_ROBOT["b"], "half the distance between the driven wheels", "m")
    r: Length | list[Length] = _f(THESIS_ROBOT["r"], "wheel radius", "m")
    m: Mass | list[Mass] = _f(THESIS_ROBOT["m"], "mass", "kg")
    I: Inertia | list[Inertia] = _f(THESIS_ROBOT["I"], "yaw inertia about C_i", "kg m^2")
    d: Length | list[Length] = _f(1.0, "link lengths d_i = |P_i P_(i+1)|, n - 1 values leader first", "m")

    @model_validator(mode="after")
    def _lengths(self) -> Robots:
        for key in ("a", "b", "r", "m", "I", "d"):
            v = getattr(self, key)
            count = self.n - 1 if key == "d" else self.n
            what = "link lengths" if key == "d" else "values"
            if isinstance(v, list) and len(v) != count:
                raise _FieldError(f"robots.{key}", f"{len(v)} {what} given, a {self.n}-robot chain needs {count}")
        return self

    def values(self, key: str) -> list[float]:
        v = getattr(self, key)
        count = self.n - 1 if key == "d" else self.n
        return list(v) if isinstance(v, list) else [float(v)] * count


_MAX_RADIUS = 1e5  # [m] a circle's radius, and a unicycle's v_d / |omega_d|


#: the fields each reference kind reads (Reference.path)
_REFERENCE_FIELDS = {
    "unicycle": ("v_d", "omega_d", "x0", "y0", "theta0_deg"),
    "circle": ("radius", "speed", "center", "start_angle_deg", "ccw"),
    "eight": ("theta0_deg", "scale"),
    "line": ("speed", "heading_deg", "start"),
    "sinusoid": ("speed", "amplitude", "frequency", "heading_deg", "start", "phase_deg"),
}


class Reference(_Strict):
    """Path of the last robot's axle midpoint P_n (a flat output of the chain)."""

    kind: Literal["unicycle", "circle", "eight", "line", "sinusoid"] = _f(..., "shape of the path", "-")
    v_d: Speed | None = _f(None, "unicycle: forward speed (required)", "m/s")
    omega_d: Rate | None = _f(
        None,
        "unicycle: turn rate (required; 0, or at least v_d / 1e5 m in magnitude: a circle of radius <= 1e5 m)",
        "rad/s",
    )
    x0: Coord = _f(0.0, "unicycle: start x", "m")
    y0: Coord = _f(0.0, "unicycle: start y", "m")
    theta0_deg: Angle | None = _f(None, "unicycle, eight: start heading (eight: 45 as in the thesis)", "deg")
    radius: _num(None, _MAX_RADIUS, gt=0) | None = _f(None, "circle: radius (required)", "m")
    speed: Speed | None = _f(None, "circle, line, sinusoid: path speed (required)", "m/s")
    center: tuple[Coord, Coord] = _f((0.0, 0.0), "circle: centre [x, y]", "m")
    start_angle_deg: Angle = _f(-90.0, "circle: polar angle of the start point (-90: bottom, heading +x)", "deg")
    ccw: StrictBool = _f(True, "circle: counter-clockwise", "-")
    heading_deg: Angle = _f(0.0, "line, sinusoid: direction of travel", "deg")
    start: tuple[Coord, Coord] = _f((0.0, 0.0), "line, sinusoid: start point [x, y]", "m")
    amplitude: _num(-1e4, 1e4) | None = _f(None, "sinusoid: amplitude (required)", "m")
    frequency: _num(None, 100.0, gt=0) | None = _f(None, "sinusoid: angular frequency (required)", "rad/s")
    phase_deg: Angle = _f(0.0, "sinusoid: phase (-90: y = A (1 - cos wt), starts along the heading)", "deg")
    scale: _num(None, 1e3, gt=0) = _f(1.0, "eight: size factor (1: the thesis's 3 sin 0.3t, 5 sin 0.15t)", "1")

    @model_validator(mode="after")
    def _needed(self) -> Reference:
        need = {
            "unicycle": ("v_d", "omega_d"),
            "circle": ("radius", "speed"),
            "line": ("speed",),
            "sinusoid": ("speed", "amplitude", "frequency"),
            "eight": (),
        }[self.kind]
        missing = [k for k in need if getattr(self, k) is None]
        if missing:
            raise ValueError(f"a '{self.kind}' reference needs {', '.join(missing)}")
        refuse_unused(self, "reference", "reference", _REFERENCE_FIELDS)
        if self.kind == "unicycle" and self.omega_d != 0 and self.v_d / abs(self.omega_d) > _MAX_RADIUS:
            raise _FieldError(
                "reference.omega_d",
                f"{self.omega_d:g} rad/s turns on a circle of radius v_d / |omega_d| = "
                f"{self.v_d / abs(self.omega_d):.3g} m, beyond {_MAX_RADIUS:g} m (the circle's radius limit; its "
                "centre that far away loses every digit of the position): give 0 for a straight line",
            )
        return self

    def path(self):
        from .. import references as R

        deg = math.radians
        if self.kind == "unicycle":
            th0 = deg(self.theta0_deg or 0.0)
            return R.unicycle(self.v_d, self.omega_d, self.x0, self.y0, th0)
        if self.kind == "circle":
            return R.circle(self.radius, self.speed, self.center, deg(self.start_angle_deg), self.ccw)
        if self.kind == "eight":
            return R.eight(45.0 if self.theta0_deg is None else self.theta0_deg, scale=self.scale)
        if self.kind == "line":
            return R.line(self.speed, deg(self.heading_deg), self.start)
        return R.sinusoid(
            self.speed, self.amplitude, self.frequency, deg(self.heading_deg), self.start, deg(self.phase_deg)
        )


class Initial(_Strict):
    """Initial state: absolute, or as offsets from the reference at t = 0."""

    mode: Literal["absolute", "offset"] = _f("offset", "offsets from the reference at t = 0, or absolute", "-")
    x: Coord = _f(0.0, "P_n's x (absolute) or its offset from x_d(0)", "m")
    y: Coord = _f(0.0, "P_n's y (absolute) or its offset from y_d(0)", "m")
    headings_deg: list[Angle] | None = _f(None, "theta_1..theta_n, n values (absolute) or per-robot offsets", "deg")
    heading_offset_deg: Angle = _f(0.0, "offset mode: added to every heading", "deg")
    eta: tuple[_num(-1e3, 1e3), _num(-1e3, 1e3)] | None = _f(
        None, "[v_n, omega_1]; default: the reference's (offset mode) or zero (absolute mode)", "m/s, rad/s"
    )


class Fault(_Strict):
    """From ``time`` on, ``wheel`` has effectiveness ``sigma`` and friction ``ubar``: tau = sigma u + ubar (2.101)."""

    time: Time = _f(..., "event time, before the end of the run (lands exactly on a step boundary)", "s")
    wheel: str = _f(..., 'the wheel: "1r", "1l", ..., "nr", "nl"', "-")
    sigma: Unit = _f(0.0, "effectiveness after the event (0: the motor gives no torque)", "1")
    ubar: Torque = _f(0.0, "additive friction torque after the event", "N m")
    motor: Literal[MOTOR_KINDS] | None = _f(
        None,
        "a motor fault instead of (sigma, ubar), needs [actuators]: km_loss (k_m and k_b scaled), resistance "
        "(R_a scaled), open (no current), short (winding shorted: braking), stuck (driver stuck at a voltage), "
        "none (motor repaired)",
        "-",
    )
    value: _num(-1e4, 1e4) | None = _f(
        None,
        "the motor fault's value: km_loss: remaining fraction of k_m in (0, 1]; resistance: factor on R_a in "
        "[1, 1000]; stuck: the driver's voltage (saturated at V_max); none for the other kinds",
        "1 or V",
    )


_ACT = "a scalar applies to every robot, a list is leader first"


def _each(t: Any) -> Any:
    """A per-robot field: one value for every robot, or a list of them, leader first."""
    return t | list[t]


_MODEL = "the drive's model of the motor; default: the plant's ([actuators])"


class DriveModel(_Strict):
    """What the drive knows of its motor (issue 36): each field defaults to the plant's value in [actuators]."""

    R_a: _each(_num(None, 1e3, gt=0)) | None = _f(None, f"armature resistance; {_MODEL}; {_ACT}", "ohm")
    L_a: _each(_num(None, 10.0, gt=0)) | None = _f(None, f"armature inductance; {_MODEL}; {_ACT}", "H")
    k_m: _each(_num(None, 100.0, gt=0)) | None = _f(None, f"torque constant; {_MODEL}; {_ACT}", "N m/A")
    k_b: _each(_num(None, 100.0, gt=0)) | None = _f(None, f"back-EMF constant; {_MODEL}; {_ACT}", "V s/rad")
    N: _each(_num(None, 1e4, gt=0)) | None = _f(None, f"gear ratio; {_MODEL}; {_ACT}", "1")
    eta_g: _each(_num(None, 1.0, gt=0)) | None = _f(None, f"gear efficiency; {_MODEL}; {_ACT}", "1")
    b_m: _each(_num(0.0, 100.0)) | None = _f(None, f"rotor viscous damping; {_MODEL}; {_ACT}", "N m s/rad")
    b_m_compensation: _each(_num(0.0, 1.0)) = _f(
        1.0,
        "fraction of its b_m the drive compensates from the measured wheel speed (1: all, 0: no drag "
        f"compensation; the rest acts on the chain as a speed-proportional friction); {_ACT}",
        "1",
    )


class Actuators(_Strict):
    """DC motors of the wheels (thesis 2.3.3, issue 19) and their drives (issue 36).

    Both wheels of a robot get the robot's values.  Defaults: maxon RE 65 48 V with a 20:1 gear of
    efficiency 0.75 and a 48 V supply (ftcreport.model.actuators gives the datasheet source), driven
    by the static inversion.  With this table the plant integrates the armature currents (and the PI
    drive's integral part); without it the wheel torque is the command (today's ideal plant).
    """

    R_a: _each(_num(None, 1e3, gt=0)) = _f(MAXON_RE65.R_a, f"armature resistance; {_ACT}", "ohm")
    L_a: _each(_num(None, 10.0, gt=0)) = _f(MAXON_RE65.L_a, f"armature inductance (> 0); {_ACT}", "H")
    k_m: _each(_num(None, 100.0, gt=0)) = _f(MAXON_RE65.k_m, f"torque constant; {_ACT}", "N m/A")
    k_b: _each(_num(None, 100.0, gt=0)) = _f(
        MAXON_RE65.k_b, f"back-EMF constant (= k_m in SI units); {_ACT}", "V s/rad"
    )
    N: _each(_num(None, 1e4, gt=0)) = _f(MAXON_RE65.N, f"gear ratio motor speed / wheel speed; {_ACT}", "1")
    eta_g: _each(_num(None, 1.0, gt=0)) = _f(
        MAXON_RE65.eta_g, f"gear efficiency (wheel torque = eta_g N motor torque); {_ACT}", "1"
    )
    J_m: _each(_num(0.0, 10.0)) = _f(
        MAXON_RE65.J_m, f"rotor inertia (eta_g N^2 J_m on the wheel axis); {_ACT}", "kg m^2"
    )
    b_m: _each(_num(0.0, 100.0)) = _f(MAXON_RE65.b_m, f"rotor viscous damping; {_ACT}", "N m s/rad")
    V_max: _each(_num(None, 1e5, gt=0)) = _f(
        MAXON_RE65.V_max, f"supply voltage: the driver saturates at +-V_max; {_ACT}", "V"
    )
    I_max: _each(_num(None, 1e6, gt=0)) | None = _f(
        None, f"limit on the driver's target current (none by default); {_ACT}", "A"
    )
    driver: Literal["static", "pi"] = _f(
        "static",
        'the drive: "static" (the motor\'s steady state inverted: v = R_a i* + k_b N omega, no current '
        'feedback) or "pi" (a PI current loop with anti-windup, the class of maxon\'s ESCON servo drives)',
        "-",
    )
    current_bandwidth: _each(_num(None, 1e6, gt=0)) = _f(
        1000.0,
        "pi: the closed current loop's bandwidth f (time constant 1 / (2 pi f)); the gains follow by "
        f"pole-zero cancellation, K_p = L_a 2 pi f, K_i = R_a 2 pi f (the drive's model); {_ACT}",
        "Hz",
    )
    current_kp: _each(_num(None, 1e6, gt=0)) | None = _f(
        None, f"pi: proportional gain instead of L_a 2 pi f; {_ACT}", "V/A"
    )
    current_ki: _each(_num(None, 1e9, gt=0)) | None = _f(
        None, f"pi: integral gain instead of R_a 2 pi f; {_ACT}", "V/(A s)"
    )
    back_emf_feedforward: StrictBool = _f(
        False, "pi: add k_b N omega (the drive's model, the measured wheel speed) to the PI's output", "-"
    )
    drive_rate: _num(None, 1e7, gt=0) | None = _f(
        None,
        "pi: the drive's sampling rate: a discrete PI whose voltage is held between its samples (its period a "
        "whole number of steps dt); absent: a continuous PI (a drive sampled far faster than the loop)",
        "Hz",
    )
    drive_model: DriveModel = _f(DriveModel(), "what the drive knows of the motor ([actuators.drive_model])", "-")

    @model_validator(mode="after")
    def _pi_fields(self) -> Actuators:
        if self.driver == "static":  # current_bandwidth has a default a stored case writes back: only another value
            pi = [k for k in ("current_kp", "current_ki", "back_emf_feedforward", "drive_rate") if getattr(self, k)]
            if self.current_bandwidth != type(self).model_fields["current_bandwidth"].default:
                pi.insert(0, "current_bandwidth")
            if len(pi) == 1:
                raise _FieldError(f"actuators.{pi[0]}", 'belongs to the PI drive: set driver = "pi" (or remove it)')
            if pi:  # every one at once, not one per attempt
                why = 'belong to the PI drive: set driver = "pi" (or remove them)'
                raise _FieldError("actuators", f"{', '.join(pi)} {why}")
        return self

    def params(self, n: int) -> list[MotorParams]:
        """One MotorParams per robot, leader first (a scalar applies to every robot)."""
        out = []
        for i in range(n):
            kw = {}
            for key in MotorParams.__dataclass_fields__:
                v = getattr(self, key)
                v = v[i] if isinstance(v, list) else v
                kw[key] = math.inf if v is None else float(v)
            out.append(MotorParams(**kw))
        return out

    def drive_params(self, n: int) -> list[DriveParams]:
        """One DriveParams per robot, leader first: the drive's settings and its model of the motor."""

        def at(v: Any, i: int) -> Any:
            return v[i] if isinstance(v, list) else v

        out = []
        for i, motor in enumerate(self.params(n)):
            model = {key: at(getattr(self.drive_model, key), i) for key in DRIVE_MODEL_FIELDS}
            kw = {key: float(v) for key, v in model.items() if v is not None}
            kw["b_m_compensation"] = float(at(self.drive_model.b_m_compensation, i))
            for key in ("current_bandwidth", "current_kp", "current_ki"):
                v = at(getattr(self, key), i)
                if v is not None:
                    kw[key] = float(v)
            out.append(
                DriveParams.of_motor(
                    motor, driver=self.driver, back_emf_feedforward=self.back_emf_feedforward,
                    drive_rate=self.drive_rate, **kw,
                )
            )  # fmt: skip
        return out


class Simulation(_Strict):
    """Integration settings."""

    dt: _num(None, 10.0, gt=0) = _f(
        ...,
        "step of the fixed-step methods; the longest step of the error-controlled ones (and the period at which "
        "they draw sensor noise and run the UKF)",
        "s",
    )
    duration: _num(None, 1e6, gt=0) = _f(..., "simulated time", "s")
    method: Literal["rk4", "ros2", "etd2", "auto", "dopri5", "ros2ec", "etd2ec", "etd3ec", "ros34pw2"] = _f(
        "rk4",
        "fixed step: RK4; the stiff-capable Rosenbrock W-method ROS2 (for k_v in the thousands); the exponential"
        " ETD2RK, exact on the motors' currents (DC-motor cases: one step per control sample). Error-controlled"
        " (rtol, atol): dopri5 (Dormand-Prince 5(4), non-stiff), ros2ec (ROS2, stiff loops), etd2ec (ETD2, motors"
        " under sampled control), both with step doubling's estimate; etd3ec (ETD3RK with an embedded ETD2, motors"
        " under sampled control: 5 evaluations a step against etd2ec's 7); ros34pw2 (the Rosenbrock W-method"
        " ROS34PW2, third order with an embedded second order, stiff loops); or auto: dopri5, ros34pw2 or etd3ec,"
        " picked from the loop's linearization at t0",
        "-",
    )
    # Defaults: six digits on every state (positions of metres: a micrometre, the resolution of the
    # tracking metrics the cases quote), and atol for the states that pass through zero (velocities,
    # filter states, weights): 1e-8 in their units; benchmarks/accuracy.py measures what they give.
    rtol: _num(1e-12, 0.1) = _f(
        1e-6,
        "error-controlled methods: relative tolerance of every state's local error per step (fixed-step methods: "
        "of the error-controlled re-check of a stop that persists at dt/4, see step_unstable)",
        "1",
    )
    atol: _num(1e-15, 1.0) = _f(
        1e-8,
        "error-controlled methods: absolute tolerance of every state's local error per step (fixed-step methods: "
        "of the error-controlled re-check of a stop that persists at dt/4, see step_unstable)",
        "state's unit",
    )
    min_step: _num(None, 1.0, gt=0) = _f(
        1e-8,
        "error-controlled methods (and a fixed step's error-controlled re-check of a stop): the shortest step; a "
        "step at min_step whose error is still over the tolerance is taken anyway and counted "
        "(integrator.forced_steps in metrics.json; 'run' says how many), and 100 such steps in a row, or a trial "
        "stage leaving the domain at min_step, stop the run (status and reason)",
        "s",
    )
    log_every: Int = _f(1, "log one step in log_every", "1", ge=1, le=1_000_000)
    singularity_margin_deg: _num(0.0, lt=90) = _f(
        2.0, "stop (status singular) when an articulation angle comes this close to 90 deg", "deg"
    )
    sample_time: _num(None, 10.0, gt=0) | None = _f(
        None,
        "sampled (digital) control: the controller's period, a whole number of steps dt (fixed-step methods; the "
        "error-controlled ones land on every sample) and at most the duration; "
        "its command is held between samples (zero-order hold). Absent: continuous-time control",
        "s",
    )
    measurement_delay: Int = _f(
        0,
        "sampled control: the controller sees the measurements of this many samples before (a transport delay "
        "of whole samples, shorter than the run; the first sample's measurement until there is one that old)",
        "samples",
        ge=0,
        le=1000,
    )

    @model_validator(mode="after")
    def _whole_steps(self) -> Simulation:
        if self.measurement_delay and self.sample_time is None:
            raise _FieldError(
                "simulation.measurement_delay",
                f"{self.measurement_delay} samples needs sampled control: set simulation.sample_time",
            )
        auto = self.method in AUTO_METHODS
        if auto and self.min_step >= self.dt:
            raise _FieldError(
                "simulation.min_step", f"{self.min_step} s is not below the longest step dt = {self.dt} s"
            )
        if self.sample_time is not None:
            ratio = self.sample_time / self.dt
            # error-controlled steps land on the samples whatever dt is
            if not auto and (ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio):
                raise _FieldError(
                    "simulation.sample_time", f"{self.sample_time} s is not a whole number of steps dt = {self.dt} s"
                )
            if self.sample_time > self.duration:
                raise _FieldError(
                    "simulation.sample_time",
                    f"{self.sample_time} s is longer than the run ({self.duration} s): the controller would act once",
                )
            delay = self.measurement_delay * self.sample_time
            if self.measurement_delay and delay >= self.duration:
                raise _FieldError(
                    "simulation.measurement_delay",
                    f"{self.measurement_delay} sample(s) of {self.sample_time} s ({delay:g} s) is not shorter than the "
                    f"run ({self.duration} s): the controller would never see a measurement taken after t = 0",
                )
        return self


class Noise(_Strict):
    """Measurement noise (standard deviations) the controllers see: one draw per sensor sample, held, seeded."""

    position: Std = _f(0.0, "on x and y", "m")
    heading: Std = _f(0.0, "on every theta", "rad")
    velocity: Std = _f(0.0, "on v_n and omega_1", "m/s, rad/s")
    sample_time: _num(1e-9, 1e6, gt=0) | None = _f(
        None,
        "the sensor's sample period: one draw per period, held in between, whatever the integration step "
        "(a fixed step must divide it); default simulation.dt",
        "s",
    )
    # 63 bits: campaigns give each sample a SeedSequence child of 63 bits (ftcreport.studies.campaign.sample_seeds)
    seed: Int = _f(0, "seed of the noise (runs are reproducible)", "1", ge=0, le=2**63 - 1)

    @property
    def noisy(self) -> bool:
        """Whether the sensor draws any noise (some standard deviation above 0)."""
        return self.position > 0 or self.heading > 0 or self.velocity > 0

    def period(self, dt: float) -> float:
        """The sensor's sample period: ``sample_time``, else the run's step dt (fast.engine.noise_clock's rule)."""
        return float(dt) if self.sample_time is None else float(self.sample_time)


class Mismatch(_Strict):
    """Plant parameters = [robots] x these factors (the controllers keep [robots])."""

    a: Signed | list[Signed] = _f(1.0, "factor on a", "1")
    b: Factor | list[Factor] = _f(1.0, "factor on b", "1")
    r: Factor | list[Factor] = _f(1.0, "factor on r", "1")
    m: Factor | list[Factor] = _f(1.0, "factor on m", "1")
    I: Factor | list[Factor] = _f(1.0, "factor on I", "1")
    d: Factor | list[Factor] = _f(1.0, "factor on d", "1")


class Plant(_Strict):
    """The simulated plant beyond [robots]: saturation, sensor noise, parameter mismatch."""

    saturation: _num(None, 1e6, gt=0) | None = _f(
        None, "limit on every wheel's control signal, applied before the fault model", "N m"
    )
    noise: Noise = _f(Noise(), "measurement noise ([plant.noise])", "-")
    mismatch: Mismatch = _f(Mismatch(), "true parameters = [robots] x these factors ([plant.mismatch])", "-")
