r"""Baselines across commits (issue 35 item 10): save a run's headline metrics and key signals, compare later.

``ftcreport baseline save CASES --dest DIR`` stores, per case and scheme, the headline metrics and a
compact copy of the key signals of the stored runs (running what is missing), with their provenance;
``ftcreport check CASES --baseline DIR`` compares the current runs with it.  The criteria are those
of Simulink Test's baseline tests (MathWorks, "Set Signal Tolerances" and "How the Simulation Data
Inspector Compares Data"): a value passes when

    |new - baseline| <= max(abs_tol, rel_tol * |baseline|)

and a signal passes when it stays, at every instant, inside that band drawn around the baseline
signal, the band widened in time by a leading tolerance (the new signal may run that much ahead:
new(t) = baseline(t + d), 0 <= d <= leading_tol) and a lagging one (new(t) = baseline(t - d)),
that is between the smallest lower and the largest upper bound of the baseline over
[t - lagging_tol, t + leading_tol].

**Defaults** (:data:`BASELINE_REL_TOL`, :data:`BASELINE_ABS_TOL`): rel_tol = 1e-3 and abs_tol = 1e-9
(in each metric's or signal's own unit), no time tolerance.  An unchanged method reproduces its
numbers to round-off (the golden windows hold q and eta to 1e-9 absolute, tests/test_golden.py),
so these pass a commit that does not change the numerics and fail one that moves a headline
metric by more than 0.1 % (the issue's "+40 % against main" by a factor 400).  A case overrides
them in its ``[baseline]`` table, per metric (``[baseline.metrics.<name>]``) and per signal family
(``[baseline.signals.<name>]``): a run whose chatter makes its switch count round-off-chaotic
gives that metric its own tolerance there, with the reason in a comment.

**What is compared.** The metrics of :data:`COMPARED_METRICS` a run has (whole-run scalars of
``metrics.json``, computed from every step), its status, and the metrics a ``[baseline.metrics]``
table names; the signals of :func:`key_signals`: position error, the heading error of every robot
and the applied torque of every wheel.  A metric null in one run and not the other is a change.

**Compact signals.** Each signal is kept as its minimum and maximum over :data:`BINS` = 500 equal
intervals of the run (fewer for a shorter log), taken from the stored log: the envelope keeps every
logged spike however short (a uniform grid of 500 points would miss a 4,320 N m start-up spike that
lasts one step), costs 1,000 numbers per signal whatever the duration, and compares the same way
whatever ``log_every`` the new run logs at.  The price is resolution in time: within one interval
(duration / 500: 0.28 s for a 140 s run) a shift of the signal is not seen, so the effective time
tolerance is at least one interval.  The new run's envelope is taken over the baseline's intervals
and must lie inside the band of the interval (widened by the time tolerances): its maximum under
the largest upper bound, its minimum over the smallest lower bound.  Metrics, which read every
step, catch what happens between logged samples.

**Provenance.** Each case's entry holds the git revision and whether the checkout had uncommitted
changes, the package and numeric dependency versions, the case content hash and each run's cache
key, the case file's text as stored beside its runs and its validated fields (plug-in scheme files
by name and content hash), so that ``check`` can say *which* fields changed since the baseline:
a delta is read against the edit that explains it.  A changed case is still compared.

**Missing baseline.** A case or scheme the baseline does not hold fails ``check`` (exit 1) with a
line saying so and how to save it: a gate asked to compare must not pass what it could not
compare (as a baseline test without its baseline file fails in Simulink Test and pytest-regressions).

Layout of DIR::

    baseline.json                 {"format", "cases": {name: {created, git, case_hash}}}
    <case>/baseline.json          provenance, case text and fields, per scheme status and metrics
    <case>/signals.npz            per scheme and signal: "<scheme>|edges", "<scheme>|<signal>|lo", "|hi"

Every file is written atomically; a case's JSON last, naming the SHA-256 of its signals file.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cases import (
    BASELINE_ABS_TOL,
    BASELINE_METRIC_NAMES,
    BASELINE_REL_TOL,
    BASELINE_SIGNAL_FAMILIES,
    BaselineSpec,
    configured_schemes,
)
from ..evaluation.metrics import HEADLINE_METRICS
from .check import GateItem

__all__ = [
    "BASELINE_ABS_TOL",
    "BASELINE_METRIC_NAMES",
    "BASELINE_REL_TOL",
    "BASELINE_SIGNAL_FAMILIES",
    "BINS",
    "COMPARED_METRICS",
    "CaseComparison",
    "band",
    "baseline_items",
    "compare_case",
    "compare_metric",
    "compare_signal",
    "envelope",
    "field_diff",
    "key_signals",
    "save_baseline",
]

FORMAT = 1
BINS = 500
#: compared by default when the run has them (metrics.json names): every run's headline scalars
#: (metrics.HEADLINE_METRICS) but the after-fault peak (a baseline compares whole-run scalars; the whole
#: run's torque_peak is one), then the run's end and the scheme-specific ones
COMPARED_METRICS: tuple[str, ...] = (
    *(m for m in HEADLINE_METRICS if m != "torque_peak_after_fault"),
    "t_end",
    "switch_count",
    "switching_match_fraction",
    "detection_delay_max",
    "fault_estimation_error_final",
)
_UNITS = {
    "position_error_max": "m", "position_error_rms": "m", "position_error_final": "m", "position_error_iae": "m s",
    "heading_error_max": "rad", "heading_error_final": "rad", "recovery_time_max": "s", "torque_peak": "N m",
    "torque_rms": "N m", "energy": "J", "t_end": "s", "detection_delay_max": "s", "singularity_margin_min": "rad",
}  # fmt: skip


# ------------------------------------------------------------------------------ pure comparison
def key_signals(ts: Mapping[str, np.ndarray], wheels: list[str]) -> dict[str, np.ndarray]:
    """The compared signals of a logged run: position_error, heading_error[i] (robot i, leader 1), torque[w]."""
    from ..control.kinematic import wrap

    q, qd = np.asarray(ts["q"], float), np.asarray(ts["q_d"], float)
    out = {"position_error": np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])}
    head = np.abs(wrap(q[:, 2:] - qd[:, 2:]))  # last robot first
    n = head.shape[1]
    for i in range(1, n + 1):
        out[f"heading_error[{i}]"] = head[:, n - i]
    if "tau" in ts:
        tau = np.asarray(ts["tau"], float)
        for j, w in enumerate(wheels[: tau.shape[1]]):
            out[f"torque[{w}]"] = tau[:, j]
    return out


def family(signal: str) -> str:
    """``torque[1r]`` -> ``torque``."""
    return signal.split("[", 1)[0]


def edges_for(t: np.ndarray, bins: int = BINS) -> np.ndarray:
    """Equal intervals over the logged run: at most ``bins``, and no more than the log has samples."""
    t = np.asarray(t, float)
    nb = max(1, min(int(bins), t.size - 1))
    return np.linspace(float(t[0]), float(t[-1]), nb + 1)


def envelope(t: np.ndarray, y: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum and maximum of the finite samples in each interval (NaN where it has none).

    A sample on an interior edge belongs to the interval that starts there; the last edge closes the last.
    """
    t, y = np.asarray(t, float), np.asarray(y, float)
    nb = edges.size - 1
    lo, hi = np.full(nb, np.nan), np.full(nb, np.nan)
    slack = 1e-9 * max(1.0, abs(float(edges[-1])))
    keep = (t >= edges[0] - slack) & (t <= edges[-1] + slack) & np.isfinite(y)
    idx = np.clip(np.searchsorted(edges, t[keep], side="right") - 1, 0, nb - 1)
    np.fmin.at(lo, idx, y[keep])
    np.fmax.at(hi, idx, y[keep])
    return lo, hi


def tolerance(value: np.ndarray | float, rel_tol: float, abs_tol: float) -> np.ndarray | float:
    """max(abs_tol, rel_tol |value|) (Simulink's value tolerance)."""
    return np.maximum(abs_tol, rel_tol * np.abs(value))


def band(
    lo: np.ndarray,
    hi: np.ndarray,
    edges: np.ndarray,
    rel_tol: float,
    abs_tol: float,
    lead: float = 0.0,
    lag: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound per interval: the baseline's envelope widened by the value tolerance, then
    by the time tolerances (the extremes over every interval meeting [start - lag, end + lead])."""
    upper = hi + tolerance(hi, rel_tol, abs_tol)
    lower = lo - tolerance(lo, rel_tol, abs_tol)
    if lead <= 0 and lag <= 0:
        return lower, upper
    a, b = edges[:-1] - lag, edges[1:] + lead
    ja = np.searchsorted(edges[1:], a, side="right")  # first interval ending after a
    jb = np.searchsorted(edges[:-1], b, side="left") - 1  # last interval starting before b
    U, L = np.empty_like(upper), np.empty_like(lower)
    for i in range(upper.size):
        U[i] = np.fmax.reduce(upper[ja[i] : jb[i] + 1])
        L[i] = np.fmin.reduce(lower[ja[i] : jb[i] + 1])
    return L, U


@dataclass(frozen=True)
class SignalDelta:
    """A signal outside its band: where first, where worst, by how much."""

    signal: str
    unit: str
    bins_out: int
    bins_compared: int
    first_time: float
    worst_time: float
    worst_value: float
    band_lo: float
    band_hi: float
    excess: float
    note: str = ""  # a signal in one run only: why it is not compared

    def line(self) -> str:
        if self.note:
            return f"signal {self.signal}: {self.note}"
        u = f" {self.unit}"
        return (
            f"signal {self.signal}: outside the band in {self.bins_out} of {self.bins_compared} intervals from "
            f"{self.first_time:.4g} s; worst at {self.worst_time:.4g} s: new {self.worst_value:.4g}{u}, band "
            f"[{self.band_lo:.4g}, {self.band_hi:.4g}]{u} (beyond by {self.excess:.3g}{u})"
        )


def _unmatched(signal: str, where: str) -> SignalDelta:
    """A signal in one run only (the chain's robots or wheels changed): a change, not compared."""
    nan = math.nan
    return SignalDelta(signal, "", 0, 0, nan, nan, nan, nan, nan, math.inf, f"{where} (the chain changed)")


def compare_signal(
    name: str,
    unit: str,
    edges: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    t_new: np.ndarray,
    y_new: np.ndarray,
    rel_tol: float,
    abs_tol: float,
    lead: float = 0.0,
    lag: float = 0.0,
) -> tuple[SignalDelta | None, dict]:
    """Compare a new logged signal with a baseline envelope on the baseline's intervals.

    Returns (the delta, None when inside the band; the arrays a figure draws: edges, band, new envelope).
    Intervals where either run has no sample (a run that stopped sooner) are not compared.
    """
    n_lo, n_hi = envelope(t_new, y_new, edges)
    L, U = band(lo, hi, edges, rel_tol, abs_tol, lead, lag)
    with np.errstate(invalid="ignore"):
        excess = np.fmax(n_hi - U, L - n_lo)
    compared = np.isfinite(n_hi) & np.isfinite(U)
    out = compared & (excess > 0)
    drawn = {"edges": edges, "lower": L, "upper": U, "base_lo": lo, "base_hi": hi, "new_lo": n_lo, "new_hi": n_hi}
    if not out.any():
        return None, drawn
    k = np.flatnonzero(out)
    w = k[np.argmax(excess[k])]
    above = n_hi[w] - U[w] >= L[w] - n_lo[w]
    delta = SignalDelta(
        name,
        unit,
        int(k.size),
        int(compared.sum()),
        float(edges[k[0]]),
        float(0.5 * (edges[w] + edges[w + 1])),
        float(n_hi[w] if above else n_lo[w]),
        float(L[w]),
        float(U[w]),
        float(excess[w]),
    )
    return delta, drawn


@dataclass(frozen=True)
class MetricDelta:
    """One metric of one run against its baseline value."""

    metric: str
    old: Any
    new: Any
    tol: float | None
    ok: bool

    @property
    def delta(self) -> float | None:
        if _number(self.old) and _number(self.new):
            return float(self.new) - float(self.old)
        return None

    def line(self) -> str:
        unit = _UNITS.get(self.metric, "")
        u = f" {unit}" if unit else ""
        old, new = _show(self.old), _show(self.new)
        d = self.delta
        if d is None:
            return f"{self.metric}: baseline {old}, new {new} (no numeric delta)"
        rel = f" ({100 * d / abs(float(self.old)):+.3g} %)" if _number(self.old) and float(self.old) != 0 else ""
        tol = f"; tolerance {self.tol:.3g}{u}" if self.tol is not None else ""
        return f"{self.metric}: baseline {old}{u}, new {new}{u}, delta {d:+.4g}{u}{rel}{tol}"


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _show(x: Any) -> str:
    if x is None:
        return "null"
    if _number(x):
        return f"{x:.6g}"
    return str(x)


def compare_metric(name: str, old: Any, new: Any, rel_tol: float, abs_tol: float) -> MetricDelta:
    """|new - old| <= max(abs_tol, rel_tol |old|); both null is equal, one null is a change."""
    if old is None and new is None:
        return MetricDelta(name, old, new, None, True)
    if not (_number(old) and _number(new)):
        return MetricDelta(name, old, new, None, old == new)
    tol = float(tolerance(float(old), rel_tol, abs_tol))
    return MetricDelta(name, old, new, tol, abs(float(new) - float(old)) <= tol)


def field_diff(old: Any, new: Any, path: str = "") -> list[str]:
    """Where two validated case dicts differ: ``schemes.switching.k_v: 3000.0 -> 2000.0`` per field."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in list(dict.fromkeys([*old, *new])):
            p = f"{path}.{k}" if path else str(k)
            if k not in old:
                out.append(f"{p}: added ({_short(new[k])})")
            elif k not in new:
                out.append(f"{p}: removed (was {_short(old[k])})")
            else:
                out += field_diff(old[k], new[k], p)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        out = []
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            out += field_diff(a, b, f"{path}[{i}]")
        return out
    if old != new:
        return [f"{path}: {_short(old)} -> {_short(new)}"]
    return []


def _short(v: Any, limit: int = 80) -> str:
    text = json.dumps(v, default=str)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ------------------------------------------------------------------------------------ case inputs
def case_fields(case) -> dict:
    """The validated case as plain data, plug-in files as {file name: content hash} (not their paths)."""
    data = case.model_dump(mode="json")
    data["plugins"] = {Path(p).name: _file_hash(Path(p)) for p in case.plugins}
    return data


def _file_hash(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    except OSError:
        return "unreadable"


def stored_case(out: Path, name: str):
    """(the case as stored beside its runs, its text, its record); raises FtcError when unreadable or changed
    after its runs (storage.store.load_stored_case)."""
    from ..storage.store import load_stored_case, read_json

    rec = read_json(Path(out) / name / "case.json")
    rec = rec if isinstance(rec, dict) else {}
    case = load_stored_case(out, name, rec)  # damaged, or edited after its runs: FtcError naming the file
    return case, (Path(out) / name / "case.toml").read_text(encoding="utf-8"), rec


def _spec(case):
    """The case's [baseline] table, or the defaults."""
    return case.baseline if case.baseline is not None else BaselineSpec()


def _tols(spec, table: str, name: str) -> tuple[float, float, float, float, bool]:
    """(rel_tol, abs_tol, leading, lagging, ignore) of one metric or signal family."""
    own = getattr(spec, table).get(name)

    def pick(k: str):
        return getattr(own, k) if own is not None and getattr(own, k) is not None else getattr(spec, k)

    return pick("rel_tol"), pick("abs_tol"), pick("leading_tol"), pick("lagging_tol"), bool(own and own.ignore)


def scalar_metrics(m: Mapping[str, Any]) -> dict[str, Any]:
    """The whole-run scalar metrics of a metrics.json (numbers and nulls of the known names)."""
    return {k: m.get(k) for k in BASELINE_METRIC_NAMES if k in m and (m.get(k) is None or _number(m.get(k)))}


# --------------------------------------------------------------------------------------- saving
def save_baseline(out: Path, names: Iterable[str], dest: Path) -> list[tuple[str, str]]:
    """Store the baseline of each named case (its stored runs under ``out``) in ``dest``.

    Returns the (case, reason) pairs not saved: a case whose runs ended with a status the case
    does not expect (a failure is never kept as the reference), or that has no stored run.
    """
    from ..model.faults import wheel_names
    from ..storage.manifest import environment, numeric_versions
    from ..storage.store import check_run, load_timeseries, read_json, write_atomic, write_json

    out, dest = Path(out), Path(dest)
    refused: list[tuple[str, str]] = []
    env = environment()
    created = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    for name in names:
        case, text, rec = stored_case(out, name)
        schemes = configured_schemes(case)
        stored = {s: check_run(out, name, s) for s in schemes}  # the record checked against its files
        metrics = {s: r.metrics if r.sound else None for s, r in stored.items()}
        bad = [
            f"{s} {'not run' if r.absent else ('damaged: ' + r.problem) if not r.sound else r.metrics.get('status')}"
            for s, r in stored.items()
            if not r.sound or r.metrics.get("status") not in case.expected_for(s)
        ]
        if bad:
            refused.append((name, f"runs that did not end as the case expects: {', '.join(bad)}"))
            continue
        wheels = list(wheel_names(case.robots.n))
        arrays: dict[str, np.ndarray] = {}
        entry: dict[str, Any] = {}
        for s, m in metrics.items():
            sig_names: list[str] = []
            ts = load_timeseries(out, name, s)
            if ts is not None and ts.get("t") is not None and ts["t"].size > 1:
                edges = edges_for(ts["t"])
                arrays[f"{s}|edges"] = edges
                for sig, y in key_signals(ts, wheels).items():
                    lo, hi = envelope(ts["t"], y, edges)
                    arrays[f"{s}|{sig}|lo"], arrays[f"{s}|{sig}|hi"] = lo, hi
                    sig_names.append(sig)
            entry[s] = {
                "status": m.get("status"),
                "reason": m.get("reason", ""),
                "key": (stored[s].record or {}).get("key"),
                "metrics": scalar_metrics(m),
                "signals": sig_names,
            }
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        blob = buf.getvalue()
        write_atomic(dest / name / "signals.npz", blob)
        record = {
            "format": FORMAT,
            "case": name,
            "created": created,
            "ftcreport": env["ftcreport"],
            "versions": numeric_versions(),
            "case_hash": rec.get("key"),
            "source": rec.get("source"),
            "case_text": text,
            "case_fields": case_fields(case),
            "bins": BINS,
            "signals_sha256": hashlib.sha256(blob).hexdigest(),
            "schemes": entry,
        }
        write_json(dest / name / "baseline.json", record)
        index = read_json(dest / "baseline.json")
        index = index if isinstance(index, dict) and isinstance(index.get("cases"), dict) else {"cases": {}}
        index["format"] = FORMAT
        index["cases"][name] = {"created": created, "git": env["ftcreport"]["git"], "case_hash": rec.get("key")}
        write_json(dest / "baseline.json", index)
    return refused


# ------------------------------------------------------------------------------------ comparing
@dataclass
class SchemeComparison:
    """One scheme of one case against its baseline."""

    scheme: str
    missing: str = ""  # why there is nothing to compare ('' when compared)
    status: tuple[str | None, str | None] = (None, None)  # (baseline, new)
    metrics: list[MetricDelta] = field(default_factory=list)
    signals: list[SignalDelta] = field(default_factory=list)
    signals_compared: int = 0
    drawn: dict[str, dict] = field(default_factory=dict)  # signal -> arrays, for the differing ones

    @property
    def ok(self) -> bool:
        return (
            not self.missing
            and self.status[0] == self.status[1]
            and all(d.ok for d in self.metrics)
            and not self.signals
        )


@dataclass
class CaseComparison:
    """One case against its baseline: its inputs' changes and every scheme."""

    case: str
    missing: str = ""
    created: str = ""
    git: dict | None = None
    changed: list[str] = field(default_factory=list)  # fields of the case that differ from the baseline's
    schemes: list[SchemeComparison] = field(default_factory=list)


def _load(dest: Path, name: str) -> tuple[dict | None, dict[str, np.ndarray] | None, str]:
    """(the case's baseline record, its signal arrays, why not) from ``dest``."""
    from ..storage.store import read_json

    rec = read_json(dest / name / "baseline.json")
    if not isinstance(rec, dict) or not isinstance(rec.get("schemes"), dict):
        saved = read_json(dest / "baseline.json") or {}
        listed = ", ".join(sorted(saved.get("cases") or {})) if isinstance(saved, dict) else ""
        return None, None, f"no baseline of case '{name}' in {dest} (it holds: {listed or 'none'})"
    damaged = _damaged(rec)
    if damaged:
        return None, None, f"{dest / name / 'baseline.json'}: damaged: {damaged} (save the baseline again)"
    try:
        blob = (dest / name / "signals.npz").read_bytes()
    except OSError:
        return rec, None, f"{dest / name / 'signals.npz'} is missing"
    if hashlib.sha256(blob).hexdigest() != rec.get("signals_sha256"):
        return rec, None, f"{dest / name / 'signals.npz'} is not the file its baseline.json names (damaged or mixed)"
    with np.load(io.BytesIO(blob)) as data:
        arrays = {k: data[k] for k in data.files}
    for s, old in rec["schemes"].items():  # every listed signal has its band (a name added by hand has not)
        for sig in old.get("signals", []):
            if f"{s}|edges" in arrays and not all(f"{s}|{sig}|{b}" in arrays for b in ("lo", "hi")):
                return (
                    None,
                    None,
                    f"{dest / name / 'baseline.json'}: damaged: schemes.{s}.signals names '{sig}', "
                    f"which {dest / name / 'signals.npz'} has no band of (save the baseline again)",
                )
    return rec, arrays, ""


def _damaged(rec: dict) -> str:
    """What of a baseline record :func:`compare_case` reads is not as :func:`save_baseline` wrote it ('' if all)."""
    tops = (("case_fields", dict, "a table"), ("created", str, "a text"), ("ftcreport", dict, "a table"))
    for key, kind, what in tops:
        if rec.get(key) is not None and not isinstance(rec[key], kind):
            return f"{key} is not {what}"
    git = (rec.get("ftcreport") or {}).get("git")
    if git is not None and not isinstance(git, dict):
        return "ftcreport.git is not a table"
    for s, old in rec["schemes"].items():
        if not isinstance(old, dict):
            return f"schemes.{s} is not a table"
        if not isinstance(old.get("metrics"), dict):
            return f"schemes.{s}.metrics is not a table"
        sig = old.get("signals", [])
        if not isinstance(sig, list) or not all(isinstance(v, str) for v in sig):
            return f"schemes.{s}.signals is not a list of names"
    return ""


def compare_case(out: Path, name: str, dest: Path) -> CaseComparison:
    """Compare the stored runs of one case under ``out`` with its baseline in ``dest``."""
    from ..model.faults import wheel_names
    from ..storage.store import load_metrics, load_timeseries

    out, dest = Path(out), Path(dest)
    case, _text, _rec = stored_case(out, name)
    base, arrays, why = _load(dest, name)
    cmp = CaseComparison(name)
    if base is None or arrays is None:
        cmp.missing = why
        cmp.schemes = [SchemeComparison(s, missing=why) for s in configured_schemes(case)]
        return cmp
    cmp.created, cmp.git = base.get("created", ""), (base.get("ftcreport") or {}).get("git")
    cmp.changed = field_diff(base.get("case_fields") or {}, case_fields(case))
    spec = _spec(case)
    wheels = list(wheel_names(case.robots.n))
    schemes = list(dict.fromkeys([*configured_schemes(case), *base["schemes"]]))
    for s in schemes:
        old = base["schemes"].get(s)
        m = load_metrics(out, name, s) if s in configured_schemes(case) else None
        if old is None:
            cmp.schemes.append(SchemeComparison(s, missing=f"the baseline has no run of {s} (saved {cmp.created})"))
            continue
        if m is None:
            cmp.schemes.append(SchemeComparison(s, missing=f"{s} is in the baseline but not run now"))
            continue
        sc = SchemeComparison(s, status=(old.get("status"), m.get("status")))
        now = scalar_metrics(m)
        for k in dict.fromkeys([*COMPARED_METRICS, *spec.metrics]):
            if k not in old["metrics"] and k not in now:
                continue
            rel, ab, _, _, ignore = _tols(spec, "metrics", k)
            if not ignore:
                sc.metrics.append(compare_metric(k, old["metrics"].get(k), now.get(k), rel, ab))
        ts = load_timeseries(out, name, s)
        if ts is not None and ts.get("t") is not None and ts["t"].size > 1 and f"{s}|edges" in arrays:
            edges = arrays[f"{s}|edges"]
            new = key_signals(ts, wheels)
            for sig in old.get("signals", []):
                rel, ab, lead, lag, ignore = _tols(spec, "signals", family(sig))
                if ignore:
                    continue
                if sig not in new:
                    sc.signals.append(_unmatched(sig, "in the baseline, not in the new run"))
                    continue
                unit = BASELINE_SIGNAL_FAMILIES.get(family(sig), "")
                delta, drawn = compare_signal(
                    sig,
                    unit,
                    edges,
                    arrays[f"{s}|{sig}|lo"],
                    arrays[f"{s}|{sig}|hi"],
                    ts["t"],
                    new[sig],
                    rel,
                    ab,
                    lead,
                    lag,
                )
                sc.signals_compared += 1
                if delta is not None:
                    sc.signals.append(delta)
                    sc.drawn[sig] = drawn
            for sig in (x for x in new if x not in old.get("signals", [])):
                sc.signals.append(_unmatched(sig, "in the new run, not in the baseline"))
        cmp.schemes.append(sc)
    return cmp


def _where(cmp: CaseComparison) -> str:
    git = cmp.git or {}
    rev = (git.get("revision") or "")[:10]
    dirty = " with uncommitted changes" if git.get("dirty") else ""
    return f"saved {cmp.created}" + (f" at git {rev}{dirty}" if rev else "")


def gate_items(cmp: CaseComparison) -> list[GateItem]:
    """A gate item per scheme: passed when status, metrics and signals are within tolerance.

    The message carries every delta; the details (terminal lines) one line per change, each naming
    the case, scheme, metric, baseline value, new value and delta, after a line saying which fields
    of the case changed since the baseline (when some did).
    """
    items = []
    inputs = (
        f"inputs changed since the baseline ({len(cmp.changed)} field(s)): "
        + "; ".join(cmp.changed[:12])
        + (f"; and {len(cmp.changed) - 12} more" if len(cmp.changed) > 12 else "")
        if cmp.changed
        else ""
    )
    for sc in cmp.schemes:
        head = f"{cmp.case} / {sc.scheme}"
        if sc.missing:
            msg = f"baseline missing: {sc.missing}"
            items.append(_item(cmp.case, sc.scheme, False, msg, (f"{head} / {msg}",)))
            continue
        changes = []
        if sc.status[0] != sc.status[1]:
            changes.append(f"status: baseline {sc.status[0]}, new {sc.status[1]}")
        changes += [d.line() for d in sc.metrics if not d.ok]
        changes += [d.line() for d in sc.signals]
        n_m, n_s = len(sc.metrics), sc.signals_compared
        if not changes:
            msg = f"within tolerance of the baseline ({_where(cmp)}): {n_m} metrics, {n_s} signals"
            items.append(_item(cmp.case, sc.scheme, True, msg + (f"; {inputs}" if inputs else ""), ()))
            continue
        msg = f"{len(changes)} change(s) beyond tolerance against the baseline ({_where(cmp)}): " + "; ".join(changes)
        if inputs:
            msg += f". {inputs}"
        lines = ([f"{head}: {inputs}"] if inputs else []) + [f"{head} / {c}" for c in changes]
        items.append(_item(cmp.case, sc.scheme, False, msg, tuple(lines)))
    return items


def _item(case: str, scheme: str, ok: bool, message: str, lines: tuple[str, ...]) -> GateItem:
    """The gate item of one scheme's comparison (``lines``: its findings, a terminal line each)."""
    return GateItem(
        "baseline",
        case,
        f"{scheme} / baseline",
        ok,
        message,
        schemes=(scheme,),
        field="--baseline",
        classname=f"{case}.{scheme}",
        testname="baseline",
        detail="\n".join(lines) or message,
        lines=lines,
    )


def baseline_items(out: Path, names: Iterable[str], dest: Path) -> tuple[list[GateItem], list[CaseComparison]]:
    """The gate items of ``check --baseline`` for these cases, and the comparisons (for the page)."""
    comparisons = [compare_case(out, n, dest) for n in names]
    return [i for c in comparisons for i in gate_items(c)], comparisons


def absent_items(
    dest: Path, names: Iterable[str], errors: Mapping[str, str], inputs: Iterable[Path]
) -> tuple[list[GateItem], list[str]]:
    """The baseline's cases that this check does not compare: (a failing gate item for each whose case file
    lay among the check's inputs, a directory holding it or the file itself, and is not checked now: its file
    deleted, moved or renamed as another case; the names of the others, outside the inputs: a check of a
    subset, named in a note).  A case whose file is still there but cannot be read is already an error of the
    batch (``errors``, by file) and is not counted twice.

    A missing scheme fails the comparison (:func:`compare_case`); a missing case must too, or deleting a
    regression's case file would pass the gate.
    """
    from ..storage.store import read_json

    index = read_json(Path(dest) / "baseline.json")
    saved = index.get("cases") if isinstance(index, dict) else None
    if not isinstance(saved, dict):
        return [], []
    now = set(names)
    roots = [Path(p).resolve() for p in inputs]
    failed = {Path(p).resolve() for p in errors}
    items, outside = [], []
    for name in sorted(saved):
        if name in now:
            continue
        rec = read_json(Path(dest) / name / "baseline.json")
        source = rec.get("source") if isinstance(rec, dict) else None
        where = Path(source).resolve() if isinstance(source, str) and source else None
        if where is None or not any(where == r or where.is_relative_to(r) for r in roots):
            outside.append(name)
            continue
        if where in failed:
            continue
        why = "deleted or moved" if not where.exists() else "now holds another case"
        msg = (
            f"baseline missing: {name} is in the baseline (its file {source}) but not checked now: the file is "
            f"{why}; save the baseline again if the case was retired on purpose"
        )
        items.append(_item(name, "*", False, msg, (f"{name} / {msg}",)))
    return items, outside


def check_dest(dest: Path) -> None:
    """Refuse a --baseline directory that holds no baseline at all (a mistyped path: exit 2)."""
    from ..errors import FtcError
    from ..storage.store import read_json

    if not (Path(dest) / "baseline.json").is_file() or not isinstance(read_json(Path(dest) / "baseline.json"), dict):
        raise FtcError(
            f"{dest}: --baseline: no baseline here (no readable baseline.json); "
            f"'ftcreport baseline save CASES --dest {dest}' writes one"
        )
