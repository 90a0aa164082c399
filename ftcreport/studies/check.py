"""The one gate: every item ``check`` (and ``run``) judges, in one list (pure but for reading the store).

A gate item is one thing that holds or not, with a name and a one-line message: a run (its status
is one its case expects), a threshold (``[thresholds.<scheme>]`` maps metric names of
``metrics.json`` to ``{min, max}``), a thesis claim (:mod:`ftcreport.evaluation.claims`), a case file that
could not be read.  The exit code, the terminal lines and the JUnit testcases all come from the
list (:func:`exit_code`, :meth:`GateItem.line`, :func:`ftcreport.report.junit.junit_xml`), so they
cannot disagree: ``check`` exits 1 when any item fails, 2 when a case file is bad input.

The items of a stored case come from the functions of :data:`CASE_ITEMS`, each given the case as
stored (:class:`StoredCase`); a new kind of item (requirements, baseline deltas) is one function
appended there, and a line of :data:`SUMMARY` for its count.

A run that did not complete fails every threshold of its scheme (a metric of a stopped run is not
comparable); a metric absent from the run fails with that reason.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..evaluation.claims import ClaimResult, bound_text, evaluate_claims
from ..evaluation.requirements import applies_to
from ..storage.store import StoredRun, read_json, stored_runs

__all__ = [
    "CASE_ITEMS",
    "SUMMARY",
    "GateItem",
    "StoredCase",
    "ThresholdResult",
    "case_items",
    "claim_items",
    "error_items",
    "evaluate",
    "exit_code",
    "gate",
    "requirement_items",
    "run_items",
    "stored_case",
    "summary",
    "threshold_items",
]


@dataclass(frozen=True)
class GateItem:
    """One thing the gate judges.

    ``kind`` groups items in the summary (:data:`SUMMARY`); ``name`` says what is judged within the
    case (``nominal / status``, ``switching / position_error_final``, ``claim c1 (Fig. 3.4)``);
    ``message`` is one line, why it holds or not; ``schemes`` the schemes whose runs it reads.
    ``field`` is the case file's field that states it (``run`` names it in its error line);
    ``classname``/``testname`` are the JUnit testcase's (default ``<case>.<kind>`` and ``name``);
    ``detail`` its system-out; ``time`` its seconds.  ``error``: bad input (a case file that cannot
    be read), a JUnit ``<error>`` and exit 2, not a failed item.
    """

    kind: str
    case: str
    name: str
    ok: bool
    message: str
    schemes: tuple[str, ...] = ()
    field: str = ""
    classname: str = ""
    testname: str = ""
    detail: str = ""
    time: float = 0.0
    error: bool = False
    lines: tuple[str, ...] = ()

    def line(self) -> str:
        """The terminal line: ``pass  <case> / <name>: <message>`` (``FAIL`` when it does not hold)."""
        mark = "pass" if self.ok else "FAIL"
        return f"{mark:4}  {self.case} / {self.name}: {self.message}".rstrip()

    def terminal_lines(self) -> list[str]:
        """:meth:`line`, or for a failed item that lists its findings (``lines``: a baseline's changes, one
        per metric or signal) one ``FAIL  <finding>`` line each."""
        if self.ok or not self.lines:
            return [self.line()]
        return [f"FAIL  {x}" for x in self.lines]

    @property
    def junit_class(self) -> str:
        return self.classname or f"{self.case}.{self.kind}"

    @property
    def junit_name(self) -> str:
        return self.testname or self.name


@dataclass
class StoredCase:
    """A case as the gate sees it: its record (``<out>/<case>/case.json``), the runs stored for it and the
    runs this invocation could not store (``{scheme: why}``, the batch's ``not_stored``)."""

    name: str
    record: dict
    runs: dict[str, StoredRun] = field(default_factory=dict)
    not_stored: dict[str, str] = field(default_factory=dict)

    @property
    def schemes(self) -> list[str]:
        return list(self.record.get("schemes") or self.runs)

    def metrics(self) -> dict[str, dict | None]:
        """``{scheme: metrics}`` the thresholds and claims read: a sound run's, a damaged run's stand-in
        (status ``error``, the damage as reason), None for a run not stored (or not stored this time)."""
        out: dict[str, dict | None] = {}
        for s in dict.fromkeys([*self.schemes, *self.runs]):
            run = self.runs.get(s)
            out[s] = None if run is None or run.absent or s in self.not_stored else run.shown()
        return out

    def wall_time(self, scheme: str) -> float:
        m = self.runs[scheme].metrics if scheme in self.runs else None
        return float((m or {}).get("wall_time") or 0.0)


def stored_case(out: Path, name: str, not_stored: dict[str, str] | None = None) -> StoredCase:
    """The case ``name`` under ``out`` as stored (every run checked: :func:`ftcreport.storage.store.check_run`)."""
    rec = read_json(Path(out) / name / "case.json")
    return StoredCase(name, rec if isinstance(rec, dict) else {}, stored_runs(out, name), dict(not_stored or {}))


# ------------------------------------------------------------------------------------------ runs
def run_items(case: StoredCase) -> list[GateItem]:
    """One item per scheme the case runs: it holds when the run is stored, sound, and ends in a status the
    case expects (a failure cached by an earlier batch fails here as it did then)."""
    out = []
    for s in case.schemes:
        run = case.runs.get(s)
        if s in case.not_stored:
            ok, msg = False, f"not stored: {case.not_stored[s]}"
        elif run is None or run.absent:
            ok, msg = False, "no stored run (run 'ftcreport batch' on the case)"
        elif not run.sound:
            ok, msg = False, f"damaged stored result: {run.problem}"
        elif run.failed:
            ok, msg = False, run.record.get("failure") or f"{run.record.get('status')}"
        else:
            ok, msg = True, f"{run.record.get('status')}"
        out.append(
            GateItem(
                "run",
                case.name,
                f"{s} / status",
                ok,
                msg,
                schemes=(s,),
                field="expected_status",
                classname=f"{case.name}.{s}",
                testname="status",
                detail=msg,
                time=case.wall_time(s),
            )
        )
    return out


# ------------------------------------------------------------------------------------------ thresholds
@dataclass(frozen=True)
class ThresholdResult:
    """One threshold of one scheme of one case."""

    case: str
    scheme: str
    metric: str
    min: float | None
    max: float | None
    actual: float | None
    ok: bool
    reason: str


def evaluate(case_name: str, thresholds: dict, metrics_by_scheme: dict[str, dict | None]) -> list[ThresholdResult]:
    """Compare every threshold with the stored metrics.

    Parameters
    ----------
    thresholds : dict
        ``{scheme: {metric: bound}}`` with bound having ``min``/``max`` attributes or keys.
    metrics_by_scheme : dict
        ``{scheme: metrics dict or None (not run)}``.
    """
    out = []
    for scheme, bounds in thresholds.items():
        m = metrics_by_scheme.get(scheme)
        for metric, bound in bounds.items():
            lo = bound.get("min") if isinstance(bound, dict) else bound.min
            hi = bound.get("max") if isinstance(bound, dict) else bound.max
            if m is None:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, "scheme not run"))
                continue
            if m.get("status") != "ok":
                why = f"run {m.get('status')}: {m.get('reason', '')}".strip()
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, why))
                continue
            base, _, key = metric.partition(".")  # ``metric.key``: an entry of a table metric
            val = m.get(base)
            present = base in m
            if key:
                present = isinstance(val, dict) and key in val
                val = val.get(key) if present else None
            if not isinstance(val, int | float) or isinstance(val, bool):
                why = "metric absent"
                if present and val is None:  # computed, and null for a reason the run stored
                    why = f"null: {(m.get('null_reasons') or {}).get(metric, 'not defined for this run')}"
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, None, False, why))
                continue
            val = float(val)
            if lo is not None and val < lo:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, False, f"{val:.6g} < min {lo:g}"))
            elif hi is not None and val > hi:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, False, f"{val:.6g} > max {hi:g}"))
            else:
                out.append(ThresholdResult(case_name, scheme, metric, lo, hi, val, True, ""))
    return out


def _fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def threshold_item(r: ThresholdResult, time: float = 0.0) -> GateItem:
    """The gate item of one evaluated threshold."""
    expected = bound_text(r.min, r.max)
    actual = "n/a" if r.actual is None else f"{r.actual:.6g}"
    msg = f"actual {_fmt(r.actual, '.6g')} (min {_fmt(r.min, 'g')}, max {_fmt(r.max, 'g')}) {r.reason}".rstrip()
    return GateItem(
        "threshold",
        r.case,
        f"{r.scheme} / {r.metric}",
        r.ok,
        msg,
        schemes=(r.scheme,),
        field=f"thresholds.{r.scheme}.{r.metric}",
        classname=f"{r.case}.{r.scheme}",
        testname=r.metric,
        detail=f"expected {expected}; actual {actual}" + (f"; {r.reason}" if r.reason else ""),
        time=time,
    )


def threshold_items(case: StoredCase) -> list[GateItem]:
    """One item per threshold of the case (``[thresholds.<scheme>]``)."""
    results = evaluate(case.name, case.record.get("thresholds") or {}, case.metrics())
    return [threshold_item(r, case.wall_time(r.scheme)) for r in results]


# ------------------------------------------------------------------------------------------ claims
def claim_item(c: ClaimResult, index: int | None = None, relative_to: str | None = None) -> GateItem:
    """The gate item of one evaluated thesis claim (``index``: its place in ``[[claims]]``; ``relative_to``:
    the other scheme it reads)."""
    msg = f"{c.outcome} (expected {c.expect}); {c.reason}"
    return GateItem(
        "claim",
        c.case,
        f"claim {c.id} ({c.source})",
        c.ok,
        msg,
        schemes=tuple(s for s in (c.scheme, relative_to) if s),
        field=f"claims[{'' if index is None else index}] (id '{c.id}')",
        classname=f"{c.case}.claims",
        testname=c.id,
        detail=f"{c.source}: {msg}",
    )


def claim_items(case: StoredCase) -> list[GateItem]:
    """One item per thesis claim of the case (``[[claims]]``)."""
    claims = case.record.get("claims") or []
    results = evaluate_claims(case.name, claims, case.metrics())
    return [claim_item(c, i, _get(claims[i], "relative_to")) for i, c in enumerate(results)]


def _get(obj, key: str):
    return obj.get(key) if isinstance(obj, dict) else getattr(obj, key, None)


# ------------------------------------------------------------------------------------------ requirements
def requirement_items(
    case: str, requirements: Sequence[Any], metrics_by_scheme: Mapping[str, dict | None]
) -> list[GateItem]:
    """One item per requirement x scheme x window (issue 35 item 11; :mod:`ftcreport.evaluation.requirements`).

    ``requirements``: the case's ``[[requirements]]`` (models or dicts); ``metrics_by_scheme``: the
    stored metrics (None: the scheme was not run).  A window holds when every step's value is within
    its bound; one violated or not evaluated (empty, or cut by a stopped run) fails.  A scheme whose
    stored run has no record of a requirement (the run failed before its metrics) gives one failed
    item saying so.
    """
    items: list[GateItem] = []
    for scheme, m in metrics_by_scheme.items():
        stored = (m or {}).get("requirements") or []
        for index, req in enumerate(requirements):
            if not applies_to(req, scheme):
                continue
            rid = _get(req, "id")
            common = {
                "schemes": (scheme,),
                "field": f"requirements[{index}] (id '{rid}')",
                "classname": f"{case}.{scheme}.requirements",
            }
            recs = [r for r in stored if isinstance(r, dict) and r.get("id") == rid]
            if not recs:
                why = (
                    "the scheme was not run"
                    if m is None
                    else f"no result stored (run {m.get('status')}: {m.get('reason') or 'no reason given'})"
                )
                msg = f"not evaluated: {why}"
                items.append(
                    GateItem(
                        "requirement",
                        case,
                        f"{scheme} / requirement {rid}",
                        False,
                        msg,
                        testname=rid,
                        detail=f"requirement {rid}: {msg}",
                        **common,
                    )
                )
                continue
            for r in recs:
                label = f"{rid} [{r.get('window_label')}]"
                msg = f"{r.get('label')} {r.get('bound')}: {r.get('outcome')}: {r.get('reason')}"
                items.append(
                    GateItem(
                        "requirement",
                        case,
                        f"{scheme} / requirement {label}",
                        r.get("outcome") == "holds",
                        msg,
                        testname=label,
                        detail=f"requirement {label}: {msg}",
                        **common,
                    )
                )
    return items


def _requirement_items(case: StoredCase) -> list[GateItem]:
    return requirement_items(case.name, case.record.get("requirements") or [], case.metrics())


# ------------------------------------------------------------------------------------------ the gate
#: The sources of a stored case's items, in the order they are shown.  Another kind of item is one
#: function ``(StoredCase) -> list[GateItem]`` appended here (and its count's words in SUMMARY).
CASE_ITEMS: list[Callable[[StoredCase], list[GateItem]]] = [run_items, threshold_items, claim_items, _requirement_items]

#: kind -> (words of its count line, shown even when there is none of the kind)
SUMMARY: dict[str, tuple[str, bool]] = {
    "run": ("runs end as the case expects", True),
    "threshold": ("thresholds hold", True),
    "claim": ("thesis claims have their expected outcome", False),
    "requirement": ("requirement windows hold", False),
    "baseline": ("runs match the baseline", False),
}


def case_items(case: StoredCase) -> list[GateItem]:
    """Every item of one stored case (:data:`CASE_ITEMS`)."""
    return [item for source in CASE_ITEMS for item in source(case)]


def error_items(case_errors: dict[str, str]) -> list[GateItem]:
    """One errored item per case file that could not be read or validated (bad input)."""
    return [
        GateItem("case file", path, "load", False, msg, classname=path, testname="load", detail=msg, error=True)
        for path, msg in case_errors.items()
    ]


def gate(
    out: Path,
    cases: Iterable[str],
    case_errors: dict[str, str] | None = None,
    not_stored: Iterable[tuple[str, str, str]] = (),
) -> list[GateItem]:
    """Every gate item of the cases stored under ``out``, then the case files in error.

    ``not_stored``: ``(case, scheme, why)`` of the runs this invocation could not store (the batch's).
    """
    missing: dict[str, dict[str, str]] = {}
    for c, s, why in not_stored:
        missing.setdefault(c, {})[s] = why
    items = [item for name in cases for item in case_items(stored_case(out, name, missing.get(name)))]
    return items + error_items(case_errors or {})


def exit_code(items: Iterable[GateItem]) -> int:
    """2 when a case file is bad input, else 1 when any item fails, else 0."""
    items = list(items)
    if any(i.error for i in items):
        return 2
    return 1 if any(not i.ok for i in items) else 0


def ungated(items: Iterable[GateItem]) -> list[str]:
    """A note per case the gate judges by its runs' outcomes alone (no threshold, claim, requirement or
    baseline item): its pass says only that the runs ended as expected."""
    kinds: dict[str, set[str]] = {}
    for i in items:
        if not i.error:
            kinds.setdefault(i.case, set()).add(i.kind)
    return [
        f"note: {case}: no thresholds, claims or requirements: only its runs' outcomes are gated"
        for case, k in kinds.items()
        if k <= {"run"}
    ]


def summary(items: Iterable[GateItem]) -> list[str]:
    """The count lines: ``3/4 thresholds hold`` per kind of :data:`SUMMARY` (others by their kind's name)."""
    items = [i for i in items if not i.error]
    kinds = list(SUMMARY) + [k for k in dict.fromkeys(i.kind for i in items) if k not in SUMMARY]
    lines = []
    for kind in kinds:
        mine = [i for i in items if i.kind == kind]
        words, always = SUMMARY.get(kind, (f"{kind} items hold", False))
        if mine or always:
            lines.append(f"{sum(i.ok for i in mine)}/{len(mine)} {words}")
    return lines
