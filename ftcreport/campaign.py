r"""Monte Carlo fault campaigns: many drawn variants of a base case, run on Dask (issue 10).

base case + ``[campaign]`` distributions --draw(seed(campaign seed, index))--> variant case
variant --run every scheme (runner.run_scheme)--> one row per scheme (metrics.json names)
rows --atomic per-sample files--> samples/<index>.json --atomic rewrite--> results.csv
results.csv --summarize--> success rates (Wilson intervals), distributions, worst patterns --> index.html

Execution goes through ``dask.distributed``: by default a ``LocalCluster`` of
processes on the loopback interface, or an existing scheduler given by
address; the same ``client.submit`` path serves both.  ``in_process=True``
runs the same sample function in this process (the reference the cluster
run is compared with).

Reproducible and resumable: sample ``i``'s seed is derived from (campaign seed,
i) with ``numpy.random.SeedSequence``, so a sample is the same wherever and
whenever it runs; every finished sample is written atomically to its own file
and a re-run skips the samples already there.  A worker that dies loses only
its in-flight samples, which the scheduler resubmits (``retries``).  The table
``results.csv`` is rewritten atomically from the sample files, so an
interruption never leaves it half-written.

The drawing and the summary are pure; files and the cluster are at the edge
(:func:`run_campaign`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .cases import SCHEME_NAMES, Case, parse_case
from .errors import CaseError, FtcError
from .model import pattern_is_compensable, wheel_names
from .store import _jsonable, write_atomic

__all__ = [
    "CampaignResult",
    "draw_variant",
    "read_table",
    "run_campaign",
    "run_sample",
    "sample_seed",
    "summarize",
    "wilson_interval",
]

LEAD_COLUMNS = (
    "sample",
    "scheme",
    "seed",
    "status",
    "success",
    "faulted_wheels",
    "failed_wheels",
    "compensable",
    "n_faults",
)


# ---------------------------------------------------------------------- drawing (pure)
def sample_seed(campaign_seed: int, index: int) -> int:
    """The seed of sample ``index``: a pure function of (campaign seed, index)."""
    return int(np.random.SeedSequence(int(campaign_seed), spawn_key=(int(index),)).generate_state(1)[0])


def draw_variant(base: Case, seed: int) -> Case:
    """A variant of ``base`` drawn from its ``[campaign]`` distributions with generator ``seed``."""
    spec = base.campaign
    if spec is None:
        raise CaseError(f"{base.name}: no [campaign] table: nothing to draw")
    rng = np.random.default_rng(seed)
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
    for j in chosen:
        t = float(np.round(rng.uniform(t_lo, t_hi), 3))
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
    noise["seed"] = int(seed % (2**31))
    data["name"] = f"{base.name[:52]}.s{seed}"  # a safe case name (ftcreport.limits): at most 64 characters
    return parse_case(data, f"{base.name} (campaign draw, seed {seed})")


def _scalar_metrics(m: dict) -> dict:
    out = {}
    for k, v in m.items():
        if isinstance(v, bool) or v is None or isinstance(v, int | float | str):
            out[k] = v
    return out


def _success(m: dict, criteria: dict) -> bool:
    if m.get("status") != "ok":
        return False
    for metric, bound in criteria.items():
        v = m.get(metric)
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return False
        if bound.get("min") is not None and v < bound["min"]:
            return False
        if bound.get("max") is not None and v > bound["max"]:
            return False
    return True


def run_sample(base_json: str, index: int, seed: int, schemes: list[str]) -> dict:
    """Draw sample ``index`` and run every scheme on it; the sample's record (rows per scheme).

    Runs in a Dask worker or in-process; pure apart from the simulation itself.
    """
    from .runner import build, run_scheme

    base = parse_case(json.loads(base_json), "campaign base")
    variant = draw_variant(base, seed)
    criteria = {k: v.model_dump() for k, v in base.campaign.success.items()}
    sched = variant.fault_schedule()
    final = sched.pattern(variant.simulation.duration)
    names = wheel_names(variant.robots.n)
    failed = [w for w, s in zip(names, final, strict=True) if s == 0]
    sigma, ubar = sched.at(variant.simulation.duration)
    faulted = [w for w, g, f in zip(names, sigma, ubar, strict=True) if g < 1.0 or f != 0.0]
    common = {
        "sample": int(index),
        "seed": int(seed),
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
    return {"sample": int(index), "seed": int(seed), "rows": rows, "faults": [f.model_dump() for f in variant.faults]}


# ---------------------------------------------------------------------- table (edge)
def _sample_path(out: Path, index: int) -> Path:
    return out / "samples" / f"{index:08d}.json"


def done_samples(out: Path) -> dict[int, dict]:
    """Samples already stored under ``out`` (a corrupt or partial file counts as not done)."""
    got = {}
    for p in sorted((out / "samples").glob("*.json")):
        try:
            rec = json.loads(p.read_text())
            got[int(rec["sample"])] = rec
        except (OSError, ValueError, KeyError):
            continue
    return got


def write_table(out: Path, records: Iterable[dict]) -> Path:
    """Rewrite ``results.csv`` atomically from sample records (sorted by sample, then scheme order)."""
    rows = [r for rec in sorted(records, key=lambda r: r["sample"]) for r in rec["rows"]]
    keys = sorted({k for r in rows for k in r} - set(LEAD_COLUMNS))
    cols = list(LEAD_COLUMNS) + keys
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else (repr(r[k]) if isinstance(r[k], float) else r[k])) for k in cols})
    path = out / "results.csv"
    write_atomic(path, buf.getvalue().encode())
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
def wilson_interval(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); (0, 1) when n = 0."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact ends (round-off would leave 1 - 1e-16)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi


def summarize(rows: list[dict]) -> dict:
    """Success rates with Wilson intervals, distributions, worst patterns, comparison with the baselines."""
    schemes = [s for s in SCHEME_NAMES if any(r["scheme"] == s for r in rows)]
    by = {s: [r for r in rows if r["scheme"] == s] for s in schemes}
    out: dict = {"n_samples": len({r["sample"] for r in rows}), "schemes": {}}
    success = {s: {r["sample"]: bool(r["success"]) for r in by[s]} for s in schemes}
    for s in schemes:
        rs = by[s]
        k = sum(bool(r["success"]) for r in rs)
        lo, hi = wilson_interval(k, len(rs))
        pats: dict[str, list[int]] = {}
        for r in rs:
            fail_ok = pats.setdefault(str(r["faulted_wheels"]), [0, 0])
            fail_ok[0] += 0 if r["success"] else 1
            fail_ok[1] += 1
        worst = sorted(pats.items(), key=lambda kv: (-kv[1][0], -kv[1][0] / kv[1][1], kv[0]))[:5]
        rec = [r.get("recovery_time_max") for r in rs]
        err = [r.get("position_error_max") for r in rs]
        entry = {
            "n": len(rs),
            "successes": k,
            "rate": k / len(rs) if rs else None,
            "wilson_low": lo,
            "wilson_high": hi,
            "recovery_times": [float(v) for v in rec if isinstance(v, int | float)],
            "recovery_never": sum(not isinstance(v, int | float) for v in rec),
            "max_errors": [float(v) for v in err if isinstance(v, int | float)],
            "worst_patterns": [{"faulted_wheels": p, "failures": f, "samples": n} for p, (f, n) in worst if f > 0],
        }
        for base in ("nominal", "oracle"):
            if base in success and base != s:
                common = set(success[s]) & set(success[base])
                entry[f"vs_{base}"] = {
                    "samples": len(common),
                    "better": sum(success[s][i] and not success[base][i] for i in common),
                    "worse": sum(success[base][i] and not success[s][i] for i in common),
                }
        out["schemes"][s] = entry
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
) -> CampaignResult:
    """Run (or resume) a campaign of ``samples`` samples; results under ``out``.

    ``scheduler``: address of an existing Dask scheduler; otherwise a LocalCluster
    of ``workers`` processes on 127.0.0.1 (or this process when ``in_process``).
    ``results.csv`` is rewritten (atomically) at most every ``table_every`` seconds
    while samples finish, and once at the end; the per-sample files are written at once.
    """
    if base.campaign is None:
        raise CaseError(f"{base.name}: no [campaign] table: add the distributions to draw from (cases/README.md)")
    if samples < 1:
        raise FtcError(f"--samples: must be >= 1, got {samples}")
    configured = [s for s in SCHEME_NAMES if getattr(base.schemes, s) is not None]
    schemes = configured if schemes is None else list(schemes)
    unknown = [s for s in schemes if s not in configured]
    if unknown:
        raise FtcError(f"schemes {unknown} are not configured in {base.name} (configured: {', '.join(configured)})")
    out = Path(out)
    (out / "samples").mkdir(parents=True, exist_ok=True)
    meta = {"case": base.name, "seed": int(seed), "schemes": schemes, "base": json.loads(base.model_dump_json())}
    meta_path = out / "campaign.json"
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding="utf-8"))
            old.get("seed")
        except (ValueError, AttributeError) as exc:
            why = f"damaged ({str(exc)[:120]}); remove it to start over, or choose another --out"
            raise FtcError(f"{meta_path}: {why}") from None
        if old.get("seed") != meta["seed"] or old.get("schemes") != schemes or old.get("base") != meta["base"]:
            raise FtcError(f"{out}: holds a campaign with another seed, scheme list or base case; choose another --out")
    write_atomic(meta_path, json.dumps(meta, indent=1).encode())
    records = done_samples(out)
    todo = [i for i in range(samples) if i not in records]
    res = CampaignResult(out=out, table=out / "results.csv", requested=samples, skipped=samples - len(todo))
    base_json = base.model_dump_json()
    wall0 = time.perf_counter()

    last_table = [0.0]

    def store(rec: dict) -> None:
        write_atomic(_sample_path(out, rec["sample"]), json.dumps(_jsonable(rec)).encode())
        records[rec["sample"]] = rec
        res.completed.append(rec["sample"])
        # the table is a view of the sample files: refreshed at most every table_every seconds
        if time.perf_counter() - last_table[0] >= table_every:
            write_table(out, records.values())
            last_table[0] = time.perf_counter()
        if on_sample is not None:
            on_sample(rec["sample"])

    with _Progress(show_progress, len(todo)) as bar:
        if in_process:
            for i in todo:
                try:
                    store(run_sample(base_json, i, sample_seed(seed, i), schemes))
                except Exception as exc:  # a sample that cannot run is recorded, the campaign goes on
                    res.failed[i] = f"{type(exc).__name__}: {exc}"
                bar(len(res.completed), len(res.failed))
        else:
            _run_dask(base_json, todo, seed, schemes, scheduler, workers, retries, store, res, bar)
    write_table(out, records.values())
    if res.failed:
        write_atomic(out / "failed.json", json.dumps(res.failed, indent=1).encode())
    res.wall_time = time.perf_counter() - wall0
    return res


def _run_dask(base_json, todo, seed, schemes, scheduler, workers, retries, store, res, bar) -> None:
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=max(1, workers),
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        )
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futures = {
            client.submit(
                run_sample, base_json, i, sample_seed(seed, i), schemes, key=f"sample-{seed}-{i}", retries=retries
            ): i
            for i in todo
        }
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                store(fut.result())
            except Exception as exc:
                res.failed[i] = f"{type(exc).__name__}: {exc}"
            bar(len(res.completed), len(res.failed))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class _Progress:
    """A rich progress bar with samples done / failed / rate (or nothing)."""

    def __init__(self, show: bool, total: int) -> None:
        self.show, self.total = show, total
        self.p = None

    def __enter__(self):
        if not self.show:
            return lambda done, failed: None
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.p = Progress(
            TextColumn("campaign"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("failed {task.fields[failed]}"),
            TextColumn("{task.fields[rate]:.1f} samples/min"),
            TimeElapsedColumn(),
        )
        self.p.__enter__()
        task = self.p.add_task("run", total=self.total, failed=0, rate=0.0)
        t0 = time.perf_counter()

        def update(done: int, failed: int) -> None:
            rate = 60.0 * (done + failed) / max(time.perf_counter() - t0, 1e-9)
            self.p.update(task, completed=done + failed, failed=failed, rate=rate)

        return update

    def __exit__(self, *exc) -> None:
        if self.p is not None:
            self.p.__exit__(*exc)
