"""Bad input to the analysis says what is wrong, in which file and field, and for which scheme
(issue 37; the attack on `ftcreport analyze`: an infeasible reference named no file, numpy's own words
reached the page for a plug-in whose state or law is not finite)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import tomli_w
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


def _plugin_case(tmp_path: Path, name: str, edit) -> Path:
    """The sliding-mode example as scheme ``name`` (edited by ``edit``), the case's only scheme."""
    src = edit((ROOT / "examples" / "schemes" / "sliding_mode.py").read_text().replace('"sliding_mode"', f'"{name}"'))
    plugin = tmp_path / f"{name}.py"
    plugin.write_text(src)
    data = tomllib.loads((ROOT / "cases" / "two_link_sliding_mode.toml").read_text())
    data["plugins"] = [str(plugin)]
    data["schemes"][name] = data["schemes"].pop("sliding_mode")
    data["schemes"]["run"] = [name]
    data.pop("thresholds", None)
    data["plant"].pop("saturation", None)
    path = tmp_path / f"{name}_case.toml"
    path.write_text(tomli_w.dumps(data))
    return path


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
