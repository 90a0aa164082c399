"""The README's Python API tour runs as written (every ```python block, in order, in one namespace)."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_blocks_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) >= 4
    ns: dict = {}
    for i, code in enumerate(blocks):
        exec(compile(code, f"README.md python block {i}", "exec"), ns)
    run = ns["run"]
    assert run.ok and run["rho_hat"].shape[1] == ns["chain"].n_wheels
    # the tidy-data tour: a Dataset with units, a DataFrame, stored results read back
    assert ns["ds"]["tau"].attrs["units"] == "N m" and ns["ds"].sizes["wheel"] == 4
    assert list(ns["res"]["scheme"]) == ["nominal", "switching"]
    assert (ns["stored"]["q"] == ns["sw"]["q"]).all() and (ns["reports"] / "switching.nc").exists()
