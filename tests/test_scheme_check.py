"""The scheme contract (issue 38 item 5): ``ftcreport schemes check``, the guards, where the user erred.

The shipped example passes the battery; four broken variants of it (a missing decorator, a typo, a
wrong return arity, a write past a declared signal) each fail with one line naming the file and the
line to fix, and exit 2.  A law that writes past its declared signal width stops its run with an
error naming the scheme and the signal, never status ok, never a crash (the issue's break).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ftcreport.cases import parse_case, with_duration
from ftcreport.cli import app
from ftcreport.errors import ModelError
from ftcreport.runner import run_scheme

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "schemes" / "sliding_mode.py"
CASE = ROOT / "cases" / "two_link_sliding_mode.toml"
runner = CliRunner()


def _variant(tmp_path: Path, stem: str, old: str, new: str) -> tuple[Path, int]:
    """The example with ``old`` replaced by ``new`` (its scheme renamed after the file); the changed line."""
    text = EXAMPLE.read_text()
    assert old in text, old
    text = text.replace(old, new).replace('name="sliding_mode"', f'name="{stem}"')
    path = tmp_path / f"{stem}.py"
    path.write_text(text)
    first = new.splitlines()[-1].strip()
    line = next(i for i, x in enumerate(text.splitlines(), 1) if x.strip() == first)
    return path, line


def _fail_lines(output: str) -> list[str]:
    return [x.removeprefix("FAIL ") for x in output.splitlines() if x.startswith("FAIL ")]


def test_the_shipped_example_passes_the_battery():
    res = runner.invoke(app, ["schemes", "check", str(EXAMPLE)])
    assert res.exit_code == 0, res.output
    assert not _fail_lines(res.output)
    ok = [x for x in res.output.splitlines() if x.startswith("ok ")]
    assert len(ok) == 1 and "scheme sliding_mode: passed" in ok[0] and "bounds (boundscheck)" in ok[0]


BROKEN = [
    # (stem, old text, new text, what the one line says)
    (
        "sm_no_decorator",
        "@jit\ndef law(P, step, terms, x, out):",
        "def law(P, step, terms, x, out):",
        "is not compiled",
    ),
    (
        "sm_typo",
        "    out.u[:] = law_for_pattern(terms.MB, v, P.healthy)",
        "    out.u[:] = law_for_patern(terms.MB, v, P.healthy)",
        "numba TypingError",
    ),
    ("sm_arity", "    out.sig[2] = K\n", "    out.sig[2] = K\n    return out.u, out.dx\n", "returns a tuple of 2"),
    ("sm_overrun", "    out.sig[2] = K\n", "    out.sig[2] = K\n    out.sig[3] = K\n", "index out of bounds"),
]


@pytest.mark.parametrize(("stem", "old", "new", "says"), BROKEN, ids=[b[0] for b in BROKEN])
def test_a_broken_variant_gives_one_line_at_its_line_and_exit_2(tmp_path, stem, old, new, says):
    path, line = _variant(tmp_path, stem, old, new)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        res = runner.invoke(app, ["schemes", "check", str(path)])
    assert res.exit_code == 2, res.output
    fails = _fail_lines(res.output)
    assert len(fails) == 1, res.output
    msg = fails[0]
    where = re.match(r"(.+?):(\d+): ", msg)
    assert where, msg
    assert Path(where.group(1)).resolve() == path.resolve(), msg  # the user's file, not the generated loop
    if stem == "sm_no_decorator":  # register names the function's definition
        assert int(where.group(2)) == line, msg
    else:
        assert int(where.group(2)) == line, msg  # the offending line itself
    assert says in msg and (stem in msg or "sliding" in msg), msg
    assert "a bug" not in res.output and "ftcreport_loop" not in msg


def test_the_typo_shows_numba_s_message_after_the_line(tmp_path):
    path, _ = _variant(
        tmp_path,
        "sm_typo2",
        "    out.u[:] = law_for_pattern(terms.MB, v, P.healthy)",
        "    out.u[:] = law_for_patern(terms.MB, v, P.healthy)",
    )
    res = runner.invoke(app, ["schemes", "check", str(path)])
    assert res.exit_code == 2
    lines = res.output.splitlines()
    i = next(k for k, x in enumerate(lines) if x.startswith("FAIL "))
    assert "law_for_patern" in lines[i]  # the name numba could not resolve, in the one line
    assert any(x.startswith("     | ") for x in lines[i + 1 :])  # numba's full message after it


def _run_only(data: dict, schemes: dict) -> None:
    """The case's ``[schemes]`` replaced by ``schemes``, and only the thresholds of the schemes it runs kept
    (validation refuses a threshold for a scheme the case does not run)."""
    data["schemes"] = schemes
    data["thresholds"] = {k: v for k, v in data.get("thresholds", {}).items() if k in schemes["run"]}


# ------------------------------------------------------------------ the break: a write past a signal
def _overrun_case(tmp_path: Path, stem: str, by: str):
    path, _ = _variant(tmp_path, stem, "    out.sig[2] = K\n", f"    out.sig[2] = K\n    out.sig[{by}] = K\n")
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    _run_only(data, {"run": ["nominal", stem], "k_v": 20.0})
    return with_duration(parse_case(data, str(CASE)), 2.0)


def test_a_law_writing_past_its_declared_signal_is_an_error_naming_the_scheme_and_line(tmp_path):
    """The first run of a plug-in runs its law under numba's bounds checks: the overrun is reported before
    the real run, at its line; the run's status is error (never ok), the process goes on."""
    case = _overrun_case(tmp_path, "sm_past_first", "3")
    run, m = run_scheme(case, "sm_past_first")
    assert m["status"] == "error" and run.status == "error"
    assert "scheme sm_past_first" in m["reason"] and "index out of bounds" in m["reason"]
    assert "sm_past_first.py:" in m["reason"]
    _, mn = run_scheme(case, "nominal")  # the process is fine: the next run works
    assert mn["status"] == "ok"


def test_a_write_past_the_signals_in_a_real_run_stops_it_at_the_first_call(tmp_path, monkeypatch):
    """Without the first run's check (e.g. a record of an earlier version), the bounds-checked law stops the run
    at the first call: status error naming the scheme, the output and index, and the declared signals."""
    import ftcreport.fast.scheme_check as check

    monkeypatch.setattr(check, "ensure_checked", lambda ctrl: None)
    case = _overrun_case(tmp_path, "sm_past_guard", "4")  # two cells past the three declared values
    _, m = run_scheme(case, "sm_past_guard")
    assert m["status"] == "error", m
    assert "scheme 'sm_past_guard'" in m["reason"] and "out.sig[4]: index 4 is out of bounds" in m["reason"]
    assert "s (2), K (1)" in m["reason"] and "t = 0 s" in m["reason"], m["reason"]  # the first call of the law


def test_a_write_past_the_state_rates_stops_the_run(tmp_path, monkeypatch):
    import ftcreport.fast.scheme_check as check

    monkeypatch.setattr(check, "ensure_checked", lambda ctrl: None)
    path, _ = _variant(tmp_path, "sm_past_dx", "    out.sig[2] = K\n", "    out.sig[2] = K\n    out.dx[0] = 1.0\n")
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    _run_only(data, {"run": ["sm_past_dx"], "k_v": 20.0})
    _, m = run_scheme(with_duration(parse_case(data, str(CASE)), 1.0), "sm_past_dx")
    assert m["status"] == "error" and "out.dx[0]: index 0 is out of bounds" in m["reason"], m


# ------------------------------------------------------------------ registration errors, the round-2 form
def test_register_names_the_function_of_a_wrong_signature(tmp_path):
    from ftcreport.schemes import load_plugin

    path, _ = _variant(tmp_path, "sm_args", "def law(P, step, terms, x, out):", "def law(P, step, terms, x):")
    with pytest.raises(ModelError) as info:
        load_plugin(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:") and "takes 4 arguments; the contract is law(P, step, terms, x, out)" in msg


def test_a_round2_law_still_runs_through_the_adapter_with_a_warning():
    """One deprecation cycle: the 13-argument law of round 2 gives the nominal law's numbers to the bit."""
    from ftcreport.schemes import registered

    path = ROOT / "tests" / "data" / "round2_copy_nominal_scheme.py"
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    _run_only(data, {"run": ["nominal", "round2_copy_nominal"], "k_v": 20.0})
    with pytest.warns(DeprecationWarning, match=r"round-2 13 arguments"):
        case = with_duration(parse_case(data, str(CASE)), 3.0)
    assert "round2_copy_nominal" in registered()
    run_r, m_r = run_scheme(case, "round2_copy_nominal")
    run_n, _ = run_scheme(case, "nominal")
    assert m_r["status"] == "ok", m_r
    for key in ("q", "eta", "u", "tau"):
        assert np.abs(run_r.signals[key] - run_n.signals[key]).max() == 0.0, key
    assert np.abs(run_r.signals["u0"][:, 0] - run_n.signals["u"][:, 0]).max() == 0.0


def test_a_law_returning_nan_stops_the_run_naming_it_and_keeps_what_ran(tmp_path, monkeypatch):
    """The campaign attack (round 3): a plug-in law writing out.u[1] = nan from t = 1 s ended 'error' with
    "its compiled law ... raised LinAlgError: Array must not contain infs or NaNs" (the law raised nothing:
    the plant's solve did, on its NaN torque), no time in the reason, t_end null and a log of 0 rows: the
    first second was lost.  The loop checks the law's command as it returns: the stop names the scheme, the
    wheel, the value and the time, and the run keeps its rows up to it."""
    import ftcreport.fast.scheme_check as check

    monkeypatch.setattr(check, "ensure_checked", lambda ctrl: None)  # the battery's t = 0 calls see no NaN
    new = "    out.sig[2] = K\n    if step.t >= 1.0:\n        out.u[1] = np.nan\n"
    path, _ = _variant(tmp_path, "sm_nan", "    out.sig[2] = K\n", new)
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    _run_only(data, {"run": ["sm_nan"], "k_v": 20.0})
    run, m = run_scheme(with_duration(parse_case(data, str(CASE)), 3.0), "sm_nan")
    assert m["status"] == "error", m
    assert "scheme 'sm_nan'" in m["reason"] and "non-finite command" in m["reason"], m["reason"]
    assert "out.u[1] (wheel 1l) = nan" in m["reason"] and "t = 1 s" in m["reason"], m["reason"]
    assert "LinAlgError" not in m["reason"]
    assert run.t_end == pytest.approx(1.0, abs=0.011)  # the first stage at or after 1 s (dt = 10 ms)
    # the first second is kept: every step in the metric stream, every 10th in the log (log_every = 10)
    assert run.t_stream.size >= 100 and run.t_stream[-1] == pytest.approx(1.0, abs=0.011)
    assert run.t.size >= 10


def test_a_law_returning_nan_is_named_alike_under_an_error_controlled_step(tmp_path, monkeypatch):
    """The review: the stop code of a non-finite command was worded by the fixed step's path only; an
    error-controlled run (auto, dopri5) said 'compiled engine: unknown error code 18'."""
    import ftcreport.fast.scheme_check as check

    monkeypatch.setattr(check, "ensure_checked", lambda ctrl: None)
    new = "    out.sig[2] = K\n    if step.t >= 1.0:\n        out.u[1] = np.nan\n"
    path, _ = _variant(tmp_path, "sm_nan_auto", "    out.sig[2] = K\n", new)
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    data["simulation"]["method"] = "dopri5"
    _run_only(data, {"run": ["sm_nan_auto"], "k_v": 20.0})
    _, m = run_scheme(with_duration(parse_case(data, str(CASE)), 2.0), "sm_nan_auto")
    assert m["status"] == "error", m
    assert "unknown error code" not in m["reason"] and "non-finite command out.u[1]" in m["reason"], m["reason"]


def test_the_scheme_check_names_a_non_finite_command(tmp_path):
    """The review: the battery's law calls go through the loop's law, whose non-finite check now stops with
    its own code; the check said 'law: stopped the run (error code 18) at a regular state' where it named
    the output ('out.u[1] is nan ... the outputs must be finite')."""
    new = "    out.sig[2] = K\n    out.u[1] = np.nan\n"
    path, _ = _variant(tmp_path, "sm_nan_check", "    out.sig[2] = K\n", new)
    res = runner.invoke(app, ["schemes", "check", str(path)])
    assert res.exit_code == 2, res.output
    assert "out.u[1] is nan" in res.output and "error code" not in res.output, res.output


@pytest.mark.parametrize("method", ["rk4", "dopri5"])
def test_a_non_finite_signal_stops_the_run_naming_it_and_keeps_what_ran(tmp_path, monkeypatch, method):
    """The attack (round 3, s11 break 3): a law whose declared signal became NaN (or inf) after t = 1 s passed the
    battery (t = 0 and 1.3 s) and its run was stored as ok with NaN and inf in timeseries.npz.  The loop checks
    the logged signals as it checks the command: the stop names out.sig[j], the signal's declared name, the
    value and the time, and the run keeps its rows up to it."""
    import ftcreport.fast.scheme_check as check

    monkeypatch.setattr(check, "ensure_checked", lambda ctrl: None)
    stem = f"sm_sig_nan_{method}"
    new = "    out.sig[2] = K\n    if step.t >= 1.0:\n        out.sig[2] = np.nan\n        out.sig[1] = np.inf\n"
    path, _ = _variant(tmp_path, stem, "    out.sig[2] = K\n", new)
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    data["simulation"]["method"] = method
    _run_only(data, {"run": [stem], "k_v": 20.0})
    run, m = run_scheme(with_duration(parse_case(data, str(CASE)), 3.0), stem)
    assert m["status"] == "error", m
    assert f"scheme '{stem}'" in m["reason"] and "non-finite signal" in m["reason"], m["reason"]
    assert "out.sig[1] (s[1]) = inf" in m["reason"], m["reason"]
    t_stop = float(re.search(r"at t = ([0-9.]+) s", m["reason"]).group(1))
    assert 1.0 <= t_stop < 1.05 and run.t_end == pytest.approx(t_stop, abs=0.011), (t_stop, run.t_end)
    assert run.t_stream.size >= 10 and run.t_stream[-1] < 1.0 + 1e-9
    assert np.isfinite(run.signals["K"]).all() and np.isfinite(run.signals["s"]).all()


def test_the_scheme_check_names_a_non_finite_signal(tmp_path):
    """The loop's own check of a plug-in's logged signals stops with its own code: the battery still names the
    output and the signal ('out.sig[2] (K) is nan'), not an error code."""
    new = "    out.sig[2] = K\n    out.sig[2] = np.nan\n"
    path, _ = _variant(tmp_path, "sm_nan_sig_check", "    out.sig[2] = K\n", new)
    res = runner.invoke(app, ["schemes", "check", str(path)])
    assert res.exit_code == 2, res.output
    assert "out.sig[2] (K) is nan" in res.output and "error code" not in res.output, res.output


@pytest.mark.parametrize("method", ["rk4", "dopri5"])
def test_a_write_far_past_a_signal_late_in_the_run_stops_it_naming_output_index_and_time(tmp_path, method):
    """The attack (round 3, s11 break 2): a law writing out.sig[16] (5 cells past the guard cells) only after the
    battery's states (t = 0 and 1.3 s) passed every check and the run reported ok (or, at out.sig[11], corrupted
    the heap: SIGSEGV after storing ok).  Every plug-in function is compiled with numba's boundscheck: the
    write raises inside the loop, which stops the run as an error naming the output, the index, the time and
    the line; the rows before it are kept and the process goes on."""
    new = "    out.sig[2] = K\n    if step.t > 1.5:\n        out.sig[16] = 7.0e3\n"
    stem = f"sm_late_oob_{method}"
    path, line = _variant(tmp_path, stem, "    out.sig[2] = K\n", new)
    data = __import__("tomllib").loads(CASE.read_text())
    data["plugins"] = [str(path)]
    data["simulation"]["method"] = method
    _run_only(data, {"run": ["nominal", stem], "k_v": 20.0})
    case = with_duration(parse_case(data, str(CASE)), 3.0)
    run, m = run_scheme(case, stem)
    assert m["status"] == "error" and run.status == "error", m
    reason = m["reason"]
    assert f"scheme '{stem}'" in reason and "out.sig[16]" in reason, reason
    assert "index 16 is out of bounds" in reason and "size 3" in reason, reason
    assert f"{stem}.py:{line}" in reason, reason
    t_stop = float(re.search(r"at t = ([0-9.]+) s", reason).group(1))  # a trial stage of the step from 1.5 s
    # t_end: the stage's time (fixed step), the last accepted state's (error-controlled: fast.auto_run)
    assert 1.5 <= t_stop <= 1.52 and t_stop - 0.02 <= run.t_end <= t_stop + 1e-9, (t_stop, run.t_end)
    assert run.t_stream.size >= 100 and run.t_stream[-1] <= t_stop
    _, mn = run_scheme(case, "nominal")  # the process is fine: the next run works
    assert mn["status"] == "ok"
