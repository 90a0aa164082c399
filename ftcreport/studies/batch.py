"""``ftcreport batch``: every case x scheme, in parallel processes, cached, then reports.

Edge module (files, processes, progress).  For each case file:

* it is validated; a broken file is recorded (``<out>/<stem>/case.json`` with the
  error) and the batch goes on;
* each scheme's run is cached (not simulated again) when its record ``<out>/<case>/<scheme>/record.json``
  is sound, matches its files (size and SHA-256) and holds :func:`run_key`, the hash of (case
  content, package version, scheme, the engine that runs it, the versions that can change
  numbers: numpy, scipy, numba, ...) (:func:`ftcreport.storage.store.check_run`; ``force`` re-runs).  A
  stored run that is not sound is re-run with one line naming its file and why.  Otherwise the
  run is simulated in a worker process and stored atomically as soon as it finishes, so an
  interrupted batch keeps every finished run;
* a run that ends in a status its case counts as a failure (``expected_status``) is stored as
  that failure: this batch and every later one (cached or not), ``report`` and ``check`` report
  it failed and exit 1;
* a run that fails because of its environment, not its case (a compiled-code cache that cannot
  be loaded, an OS error, memory, a worker that died; or a bug) is never stored: the batch reports
  it failed for this invocation (:attr:`BatchResult.not_stored`, the manifest), and the next
  batch runs it again (see :data:`ftcreport.runner.CASE_ERRORS` for the rule).

Progress (on a terminal's stderr only, not with ``--quiet``): one overall bar (runs done of the
batch's total, elapsed time, an estimate of the time left) and one line per run a worker is on
(case / scheme and its fraction of simulated time); a finished run leaves the display (rich).

Provenance: ``<out>/manifest.json`` describes the batches into ``out`` (:mod:`ftcreport.storage.manifest`:
package, git revision, dependency versions, Python, platform, CPU of the last; per run the engine,
status, cache key and noise seed; per case its content hash; ``batches``: each batch's time and
cases), merged across batches (:func:`merge_manifest`); ``<out>/<case>/manifest.json`` the same for
one case (its page shows it).  ``<out>/metrics.parquet`` holds every run's metrics, one row per
(case, scheme, phase) (:func:`ftcreport.storage.tidy.metrics_table`).

Memory: each worker returns its peak resident memory with its result (:func:`peak_rss_mb`); the
batch's maximum over its workers is :attr:`BatchResult.worker_peak_rss_mb`, printed by
``ftcreport batch``, stored in ``<out>/manifest.json`` (``memory``) and shown on the index page.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import multiprocessing as mp
import os
import queue as _queue
import signal
import sys
import threading
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__
from ..cases import Case, case_hash, configured_schemes, dropped_faults, load_case, overlay_text, with_duration
from ..errors import CaseError, note_stored, printable
from ..infra.inputs import read_input
from ..infra.limits import worker_count
from ..storage.store import (
    OutputError,
    check_inside,
    check_run,
    output_lock,
    read_json,
    save_run,
    write_atomic,
    write_json,
)
from . import PAGES
from .display import BatchDisplay

__all__ = [
    "BatchResult",
    "discover",
    "failures_summary",
    "merge_manifest",
    "peak_rss_mb",
    "record_case",
    "run_batch",
    "run_key",
    "worker_count",
    "write_case_manifest",
    "write_manifests",
]


@dataclass
class BatchResult:
    """What a batch did."""

    simulated: list[tuple[str, str]] = field(default_factory=list)
    cached: list[tuple[str, str]] = field(default_factory=list)
    failed_runs: list[tuple[str, str, str]] = field(default_factory=list)
    case_errors: dict[str, str] = field(default_factory=dict)
    cases: list[str] = field(default_factory=list)
    #: peak resident memory [MB] of the worker process that ran each simulated run, when it finished
    #: (a worker runs several jobs: its peak so far); only runs whose worker reported one
    run_peak_rss_mb: dict[tuple[str, str], float] = field(default_factory=dict)
    #: peak resident memory [MB] of each worker process (by process id) over the batch
    worker_peaks_mb: dict[int, float] = field(default_factory=dict)
    #: runs this batch simulated and stored complete (with their cache key): a re-run skips them
    stored: int = 0
    #: runs that failed because of their environment (or a bug), not their case: (case, scheme, why);
    #: not stored, so the next batch runs them again (each is in failed_runs too)
    not_stored: list[tuple[str, str, str]] = field(default_factory=list)

    @property
    def worker_peak_rss_mb(self) -> float | None:
        """The largest peak resident memory [MB] of the batch's worker processes (None: no worker ran)."""
        return max(self.worker_peaks_mb.values(), default=None)


def peak_rss_mb() -> float | None:
    """This process's peak resident memory [MB] so far (None where it cannot be read).

    Linux: ``VmHWM`` of /proc/self/status, the high-water mark of this process's address space since
    its exec.  Not ``getrusage(RUSAGE_SELF).ru_maxrss``: Linux carries the peak of the address space
    a process had before exec into it, so a worker started (fork + exec) by a large batch process
    would report the batch process's size.  Elsewhere ru_maxrss (bytes on macOS, KiB otherwise).
    """
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    except (ImportError, OSError):  # pragma: no cover - Windows
        return None
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def discover(paths: Iterable[Path], on_note: Callable[[str], None] | None = None) -> list[Path]:
    """Case files: directories are searched for ``*.toml`` (sorted), files taken as given.

    A directory's subdirectories are not searched (``cases/motors/`` is a set of its own, slower cases); when
    they hold ``*.toml`` files, ``on_note`` gets one line naming them and how to run them, so that none is
    left out without a word.
    """
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out.extend(sorted(p.glob("*.toml")))
            if on_note is not None:
                deeper = Counter(f.parent for f in p.rglob("*.toml") if f.parent != p)
                if deeper:
                    where = ", ".join(f"{d.relative_to(p).as_posix()}/: {k}" for d, k in sorted(deeper.items()))
                    first = min(deeper)
                    on_note(
                        f"{p}: {sum(deeper.values())} case files in subdirectories are not run ({where}): a "
                        f"directory's own *.toml files are; to run the others, name their directory too ({first})"
                    )
        else:
            out.append(p)
    return out


def _record(out: Path, name: str, payload: dict) -> None:
    write_json(out / name / "case.json", payload | {"time": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")})


def base_name(path: Path, base_case: str) -> str:
    """The name (report directory) of an overlay's base case: its ``name`` field, else its file stem."""
    base = (Path(path).parent / base_case).resolve()
    try:
        return load_case(base).name or base.stem
    except CaseError:
        return base.stem


def _another_source(out: Path, name: str, path: Path, on_note) -> None:
    """Say so when the case stored under ``name`` came from another file than ``path``: results are stored by
    case name, so a copy of a case (another directory, another gain) replaces the runs of the original, which
    the index then shows no more (session 12's new user: no word of it)."""
    from ..storage.store import read_json

    rec = read_json(out / name / "case.json") if (out / name / "case.json").is_file() else None
    old = rec.get("source") if isinstance(rec, dict) else None
    if not isinstance(old, str) or not old or on_note is None:
        return
    if not _same_file(old, path):
        on_note(f"case {name}: the results stored in {out / name} came from {old}; {path} has the same case name "
                "and replaces them")  # fmt: skip


def _same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name the same file (compared resolved; False when either cannot be resolved)."""
    try:
        return Path(a).resolve() == Path(b).resolve()
    except (OSError, ValueError):
        return False


def record_case(
    out: Path, case: Case, path: Path, duration: float | None = None, notes: Iterable[str] = (), on_note=None
) -> str:
    """Store the case record and a copy of the case file (provenance); returns the case content hash.

    ``notes``: warnings beside the case's own (the faults a ``--duration`` drops).  The stored runs of schemes
    the case no longer runs, made from an earlier content of it, are removed (:func:`_dropped_schemes`), said
    on the case's page and through ``on_note``."""
    from ..evaluation.families import not_applicable

    key = case_hash(case, __version__)
    _another_source(out, case.name, path, on_note)
    # an overlay (base_case) is stored resolved, so the copy parses on its own
    resolved = overlay_text(path) if case.base_case is not None else None
    write_atomic(out / case.name / "case.toml", read_input(path) if resolved is None else resolved.encode())
    schemes = configured_schemes(case)
    thresholds = {s: {m: b.model_dump() for m, b in t.items()} for s, t in case.thresholds.items()}
    payload = {
        "source": str(path),
        "status": "ok",
        "key": key,
        "package_version": __version__,  # the key's version: a stored case is checked against it (load_stored_case)
        "code": code_identity()["code"],  # the code that hashed it: another's may hash the same file otherwise
        "schemes": schemes,
        "n": case.robots.n,
        "reference": case.reference.kind,
        "warnings": [*notes, *case.warnings()],
        "thresholds": thresholds,
        "duration_override": duration,
        "claims": [c.model_dump() for c in case.claims],  # thesis claims that `check` gates on
        "requirements": [r.model_dump() for r in case.requirements],  # time-windowed requirements (check)
        "not_run": not_applicable(case),  # families the case does not run, each with its reason (issue 21)
        "plugin_schemes": plugin_info(case),  # the plug-in schemes' family, description, reference (report pages)
    }
    if case.base_case is not None:  # the page compares with the base's runs (issue 19 item 4)
        payload["base"] = base_name(Path(path), case.base_case)
    dropped = _dropped_schemes(out, case.name, schemes, key)
    if dropped:
        line = (f"the stored runs of {', '.join(dropped)} were removed: the case no longer runs them, and they were "
                "made from its earlier content")  # fmt: skip
        payload["warnings"].append(line)
        if on_note is not None:
            on_note(f"{path}: {line}")
    _record(out, case.name, payload)
    from ..storage.store import remove_run

    for s in dropped:
        remove_run(out, case.name, s)
    return key


def _dropped_schemes(out: Path, case_name: str, schemes: list[str], key: str) -> list[str]:
    """The schemes stored under ``out/<case>`` that the case no longer runs and whose runs were made from another
    content of it (their record's case hash is not ``key``), or left without a record (an interrupted store or
    removal): nothing would ever run or show them again.  A run whose record exists but cannot be read is
    left, named as damaged, for the user to look at."""
    from ..storage.store import read_json, stored_schemes

    out_ = []
    for s in stored_schemes(out, case_name):
        if s in schemes:
            continue
        d = Path(out) / case_name / s
        rec = read_json(d / "record.json")
        earlier = isinstance(rec, dict) and isinstance(rec.get("case_hash"), str) and rec["case_hash"] != key
        orphan = not (d / "record.json").exists()  # files without a record: an interrupted store or removal
        if earlier or orphan:
            out_.append(s)
    return out_


def plugin_info(case: Case) -> dict[str, dict]:
    """``{name: {family, description, reference, file}}`` of the registered schemes a case runs."""
    from ..schemes import registered

    reg = registered()
    out = {}
    for s in configured_schemes(case):
        if s in reg:
            sc = reg[s]
            law = getattr(sc.law, "py_func", sc.law)
            where = getattr(law, "__code__", None)
            out[s] = {
                "family": sc.family,
                "description": sc.description,
                "reference": sc.reference,
                "file": where.co_filename if where is not None else "",
            }
    return out


def code_identity() -> dict:
    """What besides the case makes a result, as this process runs it: the package's own code
    (:mod:`ftcreport.storage.code_digest`, ``code``) and the versions of the package and of the dependencies
    that can change numbers (:func:`ftcreport.storage.manifest.numeric_versions`, ``versions``).  Part of the
    result cache key (:func:`run_key`) and of a campaign's, coverage's or FDI run's records
    (:func:`ftcreport.studies.campaign.run_hash`)."""
    from ..storage import code_digest, manifest

    return {"code": code_digest.code_digest(), "versions": manifest.numeric_versions()}


def run_key(case: Case, scheme: str) -> str:
    """Result cache key of one scheme of a case: case content, package version, the package's own code
    (:mod:`ftcreport.storage.code_digest`), scheme, engine and the dependency versions that can change
    numbers (:func:`ftcreport.storage.manifest.numeric_versions`): :func:`code_identity`."""
    from ..runner import expected_engine

    blob = {
        "case": case_hash(case, __version__),
        "scheme": scheme,
        "engine": expected_engine(scheme),
        **code_identity(),
    }
    return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:16]


def _run_record(
    out: Path, case: Case, scheme: str, cached: bool, peak_mb: float | None = None, res: BatchResult | None = None
) -> dict:
    stored = check_run(out, case.name, scheme)
    m = stored.metrics or {}
    not_stored = next(
        (why for c, s, why in (res.not_stored if res is not None else ()) if (c, s) == (case.name, scheme)), None
    )
    record = {
        "case": case.name,
        "scheme": scheme,
        "engine": m.get("engine"),
        "status": m.get("status") if not_stored is None else "error",
        "cached": cached,
        "key": (stored.record or {}).get("key"),
        "seed": case.plant.noise.seed,
        "wall_time": m.get("wall_time"),
    }
    if not stored.sound and not stored.absent:
        record["damaged"] = stored.problem
    if not_stored is not None:  # this invocation's failure of the environment: not the run's result
        record["not_stored"] = not_stored
    if peak_mb is not None:  # simulated by a batch worker: its peak resident memory when the run finished
        record["worker_peak_rss_mb"] = peak_mb
    return record


def write_case_manifest(out: Path, case: Case, settings: dict, runs: list[dict] | None = None) -> Path:
    """``<out>/<case>/manifest.json``: the environment, the case's content hash and its runs."""
    from ..storage.manifest import build_manifest, write_manifest

    out = Path(out)
    if runs is None:
        schemes = configured_schemes(case)
        runs = [_run_record(out, case, s, False) for s in schemes if not check_run(out, case.name, s).absent]
    one = build_manifest(
        "case",
        cases={case.name: case_hash(case, __version__)},
        runs=runs,
        seeds={case.name: case.plant.noise.seed},
        settings=settings,
    )
    return write_manifest(out / case.name / "manifest.json", one)


def write_manifests(
    out: Path, cases: list[Case], cached: set[tuple[str, str]], settings: dict, res: BatchResult | None = None
) -> Path:
    """``<out>/manifest.json`` for the batch and ``<out>/<case>/manifest.json`` per case; returns the first.

    With ``res``, the batch manifest's ``memory`` holds the workers' peak resident memory.
    """
    from ..storage.manifest import build_manifest, write_manifest

    out = Path(out)
    peaks = res.run_peak_rss_mb if res is not None else {}
    all_runs = []
    for case in cases:
        schemes = configured_schemes(case)
        runs = [_run_record(out, case, s, (case.name, s) in cached, peaks.get((case.name, s)), res) for s in schemes]
        all_runs += runs
        write_case_manifest(out, case, settings, runs)
    m = build_manifest(
        "batch",
        cases={c.name: case_hash(c, __version__) for c in cases},
        runs=all_runs,
        seeds={c.name: c.plant.noise.seed for c in cases},
        settings=settings,
        **({"memory": memory_summary(res)} if res is not None else {}),
    )
    return write_manifest(out / "manifest.json", merge_manifest(read_json(out / "manifest.json"), m, out))


def merge_manifest(old: dict | None, new: dict, out: Path) -> dict:
    """The batch manifest of ``out`` after a batch: ``new`` (this batch: environment, settings, memory)
    with the cases, runs and seeds of the earlier batches into the same directory that this one did
    not redo and whose results are still there, and ``batches``: one entry per batch (its time,
    cases, settings and package version), so the manifest covers every case the index shows."""
    this = {
        "created": new["created"],
        "cases": sorted(new["cases"]),
        "settings": new.get("settings"),
        "ftcreport": new["ftcreport"]["version"],
    }
    if not isinstance(old, dict) or old.get("kind") != "batch":
        return new | {"batches": [this]}
    mine = set(new["cases"])
    kept = {
        c: h for c, h in (old.get("cases") or {}).items() if c not in mine and (Path(out) / c / "case.json").exists()
    }
    merged = dict(new)
    merged["cases"] = kept | new["cases"]
    merged["runs"] = [r for r in old.get("runs") or [] if r.get("case") in kept] + new["runs"]
    merged["seeds"] = {c: s for c, s in (old.get("seeds") or {}).items() if c in kept} | new["seeds"]
    earlier = old.get("batches") or [
        {"created": old.get("created"), "cases": sorted(old.get("cases") or {}), "settings": old.get("settings")}
    ]
    merged["batches"] = [b for b in earlier if set(b.get("cases") or ()) & set(kept)] + [this]
    return merged


def memory_summary(res: BatchResult) -> dict:
    """The ``memory`` block of the batch manifest: the workers' peak resident memory [MB]."""
    return {
        "worker_peak_rss_mb": res.worker_peak_rss_mb,
        "workers": len(res.worker_peaks_mb),
        "runs_measured": len(res.run_peak_rss_mb),
        "measure": "VmHWM of each worker process (peak resident set since its start), maximum over the workers",
    }


def _cost(case: Case, scheme: str, source: str) -> float:
    """A rough relative cost of a run (steps x the scheme's per-step weight, ``Scheme.cost``): the longest
    start first, so the last worker does not start a long run when the others are done.  A plug-in's cost
    that fails only orders its run as weight 1, said on stderr (``cases validate`` refuses it)."""
    from ..errors import PluginError
    from ..runner import run_cost

    steps = case.simulation.duration / case.simulation.dt
    try:
        return steps * run_cost(case, scheme)
    except PluginError as exc:
        _note(f"ftcreport: warning: {source}: {exc}; its run is ordered as weight 1 (the cost only orders the runs)")
        return steps


def _loop_of(case: Case, scheme: str) -> tuple:
    """Which compiled loop a run needs (ftcreport.fast.engine.loop_for): one per (law, discrete update) of
    the registry (the built-in schemes share two dispatchers: control/*_law.py), motors and sampled control
    are variants of each."""
    from ..schemes import get

    sc = get(scheme)
    group = (_name(sc.law), _name(sc.discrete), sc.terms)
    return group, case.actuators is not None, case.simulation.sample_time is not None


def _name(fn) -> str:
    """A compiled function's identity without importing it (a built-in's is its "module:function")."""
    if fn is None or isinstance(fn, str):
        return str(fn)
    py = getattr(fn, "py_func", fn)
    return f"{py.__module__}:{py.__qualname__}"


def _compile_first(todo: list) -> list:
    """The runs in the given order, except that the first run of each distinct loop comes first.

    A cold batch compiles each loop once (the workers take turns under a file lock, see
    fast.engine): started together, the first wave compiles the loops in parallel instead of one
    worker compiling while the others wait for it."""
    seen: set[tuple] = set()
    first, rest = [], []
    for job in todo:
        key = _loop_of(job[0], job[2])
        (rest if key in seen else first).append(job)
        seen.add(key)
    return first + rest


def error_record_name(path: Path, avoid: Iterable[str] = ()) -> str:
    """Directory of a rejected case file's record: its stem when that is a safe name not in ``avoid``
    (lower-case names of the batch's valid cases), else a hash of the path."""
    from ..infra.limits import name_problem

    stem = Path(path).stem
    if name_problem(stem) is None and stem.lower() not in set(avoid):
        return stem
    return "rejected-" + hashlib.sha256(str(path).encode("utf-8", "surrogateescape")).hexdigest()[:12]


def _record_error(out: Path, path: Path, error: str, avoid: Iterable[str] = ()) -> None:
    """Record a rejected case file (shown on the index) without letting its name escape ``out``
    or overwrite a valid case's record."""
    try:
        raw = read_input(path)[:200_000]
    except CaseError:  # not a regular file, too large, unreadable: the error says so
        raw = b""
    text = raw.decode("utf-8", errors="replace")
    record = {"source": str(path), "status": "error", "error": error, "source_text": text}
    try:
        written = error_record_name(path, avoid)
        _record(out, written, record)
    except OutputError:  # its stem is a folder linked out of --out: the record goes under a hash of the path
        written = error_record_name(path, (*avoid, Path(path).stem.lower()))
        _record(out, written, record)
    for name in _stored_from(out, path):  # a case stored from this file under its `name` field: its runs are stale
        if name != written and name.lower() not in set(avoid):
            with contextlib.suppress(OutputError):  # a folder linked out of --out: not this report's
                _record(out, name, record)


def _stored_from(out: Path, path: Path) -> list[str]:
    """The cases stored under ``out`` whose record names ``path`` as their source (compared resolved, as
    :func:`_another_source` does): a file with a ``name`` field stores its runs under that name, not its stem.

    A rejected file's record is written under each of them too (:func:`_record_error`): the index counts the
    runs stored beside a rejection as stale (ftcreport.report.render.stale_runs), never as the file's current
    results; they stay stored, and a batch that accepts the file again writes its record again."""
    from ..storage.store import read_json

    found = []
    for rec_path in sorted(Path(out).glob("*/case.json")):
        rec = read_json(rec_path)
        source = rec.get("source") if isinstance(rec, dict) else None
        if isinstance(source, str) and source and _same_file(source, path):
            found.append(rec_path.parent.name)
    return found


#: a batch worker's progress queue (set by :func:`_init_worker`; None outside a batch's workers)
_PROGRESS_Q: list = [None]
_TIE: list = [None]  # a batch worker's tie to its batch (its lock's descriptor held for the worker's life)


class _Tie:
    """What ties a batch worker to its batch: the batch's pid, its output directory and its lock.

    Pickled when a worker starts (its initializer's argument): the lock's file descriptor passes to
    the worker (``multiprocessing.reduction.DupFd``, as multiprocessing passes its own pipes), so the
    worker holds the batch's lock too and the kernel frees it only when the last of them is gone.
    """

    def __init__(self, parent: int, out: str, lock: int | None) -> None:
        self.parent, self.out, self.lock = parent, out, lock

    def __reduce__(self):
        from multiprocessing.reduction import DupFd

        return (_Tie._rebuild, (self.parent, self.out, None if self.lock is None else DupFd(self.lock)))

    @staticmethod
    def _rebuild(parent: int, out: str, dup) -> _Tie:
        return _Tie(parent, out, None if dup is None else dup.detach())

    def bind(self) -> None:
        """In the worker: die with the batch, write only inside its ``out`` and only while it lives."""
        from ..infra.lifetime import die_with_parent
        from ..storage.store import confine, set_write_guard

        die_with_parent(self.parent)
        confine(Path(self.out))
        parent = self.parent
        set_write_guard(lambda: os.getppid() == parent)  # else the batch is gone (its lock may be another's)


def _init_worker(progress_q, tie: _Tie | None = None) -> None:
    """Initializer of a batch worker process: the queue its runs report their simulated time on, and
    its tie to the batch (:class:`_Tie`)."""
    _PROGRESS_Q[0] = progress_q
    if tie is not None:
        _TIE[0] = tie  # holds the lock's descriptor for the worker's life
        tie.bind()


def _worker(case_data: dict, source: str, scheme: str, out: str, key: str) -> tuple[dict, dict]:
    """Run one scheme in a worker process and store it; returns its metrics and the worker's
    ``{"pid", "peak_rss_mb"}`` (its peak resident memory after the run and its storage).

    A failure that is not the case's outcome (:func:`ftcreport.runner.run_scheme` raises it: the
    environment, or a bug) is not stored: the metrics returned are then ``{"not_stored": why}``.
    """
    from ..cases import parse_case
    from ..runner import run_scheme

    progress_q = _PROGRESS_Q[0]
    worker = {"pid": os.getpid()}
    try:
        case = parse_case(case_data, source)
    except Exception as exc:  # a scheme file gone or changed since the batch read the case: not the run's result
        return {"not_stored": _not_the_case(exc)}, worker | {"peak_rss_mb": peak_rss_mb()}
    last = [0.0]
    if progress_q is not None:  # started: the display shows the run from now on (its compile included)
        with contextlib.suppress(Exception):
            progress_q.put_nowait((case.name, scheme, 0.0))

    def progress(t: float) -> None:
        if progress_q is not None and t - last[0] >= 0.005 * case.simulation.duration:
            last[0] = t
            with contextlib.suppress(Exception):
                progress_q.put_nowait((case.name, scheme, t))

    try:
        run, metrics = run_scheme(case, scheme, progress=progress)
    except Exception as exc:
        return {"not_stored": _not_the_case(exc)}, worker | {"peak_rss_mb": peak_rss_mb()}
    status = metrics.get("status", "error")
    why = case.unexpected(scheme, status, metrics.get("reason")) if status not in case.expected_for(scheme) else None
    save_run(Path(out), case.name, scheme, run, metrics, key, case.expected_for(scheme), why)
    return metrics, worker | {"peak_rss_mb": peak_rss_mb()}


def _not_the_case(exc: BaseException) -> str:
    """Why a run failed when the failure is not its case's outcome: the environment's words, or a bug's
    one line with the log holding its traceback."""
    from ..errors import RunEnvironmentError, environment_cause
    from ..infra.crashlog import write_crash_log

    if isinstance(exc, RunEnvironmentError):
        return str(exc)
    cause = environment_cause(exc)
    if cause is not None:
        return cause
    return f"unexpected {type(exc).__name__}: {str(exc)[:200]} (a bug: traceback in {write_crash_log(exc)})"


def run_batch(
    paths: Iterable[Path],
    out: Path = Path("reports"),
    jobs: int | None = None,
    force: bool = False,
    duration: float | None = None,
    show_progress: bool = True,
    render: bool = True,
) -> BatchResult:
    """Run every case x scheme not already cached, then render the reports.

    Holds the output directory's lock (:func:`ftcreport.storage.store.output_lock`) throughout:
    a second batch, run, report or check on the same ``out`` fails at once with a message.
    """
    out = Path(out)
    res = BatchResult()
    worker_count(jobs, 1)  # a --jobs below 1 is refused before the output directory is touched
    try:
        with output_lock(out, "batch"):
            return _run_batch(paths, out, jobs, force, duration, show_progress, render, res)
    except (KeyboardInterrupt, OSError) as exc:  # the CLI's message (a full disk's too) says how many runs are stored
        note_stored(exc, res.stored)
        raise


def _note(line: str) -> None:
    """One line on stderr, at once (a stored run re-run and why; a --duration that drops a fault)."""
    print(printable(line), file=sys.stderr, flush=True)


def _run_batch(paths, out: Path, jobs, force, duration, show_progress, render, res: BatchResult) -> BatchResult:
    todo: list[tuple[Case, str, str, str]] = []  # case, source, scheme, key
    expected: dict[str, Case] = {}  # case name -> the case (its expected_for(scheme): statuses that are not failures)
    loaded: list[Case] = []
    taken: dict[str, str] = {}  # lower-case case name -> the file that has it
    for path in discover(paths, on_note=(lambda line: _note(f"ftcreport: note: {line}")) if show_progress else None):
        notes = []
        try:
            case = load_case(path)
            if duration is not None:
                if (drop := dropped_faults(case, duration)) is not None:
                    notes.append(drop)
                case = with_duration(case, duration)
            first = taken.setdefault(case.name.lower(), str(path))
            if first != str(path):
                raise CaseError(
                    f"{path}: name: '{case.name}' is already the name of {first} (names must differ in more than "
                    "letter case: each is a directory of the report)"
                )
            for s in configured_schemes(case):  # a case or scheme folder linked out of --out is refused
                check_inside(out / case.name / s / "record.json")
        except (CaseError, OutputError) as exc:
            res.case_errors[str(path)] = str(exc)
            continue
        res.cases.append(case.name)
        loaded.append(case)
        for line in notes if show_progress else ():  # --quiet: on the case's page only
            _note(f"ftcreport: warning: {path}: {line}")
        record_case(out, case, Path(path), duration, notes, on_note=lambda line: _note(f"ftcreport: note: {line}"))
        expected[case.name] = case
        schemes = configured_schemes(case)
        for s in schemes:
            key = run_key(case, s)
            stored = check_run(out, case.name, s, key=key)
            if not force and stored.sound:
                res.cached.append((case.name, s))
                if stored.failed:  # cached as the failure it is
                    rec = stored.record
                    res.failed_runs.append((case.name, s, case.unexpected(s, rec["status"], rec.get("reason"))))
                continue
            if not force and not stored.absent:
                _note(f"ftcreport: note: {stored.problem}; re-running {case.name} / {s}")
            todo.append((case, str(path), s, key))
    for path, error in res.case_errors.items():  # after every valid name is known
        _record_error(out, Path(path), error, taken)
    costs = [_cost(case, s, source) for case, source, s, _ in todo]
    todo = _compile_first([job for _, job in sorted(zip(costs, todo, strict=True), key=lambda p: -p[0])])

    def finish(pool=None) -> None:
        """Manifests, the tidy table and the pages (in the workers, when there are some)."""
        settings = {"jobs": jobs, "force": force, "duration": duration}
        write_manifests(out, loaded, set(res.cached), settings, res)
        from ..storage.tidy import table_stale, write_metrics_parquet

        if table_stale(out):  # by content: damaged, or of other runs than those stored now
            write_metrics_parquet(out)
        if render:  # ftcreport.report.render.render_all (studies names no report module: PAGES)
            PAGES["render_all"](out, pool=pool, notify=_render_notice if show_progress else None)

    if todo:
        workers, capped = worker_count(jobs, len(todo))
        if capped is not None:
            _note(f"ftcreport: note: --jobs {jobs}: capped at {workers} ({capped})")
        _execute(todo, out, workers, show_progress, res, expected, finish)
    else:
        finish()
    return res


def _render_notice(pages: int) -> None:
    """Say why the terminal is quiet after the last run: the figures and analyses of the pages."""
    from rich.console import Console

    Console(stderr=True, highlight=False).print(f"rendering {pages} case page(s) (figures and linearized analyses) ...")


def _records(out: Path, todo) -> dict[tuple[str, str], bytes | None]:
    """The run records (record.json's bytes, None when absent) of ``todo``'s runs as they are now."""
    from ..storage.store import RECORD

    def read(p: Path) -> bytes | None:
        try:
            return p.read_bytes()
        except OSError:
            return None

    return {(c.name, s): read(Path(out) / c.name / s / RECORD) for c, _, s, _ in todo}


def newly_stored(out: Path, todo, before: dict[tuple[str, str], bytes | None]) -> int:
    """How many of ``todo``'s runs this batch stored: sound now, with a record other than ``before``'s
    (a --force batch's todo holds the earlier batch's sound runs too: those are not this batch's)."""
    now = _records(out, todo)
    return sum(
        1
        for c, _, s, key in todo
        if now[(c.name, s)] != before.get((c.name, s)) and check_run(out, c.name, s, key=key).sound
    )


def _execute(todo, out: Path, jobs: int, show_progress: bool, res: BatchResult, expected: dict, finish) -> None:
    """Run ``todo`` in worker processes, then ``finish(pool)`` (the pages render in the same workers)."""
    from ..infra.lifetime import shielded, stop_pool
    from ..storage.store import lock_fd

    before = _records(out, todo)  # the interrupt message counts what this batch stored, not what it found

    ctx = mp.get_context("spawn")
    q = ctx.Queue()  # the workers' progress reports, handed to each worker as it starts
    display = BatchDisplay.make(len(todo), show_progress)
    tie = _Tie(os.getpid(), str(out), lock_fd(out))
    pool = _Pool(max_workers=max(1, jobs), mp_context=ctx, initializer=_init_worker, initargs=(q, tie))
    with display, pool:
        futures = {}
        for case, source, scheme, key in todo:
            fut = pool.submit(_worker, case.model_dump(mode="json"), source, scheme, str(out), key)
            futures[fut] = (case.name, scheme)
            display.durations[(case.name, scheme)] = case.simulation.duration
        pending = set(futures)
        try:
            _collect(pending, futures, q, display, out, res, expected)
            display.stop()
            try:
                finish(pool)
            except BrokenProcessPool:  # a worker was killed: the pages render here instead
                finish(None)
        except BaseException:  # Ctrl-C, SIGTERM, SIGHUP: stop the workers now; every stored run is complete
            with shielded():
                display.stop()
                # terminated and waited for: none writes after this, and their temporary files can go.
                # The pool cancels the waiting runs itself: a future cancelled here, which the pool then
                # finds broken (its workers terminated), raised InvalidStateError in its thread (Python 3.11)
                stop_pool(pool)
                # what is on disk now, complete with this batch's key (a worker may have stored a run
                # whose result this process had not collected yet)
                res.stored = newly_stored(out, todo, before)
            raise
        finally:
            q.close()


class _Pool(ProcessPoolExecutor):
    """A process pool whose workers ignore Ctrl-C: the batch process takes it and terminates them.

    Ctrl-C reaches the terminal's whole process group, and a worker still starting (importing)
    printed a KeyboardInterrupt traceback.  A submit starts a worker while fewer than
    ``max_workers`` run; it does so with SIGINT ignored (:func:`_children_ignore_sigint`).
    """

    def submit(self, fn, /, *args, **kwargs):
        with _children_ignore_sigint():
            return super().submit(fn, *args, **kwargs)


@contextlib.contextmanager
def _children_ignore_sigint():
    """Processes started inside ignore Ctrl-C (SIGINT) for life; this process's handler is back after.

    An ignored signal stays ignored across fork and exec, and Python leaves it so.  Inside is only
    the start of a process (fork and exec, milliseconds): a Ctrl-C then is lost.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old if old is not None else signal.default_int_handler)


def _collect(pending, futures, q, display: BatchDisplay, out: Path, res: BatchResult, expected: dict) -> None:
    """Wait for the runs, recording each as it finishes."""
    while pending:
        done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
        _drain(q, display)
        for fut in done:
            name, scheme = futures[fut]
            try:
                m, worker = fut.result()
            except Exception as exc:  # the worker died (killed, out of memory) or its result did not come back
                m, worker = {"not_stored": f"worker failed: {type(exc).__name__}: {exc}"}, {}
            _note_peak(res, name, scheme, worker)
            res.simulated.append((name, scheme))
            if "not_stored" in m:  # not the case's outcome: this invocation's failure, never its stored result
                why = f"{m['not_stored']} (not the case's result: not stored, the next batch runs it again)"
                res.not_stored.append((name, scheme, why))
                res.failed_runs.append((name, scheme, why))
            else:
                res.stored += 1  # the worker stored it (save_run) before it returned
                status, reason = m.get("status", "error"), m.get("reason", "")
                if name not in expected or status not in expected[name].expected_for(scheme):
                    why = (
                        expected[name].unexpected(scheme, status, reason) if name in expected else f"{status}: {reason}"
                    )
                    res.failed_runs.append((name, scheme, why))
            display.finished(name, scheme)


def _note_peak(res: BatchResult, name: str, scheme: str, worker: dict) -> None:
    """Record a worker's reported peak resident memory for its run and for the worker."""
    peak = worker.get("peak_rss_mb")
    if peak is None:
        return
    res.run_peak_rss_mb[(name, scheme)] = float(peak)
    pid = int(worker.get("pid", -1))
    res.worker_peaks_mb[pid] = max(res.worker_peaks_mb.get(pid, 0.0), float(peak))


def _drain(q, display: BatchDisplay) -> None:
    while True:
        try:
            name, scheme, t = q.get_nowait()
        except (_queue.Empty, EOFError, OSError):
            return
        display.advanced(name, scheme, t)


def failures_summary(res: BatchResult) -> str:  # pragma: no cover - CLI text helper
    lines = [f"ftcreport: error: {e if e.startswith(p) else f'{p}: {e}'}" for p, e in res.case_errors.items()]
    lines += [f"ftcreport: error: {c} / {s}: {r}" for c, s, r in res.failed_runs]
    return "\n".join(printable(line) for line in lines)
