"""How the loops are compiled (issue 20 item 1): refs, the variant constants, the optimization hook.

None of these may change a number: the golden windows (tests/test_golden.py) hold the results at
1e-9; here, the pieces' own contracts.
"""

from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np
from numba import njit

from ftcreport.fast import compiling
from ftcreport.fast import kernels as F
from ftcreport.fast.engine import loop_for
from ftcreport.fast.refs import as_ref


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


def test_ref_reads_the_same_fields_as_the_tuple():
    P = _Outer(np.arange(6.0).reshape(3, 2), _Inner(np.array([1.0, 2.0, 3.0]), 0.5), 4)
    assert _read_ref(P) == _read(P) == 2.0 + 1.5 + 4  # exact: the same loads, no arithmetic changed
    Q = P._replace(n=10)
    assert _pair_ref(P, Q) == (2.0 + 1.5 + 4) + (2.0 + 1.5 + 10)
    assert P.inner.a[0] == 7.0


def test_the_optimization_hook_is_installed_on_the_pinned_numba():
    # if a numba release renames the hooked method, every kernel is optimized fully again (slower
    # to compile, same numbers): this test makes that visible instead of silent
    assert compiling.ACTIVE
    from numba.core import codegen

    assert getattr(codegen.CPUCodeLibrary._optimize_final_module, "_ftcreport", False)


def test_loop_compile_is_per_thread_and_nests():
    seen = {}

    def other():
        seen["other"] = getattr(compiling._STATE, "on", False)

    with compiling.loop_compile():
        with compiling.loop_compile():
            assert compiling._STATE.on
        assert compiling._STATE.on  # the inner block restores, not clears
        t = threading.Thread(target=other)
        t.start()
        t.join()
    assert not compiling._STATE.on
    assert seen["other"] is False  # another thread's compiles are not affected


def test_variants_are_separate_modules_with_their_constants():
    from ftcreport.schemes.laws.passive import passive_discrete, passive_law

    plain = loop_for(passive_law, passive_discrete, motors=False, sampled=False)
    motors = loop_for(passive_law, passive_discrete, motors=True, sampled=False)
    own = loop_for(passive_law, passive_discrete, motors=False, sampled=False, terms=1)
    assert plain is not motors and own is not plain
    assert (plain.MOTORS, plain.SAMPLED, plain.TERMS_MODE) == (False, False, 0)
    assert (motors.MOTORS, motors.SAMPLED) == (True, False)
    assert own.TERMS_MODE == 1
    assert loop_for(passive_law, passive_discrete, motors=False, sampled=False) is plain  # one per process


def test_every_ftcreport_kernel_cache_is_keyed_on_all_compiled_sources():
    # a kernel cached from one file (fast/builtin.py) links kernels of another (fast/kernels.py):
    # its cache entry must go stale when any compiled source changes, not only its own file
    import hashlib
    from pathlib import Path

    from ftcreport.schemes.laws import passive

    root = Path(F.__file__).parents[1]
    h = hashlib.sha256()
    for sub in ("fast", "schemes", "schemes/laws"):  # the engine, the scheme interface, the built-in laws
        for path in sorted((root / sub).glob("*.py")):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    assert compiling.engine_stamp() == h.hexdigest()
    for kernel in (F._solve2, passive.passive_law):
        stamp = kernel._cache._impl._locator.get_source_stamp()
        assert stamp[1] == h.hexdigest()
        assert stamp[0] == hashlib.sha256(Path(kernel.py_func.__code__.co_filename).read_bytes()).digest()
        # numba's warning that a kernel cannot be cached reads its locator's _py_file
        assert kernel._cache._impl._locator._py_file == kernel.py_func.__code__.co_filename

    @njit(cache=True)
    def elsewhere(x):  # not ftcreport's (this test module): numba's own locator, untouched
        return x

    assert not getattr(type(elsewhere._cache._impl._locator), "_ftcreport", False)


def test_the_deferred_emission_is_installed_on_the_pinned_numba():
    # if numba renames what the deferral wraps, every kernel's machine code is emitted at once again
    # (numba's default: slower to compile, same numbers): this test makes that visible
    assert compiling.DEFERRED
    from numba.core import codegen, cpu, dispatcher

    for fn in (
        codegen.CPUCodeLibrary._finalize_final_module, codegen.CPUCodeLibrary.serialize_using_object_code,
        codegen.JITCodeLibrary.get_pointer_to_function, codegen.JITCPUCodegen.set_env,
        cpu.CPUContext.get_executable, dispatcher.Dispatcher.add_overload, dispatcher.Dispatcher.compile,
    ):  # fmt: skip
        assert getattr(fn, "_ftcreport", False), fn


_DEFERRED_MODULE = """
import numpy as np
from numba import njit


@njit(cache=True)
def leaf(x):
    s = 0.0
    for i in range(x.size):
        s += x[i] * x[i] + 0.5
    if x[0] > 100.0:
        print("big", s)  # numba's Python API: needs the kernel's environment, set once code holds it
    return s


@njit(cache=True)
def middle(x):
    return leaf(x) * 2.0 + leaf(x[:2])


@njit(cache=True)
def run_steps(x):  # a loop's entry point (compiling.ROOTS)
    return middle(x) + 1.0


@njit(cache=True)
def first_law(x):  # another entry point, compiled after: links the deferred kernels again
    return middle(x) - leaf(x)
"""

_DEFERRED_PROBE = """
import json
import numpy as np
from ftcreport.fast import compiling
import defmod

x = np.linspace(-1.0, 1.0, 5)
out = {}
with compiling.loop_compile():
    out["root"] = defmod.run_steps(x)
    out["big"] = defmod.run_steps(x + 200.0)
sigs = defmod.leaf.signatures
entry = defmod.leaf.overloads[sigs[0]].entry_point if sigs else None
out["leaf_deferred"] = isinstance(entry, compiling.LazyEntry) and entry.cfunc is None
out["middle"] = defmod.middle(x)  # from Python: its code is emitted on this first call
out["middle_again"] = defmod.middle(x)  # numba's own table of wrappers now
out["leaf"] = defmod.leaf(x)
lib = defmod.middle.overloads[defmod.middle.signatures[0]].library
out["middle_full"] = getattr(lib, "_ftc_cheap", None) is False  # optimized fully before its code was emitted
with compiling.loop_compile():
    out["second_root"] = defmod.first_law(x)
out["hits"] = [sum(f.stats.cache_hits.values()) for f in (defmod.leaf, defmod.middle, defmod.run_steps)]
print(json.dumps(out))
"""


def test_kernels_below_a_loop_emit_code_only_when_asked_and_cache_in_a_fresh_process(tmp_path):
    import json
    import os
    import subprocess
    import sys

    (tmp_path / "defmod.py").write_text(_DEFERRED_MODULE)
    (tmp_path / "probe.py").write_text(_DEFERRED_PROBE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(tmp_path))
    runs = []
    for _ in range(2):  # compiles and saves, then loads from the cache in a fresh process
        res = subprocess.run([sys.executable, "probe.py"], cwd=tmp_path, env=env, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        lines = res.stdout.splitlines()
        assert lines[:2] == ["big 200005.0", "big 79402.25"]  # the deferred kernel's environment was set
        runs.append(json.loads(lines[-1]))
    x = np.linspace(-1.0, 1.0, 5)
    leaf = float(np.sum(x * x + 0.5))  # 5.0: sums of squares of multiples of 0.5, exact in binary
    middle = 2.0 * leaf + float(np.sum(x[:2] * x[:2] + 0.5))
    for out in runs:
        assert out["root"] == middle + 1.0
        assert (out["middle"], out["middle_again"], out["leaf"]) == (middle, middle, leaf)
        assert out["second_root"] == middle - leaf
        assert out["middle_full"]  # compiled (first run) or loaded as bitcode (second): numba's full pipeline
    assert runs[0]["leaf_deferred"] and runs[0]["hits"] == [0, 0, 0]
    assert runs[1]["hits"] == [1, 1, 1]  # each from the cache: leaf and middle as bitcode, run_steps as code


_ENTRY_PROBE = """
import json
import numpy as np
from ftcreport.fast import compiling
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
cheap = bool(getattr(cres.library, "_ftc_cheap", False))
Bbar = F.reduced(pc, Q[1], ETA[1])[3]  # from Python: optimized fully, then emitted
print(json.dumps({
    "deferred": deferred, "cheap": cheap, "cheap_after": bool(getattr(cres.library, "_ftc_cheap", False)),
    "rows": rows[1].tolist(), "direct": (Bbar[0] * ETA[1, 0] + Bbar[1] * ETA[1, 1]).tolist(),
    "model": chain.wheel_speeds(Q[1], ETA[1]).tolist(),
}))
"""


def test_a_kernel_called_from_python_is_an_entry_point_and_its_callees_are_deferred(tmp_path):
    # the rule of loop_compile holds for every ftcreport kernel called from Python (the reference checks,
    # the metrics' kernels): what is compiled below it gets the cheap passes and no machine code until
    # asked; asked from Python, it is optimized fully first and computes the same numbers
    import json
    import os
    import subprocess
    import sys

    (tmp_path / "probe.py").write_text(_ENTRY_PROBE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "probe.py"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.splitlines()[-1])
    assert out["deferred"] and out["cheap"] and not out["cheap_after"]
    # bit for bit: the same IEEE operations (no fast-math) in the inlined and the emitted callee (and numpy's
    # elementwise products and sum, the kernel's order); 1e-12 to
    # the Python model (its own order of operations, as in tests/test_fast.py)
    assert out["rows"] == out["direct"]
    np.testing.assert_allclose(out["rows"], out["model"], rtol=1e-12, atol=1e-12)


def test_numba_llvm_lock_event_is_off_while_a_kernel_compiles_and_back_after():
    import llvmlite.binding as llb

    lock = llb.ffi.lib._lock
    numba_owned = lambda cbs: [cb for cb in cbs if cb[0].__module__ == "numba.core.base"]  # noqa: E731
    assert numba_owned(lock._cblist)  # numba's timer feed is registered (llvmlite's internals as read)
    with compiling._quiet_llvm_lock():
        assert not numba_owned(lock._cblist)
    assert numba_owned(lock._cblist)


def test_deferred_emission_can_be_switched_off_for_memory():
    """FTCREPORT_DEFER_EMISSION=0: numba's own emission (measured: the 400 s Table 4.2 run's warm peak
    193 MB instead of 203 MB, a cold first result 55 s instead of 36-47 s; docs/ENGINE.md)."""
    import os
    import subprocess
    import sys

    code = "from ftcreport.fast import compiling; print(compiling.DEFERRED)"
    for value, want in (("0", "False"), ("1", "True")):
        env = dict(os.environ, FTCREPORT_DEFER_EMISSION=value)
        res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert res.stdout.split()[-1] == want
