"""Exception hierarchy of ftcreport.

Every error the package raises on purpose derives from :class:`FtcError`; the
CLI turns these into a one-line message and an exit code, never a traceback.
"""

from __future__ import annotations

import math
import re

__all__ = [
    "BIDI",
    "BIDI_CONTROLS",
    "CASE_ERRORS",
    "CaseError",
    "FaultError",
    "FtcError",
    "ModelError",
    "PluginError",
    "RunEnvironmentError",
    "SingularityError",
    "StoredCaseChangedError",
    "UncompensableError",
    "articulation_reason",
    "bound_reason",
    "chained_reason",
    "controlled_reason",
    "environment_cause",
    "interrupted_message",
    "kappa_reason",
    "min_step_reason",
    "nonfinite_reason",
    "note_stored",
    "persists_reason",
    "printable",
    "reference_articulation_reason",
    "reference_speed_reason",
    "step_growth_reason",
    "step_words",
    "stored_note",
    "trial_stage_reason",
    "two_link_reason",
    "vanishes_reason",
    "with_step",
]


class FtcError(Exception):
    """Base class of the errors ftcreport raises deliberately."""

    exit_code = 2


class CaseError(FtcError):
    """A case file is malformed or names something impossible.

    The message names the file, the field path and the reason, e.g.
    ``cases/x.toml: faults[2].wheel: '4r' is not a wheel of a 3-robot chain``.
    A file with several errors has them all in ``lines`` (one ``file: field: reason`` each,
    the message's first); the message is the first with the count of the others.
    """

    def __init__(self, message: str, lines: tuple[str, ...] | list[str] | None = None) -> None:
        super().__init__(message)
        self.lines: tuple[str, ...] = tuple(lines) if lines else (message,)


class ModelError(FtcError, ValueError):
    """Impossible physical parameters or inconsistent array shapes."""


class FaultError(FtcError, ValueError):
    """A fault schedule that cannot be applied (bad wheel, time or value)."""


class UncompensableError(FtcError):
    """A failure pattern violates the redundancy condition rank(Bbar sigma) = 2."""


class SingularityError(FtcError):
    """The state approaches a singular configuration (ERRATA P4)."""


class PluginError(ModelError):
    """A plug-in scheme's own code raised (its pack, n_states, signals, stiff, initial_state or derived):
    the message names its file and line, the scheme and the hook; a run of it ends with status error."""


class ReferenceError(FtcError, ValueError):
    """An infeasible reference (speed near 0, articulation angle near 90 deg)."""


# --------------------------------------------------------------------------- the case's own error, or not
class StoredCaseChangedError(FtcError):
    """A stored case file that no longer hashes as the content its runs were made from (edited since, or
    hashed otherwise by other code: storage.store.load_stored_case): its page says so instead of showing it."""


class RunEnvironmentError(FtcError):
    """A run that failed because of where it ran, not because of its case: never stored as its result.

    Raised by :func:`ftcreport.runner.run_scheme` for an exception of the environment (see
    :func:`environment_cause`); code that meets such a condition itself (a compiled-code cache it
    cannot use) may raise it directly.  A batch reports the run as failed for this invocation only,
    so the next one retries it.
    """

    exit_code = 1


#: What a run raises about its own case, stored as the run's result (status ``error``): the case asks
#: for something impossible (FtcError) or its numbers fail (ArithmeticError; numpy's LinAlgError is
#: added by ftcreport.runner, which imports numpy).  Anything else is not the case's outcome.
CASE_ERRORS: tuple[type[BaseException], ...] = (FtcError, ArithmeticError)


def environment_cause(exc: BaseException) -> str | None:
    """What of the environment made a run fail (``"UnpicklingError: ..."``), or None when ``exc`` is not such.

    The environment: an OS error (a file, a disk, a permission), memory, an interrupt, and the
    compiled-code machinery: numba's or llvmlite's errors, and a cache file that cannot be loaded
    (``EOFError``, ``pickle.UnpicklingError``, ``ImportError`` of a cached module).  These say
    nothing about the case: the same run elsewhere or later may succeed.
    """
    env = (RunEnvironmentError, OSError, MemoryError, EOFError, ImportError, KeyboardInterrupt, SystemExit)
    module = (type(exc).__module__ or "").split(".")[0]
    unpickling = any(
        c.__name__ == "UnpicklingError" and c.__module__ in ("pickle", "_pickle") for c in type(exc).__mro__
    )
    if isinstance(exc, env) or unpickling or module in ("numba", "llvmlite"):
        return f"{type(exc).__name__}: {exc}".rstrip(": ")
    return None


# --------------------------------------------------------------------------- text that cannot break a file
#: bidirectional embeddings, overrides and isolates (U+202A..U+202E, U+2066..U+2069): they reorder the
#: text around them on a terminal and in a page, so what is shown is not what is stored ("Trojan Source")
BIDI_CONTROLS = "\u202a-\u202e\u2066-\u2069"
_CONTROL = re.compile(rf"[\x00-\x1f\x7f-\x9f\ud800-\udfff\ufffe\uffff{BIDI_CONTROLS}]")
BIDI = re.compile(f"[{BIDI_CONTROLS}]")  # one of them


def printable(text: object, keep: str = "") -> str:
    """``text`` with every control character (C0, DEL, C1), bidirectional control (:data:`BIDI_CONTROLS`), lone
    surrogate and non-character written as an escape (``\\x1b``, ``\\u202e``, ``\\ud800``), except those in
    ``keep``: safe on a terminal, in HTML and in XML 1.0."""
    s = str(text)
    if not _CONTROL.search(s):
        return s

    def esc(m: re.Match) -> str:
        ch = m.group()
        if ch in keep:
            return ch
        o = ord(ch)
        return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}"

    return _CONTROL.sub(esc, s)


# --------------------------------------------------------------------------- interrupts
def note_stored(exc: BaseException, count: int, noun: str = "run") -> None:
    """Tell the CLI's interrupt message (or an OS error's line: :func:`stored_note`) how many finished
    ``noun``s the command stored before ``exc``.

    The innermost note wins (the code that stored them knows best); see :func:`interrupted_message`.
    """
    if getattr(exc, "ftc_stored", None) is None:
        exc.ftc_stored = (int(count), noun)  # type: ignore[attr-defined]


def interrupted_message(exc: BaseException) -> str:
    """The one line of an interrupted command: how many finished runs it stored (:func:`note_stored`).

    A command that stores nothing (or was interrupted before it could) says only that it was interrupted.
    """
    signum = getattr(exc, "signum", None)  # ftcreport.infra.lifetime.Interrupted: SIGTERM and SIGHUP are named
    how = "interrupted" if signum in (None, 2) else f"interrupted by {exc.args[0] if exc.args else signum}"
    stored = getattr(exc, "ftc_stored", None)
    if stored is None:
        return how
    count, noun = stored
    if count == 0:
        return f"{how} before any {noun} finished; nothing was stored"
    return f"{how}; {_stored_words(count, noun)}"


def _stored_words(count: int, noun: str) -> str:
    them = f"1 finished {noun} is" if count == 1 else f"{count} finished {noun}s are"
    return f"{them} stored, re-run the same command to resume"


def stored_note(exc: BaseException) -> str:
    """What a command that failed on ``exc`` (an OS error: a full disk...) had stored before it, as the end of
    its one line (``"; 2 finished runs are stored, re-run the same command to resume"``), or ``""`` when the
    command noted nothing (:func:`note_stored`)."""
    stored = getattr(exc, "ftc_stored", None)
    if stored is None:
        return ""
    count, noun = stored
    return f"; no {noun} was stored before it" if count == 0 else f"; {_stored_words(count, noun)}"


# --------------------------------------------------------------------------- reasons
# One wording per stop. The Python faces raise with these (the kinematic laws, the references); the
# compiled engine (ftcreport.fast.engine), which reports the same stops as error codes, words them
# with the same functions, so a stop reads the same wherever it is met.
def nonfinite_reason(what: str, t: float) -> str:
    """``what``: "state" or "control or derivative"."""
    return f"non-finite {what} at t = {t:.6g} s"


def bound_reason(what: str, values: list[float], bound: float, unit: str = "") -> str:
    return f"{what} {values} exceeds the bound {bound}{unit}"


def articulation_reason(i: int, angle_deg: float, margin_rad: float) -> str:
    """Articulation angle between robots i + 1 and i + 2 (0-based i) near 90 deg."""
    return (
        f"articulation angle theta_{i + 1} - theta_{i + 2} reached {angle_deg:.2f} deg "
        f"(within {math.degrees(margin_rad):.2g} deg of 90 deg)"
    )


def two_link_reason(label: str, angle_deg: float) -> str:
    """The two-link law (3.8)-(3.29) is singular where cos e_theta or cos phi vanishes (ERRATA P4)."""
    return f"{label} = {angle_deg:.1f} deg: the two-link law's singular set (90 deg, ERRATA P4)"


def chained_reason(label: str, angle_deg: float, where: str = "") -> str:
    """The chained form (3.67)-(3.106) is singular where a heading in its frame or an articulation angle is 90 deg."""
    return f"{label} = {angle_deg:.2f} deg{where}: the chained form's singular set (90 deg, ERRATA P4)"


def kappa_reason(kd: float) -> str:
    return f"kappa - Delta_1 = {kd:.3g}: the backstepping law's singular set (kappa = Delta_1, ERRATA E12d)"


def reference_speed_reason(t: float, robot: int, speed: float, min_speed: float) -> str:
    """``robot``: 1-based index of the robot whose reference speed vanishes."""
    return (
        f"infeasible reference at t = {t:.4g} s: the speed of P_{robot} is {speed:.3g} m/s "
        f"(below {min_speed:g}); the chain needs v_d != 0 (see the [reference] table)"
    )


def reference_articulation_reason(t: float, i: int, angle_deg: float, max_rad: float) -> str:
    return (
        f"infeasible reference at t = {t:.4g} s: articulation angle theta_{i + 1} - theta_{i + 2} "
        f"= {angle_deg:.1f} deg exceeds {math.degrees(max_rad):.0f} deg (path too curved for these link lengths: "
        "make the [reference] path's turns wider or robots.d shorter)"
    )


def step_growth_reason(t: float, g0: float, g1: float, steps: int, factor: float, how: str) -> str:
    """A geometric growth of the applied torque from step to step (``how``: the step, :func:`step_words`)."""
    return (
        f"at t = {t:.6g} s max |tau| grew more than {factor:.3g}x per step for {steps} steps "
        f"({g0:.3g} -> {g1:.3g} N m; {how})"
    )


def trial_stage_reason(t: float, detail: str, how: str, method: str, stage: bool = True) -> str:
    """A trial stage of the integrator (or the new state of the step) left the domain from a regular state."""
    where = f"a {method} trial stage left the domain" if stage else f"the {method} step blew up"
    start = " (at t = 0 the start pose, initial.headings_deg, may be too close to the singularity)" if t == 0.0 else ""
    return f"at t = {t:.6g} s {where} ({detail}) while the accepted state is regular ({how}){start}"


def step_words(dt: float, method: str, rtol: float | None = None, atol: float | None = None) -> str:
    """The step a reason names: ``dt = 0.01 s, rk4`` (fixed) or ``dopri5 at rtol = 1e-06, atol = 1e-08``."""
    if rtol is None:
        return f"dt = {dt:g} s, {method}"
    return f"{method} at rtol = {rtol:g}, atol = {atol:g}, longest step dt = {dt:g} s"


def with_step(reason: str, how: str) -> str:
    """A stop's reason with the step named (``how``: :func:`step_words`)."""
    return f"{reason} ({how})"


# The re-check of a fixed-step stop (issue 36 item 4): the interval again at dt/4 by the same method
# (``finer``: "at dt/4 = 0.005 s").
def vanishes_reason(reason: str, finer: str, t_to: float) -> str:
    """``step_unstable``: the run at dt/4 passes the instant where the step dt stopped."""
    return (
        f"step unstable: {reason}; {finer} the same run passes this instant (checked to t = {t_to:.6g} s): "
        'the step, not the loop, stopped it (a smaller dt, or method = "auto")'
    )


def controlled_reason(reason: str, finer: str, t_fine: float, how: str, t_to: float, h_min: float | None) -> str:
    """``step_unstable``: the run at dt/4 stops too, but an error-controlled step passes the instant."""
    small = f"; its steps fell to {h_min:.2g} s there" if h_min is not None else ""
    return (
        f"step unstable: {reason}; {finer} the same run stops too (t = {t_fine:.6g} s), but an error-controlled step "
        f"({how}) passes this instant (checked to t = {t_to:.6g} s{small}): the step, not the loop, stopped it "
        '(a much smaller dt, or method = "auto")'
    )


def persists_reason(
    reason: str, dt: float, finer: str, t: float, t_fine: float, singular: bool, trial: bool = False
) -> str:
    """``singular`` or ``diverged``: the run at dt/4 stops too, in the stop's window (``trial``: the step dt's stop was
    a trial stage reaching the set)."""
    by = " by a trial stage" if trial else ""
    again = f"at dt = {dt:g} s (t = {t:.6g} s) and again {finer} (t = {t_fine:.6g} s)"
    if singular:
        return f"{reason}; reached{by} {again}: the law's own singular set, not the step"
    return f"{reason}; the blow-up persists {again}: the loop's own divergence, not the step's"


def min_step_reason(t: float, h: float, how: str, min_step: float, cause: str) -> str:
    """An error-controlled run whose step fell below its minimum (``cause``: the last rejection's)."""
    return (
        f"at t = {t:.6g} s the error-controlled step ({how}) fell below min_step = {min_step:g} s "
        f"(to {h:.3g} s): {cause}"
    )
