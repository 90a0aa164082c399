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
