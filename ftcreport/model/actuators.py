r"""DC motor parameters of one robot's two wheels, thesis section 2.3.3 (2.26)-(2.29), ERRATA E19.

The thesis gives no numeric motor data (E19).  The defaults are a brushed DC motor of realistic
size for the thesis robots (30 kg, wheel radius 0.15 m, ``chain.THESIS_ROBOT``):

* Motor: maxon RE 65, 250 W, 48 V winding (graphite brushes), the maxon datasheet values as quoted
  in https://pastebin.com/7kFwyXJK (listed there as variant 353297): terminal resistance 0.365 ohm,
  terminal inductance 0.161 mH, torque constant 123 mNm/A, speed constant 77.8 rpm/V, rotor
  inertia 1340 g cm^2, no-load current 289 mA at 3670 rpm, nominal voltage 48 V, nominal
  (continuous) torque 800 mNm at 6.8 A, stall torque 16100 mNm at 131 A, mechanical time constant
  3.25 ms.  The source is a copy of the datasheet, not maxon's own page; the numbers are
  self-consistent (the speed constant gives k_b = 60 / (2 pi 77.8) = 0.1227 V s/rad against
  k_m = 0.123 N m/A;
  R_a J_m / (k_m k_b) = 3.23 ms against the quoted 3.25 ms; 48 V / 0.365 ohm = 131.5 A against the
  quoted stall current), which is why we trust them.
* k_b = k_m = 0.123: in SI units they are the same constant (the motor converts power losslessly);
  the 0.2 % the speed constant differs by is the datasheet's rounding.
* b_m from the no-load point: k_m I_0 / omega_0 = 0.123 * 0.289 / (3670 * 2 pi / 60) =
  9.25e-5 N m s/rad (the datasheet's friction modelled as viscous).
* Gear: N = 20, eta_g = 0.75.  These are our choice, not from a datasheet: 20:1 puts the wheel's
  no-load speed at 19.2 rad/s (2.9 m/s at r = 0.15 m) and the continuous wheel torque at
  0.8 * 20 * 0.75 = 12 N m; 0.75 is a typical two-stage planetary efficiency.
* V_max = 48 V (the nominal voltage); no current limit by default (I_max = inf).

Time constants of these defaults: electrical L_a / R_a = 0.44 ms, mechanical (motor alone)
R_a J_m / (k_m k_b) = 3.23 ms.

The drive (:class:`DriveParams`, ftcreport.model.drive_compiled gives the equations): "static" (a voltage
computed from the torque command by inverting the motor's steady state, today's driver) or "pi" (a
PI current loop, the servo-drive class of maxon's ESCON: its hardware reference gives a PI current
controller sampled at 53.6 kHz, an output voltage of at most 0.98 of the supply and a peak current
limit).  The drive has its own model of the motor (R_a, L_a, k_m, k_b, N, eta_g, b_m), equal to the
plant's unless the case says otherwise, and compensates a fraction of the rotor drag it believes in.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np

from ..errors import ModelError

__all__ = ["MAXON_RE65", "DriveParams", "MotorParams", "pack", "pack_drive", "rotor_inertia_wheels"]


@dataclass(frozen=True)
class MotorParams:
    """One wheel motor with its gear and driver supply (both wheels of a robot share them).

    Attributes
    ----------
    R_a : float
        Armature resistance [ohm], > 0.
    L_a : float
        Armature inductance [H], > 0.
    k_m : float
        Torque constant [N m/A], > 0.
    k_b : float
        Back-EMF constant [V s/rad], > 0 (equal to k_m in SI units for a lossless conversion).
    N : float
        Gear ratio omega_motor / omega_wheel [-], > 0.
    eta_g : float
        Gear efficiency [-], in (0, 1]; the wheel torque is eta_g N tau_l.
    J_m : float
        Rotor inertia [kg m^2], >= 0 (adds eta_g N^2 J_m on the wheel axis).
    b_m : float
        Rotor viscous damping [N m s/rad], >= 0.
    V_max : float
        Supply voltage [V], > 0 (inf: none).
    I_max : float
        Limit on the driver's target current [A], > 0 (inf: none).
    """

    R_a: float = 0.365
    L_a: float = 0.161e-3
    k_m: float = 0.123
    k_b: float = 0.123
    N: float = 20.0
    eta_g: float = 0.75
    J_m: float = 1340e-7
    b_m: float = 0.123 * 0.289 / (3670.0 * 2.0 * math.pi / 60.0)
    V_max: float = 48.0
    I_max: float = math.inf

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if math.isnan(v):
                raise ModelError(f"actuators.{f.name}: not a number")
            object.__setattr__(self, f.name, v)
        for key in ("R_a", "L_a", "k_m", "k_b", "N"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0):
                raise ModelError(f"actuators.{key}: must be finite and > 0, got {v}")
        for key in ("J_m", "b_m"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0):
                raise ModelError(f"actuators.{key}: must be finite and >= 0, got {v}")
        if not 0.0 < self.eta_g <= 1.0:
            raise ModelError(f"actuators.eta_g: must be in (0, 1], got {self.eta_g}")
        for key in ("V_max", "I_max"):
            if not getattr(self, key) > 0:
                raise ModelError(f"actuators.{key}: must be > 0 (inf: no limit), got {getattr(self, key)}")

    @property
    def tau_electrical(self) -> float:
        """Electrical time constant L_a / R_a [s]: the lag of the current behind the driver."""
        return self.L_a / self.R_a

    @property
    def tau_mechanical(self) -> float:
        """Mechanical time constant of the unloaded motor, R_a J_m / (k_m k_b) [s] (datasheet's)."""
        return self.R_a * self.J_m / (self.k_m * self.k_b)

    def tau_mechanical_loaded(self, J_wheel: float) -> float:
        """Mechanical time constant with a load inertia J_wheel [kg m^2] on the wheel axis [s].

        (J_wheel + eta_g N^2 J_m) / (eta_g N^2 (k_m k_b / R_a + b_m)): the speed's time constant
        under a fixed voltage, the electrical damping seen through the gear.
        """
        gN2 = self.eta_g * self.N**2
        return (J_wheel + gN2 * self.J_m) / (gN2 * (self.k_m * self.k_b / self.R_a + self.b_m))

    @property
    def stall_torque_wheel(self) -> float:
        """Wheel torque at standstill with the full supply and no current limit [N m]."""
        i = min(self.V_max / self.R_a, self.I_max)
        return self.eta_g * self.N * self.k_m * i


#: The defaults (module docstring: maxon RE 65 48 V, 20:1 gear of efficiency 0.75, 48 V supply).
MAXON_RE65 = MotorParams()


DRIVERS = ("static", "pi")

#: The fields of the drive's model of the motor: the plant's (MotorParams) unless the case sets them.
DRIVE_MODEL_FIELDS = ("R_a", "L_a", "k_m", "k_b", "N", "eta_g", "b_m")


@dataclass(frozen=True)
class DriveParams:
    """One robot's wheel drives: the driver's kind, its current loop and its model of the motor.

    Attributes
    ----------
    driver : str
        "static" (the steady-state inversion, voltage computed from the torque command) or "pi"
        (a PI current loop, ftcreport.model.drive_compiled).
    R_a, L_a, k_m, k_b, N, eta_g, b_m : float
        The drive's model of the motor and gear (the plant's :class:`MotorParams` by default).
    b_m_compensation : float
        Fraction in [0, 1] of the drive's b_m it compensates (0: no drag compensation).
    current_bandwidth : float
        Closed current loop bandwidth f [Hz] of the "pi" driver (gains by pole-zero cancellation).
    current_kp, current_ki : float or None
        PI gains [V/A], [V/(A s)]; None: L_a 2 pi f and R_a 2 pi f of the drive's model.
    back_emf_feedforward : bool
        The "pi" driver adds k_b N omega (its model, measured speed) to its output.
    drive_rate : float or None
        The "pi" driver's sampling rate [Hz] (a discrete PI, its voltage held between samples);
        None: continuous (a drive sampled far faster than anything else in the loop).
    """

    driver: str = "static"
    R_a: float = MAXON_RE65.R_a
    L_a: float = MAXON_RE65.L_a
    k_m: float = MAXON_RE65.k_m
    k_b: float = MAXON_RE65.k_b
    N: float = MAXON_RE65.N
    eta_g: float = MAXON_RE65.eta_g
    b_m: float = MAXON_RE65.b_m
    b_m_compensation: float = 1.0
    current_bandwidth: float = 1000.0
    current_kp: float | None = None
    current_ki: float | None = None
    back_emf_feedforward: bool = False
    drive_rate: float | None = None

    def __post_init__(self) -> None:
        if self.driver not in DRIVERS:
            raise ModelError(f"actuators.driver: must be one of {', '.join(DRIVERS)}, got {self.driver!r}")
        for key in (*DRIVE_MODEL_FIELDS, "current_bandwidth"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and (v >= 0 if key == "b_m" else v > 0)):
                raise ModelError(
                    f"actuators.drive_model.{key}: must be finite and {'>=' if key == 'b_m' else '>'} 0, got {v}"
                )
            object.__setattr__(self, key, v)
        if not 0.0 <= self.b_m_compensation <= 1.0:
            raise ModelError(f"actuators.drive_model.b_m_compensation: must be in [0, 1], got {self.b_m_compensation}")
        for key in ("current_kp", "current_ki", "drive_rate"):
            v = getattr(self, key)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ModelError(f"actuators.{key}: must be finite and > 0, got {v}")

    @classmethod
    def of_motor(cls, motor: MotorParams, **kw) -> DriveParams:
        """A drive whose model of the motor is ``motor`` (the plant's), with ``kw`` on top."""
        model = {key: getattr(motor, key) for key in DRIVE_MODEL_FIELDS}
        return cls(**(model | kw))

    @property
    def kp(self) -> float:
        """Proportional gain [V/A]: given, or L_a 2 pi f (pole-zero cancellation)."""
        return self.current_kp if self.current_kp is not None else self.L_a * 2.0 * math.pi * self.current_bandwidth

    @property
    def ki(self) -> float:
        """Integral gain [V/(A s)]: given, or R_a 2 pi f (the PI's zero at R_a / L_a cancels the winding's pole)."""
        return self.current_ki if self.current_ki is not None else self.R_a * 2.0 * math.pi * self.current_bandwidth

    @property
    def b_m_compensated(self) -> float:
        """The drag the drive compensates [N m s/rad]: b_m_compensation x its b_m."""
        return self.b_m_compensation * self.b_m


def rotor_inertia_wheels(motors: Sequence[MotorParams]) -> np.ndarray:
    """eta_g N^2 J_m of every wheel, (2 n,) [kg m^2]: the rotor inertia on the wheel axis (ERRATA E19)."""
    return np.repeat([m.eta_g * m.N**2 * m.J_m for m in motors], 2).astype(float)


def pack(motors: MotorParams | Sequence[MotorParams], n: int):
    """Per-wheel arrays for the compiled kernels: ``model.motor_compiled.Motors`` of length 2 n.

    Parameters
    ----------
    motors : MotorParams or sequence of n MotorParams
        One for every robot, or one per robot leader first; both wheels of robot i get robot i's.
    n : int
        Number of robots.
    """
    from .motor_compiled import Motors

    per_robot = _per_robot(motors, MotorParams, n, "motor")
    cols = {f.name: np.empty(2 * n) for f in fields(MotorParams)}
    for i, mp in enumerate(per_robot):
        for key, val in asdict(mp).items():
            cols[key][2 * i] = val
            cols[key][2 * i + 1] = val
    return Motors(**cols)


def pack_drive(drives: DriveParams | Sequence[DriveParams] | None, motors: MotorParams | Sequence[MotorParams], n: int):
    """Per-wheel arrays of the drives: ``model.drive_compiled.Drive`` for 2 n wheels.

    ``drives`` None: the static driver with the plant's own model of every motor (today's driver).
    The limits (V_max, I_max) are the plant's supply and the drive's current limit, from ``motors``.
    Every robot's drive must be of the same kind and rate (the loop runs one kind).
    """
    from .drive_compiled import DRIVER_PI, DRIVER_PI_SAMPLED, DRIVER_STATIC, Drive

    mots = _per_robot(motors, MotorParams, n, "motor")
    drs = [DriveParams.of_motor(m) for m in mots] if drives is None else _per_robot(drives, DriveParams, n, "drive")
    kinds = {(d.driver, d.drive_rate) for d in drs}
    if len(kinds) > 1:
        raise ModelError("actuators: every robot's drive must be of the same kind and rate (driver, drive_rate)")
    first = drs[0]
    kind = {"static": DRIVER_STATIC, "pi": DRIVER_PI if first.drive_rate is None else DRIVER_PI_SAMPLED}[first.driver]

    def col(values):
        return np.repeat(np.asarray(values, dtype=float), 2)

    model = {key: col([getattr(d, key) for d in drs]) for key in DRIVE_MODEL_FIELDS if key != "b_m"}
    return Drive(
        kind,
        **model,
        b_m=col([d.b_m_compensated for d in drs]),
        K_p=col([d.kp for d in drs]),
        K_i=col([d.ki for d in drs]),
        V_max=col([m.V_max for m in mots]),
        I_max=col([m.I_max for m in mots]),
        ff=col([1.0 if d.back_emf_feedforward else 0.0 for d in drs]),
        T_d=math.nan if first.drive_rate is None else 1.0 / first.drive_rate,
    )


def _per_robot(values, cls, n: int, what: str) -> list:
    per_robot = [values] * n if isinstance(values, cls) else list(values)
    if len(per_robot) != n:
        raise ModelError(f"actuators: {len(per_robot)} {what} sets given, a {n}-robot chain needs {n}")
    return per_robot
