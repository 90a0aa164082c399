"""The module paths of releases before the layout by role (issue 38 item 6), kept importable.

``ftcreport.batch`` (the README's ``record_case``, ``run_key``), ``ftcreport.metrics`` and the other
modules that moved into a role folder are the same module objects under their old names: an import of
the old name imports the new module and registers it under both, so a monkeypatch through either name
reaches the one module.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from types import ModuleType

#: old name -> new name, relative to the package
MOVED = {
    **{
        m: f"evaluation.{m}" for m in ("metrics", "claims", "requirements", "compare", "families", "diagnosis", "stats")
    },
    **{m: f"studies.{m}" for m in ("batch", "campaign", "coverage", "fdi", "cluster", "check", "baseline")},
    **{m: f"storage.{m}" for m in ("store", "results", "tidy", "manifest")},
    **{m: f"infra.{m}" for m in ("paths", "inputs", "crashlog", "lifetime", "limits", "names")},
    "display": "studies.display",
    "fields": "schemes.fields",
    "schema_doc": "cases.schema_doc",
    # the compile machinery went below every domain (issue 38 item 6)
    **{f"fast.{m}": f"jit.{m}" for m in ("compiling", "lazy_link", "packed", "refs")},
    # each compiled kernel beside its readable face, by domain
    "fast.motor": "model.motor_compiled",
    "fast.drive": "model.drive_compiled",
    "fast.ukf": "observers.ukf_compiled",
    # the scheme interface's compiled side and the built-in laws and schemes live with the control laws;
    # the check of a new law runs it through the engine
    "schemes.kernels": "control.interface_compiled",
    **{
        f"schemes.{m}": f"control.builtin.{m}"
        for m in ("nominal", "oracle", "switching", "adaptive", "active", "active_ukf")
    },
    "schemes.check": "fast.scheme_check",
}


class _Alias(importlib.abc.Loader):
    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(self.target)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """The module ran under its new name already; the import machinery set the alias's spec on it: undone."""
        module.__spec__ = self.spec


class _MovedFinder(importlib.abc.MetaPathFinder):
    def __init__(self, package: str) -> None:
        self.prefix = package + "."

    def find_spec(self, fullname: str, path=None, target=None):
        if not fullname.startswith(self.prefix):
            return None
        new = MOVED.get(fullname[len(self.prefix) :])
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Alias(self.prefix + new))


def install(package: str) -> None:
    """Let ``package.<old name>`` import the moved module (once per process)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        # first: an alias of a moved package would otherwise let the path finder load the package's files a
        # second time under the old name, from the package's __path__ (seen while control/laws/ was one)
        sys.meta_path.insert(0, _MovedFinder(package))
