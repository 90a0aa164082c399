"""Issue 23: one error boundary, safe names, stated limits, explained nulls, one writer per --out.

Each reproduction of the issue is a regression test here: the command ends with one line
``ftcreport: error: <file>: <field>: <reason>`` on stderr, the documented exit code and no
traceback.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest
import tomli_w
from typer.testing import CliRunner

from ftcreport.cli import app
from ftcreport.infra.limits import MAX_STEPS, MEMORY_BUDGET_BYTES, name_collisions, name_problem
from ftcreport.schemes.budget import budget_problem

CASES = Path(__file__).resolve().parents[1] / "cases"
runner = CliRunner()


def _one_error_line(res, code: int, *needles: str) -> str:
    """The command failed with ``code`` and exactly one error line naming every needle."""
    err = res.stderr
    assert res.exit_code == code, (res.exit_code, res.output)
    assert "Traceback" not in res.output
    # warnings and the progress line of the pages (piped: 'rendering N case page(s) ...') are not errors
    skip = ("warning: ", "ftcreport: warning: ", "rendering ")
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith(skip)]
    assert len(lines) == 1, err
    assert lines[0].startswith("ftcreport: error: "), lines[0]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def _case(tmp_path: Path, base: str = "two_link_uncompensable", fname: str = "c.toml", **top) -> Path:
    """A copy of a shipped case with top-level fields replaced (None removes them); nominal scheme only."""
    data = tomllib.loads((CASES / f"{base}.toml").read_text())
    data["schemes"] = {"nominal": data["schemes"]["nominal"]}
    data.pop("thresholds", None)
    for k, v in top.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    p = tmp_path / fname
    p.write_text(tomli_w.dumps(data))
    return p


# ------------------------------------------------------------------ the reproductions
def test_binary_case_file_via_run_is_one_line(tmp_path):
    bad = tmp_path / "bin.toml"
    bad.write_bytes(bytes(range(256)) * 3)
    res = runner.invoke(app, ["run", str(bad), "--out", str(tmp_path / "o")])
    _one_error_line(res, 2, "bin.toml", "not UTF-8")


def test_binary_case_file_via_batch_is_recorded_and_one_line(tmp_path):
    bad = tmp_path / "bin.toml"
    bad.write_bytes(b"\xff\xfe\x00name = 1\n" + os.urandom(64))
    out = tmp_path / "o"
    res = runner.invoke(app, ["batch", str(bad), "--out", str(out), "-q"])
    assert res.exit_code == 2 and "Traceback" not in res.output  # bad input
    assert "bin.toml" in res.stderr and "not UTF-8" in res.stderr
    rec = json.loads((out / "bin" / "case.json").read_text())
    assert rec["status"] == "error" and "not UTF-8" in rec["error"]
    assert (out / "index.html").exists()


def test_tiny_dt_in_demo_is_refused_before_it_starts():
    res = runner.invoke(app, ["demo", "--dt", "1e-9", "--duration", "20"])
    line = _one_error_line(res, 2, "--dt", "steps")
    assert f"{MAX_STEPS:.0e}" in line


@pytest.mark.parametrize(
    ("name", "why"),
    [
        ("a" * 300, "longer than 64 characters"),
        ("a\x00b", "control character U+0000"),
        ("index.html", "a name the report uses itself"),
        ("index", "a name the report uses itself"),
        ("INDEX", "a name the report uses itself"),
        ("../x", "must start with a letter or digit"),
        ("/abs", "must start with a letter or digit"),
        ("a/b", "must start with a letter or digit"),
        ("<script>", "must start with a letter or digit"),
        ("café", "must start with a letter or digit"),
        ("😀", "must start with a letter or digit"),
        (".hidden", "must start with a letter or digit"),
        ("", "must start with a letter or digit"),
    ],
)
def test_unsafe_names_are_rejected_on_run_and_validate(tmp_path, name, why):
    p = _case(tmp_path, name=name)
    res = runner.invoke(app, ["cases", "validate", str(p)])
    _one_error_line(res, 2, "c.toml", "name: ", why)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(p), "--out", str(out), "--duration", "0.2"])
    _one_error_line(res, 2, "c.toml", "name: ", why)
    assert not out.exists()  # refused before anything is written
    assert sorted(x.name for x in tmp_path.iterdir()) == ["c.toml"]  # nothing outside --out either


def test_safe_names_pass():
    for ok in ("a", "Two_link-3.v2", "x" * 64, "0"):
        assert name_problem(ok) is None, ok
    assert "longer" in name_problem("x" * 65)


def test_unsafe_file_stem_is_rejected_with_a_hint(tmp_path):
    p = _case(tmp_path, fname="my case.toml")
    res = runner.invoke(app, ["cases", "validate", str(p)])
    _one_error_line(res, 2, "my case.toml", "name: taken from the file name", 'set name = "..."')


def test_names_differing_only_in_case_collide_in_a_batch(tmp_path):
    a = _case(tmp_path, fname="a.toml", name="Alpha")
    b = _case(tmp_path, fname="b.toml", name="alpha")
    assert name_collisions(["Alpha", "beta", "alpha"]) == {2: 0}
    out = tmp_path / "o"
    res = runner.invoke(app, ["batch", str(a), str(b), "--out", str(out), "--duration", "0.2", "-q", "--jobs", "1"])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "b.toml: name: 'alpha' is already the name of" in res.stderr
    assert json.loads((out / "Alpha" / "nominal" / "metrics.json").read_text())["status"] == "ok"
    assert not (out / "alpha" / "nominal").exists()
    # a rejected file whose stem is a valid case's name does not overwrite that case's record
    c = tmp_path / "sub"
    c.mkdir()
    broken = c / "alpha.toml"
    broken.write_text("[robots]\nn = 1\n")
    res = runner.invoke(app, ["batch", str(a), str(broken), "--out", str(out), "--duration", "0.2", "-q"])
    assert res.exit_code == 2 and "robots.n" in res.stderr
    assert json.loads((out / "Alpha" / "case.json").read_text())["status"] == "ok"
    rejected = [p for p in out.glob("rejected-*/case.json") if "sub/alpha.toml" in p.read_text()]
    assert len(rejected) == 1


def test_cases_new_onto_an_existing_file_is_one_line(tmp_path):
    f = tmp_path / "afile"
    f.write_text("keep")
    res = runner.invoke(app, ["cases", "new", "x", "--dir", str(f)])
    _one_error_line(res, 2, "afile", "--dir", "not a directory")
    assert f.read_text() == "keep"


def test_cases_new_with_a_very_long_name_is_one_line(tmp_path):
    res = runner.invoke(app, ["cases", "new", "n" * 300, "--dir", str(tmp_path)])
    _one_error_line(res, 2, "name: ", "longer than 64")
    assert list(tmp_path.iterdir()) == []


def test_cases_new_never_overwrites(tmp_path):
    (tmp_path / "mine.toml").write_text("# mine\n")
    res = runner.invoke(app, ["cases", "new", "mine", "--dir", str(tmp_path)])
    _one_error_line(res, 2, "mine.toml", "not overwritten")
    assert (tmp_path / "mine.toml").read_text() == "# mine\n"


# ------------------------------------------------------------------ HTML escaping
def test_markup_in_case_text_is_escaped_on_every_page(tmp_path):
    evil = "<script>alert('x')</script><img src=x onerror=alert(1)>"
    good = _case(tmp_path, fname="good.toml", description=evil)
    bad = _case(tmp_path, fname="bad.toml", name=evil)  # rejected, its error shown on the index
    out = tmp_path / "o"
    res = runner.invoke(
        app, ["batch", str(good), str(bad), "--out", str(out), "--duration", "0.2", "-q", "--jobs", "1"]
    )
    assert res.exit_code == 2
    pages = [out / "index.html", out / "good" / "index.html", out / "bad" / "index.html"]
    for page in pages:
        html = page.read_text()
        assert "alert('x')</script>" not in html and "<img src=x" not in html, page
    assert "&lt;script&gt;alert(" in (out / "good" / "index.html").read_text()
    assert "&lt;script&gt;alert(" in (out / "index.html").read_text()


# ------------------------------------------------------------------ OS errors
@pytest.mark.parametrize(
    ("err", "text"),
    [
        (errno.ENOSPC, "no space left on the device"),
        (errno.EROFS, "read-only file system"),
        (errno.EACCES, "permission denied"),
        (errno.ENAMETOOLONG, "file name too long"),
    ],
)
def test_os_errors_while_writing_are_one_line(tmp_path, monkeypatch, err, text):
    import ftcreport.infra.atomic as atomic

    def failing(*a, **k):
        raise OSError(err, os.strerror(err), str(tmp_path / "o" / "x.json"))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", failing)  # every atomic write fails
    p = _case(tmp_path)
    res = runner.invoke(app, ["run", str(p), "--out", str(tmp_path / "o"), "--duration", "0.2"])
    _one_error_line(res, 2, "x.json", text)


def test_a_full_disk_during_a_batch_names_the_file_and_the_runs_stored(tmp_path, monkeypatch):
    """Attack 13 break 03: a batch that filled its disk said "ftcreport: error: <output>: no space left on
    the device": the write through a file descriptor raised ENOSPC without a file name.  The line names
    the file being written and says how many runs the batch stored before it."""
    import ftcreport.infra.atomic as atomic

    out = tmp_path / "o"
    real_fsync = os.fsync

    def full_once_stored(fd: int) -> None:  # the disk fills after the run is stored (in the worker)
        if (out / "c" / "nominal" / "record.json").exists():
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # no file name: a write to a descriptor
        real_fsync(fd)

    monkeypatch.setattr(atomic.os, "fsync", full_once_stored)
    p = _case(tmp_path)
    res = runner.invoke(app, ["batch", str(p), "--out", str(out), "--duration", "0.2", "--jobs", "1", "-q"])
    stored = len(list(out.glob("c/*/record.json")))  # every configured scheme's run, stored by the workers
    assert stored > 1
    line = _one_error_line(res, 2, "no space left on the device", f"; {stored} finished runs are stored")
    assert "<output>" not in line and f"{out / 'c' / 'manifest.json'}: no space" in line, line


def test_an_os_error_of_an_atomic_write_names_the_file_written(tmp_path, monkeypatch):
    """A write, flush or sync of the temporary file, or its rename, fails: the error names the target."""
    import ftcreport.infra.atomic as atomic

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", full)
    with pytest.raises(OSError) as got:
        atomic.replace_file(tmp_path / "d" / "x.json", b"{}")
    assert got.value.errno == errno.ENOSPC and got.value.filename == str(tmp_path / "d" / "x.json")
    assert list((tmp_path / "d").iterdir()) == []  # the temporary file is gone


def test_a_full_disk_under_cases_new_names_the_file(tmp_path, monkeypatch):
    """``cases new`` writes its file through a descriptor: a full disk's error named no file ("<output>")."""
    real_fdopen = os.fdopen

    def full(fd, *a, **k):
        fh = real_fdopen(fd, *a, **k)

        def write(text: str) -> int:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        fh.write = write
        return fh

    monkeypatch.setattr(os, "fdopen", full)
    res = runner.invoke(app, ["cases", "new", "mine", "--dir", str(tmp_path / "d")])
    _one_error_line(res, 2, f"{tmp_path / 'd' / 'mine.toml'}: no space left on the device")
    assert not (tmp_path / "d" / "mine.toml").exists()


def test_name_too_long_out_directory_is_one_line(tmp_path):
    p = _case(tmp_path)
    res = runner.invoke(app, ["run", str(p), "--out", str(tmp_path / ("o" * 300)), "--duration", "0.2"])
    _one_error_line(res, 2, "o" * 300, "file name too long")


def test_unreadable_case_path_is_one_line(tmp_path):
    res = runner.invoke(app, ["run", str(tmp_path), "--out", str(tmp_path / "o")])  # a directory
    _one_error_line(res, 2, str(tmp_path), "not a regular file (a directory)")


# ------------------------------------------------------------------ unexpected errors
def test_unexpected_exception_gives_one_line_and_a_log(tmp_path, monkeypatch):
    import ftcreport.model as model

    def boom(*a, **k):
        raise KeyError("internal")

    monkeypatch.setattr(model, "compensable_patterns", boom)
    monkeypatch.setenv("FTCREPORT_LOG_DIR", str(tmp_path / "logs"))
    res = runner.invoke(app, ["patterns", "3"])
    line = _one_error_line(res, 3, "unexpected KeyError", "--debug")
    logs = list((tmp_path / "logs").glob("ftcreport-crash-*.log"))
    assert len(logs) == 1 and str(logs[0]) in line
    assert "Traceback" in logs[0].read_text() and "boom" in logs[0].read_text()
    dbg = runner.invoke(app, ["--debug", "patterns", "3"])
    assert isinstance(dbg.exception, KeyError)  # --debug: the exception itself, with its traceback


def test_numeric_error_is_exit_1(monkeypatch):
    import ftcreport.model as model

    def boom(*a, **k):
        raise FloatingPointError("overflow encountered")

    monkeypatch.setattr(model, "compensable_patterns", boom)
    res = runner.invoke(app, ["patterns", "3"])
    _one_error_line(res, 1, "numeric error", "overflow")


# ------------------------------------------------------------------ limits
def test_memory_budget_refuses_long_logged_runs(tmp_path):
    sim = {"dt": 0.001, "duration": 9000.0, "log_every": 1}
    p = _case(tmp_path, simulation=sim)
    res = runner.invoke(app, ["cases", "validate", str(p)])
    line = _one_error_line(res, 2, "c.toml", "simulation.log_every", f"{MEMORY_BUDGET_BYTES / 2**20:.0f} MiB")
    assert "logged samples" in line
    sim["log_every"] = 100  # the same run, logged every 100th step, fits
    p = _case(tmp_path, simulation=sim)
    assert runner.invoke(app, ["cases", "validate", str(p)]).exit_code == 0


def test_switching_models_of_a_long_chain_are_refused():
    # n = 11: 3 * 4^10 - 2 = 3145726 models, about 1.3 GiB of pattern table and its tuples alone
    # (the superposed filters keep O(n^2) states: n = 10 fits, at 0.3 GiB)
    field, why = budget_problem(11, 10.0, 0.01, 10, "switching")
    assert field == "robots.n" and "3145726 models" in why and "MiB" in why
    assert budget_problem(11, 10.0, 0.01, 10, "nominal") is None
    assert budget_problem(10, 10.0, 0.01, 10, "switching") is None
    assert budget_problem(5, 80.0, 0.02, 5, "switching") is None  # five_link_cascade


def _twelve_robots(tmp_path: Path, tables: list[str]) -> tuple[dict, Path]:
    """three_link_circle_faults with 12 robots (a circle they fit on), only the scheme tables ``tables`` and no
    thresholds or claims, written to tmp_path/twelve.toml: (its data, the file)."""
    text = (CASES / "three_link_circle_faults.toml").read_text()
    data = tomllib.loads(text.replace("n = 3", "n = 12", 1).replace("radius = 5.0", "radius = 30.0", 1))
    data["schemes"] = {k: data["schemes"][k] for k in tables}
    data.pop("thresholds", None)
    data.pop("claims", None)
    p = tmp_path / "twelve.toml"
    p.write_text(tomli_w.dumps(data))
    return data, p


def test_twelve_robots_with_switching_are_refused_for_the_bank_not_the_log(tmp_path):
    """n = 12: the switching bank's 12582910 patterns alone need about 5.5 GiB; the advice was to raise
    log_every and shorten the duration, which cannot help.  It names the bank and what helps."""
    data, p = _twelve_robots(tmp_path, ["nominal", "switching"])
    data["schemes"]["run"] = ["nominal", "switching"]
    p.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["cases", "validate", str(p)])
    line = _one_error_line(res, 2, "twelve.toml", "robots.n", "switching", "12582910", "bank", "MiB")
    for words in ("[schemes] run", "fewer robots", "patterns"):
        assert words in line, (words, line)
    assert "simulation.log_every" not in line and "simulation.duration" not in line, line
    # the adaptive bank's weights are logged at every sample: even two samples are over the budget
    field, why = budget_problem(12, 40.0, 0.01, 10, "adaptive")
    assert field == "robots.n" and "log_every" not in why and "[schemes] run" in why, why


def test_twelve_robots_with_switching_by_default_are_refused_too(tmp_path):
    """A 12-robot case that names no switching table and no [schemes] run gets switching's default table
    after validation (every FTC family runs): that table was never checked against the memory budget, so
    the case validated and its run would have built the 5.5 GiB bank."""
    data, p = _twelve_robots(tmp_path, ["nominal"])
    res = runner.invoke(app, ["cases", "validate", str(p)])
    line = _one_error_line(res, 2, "twelve.toml", "robots.n", "switching", "12582910", "bank", "by default")
    assert "[schemes] run" in line, line
    data["schemes"]["run"] = ["nominal", "oracle"]  # what the advice says: the case loads
    p.write_text(tomli_w.dumps(data))
    assert runner.invoke(app, ["cases", "validate", str(p)]).exit_code == 0


def test_memory_advice_names_the_log_every_that_fits():
    """When the time series dominate, the advice is the log_every that brings the run within the budget."""
    field, why = budget_problem(2, 9000.0, 0.001, 1)
    assert field == "simulation.log_every" and "logged" in why, why
    k = int(why.split("simulation.log_every to at least ")[1].split()[0].rstrip(","))
    assert budget_problem(2, 9000.0, 0.001, k) is None
    assert budget_problem(2, 9000.0, 0.001, k - 1) is not None


def test_duration_override_is_checked_against_the_limits(tmp_path):
    p = _case(tmp_path)
    res = runner.invoke(app, ["run", str(p), "--duration", "1e9", "--out", str(tmp_path / "o")])
    # the override is validated as the case's own field would be: the schema's bound on the duration
    _one_error_line(res, 2, "--duration", "simulation.duration", "must be <= 1e+06")
    res = runner.invoke(app, ["run", str(p), "--duration", "5e5", "--out", str(tmp_path / "o")])
    _one_error_line(res, 2, "--duration", "simulation.dt", "steps")  # within the bound: over the step limit
    res = runner.invoke(app, ["run", str(p), "--duration", "nan", "--out", str(tmp_path / "o")])
    _one_error_line(res, 2, "--duration", "finite")


# ------------------------------------------------------------------ metrics: finite or explained null
def test_metrics_are_finite_or_null_with_a_reason():
    from ftcreport.runner import explain_nulls

    m = explain_nulls(
        {
            "status": "diverged",
            "reason": "non-finite state at t = 3 s",
            "torque_peak": float("nan"),
            "recovery_time_max": None,
            "phases": [{"recovery_time": None, "position_error_max": 0.1}, {"position_error_max": float("inf")}],
        }
    )
    assert m["torque_peak"] is None and m["phases"][1]["position_error_max"] is None
    assert set(m["null_reasons"]) == {
        "torque_peak",
        "recovery_time_max",
        "phases[0].recovery_time",
        "phases[1].position_error_max",
    }
    assert "non-finite" in m["null_reasons"]["torque_peak"] and "diverged" in m["null_reasons"]["torque_peak"]
    assert "recovery band" in m["null_reasons"]["phases[0].recovery_time"]


def test_a_stored_run_explains_its_nulls(tmp_path):
    # two_link_uncompensable's nominal run never recovers after the uncompensable fault
    p = CASES / "two_link_uncompensable.toml"
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(p), "--out", str(out), "--scheme", "nominal", "--duration", "12", "-q"])
    assert res.exit_code in (0, 1), res.output
    m = json.loads((out / "two_link_uncompensable" / "nominal" / "metrics.json").read_text())
    nulls = _null_paths(m)
    assert nulls == set(m["null_reasons"]), (nulls, m["null_reasons"])


def _null_paths(v, path: str = "") -> set[str]:
    if isinstance(v, dict):
        out = set()
        for k, x in v.items():
            if k in ("null_reasons", "reason", "traceback", "description"):
                continue
            out |= _null_paths(x, f"{path}.{k}" if path else k)
        return out
    if isinstance(v, list):
        return set().union(*[_null_paths(x, f"{path}[{i}]") for i, x in enumerate(v)]) if v else set()
    return {path} if v is None else set()


# ------------------------------------------------------------------ one writer per output directory
def _hold_lock(out: Path) -> subprocess.Popen:
    code = textwrap.dedent(
        f"""
        import sys, time
        from ftcreport.storage.store import output_lock
        with output_lock({str(out)!r}, "batch"):
            print("held", flush=True)
            time.sleep(60)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


@pytest.mark.parametrize("command", ["run", "batch", "report", "check", "campaign"])
def test_second_writer_on_the_same_out_fails_with_a_clear_message(tmp_path, command):
    out = tmp_path / "o"
    holder = _hold_lock(out)
    try:
        p = _case(tmp_path)
        args = {
            "run": ["run", str(p), "--out", str(out)],
            "batch": ["batch", str(p), "--out", str(out), "-q"],
            "report": ["report", "--out", str(out)],
            "check": ["check", str(p), "--out", str(out), "-q"],
            "campaign": ["campaign", str(CASES / "two_link_campaign.toml"), "--out", str(out), "--in-process"],
        }[command]
        res = runner.invoke(app, args)
        _one_error_line(res, 2, str(out), "in use by ftcreport batch (pid", "choose another --out")
    finally:
        holder.kill()
        holder.wait()
    assert not (out / "c").exists()  # nothing written by the refused command


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["patterns", "-3"], "No such option: -3"),
        (["run"], "Missing argument 'case'"),
        (["run", "x.toml", "--duration", "abc"], "'--duration'"),
        (["cases", "new"], "Missing argument 'name'"),
    ],
)
def test_usage_errors_are_one_line(args, needle):
    res = runner.invoke(app, args)
    _one_error_line(res, 2, "ftcreport", needle, "--help")


# ------------------------------------------------------------------ run --verify-dt
def test_verify_dt_reports_a_converged_step(tmp_path):
    out = tmp_path / "o"
    args = ["run", str(CASES / "two_link_uncompensable.toml"), "--scheme", "oracle", "--duration", "3"]
    res = runner.invoke(app, [*args, "--out", str(out), "--verify-dt", "--no-report"])
    assert res.exit_code == 0, res.output
    assert "dt = 0.01 s vs 0.005 s: converged" in res.stdout
    v = json.loads((out / "two_link_uncompensable" / "oracle" / "metrics.json").read_text())["verify_dt"]
    assert v["dt"] == 0.01 and v["dt_half"] == 0.005 and v["converged"]
    # the oracle holds a zero error: torques are set by the reference and agree to < 1e-6 relative
    assert v["metrics"]["torque_peak"]["rel_change"] < 1e-6
    assert not (out / "index.html").exists()  # --no-report


def test_verify_dt_flags_a_step_that_is_not_converged(tmp_path):
    """two_link_switching at its 5 ms step: the start-up torque transient's energy halves with dt."""
    from ftcreport.cases import load_case, with_duration
    from ftcreport.runner import halve_dt, run_scheme

    out = tmp_path / "o"
    case = CASES / "two_link_switching.toml"
    res = runner.invoke(
        app, ["run", str(case), "--scheme", "nominal", "--duration", "2", "--out", str(out), "--verify-dt", "-q"]
    )
    line = _one_error_line(res, 1, str(case), "simulation.dt", "not converged at dt = 0.005 s")
    assert "energy" in line
    v = json.loads((out / "two_link_switching" / "nominal" / "metrics.json").read_text())["verify_dt"]
    assert not v["converged"] and v["worst"] == "energy" and v["worst_rel_change"] > 0.1
    # the dt/2 column is exactly an independent run at dt/2
    _, half = run_scheme(halve_dt(with_duration(load_case(case), 2.0)), "nominal")
    assert v["metrics"]["energy"]["dt_half"] == half["energy"]
    assert v["metrics"]["position_error_max"]["dt_half"] == half["position_error_max"]


def test_verify_dt_of_an_auto_run_is_a_tolerance_check(tmp_path):
    """An error-controlled run (method = "auto") is checked at a tenth of its tolerances and half its longest step."""
    src = (CASES / "two_link_uncompensable.toml").read_text().replace("\ndt = 0.01\n", '\ndt = 0.01\nmethod = "auto"\n')
    case = tmp_path / "c.toml"
    case.write_text(src)
    out = tmp_path / "o"
    args = ["run", str(case), "--scheme", "oracle", "--duration", "3", "--out", str(out), "--verify-dt", "--no-report"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "rtol = 1e-06 vs 1e-07, atol = 1e-08 vs 1e-09, longest step 0.01 s vs 0.005 s: converged" in res.stdout
    m = json.loads((out / "c" / "oracle" / "metrics.json").read_text())
    v = m["verify_dt"]
    assert v["dt"] == 0.01 and v["dt_half"] == 0.005 and v["converged"] and not v["empty"]
    assert m["integrator"]["rtol"] == 1e-6 and m["integrator"]["requested"] == "auto"


def _sampled_auto_case(tmp_path: Path) -> Path:
    """two_link_campaign under sampled control (20 ms) with method = "auto" at a 10 ms longest step, wheel 2l
    lost at 3 s: every auto step lands on a sample, so rtol and atol alone do not change the steps."""
    data = tomllib.loads((CASES / "two_link_campaign.toml").read_text())
    data.pop("campaign")
    data["schemes"] = {"run": ["nominal", "oracle"], "nominal": {"k_v": 5.0}, "oracle": {"k_v": 5.0}}
    data["simulation"] = {"dt": 0.01, "duration": 6.0, "sample_time": 0.02, "method": "auto"}
    data["faults"] = [{"time": 3.0, "wheel": "2l"}]
    p = tmp_path / "sampled_auto.toml"
    p.write_text(tomli_w.dumps(data))
    return p


def test_verify_dt_of_a_sampled_auto_run_halves_the_longest_step(tmp_path):
    """A sampled loop's auto steps are capped by the samples: at a tenth of rtol and atol alone the refined
    run was bit-identical and the check said "converged" at 0.00 % on every metric.  The refined run also
    halves the longest step, and verify_dt records what it was."""
    case = _sampled_auto_case(tmp_path)
    out = tmp_path / "o"
    args = ["run", str(case), "--scheme", "nominal", "--out", str(out), "--verify-dt", "--no-report"]
    res = runner.invoke(app, args)
    assert "Traceback" not in res.output, res.output
    assert "longest step 0.01 s vs 0.005 s" in res.stdout, res.stdout
    v = json.loads((out / "sampled_auto" / "nominal" / "metrics.json").read_text())["verify_dt"]
    assert v["dt"] == 0.01 and v["dt_half"] == 0.005
    assert v["refined_run"] == {"method": "auto", "rtol": 1e-7, "atol": 1e-9, "max_step": 0.005}
    assert not v["empty"]
    assert any(r["abs_change"] for r in v["metrics"].values()), v["metrics"]


def test_verify_dt_says_a_bit_identical_refined_run_is_an_empty_check(tmp_path, monkeypatch):
    """A refined run identical to the run on every metric tested nothing: the output says the check was
    empty (exit 1), never "converged"."""
    import ftcreport.runner

    monkeypatch.setattr(ftcreport.runner, "halve_dt", lambda c, source="": c)
    case = _sampled_auto_case(tmp_path)
    out = tmp_path / "o"
    args = ["run", str(case), "--scheme", "nominal", "--duration", "1", "--out", str(out), "--verify-dt"]
    res = runner.invoke(app, [*args, "--no-report"])
    _one_error_line(res, 1, str(case), "simulation.dt", "nominal", "empty", "bit-identical")
    assert "converged" not in res.stdout, res.stdout
    assert "EMPTY" in res.stdout, res.stdout
    v = json.loads((out / "sampled_auto" / "nominal" / "metrics.json").read_text())["verify_dt"]
    assert v["empty"] and not v["converged"]


def test_verify_dt_refuses_an_auto_longest_step_halved_to_its_min_step(tmp_path):
    """Halving an error-controlled run's longest step must keep it above min_step (as validation does for dt)."""
    from ftcreport.cases import load_case
    from ftcreport.errors import CaseError
    from ftcreport.runner import halve_dt

    case = load_case(
        _case(tmp_path, simulation={"dt": 0.01, "duration": 1.0, "method": "auto", "min_step": 0.006}, faults=[])
    )
    with pytest.raises(CaseError, match=r"--verify-dt: at dt/2, simulation.min_step: 0.006 s is not below"):
        halve_dt(case, "c.toml")


def test_dt_sensitivity_rules():
    from ftcreport.runner import dt_sensitivity

    a = {"status": "ok", "dt": 0.01, "torque_peak": 10.0, "position_error_max": 1e-9}
    assert dt_sensitivity(a, a | {"dt": 0.005, "torque_peak": 10.09})["converged"]  # 0.9 % change
    v = dt_sensitivity(a, a | {"dt": 0.005, "torque_peak": 10.2})  # 2 %
    assert not v["converged"] and v["worst"] == "torque_peak"
    assert v["worst_rel_change"] == pytest.approx(0.2 / 10.2)
    assert not dt_sensitivity(a, a | {"status": "diverged"})["converged"]
    assert not dt_sensitivity(a, a | {"torque_peak": None})["converged"]
    # the same run twice: an empty check, never "converged"
    v = dt_sensitivity(a, dict(a))
    assert v["empty"] and not v["converged"]
    assert not dt_sensitivity(a, a | {"dt": 0.005, "torque_peak": 10.09})["empty"]


def test_partial_files_are_cleaned_except_in_nested_output_directories(tmp_path):
    from ftcreport.storage.store import output_lock

    out = tmp_path / "o"
    (out / "c" / "nominal").mkdir(parents=True)
    (out / "campaigns" / "x" / "samples").mkdir(parents=True)
    stale = out / "c" / "nominal" / ".metrics.json.abc123.partial"
    stale.write_text('{"trunc')
    (out / "campaigns" / "x" / ".ftcreport.lock").write_text("")
    busy = out / "campaigns" / "x" / "samples" / ".000001.json.def456.partial"  # another writer's
    busy.write_text("{")
    with output_lock(out, "batch"):
        assert not stale.exists() and busy.exists()
    assert (out / ".ftcreport.lock").read_text() == ""  # released: no holder named


def test_fuzz_finding_link_of_1e_minus_300_is_a_failed_run(tmp_path):
    """Found by tests/test_fuzz.py: three_link_active with robots.d = 1e-300 made the active scheme's
    engine solve on inf (LinAlgError), which escaped as '<run>: numeric error' without the file."""
    data = tomllib.loads((CASES / "three_link_active.toml").read_text())
    data["robots"]["d"] = 1e-300
    p = tmp_path / "tiny_link.toml"
    p.write_text(tomli_w.dumps(data))
    out = tmp_path / "o"
    res = runner.invoke(
        app, ["run", str(p), "--scheme", "active", "--duration", "1", "--out", str(out), "-q", "--no-report"]
    )
    line = _one_error_line(res, 1, "tiny_link.toml", "active")
    m = json.loads((out / "tiny_link" / "active" / "metrics.json").read_text())
    assert m["status"] != "ok" and m["reason"] in line


def test_report_names_a_damaged_stored_case_copy(tmp_path):
    p = _case(tmp_path)
    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(p), "--duration", "0.2", "--out", str(out), "-q"]).exit_code == 0
    (out / "c" / "case.toml").write_bytes(b"\xff\xfe[robots")
    res = runner.invoke(app, ["report", "--out", str(out)])
    _one_error_line(res, 2, str(out / "c" / "case.toml"), "stored copy of", "damaged", "store it again")
    assert runner.invoke(app, ["run", str(p), "--duration", "0.2", "--out", str(out), "-q"]).exit_code == 0
    assert runner.invoke(app, ["report", "--out", str(out)]).exit_code == 0


def test_campaign_with_a_damaged_record_is_one_line(tmp_path):
    out = tmp_path / "camp"
    out.mkdir()
    (out / "campaign.json").write_text('{"seed": 0, "sche')
    res = runner.invoke(
        app, ["campaign", str(CASES / "two_link_campaign.toml"), "-n", "1", "--in-process", "--out", str(out), "-q"]
    )
    _one_error_line(res, 2, "campaign.json", "damaged", "remove it")
