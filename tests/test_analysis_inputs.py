"""Bad input to the analysis says what is wrong, in which file and field, and for which scheme
(issue 37; the attack on `ftcreport analyze`: an infeasible reference named no file, numpy's own words
reached the page for a plug-in whose state or law is not finite)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import tomli_w
from conftest import plugin_case as _plugin_case
from typer.testing import CliRunner

from ftcreport.cases import load_case
from ftcreport.cli import app

ROOT = Path(__file__).resolve().parents[1]


def _tight_circle(tmp_path: Path) -> Path:
    """cases/three_link_circle_faults.toml on a circle of 5 cm: the steady articulation atan(d / R) of
    three 1-m links is near 90 deg, beyond the reference's 80 deg (FlatReference.max_articulation)."""
    data = tomllib.loads((ROOT / "cases" / "three_link_circle_faults.toml").read_text())
    data["reference"]["radius"] = 0.05
    path = tmp_path / "tight.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_an_infeasible_reference_is_named_by_file_and_field(tmp_path):
    path = _tight_circle(tmp_path)
    res = CliRunner().invoke(app, ["analyze", str(path), "--no-confirm"])
    assert res.exit_code == 2
    assert f"{path}: reference: infeasible reference at t = 0 s" in res.output
    res = CliRunner().invoke(app, ["cases", "validate", str(path)])  # was 'ok'
    assert res.exit_code == 2 and f"{path}: reference: infeasible reference at t = 0 s" in res.output


def _nan_state(src: str) -> str:
    src = src.replace("        pack=pack,\n", "        pack=pack,\n        n_states=lambda ctx: 1,\n"
                      "        initial_state=lambda ctx, q, eta: [float('nan')],\n")  # fmt: skip
    return src.replace("    out.sig[2] = K\n", "    out.sig[2] = K\n    out.dx[0] = -x[0]\n")


def _overflowing_law(src: str) -> str:
    return src.replace("    out.u[:] = law_for_pattern(", "    out.u[:] = 1e300 * law_for_pattern(")


def test_a_plugin_state_or_law_that_is_not_finite_is_named_not_numpys_words(tmp_path):
    """Were 'SVD did not converge' (a NaN initial state) and 'Array must not contain infs or NaNs' (a law
    ×1e300): now the scheme, its file and line, the time and what is not finite."""
    from ftcreport.analysis import analyze_case

    path = _plugin_case(tmp_path, "nan_state_probe", _nan_state)
    res = CliRunner().invoke(app, ["cases", "validate", str(path)])
    assert res.exit_code == 2 and "schemes.nan_state_probe" in res.output
    assert "initial_state is not finite at t = 0" in res.output and "nan_state_probe.py:" in res.output
    out = analyze_case(load_case(path), margins=False)
    for phase in out["phases"]["nan_state_probe"]:
        assert phase["stability"] == "not computed"
        assert "scheme nan_state_probe: its state at the operating point" in phase["note"]
        assert "not finite (1 of 1 entries: its initial_state)" in phase["note"]
    assert all("not finite" in v for v in out["limit_notes"]["nan_state_probe"].values())

    path = _plugin_case(tmp_path, "overflow_probe", _overflowing_law)
    out = analyze_case(load_case(path), margins=False)
    assert not out["not_analyzed"]
    for phase in out["phases"]["overflow_probe"]:
        note = phase["note"]
        assert "overflow_probe.py:" in note and "scheme overflow_probe: at t = " in note
        assert "would overflow" in note or "is not finite" in note
        assert "Array must not contain" not in note


# the second attack on analyze and validate (helper report, 2026-12-03): hooks that return junk, call a
# builtin or sys.exit, laws whose output or rates are not finite, a drive saturated everywhere
JUNK_HOOKS = {
    "stiff_size": ("        pack=pack,\n", "        pack=pack,\n        stiff=lambda ctx: [1.0, 2.0, 3.0],\n",
                   "stiff returned 3 values, n_states is 0"),
    "stiff_nan": ("        pack=pack,\n", "        pack=pack,\n        n_states=lambda ctx: 1,\n"
                  "        stiff=lambda ctx: [float('nan')],\n", "stiff returned values that are not finite"),
    "names_int": ("        pack=pack,\n", "        pack=pack,\n        derived_names=lambda ctrl: 5,\n",
                  "derived_names returned 5, not a tuple of names"),
    "n_builtin": ("        pack=pack,\n", "        pack=pack,\n        n_states=len,\n",
                  "n_states raised TypeError: object of type 'SchemeContext' has no len()"),
    "init_none": ("        pack=pack,\n", "        pack=pack,\n        n_states=lambda ctx: 1,\n"
                  "        initial_state=lambda ctx, q, eta: None,\n", "initial_state returned None"),
    "exits": ("def pack(ctx: SchemeContext) -> P:\n", "def pack(ctx: SchemeContext) -> P:\n    import sys\n\n"
              "    sys.exit(0)\n", "pack called sys.exit(0)"),
}  # fmt: skip


def test_a_plugin_hook_that_returns_junk_or_exits_is_named_in_validate(tmp_path):
    """Were exit 3 'unexpected ValueError/TypeError ... (a bug)' (a stiff of the wrong size, derived_names
    not a tuple, the builtin len as n_states) or silence with exit 0 (sys.exit in pack)."""
    for tag, (anchor, edit, words) in JUNK_HOOKS.items():
        path = _plugin_case(tmp_path, f"junk_{tag}", lambda src, a=anchor, e=edit: src.replace(a, e, 1))
        res = CliRunner().invoke(app, ["cases", "validate", str(path)])
        assert res.exit_code == 2, (tag, res.output)
        assert f"junk_{tag}.py:" in res.output and f"scheme junk_{tag}: {words}" in res.output, (tag, res.output)


def test_a_law_whose_command_or_rates_are_not_finite_is_named_in_the_analysis(tmp_path):
    """Were 'the law stops at t = 5 s (error code 18)' (an inf command) and a NaN state rate blamed on the
    measurement's Jacobian overflowing."""
    from ftcreport.analysis import analyze_case

    inf = _plugin_case(
        tmp_path,
        "inf_command",
        lambda s: s.replace("    out.sig[2] = K\n", "    out.sig[2] = K\n    out.u[1] = math.inf\n"),
    )
    out = analyze_case(load_case(inf), margins=False)
    note = out["phases"]["inf_command"][0]["note"]
    assert "inf_command.py:" in note and "its law returned a non-finite command out.u[1] (wheel 1l) = inf" in note
    assert "error code" not in note
    nan_rate = lambda s: _nan_state(s).replace("    out.dx[0] = -x[0]\n", "    out.dx[0] = math.nan\n")  # noqa: E731
    path = _plugin_case(
        tmp_path,
        "nan_rate",
        lambda s: nan_rate(s).replace("lambda ctx, q, eta: [float('nan')]", "lambda ctx, q, eta: [0.0]"),
    )
    out = analyze_case(load_case(path), margins=False)
    note = out["phases"]["nan_rate"][0]["note"]
    assert "its law's state rates at the operating point" in note and "out.dx[0]" in note, note


def test_a_drive_saturated_everywhere_has_no_gain_limit_below_which_it_is_marginal(tmp_path):
    """cases/motors/two_link_switching_motors.toml with I_max = 1e-6 A: its own loop (k_v = 3000) is unstable,
    the search down found 'largest stable k_v 638 1/s', below which every loop is only marginal (the drive has
    no authority: at 300 1/s every phase marginal) and both confirmation runs diverged.  Now no stable range."""
    from ftcreport.analysis import analyze_case

    data = tomllib.loads((ROOT / "cases" / "motors" / "two_link_switching_motors.toml").read_text())
    data["base_case"] = str(ROOT / "cases" / "two_link_switching.toml")
    data["actuators"]["I_max"] = 1e-6
    for key in ("thresholds", "claims", "requirements"):
        data.pop(key, None)
    path = tmp_path / "saturated_drive.toml"
    path.write_text(tomli_w.dumps(data))
    out = analyze_case(load_case(path), margins=False)
    for scheme in ("nominal", "switching", "oracle"):
        assert out["limits"][scheme]["k_v_max"] is None
        assert out["limit_kinds"][scheme]["limits.k_v_max"] == "marginal"
        assert (
            "no stable range: below the point where the loop turns unstable"
            in out["limit_notes"][scheme]["limits.k_v_max"]
        )


def test_a_reference_infeasible_after_the_start_is_analysed_up_to_that_instant(tmp_path):
    """Was: validate warned 'infeasible reference at t = 1 s' (its 50-ms grid), analyze refused the case
    (exit 2, 'at t = 0.9733 s', a frozen instant) and the run stopped at its own step: three instants.  Now one
    instant, validate's warning and analyze's horizon alike; no run goes more than a step past it."""
    import json

    from ftcreport.runner import run_scheme

    data = tomllib.loads((ROOT / "cases" / "three_link_circle_faults.toml").read_text())
    data["reference"] = {"kind": "eight", "scale": 0.18}  # the thesis's eight at 0.18x: too tight after 0.97 s
    data["simulation"]["duration"] = 5.0
    data["faults"] = []
    data["initial"] = {}  # on the reference (its offsets zero): the run follows it until it turns infeasible
    for key in ("thresholds", "claims", "requirements"):
        data.pop(key, None)
    path = tmp_path / "tight_eight.toml"
    path.write_text(tomli_w.dumps(data))
    res = CliRunner().invoke(app, ["cases", "validate", str(path)])
    assert res.exit_code == 0 and "infeasible reference at t = 0.9708 s" in res.output, res.output
    res = CliRunner().invoke(app, ["analyze", str(path), "--json", "--no-confirm"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    horizon = out["horizon"]
    assert horizon["duration"] == 5.0 and "infeasible reference at t = 0.9708 s" in horizon["reason"]
    t = horizon["t_end"]
    assert 0.97065 < t < 0.97075  # the last feasible instant, within the fine grid's 50 us (50 ms / 1000)
    for scheme, phases in out["phases"].items():
        assert [(p["t_start"], p["t_end"]) for p in phases] == [(0.0, t)], scheme
        assert all(p["stability"] in ("stable", "marginal", "unstable") for p in phases), (scheme, phases)
    assert out["limits"] and not out["not_analyzed"]
    _, metrics = run_scheme(load_case(path), "nominal")  # this chain turns singular first, at 0.68 s
    assert metrics["status"] != "ok" and metrics["t_end"] <= t + data["simulation"]["dt"], metrics["t_end"]
    res = CliRunner().invoke(app, ["analyze", str(path), "--no-confirm"])
    assert "analysed up to t = 0.9707 s of 5 s: infeasible reference at t = 0.9708 s" in res.output, res.output


def _tight_eight(tmp_path: Path, name: str, scale: float, duration: float, **simulation) -> Path:
    """cases/three_link_circle_faults.toml on the thesis's eight at ``scale`` (too tight after about 1 s), from
    on the reference, without faults, the nominal scheme alone."""
    data = tomllib.loads((ROOT / "cases" / "three_link_circle_faults.toml").read_text())
    data["reference"] = {"kind": "eight", "scale": scale}
    data["simulation"] |= {"duration": duration} | simulation
    data["faults"], data["initial"], data["schemes"] = [], {}, {"run": ["nominal"]}
    for key in ("thresholds", "claims", "requirements"):
        data.pop(key, None)
    path = tmp_path / f"{name}.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_the_horizon_is_within_the_run_and_its_first_step(tmp_path):
    """The attack on the horizon: its grid ran 25 ms past the case's end (a run of 0.98 s 'analysed up to
    0.9922 s of 0.98 s'); a reference infeasible within the first step (0.00525 s, dt 20 ms) was validate's
    warning and analyze's 'dt longer than the duration'; with sampled control the periodic limit's instants
    went past the horizon (every scheme 'not analysed')."""
    import json

    path = _tight_eight(tmp_path, "ends_first", 0.1825, 0.98)  # infeasible from 0.9922 s, after the end
    res = CliRunner().invoke(app, ["cases", "validate", str(path)])
    assert res.exit_code == 0 and "infeasible" not in res.output, res.output
    res = CliRunner().invoke(app, ["analyze", str(path), "--json", "--no-confirm"])
    assert res.exit_code == 0 and json.loads(res.output)["horizon"] is None, res.output
    path = _tight_eight(tmp_path, "first_step", 0.0655, 5.0)  # infeasible from 0.00525 s
    for command in (["cases", "validate"], ["analyze", "--no-confirm"]):
        res = CliRunner().invoke(app, [*command, str(path)])
        assert res.exit_code == 2, res.output
        assert "within the run's first step (dt = 0.02 s): no run takes a step" in " ".join(res.output.split())
    path = _tight_eight(tmp_path, "sampled", 0.18, 5.0, sample_time=0.04)
    out = json.loads(CliRunner().invoke(app, ["analyze", str(path), "--json", "--no-confirm"]).output)
    assert not out["not_analyzed"] and out["phases"]["nominal"][0]["t_end"] == out["horizon"]["t_end"]
