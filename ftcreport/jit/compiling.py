r"""How ftcreport's kernels are compiled: numba's pipeline through subclasses of ftcreport's own, numba left as found.

Every kernel of ftcreport (``fast/*.py``, the generated loops, a plug-in's law through
``schemes.jit``) is made by :func:`jit`: numba's CPU dispatcher, compiler and code library, each
through a subclass of ftcreport's own (:class:`KernelDispatcher`, :class:`KernelCompiler`,
:class:`KernelLibrary`, :class:`KernelCache`), the way numba's ``jit`` makes its own
(``pipeline_class`` is numba's documented way to customize the compiler; the dispatcher is built as
``numba.jit`` builds it).  Nothing of numba or llvmlite is replaced: another package's function,
compiled in the same process before or after ftcreport's, goes through numba's own classes and
methods (tests/test_compiling.py compares them with a snapshot taken before ``import ftcreport``).

What the subclasses change, and why (docs/ENGINE.md, "Compile time"; measured on the cold first
result of two_link_switching, CPU seconds to simulating: 26 s with all of it, 55 s with numba's own
pipeline):

1. **Each kernel's code optimized once, in its entry point.**  numba compiles a kernel that another
   kernel calls as a library of its own, links every kernel below it into that library, runs LLVM's
   full O3 pipeline over it and emits its machine code, so with the loop nine calls deep a leaf's code
   was optimized and emitted nine times.  Only the entry point's module runs (the loop's
   ``run_steps``, or a kernel Python calls: the outermost ftcreport compile of a thread), and it
   contains every kernel below it, linked in; so a kernel compiled *below* an entry point gets
   numba's cheap module passes only (:meth:`KernelLibrary._optimize_final_module`) and the entry
   point gets numba's full pipeline over all of them.  No fast-math flags anywhere: LLVM keeps IEEE
   semantics, the numbers are the same (the golden windows hold at 1e-9; ``.ci/run`` checks that a
   run is bit-identical with ``FTCREPORT_FAST_COMPILE=0``).
2. **Deferred emission.**  A kernel compiled below an entry point keeps its optimized module
   unemitted; its Python entry point is a :class:`LazyEntry` that emits it (numba's full
   optimization first) on a first call from Python, and a function pointer asked of it or a link
   into a library compiled outside ftcreport's compiles emits it first too, so outside code only
   ever sees numba's own state.  Its cache entry is numba's bitcode serialization.
3. **Lazy linking IR on cache loads** (memory: about 32 MB for a run's loop): a kernel loaded from
   the cache as machine code keeps the bitcode numba stores beside it for later links as bytes, takes
   the names of the symbols it defines from the object's ELF symbol table (:mod:`.lazy_link`),
   and parses the bitcode on the first link (``FTCREPORT_LAZY_LINK=0``: parsed on load, as numba does).
4. **The cache outside the package** (issue 38 item 3): :class:`KernelCache` is numba's function
   cache with ftcreport's locator (:class:`KernelLocator`): entries under
   ``ftcreport.infra.paths.cache_dir("numba")``, stamped with the source file's and every compiled
   source's hash (:func:`engine_stamp`: a kernel links kernels of other files, and numba keys an
   entry on its own file only).  numba documents no per-function registration of a cache locator
   (``NUMBA_CACHE_LOCATOR_CLASSES`` is process-wide), so ftcreport's cache implementation is a
   subclass with its own list of locators; numba's list is left alone.
5. **No ``numba:llvm_lock`` event** while an ftcreport entry point compiles (:func:`_quiet_llvm_lock`:
   numba broadcasts it to a timer of every compile in progress around each of the 10^5 calls a
   loop's compile makes into LLVM); numba's callbacks are taken out of llvmlite's list under numba's
   compiler lock and put back, the same list, before the lock is released.

Items 1, 2, 3 and 5 rest on numba's internals (method names of its code library and context), read
in the numba releases of :data:`TESTED`; on any other release, or with ``FTCREPORT_FAST_COMPILE=0``,
ftcreport's kernels compile through numba's own compiler and library (item 4 stays: it only names a
directory and a stamp).  A failure inside them turns them off for the process with one warning
(:class:`AccelerationWarning`) and the step that failed is done by numba's own method: never an error.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import os
import threading
import warnings
import weakref
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import numba
from numba.core import caching, compiler, registry
from numba.core.codegen import JITCodeLibrary
from numba.core.compiler_lock import global_compiler_lock

try:  # POSIX file locks: a kernel's cache entries written by one process at a time
    import fcntl
except ImportError:  # pragma: no cover - Windows: numba's own unlocked behaviour
    fcntl = None

from . import lazy_link
from .lazy_link import defined_symbols

__all__ = [
    "STALE_ENTRY",
    "TESTED",
    "AccelerationWarning",
    "KernelCache",
    "KernelDispatcher",
    "LazyEntry",
    "accelerated",
    "engine_stamp",
    "jit",
]

#: numba releases (major, minor) whose internals the acceleration was read in and CI has run it on
TESTED = frozenset({(0, 61), (0, 68)})

_STATE = threading.local()  # depth: ftcreport compiles in progress in this thread (numba compiles in the caller's)
_FAILED: list[str] = []  # the first failure of the acceleration in this process (then it is off)
_PENDING_ENVS: dict[str, object] = {}  # environments of deferred kernels, set once emitted code defines them
_KERNEL_FUNCS: weakref.WeakSet = weakref.WeakSet()  # the Python functions of KernelDispatchers


class AccelerationWarning(RuntimeWarning):
    """ftcreport's compile-time acceleration failed and was turned off: numba's own pipeline compiles."""


def _numba_release() -> tuple[int, int]:
    major, minor = numba.__version__.split(".")[:2]
    return int(major), int("".join(c for c in minor if c.isdigit()) or 0)


def accelerated() -> bool:
    """Whether ftcreport's kernels compile with the acceleration (items 1-3 and 5 above) in this process."""
    return not _FAILED and os.environ.get("FTCREPORT_FAST_COMPILE", "1") != "0" and _numba_release() in TESTED


def _fail(where: str, exc: BaseException) -> None:
    """Turn the acceleration off for the process, with one warning (the first failure's)."""
    if _FAILED:
        return
    _FAILED.append(f"{where}: {type(exc).__name__}: {exc}")
    warnings.warn(
        f"ftcreport: the compile-time acceleration failed on numba {numba.__version__} ({_FAILED[0]}); "
        "compiling with numba's own pipeline from now on (same results, slower first compiles). "
        "FTCREPORT_FAST_COMPILE=0 turns it off without this warning.",
        AccelerationWarning,
        stacklevel=3,
    )


def _depth() -> int:
    return getattr(_STATE, "depth", 0)


# --------------------------------------------------------------------------- the code library
class KernelLibrary(JITCodeLibrary):
    """numba's JIT code library; below an entry point: cheap passes and its machine code deferred."""

    _ftc_below = False  # compiled (or loaded) below an entry point, with the acceleration on
    _ftc_defer = True  # its machine code may wait (a kernel's: its dispatcher takes a LazyEntry)
    _ftc_cheap = False  # has had the cheap passes only (numba's full optimization runs before emission)
    _ftc_deferred = False  # finalized without its machine code
    _ftc_bitcode: bytes | None = None  # linking IR kept unparsed (a cache load)

    def _optimize_final_module(self) -> None:
        if not (self._ftc_below and accelerated()):
            return super()._optimize_final_module()
        try:
            _cheap_passes(self)
        except Exception as exc:
            _fail("cheap module passes", exc)
            return super()._optimize_final_module()
        self._ftc_cheap = True
        return None

    def _finalize_final_module(self) -> None:
        deferrable = self._ftc_below and self._ftc_defer and getattr(self, "_compiled_object", None) is None
        if not (deferrable and accelerated()):
            self._emit()
            return
        try:  # what numba's finalization checks and records, without adding the module to the JIT engine
            self._finalize_dynamic_globals()
            self._verify_declare_only_symbols()
        except Exception as exc:
            _fail("deferred emission", exc)
            self._dynamic_globals = []
            self._emit()
            return
        self._ftc_deferred = True
        self._finalized = True

    def _emit(self) -> None:
        """numba's finalization (the module added to the JIT engine, machine code emitted), fully optimized
        (an overload's implementation below an entry point excepted: its code is only ever linked)."""
        if self._ftc_cheap and self._ftc_defer:
            self._ftc_cheap = False
            super()._optimize_final_module()
        super()._finalize_final_module()
        _flush_envs(self._codegen)

    def realize(self) -> None:
        """Emit a deferred library's machine code (numba's full optimization first): numba's own state after."""
        if self._ftc_deferred:
            with global_compiler_lock:
                if self._ftc_deferred:
                    self._ftc_deferred = False
                    self._dynamic_globals = []  # numba's finalization lists them again
                    self._emit()

    def get_pointer_to_function(self, name):
        self._ensure_finalized()
        self.realize()
        return super().get_pointer_to_function(name)

    def serialize_using_object_code(self):
        self._ensure_finalized()
        if self._ftc_deferred:  # no object code: the cache keeps the optimized bitcode
            return self.serialize_using_bitcode()
        return super().serialize_using_object_code()

    def _get_module_for_linking(self):
        if self._ftc_deferred and _depth() == 0:  # linked by a compile that is not ftcreport's: numba's own state
            self.realize()
        if self._ftc_bitcode is not None:
            from llvmlite import binding as ll

            self._shared_module = ll.parse_bitcode(self._ftc_bitcode)
            self._ftc_bitcode = None
        return super()._get_module_for_linking()

    @classmethod
    def load(cls, codegen, state, below: bool) -> KernelLibrary:
        """A library from its cache entry (numba's ``serialize_using_*``): machine code, or deferred bitcode."""
        from llvmlite import binding as ll

        name, kind, data = state
        self = cls(codegen, name)
        if kind == "bitcode":  # a kernel that was deferred: the cheap passes, no machine code
            self._ftc_below, self._ftc_cheap = below, True
            self._final_module = ll.parse_bitcode(data)
            self._finalize_final_module()  # deferred again below an entry point, else optimized fully and emitted
            return self
        if kind != "object":
            raise ValueError(f"unsupported serialization kind {kind!r}")
        object_code, shared_bitcode = data
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        symbols = defined_symbols(object_code) if lazy_link.enabled() and accelerated() else None
        if symbols is None:
            self._shared_module = ll.parse_bitcode(shared_bitcode)
        else:
            self._ftc_bitcode = shared_bitcode
        self._finalize_final_module()
        engine = codegen._engine
        if symbols is None:
            engine._load_defined_symbols(self._shared_module)
        else:  # the names numba would read from the parsed module (tests/test_lazy_link.py)
            engine._defined_symbols |= symbols
        return self


def _cheap_passes(library: KernelLibrary) -> None:
    """numba's cheap module passes (its first stage, inlining for reference-count pruning) at O0, without
    the full O3 run: what numba's ``_optimize_final_module`` runs first, read in numba 0.61 and 0.68."""
    passes = library._codegen._module_pass_manager(loop_vectorize=False, slp_vectorize=False, opt=0, cost="cheap")
    if isinstance(passes, tuple):  # numba >= 0.62: LLVM's new pass manager and its builder
        passes[0].run(library._final_module, passes[1])
    else:  # numba 0.61: the legacy pass manager
        passes.run(library._final_module)


def _set_env(codegen, name: str, env) -> None:
    """numba's ``set_env``, or pending until emitted code defines the environment's global."""
    if codegen._engine.is_symbol_defined(name):
        codegen.set_env(name, env)
    else:
        _PENDING_ENVS[name] = env


def _flush_envs(codegen) -> None:
    """Point the environment globals of deferred kernels at their environments, once emitted code holds them."""
    for name in [n for n in _PENDING_ENVS if codegen._engine.is_symbol_defined(n)]:
        codegen.set_env(name, _PENDING_ENVS.pop(name))


def _executable(context, library, fndesc, env):
    """numba's ``get_executable``, or a :class:`LazyEntry` for a deferred library."""
    from numba.core.cpu import CPUContext

    library._ensure_finalized()  # numba finalizes in get_pointer_to_function: first, to know if it is deferred
    if library._ftc_deferred:
        _set_env(library.codegen, context.get_env_name(fndesc), env)
        return LazyEntry(context, library, fndesc, env)
    cfunc = CPUContext.get_executable(context, library, fndesc, env)
    _flush_envs(library.codegen)
    return cfunc


class LazyEntry:
    """A kernel's Python entry point whose machine code is emitted on its first call.

    numba gives every compiled function a Python-callable wrapper at once, and so emits the machine
    code of its whole library.  A kernel compiled below an entry point runs only inside the entry
    point's own module, so its library is emitted only if asked for: a call from Python (numba's
    dispatcher calls an entry point that is not a compiled function as a Python callable; this one
    then gives the dispatcher the real wrapper), a function pointer, a link outside ftcreport's compiles.
    """

    __slots__ = ("_context", "_env", "_fndesc", "_library", "_targets", "cfunc")

    def __init__(self, context, library, fndesc, env) -> None:
        self._context, self._library, self._fndesc, self._env = context, library, fndesc, env
        self.cfunc = None  # numba's wrapper, once emitted
        self._targets: list = []  # (dispatcher, compile result) to give the wrapper to

    def realize(self):
        """numba's wrapper of the kernel (its library's machine code emitted on the first call)."""
        if self.cfunc is None:
            from numba.core.cpu import CPUContext
            from numba.core.dispatcher import Dispatcher

            with global_compiler_lock:
                if self.cfunc is None:
                    self._library.realize()
                    self.cfunc = CPUContext.get_executable(self._context, self._library, self._fndesc, self._env)
                    _flush_envs(self._library.codegen)
                    for disp, cres in self._targets:
                        disp.targetctx.insert_user_function(self.cfunc, cres.fndesc, [cres.library])
                        Dispatcher.add_overload(disp, cres._replace(entry_point=self.cfunc))
                    self._targets.clear()
        return self.cfunc

    def __call__(self, *args, **kws):
        return self.realize()(*args, **kws)

    def __repr__(self) -> str:
        state = "emitted" if self.cfunc is not None else "deferred"
        return f"<LazyEntry {self._fndesc.qualname} ({state})>"


# --------------------------------------------------------------------------- the compiler and the dispatcher
class KernelCompiler(compiler.Compiler):
    """numba's default compiler (its pipelines unchanged) writing into a :class:`KernelLibrary`.

    It compiles the kernels of :func:`jit` and ftcreport's own overloads (``jit_options={"pipeline_class":
    KernelCompiler}``, jit/refs.py): an overload's implementation is held by numba's dispatcher, which
    takes compiled functions only, so its machine code is never deferred (the cheap passes below an entry
    point still apply)."""

    def compile_extra(self, func):
        if not accelerated() or self.state.library is not None:
            return super().compile_extra(func)
        context = self.state.targetctx  # this compile's own copy of numba's context (numba's subtarget)
        kernel = func in _KERNEL_FUNCS  # compiled by a KernelDispatcher (its depth counts this compile)
        try:
            library = KernelLibrary(context.codegen(), func.__qualname__)
            library.enable_object_caching()
            library._ftc_below = _depth() > int(kernel)  # the outermost ftcreport compile of a thread: an entry point
            library._ftc_defer = kernel
        except Exception as exc:
            _fail("code library", exc)
            return super().compile_extra(func)
        self.state.library = library
        context.get_executable = lambda lib, fndesc, env: _executable(context, lib, fndesc, env)
        try:
            return super().compile_extra(func)
        finally:
            del context.get_executable  # the copy keeps numba's method (it is the compile result's context)


class KernelDispatcher(registry.CPUDispatcher):
    """numba's CPU dispatcher: ftcreport's compiler and cache; a deferred kernel's overload kept aside."""

    def __init__(self, py_func, locals=None, targetoptions=None, pipeline_class=KernelCompiler):
        super().__init__(py_func, locals=locals or {}, targetoptions=targetoptions or {}, pipeline_class=pipeline_class)
        _KERNEL_FUNCS.add(py_func)

    def compile(self, sig):
        depth = _depth()
        _STATE.depth = depth + 1
        try:
            if depth == 0 and accelerated():  # an entry point: no llvm_lock event while it compiles
                with global_compiler_lock, _quiet_llvm_lock():
                    return super().compile(sig)
            return super().compile(sig)
        finally:
            _STATE.depth = depth

    def add_overload(self, cres) -> None:
        entry = cres.entry_point
        if not isinstance(entry, LazyEntry):
            return super().add_overload(cres)
        if entry.cfunc is not None:
            return super().add_overload(cres._replace(entry_point=entry.cfunc))
        # numba's table of wrappers takes compiled functions only: the first call from Python goes through
        # compile(), which returns the LazyEntry, which emits the code and gives the table the wrapper
        entry._targets.append((self, cres))
        self.overloads[tuple(cres.signature.args)] = cres
        return None

    def enable_caching(self) -> None:
        try:
            self._cache = KernelCache(self.py_func)
        except Exception as exc:  # no writable cache directory: compiled in every process, nothing written
            warnings.warn(
                f"ftcreport: no numba cache for {self.py_func.__qualname__} ({exc}); it is compiled in every process",
                RuntimeWarning,
                stacklevel=2,
            )


def jit(fn: Callable | None = None, *, cache: bool = True, **options):
    """numba's ``njit`` for ftcreport's kernels: ``cache=True, nogil=True, error_model="numpy"`` by default.

    ``@jit`` or ``@jit(cache=False, error_model="python", ...)``; the options are numba's ``jit`` options.
    A function defined outside ftcreport's own modules (a plug-in scheme's law and its helpers, through
    ``schemes.jit``) is always compiled with numba's ``boundscheck=True``: an index out of bounds, read or
    write, raises IndexError instead of reaching memory past the array (the loop turns it into the run's
    error, fast.loop._contract_law); ftcreport's kernels and generated loops keep numba's default."""
    targetoptions = {"nogil": True, "error_model": "numpy", **options, "nopython": True}
    targetoptions.setdefault("boundscheck", None)

    def wrap(py_func):
        if numba.config.DISABLE_JIT:
            return py_func
        opts = dict(targetoptions)
        if not own_module(getattr(py_func, "__module__", None) or ""):
            opts["boundscheck"] = True
        disp = KernelDispatcher(py_func, targetoptions=opts)
        if cache:
            disp.enable_caching()
        return disp

    return wrap if fn is None else wrap(fn)


def own_module(name: str) -> bool:
    """Whether a module is ftcreport's own code: the package, or a loop module it generates (fast.engine)."""
    return name == "ftcreport" or name.startswith(("ftcreport.", "ftcreport_loop_"))


# --------------------------------------------------------------------------- the cache
#: the folders of compiled sources
_ENGINE_FILES = ("jit", "fast", "schemes", "model", "control", "observers", "references")


def engine_stamp() -> str:
    """A hash of every compiled source of the package (read once per process)."""
    stamp = getattr(engine_stamp, "_value", None)
    if stamp is None:
        root = Path(__file__).resolve().parents[1]
        h = hashlib.sha256()
        for sub in _ENGINE_FILES:
            for path in sorted((root / sub).glob("*.py")):
                h.update(path.name.encode() + b"\0" + path.read_bytes())
        stamp = engine_stamp._value = h.hexdigest()
    return stamp


_Locator = getattr(caching, "_CacheLocator", None) or caching.CacheLocator  # numba 0.61 and 0.68 name it so


class KernelLocator(_Locator):
    """Where numba keeps an ftcreport kernel's cache entries: ``paths.cache_dir("numba")``, never the package.

    One folder per source directory (its name and a hash of its path, as numba's own user-wide locator
    names them), under ``fast`` or ``numba`` (entries compiled with or without the acceleration: a
    deferred kernel is stored as bitcode, which numba's own load would emit unoptimized).  The stamp is
    the source file's (modification time and size, as numba's) and :func:`engine_stamp`."""

    def __init__(self, py_func, py_file: str) -> None:
        from ..infra.paths import cache_dir

        self._py_file = py_file  # numba's warnings read it
        self._lineno = py_func.__code__.co_firstlineno
        mode = "fast" if accelerated() else "numba"
        self._cache_path = str(cache_dir("numba") / mode / self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self):
        st = os.stat(self._py_file)
        return st.st_mtime, st.st_size, engine_stamp()

    def get_disambiguator(self) -> str:
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        if not os.path.exists(py_file):
            return None
        self = cls(py_func, py_file)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


class KernelCacheImpl(caching.CompileResultCacheImpl):
    """numba's cache of compile results, ftcreport's locator first; loads into :class:`KernelLibrary`."""

    _locator_classes = [KernelLocator]  # noqa: RUF012 - numba's class attribute, a list of ftcreport's own

    def reduce(self, cres):
        """numba's payload, its environments as :class:`EnvRecord` (read back by :func:`environment`)."""
        payload = list(cres._reduce())
        payload[2] = EnvRecord.of(payload[2])
        payload[8] = tuple(EnvRecord.of(env) for env in payload[8])
        return tuple(payload)

    def rebuild(self, target_context, payload):
        payload = list(payload)
        payload[2] = environment(payload[2])
        payload[8] = tuple(environment(env) for env in payload[8])
        if not accelerated():
            return super().rebuild(target_context, payload)
        try:
            return _rebuild(target_context, *payload)
        except Exception as exc:
            _fail("cache load", exc)
            return super().rebuild(target_context, payload)


class KernelCache(caching.FunctionCache):
    """numba's function cache with :class:`KernelCacheImpl`, its entries read and written under a file lock.

    **One writer at a time.**  numba's save reads the function's index, picks the first data-file
    number the index does not use, writes the index and then the data.  Two processes that compile
    two signatures of one kernel at once (a batch's or the test suite's workers on an empty cache)
    both read the same index and pick the same number: the second's data overwrites the first's
    under the first's key, and the next process that loads the first signature gets the second's
    code, its wrapper reading constants of another environment (``'descr' is NULL`` when it boxes
    an array).  Here a save holds an exclusive ``fcntl`` lock on ``<function>.lock`` beside the
    index, a load a shared one, so a load never sees an index entry whose data is being written.

    **A loaded entry is checked.**  An entry whose compiled signature is not the one asked for (a
    cache written before the lock, by another tool, or damaged) is a miss: the function's entries
    are flushed and it compiles again.

    **An entry's environment agrees with the process's.**  numba names a compiled function's
    environment (the Python constants its wrapper reads, by index: the dtype of an array it returns)
    after the function, its argument types and a per-process compile counter, so one name recurs
    across processes, and numba keeps one live environment per name: a load takes the live one and
    drops the entry's constants.  A function compiled while a loaded caller holds its environment
    appends its constants behind the caller's copies (``'descr' is NULL`` when another process
    loads that entry after the caller).  Environments are stored as :class:`EnvRecord` and read
    back by :func:`environment`, which completes a live environment with the entry's constants, or
    makes the entry a miss when the two disagree.

    **A stale index is a miss.**  An index that cannot be read back (:data:`STALE_ENTRY`: written by
    another version of ftcreport whose modules or classes it names are gone, or truncated) is a
    miss, not an error: flushed (numba's ``Cache.flush``) and compiled again, so a cache that
    outlived an upgrade never stops a run.
    """

    _impl_class = KernelCacheImpl

    @contextlib.contextmanager
    def _locked(self, mode: int) -> Iterator[None]:
        """``fcntl.flock`` of ``mode`` on the function's lock file (no lock where it cannot be opened)."""
        if fcntl is None:
            yield
            return
        try:
            fh = open(Path(self.cache_path) / f"{self._impl.filename_base}.lock", "a")  # noqa: SIM115
        except OSError:  # a read-only cache directory: nothing is written there either
            yield
            return
        with fh:
            fcntl.flock(fh, mode)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def load_overload(self, sig, target_context):
        with self._locked(fcntl.LOCK_SH if fcntl else 0):
            try:
                cres = super().load_overload(sig, target_context)
            except EnvConflictError:  # the live environment holds other constants: compile here, keep the entry
                return None
            except Exception as exc:
                if not _stale(exc):
                    raise
                cres, wrong = None, True
            else:
                wrong = cres is not None and tuple(cres.signature.args) != _arg_types(sig)
        if wrong:
            with self._locked(fcntl.LOCK_EX if fcntl else 0), contextlib.suppress(OSError):
                self.flush()  # numba's save reads the index first: an unreadable one would fail it too
            return None
        return cres

    def save_overload(self, sig, data) -> None:
        with self._locked(fcntl.LOCK_EX if fcntl else 0):
            super().save_overload(sig, data)


class EnvConflictError(Exception):
    """A cache entry's environment constants disagree with the live environment of the same name."""


class EnvRecord(NamedTuple):
    """A compiled function's environment as a cache entry stores it: numba's environment (pickled by
    numba: read back, it is the live one of its name if there is one) and the constants it held."""

    env: object
    consts: list

    @classmethod
    def of(cls, env) -> EnvRecord:
        return cls(env, list(env.consts))


def _same_const(a, b) -> bool:
    if a is b:
        return True
    try:
        return type(a) is type(b) and bool(a == b)
    except Exception:  # an array or an object without a plain equality: not provably the same
        return False


def environment(record):
    """The environment of ``record`` holding the record's constants at their indices.

    numba's unpickling gave the live environment of the name if there is one, else a new one with
    the record's constants.  A live one holding a prefix of them (equal values: a dtype read back
    from a pickle is a new object) gets the rest appended, which moves no index its code reads;
    anything else is an :class:`EnvConflictError`.  Not a record (an entry numba reduced): returned."""
    if not isinstance(record, EnvRecord):
        return record
    env, want = record
    have = env.consts
    if not all(_same_const(a, b) for a, b in zip(have, want, strict=False)):
        raise EnvConflictError(f"environment {env.env_name}: the cached constants differ from the live ones")
    have.extend(want[len(have) :])
    return env


def _arg_types(sig) -> tuple:
    """The argument types of a dispatcher's signature (a tuple of types, or a numba Signature)."""
    from numba.core import sigutils

    return tuple(sigutils.normalize_signature(sig)[0])


#: what reading back a cache entry raises when it was written by other code (a module or class it
#: names that no longer exists) or cut short; pickle's own error is told by its name (see _stale)
STALE_ENTRY = (ImportError, AttributeError, EOFError, ValueError, TypeError, IndexError, KeyError, OSError)


def _stale(exc: BaseException) -> bool:
    """Whether ``exc`` says a cache entry cannot be read back (:data:`STALE_ENTRY`, pickle's
    UnpicklingError: matched by name, so the engine imports no pickle)."""
    return isinstance(exc, STALE_ENTRY) or any(c.__name__ == "UnpicklingError" for c in type(exc).__mro__)


def _rebuild(ctx, libdata, fndesc, env, signature, objectmode, lifted, typeann, reload_init, referenced_envs):
    """numba's compile result from its cache payload (``CompileResult._reduce``), its library a KernelLibrary."""
    for fn in reload_init or ():
        fn()
    library = KernelLibrary.load(ctx.codegen(), libdata, below=_depth() > 1)
    cres = compiler.CompileResult(
        target_context=ctx, typing_context=ctx.typing_context, library=library, environment=env,
        entry_point=_executable(ctx, library, fndesc, env), fndesc=fndesc, type_annotation=typeann,
        signature=signature, objectmode=objectmode, lifted=lifted, typing_error=None, call_helper=None,
        metadata=None, reload_init=reload_init, referenced_envs=referenced_envs,
    )  # fmt: skip
    for ref in referenced_envs:
        _set_env(library.codegen, ref.env_name, ref)
    return cres


# --------------------------------------------------------------------------- helpers
@contextlib.contextmanager
def _quiet_llvm_lock() -> Iterator[None]:
    """Without numba's ``numba:llvm_lock`` event around each call into LLVM, while an entry point compiles.

    numba broadcasts the event to a timer of every compile in progress (one per level of nesting) at
    each of the 100,000s of calls a loop's compile makes into LLVM.  It only feeds the LLVM-time entry
    of numba's compile metadata, then 0 for ftcreport's kernels (``FTCREPORT_LLVM_EVENTS=1`` keeps it).
    Called under numba's compiler lock; llvmlite's list of callbacks is put back (the same list) on exit.
    """
    from llvmlite.binding import ffi

    lock = getattr(ffi.lib, "_lock", None)
    callbacks = getattr(lock, "_cblist", None)
    if os.environ.get("FTCREPORT_LLVM_EVENTS") == "1" or not isinstance(callbacks, list):
        yield
        return
    lock._cblist = [cb for cb in callbacks if getattr(cb[0], "__module__", "") != "numba.core.base"]
    try:
        yield
    finally:
        lock._cblist = callbacks


def source_file(fn) -> Path:
    """The file a kernel (a dispatcher or a Python function) is defined in."""
    return Path(inspect.getfile(getattr(fn, "py_func", fn)))
