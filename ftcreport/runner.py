"""Run one scheme of a validated case and compute its metrics (pure, no I/O).

case --build--> chain, reference, faults, plant, controller
(plant, controller) --simulate--> Run --metrics--> dict (the metrics.json content)
"""

from __future__ import annotations

import math
import time

import numpy as np

from . import __version__
from .cases import Case, build_chain, build_plant_chain, case_hash, initial_state
from .control.kinematic import ChainedBackstepping, TwoLinkKinematic
from .errors import CASE_ERRORS as _FTC_CASE_ERRORS
from .errors import FtcError, RunEnvironmentError, environment_cause
from .evaluation.metrics import HEADLINE_METRICS, singularity_margin, torque_metrics, tracking_metrics
from .references import FlatReference
from .sim import Plant, Run, SimSettings, simulate

__all__ = [
    "CASE_ERRORS",
    "HEADLINE_METRICS",
    "Built",
    "build",
    "dt_sensitivity",
    "expected_engine",
    "explain_nulls",
    "halve_dt",
    "integrator_words",
    "make_controller",
    "run_metrics",
    "run_scheme",
    "start_problems",
]


#: The exceptions of a run that are its case's own outcome, stored as the run's result (status ``error``):
#: ftcreport.errors.CASE_ERRORS and numpy's LinAlgError (a linear solve on the case's numbers).
CASE_ERRORS: tuple[type[BaseException], ...] = (*_FTC_CASE_ERRORS, np.linalg.LinAlgError)


def expected_engine(scheme: str) -> str:
    """The engine that runs a scheme: the compiled one, the only engine since issue 17.

    Part of the result cache key (``ftcreport.studies.batch.run_key``), so it is known before the run;
    ``tests/test_tidy.py`` checks it against the engine each run records.
    """
    return "compiled"


class Built:
    """The simulation objects of a case (shared by its schemes)."""

    def __init__(self, case: Case) -> None:
        self.case = case
        self.chain = build_chain(case)
        self.reference = FlatReference(case.reference.path(), self.chain.d)
        self.faults = case.fault_schedule()
        nz = case.plant.noise
        n = self.chain.n
        self.plant = Plant(
            build_plant_chain(case),
            self.faults,
            case.plant.saturation,
            noise_q=[nz.position, nz.position] + [nz.heading] * n,
            noise_eta=[nz.velocity, nz.velocity],
            seed=nz.seed,
            noise_period=nz.sample_time,
            motors=case.motor_params(),
            drive=case.drive_params(),
        )
        self.q0, self.eta0 = initial_state(case, self.reference)
        s = case.simulation  # the same fields by name; the margin in radians
        margin = math.radians(s.singularity_margin_deg)
        self.settings = SimSettings(**s.model_dump(exclude={"singularity_margin_deg"}), singularity_margin=margin)

    def kinematic(self) -> TwoLinkKinematic | ChainedBackstepping:
        k = self.case.kinematic
        if k.kind == "two_link":
            return TwoLinkKinematic(self.chain.d[0], self.reference, k.k1, k.k2, k.k3)
        c = k.c_chain if isinstance(k.c_chain, list) else [k.c_chain] * self.chain.n
        return ChainedBackstepping(
            self.chain.d, self.reference, c, k.c_alpha2, k.c_xi1, k.kappa, band=math.radians(k.band_deg), mu=k.mu
        )


def build(case: Case) -> Built:
    """Chain, reference, faults, plant, initial state and settings of a case."""
    return Built(case)


def start_problems(case: Case) -> tuple[list[str], list[str]]:
    """What makes a valid case's runs fail before or while they start, found without running them
    (``cases validate``): ``(errors, warnings)``, each ``field: reason``.

    Errors: the reference infeasible at t = 0 (no run can start), a plug-in scheme whose declarations
    (n_states, signals, pack, stiff, initial_state) raise when bound to the case.  Warnings: the
    reference infeasible later in the run (every run stops there at the latest, status error), found on a grid
    of 50 ms and then of 50 us (``FlatReference.first_infeasible``: the instant analyze covers the run up to).
    """
    from .errors import ReferenceError
    from .schemes import get
    from .schemes.registry import is_built_in

    errors: list[str] = []
    warnings: list[str] = []
    try:
        built = build(case)
        built.reference.at(0.0)
    except FtcError as exc:
        field = "reference" if isinstance(exc, ReferenceError) else "case"
        return [f"{field}: {exc} (no run can start)"], []
    try:
        found = reference_stop(case, built)
    except ReferenceError as exc:
        return [f"reference: {exc}"], []
    if found is not None:  # the instant analyze analyses up to (analysis.case.analysed_horizon)
        why = "every run stops there at the latest (status error); analyze covers the run up to it"
        warnings.append(f"reference: {found[1]}: {why}")
    from .cases import configured_schemes

    for name in configured_schemes(case):
        if is_built_in(get(name)):
            continue  # a built-in scheme: its declarations are ftcreport's own
        try:
            ctrl = make_controller(built, name, checked=False)
            x0 = ctrl.own_initial_state(0.0, built.q0, built.eta0)
            run_cost(case, name)
        except FtcError as exc:
            errors.append(f"schemes.{name}: {exc}")
            continue
        if not np.all(np.isfinite(x0)):
            from .schemes.registry import _where

            sc = get(name)
            where = _where(sc.initial_state) if sc.initial_state is not None else name
            errors.append(f"schemes.{name}: {where}: initial_state is not finite at t = 0 ({x0.tolist()[:6]})")
    return errors, warnings


def reference_stop(case: Case, built: Built) -> tuple[float, Exception, float] | None:
    """Where the reference turns infeasible within the run (``FlatReference.first_infeasible``: the first
    instant found infeasible, its error, the last found feasible), else None; a ReferenceError when the
    last feasible instant is within the run's first step (no run takes one: ``cases validate`` and ``analyze``
    both refuse the case)."""
    from .errors import ReferenceError

    found = built.reference.first_infeasible(case.simulation.duration)
    if found is not None and found[2] < case.simulation.dt:
        dt = case.simulation.dt
        raise ReferenceError(f"{found[1]}, within the run's first step (dt = {dt:g} s): no run takes a step")
    return found


def make_controller(built: Built, scheme: str, checked: bool = True):
    """The controller of one scheme of the case: the registered scheme bound to the case (ftcreport.schemes)."""
    from .evaluation.families import default_k_v
    from .schemes import SchemeContext, SchemeController, get
    from .schemes.hooks import hook
    from .schemes.registry import is_built_in

    case = built.case
    cfg = getattr(case.schemes, scheme, None)
    if cfg is None:
        raise FtcError(f"scheme '{scheme}' is not configured in case '{case.name}'")
    kin = built.kinematic()
    sc = get(scheme)
    k_v = getattr(cfg, "k_v", None)
    k_v = default_k_v(case) if k_v is None else k_v
    if sc.controller is None:  # a plug-in: the engine runs its compiled law
        ctrl = SchemeController(sc, built.chain, kin, k_v, cfg, saturation=case.plant.saturation, case=case)
    else:
        nz, nq = len(kin.z_names), built.chain.n_q
        ctx = SchemeContext(built.chain, kin, float(k_v), cfg, case.plant.saturation, kin.n_states, 6 + nz + nq, case)
        if is_built_in(sc):
            return sc.controller(sc, ctx)  # a built-in scheme's face (ftcreport.control)
        ctrl = hook(sc, "controller", sc.controller, sc, ctx, convert=_face)  # a plug-in's own face
    from .fast.scheme_check import ensure_checked

    if checked:  # a plug-in's first run: its law under bounds checks first (once per version of its file)
        ensure_checked(ctrl)
    return ctrl


def _face(value):
    """A plug-in's ``controller`` hook's result: a :class:`~ftcreport.schemes.SchemeController`."""
    from .schemes import SchemeController
    from .schemes.hooks import ResultError, one_line

    if not isinstance(value, SchemeController):
        raise ResultError(f"returned {one_line(repr(value))[:80]}, not a SchemeController (ftcreport.schemes)")
    return value


def run_cost(case: Case, scheme: str) -> float:
    """A run's relative cost per step, ``Scheme.cost`` (1 without one): a finite number > 0, else a
    :class:`~ftcreport.errors.PluginError` naming the plug-in's hook (a batch orders its runs by it)."""
    from .schemes import get
    from .schemes.hooks import ResultError, hook, one_line

    sc = get(scheme)
    if sc.cost is None:
        return 1.0

    def number(value) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not 0.0 < value < math.inf:
            raise ResultError(f"returned {one_line(repr(value))[:80]}, not a finite number > 0")
        return float(value)

    return hook(sc, "cost", sc.cost, case, convert=number)


def run_scheme(case: Case, scheme: str, built: Built | None = None, progress=None) -> tuple[Run, dict]:
    """Simulate one scheme of a case; always returns (run, metrics), failures included.

    A run that stops early (singular, diverged) keeps its log and its metrics
    over the simulated part; the case's own error while building or simulating
    (:data:`CASE_ERRORS`: an impossible setting, a numeric failure) is reported with
    status ``error`` and an empty run.  Any other exception is not the case's outcome
    and is never returned as a result: one of the environment (a compiled-code cache
    that cannot be loaded, an OS error, memory; :func:`ftcreport.errors.environment_cause`)
    is raised as :class:`~ftcreport.errors.RunEnvironmentError`, anything else (a bug) as it is.
    """
    try:
        return _run_scheme(case, scheme, built, progress)
    except RunEnvironmentError:
        raise
    except Exception as exc:
        if (cause := environment_cause(exc)) is not None:
            raise RunEnvironmentError(cause) from exc
        raise


def _run_scheme(case: Case, scheme: str, built: Built | None, progress) -> tuple[Run, dict]:
    wall0 = time.perf_counter()
    try:
        built = built or build(case)
        ctrl = make_controller(built, scheme)
        run = simulate(built.plant, ctrl, built.q0, built.eta0, built.settings, progress=progress)
    except RunEnvironmentError:
        raise
    except CASE_ERRORS as exc:
        # a numeric failure inside the engine (e.g. a linear solve on non-finite values) is a failed run
        why = str(exc) if isinstance(exc, FtcError) else f"numeric error in the simulation: {type(exc).__name__}: {exc}"
        exc = FtcError(why)
        empty = Run(t=np.zeros(0), signals={}, status="error", reason=str(exc))
        return empty, explain_nulls(_identity(case, scheme) | {"status": "error", "reason": str(exc), "wall_time": 0.0})
    metrics = run_metrics(case, scheme, run, built, ctrl)
    metrics["wall_time"] = time.perf_counter() - wall0
    # of which compiling or loading the engine's loop, when this process had not yet (fast.engine)
    metrics["compile_time"] = float(run.meta.get("compile_time", 0.0))
    run.meta |= {  # what the arrays do not carry (Run.to_xarray, notebook views)
        "case": case.name,
        "scheme": scheme,
        "case_hash": metrics["case_hash"],
        "n_robots": case.robots.n,
        "package_version": __version__,
    }
    for key in ("estimated_parameters", "patterns"):
        if key in metrics:
            run.meta[key] = metrics[key]
    return run, explain_nulls(metrics)


def _identity(case: Case, scheme: str) -> dict:
    return {
        "case": case.name,
        "scheme": scheme,
        "n_robots": case.robots.n,
        "reference_kind": case.reference.kind,
        "duration": case.simulation.duration,
        "dt": case.simulation.dt,
        "method": case.simulation.method,
        "package_version": __version__,
        "case_hash": case_hash(case, __version__),  # content hash of the case (tidy exports, manifest)
    }


def run_metrics(case: Case, scheme: str, run: Run, built: Built, ctrl) -> dict:
    """The metrics.json content of one run (see ftcreport.evaluation.metrics for definitions)."""
    out = _identity(case, scheme) | {"status": run.status, "reason": run.reason, "t_end": run.t_end}
    out["engine"] = run.meta["engine"]  # "compiled" (ftcreport.fast): the only engine
    if "integrator" in run.meta:  # the method that ran (auto's pick), its steps and its stop's re-check
        out["integrator"] = run.meta["integrator"]
    # every metric reads the metric stream (every accepted step), never the decimated log
    t, S = (run.t_stream, run.stream) if run.stream else (run.t, run.signals)
    out["metric_samples"] = int(t.size)
    if case.requirements:  # every window of every [[requirements]] table, from the same stream
        out["requirements"] = _requirements(case, scheme, run, built, t, S)
    if t.size < 2:
        return out
    phases = built.faults.phases(min(case.simulation.duration, run.t_end))
    out |= tracking_metrics(t, S["q"], S["q_d"], phases, case.recovery_band, built.faults.times)
    chain = built.plant.chain
    from .fast.engine import wheel_speeds_rows

    omega = wheel_speeds_rows(chain, S["q"], S["eta"])  # every step: compiled, one call
    first_fault = min(built.faults.times, default=None)
    # inside each step (evaluation.metrics.step_integrals): sampled control holds the command, and with
    # motors the currents settle within L_a / R_a after each held voltage, read at the steps' midpoints
    sampled, motors = case.simulation.sample_time is not None, case.actuators is not None
    fast = current_time_constants(case) if motors else None
    out |= torque_metrics(
        S["tau"], S["u"], case.plant.saturation, t, omega, first_fault, S.get("tau_mid") if sampled else None, fast,
        held=sampled and not motors,
    )  # fmt: skip
    out["singularity_margin_min"] = singularity_margin(S["q"])
    own = ctrl.scheme.metrics  # the scheme's own metrics (switching detection, adaptive weights, diagnosis)
    if own is not None:
        from .errors import PluginError
        from .schemes.hooks import hook
        from .schemes.registry import is_built_in

        try:
            convert = lambda v: _metrics_dict(v, out, not is_built_in(ctrl.scheme))  # noqa: E731
            out |= hook(ctrl.scheme, "metrics", own, case, scheme, t, S, built, ctrl, run, convert=convert)
        except PluginError as exc:  # a plug-in's: the run keeps its log and the common metrics, and fails
            failed = run.status != "ok"  # already stopped (diverged, singular...): its own reason first
            run.status, run.reason = (run.status, f"{run.reason}; and {exc}") if failed else ("error", str(exc))
            out |= {"status": run.status, "reason": run.reason}
    return out


def _metrics_dict(value, common: dict, plugin: bool = True) -> dict:
    """A ``metrics`` hook's result: a dict keyed by names, none of the ``common`` ones (a scheme's own
    metrics never overwrite the run's status, reason or tracking errors), its values what metrics.json holds."""
    from .schemes.hooks import ResultError, one_line

    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise ResultError(f"returned {one_line(repr(value))[:80]}, not a dict of metrics keyed by name")
    if not plugin:  # a built-in scheme's: ftcreport's own (its arrays are stored by storage.store._jsonable)
        return value
    if taken := sorted(set(value) & (set(common) | _SET_AFTER)):
        raise ResultError(f"returned {', '.join(map(repr, taken[:5]))}: names of the run's own metrics (status ...)")
    for key, v in value.items():
        if (why := _not_stored(v)) is not None:
            raise ResultError(
                f"returned {key!r}: {why} (metrics.json holds numbers, text, null and lists or dicts of them)"
            )
    return value


#: metrics the run sets after the scheme's own (run_scheme)
_SET_AFTER = frozenset({"wall_time", "compile_time"})


def _not_stored(v, depth: int = 0) -> str | None:
    """Why ``v`` cannot be a metric of metrics.json (JSON, and a 64-bit number where it is a number), or None."""
    if depth > 8:
        return "nested more than 8 deep"
    if v is None or isinstance(v, bool | np.bool_ | str):
        return None
    if isinstance(v, int | np.integer):
        return None if -(2**63) <= int(v) < 2**63 else f"an integer of {len(str(abs(int(v))))} digits, beyond 64 bits"
    if isinstance(v, float | np.floating):
        return None
    if isinstance(v, np.ndarray):  # stored as its list (storage.store._jsonable)
        return None if v.dtype.kind in "biuf" else f"an array of {v.dtype}"
    if isinstance(v, list | tuple):
        return next((w for x in v if (w := _not_stored(x, depth + 1)) is not None), None)
    if isinstance(v, dict):
        if not all(isinstance(k, str) for k in v):
            return "a dict whose keys are not all text"
        return next((w for x in v.values() if (w := _not_stored(x, depth + 1)) is not None), None)
    return f"a value of type {type(v).__name__}"


def current_time_constants(case: Case) -> np.ndarray:
    """Each wheel's armature-current time constant [s] (robot order, right wheel first): L_a / R_a with the
    static drive (the back-EMF of a held rotor), L_a / K_p with the PI drive (its closed current loop:
    1 / (2 pi f) with the gains of pole-zero cancellation).  The metrics' quadrature of each step's
    transient reads it (evaluation.metrics.step_integrals).  A motor fault that changes R_a is not in it:
    measured on two_link_active_motors with R_a x4 (x10) on robot 1's wheels from 0.5 s, torque_rms at
    dt = 5 ms stays within 5.5e-4 (3.7e-4) of dt/16, as on the healthy case (tests/test_torque_metric.py)."""
    n = case.robots.n
    motors, drives = case.actuators.params(n), case.actuators.drive_params(n)
    per_robot = [m.L_a / (d.kp if d.driver == "pi" else m.R_a) for m, d in zip(motors, drives, strict=True)]
    return np.repeat(np.asarray(per_robot, dtype=float), 2)


def _requirements(case: Case, scheme: str, run: Run, built: Built, t: np.ndarray, S: dict) -> list[dict]:
    """The case's requirements on this run (ftcreport.evaluation.requirements), windows from the run's fault events."""
    from .evaluation.requirements import evaluate_requirements
    from .model import wheel_index

    return evaluate_requirements(
        case.requirements,
        scheme,
        t,
        S,
        built.faults.times,
        case.simulation.duration,
        run.t_end,
        run.status,
        wheel_index=lambda w: wheel_index(w, case.robots.n),
    )


# Why a metric can be null, by its key (the last part of its path in metrics.json).
_NULL_WHY = {
    "recovery_time": "the position error did not enter the recovery band and stay in it before the phase ended",
    "recovery_time_max": "some phase that starts with a fault never recovers (see phases[*].recovery_time)",
    "torque_peak_after_fault": "the run has no fault (or stopped before the first one)",
    "delay": "the applied model never matched the true pattern after this event",
    "detection_delay_max": "some fault was never detected (see the per-event delays)",
    "t_declared": "the fault was never declared",
    "estimate": "the fault was never declared",
    "position_error_max": "no logged sample in this phase (the run stopped before it)",
    "position_error_rms": "no logged sample in this phase (the run stopped before it)",
    "position_error_final": "no logged sample in this phase (the run stopped before it)",
    "position_error_iae": "fewer than two logged samples in this phase",
}
_NOT_METRICS = {"reason", "traceback", "name", "description", "null_reasons", "requirements"}


def explain_nulls(metrics: dict) -> dict:
    """Every metric finite or null with its reason: non-finite floats become None, and
    ``null_reasons`` maps the path of every null (e.g. ``phases[2].recovery_time``) to why."""
    reasons: dict[str, str] = {}
    status = metrics.get("status", "?")
    stopped = "" if status == "ok" else f" (the run ended '{status}': {metrics.get('reason') or 'no reason given'})"

    def walk(v, path: str, key: str):
        if isinstance(v, dict):
            return {k: (x if k in _NOT_METRICS else walk(x, f"{path}.{k}" if path else k, k)) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [walk(x, f"{path}[{i}]", key) for i, x in enumerate(v)]
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            reasons[path] = f"non-finite value ({v}) computed from the logged run{stopped}"
            return None
        if v is None:
            reasons[path] = _NULL_WHY.get(key, "not defined for this run") + stopped
        return v

    out = walk({k: v for k, v in metrics.items() if k != "null_reasons"}, "", "")
    out["null_reasons"] = reasons
    return out


# ---------------------------------------------------------------------- step-size check (run --verify-dt)


def halve_dt(case: Case, source: str = "") -> Case:
    """The case ``run --verify-dt`` compares with: at half the step, logged every 2 * log_every steps (a
    fixed step: the same instants), the sensor on the clock it had (dt: the same noise draws, and a discrete-time
    filter's updates, the UKF's, at the same instants).  An
    error-controlled method also runs at a tenth of rtol and atol:
    its longest step halved too, since a run whose every step is capped at dt (a sampled loop's steps
    land on every sample; or dt binds) takes the same steps at any tolerance.

    Raises CaseError when the refined run is over the limits of ftcreport.infra.limits.
    """
    from .cases import _check_budget, _FieldError
    from .errors import CaseError
    from .runs import AUTO_METHODS

    sim = case.simulation
    update = {"dt": sim.dt / 2, "log_every": sim.log_every * 2}
    if sim.method in AUTO_METHODS:
        update |= {"rtol": sim.rtol / 10, "atol": sim.atol / 10}
    half = case.model_copy(update={"simulation": sim.model_copy(update=update)})
    noise = case.plant.noise
    if noise.sample_time is None:  # the sensor keeps its clock (dt's): the same draws and UKF updates, over two steps
        plant = case.plant.model_copy(update={"noise": noise.model_copy(update={"sample_time": sim.dt})})
        half = half.model_copy(update={"plant": plant})
    if sim.method in AUTO_METHODS and sim.min_step >= sim.dt / 2:  # as Simulation's validator asks of dt
        raise CaseError(
            f"{source or case.name}: --verify-dt: at dt/2, simulation.min_step: {sim.min_step:g} s is not below the "
            f"longest step dt/2 = {sim.dt / 2:g} s (lower min_step to check the step)"
        )
    try:
        _check_budget(half)
    except _FieldError as exc:
        raise CaseError(f"{source or case.name}: --verify-dt: at dt/2, {exc.loc}: {exc.msg}") from None
    return half


def _refined_run(half: dict) -> dict:
    """What the refined run of ``--verify-dt`` was: its method and step, or its tolerances and longest step."""
    g = half.get("integrator") or {}
    if "rtol" in g:
        return {"method": g.get("requested", g.get("method")), "rtol": g["rtol"], "atol": g["atol"],
                "max_step": g["max_step"]}  # fmt: skip
    return {"method": g.get("method"), "dt": half.get("dt")}


def _refinement(full: dict, half: dict) -> str:
    """What ``--verify-dt`` refined: "dt = 0.01 s vs 0.005 s", or (error-controlled) "rtol = 1e-06 vs 1e-07,
    atol = 1e-08 vs 1e-09, longest step 0.01 s vs 0.005 s"."""
    a, b = full.get("integrator") or {}, half.get("integrator") or {}
    if "rtol" in a and "rtol" in b:
        return (
            f"rtol = {a['rtol']:g} vs {b['rtol']:g}, atol = {a['atol']:g} vs {b['atol']:g}, "
            f"longest step {a['max_step']:g} s vs {b['max_step']:g} s"
        )
    return f"dt = {full.get('dt'):g} s vs {half.get('dt'):g} s"


def _recheck_found(check: dict) -> str:
    """What the stop's re-check at dt/4 (fast.recheck._recheck) found, in words: it passed the stop, or where it
    stopped again and how fast the torque grew over the growth detector's window there."""
    if check.get("status") == "ok":
        return "it runs past the stop"
    words = f"it stops again at t = {check['t_end']:.6g} s"
    if check.get("growth") is not None:
        words += f", max |tau| {check['growth']:.3g}x over the growth detector's window"
    return words


def integrator_words(metrics: dict) -> str:
    """The integrator of a run in words (the case page's provenance): the method, auto's pick, the steps."""
    g = metrics.get("integrator") or {}
    if not g:
        return ""
    if "rtol" not in g:  # a fixed step
        words = f"{g.get('method')} at dt = {g.get('dt'):g} s, {g.get('steps')} steps"
        check = g.get("recheck")
        if check:  # what the re-check found; the label it led to is the run's status and reason
            words += f" (its stop re-checked at dt = {check['dt']:g} s: {_recheck_found(check)})"
        return words
    rho = g.get("spectral_radius")
    pick = ""
    if g.get("requested") == "auto" and rho is not None:
        stiff = g.get("method") != "dopri5"
        pick = f"auto: rho dt = {rho * g['max_step']:.3g}, {'stiff' if stiff else 'non-stiff'}; "
    return (
        f"{g.get('method')} ({pick}rtol = {g['rtol']:g}, atol = {g['atol']:g}, longest step {g['max_step']:g} s), "
        f"{g.get('accepted')} steps ({g.get('rejected')} rejected), {g.get('evaluations')} rate evaluations"
    )


def step_change_over(row: dict, rtol: float, atol: float) -> bool:
    """Whether one metric's row of :func:`dt_sensitivity` moved beyond the step check's tolerance: ``atol +
    rtol * max(|a|, |b|)``, or null in one run (the rule the run's verdict and the case page both read)."""
    if row.get("abs_change") is None:
        return True
    scale = max(abs(float(row["dt"])), abs(float(row["dt_half"])))
    return float(row["abs_change"]) > atol + rtol * scale


def dt_sensitivity(full: dict, half: dict, rtol: float = 0.01, atol: float = 1e-6) -> dict:
    """Change of the headline metrics from dt to dt/2 (an error-controlled run: also from rtol, atol to a tenth).

    Converged when both runs end with the same status and every headline metric
    changes by at most ``atol + rtol * max(|a|, |b|)`` (a metric null in exactly one
    run is a change).  A fixed-step method's error at dt is about the change
    from dt to dt/2 times 2^p / (2^p - 1) (p = 4 for RK4), so the change bounds it.
    Empty (and not converged) when the refined run is bit-identical to the run on
    every headline metric and the status: it tested nothing.
    """
    rows, ok, worst, worst_rel = {}, full.get("status") == half.get("status"), "status", 0.0
    empty = ok and all(full.get(k) == half.get(k) for k in HEADLINE_METRICS)
    refined = _refinement(full, half)
    for k in HEADLINE_METRICS:
        a, b = full.get(k), half.get(k)
        if a is None and b is None:
            continue
        if a is None or b is None:
            rows[k] = {"dt": a, "dt_half": b, "abs_change": None, "rel_change": None}
            ok, worst, worst_rel = False, k, math.inf
            continue
        d = abs(float(a) - float(b))
        scale = max(abs(float(a)), abs(float(b)))
        rel = d / scale if scale > 0 else 0.0
        rows[k] = {"dt": a, "dt_half": b, "abs_change": d, "rel_change": rel}
        if step_change_over(rows[k], rtol, atol):
            ok = False
        if rel > worst_rel and d > atol:
            worst, worst_rel = k, rel
    return {
        "dt": full.get("dt"),
        "dt_half": half.get("dt"),
        "refined": refined,
        "refined_run": _refined_run(half),
        "status": f"{full.get('status')} / {half.get('status')}",
        "metrics": rows,
        "rtol": rtol,
        "atol": atol,
        "converged": ok and not empty,
        "empty": empty,
        "worst": worst,
        "worst_rel_change": worst_rel if math.isfinite(worst_rel) else None,
    }
