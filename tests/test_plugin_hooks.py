"""A plug-in's every hook under the same rule: what its own code raises or returns wrong is named by its
file and line, the scheme and the hook, in `cases validate`, `analyze`, `run` and `batch` alike (the second
attack on analyze and validate, items left open: the ``validate``, ``budget``, ``controller``, ``metrics``
and ``cost`` hooks raised as 'unexpected RuntimeError ... (a bug)', exit 3; a signal named ``q`` passed
validate and analyze and crashed the run's metrics; signals of 1e11 values gave an out-of-memory error
naming no scheme; a ``pack`` that refuses k_v > 100 got 'stable at every gain up to 1e+07')."""

from __future__ import annotations

import json

from conftest import plugin_case
from typer.testing import CliRunner

from ftcreport.cases import load_case
from ftcreport.cli import app


def _with_hook(role: str, body: str):
    """An edit of the example that declares ``role=_hook`` with ``body`` as the hook's code."""

    def edit(src: str) -> str:
        src = src.replace("        pack=pack,\n", f"        pack=pack,\n        {role}=_hook,\n", 1)
        return src.replace("# 5. Register", f"def _hook(*args):\n    {body}\n\n\n# 5. Register", 1)

    return edit


def _line(path, words: str) -> int:
    """The line of the plug-in file beside ``path`` (the case) that holds ``words``."""
    plugin = path.parent / path.name.replace("_case.toml", ".py")
    return next(i for i, text in enumerate(plugin.read_text().splitlines(), 1) if words in text)


def _invoke(*args: str):
    return CliRunner().invoke(app, list(args))


def _raising(tmp_path, name: str, role: str, duration: float | None = None):
    """A case whose plug-in's ``role`` hook raises RuntimeError('<name> boom'): (its path, the words that name
    the hook's line), after checking that ``cases validate`` refuses it with them (exit 2)."""
    path = plugin_case(tmp_path, name, _with_hook(role, f"raise RuntimeError('{name} boom')"), duration)
    words = f"{name}.py:{_line(path, f'{name} boom')}: scheme {name}: {role} raised RuntimeError: {name} boom"
    res = _invoke("cases", "validate", str(path))
    assert res.exit_code == 2 and words in " ".join(res.output.split()), res.output
    return path, words


def test_a_validate_or_budget_hook_that_raises_is_named_by_its_line(tmp_path):
    """Were exit 3 in validate and analyze: now exit 2 naming the table, the file and line and the hook."""
    for role in ("validate", "budget"):
        name = f"raising_{role}"
        path = plugin_case(tmp_path, name, _with_hook(role, f"raise RuntimeError('{role} boom')"))
        line = _line(path, f"{role} boom")
        for command in (("cases", "validate"), ("analyze", "--no-confirm")):
            res = _invoke(*command, str(path))
            assert res.exit_code == 2, (role, command, res.output)
            assert f"schemes.{name}" in res.output, res.output
            assert f"{name}.py:{line}" in res.output and f"scheme {name}: {role} raised RuntimeError: {role} boom" in (
                " ".join(res.output.split())
            )


def test_a_validate_hook_field_error_keeps_its_field(tmp_path):
    """The hook's own way to refuse a table (fields.FieldError) is the table's error, not the plug-in's."""
    body = "from ftcreport.schemes import fields\n    raise fields.FieldError("
    body += "'schemes.refusing_validate.k0', 'too large')"
    path = plugin_case(tmp_path, "refusing_validate", _with_hook("validate", body))
    res = _invoke("cases", "validate", str(path))
    assert res.exit_code == 2 and "schemes.refusing_validate.k0: too large" in res.output
    assert "validate raised" not in res.output and "refusing_validate.py:" not in res.output


def test_a_budget_hook_that_returns_junk_is_named(tmp_path):
    path = plugin_case(tmp_path, "junk_budget", _with_hook("budget", "return 'a lot'"))
    res = _invoke("cases", "validate", str(path))
    assert res.exit_code == 2 and "scheme junk_budget: budget returned 'a lot', not" in res.output, res.output


def test_a_controller_hook_that_raises_fails_its_runs_and_is_not_analyzed(tmp_path):
    """Were exit 3 in analyze and run; validate said 'ok'."""
    from ftcreport.analysis import analyze_case
    from ftcreport.runner import run_scheme

    path, words = _raising(tmp_path, "raising_face", "controller", 2.0)
    case = load_case(path)
    out = analyze_case(case, margins=False, limits=False)
    assert words in out["not_analyzed"]["raising_face"] and "raising_face" not in out["phases"]
    run, metrics = run_scheme(case, "raising_face")
    assert metrics["status"] == "error" and words in metrics["reason"] and run.status == "error"


def test_a_controller_hook_that_returns_no_controller_is_named(tmp_path):
    path = plugin_case(tmp_path, "junk_face", _with_hook("controller", "return 42"), 2.0)
    res = _invoke("cases", "validate", str(path))
    assert res.exit_code == 2, res.output
    assert "scheme junk_face: controller returned 42, not a SchemeController" in " ".join(res.output.split())


def test_a_metrics_hook_that_raises_fails_the_run_and_keeps_what_it_computed(tmp_path):
    """Was exit 3 at the end of the run, the simulation lost: now the run's status is error with the hook's
    line, and its log and its other metrics are kept (stored as the failure it is)."""
    from ftcreport.runner import run_scheme

    path = plugin_case(tmp_path, "raising_metrics", _with_hook("metrics", "raise RuntimeError('metrics boom')"), 2.0)
    line = _line(path, "metrics boom")
    run, metrics = run_scheme(load_case(path), "raising_metrics")
    assert metrics["status"] == "error" and run.status == "error"
    assert f"raising_metrics.py:{line}: scheme raising_metrics: metrics raised RuntimeError" in metrics["reason"]
    assert metrics["t_end"] == 2.0 and metrics["metric_samples"] == 201 and run.t.size == 21  # dt 10 ms, log_every 10
    assert metrics["position_error_final"] is not None
    out = tmp_path / "out"
    res = _invoke("run", str(path), "--out", str(out))
    assert res.exit_code == 1, res.output  # a failed run, reported; not an unexpected error (3)
    stored = json.loads((out / "raising_metrics_case" / "raising_metrics" / "metrics.json").read_text())
    assert stored["status"] == "error" and "metrics boom" in stored["reason"]


def test_a_metrics_hook_that_returns_no_dict_is_named(tmp_path):
    from ftcreport.runner import run_scheme

    path = plugin_case(tmp_path, "junk_metrics", _with_hook("metrics", "return [1, 2]"), 1.0)
    _, metrics = run_scheme(load_case(path), "junk_metrics")
    assert metrics["status"] == "error"
    assert "scheme junk_metrics: metrics returned [1, 2], not a dict of metrics" in metrics["reason"]


def test_a_cost_hook_that_raises_is_an_error_in_validate_and_only_a_warning_in_batch(tmp_path):
    """The cost only orders a batch's runs: the batch warns and runs the case; validate refuses it."""
    path, words = _raising(tmp_path, "raising_cost", "cost", 1.0)
    out = tmp_path / "out"
    res = _invoke("batch", str(path), "--out", str(out), "--jobs", "1")
    assert res.exit_code == 0, res.output
    assert words in " ".join(res.output.split()) and "ordered as weight 1" in res.output
    stored = json.loads((out / "raising_cost_case" / "raising_cost" / "metrics.json").read_text())
    assert stored["status"] == "ok"


def test_a_signal_that_shadows_an_engine_signal_is_refused_before_any_run(tmp_path):
    """Was: 'q' passed validate and analyze, then the run's metrics read the law's signal as the chain's
    configuration (IndexError, exit 3)."""
    for clash, words in (("q", "the chain's configuration"), ("tau", "the wheels' torques"), ("t", "the time")):
        name = f"shadow_{clash}"
        edit = lambda s, c=clash: s.replace('signals={"s": 2, "K": 1}', f'signals={{"s": 2, "K": 1, "{c}": 1}}')  # noqa: E731
        path = plugin_case(tmp_path, name, edit)
        res = _invoke("cases", "validate", str(path))
        assert res.exit_code == 2, res.output
        assert f"scheme {name}: signal '{clash}' is a name the engine logs ({words})" in " ".join(res.output.split())
    edit = lambda s: s.replace("        pack=pack,\n", "        pack=pack,\n        derived_names=('K',),\n")  # noqa: E731
    path = plugin_case(tmp_path, "shadow_derived", edit)
    res = _invoke("cases", "validate", str(path))
    assert res.exit_code == 2 and "derived signal 'K' is also a signal of the law" in " ".join(res.output.split())


def test_every_engine_signal_is_a_reserved_name(tmp_path):
    """The names the refusal above holds are the ones a run logs besides the scheme's (a new engine signal
    not added to ENGINE_SIGNALS fails here)."""
    from ftcreport.runner import run_scheme
    from ftcreport.schemes.controller import ENGINE_SIGNALS, KINEMATIC_SIGNALS

    path = plugin_case(tmp_path, "plain_probe", lambda s: s, 0.5)
    case = load_case(path)
    data = case.model_dump()
    data["plant"]["noise"] = {"position": 1e-4, "velocity": 1e-4, "seed": 1}  # q_meas is logged
    from ftcreport.cases import Case

    for c in (case, Case.model_validate(data)):
        run, metrics = run_scheme(c, "plain_probe")
        assert metrics["status"] == "ok", metrics["reason"]
        own = {"s", "K"}
        engine = set(run.signals) - own - set(KINEMATIC_SIGNALS)
        assert engine <= set(ENGINE_SIGNALS) - {"t"}, engine - set(ENGINE_SIGNALS)
        assert set(run.stream) - own - set(KINEMATIC_SIGNALS) <= set(ENGINE_SIGNALS)
    assert "q_meas" in run.signals


def test_signals_too_wide_for_memory_are_named_before_any_allocation(tmp_path):
    """Was 'out of memory (see the limits in cases/README.md)', naming neither the scheme nor the signal."""
    for role, edit, words in (
        ("signals", lambda s: s.replace('signals={"s": 2, "K": 1}', 'signals={"s": 2, "K": 10**11}'), "K: 1e+11"),
        ("n_states", _with_hook("n_states", "return 10**11"), "n_states: 1e+11"),
    ):
        name = f"wide_{role}"
        path = plugin_case(tmp_path, name, edit, 2.0)
        for command in (("cases", "validate"), ("run", "--out", str(tmp_path / "out"))):
            res = _invoke(*command, str(path))
            text = " ".join(res.output.split())
            assert res.exit_code in (1, 2), (role, command, res.output)
            assert f"scheme {name}:" in text and words in text and "over the memory budget of 1024 MiB" in text, text


def test_a_gain_limit_never_reaches_past_the_gains_the_scheme_accepts(tmp_path):
    """Was 'stable at every gain up to 1e+07' for a pack that refuses k_v > 100 (the gain family's line,
    drawn through 10, 20 and 40 1/s, was followed where the scheme never ran).  Every way a plug-in bounds
    its gain: its pack raising, its table's range (le = 150), its validate hook refusing the table."""
    from ftcreport.analysis import analyze_case

    refusing = "    if ctx.k_v > 100.0:\n        raise ValueError(f'k_v {ctx.k_v} too large for this law')\n"
    validating = (
        "def _val(table, case):\n    from ftcreport.schemes import fields\n\n    if table.k_v > 120.0:\n"
        "        raise fields.FieldError('schemes.bounded_validate.k_v', 'chatters above 120')\n\n\n"
    )
    edits = {
        "pack": (lambda s: s.replace("def pack(ctx: SchemeContext) -> P:\n", "def pack(ctx: SchemeContext) -> P:\n"
                                     + refusing), 100.0, "too large for this law"),
        "table": (lambda s: s.replace("        le=1e6,\n        description=\"linear velocity-error gain",
                                      "        le=150.0,\n        description=\"linear velocity-error gain"), 150.0,
                  "less than or equal to 150"),
        "validate": (lambda s: s.replace("# 5. Register", validating + "# 5. Register").replace(
            "        pack=pack,\n", "        pack=pack,\n        validate=_val,\n"), 120.0, "chatters above 120"),
    }  # fmt: skip
    for tag, (edit, top, why) in edits.items():
        name = f"bounded_{tag}"
        case = load_case(plugin_case(tmp_path, name, edit, 2.0))
        out = analyze_case(case, margins=False, confirm=False)
        assert out["limit_kinds"][name]["limits.k_v_max"] == "beyond_range", out["limit_notes"][name]
        assert out["limits"][name]["k_v_max"] is None
        note = out["limit_notes"][name]["limits.k_v_max"]
        assert f"stable at every gain tried from the case's 20 up to {top:g} 1/s, the largest the scheme accepts" in (
            note
        ), note
        assert why in note, note
        assert max(out["_curves"][name]["k"]) <= top  # the figure's curve too: only gains the scheme runs


def test_a_metrics_hook_value_that_metrics_json_cannot_hold_is_named(tmp_path):
    """Was exit 3 'Object of type object is not JSON serializable' at the end of the run (the attack's metobj):
    every value is checked; numeric arrays are stored as lists."""
    from ftcreport.runner import run_scheme

    body = "import numpy as np\n    return {'per_wheel': np.arange(4.0), 'mine': object()}"
    path = plugin_case(tmp_path, "odd_metrics", _with_hook("metrics", body), 1.0)
    _, metrics = run_scheme(load_case(path), "odd_metrics")
    assert metrics["status"] == "error" and "metrics returned 'mine': a value of type object" in metrics["reason"]


def test_a_validate_hook_that_changes_the_case_does_not_change_the_run(tmp_path):
    """Was: a validate hook that set the frozen case's duration to 0.5 s (object.__setattr__) made a 2-s case
    run 0.5 s, status ok; the hook now gets copies."""
    from ftcreport.runner import run_scheme

    body = "object.__setattr__(args[1].simulation, 'duration', 0.5)"
    path = plugin_case(tmp_path, "meddling_validate", _with_hook("validate", body), 2.0)
    case = load_case(path)
    assert case.simulation.duration == 2.0
    _, metrics = run_scheme(case, "meddling_validate")
    assert metrics["status"] == "ok" and metrics["t_end"] == 2.0
