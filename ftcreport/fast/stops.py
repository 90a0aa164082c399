"""A compiled run's stop: the error code's status and reason, and whether the state is at the singular set."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

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
from ..jit.packed import (
    AT_STATE,
    AT_TRIAL,
    E_CHAINED_ART,
    E_CHAINED_THN,
    E_KAPPA,
    E_LAW_NONFINITE,
    E_LAW_RAISED,
    E_LAW_SIGNAL,
    E_LAW_WRITE,
    E_NONFINITE_DERIV,
    E_NONFINITE_STATE,
    E_POSITION,
    E_REF_ART,
    E_REF_SPEED,
    E_SPEED,
    E_STATE_SINGULAR,
    E_STEP_GROWTH,
    E_STEP_JUMP,
    E_TWO_LINK_ETH,
    E_TWO_LINK_PHI,
    E_UKF,
    Ref,
)
from .integrators import AUTO_METHODS

if TYPE_CHECKING:
    from .engine import Spec


# --------------------------------------------------------------------------- errors
def _how(settings, used: str | None = None) -> str:
    """The step a reason names: dt and the method (fixed), or the method used and its tolerances."""
    if settings.method in AUTO_METHODS:
        return step_words(settings.dt, used or settings.method, settings.rtol, settings.atol)
    return step_words(settings.dt, settings.method)


def _message(info: np.ndarray, t: float, settings, ref: Ref, how: str = "") -> tuple[str, str]:
    """(status, reason) of a kernel error code (one wording per stop: ftcreport.errors)."""
    how = how or _how(settings)
    code = int(info[0])
    a, b, c = (float(v) for v in info[1:4])
    if code == E_STATE_SINGULAR:
        return "singular", articulation_reason(int(a), b, settings.singularity_margin)
    if code == E_LAW_NONFINITE:
        return "error", law_nonfinite_reason(None, int(b), c, a)
    if code == E_LAW_SIGNAL:
        return "error", law_signal_reason(None, int(b), c, a)
    if code == E_LAW_RAISED:
        return "error", law_raised_reason(None, info)
    if code in (E_NONFINITE_STATE, E_NONFINITE_DERIV):
        reason = nonfinite_reason("state" if code == E_NONFINITE_STATE else "control or derivative", a)
        return "diverged", with_step(reason, how)
    if code == E_SPEED:
        return "diverged", with_step(bound_reason("velocity", [a, b], settings.max_speed), how)
    if code == E_POSITION:
        return "diverged", with_step(bound_reason("position", [a, b], settings.max_position, " m"), how)
    if code == E_TWO_LINK_ETH:
        return "singular", two_link_reason(f"heading error e_theta of robot {ref.n}", a)
    if code == E_TWO_LINK_PHI:
        return "singular", two_link_reason("articulation angle theta_1 - theta_2", a)
    if code == E_CHAINED_THN:
        return "singular", chained_reason(f"theta_{ref.n}", a, " in its frame")
    if code == E_CHAINED_ART:
        return "singular", chained_reason(f"theta_{int(a) + 1} - theta_{int(a) + 2}", b)
    if code == E_KAPPA:
        return "singular", kappa_reason(a)
    if code == E_REF_SPEED:
        return "error", reference_speed_reason(a, int(b), c, ref.min_speed)
    if code == E_REF_ART:
        return "error", reference_articulation_reason(a, int(b), c, ref.max_art)
    if code == E_UKF:
        from ..jit.packed import ukf_message

        reason = f"the UKF stopped at t = {b:.6g} s: {ukf_message(int(a))}"
        return "diverged", with_step(reason, how)
    if code == E_STEP_GROWTH:
        from ..runs import GROWTH_FACTOR, GROWTH_STEPS

        return "step_unstable", step_growth_reason(a, b, c, GROWTH_STEPS, GROWTH_FACTOR, how)
    return "error", f"compiled engine: unknown error code {code} at t = {t:.6g} s"


def law_nonfinite_reason(spec: Spec | None, j: int, value: float, t: float) -> str:
    """Why a run stopped when the scheme's law returned a non-finite command (E_LAW_NONFINITE): its inputs
    were finite (the state is checked before), so the law computed it."""
    from ..model import wheel_names

    who = f"scheme '{spec.controller.scheme.name}'" if spec is not None else "the scheme"
    wheels = wheel_names(spec.controller.chain.n) if spec is not None else []
    wheel = f" (wheel {wheels[j]})" if j < len(wheels) else ""
    return (
        f"{who}: its law returned a non-finite command out.u[{j}]{wheel} = {value} at t = {t:.6g} s from a "
        "finite state (a division by zero or a NaN inside the law; 'ftcreport schemes check FILE' runs it with "
        "bounds checks)"
    )


def law_signal_reason(spec: Spec | None, j: int, value: float, t: float) -> str:
    """Why a run stopped when a plug-in's law wrote a non-finite value into a declared signal (E_LAW_SIGNAL) at a
    logged step, from a finite state: the signal's index into out.sig and its declared name."""
    who = f"scheme '{spec.controller.scheme.name}'" if spec is not None else "the scheme"
    names = []
    if spec is not None:
        for name, width in spec.controller.widths.items():
            names += [name] if width == 1 else [f"{name}[{i}]" for i in range(width)]
    named = f" ({names[j]})" if j < len(names) else ""
    return (
        f"{who}: its law wrote a non-finite signal out.sig[{j}]{named} = {value} at t = {t:.6g} s from a finite "
        "state (a division by zero or a NaN inside the law); the run keeps its rows before it ('ftcreport schemes "
        "check FILE' tests the signals at a few states only)"
    )


def law_raised_reason(spec: Spec | None, info: np.ndarray, bufs: tuple | None = None) -> str:
    """Why a run stopped when a plug-in's law or discrete update raised inside the loop (E_LAW_RAISED): numba's
    ``boundscheck`` (an index out of bounds, read or write: every plug-in function is compiled with it) or
    another exception numba raises (a shape mismatch).  The compiled code cannot say which array, index or
    line: the call is run again in Python on the inputs the loop recorded (``bufs``, the law buffers, their
    ``rec``), where numpy names the index and the size, and the output (:class:`_Named`) and line are found."""
    which = "discrete update" if int(info[1]) == 1 else "law"
    t = float(info[2])
    who = f"scheme '{spec.controller.scheme.name}'" if spec is not None else "the scheme"
    found = None
    if spec is not None and bufs is not None and len(bufs) > 6:
        try:
            found = _rerun(spec, bufs[6])
        except Exception:  # the reason is still given, without the detail
            found = None
    sizes = ""
    if spec is not None:
        c = spec.controller
        declared = ", ".join(f"{k} ({v})" for k, v in c.widths.items()) or "none declared"
        n_sig = sum(c.widths.values())
        sizes = f": out.u[0:{c.chain.n_wheels}], out.dx[0:{c.n_own}], out.sig[0:{n_sig}] ({declared})"
    if found is not None:
        kind, detail, line = found
        at = f" ({line})" if line else ""
        what = f"its {which} raised {kind} at t = {t:.6g} s{at}: {detail}"
    else:
        what = (
            f"its {which} raised inside the compiled loop at t = {t:.6g} s (numba's boundscheck: an index out of "
            "bounds, or a shape mismatch)"
        )
    return (
        f"{who}: {what}; a law reads and writes only its own x and the declared sizes{sizes} (the run stops "
        "there, its rows before kept; 'ftcreport schemes check FILE' names the line)"
    )


class _Named(np.ndarray):
    """An output array of a law run again in Python (:func:`_rerun`): an IndexError names it (``out.sig[16]``)."""

    def __array_finalize__(self, obj) -> None:
        self.label = getattr(obj, "label", "")

    def __setitem__(self, key, value) -> None:
        try:
            super().__setitem__(key, value)
        except IndexError as exc:
            raise IndexError(f"{self.label}[{_index(key)}]: {exc}") from None

    def __getitem__(self, key):
        try:
            return super().__getitem__(key)
        except IndexError as exc:
            raise IndexError(f"{self.label}[{_index(key)}]: {exc}") from None


def _index(key) -> str:
    if isinstance(key, tuple):
        return ", ".join(_index(k) for k in key)
    if isinstance(key, slice):
        return ":".join("" if v is None else str(v) for v in (key.start, key.stop)) + (
            f":{key.step}" if key.step is not None else ""
        )
    return str(key)


def _named(n: int, label: str) -> _Named:
    out = np.zeros(n).view(_Named)
    out.label = label
    return out


def _rerun(spec: Spec, rec: np.ndarray) -> tuple[str, str, str | None] | None:
    """(exception class, message, ``file:line`` in the user's code) of the law or discrete update run again in
    Python on the inputs ``rec`` the loop recorded (fast.loop._raised); None when it raises nothing here."""

    from ..jit.packed import new_cache
    from ..jit.refs import to_ref
    from ..schemes.api import Out, Step, Terms
    from ..schemes.registry import user_frame

    c = spec.controller
    nq, nx, nw, nk = c.chain.n_q, int(c.n_states), c.chain.n_wheels, int(c.kin.n_states)
    rec = np.array(rec, dtype=float)
    which, t = int(rec[0]), float(rec[1])
    parts, k = [], 2
    for n in (nq, 2, nx, nw, nw, 2, 2 * nw, 2, 2):
        parts.append(rec[k : k + n].copy())
        k += n
    q, eta, xc, st, ut, w, MB, g, ee = parts
    info = np.zeros(4)
    kin = (to_ref(spec.kin), to_ref(spec.ref), to_ref(new_cache(c.chain.n)), xc[:nk].copy(), np.zeros(1))
    step = Step(t, q, eta, st, ut, to_ref(spec.chain), info, kin)
    n_sig = spec.n_sig - spec.n_kin_sig
    try:
        if which == 0:
            x = xc[nk:].copy()
            x.setflags(write=False)
            out = Out(_named(nw, "out.u"), _named(c.n_own, "out.dx"), _named(n_sig, "out.sig"))
            spec.law.py_func(spec.P, step, Terms(w, MB.reshape(2, nw), g, ee), x, out)
        else:
            spec.disc.py_func(spec.P, step, _named(c.n_own, "x"))
    except Exception as exc:  # whatever the law raises is what the user is told, at its innermost own line
        line = user_frame(exc)
        return type(exc).__name__, str(exc).strip().splitlines()[0] if str(exc).strip() else "", line
    return None


def _stop(
    info: np.ndarray,
    where: int,
    t_state: float,
    t_next: float,
    settings,
    ref: Ref,
    spec: Spec | None = None,
    bufs: tuple | None = None,
) -> tuple[str, str, float]:
    """(status, reason, t_end) of a fixed-step stop: a failed trial stage is a step problem, not a singularity
    (until the re-check says otherwise, :func:`_relabel`); a scheme that wrote past its buffers, or whose law
    raised (``bufs``: its law buffers, :func:`law_raised_reason`), is an error naming the scheme and the
    buffer (ftcreport.schemes.api)."""
    if int(info[0]) == E_LAW_RAISED:
        return "error", law_raised_reason(spec, info, bufs), float(info[2])
    if int(info[0]) == E_LAW_WRITE and spec is not None:
        from ..schemes.controller import write_reason

        return "error", write_reason(spec.controller, int(info[1]), float(info[2])), float(info[2])
    if int(info[0]) == E_LAW_NONFINITE:
        return "error", law_nonfinite_reason(spec, int(info[2]), float(info[3]), float(info[1])), float(info[1])
    if int(info[0]) == E_LAW_SIGNAL:
        return "error", law_signal_reason(spec, int(info[2]), float(info[3]), float(info[1])), float(info[1])
    how = _how(settings)
    if int(info[0]) == E_STEP_JUMP:
        from ..runs import step_jump_words

        words = step_jump_words(int(info[1]), float(info[2]), float(info[3]))
        return "step_unstable", trial_stage_reason(t_state, words, how, settings.method, stage=False), t_state
    if where == AT_TRIAL and int(info[0]) not in (E_REF_SPEED, E_REF_ART):
        _, detail = _message(info, t_state, settings, ref)
        return "step_unstable", trial_stage_reason(t_state, detail, how, settings.method), t_state
    if where == AT_STATE:
        return (*_message(info, t_state, settings, ref), t_state)
    return (*_message(info, t_next, settings, ref), t_next)


def _in_singular_set(info, where: int, x: np.ndarray, t: float, settings, spec: Spec) -> bool:
    """Did the run stop because the accepted state reached a law's singular set (ERRATA P4, E12d)?

    At the accepted state (``where`` AT_STATE) a singular code is the set itself.  At a trial stage it
    is only if the accepted state x at t is already near the set the stage reached: within
    JUMP_MARGINS singularity margins of it (|cos| of the angle below sin(20 deg) at the default 2 deg
    margin; for the chained form, its law refusing x with its tolerance widened to that), the band
    within which fast.checks._step_jump does not call an arrival at the set a step's blow-up.  A stage
    that reaches the set from farther out is a blow-up passing through it (``diverged`` if it persists).
    """
    from ..runs import JUMP_MARGINS

    code = int(info[0])
    if code not in _SINGULAR_CODES:
        return False
    if where == AT_STATE:
        return True
    band = math.sin(JUMP_MARGINS * settings.singularity_margin)
    nq = spec.chain.n + 2
    q = x[:nq]
    kin = spec.controller.kin
    if code == E_TWO_LINK_PHI:
        return abs(math.cos(q[3] - q[2])) <= band
    if code == E_TWO_LINK_ETH:  # the heading error of robot n against the reference's heading at t
        return abs(math.cos(q[2] - float(kin.reference.at(t).q_d[2]))) <= band
    if code in (E_CHAINED_THN, E_CHAINED_ART, E_KAPPA) and hasattr(kin, "singular_tol"):
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
_SINGULAR_CODES = frozenset((E_STATE_SINGULAR, E_TWO_LINK_ETH, E_TWO_LINK_PHI, E_CHAINED_THN, E_CHAINED_ART, E_KAPPA))
