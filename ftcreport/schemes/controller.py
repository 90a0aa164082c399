r"""A scheme bound to a case's chain and kinematic controller: what the engine runs.

:class:`SchemeController` evaluates a :class:`~ftcreport.schemes.api.Scheme`'s declarations for one
chain, kinematic controller and table (its state size, signals, packed parameters).  The built-in
schemes' Python faces (``ftcreport.control``: ``TrackingController``, ``SwitchingController``, ...)
are subclasses that lay out their state themselves; the engine reads only what is defined here.
"""

from __future__ import annotations

import numpy as np

from ..errors import ModelError
from .api import Scheme, SchemeContext
from .budget import own_memory_problem
from .hooks import ResultError, hook, hook_where, one_line

__all__ = ["ENGINE_SIGNALS", "KINEMATIC_SIGNALS", "SchemeController"]

#: The kinematic controller's logged signals, before every scheme's own (fast.engine splits them).
KINEMATIC_SIGNALS = ("eta_c", "eta_c_dot", "z", "q_d", "eta_d")
#: What every run logs besides the controller's signals (fast.engine._chunk_signals), by name: a scheme's
#: signal or derived signal of one of these names would take its place in the log and the metrics.
ENGINE_SIGNALS = {
    "t": "the time",
    "q": "the chain's configuration",
    "eta": "the chain's velocities",
    "u": "the commanded torques",
    "tau": "the wheels' torques",
    "sigma": "the wheels' effectiveness",
    "ubar": "the wheels' additive faults",
    "xc": "the controller's states",
    "i_a": "the motor currents",
    "z_drive": "the drives' states",
    "tau_mid": "the torques at each step's midpoint",
    "q_meas": "the measured configuration",
}


class SchemeController:
    """A registered scheme bound to a case's chain and kinematic controller (what the engine runs).

    It has no law of its own in Python: the engine runs ``scheme.law`` on the compiled loop.

    Attributes the engine reads: ``scheme``, ``chain``, ``kin``, ``k_v``, ``h`` (the step of the
    kinematic law's central difference), ``P`` (the packed parameters), ``n_own`` (the scheme's own
    states), ``n_states`` (the whole controller state: the kinematic controller's first),
    ``widths`` (``{name: width}`` of the law's signals), ``signal_names``, ``stiff_diagonal``,
    :meth:`initial_state` and :meth:`derived_signals`.
    """

    h = 1e-5  # [s] step of the directional central difference of eta_c (ERRATA P5)
    #: the kinematic signals this scheme's runs show (all are logged; eta_c_dot is the nominal law's)
    kinematic_signals: tuple[str, ...] = ("eta_c", "z", "q_d", "eta_d")

    def __init__(self, scheme: Scheme, chain, kinematic, k_v: float, params=None, saturation=None, case=None) -> None:
        self._bind(scheme, chain, kinematic, k_v, params, saturation, case)
        ctx = self.ctx
        n_own = hook(scheme, "n_states", scheme.n_states, ctx)
        if isinstance(n_own, bool) or not isinstance(n_own, int | np.integer) or n_own < 0:
            where = hook_where(scheme, scheme.n_states)
            raise ModelError(f"{where}scheme {scheme.name}: n_states must be an int >= 0, got {one_line(repr(n_own))}")
        self.n_own = int(n_own)
        self.widths = _widths(scheme, ctx)
        if case is not None and (why := own_memory_problem(scheme.name, self.n_own, self.widths, case)) is not None:
            raise ModelError(f"{hook_where(scheme, scheme.n_states)}{why}")  # before any array of that size
        self.P = hook(scheme, "pack", scheme.pack, ctx)
        stiff = None
        if scheme.stiff is not None:
            n = self.n_own
            stiff = hook(scheme, "stiff", scheme.stiff, ctx, convert=lambda v: _floats(v, n, "stiff"))
        self._finish(stiff)

    # ------------------------------------------------------------------ the parts a face sets itself
    def _bind(self, scheme: Scheme, chain, kinematic, k_v: float, params=None, saturation=None, case=None) -> None:
        """The common attributes (a face calls this first, then lays out its state, then :meth:`_finish`)."""
        self.scheme = scheme
        self.name = scheme.name
        self.chain = chain
        self.kin = kinematic
        self.k_v = float(k_v)
        self.u_limit = saturation
        nz, nq = len(kinematic.z_names), chain.n_q
        self.ctx = SchemeContext(chain, kinematic, self.k_v, params, saturation, kinematic.n_states, 6 + nz + nq, case)

    def _finish(self, stiff_own: np.ndarray | None = None) -> None:
        """The whole state's size, the signal names and the stiff diagonal from ``n_own`` and ``widths``."""
        nk = self.kin.n_states
        self.n_states = nk + self.n_own
        names = self.scheme.derived_names
        derived = hook(self.scheme, "derived_names", names, self, convert=_names) if callable(names) else tuple(names)
        _check_derived(self.scheme, derived, self.widths)
        self.signal_names = (*self.kinematic_signals, *self.widths, *derived)
        self.stiff_diagonal = np.zeros(self.n_states)
        if stiff_own is not None:
            self.stiff_diagonal[nk:] = stiff_own

    def own_initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """The scheme's own states at t0 (``Scheme.initial_state``, default zeros)."""
        if self.scheme.initial_state is None:
            return np.zeros(self.n_own)
        n = self.n_own
        convert = lambda v: _floats(v, n, "initial_state", finite=False)  # noqa: E731  (not finite: its caller says)
        return hook(self.scheme, "initial_state", self.scheme.initial_state, self.ctx, q, eta, convert=convert)

    # ------------------------------------------------------------------ what the engine reads
    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """The whole controller state at t0: the kinematic controller's, then the scheme's own."""
        kin = np.asarray(self.kin.initial_state(t, q), dtype=float).reshape(-1)
        return np.concatenate((kin, self.own_initial_state(t, q, eta)))

    def derived_signals(self, xc: np.ndarray, meas: np.ndarray, costs: bool = True) -> dict[str, np.ndarray]:
        """Signals computed from the logged rows (``Scheme.derived``): ``xc`` the scheme's own states,
        ``meas`` the measured [q, eta], ``costs`` also those only the saved log holds."""
        if self.scheme.derived is None:
            return {}
        return hook(self.scheme, "derived", self.scheme.derived, self, xc, meas, costs)


def _floats(value, n: int, role: str, finite: bool = True) -> np.ndarray:
    """A hook's result as n floats (``stiff``, ``initial_state``), or :class:`ResultError` saying what it was."""
    if value is None:
        raise ResultError(f"returned None, not {n} numbers")
    try:
        x = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ResultError(f"returned {one_line(repr(value))[:80]}, not {n} numbers") from None
    if x.size != n:
        raise ResultError(f"returned {x.size} values, n_states is {n}")
    if finite and not np.all(np.isfinite(x)):
        raise ResultError(f"returned values that are not finite ({one_line(x.tolist())[:80]})")
    return x


def _names(value) -> tuple[str, ...]:
    """``derived_names``'s result as a tuple of names, or :class:`ResultError`."""
    if isinstance(value, str) or not hasattr(value, "__iter__"):
        raise ResultError(f"returned {one_line(repr(value))[:80]}, not a tuple of names")
    return tuple(value)


def _name_problem(name) -> str | None:
    """Why a signal's name cannot be logged beside the engine's ('name 5 is not an identifier', "'q' is a name
    the engine logs (the chain's configuration); rename it"), else None: the law's and derived signals alike."""
    if not isinstance(name, str) or not name.isidentifier():
        return f"name {name!r} is not an identifier"
    if name in KINEMATIC_SIGNALS:
        return f"{name!r} is a kinematic signal the engine logs; rename it"
    if name in ENGINE_SIGNALS:
        return f"{name!r} is a name the engine logs ({ENGINE_SIGNALS[name]}); rename it"
    return None


def _check_derived(scheme: Scheme, names: tuple[str, ...], widths: dict[str, int]) -> None:
    """The derived signals' names: identifiers, none the engine's, the kinematic controller's or the law's."""
    where = hook_where(scheme, scheme.derived_names if callable(scheme.derived_names) else scheme.derived)
    for name in names:
        if (why := _name_problem(name)) is not None:
            raise ModelError(f"{where}scheme {scheme.name}: derived signal {why}")
        if name in widths:
            raise ModelError(
                f"{where}scheme {scheme.name}: derived signal {name!r} is also a signal of the law (signals)"
            )


def _widths(scheme: Scheme, ctx: SchemeContext) -> dict[str, int]:
    """The declared signals, checked: identifiers, whole widths >= 1, no kinematic or engine signal's name."""
    widths = hook(scheme, "signals", scheme.signal_widths, ctx)
    where = hook_where(scheme, scheme.signals)
    for name, width in widths.items():
        if (why := _name_problem(name)) is not None:
            raise ModelError(f"{where}scheme {scheme.name}: signal {why}")
        if isinstance(width, bool) or not isinstance(width, int | np.integer) or width < 1:
            raise ModelError(f"{where}scheme {scheme.name}: signal {name!r}: width must be an int >= 1, got {width!r}")
    return {k: int(v) for k, v in widths.items()}


def write_reason(ctrl: SchemeController, which: int, t: float) -> str:
    """Why a run stopped when the scheme wrote past a buffer (the loop's guard cells, E_LAW_WRITE)."""
    name = ctrl.scheme.name
    at = f"at t = {t:.6g} s"
    if which == 0:
        nw = ctrl.chain.n_wheels
        return f"scheme '{name}': the law wrote past out.u ({nw} wheel torques) {at}; it writes out.u[0:{nw}] only"
    if which == 1:
        return (
            f"scheme '{name}': the law wrote past out.dx ({ctrl.n_own} state rates: n_states) {at}; declare "
            "every state it has in n_states"
        )
    if which == 3:
        return (
            f"scheme '{name}': the discrete update wrote past its {ctrl.n_own} states (n_states) {at}; declare every "
            "state it has in n_states"
        )
    widths = ctrl.widths
    total = sum(widths.values())
    if not widths:
        return f"scheme '{name}': the law wrote into out.sig {at}, but the scheme declares no signal (Scheme.signals)"
    last = list(widths)[-1]
    listed = ", ".join(f"{k} ({v})" for k, v in widths.items())
    return (
        f"scheme '{name}': the law wrote past its declared signals {at}: past '{last}', the last of {listed}, "
        f"out.sig[0:{total}]; declare every signal it writes, with its width, in Scheme.signals"
    )
