"""Everything imported is declared: ftcreport/ against pyproject's dependencies, tests/ against them plus the
test extra (imports found by parsing the source, so an import inside a function counts too)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement(spec: str) -> tuple[str, list[str]]:
    m = re.match(r"\s*([A-Za-z0-9_.\-]+)\s*(?:\[([^\]]*)\])?", spec)
    assert m, spec
    return _norm(m.group(1)), [e.strip() for e in (m.group(2) or "").split(",") if e.strip()]


def _declared(specs: list[str]) -> set[str]:
    """Distributions named in ``specs``, with those their extras bring (dask[distributed] -> distributed)."""
    out = set()
    for spec in specs:
        name, extras = _requirement(spec)
        out.add(name)
        for extra in extras:
            for req in metadata.requires(name) or []:
                if re.search(rf"extra\s*==\s*['\"]{re.escape(extra)}['\"]", req):
                    out.add(_requirement(req)[0])
    return out


def _imports(folder: Path) -> dict[str, set[str]]:
    """Top-level module name -> files importing it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for path in sorted(folder.rglob("*.py")):
        if ".venv" in path.parts or "_loops" in path.parts:  # _loops: the engine's generated, git-ignored modules
            continue  # (one per law; a plug-in law's imports its scheme file, ftcreport_plugin_<stem>)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for n in names:
                found.setdefault(n.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


def _undeclared(folder: Path, declared: set[str]) -> dict[str, list[str]]:
    dists = metadata.packages_distributions()
    bad = {}
    for mod, files in _imports(folder).items():
        if mod in sys.stdlib_module_names or mod in ("ftcreport", "__future__"):
            continue
        if folder.name == "tests" and (ROOT / "tests" / f"{mod}.py").exists():
            continue  # conftest and helpers of the suite
        providers = {_norm(d) for d in dists.get(mod, [])}
        if not providers:
            bad[mod] = [f"no installed distribution provides it ({', '.join(sorted(files))})"]
        elif not providers & declared:
            bad[mod] = [f"provided by {', '.join(sorted(providers))}, not declared ({', '.join(sorted(files))})"]
    return bad


RUNTIME = _declared(PYPROJECT["project"]["dependencies"])
TEST = RUNTIME | _declared(PYPROJECT["project"]["optional-dependencies"]["test"])


def test_package_imports_only_declared_dependencies():
    bad = _undeclared(ROOT / "ftcreport", RUNTIME)
    assert bad == {}, bad
    # the direct ones the issue names are declared by name, not only through another package
    for name in ("rich", "numba", "slycot", "dask", "pandas", "pyarrow", "xarray", "h5netcdf"):
        assert name in RUNTIME, name


def test_tests_import_only_declared_dependencies():
    assert _undeclared(ROOT / "tests", TEST) == {}


def test_the_scan_finds_an_undeclared_import(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text("import numpy\n\ndef f():\n    import rich.progress\n    from typer import Typer\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert set(_undeclared(pkg, {"numpy"})) == {"rich", "typer"}
    assert _undeclared(pkg, {"numpy", "rich", "typer"}) == {}


def test_the_numeric_core_does_not_load_pandas_or_xarray():
    code = (
        "import sys\n"
        "import ftcreport.sim, ftcreport.runner, ftcreport.cases, ftcreport.evaluation.metrics, ftcreport.model\n"
        "print(sorted(m for m in ('pandas', 'xarray', 'pyarrow', 'h5netcdf', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"
