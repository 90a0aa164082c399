r"""Who wins, by how much, and why: the comparison of schemes on one case and across cases (pure).

Input is a tidy table of metrics, one :class:`Row` per (case, scheme, metric), built from the
``metrics.json`` dicts of the runs by :func:`tidy` (names of :mod:`ftcreport.evaluation.metrics` and
:mod:`ftcreport.evaluation.diagnosis`).  No I/O, no plotting: the report renders what this module returns.

Definitions (every headline metric is "lower is better"):

* **Headline metrics** (:data:`HEADLINE`): the largest position error after the first fault
  (the largest ``phases[k].position_error_max`` over the phases that start with a fault),
  ``position_error_final``, ``recovery_time_max`` (``None`` in metrics.json, "never settles", ranks
  last), ``torque_peak_after_fault``, ``energy``, and for the active schemes ``detection_delay_max``
  (a missed change ranks last) and ``false_alarms``.
* **Not applicable.**  A run without a fault has no response to a fault: the metrics of
  :data:`FAULT_RESPONSE` are :data:`NOT_APPLICABLE` for it (the reason as its note), not its whole
  run's values.  The whole run's peak error is the initial offset, equal for every scheme, and
  metrics.json's ``recovery_time_max`` of 0 s is a maximum over no fault phase: ranked, they made
  every scheme a winner of a contest that did not take place.  A metric not applicable to every run
  of a case has no winner, no tie and no contest there (:attr:`MetricVerdict.not_applicable`).
* **Ties.**  Two values tie when ``|a - b| <= max(abs_tol, rel_tol * min(|a|, |b|))`` with the
  metric's tolerances (:class:`MetricSpec`; 5 % relative, and an absolute floor such as 0.1 mm
  for position errors, below which differences are numerical rather than physical).  The relative
  part is taken of the better (smaller) value: 3.02 s ties with 2.89 s (0.13 s, under 5 % of
  2.89 s) and 3.04 s does not (0.15 s, over 0.1 s and over 5 % of 2.89 s), though 0.15 s is under
  5 % of 3.04 s.
* **Ranking.**  Competition ranking: a scheme's rank is one plus the number of schemes whose
  value is smaller beyond the tolerance; so rank 1 is the group within the tolerance of the best
  value, each scheme compared with that value, never through another tied scheme.  A run that
  did not complete (``status`` other than ``ok``) is not ranked on that case (its metrics cover
  only the simulated part); it is listed as failed.  A scheme without the metric is listed as missing.
* **Winner.**  The oracle knows the true faults: it is the bound, not a contestant.  Every other
  ranked scheme (nominal included) competes; the winners are those tied with the best of them
  (each with the best value itself).  A sentence or a cell that names tied winners gives the range
  of their own values (``fmt_best``: "287-298 N m"), never the best value for all of them.
* **Regret against the oracle** = winner / oracle and **benefit against nominal** = nominal /
  winner, both ratios (regret 1.12: 12 % worse than the oracle; benefit 4: a quarter of
  nominal's value).  Values tied within the tolerance give the ratio 1 (flagged ``tie``).  A
  ratio needs a denominator above the metric's **resolution floor** (:attr:`MetricSpec.floor`,
  the same absolute floor as ties: 0.1 mm, 0.1 s, 0.1 N m, 0.1 J, one count): below it the
  denominator is numerical residue (an oracle's final error of 1e-9 m made "regret 5.8e6") and
  the verdict gives the absolute difference instead (``regret_diff``, ``benefit_diff``).  A value
  that is "never" (inf) has no ratio either.  So no ratio is ever inf or astronomically large.
* **False alarms are won by a detector that missed no change.**  The fewest false alarms from a
  detector that misses faults is bought with insensitivity (active_ukf missing 10 of 10 changes
  with 0 false alarms): such a run is ranked on its count, with the reason as its note, but only
  the runs that missed no change (and whose detection was computed) are eligible to win.  "Missed
  none" rather than "detected at least one": a detector that misses some changes is still less
  sensitive than one that misses none, and a case without a fault (nothing to miss) leaves every
  detector eligible.  With no eligible run the metric has no winner.
* **Nominal among the best** (the verdict's "Surprise" sentence, and the analysis's agreeing with
  it): nominal is among the winners on each metric of tracking after the faults
  (:data:`AFTER_FAULTS`: the largest error after the faults, the final error, the worst recovery
  time).  A metric nobody wins (every contestant never settles) or that no run has does not count
  against it; a tie on the peak error alone, with a final error over 60 times the winner's or no
  recovery after a later fault, is no surprise and is not stated as one.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from ..schemes import built_in
from .metrics import fault_phases
from .verdict_analysis import analysis_sentences, every_loop_unstable

__all__ = [
    "ACTIVE",
    "CONTESTANTS",
    "FAULT_RESPONSE",
    "HEADLINE",
    "NOT_APPLICABLE",
    "NOT_COMPARED",
    "NO_DETECTOR",
    "CaseVerdict",
    "MetricSpec",
    "MetricVerdict",
    "Row",
    "Scoreboard",
    "compare_case",
    "compare_metric",
    "contestant",
    "difference",
    "fault_free",
    "fmt_best",
    "fmt_relative",
    "ratio",
    "scoreboard",
    "tidy",
    "tied",
]

# from the registry of schemes (each built-in scheme's file gives its family and its name in sentences)
ACTIVE = tuple(name for name, sc in built_in().items() if sc.family == "active")
# display names of the schemes in sentences
LABEL = {name: sc.display for name, sc in built_in().items()}
CONTESTANTS = tuple(name for name, sc in built_in().items() if sc.contestant)  # the three FTC families
BOUND = next(name for name, sc in built_in().items() if sc.family == "bound")  # the oracle: told the true faults
BASELINE = next(name for name, sc in built_in().items() if sc.family == "baseline")  # nominal: no FTC


def contestant(scheme: str) -> bool:
    """An FTC scheme in the race: the built-in families, and every registered (plug-in) scheme."""
    return scheme in CONTESTANTS or scheme not in LABEL


@dataclass(frozen=True)
class MetricSpec:
    """A headline metric: key, label, unit and tie tolerances (see the module docstring)."""

    key: str
    label: str
    unit: str
    rel_tol: float
    abs_tol: float
    only: tuple[str, ...] | None = None  # schemes the metric exists for (None: every scheme)
    note: str = ""  # what the metric covers (start-up included or not), for the pages
    only_why: str = ""  # why the metric does not apply to a built-in scheme outside ``only`` ("no detector")

    @property
    def floor(self) -> float:
        """The resolution floor of a ratio's denominator: the tie floor ``abs_tol`` (a count: 0, so
        any non-zero count).  Below it differences are numerical rather than physical (module docstring)."""
        return self.abs_tol


#: why the detection metrics do not apply to a built-in scheme outside the active family (the scoreboard's "n/a")
NO_DETECTOR = "no detector"
#: why they do not apply to a plug-in scheme: only the built-in active schemes' detections are compared
NOT_COMPARED = "not compared for a plug-in"

HEADLINE: tuple[MetricSpec, ...] = (
    MetricSpec("after_fault_error_max", "max error after faults", "m", 0.05, 1e-4, note="from the first fault on"),
    MetricSpec("position_error_final", "final error", "m", 0.05, 1e-4, note="at the end of the run"),
    MetricSpec("recovery_time_max", "worst recovery time", "s", 0.05, 0.1, note="phases that start with a fault"),
    MetricSpec(
        "torque_peak_after_fault", "peak torque after the first fault", "N m", 0.05, 0.1, note="from the first fault on"
    ),
    MetricSpec("energy", "energy", "J", 0.05, 0.1, note="whole run, start-up included"),
    MetricSpec(
        "detection_delay_max", "worst detection delay", "s", 0.05, 0.1, ACTIVE, note="every fault", only_why=NO_DETECTOR
    ),
    MetricSpec("false_alarms", "false alarms", "", 0.0, 0.0, ACTIVE, note="whole run", only_why=NO_DETECTOR),
)
SPECS = {s.key: s for s in HEADLINE}
#: the headline metrics of the response to a fault: not applicable to a run without one (module docstring)
FAULT_RESPONSE = ("after_fault_error_max", "recovery_time_max", "torque_peak_after_fault", "detection_delay_max")
#: the note of a metric of :data:`FAULT_RESPONSE` for a run without a fault
NOT_APPLICABLE = "not applicable: no fault in the run"
#: the headline metrics of tracking after the faults: nominal must be among their winners to be "among the best"
AFTER_FAULTS = ("after_fault_error_max", "position_error_final", "recovery_time_max")


@dataclass(frozen=True)
class Row:
    """One value of the tidy table.

    ``value`` is a float (``inf`` = the worst outcome: never settles, a missed detection) or
    ``None`` (the metric is missing for this run); ``note`` says why in words.
    """

    case: str
    scheme: str
    status: str
    metric: str
    value: float | None
    note: str = ""
    t_end: float | None = None


def _num(x) -> float | None:
    if isinstance(x, bool) or x is None:
        return None
    if isinstance(x, int | float):
        return float(x)
    return None


def tidy(case: str, metrics_by_scheme: Mapping[str, Mapping]) -> list[Row]:
    """The headline rows of one case from its runs' metrics.json dicts."""
    rows = []
    for scheme, m in metrics_by_scheme.items():
        status = str(m.get("status", "error"))
        t_end = _num(m.get("t_end"))
        for spec in HEADLINE:
            if spec.only is not None and scheme not in spec.only:
                continue
            value, note = _extract(spec.key, m)
            rows.append(Row(case, scheme, status, spec.key, value, note, t_end))
    return rows


def fault_free(m: Mapping) -> bool:
    """Whether a run's phases hold no fault (a run stored without phases cannot tell: False)."""
    phases = m.get("phases")
    return bool(phases) and not fault_phases(phases)


def _extract(key: str, m: Mapping) -> tuple[float | None, str]:
    if key in FAULT_RESPONSE and fault_free(m):
        return None, NOT_APPLICABLE
    if key == "after_fault_error_max":
        phases = m.get("phases")
        if not phases:
            return _num(m.get("position_error_max")), "" if "position_error_max" in m else "not computed"
        faulty = fault_phases(phases)
        vals = [_num(p.get("position_error_max")) for p in faulty]
        vals = [v for v in vals if v is not None]
        return (max(vals), "") if vals else (None, "no sample after the faults")
    if key == "torque_peak_after_fault":
        if key not in m:
            return None, "not computed (stored before this metric existed: re-run with --force)"
        v = _num(m[key])
        return (v, "") if v is not None else (None, "no sample after the first fault")
    if key == "recovery_time_max":
        if key not in m:
            return None, "not computed"
        v = _num(m[key])
        return (math.inf, "never settles") if v is None else (v, "")
    if key == "detection_delay_max":
        events = m.get("detection_events")
        if events is None:
            return None, "not computed"
        if not events:
            return None, NOT_APPLICABLE
        if m.get("missed_detections"):
            return math.inf, f"misses {m['missed_detections']} of {len(events)} changes"
        v = _num(m.get(key))
        return (v, "") if v is not None else (None, "not computed")
    if key not in m:
        return None, "not computed"
    return _num(m[key]), ""


# ---------------------------------------------------------------------- one metric, one case
def tied(a: float, b: float, spec: MetricSpec) -> bool:
    """Whether two values of a metric are equal within its tolerance (inf ties only with inf).

    The relative tolerance is taken of the better (smaller) value, so a value ties with the best
    when it is within 5 % of the best itself (module docstring, **Ties**).
    """
    if math.isinf(a) or math.isinf(b):
        return a == b
    # |a - b| <= max(abs_tol, rel_tol min(|a|, |b|))
    return abs(a - b) <= max(spec.abs_tol, spec.rel_tol * min(abs(a), abs(b)))


def ratio(num: float | None, den: float | None, spec: MetricSpec) -> tuple[float | None, bool]:
    """(num / den, tie): 1 when tied within tolerance; None when either is missing or "never" (inf),
    or when the denominator is not above the metric's resolution floor (then :func:`difference`)."""
    if num is None or den is None:
        return None, False
    if tied(num, den, spec):
        return 1.0, True
    if math.isinf(num) or math.isinf(den) or abs(den) <= spec.floor:
        return None, False
    return num / den, False


def difference(num: float | None, den: float | None) -> float | None:
    """num - den, where a ratio has no meaning (None when either is missing; inf when num is "never")."""
    if num is None or den is None or math.isinf(den):
        return None
    return num - den


@dataclass
class Ranked:
    scheme: str
    value: float
    rank: int
    note: str = ""


@dataclass
class MetricVerdict:
    """The comparison of one metric on one case."""

    spec: MetricSpec
    ranking: list[Ranked]  # completed runs, best first
    winners: list[str]  # non-oracle schemes tied with the best non-oracle value
    best: float | None
    oracle: float | None
    nominal: float | None
    regret: float | None  # best / oracle (None: no ratio, see regret_diff)
    regret_tie: bool
    benefit: float | None  # nominal / best (None: no ratio, see benefit_diff)
    benefit_tie: bool
    failed: list[tuple[str, str]] = field(default_factory=list)  # (scheme, status)
    missing: list[tuple[str, str]] = field(default_factory=list)  # (scheme, why)
    regret_diff: float | None = None  # best - oracle, when the oracle is below the floor
    benefit_diff: float | None = None  # nominal - best, when the best is below the floor
    not_applicable: str = ""  # why no run has the metric, when it applies to none (NOT_APPLICABLE)

    def value(self, scheme: str) -> float | None:
        return next((r.value for r in self.ranking if r.scheme == scheme), None)

    def regret_of(self, scheme: str) -> float | None:
        """scheme / oracle (None when either is missing)."""
        return ratio(self.value(scheme), self.oracle, self.spec)[0]


def compare_metric(rows: Sequence[Row], spec: MetricSpec, ineligible: Mapping[str, str] | None = None) -> MetricVerdict:
    """Rank the schemes of one case on one metric (rows of that case and metric).

    ``ineligible``: ``{scheme: why}`` of schemes ranked on their value, ``why`` as their note, that
    cannot win (a detector that missed a change on the false alarms: module docstring).
    """
    ineligible = dict(ineligible or {})
    done, failed, missing = [], [], []
    for r in rows:
        if r.status != "ok":
            failed.append((r.scheme, r.status))
        elif r.value is None:
            missing.append((r.scheme, r.note or "not computed"))
        else:
            done.append(r)
    done.sort(key=lambda r: r.value)
    ranking = [
        Ranked(
            r.scheme,
            r.value,
            1 + sum(o.value < r.value and not tied(o.value, r.value, spec) for o in done),
            ineligible.get(r.scheme, r.note),
        )
        for r in done
    ]
    field_ = [r for r in ranking if r.scheme != BOUND and r.scheme not in ineligible]
    best = field_[0].value if field_ else None
    # nobody wins when the best is "never" (every contestant never settles / misses a change)
    winners = [r.scheme for r in field_ if tied(r.value, best, spec)] if field_ and math.isfinite(best) else []
    oracle = next((r.value for r in ranking if r.scheme == BOUND), None)
    nominal = next((r.value for r in ranking if r.scheme == BASELINE), None)
    regret, regret_tie = ratio(best, oracle, spec)
    benefit, benefit_tie = ratio(nominal, best, spec)
    return MetricVerdict(
        spec,
        ranking,
        winners,
        best,
        oracle,
        nominal,
        regret,
        regret_tie,
        benefit,
        benefit_tie,
        failed,
        missing,
        None if regret is not None or regret_tie else difference(best, oracle),
        None if benefit is not None or benefit_tie else difference(nominal, best),
        # no contest at all (module docstring): no completed run has the metric, for the one reason
        NOT_APPLICABLE if not done and missing and all(why == NOT_APPLICABLE for _, why in missing) else "",
    )


# ---------------------------------------------------------------------- one case
@dataclass
class CaseVerdict:
    """Every headline metric of one case, and the generated sentences."""

    case: str
    schemes: list[str]
    metrics: dict[str, MetricVerdict]
    sentences: list[str]
    outside_expected: list[tuple[str, str]]  # (scheme, status) of runs outside expected_status
    failed: list[tuple[str, str, float | None]]  # (scheme, status, t_end) of runs that did not complete


def compare_case(
    case: str,
    metrics_by_scheme: Mapping[str, Mapping],
    expected_status: Iterable[str] | Mapping[str, Iterable[str]] = ("ok",),
    fault_times: Sequence[float] = (),
    facts: Mapping[str, object] | None = None,
) -> CaseVerdict:
    """The verdict of one case.

    Parameters
    ----------
    metrics_by_scheme : mapping
        ``{scheme: metrics.json dict}`` of the runs that exist.
    expected_status : iterable of str, or mapping of scheme to iterable of str
        The statuses that are not failures: the case's ``expected_status``, or per scheme
        (``Case.expected_for``).
    fault_times : sequence of float
        Event times (for the sentences).
    facts : mapping, optional
        Facts of the case the sentences may explain with: ``friction`` (a fault adds a friction
        torque), ``fractional`` (a gain strictly between 0 and 1), ``uncompensable`` (a phase with
        rank(Bbar sigma) < 2), ``analysis`` (the case's linearized analysis, ``ftcreport.analysis.analyze_case``:
        the verdict then cites it where a scheme loses or chatters, or nominal wins), ``limit`` (what bounds
        the wheels' inputs, ``verdict_analysis.limit_words``; absent for ideal torques), ``recovery_band``
        (the case's band of the recovery time [m], stated where the sentences use it).
    """
    facts = dict(facts or {})
    rows = tidy(case, metrics_by_scheme)
    verdicts = {}
    for spec in HEADLINE:
        mine = [r for r in rows if r.metric == spec.key]
        if mine:
            verdicts[spec.key] = compare_metric(
                mine, spec, _undetecting(metrics_by_scheme) if spec.key == "false_alarms" else None
            )
    if isinstance(expected_status, Mapping):
        expected = {s: set(v) for s, v in expected_status.items()}
    else:
        expected = {s: set(expected_status) for s in metrics_by_scheme}
    outside = [
        (s, str(m.get("status", "error")))
        for s, m in metrics_by_scheme.items()
        if str(m.get("status", "error")) not in expected.get(s, {"ok"})
    ]
    failed = [
        (s, str(m.get("status", "error")), _num(m.get("t_end")))
        for s, m in metrics_by_scheme.items()
        if m.get("status") != "ok"
    ]
    sentences = _sentences(verdicts, metrics_by_scheme, list(fault_times), facts, failed)
    line = _identification(metrics_by_scheme.get("switching"), facts)
    # once per verdict: a switching that never settles already has its wrong-model time in the recovery sentence
    if line is not None and not any("switching never settles" in s.lower() for s in sentences):
        sentences.append(line)
    if facts.get("analysis"):
        cited = _analysis_sentences(facts["analysis"], verdicts, metrics_by_scheme, facts.get("limit"))
        # every completed loop predicted unstable (two_link_switching_motors: all chatter at the voltage limit):
        # the ranking is among chattering loops, and the reader is told that first (session 12's new user, M4)
        done = [s for s, m in metrics_by_scheme.items() if m.get("status") == "ok"]
        sentences = cited + sentences if done and every_loop_unstable(facts["analysis"], done) else sentences + cited
    return CaseVerdict(case, list(metrics_by_scheme), verdicts, sentences, outside, failed)


#: switching on the true pattern's model less than this fraction of the run is said in the verdict, when it
#: also ran on a model missing a true failure more than 1 - EFFECTIVE of the run, or chattered (_identification)
IDENTIFIED = 0.5
EFFECTIVE = 0.9


def _identification(m: Mapping | None, facts: Mapping) -> str | None:
    """The verdict's sentence on switching's identification, when its run held the true pattern's model less
    than :data:`IDENTIFIED` of the time (the comparison of the families reads how each copes with the fault:
    switching's is which model it selects), or None.  Its exact and effective match fractions (a model that
    assumes at least the true failures) and its switch count, from metrics.json, and the case's reason where
    ``facts`` gives one (partial losses between its 0/1 models, a friction it has no term for)."""
    if not m or m.get("status") != "ok":
        return None
    exact, effective = _num(m.get("switching_exact_match_fraction")), _num(m.get("switching_match_fraction"))
    if exact is None or exact >= IDENTIFIED:
        return None
    # a model assuming at least the true failures tracks (two_link_intermittent: 45 % exact, 99.6 % such, 8
    # switches in 22 s, in the band throughout): said only when it ran on a model missing a true failure
    # often (EFFECTIVE), or switched more than once a second on average (chatter between models)
    n = _num(m.get("switch_count"))
    phases = m.get("phases") or []
    span = _num(m.get("t_end")) or (_num(phases[-1].get("t_end")) if phases else None)
    chatters = n is not None and span is not None and n > span
    if not chatters and (effective is None or effective >= EFFECTIVE):
        return None
    line = f"Switching ran on the true pattern's model {_percent(exact)} of the time"
    if effective is not None:
        line += f" (on a model assuming at least the true failures {_percent(effective)})"
    if n is not None:
        line += f", with {n:.0f} switches" + (f" in {span:g} s" if span else "")
    why = []
    if facts.get("fractional"):
        why.append("the partial gain losses lie between its 0/1 models")
    if facts.get("friction"):
        why.append("a friction torque biases its models, which have no friction term")
    return line + (": " + "; ".join(why) if why else "") + "."


def _percent(f: float) -> str:
    """A fraction as a percentage: 3 significant digits below 100 %, never rounded up to 100 % or down to 0 %."""
    p = 100.0 * f
    if p == 0.0 or p == 100.0:
        return f"{p:.0f} %"
    text = f"{p:.3g}"
    if float(text) >= 100.0:
        text = "99.9"
    return f"{text} %"


def _undetecting(metrics_by_scheme: Mapping[str, Mapping]) -> dict[str, str]:
    """``{scheme: why}`` of the detectors that cannot win the false alarms: a missed change, or no
    detection computed (module docstring)."""
    out = {}
    for s, m in metrics_by_scheme.items():
        events = m.get("detection_events")
        if events is None:
            out[s] = "detection not computed: no false-alarm win"
        elif m.get("missed_detections"):
            out[s] = f"misses {m['missed_detections']} of {len(events)} changes: no false-alarm win"
    return out


def _analysis_sentences(analysis: dict, verdicts, metrics, limit: str | None = None) -> list[str]:
    """The linearized analysis cited where a scheme loses or chatters, or nominal wins (issue 37 item 7)."""
    after = verdicts.get("after_fault_error_max")
    if after and after.not_applicable:  # no fault: the schemes as the final error ranks them
        after = verdicts.get("position_error_final")
    ranking = [r.scheme for r in after.ranking] if after else []
    stopped = [s for s, m in metrics.items() if m.get("status") != "ok"]
    # nominal "wins" (and the analysis agrees) only when among the best after the faults (module docstring)
    winners = [s for s in (after.winners if after else []) if s != BASELINE or _nominal_among_best(verdicts)]
    return analysis_sentences(analysis, ranking, winners, stopped, limit)


def _nominal_among_best(verdicts: Mapping[str, MetricVerdict]) -> bool:
    """Whether nominal is among the winners on every metric of :data:`AFTER_FAULTS` that has winners."""
    won = [mv for k in AFTER_FAULTS if (mv := verdicts.get(k)) is not None and mv.winners]
    return bool(won) and all(BASELINE in mv.winners for mv in won)


def fmt_value(x: float | None, unit: str = "") -> str:
    """A value for a sentence: 3 significant digits, 'never' for inf."""
    if x is None:
        return "n/a"
    if math.isinf(x):
        return "never"
    s = f"{x:.3g}"
    return f"{s} {unit}".strip() if unit else s


def fmt_span(values: Sequence[float], unit: str = "") -> str:
    """Values for a sentence: one value when they print alike (3 significant digits), else "lo-hi"."""
    lo, hi = fmt_value(min(values)), fmt_value(max(values))
    if lo == hi:
        return fmt_value(min(values), unit)
    return f"{lo}-{hi} {unit}".strip()


def fmt_best(mv: MetricVerdict, unit: str = "") -> str:
    """The winners' value: the best one for a single winner, the range of their own values for a tie
    ("287-298 N m": never the best value attributed to every tied scheme)."""
    values = [v for s in mv.winners if (v := mv.value(s)) is not None]
    return fmt_span(values, unit) if values else fmt_value(mv.best, unit)


def fmt_ratio(x: float | None, tie: bool = False) -> str:
    """A ratio for a page: 3 significant digits, '1 (tie)', 'n/a'; never 'inf' (ratio() gives none)."""
    if tie:
        return "1 (tie)"
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x:.3g}"


def fmt_relative(mv: MetricVerdict, which: str) -> str:
    """Regret (``which="regret"``) or benefit of a verdict in words for a table cell: the ratio, or
    the absolute difference when the denominator is below the metric's floor (module docstring), or
    which side is "never" (inf: no ratio and no difference)."""
    r, tie, diff = getattr(mv, which), getattr(mv, f"{which}_tie"), getattr(mv, f"{which}_diff")
    if tie or r is not None:
        return fmt_ratio(r, tie)
    num, den = (mv.best, mv.oracle) if which == "regret" else (mv.nominal, mv.best)
    who = ("best", BOUND) if which == "regret" else (BASELINE, "best")
    for side, x in zip(who, (num, den), strict=True):
        if x is not None and math.isinf(x):
            return f"n/a ({side}: never)"
    if diff is None:
        return "n/a"
    unit = f" {mv.spec.unit}" if mv.spec.unit else ""
    return f"{diff:+.3g}{unit} (difference: {fmt_value(den)}{unit} is below the {mv.spec.floor:g}{unit} floor)"


def _names(schemes: Sequence[str]) -> str:
    names = [LABEL.get(s, s) for s in schemes]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _times(ts: Sequence[float]) -> str:
    ts = sorted({round(float(t), 6) for t in ts})
    if not ts:
        return ""
    s = [f"{t:g}" for t in ts]
    return (s[0] if len(s) == 1 else ", ".join(s[:-1]) + " and " + s[-1]) + " s"


#: a run whose error at the first fault is at least this share of its peak after the faults has that peak from
#: the start-up's residual, not from the faults (:func:`startup_at_first_fault`)
RESIDUAL_SHARE = 0.9


def startup_at_first_fault(metrics: Mapping[str, Mapping], band: float | None) -> dict | None:
    """What the start-up left at the first fault, when it matters to the metrics taken from that fault on:
    ``{"t", "error", "above_band", "decides"}`` or None.

    ``error``: the largest position error [m] of the completed runs at the first fault ``t`` [s] (the final
    error of the phase before it); ``above_band``: above the recovery ``band``, the start-up has not settled;
    ``decides``: every run's error there is at least :data:`RESIDUAL_SHARE` of its peak after the faults, so
    that peak is the start-up's residual, not the faults' effect (five_link_cascade: 0.005-0.007 m at 15 s).
    None when neither holds, when the first fault acts at the start (no phase before it), or when the error
    at the fault is below the peak error's resolution (its tie floor).
    """
    at, peaks, t = [], [], None
    for m in metrics.values():
        phases = m.get("phases") or []
        if m.get("status") != "ok" or len(phases) < 2 or phases[0].get("fault") or not fault_phases(phases):
            continue
        e0, peak = _num(phases[0].get("position_error_final")), _extract("after_fault_error_max", m)[0]
        if e0 is None or peak is None:
            continue
        at.append(e0)
        peaks.append(peak)
        t = _num(phases[0].get("end"))
    if not at or t is None or max(at) <= SPECS["after_fault_error_max"].floor:
        return None
    above = band is not None and max(at) > band
    decides = all(e >= RESIDUAL_SHARE * p for e, p in zip(at, peaks, strict=True))
    return {"t": t, "error": max(at), "above_band": above, "decides": decides} if above or decides else None


def _startup_sentence(metrics, facts) -> str | None:
    """The verdict's sentence on :func:`startup_at_first_fault`, or None."""
    band = _num(facts.get("recovery_band"))
    got = startup_at_first_fault(metrics, band)
    if got is None:
        return None
    if got["decides"]:
        return (
            f"Those peaks are what the start-up left at the first fault ({got['t']:g} s: up to {got['error']:.3g} m, "
            f"at least {100 * RESIDUAL_SHARE:g} % of each run's peak after it), not the faults' effect."
        )
    return (
        f"The start-up has not settled at the first fault ({got['t']:g} s: position error up to {got['error']:.3g} m,"
        f" above the {band:g} m band): the peaks after the faults include its decay."
    )


def _sentences(verdicts, metrics, fault_times, facts, failed) -> list[str]:
    out = []
    ok = [s for s, m in metrics.items() if m.get("status") == "ok"]
    if failed and not any(s != BOUND for s in ok):
        longest = max(failed, key=lambda f: f[2] or 0.0)
        stops = ", ".join(f"{LABEL.get(s, s)} {st} at {fmt_value(t)} s" for s, st, t in failed)
        why = " The fault pattern is uncompensable: no law can keep tracking." if facts.get("uncompensable") else ""
        out.append(
            f"No scheme completes the run: every one stops ({stops}); {LABEL.get(longest[0], longest[0])} "
            f"lasts longest.{why}"
        )
        return out
    after = verdicts.get("after_fault_error_max")
    final = verdicts.get("position_error_final")
    if after and after.not_applicable and final and final.winners:
        # no fault: the peak error is the initial offset, alike for every scheme; the final error still ranks
        out.append(
            "With no fault in the run, the fault-response metrics do not apply; "
            + ", ".join(_smallest(final, "the smallest final error"))
            + "."
        )
    if after and after.winners:
        when = f"After the faults at {_times(fault_times)}" if fault_times else "After the faults"
        out.append(", ".join(_smallest(after, "the smallest peak error", when)) + ".")
        line = _startup_sentence(metrics, facts)
        if line:
            out.append(line)
        if BASELINE in after.winners and any(contestant(s) for s in ok) and _nominal_among_best(verdicts):
            out.append(_why_nominal(facts, after, metrics))
    if failed:
        stops = "; ".join(f"{LABEL.get(s, s)} {st} at {fmt_value(t)} s" for s, st, t in failed)
        out.append(f"Not ranked, the run stopped: {stops}.")
    rec = verdicts.get("recovery_time_max")
    if rec and rec.not_applicable:
        line = _startup_band(metrics, facts)
        if line:
            out.append(line)
    elif rec:
        bits = []
        band = _num(facts.get("recovery_band"))
        # the band as a number where a sentence first uses it: "settles within the band" says nothing else
        the_band = "the recovery band" if band is None else f"the recovery band (position error <= {band:g} m)"
        settled = [r for r in rec.ranking if contestant(r.scheme) and not math.isinf(r.value)]
        never = [r.scheme for r in rec.ranking if contestant(r.scheme) and math.isinf(r.value)]
        if settled:
            first = [r for r in settled if tied(r.value, settled[0].value, rec.spec)]
            who, values = _names([r.scheme for r in first]), [r.value for r in first]
            verb = "s" if len(first) == 1 else ""
            if max(values) == 0.0:
                bits.append(f"{who} never leave{verb} {the_band}")
            else:
                bits.append(f"{who} settle{verb} within {the_band} in {fmt_span(values, 's')} at worst")
        for i, s in enumerate(never):
            m = metrics.get(s, {})
            extra = ""
            if _num(m.get("switching_match_fraction")) is not None:  # a switching scheme's detection metric
                extra = f" (wrong model {100 * (1 - float(m['switching_match_fraction'])):.0f} % of the time)"
            where = f" within {the_band}" if not settled and i == 0 else ""
            bits.append(f"{LABEL.get(s, s)} never settles{where}{extra}")
        if rec.oracle is not None and bits:
            o = rec.oracle
            bits.append(
                "the oracle "
                + (
                    "never settles"
                    if math.isinf(o)
                    else "never leaves it"
                    if o == 0.0
                    else f"takes {fmt_value(o, 's')}"
                )
            )
        if bits:
            out.append(_cap("; ".join(bits)) + ".")
    det = verdicts.get("detection_delay_max")
    fa = verdicts.get("false_alarms")
    if det and (det.ranking or det.missing):
        bits = []
        for s in ACTIVE:
            v = det.value(s)
            if v is None:
                continue
            f = fa.value(s) if fa else None
            alarms = "" if f is None else f", {int(f)} false alarm{'s' if f != 1 else ''}"
            if math.isinf(v):
                note = next((r.note for r in det.ranking if r.scheme == s), "")
                bits.append(f"{LABEL[s]} {note}{alarms}")
            else:
                bits.append(f"{LABEL[s]} detects every change within {fmt_value(v, 's')}{alarms}")
        if bits:
            out.append(_cap("; ".join(bits)) + ".")
    elif (tq := verdicts.get("torque_peak_after_fault")) and tq.winners:
        out.append(
            "Smallest peak torque after the first fault: "
            f"{_names(tq.winners)}, {fmt_best(tq, 'N m')}"
            + (f" (the oracle needs {fmt_value(tq.oracle, 'N m')})" if tq.oracle is not None else "")
            + "."
        )
    return out[:4]


def _smallest(mv: MetricVerdict, what: str, when: str = "") -> list[str]:
    """The parts of a sentence naming the winners of ``mv`` on a position error (``what``: "the smallest
    peak error") with their value, against the oracle and nominal (the caller joins them with ", ")."""
    tie = " (a tie)" if len(mv.winners) > 1 else ""
    lead = f"{when}, " if when else ""
    verb = "s" if len(mv.winners) == 1 else ""
    parts = [f"{lead}{_names(mv.winners)} keep{verb} {what}{tie}, {fmt_best(mv, 'm')}"]
    if mv.oracle is not None:
        if mv.regret_tie:
            parts.append("matching the oracle within the tolerance")
        elif mv.regret is not None:
            parts.append(f"{fmt_ratio(mv.regret)} times the oracle's {fmt_value(mv.oracle, 'm')}")
        elif mv.regret_diff is not None:
            parts.append(f"{fmt_value(mv.regret_diff, 'm')} above the oracle's {fmt_value(mv.oracle, 'm')}")
    if mv.nominal is not None and BASELINE not in mv.winners:
        if mv.benefit_tie:
            parts.append("no better than nominal")
        elif mv.benefit is not None:
            parts.append(f"{fmt_ratio(mv.benefit)} times smaller than nominal's")
        elif mv.benefit_diff is not None:
            parts.append(f"{fmt_value(mv.benefit_diff, 'm')} smaller than nominal's")
    return parts


def _startup_band(metrics: Mapping[str, Mapping], facts: Mapping) -> str:
    """When the runs of a case without a fault enter the recovery band (their one phase's
    ``recovery_time``), for the verdict.  Such a run starts off the reference, so its error is outside
    the band until the start-up transient decays: "never leaves the band" (read from metrics.json's
    ``recovery_time_max`` of 0 s, a maximum over no fault phase) was false.  '' when no contestant's
    run has the time."""
    band = _num(facts.get("recovery_band"))
    the_band = "the recovery band" if band is None else f"the recovery band (position error <= {band:g} m)"

    def entered(m: Mapping) -> tuple[bool, float | None]:  # (known, when: None = never)
        phases = m.get("phases") or []
        if m.get("status") != "ok" or len(phases) != 1 or "recovery_time" not in phases[0]:
            return False, None
        return True, _num(phases[0]["recovery_time"])

    times = {s: e[1] for s, m in metrics.items() if contestant(s) and (e := entered(m))[0]}
    settled = sorted((t, s) for s, t in times.items() if t is not None)
    never = [s for s, t in times.items() if t is None]
    spec = SPECS["recovery_time_max"]
    bits = []
    if settled:
        first = [(t, s) for t, s in settled if tied(t, settled[0][0], spec)]
        last = [(t, s) for t, s in settled if tied(t, settled[-1][0], spec) and (t, s) not in first]
        verb = "s" if len(first) == 1 else ""
        bits.append(
            f"{_names([s for _, s in first])} enter{verb} {the_band} after the start-up transient, at "
            f"{fmt_span([t for t, _ in first], 's')}, and stay{verb} in it"
        )
        if last:
            bits.append(f"{_names([s for _, s in last])}, the last, at {fmt_span([t for t, _ in last], 's')}")
    for i, s in enumerate(never):
        bits.append(f"{LABEL.get(s, s)} never enters {'it' if settled or i else the_band}")
    if not bits:
        return ""
    if BOUND in metrics and (e := entered(metrics[BOUND]))[0]:
        bits.append("the oracle never enters it" if e[1] is None else f"the oracle at {fmt_value(e[1], 's')}")
    return _cap("; ".join(bits)) + "."


#: a scheme at its torque limit this fraction of the run or more has its tracking set by the limit
SATURATED = 0.5


def _why_nominal(facts, after: MetricVerdict, metrics: Mapping[str, Mapping] | None = None) -> str:
    """Why the baseline without FTC is among the best: the case's facts that explain it, else none claimed
    (the analysis's own sentence says whether the healthy loop stays stable)."""
    why = []
    sats = [
        m.get("saturation_fraction")
        for m in (metrics or {}).values()
        if m.get("status") == "ok" and isinstance(m.get("saturation_fraction"), int | float)
    ]
    if sats and min(sats) >= SATURATED:
        lo, hi = 100 * min(sats), 100 * max(sats)
        span = f"{lo:.0f} %" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} %"
        return (
            "Surprise: the baseline without FTC is among the best here; the schemes are at their torque limit "
            f"{span} of the run: the limit, not the law, sets the tracking."
        )
    if facts.get("fractional"):
        why.append("partial gain losses lie between the 0/1 models of switching and adaptive")
    if facts.get("friction"):
        why.append("a friction torque biases the fault models (the switching laws have no friction term)")
    if facts.get("follower_only"):
        why.append("the faults hit followers only, which need little torque redistribution")
    if not why:
        why.append("no partial loss, friction or follower-only pattern of the case explains it")
    return "Surprise: the baseline without FTC is among the best here; " + "; ".join(why) + "."


def _cap(s: str) -> str:
    return s[:1].upper() + s[1:]


# ---------------------------------------------------------------------- across cases
@dataclass
class Scoreboard:
    """Wins per metric per scheme across cases, median regret, runs outside expected_status."""

    schemes: list[str]
    metrics: list[MetricSpec]
    wins: dict[str, dict[str, int]]  # scheme -> metric -> number of cases won (ties count for each)
    contests: dict[str, dict[str, int]]  # scheme -> metric -> cases with a winner the scheme took part in
    median_regret: dict[str, dict[str, float | None]]  # scheme -> metric -> median of scheme / oracle
    regret_counts: dict[str, dict[str, tuple[int, int]]]  # scheme -> metric -> (cases with a ratio, cases ranked)
    outside_expected: dict[str, int]  # scheme -> runs whose status is not in the case's expected_status
    runs: dict[str, int]  # scheme -> runs
    cases: list[dict]  # one row per case: name, winners per metric, not applicable (why) per metric, outside expected
    # scheme -> metric -> cases where the metric does not apply to the scheme's run (no contest: no fault)
    not_applicable: dict[str, dict[str, int]] = field(default_factory=dict)
    # scheme -> metric -> why the metric does not apply to the scheme at all, in any case ("no detector")
    inapplicable: dict[str, dict[str, str]] = field(default_factory=dict)


def scoreboard(
    verdicts: Sequence[CaseVerdict], schemes: Sequence[str], families: Mapping[str, str] | None = None
) -> Scoreboard:
    """Aggregate case verdicts (the index page's scoreboard).

    A scheme's wins on a metric are counted out of the contests it took part in: the cases where the
    metric has a winner and the scheme's run is ranked on it or stopped (a run that did not complete
    took part and lost).  A case it did not run in, or whose run lacks the metric, is no contest of it;
    nor is a case where the metric does not apply (no fault: module docstring), counted apart so the page
    says "n/a" with the reason rather than "0 / 0".  A metric that exists only for some schemes
    (:attr:`MetricSpec.only`: the detection delay and the false alarms, of a fault detector) does not apply
    to the others at all: ``inapplicable`` gives why, so the page says "n/a: no detector", not a zero score:
    :data:`NO_DETECTOR` for a built-in scheme and for a plug-in whose family (``families``: plug-in name ->
    family) is not the detectors' ("active"), :data:`NOT_COMPARED` for another plug-in.
    """
    wins = {s: {m.key: 0 for m in HEADLINE} for s in schemes}
    regrets: dict[str, dict[str, list[float]]] = {s: {m.key: [] for m in HEADLINE} for s in schemes}
    ranked: dict[str, dict[str, int]] = {s: {m.key: 0 for m in HEADLINE} for s in schemes}
    outside = dict.fromkeys(schemes, 0)
    runs = dict.fromkeys(schemes, 0)
    contests = {s: {m.key: 0 for m in HEADLINE} for s in schemes}
    not_applicable = {s: {m.key: 0 for m in HEADLINE} for s in schemes}
    families = dict(families or {})

    def why(s: str, m: MetricSpec) -> str:
        detector = s not in LABEL and families.get(s, "active") == "active"  # a plug-in that may have one
        return NOT_COMPARED if detector else m.only_why

    inapplicable = {s: {m.key: why(s, m) for m in HEADLINE if m.only is not None and s not in m.only} for s in schemes}
    cases = []
    for v in verdicts:
        for s in v.schemes:
            if s in runs:
                runs[s] += 1
        for s, _ in v.outside_expected:
            if s in outside:
                outside[s] += 1
        row = {"case": v.case, "winners": {}, "not_applicable": {}, "outside_expected": list(v.outside_expected)}
        for key, mv in v.metrics.items():
            row["winners"][key] = list(mv.winners)
            if mv.not_applicable:
                row["not_applicable"][key] = mv.not_applicable
                for s, why in mv.missing:
                    if s in not_applicable and why == mv.not_applicable:
                        not_applicable[s][key] += 1
            if mv.winners:
                for s in {r.scheme for r in mv.ranking} | {s for s, _ in mv.failed}:
                    if s in contests:
                        contests[s][key] += 1
            for s in mv.winners:
                if s in wins:
                    wins[s][key] += 1
            # a ratio only where the oracle's value is above the floor, as the page says: a tie under the floor
            # (five_link_cascade's final error, oracle 1.46e-8 m) is the case page's "1 (tie)", no ratio
            ratio_ok = mv.oracle is not None and math.isfinite(mv.oracle) and abs(mv.oracle) > mv.spec.floor
            for r in mv.ranking:
                if r.scheme in regrets and r.scheme != BOUND and mv.oracle is not None:
                    ranked[r.scheme][key] += 1
                    g = mv.regret_of(r.scheme) if ratio_ok else None
                    if g is not None:
                        regrets[r.scheme][key].append(g)
        cases.append(row)
    med = {s: {k: (statistics.median(v) if v else None) for k, v in d.items()} for s, d in regrets.items()}
    counts = {s: {k: (len(v), ranked[s][k]) for k, v in d.items()} for s, d in regrets.items()}
    return Scoreboard(
        list(schemes),
        list(HEADLINE),
        wins,
        contests,
        med,
        counts,
        outside,
        runs,
        cases,
        not_applicable=not_applicable,
        inapplicable=inapplicable,
    )
