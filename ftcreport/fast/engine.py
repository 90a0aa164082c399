r"""The compiled engine: the one simulation loop (ftcreport/fast/loop.py on ftcreport.fast.kernels).

:func:`compiled_spec` reads a controller built by the Python faces (the classes of
:mod:`ftcreport.control`, a registered scheme's ``SchemeController``) into the plain
arrays the kernels take, or returns None when the controller has no compiled
counterpart: :func:`ftcreport.sim.simulate` then refuses it (issue 17: there is no
Python loop; a new law is written as a scheme).  :func:`simulate_compiled` runs the
steps (fault sampling, noise, checks, logging, RK4, ROS2 or ETD2, discrete updates)
and builds the :class:`~ftcreport.sim.Run`; the signals that are plain functions of
the logged state (switching costs, adaptive weights, the observer's P) are computed
here, vectorized, from the log.

The loop runs in chunks of about 1 % of the steps so that the progress
callback is called every ~1 % of the run.  numba compiles the kernels
on first use and caches the machine code in the user's cache directory
(:mod:`ftcreport.paths`): a fresh install builds the cache on its first run (:func:`ftcreport.sim.warm_up` does it
explicitly and reports the time).
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time as _time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

from ..errors import (
    articulation_reason,
    bound_reason,
    chained_reason,
    kappa_reason,
    nonfinite_reason,
    reference_articulation_reason,
    reference_speed_reason,
    step_growth_reason,
    step_words,
    trial_stage_reason,
    two_link_reason,
    with_step,
)
from ..model.kernels import kernel_ref, packed
from ..schemes.api import GUARD, N_GUARD, TERMS_MODES
from ..schemes.controller import SchemeController
from . import kernels as F
from .compiling import engine_stamp
from .drive import motor_state_count
from .integrators import AUTO_METHODS, METHOD_CODES

__all__ = ["Spec", "compiled_spec", "loop_for", "simulate_compiled"]

NAN = float("nan")


class Spec(NamedTuple):
    """Everything the kernels need of a controller (a scheme bound to a case: ftcreport.schemes)."""

    kin: F.Kin
    ref: F.Ref
    law: object  # the scheme's compiled law (ftcreport.schemes.api)
    disc: object  # its discrete update
    P: tuple  # its packed parameters
    chain: F.Chain
    n_sig: int  # the logged signals: the kinematic ones, then the law's
    controller: SchemeController
    start: bool = False  # the discrete update also runs at t0, before the first step
    terms: int = 0  # how the matched terms reach the law (ftcreport.schemes.api.TERMS_MODES)
    n_kin_sig: int = 0  # the kinematic signals' count (they come first in the signal row)


def _chain(params) -> F.Chain:
    return packed(params)  # Chain.params is already the kernels' tuple (model.kernels.make_params)


def compiled_spec(controller) -> Spec | None:
    """The kernels' description of a controller, or None if it has no compiled counterpart.

    A controller is a scheme bound to a case (:class:`ftcreport.schemes.SchemeController`: a plug-in's, or
    a built-in scheme's face): its scheme gives the law, the discrete update and how the terms reach the
    law; the kinematic controller and its reference give their packed kernels (``kin.packed(h)``,
    ``reference.packed()``), or None when either has none.
    """
    from ..schemes.registry import resolve

    if not isinstance(controller, SchemeController):
        return None
    kin_obj = controller.kin
    ref_obj = getattr(kin_obj, "reference", None)
    if not hasattr(kin_obj, "packed") or not hasattr(ref_obj, "packed"):
        return None
    ref = ref_obj.packed()  # the faces build (and keep) the kernels' tuples
    kin = kin_obj.packed(float(controller.h))
    if ref is None or kin is None:
        return None
    scheme = controller.scheme
    law = resolve(scheme.law)
    disc = resolve(scheme.discrete) if scheme.discrete is not None else _no_discrete(law)
    n_kin = 4 + len(kin_obj.z_names) + controller.chain.n_q + 2  # eta_c, eta_c_dot, z, q_d, eta_d
    n_sig = n_kin + sum(controller.widths.values())
    pc = _chain(controller.chain.params)
    return Spec(
        kin, ref, law, disc, controller.P, pc, n_sig, controller, bool(scheme.start), TERMS_MODES[scheme.terms], n_kin
    )


def _no_discrete(law):
    """The discrete update of a scheme without one (the round-2 form's for a round-2 law)."""
    from ..schemes.kernels import legacy_no_discrete, no_discrete
    from ..schemes.registry import legacy

    return legacy_no_discrete if legacy(law) else no_discrete


def law_buffers(spec: Spec) -> tuple:
    """The buffers a law writes (the loop's ``P[1]``): ``(k_v, u, dx, sig, x, fresh)``.

    u (2n), dx and x (the scheme's own states), sig (its declared signals), each followed by
    ``N_GUARD`` cells holding ``GUARD``, which the loop checks after every call of the law (and of
    the discrete update, for x); ``fresh`` flags a kinematic evaluation by the law itself.
    """
    c = spec.controller

    def guarded(n: int) -> np.ndarray:
        buf = np.full(n + N_GUARD, GUARD)
        buf[:n] = 0.0
        return buf

    n_own_sig = spec.n_sig - spec.n_kin_sig
    nw, n = c.chain.n_wheels, c.n_own
    return (float(c.k_v), guarded(nw), guarded(n), guarded(n_own_sig), guarded(n), np.zeros(1))


def _law_input(spec: Spec, bufs: tuple) -> tuple:
    """The loop's ``P``: the scheme's parameters and its law buffers."""
    return (spec.P, bufs)


def wheel_speeds_rows(chain, Q: np.ndarray, ETA: np.ndarray) -> np.ndarray:
    """Wheel speeds (K, 2n) at K states: the compiled reduced model's Bbar(q)^T eta, row by row."""
    Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, chain.n_q)
    ETA = np.ascontiguousarray(ETA, dtype=float).reshape(-1, 2)
    return F.wheel_speeds_rows(kernel_ref(chain.params), Q, ETA)  # a ref: the loop's compile of reduced


def input_matrices_rows(chain, Q: np.ndarray) -> np.ndarray:
    """Mbar1(q)^-1 Bbar(q), (K, 2, 2n), at K configurations: one compiled call (no per-row Python)."""
    Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, chain.n_q)
    return F.input_matrices_rows(kernel_ref(chain.params), Q)  # a ref: the loop's compile of reduced


# --------------------------------------------------------------------------- signals from the log
def _split_signals(
    spec: Spec, sg: np.ndarray, xc: np.ndarray, meas: np.ndarray, nq: int, costs: bool = True
) -> dict[str, np.ndarray]:
    """The controller's named signals (its ``signal_names``) from the compiled log.

    The kinematic signals and the law's (by their declared widths) are columns of the signal rows;
    the scheme's derived signals (``Scheme.derived``: the switching costs, the adaptive weights, the
    estimators' covariance) are computed from the logged own states.  ``costs=False`` leaves out
    what no metric reads, so the metric stream does not compute it at every step.
    """
    c = spec.controller
    nz = len(c.kin.z_names)
    cols = {"eta_c": (0, 2), "eta_c_dot": (2, 4), "z": (4, 4 + nz), "q_d": (4 + nz, 4 + nz + nq)}
    cols["eta_d"] = (4 + nz + nq, 6 + nz + nq)
    k = 6 + nz + nq
    for name, width in c.widths.items():
        cols[name] = (k, k + width)
        k += width
    wanted = set(c.signal_names)
    out: dict[str, np.ndarray] = {name: sg[:, a:b].copy() for name, (a, b) in cols.items() if name in wanted}
    out |= c.derived_signals(xc[:, c.kin.n_states :], meas, costs)
    return {name: out[name] for name in c.signal_names if name in out}


# --------------------------------------------------------------------------- errors
def _how(settings, used: str | None = None) -> str:
    """The step a reason names: dt and the method (fixed), or the method used and its tolerances."""
    if settings.method in AUTO_METHODS:
        return step_words(settings.dt, used or settings.method, settings.rtol, settings.atol)
    return step_words(settings.dt, settings.method)


def _message(info: np.ndarray, t: float, settings, ref: F.Ref, how: str = "") -> tuple[str, str]:
    """(status, reason) of a kernel error code (one wording per stop: ftcreport.errors)."""
    how = how or _how(settings)
    code = int(info[0])
    a, b, c = (float(v) for v in info[1:4])
    if code == F.E_STATE_SINGULAR:
        return "singular", articulation_reason(int(a), b, settings.singularity_margin)
    if code in (F.E_NONFINITE_STATE, F.E_NONFINITE_DERIV):
        reason = nonfinite_reason("state" if code == F.E_NONFINITE_STATE else "control or derivative", a)
        return "diverged", with_step(reason, how)
    if code == F.E_SPEED:
        return "diverged", with_step(bound_reason("velocity", [a, b], settings.max_speed), how)
    if code == F.E_POSITION:
        return "diverged", with_step(bound_reason("position", [a, b], settings.max_position, " m"), how)
    if code == F.E_TWO_LINK_ETH:
        return "singular", two_link_reason(f"heading error e_theta of robot {ref.n}", a)
    if code == F.E_TWO_LINK_PHI:
        return "singular", two_link_reason("articulation angle theta_1 - theta_2", a)
    if code == F.E_CHAINED_THN:
        return "singular", chained_reason(f"theta_{ref.n}", a, " in its frame")
    if code == F.E_CHAINED_ART:
        return "singular", chained_reason(f"theta_{int(a) + 1} - theta_{int(a) + 2}", b)
    if code == F.E_KAPPA:
        return "singular", kappa_reason(a)
    if code == F.E_REF_SPEED:
        return "error", reference_speed_reason(a, int(b), c, ref.min_speed)
    if code == F.E_REF_ART:
        return "error", reference_articulation_reason(a, int(b), c, ref.max_art)
    if code == F.E_UKF:
        from .ukf import ukf_message

        reason = f"the UKF stopped at t = {b:.6g} s: {ukf_message(int(a))}"
        return "diverged", with_step(reason, how)
    if code == F.E_STEP_GROWTH:
        from ..runs import GROWTH_FACTOR, GROWTH_STEPS

        return "step_unstable", step_growth_reason(a, b, c, GROWTH_STEPS, GROWTH_FACTOR, how)
    return "error", f"compiled engine: unknown error code {code} at t = {t:.6g} s"


def _stop(
    info: np.ndarray, where: int, t_state: float, t_next: float, settings, ref: F.Ref, spec: Spec | None = None
) -> tuple[str, str, float]:
    """(status, reason, t_end) of a fixed-step stop: a failed trial stage is a step problem, not a singularity
    (until the re-check says otherwise, :func:`_relabel`); a scheme that wrote past its buffers is an error
    naming the scheme and the buffer (ftcreport.schemes.api)."""
    if int(info[0]) == F.E_LAW_WRITE and spec is not None:
        from ..schemes.controller import write_reason

        return "error", write_reason(spec.controller, int(info[1]), float(info[2])), float(info[2])
    how = _how(settings)
    if int(info[0]) == F.E_STEP_JUMP:
        from ..runs import step_jump_words

        words = step_jump_words(int(info[1]), float(info[2]), float(info[3]))
        return "step_unstable", trial_stage_reason(t_state, words, how, settings.method, stage=False), t_state
    if where == F.AT_TRIAL and int(info[0]) not in (F.E_REF_SPEED, F.E_REF_ART):
        _, detail = _message(info, t_state, settings, ref)
        return "step_unstable", trial_stage_reason(t_state, detail, how, settings.method), t_state
    if where == F.AT_STATE:
        return (*_message(info, t_state, settings, ref), t_state)
    return (*_message(info, t_next, settings, ref), t_next)


# --------------------------------------------------------------------------- the loop
def _no_motors():
    from .motor import Motors

    z = np.zeros(0)
    return Motors(z, z, z, z, z, z, z, z, z, z)


def _no_drive():
    from .drive import DRIVER_STATIC, Drive

    z = np.zeros(0)
    return Drive(DRIVER_STATIC, z, z, z, z, z, z, z, z, z, z, z, z, NAN)


def _initial_currents(loop, spec: Spec, plant, mo, dr, sigma, ubar, fm, t0: float, x: np.ndarray, npl: int):
    """The motor states at t0 (currents, drive states): quasi-static for the first command (its wheel
    torque is the command; fast.drive.initial_motor_states)."""
    from .drive import initial_motor_states

    nq = plant.chain.n_q
    pc = spec.chain
    info = np.zeros(4)
    q, eta = x[:nq], x[nq : nq + 2]
    with _compiling(loop, loop.first_law):
        u = loop.first_law(_law_input(spec, law_buffers(spec)), spec.kin, spec.ref, pc, t0, q, eta, x[npl:], sigma,
                           ubar, info, np.zeros(0))  # fmt: skip
    if info[0] != 0 or not np.all(np.isfinite(u)):
        return np.zeros(npl - nq - 2)  # the loop reports the law's failure at its first step
    sat = plant.saturation
    tau_c = sigma * (u if sat is None else np.clip(u, -sat, sat)) + ubar
    omega = F.reduced(kernel_ref(plant.chain.params), q, eta)[3].T @ eta
    return initial_motor_states(mo, dr, tau_c, omega, fm)


def _cache_dir() -> Path:
    """Where the generated loop modules live: ``ftcreport.paths.cache_dir("loops")`` (the user's cache
    directory or ``$FTCREPORT_CACHE``, keyed by versions and CPU), never inside the installed package."""
    from ..paths import cache_dir

    return cache_dir("loops")


_LOOPS: dict[tuple, object] = {}
_LOOPS_LOCK = threading.Lock()


def loop_for(law, disc, motors: bool = True, sampled: bool = True, terms: int = 0, checked: bool = False):
    """The compiled loop (``run_steps`` of ftcreport.fast.loop) bound to a scheme's law and discrete update.

    ``motors``, ``sampled``: the loop's variant.  A variant without one of them does not compile its
    code at all (numba prunes the branches on these constants before typing).  Both integrators are
    always in (RK4 and ROS2 share the stages; a batch of RK4 and ROS2 cases needs one loop).
    ``terms``: how the matched terms reach the law (ftcreport.schemes.api.TERMS_MODES), a constant of
    the law's loop.  ``checked``: the bounds-checked loop of ``ftcreport schemes check`` (``law`` and
    ``disc`` are then bounds-checked copies, ftcreport.schemes.check.boundschecked; nothing is cached).

    The loop's module is written once per (law, discrete update) from ftcreport/fast/loop.py, with
    its LOOP-BINDING line importing them, and imported under a name that is the same in every
    process, so numba's cache of it is found by the next run.  The module is written again when
    the template or the law's source file changes (its text carries a hash of both), which also
    renews numba's cache: numba alone does not see a change in a function another file calls.
    """
    key = (law, disc, bool(motors), bool(sampled), int(terms), bool(checked))
    loop = _LOOPS.get(key)
    if loop is not None:
        return loop
    with _LOOPS_LOCK:  # threads (a Dask worker's) load each loop once, never half-loaded
        loop = _LOOPS.get(key)
        if loop is None:
            loop = _LOOPS[key] = _load_loop(*key)
    return loop


#: the template's lines that fast.engine.loop_for rewrites in each generated loop module
BINDING = "LAW, DISC = no_law, no_discrete  # LOOP-BINDING"
TERMS_LINE = "TERMS_MODE = 0  # LOOP-TERMS"
LEGACY_LINE = "LEGACY = False  # LOOP-LEGACY"
VARIANT = "MOTORS, SAMPLED = True, True  # LOOP-VARIANT"


def _load_loop(law, disc, motors: bool, sampled: bool, terms: int = 0, checked: bool = False):
    """Write (if needed) and import the loop module bound to (law, disc) and the variant."""
    import hashlib
    import importlib.util
    import inspect
    import sys

    from . import loop as template

    text = Path(template.__file__).read_text()
    for line in (BINDING, TERMS_LINE, LEGACY_LINE, VARIANT):
        if line not in text:
            raise RuntimeError(f"ftcreport/fast/loop.py: the line {line!r} is missing")
    # the text carries a hash of the law's and discrete update's files and of every compiled source of
    # the package (compiling.engine_stamp, which also stamps every kernel's numba cache entry)
    shared = engine_stamp()[:12]
    parts = []
    for fn, alias in ((law, "LAW"), (disc, "DISC")):
        py = fn.py_func
        source = Path(inspect.getfile(py)).read_bytes()
        parts.append((py.__module__, py.__qualname__, alias, hashlib.sha1(source).hexdigest()[:12]))
    if checked:  # the bounds-checked copies (memoized: the same objects as the caller's)
        lines = ["from ftcreport.schemes.check import boundschecked"]
        lines += [f"from {m} import {q} as _{a}0  # source {h}" for m, q, a, h in parts]
        lines += [f"{a} = boundschecked(_{a}0)" for _m, _q, a, _h in parts]
    else:
        lines = [f"from {m} import {q} as {a}  # source {h}" for m, q, a, h in parts]
    lines.append(f"# ftcreport sources {shared}")
    text = text.replace(BINDING, "\n".join(lines))
    from ..schemes.registry import legacy

    text = text.replace(TERMS_LINE, f"TERMS_MODE = {int(terms)}")
    text = text.replace(LEGACY_LINE, f"LEGACY = {legacy(law)}")
    variant = f"MOTORS, SAMPLED = {motors}, {sampled}"
    if checked:  # every function of the module compiled with bounds checks, not cached
        variant += "\nfrom ftcreport.schemes.check import checked_jit as jit  # noqa: E402"
    text = text.replace(VARIANT, variant)
    tag = "__".join(f"{m}.{q}" for m, q, _, _ in parts)
    tag += "__" + "".join(c for c, on in zip("ms", (motors, sampled), strict=True) if on) + ("", "o", "n")[terms]
    tag += "_bc" if checked else ""
    name = "ftcreport_loop_" + "".join(c if c.isalnum() else "_" for c in tag)
    folder = _cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    if not path.exists() or path.read_text() != text:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)  # atomic: a concurrent process sees the old or the new file, whole
    module = sys.modules.get(name)
    if module is None or getattr(module, "__file__", None) != str(path):
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        sys.modules[name] = module  # only once loaded: numba's cache imports it by name
    return module


@contextlib.contextmanager
def _compiling(loop, entry) -> Iterator[None]:
    """Around a call of a loop's entry point: its first call in this process compiles it (or loads it
    from numba's cache) under a file lock beside its module, so that two processes that need the
    same loop (a batch's workers) compile it once: the second waits and then loads the first's."""
    if entry in _READY or fcntl is None:  # already loaded here (or no POSIX locks: compile twice)
        yield
        return
    t0 = _time.perf_counter()
    with open(Path(loop.__file__).with_suffix(".lock"), "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
    if entry.signatures:
        _READY.add(entry)  # numba's signature list costs 0.3 ms to read: once per entry point
    _FIRST_CALLS[0] += _time.perf_counter() - t0


_FIRST_CALLS = [0.0]  # seconds in the entry points' first calls in this process (compile or cache load)


_READY: set = set()  # the loops' entry points compiled or loaded in this process


@contextlib.contextmanager
def _law_errors(spec: Spec) -> Iterator[None]:
    """A plug-in law that raises inside the compiled loop (numba's shape checks on a slice assignment, a
    bounds-checked compile) is the scheme's error, naming it (:class:`~ftcreport.errors.ModelError`)."""
    try:
        yield
    except (ValueError, IndexError, ZeroDivisionError, AssertionError, TypeError) as exc:
        from ..schemes.registry import built_in

        name = spec.controller.scheme.name
        if name in built_in():
            raise
        from ..errors import ModelError

        raise ModelError(
            f"scheme {name}: its compiled law or discrete update raised {type(exc).__name__}: {exc} "
            "(ftcreport schemes check FILE runs it with bounds checks and names the line)"
        ) from exc


def _timing_mark(event: str) -> None:
    """``FTCREPORT_TIMING=path``: append one line when this process first reaches ``event``.

    ``loop_call``: the loop's first call (before it, imports, the case, the references' checks, the
    controller); ``first_chunk``: its return (the loop compiled or loaded, the first chunk simulated).
    The line holds the wall clock (``time.time()``: whoever started the process knows when) and the
    process's CPU time so far (``time.process_time()``, interpreter and CLI startup included); read by
    benchmarks/run.py ``--only-first-result`` (issue 20 item 1)."""
    path = os.environ.get("FTCREPORT_TIMING")
    if not path or event in _MARKED:
        return
    _MARKED.add(event)
    with open(path, "a") as fh:
        fh.write(f'{{"event": "{event}", "time": {_time.time()!r}, "cpu": {_time.process_time()!r}}}\n')


_MARKED: set = set()


class _Loop:
    """The arrays one run's loop reads and carries across its chunks (both step modes and the re-check)."""

    def __init__(self, spec: Spec, plant, q0, eta0, settings, starts: np.ndarray, n_noise: int) -> None:
        from ..runs import GROWTH_FACTOR, GROWTH_FLOOR, GROWTH_STEPS, GROWTH_TOTAL, JUMP_FRACTION, JUMP_MARGINS

        controller = spec.controller
        chain = plant.chain
        self.spec, self.plant, self.settings = spec, plant, settings
        self.nq, self.nw, self.nc = nq, nw, nc = chain.n_q, chain.n_wheels, int(controller.n_states)
        t0 = float(starts[0])
        # fault values held over each segment: the schedule is piecewise constant between its event times
        table = [plant.faults.at(float(t)) for t in starts]
        self.fsig = np.array([np.asarray(s, float) for s, _ in table]).reshape(-1, nw)
        self.fubar = np.array([np.asarray(u, float) for _, u in table]).reshape(-1, nw)
        # one draw per step (fixed) or per tick of the clock dt (error-controlled), in order (seeded)
        if plant.noisy:
            rng = np.random.default_rng(plant.seed)
            self.noise = rng.standard_normal((n_noise, nq + 2)) * plant.noise_std
        else:
            self.noise = np.zeros((1, nq + 2))
        # DC motors: their currents and drive states follow eta in the state, their fault tables follow
        # the segments
        if plant.motors is not None:
            from ..model.actuators import pack as pack_motors
            from ..model.actuators import pack_drive

            self.mo = pack_motors(plant.motors, chain.n)
            self.dr = pack_drive(getattr(plant, "drive", None), plant.motors, chain.n)
            self.fmot = np.array([plant.faults.motor(float(t)) for t in starts], dtype=float).reshape(-1, nw, 4)
        else:
            self.mo = _no_motors()
            self.dr = _no_drive()
            self.fmot = np.zeros((len(starts), 0, 4))
        self.nm = nm = motor_state_count(self.mo.R_a.shape[0], self.dr.kind)  # the currents and the drives' states
        self.npl = npl = nq + 2 + nm
        # ETD2 is compiled in the motor variant only (it needs no motors: with none its block is eta's)
        motor_loop = nm > 0 or settings.method in ("etd2", "etd2ec")
        self.loop = loop = loop_for(
            spec.law, spec.disc, motors=motor_loop, sampled=settings.sample_time is not None, terms=spec.terms
        )
        self.P = _law_input(spec, law_buffers(spec))  # the scheme's parameters and the buffers its law writes
        xc0 = np.asarray(controller.initial_state(t0, q0, eta0), dtype=float).reshape(nc)
        self.x = np.concatenate((q0, eta0, np.zeros(nm), xc0))
        self.info = np.zeros(4)
        if spec.start:  # the first command of a sampled scheme, at t0 (h = 0: no filter step)
            with _compiling(loop, loop.first_discrete), _law_errors(spec):
                loop.first_discrete(self.P, spec.kin, spec.ref, spec.chain, t0, q0, eta0, self.x[npl:], self.info)
        if nm and self.info[0] == 0:
            self.x[nq + 2 : npl] = _initial_currents(
                loop, spec, plant, self.mo, self.dr, self.fsig[0], self.fubar[0], self.fmot[0], t0, self.x, npl
            )
        self.grow = np.zeros(3)  # step-growth detector state, carried across chunks
        self.growth = np.array(
            [
                GROWTH_FACTOR,
                GROWTH_STEPS,
                GROWTH_FLOOR,
                JUMP_FRACTION,
                math.sin(JUMP_MARGINS * settings.singularity_margin),
                GROWTH_TOTAL,
            ]
        )
        self.sat = NAN if plant.saturation is None else float(plant.saturation)
        self.diag = np.zeros(npl + nc)
        stiff = getattr(controller, "stiff_diagonal", None)
        if stiff is not None:
            self.diag[npl:] = np.asarray(stiff, dtype=float)
        self.lim = math.sin(settings.singularity_margin)
        self.pp = pp = _chain(chain.params)
        self.share = not plant.noisy and all(np.array_equal(a, b) for a, b in zip(pp, spec.chain, strict=True))
        # sampled control: [next sample time, last sample time, T_s, samples taken], the held u, rates, signals,
        # and a sampled PI drive's [next sample time, period] (fast.drive)
        ts = settings.sample_time
        self.hold_t = np.array([t0, NAN, NAN if ts is None else float(ts), 0.0, t0, self.dr.T_d])
        self.mbuf = np.zeros((int(settings.measurement_delay) + 1, nq + 2))  # the delayed measurements' ring
        self.u_h = np.zeros(0 if ts is None else nw)
        self.dx_h = np.zeros(nc)
        self.sig_h = np.zeros(spec.n_sig)
        self.v_h = np.zeros(0 if ts is None else self.mo.R_a.shape[0])  # the drives' inputs held by sampled control

    def buffers(self, rows: int) -> None:
        """The chunk buffers: every accepted step of a chunk is logged into them (``rows`` at most)."""
        nq, nw, nc, nm = self.nq, self.nw, self.nc, self.nm
        self.lq = np.full((rows, nq), np.nan)
        self.leta = np.full((rows, 2), np.nan)
        self.lu = np.full((rows, nw), np.nan)
        self.ltau = np.full((rows, nw), np.nan)
        self.lsig = np.full((rows, nw), np.nan)
        self.lubar = np.full((rows, nw), np.nan)
        self.lxc = np.full((rows, nc), np.nan)
        self.lia = np.full((rows, nm), np.nan)
        self.lmeas = np.full((rows if self.plant.noisy else 0, nq + 2), np.nan)
        self.lsg = np.full((rows, self.spec.n_sig), np.nan)
        self.lt = np.full(rows, np.nan)

    @property
    def bufs(self) -> tuple[np.ndarray, ...]:
        return (self.lt, self.lq, self.leta, self.lu, self.ltau, self.lsig, self.lubar, self.lxc, self.lmeas, self.lsg,
                self.lia)  # fmt: skip

    def carried(self) -> tuple[np.ndarray, ...]:
        """Copies of everything a chunk changes: a checkpoint the re-check restarts from."""
        return tuple(a.copy() for a in (self.x, self.grow, self.hold_t, self.u_h, self.dx_h, self.sig_h, self.v_h,
                                        self.mbuf))  # fmt: skip

    def restore(self, saved: tuple[np.ndarray, ...]) -> None:
        x, self.grow, self.hold_t, self.u_h, self.dx_h, self.sig_h, self.v_h, self.mbuf = (a.copy() for a in saved)
        self.x = x

    def steps(self, grid, fidx, noise, method: int, k0: int, k1: int, logged) -> tuple[int, int, int]:
        """run_steps over steps k0..k1 of ``grid``: (last step, rows logged, where); updates x."""
        spec, st = self.spec, self.settings
        # compiles the loop on its first use (fast.compiling); the law's errors name the scheme (_law_errors)
        with _compiling(self.loop, self.loop.run_steps), _law_errors(spec):
            self.x, k_last, li, where = self.loop.run_steps(
                self.P, spec.kin, spec.ref, spec.chain, self.pp,
                grid, fidx, self.fsig, self.fubar, noise, self.sat, self.diag, method, self.lim, st.max_speed,
                st.max_position, self.x, k0, k1, logged, 0,
                self.lq, self.leta, self.lu, self.ltau, self.lsig, self.lubar, self.lxc, self.lmeas, self.lsg, self.lt,
                spec.n_sig, self.info, self.share, self.grow, self.growth,
                self.lia, self.hold_t, self.u_h, self.dx_h, self.sig_h, self.mo, self.fmot, self.v_h, self.mbuf,
                self.dr,
            )  # fmt: skip
        return int(k_last), int(li), int(where)

    def auto_steps(self, events, fsig, fubar, fmot, noise, opt, ctl, rows: int) -> tuple[int, int]:
        """run_auto from t = ctl[0] (fast.loop: error-controlled steps): (rows logged, where); updates x."""
        spec, st = self.spec, self.settings
        with _compiling(self.loop, self.loop.run_auto), _law_errors(spec):
            self.x, li, where = self.loop.run_auto(
                self.P, spec.kin, spec.ref, spec.chain, self.pp,
                events, fsig, fubar, noise, self.sat, self.diag, self.lim, st.max_speed, st.max_position,
                self.x, opt, ctl, rows,
                self.lq, self.leta, self.lu, self.ltau, self.lsig, self.lubar, self.lxc, self.lmeas, self.lsg, self.lt,
                spec.n_sig, self.info, self.share, self.lia, self.hold_t, self.u_h, self.dx_h, self.sig_h, self.mo,
                fmot, self.v_h, self.mbuf, self.growth, self.dr,
            )  # fmt: skip
        return int(li), int(where)


def simulate_compiled(spec: Spec, plant, q0, eta0, settings, grid, log_idx, progress=None):
    """sim.simulate on the compiled kernels; returns a :class:`~ftcreport.sim.Run`.

    ``grid`` (the step boundaries) and ``log_idx`` (the logged steps) for a fixed-step method; both
    None for an error-controlled one (``SimSettings.method`` in fast.integrators.AUTO_METHODS).
    """
    if grid is None:
        return _simulate_auto(spec, plant, q0, eta0, settings, progress)
    from ..runs import Run

    n_steps = grid.shape[0] - 1
    is_logged = np.zeros(n_steps + 1, dtype=np.bool_)
    is_logged[log_idx] = True
    times = np.array(sorted(set(float(v) for v in plant.faults.times)), dtype=float)
    seg = np.searchsorted(times, grid, side="right")
    firsts = np.unique(seg, return_index=True)[1]
    fidx = np.searchsorted(np.unique(seg), seg).astype(np.int64)
    compile0 = _FIRST_CALLS[0]  # compile_time below
    L = _Loop(spec, plant, q0, eta0, settings, grid[firsts], n_steps + 1)
    steps_new = L.loop.run_steps not in _READY
    nq = L.nq
    # The kernels log every step of a chunk (about 1 % of the run) into chunk buffers; after each chunk
    # the light signals go to the full-rate metric stream and every signal of the logged steps
    # (log_every) to the saved log, so the heavy ones (xc, switching costs, weights) are never held
    # at full rate.
    chunk = max(1, n_steps // 100)
    L.buffers(chunk + 1)
    every_step = np.ones(n_steps + 1, dtype=np.bool_)
    method = METHOD_CODES[settings.method]
    stream: dict[str, np.ndarray] = {}  # preallocated for every step on the first chunk
    log_parts: list[list[np.ndarray]] = []
    si = 0
    k = 0
    status, reason = "ok", ""
    t_end = float(grid[0])
    checkpoints: list[tuple[int, tuple]] = []  # (step, carried state) at chunk starts: the re-check's restarts
    recheck = None
    wall0 = _time.perf_counter()
    first_s, chunks = 0.0, 0  # the first chunk's call (with the loop's compile or load when it is new here)
    if L.info[0] != 0:  # the first command failed (at t0, before any step)
        status, reason, t_end = _stop(L.info, F.AT_STATE, t_end, t_end, settings, spec.ref, spec)
    with np.errstate(all="ignore"):
        while status == "ok":
            k1 = min(k + chunk - 1, n_steps)
            if k == 0:
                _timing_mark("loop_call")
            checkpoints = _keep_checkpoints(checkpoints, k, L)
            k_last, li, where = L.steps(grid, fidx, L.noise, method, k, k1, every_step)
            if k == 0:
                _timing_mark("first_chunk")
                first_s = _time.perf_counter() - wall0
            chunks += 1
            if li:
                keep = is_logged[k : k + li]
                si = _collect(spec, plant, nq, li, keep, L.bufs, stream, si, n_steps + 1, log_parts)
            if L.info[0] != 0:
                status, reason, t_end = _stop(
                    L.info, where, float(grid[k_last]), float(grid[min(k_last + 1, n_steps)]), settings, spec.ref,
                    spec,
                )
                if status in ("step_unstable", "diverged"):  # does a smaller step remove the stop? (36 item 4)
                    code = int(L.info[0])
                    recheck = _recheck(L, grid, fidx, checkpoints, k_last)
                    if recheck["status"] not in ("ok", "singular"):  # it persists at dt/4: a second opinion
                        recheck["controlled"] = _controlled_recheck(L, grid, checkpoints, k_last, recheck["k_to"])
                    status, reason = _relabel(code, where, reason, recheck, settings, t_end)
                k = k_last
                break
            k = k_last
            t_end = float(grid[k])
            if k >= n_steps:
                break
            if progress is not None:
                progress(float(grid[k + 1]))
            k += 1
    wall = _time.perf_counter() - wall0
    meta = {"integrator": {"method": settings.method, "dt": settings.dt, "steps": int(k)}}
    if recheck is not None:  # what the run at dt/4 found (plain values: run metadata)
        meta["integrator"]["recheck"] = recheck
    meta["compile_time"] = _compile_time(compile0, wall, first_s, chunks, steps_new)
    return _finish(Run, spec, plant, settings, nq, stream, si, log_parts, status, reason, t_end, int(k), wall, meta,
                   progress)  # fmt: skip


def _compile_time(compile0: float, wall: float, first_s: float, chunks: int, new: bool) -> float:
    """Compiling or loading the loop: its entry points' first calls here since ``compile0``, less the first
    chunk's own simulation (estimated by the mean of the other chunks, which are about the same size)
    when the loop's stepping entry point was new here."""
    sim_first = (wall - first_s) / (chunks - 1) if chunks > 1 else 0.0
    return max(0.0, _FIRST_CALLS[0] - compile0 - (sim_first if new else 0.0))


def _finish(Run, spec, plant, settings, nq, stream, si, log_parts, status, reason, t_end, steps, wall, meta, progress):
    """The Run of a finished loop: the stream cut to its rows, the log joined and named."""
    if progress is not None:
        progress(t_end)
    # an error-controlled run's stream was grown by doubling: cut to its rows (a fixed run's fits)
    stream = {name: v[:si] if v.shape[0] <= si + 1 else v[:si].copy() for name, v in stream.items()}
    logs = _chunk_signals(spec, plant, nq, slice(None), _concat(log_parts)) if log_parts else {}
    t_log = logs.pop("t", np.zeros(0))
    t_stream = stream.pop("t", np.zeros(0))
    return Run(
        t=t_log,
        signals=logs,
        status=status,
        reason=reason,
        t_end=t_end,
        steps=steps,
        wall_time=wall,
        meta={
            "dt": settings.dt,
            "duration": settings.duration,
            "log_every": int(settings.log_every),
            "sample_time": settings.sample_time,
            "measurement_delay": int(settings.measurement_delay),
            "engine": "compiled",
        }
        | meta,
        t_stream=t_stream,
        stream=stream,
    )


# --------------------------------------------------------------------------- error-controlled runs
#: the opt codes of fast.loop.run_auto's method (-1: auto picks at t0)
_AUTO_CODES = {"auto": -1, "dopri5": 3, "ros2ec": 4, "etd2ec": 5}
_CODE_NAMES = {3: "dopri5", 4: "ros2ec", 5: "etd2ec"}


def _dwell(controller) -> tuple[int, float]:
    """(slot of the last switch's time in xc, T_min) of a switching scheme's dwell, or (-1, 0): its end is
    known from the controller's state, so a step lands on it (switching_select changes the model only
    once t - xc[tsw] >= T_min)."""
    slot = getattr(controller, "_tsw", None)
    T_min = getattr(controller, "T_min", None)
    if slot is None or T_min is None or float(T_min) <= 0.0:
        return -1, 0.0
    return int(slot), float(T_min)


def _simulate_auto(spec: Spec, plant, q0, eta0, settings, progress=None):
    """An error-controlled run (fast.loop.run_auto): chunks by time (1 % of the run, for the progress
    callback), each logged at every accepted step into buffers that the stream and the decimated log
    (every ``log_every``-th accepted step, and the last) take from, as for the fixed steps."""
    from ..limits import MAX_STEPS, MEMORY_BUDGET_BYTES
    from ..runs import Run

    t0, duration = float(settings.t0), float(settings.duration)
    t_end = t0 + duration
    times = np.array(sorted(set(float(v) for v in plant.faults.times)), dtype=float)
    events = times[(times > t0) & (times < t_end)]
    clock = float(settings.dt) if (plant.noisy or spec.start) else NAN  # noise draws and the UKF tick at dt
    n_ticks = math.floor(duration / settings.dt + 1e-9) + 2
    compile0 = _FIRST_CALLS[0]  # compile_time below
    L = _Loop(spec, plant, q0, eta0, settings, np.concatenate(([t0], events)), n_ticks)
    steps_new = L.loop.run_auto not in _READY
    nq = L.nq
    # the chunk buffers: about 4x the steps of 1 % of the run at the longest step, at most 32 MB
    row_bytes = 8 * (L.nc + spec.n_sig + 5 * L.nw + 2 * (L.nq + 2) + L.nm + 1)
    rows = max(64, min(math.ceil(duration / settings.dt / 100) * 4 + 8, (32 << 20) // row_bytes))
    L.buffers(rows)
    opt, ctl = _auto_arrays(spec, settings, t0, t_end, t0, clock, _AUTO_CODES[settings.method])
    stream: dict[str, np.ndarray] = {}
    log_parts: list[list[np.ndarray]] = []
    si = 0
    status, reason = "ok", ""
    t_now = t0
    every = int(settings.log_every)
    cap = None
    wall0 = _time.perf_counter()
    first_s, calls = 0.0, 0  # the first chunk's call (with the loop's compile or load when it is new here)
    if L.info[0] != 0:
        status, reason, _ = _stop(L.info, F.AT_STATE, t0, t0, settings, spec.ref, spec)
    chunk = 0
    with np.errstate(all="ignore"):
        while status == "ok":
            opt[5] = t0 + duration * min(1.0, (chunk + 1) / 100.0)  # this chunk's end (O_TCHUNK)
            if si == 0:
                _timing_mark("loop_call")
            li, where = L.auto_steps(events, L.fsig, L.fubar, L.fmot, L.noise, opt, ctl, rows)
            if si == 0:
                _timing_mark("first_chunk")
            if calls == 0:
                first_s = _time.perf_counter() - wall0
            calls += 1
            done = L.info[0] == 0 and li > 0 and L.lt[li - 1] >= t_end
            if li:
                keep = (np.arange(si, si + li) % every) == 0
                if done:
                    keep[-1] = True  # the last step is always logged
                si = _collect(spec, plant, nq, li, keep, L.bufs, stream, si, None, log_parts)
                t_now = float(L.lt[li - 1])
            if L.info[0] != 0:
                status, reason = _auto_stop(L, int(where), ctl, settings, spec)
                t_now = float(ctl[0])
                break
            if done:
                break
            if cap is None and stream:  # the stream's rows within the memory budget (ftcreport.limits)
                width = sum(v[0].size for v in stream.values())
                cap = min(MAX_STEPS, MEMORY_BUDGET_BYTES // (8 * width))
            if cap is not None and si > cap:
                status = "error"
                reason = (
                    f"at t = {t_now:.6g} s the error-controlled run has taken {si} steps, the limit of "
                    f"ftcreport.limits (MAX_STEPS, or its metric stream over MEMORY_BUDGET_BYTES; mean step "
                    f"{(t_now - t0) / si:.3g} s): loosen simulation.rtol/atol, or name a stiff method (ros2ec, etd2ec)"
                )
                break
            if float(ctl[0]) >= opt[5]:
                chunk += 1
                if progress is not None:
                    progress(float(ctl[0]))
    wall = _time.perf_counter() - wall0
    used = _CODE_NAMES.get(int(ctl[8]), settings.method)
    meta = {
        "integrator": {
            "method": used,
            "requested": settings.method,
            "rtol": settings.rtol,
            "atol": settings.atol,
            "max_step": settings.dt,
            "min_step": settings.min_step,
            "accepted": int(ctl[3]),
            "rejected": int(ctl[4]),
            "evaluations": int(ctl[5]),
            "spectral_radius": None if math.isnan(ctl[9]) else float(ctl[9]),
            # steps taken at min_step with the error over the tolerance (a discontinuity: fast.loop.run_auto)
            "forced_steps": int(ctl[15]),
            "first_forced_at": float(ctl[16]) if ctl[15] else None,
        },
        "compile_time": _compile_time(compile0, wall, first_s, calls, steps_new),
    }
    return _finish(Run, spec, plant, settings, nq, stream, si, log_parts, status, reason, t_now, int(ctl[3]), wall,
                   meta, progress)  # fmt: skip


def _auto_arrays(spec: Spec, settings, t_start: float, t_end: float, t0: float, clock: float, method: int):
    """fast.loop.run_auto's ``opt`` (settings) and ``ctl`` (state) for a run from t_start to t_end (the
    noise and UKF clock ``clock`` ticking from t0; ``method`` -1: auto picks)."""
    slot, T_min = _dwell(spec.controller)
    opt = np.array(
        [
            settings.rtol, settings.atol, settings.dt, settings.min_step, t_end, t_start, clock, t0, float(slot),
            T_min, float(method), 1.0 if spec.start else 0.0,
        ]
    )  # fmt: skip
    ctl = np.zeros(18)
    ctl[0] = t_start  # t
    ctl[7] = -math.inf  # the chained frame's next re-anchoring: none located yet
    ctl[8] = -1.0  # the method: not chosen yet
    ctl[9] = NAN  # the spectral radius: not estimated (a named method)
    return opt, ctl


#: fast.loop.FORCED_STREAK (tests/test_auto.py checks they agree)
FORCED_STREAK = 100


def _auto_stop(L: _Loop, where: int, ctl: np.ndarray, settings, spec: Spec) -> tuple[str, str]:
    """(status, reason) of an error-controlled run's stop (:func:`_auto_cause`), with the steps forced at
    min_step named when there were some."""
    status, reason = _auto_cause(L, where, ctl, settings, spec)
    if ctl[15]:
        reason += (
            f"; {int(ctl[15])} step(s) were taken at min_step = {settings.min_step:g} s with the error over the "
            f"tolerance, the first at t = {ctl[16]:.6g} s"
        )
    return status, reason


def _auto_cause(L: _Loop, where: int, ctl: np.ndarray, settings, spec: Spec) -> tuple[str, str]:
    """(status, reason) of an error-controlled run's stop.  No ``step_unstable``: the step is the
    controller's, so a stop at an accepted state is the loop's (singular, diverged, error); below the
    minimum step the label follows the last rejection's cause (a singular set: ``singular``; the
    error estimate, a non-finite or jumping state: ``diverged``)."""
    from ..errors import min_step_reason

    info = L.info
    used = _CODE_NAMES.get(int(ctl[8]), settings.method)
    how = _how(settings, used)
    t = float(ctl[0])
    if int(info[0]) == F.E_LAW_WRITE:  # the scheme wrote past its buffers (the loop's guard cells)
        from ..schemes.controller import write_reason

        return "error", write_reason(spec.controller, int(info[1]), float(info[2]))
    if int(info[0]) != F.E_MIN_STEP:
        status, reason = _message(info, t, settings, spec.ref, how)
        if status == "step_unstable":  # a stop of the fixed-step detectors' kind: the error control followed it
            status = "diverged"
        return status, reason
    cause = ctl[10:14]
    code = int(cause[0])
    if code == 0:
        why = (
            f"the local error stayed {float(cause[1]):.3g} times the tolerance for {FORCED_STREAK} steps in a row at "
            "min_step: the rates change faster than any step resolves (a finite-time blow-up, or a discontinuity "
            "crossed at every step)"
        )
        return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    if code == F.E_STEP_JUMP:
        from ..runs import step_jump_words

        why = f"every shorter step blew up ({step_jump_words(int(cause[1]), float(cause[2]), float(cause[3]))})"
        return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    status, words = _message(cause, t, settings, spec.ref, how)
    why = f"every shorter step's trial stage left the domain ({words})"
    if _in_singular_set(cause, F.AT_TRIAL, L.x, t, settings, spec):  # the state is at the set's edge
        return "singular", min_step_reason(t, float(info[2]), how, settings.min_step, why)
    if status == "error":  # the reference's own infeasibility (E_REF_*)
        return "error", words
    return "diverged", min_step_reason(t, float(info[2]), how, settings.min_step, why)


# --------------------------------------------------------------------------- the stop's re-check (fixed steps)
#: the error-controlled twin of each fixed-step method (the second opinion on a stop that persists at dt/4)
_CHECKED_BY = {"rk4": "dopri5", "ros2": "ros2ec", "etd2": "etd2ec"}
#: the re-check restarts at least this many steps before the stop (a checkpoint at a chunk start) ...
RECHECK_BACK = 32
#: ... and runs past it by this many steps of dt or this fraction of the time run so far, the longer: a
#: blow-up of the loop itself reaches its bound at dt/4 too, if a little later (two_link_uncompensable's
#: oracle with 1r and 1l failed at 1 and 2 s, rk4: velocity bound at 21.95 s at dt = 0.01 s, 22.46 s at
#: dt/2, 22.83 s at dt/4, 4 % of the time run later); a stop of the step's vanishes
RECHECK_PAST = 10
RECHECK_AHEAD = 0.1
#: ... at this fraction of the step (the issue's test: a stop that blames the step runs at dt/4)
RECHECK_SPLIT = 4


def _keep_checkpoints(checkpoints: list, k: int, L: _Loop) -> list:
    """Add the state at step k; keep the newest checkpoint at least RECHECK_BACK steps back and all newer."""
    checkpoints = [*checkpoints, (k, L.carried())]
    while len(checkpoints) > 1 and checkpoints[1][0] <= k - RECHECK_BACK:
        checkpoints.pop(0)
    return checkpoints


def _recheck(L: _Loop, grid, fidx, checkpoints, k_stop: int) -> dict:
    """Run the stop's interval again at dt/4 by the same fixed-step method (36 item 4): from a checkpoint
    at least 32 steps before the stop to 10 steps of dt or a tenth of the time run past it (the longer),
    each step of the grid split in four.

    Returns ``{"method", "dt", "from", "to", "status", "reason", "t_end", "growth"}``: status "ok" when
    the finer run passes the stop's interval; ``growth`` the ratio of max |tau| over the growth
    detector's window (the stop and the GROWTH_STEPS steps of dt before it) in the finer run.  Faults,
    samples and dwell ends fall where they fell (the fine grid holds every coarse instant); the noise of
    each coarse step is held over its four.
    """
    import dataclasses

    from ..runs import GROWTH_STEPS

    settings = L.settings
    split = RECHECK_SPLIT
    fine_settings = dataclasses.replace(settings, dt=settings.dt / split)
    back = [c for c in checkpoints if c[0] <= k_stop - RECHECK_BACK]
    k0, saved = back[-1] if back else checkpoints[0]
    ahead = math.ceil(RECHECK_AHEAD * (float(grid[k_stop]) - float(grid[0])) / settings.dt - 1e-9)
    k_to = min(k_stop + max(RECHECK_PAST, ahead), grid.shape[0] - 1)
    coarse = np.arange(k0, k_to)  # the coarse steps re-run, each split in four
    frac = np.arange(split) / split
    fine = (grid[coarse][:, None] + np.diff(grid)[coarse][:, None] * frac[None, :]).ravel()
    fine = np.append(fine, grid[k_to])
    owner = np.append(np.repeat(coarse, split), k_to)  # the coarse step each fine instant falls in
    first = 0
    if k0 > 0:  # the step before the checkpoint: a fault at k0 resets the windings as in the coarse run
        fine, owner, first = np.concatenate(([grid[k0 - 1]], fine)), np.concatenate(([k0 - 1], owner)), 1
    fine_fidx = np.ascontiguousarray(fidx[owner])
    noise = L.noise
    if noise.shape[0] > 1:
        noise = np.ascontiguousarray(noise[owner])
    L.restore(saved)
    L.info[:] = 0.0
    n_fine = fine.shape[0]
    L.buffers(n_fine)
    k_last, li, where = L.steps(fine, fine_fidx, noise, METHOD_CODES[settings.method], first, n_fine - 1,
                                np.ones(n_fine, dtype=np.bool_))  # fmt: skip
    tt, tau = L.lt[:li].copy(), np.max(np.abs(L.ltau[:li]), axis=1) if li else np.zeros(0)
    out = {
        "method": settings.method,
        "dt": fine_settings.dt,
        "from": float(grid[k0]),
        "to": float(grid[k_to]),
        "k_to": int(k_to),
        "status": "ok",
        "reason": "",
        "t_end": float(tt[-1]) if tt.size else float(grid[k0]),
        "growth": None,
    }
    window = (float(grid[max(k_stop - GROWTH_STEPS, 0)]), float(grid[k_stop]))
    a, b = np.searchsorted(tt, window[0] - 1e-12), np.searchsorted(tt, window[1] + 1e-12, side="right") - 1
    if 0 <= a < b < tt.size and tau[a] > 0 and tt[b] >= window[1] - 1e-9:
        out["growth"] = float(tau[b] / tau[a])
    if L.info[0] != 0:
        t_state, t_next = float(fine[k_last]), float(fine[min(k_last + 1, n_fine - 1)])
        st, why, t_end = _stop(L.info, where, t_state, t_next, fine_settings, L.spec.ref, L.spec)
        if _in_singular_set(L.info, where, L.x, t_state, fine_settings, L.spec):  # the state at the set's edge
            st, why = "singular", _message(L.info, t_state, fine_settings, L.spec.ref)[1]
        out |= {"status": st, "reason": why, "t_end": t_end, "where": int(where)}
    return out


def _controlled_recheck(L: _Loop, grid, checkpoints, k_stop: int, k_to: int) -> dict:
    """The second opinion on a stop that persists at dt/4 (:func:`_recheck`): its window again with an
    error-controlled step, from the same checkpoint to step ``k_to``, by the fixed method's
    error-controlled twin (dopri5 for rk4, ros2ec for ros2, etd2ec for etd2) at the case's rtol/atol
    and dt as its longest step (three_link_eight_faults' adaptive law stops at 26.265 s at dt/4 too;
    this step passes it with steps down to 4e-8 s, and the whole run is ok with ``auto``).

    Returns ``{"method", "from", "to", "status", "reason", "t_end", "min_step_taken", "growth"}``: status
    "ok" when it passes the stop; ``growth`` the ratio of max |tau| over the growth detector's window
    (the stop and the GROWTH_STEPS steps of dt before it).  Faults, samples and dwell ends fall where
    they fell; the noise of each coarse step is held over it (the clock dt).
    """
    import dataclasses

    from ..runs import GROWTH_STEPS

    settings = L.settings
    method = _CHECKED_BY[settings.method]
    fine_settings = dataclasses.replace(settings, method=method)
    back = [c for c in checkpoints if c[0] <= k_stop - RECHECK_BACK]
    k0, saved = back[-1] if back else checkpoints[0]
    t_from = float(grid[k0])
    t_to = float(grid[k_to])
    times = np.array(sorted(set(float(v) for v in L.plant.faults.times)), dtype=float)
    events = times[(times > t_from) & (times < t_to)]
    seg_all = np.unique(np.searchsorted(times, grid, side="right"))
    rows_of = np.searchsorted(seg_all, np.searchsorted(times, np.concatenate(([t_from], events)), side="right"))
    t0 = float(grid[0])
    clock = float(settings.dt) if (L.plant.noisy or L.spec.start) else NAN
    noise = L.noise
    if noise.shape[0] > 1:  # tick j of the clock holds the draw of the coarse step it falls in
        ticks = t0 + settings.dt * np.arange(math.floor((t_to - t0) / settings.dt + 1e-9) + 2)
        noise = np.ascontiguousarray(noise[np.clip(np.searchsorted(grid, ticks, side="right") - 1, 0, None)])
    opt, ctl = _auto_arrays(L.spec, fine_settings, t_from, t_to, t0, clock, _AUTO_CODES[method])
    opt[5] = t_to  # one chunk
    L.restore(saved)
    L.info[:] = 0.0
    L.buffers(256)
    window = (float(grid[max(k_stop - GROWTH_STEPS, 0)]), float(grid[k_stop]))
    t_rows: list[np.ndarray] = []
    tau_rows: list[np.ndarray] = []
    while True:
        li, where = L.auto_steps(events, L.fsig[rows_of], L.fubar[rows_of], L.fmot[rows_of], noise, opt, ctl, 256)
        t_rows.append(L.lt[:li].copy())
        tau_rows.append(np.max(np.abs(L.ltau[:li]), axis=1) if li else np.zeros(0))
        if L.info[0] != 0 or li == 0 or L.lt[li - 1] >= t_to or ctl[3] > 1_000_000:
            break
    tt, tau = np.concatenate(t_rows), np.concatenate(tau_rows)
    steps = np.diff(tt)
    out = {
        "method": method,
        "from": t_from,
        "to": t_to,
        "status": "ok",
        "reason": "",
        "t_end": float(tt[-1]) if tt.size else t_from,
        "min_step_taken": float(steps.min()) if steps.size else None,
        "growth": None,
    }
    a, b = np.searchsorted(tt, window[0]), np.searchsorted(tt, window[1], side="right") - 1
    if 0 <= a < b < tt.size and tau[a] > 0 and tt[b] >= window[1] - 1e-9:
        out["growth"] = float(tau[b] / tau[a])
    if L.info[0] != 0:
        st, why = _auto_stop(L, where, ctl, fine_settings, L.spec)
        out |= {"status": st, "reason": why, "t_end": float(ctl[0])}
    return out


def _relabel(code: int, where: int, reason: str, recheck: dict, settings, t_stop: float) -> tuple[str, str]:
    """The stop's label from its re-check at dt/4 (36 item 4).

    ``step_unstable`` only when the finer run passes the stop's window (RECHECK_PAST, RECHECK_AHEAD: the
    stop vanishes, or moves out of it); ``singular`` when it stops within it with the state in a law's
    singular set; ``diverged`` when it stops within it otherwise (a blow-up that persists at the smaller
    step, if a little later or earlier) unless the error-controlled step passes the window (then
    ``step_unstable``: only a much smaller step removes it), or when the growth detector's stop
    (``code`` E_STEP_GROWTH) finds the torque growing as fast in time at dt/4 (more than e-fold per step
    of dt over the detector's window: a fast mode of the loop itself, which the finer step resolves).
    """
    from ..errors import controlled_reason, persists_reason, vanishes_reason
    from ..runs import GROWTH_FACTOR, GROWTH_STEPS

    fine = recheck
    growth = fine["growth"]
    finer = f"at dt/{RECHECK_SPLIT} = {fine['dt']:g} s"
    if code == F.E_STEP_GROWTH and growth is not None and growth > GROWTH_FACTOR**GROWTH_STEPS:
        return "diverged", (
            f"{reason}; {finer} the torque grows as fast ({growth:.3g}x over the same {GROWTH_STEPS} steps of dt): "
            "the loop's own fast mode, not the step's"
        )
    if fine["status"] == "ok":
        return "step_unstable", vanishes_reason(reason, finer, fine["to"])
    if fine["status"] == "singular":
        trial = where == F.AT_TRIAL and code in _SINGULAR_CODES  # the step dt's trial stage reached the set
        return "singular", persists_reason(fine["reason"], settings.dt, finer, t_stop, fine["t_end"], True, trial)
    controlled = fine.get("controlled")
    if controlled is not None and controlled["status"] == "ok":  # only a much smaller step passes it
        how = step_words(settings.dt, controlled["method"], settings.rtol, settings.atol)
        return "step_unstable", controlled_reason(
            reason, finer, fine["t_end"], how, controlled["to"], controlled["min_step_taken"]
        )
    return "diverged", persists_reason(reason, settings.dt, finer, t_stop, fine["t_end"], False)


def _in_singular_set(info, where: int, x: np.ndarray, t: float, settings, spec: Spec) -> bool:
    """Did the run stop because the accepted state reached a law's singular set (ERRATA P4, E12d)?

    At the accepted state (``where`` AT_STATE) a singular code is the set itself.  At a trial stage it
    is only if the accepted state x at t is already near the set the stage reached: within
    JUMP_MARGINS singularity margins of it (|cos| of the angle below sin(20 deg) at the default 2 deg
    margin; for the chained form, its law refusing x with its tolerance widened to that), the band
    within which fast.kernels._step_jump does not call an arrival at the set a step's blow-up.  A stage
    that reaches the set from farther out is a blow-up passing through it (``diverged`` if it persists).
    """
    from ..runs import JUMP_MARGINS

    code = int(info[0])
    if code not in _SINGULAR_CODES:
        return False
    if where == F.AT_STATE:
        return True
    band = math.sin(JUMP_MARGINS * settings.singularity_margin)
    nq = spec.chain.n + 2
    q = x[:nq]
    kin = spec.controller.kin
    if code == F.E_TWO_LINK_PHI:
        return abs(math.cos(q[3] - q[2])) <= band
    if code == F.E_TWO_LINK_ETH:  # the heading error of robot n against the reference's heading at t
        return abs(math.cos(q[2] - float(kin.reference.at(t).q_d[2]))) <= band
    if code in (F.E_CHAINED_THN, F.E_CHAINED_ART, F.E_KAPPA) and hasattr(kin, "singular_tol"):
        import copy

        from ..errors import FtcError

        wide = copy.copy(kin)  # the same law, refusing a band of the sets around them
        wide.singular_tol, wide._kin, wide._cache = band, None, None
        try:
            wide.law(t, q, x[-int(spec.controller.n_states) :])
        except FtcError:
            return True
    return False


#: the kinematic laws' and the chained form's singular sets (ERRATA P4, E12d): a stop there is ``singular``
_SINGULAR_CODES = frozenset(
    (F.E_STATE_SINGULAR, F.E_TWO_LINK_ETH, F.E_TWO_LINK_PHI, F.E_CHAINED_THN, F.E_CHAINED_ART, F.E_KAPPA)
)


def _chunk_signals(spec: Spec, plant, nq: int, rows, bufs, costs: bool = True) -> dict[str, np.ndarray]:
    """Every logged array of the chunk buffers' ``rows`` (a slice: views; an index array: copies), by name."""
    lt, lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lia = bufs
    out = {
        "t": lt[rows], "q": lq[rows], "eta": leta[rows], "u": lu[rows], "tau": ltau[rows], "sigma": lsig[rows],
        "ubar": lubar[rows], "xc": lxc[rows],
    }  # fmt: skip
    if lia.shape[1]:  # the motor states: the currents, then the drives' states (fast.drive)
        nw = plant.chain.n_wheels
        out["i_a"] = lia[rows][:, :nw]
        if lia.shape[1] > nw:
            out["z_drive"] = lia[rows][:, nw:]
    meas = lmeas[rows] if plant.noisy else np.concatenate((out["q"], out["eta"]), axis=1)
    out |= _split_signals(spec, lsg[rows], out["xc"], meas, nq, costs)
    if plant.noisy:
        out["q_meas"] = meas[:, :nq]
    return out


def _collect(spec, plant, nq, li, keep, bufs, stream, si, rows, log_parts) -> int:
    """Split one chunk (its first ``li`` buffer rows) into the metric stream (rows si..) and the saved log.

    ``keep``: (li,) which rows the log saves; ``rows``: the stream's length, preallocated on the first
    chunk (fixed steps), or None: grown by doubling (error-controlled steps).  Returns the stream's
    new length.
    """
    from ..runs import stream_of

    sig = _chunk_signals(spec, plant, nq, slice(0, li), bufs, costs=False)
    part = stream_of(sig) | {"t": sig["t"]}
    if not stream:
        n = rows if rows is not None else max(1024, 4 * li)
        stream.update({name: np.full((n, *v.shape[1:]), np.nan) for name, v in part.items()})
    size = next(iter(stream.values())).shape[0]
    if si + li > size:  # error-controlled: the steps are not known in advance
        n = max(2 * size, si + li)
        for name, v in stream.items():
            grown = np.full((n, *v.shape[1:]), np.nan)
            grown[:si] = v[:si]
            stream[name] = grown
    for name, v in part.items():
        stream[name][si : si + li] = v
    kept = np.flatnonzero(keep)
    if kept.size:  # the saved steps' raw buffers (fancy indexing copies them); named once, at the end
        log_parts.append([b[kept] if b.shape[0] else b for b in bufs])  # unused buffers have no rows
    return si + li


def _concat(parts: list[list[np.ndarray]]) -> tuple[np.ndarray, ...]:
    """The chunks' raw log buffers joined, buffer by buffer; each chunk's copy is dropped once joined.

    The named signals are then views and slices of the joined buffers (``_chunk_signals`` with a
    slice), so the log is held once, not once per chunk plus once joined (the five-link adaptive
    case's controller state is 49 MB).
    """
    out = []
    for i in range(len(parts[0])):
        out.append(np.concatenate([p[i] for p in parts], axis=0) if parts[0][i].shape[0] else parts[0][i])
        for p in parts:
            p[i] = None
    parts.clear()
    return tuple(out)
