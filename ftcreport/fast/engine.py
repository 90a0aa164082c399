r"""The compiled engine: the one simulation loop (ftcreport/fast/loop.py, on the domains' compiled kernels).

:func:`compiled_spec` reads a controller built by the Python faces (the classes of
:mod:`ftcreport.control`, a registered scheme's ``SchemeController``) into the plain
arrays the kernels take, or returns None when the controller has no compiled
counterpart: :func:`ftcreport.sim.simulate` then refuses it (issue 17: there is no
Python loop; a new law is written as a scheme).  :func:`ftcreport.fast.simulate.simulate_compiled` runs the
steps (fault sampling, noise, checks, logging, RK4, ROS2 or ETD2, discrete updates)
and builds the :class:`~ftcreport.sim.Run`; the signals that are plain functions of
the logged state (switching costs, adaptive weights, the observer's P) are computed
here, vectorized, from the log.

The loop runs in chunks of about 1 % of the steps so that the progress
callback is called every ~1 % of the run.  numba compiles the kernels
on first use and caches the machine code in the user's cache directory
(:mod:`ftcreport.infra.paths`): a fresh install builds the cache on its first run (:func:`ftcreport.sim.warm_up` does it
explicitly and reports the time).

The Python side of a run, by role: this module (the spec, the loops' modules, the chunked calls, the
log's signals), :mod:`.simulate` (a run from start to status), :mod:`.auto_run` (error-controlled
runs), :mod:`.recheck` (a fixed-step stop checked again at a finer step), :mod:`.stops` (a stop's
status and reason).
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

from ..infra.atomic import replace_file
from ..jit.compiling import engine_stamp
from ..jit.packed import Chain, Kin, Ref
from ..model import compiled as model_compiled
from ..model.compiled import reduced
from ..model.drive_compiled import motor_state_count
from ..model.kernels import kernel_ref, packed
from ..schemes.api import GUARD, N_GUARD, TERMS_MODES
from ..schemes.controller import SchemeController

__all__ = ["Spec", "compiled_spec", "loop_for"]

NAN = float("nan")


class Spec(NamedTuple):
    """Everything the kernels need of a controller (a scheme bound to a case: ftcreport.schemes)."""

    kin: Kin
    ref: Ref
    law: object  # the scheme's compiled law (ftcreport.schemes.api)
    disc: object  # its discrete update
    P: tuple  # its packed parameters
    chain: Chain
    n_sig: int  # the logged signals: the kinematic ones, then the law's
    controller: SchemeController
    start: bool = False  # the discrete update also runs at t0, before the first step
    terms: int = 0  # how the matched terms reach the law (ftcreport.schemes.api.TERMS_MODES)
    n_kin_sig: int = 0  # the kinematic signals' count (they come first in the signal row)


def _chain(params) -> Chain:
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
    from ..control.interface_compiled import legacy_no_discrete, no_discrete
    from ..schemes.registry import legacy

    return legacy_no_discrete if legacy(law) else no_discrete


def law_buffers(spec: Spec) -> tuple:
    """The buffers a law writes (the loop's ``P[1]``): ``(k_v, u, dx, sig, x, fresh, rec)``.

    u (2n), dx and x (the scheme's own states), sig (its declared signals), each followed by
    ``N_GUARD`` cells holding ``GUARD``, which the loop checks after every call of the law (and of
    the discrete update, for x); ``fresh`` flags a kinematic evaluation by the law itself; ``rec``: the
    inputs of a plug-in's call that raised (fast.loop._raised: which, t, q, eta, xc, sigma, ubar, w, MB, g,
    eta_e).
    """
    c = spec.controller

    def guarded(n: int) -> np.ndarray:
        buf = np.full(n + N_GUARD, GUARD)
        buf[:n] = 0.0
        return buf

    n_own_sig = spec.n_sig - spec.n_kin_sig
    nw, n = c.chain.n_wheels, c.n_own
    rec = np.zeros(2 + c.chain.n_q + 2 + int(c.n_states) + 2 * nw + 2 + 2 * nw + 2 + 2)
    return (float(c.k_v), guarded(nw), guarded(n), guarded(n_own_sig), guarded(n), np.zeros(1), rec)


def _law_input(spec: Spec, bufs: tuple) -> tuple:
    """The loop's ``P``: the scheme's parameters and its law buffers."""
    return (spec.P, bufs)


def wheel_speeds_rows(chain, Q: np.ndarray, ETA: np.ndarray) -> np.ndarray:
    """Wheel speeds (K, 2n) at K states: the compiled reduced model's Bbar(q)^T eta, row by row."""
    Q = np.ascontiguousarray(Q, dtype=float).reshape(-1, chain.n_q)
    ETA = np.ascontiguousarray(ETA, dtype=float).reshape(-1, 2)
    return model_compiled.wheel_speeds_rows(kernel_ref(chain.params), Q, ETA)  # a ref: the loop's compile of reduced


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


# --------------------------------------------------------------------------- the loop
def _no_motors():
    from ..model.motor_compiled import Motors

    z = np.zeros(0)
    return Motors(z, z, z, z, z, z, z, z, z, z)


def _no_drive():
    from ..model.drive_compiled import DRIVER_STATIC, Drive

    z = np.zeros(0)
    return Drive(DRIVER_STATIC, z, z, z, z, z, z, z, z, z, z, z, z, NAN)


def _initial_currents(loop, spec: Spec, plant, mo, dr, sigma, ubar, fm, t0: float, x: np.ndarray, npl: int):
    """The motor states at t0 (currents, drive states): quasi-static for the first command (its wheel
    torque is the command; model.drive_compiled.initial_motor_states)."""
    from ..model.drive_compiled import initial_motor_states

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
    omega = reduced(kernel_ref(plant.chain.params), q, eta)[3].T @ eta
    return initial_motor_states(mo, dr, tau_c, omega, fm)


def _cache_dir() -> Path:
    """Where the generated loop modules live: ``ftcreport.infra.paths.cache_dir("loops")`` (the user's cache
    directory or ``$FTCREPORT_CACHE``, keyed by versions and CPU), never inside the installed package."""
    from ..infra.paths import cache_dir

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
    ``disc`` are then bounds-checked copies, ftcreport.fast.scheme_check.boundschecked; nothing is cached).

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
PLUGIN_LINE = "PLUGIN, CATCH = False, False  # LOOP-PLUGIN"
VARIANT = "MOTORS, SAMPLED = True, True  # LOOP-VARIANT"


def is_plugin(fn) -> bool:
    """Whether a compiled law (or discrete update) is a plug-in's: defined outside ftcreport's own package."""
    from ..jit.compiling import own_module

    return not own_module(getattr(fn, "py_func", fn).__module__)


def _load_loop(law, disc, motors: bool, sampled: bool, terms: int = 0, checked: bool = False):
    """Write (if needed) and import the loop module bound to (law, disc) and the variant."""
    import hashlib
    import importlib.util
    import inspect
    import sys

    from . import loop as template

    text = Path(template.__file__).read_text()
    for line in (BINDING, TERMS_LINE, LEGACY_LINE, PLUGIN_LINE, VARIANT):
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
        lines = ["from ftcreport.fast.scheme_check import boundschecked"]
        lines += [f"from {m} import {q} as _{a}0  # source {h}" for m, q, a, h in parts]
        lines += [f"{a} = boundschecked(_{a}0)" for _m, _q, a, _h in parts]
    else:
        lines = [f"from {m} import {q} as {a}  # source {h}" for m, q, a, h in parts]
    lines.append(f"# ftcreport sources {shared}")
    text = text.replace(BINDING, "\n".join(lines))
    from ..schemes.registry import legacy

    text = text.replace(TERMS_LINE, f"TERMS_MODE = {int(terms)}")
    text = text.replace(LEGACY_LINE, f"LEGACY = {legacy(law)}")
    text = text.replace(PLUGIN_LINE, f"PLUGIN, CATCH = {is_plugin(law)}, {is_plugin(law) and not checked}")
    variant = f"MOTORS, SAMPLED = {motors}, {sampled}"
    if checked:  # every function of the module compiled with bounds checks, not cached
        variant += "\nfrom ftcreport.fast.scheme_check import checked_jit as jit  # noqa: E402"
    text = text.replace(VARIANT, variant)
    tag = "__".join(f"{m}.{q}" for m, q, _, _ in parts)
    tag += "__" + "".join(c for c, on in zip("ms", (motors, sampled), strict=True) if on) + ("", "o", "n")[terms]
    tag += "_bc" if checked else ""
    name = "ftcreport_loop_" + "".join(c if c.isalnum() else "_" for c in tag)
    folder = _cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    if not path.exists() or path.read_text() != text:
        replace_file(path, text.encode())  # atomic: a concurrent process sees the old or the new file, whole
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
    """A plug-in law that raises inside the compiled loop uncaught (the round-2 form's: a law of the contract
    that raises stops the run as E_LAW_RAISED, fast.loop._raised) is the scheme's error, naming it
    (:class:`~ftcreport.errors.ModelError`)."""
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


def noise_clock(plant, settings) -> float:
    """The sensor's sample period: the plant's ``noise_period``, else the run's dt (one draw per step)."""
    return float(settings.dt) if plant.noise_period is None else plant.noise_period


def noise_ticks(plant, settings, t0: float, times: np.ndarray) -> np.ndarray:
    """The tick of the sensor's clock each instant of ``times`` falls in (its draw), floor((t - t0) / T)."""
    return np.floor((np.asarray(times, dtype=float) - t0) / noise_clock(plant, settings) + 1e-9).astype(np.int64)


def disc_ticks(spec, plant, settings, times: np.ndarray) -> np.ndarray:
    """Whether the scheme's discrete update runs at each instant of ``times`` (a fixed step's grid): at every
    step, or for a discrete-time filter (the UKF: ``spec.start``) at the sensor's ticks (:func:`noise_clock`:
    the filter updates when a measurement arrives; with the default clock dt, every step of dt) and at the end."""
    times = np.asarray(times, dtype=float)
    on = np.ones(times.shape[0], dtype=np.bool_)
    if spec.start and times.size:
        T = noise_clock(plant, settings)
        r = (times - float(settings.t0)) / T
        on = np.abs(r - np.round(r)) <= 1e-9 * np.maximum(1.0, r)
        on[-1] = on[-1] or times[-1] >= float(settings.t0) + float(settings.duration) - 1e-9 * T
    return on


def n_noise_ticks(plant, settings) -> int:
    """How many draws a run takes: the ticks of its clock over the duration, and one past the end."""
    return math.floor(float(settings.duration) / noise_clock(plant, settings) + 1e-9) + 2


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
        # one draw per tick of the sensor's clock (noise_clock), in order (seeded); a fixed step reads the draw of
        # the tick it starts in (step_noise)
        if plant.noisy:
            rng = np.random.default_rng(plant.seed)
            self.noise = rng.standard_normal((n_noise, nq + 2)) * plant.noise_std
        else:
            self.noise = np.zeros((1, nq + 2))
        self.step_noise = self.noise  # a fixed-step run's draw of each step (fast.simulate)
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
        motor_loop = nm > 0 or settings.method in ("etd2", "etd2ec", "etd3ec")
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
        # and a sampled PI drive's [next sample time, period] (model.drive_compiled)
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
        # the motor states, then (sampled control) each step's wheel torques at its midpoint (fast.loop)
        # (NaN where none: continuous control, ROS2, DOPRI5; the metrics then keep the trapezoid)
        self.lia = np.full((rows, nm + nw if nm else 0), np.nan)
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

    def steps(self, grid, fidx, noise, method: int, k0: int, k1: int, logged, disc_on=None) -> tuple[int, int, int]:
        """run_steps over steps k0..k1 of ``grid``: (last step, rows logged, where); updates x.  ``disc_on``:
        whether the scheme's discrete update runs at the end of each step (:func:`disc_ticks`; default every step)."""
        spec, st = self.spec, self.settings
        # compiles the loop on its first use (jit.compiling); the law's errors name the scheme (_law_errors)
        with _compiling(self.loop, self.loop.run_steps), _law_errors(spec):
            self.x, k_last, li, where = self.loop.run_steps(
                self.P, spec.kin, spec.ref, spec.chain, self.pp,
                grid, fidx, self.fsig, self.fubar, noise, self.sat, self.diag, method, self.lim, st.max_speed,
                st.max_position, self.x, k0, k1, logged, disc_ticks(self.spec, self.plant, st, grid) if disc_on is None
                else disc_on, 0,
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
    logs.pop("tau_mid", None)  # a metric-stream quantity: the saved log keeps the states and signals
    t_stream = stream.pop("t", np.zeros(0))
    if settings.sample_time is not None:
        reference = spec.controller.kin.reference
        _reference_now(reference, t_stream, stream, settings.sample_time)
        _reference_now(reference, t_log, logs, settings.sample_time)
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


def _reference_now(reference, t: np.ndarray, signals: dict[str, np.ndarray], sample_time: float) -> None:
    """``q_d`` and ``eta_d`` of the rows between samples set to the reference at the row's own time.

    Sampled control logs the law's signals as held since the last sample, the reference among them (the
    law's own signals, z and eta_c, stay as the law held them);
    the tracking errors (metrics, requirements, pages) compare the chain now with the reference now,
    not with where the reference was at the last sample (a sawtooth of v (t - t_sample)).  Rows at a
    sample instant already hold it, exactly: they are left alone.
    """
    if t.size == 0 or not any(k in signals for k in ("q_d", "eta_d")):
        return
    k = t / sample_time
    between = np.flatnonzero(np.abs(k - np.round(k)) > 1e-9 * np.maximum(1.0, np.abs(k)))
    if between.size == 0:
        return
    # every row in one compiled call; where the reference is infeasible between samples the row keeps the
    # law's held reference (the run says where the reference fails when it reaches it)
    q_d, eta_d, ok = reference.rows(t[between])
    rows = between[ok]
    if "q_d" in signals:
        signals["q_d"][rows] = q_d[ok]
    if "eta_d" in signals:
        signals["eta_d"][rows] = eta_d[ok]


def _chunk_signals(spec: Spec, plant, nq: int, rows, bufs, costs: bool = True) -> dict[str, np.ndarray]:
    """Every logged array of the chunk buffers' ``rows`` (a slice: views; an index array: copies), by name."""
    lt, lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lia = bufs
    out = {
        "t": lt[rows], "q": lq[rows], "eta": leta[rows], "u": lu[rows], "tau": ltau[rows], "sigma": lsig[rows],
        "ubar": lubar[rows], "xc": lxc[rows],
    }  # fmt: skip
    if lia.shape[1]:  # the motor states: the currents, then the drives' states (model.drive_compiled)
        nw = plant.chain.n_wheels
        nm = lia.shape[1] - nw  # the motor states, then each step's torques at its midpoint (fast.loop)
        out["i_a"] = lia[rows][:, :nw]
        if nm > nw:
            out["z_drive"] = lia[rows][:, nw:nm]
        out["tau_mid"] = lia[rows][:, nm:]
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
