"""The package reads top-down (DESIGN.md: model -> control -> sim -> metrics -> report -> cli).

Every import statement of ftcreport/ counts, module level and inside functions alike (a lazy
import is still a dependency): the graph has no cycle, and the numeric core imports nothing from
the edges (reports, CLI, storage, file formats).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "ftcreport"

#: the numeric core: pure, no I/O, no plotting
CORE = ("ftcreport.model", "ftcreport.control", "ftcreport.observers", "ftcreport.sim", "ftcreport.references")
CORE += ("ftcreport.fast.kernels", "ftcreport.fast.loop", "ftcreport.observers.ukf_compiled")
CORE += ("ftcreport.model.motor_compiled", "ftcreport.jit")
#: the edges the core must not reach
EDGES = (
    "ftcreport.report",
    "ftcreport.cli",
    "ftcreport.storage.tidy",
    "ftcreport.storage.store",
    "ftcreport.storage.manifest",
)
EDGES += (
    "ftcreport.storage.results",
    "ftcreport.studies.batch",
    "ftcreport.studies.campaign",
    "ftcreport.studies.coverage",
    "ftcreport.studies.fdi",
)
EDGES += (
    "ftcreport.studies.cluster",
    "ftcreport.cases",
    "ftcreport.cases.schema_doc",
    "ftcreport.runner",
    "ftcreport.studies.check",
)
EDGES += ("ftcreport.infra.lifetime",)
#: standard modules that read or write files or the network, and plotting
IO_MODULES = ("json", "pickle", "shutil", "tomllib", "csv", "sqlite3", "socket", "urllib", "matplotlib", "plotly")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _runtime_nodes(tree: ast.AST):
    """Every node of the file except those under ``if TYPE_CHECKING:`` (annotations only, never run)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                todo.extend(child.orelse)
                continue
            todo.append(child)


def _imports(path: Path, source: str | None = None) -> set[str]:
    """Every module this file imports at run time (relative imports resolved), at any depth of the file."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in _runtime_nodes(ast.parse(path.read_text() if source is None else source)):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # "from .fast import kernels" imports the module fast.kernels; "from .sim import Run" imports sim
            subs = {f"{mod}.{alias.name}" for alias in node.names}
            modules = {s for s in subs if (ROOT.parent / (s.replace(".", "/") + ".py")).exists()}
            modules |= {s for s in subs if (ROOT.parent / s.replace(".", "/") / "__init__.py").exists()}
            out |= modules
            if len(modules) < len(subs):
                out.add(mod)
    return out


def _graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts}
    graph = {}
    for name, path in files.items():
        deps = {d for d in _imports(path) if d in files and d != name}
        graph[name] = deps
    return graph


def test_the_package_imports_no_old_path_of_a_moved_module():
    """The graph above knows only the files on disk: an import of an old path (ftcreport.batch, an alias of
    ftcreport/_moved.py) would be a dependency it cannot see, so the package itself uses none."""
    from ftcreport._moved import MOVED

    old = {f"ftcreport.{name}" for name in MOVED}
    files = [p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts]
    found = sorted(f"{_module_name(p)} -> {d}" for p in files for d in _imports(p) if d in old)
    assert len(files) > 100 and not found, found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_import_graph_has_no_cycle():
    graph = _graph()
    # the package root wires the edges' conversions of a Run (ftcreport/__init__.py): every
    # submodule is imported with the package, so the root's own imports are not dependencies of
    # the modules below it
    graph.pop("ftcreport", None)
    for deps in graph.values():
        deps.discard("ftcreport")
    assert _cycles(graph) == []


def _under(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


@pytest.mark.parametrize("core", CORE)
def test_the_core_imports_no_edge_and_no_file_io(core):
    graph = _graph()
    modules = [m for m in graph if _under(m, (core,))]
    if not modules:
        pytest.skip(f"{core} does not exist")
    for m in modules:
        # everything the module reaches, transitively
        seen, todo = set(), [m]
        while todo:
            v = todo.pop()
            for w in graph.get(v, ()):
                if w not in seen:
                    seen.add(w)
                    todo.append(w)
        assert not [w for w in seen if _under(w, EDGES)], m
        path = ROOT.parent / (m.replace(".", "/") + ".py")
        if not path.exists():
            path = ROOT.parent / m.replace(".", "/") / "__init__.py"
        stdlib = {d.split(".")[0] for d in _imports(path)}
        assert not stdlib & set(IO_MODULES), (m, stdlib & set(IO_MODULES))


def test_the_graph_sees_lazy_imports_and_skips_type_checking():
    """The check can fail: a function-level import is an edge; an annotation-only import is not."""
    src = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .cli import app\n"
    src += "def f():\n    from .report import render\n"
    deps = _imports(ROOT / "sim.py", source=src)
    assert "ftcreport.report.render" in deps
    assert "ftcreport.cli" not in deps
    assert "ftcreport.fast.engine" in _graph()["ftcreport.sim"]  # simulate's function-level import


#: the linearized analysis's numeric part: the loop's matrices, their sampling, limits and margins (pure)
ANALYSIS_CORE = ("ftcreport.analysis.blocks", "ftcreport.analysis.sampled", "ftcreport.analysis.limits")
ANALYSIS_CORE += ("ftcreport.analysis.margins",)
#: the whole analysis package builds a case's loops (it may read the case and build it: cases, runner), but
#: reaches no report, CLI or storage: the page and the command call it, never the reverse
ANALYSIS_EDGES = tuple(e for e in EDGES if e not in ("ftcreport.cases", "ftcreport.runner"))


def _reach(graph: dict[str, set[str]], m: str) -> set[str]:
    seen, todo = set(), [m]
    while todo:
        for w in graph.get(todo.pop(), ()):
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


def test_the_analysis_reaches_no_report_cli_or_store():
    graph = _graph()
    # runner reads the package root's __version__; the root wires the edges' conversions of a Run
    # (as in test_the_import_graph_has_no_cycle), so its own imports are not the analysis's
    graph.pop("ftcreport", None)
    modules = [m for m in graph if _under(m, ("ftcreport.analysis",))]
    assert len(modules) > 5
    for m in modules:
        assert not [w for w in _reach(graph, m) if _under(w, ANALYSIS_EDGES)], m
    for m in ANALYSIS_CORE:
        assert m in graph
        assert not [w for w in _reach(graph, m) if _under(w, EDGES)], m
        stdlib = {d.split(".")[0] for d in _imports(ROOT.parent / (m.replace(".", "/") + ".py"))}
        assert not stdlib & set(IO_MODULES), (m, stdlib & set(IO_MODULES))


#: the loop and what it is made of, and the run's Python side around it (the metric stream, the stops, the
#: re-checks), know the scheme interface (ftcreport.schemes.api and its compiled side,
#: control/interface_compiled.py), the plant (model, with the motors' and drives' kernels) and the engine's
#: own parts, never a concrete law, observer or reference (issue 38 item 6): those reach it through the
#: scheme interface only
LOOP_PARTS = ("ftcreport.fast.loop", "ftcreport.fast.loop_plant", "ftcreport.fast.integrators")
LOOP_PARTS += ("ftcreport.fast.engine", "ftcreport.fast.simulate", "ftcreport.fast.auto_run")
LOOP_PARTS += ("ftcreport.fast.recheck", "ftcreport.fast.stops")
CONCRETE = ("ftcreport.control", "ftcreport.observers", "ftcreport.references", "ftcreport.fast.kernels")
#: the interface's compiled side and what it is built on: the kinematic terms every law is handed (the
#: kinematic law, the matched terms, the reference's jets the kinematic law reads) are the engine's business
#: (issue 38 item 5), computed once per step for whichever scheme runs
INTERFACE = ("ftcreport.control.interface_compiled", "ftcreport.control.kinematic_compiled")
INTERFACE += ("ftcreport.control.tracking_compiled", "ftcreport.references.compiled")


@pytest.mark.parametrize("part", LOOP_PARTS)
def test_the_loop_imports_no_concrete_law_observer_or_reference(part):
    """Transitively: what the part imports, what that imports, and so on."""
    seen = _reach(_graph(), part)
    assert not [d for d in seen if _under(d, CONCRETE) and not _under(d, INTERFACE)], sorted(seen)


#: the top level groups by role (issue 38 item 6): folders, and the four modules every room shares
TOP_LEVEL_MODULES = {"__init__", "_moved", "errors", "runner", "runs", "sim"}
TOP_LEVEL_MODULES |= {"__main__"}  # ``python -m ftcreport``: two lines handing over to the cli room


def test_the_top_level_holds_folders_by_role_and_four_modules():
    modules = {p.stem for p in ROOT.glob("*.py")}
    assert modules == TOP_LEVEL_MODULES, sorted(modules - TOP_LEVEL_MODULES)
    rooms = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()}
    for room in rooms:  # every room says what it is for
        doc = ast.get_docstring(ast.parse((ROOT / room / "__init__.py").read_text()))
        assert doc and len(doc) > 30, room


def test_the_paths_of_earlier_releases_import_the_moved_modules():
    """``ftcreport.batch`` (the README's record_case) and every other moved path: the same module object, in a
    fresh interpreter, whichever name is imported first; a patch through the old name reaches the new."""
    import subprocess
    import sys

    from ftcreport._moved import MOVED

    assert len(MOVED) == 42  # round 3: 27 modules into role folders, 15 of the core below or beside their users
    for name in MOVED:  # every old path is gone from the tree: the alias is the only way in
        assert not (ROOT / (name.replace(".", "/") + ".py")).exists(), name
    code = (
        "import importlib, sys\n"
        "from ftcreport._moved import MOVED\n"
        "for old, new in MOVED.items():\n"
        "    a = importlib.import_module('ftcreport.' + old)\n"
        "    b = importlib.import_module('ftcreport.' + new)\n"
        "    assert a is b and sys.modules['ftcreport.' + old] is b, old\n"
        "    assert b.__name__ == b.__spec__.name == 'ftcreport.' + new, (old, b.__spec__.name)\n"
        "from ftcreport.batch import record_case, run_key\n"
        "import ftcreport.batch as old, ftcreport.studies.batch as new\n"
        "old.run_key = 'patched'\n"
        "assert new.run_key == 'patched'\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


#: the entry points a process may import first: a CLI command, a Dask worker unpickling a task
#: (studies.campaign.run_sample), the warm-up plugin (sim), a plug-in author (schemes), a notebook
FIRST_IMPORTS = (
    "from ftcreport.schemes import get; get('nominal')",
    "import ftcreport.sim",
    "import ftcreport.studies.campaign",
    "import ftcreport.studies.cluster",
    "import ftcreport.evaluation.metrics",
    "import ftcreport.runner",
    "import ftcreport.fast.engine",
    "import ftcreport.analysis",
)


@pytest.mark.parametrize("first", FIRST_IMPORTS)
def test_a_case_loads_whatever_the_process_imported_first(first):
    """The [schemes] table is built from the registry: no import order may build it from a half-filled one
    (a built-in scheme's file importing the case package while the registry loads it gave 'schemes.nominal:
    unknown field' on Dask workers, whose first import is the task's module)."""
    import subprocess
    import sys

    case = ROOT.parent / "cases" / "two_link_switching.toml"
    code = f"{first}\nfrom ftcreport.cases import load_case\nload_case({str(case)!r})\nprint('ok')\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-1500:]


def test_moved_modules_still_find_the_checkout():
    """Two moved modules locate the checkout from their own file: the manifest's git revision (None would
    silently drop the provenance) and the schema docs' files (cases/README.md, cases/case.schema.json)."""
    import subprocess

    from ftcreport.cases import schema_doc
    from ftcreport.storage import manifest

    head = subprocess.run(
        ["git", "-C", str(ROOT.parent), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    git = manifest._git()
    assert git is not None and git["revision"] == head, git
    assert schema_doc.main(["--check"]) == 0


def test_pyproject_lists_every_package_folder():
    """setuptools installs the packages pyproject lists: every folder of ftcreport/ with an __init__.py, and
    the templates (mapped from templates/).  A folder left out is missing from a wheel and a non-editable
    install (tests/test_install.py runs one), which the editable install of a checkout hides."""
    import tomllib

    listed = set(tomllib.loads((ROOT.parent / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    on_disk = {_module_name(p) for p in ROOT.rglob("__init__.py") if "__pycache__" not in p.parts}
    assert listed == on_disk | {"ftcreport.templates"}, (sorted(on_disk - listed), sorted(listed - on_disk))


#: the rooms from the bottom up (docs/ARCHITECTURE.md, "Layers"): a room imports only rooms before it
ROOM_ORDER = (
    "errors", "runs", "infra", "jit", "model", "references", "observers", "schemes", "evaluation", "control",
    "fast", "sim", "cases", "runner", "analysis", "storage", "studies", "report", "cli",
)  # fmt: skip


def _room_edges() -> dict[tuple[str, str], list[str]]:
    """(room, room it imports): the module-level imports behind it, function-local ones included."""
    graph = _graph()
    graph.pop("ftcreport", None)
    edges: dict[tuple[str, str], list[str]] = {}
    for m, deps in graph.items():
        for d in deps:
            a, b = m.split(".")[1:2], d.split(".")[1:2]
            if a and b and a != b and d.startswith("ftcreport.") and not a[0].startswith("_"):
                edges.setdefault((a[0], b[0]), []).append(f"{m} -> {d}")
    return edges


def test_no_cycle_between_folders_and_the_rooms_are_layered():
    """Issue 38 item 6: no cycle between subpackages, counting function-local imports.  Stronger than no pair
    importing each other: every room imports only rooms below it in ROOM_ORDER (so no cycle of any length),
    and ROOM_ORDER names every room there is."""
    edges = _room_edges()
    rooms = {r for e in edges for r in e}
    assert rooms <= set(ROOM_ORDER), sorted(rooms - set(ROOM_ORDER))
    rank = {r: i for i, r in enumerate(ROOM_ORDER)}
    upward = {e: why for e, why in edges.items() if rank[e[0]] <= rank[e[1]]}
    assert not upward, sorted(upward.items())[:5]


def test_the_readme_lists_the_rooms_in_their_order():
    """README's "Layout" says each room imports only those listed before it: its order is ROOM_ORDER's."""
    import re

    text = (ROOT.parent / "README.md").read_text().split("## Layout", 1)[1]
    listed = []
    for line in text.split("```")[1].splitlines():
        m = re.match(r"ftcreport/(\S+?)(?:/|\.py,?)\s", line)
        if m:
            listed += [m.group(1)] + (["runs"] if m.group(1) == "errors" else [])
    assert listed == list(ROOM_ORDER), listed


def test_no_cycle_between_packages_nested_ones_included():
    """A package inside a room (control/builtin/) and the room's own modules do not import each other in a
    circle either: packages by their full dotted name, every import counted."""
    graph = _graph()
    packages = {m for m in graph if (ROOT.parent / m.replace(".", "/") / "__init__.py").is_file()}
    edges: dict[str, set[str]] = {p: set() for p in packages}
    for m, deps in graph.items():
        a = m if m in packages else m.rpartition(".")[0]
        for d in deps:
            b = d if d in packages else d.rpartition(".")[0]
            if a != b and "ftcreport" not in (a, b) and not m.startswith("ftcreport._"):
                edges[a].add(b)
    assert any(p.count(".") > 1 for p in packages)  # there are nested packages to check
    assert _cycles(edges) == []


def test_storage_and_studies_reach_the_pages_through_the_package_root(tmp_path, monkeypatch):
    """storage and studies import no report module: the package root hands them report's functions (a
    batch's pages, a case's notebook view), looked up when called, so a patch of the report module reaches
    the batch as before (tests/test_cli.py interrupts the pages so)."""
    import ftcreport.report.notebook as notebook
    import ftcreport.report.render as render
    from ftcreport import storage, studies

    graph = _graph()
    for room in ("ftcreport.storage", "ftcreport.studies"):
        for m in (m for m in graph if _under(m, (room,))):
            assert not [d for d in graph[m] if _under(d, ("ftcreport.report",))], m
    calls = []
    monkeypatch.setattr(render, "render_all", lambda *a, **k: calls.append((a, k)) or "index")
    assert studies.PAGES["render_all"](tmp_path, pool=None, notify=None) == "index"
    assert calls == [((tmp_path,), {"pool": None, "notify": None})]
    monkeypatch.setattr(notebook, "case_html", lambda res: f"<p>{res}</p>")
    assert storage.VIEWS["case_html"]("case") == "<p>case</p>"
