"""The case file's thresholds, claims, requirements, baseline and campaign tables."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictBool, model_validator

from ..errors import FtcError
from ..evaluation.requirements import SIGNALS as REQUIREMENT_SIGNALS
from ..model import wheel_index
from ..schemes.fields import _NUMBER, Limit, Std, Time, Torque, Unit, _f, _FieldError, _num, _Strict, did_you_mean

Status = Literal["ok", "singular", "diverged", "step_unstable"]  # run outcomes (ftcreport.sim)


def _ordered(lo: float | None, hi: float | None) -> None:
    """min above max: no value can pass (the gate would fail for ever, whatever the run)."""
    if lo is not None and hi is not None and lo > hi:
        raise ValueError(f"min = {lo:g} is above max = {hi:g}: no value can satisfy both")


class Bound(_Strict):
    """Bounds on one metric."""

    min: Limit | None = _f(None, "lower bound", "unit of the metric")
    max: Limit | None = _f(None, "upper bound", "unit of the metric")

    @model_validator(mode="after")
    def _order(self) -> Bound:
        _ordered(self.min, self.max)
        return self


_Count = Annotated[int, Field(ge=0, le=100), _NUMBER]


class Claim(_Strict):
    """A thesis claim about the case, checked by ``ftcreport check`` (ftcreport.evaluation.claims, issue 18)."""

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
        _ordered(self.min, self.max)
        if self.not_applicable is not None:
            if self.expect != "not applicable":
                raise ValueError("a claim marked not_applicable must expect 'not applicable'")
            return self
        if self.expect == "not applicable":
            raise ValueError("expect = 'not applicable' needs not_applicable = '<why>'")
        if self.scheme is None or self.metric is None:
            raise ValueError("give scheme and metric (or not_applicable = '<why>')")
        # scheme and relative_to are checked by the case (known, run), which knows the claim's index
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
    """A bound on a signal over windows defined by events, checked at every step (ftcreport.evaluation.requirements)."""

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
        return self  # min above max: problems() names it ("the band is empty")

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


#: [baseline] defaults: ftcreport.studies.baseline's module docstring and cases/README.md ("Baselines") say why
BASELINE_REL_TOL = 1e-3
BASELINE_ABS_TOL = 1e-9
#: the scalar metrics of metrics.json a [baseline.metrics.<name>] table may name (ftcreport.studies.baseline
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
    """Tolerances of ``ftcreport check --baseline`` for this case (``studies.baseline``; as Simulink Test's criteria).

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
        tables = (
            ("metrics", self.metrics, BASELINE_METRIC_NAMES, "not a scalar metric of metrics.json"),
            ("signals", self.signals, BASELINE_SIGNAL_FAMILIES, "not a baseline signal"),
        )
        for field, given, known, what in tables:
            for name in given:
                if name not in known:
                    raise _FieldError(
                        f"baseline.{field}.{name}",
                        what + did_you_mean(name, list(known)) + f" (known: {', '.join(known)})",
                    )
        return self


class CampaignSpec(_Strict):
    """Distributions a Monte Carlo campaign draws variants of the case from (ftcreport.studies.campaign)."""

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
