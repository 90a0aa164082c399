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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np

from ..errors import ModelError

__all__ = ["MAXON_RE65", "MotorParams", "pack"]


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


def pack(motors: MotorParams | Sequence[MotorParams], n: int):
    """Per-wheel arrays for the compiled kernels: ``fast.motor.Motors`` of length 2 n.

    Parameters
    ----------
    motors : MotorParams or sequence of n MotorParams
        One for every robot, or one per robot leader first; both wheels of robot i get robot i's.
    n : int
        Number of robots.
    """
    from ..fast.motor import Motors

    per_robot = [motors] * n if isinstance(motors, MotorParams) else list(motors)
    if len(per_robot) != n:
        raise ModelError(f"actuators: {len(per_robot)} motor sets given, a {n}-robot chain needs {n}")
    cols = {f.name: np.empty(2 * n) for f in fields(MotorParams)}
    for i, mp in enumerate(per_robot):
        for key, val in asdict(mp).items():
            cols[key][2 * i] = val
            cols[key][2 * i + 1] = val
    return Motors(**cols)
