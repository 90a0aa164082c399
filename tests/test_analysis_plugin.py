"""A case whose only scheme is a plug-in: the analysis linearizes it through the scheme interface."""

from __future__ import annotations

import tomllib
from pathlib import Path

import tomli_w

from ftcreport.cases import load_case

ROOT = Path(__file__).resolve().parents[1]


def plugin_only_case(tmp_path: Path):
    """cases/two_link_sliding_mode.toml with only the plug-in scheme run (its plugin path made absolute)."""
    data = tomllib.loads((ROOT / "cases" / "two_link_sliding_mode.toml").read_text())
    data["plugins"] = [str((ROOT / "examples" / "schemes" / "sliding_mode.py").resolve())]
    data["schemes"]["run"] = ["sliding_mode"]
    data["simulation"]["duration"] = 40.0
    path = tmp_path / "plugin_only.toml"
    path.write_text(tomli_w.dumps(data))
    return load_case(path)


def test_analysis_of_a_plugin_only_case_does_not_crash(tmp_path):
    """Was IndexError on schemes[0] (exit 3 while the page rendered): the built-in schemes list was empty."""
    from ftcreport.analysis import analyze_case

    res = analyze_case(plugin_only_case(tmp_path))
    assert res["case"] == "plugin_only"
    assert res["controllability"]


def _raising_hook_case(tmp_path: Path, hook: str, tag: str):
    """The sliding-mode example copied under another name with one declaration hook raising KeyError.

    Returns (the case, the plug-in file, the line that raises, the scheme's name, the case file)."""
    src = (ROOT / "examples" / "schemes" / "sliding_mode.py").read_text()
    name = f"raising_{hook}_{tag}"  # a scheme file's stem is its module's name: one per test
    src = src.replace('name="sliding_mode"', f'name="{name}"')
    if hook == "pack":
        anchor = "    p = ctx.params if ctx.params is not None else SlidingModeParams()\n"
        src = src.replace(anchor, anchor + '    {}["missing_key"]\n')
    elif hook == "pack_ftc":  # an ftcreport error the plug-in raises itself: its message, with its line
        anchor = "    p = ctx.params if ctx.params is not None else SlidingModeParams()\n"
        src = src.replace(anchor, anchor + "    raise ModelError(\"k0 is too large {}['missing_key']\")\n")
        src = src.replace(
            "from ftcreport import schemes\n",
            "from ftcreport import schemes\nfrom ftcreport.errors import ModelError\n",
        )
    else:  # initial_state: the law has no own state; declare one so that the hook runs
        src = src.replace("        pack=pack,\n", "        pack=pack,\n        initial_state=_init,\n")
        src = src.replace("# 5. Register", 'def _init(ctx, q, eta):\n    return {}["missing_key"]\n\n\n# 5. Register')
    plugin = tmp_path / f"{name}.py"
    plugin.write_text(src)
    line = next(i for i, text in enumerate(src.splitlines(), 1) if "missing_key" in text)
    data = tomllib.loads((ROOT / "cases" / "two_link_sliding_mode.toml").read_text())
    data["plugins"] = [str(plugin)]
    data["schemes"][name] = data["schemes"].pop("sliding_mode")
    data["schemes"]["run"] = ["nominal", name]
    data.pop("thresholds", None)
    path = tmp_path / f"{name}_case.toml"
    path.write_text(tomli_w.dumps(data))
    return load_case(path), plugin, line, name, path


def test_a_plugin_whose_pack_raises_is_not_analyzed_and_says_where(tmp_path):
    """Was exit 3 ('unexpected KeyError ... a bug', the page's render and analyze both): the plug-in's own
    error is the plug-in's, named by its file, line and hook, and the case's other schemes are analysed."""
    from ftcreport.analysis import analyze_case
    from ftcreport.runner import run_scheme

    case, plugin, line, name, _ = _raising_hook_case(tmp_path, "pack", "analyze")
    res = analyze_case(case, margins=False, limits=False)
    why = res["not_analyzed"][name]
    assert f"{plugin}:{line}" in why and "pack raised KeyError" in why and "missing_key" in why
    assert name not in res["phases"] and "nominal" in res["phases"]
    _, metrics = run_scheme(case, name)  # a run's outcome (status error, stored as such), not a bug
    assert metrics["status"] == "error" and f"{plugin}:{line}" in metrics["reason"]


def test_cases_validate_names_a_plugin_hook_that_raises(tmp_path):
    """Was 'ok': validate now binds every plug-in scheme to the case (its declarations, not its compiled law)."""
    from typer.testing import CliRunner

    from ftcreport.cli import app

    for hook in ("pack", "initial_state", "pack_ftc"):
        _, plugin, line, name, path = _raising_hook_case(tmp_path, hook, "validate")
        res = CliRunner().invoke(app, ["cases", "validate", str(path)])
        assert res.exit_code == 2, res.output
        assert f"schemes.{name}" in res.output and f"{plugin}:{line}" in res.output
        if hook == "pack_ftc":
            assert f"scheme {name}: pack: k0 is too large" in res.output, res.output
        else:
            assert f"{hook} raised KeyError" in res.output
