"""Fuzzer (issue 23): every field of every shipped case, mutated, through the CLI.

Each example takes one case of the corpus, mutates it (a field replaced by a value of another
type, NaN, inf, a negative, zero or huge number, an empty list, a table; a field deleted;
an unknown key added; or the file's bytes truncated, broken by non-UTF-8 bytes or
overwritten) and runs ``ftcreport cases validate`` and ``ftcreport run --duration 1`` on it
in this process (typer's CliRunner).  Every mutant must end

* without a traceback and with a documented exit code (validate: 0 or 2; run: 0, 1 or 2);
* with a message naming the file when it fails (``ftcreport: error: <file>: ...``);
* within a per-example deadline (a hang fails the test through SIGALRM);
* with every written ``metrics.json`` free of NaN/inf and every null explained in ``null_reasons``.

The corpus is every shipped case: ``cases/*.toml`` and the DC-motor overlays ``cases/motors/*.toml``,
their relative paths (``plugins``, ``base_case``) made absolute so a mutant written elsewhere still
finds its scheme file and its base.  The motor overlays get every ``[actuators]`` field written out
(the shipped ones take the defaults, so there would be nothing to mutate) and
``measurement_delay``; ``motor_faults`` is two_link_switching_motors resolved over its base with one
event of every motor-fault kind inside the first second (the runs last 1 s), per-robot motor lists
and a one-sample measurement delay.  Half the examples draw a motor case, and a quarter of those
apply a targeted motor mutation (:func:`_motor_mutation`: a sample_time off the step grid or beyond
the run, a delay that is negative, fractional or longer than the run, a motor fault with a missing,
superfluous or out-of-range value, a method name, etd2 without motors, ...).

CI runs ``FUZZ_EXAMPLES`` examples (default 60, derandomized so CI is reproducible; about
a minute on one core).  ``FUZZ_EXAMPLES=2000 pytest -n 0 tests/test_fuzz.py -s`` runs more,
with fresh random draws (``FUZZ_LOG=file`` appends one JSON line per example, with its time;
``FUZZ_KEEP_GOING=1`` logs a failing example and goes on, failing the test at the end with the list,
instead of stopping at the first and shrinking it; ``FUZZ_RENDER_ALL=1`` also renders the slow pages
of the five-link and Table 4.2 cases).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import re
import signal
import time
import tomllib
import traceback
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from ftcreport.cases import Actuators, resolve_overlay
from ftcreport.cli import app
from ftcreport.model.faults import MOTOR_KINDS

CASES = Path(__file__).resolve().parents[1] / "cases"


def _absolute(data: dict, where: Path) -> dict:
    """``data`` with its relative ``plugins`` and ``base_case`` paths made absolute (from ``where``)."""
    out = dict(data)
    if "plugins" in out:
        out["plugins"] = [str((where / p).resolve()) for p in out["plugins"]]
    if "base_case" in out:
        out["base_case"] = str((where / out["base_case"]).resolve())
    return out


def _written(table: dict) -> dict:
    """A table's fields as TOML writes them: those set (None is no TOML value), sub-tables likewise."""
    return {k: _written(v) if isinstance(v, dict) else v for k, v in table.items() if v is not None}


def _motor_overlay(path: Path) -> dict:
    """A shipped motor overlay with every [actuators] field and measurement_delay written out."""
    data = _absolute(tomllib.loads(path.read_text()), path.parent)
    fields = _written(Actuators().model_dump())
    data["actuators"] = {**fields, "I_max": 400.0, **data.get("actuators", {})}
    data["simulation"] = {**data["simulation"], "measurement_delay": 0}
    return data


def _motor_faults() -> dict:
    """two_link_switching_motors resolved over its base, with a motor fault of every kind before 1 s."""
    path = CASES / "motors" / "two_link_switching_motors.toml"
    over = tomllib.loads(path.read_text())
    data = resolve_overlay(path, over)
    data.pop("base_case")
    data["actuators"] = {
        "R_a": [0.365, 0.4],
        "L_a": 0.161e-3,
        "k_m": [0.123, 0.123],
        "k_b": 0.123,
        "N": 20.0,
        "eta_g": [0.75, 0.7],
        "J_m": 1340e-7,
        "b_m": 9.25e-5,
        "V_max": [48.0, 48.0],
        "I_max": 400.0,
    }
    data["faults"] = [
        {"time": 0.1, "wheel": "2l", "motor": "short"},
        {"time": 0.2, "wheel": "1r", "motor": "stuck", "value": -12.0},
        {"time": 0.3, "wheel": "2l", "motor": "none"},
        {"time": 0.4, "wheel": "1l", "motor": "km_loss", "value": 0.4},
        {"time": 0.5, "wheel": "2r", "motor": "resistance", "value": 3.0},
        {"time": 0.6, "wheel": "2r", "motor": "open"},
        {"time": 0.7, "wheel": "1r", "sigma": 0.5, "ubar": 0.1},
    ]
    data["simulation"] = {**data["simulation"], "measurement_delay": 1}
    data["claims"] = []  # they are about the shipped case's faults
    return data


SHIPPED = {p.stem: _absolute(tomllib.loads(p.read_text()), p.parent) for p in sorted(CASES.glob("*.toml"))}
MOTORS = {p.stem: _motor_overlay(p) for p in sorted((CASES / "motors").glob("*.toml"))}
MOTORS["motor_faults"] = _motor_faults()
CORPUS = {**SHIPPED, **MOTORS}
EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "60"))
LONG = "FUZZ_EXAMPLES" in os.environ
# per example: validate + a 1 s run (+ its page), and the first compile of a loop variant the example is the
# first to need: a cold compile took up to 122.5 s on the shared 2-core machine (docs/ENGINE.md), and an
# example at 120 s failed there on a compile still in LLVM's passes; a hang runs for ever, so 300 s still
# tells one
DEADLINE_S = 300
# pages whose render derives the chained form for n = 5 (sympy, ~30 s once) and its frozen-pole
# analysis (~10 s a page) or the Table 4.2 analyses: rendered only with FUZZ_RENDER_ALL=1
SLOW_PAGES = {"five_link_cascade", "three_link_active"}
RENDER_ALL = os.environ.get("FUZZ_RENDER_ALL") == "1"
# FUZZ_KEEP_GOING=1: a failing example is logged (FUZZ_LOG) and listed at the end instead of stopping the run
KEEP_GOING = os.environ.get("FUZZ_KEEP_GOING") == "1"
FAILURES: list[dict] = []
LOG = os.environ.get("FUZZ_LOG")  # a file: one JSON line per example (counts survive an interrupted run)
VALIDATE_CODES = {0, 2}
RUN_CODES = {0, 1, 2}
runner = CliRunner()


def _paths(obj, prefix=()):
    """Every key path (tables, their keys, list items) of a parsed case."""
    out = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.append((*prefix, k))
            out.extend(_paths(v, (*prefix, k)))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.append((*prefix, i))
            out.extend(_paths(v, (*prefix, i)))
    return out


PATHS = {name: _paths(data) for name, data in CORPUS.items()}

SPECIAL = [
    math.nan,
    math.inf,
    -math.inf,
    0,
    0.0,
    -0.0,
    -1,
    -1.0,
    1e-300,
    1e300,
    -1e300,
    2**63 - 1,
    -(2**63),
    10**30,
    True,
    False,
    "",
    "x",
    "\x00",
    "é" * 80,
    "a" * 300,
    "<script>",
    "../x",
    [],
    [0.0],
    [math.nan, 1.0],
    [[]],
    {},
    {"unknown_key": 1},
    datetime.date(2020, 1, 1),
]
VALUES = st.one_of(
    st.sampled_from(SPECIAL),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.text(max_size=12),
    st.lists(st.floats(min_value=-1e6, max_value=1e6), max_size=4),
)


def _set(data, path, value):
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


def _delete(data, path):
    node = data
    for p in path[:-1]:
        node = node[p]
    if isinstance(node, dict):
        node.pop(path[-1], None)
    else:
        del node[path[-1]]


_ACT_FIELDS = list(Actuators.model_fields)
_ACT_VALUES = [0.0, -1.0, math.nan, math.inf, 1e-300, 1e300, 1e4, [1.0], [1.0, math.nan], [1.0, 2.0, 3.0], "1", True]


def _motor_mutation(draw, data: dict) -> str:
    """A mutation that matters for the motor cases (sampling, delay, motor faults, method), applied to
    ``data`` (a motor case of the corpus); its label."""
    sim = data["simulation"]
    dt = sim["dt"]
    what = draw(st.sampled_from(["sample_time", "delay", "method", "no_motors", "motor_fault", "actuator"]))
    if what == "sample_time":
        value = draw(st.sampled_from([0.5 * dt, 1.5 * dt, 2.0000001 * dt, 3 * dt, 0.999 * dt, 0.9, 1.0, 5.0, 9.99]))
        sim["sample_time"] = value
        return f"simulation.sample_time = {value!r} (dt = {dt})"
    if what == "delay":
        value = draw(st.sampled_from([-1, 1, 2, 1.5, 199, 200, 201, 1000, 1001, 10**9, "1", True]))
        sim["measurement_delay"] = value
        return f"simulation.measurement_delay = {value!r}"
    if what == "method":
        value = draw(st.sampled_from(["rk4", "ros2", "etd2", "ETD2", "etd", "exp", ""]))
        sim["method"] = value
        return f"simulation.method = {value!r}"
    if what == "no_motors":
        data.pop("actuators", None)
        if draw(st.booleans()):
            sim.pop("sample_time", None)
        return f"etd2 without [actuators] (sample_time {'kept' if 'sample_time' in sim else 'dropped'})"
    if what == "motor_fault":
        kind = draw(st.sampled_from([*MOTOR_KINDS, "melted", "Short", 3]))
        value = draw(st.sampled_from([None, math.nan, 0.0, -1.0, 0.5, 1.0, 1000.0, 1001.0, 1e300, -1e5, True, "x"]))
        time = draw(st.sampled_from([0.0, 0.25, 0.5, 0.999]))
        wheel = draw(st.sampled_from(["1r", "1l", "2r", "2l", "3l", "9r"]))
        event = {"time": time, "wheel": wheel, "motor": kind}
        if value is not None:
            event["value"] = value
        if draw(st.booleans()):
            event["sigma"] = 0.5
        faults = [f for f in data.get("faults", []) if f["time"] < time] + [event]
        data["faults"] = faults + [f for f in data.get("faults", []) if f["time"] >= time]
        return f"faults += {event!r}"
    key = draw(st.sampled_from(_ACT_FIELDS))
    value = draw(st.sampled_from(_ACT_VALUES))
    data.setdefault("actuators", {})[key] = value
    return f"actuators.{key} = {value!r}"


@st.composite
def mutants(draw):
    """(case stem, file bytes, a label of the mutation)."""
    group = MOTORS if draw(st.booleans()) else SHIPPED
    name = draw(st.sampled_from(sorted(group)))
    data = json.loads(json.dumps(CORPUS[name]))  # deep copy (the corpus holds only JSON types)
    kinds = ["replace", "replace", "replace", "replace", "delete", "unknown", "bytes"]
    kind = draw(st.sampled_from(kinds + ["motor"] * 2 if group is MOTORS else kinds))
    paths = PATHS[name]
    if kind == "motor":
        label = _motor_mutation(draw, data)
    elif kind == "replace":
        path = draw(st.sampled_from(paths))
        value = draw(VALUES)
        _set(data, path, value)
        label = f"{'.'.join(map(str, path))} = {value!r:.60}"
    elif kind == "delete":
        path = draw(st.sampled_from(paths))
        _delete(data, path)
        label = f"del {'.'.join(map(str, path))}"
    elif kind == "unknown":
        tables = [()] + [p for p in paths if isinstance(_get(data, p), dict)]
        where = draw(st.sampled_from(tables))
        _set(data, (*where, "unknown_field"), draw(VALUES))
        label = f"unknown key in {'.'.join(map(str, where)) or '<root>'}"
    try:
        raw = tomli_w.dumps(data).encode()
    except (TypeError, ValueError):  # a value TOML cannot hold: write the unmutated case
        raw = tomli_w.dumps(CORPUS[name]).encode()
        label += " (not TOML-encodable; unmutated)"
    if kind == "bytes":
        op = draw(st.sampled_from(["truncate", "non-utf8", "overwrite", "nul"]))
        at = draw(st.integers(min_value=0, max_value=len(raw)))
        if op == "truncate":
            raw = raw[:at]
        elif op == "non-utf8":
            raw = raw[:at] + draw(st.sampled_from([b"\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\x80\x80"])) + raw[at:]
        elif op == "nul":
            raw = raw[:at] + b"\x00" + raw[at:]
        else:
            junk = draw(st.binary(min_size=1, max_size=16))
            raw = raw[:at] + junk + raw[at + len(junk) :]
        label = f"bytes: {op} at {at}"
    return name, raw, label


def _get(data, path):
    node = data
    for p in path:
        node = node[p]
    return node


class _HangError(Exception):
    pass


def _alarm(signum, frame):
    raise _HangError(f"example took longer than {DEADLINE_S} s")


def _check_failure_message(res, path: Path, label: str) -> None:
    assert "Traceback" not in res.output, (label, res.output)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    assert errors, (label, res.stderr)
    assert all(str(path) in ln for ln in errors), (label, errors)


#: what may follow ``<file>: `` in a refusal: a field path (``faults[2].wheel``), or the file itself is unreadable
_FIELD = re.compile(r"(<root>|[^\s:\[\]][^\s:]*): \S")
_FILE_LEVEL = ("not valid TOML", "not UTF-8 text", "cannot read", "not a regular file", "too large")


def _check_names_a_field(res, path: Path, label: str) -> None:
    """Every line of a refused file names the field (the project's standard), unless the file is not TOML."""
    for ln in res.stderr.splitlines():
        rest = ln.removeprefix(f"ftcreport: error: {path}: ")
        if rest == ln or rest.startswith(_FILE_LEVEL):
            continue
        assert _FIELD.match(rest), (label, ln)


def _reject_constant(c):
    raise ValueError(f"non-finite number {c} in metrics.json")


def _check_metrics(out: Path, label: str) -> int:
    n = 0
    for f in out.rglob("metrics.json"):
        m = json.loads(f.read_text(), parse_constant=_reject_constant)
        assert isinstance(m.get("null_reasons"), dict), (label, f)
        nulls = _nulls(m)
        assert nulls <= set(m["null_reasons"]), (label, f, nulls - set(m["null_reasons"]))
        n += 1
    return n


def _nulls(v, path: str = "") -> set[str]:
    if isinstance(v, dict):
        out: set[str] = set()
        for k, x in v.items():
            if k not in ("null_reasons", "reason", "traceback", "description", "verify_dt"):
                out |= _nulls(x, f"{path}.{k}" if path else k)
        return out
    if isinstance(v, list):
        out = set()
        for i, x in enumerate(v):
            out |= _nulls(x, f"{path}[{i}]")
        return out
    return {path} if v is None else set()


COUNTS: dict[str, int] = {}


@settings(
    max_examples=EXAMPLES,
    deadline=datetime.timedelta(seconds=DEADLINE_S),
    derandomize=not LONG,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
    database=None,
)
@given(mutant=mutants())
def test_mutated_cases_never_crash(mutant, tmp_path_factory):
    name, raw, label = mutant
    d = tmp_path_factory.mktemp("fuzz")
    path = d / f"{name}.toml"
    path.write_bytes(raw)
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(DEADLINE_S)
    start = time.perf_counter()
    rec = {"case": name, "mutation": label}
    try:
        _check_one(path, name, label, d / "out", rec)
    except (AssertionError, _HangError) as exc:
        if not KEEP_GOING:
            raise
        rec["failure"] = repr(exc)[:2000]
        FAILURES.append(rec)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    rec["seconds"] = round(time.perf_counter() - start, 2)
    if LOG:
        with open(LOG, "a") as fh:
            fh.write(json.dumps(rec) + "\n")
    if "failure" not in rec:
        key = f"validate={rec['validate']} run={rec['run']}"
        COUNTS[key] = COUNTS.get(key, 0) + 1
        COUNTS["metrics_files"] = COUNTS.get("metrics_files", 0) + rec["metrics"]


def _check_one(path: Path, name: str, label: str, out: Path, rec: dict) -> None:
    """validate and run one mutant; its exit codes and metrics count into ``rec``."""
    res = runner.invoke(app, ["cases", "validate", str(path)])
    rec["validate"] = res.exit_code
    assert res.exit_code in VALIDATE_CODES, (label, res.exit_code, res.output, _trace(res))
    if res.exit_code != 0:
        _check_failure_message(res, path, label)
        _check_names_a_field(res, path, label)
    args = ["run", str(path), "--duration", "1", "--out", str(out), "-q"]
    if name in SLOW_PAGES and not RENDER_ALL:
        args.append("--no-report")
    run = runner.invoke(app, args)
    rec["run"] = run.exit_code
    if run.exit_code:
        rec["error"] = next((ln for ln in run.stderr.splitlines() if ln.startswith("ftcreport: error:")), "")[:400]
    if isinstance(run.exception, _HangError):
        raise run.exception
    assert run.exit_code in RUN_CODES, (label, run.exit_code, run.output, _trace(run))
    if run.exit_code != 0:
        _check_failure_message(run, path, label)
    if res.exit_code == 2:
        assert run.exit_code == 2, (label, run.output)  # an invalid file is refused by run too
    rec["metrics"] = _check_metrics(out, label) if out.exists() else 0


def _trace(res) -> str:
    """The last lines of the traceback of an exception the CLI did not handle ('' when none)."""
    if res.exc_info is None or isinstance(res.exception, SystemExit):
        return ""
    return "".join(traceback.format_exception(*res.exc_info)[-3:])


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_the_corpus_validates_unmutated(name, tmp_path):
    """Every corpus case is valid as written (its scheme file and base found): the mutants start from a live case."""
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(CORPUS[name]))
    res = runner.invoke(app, ["cases", "validate", str(path)])
    assert res.exit_code == 0, res.output


@pytest.fixture(scope="module", autouse=True)
def _report_counts():
    yield
    for rec in FAILURES:
        print(f"\nfuzz failure: {rec}")
    if COUNTS:
        total = sum(v for k, v in COUNTS.items() if k.startswith("validate="))
        print(f"\nfuzz: {total} examples; " + ", ".join(f"{k}: {v}" for k, v in sorted(COUNTS.items())))
    if FAILURES:
        pytest.fail(f"{len(FAILURES)} failing examples (FUZZ_KEEP_GOING=1), listed above")


@pytest.mark.slow
@settings(
    max_examples=max(1, EXAMPLES // 100),
    deadline=None,
    derandomize=not LONG,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
    database=None,
)
@given(batch=st.lists(mutants(), min_size=8, max_size=8))
def test_mutated_cases_through_one_batch(batch, tmp_path_factory):
    """Eight mutants in one ``batch`` (worker processes): exit 0, 1 or 2 (a file refused), every rejected file named."""
    d = tmp_path_factory.mktemp("fuzzbatch")
    paths = []
    for i, (name, raw, _) in enumerate(batch):
        p = d / f"m{i}_{name}.toml"
        p.write_bytes(raw)
        paths.append(p)
    out = d / "out"
    res = runner.invoke(app, ["batch", *map(str, paths), "--out", str(out), "--duration", "1", "--jobs", "1", "-q"])
    labels = [b[2] for b in batch]
    assert res.exit_code in (0, 1, 2), (labels, res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output, labels
    for p in paths:
        if runner.invoke(app, ["cases", "validate", str(p)]).exit_code != 0:
            assert f"ftcreport: error: {p}" in res.stderr, (p, res.stderr)
    _check_metrics(out, "; ".join(labels))
    assert (out / "index.html").exists()


# ------------------------------------------------------------------ stored results (issue 34)
# A stored batch (one case, two runs) is damaged the ways a disk, a copy or a hand can damage it, then
# read back: ``report`` must name every damaged run and exit 1 (an undamaged store: 0), never exit 3
# or drop a run silently; the batch's cache decision (ftcreport.storage.store.check_run with the run's key) must
# re-run exactly the damaged runs; for a few examples ``batch`` itself re-runs them and the store is
# whole again.  FUZZ_STORED_EXAMPLES (default 16, about 3.5 s each: report renders the page, export
# writes netCDF) sets the count; a tenth of them (at least 2) also go through ``batch`` (about 18 s each:
# a worker starts and loads the compiled loop).  30 + 3 examples took 109 + 54 s on 2 shared cores.
STORED_EXAMPLES = int(os.environ.get("FUZZ_STORED_EXAMPLES", "16"))
STORED_BATCHES = max(2, STORED_EXAMPLES // 10)
STORED_CASE = {
    "name": "st",
    "robots": {"n": 2, "d": 1.7},
    "reference": {"kind": "unicycle", "v_d": 0.5, "omega_d": 0.1},
    "initial": {"x": 0.1, "y": 0.05},
    "kinematic": {"kind": "two_link", "k1": 10.0, "k2": 2.0, "k3": 0.5},
    "schemes": {"run": ["nominal", "oracle"], "nominal": {"k_v": 5.0}, "oracle": {"k_v": 5.0}},
    "simulation": {"dt": 0.01, "duration": 0.5},
    "thresholds": {"oracle": {"position_error_final": {"max": 1.0}}},
}
STORED_RUNS = ("nominal", "oracle")
STORED_FILES = ("metrics.json", "timeseries.npz", "record.json")
WRONG_JSON = [None, [], {}, "", "x", 0, -1.5, True, [1, 2], {"scheme": "nominal"}, {"status": "ok", "scheme": "oracle"}]
STORED_KINDS = ["truncate", "empty", "json", "drop key", "retype", "swap", "swap runs", "delete", "flip", "append"]


@pytest.fixture(scope="module")
def stored_store(tmp_path_factory):
    d = tmp_path_factory.mktemp("stored")
    case = d / "st.toml"
    case.write_text(tomli_w.dumps(STORED_CASE))
    out = d / "base"
    res = runner.invoke(app, ["batch", str(case), "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    return case, out


@st.composite
def stored_mutations(draw):
    """(kind, run, file, argument) of one damage to a stored run."""
    kind = draw(st.sampled_from(STORED_KINDS))
    run = draw(st.sampled_from(STORED_RUNS))
    json_only = kind in ("drop key", "retype")
    fname = draw(st.sampled_from(["metrics.json", "record.json"] if json_only else STORED_FILES))
    if kind in ("truncate", "flip"):
        arg = (draw(st.floats(0.0, 1.0, exclude_max=True)), draw(st.integers(1, 255)))
    elif kind in ("json", "retype"):
        arg = (draw(st.integers(0, 99)), draw(st.sampled_from(WRONG_JSON)))
    elif kind == "drop key":
        arg = (draw(st.integers(0, 99)), None)
    elif kind == "append":
        arg = (0.0, draw(st.binary(min_size=1, max_size=8)))
    else:
        arg = None
    return kind, run, fname, arg


def _damage(out: Path, mutation) -> str:
    """Apply a stored_mutations draw to the store under ``out``; its label."""
    kind, run, fname, arg = mutation
    d = out / "st" / run
    other = out / "st" / next(s for s in STORED_RUNS if s != run)
    p = d / fname
    raw = p.read_bytes()
    if kind == "truncate":
        p.write_bytes(raw[: int(arg[0] * len(raw))])
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "json":
        p.write_text(json.dumps(arg[1]))
    elif kind in ("drop key", "retype"):
        data = json.loads(raw)
        key = sorted(data)[arg[0] % len(data)]
        if kind == "drop key":
            del data[key]
        else:
            data[key] = arg[1]
        p.write_text(json.dumps(data, indent=2))
    elif kind == "swap":
        theirs = (other / fname).read_bytes()
        (other / fname).write_bytes(raw)
        p.write_bytes(theirs)
    elif kind == "swap runs":
        d.rename(out / "st" / "tmp")
        other.rename(d)
        (out / "st" / "tmp").rename(other)
    elif kind == "delete":
        p.unlink()
    elif kind == "flip":
        at = int(arg[0] * len(raw))
        p.write_bytes(raw[:at] + bytes([raw[at] ^ arg[1]]) + raw[at + 1 :])
    elif kind == "append":
        p.write_bytes(raw + arg[1])
    return f"{kind} {run}/{fname} {arg!r:.60}"


def _stored_bytes(out: Path) -> dict[str, dict[str, bytes | None]]:
    return {
        s: {f: (out / "st" / s / f).read_bytes() if (out / "st" / s / f).exists() else None for f in STORED_FILES}
        for s in STORED_RUNS
    }


def _damaged_store(stored_store, tmp_path, mutation):
    """A copy of the stored batch with one damage: (case file, out, label, the runs whose bytes changed)."""
    import shutil

    case, base = stored_store
    out = tmp_path / "out"
    shutil.copytree(base, out)
    before = _stored_bytes(out)
    label = _damage(out, mutation)
    after = _stored_bytes(out)
    return case, out, label, {s for s in STORED_RUNS if before[s] != after[s]}


@settings(
    max_examples=STORED_EXAMPLES,
    deadline=None,
    derandomize=not LONG,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
)
@given(mutation=stored_mutations())
def test_a_damaged_stored_result_is_named_never_served(stored_store, tmp_path_factory, mutation):
    from ftcreport.cases import load_case
    from ftcreport.storage.store import check_run
    from ftcreport.studies.batch import run_key

    case, out, label, changed = _damaged_store(stored_store, tmp_path_factory.mktemp("dmg"), mutation)
    res = runner.invoke(app, ["report", "--out", str(out)])
    assert res.exit_code == (1 if changed else 0), (label, res.exit_code, res.output, _trace(res))
    assert "Traceback" not in res.output and "a bug" not in res.output, (label, res.output)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: error:")]
    for s in changed:  # each damaged run named by its file (or its directory), once
        assert sum(str(out / "st" / s) in ln for ln in errors) == 1, (label, s, errors)
    assert len(errors) == len(changed), (label, errors)
    page = (out / "st" / "index.html").read_text()
    for s in STORED_RUNS:  # a damaged run is on the page as such, not gone from it
        assert (f"damaged stored result: {out / 'st' / s}" in page) == (s in changed), (label, s)
    c = load_case(case)
    for s in STORED_RUNS:  # the batch's cache decision: exactly the damaged runs are re-run
        assert check_run(out, "st", s, key=run_key(c, s)).sound == (s not in changed), (label, s)
    exported = runner.invoke(app, ["export", "--out", str(out)])
    assert exported.exit_code == (1 if changed else 0), (label, exported.output, _trace(exported))


@settings(
    max_examples=STORED_BATCHES,
    deadline=None,
    derandomize=not LONG,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
)
@given(mutation=stored_mutations())
def test_batch_re_runs_a_damaged_stored_result(stored_store, tmp_path_factory, mutation):
    from ftcreport.storage.store import check_run

    case, out, label, changed = _damaged_store(stored_store, tmp_path_factory.mktemp("dmgb"), mutation)
    res = runner.invoke(app, ["batch", str(case), "--out", str(out), "-q"])
    assert res.exit_code == 0, (label, res.output, _trace(res))
    assert f"{len(changed)} run(s) simulated, {2 - len(changed)} cached, 0 failed" in res.stdout, (label, res.stdout)
    notes = [ln for ln in res.stderr.splitlines() if ln.startswith("ftcreport: note:")]
    assert sorted(ln.rsplit("re-running st / ", 1)[-1] for ln in notes) == sorted(changed), (label, notes)
    assert all(check_run(out, "st", s).sound for s in STORED_RUNS), label
    assert runner.invoke(app, ["report", "--out", str(out)]).exit_code == 0, label


# ------------------------------------------------------------------ the input's file type (issue 34)
#: what a case file, its base case or its scheme file may be instead of a regular file of a sane size
FILE_TYPES = (
    "fifo",
    "dev_zero",
    "dev_null",
    "dev_urandom",
    "directory",
    "socket",
    "oversize",
    "link_to_fifo",
    "link_to_dev_zero",
    "link_to_directory",
    "dangling_link",
    "link_loop",
    "link_to_regular",  # the one mutation that must still be accepted
)


def _make(path: Path, kind: str, regular: Path) -> None:
    """Make ``path`` a ``kind`` of file (``regular``: the real file a link to a regular file points at)."""
    import socket

    d = path.parent
    if kind == "fifo":
        os.mkfifo(path)
    elif kind.startswith("dev_"):
        path.symlink_to(f"/dev/{kind[4:]}")
    elif kind == "directory":
        path.mkdir()
    elif kind == "socket":
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(path))
        s.close()
    elif kind == "oversize":  # valid TOML and Python: comments only, 1.5 MB
        path.write_bytes(b"# padding\n" * 150_000)
    elif kind == "link_to_fifo":
        os.mkfifo(d / "target")
        path.symlink_to(d / "target")
    elif kind == "link_to_dev_zero":
        (d / "target").symlink_to("/dev/zero")
        path.symlink_to(d / "target")
    elif kind == "link_to_directory":
        (d / "target").mkdir()
        path.symlink_to(d / "target")
    elif kind == "dangling_link":
        path.symlink_to(d / "nowhere")
    elif kind == "link_loop":
        (d / "loop").symlink_to(path)
        path.symlink_to(d / "loop")
    elif kind == "link_to_regular":
        path.symlink_to(regular)


@pytest.mark.parametrize("role", ["case", "base_case", "plugin"])
@pytest.mark.parametrize("kind", FILE_TYPES)
def test_input_file_types(tmp_path, role, kind):
    """The case file, its ``base_case`` or its scheme file mutated into a FIFO, a device, a directory, a socket,
    a file over the size bound or a symbolic link (to those, dangling, in a loop, or to a regular file).

    ``cases validate`` and ``run``: refused at once (exit 2, no hang: SIGALRM, the file named with the
    field that names it), never read without end; a link to a regular file is accepted.
    """
    d = tmp_path / "in"
    d.mkdir()
    if role == "case":
        path = d / "m.toml"
        _make(path, kind, CASES / "two_link_switching.toml")
        needle = f"{path}: "
    elif role == "base_case":
        _make(d / "base.toml", kind, CASES / "two_link_switching.toml")
        path = d / "m.toml"
        path.write_text('base_case = "base.toml"\nname = "m"\n')
        needle = f"{path}: base_case: 'base.toml': "
    else:
        _make(d / "law.py", kind, Path(CORPUS["two_link_sliding_mode"]["plugins"][0]))
        path = d / "m.toml"
        path.write_text(tomli_w.dumps({**CORPUS["two_link_sliding_mode"], "plugins": [str(d / "law.py")]}))
        needle = f"{path}: plugins[0]: "
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(60)
    try:
        res = runner.invoke(app, ["cases", "validate", str(path)])
        if kind == "link_to_regular":
            assert res.exit_code == 0, res.output
            return
        assert res.exit_code == 2, (res.exit_code, res.output, _trace(res))
        _check_failure_message(res, path, kind)
        _check_names_a_field(res, path, kind)
        searched = role == "case" and kind in ("directory", "link_to_directory")  # validate searches a directory
        assert needle in res.stderr or (searched and f"no case files (*.toml) in {path}" in res.stderr), res.stderr
        run = runner.invoke(app, ["run", str(path), "--duration", "1", "--out", str(tmp_path / "o"), "-q"])
        assert run.exit_code == 2 and needle in run.stderr, (run.exit_code, run.output, _trace(run))
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
