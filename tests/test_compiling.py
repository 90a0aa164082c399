"""How ftcreport's kernels are compiled (jit/compiling.py): numba left as found, the acceleration scoped to
ftcreport's own kernels, refs, the loop's variant constants, the cache outside the package.

None of these may change a number: the golden windows (tests/test_golden.py) hold the results at 1e-9, and
``.ci/run`` checks that runs are bit-identical with the acceleration off; here, the pieces' own contracts.
Probes that compile run in a fresh process with their own cache directory (``FTCREPORT_CACHE``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit

from ftcreport.fast import kernels as F
from ftcreport.fast.engine import loop_for
from ftcreport.jit import compiling
from ftcreport.jit.refs import as_ref

ROOT = Path(__file__).resolve().parents[1]


class _Inner(NamedTuple):
    a: np.ndarray
    g: float


class _Outer(NamedTuple):
    m: np.ndarray
    inner: _Inner
    n: int


@njit(cache=False)
def _read(P):
    return P.m[1, 0] + P.inner.a[2] * P.inner.g + P.n


@njit(cache=False)
def _read_ref(P):
    return _read(as_ref(P))


@njit(cache=False)
def _pair_ref(P, Q):
    r = as_ref((P, Q))
    r[0].inner.a[0] = 7.0  # a ref holds the same arrays: writes reach the caller's tuple
    return _read(r[0]) + _read(r[1])


def _python(code: str, folder: Path, **env: str) -> str:
    """Run ``code`` in a fresh interpreter (cwd and import path ``folder``); its standard output."""
    environ = dict(os.environ, FTCREPORT_CACHE=str(folder / "cache"), PYTHONPATH=f"{folder}{os.pathsep}{ROOT}")
    environ.update(env)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ, cwd=folder)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _last_json(out: str) -> dict:
    return json.loads(out.strip().splitlines()[-1])


def test_ref_reads_the_same_fields_as_the_tuple():
    P = _Outer(np.arange(6.0).reshape(3, 2), _Inner(np.array([1.0, 2.0, 3.0]), 0.5), 4)
    assert _read_ref(P) == _read(P) == 2.0 + 1.5 + 4  # exact: the same loads, no arithmetic changed
    Q = P._replace(n=10)
    assert _pair_ref(P, Q) == (2.0 + 1.5 + 4) + (2.0 + 1.5 + 10)
    assert P.inner.a[0] == 7.0


def test_variants_are_separate_modules_with_their_constants():
    from ftcreport.control.passive_law import passive_discrete, passive_law

    plain = loop_for(passive_law, passive_discrete, motors=False, sampled=False)
    motors = loop_for(passive_law, passive_discrete, motors=True, sampled=False)
    own = loop_for(passive_law, passive_discrete, motors=False, sampled=False, terms=1)
    assert plain is not motors and own is not plain
    assert (plain.MOTORS, plain.SAMPLED, plain.TERMS_MODE) == (False, False, 0)
    assert (motors.MOTORS, motors.SAMPLED) == (True, False)
    assert own.TERMS_MODE == 1
    assert loop_for(passive_law, passive_discrete, motors=False, sampled=False) is plain  # one per process


# --------------------------------------------------------------------------- numba as it was found (38.1)
_AS_FOUND = """
import json, sys
import numpy as np
from numba import njit

@njit
def warm(x):  # numba's own first use (target context, registries) before the snapshot
    return x + 1

warm(1)


def snapshot():
    mods = {n: m for n, m in list(sys.modules.items()) if m is not None and n.split(".")[0] in ("numba", "llvmlite")}
    classes = {}
    for n, m in mods.items():
        for k, v in vars(m).items():
            if isinstance(v, type) and v.__module__ == n:
                classes[f"{n}.{k}"] = (v, dict(vars(v)))
    return {n: dict(vars(m)) for n, m in mods.items()}, classes


globs, classes = snapshot()
from llvmlite.binding import ffi
from numba.core import caching
callbacks = list(ffi.lib._lock._cblist)
impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
locators = list(impl._locator_classes)

import ftcreport
from ftcreport.cases import load_case
from ftcreport.runner import run_scheme

run, metrics = run_scheme(load_case(sys.argv[1]), "switching")  # compiles (or loads) the loop and its kernels


@njit(cache=True)
def unrelated(a, b):  # another package's function, compiled after ftcreport's
    a[:] = b
    return a.sum()


try:
    unrelated(np.zeros(2), np.zeros(3))
    message = ""
except ValueError as exc:
    message = str(exc)
changed = []
for n, g in globs.items():
    mod = sys.modules[n]
    changed += [f"{n}.{k}" for k, v in g.items() if not k.startswith("__") and getattr(mod, k, None) is not v]
for name, (cls, attrs) in classes.items():
    now = dict(vars(cls))
    changed += [f"{name}.{k}" for k, v in attrs.items() if now.get(k) is not v]
    changed += [f"{name}.{k} (new)" for k in set(now) - set(attrs) if k != "__slotnames__"]  # copyreg's own cache
cres = unrelated.overloads[unrelated.signatures[0]]
name = lambda c: c.__module__ + "." + c.__qualname__
print(json.dumps({
    "status": metrics["status"], "changed": changed, "message": message,
    "callbacks": ffi.lib._lock._cblist == callbacks and all(a is b for a, b in zip(ffi.lib._lock._cblist, callbacks)),
    "locators": all(a is b for a, b in zip(locators, impl._locator_classes, strict=True)),
    "library": name(type(cres.library)), "dispatcher": name(type(unrelated)),
    "pipeline": name(unrelated._compiler.pipeline_class), "entry": type(cres.entry_point).__name__,
    "locator": name(type(unrelated._cache._impl._locator)),
}))
"""


def test_numba_is_left_as_found_after_a_run(tmp_path):
    # issue 38 item 1: after import ftcreport and a run, every numba and llvmlite class attribute and module
    # global is the object it was before the import, and a function of another package compiled afterwards
    # goes through numba's own dispatcher, compiler, code library, cache locator, and gets numba's own messages
    (tmp_path / "probe.py").write_text(_AS_FOUND)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))  # the unrelated function's cache (numba's)
    env.setdefault("FTCREPORT_CACHE", str(tmp_path / "cache"))
    res = subprocess.run(
        [sys.executable, "probe.py", str(ROOT / "cases" / "two_link_switching.toml")],
        cwd=tmp_path, env=env, capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    out = _last_json(res.stdout)
    assert out["status"] == "ok"
    assert out["changed"] == []
    assert out["callbacks"] and out["locators"]
    assert out["library"] == "numba.core.codegen.JITCodeLibrary"
    assert out["dispatcher"] == "numba.core.registry.CPUDispatcher"
    assert out["pipeline"] == "numba.core.compiler.Compiler"
    assert out["entry"] == "builtin_function_or_method"  # numba's compiled wrapper, nothing deferred
    assert out["locator"].startswith("numba.core.caching.")
    # numba's own words (with the shapes; numba 0.61 prints them in the other order)
    assert re.fullmatch(r"cannot assign slice of shape \([23],\) from input of shape \([23],\)", out["message"])


# --------------------------------------------------------------------------- the acceleration, scoped
_KERNELS = """
import numpy as np
from ftcreport.jit.compiling import jit


@jit
def leaf(x):
    s = 0.0
    for i in range(x.size):
        s += x[i] * x[i] + 0.5
    if x[0] > 100.0:
        print("big", s)  # numba's Python API: needs the kernel's environment, set once code holds it
    return s


@jit
def middle(x):
    return leaf(x) * 2.0 + leaf(x[:2])


@jit
def root(x):  # compiled first from Python: an entry point
    return middle(x) + 1.0


@jit
def other_root(x):  # another entry point, compiled after: links the deferred kernels again
    return middle(x) - leaf(x)
"""

_DEFERRED_PROBE = """
import json
import numpy as np
from numba import njit
from ftcreport.jit import compiling
from ftcreport.jit.compiling import jit
import kmod


@jit(cache=False)
def third(x):  # an entry point compiled in every process: below it, leaf and middle compile or load as bitcode
    return kmod.middle(x) * kmod.leaf(x)


x = np.linspace(-1.0, 1.0, 5)
out = {"accelerated": compiling.accelerated()}
out["root"] = kmod.root(x)  # compiled, or loaded from the cache as machine code (nothing below it loads)
out["big"] = kmod.root(x + 200.0)
out["third"] = third(x)
cres = lambda f: f.overloads[f.signatures[0]]
out["leaf_deferred"] = isinstance(cres(kmod.leaf).entry_point, compiling.LazyEntry)
out["leaf_cheap"] = bool(cres(kmod.leaf).library._ftc_cheap)
out["root_library"] = type(cres(kmod.root).library).__name__
out["root_emitted"] = type(cres(kmod.root).entry_point).__name__
out["middle"] = kmod.middle(x)  # from Python: its code is emitted on this first call, fully optimized
out["middle_again"] = kmod.middle(x)  # numba's own table of wrappers now
out["middle_full"] = not cres(kmod.middle).library._ftc_cheap and not cres(kmod.middle).library._ftc_deferred
out["middle_entry"] = type(cres(kmod.middle).entry_point).__name__
out["second_root"] = kmod.other_root(x)


@njit
def outside(x):  # another package's function linking a deferred ftcreport kernel: emitted first
    return kmod.leaf(x) + 1.0


out["outside"] = outside(x)
out["leaf_after_outside"] = type(cres(kmod.leaf).library).__name__, bool(cres(kmod.leaf).library._ftc_deferred)
out["hits"] = [sum(f.stats.cache_hits.values()) for f in (kmod.leaf, kmod.middle, kmod.root)]
print(json.dumps(out))
"""


def test_below_an_entry_point_cheap_passes_and_deferred_code_then_from_the_cache(tmp_path):
    (tmp_path / "kmod.py").write_text(_KERNELS)
    runs = []
    for _ in range(2):  # compiles and saves, then loads from the cache in a fresh process
        out = _python(_DEFERRED_PROBE, tmp_path)
        lines = out.splitlines()
        assert lines[:2] == ["big 200005.0", "big 79402.25"]  # the deferred kernel's environment was set
        runs.append(json.loads(lines[-1]))
    x = np.linspace(-1.0, 1.0, 5)
    leaf = float(np.sum(x * x + 0.5))  # 5.0: sums of squares of multiples of 0.5, exact in binary
    middle = 2.0 * leaf + float(np.sum(x[:2] * x[:2] + 0.5))
    for out in runs:
        assert out["accelerated"]
        assert out["root"] == middle + 1.0 and out["second_root"] == middle - leaf
        assert out["third"] == middle * leaf
        assert out["leaf_deferred"] and out["leaf_cheap"]
        assert (out["middle"], out["middle_again"]) == (middle, middle)
        assert out["middle_full"] and out["middle_entry"] == "builtin_function_or_method"
        assert out["root_library"] == "KernelLibrary" and out["root_emitted"] == "builtin_function_or_method"
        assert out["outside"] == leaf + 1.0
        assert out["leaf_after_outside"] == ["KernelLibrary", False]  # emitted before numba's own link
    assert runs[0]["hits"] == [0, 0, 0]
    assert runs[1]["hits"] == [1, 1, 1]  # leaf and middle loaded as bitcode below third, root as machine code


_ENTRY_PROBE = """
import json
import numpy as np
from ftcreport.jit import compiling
from ftcreport.fast import kernels as F
from ftcreport.fast.engine import _chain
from ftcreport.model import Chain

chain = Chain.uniform(3, d=[1.0, 1.2])
pc = _chain(chain.params)
rng = np.random.default_rng(3)
Q = np.array([np.concatenate((rng.normal(size=2), rng.uniform(-0.6, 0.6, 3))) for _ in range(4)])
ETA = rng.normal(size=(4, 2))
rows = F.wheel_speeds_rows(pc, Q, ETA)  # an entry point: reduced below it is compiled, not emitted
sig = [s for s in F.reduced.signatures if str(s[0]).startswith("Chain")][0]
cres = F.reduced.overloads[sig]
deferred = isinstance(cres.entry_point, compiling.LazyEntry) and cres.entry_point.cfunc is None
cheap = bool(cres.library._ftc_cheap)
Bbar = F.reduced(pc, Q[1], ETA[1])[3]  # from Python: optimized fully, then emitted
print(json.dumps({
    "deferred": deferred, "cheap": cheap, "cheap_after": bool(cres.library._ftc_cheap),
    "rows": rows[1].tolist(), "direct": (Bbar[0] * ETA[1, 0] + Bbar[1] * ETA[1, 1]).tolist(),
    "model": chain.wheel_speeds(Q[1], ETA[1]).tolist(),
}))
"""


def test_a_kernel_called_from_python_is_an_entry_point_and_its_callees_are_deferred(tmp_path):
    # the outermost ftcreport compile of a thread is an entry point (the references' checks, the metrics'
    # kernels, the loop): what is compiled below it gets the cheap passes and no machine code until asked;
    # asked from Python, it is optimized fully first and computes the same numbers
    out = _last_json(_python(_ENTRY_PROBE, tmp_path))
    assert out["deferred"] and out["cheap"] and not out["cheap_after"]
    # bit for bit: the same IEEE operations (no fast-math) in the inlined and the emitted callee; 1e-12 to
    # the Python model (its own order of operations, as in tests/test_fast.py)
    assert out["rows"] == out["direct"]
    np.testing.assert_allclose(out["rows"], out["model"], rtol=1e-12, atol=1e-12)


_OFF_PROBE = """
import json
import numpy as np
from numba.core.codegen import JITCodeLibrary
from ftcreport.jit import compiling
import kmod

x = np.linspace(-1.0, 1.0, 5)
values = [kmod.root(x), kmod.middle(x), kmod.leaf(x)]
libs = {f.__name__: type(f.overloads[f.signatures[0]].library) is JITCodeLibrary for f in (kmod.leaf, kmod.root)}
entries = {f.__name__: type(f.overloads[f.signatures[0]].entry_point).__name__ for f in (kmod.leaf, kmod.root)}
print(json.dumps({"accelerated": compiling.accelerated(), "values": values, "numba_libraries": libs,
                  "entries": entries, "pipeline": kmod.leaf._compiler.pipeline_class.__name__}))
"""


def test_fast_compile_off_is_numbas_own_pipeline_with_the_same_numbers(tmp_path):
    (tmp_path / "kmod.py").write_text(_KERNELS)
    on = _last_json(_python(_OFF_PROBE, tmp_path))
    off = _last_json(_python(_OFF_PROBE, tmp_path, FTCREPORT_FAST_COMPILE="0"))
    assert on["accelerated"] and not off["accelerated"]
    assert off["numba_libraries"] == {"leaf": True, "root": True}  # numba's code library, numba's compiler
    assert on["numba_libraries"] == {"leaf": False, "root": False}
    assert off["entries"] == {"leaf": "builtin_function_or_method", "root": "builtin_function_or_method"}
    assert on["values"] == off["values"]  # bit-identical
    # the two modes keep separate cache entries (a deferred kernel is stored as bitcode)
    cache = tmp_path / "cache"
    assert {p.name for p in cache.glob("*/numba/*")} == {"fast", "numba"}


_FAIL_PROBE = """
import json, warnings
import numpy as np
from ftcreport.jit import compiling
import kmod


def broken(library):  # what numba 0.61 did to the hook of round 2: a pass manager's API changed under it
    raise TypeError("cannot unpack non-iterable ModulePassManager")


compiling._cheap_passes = broken
x = np.linspace(-1.0, 1.0, 5)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    values = [kmod.root(x), kmod.other_root(x), kmod.middle(x)]
lib = kmod.leaf.overloads[kmod.leaf.signatures[0]].library
print(json.dumps({
    "values": values, "accelerated": compiling.accelerated(),
    "warnings": [str(w.message) for w in caught if issubclass(w.category, compiling.AccelerationWarning)],
    "leaf_cheap": bool(lib._ftc_cheap), "leaf_deferred": bool(lib._ftc_deferred),
}))
"""


def test_a_failure_inside_the_acceleration_falls_back_to_numba_with_one_warning(tmp_path):
    (tmp_path / "kmod.py").write_text(_KERNELS)
    out = _last_json(_python(_FAIL_PROBE, tmp_path))
    x = np.linspace(-1.0, 1.0, 5)
    leaf = float(np.sum(x * x + 0.5))
    middle = 2.0 * leaf + float(np.sum(x[:2] * x[:2] + 0.5))
    assert out["values"] == [middle + 1.0, middle - leaf, middle]
    assert not out["accelerated"] and not out["leaf_cheap"] and not out["leaf_deferred"]
    assert len(out["warnings"]) == 1
    assert "cannot unpack non-iterable ModulePassManager" in out["warnings"][0]
    assert "numba's own pipeline" in out["warnings"][0]


def test_only_tested_numba_releases_are_accelerated(monkeypatch):
    monkeypatch.delenv("FTCREPORT_FAST_COMPILE", raising=False)
    assert compiling._numba_release() in compiling.TESTED  # the numba this suite runs on (CI: both ends)
    assert compiling.accelerated()
    monkeypatch.setattr(compiling, "TESTED", frozenset({(0, 1)}))
    assert not compiling.accelerated()
    monkeypatch.setattr(compiling, "TESTED", frozenset({compiling._numba_release()}))
    monkeypatch.setenv("FTCREPORT_FAST_COMPILE", "0")
    assert not compiling.accelerated()


def test_numba_llvm_lock_event_is_off_while_an_entry_point_compiles_and_back_after():
    import llvmlite.binding as llb

    lock = llb.ffi.lib._lock
    numba_owned = lambda cbs: [cb for cb in cbs if cb[0].__module__ == "numba.core.base"]  # noqa: E731
    before = lock._cblist
    assert numba_owned(before)  # numba's timer feed is registered (llvmlite's internals as read)
    with compiling._quiet_llvm_lock():
        assert not numba_owned(lock._cblist)
    assert lock._cblist is before


# --------------------------------------------------------------------------- the cache (38.3)
def test_every_kernel_cache_is_outside_the_package_and_keyed_on_all_compiled_sources():
    # a kernel cached from one file (control/passive_law.py) links kernels of another (fast/kernels.py): its
    # cache entry must go stale when any compiled source changes, not only its own file
    import hashlib

    from ftcreport import paths
    from ftcreport.control import passive_law as passive

    root = Path(F.__file__).parent
    h = hashlib.sha256()
    # the engine, the scheme interface, the built-in laws, and the domains whose compiled kernels live beside
    # their faces (model, control, observers, references)
    for sub in ("jit", "fast", "schemes", "model", "control", "observers", "references"):
        for path in sorted((root.parent / sub).glob("*.py")):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    assert compiling.engine_stamp() == h.hexdigest()
    for kernel in (F._solve2, passive.passive_law):
        locator = kernel._cache._impl._locator
        assert isinstance(locator, compiling.KernelLocator)
        stamp = locator.get_source_stamp()
        st = os.stat(kernel.py_func.__code__.co_filename)
        assert stamp == (st.st_mtime, st.st_size, h.hexdigest())
        assert Path(locator.get_cache_path()).is_relative_to(paths.cache_dir("numba"))
        assert not Path(locator.get_cache_path()).is_relative_to(root.parent)  # never inside the package
        assert locator._py_file == kernel.py_func.__code__.co_filename  # numba's warnings read it

    @njit(cache=True)
    def elsewhere(x):  # not ftcreport's: numba's own locator, untouched
        return x

    assert not isinstance(elsewhere._cache._impl._locator, compiling.KernelLocator)


def test_every_file_that_defines_kernels_is_in_the_engine_stamp():
    """A compiled kernel's source must be in :func:`engine_stamp` (its callers' entries embed its code): every
    file of the package with a function decorated ``@jit`` or ``@jit(...)`` lies in a stamped directory."""
    import ast

    root = Path(F.__file__).resolve().parents[1]
    stamped = {(root / sub).resolve() for sub in compiling._ENGINE_FILES}
    with_kernels = []
    for path in root.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and any(
                (d.func if isinstance(d, ast.Call) else d).__dict__.get("id") == "jit" for d in node.decorator_list
            ):
                with_kernels.append(path)
                break
    assert len(with_kernels) >= 15  # the domains' compiled modules, the engine's, the built-in laws
    assert [p for p in with_kernels if p.parent.resolve() not in stamped] == []


def test_cache_dir_is_keyed_by_versions_and_cpu_and_overridable(tmp_path, monkeypatch):
    import llvmlite
    import numba

    from ftcreport import __version__, paths

    monkeypatch.setenv("FTCREPORT_CACHE", str(tmp_path))
    key = paths.compiled_key()
    assert paths.cache_dir("loops") == tmp_path / key / "loops"
    assert paths.cache_dir("numba") == tmp_path / key / "numba"
    assert paths.cache_dir("runs") == tmp_path / "runs"  # no compiled code: not keyed
    for part in (f"ftcreport-{__version__}", f"numba-{numba.__version__}", f"llvmlite-{llvmlite.__version__}"):
        assert part in key
    import llvmlite.binding as ll

    assert (numba.config.CPU_NAME or ll.get_host_cpu_name()) in key
    with pytest.raises(ValueError, match="cache kind"):
        paths.cache_dir("../x")
    monkeypatch.delenv("FTCREPORT_CACHE")
    import platformdirs

    assert paths.cache_root() == Path(platformdirs.user_cache_dir("ftcreport", appauthor=False))


def test_generated_loops_live_in_the_cache_dir(tmp_path, monkeypatch):
    from ftcreport import paths
    from ftcreport.control.passive_law import passive_discrete, passive_law
    from ftcreport.fast import engine

    loop = loop_for(passive_law, passive_discrete, motors=False, sampled=False)
    assert Path(loop.__file__).parent == paths.cache_dir("loops")
    assert not Path(loop.__file__).is_relative_to(Path(F.__file__).parents[1])
    monkeypatch.setenv("FTCREPORT_CACHE", str(tmp_path))
    assert engine._cache_dir() == tmp_path / paths.compiled_key() / "loops"


def test_the_slice_size_message_of_a_kernel_is_numbas_own(tmp_path):
    # round 2 swapped numba's slice-size message for a plain one process-wide; it is numba's again
    kernels = textwrap.dedent(
        """
        from numba import njit
        from ftcreport.jit.compiling import jit

        def assign(a, b):
            a[:] = b

        ours, theirs = jit(cache=False)(assign), njit(assign)  # compiled in this order: ftcreport's first
        """
    )
    (tmp_path / "smod.py").write_text(kernels)
    code = (
        "import numpy as np, smod\nfor f in (smod.ours, smod.theirs):\n    try:\n"
        "        f(np.zeros(2), np.zeros(3))\n    except ValueError as e:\n        print(e)"
    )
    ours, theirs = _python(code, tmp_path).strip().splitlines()
    assert ours == theirs
    assert re.fullmatch(r"cannot assign slice of shape \([23],\) from input of shape \([23],\)", ours)


def test_a_cache_index_written_by_other_code_is_a_miss_not_an_error(monkeypatch, tmp_path):
    """A cache index naming a module that no longer exists (left by another version of ftcreport: seen
    as ``ModuleNotFoundError: No module named 'ftcreport.fast.builtin'`` after the schemes moved), or
    pickle data cut short, makes KernelCache.load_overload return None (compile again) and flush the
    function's index; any other error still propagates."""
    import pickle

    from numba.core import caching

    from ftcreport.jit import compiling

    monkeypatch.setenv("FTCREPORT_CACHE", str(tmp_path))
    flushed = []
    cache = compiling.KernelCache(_read.py_func)
    monkeypatch.setattr(compiling.KernelCache, "flush", lambda self: flushed.append(1))
    for exc in (ModuleNotFoundError("No module named 'ftcreport.fast.builtin'"), pickle.UnpicklingError("x"),
                EOFError(), AttributeError("gone")):  # fmt: skip

        def raising(self, sig, ctx, exc=exc):
            raise exc

        monkeypatch.setattr(caching.FunctionCache, "load_overload", raising)
        assert cache.load_overload(None, None) is None
    assert len(flushed) == 4

    def bug(self, sig, ctx):
        raise ZeroDivisionError("a bug is not a stale entry")

    monkeypatch.setattr(caching.FunctionCache, "load_overload", bug)
    with pytest.raises(ZeroDivisionError):
        cache.load_overload(None, None)


def test_a_cache_entry_of_another_signature_is_a_miss(monkeypatch, tmp_path):
    """An entry whose compiled signature is not the one asked for (what the unlocked race of numba's
    save left behind, test above) is never handed to the dispatcher: None (compile again), index flushed."""
    from types import SimpleNamespace

    from numba import types
    from numba.core import caching

    from ftcreport.jit import compiling

    monkeypatch.setenv("FTCREPORT_CACHE", str(tmp_path))
    flushed = []
    cache = compiling.KernelCache(_read.py_func)
    monkeypatch.setattr(compiling.KernelCache, "flush", lambda self: flushed.append(1))
    entry = SimpleNamespace(signature=SimpleNamespace(args=(types.float64[:],)))
    monkeypatch.setattr(caching.FunctionCache, "load_overload", lambda self, sig, ctx: entry)
    assert cache.load_overload((types.int64[:],), None) is None and flushed == [1]
    assert cache.load_overload((types.float64[:],), None) is entry and flushed == [1]


# --------------------------------------------------------------------------- concurrent cache writers
_TWICE = """
from ftcreport.jit.compiling import jit


@jit
def twice(x):
    return x * 2  # an array out: boxing it reads the dtype from the kernel's environment
"""

_WRITER = """
import json, os, sys, time
import numpy as np
from numba.core import caching
import kmod

dtype, index_delay, data_delay = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
save_index, save_data = caching.IndexDataCacheFile._save_index, caching.IndexDataCacheFile._save_data


def slow_save_index(self, overloads):  # numba's save: index read, a number picked, [here] index, data written
    time.sleep(index_delay)
    return save_index(self, overloads)


def slow_save_data(self, name, data):
    time.sleep(data_delay)
    return save_data(self, name, data)


caching.IndexDataCacheFile._save_index = slow_save_index
caching.IndexDataCacheFile._save_data = slow_save_data
x = np.arange(1, 4).astype(dtype)
while time.time() < float(os.environ["START"]):
    time.sleep(0.001)
t_call = time.time()
y = kmod.twice(x)
print(json.dumps({"t_call": t_call, "y": y.tolist()}))
"""

_READER = """
import json
import numpy as np
import kmod

print(json.dumps({d: [kmod.twice(np.arange(1, 4).astype(d)).tolist(), kmod.twice._cache_hits.total()]
                  for d in ("float64", "int64", "float32")}))
"""


def test_concurrent_writers_of_one_kernel_keep_each_signature_its_own_entry(tmp_path):
    """Three processes compile three signatures of one kernel into an empty cache at once (a batch's
    workers, the suite's).  numba's save reads the index, picks a data file the index does not use, then
    writes the index and the data: without a lock all three pick the same file, the last index names one
    signature and the last data is another's, and a later load of the first gets the second's code (on
    CI: ``In 'NRT_adapt_ndarray_to_python', 'descr' is NULL`` from a kernel returning an array; here
    int64 elements read as float64 ones).  The writes are slowed (seconds, per process: float64 writes
    its index first and its data last) to make that interleaving certain; the processes call within a
    third of a delay of each other (asserted, else the test proves nothing)."""
    import time

    (tmp_path / "kmod.py").write_text(_TWICE)
    w = 2.0
    delays = {"float64": (w, 2 * w), "int64": (2 * w, 0.0), "float32": (1.5 * w, 0.0)}  # index, data
    env = dict(os.environ, FTCREPORT_CACHE=str(tmp_path / "cache"), PYTHONPATH=f"{tmp_path}{os.pathsep}{ROOT}")
    env["START"] = str(time.time() + 8.0)  # after the imports
    procs = [
        subprocess.Popen([sys.executable, "-c", _WRITER, d, str(a), str(b)], env=env, cwd=tmp_path,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for d, (a, b) in delays.items()
    ]  # fmt: skip
    outs = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stderr
        outs.append(_last_json(stdout))
    calls = [o["t_call"] for o in outs]
    assert max(calls) - min(calls) < w / 3, calls  # they overlapped inside the slowed saves
    assert [o["y"] for o in outs] == [[2.0, 4.0, 6.0], [2, 4, 6], [2.0, 4.0, 6.0]]
    loaded = _last_json(_python(_READER, tmp_path))
    assert loaded == {"float64": [[2.0, 4.0, 6.0], 1], "int64": [[2, 4, 6], 2], "float32": [[2.0, 4.0, 6.0], 3]}
    entries = sorted(p.name for p in (tmp_path / "cache").rglob("kmod.twice-*.nbc"))
    assert len(entries) == 3, entries  # one data file per signature


# --------------------------------------------------------------------------- environments across processes
_CALLER = """
from ftcreport.jit.compiling import jit


@jit
def twice(x):
    return x * 2  # an array out: its wrapper reads the dtype from the environment's constants, by index


@jit
def use(x):
    return twice(x)[0] + 1.0  # embeds twice's code: its entry keeps twice's environment
"""

_CALL = """
import json
import numpy as np
from numba.core.environment import Environment
import kmod

x = np.arange(3.0)
if TWICE_FIRST:
    out = kmod.twice(x).tolist()
out = [kmod.use(x), kmod.twice(x).tolist()]
consts = [len(e.consts) for k, e in list(Environment._memo.items()) if "twice" in k]
hits = [kmod.use._cache_hits.total(), kmod.twice._cache_hits.total()]
print(json.dumps({"out": out, "consts": consts, "hits": hits}))
"""


def test_a_kernel_compiled_while_a_loaded_caller_holds_its_environment_loads_everywhere(tmp_path):
    """numba names an environment after the function, its argument types and a per-process compile
    counter (the same in two processes that compile in the same order) and keeps one live environment
    per name.  A process that loads ``use`` (its entry embeds ``twice`` and twice's environment) and
    then compiles ``twice`` (its own entry missing: flushed, or not yet written by a concurrent worker)
    gets the caller's environment and appends the dtype behind the pickled copy: twice's wrapper reads
    constant 1.  A third process that loads ``use`` and then that entry of twice: numba's load keeps the
    caller's one-constant environment, and the call failed with CI's ``In
    'NRT_adapt_ndarray_to_python', 'descr' is NULL``.  Now a loaded entry completes the live environment."""
    (tmp_path / "kmod.py").write_text(_CALLER)
    first = _last_json(_python("TWICE_FIRST = True" + _CALL, tmp_path))  # twice compiled first: counter 1
    assert first == {"out": [1.0, [0.0, 2.0, 4.0]], "consts": [1], "hits": [0, 0]}
    (index,) = (tmp_path / "cache").rglob("kmod.twice-*.nbi")
    index.unlink()  # twice's entry gone, use's kept
    second = _last_json(_python("TWICE_FIRST = False" + _CALL, tmp_path))  # twice compiled first here too
    assert second == {"out": [1.0, [0.0, 2.0, 4.0]], "consts": [2], "hits": [1, 0]}  # compiled onto use's copy
    third = _last_json(_python("TWICE_FIRST = False" + _CALL, tmp_path))
    assert third == {"out": [1.0, [0.0, 2.0, 4.0]], "consts": [2], "hits": [1, 1]}  # both from the cache


def test_an_environment_whose_cached_constants_disagree_is_a_miss():
    """A live environment holding other values where the entry's code reads its own: the entry cannot be
    used without breaking the live code, so it is a miss (EnvConflictError, compiled again), not a repair."""
    from numba.core.environment import Environment

    env = Environment({"__name__": __name__})
    env.env_name = "ftcreport-test-env"
    env.consts[:] = [np.dtype("float64")]
    assert compiling.environment(compiling.EnvRecord(env, [np.dtype("float64"), np.dtype("int64")])) is env
    assert list(env.consts) == [np.dtype("float64"), np.dtype("int64")]  # completed, index 0 unmoved
    with pytest.raises(compiling.EnvConflictError, match="ftcreport-test-env"):
        compiling.environment(compiling.EnvRecord(env, [np.dtype("int32")]))
    assert compiling.environment(env) is env  # an entry numba reduced itself: as it is
