"""Fuzzer (issue 23): every field of every shipped case, mutated, through the CLI.

Each example takes one shipped case, mutates it (a field replaced by a value of another
type, NaN, inf, a negative, zero or huge number, an empty list, a table; a field deleted;
an unknown key added; or the file's bytes truncated, broken by non-UTF-8 bytes or
overwritten) and runs ``ftcreport cases validate`` and ``ftcreport run --duration 1`` on it
in this process (typer's CliRunner).  Every mutant must end

* without a traceback and with a documented exit code (validate: 0 or 2; run: 0, 1 or 2);
* with a message naming the file when it fails (``ftcreport: error: <file>: ...``);
* within a per-example deadline (a hang fails the test through SIGALRM);
* with every written ``metrics.json`` free of NaN/inf and every null explained in ``null_reasons``.

CI runs ``FUZZ_EXAMPLES`` examples (default 60, derandomized so CI is reproducible; about
a minute on one core).  ``FUZZ_EXAMPLES=2000 pytest -n 0 tests/test_fuzz.py -s`` runs more,
with fresh random draws (``FUZZ_LOG=file`` appends one JSON line per example;
``FUZZ_RENDER_ALL=1`` also renders the slow pages of the five-link and Table 4.2 cases).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import signal
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from ftcreport.cli import app

CASES = Path(__file__).resolve().parents[1] / "cases"
SHIPPED = {p.stem: tomllib.loads(p.read_text()) for p in sorted(CASES.glob("*.toml"))}
EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "60"))
LONG = "FUZZ_EXAMPLES" in os.environ
DEADLINE_S = 120  # per example: validate + a 1 s run (+ its page)
# pages whose render derives the chained form for n = 5 (sympy, ~30 s once) and its frozen-pole
# analysis (~10 s a page) or the Table 4.2 analyses: rendered only with FUZZ_RENDER_ALL=1
SLOW_PAGES = {"five_link_cascade", "three_link_active"}
RENDER_ALL = os.environ.get("FUZZ_RENDER_ALL") == "1"
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


PATHS = {name: _paths(data) for name, data in SHIPPED.items()}

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


@st.composite
def mutants(draw):
    """(case stem, file bytes, a label of the mutation)."""
    name = draw(st.sampled_from(sorted(SHIPPED)))
    data = json.loads(json.dumps(SHIPPED[name]))  # deep copy (shipped cases hold only JSON types)
    kind = draw(st.sampled_from(["replace", "replace", "replace", "replace", "delete", "unknown", "bytes"]))
    paths = PATHS[name]
    if kind == "replace":
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
    except (TypeError, ValueError):  # a value TOML cannot hold: write the shipped file's text
        raw = (CASES / f"{name}.toml").read_bytes()
        label += " (not TOML-encodable; shipped text)"
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
    try:
        res = runner.invoke(app, ["cases", "validate", str(path)])
        assert res.exit_code in VALIDATE_CODES, (label, res.exit_code, res.output)
        if res.exit_code != 0:
            _check_failure_message(res, path, label)
        out = d / "out"
        args = ["run", str(path), "--duration", "1", "--out", str(out), "-q"]
        if name in SLOW_PAGES and not RENDER_ALL:
            args.append("--no-report")
        run = runner.invoke(app, args)
        if isinstance(run.exception, _HangError):
            raise run.exception
        assert run.exit_code in RUN_CODES, (label, run.exit_code, run.output, run.exception)
        if run.exit_code != 0:
            _check_failure_message(run, path, label)
        if res.exit_code == 2:
            assert run.exit_code == 2, (label, run.output)  # an invalid file is refused by run too
        written = _check_metrics(out, label) if out.exists() else 0
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    key = f"validate={res.exit_code} run={run.exit_code}"
    if LOG:
        rec = {"case": name, "mutation": label, "validate": res.exit_code, "run": run.exit_code, "metrics": written}
        with open(LOG, "a") as fh:
            fh.write(json.dumps(rec) + "\n")
    COUNTS[key] = COUNTS.get(key, 0) + 1
    COUNTS["metrics_files"] = COUNTS.get("metrics_files", 0) + written


@pytest.fixture(scope="module", autouse=True)
def _report_counts():
    yield
    if COUNTS:
        total = sum(v for k, v in COUNTS.items() if k.startswith("validate="))
        print(f"\nfuzz: {total} examples; " + ", ".join(f"{k}: {v}" for k, v in sorted(COUNTS.items())))


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
    """Eight mutants in one ``batch`` (worker processes): exit 0 or 1, every rejected file named once."""
    d = tmp_path_factory.mktemp("fuzzbatch")
    paths = []
    for i, (name, raw, _) in enumerate(batch):
        p = d / f"m{i}_{name}.toml"
        p.write_bytes(raw)
        paths.append(p)
    out = d / "out"
    res = runner.invoke(app, ["batch", *map(str, paths), "--out", str(out), "--duration", "1", "--jobs", "1", "-q"])
    labels = [b[2] for b in batch]
    assert res.exit_code in (0, 1), (labels, res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output, labels
    for p in paths:
        if runner.invoke(app, ["cases", "validate", str(p)]).exit_code != 0:
            assert f"ftcreport: error: {p}" in res.stderr, (p, res.stderr)
    _check_metrics(out, "; ".join(labels))
    assert (out / "index.html").exists()
