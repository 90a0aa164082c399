"""Result storage at the edge: atomic files, one directory per case and scheme, each run with its record.

Layout under the output directory (``reports/`` by default)::

    <case>/<scheme>/metrics.json      the metrics (ftcreport.evaluation.metrics names), status and reason
    <case>/<scheme>/timeseries.npz    t, q, q_d, eta, u, tau, sigma, ubar and the controller's signals
    <case>/<scheme>/record.json       the run's record, written last: what the directory holds

Every file is written to a temporary name in the same directory and renamed
into place (``os.replace``), so a reader never sees a half-written file and an
interrupted run loses nothing already stored.

The store knows what it holds (issue 34).  A run's record names the run (case, scheme), its cache
key and case content hash, the package version, its status and whether the case counts that
status as a failure, and the size and SHA-256 of each of its files.  It is removed first when a
run is stored again and written last, so a directory without it is incomplete.  A stored run is
served (cached, rendered, gated) only when :func:`check_run` finds its record sound and matching
its files and, where the caller knows them, the key and the case content; anything else is named,
one line with the file and why, and treated as not there (a batch re-runs it).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import time
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import FtcError, StoredCaseChangedError
from ..infra.atomic import TMP_SUFFIX, replace_file
from ..infra.lifetime import shielded
from ..sim import Run

__all__ = [
    "DERIVED_FILES",
    "NETCDF",
    "RECORD",
    "RUN_FILES",
    "OutputBusyError",
    "OutputError",
    "StoredRun",
    "check_inside",
    "check_run",
    "clean_partial",
    "confine",
    "deleted_runs",
    "edited_cases",
    "kind_of",
    "load_metrics",
    "load_stored_case",
    "load_timeseries",
    "lock_fd",
    "locked",
    "output_lock",
    "read_json",
    "save_run",
    "set_write_guard",
    "stored_metrics",
    "stored_runs",
    "stored_schemes",
    "unrecorded_cases",
    "write_atomic",
    "write_json",
]

LOCK_NAME = ".ftcreport.lock"


def write_atomic(path: Path, data: bytes) -> None:
    """Write bytes to ``path`` atomically (temporary file + rename: :func:`ftcreport.infra.atomic.replace_file`),
    inside the registered output directories and while this process may write (a stopped worker exits)."""
    path = Path(path)
    if _roots:
        check_inside(path)
    _check_may_write()
    replace_file(path, data, before_rename=_check_may_write)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _json_bytes(obj: Any) -> bytes:
    return (json.dumps(_jsonable(obj), indent=2, sort_keys=False) + "\n").encode()


def write_json(path: Path, obj: Any) -> None:
    """Atomic JSON (NaN and inf written as null)."""
    write_atomic(path, _json_bytes(obj))


RECORD = "record.json"  # a run's record (written last)
RUN_FILES = ("metrics.json", "timeseries.npz")  # a run's files, each in its record with its size and hash
NETCDF = "timeseries.nc"  # export's netCDF of a run, beside it (ftcreport.storage.tidy.export)
#: Files other commands make from a run in its directory: not in its record, but of the run they were made
#: from (its case hash, status and trajectory inside), so they go when that run is stored again or removed:
#: a later run's directory never holds an export of the one before it.
DERIVED_FILES = (NETCDF,)
RECORD_FORMAT = 1


def _digest(data: bytes) -> dict:
    return {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def save_run(
    out: Path,
    case_name: str,
    scheme: str,
    run: Run,
    metrics: dict,
    key: str,
    expected: Iterable[str] = ("ok",),
    failure: str | None = None,
) -> Path:
    """Store one run: its files, then its record (:data:`RECORD`), so a complete directory has one.

    ``expected``: the statuses the case does not count as failures (``Case.expected_for``);
    ``failure``: the case's words for a status outside them (``Case.unexpected``), kept in the record
    so that every later command reports the cached run as the failure it is.
    """
    d = Path(out) / case_name / scheme
    check_inside(d / RECORD)  # a case folder linked out of --out is refused, not written (nor its record removed)
    (d / RECORD).unlink(missing_ok=True)  # the directory is incomplete until the new record is written
    (d / "key").unlink(missing_ok=True)  # the record's predecessor (ftcreport before issue 34)
    for name in DERIVED_FILES:  # made from the run before: export makes them again from this one
        (d / name).unlink(missing_ok=True)
    buf = io.BytesIO()
    arrays = {"t": run.t, **{k: v for k, v in run.signals.items()}}
    np.savez_compressed(buf, **arrays)
    files = {"timeseries.npz": buf.getvalue(), "metrics.json": _json_bytes(metrics)}
    for name in RUN_FILES:
        write_atomic(d / name, files[name])
    status = metrics.get("status", "error")
    failed = status not in set(expected)
    record = {
        "format": RECORD_FORMAT,
        "case": case_name,
        "scheme": scheme,
        "key": key,
        "case_hash": metrics.get("case_hash") or "",
        "package_version": __version__,
        "status": status,
        "reason": metrics.get("reason") or "",
        "expected": sorted(set(expected)),
        "failed": failed,
        "failure": (failure or f"{status}: {metrics.get('reason') or 'no reason given'}") if failed else None,
        "files": {name: _digest(files[name]) for name in RUN_FILES},
    }
    write_json(d / RECORD, record | {"sha256": _seal(record)})
    return d


def _is(value: Any, t: type | tuple[type, ...]) -> bool:
    """isinstance, where a boolean is not an int (JSON's true is not the number 1)."""
    return isinstance(value, t) and (isinstance(value, bool) == (t is bool))


def _seal(record: dict) -> str:
    """SHA-256 of a record's fields (canonical JSON): an edited record (a status or failed flag changed by
    hand, a field dropped) no longer matches it."""
    return hashlib.sha256(json.dumps(record, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


#: The fields of a record and their types (a record missing one, or with another type, is not a record)
_RECORD_FIELDS = {
    "format": int,
    "case": str,
    "scheme": str,
    "key": str,
    "case_hash": str,
    "package_version": str,
    "status": str,
    "reason": str,
    "expected": list,
    "failed": bool,
    "failure": (str, type(None)),
    "files": dict,
    "sha256": str,
}


@dataclass(frozen=True)
class StoredRun:
    """What :func:`check_run` found in ``<out>/<case>/<scheme>/``.

    ``problem`` is None for a sound run, else one line, ``<file>: <why>``; ``absent`` when nothing of
    the run is stored (not a damage: the run was never made there).  ``metrics`` and ``record`` are
    the stored ones for a sound run only.
    """

    case: str
    scheme: str
    path: Path
    problem: str | None = None
    absent: bool = False
    record: dict | None = None
    metrics: dict | None = None

    @property
    def sound(self) -> bool:
        return self.problem is None

    @property
    def failed(self) -> bool:
        """A sound run whose status the case counts as a failure."""
        return self.sound and bool(self.record.get("failed"))

    def shown(self) -> dict:
        """The metrics a page, a table or a gate shows: the stored ones, or for a damaged run a stand-in with
        status ``error`` and the damage as its reason (the run is on the page as damaged, not gone from it)."""
        if self.metrics is not None:
            return self.metrics
        why = f"damaged stored result: {self.problem}; re-run 'ftcreport batch' on the case to make it again"
        return {"case": self.case, "scheme": self.scheme, "status": "error", "reason": why, "damaged": self.problem,
                "null_reasons": {}}  # fmt: skip


def check_run(
    out: Path, case_name: str, scheme: str, key: str | None = None, case_hash: str | None = None
) -> StoredRun:
    """Whether ``<out>/<case>/<scheme>/`` holds a sound run: its record readable and of this run, this
    package version, ``key`` and ``case_hash`` (when given), and every file of the size and SHA-256 it
    records; the metrics a JSON table of this run."""
    d = Path(out) / case_name / scheme
    rp = d / RECORD

    def bad(problem: str, **kw: Any) -> StoredRun:
        return StoredRun(case_name, scheme, d, problem, **kw)

    if not rp.exists():
        if not any((d / f).exists() for f in RUN_FILES):
            return bad(f"{d}: not stored", absent=True)
        return bad(f"{rp}: missing (the run's files are there without their record: an interrupted store, or "
                   "one made before ftcreport kept records)")  # fmt: skip
    try:
        rec = json.loads(rp.read_bytes())
    except (OSError, ValueError) as exc:
        return bad(f"{rp}: unreadable ({_short(exc)})")
    if not isinstance(rec, dict):
        return bad(f"{rp}: unreadable (not a run record: a JSON {type(rec).__name__})")
    wrong = [k for k, t in _RECORD_FIELDS.items() if not _is(rec.get(k), t)]
    if wrong:
        return bad(f"{rp}: unreadable (not a run record: {', '.join(wrong)} missing or of another type)")
    if rec.get("format") != RECORD_FORMAT:
        return bad(f"{rp}: a record of format {rec.get('format')}, this ftcreport reads {RECORD_FORMAT}")
    if _seal({k: v for k, v in rec.items() if k != "sha256"}) != rec["sha256"]:
        return bad(f"{rp}: hash mismatch (its fields were changed after the run)")
    files = rec["files"]
    if not all(isinstance(files.get(f), dict) for f in RUN_FILES):
        return bad(f"{rp}: unreadable (not a run record: no size and hash of {', '.join(RUN_FILES)})")
    if (rec.get("case"), rec.get("scheme")) != (case_name, scheme):
        return bad(f"{rp}: the record of another run ({rec.get('case')} / {rec.get('scheme')})")
    if rec.get("package_version") != __version__:
        return bad(f"{rp}: stored by ftcreport {rec.get('package_version')}, this is {__version__}")
    if case_hash is not None and rec.get("case_hash") != case_hash:
        return bad(f"{rp}: made from another content of the case (its case hash {rec.get('case_hash')}, the case "
                   f"record's {case_hash})")  # fmt: skip
    if key is not None and rec.get("key") != key:
        return bad(f"{rp}: of another cache key ({rec.get('key')}, now {key}: the case, its scheme's engine or a "
                   "numeric library changed)")  # fmt: skip
    for name in RUN_FILES:
        p, want = d / name, files[name]
        try:
            size, digest = _file_digest(p)
        except FileNotFoundError:
            return bad(f"{p}: missing")
        except OSError as exc:
            return bad(f"{p}: unreadable ({_short(exc)})")
        if size != want.get("size"):
            short = isinstance(want.get("size"), int) and size < want["size"]
            why = (
                f"truncated ({size} of {want['size']} bytes)"
                if short
                else f"size {size} bytes, the record says {want.get('size')}"
            )
            return bad(f"{p}: {why}")
        if digest != want.get("sha256"):
            return bad(f"{p}: hash mismatch (SHA-256 differs from the record's: the file was changed after the run)")
    try:
        raw = (d / "metrics.json").read_bytes()
    except OSError as exc:
        return bad(f"{d / 'metrics.json'}: unreadable ({_short(exc)})")
    if hashlib.sha256(raw).hexdigest() != files["metrics.json"].get("sha256"):  # replaced since it was hashed
        return bad(f"{d / 'metrics.json'}: hash mismatch (SHA-256 differs from the record's: the file was changed)")
    try:
        metrics = json.loads(raw)
    except ValueError as exc:
        return bad(f"{d / 'metrics.json'}: unreadable ({_short(exc)})")
    if not isinstance(metrics, dict) or metrics.get("scheme") != scheme or not isinstance(metrics.get("status"), str):
        return bad(f"{d / 'metrics.json'}: not the metrics of {case_name} / {scheme}")
    return StoredRun(case_name, scheme, d, record=rec, metrics=metrics)


#: (size, SHA-256) of the files this process hashed, by path, with the (inode, size, mtime) they had: a
#: batch checks a run several times (cache decision, manifest, pages, table) and hashes a file once.
#: Every file of a run is replaced (a new inode), never written in place, so a changed file is hashed again.
_DIGESTS: dict[str, tuple[tuple[int, int, int], tuple[int, str]]] = {}


def _file_digest(p: Path) -> tuple[int, str]:
    """(size, SHA-256) of a file, from :data:`_DIGESTS` when it has not changed since it was hashed."""
    st = os.stat(p)
    stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
    known = _DIGESTS.get(str(p))
    if known is not None and known[0] == stamp:
        return known[1]
    h = hashlib.sha256()
    size = 0
    with open(p, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    result = (size, h.hexdigest())
    if size == st.st_size:
        _DIGESTS[str(p)] = (stamp, result)
    return result


def _short(exc: BaseException) -> str:
    return (getattr(exc, "strerror", None) or str(exc) or type(exc).__name__)[:160]


def stored_schemes(out: Path, case_name: str) -> list[str]:
    """The schemes with something of a run stored for a case, sound or not (built-in ones first, then
    plug-in ones by name)."""
    from ..cases import ordered_schemes

    d = Path(out) / case_name
    if not d.is_dir():
        return []
    found = sorted(p.name for p in d.iterdir() if p.is_dir() and any((p / f).exists() for f in (RECORD, *RUN_FILES)))
    return ordered_schemes(found)


def remove_run(out: Path, case_name: str, scheme: str) -> None:
    """Remove a stored run: the files made from it (:data:`DERIVED_FILES`) and its files first, its record
    last (an interruption leaves the record, of the earlier content, which the next batch removes again:
    studies.batch._dropped_schemes), then its directory when nothing else is in it."""
    d = Path(out) / case_name / scheme
    check_inside(d / RECORD)
    for name in (*DERIVED_FILES, *RUN_FILES, RECORD):
        with contextlib.suppress(FileNotFoundError):
            (d / name).unlink()
    with contextlib.suppress(OSError):
        d.rmdir()


def stored_runs(out: Path, case_name: str) -> dict[str, StoredRun]:
    """``{scheme: StoredRun}`` of every run stored for a case, each checked (:func:`check_run`) against the
    case record's content hash (``<case>/case.json``'s ``key``) when there is one."""
    rec = read_json(Path(out) / case_name / "case.json")
    case_hash = rec.get("key") if isinstance(rec, dict) and isinstance(rec.get("key"), str) else None
    return {s: check_run(out, case_name, s, case_hash=case_hash) for s in stored_schemes(out, case_name)}


def load_stored_case(out: Path, name: str, rec: dict):
    """The case as stored beside its runs (``<case>/case.toml``, with the record's ``--duration``), checked
    against the content hash its runs were made from (``case.json``'s key, which holds the plug-in files'
    contents too).  Raises :class:`FtcError` naming the file: unreadable, or changed after its runs (a hand
    edit, a plug-in file edited since): a page or an export from it would show another case than the
    one simulated."""
    import tomllib

    from .. import __version__
    from ..cases import parse_case, with_duration
    from ..cases.files import case_hash

    path = Path(out) / name / "case.toml"
    try:
        case = parse_case(tomllib.loads(path.read_text(encoding="utf-8")), rec.get("source", name))
    except (OSError, ValueError, FtcError) as exc:
        raise FtcError(
            f"{path}: the stored copy of {rec.get('source', name)} is damaged ({str(exc)[:200]}); re-run "
            "'ftcreport batch' or 'ftcreport run' on the case to store it again"
        ) from None
    case = case.model_copy(update={"name": name})
    if rec.get("duration_override"):
        case = with_duration(case, rec["duration_override"])
    key = rec.get("key")
    # the key was made by the version that stored the case (another version's runs are named as such by
    # check_run): the content is compared, not the package
    version = rec.get("package_version") if isinstance(rec.get("package_version"), str) else __version__
    if isinstance(key, str) and (now := case_hash(case, version)) != key:
        from .code_digest import code_digest

        stored_by, here = rec.get("code"), code_digest()
        if stored_by != here:  # the same file may hash otherwise under other code (a field joined the content)
            raise StoredCaseChangedError(
                f"{path}: its content hash is {now}, its runs' {key}, and they were stored by other code of "
                f"ftcreport (code digest {stored_by or 'not recorded'}, now {here}), which may hash a case "
                "otherwise (or the file, or one of its scheme files, changed since): not shown as theirs; re-run "
                "'ftcreport batch' on the case"
            )
        raise StoredCaseChangedError(
            f"{path}: changed after its runs (content hash {now}, the runs' {key}: the "
            "file or one of its scheme files was edited): not shown as theirs; re-run 'ftcreport batch' on the case"
        )
    return case


def deleted_runs(out: Path) -> list[str]:
    """A problem line per run a case's ``manifest.json`` lists (the runs its last batch or run stored, for
    the case content its record holds) whose directory is gone: a run deleted by hand would otherwise
    drop out of the pages and the exports without a word."""
    problems = []
    for rec_path in sorted(Path(out).glob("*/case.json")):
        rec, man = read_json(rec_path), read_json(rec_path.parent / "manifest.json")
        if not isinstance(rec, dict) or not isinstance(man, dict) or rec.get("status") != "ok":
            continue
        name = rec_path.parent.name
        if (man.get("cases") or {}).get(name) != rec.get("key") or not isinstance(man.get("runs"), list):
            continue  # a manifest of another content of the case
        for r in man["runs"]:
            s = r.get("scheme") if isinstance(r, dict) else None
            if not isinstance(s, str) or not s or r.get("not_stored") or not r.get("key"):
                continue  # a run the environment failed was never stored (batch._run_record)
            d = Path(out) / name / s
            if not any((d / f).exists() for f in (RECORD, *RUN_FILES)):
                problems.append(
                    f"{Path(out) / name / s}: missing (the case's manifest.json lists its run, stored on "
                    f"{str(man.get('created', '?'))[:10]}; its directory was deleted): not shown or exported; "
                    "re-run 'ftcreport batch' on the case"
                )
    return problems


def edited_cases(out: Path) -> list[str]:
    """A problem line per recorded case whose stored case file no longer is the one its runs were made
    from (:func:`load_stored_case`)."""
    problems = []
    for rec_path in sorted(Path(out).glob("*/case.json")):
        rec = read_json(rec_path)
        if not isinstance(rec, dict) or rec.get("status") != "ok" or not (rec_path.parent / "case.toml").exists():
            continue
        try:
            load_stored_case(out, rec_path.parent.name, rec)
        except FtcError as exc:
            problems.append(str(exc))
    return problems


def unrecorded_cases(out: Path) -> list[str]:
    """A problem line per case directory under ``out`` that holds stored runs but no readable case record
    (``<case>/case.json`` deleted or damaged): its runs would be left out of the pages and the exports
    without a word.  The case record is written by ``batch`` (studies.batch.record_case)."""
    out = Path(out)
    problems = []
    for d in sorted(p for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")) if out.is_dir() else []:
        runs = stored_schemes(out, d.name)
        if not runs:
            continue
        rec_path = d / "case.json"
        if not rec_path.exists():
            why = "missing"
        elif not isinstance(read_json(rec_path), dict):
            why = "unreadable or not a case record"
        else:
            continue
        problems.append(
            f"{rec_path}: {why}: the case's {len(runs)} stored run(s) ({', '.join(runs)}) are not shown or exported "
            "(run 'ftcreport batch' on its case file again)"
        )
    return problems


def read_json(path: Path) -> Any:
    """The content of a JSON file, or None when it is missing, unreadable or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def load_metrics(out: Path, case_name: str, scheme: str) -> dict | None:
    """The metrics of a sound stored run (:func:`check_run`), or None."""
    return check_run(out, case_name, scheme).metrics


def stored_metrics(out: Path, case_name: str) -> dict[str, dict]:
    """``{scheme: metrics}`` of the case's stored runs, in scheme order (plug-ins last): a sound run's
    ``metrics.json``, a damaged run's stand-in (status ``error``, the damage as reason: :meth:`StoredRun.shown`)."""
    return {s: r.shown() for s, r in stored_runs(out, case_name).items()}


def load_timeseries(out: Path, case_name: str, scheme: str) -> dict[str, np.ndarray] | None:
    """The arrays of a sound stored run (its record matches its files), or None."""
    if not check_run(out, case_name, scheme).sound:
        return None
    try:
        with np.load(Path(out) / case_name / scheme / "timeseries.npz") as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
        return None


# ------------------------------------------------------------------ one writer per output directory
class OutputBusyError(FtcError):
    """Another ftcreport process is writing to the same output directory."""

    exit_code = 2


class OutputError(FtcError):
    """An output directory ftcreport must not write as asked (a symbolic link leaving it, another command's)."""

    exit_code = 2


KIND_NAME = ".ftcreport.kind"  # which command family's results a directory holds (see output_lock)
#: the family of each locking command: commands of one family share a directory's layout
KINDS = {"batch": "results", "run": "results", "check": "results", "report": "results", "export": "results"}
KINDS |= {"sample": "campaign"}  # ftcreport sample: a campaign's sample pages
KINDS |= {"baseline save": "baseline"}  # ftcreport baseline save --dest: a baseline's directory
KINDS |= {"export --dest": "export"}  # ftcreport export --dest: netCDF files and a table, never over a batch's
_HOMES = {
    "results": "reports",
    "campaign": "reports/campaigns/<case>",
    "coverage": "reports/coverage/<case>",
    "fdi": "reports/fdi/<case>",
}

_held: dict[str, list] = {}  # resolved directory -> [lock file descriptor, depth] (re-entrant in one process)


def check_apart(dest: Path, out: Path, option: str = "--dest") -> None:
    """Refuse a directory to write (``dest``, a baseline's or an export's) that is the results directory ``out``
    or inside it (OutputError): its files would land in the results tree, or in a stored run's folder.  Checked
    before anything runs: the lock of ``out`` is re-entrant, so a ``dest`` equal to it would skip the check of
    the directory's kind (:func:`output_lock`)."""
    d, o = Path(dest).resolve(), Path(out).resolve()
    if d == o or o in d.parents:
        where = "is --out itself" if d == o else "is inside --out"
        raise OutputError(
            f"{dest}: {option}: {where} ({out}, the stored results it reads): its files would be mixed into "
            f"the results tree; choose a directory outside it"
        )


@contextlib.contextmanager
def output_lock(out: Path, command: str, option: str = "--out"):
    """Hold the exclusive lock of an output directory (``<out>/.ftcreport.lock``, ``flock``).

    Two processes never write to the same directory at once: the second one fails at
    once with :class:`OutputBusyError` naming the holder.  The kernel drops the lock when
    the last process holding it exits, however it exits (SIGKILL included), so no stale lock
    remains; a batch's worker processes hold it with their parent (:func:`lock_fd`), so it is
    free only once every one of them is gone.  Re-entrant within one process (``batch``
    renders the report under its own lock).

    The lock file is opened without following a symbolic link and must be a regular file with
    one link: its holder text is never written into another file.  Under the lock, the directory
    is claimed for the command's family (:data:`KINDS`; ``<out>/.ftcreport.kind``): a campaign,
    coverage map or FDI evaluation never writes into a batch's directory or another family's
    (:class:`OutputError`), and no file is written through a symbolic link below ``out``
    (:func:`write_atomic`).  On leaving, the temporary files of writers killed meanwhile are
    removed; the lock is released last.
    """
    out = Path(out)
    key = str(out.resolve())
    if key in _held:
        _held[key][1] += 1
        try:
            yield
        finally:
            _held[key][1] -= 1
        return
    created = not out.exists()
    fd = _acquire(out, option)
    roots = _confine(out)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"ftcreport {command} (pid {os.getpid()})".encode(), 0)
        _held[key] = [fd, 1]
        _claim(out, KINDS.get(command, command), command, option)
        clean_partial(out)
        yield
    finally:
        with shielded():  # a stop signal meanwhile does not cut this short
            _release(out, key, fd, roots, created)


def _release(out: Path, key: str, fd: int, roots: list[str], created: bool) -> None:
    """Leave ``out``: a killed writer's temporary files removed, then the lock released (last)."""
    _held.pop(key, None)
    with contextlib.suppress(OSError):
        clean_partial(out)  # a terminated worker's temporary files (this command's writers are gone)
    for r in roots:
        _roots[r] -= 1
        if not _roots[r]:
            del _roots[r]
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        if created and _untouched(out):  # a command refused before it wrote anything leaves nothing
            for name in (KIND_NAME, LOCK_NAME):  # removed while locked: see _acquire
                (out / name).unlink(missing_ok=True)
    os.close(fd)  # releases the flock (once no worker holds it either)
    if created:
        with contextlib.suppress(OSError):
            out.rmdir()  # only when empty


def _acquire(out: Path, option: str = "--out") -> int:
    """Open ``out``'s lock file and take its lock (non-blocking); its descriptor, or OutputBusyError.

    A holder that created ``out`` and wrote nothing removes the lock file before it releases it: a
    lock taken on a file no longer at ``out/.ftcreport.lock`` is dropped and taken again on the new one.
    """
    import fcntl

    for _ in range(10):
        out.mkdir(parents=True, exist_ok=True)
        path = out / LOCK_NAME
        try:
            fd = _open_lock(path)
        except FileNotFoundError:  # the directory was removed meanwhile (see above): make it again
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            # the holder writes its name just after it takes the lock: wait a moment for it
            holder = ""
            for _ in range(50):
                holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip()
                if holder:
                    break
                time.sleep(0.01)
            holder = holder or "another process"
            os.close(fd)
            raise OutputBusyError(
                f"{out}: {option}: in use by {holder}; wait for it to finish or choose another {option} "
                "(one ftcreport process writes to an output directory at a time)"
            ) from None
        try:
            now = os.stat(path, follow_symlinks=False)
        except OSError:
            now = None
        mine = os.fstat(fd)
        if now is not None and (now.st_dev, now.st_ino) == (mine.st_dev, mine.st_ino):
            return fd
        os.close(fd)  # the file was removed after this process opened it
    raise OutputBusyError(f"{out}: --out: its lock file keeps being replaced; another process is cleaning it up")


def _untouched(out: Path) -> bool:
    """``out`` holds nothing but its lock and kind files."""
    return set(os.listdir(out)) <= {LOCK_NAME, KIND_NAME}


def locked(command: str):
    """Decorator: the function runs under ``output_lock(out, command)``, ``out`` being its argument of that name.

    For the library functions that write a directory (``run_campaign``, ``run_coverage``, ``run_fdi``);
    the CLI holds the same lock around them and their page (the lock is re-entrant).
    """
    import functools
    import inspect

    def wrap(fn):
        sig = inspect.signature(fn)

        @functools.wraps(fn)
        def under_lock(*args, **kwargs):
            with output_lock(Path(sig.bind(*args, **kwargs).arguments["out"]), command):
                return fn(*args, **kwargs)

        return under_lock

    return wrap


def lock_fd(out: Path) -> int | None:
    """The descriptor of the lock this process holds on ``out`` (None when it holds none).

    A batch hands it to its worker processes (:mod:`multiprocessing.reduction` ``DupFd``): they hold
    the same lock, so the kernel releases it only when the batch and all its workers are gone.
    """
    held = _held.get(str(Path(out).resolve()))
    return None if held is None else held[0]


def _open_lock(path: Path) -> int:
    """Open (or create) a lock file without following a symbolic link; refuse anything but a plain file."""
    import errno
    import stat

    flags = os.O_RDWR | os.O_CREAT | os.O_CLOEXEC
    flags |= getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP or os.path.islink(path):
            raise OutputError(
                f"{path}: the lock file is a symbolic link (to {_link_target(path)}); ftcreport never writes "
                "through it: remove it"
            ) from None
        raise
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        os.close(fd)
        what = "has other hard links" if stat.S_ISREG(st.st_mode) else "is not a regular file"
        raise OutputError(f"{path}: the lock file {what}; ftcreport never writes into another file: remove it")
    return fd


def _link_target(path: Path) -> str:
    try:
        return os.readlink(path)
    except OSError:
        return "?"


def _claim(out: Path, kind: str, command: str, option: str = "--out") -> None:
    """Mark ``out`` as holding ``kind`` results, or refuse when it holds another family's (OutputError);
    ``option``: the command's option that named ``out``."""
    marker = out / KIND_NAME
    mine = _marker(out)
    held = (mine or _legacy_kind(out)) if not _untouched(out) else None  # an empty directory is anyone's
    if kind == "export" and held == "results" and _legacy_kind(out) is None:
        held = None  # an export made before it had a family of its own: no case results, no page there
    if held is not None and held != kind:
        if kind == "export":
            option, files, home = "--dest", "metrics.parquet and netCDF files", "an empty directory, or no --dest"
        else:
            files, home = "files", _HOMES.get(kind)
        raise OutputError(
            f"{out}: {option}: holds the results of another kind of command ({_describe(held)}); ftcreport "
            f"{command.split()[0]} writes {_describe(kind)}, which would overwrite or mix with its {files}: "
            f"choose another {option}" + (f" (the default is {home})" if home else "")
        )
    if mine != kind:
        write_atomic(marker, f"{kind}\n".encode())


def kind_of(out: Path) -> str | None:
    """The family of results ``out`` holds ("results", "campaign", ...), or None (not a directory of ours)."""
    if not Path(out).is_dir():
        return None
    return _marker(Path(out)) or _legacy_kind(Path(out))


def _marker(out: Path) -> str:
    """The kind marker's text in ``out`` ("" when absent, unreadable or a symbolic link)."""
    marker = out / KIND_NAME
    try:
        return marker.read_text(encoding="utf-8", errors="replace").strip() if not marker.is_symlink() else ""
    except OSError:
        return ""


def _describe(kind: str) -> str:
    return {
        "results": "case results of batch/run",
        "campaign": "a campaign",
        "coverage": "a coverage map",
        "fdi": "an FDI evaluation",
        "export": "an export (netCDF files and metrics.parquet)",
    }.get(kind, kind)


def _legacy_kind(out: Path) -> str | None:
    """The family of a directory written before the kind marker existed (its manifest, its files), or None."""
    manifest = read_json(out / "manifest.json")
    kind = manifest.get("kind") if isinstance(manifest, dict) else None
    if isinstance(kind, str):
        return KINDS.get(kind, kind)
    for k in ("campaign", "coverage", "fdi"):
        if (out / f"{k}.json").is_file():
            return k
    if next(out.glob("*/case.json"), None) is not None or (out / "index.html").exists():
        return "results"
    return None


# ------------------------------------------------------------------ writes stay inside --out
_roots: dict[str, int] = {}  # absolute paths of the output directories this process writes -> uses
_write_guard: list = [None]  # a worker's check that it still may write (set_write_guard)


def _confine(out: Path) -> list[str]:
    """Register ``out`` (as given and resolved): :func:`write_atomic` refuses a symbolic link below it."""
    roots = list(dict.fromkeys([os.path.abspath(out), str(Path(out).resolve())]))
    for r in roots:
        _roots[r] = _roots.get(r, 0) + 1
    return roots


def confine(out: Path) -> None:
    """Refuse writes through a symbolic link below ``out`` in this process (a worker writing for a batch)."""
    _confine(out)


def set_write_guard(may_write) -> None:
    """``may_write()`` is asked before every :func:`write_atomic` in this process, and again before its
    rename: when it says False (a worker whose batch is gone), the process exits at once, its
    temporary file removed: it writes nothing more."""
    _write_guard[0] = may_write


def _check_may_write(tmp: str | None = None) -> None:
    if _write_guard[0] is not None and not _write_guard[0]():
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        os._exit(1)


def check_inside(path: Path) -> None:
    """Refuse (:class:`OutputError`) a path below a registered output directory that passes through a
    symbolic link below it (a case folder linked elsewhere): results never leave ``--out``."""
    import stat

    p = os.path.abspath(path)
    for root in _roots:
        if not p.startswith(root.rstrip(os.sep) + os.sep):
            continue
        cur = root
        for part in Path(p[len(root) :].lstrip(os.sep)).parts[:-1]:
            cur = os.path.join(cur, part)
            try:
                st = os.lstat(cur)
            except FileNotFoundError:
                break
            if stat.S_ISLNK(st.st_mode):
                raise OutputError(
                    f"{cur}: is a symbolic link (to {_link_target(Path(cur))}) inside the output directory {root}; "
                    "ftcreport writes results only inside --out: remove the link or choose another --out"
                )


def clean_partial(out: Path) -> int:
    """Remove the temporary files a killed writer left (call with the lock held); returns how many."""
    n = 0
    for root, dirs, files in os.walk(out):
        # a nested output directory (reports/campaigns/<case>) has its own lock and writer: not ours
        dirs[:] = [d for d in dirs if not (Path(root) / d / LOCK_NAME).exists()]
        for f in files:
            if f.startswith(".") and f.endswith(TMP_SUFFIX):
                with contextlib.suppress(OSError):
                    (Path(root) / f).unlink()
                    n += 1
    return n
