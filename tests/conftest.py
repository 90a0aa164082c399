"""Shared helpers for the test-suite."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ftcreport.model import Chain


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
