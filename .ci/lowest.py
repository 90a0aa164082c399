"""Print pyproject's lower bounds of numba, llvmlite and platformdirs as pins (``numba==0.61.2 ...``) for .ci/run."""

import re
import tomllib
from pathlib import Path

deps = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]["dependencies"]
pins = [re.sub(r"^([A-Za-z0-9_.-]+)>=([^,]+),.*$", r"\1==\2", d) for d in deps]
pins = [p for p in pins if p.split("==")[0] in ("numba", "llvmlite", "platformdirs") and "==" in p]
assert len(pins) == 3, f"pyproject.toml: expected lower and upper bounds of numba, llvmlite, platformdirs: {pins}"
print(" ".join(pins))
