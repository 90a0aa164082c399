"""The whole case (pydantic model) and its checks across tables."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import get_args

from pydantic import field_validator, model_validator

from ..errors import FtcError, PluginError
from ..infra.limits import name_problem
from ..model import FaultEvent, FaultSchedule, wheel_index, wheel_names
from ..model.actuators import DriveParams, MotorParams
from ..model.faults import motor_row
from ..runs import AUTO_METHODS
from ..schemes.budget import STEP_DT, STEP_SENSOR, budget_problem
from ..schemes.fields import _f, _FieldError, _num, _Strict, did_you_mean
from .scheme_tables import (
    SCHEME_NAMES,
    Kinematic,
    Schemes,
    _scheme_file,
    configured_schemes,
    known_schemes,
)
from .tables import Actuators, Fault, Initial, Noise, Plant, Reference, Robots, Simulation
from .thresholds import BaselineSpec, Bound, CampaignSpec, Claim, Requirement, Status

#: [s] two fault events at distinct times closer than this are refused: the requirements' windows take a sample
#: this close to an edge as on it (evaluation.requirements.EDGE_SLACK), so a phase this short is no phase
EVENT_RESOLUTION = 1e-9


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
    claims: list[Claim] = _f(
        [], "thesis claims checked against the runs ([[claims]], ftcreport.evaluation.claims)", "-"
    )
    requirements: list[Requirement] = _f(
        [], "bounds on a signal over event-defined windows ([[requirements]], ftcreport.evaluation.requirements)", "-"
    )
    baseline: BaselineSpec | None = _f(
        None,
        "tolerances of check --baseline ([baseline], ftcreport.studies.baseline); absent: the documented defaults",
        "-",
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
        for i in range(1, len(self.faults)):
            t0, t = self.faults[i - 1].time, self.faults[i].time
            if 0.0 < t - t0 < EVENT_RESOLUTION:
                raise _FieldError(
                    f"faults[{i}].time",
                    f"{t!r} s is {t - t0:.2g} s after event {i - 1} (t = {t0!r} s): distinct event times must be at "
                    f"least {EVENT_RESOLUTION:g} s apart (give both the same time, or separate them)",
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
        _check_noise_clock(self.plant.noise, self.simulation)
        for sname in configured_schemes(self):  # each scheme's own checks of its table against the case
            scheme_validate(sname, getattr(self.schemes, sname), self)
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
            _check_campaign_draws(self.campaign, n, kept=self.faults)
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
                if s is not None and (why := _scheme_problem(s, run, known)) is not None:
                    raise _FieldError(f"claims[{i}].{key}", why)
            if c.not_applicable is None and c.metric is not None:
                kinds = ("sequence",) if c.sequence is not None else ("number", "table", "list")
                for s in (c.scheme, c.relative_to):
                    if s is not None and (why := metric_problem(s, c.metric, kinds)) is not None:
                        raise _FieldError(f"claims[{i}].metric", why)
        _check_requirements(self, run, known)
        for scheme, metrics in self.thresholds.items():
            if (why := _scheme_problem(scheme, run, known)) is not None:
                raise _FieldError(f"thresholds.{scheme}", why)
            _check_bounds(f"thresholds.{scheme}", scheme, metrics)
        if self.campaign is not None:  # a sample succeeds on every bound, for each scheme the campaign runs
            for scheme in configured_schemes(self):
                _check_bounds("campaign.success", scheme, self.campaign.success)
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


def _check_noise_clock(noise: Noise, sim: Simulation) -> None:
    """The sensor's sample period (``[plant.noise] sample_time``) against the step: a fixed step must divide it
    (each step holds one draw: a tick inside a step would fall between two steps' draws); an error-controlled
    step lands on its ticks."""
    T = noise.sample_time
    if T is None:
        return
    if sim.duration < T:
        raise _FieldError("plant.noise.sample_time", f"{T:g} s is longer than the run ({sim.duration:g} s)")
    if sim.method not in AUTO_METHODS:
        ratio = T / sim.dt
        if not (ratio >= 1 - 1e-9 and abs(ratio - round(ratio)) <= 1e-9 * ratio):
            raise _FieldError(
                "plant.noise.sample_time",
                f"{T:g} s is not a whole number of steps dt = {sim.dt:g} s: a fixed step holds one draw "
                "(make it a multiple of dt, or use an error-controlled method, which lands on every draw)",
            )


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
        if r.scheme != "*" and (why := _scheme_problem(r.scheme, run, known, ', or "*"')) is not None:
            raise _FieldError(f"requirements[{i}].scheme", why)
        for key, why in r.problems(case.robots.n):
            raise _FieldError(f"requirements[{i}].{key}", why)


def _check_bounds(field: str, scheme: str, bounds: dict[str, Bound]) -> None:
    """Bounds on a run's metrics (``[thresholds.<scheme>]``, ``[campaign] success``): each names a number
    ``scheme``'s run writes (:func:`metric_problem`) and gives min, max or both; else a FieldError at
    ``field.<metric>``."""
    for metric, bound in bounds.items():
        if (why := metric_problem(scheme, metric)) is not None:
            raise _FieldError(f"{field}.{metric}", why)
        if bound.min is None and bound.max is None:
            raise _FieldError(f"{field}.{metric}", "give min, max or both")


def _scheme_problem(name: str, run: list[str] | None, known: list[str], more: str = "") -> str | None:
    """Why a claim, threshold or requirement may not name the scheme ``name``, or None: it is no scheme
    (with a did-you-mean), or the case's ``[schemes] run`` does not list it (its bound could never be
    checked: ``run`` would pass and ``check`` fail on "scheme not run").  ``more``: other accepted names."""
    if name not in known:
        return f"unknown scheme '{name}'{did_you_mean(name, known)} (known: {', '.join(known)}{more})"
    if run is not None and name not in run:
        return f"scheme '{name}' is not in [schemes] run ({', '.join(run)}): add it there, or remove this entry"
    return None


def metric_problem(scheme: str, name: str, kinds: tuple[str, ...] = ("number",)) -> str | None:
    """Why the metric ``name`` cannot be compared on a run of ``scheme`` as one of ``kinds``, or None.

    The names are those a run writes (:data:`ftcreport.evaluation.metrics.METRICS`, the one list); ``name`` may be
    ``metric.key``, an entry of a table metric.  An unknown name gets the closest of the scheme's own.
    """
    from ..evaluation.metrics import METRICS, metrics_of

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
    from ..evaluation.metrics import METRICS

    return [k for k in names if METRICS[k].kind == "number"]


def _check_campaign_draws(spec: CampaignSpec, n: int, kept: list[Fault]) -> None:
    """The faults a campaign draws exist: its wheels are wheels of the chain, each listed once, at least
    as many as the faults it draws per sample (each on a distinct wheel), and it draws a fault at all, one
    that changes a wheel (a sigma below 1 or a friction), unless the case keeps faults of its own
    (``kept``, the case's faults).  A drawn fault can avoid a kept one on its wheel at its time
    (:func:`ftcreport.studies.campaign.draw_variant` draws the time again), unless fault_time is one instant."""
    keeps = bool(kept)
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
    if spec.keep_base_faults and hi > 0:
        _check_kept_coincidence(spec, n, kept, wheels)
    # a drawn fault is effective when its sigma is below 1 (drawn from [sigma lo, hi]: below 1 unless lo = 1)
    # or it adds a friction (drawn with friction_probability, ubar from [ubar lo, hi]: nonzero unless both 0)
    friction = spec.friction_probability > 0.0 and spec.ubar != (0.0, 0.0)
    if spec.sigma[0] >= 1.0 and not friction and not (spec.keep_base_faults and keeps):
        why = "friction_probability = 0" if spec.friction_probability == 0.0 else "ubar = [0, 0]"
        raise _FieldError(
            "campaign.sigma",
            f"[{spec.sigma[0]:g}, {spec.sigma[1]:g}] keeps every motor at full effectiveness and no friction is "
            f"drawn ({why}): every draw leaves every wheel healthy, so every sample would be fault-free and "
            "'succeed'; give sigma a lower bound below 1, or a friction_probability above 0 with a nonzero ubar",
        )


def _check_kept_coincidence(spec: CampaignSpec, n: int, kept: list[Fault], wheels: list[str]) -> None:
    """fault_time one instant (to the ms the draw rounds to) where a kept fault sits on a wheel that can be
    drawn: such a draw is a second event on that wheel at that time, and its sample cannot run."""
    import numpy as np

    t_lo, t_hi = (float(np.round(t, 3)) for t in spec.fault_time)  # the draw's rounding
    if t_lo != t_hi:
        return
    drawable = {wheel_index(w, n) for w in wheels}
    for i, f in enumerate(kept):
        if f.time == t_lo and wheel_index(f.wheel, n) in drawable:
            raise _FieldError(
                "campaign.fault_time",
                f"[{spec.fault_time[0]:g}, {spec.fault_time[1]:g}] draws every fault at t = {t_lo:g} s, where "
                f"faults[{i}] on wheel {f.wheel} is kept (keep_base_faults): a fault drawn on {f.wheel} would be a "
                f"second event on that wheel at that time and its sample could not run; widen fault_time, "
                f"or leave {f.wheel} out of campaign.wheels",
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

    The engine's test (fast.checks._check_state: |cos(theta_i - theta_(i+1))| <= sin(margin)) on the
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


def scheme_validate(name: str, table, case: Case) -> None:
    """A scheme's own check of its table against the case (``Scheme.validate``): a ``fields.FieldError`` it
    raises is the table's error; anything else a plug-in's validate raises is named by its file and line.  A
    plug-in's hook gets copies: what it changes in them (``object.__setattr__`` past the frozen models) is
    not the case that runs."""
    from ..schemes import every
    from ..schemes.hooks import hook
    from ..schemes.registry import is_built_in

    sc = every().get(name)
    if sc is None or sc.validate is None:
        return
    if not is_built_in(sc):
        table, case = copy.deepcopy(table), case.model_copy(deep=True)
    try:
        hook(sc, "validate", sc.validate, table, case, passes=(_FieldError,))
    except PluginError as exc:
        raise _FieldError(f"schemes.{name}", str(exc)) from None


def _check_name(v: str | None) -> str | None:
    """A case name is a directory name and a page title: the safe set of ftcreport.infra.limits."""
    if v is not None and (why := name_problem(v)) is not None:
        raise ValueError(why)
    return v


def _check_budget(case: Case, schemes: list[str] | None = None) -> None:
    """Refuse, before it starts, a run over the step limit or memory budget (ftcreport.infra.limits): of each of
    ``schemes`` (default: every scheme the case configures)."""
    s = case.simulation
    for scheme in configured_schemes(case) if schemes is None else schemes:
        cfg = getattr(case.schemes, scheme)
        pats = getattr(cfg, "patterns", "all")
        models = None if pats == "all" else len(pats)
        # an error-controlled run lands on every tick of the sensor's clock where it reads one: a noise draw, or a
        # discrete-time filter's update (the UKF's, fast.engine.disc_ticks); its steps are then at most that long
        T, why_ticks = case.plant.noise.sample_time, _tick_readers(case, scheme)
        ticks = T is not None and s.dt > T and s.method in AUTO_METHODS and bool(why_ticks)
        dt, step = (T, STEP_SENSOR) if ticks else (s.dt, STEP_DT)
        try:
            problem = budget_problem(case.robots.n, s.duration, dt, s.log_every, scheme, models, step)
        except PluginError as exc:  # a plug-in's own budget hook (Scheme.budget), named by its line
            raise _FieldError(f"schemes.{scheme}", str(exc)) from None
        if problem is not None:
            field, why = problem
            if field == STEP_SENSOR[0]:  # the sensor's clock binds, not dt: say what lands on each tick
                why = f"{why} ({s.method} lands on each tick: {why_ticks})"
            raise _FieldError(field, why)


def _tick_readers(case: Case, scheme: str) -> str:
    """What makes a run of ``scheme`` land on the sensor's ticks ("" when nothing does): the noise's draws, and
    a discrete-time filter's updates (a scheme whose discrete update starts at t0: the UKF's)."""
    from ..schemes.registry import discrete_time

    readers = ["the noise's draws"] if case.plant.noise.noisy else []
    if discrete_time(scheme):
        readers.append(f"the {scheme} filter's updates")
    return " and ".join(readers)
