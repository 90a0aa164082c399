r"""``ftcreport schemes check FILE``: a new scheme's law through a battery of checks before its first real run.

In the manner of scikit-learn's ``check_estimator``: each check exercises one promise of the contract
(:mod:`ftcreport.schemes.api`) and a failure is one line naming the file (and line, where there is one),
the scheme, the function and what to fix::

    examples/schemes/my_law.py:42: scheme my_law: law: wrote past its declared signals ...

The battery, per scheme the file registers:

1. the file imports and registers its schemes (a law without ``@schemes.jit`` or with the wrong number
   of arguments is refused by ``register``, at the function's line);
2. the parameter model's defaults are valid and every field is documented (description, unit);
3. ``pack``, ``n_states``, ``initial_state`` and ``signals`` on a two-robot (two-link controller) and a
   three-robot (chained controller) case: a tuple of numbers and arrays, a state of the declared size,
   finite, signal widths of whole numbers;
4. the law and the discrete update compile in the loop's own types (a numba TypingError is reported at
   the user's line, numba's message after it); the law returns nothing (it writes ``out``);
5. bounds: the law and the discrete update compiled with numba's ``boundscheck=True`` (the file's own
   compiled helpers too) and run on every state below: an index out of bounds, read or write, is
   reported, with its line (the function run once more in Python, where numpy names it);
6. on healthy and faulty patterns (every wheel working, a wheel lost, a partial loss with friction) at
   perturbed states: the outputs ``u``, ``dx`` and every declared signal are finite, every declared
   signal is written, no write past a declared width (the guard cells), the inputs are not modified,
   and two calls on the same inputs give the same bits (determinism);
7. the discrete update: finite, within its states, deterministic.

:func:`ensure_checked` runs checks 5-7 on a plug-in's first run in a case (its own chain, controller and
table), once per version of its file (recorded in the cache directory).
"""

from __future__ import annotations

import hashlib
import inspect
import re
import threading
import traceback
import types as pytypes
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..schemes.api import Scheme
from ..schemes.controller import write_reason

__all__ = ["Finding", "check_file", "check_scheme", "ensure_checked"]


@dataclass(frozen=True)
class Finding:
    """One check's outcome: ``ok`` and a one-line message (what passed, or what to fix); ``detail``: more lines
    (numba's own message after a TypingError)."""

    ok: bool
    message: str
    detail: str = ""


# ---------------------------------------------------------------------------------------- where things are
def _where(fn) -> str:
    """``file:line`` of a function's definition (a dispatcher's Python function, a class)."""
    py = getattr(fn, "py_func", fn)
    try:
        return f"{inspect.getsourcefile(py)}:{inspect.getsourcelines(py)[1]}"
    except (TypeError, OSError):
        code = getattr(py, "__code__", None)
        return f"{code.co_filename}:{code.co_firstlineno}" if code is not None else repr(fn)


def _fn_name(fn) -> str:
    return getattr(getattr(fn, "py_func", fn), "__name__", repr(fn))


_FILE_LINE = re.compile(r'File "([^"]+)", line (\d+)')


def _user_line(message: str, files: set[str]) -> str | None:
    """The first ``file:line`` of numba's message that is in one of ``files`` (resolved paths)."""
    for m in _FILE_LINE.finditer(message):
        path = Path(m.group(1))
        for base in (Path.cwd(), Path("/")):
            p = (base / path).resolve() if not path.is_absolute() else path.resolve()
            if str(p) in files:
                return f"{p}:{m.group(2)}"
    return None


_NAMED = re.compile(r"(?:name '(\w+)' is not defined|Untyped global name '(\w+)'|Unknown attribute '(\w+)')")


def _name_line(message: str, *fns) -> str | None:
    """``file:line`` of the first use of the name numba could not resolve, in the law (or the discrete update)
    then anywhere in its file: numba names an undefined global without its line (only the caller's)."""
    m = _NAMED.search(message)
    if m is None:
        return None
    name = next(g for g in m.groups() if g)
    word = re.compile(rf"(?<![\w.]){re.escape(name)}\b" if "attribute" not in m.group(0) else rf"\.{re.escape(name)}\b")
    for fn in fns:
        if fn is None:
            continue
        py = getattr(fn, "py_func", fn)
        try:
            lines, first = inspect.getsourcelines(py)
            path = inspect.getsourcefile(py)
        except (TypeError, OSError):
            continue
        for i, line in enumerate(lines):
            if word.search(line.split("#")[0]):
                return f"{path}:{first + i}"
    return None


def _numba_reason(message: str) -> str:
    """The one line of a numba TypingError that says what is wrong."""
    lines = [x.strip() for x in message.splitlines() if x.strip()]
    for i, line in enumerate(lines):
        if line.startswith("Rejected as the implementation raised a specific error:") and i + 1 < len(lines):
            return lines[i + 1]
    for line in lines:
        if line.startswith(("Untyped global name", "NameError", "Unknown attribute", "Cannot unify", "Invalid use")):
            return line
        if "readonly array" in line and "Cannot modify" in line:
            return line
    for line in lines:
        if not line.startswith(("Failed in", "During:", "File ", "^", "No implementation", ">>>", "There are")):
            return line
    return lines[0] if lines else "numba could not compile it"


def _typing_hint(reason: str) -> str:
    if "readonly array" in reason:
        return "the law's state x is read-only (its rates go in out.dx; a discrete update changes the state)"
    if "Untyped global name" in reason or "NameError" in reason:
        return "a name the function uses is not defined, or not a compiled (@schemes.jit) function"
    return "numba's message follows"


# ---------------------------------------------------------------------------------------- test contexts
def _contexts(scheme: Scheme) -> list[tuple[str, object]]:
    """(label, controller) of the scheme on a two-robot chain (two-link controller, circle) and a three-robot
    chain (chained controller, eight), with its parameter model's defaults."""
    from ..control.kinematic import ChainedBackstepping, TwoLinkKinematic
    from ..model import Chain
    from ..references import FlatReference, circle, eight
    from ..schemes.controller import SchemeController

    out = []
    table = _default_table(scheme)
    two = Chain.uniform(2, d=1.7)
    kin2 = TwoLinkKinematic(1.7, FlatReference(circle(5.0, 0.5), two.d), 10.0, 2.0, 0.5)
    three = Chain.uniform(3, d=1.0)
    kin3 = ChainedBackstepping(three.d, FlatReference(eight(), three.d), [0.3] * 3, 2.0, 2.0, 5.0)
    for label, chain, kin in (("2 robots, two-link controller", two, kin2), ("3 robots, chained", three, kin3)):
        k_v = getattr(table, "k_v", None) or 5.0
        if scheme.controller is not None:
            from ..schemes.api import SchemeContext

            nz, nq = len(kin.z_names), chain.n_q
            ctx = SchemeContext(chain, kin, k_v, table, 5.0, kin.n_states, 6 + nz + nq)
            out.append((label, scheme.controller(scheme, ctx)))
        else:
            out.append((label, SchemeController(scheme, chain, kin, k_v, table, saturation=5.0)))
    return out


def _default_table(scheme: Scheme):
    if scheme.params is None:
        return None
    try:
        return scheme.params()
    except Exception:
        return None


# ---------------------------------------------------------------------------------------- the states
def _states(ctrl) -> list[tuple[str, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(label, t, q, eta, xc, sigma, ubar): the reference start, perturbed, on healthy and faulty patterns."""
    ref = ctrl.kin.reference
    nw = ctrl.chain.n_wheels
    rng = np.random.default_rng(7)
    out = []
    healthy = (np.ones(nw), np.zeros(nw))
    lost = np.ones(nw)
    lost[1] = 0.0
    partial = np.ones(nw)
    partial[-1] = 0.5
    friction = np.zeros(nw)
    friction[0] = 0.4
    patterns = (
        ("healthy", *healthy),
        ("wheel 1l lost", lost, np.zeros(nw)),
        ("partial loss and friction", partial, friction),
    )
    for i, t in enumerate((0.0, 1.3)):
        r = ref.at(t)
        q = r.q_d + (0.0 if i == 0 else rng.normal(scale=0.05, size=r.q_d.shape))
        eta = r.eta_d + (0.0 if i == 0 else rng.normal(scale=0.1, size=2))
        xc = np.asarray(ctrl.initial_state(t, q, eta), dtype=float)
        for label, sigma, ubar in patterns:
            out.append((f"{label}, t = {t:g} s", t, q.copy(), eta.copy(), xc.copy(), sigma, ubar))
    return out


# ---------------------------------------------------------------------------------------- one call
class _Call:
    """The law (and the discrete update) of a bound scheme, called through its loop's entry points."""

    def __init__(self, ctrl, checked: bool = False) -> None:
        from .engine import compiled_spec, loop_for

        self.ctrl = ctrl
        self.spec = compiled_spec(ctrl)
        if self.spec is None:
            raise ModelError(f"scheme {ctrl.name}: no compiled counterpart (its kinematic controller or reference)")
        law, disc = self.spec.law, self.spec.disc
        if checked:
            law, disc = boundschecked(law), boundschecked(disc)
        self.loop = loop_for(law, disc, motors=False, sampled=False, terms=self.spec.terms, checked=checked)

    def law(self, t, q, eta, xc, sigma, ubar):
        """(u, dx, sig_own, info, row): one call; sig_own pre-filled with a sentinel to see what is written."""
        from .engine import law_buffers

        bufs = law_buffers(self.spec)
        n_sig = self.spec.n_sig - self.spec.n_kin_sig
        bufs[3][:n_sig] = _SENTINEL
        info = np.zeros(4)
        row = np.zeros(self.spec.n_sig)
        u = self.loop.first_law((self.spec.P, bufs), self.spec.kin, self.spec.ref, self.spec.chain, float(t), q, eta,
                                xc, sigma, ubar, info, row)  # fmt: skip
        no = self.ctrl.n_own
        return u, bufs[2][:no].copy(), bufs[3][:n_sig].copy(), info, row, bufs

    def discrete(self, t, q, eta, xc):
        """(xc after, info, buffers): one discrete update on a copy of xc."""
        from .engine import law_buffers

        bufs = law_buffers(self.spec)
        info = np.zeros(4)
        x = xc.copy()
        self.loop.first_discrete((self.spec.P, bufs), self.spec.kin, self.spec.ref, self.spec.chain, float(t), q, eta,
                                 x, info)  # fmt: skip
        return x, info, bufs


_SENTINEL = -1.2345678901234567e299  # a declared signal still holding it after a call was not written


# ---------------------------------------------------------------------------------------- boundscheck copies
_BC: dict[int, object] = {}
_BC_LOCK = threading.Lock()


def boundschecked(fn):
    """A copy of a compiled function compiled with numba's ``boundscheck=True`` (not cached), with the compiled
    functions of its own module that it calls replaced by their bounds-checked copies too.  ftcreport's own
    kernels are left as they are (they are tested)."""
    with _BC_LOCK:
        return _boundschecked(fn, {})


def _boundschecked(fn, seen: dict):
    from numba import njit
    from numba.core.registry import CPUDispatcher

    key = id(fn)
    if key in _BC:
        return _BC[key]
    if key in seen:
        return seen[key]
    py = fn.py_func
    module = py.__module__
    if module.startswith("ftcreport.") and not module.startswith("ftcreport_plugin"):
        return fn  # ftcreport's own kernel: tested, compiled as it is
    glb = dict(py.__globals__)
    copy = pytypes.FunctionType(py.__code__, glb, py.__name__, py.__defaults__, py.__closure__)
    copy.__qualname__ = py.__qualname__
    disp = njit(boundscheck=True, nogil=True, error_model="numpy")(copy)
    seen[key] = disp
    for name in py.__code__.co_names:
        g = glb.get(name)
        if isinstance(g, CPUDispatcher) and getattr(g.py_func, "__module__", "") == module:
            glb[name] = _boundschecked(g, seen)
    _BC[key] = disp
    return disp


def checked_jit(fn=None, **kw):
    """The loop's ``jit`` in a bounds-checked loop module: numba's njit without a cache (the module is built
    for one check), with ``boundscheck=True`` (the loop's own indexing is checked as well)."""
    from numba import njit

    opts = {"nogil": True, "error_model": "numpy", "boundscheck": True}
    return njit(**opts)(fn) if fn is not None else njit(**opts)


# ---------------------------------------------------------------------------------------- the battery
def check_file(path: str | Path) -> list[Finding]:
    """The battery for every scheme a scheme file registers (the file is imported first)."""
    from ..schemes.registry import load_plugin, registered

    p = Path(path)
    if not p.is_file():
        return [Finding(False, f"{path}: no such scheme file")]
    before = set(registered())
    try:
        load_plugin(p)
    except ModelError as exc:
        return [Finding(False, str(exc))]
    mine = [sc for name, sc in registered().items() if _defined_in(sc, p.resolve()) or name not in before]
    if not mine:
        return [
            Finding(False, f"{path}: registers no scheme: call schemes.register(Scheme(...)) at the end of the file")
        ]
    out: list[Finding] = []
    for sc in mine:
        out += check_scheme(sc, str(p))
    return out


def _defined_in(sc: Scheme, path: Path) -> bool:
    code = getattr(getattr(sc.law, "py_func", sc.law), "__code__", None)
    return code is not None and Path(code.co_filename).resolve() == path


def check_scheme(sc: Scheme, path: str) -> list[Finding]:
    """The battery for one registered scheme (``path``: its file, for the messages)."""
    from ..schemes.registry import legacy, resolve

    name = sc.name
    head = f"scheme {name}"
    files = {str(Path(path).resolve())}
    out: list[Finding] = []

    def fail(where: str, what: str, detail: str = "") -> None:
        out.append(Finding(False, f"{where}: {head}: {what}", detail))

    # 2. the parameter model
    if sc.params is not None:
        try:
            sc.params()
        except Exception as exc:
            fail(
                _where(sc.params),
                f"params: the defaults do not validate ({_first_line(exc)}): give every field "
                "a valid default (a case that names the scheme without its table gets them)",
            )
        for field, info in getattr(sc.params, "model_fields", {}).items():
            unit = (info.json_schema_extra or {}).get("unit") if isinstance(info.json_schema_extra, dict) else None
            if not info.description or unit is None:
                fail(
                    _where(sc.params),
                    f"params.{field}: no description or unit: give it "
                    "Field(..., description='...', json_schema_extra={'unit': '...'}) (cases/README.md shows them)",
                )
    law = resolve(sc.law)
    if legacy(law):
        fail(
            _where(law),
            "law: the round-2 form (13 arguments, returning (u, xcdot)) runs through a deprecated "
            "adapter without the guards; write law(P, step, terms, x, out) (README 'Write your own scheme')",
        )
        return out
    # 3. the declarations on two cases
    try:
        bound = _contexts(sc)
    except Exception as exc:
        exc = _own(exc)
        fail(_hook_where(sc, exc), f"{_hook_name(exc)}: {type(exc).__name__}: {_first_line(exc)}")
        return out
    for label, ctrl in bound:
        problem = _pack_problem(ctrl.P)
        if problem:
            fail(_where(sc.pack) if sc.pack else path, f"pack ({label}): {problem}")
        try:
            x0 = ctrl.initial_state(0.0, *_start(ctrl))
        except Exception as exc:
            fail(_where(sc.initial_state) if sc.initial_state else path, f"initial_state ({label}): {_own(exc)}")
            continue
        if not np.all(np.isfinite(x0)):
            fail(_where(sc.initial_state) if sc.initial_state else path, f"initial_state ({label}): not finite")
    if any(not f.ok for f in out):
        return out
    # 4. compile in the loop's types; 5. bounds; 6., 7. the outputs
    for label, ctrl in bound:
        problems = _run_battery(sc, ctrl, label, files, path)
        out += problems
        if problems:
            break
    if not out:
        checks = "defaults, declarations, compile, bounds (boundscheck), finite on healthy and faulty patterns, "
        checks += "signals written, within declared widths, inputs untouched, determinism"
        if sc.discrete is not None:
            checks += ", discrete update"
        out.append(Finding(True, f"{path}: {head}: passed ({checks}; 2 cases x 6 states)"))
    return out


def _start(ctrl) -> tuple[np.ndarray, np.ndarray]:
    r = ctrl.kin.reference.at(0.0)
    return r.q_d.copy(), r.eta_d.copy()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return " ".join(x.strip() for x in text[:3]) if text else type(exc).__name__


def _own(exc: BaseException) -> BaseException:
    """What the scheme's own code raised: the cause of the PluginError that names it for a run."""
    from ..errors import PluginError

    return exc.__cause__ if isinstance(exc, PluginError) and exc.__cause__ is not None else exc


def _hook_where(sc: Scheme, exc: BaseException) -> str:
    """The file and line in the scheme's own code where ``exc`` was raised (else its law's file)."""
    files = {getattr(getattr(f, "py_func", f), "__code__", None) for f in (sc.pack, sc.n_states, sc.initial_state)}
    names = {c.co_filename for c in files if c is not None}
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        if frame.filename in names:
            return f"{frame.filename}:{frame.lineno}"
    return _where(sc.law) if not isinstance(sc.law, str) else sc.name


def _hook_name(exc: BaseException) -> str:
    for frame in reversed(traceback.extract_tb(exc.__traceback__)):
        if frame.name in ("pack", "n_states", "initial_state", "signals") or not frame.filename.startswith(
            str(Path(__file__).resolve().parents[1])
        ):
            return frame.name
    return "declarations"


def _pack_problem(P, where: str = "P") -> str | None:
    """What the loop cannot take in ``pack``'s result: not a tuple, a list, an object, a non-contiguous array."""
    if not isinstance(P, tuple):
        return f"returned a {type(P).__name__}, not a tuple (a NamedTuple of numbers and arrays)"
    fields = getattr(P, "_fields", None) or [str(i) for i in range(len(P))]
    for f, v in zip(fields, P, strict=True):
        at = f"{where}.{f}"
        if isinstance(v, tuple):
            problem = _pack_problem(v, at)
            if problem:
                return problem
        elif isinstance(v, np.ndarray):
            if v.dtype.kind not in "fiub":
                return f"{at}: an array of {v.dtype}: use float64, int64 or bool"
            if not v.flags.c_contiguous:
                return f"{at}: not C-contiguous: use np.ascontiguousarray"
        elif not isinstance(v, bool | int | float | np.number):
            return f"{at} is a {type(v).__name__}: only numbers, numpy arrays and tuples of them reach the law"
    return None


def _run_battery(sc: Scheme, ctrl, label: str, files: set[str], path: str, full: bool = True) -> list[Finding]:
    """Checks 4-7 on one bound scheme: [] when everything holds.  ``full=False`` (a plug-in's first run):
    the compile, the bounds-checked run and the guards only (a test law may blow up on purpose)."""
    from ..schemes.registry import resolve

    law = resolve(sc.law)
    disc = resolve(sc.discrete) if sc.discrete is not None else None
    head = f"scheme {sc.name}"
    states = _states(ctrl)
    state = states[0]
    # 4. compile (in the loop's types) and 5. bounds: the bounds-checked copy first (it cannot corrupt memory)
    try:
        checked = _Call(ctrl, checked=True)
        for state in states:
            _, t, q, eta, xc, sigma, ubar = state
            checked.law(t, q, eta, xc, sigma, ubar)
            if disc is not None:
                checked.discrete(t, q, eta, xc)
    except Exception as exc:
        return [_compile_or_bounds_failure(exc, law, disc, files, head, path, ctrl, state)]
    f = _returns_value(boundschecked(law), law, head)
    if f is not None:
        return [f]
    call = _Call(ctrl)
    for state in states:
        if full:
            problem = _one_state(call, sc, ctrl, state, head, law, disc, label)
        else:
            problem = _guards_only(call, ctrl, state, law, disc, label)
        if problem is not None:
            return [problem]
    return []


def _guards_only(call: _Call, ctrl, state, law, disc, label: str) -> Finding | None:
    """A plug-in's first run: no write past a declared width (the loop's guard cells) at one state."""
    what, t, q, eta, xc, sigma, ubar = state
    info = call.law(t, q, eta, xc, sigma, ubar)[3]
    if int(info[0]) == _E_LAW_WRITE:
        return Finding(False, f"{_where(law)}: {write_reason(ctrl, int(info[1]), float(info[2]))} ({label}, {what})")
    if disc is not None:
        info = call.discrete(t, q, eta, xc)[1]
        if int(info[0]) == _E_LAW_WRITE:
            return Finding(False, f"{_where(disc)}: {write_reason(ctrl, 3, float(info[2]))} ({label}, {what})")
    return None


def _returns_value(compiled, law, head: str) -> Finding | None:
    """A law of the contract returns nothing (it writes out): one that returns a value was written for the old
    contract (``return u, xcdot``) or returns by mistake.  ``compiled``: the copy the battery compiled."""
    from numba import types

    for sig in compiled.nopython_signatures:
        rt = sig.return_type
        if rt != types.none:
            arity = f"a tuple of {len(rt)}" if isinstance(rt, types.BaseTuple) else f"a {rt}"
            return Finding(
                False,
                f"{_return_line(law)}: {head}: law: returns {arity}; the law writes out.u, out.dx and "
                "out.sig and returns nothing (return u, xcdot was the round-2 form)",
            )
    return None


def _return_line(fn) -> str:
    """``file:line`` of the first ``return <value>`` in a function's source (else its definition)."""
    py = getattr(fn, "py_func", fn)
    try:
        lines, first = inspect.getsourcelines(py)
        path = inspect.getsourcefile(py)
    except (TypeError, OSError):
        return _where(fn)
    for i, line in enumerate(lines):
        if re.match(r"\s*return\s+[^\s#]", line):
            return f"{path}:{first + i}"
    return _where(fn)


def _compile_or_bounds_failure(exc, law, disc, files, head, path, ctrl, state) -> Finding:
    from numba.core.errors import TypingError

    msg = str(exc)
    if isinstance(exc, TypingError):
        where = _user_line(msg, files) or _name_line(msg, law, disc) or _where(law)
        reason = _numba_reason(msg)
        fn = "discrete" if disc is not None and _fn_name(disc) in msg and _fn_name(law) not in msg else "law"
        return Finding(False, f"{where}: {head}: {fn}: numba TypingError: {reason} ({_typing_hint(reason)})", msg)
    if isinstance(exc, IndexError):
        fn, line = _locate_in_python(ctrl, state, law, disc, files)
        where = line or _where(law)
        return Finding(
            False,
            f"{where}: {head}: {fn}: an index out of bounds (numba boundscheck): {msg}; a law "
            "reads and writes only its own x, out.u, out.dx and out.sig (their declared sizes)",
        )
    fn, line = _locate_in_python(ctrl, state, law, disc, files)
    return Finding(False, f"{line or _where(law)}: {head}: {fn}: raised {type(exc).__name__}: {_first_line(exc)}")


def _locate_in_python(ctrl, state, law, disc, files) -> tuple[str, str | None]:
    """Run the law (then the discrete update) once in Python on the state that failed, where numpy raises at the
    offending line: ("law" or "discrete", "file:line" or None)."""
    from ..jit.packed import new_cache
    from ..jit.refs import to_ref
    from ..schemes.api import Out, Step, Terms
    from .engine import compiled_spec, law_buffers

    spec = compiled_spec(ctrl)
    _, t, q, eta, xc, sigma, ubar = state
    nk = ctrl.kin.n_states
    bufs = law_buffers(spec)
    nw, no, ns = ctrl.chain.n_wheels, ctrl.n_own, spec.n_sig - spec.n_kin_sig
    info = np.zeros(4)
    C = to_ref(new_cache(ctrl.chain.n))  # refs, as in the loop: the kernels the law calls are typed as there
    kin = (to_ref(spec.kin), to_ref(spec.ref), C, xc[:nk].copy(), np.zeros(1))
    step = Step(float(t), q.copy(), eta.copy(), sigma, ubar, to_ref(spec.chain), info, kin)
    # terms of the right shapes (not the engine's values: only the offending line is sought here)
    MB = np.zeros((2, nw))
    MB[0, 0::2] = MB[1, 1::2] = 1.0
    terms = Terms(np.array([0.1, 0.2]), MB, np.zeros(2), np.array([0.01, -0.02]))
    x = xc[nk:].copy()
    x.setflags(write=False)
    for fn, call in (
        ("law", lambda: law.py_func(spec.P, step, terms, x, Out(bufs[1][:nw], bufs[2][:no], bufs[3][:ns]))),
        ("discrete", lambda: disc.py_func(spec.P, step, bufs[4][:no])),
    ):
        if fn == "discrete" and disc is None:
            continue
        try:
            call()
        except Exception as exc:
            for frame in reversed(traceback.extract_tb(exc.__traceback__)):
                if str(Path(frame.filename).resolve()) in files:
                    return fn, f"{frame.filename}:{frame.lineno}"
            return fn, None
    return "law", None


def _one_state(call: _Call, sc: Scheme, ctrl, state, head, law, disc, label) -> Finding | None:
    """Checks 6 and 7 at one state."""
    what, t, q, eta, xc, sigma, ubar = state
    at = f"{label}, {what}"
    q0, eta0, xc0 = q.copy(), eta.copy(), xc.copy()
    u, dx, sig, info, _row, _bufs = call.law(t, q, eta, xc, sigma, ubar)
    lw = _where(law)
    if int(info[0]) == _E_LAW_WRITE:
        return Finding(False, f"{lw}: {write_reason(ctrl, int(info[1]), float(info[2]))} ({at})")
    if int(info[0]) == _E_LAW_NONFINITE:  # the loop's own check of the command (fast.loop._law)
        j = int(info[2])
        return Finding(
            False,
            f"{lw}: {head}: law: out.u[{j}] is {float(info[3])} ({at}): the outputs must be finite on healthy "
            "and faulty patterns",
        )
    widths = ctrl.widths
    names = [n for n, w in widths.items() for _ in range(w)]
    if int(info[0]) == _E_LAW_SIGNAL:  # the loop's own check of a logged signal (fast.loop._contract_law)
        j = int(info[2])
        return Finding(
            False,
            f"{lw}: {head}: law: out.sig[{j}] ({names[j]}) is {float(info[3])} ({at}): the outputs must be finite "
            "on healthy and faulty patterns",
        )
    if info[0] != 0:
        return Finding(
            False, f"{lw}: {head}: law: stopped the run (error code {int(info[0])}) at a regular state ({at})"
        )
    if not (np.array_equal(q, q0) and np.array_equal(eta, eta0) and np.array_equal(xc, xc0)):
        return Finding(False, f"{lw}: {head}: law: changed its inputs (step.q, step.eta): a law only reads them ({at})")
    unwritten = sorted({names[i] for i in range(len(names)) if sig[i] == _SENTINEL})
    if unwritten:
        return Finding(
            False,
            f"{lw}: {head}: law: declared signal(s) {', '.join(unwritten)} not written "
            f"into out.sig ({at}): write every declared value at every call (the engine logs what it needs)",
        )
    for arr, name in ((u, "out.u"), (dx, "out.dx"), (sig, "out.sig")):
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            which = f" ({names[bad]})" if name == "out.sig" else ""
            return Finding(
                False,
                f"{lw}: {head}: law: {name}[{bad}]{which} is {arr[bad]} ({at}): the outputs must be "
                "finite on healthy and faulty patterns",
            )
    again = call.law(t, q, eta, xc, sigma, ubar)
    for a, b, name in ((u, again[0], "out.u"), (dx, again[1], "out.dx"), (sig, again[2], "out.sig")):
        if not np.array_equal(a, b, equal_nan=True):
            return Finding(
                False,
                f"{lw}: {head}: law: not deterministic: two calls on the same inputs differ in "
                f"{name} ({at}): keep no state outside x (globals, P's arrays written in the law)",
            )
    if disc is not None:
        x1, info, _ = call.discrete(t, q, eta, xc)
        dw = _where(disc)
        if int(info[0]) == _E_LAW_WRITE:
            return Finding(False, f"{dw}: {write_reason(ctrl, int(info[1]), float(info[2]))} ({at})")
        if info[0] != 0:
            return Finding(
                False, f"{dw}: {head}: discrete: stopped the run (code {int(info[0])}) at a regular state ({at})"
            )
        if not np.all(np.isfinite(x1)):
            return Finding(False, f"{dw}: {head}: discrete: the state is not finite after the update ({at})")
        x2, _, _ = call.discrete(t, q, eta, xc)
        if not np.array_equal(x1, x2, equal_nan=True):
            return Finding(False, f"{dw}: {head}: discrete: not deterministic ({at})")
    return None


_E_LAW_WRITE = 16  # jit.packed.E_LAW_WRITE (not imported: numba is loaded only when a check runs)
_E_LAW_NONFINITE = 18  # jit.packed.E_LAW_NONFINITE
_E_LAW_SIGNAL = 19  # jit.packed.E_LAW_SIGNAL


# ---------------------------------------------------------------------------------------- a plug-in's first run
_CHECKED: set[str] = set()
_CHECKED_LOCK = threading.Lock()


def ensure_checked(ctrl) -> None:
    """Before a plug-in scheme's first run: the bounds-checked battery (checks 5-7) on the case's own chain,
    controller and table, once per version of the scheme's file (recorded in the cache directory).  Raises
    :class:`~ftcreport.errors.ModelError` with the first failure's line."""
    from ..schemes.registry import built_in, resolve

    sc = ctrl.scheme
    if sc.name in built_in():
        return
    law = resolve(sc.law)
    src = inspect.getsourcefile(law.py_func) or ""
    try:
        digest = hashlib.sha256(Path(src).read_bytes()).hexdigest()[:20]
    except OSError:
        digest = "unreadable"
    key = f"{sc.name}-{digest}-{ctrl.chain.n}-{type(ctrl.kin).__name__}"
    with _CHECKED_LOCK:
        if key in _CHECKED:
            return
        record = _record_dir() / f"{key}.ok"
        if record.exists():
            _CHECKED.add(key)
            return
        files = {str(Path(src).resolve())}
        from ..schemes.registry import legacy

        if not legacy(law):
            problems = _run_battery(sc, ctrl, f"{ctrl.chain.n} robots", files, src, full=False)
            if problems:
                raise ModelError(
                    problems[0].message + " (its first run's check; ftcreport schemes check FILE runs them all)"
                )
        try:
            record.parent.mkdir(parents=True, exist_ok=True)
            record.write_text("checked\n")
        except OSError:
            pass  # a read-only cache: checked again next time
        _CHECKED.add(key)


def _record_dir() -> Path:
    from .engine import _cache_dir

    return _cache_dir() / "checked"  # beside the generated loops (the user cache directory)
