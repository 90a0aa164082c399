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

numba also emits the machine code of every such module at once (its ``finalize``), because it
makes each kernel callable from Python as soon as it is compiled: the code of a leaf was emitted
once per level above it.  While a loop compiles, the kernels below its entry points skip that
(:class:`LazyEntry`, :data:`DEFERRED`): their module is optimized and kept, linked into the callers
as before, and emitted only if something asks for it (a call from Python, a function pointer); the
cache keeps such a kernel as its optimized bitcode (numba's ``serialize_using_bitcode``) instead
of object code.  The loop's own module is emitted as always, so the code that runs is the same.
Measured on the switching loop: machine-code emission 14 -> 6 s of CPU.

The same rule holds for every ftcreport kernel that Python calls (the references' checks, the
metrics' kernels): its own top-level compile makes it an entry point, and the kernels compiled
below it get the cheap passes and no machine code until asked.  A kernel asked for from Python
after all (its module had the cheap passes only) gets numba's full optimization before its code is
emitted, in this process or when loaded from the cache (a library loaded from bitcode: only the
deferral stores one), so a kernel called from Python always runs fully optimized code.

numba's cache of a kernel is keyed on its own file's content only, so a kernel cached from one
file (fast/builtin.py's dispatchers, a plug-in's law, a loop module) kept the old code of a kernel
it calls in another file (fast/kernels.py) after that file changed: a `git pull` that changed
kernels.py alone ran stale code.  :func:`install_cache_stamp` adds numba's documented extension
point, a cache locator, for every module of ftcreport (and its generated loops and plug-ins): the
stamp of their cache entries is their own file's and :func:`engine_stamp`, a hash of every compiled
source of the package, so any change renews every entry that could have linked it.

The hook wraps one method of numba's code library (``CPUCodeLibrary._optimize_final_module``,
numba 0.58-0.68).  If a numba release renames it, :data:`ACTIVE` is False and every kernel is
optimized fully, as numba does by default: slower to compile, same results.  The deferred emission
and the entry points of Python's calls wrap seven methods of numba 0.68 (the code library's
finalization, serialization and function pointer, the codegen's ``set_env``, the context's
``get_executable``, the dispatcher's ``add_overload`` and ``compile``); if one is missing,
:data:`DEFERRED` is False and numba emits every module at once, as by default
(tests/test_compiling.py fails on the pinned numba then).  While a kernel compiles, numba's
``numba:llvm_lock`` event is off (:func:`_quiet_llvm_lock`: 3-4 s of CPU per cold loop).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

__all__ = [
    "ACTIVE",
    "DEFERRED",
    "ROOTS",
    "LazyEntry",
    "engine_stamp",
    "install_cache_stamp",
    "loop_compile",
    "short_shape_message",
]

ROOTS = frozenset({"run_steps", "first_law", "first_discrete"})  # fast/loop.py's entry points

_STATE = threading.local()  # numba compiles in the calling thread, under its global compiler lock
_NUMBA: dict = {}  # numba's own methods that the hooks wrap


def _below(library) -> bool:
    """Whether a library is compiled below an entry point: a loop's (:data:`ROOTS`, within
    :func:`loop_compile`) or a kernel's that Python calls (its own top-level compile)."""
    if not getattr(_STATE, "on", False):
        return False
    return library.name not in ROOTS and library.name not in getattr(_STATE, "roots", ())


def _install() -> bool:
    try:
        from numba.core import codegen
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    lib = getattr(codegen, "CPUCodeLibrary", None)
    full = getattr(lib, "_optimize_final_module", None)
    if full is None or getattr(full, "_ftcreport", False):
        return full is not None

    _NUMBA["_optimize_final_module"] = full

    def optimize_final_module(self) -> None:
        if not _below(self):
            return optimized_fully(self)
        # numba's own first stage (inlining for reference-count pruning), without the full O3 run
        mpm, pb = self._codegen._module_pass_manager(
            loop_vectorize=False, slp_vectorize=False, opt=0, cost="cheap"
        )  # fmt: skip
        mpm.run(self._final_module, pb)
        self._ftc_cheap = True  # emitting its own code (a call from Python) optimizes it fully first

    def optimized_fully(self) -> None:
        self._ftc_cheap = False
        full(self)

    optimize_final_module._ftcreport = True
    lib._optimize_final_module = optimize_final_module
    return True


ACTIVE = _install()


class LazyEntry:
    """A kernel's Python entry point whose machine code is emitted on its first call.

    numba gives every compiled function a Python-callable wrapper at once, and so emits the machine
    code of its whole module (the function and every kernel linked below it).  A kernel compiled
    below a loop's entry point runs only inside the loop's own module, so its module is emitted
    only if something asks for it: a call from Python (numba's dispatcher calls a non-builtin
    entry point as a Python callable, and this one then puts the real wrapper in the dispatcher's
    table), a pointer (``get_pointer_to_function``).  It is also numba's key for the function when
    other kernels call it (``BaseContext._defns``), so it stays the entry point of record.
    """

    __slots__ = ("_context", "_env", "_fndesc", "_library", "_targets", "cfunc")

    def __init__(self, context, library, fndesc, env) -> None:
        self._context, self._library, self._fndesc, self._env = context, library, fndesc, env
        self.cfunc = None  # numba's wrapper, once emitted
        self._targets: list = []  # (dispatcher, compile result) to insert the wrapper into

    def realize(self):
        """numba's wrapper of the kernel (its module's machine code emitted on the first call)."""
        if self.cfunc is None:
            from numba.core.compiler_lock import global_compiler_lock

            with global_compiler_lock:
                if self.cfunc is None:
                    _realize(self._library)
                    self.cfunc = _NUMBA["get_executable"](self._context, self._library, self._fndesc, self._env)
                    for disp, cres in self._targets:
                        _NUMBA["add_overload"](disp, cres._replace(entry_point=self.cfunc))
                        disp.overloads[tuple(cres.signature.args)] = cres  # the entry point of record
                    self._targets.clear()
        return self.cfunc

    def __call__(self, *args, **kws):
        return self.realize()(*args, **kws)

    def __repr__(self) -> str:
        state = "emitted" if self.cfunc is not None else "deferred"
        return f"<LazyEntry {self._fndesc.qualname} ({state})>"


def _deferring(library) -> bool:
    """Whether a library just optimized (or loaded as bitcode) emits its machine code later."""
    return (
        _below(library)
        and getattr(library, "_ftc_jit", False)
        and getattr(library, "_compiled_object", None) is None  # not loaded as object code
    )


def _emit(library) -> None:
    """numba's finalization: the module added to the JIT engine and its machine code emitted.

    A module that had the cheap passes only (below an entry point, now called from Python or
    loaded from the cache so) gets numba's full optimization first: its code is then what numba
    would have emitted by default."""
    loaded = not hasattr(library, "_ftc_cheap") and not library._object_caching_enabled  # from bitcode
    if getattr(library, "_ftc_cheap", False) or loaded:
        library._ftc_cheap = False
        full = _NUMBA.get("_optimize_final_module")
        if full is not None:
            full(library)
    _NUMBA["_finalize_final_module"](library)
    _flush_envs(library._codegen)


def _realize(library) -> None:
    """Emit a deferred library's machine code (numba's own finalization, which it skipped)."""
    if getattr(library, "_ftc_deferred", False):
        library._ftc_deferred = False
        library._dynamic_globals = []  # numba's finalization lists them again
        _emit(library)


def _flush_envs(cg) -> None:
    """Point the environment globals of deferred kernels at their environments, once emitted code has them."""
    pending = getattr(cg, "_ftc_pending_envs", None)
    if pending:
        for name in [n for n in pending if cg._engine.is_symbol_defined(n)]:
            _NUMBA["set_env"](cg, name, pending.pop(name))


@contextlib.contextmanager
def _quiet_llvm_lock() -> Iterator[None]:
    """Without numba's ``numba:llvm_lock`` event around each call into LLVM, while a kernel compiles.

    numba broadcasts the event to a timer of every compile in progress (one per level of nesting) at
    each of the 100,000s of calls a loop's compile makes into LLVM: measured 1.3 s per 200,000
    calls at five levels, 0.12 s without.  It only feeds the LLVM-time entry of numba's compile
    metadata (``dispatcher.get_metadata(sig)["timers"]``), which is then 0 for ftcreport's kernels
    (``FTCREPORT_LLVM_EVENTS=1`` keeps the event, for profiling with numba's event recorder).
    """
    import os

    lock = getattr(getattr(getattr(_llvm(), "ffi", None), "lib", None), "_lock", None)
    callbacks = getattr(lock, "_cblist", None)
    if os.environ.get("FTCREPORT_LLVM_EVENTS") == "1" or not isinstance(callbacks, list):
        yield
        return
    lock._cblist = [cb for cb in callbacks if getattr(cb[0], "__module__", "") != "numba.core.base"]
    try:
        yield
    finally:
        lock._cblist = callbacks


def _llvm():
    import llvmlite.binding

    return llvmlite.binding


def _install_deferred() -> bool:
    try:
        from numba.core import codegen, cpu, dispatcher
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    lib = getattr(codegen, "CPUCodeLibrary", None)
    jit_lib = getattr(codegen, "JITCodeLibrary", None)
    jit_cg = getattr(codegen, "JITCPUCodegen", None)
    ctx = getattr(cpu, "CPUContext", None)
    disp = getattr(dispatcher, "Dispatcher", None)
    needed = (
        (lib, "_finalize_final_module"), (lib, "_finalize_dynamic_globals"), (lib, "_verify_declare_only_symbols"),
        (lib, "serialize_using_object_code"), (lib, "serialize_using_bitcode"), (lib, "_ensure_finalized"),
        (jit_lib, "get_pointer_to_function"), (jit_cg, "set_env"), (ctx, "get_executable"),
        (ctx, "get_env_name"), (disp, "add_overload"), (disp, "_insert"), (disp, "compile"),
    )  # fmt: skip
    if any(getattr(owner, name, None) is None for owner, name in needed):
        return False
    if getattr(lib._finalize_final_module, "_ftcreport", False):
        return True
    if not all(hasattr(codegen.JitEngine, a) for a in ("is_symbol_defined",)):
        return False
    _NUMBA.update(
        _finalize_final_module=lib._finalize_final_module, get_pointer_to_function=jit_lib.get_pointer_to_function,
        serialize_using_object_code=lib.serialize_using_object_code, set_env=jit_cg.set_env,
        get_executable=ctx.get_executable, add_overload=disp.add_overload, compile=disp.compile,
    )  # fmt: skip

    def compile(self, sig):
        # a kernel of ftcreport compiled from Python is an entry point: the kernels below it are not
        if getattr(_STATE, "entry", False) or not str(getattr(self.py_func, "__module__", "")).startswith("ftcreport"):
            return _NUMBA["compile"](self, sig)
        before = getattr(_STATE, "on", False), getattr(_STATE, "roots", ())
        _STATE.entry, _STATE.on, _STATE.roots = True, True, (self.py_func.__qualname__,)
        short_shape_message()
        from numba.core.compiler_lock import global_compiler_lock

        try:
            with global_compiler_lock, _quiet_llvm_lock():  # the lock first: one thread swaps llvmlite's list
                return _NUMBA["compile"](self, sig)
        finally:
            _STATE.entry = False
            _STATE.on, _STATE.roots = before

    def _finalize_final_module(self) -> None:
        if not _deferring(self):
            _emit(self)
            return
        # what numba's finalization checks and records, without adding the module to the JIT engine
        self._finalize_dynamic_globals()
        self._verify_declare_only_symbols()
        self._ftc_deferred = True
        self._finalized = True

    def get_pointer_to_function(self, name):
        self._ensure_finalized()
        _realize(self)
        return _NUMBA["get_pointer_to_function"](self, name)

    def serialize_using_object_code(self):
        self._ensure_finalized()
        if getattr(self, "_ftc_deferred", False):  # no object code: the cache keeps the bitcode
            return self.serialize_using_bitcode()
        return _NUMBA["serialize_using_object_code"](self)

    def set_env(self, env_name, env) -> None:
        if not self._engine.is_symbol_defined(env_name):  # only deferred code holds it so far
            if not hasattr(self, "_ftc_pending_envs"):
                self._ftc_pending_envs = {}
            self._ftc_pending_envs[env_name] = env
            return
        _NUMBA["set_env"](self, env_name, env)

    def get_executable(self, library, fndesc, env):
        library._ensure_finalized()
        if getattr(library, "_ftc_deferred", False):
            library.codegen.set_env(self.get_env_name(fndesc), env)  # pending until code holds it
            return LazyEntry(self, library, fndesc, env)
        cfunc = _NUMBA["get_executable"](self, library, fndesc, env)
        _flush_envs(library.codegen)
        return cfunc

    def add_overload(self, cres) -> None:
        entry = cres.entry_point
        if not isinstance(entry, LazyEntry):
            return _NUMBA["add_overload"](self, cres)
        if entry.cfunc is not None:
            _NUMBA["add_overload"](self, cres._replace(entry_point=entry.cfunc))
        else:  # numba's table of wrappers takes compiled functions only: the first call goes through compile()
            entry._targets.append((self, cres))
        self.overloads[tuple(cres.signature.args)] = cres
        return None

    jit_lib._ftc_jit = True
    for fn in (_finalize_final_module, get_pointer_to_function, serialize_using_object_code, set_env,
               get_executable, add_overload, compile):  # fmt: skip
        fn._ftcreport = True
    lib._finalize_final_module = _finalize_final_module
    jit_lib.get_pointer_to_function = get_pointer_to_function
    lib.serialize_using_object_code = serialize_using_object_code
    jit_cg.set_env = set_env
    ctx.get_executable = get_executable
    disp.add_overload = add_overload
    disp.compile = compile
    return True


#: ``FTCREPORT_DEFER_EMISSION=0``: numba emits every kernel's code as it compiles (see docs/ENGINE.md)
DEFERRED = os.environ.get("FTCREPORT_DEFER_EMISSION", "1") != "0" and _install_deferred()


def _install_short_shape_message() -> bool:
    """numba's plain message for a slice assigned from an array of another size, in ftcreport's kernels.

    numba's CPU target builds the message of that error with the two shapes, formatted in compiled
    code: every slice assignment of a new dimension compiles numba's ``str(int)``, string
    concatenation and ``str.join`` for it, 2.3 s of CPU of a cold first result (measured: the switching
    loop and the references' checks, two runs each).  While an ftcreport kernel compiles (this
    thread's :func:`loop_compile` or an entry point's compile), numba's own generic overload is used
    instead: the same ``ValueError`` ("cannot assign slice from input of different size"), without
    the shapes.  It is raised only by a kernel's bug (no input reaches it); nothing else changes.
    numba keeps one implementation per signature and process, so a kernel of another package that
    compiles the same signature later in the same process gets the plain message too.
    ``FTCREPORT_SHAPE_MESSAGES=1`` keeps numba's message (then :func:`short_shape_message` is False).
    """
    if os.environ.get("FTCREPORT_SHAPE_MESSAGES") == "1":
        return False
    try:
        from numba.core.typing import templates
        from numba.np import arrayobj
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    stub = getattr(arrayobj, "raise_with_shape_context", None)
    cpu = getattr(arrayobj, "ol_raise_with_shape_context_cpu", None)
    generic = getattr(arrayobj, "ol_raise_with_shape_context_generic", None)
    registry = getattr(getattr(templates, "builtin_registry", None), "globals", None)
    if stub is None or cpu is None or generic is None or registry is None:
        return False

    def overload_func(src_shapes, index_shape):
        if getattr(_STATE, "on", False):
            return generic(src_shapes, index_shape)
        return cpu(src_shapes, index_shape)

    overload_func._ftcreport = True
    found = False
    for func, fnty in list(registry):
        for tpl in getattr(fnty, "templates", ()) if func is stub else ():
            current = getattr(tpl.__dict__.get("_overload_func"), "__func__", None)
            if current is cpu:
                tpl._overload_func = staticmethod(overload_func)
            found = found or current is cpu or getattr(current, "_ftcreport", False)
    return found


_SHORT: list = []  # [whether the plain message is installed], once tried


def short_shape_message() -> bool:
    """Whether ftcreport's kernels compile numba's plain slice-size message (``FTCREPORT_SHAPE_MESSAGES=1``:
    numba's own); installed by the first compile of an ftcreport kernel (numba's array module, which it
    changes, is imported by numba's first compile anyway, not by importing ftcreport)."""
    if not _SHORT:
        _SHORT.append(_install_short_shape_message())
    return _SHORT[0]


@contextlib.contextmanager
def loop_compile() -> Iterator[None]:
    """Within: the kernels compiled in this thread below a loop's entry points skip numba's full
    optimization of their own closure (the loop's entry point optimizes all of them, linked)."""
    before = getattr(_STATE, "on", False)
    _STATE.on = True
    short_shape_message()
    try:
        yield
    finally:
        _STATE.on = before


_ENGINE_FILES = ("fast", "schemes", "schemes/laws")  # the compiled sources: the engine, the scheme interface, laws


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

        def __getattr__(self, name):  # what numba reads of its own locators (_py_file for its warnings)
            if name == "_inner":
                raise AttributeError(name)
            return getattr(self._inner, name)

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
