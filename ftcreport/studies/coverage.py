r"""Fault-coverage map: which faults does each scheme survive (issue 22).

base case --fault set x onset times--> items (one fault pattern at one onset)
item --run every scheme (runner.run_scheme)--> rows: recovered, recovery time, final error
rows --per scheme and fault--> table + heatmaps (wheels x fault kinds) beside the prediction
of the redundancy rule (2.103): a pattern is compensable when a leader wheel and at least
two wheels still work (``ftcreport.model.pattern_is_compensable``).

The fault set of an n-robot chain: every single-wheel loss (sigma = 0), every pair of
wheel losses, partial losses (sigma in a small set) and a friction per wheel (sigma = 1,
``ubar`` = ``friction``).  Each runs at several onset times chosen along the reference's
curvature (:func:`onset_times`).  One definition of recovery for the table and the map:
a run *recovers* when it completes and meets the case's ``[campaign]`` success criteria
(default: final position error <= 0.05 m); its *recovery time* is the time from the onset
until the position error enters the success bound on the final error (:func:`recovery_bound`,
0.05 m by default) and stays in it to the end, so a run that completes within that bound
always has one (without such a bound: the case's recovery band).

Execution, resumption and provenance are the campaign's (:mod:`ftcreport.studies.campaign`,
:mod:`ftcreport.studies.cluster`): Dask keys from a hash of the content, one atomic file per
item carrying the version, stale items refused unless ``force``, ``manifest.json``.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..cases import Case, ordered_schemes, parse_case
from ..errors import FtcError
from ..evaluation.metrics import recovery_time, tracking_errors
from ..model import pattern_is_compensable, wheel_names
from ..storage.store import _jsonable, locked, write_atomic
from .campaign import (
    CampaignResult,
    _scalar_metrics,
    _success,
    case_content_hash,
    expected_identity,
    identity,
    load_records,
    run_hash,
    run_tasks,
    select_schemes,
    write_rows,
)

__all__ = [
    "FAULT_KINDS",
    "CoverageFault",
    "CoverageResult",
    "fault_set",
    "onset_times",
    "plan_coverage",
    "predicted_compensable",
    "run_coverage",
    "run_item",
    "summarize_coverage",
]

FAULT_KINDS = ("loss", "pair", "partial", "friction")
DEFAULT_CRITERIA = {"position_error_final": {"min": None, "max": 0.05}}
COLUMNS = (
    "item",
    "scheme",
    "kind",
    "column",
    "wheels",
    "sigma",
    "ubar",
    "onset",
    "predicted_compensable",
    "status",
    "recovered",
    "recovery_time",
    "recovery_bound",
    "final_error",
    "max_error",
    "version",
)


@dataclass(frozen=True)
class CoverageFault:
    """One fault pattern: ``wheels`` get effectiveness ``sigma`` and friction ``ubar``."""

    kind: str  # loss | pair | partial | friction
    wheels: tuple[str, ...]
    sigma: float = 0.0
    ubar: float = 0.0

    @property
    def column(self) -> str:
        """Its column in the wheels x kinds map (pairs have their own wheel x wheel map)."""
        if self.kind == "partial":
            return f"sigma={self.sigma:g}"
        return self.kind

    @property
    def label(self) -> str:
        extra = {"partial": f" sigma={self.sigma:g}", "friction": f" ubar={self.ubar:g}"}.get(self.kind, "")
        return f"{self.kind} {'+'.join(self.wheels)}{extra}"


def fault_set(
    n: int, sigmas: tuple[float, ...] = (0.25, 0.5), friction: float = 0.5, kinds: tuple[str, ...] = FAULT_KINDS
) -> list[CoverageFault]:
    """Single losses, pairs of losses, partial losses (``sigmas``) and a friction per wheel.

    Each setting is checked here, blamed on its option, so that a map is never of nothing (no kind, or
    partial losses without a gain: zero runs and exit 0) nor of faults no case may hold (a friction the
    case schema refuses: every run a CaseError, the command's error on no line of its own)."""
    bad = [k for k in kinds if k not in FAULT_KINDS]
    if bad:
        raise FtcError(f"--kinds: unknown {bad} (choose from {', '.join(FAULT_KINDS)})")
    if not kinds:
        raise FtcError(f"--kinds: names no fault kind; give one or more of {', '.join(FAULT_KINDS)}, comma-separated")
    if any(not 0.0 < s < 1.0 for s in sigmas):
        raise FtcError(f"--sigmas: partial losses need 0 < sigma < 1, got {list(sigmas)}")
    if "partial" in kinds and not sigmas:
        raise FtcError("--sigmas: names no gain for the partial losses; give one or more in (0, 1), comma-separated")
    _check_friction(friction, "friction" in kinds)
    w = wheel_names(n)
    out: list[CoverageFault] = []
    if "loss" in kinds:
        out += [CoverageFault("loss", (x,)) for x in w]
    if "pair" in kinds:
        out += [CoverageFault("pair", p) for p in itertools.combinations(w, 2)]
    if "partial" in kinds:
        out += [CoverageFault("partial", (x,), float(s)) for s in sigmas for x in w]
    if "friction" in kinds:
        out += [CoverageFault("friction", (x,), 1.0, float(friction)) for x in w]
    return out


def _friction_range() -> tuple[float, float]:
    """The range of a case fault's friction ``ubar`` [N m], read from the case schema (``cases.tables.Fault``),
    so that ``--friction`` accepts what a case file does and no more."""
    from ..cases.tables import Fault

    bounds = {type(m).__name__: m for m in Fault.model_fields["ubar"].metadata}
    return float(bounds["Ge"].ge), float(bounds["Le"].le)


def _check_friction(friction: float, used: bool) -> None:
    """``--friction``: a finite torque in the case schema's range (a NaN or inf one is no fault a case holds);
    nonzero when friction faults are run (sigma 1 with ubar 0 changes no wheel: every scheme would 'survive'
    it).  A bad value is refused even when unused: it is stored in the map's settings and hash."""
    lo, hi = _friction_range()
    if not (math.isfinite(friction) and lo <= friction <= hi):
        raise FtcError(
            f"--friction: must be a finite torque in [{lo:g}, {hi:g}] N m (a fault's ubar), got {friction:g}"
        )
    if used and friction == 0.0:
        raise FtcError(
            f"--friction: a friction of 0 N m changes no wheel; give a nonzero torque in [{lo:g}, {hi:g}] N m "
            "(a fault's ubar)"
        )


def plan_coverage(
    base: Case,
    times: list[float] | None = None,
    sigmas: tuple[float, ...] = (0.25, 0.5),
    friction: float = 0.5,
    kinds: tuple[str, ...] = FAULT_KINDS,
    onsets: int = 3,
) -> tuple[list[float], list[CoverageFault]]:
    """The onset times and the fault set of a map, every option checked (FtcError naming it): the command
    calls it before it makes the output directory, :func:`run_coverage` again (the API's callers too)."""
    T = base.simulation.duration
    times = onset_times(base, onsets) if times is None else [float(t) for t in times]
    if not times or any(not 0.0 <= t < T for t in times):
        raise FtcError(f"--times: onset times must lie in [0, {T:g}) s (the case's duration), got {times}")
    return times, fault_set(base.robots.n, tuple(sigmas), friction, tuple(kinds))


def predicted_compensable(n: int, fault: CoverageFault) -> bool:
    """The redundancy rule (2.103) on the pattern the fault leaves (a wheel works while sigma > 0)."""
    names = wheel_names(n)
    pattern = [0.0 if (w in fault.wheels and fault.sigma == 0.0) else 1.0 for w in names]
    return bool(pattern_is_compensable(pattern))


def _curvature(path, t: float) -> float:
    X, Y = path.jets(t, 2)
    dx, dy, ddx, ddy = X[1], Y[1], 2.0 * X[2], 2.0 * Y[2]
    sp = math.hypot(dx, dy)
    return float((dx * ddy - dy * ddx) / sp**3) if sp > 1e-12 else 0.0


def onset_times(base: Case, count: int = 3, window: tuple[float, float] = (0.2, 0.5)) -> list[float]:
    """``count`` onset times in ``window`` x duration spread along the reference's curvature.

    The times where the path's curvature reaches its quantiles 0, 1/(count-1), ..., 1 over
    the window (its smallest, middle, largest values for 3); evenly spaced when the
    curvature is constant (circle, line, unicycle), rounded to the step.
    """
    if count < 1:
        raise FtcError(f"--onsets: must be >= 1, got {count}")
    T, dt = base.simulation.duration, base.simulation.dt
    lo, hi = window[0] * T, window[1] * T
    grid = np.linspace(lo, hi, 201)
    path = base.reference.path()
    kappa = np.array([_curvature(path, t) for t in grid])
    if np.ptp(kappa) <= 1e-6 * max(1.0, float(np.max(np.abs(kappa)))):
        times = np.linspace(lo, hi, count)
    else:
        targets = np.quantile(kappa, np.linspace(0.0, 1.0, count))
        chosen: list[float] = []
        for k in targets:
            order = np.argsort(np.abs(kappa - k))
            t = next(float(grid[j]) for j in order if all(abs(grid[j] - c) > 2 * dt for c in chosen))
            chosen.append(t)
        times = np.sort(np.array(chosen))
    return [float(np.round(np.round(t / dt) * dt, 6)) for t in times]


def _variant(base: Case, fault: CoverageFault, onset: float) -> Case:
    data = json.loads(base.model_dump_json())
    data.pop("campaign", None)
    data["faults"] = [{"time": onset, "wheel": w, "sigma": fault.sigma, "ubar": fault.ubar} for w in fault.wheels]
    # a safe case name (ftcreport.infra.limits: [A-Za-z0-9][A-Za-z0-9_.-]{0,63}); the label stays in the table
    slug = f"{fault.kind}-{'-'.join(fault.wheels)}-{fault.sigma:g}-{fault.ubar:g}-t{onset:g}"
    data["name"] = f"{base.name[:24]}.{slug}"[:64]
    return parse_case(data, f"{base.name} (coverage {fault.label} at {onset:g} s)")


def run_item(base_json: str, index: int, fault: dict, onset: float, schemes: list[str], rhash: str) -> dict:
    """Run every scheme on one fault at one onset; the item's record (rows per scheme).

    Runs in a Dask worker or in-process.  ``rhash`` is the coverage run's hash, recomputed
    by the client on resume; the record carries the version of the process that ran it.
    """
    from ..runner import build, run_scheme

    base = parse_case(json.loads(base_json), "coverage base")
    f = CoverageFault(fault["kind"], tuple(fault["wheels"]), fault["sigma"], fault["ubar"])
    case = _variant(base, f, onset)
    criteria = (
        {k: v.model_dump() for k, v in base.campaign.success.items()} if base.campaign is not None else DEFAULT_CRITERIA
    )
    predicted = predicted_compensable(base.robots.n, f)
    built = build(case)
    band = recovery_bound(criteria, base.recovery_band)
    rows = []
    for s in schemes:
        run, m = run_scheme(case, s, built)
        sm = _scalar_metrics(m)
        t, S = (run.t_stream, run.stream) if run.stream else (run.t, run.signals)
        rec_time = None
        if m.get("status") == "ok" and t.size > 1:
            pos = tracking_errors(S["q"], S["q_d"])[0]
            rec_time = recovery_time(t, pos, float(onset), float(t[-1]), band)
        rows.append(
            _jsonable(
                {
                    "item": int(index),
                    "scheme": s,
                    "kind": f.kind,
                    "column": f.column,
                    "wheels": "+".join(f.wheels),
                    "sigma": f.sigma,
                    "ubar": f.ubar,
                    "onset": float(onset),
                    "predicted_compensable": predicted,
                    "status": m.get("status"),
                    "recovered": _success(m, criteria),
                    "recovery_time": rec_time,
                    "recovery_bound": band,
                    "final_error": sm.get("position_error_final"),
                    "max_error": sm.get("position_error_max"),
                    "version": __version__,
                }
            )
        )
    return {
        "item": int(index),
        "version": __version__,
        **identity(),
        "case_hash": case_content_hash(base),
        "campaign": rhash,
        "fault": asdict(f),
        "onset": float(onset),
        "rows": rows,
    }


def recovery_bound(criteria: dict, band: float) -> float:
    """The position error [m] a recovered run settles within: the success criteria's bound on the
    final position error (so "recovered" and "recovery time" agree), else the case's recovery band."""
    b = (criteria.get("position_error_final") or {}).get("max")
    return float(b) if b is not None else float(band)


# ---------------------------------------------------------------------- summary (pure)
def summarize_coverage(rows: list[dict]) -> dict:
    """Per scheme and fault: onsets recovered, recovery times, final errors; agreement with the rule.

    ``agreement``: per scheme, the faults whose outcome (recovered at every onset) equals the
    prediction, and the lists of disagreements both ways.
    """
    schemes = ordered_schemes(r["scheme"] for r in rows)
    out: dict = {"schemes": {}, "n_items": len({r["item"] for r in rows})}
    for s in schemes:
        faults: dict[str, dict] = {}
        for r in sorted((r for r in rows if r["scheme"] == s), key=lambda r: (r["item"], r["onset"])):
            key = f"{r['kind']} {r['wheels']}" + (f" sigma={r['sigma']:g}" if r["kind"] == "partial" else "")
            e = faults.setdefault(
                key,
                {
                    "kind": r["kind"],
                    "column": r["column"],
                    "wheels": r["wheels"],
                    "predicted_compensable": bool(r["predicted_compensable"]),
                    "onsets": [],
                    "recovered": [],
                    "recovery_time": [],
                    "final_error": [],
                },
            )
            e["onsets"].append(r["onset"])
            e["recovered"].append(bool(r["recovered"]))
            e["recovery_time"].append(r["recovery_time"])
            e["final_error"].append(r["final_error"])
        for e in faults.values():
            e["recovered_fraction"] = sum(e["recovered"]) / len(e["recovered"])
            # over the onsets recovered: the count says how many did not
            rt = [
                v for v, ok in zip(e["recovery_time"], e["recovered"], strict=True) if ok and isinstance(v, int | float)
            ]
            fe = [v for v in e["final_error"] if isinstance(v, int | float)]
            e["recovery_time_max"] = max(rt) if rt else None
            e["final_error_max"] = max(fe) if fe else None
        agree = [k for k, e in faults.items() if all(e["recovered"]) == e["predicted_compensable"]]
        out["schemes"][s] = {
            "faults": faults,
            "agree": len(agree),
            "n_faults": len(faults),
            "lost_but_compensable": [
                k for k, e in faults.items() if e["predicted_compensable"] and not all(e["recovered"])
            ],
            "recovered_but_uncompensable": [
                k for k, e in faults.items() if not e["predicted_compensable"] and any(e["recovered"])
            ],
        }
    return out


# ---------------------------------------------------------------------- execution (edge)
@dataclass
class CoverageResult(CampaignResult):
    """A campaign's result plus the fault onset times used."""

    times: list[float] = field(default_factory=list)


@locked("coverage")
def run_coverage(
    base: Case,
    out: Path,
    times: list[float] | None = None,
    schemes: list[str] | None = None,
    sigmas: tuple[float, ...] = (0.25, 0.5),
    friction: float = 0.5,
    kinds: tuple[str, ...] = FAULT_KINDS,
    onsets: int = 3,
    scheduler: str | None = None,
    workers: int = 2,
    in_process: bool = False,
    show_progress: bool = True,
    retries: int = 2,
    force: bool = False,
) -> CoverageResult:
    """Run (or resume) the coverage map of ``base``: every fault of :func:`fault_set` at every onset time.

    ``times`` overrides :func:`onset_times` (``onsets`` of them).  Results under ``out``:
    ``items/<index>.json``, ``coverage.csv`` + ``coverage.parquet``, ``summary.json``,
    ``manifest.json``; the page is :func:`ftcreport.report.coverage.render_coverage`.
    """
    schemes = select_schemes(base, schemes)
    times, faults = plan_coverage(base, times, sigmas, friction, kinds, onsets)
    items = [(f, t) for f in faults for t in times]
    out = Path(out)
    (out / "items").mkdir(parents=True, exist_ok=True)
    settings = {"schemes": schemes, "sigmas": list(sigmas), "friction": friction, "kinds": list(kinds), "times": times}
    chash = case_content_hash(base)
    rhash = run_hash("coverage", {"case": chash, **settings})
    expected = expected_identity(chash, rhash)
    records, stale = load_records(out / "items", expected, force, what="item")
    todo = [i for i in range(len(items)) if i not in records]
    res = CoverageResult(
        out=out, table=out / "coverage.csv", requested=len(items), skipped=len(items) - len(todo), times=times
    )
    res.rerun_stale = stale
    base_json = base.model_dump_json()
    wall0 = time.perf_counter()
    run_tasks(
        run_item,
        {i: (base_json, i, asdict(items[i][0]), items[i][1], schemes, rhash) for i in todo},
        "coverage",
        expected,
        out / "items",
        "item",
        6,
        records,
        res,
        show_progress,
        scheduler=scheduler,
        workers=workers,
        in_process=in_process,
        retries=retries,
    )
    rows = [r for i in sorted(records) if i < len(items) for r in records[i]["rows"]]
    write_table(out, rows)
    summary = summarize_coverage(rows)
    write_atomic(out / "summary.json", json.dumps(_jsonable(summary), indent=1).encode())
    if res.failed:
        write_atomic(out / "failed.json", json.dumps(res.failed, indent=1).encode())
    res.wall_time = time.perf_counter() - wall0
    from ..storage.manifest import build_manifest, write_manifest

    meta = {"case": base.name, "n": base.robots.n, "base": json.loads(base_json), **settings, "hash": rhash}
    write_atomic(out / "coverage.json", json.dumps(meta, indent=1).encode())
    write_manifest(
        out / "manifest.json",
        build_manifest(
            "coverage",
            cases={str(base.name): chash},
            coverage=rhash,
            seeds={"noise": base.plant.noise.seed, "note": "no random draws: the fault set is enumerated"},
            settings=settings | {"scheduler": scheduler, "in_process": in_process},
            workers=res.workers,
            result={"items": len(items), "stored": len(records), "failed": {str(k): v for k, v in res.failed.items()}},
        ),
    )
    return res


def write_table(out: Path, rows: list[dict]) -> Path:
    """``coverage.csv`` and ``coverage.parquet`` (one row per item and scheme), atomically."""
    return write_rows(out, "coverage", rows, list(COLUMNS))
