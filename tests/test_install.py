"""A read-only install runs a case and writes nothing inside the package (issue 38 item 3).

The package is installed non-editable (``pip install --target``, a wheel built from this checkout), its
directory made read-only (``chmod -R a-w``), and a case run from it in a fresh process with an empty cache
directory.  As root a mode bit does not stop a write, so there the case runs as the unprivileged user
``nobody`` (``setpriv``): a write inside the package would fail, not only be seen.  Either way, every file
of the install is listed (path, size, modification time) before and after.  The run's log must be
bit-identical to the same run of this checkout (the same code and compiler).
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "cases" / "two_link_switching.toml"

PROBE = """
import json, sys
import numpy as np
import ftcreport
from ftcreport.cases import load_case, with_duration
from ftcreport.runner import run_scheme

run, metrics = run_scheme(with_duration(load_case(sys.argv[1]), 2.0), "nominal")
arrays = {"t": run.t} | {k: np.asarray(v) for k, v in run.signals.items()}
np.savez(sys.argv[2], **arrays)
files = [getattr(m, "__file__", None) for k, m in list(sys.modules.items()) if k.split(".")[0] == "ftcreport"]
print(json.dumps({"package": ftcreport.__file__, "status": metrics["status"], "n": int(run.t.size), "files": files}))
"""


def _listing(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(folder.rglob("*"))}


def _reachable_by_others(path: Path) -> bool:
    """Whether another user can read ``path`` (every folder above it searchable, the file readable)."""
    path = path.resolve()
    folders_ok = all(p.stat().st_mode & stat.S_IXOTH for p in path.parents)
    return folders_ok and bool(path.stat().st_mode & stat.S_IROTH)


def _as_nobody() -> list[str]:
    """The command prefix that drops root to ``nobody`` (uid/gid 65534), or [] when not root (or when the
    interpreter or this checkout are not readable by another user: then the listing alone checks)."""
    if os.geteuid() != 0 or not all(_reachable_by_others(p) for p in (Path(sys.executable), CASE)):
        return []
    setpriv = shutil.which("setpriv")
    return [] if setpriv is None else [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]


@pytest.mark.slow
def test_a_read_only_install_runs_a_case_and_writes_nothing_inside():
    base = Path(tempfile.mkdtemp(prefix="ftcreport-install-"))
    try:
        _install_and_run(base)
    finally:
        subprocess.run(["chmod", "-R", "u+w", str(base)], check=False)
        shutil.rmtree(base, ignore_errors=True)


def _install_and_run(base: Path) -> None:
    base.chmod(0o755)  # the unprivileged run reads the install and the probe
    site = base / "site"
    # from a copy of the checkout's sources: pip builds in the source tree, and a build/ left there by an
    # earlier version (modules since moved or removed) would be installed along with them
    src = base / "src"
    skip = shutil.ignore_patterns("build", "dist", ".git", ".venv*", "reports", "*.egg-info", "__pycache__")
    shutil.copytree(ROOT, src, ignore=skip)
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(site), str(src)]
    res = subprocess.run(pip, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    package = site / "ftcreport"
    assert (package / "fast" / "kernels.py").is_file() and (package / "infra" / "paths.py").is_file()
    subprocess.run(["chmod", "-R", "a-w", str(site)], check=True)
    before = _listing(site)
    (base / "probe.py").write_text(PROBE)
    work = base / "work"  # the run's home, cache and output
    work.mkdir()
    work.chmod(0o777)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "FTCREPORT_", "PYTHON"))}
    env |= {"PYTHONPATH": str(site), "HOME": str(work), "FTCREPORT_CACHE": str(work / "cache")}
    run = [*_as_nobody(), sys.executable, str(base / "probe.py"), str(CASE), str(work / "installed.npz")]
    res = subprocess.run(run, capture_output=True, text=True, env=env, cwd=work)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.splitlines()[-1])
    assert Path(out["package"]).is_relative_to(package)  # the install ran, not this checkout
    # every module of the run came from the install: a subpackage missing from the wheel would otherwise be
    # found in this checkout by the editable install's finder, and the test would pass on a broken install
    outside = [f for f in out["files"] if f is not None and not Path(f).is_relative_to(package)]
    assert not outside, outside[:5]
    assert out["status"] == "ok" and out["n"] > 100
    assert _listing(site) == before  # nothing written, changed or removed inside the install
    assert any((work / "cache").rglob("*.nbi")) and any((work / "cache").rglob("ftcreport_loop_*.py"))
    # the same run from this checkout (its usual cache directory): the same numbers, bit for bit
    res = subprocess.run(
        [sys.executable, str(base / "probe.py"), str(CASE), str(base / "here.npz")], capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    installed, here = np.load(work / "installed.npz"), np.load(base / "here.npz")
    assert sorted(installed.files) == sorted(here.files)
    for name in here.files:
        assert np.array_equal(installed[name], here[name], equal_nan=True), name
