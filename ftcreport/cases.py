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

import hashlib
import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import CaseError, FtcError
from .limits import budget_problem, name_problem
from .model import Chain, FaultEvent, FaultSchedule, pattern_is_compensable, wheel_index, wheel_names
from .model.chain import THESIS_ROBOT

__all__ = ["SCHEME_NAMES", "Case", "case_hash", "load_case", "parse_case"]

SCHEME_NAMES = ("nominal", "switching", "adaptive", "adaptive_frozen", "active", "active_ukf", "oracle")

PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Robots(_Strict):
    """Per-robot parameters: a scalar applies to every robot, a list is leader first."""

    n: int = Field(ge=2, le=12)
    a: Finite | list[Finite] = THESIS_ROBOT["a"]
    b: Finite | list[Finite] = THESIS_ROBOT["b"]
    r: Finite | list[Finite] = THESIS_ROBOT["r"]
    m: Finite | list[Finite] = THESIS_ROBOT["m"]
    I: Finite | list[Finite] = THESIS_ROBOT["I"]
    d: Finite | list[Finite] = 1.0

    @model_validator(mode="after")
    def _lengths(self) -> Robots:
        sign = {"b": "> 0", "r": "> 0", "m": "> 0", "d": "> 0", "I": ">= 0"}
        for key in ("a", "b", "r", "m", "I", "d"):
            v = getattr(self, key)
            count = self.n - 1 if key == "d" else self.n
            what = "link lengths" if key == "d" else "values"
            if isinstance(v, list) and len(v) != count:
                raise _FieldError(f"robots.{key}", f"{len(v)} {what} given, a {self.n}-robot chain needs {count}")
            vals = v if isinstance(v, list) else [v]
            for i, x in enumerate(vals):
                bad = (sign.get(key) == "> 0" and x <= 0) or (sign.get(key) == ">= 0" and x < 0)
                if bad:
                    where = f"robots.{key}[{i}]" if isinstance(v, list) else f"robots.{key}"
                    raise _FieldError(where, f"must be {sign[key]}, got {x}")
        return self

    def values(self, key: str) -> list[float]:
        v = getattr(self, key)
        count = self.n - 1 if key == "d" else self.n
        return list(v) if isinstance(v, list) else [float(v)] * count


class Reference(_Strict):
    """Path of the last robot (a flat output of the chain)."""

    kind: Literal["unicycle", "circle", "eight", "line", "sinusoid"]
    v_d: PosFloat | None = None  # unicycle [m/s]
    omega_d: Finite | None = None  # unicycle [rad/s]
    x0: Finite = 0.0  # unicycle start [m]
    y0: Finite = 0.0
    theta0_deg: Finite | None = None  # unicycle start heading, eight start heading [deg]
    radius: PosFloat | None = None  # circle [m]
    speed: PosFloat | None = None  # circle, line, sinusoid [m/s]
    center: tuple[Finite, Finite] = (0.0, 0.0)  # circle [m]
    start_angle_deg: Finite = -90.0  # circle: polar angle of the start point [deg]
    ccw: bool = True
    heading_deg: Finite = 0.0  # line, sinusoid [deg]
    start: tuple[Finite, Finite] = (0.0, 0.0)  # line, sinusoid [m]
    amplitude: Finite | None = None  # sinusoid [m]
    frequency: PosFloat | None = None  # sinusoid [rad/s]
    phase_deg: Finite = 0.0  # sinusoid phase [deg]; -90 starts along the heading
    scale: PosFloat = 1.0  # eight

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

    mode: Literal["absolute", "offset"] = "offset"
    x: Finite = 0.0  # absolute: P_n [m]; offset: added to x_d(0)
    y: Finite = 0.0
    headings_deg: list[Finite] | None = None  # absolute: theta_1..theta_n [deg]; offset: added per robot
    heading_offset_deg: Finite = 0.0  # offset mode: added to every heading [deg]
    eta: tuple[Finite, Finite] | None = None  # [v_n, omega_1]; default: the reference's (offset) or 0 (absolute)


class Fault(_Strict):
    """From ``time`` on, ``wheel`` has effectiveness ``sigma`` and friction ``ubar``."""

    time: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    wheel: str
    sigma: Annotated[float, Field(ge=0, le=1)] = 0.0
    ubar: Finite = 0.0


class Kinematic(_Strict):
    """Kinematic controller shared by every scheme."""

    kind: Literal["two_link", "chained"]
    k1: PosFloat | None = None
    k2: PosFloat | None = None
    k3: PosFloat | None = None
    c_chain: Annotated[float, Field(ge=0)] | list[Annotated[float, Field(ge=0)]] = 0.3
    c_alpha2: PosFloat = 2.0
    c_xi1: PosFloat = 2.0
    kappa: PosFloat = 5.0
    mu: PosFloat = 1.0
    band_deg: Annotated[float, Field(gt=0, lt=90)] = 45.0


class NominalScheme(_Strict):
    k_v: PosFloat


class OracleScheme(_Strict):
    k_v: PosFloat


class SwitchingScheme(_Strict):
    k_v: PosFloat
    gamma: PosFloat = 10.0
    T_min: Annotated[float, Field(ge=0)] = 0.01
    c_inst: Annotated[float, Field(ge=0)] = 1.0
    c_int: Annotated[float, Field(ge=0)] = 0.0
    forgetting: PosFloat = 1.0
    hysteresis: Annotated[float, Field(ge=0)] = 1e-10
    patterns: Literal["all"] | list[list[str]] = "all"  # each entry: the wheels assumed failed


class AdaptiveScheme(_Strict):
    k_v: PosFloat
    gamma: PosFloat = 1.0  # adaptation gain of every weight
    Gamma_f: PosFloat = 1.0  # friction estimate gain (times the identity)
    patterns: Literal["all"] | list[list[str]] = "all"


class Diagnosis(_Strict):
    """Fault detection on the estimated gains and frictions (ftcreport.diagnosis)."""

    gain_band: PosFloat = 0.1  # |rho_hat - reference| beyond this is an excursion
    friction_band: PosFloat = 0.2  # [N m]
    dwell: PosFloat = 2.0  # [s] an estimate steady this long at a new value is declared
    settle_band: PosFloat | None = None  # "steady": within this of its window mean (default band / 4)


class ActiveScheme(_Strict):
    """Active FTC with the Farza et al. (2009) adaptive observer (thesis chapter 4)."""

    k_v: PosFloat
    Theta: PosFloat = 1.6
    k0: PosFloat = 1.0
    k1: PosFloat = 1.0
    p0: PosFloat = 0.1
    p_max: PosFloat = 1e3  # P guard: bound of P (the printed law has none; P grows like exp(Theta t))
    estimate: list[Literal["rho", "ubar"]] = ["rho", "ubar"]
    tau: PosFloat | None = None  # [s] filter 1/(tau s + 1) on the estimates used by the law
    diagnosis: Diagnosis = Diagnosis()


class ActiveUKFScheme(_Strict):
    """Active FTC with the augmented-state unscented Kalman filter (filterpy)."""

    k_v: PosFloat
    meas_std: PosFloat = 1e-3  # [m, rad] R of the filter
    eta_noise: Annotated[float, Field(ge=0)] = 1e-4  # [(m/s)^2/s]
    rho_noise: Annotated[float, Field(ge=0)] = 1e-2  # random-walk intensity of the gains [1/s]
    ubar_noise: Annotated[float, Field(ge=0)] = 1e-2  # [(N m)^2/s]
    rho_std0: PosFloat = 0.3
    ubar_std0: PosFloat = 0.5
    estimate: list[Literal["rho", "ubar"]] = ["rho", "ubar"]
    tau: PosFloat | None = None
    diagnosis: Diagnosis = Diagnosis()


class Schemes(_Strict):
    nominal: NominalScheme | None = None
    switching: SwitchingScheme | None = None
    adaptive: AdaptiveScheme | None = None
    adaptive_frozen: AdaptiveScheme | None = None  # the same law with weights and friction frozen
    active: ActiveScheme | None = None  # Farza observer + (4.14)
    active_ukf: ActiveUKFScheme | None = None  # UKF + (4.14)
    oracle: OracleScheme | None = None


class Simulation(_Strict):
    dt: PosFloat
    duration: PosFloat
    method: Literal["rk4", "ros2"] = "rk4"
    log_every: Annotated[int, Field(ge=1)] = 1
    singularity_margin_deg: Annotated[float, Field(ge=0, lt=90)] = 2.0


class Noise(_Strict):
    """Measurement noise (standard deviations), drawn once per step, seeded."""

    position: Annotated[float, Field(ge=0)] = 0.0  # on x, y [m]
    heading: Annotated[float, Field(ge=0)] = 0.0  # on every theta [rad]
    velocity: Annotated[float, Field(ge=0)] = 0.0  # on v_n [m/s] and omega_1 [rad/s]
    seed: int = 0


class Mismatch(_Strict):
    """Plant parameters = [robots] x these factors (the controllers keep [robots])."""

    a: Finite | list[Finite] = 1.0
    b: PosFloat | list[PosFloat] = 1.0
    r: PosFloat | list[PosFloat] = 1.0
    m: PosFloat | list[PosFloat] = 1.0
    I: PosFloat | list[PosFloat] = 1.0
    d: PosFloat | list[PosFloat] = 1.0


class Plant(_Strict):
    saturation: PosFloat | None = None  # |u| limit per wheel [N m]
    noise: Noise = Noise()
    mismatch: Mismatch = Mismatch()


class Bound(_Strict):
    min: Finite | None = None
    max: Finite | None = None


class CampaignSpec(_Strict):
    """Distributions a Monte Carlo campaign draws variants of the case from (ftcreport.campaign)."""

    faults: tuple[Annotated[int, Field(ge=0)], Annotated[int, Field(ge=0)]] = (1, 2)  # events per sample
    fault_time: tuple[Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)]]  # [s] uniform
    wheels: Literal["any"] | list[str] = "any"  # wheels a fault may hit (distinct per sample)
    sigma: tuple[Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(ge=0, le=1)]] = (0.0, 0.0)
    friction_probability: Annotated[float, Field(ge=0, le=1)] = 0.0  # a fault also adds a friction
    ubar: tuple[Finite, Finite] = (0.0, 0.0)  # [N m] uniform
    offset_position: Annotated[float, Field(ge=0)] = 0.0  # [m] uniform +/- on the initial x, y
    offset_heading_deg: Annotated[float, Field(ge=0)] = 0.0  # [deg] uniform +/- on every initial heading
    mismatch: Annotated[float, Field(ge=0, lt=1)] = 0.0  # relative +/- on the plant's m and I
    noise_position: tuple[Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)]] = (0.0, 0.0)  # [m]
    noise_heading: tuple[Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)]] = (0.0, 0.0)  # [rad]
    keep_base_faults: bool = False
    success: dict[str, Bound] = {"position_error_final": Bound(max=0.05)}  # a sample succeeds if all hold

    @model_validator(mode="after")
    def _ranges(self) -> CampaignSpec:
        for key in ("faults", "fault_time", "sigma", "ubar", "noise_position", "noise_heading"):
            lo, hi = getattr(self, key)
            if lo > hi:
                raise _FieldError(f"campaign.{key}", f"empty range [{lo}, {hi}]")
        return self


class Case(_Strict):
    """A validated case (see cases/README.md for every field and unit)."""

    name: str | None = None
    description: str = ""
    robots: Robots
    reference: Reference
    initial: Initial = Initial()
    faults: list[Fault] = []
    kinematic: Kinematic
    schemes: Schemes
    simulation: Simulation
    plant: Plant = Plant()
    recovery_band: PosFloat = 0.01  # [m] band of the recovery time
    # run outcomes that are not failures for this case (a case built to lose tracking says so)
    expected_status: list[Literal["ok", "singular", "diverged"]] = ["ok"]
    thresholds: dict[str, dict[str, Bound]] = {}
    campaign: CampaignSpec | None = None  # distributions for `ftcreport campaign` (ignored by batch)

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
        for sname in ("switching", "adaptive", "adaptive_frozen"):
            sw = getattr(self.schemes, sname)
            if sw is None or sw.patterns == "all":
                continue
            for i, failed in enumerate(sw.patterns):
                pat = [1] * (2 * n)
                for w in failed:
                    try:
                        pat[wheel_index(w, n)] = 0
                    except FtcError as exc:
                        raise _FieldError(f"schemes.{sname}.patterns[{i}]", str(exc)) from None
                if not pattern_is_compensable(pat):
                    raise _FieldError(
                        f"schemes.{sname}.patterns[{i}]",
                        f"{failed} is uncompensable: rank(Bbar sigma) < 2 (a leader wheel and two wheels must work)",
                    )
        for key in ("a", "b", "r", "m", "I", "d"):
            v = getattr(self.plant.mismatch, key)
            count = n - 1 if key == "d" else n
            if isinstance(v, list) and len(v) != count:
                raise _FieldError(f"plant.mismatch.{key}", f"{len(v)} factors given, {count} needed")
        if self.initial.headings_deg is not None and len(self.initial.headings_deg) != n:
            raise _FieldError("initial.headings_deg", f"{len(self.initial.headings_deg)} values for {n} robots")
        if self.campaign is not None:
            if self.campaign.fault_time[1] >= self.simulation.duration:
                raise _FieldError(
                    "campaign.fault_time",
                    f"upper bound must be before the end of the run ({self.simulation.duration} s)",
                )
            if self.campaign.wheels != "any":
                for i, w in enumerate(self.campaign.wheels):
                    try:
                        wheel_index(w, n)
                    except FtcError as exc:
                        raise _FieldError(f"campaign.wheels[{i}]", str(exc)) from None
        if not any(getattr(self.schemes, s) is not None for s in SCHEME_NAMES):
            raise _FieldError("schemes", "no scheme to run (give at least one of " + ", ".join(SCHEME_NAMES) + ")")
        for scheme, metrics in self.thresholds.items():
            if scheme not in SCHEME_NAMES:
                raise _FieldError(f"thresholds.{scheme}", f"unknown scheme (known: {', '.join(SCHEME_NAMES)})")
            for metric, bound in metrics.items():
                if bound.min is None and bound.max is None:
                    raise _FieldError(f"thresholds.{scheme}.{metric}", "give min, max or both")
        return self

    # ------------------------------------------------------------------ derived
    def fault_schedule(self) -> FaultSchedule:
        return FaultSchedule(
            self.robots.n, [FaultEvent(f.time, f.wheel.strip().lower(), f.sigma, f.ubar) for f in self.faults]
        )

    def warnings(self) -> list[str]:
        """Uncompensable phases, naming the event that makes them so."""
        out = []
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


def _check_name(v: str | None) -> str | None:
    """A case name is a directory name and a page title: the safe set of ftcreport.limits."""
    if v is not None and (why := name_problem(v)) is not None:
        raise ValueError(why)
    return v


def _check_budget(case: Case) -> None:
    """Refuse, before it starts, a run over the step limit or memory budget (ftcreport.limits)."""
    s = case.simulation
    for scheme in SCHEME_NAMES:
        cfg = getattr(case.schemes, scheme)
        if cfg is None:
            continue
        pats = getattr(cfg, "patterns", "all")
        models = None if pats == "all" else len(pats)
        problem = budget_problem(case.robots.n, s.duration, s.dt, s.log_every, scheme, models)
        if problem is not None:
            raise _FieldError(*problem)


class _FieldError(ValueError):
    """A validation error with an explicit field path (raised inside validators)."""

    def __init__(self, loc: str, msg: str) -> None:
        super().__init__(msg)
        self.loc = loc
        self.msg = msg


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def parse_case(data: dict, source: str = "<case>") -> Case:
    """Validate a case given as a dict (parsed TOML); raise CaseError naming the field."""
    try:
        case = Case.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, _FieldError):
            raise CaseError(f"{source}: {ctx_err.loc}: {ctx_err.msg}") from None
        loc = _format_loc(tuple(p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))))
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field"
        more = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
        raise CaseError(f"{source}: {loc or '<root>'}: {msg}{more}") from None
    if case.name is None:
        stem = Path(source).stem
        if (why := name_problem(stem)) is not None:
            raise CaseError(f'{source}: name: taken from the file name: {why}; set name = "..." in the file')
        case = case.model_copy(update={"name": stem})
    return case


def load_case(path: str | Path) -> Case:
    """Read and validate a TOML case file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CaseError(f"{path}: cannot read ({exc.strerror or exc})") from None
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
    return parse_case(data, str(path))


def case_hash(case: Case, version: str) -> str:
    """Content hash of a validated case and the package version (result cache key)."""
    blob = case.model_dump_json() + "|" + version
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


def switching_patterns(case: Case, chain: Chain, scheme: str = "switching") -> list[tuple[int, ...]] | None:
    """The 0/1 patterns a scheme's models use (None: every compensable pattern)."""
    sw = getattr(case.schemes, scheme)
    if sw is None or sw.patterns == "all":
        return None
    out = []
    for failed in sw.patterns:
        pat = [1] * chain.n_wheels
        for w in failed:
            pat[wheel_index(w, chain.n)] = 0
        out.append(tuple(pat))
    return out


def with_duration(case: Case, duration: float) -> Case:
    """The same case simulated for ``duration`` s (events at or after it dropped)."""
    if not (math.isfinite(duration) and duration > 0):
        raise CaseError(f"{case.name}: --duration: must be a finite number of seconds > 0, got {duration}")
    sim = case.simulation.model_copy(update={"duration": float(duration), "dt": min(case.simulation.dt, duration)})
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
dt = 0.02           # [s]
duration = 60.0     # [s]
method = "rk4"      # or "ros2" for stiff velocity loops
log_every = 5

[thresholds.switching]
position_error_final = { max = 1e-3 }
"""
