r"""The one registry of schemes: the built-in ones and the plug-ins, registered the same way.

The built-in schemes register themselves from their own files (every module of
:data:`BUILT_IN_PACKAGE`, ``ftcreport/control/builtin/``) the first time the registry is read, each with
its place in the
order the case schema and the reports list them; a plug-in registers itself when its file is
imported (:func:`load_plugin`, a case's ``plugins``).  Every reader (the runner, the engine, the
case schema, the families, the reports, campaigns) asks here.  Adding a built-in scheme is adding
its file there (and its law, ``control/*_law.py``, when it has its own) and its tests.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import os
import sys
import threading
import warnings
from pathlib import Path

from ..errors import ModelError
from .api import TERMS_MODES, Scheme

__all__ = ["built_in", "get", "load_plugin", "plugin_imports", "register", "registered", "resolve"]

#: The package of the built-in schemes' files (each registers its schemes when imported).  The registry
#: imports them by name, as it imports a plug-in by path: the registry sits below the laws they run.
BUILT_IN_PACKAGE = "ftcreport.control.builtin"

_REGISTRY: dict[str, Scheme] = {}
_BUILT_IN: list[str] = []
_RANK: dict[str, float] = {}
_LOADING = threading.RLock()
_loaded = False  # every built-in file imported (set last: another thread waits on _LOADING until then)
_loader: int | None = None  # the thread importing them (a built-in file that reads the registry meanwhile)


def _load_built_ins() -> None:
    """Import the built-in schemes' files once (each registers its schemes).

    Thread-safe: a Dask worker's threads may ask at once; all but the one that imports wait for it
    to finish (a flag set first let them read an empty registry).  The importing thread itself,
    re-entering through a built-in file that reads the registry, returns at once."""
    global _loaded, _loader
    if _loaded:
        return
    with _LOADING:
        if _loaded or _loader == threading.get_ident():
            return
        _loader = threading.get_ident()
        try:
            import pkgutil

            package = importlib.import_module(BUILT_IN_PACKAGE)
            for mod in sorted(m.name for m in pkgutil.iter_modules(package.__path__)):
                importlib.import_module(f"{BUILT_IN_PACKAGE}.{mod}")
            _loaded = True
        finally:
            _loader = None


def register_built_in(scheme: Scheme, order: float) -> Scheme:
    """Register one of ftcreport's own schemes (their files call this): listed by ``order`` (nominal 10,
    switching 20, adaptive 30, its ablation 31, active 40, active_ukf 50, the oracle 90), whatever the
    import order."""
    _check(scheme)
    _REGISTRY[scheme.name] = scheme
    if scheme.name not in _BUILT_IN:
        _BUILT_IN.append(scheme.name)
        _RANK[scheme.name] = float(order)
        _BUILT_IN.sort(key=_RANK.__getitem__)
    return scheme


def _where(fn) -> str:
    """``file:line`` of a function's definition (a numba dispatcher's Python function), or its repr."""
    py = getattr(fn, "py_func", fn)
    code = getattr(py, "__code__", None)
    if code is None:
        return repr(fn)
    return f"{code.co_filename}:{code.co_firstlineno}"


def _check(scheme: Scheme) -> None:
    """The declarations a scheme can get wrong before anything is compiled."""
    from ..infra.names import NAME_PATTERN

    if not NAME_PATTERN.fullmatch(scheme.name):
        rule = "a letter or digit, then letters, digits, '_', '.', '-' (at most 64)"
        raise ModelError(f"scheme name {scheme.name!r}: {rule}")
    if scheme.terms not in TERMS_MODES:
        raise ModelError(f"scheme {scheme.name}: terms must be one of {', '.join(TERMS_MODES)}, got {scheme.terms!r}")
    if scheme.pack is None and scheme.controller is None:
        raise ModelError(f"scheme {scheme.name}: give pack (ctx -> the law's parameters)")
    for role, fn in (("law", scheme.law), ("discrete", scheme.discrete)):
        if (fn is None and role == "discrete") or isinstance(fn, str):
            continue
        if not hasattr(fn, "py_func"):  # a plain Python function: the loop cannot call it
            raise ModelError(
                f"{_where(fn)}: scheme {scheme.name}: the {role} {getattr(fn, '__name__', fn)!r} is not compiled: "
                "decorate it with @schemes.jit (numba's njit with ftcreport's options)"
            )
        _check_arity(scheme, role, fn)


_ARGS = {"law": ("P", "step", "terms", "x", "out"), "discrete": ("P", "step", "x")}
_LEGACY_ARGS = {"law": 13, "discrete": 9}


def _check_arity(scheme: Scheme, role: str, fn) -> None:
    """The contract's argument count, or the round-2 one (accepted with a DeprecationWarning)."""
    try:
        params = inspect.signature(fn.py_func).parameters
    except (TypeError, ValueError):
        return
    n = len(params)
    want = _ARGS[role]
    if n == len(want):
        return
    if n == _LEGACY_ARGS[role]:
        warnings.warn(
            f"{_where(fn)}: scheme {scheme.name}: the {role} takes the round-2 {n} arguments; the contract is "
            f"{role}({', '.join(want)}) (README 'Write your own scheme'); the old form is run through an adapter "
            "and will be refused in a later version",
            DeprecationWarning,
            stacklevel=4,
        )
        return
    raise ModelError(
        f"{_where(fn)}: scheme {scheme.name}: the {role} takes {n} arguments; the contract is {role}({', '.join(want)})"
    )


def legacy(fn) -> bool:
    """Whether a compiled law or discrete update has the round-2 signature (13 or 9 positionals)."""
    try:
        n = len(inspect.signature(fn.py_func).parameters)
    except (AttributeError, TypeError, ValueError):
        return False
    return n in _LEGACY_ARGS.values()


def register(scheme: Scheme) -> Scheme:
    """Register a plug-in scheme under its name (a safe name, not a built-in one); returns it.

    Refused at once: a bad name, a law or discrete update that is not compiled (no ``@schemes.jit``)
    or takes the wrong number of arguments; each message names the file and line of the function.
    """
    _load_built_ins()
    if scheme.name in _BUILT_IN:
        raise ModelError(f"scheme name {scheme.name!r} is a built-in scheme")
    _check(scheme)
    old = _REGISTRY.get(scheme.name)
    if old is not None and old.law is not scheme.law and _code(old.law) != _code(scheme.law):
        raise ModelError(f"scheme {scheme.name!r} is registered twice, by two different laws")
    _REGISTRY[scheme.name] = scheme
    return scheme


def _code(fn):
    return getattr(getattr(fn, "py_func", fn), "__code__", None)


def registered() -> dict[str, Scheme]:
    """The registered plug-in schemes by name (the built-in ones: :func:`built_in`)."""
    _load_built_ins()
    return {k: v for k, v in _REGISTRY.items() if k not in _BUILT_IN}


def built_in() -> dict[str, Scheme]:
    """The built-in schemes by name, in the order the case schema and the reports list them."""
    _load_built_ins()
    return {k: _REGISTRY[k] for k in _BUILT_IN}


def is_built_in(scheme: Scheme) -> bool:
    """Whether ``scheme`` is one of ftcreport's own (a plug-in's hooks are its author's code, named when they fail)."""
    return built_in().get(scheme.name) is scheme


def every() -> dict[str, Scheme]:
    """Every scheme: the built-in ones, then the plug-ins in registration order."""
    _load_built_ins()
    return built_in() | registered()


def discrete_time(name: str) -> bool:
    """Whether scheme ``name`` (any registered) is a discrete-time filter: its discrete update also runs at t0
    (``Scheme.start``: the UKF's), so it updates on the sensor's clock (fast.engine.disc_ticks); False for a name
    no scheme has."""
    sc = every().get(name)
    return sc is not None and bool(sc.start)


def get(name: str) -> Scheme:
    _load_built_ins()
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY)) or "none"
        raise ModelError(f"no scheme {name!r} is registered (registered: {known})") from None


def resolve(fn):
    """A compiled function given as itself or as ``"module:function"`` (a built-in's, imported on first use)."""
    if not isinstance(fn, str):
        return fn
    mod, _, name = fn.partition(":")
    return getattr(importlib.import_module(mod), name)


_IMPORTS: dict[str, tuple[Path, ...]] = {}  # a loaded scheme file (resolved) -> the user modules it imports


def plugin_imports(path: str | Path) -> tuple[Path, ...]:
    """The files of the user's own modules a scheme file imported when it was loaded in this process
    (:func:`load_plugin`), sorted; () for a file not loaded here.

    A user module is one whose file lies outside the Python installation (the standard library),
    site-packages and ftcreport's own package: a helper module beside the scheme file, a package of the
    user's project (an editable install too).  They are the modules newly imported while the file was
    executed, and the modules the file's (and those modules') globals name, followed transitively (a
    helper another scheme file imported first).  The result cache hashes them with the scheme file
    (``ftcreport.cases.plugin_digest``), so editing a helper re-runs its results.

    Not seen: a module imported later, inside a function (``pack`` or the law's first call), and data
    files a module reads (a table loaded with ``np.load``): a change there is not a changed case.
    """
    return _IMPORTS.get(str(Path(path).resolve()), ())


def _system_roots() -> tuple[Path, ...]:
    """Where the interpreter's own and the installed packages' modules live (not the user's code)."""
    import site
    import sysconfig

    roots = {sys.prefix, sys.base_prefix, sys.exec_prefix, getattr(sys, "base_exec_prefix", sys.prefix)}
    roots |= {v for k, v in sysconfig.get_paths().items() if k in ("stdlib", "platstdlib", "purelib", "platlib")}
    roots |= set(getattr(site, "getsitepackages", list)())
    user_site = getattr(site, "getusersitepackages", lambda: None)()
    if user_site:
        roots.add(user_site)
    roots.add(str(Path(__file__).resolve().parents[1]))  # ftcreport itself: the code digest covers it
    return tuple(Path(r).resolve() for r in roots if r)


def user_frame(exc: BaseException) -> str | None:
    """``file:line`` of the innermost frame of ``exc``'s traceback in the user's own code (a scheme file,
    a module it imports), or None when every frame is ftcreport's, the interpreter's or an installed
    package's (then the error is not the user's code's)."""
    import traceback

    roots = _system_roots()
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        try:
            f = Path(frame.filename).resolve()
        except OSError:
            continue
        if frame.filename.startswith("<") or any(f.is_relative_to(r) for r in roots):
            continue
        return f"{frame.filename}:{frame.lineno}"
    return None


def _module_file(module) -> Path | None:
    f = getattr(module, "__file__", None)
    if not isinstance(f, str) or not f.endswith(".py"):
        return None  # a built-in or an extension module: not the user's source
    try:
        return Path(f).resolve()
    except OSError:
        return None


def _user_imports(module, new: set[str], own: Path) -> tuple[Path, ...]:
    """:func:`plugin_imports` of the scheme file ``own`` just executed as ``module``; ``new``: the names
    of the modules imported meanwhile."""
    roots = _system_roots()

    def user(m) -> Path | None:
        f = _module_file(m)
        name = getattr(m, "__name__", "") or ""
        if f is None or f == own or name.startswith(("ftcreport_loop_", "ftcreport.")) or name == "ftcreport":
            return None
        return None if any(f.is_relative_to(r) for r in roots) else f

    found: dict[Path, object] = {}
    todo = [sys.modules[n] for n in new if n in sys.modules] + [module]
    seen: set[int] = set()
    while todo:
        m = todo.pop()
        if id(m) in seen:
            continue
        seen.add(id(m))
        f = user(m)
        if f is not None:
            found[f] = m
        if m is not module and f is None:
            continue  # a system module's globals are not followed
        for v in list(vars(m).values()):
            if isinstance(v, type(sys)):
                todo.append(v)
            else:
                owner = getattr(v, "__module__", None)
                if isinstance(owner, str) and owner in sys.modules:
                    todo.append(sys.modules[owner])
    return tuple(sorted(found))


def load_plugin(path: str | Path) -> None:
    """Import a scheme file (it registers its schemes when imported); idempotent per file."""
    from ..infra.inputs import input_problem

    if not os.path.lexists(path):
        raise ModelError(f"{path}: no such scheme file")
    if (why := input_problem(path, "scheme file")) is not None:  # a FIFO, a device, a directory, too large
        raise ModelError(why)
    p = Path(path).resolve()
    # the module's name is the same in every process and for every copy of the file (numba's cache
    # indexes of the scheme's law and loop name it): two scheme files may not share a stem
    name = "ftcreport_plugin_" + "".join(c if c.isalnum() else "_" for c in p.stem)
    loaded = sys.modules.get(name)
    if loaded is not None:
        if Path(loaded.__file__).resolve() != p:
            raise ModelError(f"{path}: a scheme file named {p.name} is already loaded from {loaded.__file__}")
        return
    _load_built_ins()
    spec = importlib.util.spec_from_file_location(name, p)
    if spec is None or spec.loader is None:
        raise ModelError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    before = dict(_REGISTRY)
    modules_before = set(sys.modules)
    try:
        spec.loader.exec_module(module)
    except SystemExit as exc:  # not an Exception; the half-imported module must not stay loaded either
        del sys.modules[name]
        raise ModelError(f"{path}: the scheme file called sys.exit({exc.code!r}) on import") from None
    except ModelError as exc:  # register() refused a scheme: its message names the file and line
        del sys.modules[name]
        raise ModelError(str(exc)) from None
    except Exception as exc:
        del sys.modules[name]
        raise ModelError(f"{path}: the scheme file failed to import: {type(exc).__name__}: {exc}") from exc
    if all(before.get(k) is v for k, v in _REGISTRY.items()):  # nothing new: a wrong file, or a typo in it
        del sys.modules[name]
        raise ModelError(
            f"{path}: registers no scheme (a scheme file calls ftcreport.schemes.register(Scheme(...)) when imported)"
        )
    _IMPORTS[str(p)] = _user_imports(module, set(sys.modules) - modules_before, p)
