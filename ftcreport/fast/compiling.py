r"""How a scheme's loop is compiled: each kernel's code optimized once, in the loop, not at every level.

numba compiles a kernel that another kernel calls as a function of its own: it links every kernel
below it into one LLVM module, optimizes that module fully (O3) and emits its machine code.  The
loop (fast/loop.py) calls its kernels nine levels deep (the loop, the stage, the law, the matched
terms, the kinematic law, the reference, ...), so the code of a leaf was optimized and emitted
nine times over: 57 s of CPU for the switching loop on the 2-core machine, 96 % of it in LLVM.

Only the loop's own module runs in a simulation: it contains every kernel below it, linked in,
and its full optimization inlines and optimizes them there.  So while a loop compiles
(:func:`loop_compile`), the kernels below it get numba's cheap module passes only (no full O3
run of their closure); the loop's entry points (:data:`ROOTS`) get the full passes as always.
The loop's machine code comes from the same IR through the same full pipeline, so it computes the
same numbers (LLVM's optimizations keep IEEE semantics: no fast-math flags are set); the golden
windows (tests/test_golden.py) hold at 1e-9.  Measured on the switching loop: 57 s -> 34 s of
CPU, and the warm run no slower (benchmarks/run.py).

numba's cache of a kernel is keyed on its own file's content only, so a kernel cached from one
file (fast/builtin.py's dispatchers, a plug-in's law, a loop module) kept the old code of a kernel
it calls in another file (fast/kernels.py) after that file changed: a `git pull` that changed
kernels.py alone ran stale code.  :func:`install_cache_stamp` adds numba's documented extension
point, a cache locator, for every module of ftcreport (and its generated loops and plug-ins): the
stamp of their cache entries is their own file's and :func:`engine_stamp`, a hash of every compiled
source of the package, so any change renews every entry that could have linked it.

The hook wraps one method of numba's code library (``CPUCodeLibrary._optimize_final_module``,
numba 0.58-0.68).  If a numba release renames it, :data:`ACTIVE` is False and every kernel is
optimized fully, as numba does by default: slower to compile, same results.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

__all__ = ["ACTIVE", "ROOTS", "engine_stamp", "install_cache_stamp", "loop_compile"]

ROOTS = frozenset({"run_steps", "first_law", "first_discrete"})  # fast/loop.py's entry points

_STATE = threading.local()  # numba compiles in the calling thread, under its global compiler lock


def _install() -> bool:
    try:
        from numba.core import codegen
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    lib = getattr(codegen, "CPUCodeLibrary", None)
    full = getattr(lib, "_optimize_final_module", None)
    if full is None or getattr(full, "_ftcreport", False):
        return full is not None

    def optimize_final_module(self) -> None:
        if not getattr(_STATE, "on", False) or self.name in ROOTS:
            return full(self)
        # numba's own first stage (inlining for reference-count pruning), without the full O3 run
        mpm, pb = self._codegen._module_pass_manager(
            loop_vectorize=False, slp_vectorize=False, opt=0, cost="cheap"
        )  # fmt: skip
        mpm.run(self._final_module, pb)

    optimize_final_module._ftcreport = True
    lib._optimize_final_module = optimize_final_module
    return True


ACTIVE = _install()


@contextlib.contextmanager
def loop_compile() -> Iterator[None]:
    """Within: the kernels compiled in this thread below a loop's entry points skip numba's full
    optimization of their own closure (the loop's entry point optimizes all of them, linked)."""
    before = getattr(_STATE, "on", False)
    _STATE.on = True
    try:
        yield
    finally:
        _STATE.on = before


_ENGINE_FILES = ("fast",)  # the package's compiled sources: ftcreport/fast/*.py


def engine_stamp() -> str:
    """A hash of every compiled source of the package (read once per process)."""
    stamp = getattr(engine_stamp, "_value", None)
    if stamp is None:
        import hashlib
        from pathlib import Path

        root = Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for sub in _ENGINE_FILES:
            for path in sorted((root / sub).glob("*.py")):
                h.update(path.name.encode() + b"\0" + path.read_bytes())
        stamp = engine_stamp._value = h.hexdigest()
    return stamp


def install_cache_stamp() -> bool:
    """Key the numba cache of every ftcreport kernel on :func:`engine_stamp` too (once per process)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    base = getattr(caching, "_CacheLocator", None) or getattr(caching, "CacheLocator", None)
    classes = getattr(impl, "_locator_classes", None)
    if base is None or not isinstance(classes, list):
        return False
    if any(getattr(c, "_ftcreport", False) for c in classes):
        return True
    numba_classes = list(classes)

    class EngineLocator(base):
        """numba's own locator for the file, with the engine's stamp joined to the file's."""

        _ftcreport = True

        def __init__(self, inner):
            self._inner = inner

        def ensure_cache_path(self):
            return self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_source_stamp(self):
            return (self._inner.get_source_stamp(), engine_stamp())

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        @classmethod
        def from_function(cls, py_func, py_file):
            if not str(getattr(py_func, "__module__", "")).startswith("ftcreport"):
                return None  # another package's function: numba's locators, untouched
            for other in numba_classes:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
            return None

    classes.insert(0, EngineLocator)
    return True
