r"""Monte Carlo fault campaigns: many drawn variants of a base case, run on Dask (issue 10).

base case + ``[campaign]`` distributions --draw(seeds(campaign seed, index))--> variant case
variant --run every scheme (runner.run_scheme)--> one row per scheme (metrics.json names)
rows --atomic per-sample files--> samples/<index>.json --atomic rewrite--> results.csv + results.parquet
results.csv --summarize--> success rates (Wilson intervals), distributions, worst patterns,
                           paired comparisons (McNemar, bootstrap; ftcreport.evaluation.stats) --> index.html
provenance --> manifest.json (ftcreport.storage.manifest: versions, platform, git, seeds, case hash)

Execution goes through ``dask.distributed`` (:mod:`ftcreport.studies.cluster`): by default a
``LocalCluster`` of processes on the loopback interface, or an existing scheduler
given by address; the same ``client.submit`` path serves both.  ``in_process=True``
runs the same sample function in this process (the reference the cluster run is
compared with).  Task keys derive from the campaign hash (base case content,
schemes, seed, package version) and the sample index, so two campaigns sharing a
scheduler cannot receive each other's samples; worker versions are checked
before anything is submitted.

Reproducible and resumable: sample ``i``'s seeds come from
``SeedSequence(campaign seed, spawn_key=(i,)).spawn(2)``: one child for the
draw of the variant, one for the sensor noise (independent streams, 63 bits
each), so a sample is the same wherever and whenever it runs.  Every finished
sample is written atomically to its own file, carrying the package version and
the campaign hash computed where it ran, sealed with the SHA-256 of its content;
a re-run skips the samples already there and refuses samples of another version
or another case content, or without a seal (``force`` re-runs them).  A file
that is unreadable, malformed or no longer matches its seal (edited by hand) is
no result: a note names it and the sample runs again.  A worker that dies loses only
its in-flight samples, which the scheduler resubmits (``retries``).  The table
``results.csv`` is rewritten atomically from the sample files, so an
interruption never leaves it half-written.

The drawing and the summary are pure; files and the cluster are at the edge
(:func:`run_campaign`).
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..cases import Case, configured_schemes, ordered_schemes, parse_case, plugin_digest, plugin_digests
from ..errors import CaseError, FtcError
from ..evaluation.stats import compare_metric, compare_success, min_pairs, wilson_interval
from ..model import pattern_is_compensable, wheel_index, wheel_names
from ..runs import STATUS_DIVERGED, STATUS_OK, STATUS_SINGULAR
from ..storage.store import _jsonable, _seal, locked, read_json, write_atomic

__all__ = [
    "PAGES",
    "CampaignResult",
    "SampleSeeds",
    "campaign_hash",
    "case_content_hash",
    "comparisons",
    "completed",
    "draw_variant",
    "read_table",
    "run_campaign",
    "run_hash",
    "run_sample",
    "sample_seeds",
    "stored_table",
    "summarize",
    "task_key",
    "wilson_interval",
    "write_parquet",
    "write_table",
]

#: times drawn for one fault before a sample is refused: a drawn time that meets a kept fault on its wheel is
#: drawn again (:func:`draw_variant`); validation refuses the one-instant fault_time where it always would
MAX_REDRAWS = 1000
PAGES = "sample_pages"  # <campaign>/sample_pages/sample-00017/index.html (ftcreport.report.campaign)
LEAD_COLUMNS = (
    "sample",
    "scheme",
    "draw_seed",
    "noise_seed",
    "version",
    "status",
    "success",
    "faulted_wheels",
    "failed_wheels",
    "compensable",
    "n_faults",
)


# ---------------------------------------------------------------------- drawing (pure)
@dataclass(frozen=True)
class SampleSeeds:
    """The two seeds of one sample: the variant's draw and the sensor noise (independent streams)."""

    draw: int
    noise: int


def _int63(ss: np.random.SeedSequence) -> int:
    # 63 bits: a non-negative int64 (typed Parquet column), 2**63 values
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


def sample_seeds(campaign_seed: int, index: int) -> SampleSeeds:
    """Seeds of sample ``index``: ``SeedSequence(campaign_seed, spawn_key=(index,)).spawn(2)`` -> (draw, noise)."""
    if int(campaign_seed) < 0:
        raise FtcError(f"--seed: must be >= 0, got {campaign_seed}")
    draw, noise = np.random.SeedSequence(int(campaign_seed), spawn_key=(int(index),)).spawn(2)
    return SampleSeeds(_int63(draw), _int63(noise))


def case_content_hash(base: Case) -> str:
    """Hash (16 hex digits) of a case's validated content (campaign table included, its name excluded)."""
    blob = base.model_dump_json(exclude={"name"}) + plugin_digest(base)  # a changed scheme file is a changed case
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def run_hash(kind: str, content: dict, version: str = __version__, code: dict | None = None) -> str:
    """Hash (20 hex digits) of a run's whole content: base case, schemes, settings, package version, and the
    package's code and numeric libraries (``code``, by default this process's :func:`identity`)."""
    code = identity() if code is None else code
    blob = {"kind": kind, "content": content, "version": version, **code}
    return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()[:20]


def identity() -> dict:
    """What computes a record here, besides the package version: the package's code digest (``code``) and the
    numeric libraries' versions (``versions``), as the case-result cache key has them
    (:func:`ftcreport.studies.batch.code_identity`).  Every stored record carries its process's."""
    from .batch import code_identity

    return code_identity()


def expected_identity(case_hash: str, rhash: str) -> dict:
    """What a stored record of the run ``rhash`` on a base case of content ``case_hash`` must say it is
    (:func:`stale_reason`): this package version, code and numeric libraries."""
    return {"version": __version__, **identity(), "case_hash": case_hash, "campaign": rhash}


def task_key(kind: str, rhash: str, index: int) -> str:
    """The Dask key of task ``index`` of run ``rhash``: unique to what it computes (issue 22).

    The old rule ``sample-{seed}-{i}`` was the same for two campaigns on one seed, and the
    scheduler hands a second client the result already held under a key.
    """
    return f"ftcreport-{kind}-{rhash}-{int(index)}"


def campaign_hash(
    base: Case, schemes: list[str], seed: int, version: str = __version__, code: dict | None = None
) -> str:
    """The campaign's identity: base case content, schemes, seed, package version, code and numeric libraries
    (task keys, records)."""
    content = {"case": case_content_hash(base), "schemes": list(schemes), "seed": int(seed)}
    return run_hash("campaign", content, version, code)


def draw_variant(base: Case, seeds: SampleSeeds) -> Case:
    """A variant of ``base`` drawn from its ``[campaign]`` distributions with ``seeds.draw``.

    The variant's sensor noise is seeded with ``seeds.noise`` (a separate child of the
    sample's seed sequence: the draws and the noise never share a stream).
    """
    spec = base.campaign
    if spec is None:
        raise CaseError(f"{base.name}: no [campaign] table: nothing to draw")
    rng = np.random.default_rng(seeds.draw)
    n = base.robots.n
    data = json.loads(base.model_dump_json())
    data.pop("campaign", None)
    wheels = wheel_names(n) if spec.wheels == "any" else [w.strip().lower() for w in spec.wheels]
    lo_n, hi_n = spec.faults
    k = int(rng.integers(lo_n, hi_n + 1))
    k = min(k, len(wheels))
    chosen = rng.choice(len(wheels), size=k, replace=False)
    t_lo, t_hi = spec.fault_time
    faults = [] if not spec.keep_base_faults else list(data["faults"])
    # a kept event on the drawn wheel at the drawn time (to the ms) would make a variant that cannot run
    # (a second event on that wheel at that time): the time is drawn again (validation refuses a
    # fault_time of one instant where that is certain); samples without the coincidence draw as before
    taken = {(f["time"], wheel_index(f["wheel"], n)) for f in faults}
    for j in chosen:
        t = float(np.round(rng.uniform(t_lo, t_hi), 3))
        for _ in range(MAX_REDRAWS):
            if (t, wheel_index(wheels[j], n)) not in taken:
                break
            t = float(np.round(rng.uniform(t_lo, t_hi), 3))
        else:
            raise CaseError(
                f"{base.name}: campaign.fault_time [{t_lo:g}, {t_hi:g}]: every time drawn on wheel {wheels[j]} "
                "meets a kept fault there (keep_base_faults); widen fault_time"
            )
        sigma = float(rng.uniform(*spec.sigma))
        ubar = float(rng.uniform(*spec.ubar)) if rng.random() < spec.friction_probability else 0.0
        faults.append({"time": t, "wheel": wheels[j], "sigma": sigma, "ubar": ubar})
    faults.sort(key=lambda f: f["time"])
    data["faults"] = faults
    ini = data["initial"]
    if spec.offset_position > 0:
        ini["x"] = ini["x"] + float(rng.uniform(-spec.offset_position, spec.offset_position))
        ini["y"] = ini["y"] + float(rng.uniform(-spec.offset_position, spec.offset_position))
    if spec.offset_heading_deg > 0:
        dh = float(rng.uniform(-spec.offset_heading_deg, spec.offset_heading_deg))
        if ini["mode"] == "offset":
            ini["heading_offset_deg"] = ini["heading_offset_deg"] + dh
        elif ini["headings_deg"] is not None:
            ini["headings_deg"] = [h + dh for h in ini["headings_deg"]]
    if spec.mismatch > 0:
        mm = data["plant"]["mismatch"]
        for key in ("m", "I"):
            mm[key] = float(1.0 + rng.uniform(-spec.mismatch, spec.mismatch))
    noise = data["plant"]["noise"]
    noise["position"] = float(rng.uniform(*spec.noise_position))
    noise["heading"] = float(rng.uniform(*spec.noise_heading))
    noise["seed"] = int(seeds.noise)
    data["name"] = f"{base.name[:40]}.s{seeds.draw}"  # a safe case name (ftcreport.infra.limits): at most 64 characters
    return parse_case(data, f"{base.name} (campaign draw, seed {seeds.draw})")


def _scalar_metrics(m: dict) -> dict:
    """The metrics that are one number, flag or word (a table cell each)."""
    return {k: v for k, v in m.items() if v is None or isinstance(v, bool | int | float | str)}


def _success(m: dict, criteria: dict) -> bool:
    """The run completed and every bound of ``criteria`` holds (a name ``a.b``: entry b of table metric a)."""
    if m.get("status") != "ok":
        return False
    for metric, bound in criteria.items():
        base, _, key = metric.partition(".")
        v = m.get(base)
        v = (v.get(key) if isinstance(v, dict) else None) if key else v
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return False
        if bound.get("min") is not None and v < bound["min"]:
            return False
        if bound.get("max") is not None and v > bound["max"]:
            return False
    return True


def run_sample(base_json: str, index: int, campaign_seed: int, schemes: list[str]) -> dict:
    """Draw sample ``index`` and run every scheme on it; the sample's record (rows per scheme).

    Runs in a Dask worker or in-process; pure apart from the simulation itself.  The record
    carries the package version and the campaign hash *of the process that ran it*, so the
    client can tell a foreign or stale result from its own.
    """
    from ..runner import build, run_scheme

    base = parse_case(json.loads(base_json), "campaign base")
    seeds = sample_seeds(campaign_seed, index)
    variant = draw_variant(base, seeds)
    criteria = {k: v.model_dump() for k, v in base.campaign.success.items()}
    sched = variant.fault_schedule()
    final = sched.pattern(variant.simulation.duration)
    names = wheel_names(variant.robots.n)
    failed = [w for w, s in zip(names, final, strict=True) if s == 0]
    sigma, ubar = sched.at(variant.simulation.duration)
    faulted = [w for w, g, f in zip(names, sigma, ubar, strict=True) if g < 1.0 or f != 0.0]
    common = {
        "sample": int(index),
        "draw_seed": seeds.draw,
        "noise_seed": seeds.noise,
        "version": __version__,
        "faulted_wheels": "+".join(faulted) if faulted else "none",
        "failed_wheels": "+".join(failed) if failed else "none",
        "compensable": bool(pattern_is_compensable(final)),
        "n_faults": len(variant.faults),
    }
    rows = []
    built = build(variant)
    for s in schemes:
        _, m = run_scheme(variant, s, built)
        row = common | {"scheme": s, "success": _success(m, criteria)} | _scalar_metrics(m)
        row.pop("case", None)
        rows.append(_jsonable(row))
    return {
        "sample": int(index),
        "version": __version__,
        **identity(),
        "case_hash": case_content_hash(base),
        "campaign": campaign_hash(base, schemes, campaign_seed),
        "campaign_seed": int(campaign_seed),
        "draw_seed": seeds.draw,
        "noise_seed": seeds.noise,
        "rows": rows,
        "faults": [f.model_dump() for f in variant.faults],
    }


# ---------------------------------------------------------------------- table (edge)
#: what a run's metrics say of the run itself rather than measure (runner.run_metrics): a run that stopped early
#: keeps these in the table; its measured metrics, which cover [0, t_end] only, are left empty there
RUN_FIELDS = frozenset({
    "case", "scheme", "n_robots", "reference_kind", "duration", "dt", "method", "package_version", "case_hash",
    "status", "reason", "t_end", "engine", "metric_samples", "wall_time", "compile_time",
})  # fmt: skip


def _table_row(row: dict) -> dict:
    """A sample record's row as the table shows it: a run that stopped early (:func:`completed`) without its
    measured metrics, whose values hold for the part it ran and would read as the run's in a column of full
    runs (a mean over ``position_error_rms`` mixing 12 s of a diverging run with 60 s runs); the sample's
    columns and the run's own fields (status, reason, t_end) stay.  The sealed record keeps every number."""
    if completed(row):
        return row
    return {k: (v if k in LEAD_COLUMNS or k in RUN_FIELDS else None) for k, v in row.items()}


def write_table(out: Path, records: Iterable[dict]) -> Path:
    """Rewrite ``results.csv`` and ``results.parquet`` atomically from sample records (by sample, then scheme);
    a run that stopped early without its measured metrics (:func:`_table_row`)."""
    rows = [_table_row(r) for rec in sorted(records, key=lambda r: r["sample"]) for r in rec["rows"]]
    keys = sorted({k for r in rows for k in r} - set(LEAD_COLUMNS))
    return write_rows(out, "results", rows, list(LEAD_COLUMNS) + keys)


def write_rows(out: Path, stem: str, rows: list[dict], cols: list[str]) -> Path:
    """``<stem>.csv`` (floats as repr, a missing value empty) and ``<stem>.parquet`` of ``rows``, atomically.

    Only the columns ``cols`` are written, in that order; returns the CSV's path.
    """
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (repr(r[k]) if isinstance(r[k], float) else r[k])) for k in cols})
    path = out / f"{stem}.csv"
    write_atomic(path, buf.getvalue().encode())
    write_parquet(out / f"{stem}.parquet", rows, cols)
    return path


def _column_type(values: list) -> str:
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return "boolean"
    if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return "Int64"
    if present and all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return "float64"
    return "string"


def write_parquet(path: Path, rows: list[dict], cols: list[str]) -> Path:
    """Write ``rows`` as a typed Parquet table (pandas + pyarrow) atomically.

    Each column's type comes from its values: booleans (nullable), 64-bit integers
    (nullable), floats (missing = NaN) or strings; an empty cell stays missing.
    """
    import pandas as pd

    data = {}
    for c in cols:
        values = [r.get(c) for r in rows]
        kind = _column_type(values)
        if kind == "float64":
            data[c] = pd.array([np.nan if v is None else float(v) for v in values], dtype="float64")
        elif kind == "string":
            data[c] = pd.array([None if v is None else str(v) for v in values], dtype="string")
        else:
            data[c] = pd.array(values, dtype=kind)
    buf = io.BytesIO()
    pd.DataFrame(data, columns=cols).to_parquet(buf, engine="pyarrow", index=False)
    write_atomic(path, buf.getvalue())
    return path


def _parse_cell(v: str):
    if v == "":
        return None
    if v in ("True", "False"):
        return v == "True"
    try:
        return int(v)
    except ValueError:
        pass
    try:
        return float(v)
    except ValueError:
        return v


def read_table(path: Path) -> list[dict]:
    """Rows of a campaign table with numbers, booleans and empty cells (None) parsed."""
    with open(path, newline="") as fh:
        return [{k: _parse_cell(v) for k, v in row.items()} for row in csv.DictReader(fh)]


# ---------------------------------------------------------------------- summary (pure)
#: Metrics compared pairwise between schemes (lower is better) and their units.
COMPARED_METRICS: dict[str, str] = {
    "position_error_final": "m",
    "position_error_max": "m",
    "recovery_time_max": "s",
}


#: The paired metric comparisons' confidence level; below ``min_pairs(CONFIDENCE)`` pairs they give no verdict.
CONFIDENCE = 0.95

#: Stops the closed loop causes (the state left the domain or reached a law's singular set, a smaller step
#: included): a failure of the scheme under the sample's faults, charged to its fault pattern.  The other
#: stops are not: ``step_unstable`` is the integrator's (the step, not the loop: a smaller step passes it)
#: and ``error`` the program's; neither says how the law copes with the pattern.
LOOP_STOPS = (STATUS_DIVERGED, STATUS_SINGULAR)


def completed(row: dict) -> bool:
    """The run reached the end of the horizon (status ok).  A run that stopped early (step_unstable, diverged,
    singular, error) has metrics over a truncated horizon (a final error at the stop, a recovery time of the
    faults before it, or 0 s with no fault reached): it is a failure, and its metrics are no sample of any
    distribution or paired comparison."""
    return row.get("status") == STATUS_OK


def _value(row: dict, metric: str) -> float | None:
    """A row's number for ``metric``, None when missing or when the run stopped early (:func:`completed`)."""
    v = row.get(metric)
    return v if completed(row) and isinstance(v, int | float) and not isinstance(v, bool) else None


def comparisons(rows: list[dict], schemes: list[str]) -> list[dict]:
    """Paired comparisons of every pair of schemes on the samples both ran (ftcreport.evaluation.stats).

    Success: exact McNemar (a stopped run is a failure).  Each metric of :data:`COMPARED_METRICS`:
    bootstrap CI of the mean per-sample difference on the samples where both values exist (a recovery
    time exists when the scheme recovered; no value exists for a run that stopped early, :func:`completed`).
    """
    by = {s: {r["sample"]: r for r in rows if r["scheme"] == s} for s in schemes}
    out = []
    for ia, a in enumerate(schemes):
        for b in schemes[ia + 1 :]:
            common = sorted(set(by[a]) & set(by[b]))
            if not common:
                continue
            ra, rb = [by[a][i] for i in common], [by[b][i] for i in common]
            out.append(compare_success(a, b, [bool(r["success"]) for r in ra], [bool(r["success"]) for r in rb]))
            for m, unit in COMPARED_METRICS.items():
                va = [_value(r, m) for r in ra]
                vb = [_value(r, m) for r in rb]
                out.append(compare_metric(a, b, m, va, vb, unit, CONFIDENCE))
    return out


def summarize(rows: list[dict]) -> dict:
    """Success rates with Wilson intervals, distributions, worst patterns, paired comparisons between schemes.

    A run that stopped early counts as a failure in the rates and nowhere else (:func:`completed`): the
    distributions hold the ``completed`` runs, ``stopped`` counts the others by status, and a scheme's
    fault pattern is charged with a stop only when the loop caused it (:data:`LOOP_STOPS`)."""
    schemes = ordered_schemes(r["scheme"] for r in rows)
    by = {s: [r for r in rows if r["scheme"] == s] for s in schemes}
    out: dict = {"n_samples": len({r["sample"] for r in rows}), "schemes": {}}
    success = {s: {r["sample"]: bool(r["success"]) for r in by[s]} for s in schemes}
    for s in schemes:
        rs = by[s]
        k = sum(bool(r["success"]) for r in rs)
        lo, hi = wilson_interval(k, len(rs))
        pats: dict[str, list[int]] = {}
        stopped: dict[str, int] = {}
        for r in rs:
            if not completed(r):
                stopped[str(r.get("status"))] = stopped.get(str(r.get("status")), 0) + 1
                if r.get("status") not in LOOP_STOPS:  # the step's or the program's: says nothing of the pattern
                    continue
            fail_ok = pats.setdefault(str(r["faulted_wheels"]), [0, 0])
            fail_ok[0] += 0 if r["success"] else 1
            fail_ok[1] += 1
        worst = sorted(pats.items(), key=lambda kv: (-kv[1][0], -kv[1][0] / kv[1][1], kv[0]))[:5]
        done = [r for r in rs if completed(r)]
        rec = [r.get("recovery_time_max") for r in done]
        err = [r.get("position_error_max") for r in done]
        entry = {
            "n": len(rs),
            "successes": k,
            "rate": k / len(rs) if rs else None,
            "wilson_low": lo,
            "wilson_high": hi,
            "completed": len(done),
            "stopped": dict(sorted(stopped.items())),
            "recovery_times": [float(v) for v in rec if isinstance(v, int | float)],
            "recovery_never": sum(not isinstance(v, int | float) for v in rec),
            "max_errors": [float(v) for v in err if isinstance(v, int | float)],
            "worst_patterns": [{"faulted_wheels": p, "failures": f, "samples": n} for p, (f, n) in worst if f > 0],
        }
        for base in _reference_lines():  # the baseline and the bound (nominal, the oracle: the registry's)
            if base in success and base != s:
                common = set(success[s]) & set(success[base])
                entry[f"vs_{base}"] = {
                    "samples": len(common),
                    "better": sum(success[s][i] and not success[base][i] for i in common),
                    "worse": sum(success[base][i] and not success[s][i] for i in common),
                }
        out["schemes"][s] = entry
    out["comparisons"] = comparisons(rows, schemes)
    out["min_pairs"] = min_pairs(CONFIDENCE)  # the page says how many pairs a metric verdict needs
    return out


# ---------------------------------------------------------------------- execution (edge)
@dataclass
class CampaignResult:
    out: Path
    table: Path
    requested: int
    skipped: int = 0
    completed: list[int] = field(default_factory=list)
    failed: dict[int, str] = field(default_factory=dict)
    wall_time: float = 0.0
    rerun_stale: int = 0
    workers: dict = field(default_factory=dict)
    beyond: int = 0  # stored samples of this campaign beyond ``requested``: kept, not reported


#: The types a stored value may have (JSON's: a boolean is no number, null is None)
NUMBER = (int, float)
SCALAR = (str, int, float, bool, type(None))
_TYPE_WORDS = {
    bool: "a boolean",
    int: "an integer",
    float: "a number",
    str: "a text",
    list: "a list",
    dict: "a table",
    type(None): "null",
}


def _typed(value: object, allowed: tuple[type, ...]) -> bool:
    """``isinstance(value, allowed)``, where a boolean is only a boolean (JSON's true is not the number 1)."""
    return bool in allowed if isinstance(value, bool) else isinstance(value, allowed)


def _described(value: object) -> str:
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, int | float):
        return f"the number {value!r}"
    if isinstance(value, str):
        return f"the text {value[:40]!r}"
    return _TYPE_WORDS.get(type(value), type(value).__name__)


def _field_problem(name: str, table: dict, allowed: tuple[type, ...]) -> str | None:
    if name not in table:
        return f"{name}: missing"
    if not _typed(table[name], allowed):
        kinds = [t for t in allowed if not (t is int and float in allowed)]  # an integer is a number
        words = " or ".join(_TYPE_WORDS[t] for t in kinds)
        return f"{name}: {_described(table[name])}, not {words}"
    return None


def record_problem(
    rec: object,
    fields: dict[str, tuple[type, ...]],
    row_fields: dict[str, tuple[type, ...]] | None = None,
    row_other: Callable[[str], tuple[type, ...]] = lambda name: SCALAR,
) -> str | None:
    """The first field of a stored record that is missing or of another type, as ``field: why``; None when
    the record is well formed.  ``fields``: the record's fields and their types; ``row_fields``: those of
    every entry of its ``rows`` (a non-empty list of tables), whose other entries have the types
    ``row_other(name)``."""
    if not isinstance(rec, dict):
        return f"not a record: {_described(rec)}"
    for name, allowed in fields.items():
        if (why := _field_problem(name, rec, allowed)) is not None:
            return why
    if row_fields is None:
        return None
    if (why := _field_problem("rows", rec, (list,))) is not None:
        return why
    if not rec["rows"]:
        return "rows: empty"
    for j, row in enumerate(rec["rows"]):
        if not isinstance(row, dict):
            return f"rows[{j}]: {_described(row)}, not a table"
        for name in [*row_fields, *(k for k in row if k not in row_fields)]:
            allowed = row_fields.get(name) or row_other(name)
            if (why := _field_problem(name, row, allowed)) is not None:
                return f"rows[{j}].{why}"
    return None


#: A stored sample's fields (:func:`run_sample`) and those of each of its rows; a row's other entries are
#: metrics: a number (or null) where :data:`ftcreport.evaluation.metrics.METRICS` says so, else one value
SAMPLE_FIELDS: dict[str, tuple[type, ...]] = {  # its identity (version, case_hash, campaign): stale_reason's
    "sample": (int,),
    "campaign_seed": (int,),
    "draw_seed": (int,),
    "noise_seed": (int,),
    "faults": (list,),
}
ROW_FIELDS: dict[str, tuple[type, ...]] = {
    "sample": (int,),
    "scheme": (str,),
    "draw_seed": (int,),
    "noise_seed": (int,),
    "version": (str,),
    "status": (str,),
    "success": (bool,),
    "faulted_wheels": (str,),
    "failed_wheels": (str,),
    "compensable": (bool,),
    "n_faults": (int,),
}


def metric_types(name: str) -> tuple[type, ...]:
    """The types a row's metric ``name`` may have: a number or null for a numeric metric, else one value."""
    from ..evaluation.metrics import METRICS

    m = METRICS.get(name)
    return (*NUMBER, type(None)) if m is not None and m.kind == "number" else SCALAR


def sample_problem(rec: object) -> str | None:
    """What is malformed in a stored sample record (``field: why``), or None."""
    why = record_problem(rec, SAMPLE_FIELDS, ROW_FIELDS, metric_types)
    if why is None:
        for j, row in enumerate(rec["rows"]):
            if row["sample"] != rec["sample"]:
                return f"rows[{j}].sample: {row['sample']}, the record's sample is {rec['sample']}"
    return why


def stale_reason(rec: dict, expected: dict) -> str | None:
    """Why a stored record cannot join this run (another version, code of the package, numeric library, case
    content or settings), or None."""
    if rec.get("version") is None:
        return "records no package version (written before versions were recorded)"
    if rec["version"] != expected["version"]:
        return f"was computed by ftcreport {rec['version']}, this is {expected['version']}"
    if "code" in expected:  # the package's own sources: a fix (or a bug) in a law, a metric, the success rule
        if rec.get("code") is None:
            return "records no code digest (written before ftcreport recorded the code that computed a result)"
        if rec["code"] != expected["code"]:
            return (
                f"was computed by other code of ftcreport {rec['version']} (code digest {rec['code']}, now "
                f"{expected['code']}: a source file of the package changed)"
            )
    if "versions" in expected and rec.get("versions") != expected["versions"]:
        was = rec.get("versions") if isinstance(rec.get("versions"), dict) else {}
        moved = [f"{k} {was.get(k)}, now {v}" for k, v in expected["versions"].items() if was.get(k) != v]
        return f"was computed with {'; '.join(moved) or 'other numeric libraries'}"
    if "case_hash" in expected and rec.get("case_hash") != expected["case_hash"]:
        return f"comes from another base case content (hash {rec.get('case_hash')}, now {expected['case_hash']})"
    if rec.get("campaign") != expected["campaign"]:
        return f"belongs to another run (hash {rec.get('campaign')}, now {expected['campaign']})"
    return None


def _reference_lines() -> tuple[str, ...]:
    """The built-in schemes every other is compared with: the baseline (no FTC) and the bound (the oracle)."""
    from ..schemes import built_in

    return tuple(name for name, sc in built_in().items() if sc.family in ("baseline", "bound"))


def select_schemes(base: Case, schemes: list[str] | None) -> list[str]:
    """The schemes to run: ``schemes`` (all configured in ``base`` when None); an unknown or unconfigured
    one is refused, blamed on the ``--schemes`` option (:func:`ftcreport.cases.option_schemes`)."""
    from ..cases import option_schemes

    return configured_schemes(base) if schemes is None else option_schemes("--schemes", list(schemes), base)


def load_records(
    folder: Path,
    expected: dict,
    force: bool,
    what: str = "sample",
    check: Callable[[object], str | None] | None = None,
    then: str = "runs again",
) -> tuple[dict[int, dict], int]:
    """Stored records under ``folder`` that belong to this run; refuses stale ones unless ``force``.

    With ``force`` the stale files are deleted (their tasks run again); returns (records, stale count).
    A corrupt, partial or malformed file (its index ``what`` is not its file's, or ``check(rec)`` names
    a field of a record of this run) counts as not done: a note on stderr names the file and the field,
    and its task runs again (``then``: what the note says happens to it).
    """
    got: dict[int, dict] = {}
    stale = 0
    for p in sorted(folder.glob("*.json")):
        try:
            rec = json.loads(p.read_bytes())
        except (OSError, ValueError) as exc:
            _not_done(p, f"unreadable ({str(exc)[:120]})", what, then)
            continue
        if (why := _index_problem(p, rec, what)) is not None:
            _not_done(p, why, what, then)
            continue
        index = rec[what]
        why = stale_reason(rec, expected) or _unsealed(rec)
        if why is None:  # this run's, by what it says it is: its content is checked, then its seal
            why = (check(rec) if check is not None else None) or _seal_problem(rec)
            if why is not None:
                _not_done(p, why, what, then)
            else:
                got[index] = rec
            continue
        if not force:
            raise FtcError(
                f"{p}: {why}; results of two versions or cases must not mix: "
                "choose another --out, or re-run them with --force"
            )
        p.unlink(missing_ok=True)
        stale += 1
    return got, stale


def _index_problem(p: Path, rec: object, what: str) -> str | None:
    """A record whose index is not a non-negative integer, or not its file's (a copied file), is malformed."""
    if not isinstance(rec, dict):
        return f"not a record: {_described(rec)}"
    if (why := _field_problem(what, rec, (int,))) is not None:
        return why
    if rec[what] < 0:
        return f"{what}: {rec[what]}, not an index"
    if p.stem.isdigit() and int(p.stem) != rec[what]:
        return f"{what}: {rec[what]}, the file's name says {int(p.stem)}"
    return None


def seal(rec: dict) -> dict:
    """``rec`` as stored: JSON values, sealed with the SHA-256 of its content (``sha256``), as the case-result
    store seals a run's record (:func:`ftcreport.storage.store.save_run`): an edited record no longer matches."""
    body = _jsonable({k: v for k, v in rec.items() if k != "sha256"})
    return body | {"sha256": _seal(body)}


def _unsealed(rec: dict) -> str | None:
    """A record without a seal is refused as stale (never taken as a result: dropping the seal must not pass
    an edit off as an old record); --force runs it again."""
    if isinstance(rec.get("sha256"), str):
        return None
    return "carries no seal (sha256): written before ftcreport sealed its records, or the seal was removed"


def _seal_problem(rec: dict) -> str | None:
    if _seal({k: v for k, v in rec.items() if k != "sha256"}) == rec["sha256"]:
        return None
    return "hash mismatch (its content differs from the SHA-256 it was sealed with: changed after the run)"


def _not_done(p: Path, why: str, what: str, then: str = "runs again") -> None:
    from .batch import _note

    _note(f"ftcreport: note: {p}: {why}; not a stored result: the {what} counts as not done and {then}")


@locked("campaign")
def run_campaign(
    base: Case,
    samples: int,
    out: Path,
    seed: int = 0,
    schemes: list[str] | None = None,
    scheduler: str | None = None,
    workers: int = 2,
    in_process: bool = False,
    show_progress: bool = True,
    retries: int = 2,
    on_sample: Callable[[int], None] | None = None,
    table_every: float = 2.0,
    force: bool = False,
) -> CampaignResult:
    """Run (or resume) a campaign of ``samples`` samples; results under ``out``.

    ``scheduler``: address of an existing Dask scheduler; otherwise a LocalCluster
    of ``workers`` processes on 127.0.0.1 (or this process when ``in_process``).
    ``results.csv`` and ``results.parquet`` are rewritten (atomically) at most every
    ``table_every`` seconds while samples finish, and once at the end; the per-sample
    files are written at once.  Stored samples of another package version, case
    content or campaign settings are refused, or with ``force`` run again.  The table,
    summary and manifest hold samples ``0 .. samples - 1`` only, as a fresh campaign of
    ``samples`` would: samples a larger run stored stay on disk (``res.beyond``), unreported.
    """
    if base.campaign is None:
        raise CaseError(f"{base.name}: no [campaign] table: add the distributions to draw from (cases/README.md)")
    if samples < 1:
        raise FtcError(f"--samples: must be >= 1, got {samples}")
    if seed < 0:
        raise FtcError(f"--seed: must be >= 0, got {seed}")
    schemes = select_schemes(base, schemes)
    out = Path(out)
    (out / "samples").mkdir(parents=True, exist_ok=True)
    chash = campaign_hash(base, schemes, seed)
    expected = expected_identity(case_content_hash(base), chash)
    meta = {
        "case": base.name,
        "seed": int(seed),
        "schemes": schemes,
        "version": __version__,
        "code": expected["code"],
        "versions": expected["versions"],
        "case_hash": expected["case_hash"],
        "plugin_files": plugin_digests(base),  # which scheme file changed, when 'sample' finds the hash differs
        "campaign": chash,
        "base": json.loads(base.model_dump_json()),
    }
    meta_path = out / "campaign.json"
    old: dict = {}
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding="utf-8"))
            old.get("seed")
        except (ValueError, AttributeError) as exc:
            if not force:
                why = f"damaged ({str(exc)[:120]}); remove it to start over, or choose another --out"
                raise FtcError(f"{meta_path}: {why}") from None
            old = {}
    if meta_path.exists() and not force:
        if old.get("seed") != meta["seed"] or old.get("schemes") != schemes or old.get("base") != meta["base"]:
            raise FtcError(
                f"{out}: holds a campaign with another seed, scheme list or base case; "
                "choose another --out (or --force to replace it)"
            )
        if old.get("version") != __version__:
            raise FtcError(
                f"{meta_path}: campaign started by ftcreport {old.get('version') or '(unrecorded version)'}, "
                f"this is {__version__}; choose another --out, or re-run its samples with --force"
            )
    records, stale = load_records(
        out / "samples", expected, force, check=sample_problem
    )  # refused: nothing in out changed yet
    # a campaign of n samples reports samples 0..n-1, whatever a larger run left here; those beyond stay stored
    beyond = sum(i >= samples for i in records)
    records = {i: r for i, r in records.items() if i < samples}
    with _noting_stored(lambda: len(records), "sample"):  # an interrupt from here counts what is stored
        if old.get("campaign") != chash:  # pages rendered from another content or settings: never linked as current
            _remove_pages(out / PAGES)
        write_atomic(meta_path, json.dumps(meta, indent=1).encode())
        todo = [i for i in range(samples) if i not in records]
        res = CampaignResult(out=out, table=out / "results.csv", requested=samples, skipped=samples - len(todo))
        res.rerun_stale, res.beyond = stale, beyond
        base_json = base.model_dump_json()
        _write_manifest(out, base, expected, seed, schemes, samples, records, res, scheduler, workers, in_process)
        write_table(out, records.values())  # the stored samples' table (and pandas loaded before samples arrive)
        wall0 = time.perf_counter()

        last_table = [0.0]

        def stored(rec: dict) -> None:
            # the table is a view of the sample files: refreshed at most every table_every seconds
            if time.perf_counter() - last_table[0] >= table_every:
                write_table(out, records.values())
                last_table[0] = time.perf_counter()
            if on_sample is not None:
                on_sample(rec["sample"])

        run_tasks(
            run_sample,
            {i: (base_json, i, int(seed), schemes) for i in todo},
            "campaign",
            expected,
            out / "samples",
            "sample",
            8,
            records,
            res,
            show_progress,
            on_store=stored,
            scheduler=scheduler,
            workers=workers,
            in_process=in_process,
            retries=retries,
        )
        write_table(out, records.values())
        if res.failed:
            write_atomic(out / "failed.json", json.dumps(res.failed, indent=1).encode())
        res.wall_time = time.perf_counter() - wall0
        _write_manifest(out, base, expected, seed, schemes, samples, records, res, scheduler, workers, in_process)
    return res


def stored_table(out: Path) -> Path:
    """Rewrite the table of the campaign in ``out`` from its sealed sample records (the first ``--samples`` of
    its manifest, as :func:`run_campaign` reports them) and return its path: the table is a view of the
    records, and a page rendered after the campaign (``ftcreport sample``) must not read an edited view.

    A record that is not this campaign's (another version, code or content), or no longer matches its seal,
    is left out with a note, as a campaign counts it as not done.
    """
    out = Path(out)
    meta = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
    expected = expected_identity(str(meta.get("case_hash")), str(meta.get("campaign")))
    records, _ = load_records(out / "samples", expected, False, check=sample_problem, then="left out of the table")
    manifest = read_json(out / "manifest.json")
    settings = manifest.get("settings") if isinstance(manifest, dict) else None
    n = settings.get("samples") if isinstance(settings, dict) else None
    if isinstance(n, int) and not isinstance(n, bool):
        records = {i: r for i, r in records.items() if i < n}
    return write_table(out, records.values())


def _remove_pages(pages: Path) -> None:
    """Remove the sample pages under ``pages`` (a symbolic link there: the link, never what it names)."""
    import shutil

    if pages.is_symlink() or pages.is_file():
        pages.unlink()
    elif pages.is_dir():
        shutil.rmtree(pages)


def run_tasks(
    func: Callable[..., dict],
    args: dict[int, tuple],
    kind: str,
    expected: dict,
    folder: Path,
    what: str,
    width: int,
    records: dict[int, dict],
    res: CampaignResult,
    show_progress: bool = True,
    on_store: Callable[[dict], None] | None = None,
    **cluster,
) -> None:
    """Run ``func(*args[i])`` for every task ``i`` (:func:`ftcreport.studies.cluster.execute`) behind a progress bar.

    Task keys come from ``kind`` and the run hash ``expected["campaign"]`` (:func:`task_key`).  A result
    must belong to this run (:func:`stale_reason` against ``expected``); it is written atomically at once
    to ``folder/<rec[what]>.json`` (the index with ``width`` digits), entered in ``records`` and
    ``res.completed``, then handed to ``on_store``, sealed (:func:`seal`: :func:`load_records` takes no
    record whose content no longer matches); a failed task's message goes to ``res.failed``.
    ``cluster``: the keywords of :func:`ftcreport.studies.cluster.execute` (scheduler, workers, in_process, retries).
    """
    from .cluster import execute

    def store(rec: dict) -> None:
        why = stale_reason(rec, expected)
        if why is not None:  # never store a result that is not this run's (a foreign key, a stale worker)
            raise ValueError(f"result {why}")
        index = rec[what]
        rec = seal(rec)
        write_atomic(folder / f"{index:0{width}d}.json", json.dumps(rec).encode())
        records[index] = rec
        res.completed.append(index)
        if on_store is not None:
            on_store(rec)

    with _progress(show_progress, len(args), kind) as bar, _noting_stored(lambda: len(records), what):
        info = execute(
            func,
            args,
            {i: task_key(kind, expected["campaign"], i) for i in args},
            store,
            res.failed.__setitem__,
            tick=lambda: bar(len(res.completed), len(res.failed)),
            noun=UNITS.get(kind, "tasks"),
            **cluster,
        )
    res.workers = info["workers"]


@contextlib.contextmanager
def _noting_stored(count: Callable[[], int], noun: str):
    """An interrupt inside says how many finished tasks are stored, ``count()``: this run's and the ones
    an earlier run stored (the CLI's interrupt message)."""
    try:
        yield
    except KeyboardInterrupt as exc:
        from ..errors import note_stored

        note_stored(exc, count(), noun)
        raise


def _write_manifest(out, base, expected, seed, schemes, samples, records, res, scheduler, workers, in_process) -> None:
    from ..storage.manifest import build_manifest, write_manifest

    m = build_manifest(
        "campaign",
        cases={str(base.name): expected["case_hash"]},
        campaign=expected["campaign"],
        seeds={
            "campaign": int(seed),
            "rule": "SeedSequence(campaign, spawn_key=(sample,)).spawn(2) -> draw, noise (63 bits each)",
            "samples": {
                str(i): {"draw": r.get("draw_seed"), "noise": r.get("noise_seed")} for i, r in sorted(records.items())
            },
        },
        settings={
            "samples": int(samples),
            "schemes": list(schemes),
            "scheduler": scheduler,
            "workers": None if scheduler else int(workers),
            "in_process": bool(in_process),
        },
        workers=res.workers,
        result={
            "stored": len(records),
            "completed_now": len(res.completed),
            "skipped": res.skipped,
            "rerun_stale": res.rerun_stale,
            "failed": {str(k): v for k, v in res.failed.items()},
            "wall_time": res.wall_time,
        },
    )
    write_manifest(out / "manifest.json", m)


#: What a progress bar counts, by the kind of run (``run_tasks``'s ``kind``).
UNITS = {"campaign": "samples", "coverage": "fault onsets", "fdi": "traces"}


@contextlib.contextmanager
def _progress(show: bool, total: int, kind: str = "campaign") -> Iterator[Callable[[int, int], None]]:
    """A rich progress bar named after ``kind`` (campaign, coverage, fdi) with tasks done / failed / rate
    (or nothing); yields ``update(done, failed)``."""
    if not show:
        yield lambda done, failed: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn(kind), BarColumn(), MofNCompleteColumn(), TextColumn("failed {task.fields[failed]}"))
    rate_column = TextColumn(f"{{task.fields[rate]:.1f}} {UNITS.get(kind, 'tasks')}/min")
    with Progress(*columns, rate_column, TimeElapsedColumn()) as bar:
        task = bar.add_task("run", total=total, failed=0, rate=0.0)
        t0 = time.perf_counter()

        def update(done: int, failed: int) -> None:
            rate = 60.0 * (done + failed) / max(time.perf_counter() - t0, 1e-9)
            bar.update(task, completed=done + failed, failed=failed, rate=rate)

        yield update
