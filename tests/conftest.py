"""Shared helpers for the test-suite."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ftcreport.model import Chain

_ROOT = Path(__file__).resolve().parents[1]


def random_chain(rng: np.random.Generator, n: int) -> Chain:
    """A chain with distinct random physical parameters (so no symmetry hides a bug)."""
    return Chain(
        a=rng.uniform(-0.2, 0.5, n),
        b=rng.uniform(0.3, 0.9, n),
        r=rng.uniform(0.1, 0.3, n),
        m=rng.uniform(10.0, 40.0, n),
        I=rng.uniform(2.0, 20.0, n),
        d=rng.uniform(0.6, 2.0, n - 1),
    )


def harness():
    """The test harnesses' plug-in scheme (tests/data/harness_scheme.py), loaded once: its module."""
    from ftcreport.schemes import load_plugin

    load_plugin(Path(__file__).parent / "data" / "harness_scheme.py")
    return sys.modules["ftcreport_plugin_harness_scheme"]


def plugin_case(tmp_path: Path, name: str, edit, duration: float | None = None) -> Path:
    """The sliding-mode example as scheme ``name`` (edited by ``edit``), the case's only scheme, in a copy of
    cases/two_link_sliding_mode.toml (``duration``: its simulation's, the faults after it left out; default
    the case's 70 s)."""
    src = edit((_ROOT / "examples" / "schemes" / "sliding_mode.py").read_text().replace('"sliding_mode"', f'"{name}"'))
    plugin = tmp_path / f"{name}.py"
    plugin.write_text(src)
    data = tomllib.loads((_ROOT / "cases" / "two_link_sliding_mode.toml").read_text())
    data["plugins"] = [str(plugin)]
    data["schemes"][name] = data["schemes"].pop("sliding_mode")
    data["schemes"]["run"] = [name]
    data.pop("thresholds", None)
    data["plant"].pop("saturation", None)
    if duration is not None:
        data["simulation"]["duration"] = duration
        data["faults"] = [f for f in data["faults"] if f["time"] < duration]
    path = tmp_path / f"{name}_case.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def random_q(rng: np.random.Generator, n: int, max_art: float = np.radians(60)) -> np.ndarray:
    """Random configuration with articulation angles below max_art."""
    th1 = rng.uniform(-np.pi, np.pi)
    arts = rng.uniform(-max_art, max_art, n - 1)
    th = np.concatenate(([th1], th1 - np.cumsum(arts)))  # robot order theta_1..theta_n
    return np.concatenate((rng.normal(size=2), th[::-1]))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20181)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--regen-golden",
        action="store_true",
        default=False,
        help="rewrite tests/data/golden/*.npz from the current engine (tests/test_golden.py)",
    )
