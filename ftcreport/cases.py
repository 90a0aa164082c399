r"""Case files: one documented TOML schema, validated with pydantic.

A case says which chain, reference, initial state, fault schedule, controllers
(schemes) with their gains, simulation settings, plant extras and thresholds.
``cases/README.md`` documents every field with its unit.  Every error names the
file, the field path and the reason, e.g.
``cases/x.toml: faults[2].wheel: '4r' is not a wheel of a 3-robot chain``.

This module reads files (``load_case``) and validates; building the simulation
objects from a validated case is pure (:func:`build`), so campaigns and tests
can build variants in memory.
"""

from __future__ import annotations

import difflib
import hashlib
import math
import os
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
    create_model,
    field_validator,
    model_validator,
)

from .errors import CaseError, FtcError, printable
from .fields import (  # the schema's building blocks (shared with the schemes' parameter tables)
    _NUMBER,
    Angle,
    Coord,
    Factor,
    Gain,
    Gain0,
    Inertia,
    Int,
    Length,
    Limit,
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
    did_you_mean,
)
from .inputs import input_problem, read_input
from .limits import budget_problem, name_problem
from .model import Chain, FaultEvent, FaultSchedule, wheel_index, wheel_names
from .model.actuators import DRIVE_MODEL_FIELDS, MAXON_RE65, DriveParams, MotorParams
from .model.chain import THESIS_ROBOT
from .model.faults import MOTOR_KINDS, motor_row
from .requirements import SIGNALS as REQUIREMENT_SIGNALS
from .runs import AUTO_METHODS
from .schemes import built_in as _built_in_schemes

__all__ = [
    "SCHEME_NAMES",
    "Case",
    "case_hash",
    "case_schema",
    "configured_schemes",
    "did_you_mean",
    "dropped_faults",
    "known_schemes",
    "load_case",
    "metric_problem",
    "option_schemes",
    "ordered_schemes",
    "parse_case",
]

SCHEME_NAMES = tuple(_built_in_schemes())  # the built-in schemes, in the registry's order (ftcreport.schemes)


Status = Literal["ok", "singular", "diverged", "step_unstable"]  # run outcomes (ftcreport.sim)


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
        if self.kind == "unicycle" and self.omega_d != 0 and self.v_d / abs(self.omega_d) > _MAX_RADIUS:
            raise _FieldError(
                "reference.omega_d",
                f"{self.omega_d:g} rad/s turns on a circle of radius v_d / |omega_d| = "
                f"{self.v_d / abs(self.omega_d):.3g} m, beyond {_MAX_RADIUS:g} m (the circle's radius limit; its "
                "centre that far away loses every digit of the position): give 0 for a straight line",
            )
        return self

    def path(self):
        from . import references as R

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
        if self.driver == "static":  # (current_bandwidth has a default: a stored case writes it back)
            for key in ("current_kp", "current_ki", "back_emf_feedforward", "drive_rate"):
                if getattr(self, key) not in (None, False):
                    raise _FieldError(f"actuators.{key}", 'belongs to the PI drive: set driver = "pi" (or remove it)')
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


class Kinematic(_Strict):
    """Kinematic controller shared by every scheme."""

    kind: Literal["two_link", "chained"] = _f(
        ..., '"two_link" (n = 2 only, thesis 3.2) or "chained" (any n, thesis 3.3)', "-"
    )
    k1: Gain | None = _f(None, "two_link: gain k1 of (3.27)-(3.28) (required)", "1/s")
    k2: Gain | None = _f(None, "two_link: gain k2 of (3.27)-(3.28) (required)", "see (3.28)")
    k3: Gain | None = _f(None, "two_link: gain k3 of (3.27)-(3.28) (required)", "1/s")
    c_chain: Gain0 | list[Gain0] = _f(
        0.3, "chained: gain of every virtual control, scalar or n values (ERRATA E12d)", "1/s"
    )
    c_alpha2: Gain = _f(2.0, "chained: the thesis's c4", "1/s")
    c_xi1: Gain = _f(2.0, "chained: the thesis's c5", "1/s")
    kappa: Gain = _f(5.0, "chained: weight of the x error in the Lyapunov function", "1")
    mu: Gain = _f(1.0, "chained: length scale of the chain dynamics (1: the thesis design)", "1/m")
    band_deg: _num(gt=0, lt=90) = _f(
        45.0, "chained: re-anchor the chained-form frame when the reference heading leaves +/- band", "deg"
    )


class _SchemesBase(_Strict):
    """The schemes to run; every scheme present is run with the shared kinematic controller.

    Issue 21: every family runs unless ``run`` narrows the list; a family without its table gets
    the defaults of :mod:`ftcreport.families` (k_v: this table's ``k_v``, else the first table's,
    else the thesis's).  A registered (plug-in) scheme's table, ``[schemes.<name>]``, is validated
    with that scheme's parameter model and kept as an extra field (:func:`configured_schemes`).
    """

    model_config = ConfigDict(
        extra="allow",  # [schemes.<name>] of a registered (plug-in) scheme, validated by _plugin_tables
        frozen=True,
        json_schema_extra={
            "additionalProperties": {
                "type": "object",
                "description": "the table of a registered scheme (a file listed in plugins), validated by its "
                "parameter model",
                "unit": "-",
            }
        },
    )

    run: list[str] | None = _f(
        None,
        "the schemes to run (default: every family, adaptive_frozen only when its table is given); built-in or "
        "registered (plugins) names",
        "-",
    )
    k_v: Gain | None = _f(None, "velocity-error gain of the default tables (default: the first table's)", "1/s")

    @field_validator("run")
    @classmethod
    def _known_run(cls, v: list[str] | None) -> list[str] | None:
        known = known_schemes()
        for i, name in enumerate(v or ()):
            if name not in known:
                raise _FieldError(f"schemes.run[{i}]", _unknown_scheme(name))
        return v

    @model_validator(mode="before")
    @classmethod
    def _plugin_tables(cls, data: Any) -> Any:
        """Validate ``[schemes.<name>]`` of a registered scheme with its parameter model; refuse other names.

        A registered scheme listed in ``run`` without a table gets its parameter model's defaults.
        """
        if not isinstance(data, dict):
            return data
        from .schemes import registered

        reg = registered()
        out = dict(data)
        for key, table in data.items():
            if key in cls.model_fields:
                continue
            if key not in reg:
                raise _FieldError(f"schemes.{key}", "unknown field" + _unknown_hint(key, [*cls.model_fields, *reg]))
            out[key] = _plugin_table(key, reg[key], table)
        run = data.get("run")
        for name in run if isinstance(run, list) else ():
            if isinstance(name, str) and name in reg and name not in data:
                out[name] = _plugin_table(name, reg[name], {})
        return out


def _schemes_model() -> type[BaseModel]:
    """The ``[schemes]`` table: ``run``, ``k_v`` and one optional field per built-in scheme, its parameter
    model (the registry's order; the field's description is the scheme's summary)."""
    fields: dict[str, Any] = {}
    for name, sc in _built_in_schemes().items():
        fields[name] = (sc.params | None, _f(None, sc.summary or sc.description, "-"))
    return create_model("Schemes", __base__=_SchemesBase, __doc__=_SchemesBase.__doc__, **fields)


Schemes = _schemes_model()


class PluginTable(_Strict):
    """The table of a registered scheme that declares no parameter model."""

    k_v: Gain | None = _f(
        None,
        "velocity-error gain of the dynamic law (the thesis's k4 or c6) (default: schemes.k_v, else the case's "
        "default)",
        "1/s",
    )


def _unknown_hint(key: str, known: list[str]) -> str:
    """A did-you-mean, else how a plug-in scheme's name becomes known."""
    hint = did_you_mean(key, known)
    if hint:
        return hint
    return (
        ": neither a built-in scheme nor a registered one (a plug-in scheme's file must be listed in plugins = [...])"
    )


def _unknown_scheme(name: str) -> str:
    known = known_schemes()
    return f"unknown scheme '{name}'" + _unknown_hint(name, known) + f" (known: {', '.join(known)})"


def _plugin_table(name: str, scheme: Any, table: Any) -> BaseModel:
    """``[schemes.<name>]`` of a registered scheme, validated by its parameter model (field errors named)."""
    model = scheme.params or PluginTable
    if isinstance(table, model):
        return table
    if isinstance(table, BaseModel):
        table = table.model_dump()
    if not isinstance(table, dict):
        raise _FieldError(f"schemes.{name}", f"a table is expected, got {type(table).__name__}")
    try:
        return model.model_validate(table)
    except ValidationError as exc:
        err = min(exc.errors(), key=_rank)
        loc = _format_loc(tuple(err["loc"]))
        if err["type"] == "extra_forbidden":
            why = "unknown field" + did_you_mean(str(err["loc"][-1]), list(model.model_fields))
        else:
            why = _message(err, model)
        raise _FieldError(f"schemes.{name}" + (f".{loc}" if loc else ""), why) from None
    except ValueError as exc:  # a validator of the plug-in's model raising outside pydantic's wrapping
        raise _FieldError(f"schemes.{name}", str(exc)) from None


def _scheme_file(name: str) -> str | None:
    """The file a registered scheme's law is defined in (resolved), None when it is not a file (a notebook)."""
    from .schemes import registered

    sc = registered().get(name)
    code = getattr(getattr(sc.law, "py_func", sc.law), "__code__", None) if sc is not None else None
    if code is None or not Path(code.co_filename).is_file():
        return None
    return str(Path(code.co_filename).resolve())


def _scheme_hook(name: str, hook: str):
    """A registered scheme's hook (``Scheme.validate``, ``Scheme.budget``), None for a scheme without it."""
    from .schemes import every

    sc = every().get(name)
    return None if sc is None else getattr(sc, hook)


def known_schemes() -> list[str]:
    """The built-in scheme names, then the registered (plug-in) ones."""
    from .schemes import registered

    return [*SCHEME_NAMES, *sorted(registered())]


def configured_schemes(case: Case) -> list[str]:
    """The schemes a case runs: its built-in tables (in :data:`SCHEME_NAMES` order), then its plug-in tables."""
    return [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None] + list(case.schemes.model_extra or {})


def option_schemes(option: str, names: list[str], case: Case, among: list[str] | None = None) -> list[str]:
    """The schemes a CLI option names (``--scheme``, ``--schemes``), checked against ``case``.

    ``among``: the schemes the command can run (default: those the case configures).  A name that
    is no scheme at all is blamed on the option, with the known schemes and the closest one
    (``--scheme: got 'swiching'; known schemes: ...; did you mean 'switching'?``); a scheme the
    case does not run says so with the reason of :func:`ftcreport.families.not_applicable`.
    Raises :class:`FtcError` (exit 2); returns ``names``.
    """
    from .families import not_applicable

    known = known_schemes()
    among = configured_schemes(case) if among is None else among
    for name in names:
        if name not in known:
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise FtcError(f"{option}: got '{name}'; known schemes: {', '.join(known)}{hint}")
        if name not in among:
            why = not_applicable(case).get(name)
            reason = f": {why}" if why else ""
            runs = ", ".join(among) or "none"
            raise FtcError(f"{option}: '{name}' is not run on case '{case.name}' (this command runs {runs}){reason}")
    return names


def ordered_schemes(names) -> list[str]:
    """``names`` without repeats, the built-in schemes first in :data:`SCHEME_NAMES` order, the others as met."""
    names = list(dict.fromkeys(names))
    return [s for s in SCHEME_NAMES if s in names] + [s for s in names if s not in SCHEME_NAMES]


class Simulation(_Strict):
    """Integration settings."""

    dt: _num(None, 10.0, gt=0) = _f(
        ...,
        "step of the fixed-step methods; the longest step of the error-controlled ones (and the period at which "
        "they draw sensor noise and run the UKF)",
        "s",
    )
    duration: _num(None, 1e6, gt=0) = _f(..., "simulated time", "s")
    method: Literal["rk4", "ros2", "etd2", "auto", "dopri5", "ros2ec", "etd2ec"] = _f(
        "rk4",
        "fixed step: RK4; the stiff-capable Rosenbrock W-method ROS2 (for k_v in the thousands); the exponential"
        " ETD2RK, exact on the motors' currents (DC-motor cases: one step per control sample). Error-controlled"
        " (rtol, atol): dopri5 (Dormand-Prince 5(4), non-stiff), ros2ec (ROS2, stiff loops), etd2ec (ETD2, motors"
        " under sampled control), both with step doubling's estimate, or auto: one of them picked from the loop's"
        " linearization at t0",
        "-",
    )
    # Defaults: six digits on every state (positions of metres: a micrometre, the resolution of the
    # tracking metrics the cases quote), and atol for the states that pass through zero (velocities,
    # filter states, weights): 1e-8 in their units; benchmarks/accuracy.py measures what they give.
    rtol: _num(1e-12, 0.1) = _f(
        1e-6, "error-controlled methods: relative tolerance of every state's local error per step", "1"
    )
    atol: _num(1e-15, 1.0) = _f(
        1e-8, "error-controlled methods: absolute tolerance of every state's local error per step", "state's unit"
    )
    min_step: _num(None, 1.0, gt=0) = _f(
        1e-8, "error-controlled methods: the run stops (status and reason) when the step falls below this", "s"
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
    """Measurement noise (standard deviations) the controllers see, drawn once per step, seeded."""

    position: Std = _f(0.0, "on x and y", "m")
    heading: Std = _f(0.0, "on every theta", "rad")
    velocity: Std = _f(0.0, "on v_n and omega_1", "m/s, rad/s")
    # 63 bits: campaigns give each sample a SeedSequence child of 63 bits (ftcreport.campaign.sample_seeds)
    seed: Int = _f(0, "seed of the noise (runs are reproducible)", "1", ge=0, le=2**63 - 1)


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


class Bound(_Strict):
    """Bounds on one metric."""

    min: Limit | None = _f(None, "lower bound", "unit of the metric")
    max: Limit | None = _f(None, "upper bound", "unit of the metric")


_Count = Annotated[int, Field(ge=0, le=100), _NUMBER]


class Claim(_Strict):
    """A thesis claim about the case, checked by ``ftcreport check`` (ftcreport.claims, issue 18)."""

    id: str = _f(..., "short name, unique in the case", "-")
    source: str = _f(..., "where the thesis says it: section, figure or table", "-")
    words: str = _f(..., "the thesis's words", "-")
    expect: Literal["reproduced", "not reproduced", "not applicable"] = _f(..., "the outcome check requires", "-")
    note: str = _f("", "what we measure beside it (shown on the page)", "-")
    not_applicable: str | None = _f(None, "why this simulation cannot check it (one sentence)", "-")
    scheme: str | None = _f(None, "whose metrics decide", "-")
    metric: str | None = _f(None, 'a metrics.json name; "a.b" reads entry b of dict a', "-")
    keys: list[str] | None = _f(None, "dict metric: the entries compared (their largest)", "-")
    min: Limit | None = _f(None, "lower bound on the metric (or on the ratio with relative_to)", "metric's")
    max: Limit | None = _f(None, "upper bound on the metric (or on the ratio with relative_to)", "metric's")
    relative_to: str | None = _f(None, "bound on metric(scheme) / metric(relative_to)", "-")
    sequence: list[Annotated[int, Field(ge=1, le=10**6), _NUMBER]] | None = _f(
        None, "switch_sequence: the applied models, 1-based, repeats merged", "-"
    )

    @model_validator(mode="after")
    def _decidable(self) -> Claim:
        if self.not_applicable is not None:
            if self.expect != "not applicable":
                raise ValueError("a claim marked not_applicable must expect 'not applicable'")
            return self
        if self.expect == "not applicable":
            raise ValueError("expect = 'not applicable' needs not_applicable = '<why>'")
        if self.scheme is None or self.metric is None:
            raise ValueError("give scheme and metric (or not_applicable = '<why>')")
        for key, val in (("scheme", self.scheme), ("relative_to", self.relative_to)):
            if val is not None and val not in known_schemes():
                raise ValueError(f"{key}: unknown scheme '{val}' (known: {', '.join(known_schemes())})")
        has_bound = self.min is not None or self.max is not None
        if has_bound == (self.sequence is not None):
            raise ValueError("give either a bound (min, max) or a sequence")
        if self.sequence is not None and self.relative_to is not None:
            raise ValueError("a sequence is not compared relative to another scheme")
        return self


class AfterFault(_Strict):
    """A window edge N seconds after each fault event (one window per event)."""

    after_fault: Time = _f(
        ..., "seconds after each fault event ([[faults]] times, repairs included; one window per event)", "s"
    )


_SIGNAL_NAMES = tuple(REQUIREMENT_SIGNALS)


class Requirement(_Strict):
    """A bound on a signal over windows defined by events, checked at every step (ftcreport.requirements)."""

    id: str = _f(..., "short name, unique in the case (the JUnit testcase's name)", "-", min_length=1, max_length=64)
    description: str = _f("", "the requirement in words (shown on the page)", "-")
    signal: Literal[_SIGNAL_NAMES] = _f(
        ...,
        "position_error [m], heading_error [rad], torque [N m] (signed, one wheel), torque_abs [N m], speed (v_n) "
        "[m/s], turn_rate (omega_1) [rad/s]",
        "-",
    )
    robot: Annotated[int, Field(ge=1, le=12), _NUMBER] | None = _f(
        None, "heading_error: the robot (1 = leader); absent: the largest error over the robots", "1"
    )
    wheel: str | None = _f(
        None, 'torque (required), torque_abs (absent: the largest over the wheels): "1r", "1l", ..., "nl"', "-"
    )
    scheme: str = _f("*", 'the scheme it applies to, or "*" for every scheme the case runs', "-")
    start: Time | AfterFault = _f(
        0.0, "where each window starts: a time, or { after_fault = N }: N s after each fault event", "s"
    )
    end: Time | Literal["next_fault", "end"] | AfterFault = _f(
        "end",
        'where each window ends: a time, "next_fault" (the next event, else the end), "end" (of the run), or '
        "{ after_fault = M } (M s after the window's own event)",
        "s",
    )
    min: Limit | None = _f(None, "lower bound on the signal in every window", "signal's")
    max: Limit | None = _f(None, "upper bound on the signal in every window (min and max: within the band)", "signal's")

    @model_validator(mode="after")
    def _decidable(self) -> Requirement:
        if self.min is None and self.max is None:
            raise ValueError("give a bound: min, max, or both (within [min, max])")
        return self

    def problems(self, n: int) -> list[tuple[str, str]]:
        """(field, reason) of every inconsistency with itself and with an n-robot chain."""
        out = []
        if self.min is not None and self.max is not None and self.min > self.max:
            out.append(("max", f"{self.max:g} is below min = {self.min:g}: the band is empty"))
        if self.robot is not None and self.signal != "heading_error":
            out.append(("robot", f"a robot is chosen for heading_error only, not for {self.signal}"))
        if self.robot is not None and self.robot > n:
            out.append(("robot", f"robot {self.robot} is not in a {n}-robot chain"))
        if self.wheel is not None and self.signal not in ("torque", "torque_abs"):
            out.append(("wheel", f"a wheel is chosen for torque and torque_abs only, not for {self.signal}"))
        if self.wheel is None and self.signal == "torque":
            out.append(
                ("wheel", 'required for the signed torque: name the wheel, e.g. wheel = "1r" (or use torque_abs)')
            )
        if self.wheel is not None:
            try:
                wheel_index(self.wheel, n)
            except FtcError as exc:
                out.append(("wheel", str(exc)))
        s, e = self.start, self.end
        if isinstance(e, AfterFault) and not isinstance(s, AfterFault):
            out.append(
                ("end", "{ after_fault = M } needs start = { after_fault = N }: M is counted from each window's fault")
            )
        elif isinstance(e, AfterFault) and e.after_fault <= s.after_fault:
            out.append(
                (
                    "end.after_fault",
                    f"{e.after_fault:g} s is not after start.after_fault = {s.after_fault:g} s: every window "
                    "would be empty",
                )
            )
        if isinstance(s, float) and isinstance(e, float) and e <= s:
            out.append(("end", f"{e:g} s is not after start = {s:g} s: the window would be empty"))
        return out


#: [baseline] defaults: ftcreport.baseline's module docstring and cases/README.md ("Baselines") say why
BASELINE_REL_TOL = 1e-3
BASELINE_ABS_TOL = 1e-9
#: the scalar metrics of metrics.json a [baseline.metrics.<name>] table may name (ftcreport.baseline
#: compares COMPARED_METRICS, a part of them, by default)
BASELINE_METRIC_NAMES: tuple[str, ...] = (
    "position_error_max", "position_error_rms", "position_error_final", "position_error_iae", "heading_error_max",
    "heading_error_final", "recovery_time_max", "torque_peak", "torque_rms", "energy", "saturation_fraction",
    "singularity_margin_min", "t_end", "switch_count", "switching_match_fraction", "switching_exact_match_fraction",
    "switching_missed_detections", "detection_delay_max", "chi_hat_min", "chi_hat_max", "P_max", "false_alarms",
    "missed_detections", "fault_estimation_error_final", "combined_effect_error_rms", "combined_effect_rms",
)  # fmt: skip
#: the signal families of [baseline.signals.<name>] and their units
BASELINE_SIGNAL_FAMILIES: dict[str, str] = {"position_error": "m", "heading_error": "rad", "torque": "N m"}


class Tolerance(_Strict):
    """Tolerances of one baseline metric or signal family ([baseline.metrics.<name>], [baseline.signals.<name>])."""

    rel_tol: _num(0.0, 1e6) | None = _f(None, "relative tolerance (default: [baseline] rel_tol)", "1")
    abs_tol: _num(0.0, 1e18) | None = _f(None, "absolute tolerance (default: [baseline] abs_tol)", "unit of the metric")
    leading_tol: Time | None = _f(None, "signals: how far the new signal may lead the baseline in time", "s")
    lagging_tol: Time | None = _f(None, "signals: how far the new signal may lag the baseline in time", "s")
    ignore: StrictBool = _f(False, "leave this metric or signal out of the comparison", "-")


class BaselineSpec(_Strict):
    """Tolerances of ``ftcreport check --baseline`` for this case (ftcreport.baseline; as Simulink Test's criteria).

    A value passes when |new - baseline| <= max(abs_tol, rel_tol |baseline|); a signal when it stays
    in that band around the baseline's, widened in time by leading_tol and lagging_tol.
    """

    rel_tol: _num(0.0, 1e6) = _f(BASELINE_REL_TOL, "relative tolerance of every metric and signal", "1")
    abs_tol: _num(0.0, 1e18) = _f(
        BASELINE_ABS_TOL, "absolute tolerance of every metric and signal (in its own unit)", "unit of the metric"
    )
    leading_tol: Time = _f(0.0, "signals: how far the new signal may lead the baseline in time", "s")
    lagging_tol: Time = _f(0.0, "signals: how far the new signal may lag the baseline in time", "s")
    metrics: dict[str, Tolerance] = _f(
        {}, "[baseline.metrics.<name>]: a metrics.json name's own tolerances (naming one compares it)", "-"
    )
    signals: dict[str, Tolerance] = _f(
        {}, "[baseline.signals.<name>]: position_error, heading_error or torque: that family's own tolerances", "-"
    )

    @model_validator(mode="after")
    def _known_names(self) -> BaselineSpec:
        for name in self.metrics:
            if name not in BASELINE_METRIC_NAMES:
                raise _FieldError(
                    f"baseline.metrics.{name}",
                    "not a scalar metric of metrics.json"
                    + did_you_mean(name, list(BASELINE_METRIC_NAMES))
                    + f" (known: {', '.join(BASELINE_METRIC_NAMES)})",
                )
        for name in self.signals:
            if name not in BASELINE_SIGNAL_FAMILIES:
                raise _FieldError(
                    f"baseline.signals.{name}",
                    "not a baseline signal"
                    + did_you_mean(name, list(BASELINE_SIGNAL_FAMILIES))
                    + f" (known: {', '.join(BASELINE_SIGNAL_FAMILIES)})",
                )
        return self


class CampaignSpec(_Strict):
    """Distributions a Monte Carlo campaign draws variants of the case from (ftcreport.campaign)."""

    faults: tuple[_Count, _Count] = _f((1, 2), "number of fault events per sample, each on a distinct wheel", "1")
    fault_time: tuple[Time, Time] = _f(..., "event times; the upper bound must be before the end of the run", "s")
    wheels: Literal["any"] | list[str] = _f("any", "wheels a fault may hit", "-")
    sigma: tuple[Unit, Unit] = _f((0.0, 0.0), "effectiveness after the fault (0: motor lost)", "1")
    friction_probability: Unit = _f(0.0, "probability that a fault also adds a friction", "1")
    ubar: tuple[Torque, Torque] = _f((0.0, 0.0), "that friction", "N m")
    offset_position: Std = _f(0.0, "+/- added to the initial x and y", "m")
    offset_heading_deg: _num(0.0, 180.0) = _f(0.0, "+/- added to every initial heading", "deg")
    mismatch: _num(0.0, lt=1) = _f(0.0, "+/- relative error of the plant's mass and inertia", "1")
    noise_position: tuple[Std, Std] = _f((0.0, 0.0), "sensor-noise standard deviation on x, y", "m")
    noise_heading: tuple[Std, Std] = _f((0.0, 0.0), "sensor-noise standard deviation on the headings", "rad")
    keep_base_faults: StrictBool = _f(False, "keep the case's own faults and add the drawn ones", "-")
    success: dict[str, Bound] = _f(
        {"position_error_final": Bound(max=0.05)},
        "a sample succeeds for a scheme when its run completes and every bound holds",
        "-",
    )

    @model_validator(mode="after")
    def _ranges(self) -> CampaignSpec:
        for key in ("faults", "fault_time", "sigma", "ubar", "noise_position", "noise_heading"):
            lo, hi = getattr(self, key)
            if lo > hi:
                raise _FieldError(f"campaign.{key}", f"empty range [{lo}, {hi}]")
        return self


class Case(_Strict):
    """A validated case (cases/README.md documents every field; its tables are generated from these models)."""

    name: str | None = _f(
        None,
        "defaults to the file name without .toml; a safe name: [A-Za-z0-9][A-Za-z0-9_.-]{0,63}, not a name the "
        "report uses itself (index, *.html, manifest.json, metrics.parquet, assets, campaigns, coverage, fdi, "
        "junit.xml), unique within a batch ignoring letter case (see Limits)",
        "-",
    )
    description: str = _f("", "one line shown in reports", "-")
    plugins: list[str] = _f(
        [],
        "scheme files (ftcreport.schemes) loaded before [schemes] is read, paths relative to the case file; each "
        "registers its schemes, which [schemes.<name>] and schemes.run may then name",
        "-",
    )
    base_case: str | None = _f(
        None,
        "path of the case this file overlays, relative to this file: the base's tables, then this file's "
        "(tables merged key by key, arrays such as [[faults]] replaced whole); name, description, thresholds, "
        "claims, requirements, baseline, campaign, expected_status and expected_status_of are this file's own, never "
        "the base's",
        "-",
        max_length=1000,
    )
    robots: Robots = _f(..., "the chain ([robots])", "-")
    reference: Reference = _f(..., "the last robot's path ([reference])", "-")
    initial: Initial = _f(Initial(), "initial state ([initial])", "-")
    faults: list[Fault] = _f([], "fault events sorted by time ([[faults]])", "-")
    actuators: Actuators | None = _f(
        None, "DC motors on the wheels ([actuators]); absent: the wheel torque is the command", "-"
    )
    kinematic: Kinematic = _f(..., "kinematic controller ([kinematic])", "-")
    schemes: Schemes = _f(..., "the schemes to run ([schemes.<name>])", "-")
    simulation: Simulation = _f(..., "integration settings ([simulation])", "-")
    plant: Plant = _f(Plant(), "saturation, noise, mismatch ([plant])", "-")
    recovery_band: _num(None, 1e3, gt=0) = _f(0.01, "the band of the recovery-time metric", "m")
    expected_status: list[Status] = _f(
        ["ok"],
        "run outcomes that are not failures for batch/run exit codes (a case built to lose tracking lists them)",
        "-",
    )
    expected_status_of: dict[str, list[Status]] = _f(
        {},
        "per scheme: its outcomes that are not failures, in place of expected_status (say why in a comment)",
        "-",
    )
    thresholds: dict[str, dict[str, Bound]] = _f(
        {}, "[thresholds.<scheme>] metric = { min, max } for ftcreport check", "-"
    )
    campaign: CampaignSpec | None = _f(None, "distributions for ftcreport campaign (ignored by batch)", "-")
    claims: list[Claim] = _f([], "thesis claims checked against the runs ([[claims]], ftcreport.claims)", "-")
    requirements: list[Requirement] = _f(
        [], "bounds on a signal over event-defined windows ([[requirements]], ftcreport.requirements)", "-"
    )
    baseline: BaselineSpec | None = _f(
        None, "tolerances of check --baseline ([baseline], ftcreport.baseline); absent: the documented defaults", "-"
    )

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str | None) -> str | None:
        return _check_name(v)

    @model_validator(mode="after")
    def _budget(self) -> Case:
        _check_budget(self)
        return self

    @field_validator("faults")
    @classmethod
    def _sorted(cls, v: list[Fault]) -> list[Fault]:
        times = [f.time for f in v]
        if times != sorted(times):
            k = next(i for i in range(1, len(times)) if times[i] < times[i - 1])
            raise ValueError(
                f"events must be sorted by time: event {k} (t = {times[k]}) comes after t = {times[k - 1]}"
            )
        return v

    @model_validator(mode="after")
    def _consistency(self) -> Case:
        n = self.robots.n
        for i, f in enumerate(self.faults):
            try:
                wheel_index(f.wheel, n)
            except FtcError as exc:
                raise _FieldError(f"faults[{i}].wheel", str(exc)) from None
            if f.time >= self.simulation.duration:
                raise _FieldError(
                    f"faults[{i}].time", f"{f.time} s is not before the end of the run ({self.simulation.duration} s)"
                )
        for i, f in enumerate(self.faults):
            _check_motor_fault(i, f, self.actuators is not None)
        if self.actuators is not None:
            for table, prefix in ((self.actuators, "actuators"), (self.actuators.drive_model, "actuators.drive_model")):
                for key in type(table).model_fields:
                    v = getattr(table, key)
                    if isinstance(v, list) and len(v) != n:
                        raise _FieldError(f"{prefix}.{key}", f"{len(v)} values given, a {n}-robot chain needs {n}")
            _check_drive_rate(self.actuators, self.simulation)
        seen: set[tuple[float, int]] = set()
        for i, f in enumerate(self.faults):
            key = (f.time, wheel_index(f.wheel, n))
            if key in seen:
                raise _FieldError(f"faults[{i}]", f"a second event on wheel {f.wheel} at t = {f.time}")
            seen.add(key)
        if self.kinematic.kind == "two_link":
            if n != 2:
                raise _FieldError("kinematic.kind", f"'two_link' needs 2 robots, the chain has {n}; use 'chained'")
            for k in ("k1", "k2", "k3"):
                if getattr(self.kinematic, k) is None:
                    raise _FieldError(f"kinematic.{k}", "required by the two-link controller")
        if isinstance(self.kinematic.c_chain, list) and len(self.kinematic.c_chain) != n:
            raise _FieldError("kinematic.c_chain", f"{len(self.kinematic.c_chain)} gains given, {n} needed")
        if self.simulation.dt > self.simulation.duration:
            raise _FieldError("simulation.dt", "longer than the duration")
        for sname in configured_schemes(self):  # each scheme's own checks of its table against the case
            hook = _scheme_hook(sname, "validate")
            if hook is not None:
                hook(getattr(self.schemes, sname), self)
        for key in ("a", "b", "r", "m", "I", "d"):
            v = getattr(self.plant.mismatch, key)
            count = n - 1 if key == "d" else n
            if isinstance(v, list) and len(v) != count:
                raise _FieldError(f"plant.mismatch.{key}", f"{len(v)} factors given, {count} needed")
        if self.initial.headings_deg is not None and len(self.initial.headings_deg) != n:
            raise _FieldError("initial.headings_deg", f"{len(self.initial.headings_deg)} values for {n} robots")
        _check_initial_articulation(self.initial, self.simulation.singularity_margin_deg)
        if self.campaign is not None:
            if self.campaign.fault_time[1] >= self.simulation.duration:
                raise _FieldError(
                    "campaign.fault_time",
                    f"upper bound must be before the end of the run ({self.simulation.duration} s)",
                )
            _check_campaign_draws(self.campaign, n, keeps=bool(self.faults))
        run = self.schemes.run
        if run is not None and not run:
            raise _FieldError(
                "schemes", "no scheme to run: schemes.run is empty (list some of " + ", ".join(SCHEME_NAMES) + ")"
            )
        listed = {str(Path(p).resolve()) for p in self.plugins}
        for s in list(self.schemes.model_extra or {}):
            where = _scheme_file(s)
            if where is not None and where not in listed:
                raise _FieldError(
                    f"schemes.{s}",
                    f"scheme '{s}' comes from {where}, which this case does not list in plugins (a batch or campaign "
                    "worker would not know it)",
                )
        for s in configured_schemes(self):
            if run is not None and s not in run:
                raise _FieldError(f"schemes.{s}", f"configured but not listed in schemes.run ({', '.join(run)})")
        known = known_schemes()
        outcomes = ", ".join(repr(v) for v in get_args(Status))
        if not self.expected_status:
            raise _FieldError(
                "expected_status", f"empty: every run would count as failed, even 'ok'; list some of {outcomes}"
            )
        for s, listed in self.expected_status_of.items():
            if not listed:
                raise _FieldError(
                    f"expected_status_of.{s}",
                    f"empty: every run of {s} would count as failed, even 'ok'; list some of {outcomes}",
                )
        for s in self.expected_status_of:
            if s not in known:
                raise _FieldError(
                    f"expected_status_of.{s}", f"unknown scheme{did_you_mean(s, known)} (known: {', '.join(known)})"
                )
        ids = [c.id for c in self.claims]
        for i, c in enumerate(self.claims):
            if ids.count(c.id) > 1:
                raise _FieldError(f"claims[{i}].id", f"'{c.id}' is used by more than one claim")
            for key in ("scheme", "relative_to"):
                s = getattr(c, key)
                if s is not None and run is not None and s not in run:
                    raise _FieldError(f"claims[{i}].{key}", f"scheme '{s}' is not run by this case (schemes.run)")
            if c.not_applicable is None and c.metric is not None:
                kinds = ("sequence",) if c.sequence is not None else ("number", "table", "list")
                for s in (c.scheme, c.relative_to):
                    if s is not None and (why := metric_problem(s, c.metric, kinds)) is not None:
                        raise _FieldError(f"claims[{i}].metric", why)
        _check_requirements(self, run, known)
        for scheme, metrics in self.thresholds.items():
            if scheme not in known:
                raise _FieldError(
                    f"thresholds.{scheme}", f"unknown scheme{did_you_mean(scheme, known)} (known: {', '.join(known)})"
                )
            for metric, bound in metrics.items():
                if (why := metric_problem(scheme, metric)) is not None:
                    raise _FieldError(f"thresholds.{scheme}.{metric}", why)
                if bound.min is None and bound.max is None:
                    raise _FieldError(f"thresholds.{scheme}.{metric}", "give min, max or both")
        return self

    # ------------------------------------------------------------------ derived
    def expected_for(self, scheme: str) -> set[str]:
        """Outcomes of ``scheme``'s run that are not failures (expected_status_of, else expected_status)."""
        return set(self.expected_status_of.get(scheme, self.expected_status))

    def unexpected(self, scheme: str, status: str, reason: str | None) -> str:
        """Why a run of ``scheme`` that ended ``status`` is a failure: its reason, or which field expected otherwise."""
        if reason:
            return f"{status}: {reason}"
        field = f"expected_status_of.{scheme}" if scheme in self.expected_status_of else "expected_status"
        want = " or ".join(repr(s) for s in sorted(self.expected_for(scheme)))
        return f"{status}, where the case expects {want} ({field})"

    def fault_schedule(self) -> FaultSchedule:
        return FaultSchedule(
            self.robots.n,
            [FaultEvent(f.time, f.wheel.strip().lower(), f.sigma, f.ubar, f.motor, f.value) for f in self.faults],
        )

    def motor_params(self) -> list[MotorParams] | None:
        """The wheels' motors per robot, leader first ([actuators]), or None without the table."""
        return None if self.actuators is None else self.actuators.params(self.robots.n)

    def drive_params(self) -> list[DriveParams] | None:
        """The wheels' drives per robot, leader first ([actuators]), or None without the table."""
        return None if self.actuators is None else self.actuators.drive_params(self.robots.n)

    def warnings(self) -> list[str]:
        """Uncompensable phases, naming the event that makes them so; an RK4 step the motors' currents defeat."""
        out = []
        motors = self.motor_params()
        rk4 = None if motors is None else _rk4_on_currents(self.simulation, motors, self.drive_params())
        if rk4 is not None:
            out.append(rk4)
        sw = getattr(self.schemes, "switching", None)
        if motors is not None and sw is not None and sw.c_int == 0.0 and "switching" in configured_schemes(self):
            out.append(
                "schemes.switching: with [actuators] the thesis's instantaneous cost (c_int = 0) takes the drive's "
                "torque errors for lost wheels, and a model chosen on one such moment stays (the wheels it leaves "
                "undriven cannot be tested): measured 62 % exact identification on three_link_switching_motors "
                "against 99.6 % without motors; c_int = 10, forgetting = 1 (Narendra & Balakrishnan's cost) gives "
                "97.8 % (cases/README.md, the switching bank with motors)"
            )
        sched = self.fault_schedule()
        names = wheel_names(self.robots.n)
        for start, end, pat in sched.uncompensable_intervals(self.simulation.duration):
            idx = [i for i, f in enumerate(self.faults) if f.time == start]
            failed = [w for w, s in zip(names, pat, strict=True) if s == 0]
            why = (
                "both wheels of robot 1 failed: omega_1 cannot be actuated"
                if pat[0] == 0 and pat[1] == 0
                else "fewer than two wheels work"
            )
            where = f"faults[{idx[0]}]" if idx else "faults"
            out.append(
                f"{where} (t = {start:g} s): pattern with {','.join(failed)} failed is uncompensable "
                f"until {end:g} s ({why}); tracking is expected to be lost"
            )
        return out


def _check_drive_rate(act: Actuators, sim: Simulation) -> None:
    """A sampled PI drive's period must be a whole number of steps (its samples land on steps)."""
    if act.drive_rate is None:
        return
    period = 1.0 / act.drive_rate
    ratio = period / sim.dt
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise _FieldError(
            "actuators.drive_rate",
            f"{act.drive_rate:g} Hz (period {period:g} s) is not a whole number of steps dt = {sim.dt:g} s: "
            "the drive's samples must land on steps (choose dt = period / k)",
        )


def _check_requirements(case: Case, run: list[str] | None, known: list[str]) -> None:
    """[[requirements]]: ids unique, the scheme known and run, robots and wheels of this chain."""
    ids = [r.id for r in case.requirements]
    for i, r in enumerate(case.requirements):
        if r.id in ids[:i]:
            raise _FieldError(f"requirements[{i}].id", f"'{r.id}' is already the id of requirements[{ids.index(r.id)}]")
        if r.scheme != "*" and r.scheme not in known:
            raise _FieldError(
                f"requirements[{i}].scheme",
                f"unknown scheme '{r.scheme}'{did_you_mean(r.scheme, known)} (known: {', '.join(known)}, or \"*\")",
            )
        if r.scheme != "*" and run is not None and r.scheme not in run:
            raise _FieldError(f"requirements[{i}].scheme", f"scheme '{r.scheme}' is not run by this case (schemes.run)")
        for key, why in r.problems(case.robots.n):
            raise _FieldError(f"requirements[{i}].{key}", why)
def metric_problem(scheme: str, name: str, kinds: tuple[str, ...] = ("number",)) -> str | None:
    """Why the metric ``name`` cannot be compared on a run of ``scheme`` as one of ``kinds``, or None.

    The names are those a run writes (:data:`ftcreport.metrics.METRICS`, the one list); ``name`` may be
    ``metric.key``, an entry of a table metric.  An unknown name gets the closest of the scheme's own.
    """
    from .metrics import METRICS, metrics_of

    base, _, key = name.partition(".")
    own = metrics_of(scheme)
    if base not in METRICS:
        hint = did_you_mean(base, own) or f" (a {scheme} run writes {', '.join(_numbers(own))})"
        return f"unknown metric{hint}"
    m = METRICS[base]
    if base not in own:
        return f"'{base}' is not a metric of the {scheme} scheme (only {', '.join(m.schemes or ())} runs write it)"
    if key and m.kind != "table":
        return f"'{base}' is a {m.kind}, not a table of numbers: '{name}' reads no entry of it"
    kind = "number" if key else m.kind
    if kind not in kinds:
        return f"'{base}' is not a number (a {m.kind}); compare {' or '.join(kinds)} metrics here"
    return None


def _numbers(names: list[str]) -> list[str]:
    from .metrics import METRICS

    return [k for k in names if METRICS[k].kind == "number"]


def _check_campaign_draws(spec: CampaignSpec, n: int, keeps: bool) -> None:
    """The faults a campaign draws exist: its wheels are wheels of the chain, each listed once, at least
    as many as the faults it draws per sample (each on a distinct wheel), and it draws a fault at all
    (unless the case keeps faults of its own)."""
    lo, hi = spec.faults
    if spec.wheels == "any":
        wheels, which = wheel_names(n), f"the {2 * n} wheels of the {n}-robot chain"
    else:
        if not spec.wheels:
            raise _FieldError(
                "campaign.wheels", 'no wheel: a sample could draw no fault; list the wheels a fault may hit, or "any"'
            )
        seen: dict[str, int] = {}
        for i, w in enumerate(spec.wheels):
            try:
                wheel_index(w, n)
            except FtcError as exc:
                raise _FieldError(f"campaign.wheels[{i}]", str(exc)) from None
            first = seen.setdefault(w.strip().lower(), i)
            if first != i:
                raise _FieldError(
                    f"campaign.wheels[{i}]", f"{w!r} is listed twice (wheels[{first}]); faults hit distinct wheels"
                )
        wheels, which = list(seen), f"the {len(seen)} wheels of campaign.wheels"
    if hi > len(wheels):
        raise _FieldError(
            "campaign.faults",
            f"up to {hi} faults per sample, each on a distinct wheel, but only {len(wheels)} wheels can fail "
            f"({which}); the draw would be cut silently",
        )
    if hi == 0 and not (spec.keep_base_faults and keeps):
        raise _FieldError(
            "campaign.faults",
            f"[{lo}, {hi}] draws no fault and keeps none of the case's (keep_base_faults): every sample would be "
            "fault-free and 'succeed'; give an upper bound of 1 or more",
        )


def _check_motor_fault(i: int, f: Fault, has_actuators: bool) -> None:
    """A [[faults]] entry's motor fields: the kind needs [actuators], its value its range."""
    if f.motor is None:
        if f.value is not None:
            raise _FieldError(f"faults[{i}].value", "a value belongs to a motor fault: set motor (or remove value)")
        return
    if not has_actuators:
        raise _FieldError(
            f"faults[{i}].motor", f"motor fault {f.motor!r} needs the [actuators] table (the plant has no motors)"
        )
    for key in ("sigma", "ubar"):
        if key in f.model_fields_set:
            raise _FieldError(
                f"faults[{i}].{key}", f"a motor event sets the motor only; give {key} in an event of its own"
            )
    try:
        motor_row(f.motor, f.value)
    except FtcError as exc:
        raise _FieldError(f"faults[{i}].value", str(exc)) from None


def _check_initial_articulation(ini: Initial, margin_deg: float) -> None:
    """Absolute headings whose articulation angle starts within the singularity margin of 90 deg (ERRATA P4).

    The engine's test (fast.kernels._check_state: |cos(theta_i - theta_(i+1))| <= sin(margin)) on the
    headings as given, so the run that would stop at t = 0 is refused here, naming the field.  Offset
    mode adds the reference's headings at t = 0 (built only with the reference): the run checks those.
    """
    if ini.mode != "absolute" or ini.headings_deg is None:
        return
    lim = math.sin(math.radians(margin_deg))
    th = [math.radians(h) for h in ini.headings_deg]
    for i in range(len(th) - 1):
        if abs(math.cos(th[i] - th[i + 1])) <= lim:
            phi = ini.headings_deg[i] - ini.headings_deg[i + 1]
            raise _FieldError(
                "initial.headings_deg",
                f"the articulation angle theta_{i + 1} - theta_{i + 2} = {phi:g} deg starts within "
                f"simulation.singularity_margin_deg = {margin_deg:g} deg of +/-90 deg: the chain is singular "
                "there (ERRATA P4) and the run would stop at t = 0",
            )


#: The leftmost point of RK4's stability region |1 + z + z^2/2 + z^3/6 + z^4/24| <= 1, on the real axis
#: (z = -2.7853; a scan of the complex plane finds no point of the region further left).
RK4_REAL_LIMIT = 2.785


def _rk4_on_currents(sim: Simulation, motors: list[MotorParams], drives: list[DriveParams]) -> str | None:
    """RK4 with a step no armature current survives (the run stops step_unstable): a warning, else None.

    A motor's current and speed obey L_a J s^2 + (R_a J + L_a b) s + (R_a b + k_m k_b) = 0 (thesis
    (2.26)-(2.29)); the roots sum to -(R_a / L_a + b / J), so the fast one (or a complex pair's real part)
    lies at or left of -R_a / (2 L_a), and RK4 is unstable for certain once dt R_a / (2 L_a) > 2.785.
    A continuous PI drive adds K_p to R_a (L_a s^2 + (R_a + K_p) s + K_i = 0 with the rotor held; with
    the gains of pole-zero cancellation the roots are -R_a / L_a and -2 pi f): the bound is then
    dt (R_a + K_p) / (2 L_a).  Steps between the likely and the certain bound may fail too (the run
    says so); ETD2 is exact on the currents and the drive at any step (fast.loop._etd2).
    """
    if sim.method != "rk4":
        return None
    pi = drives[0].driver == "pi" and drives[0].drive_rate is None
    # [s] the fastest time constant: L_a / (R_a + K_p), K_p = 0 without the PI
    tau = min(m.L_a / (m.R_a + (d.kp if pi else 0.0)) for m, d in zip(motors, drives, strict=True))
    if sim.dt / (2.0 * tau) <= RK4_REAL_LIMIT:
        return None
    what = "L_a / (R_a + K_p)" if pi else "L_a / R_a"
    return (
        f"simulation.dt: {sim.dt:g} s with method = 'rk4' cannot integrate the armature currents of [actuators] "
        f"({what} = {tau * 1e3:.3g} ms: RK4 is unstable beyond dt = {2 * RK4_REAL_LIMIT * tau * 1e3:.3g} ms "
        f"for certain, likely beyond {RK4_REAL_LIMIT * tau * 1e3:.3g} ms): the runs will stop step_unstable; use "
        'method = "etd2" (exact on the currents at any step) or a smaller dt'
    )


def _check_name(v: str | None) -> str | None:
    """A case name is a directory name and a page title: the safe set of ftcreport.limits."""
    if v is not None and (why := name_problem(v)) is not None:
        raise ValueError(why)
    return v


def _check_budget(case: Case) -> None:
    """Refuse, before it starts, a run over the step limit or memory budget (ftcreport.limits)."""
    s = case.simulation
    for scheme in configured_schemes(case):
        cfg = getattr(case.schemes, scheme)
        pats = getattr(cfg, "patterns", "all")
        models = None if pats == "all" else len(pats)
        problem = budget_problem(case.robots.n, s.duration, s.dt, s.log_every, scheme, models)
        if problem is not None:
            raise _FieldError(*problem)


def _is_tag(part: Any) -> bool:
    """A union member's tag in a pydantic error location (``constrained-float``, ``list[...]``, a model name)."""
    if not isinstance(part, str):
        return False
    return "[" in part or part.startswith(("constrained-", "function-")) or part in _TAGS


_TAGS = {"float", "int", "str", "bool", "list", "tuple", "dict", "none"} | {
    cls.__name__ for cls in _Strict.__subclasses__()
}


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if _is_tag(part):
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _submodel(annotation: Any) -> type[BaseModel] | None:
    """The model class inside an annotation (``X | None``, ``list[X]``), or None."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in get_args(annotation):
        found = _submodel(arg)
        if found is not None:
            return found
    return None


def known_fields(loc: tuple[Any, ...], root: type[BaseModel]) -> list[str]:
    """Field names of the table at ``loc`` (a pydantic location inside ``root``), [] when it is not a table."""
    model = _table_model(loc, root)
    return [] if model is None else list(model.model_fields)


def _table_model(loc: tuple[Any, ...], root: type[BaseModel]) -> type[BaseModel] | None:
    """The model of the table at ``loc`` (a pydantic location inside ``root``: the case, or a plug-in's
    parameter table), None when it is not a table."""
    model: type[BaseModel] = root
    skip = 0  # keys of dict-valued fields (thresholds.<scheme>.<metric>) are not field names
    for part in loc:
        if isinstance(part, int) or _is_tag(part):
            continue
        if skip:
            skip -= 1
            continue
        field = model.model_fields.get(part)
        sub = None if field is None else _submodel(field.annotation)
        if sub is None:
            return None
        skip = _dict_depth(field.annotation)
        model = sub
    return model


def _dict_depth(annotation: Any) -> int:
    """How many dict levels wrap the model of a field (``dict[str, dict[str, Bound]]``: 2)."""
    depth = 0
    while get_origin(annotation) is dict:
        depth += 1
        annotation = get_args(annotation)[1]
    return depth


_BOUND_OPS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="), "less_than": ("lt", "<")}
_BOUND_OPS["less_than_equal"] = ("le", "<=")


def _message(err: dict, root: type[BaseModel]) -> str:
    """One reason for one pydantic error of a ``root`` model: ranges as 'must be >= 0, got -1', unknown keys with
    a suggestion."""
    kind = err["type"]
    if kind == "extra_forbidden":
        key = str(err["loc"][-1])
        return "unknown field" + did_you_mean(key, known_fields(tuple(err["loc"][:-1]), root))
    if kind in _BOUND_OPS:
        name, op = _BOUND_OPS[kind]
        return f"must be {op} {err['ctx'][name]:g}, got {err['input']}"
    if kind in ("literal_error", "enum"):  # every Literal (and enum) field of the schema
        return _choice_message(err["input"], str((err.get("ctx") or {}).get("expected", "")))
    if kind == "missing":
        return _missing_message(tuple(err["loc"]), root)
    if kind in _EXPECTED:
        return f"{_EXPECTED[kind]} is expected, got {_describe(err['input'])}"
    if kind == "finite_number":
        return f"must be a finite number, got {err['input']}"
    if kind in ("too_long", "too_short"):  # a fixed-length pair ([x, y]) or a bounded list
        ctx = err.get("ctx") or {}
        most, least = ctx.get("max_length"), ctx.get("min_length")
        bound = f"at most {most}" if kind == "too_long" else f"at least {least}"
        return f"{bound} values are expected, got {ctx.get('actual_length', '?')}"
    return err["msg"].removeprefix("Value error, ")


#: pydantic's type errors in the file's words (its own say "a valid dictionary or instance of Simulation")
_EXPECTED = {
    "model_type": "a table",
    "model_attributes_type": "a table",
    "dict_type": "a table",
    "list_type": "a list",
    "tuple_type": "a list",
    "string_type": "a text (in quotes)",
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "a whole number",
    "int_parsing": "a whole number",
    "int_parsing_size": "a whole number of at most 19 digits",
    "int_from_float": "a whole number",
    "bool_type": "true or false",
    "bool_parsing": "true or false",
}


def _describe(v: Any) -> str:
    """A TOML value as the user wrote it: ``the number 1.5``, ``the text 'x'``, ``a table``."""
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, int | float):
        return f"the number {v!r}"
    if isinstance(v, str):
        return f"the text {v[:60]!r}" + ("..." if len(v) > 60 else "")
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list | tuple):
        return "a list"
    return f"a {type(v).__name__}"  # a TOML date or time


def _missing_message(loc: tuple[Any, ...], root: type[BaseModel]) -> str:
    """``required and missing: <the field's description>; add it to [table]`` (the schema's own words)."""
    if isinstance(loc[-1], int):  # an item of a fixed-length list ([x, y]) left out
        return f"item {loc[-1]} is missing: {_format_loc(loc[:-1])} needs {loc[-1] + 1} values or more"
    model = _table_model(loc[:-1], root)
    field = None if model is None else model.model_fields.get(str(loc[-1]))
    what = f": {field.description.rstrip('.')}" if field is not None and field.description else ""
    table = _format_loc(loc[:-1])
    where = f"; add it to [{table}]" if table and not isinstance(loc[-2], int) else ""
    return f"required and missing{what}{where}"


def _choice_message(value: Any, expected: str) -> str:
    """``got 'circel'; expected one of 'unicycle', 'circle', ... (did you mean 'circle'?)``.

    ``expected`` is pydantic's list of the allowed values (``'a', 'b' or 'c'``); the closest one
    to a string value is suggested (difflib, :func:`did_you_mean`).
    """
    allowed = re.findall(r"'([^']*)'", expected)
    if not allowed:  # not strings (numbers): pydantic's own list
        return f"got {value!r}; expected one of {expected}"
    hint = did_you_mean(value, allowed) if isinstance(value, str) else ""
    return f"got {value!r}; expected one of {', '.join(repr(a) for a in allowed)}{hint}"


def _rank(err: dict) -> int:
    """Errors of the union member that matches the input's type first (a type mismatch is the other member)."""
    kind = err["type"]
    if kind == "extra_forbidden":  # a misspelt key also makes its field "missing": name the typo first
        return -1
    return int(kind.endswith("_type") or kind == "literal_error" or kind.endswith("_parsing"))


def _field_errors(errors: list[dict], root: type[BaseModel]) -> list[tuple[str, str]]:
    """Every field in error once, as (field path, reason): pydantic's errors of a ``root`` model grouped by field.

    A union field reports one error per member (``a = -300`` is neither a valid float nor a list):
    the member that matches the input's type is the reason (:func:`_rank`), and a member whose
    error lies deeper (``a[1]`` of the list member) stands for the field alone.  Typos of keys
    come first, then wrong values, then wrong types; otherwise pydantic's order (the file's).
    """
    groups: dict[str, list[tuple[int, dict]]] = {}
    for err in errors:
        ctx_err = (err.get("ctx") or {}).get("error")
        loc = ctx_err.loc if isinstance(ctx_err, _FieldError) else _format_loc(tuple(err["loc"])) or "<root>"
        groups.setdefault(loc, []).append((_rank(err), err))

    def inside(child: str, parent: str) -> bool:
        return parent == "<root>" or child.startswith((parent + ".", parent + "["))

    def type_only(loc: str) -> bool:
        return all(rank > 0 for rank, _ in groups[loc])

    kept = [loc for loc in groups if not (type_only(loc) and any(inside(o, loc) for o in groups if o != loc))]
    best = {loc: min(groups[loc], key=lambda pair: pair[0]) for loc in kept}  # stable: the first of the best rank
    out = []
    for loc in sorted(kept, key=lambda loc: best[loc][0]):
        err = best[loc][1]
        ctx_err = (err.get("ctx") or {}).get("error")
        out.append((loc, ctx_err.msg if isinstance(ctx_err, _FieldError) else _message(err, root)))
    return out


def parse_case(data: dict, source: str = "<case>") -> Case:
    """Validate a case given as a dict (parsed TOML); raise CaseError naming the field.

    The scheme files of ``plugins`` are loaded first (their schemes register themselves), and the
    case keeps their absolute paths, so a worker that parses the case's JSON loads them too.
    """
    controls = _control_errors(data)  # reported with the other fields in error, the field once
    try:
        data = _load_plugins(data, source)
        case = Case.model_validate(data)
    except ValidationError as exc:
        found = {loc for loc, _ in controls}
        _refuse(source, controls + [(loc, why) for loc, why in _field_errors(exc.errors(), Case) if loc not in found])
    except CaseError:
        if controls:  # a plugins path with a control character is not looked for
            _refuse(source, controls)
        raise
    if controls:
        _refuse(source, controls)
    if case.name is None:
        stem = Path(source).stem
        if (why := name_problem(stem)) is not None:
            raise CaseError(f'{source}: name: taken from the file name: {why}; set name = "..." in the file')
        case = case.model_copy(update={"name": stem})
    from .families import fill_defaults  # every FTC family unless schemes.run narrows the list (issue 21)

    return fill_defaults(case)


#: Fields of prose that may span lines (a TOML multi-line string): tabs and line ends are allowed there.
_PROSE = ("words", "note")


def _refuse(source: str, errors: list[tuple[str, str]]) -> None:
    """Raise the CaseError of every (field, reason), the first in its message with the count of the others."""
    lines = [f"{printable(source)}: {loc}: {why}" for loc, why in errors]
    more = f" (and {len(lines) - 1} more; 'ftcreport cases validate' lists every one)" if len(lines) > 1 else ""
    raise CaseError(lines[0] + more, lines) from None


def _control_errors(data: Any) -> list[tuple[str, str]]:
    """(field, reason) of every text of the case, keys included, that holds a control character (C0, DEL, C1).

    Every text of a case reaches a terminal line, a page or a JUnit file; an escape sequence rewrites
    the terminal, NUL and most others make XML ill-formed (issue 34 item 7).  Only the claims' prose
    (:data:`_PROSE`) may hold tabs and line ends.
    """
    import unicodedata

    out: list[tuple[str, str]] = []

    def why(text: str, allowed: str = "") -> str | None:
        bad = next(((i, c) for i, c in enumerate(text) if unicodedata.category(c) == "Cc" and c not in allowed), None)
        if bad is None:
            return None
        shown = printable(text[:60]) + ("..." if len(text) > 60 else "")
        return (
            f"control character U+{ord(bad[1]):04X} at position {bad[0]} of '{shown}': a text of a case holds "
            "printable characters only (a control character breaks the terminal, the pages and the JUnit file)"
        )

    def walk(v: Any, path: str, key: str) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                sub = f"{path}.{printable(k)}" if path else printable(k)
                if isinstance(k, str) and (w := why(k)) is not None:
                    out.append((sub, w))
                walk(x, sub, str(k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, f"{path}[{i}]", key)
        elif isinstance(v, str) and (w := why(v, "\t\n\r" if key in _PROSE else "")) is not None:
            out.append((path or "<root>", w))

    walk(data, "", "")
    return out


def _load_plugins(data: dict, source: str) -> dict:
    """Load the case's scheme files (paths relative to the case file's directory); the absolute paths."""
    plugins = data.get("plugins") if isinstance(data, dict) else None
    if plugins is None:
        return data
    if not isinstance(plugins, list) or not all(isinstance(p, str) for p in plugins):
        raise CaseError(f"{source}: plugins: a list of scheme file paths is expected, got {plugins!r}")
    from .schemes import load_plugin

    base = Path(source).parent
    resolved = []
    for i, p in enumerate(plugins):
        path = Path(p).expanduser()
        path = path if path.is_absolute() else base / path
        if not os.path.lexists(path):
            raise CaseError(f"{source}: plugins[{i}]: no such scheme file: {path}")
        try:
            load_plugin(path)
        except FtcError as exc:  # a file that fails or calls sys.exit on import (load_plugin names it)
            raise CaseError(f"{source}: plugins[{i}]: {exc}") from None
        resolved.append(str(path.resolve()))
    return {**data, "plugins": resolved}


def plugin_digest(case: Case) -> str:
    """Hash of the contents of the case's scheme files ('' when it has none): a changed law is a changed case."""
    if not case.plugins:
        return ""
    h = hashlib.sha256()
    for p in case.plugins:
        try:
            h.update(Path(p).name.encode() + b"\0" + read_input(p, "scheme file"))
        except CaseError:
            h.update(f"{p}: unreadable".encode())
    return h.hexdigest()[:16]


def case_schema() -> dict[str, Any]:
    """The JSON Schema of a case file, generated from the models (descriptions, units, ranges).

    ``ftcreport cases schema`` prints it; ``cases/case.schema.json`` is this, written by
    ``python -m ftcreport.schema_doc`` (a test fails when it drifts).
    """
    schema = Case.model_json_schema(mode="validation")
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://ftcreport.invalid/case.schema.json",
        **schema,
        "title": "ftcreport case file",
    }


def load_case(path: str | Path) -> Case:
    """Read and validate a TOML case file (an overlay is resolved over its ``base_case`` first)."""
    path = Path(path)
    data = _read_toml(path)
    if "base_case" not in data:
        return parse_case(data, str(path))
    merged = resolve_overlay(path, data)
    try:
        return parse_case(merged, str(path))
    except CaseError as exc:
        lines = [_name_base_field(line, str(path), data, merged) for line in exc.lines]
        raise CaseError(_name_base_field(str(exc), str(path), data, merged), lines) from None


#: Fields an overlay never takes from its base: they describe the base's own results or identity.
OWN_FIELDS = (
    "name",
    "description",
    "thresholds",
    "claims",
    "requirements",
    "baseline",
    "campaign",
    "expected_status",
    "expected_status_of",
)


def _merge(base: dict, over: dict) -> dict:
    """``over`` on ``base``: tables merged key by key, anything else (values, arrays) replaced whole."""
    out = dict(base)
    for key, val in over.items():
        if isinstance(val, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], val)
        else:
            out[key] = val
    return out


def resolve_overlay(path: Path, data: dict, _seen: tuple[Path, ...] = ()) -> dict:
    """The full case of an overlay file: its base (resolved in turn), without OWN_FIELDS, then ``data``.

    ``base_case`` stays in the result (provenance; :func:`parse_case` only checks it is a string).
    Errors name the overlay file and its ``base_case`` field.
    """
    ref = data.get("base_case")
    if not isinstance(ref, str) or not ref.strip():
        raise CaseError(f"{path}: base_case: must be the path of a case file (a string), got {ref!r}")
    if (why := input_problem(path.parent / ref)) is not None:  # a FIFO, device, directory, link loop: never opened
        raise CaseError(f"{path}: base_case: '{ref}': {why}")
    base_path = (path.parent / ref).resolve()
    seen = (*_seen, path.resolve())
    if base_path in seen:
        chain = " -> ".join(str(p) for p in (*seen, base_path))
        raise CaseError(f"{path}: base_case: '{ref}' makes a cycle ({chain})")
    if len(seen) > 8:
        raise CaseError(f"{path}: base_case: more than 8 overlays deep")
    try:
        base = _read_toml(base_path)
    except CaseError as exc:
        raise CaseError(f"{path}: base_case: '{ref}': {exc}") from None
    if "base_case" in base:
        base = resolve_overlay(base_path, base, seen)
    base = {k: v for k, v in base.items() if k not in OWN_FIELDS and k != "base_case"}
    return _merge(base, data)


_ABSENT = object()


def _lookup(node: Any, parts: list[str]) -> Any:
    """The value at a field path's parts (``["faults", "[1]", "value"]``) in parsed TOML, or _ABSENT."""
    for part in parts:
        if part.startswith("[") and isinstance(node, list):
            i = int(part.strip("[]"))
            if i >= len(node):
                return _ABSENT
            node = node[i]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return _ABSENT
    return node


def _name_base_field(message: str, source: str, overlay: dict, merged: dict) -> str:
    """Say so when the field an error names has its value from the base case, not from the overlay.

    A field in neither (a required field missing, an event's value left out) is nobody's: no note.
    """
    rest = message.removeprefix(f"{source}: ")
    loc = rest.split(": ", 1)[0]
    parts = [p for p in loc.replace("[", ".[").split(".") if p]
    if not parts or loc in ("<root>", "name"):
        return message
    if _lookup(overlay, parts) is _ABSENT and _lookup(merged, parts) is not _ABSENT:
        return f"{message} (the value comes from the base case {overlay['base_case']})"
    return message


def overlay_text(path: str | Path) -> str | None:
    """The resolved case of an overlay file as TOML text (None for a plain case file).

    Batch and run store this beside the runs, so the stored copy parses on its own; the overlay's
    own text follows as comments (provenance).
    """
    path = Path(path)
    data = _read_toml(path)
    if "base_case" not in data:
        return None
    merged = resolve_overlay(path, data)
    own = "".join(f"# | {line}\n" for line in read_input(path).decode("utf-8").splitlines())
    body = "".join(f"{_toml_key(k)} = {_toml_value(v)}\n" for k, v in merged.items())
    return f"# {path} resolved over its base case {data['base_case']}; the file itself:\n{own}\n{body}"


def _toml_key(key: str) -> str:
    return key if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key) else _toml_string(key)


def _toml_string(s: str) -> str:
    """A TOML basic string: quote, backslash and control characters escaped (TOML 1.0, "String").

    Not ``json.dumps``: JSON writes a character beyond U+FFFF as a surrogate pair of escapes, which
    TOML refuses (a stored overlay with such a description read back as damaged), and leaves U+007F as is.
    """
    out = []
    for ch in s:
        o = ord(ch)
        if ch in '"\\':
            out.append("\\" + ch)
        elif (o < 0x20 and ch != "\t") or o == 0x7F:
            out.append(f"\\u{o:04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(v: Any) -> str:
    """One TOML value on one line (inline tables and arrays; a case file holds nothing else)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise CaseError(f"cannot write {type(v).__name__} as TOML")


def _read_toml(path: Path) -> dict:
    """A TOML file as a dict; CaseError naming the file when it cannot be read or parsed."""
    raw = read_input(path)  # a regular file of a bounded size, or CaseError naming it (never blocks)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CaseError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); a case file is TOML text"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise CaseError(f"{path}: not valid TOML (nested too deeply)") from None
    return data


def case_hash(case: Case, version: str) -> str:
    """Content hash of a validated case and the package version (result cache key).

    The thesis claims are left out: they are judged on stored metrics and change no run.
    """
    # the motor fields (issue 19) are left out when unused, so older cases keep their hashes
    # [baseline] only sets check's tolerances; [[requirements]] are evaluated during the run (from every
    # step) and so belong to its content, left out when absent so that older cases keep their hashes
    exclude: dict[str, Any] = {"claims": True, "plugins": True, "baseline": True}
    if not case.requirements:
        exclude["requirements"] = True
    if case.actuators is None:
        exclude["actuators"] = True
    if case.base_case is None:  # the overlay field (issue 19 item 4): older cases keep their hashes
        exclude["base_case"] = True
    if case.simulation.method not in AUTO_METHODS:  # the tolerances (issue 36) change only error-controlled runs
        exclude["simulation"] = {"rtol", "atol", "min_step"}
    plain = {i: {"motor", "value"} for i, f in enumerate(case.faults) if f.motor is None and f.value is None}
    if plain:
        exclude["faults"] = plain
    blob = case.model_dump_json(exclude=exclude) + "|" + version
    if case.plugins:  # the scheme files' contents, not where they are
        blob += "|" + plugin_digest(case)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------- building (pure)
def build_chain(case: Case) -> Chain:
    """The controllers' model of the chain ([robots])."""
    r = case.robots
    return Chain(**{k: r.values(k) for k in ("a", "b", "r", "m", "I", "d")})


def build_plant_chain(case: Case) -> Chain:
    """The true chain: [robots] times the [plant.mismatch] factors."""
    r, mm = case.robots, case.plant.mismatch
    vals = {}
    for k in ("a", "b", "r", "m", "I", "d"):
        base = np.asarray(r.values(k), dtype=float)
        f = getattr(mm, k)
        vals[k] = (base * (np.asarray(f, dtype=float) if isinstance(f, list) else float(f))).tolist()
    return Chain(**vals)


def initial_state(case: Case, ref) -> tuple[np.ndarray, np.ndarray]:
    """(q0, eta0) from the case's initial block and the reference at t = 0."""
    n = case.robots.n
    ini = case.initial
    r0 = ref.at(0.0)
    if ini.mode == "absolute":
        th = np.radians(ini.headings_deg) if ini.headings_deg is not None else r0.q_d[:1:-1]
        q0 = np.concatenate(([ini.x, ini.y], np.asarray(th, dtype=float)[::-1]))
        eta0 = np.zeros(2) if ini.eta is None else np.asarray(ini.eta, dtype=float)
    else:
        q0 = r0.q_d.copy()
        q0[0] += ini.x
        q0[1] += ini.y
        off = np.zeros(n) if ini.headings_deg is None else np.radians(ini.headings_deg)
        q0[2:] += (off + math.radians(ini.heading_offset_deg))[::-1]
        eta0 = r0.eta_d.copy() if ini.eta is None else np.asarray(ini.eta, dtype=float)
    return q0, eta0


def dropped_faults(case: Case, duration: float) -> str | None:
    """The warning for the events a ``--duration`` drops (those at or after it), each named, or None.

    Not a refusal (issue 34 item 10 allows either): shortening every case is how a batch is smoke-tested
    (``batch cases/ --duration 2``, the README's ``run ... --duration 30``), and the warning names
    what the shortened run no longer covers.  The same event in a case file is an error
    (``faults[i].time``): there nothing says the user chose to cut the run.
    """
    late = [(i, f) for i, f in enumerate(case.faults) if f.time >= duration]
    if not late:
        return None
    named = ", ".join(f"faults[{i}] (t = {f.time:g} s, wheel {f.wheel})" for i, f in late)
    return (
        f"--duration {duration:g}: drops {named}, at or after the end of the shortened run; "
        f"the run covers only the events before {duration:g} s"
    )


def with_duration(case: Case, duration: float) -> Case:
    """The same case simulated for ``duration`` s (events at or after it dropped: :func:`dropped_faults`
    words the warning)."""
    if not (math.isfinite(duration) and duration > 0):
        raise CaseError(f"{case.name}: --duration: must be a finite number of seconds > 0, got {duration}")
    s = case.simulation
    if s.sample_time is not None and duration < s.sample_time:
        raise CaseError(
            f"{case.name}: --duration {duration:g}: shorter than one control sample (simulation.sample_time = "
            f"{s.sample_time:g} s)"
        )
    try:  # validated again: the sampling's limits depend on the duration
        sim = Simulation.model_validate({**s.model_dump(), "duration": float(duration), "dt": min(s.dt, duration)})
    except ValidationError as exc:
        loc, why = _field_errors(exc.errors(), Case)[0]
        loc = loc if loc.startswith("simulation") else f"simulation.{loc}"
        raise CaseError(f"{case.name}: --duration {duration:g}: {loc}: {why}") from None
    faults = [f for f in case.faults if f.time < duration]
    # the campaign table's ranges refer to the full duration; a shortened run is not a campaign base
    short = case.model_copy(update={"simulation": sim, "faults": faults, "campaign": None})
    try:
        _check_budget(short)
    except _FieldError as exc:
        raise CaseError(f"{case.name}: --duration {duration:g}: {exc.loc}: {exc.msg}") from None
    return short


TEMPLATE = """# A case file for ftcreport (documented field by field in cases/README.md).
# Units: SI; angles in degrees where a name ends in _deg.
description = "Three robots on a circle; robot 2 loses its left motor at 20 s"

[robots]
n = 3               # number of robots (robot 1 is the leader)
d = 1.0             # link lengths [m]: a scalar, or a list of n - 1 values leader first
# a, b, r, m, I default to the thesis robots: 0.3 m, 0.75 m, 0.15 m, 30 kg, 15.625 kg m^2

[reference]         # path of the last robot: unicycle | circle | eight | line | sinusoid
kind = "circle"
radius = 5.0        # [m]
speed = 0.5         # [m/s]

[initial]           # offsets from the reference at t = 0 (mode = "absolute" for absolute values)
x = 0.3             # [m]
y = -0.2            # [m]
heading_offset_deg = 10.0

[[faults]]          # from time on, wheel has tau = sigma u + ubar
time = 20.0         # [s]
wheel = "2l"        # "1r", "1l", ..., "nr", "nl"
sigma = 0.0         # effectiveness in [0, 1]
ubar = 0.0          # friction [N m]

[kinematic]         # "two_link" (n = 2: k1, k2, k3) or "chained" (any n)
kind = "chained"
c_chain = 0.3
c_alpha2 = 2.0
c_xi1 = 2.0
kappa = 5.0

[schemes.nominal]   # no FTC
k_v = 5.0
[schemes.switching] # multiple models + switching
k_v = 5.0
gamma = 10.0
T_min = 0.01
[schemes.oracle]    # knows the true faults
k_v = 5.0

[simulation]
method = "auto"     # error-controlled: DOPRI5, or ROS2/ETD2 for a stiff loop (the page says which); "rk4": fixed
dt = 0.02           # [s] the longest step (metrics and figures read the steps); auto takes shorter ones where needed
rtol = 1e-6         # each step's local error at most atol + rtol |x| for every state
atol = 1e-8
duration = 60.0     # [s]
log_every = 5

[thresholds.switching]
position_error_final = { max = 1e-3 }
"""
