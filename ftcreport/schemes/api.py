r"""The scheme interface: what a scheme declares and what its compiled law is handed (no numba here).

This module is the whole contract between the engine (``ftcreport.fast``) and a scheme, built-in
or plug-in; the engine imports it and no concrete scheme.

**A scheme** (:class:`Scheme`) is a name, a parameters model (the case's ``[schemes.<name>]``
table), ``pack(ctx) -> P`` (what its compiled law reads), its state size and initial state, the
signals its law logs, the law and an optional discrete update, and how the reports show it.

**The law** is a numba function of five named structures; it returns nothing::

    @schemes.jit
    def law(P, step, terms, x, out):
        out.u[:] = schemes.law_for_pattern(terms.MB, terms.w, P.healthy)   # the wheel torques
        out.dx[0] = ...                                                 # its states' rates
        out.sig[0] = ...                                                # its declared signals

- ``P``: the tuple ``pack`` returned;
- ``step`` (:class:`Step`): ``t``, the measured ``q`` and ``eta``, the controller's chain
  ``model`` (``schemes.reduced(step.model, q, eta)`` gives Mbar1, Mbar2, Cbar, Bbar, S, Sdot of
  (2.70)), the true faults ``sigma_true`` and ``ubar_true`` (an oracle's; a real scheme must not
  read them) and ``info``, the error flag (``info[0] != 0`` stops the run);
- ``terms`` (:class:`Terms`): the matched dynamic law's terms of (3.35)-(3.37) at the measured
  state, computed by the engine from the case's kinematic controller and reference: ``w``,
  ``MB = Mbar1^-1 Bbar``, ``g`` and ``eta_e = eta - eta_c``;
- ``x``: the scheme's own states (``n_states`` of them), **read-only** in the law;
- ``out`` (:class:`Out`): ``u`` (2n,), ``dx`` (its states' rates) and ``sig`` (its declared
  signals, in the order of ``signals``), views of buffers the engine owns, of exactly the
  declared sizes.  The engine logs what it wants of them; the law always writes.

The kinematic controller's state, the kinematic signals, the offsets into the controller state
and the signal row, and whether a step is logged are the engine's.

**The discrete update** ``disc(P, step, x)`` runs after every step (and at t0 when ``start``) and
changes ``x`` (its own states, writable here) in place: switching rules, projections, a sampled
filter.  ``schemes.terms_at(step, eta, k_v)`` gives it (and a law that needs them elsewhere than at
the measured velocity, e.g. at an estimate) the terms at another velocity.

**What cannot happen.** A law cannot write its state (a typing error at compile time, naming the
line).  Every function a plug-in compiles with ``schemes.jit`` is compiled with numba's
``boundscheck=True`` (ftcreport.jit.compiling.jit): an out-of-bounds index, read or write, raises
inside the loop, which stops the run (``status = "error"``, never ``ok``) naming the scheme, the
output, the index, the time and the line (fast.loop._raised, fast.stops.law_raised_reason).  Each of
``out``'s views is also followed by guard cells the engine checks after every call of the law (and
the discrete update's state after every update): a write up to :data:`N_GUARD` cells past a
declared width by a law compiled without bounds checks (a built-in's) stops the
run with an error naming the scheme and the buffer.  A plug-in's
declared signals are checked finite at every logged step: a NaN or inf there, from a finite state,
stops the run with an error naming ``out.sig[j]``, the signal, the value and the time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "GUARD",
    "N_GUARD",
    "TERMS_MODES",
    "Out",
    "Scheme",
    "SchemeContext",
    "Step",
    "Terms",
]

#: How the engine provides the matched terms (``Scheme.terms``): "measured", at the measured state
#: before every call of the law (the default); "own", not at all (the law calls ``terms_at`` where
#: it needs them, e.g. at an estimated velocity; the logged kinematic signals are those of its last
#: evaluation, else the engine's at the measured state); "none", never (a scheme that ignores the
#: kinematic controller: its signals are not logged, NaN).
TERMS_MODES = {"measured": 0, "own": 1, "none": 2}

#: Guard cells after each buffer a law writes, and the value they hold (checked after every call).
N_GUARD = 8
GUARD = -(2.0**1021) * 1.2345678901234567


class Step(NamedTuple):
    """What a law is told at one evaluation (built by the loop; the law reads it)."""

    t: float
    q: np.ndarray  # (n + 2,) measured configuration [x, y, theta_n, ..., theta_1]
    eta: np.ndarray  # (2,) measured velocities [v_n, omega_1]
    sigma_true: np.ndarray  # (2n,) the effectiveness the plant applies (an oracle's only)
    ubar_true: np.ndarray  # (2n,) the friction the plant applies [N m] (an oracle's only)
    model: Any  # the controller's chain model (jit.packed.Chain): schemes.reduced(model, q, eta)
    info: np.ndarray  # (4,) the error flag: info[0] != 0 stops the run (code, then three numbers)
    kin: Any  # the engine's kinematic side (opaque): what schemes.terms_at reads


class Terms(NamedTuple):
    """The matched dynamic law's terms (3.35)-(3.37) at one state: Mbar1 eta_e' = ... = MB tau - w terms.

    ``w = -k_v eta_e - T^T f_eta + Mbar1^-1 (Mbar2 eta + Cbar) + etadot_c``, ``MB = Mbar1^-1 Bbar``,
    ``g = -Mbar1^-1 (Mbar2 eta + Cbar)``, ``eta_e = eta - eta_c``: ``u = (MB diag(sigma))^+ w`` gives
    ``eta_e' = -k_v eta_e - T^T f_eta`` when sigma is the true pattern (control.tracking_compiled.law_terms).
    """

    w: np.ndarray  # (2,)
    MB: np.ndarray  # (2, 2n)
    g: np.ndarray  # (2,)
    eta_e: np.ndarray  # (2,)


class Out(NamedTuple):
    """What a law writes: views of the engine's buffers, of exactly the declared sizes."""

    u: np.ndarray  # (2n,) the wheel torque command [N m]
    dx: np.ndarray  # (n_states,) the rates of the scheme's own states
    sig: np.ndarray  # the declared signals, in the order of Scheme.signals


@dataclass(frozen=True)
class SchemeContext:
    """What a scheme's ``pack``, ``n_states``, ``initial_state`` and ``signals`` may read.

    chain : the controller's model (``ftcreport.model.Chain``); kin : the case's kinematic
    controller; k_v : the velocity-error gain; params : the validated ``[schemes.<name>]``
    table (the scheme's parameter model) or None; saturation : the plant's torque limit [N m]
    or None.  n_kin_states, n_kin_signals: the kinematic controller's states and signals, which the
    engine keeps before the scheme's own (a law never needs them).  case : the validated case
    (``ftcreport.cases.Case``: its robots, actuators, ...), None outside a case file.
    """

    chain: Any
    kin: Any
    k_v: float
    params: Any
    saturation: float | None
    n_kin_states: int
    n_kin_signals: int
    case: Any = None


def _no_states(ctx: SchemeContext) -> int:
    return 0


@dataclass(frozen=True)
class Scheme:
    """A registered FTC scheme (:func:`ftcreport.schemes.register`).

    What every scheme declares:

    name : its key in case files (``[schemes.<name>]``) and reports;
    law : the compiled law (the module docstring), or ``"module:function"`` (imported on first use);
    pack : ``ctx -> P``, the law's parameters (numbers and arrays; a NamedTuple reads best);
    params : the pydantic model of its case table (None: no parameters but ``k_v``);
    n_states : ``ctx -> int``, the scheme's own states;
    initial_state : ``(ctx, q0, eta0) -> (n_states,)``, default zeros;
    discrete : the compiled discrete update, or ``"module:function"`` (default none);
    signals : ``{name: width}`` of what the law writes into ``out.sig``, or ``ctx -> {name: width}``;
    terms : how the engine provides the matched terms (:data:`TERMS_MODES`);
    family : how the reports group it: ``"passive"``, ``"active"``, ... (``"baseline"``, ``"bound"``
        and ``"ablation"`` are not contestants in the comparisons);
    description, reference : one line each, shown on the report pages.

    What the built-in schemes also use (each optional):

    label : its name in the reports' sentences (default: the name); summary : the one-line description
    of its ``[schemes]`` field (default: the description); color : its line colour in the figures;
    controller : ``(scheme, ctx) -> SchemeController``, the Python face bound to a case (default:
    :class:`ftcreport.schemes.SchemeController`); derived : ``(controller, xc, meas, costs) -> {name:
    rows}``, signals computed from the logged rows (``xc``: the scheme's own states; ``meas``: the
    measured [q, eta]; ``costs``: also the ones only the saved log holds) with their names in
    ``derived_names`` (``ctx -> tuple``); stiff : ``ctx -> (n_states,)``, the exact diagonal of its
    states' linear part (ROS2 and ETD2 use it); start : the discrete update also runs at t0; metrics :
    ``(case, scheme, t, S, built, controller, run) -> dict``, its own metrics; default_run : run on
    every case unless ``schemes.run`` narrows the list (ftcreport.evaluation.families); defaults : ``(case, k_v) ->
    table``, the table a case that does not give one gets; not_applicable : ``(case, k_v) -> str |
    None``, why a default table is not added; validate : ``(table, case) -> None``, raising
    ``fields.FieldError`` for a table that does not fit the case; budget : ``(n, models) -> (values
    logged per sample, bytes of its bank)`` beyond the common ones (ftcreport.schemes.budget); cost :
    ``(case) -> float``, a run's relative cost per step (a batch starts the longest first).
    """

    name: str
    law: Any
    pack: Callable[[SchemeContext], tuple] | None = None
    params: Any = None
    n_states: Callable[[SchemeContext], int] = _no_states
    initial_state: Callable[[SchemeContext, np.ndarray, np.ndarray], np.ndarray] | None = None
    discrete: Any = None
    signals: dict[str, int] | Callable[[SchemeContext], dict[str, int]] = field(default_factory=dict)
    terms: str = "measured"
    family: str = "user"
    description: str = ""
    reference: str = ""
    label: str = ""
    summary: str = ""
    color: str | None = None
    controller: Callable[..., Any] | None = None
    derived: Callable[..., dict] | None = None
    derived_names: tuple[str, ...] | Callable[[Any], tuple[str, ...]] = ()
    stiff: Callable[[SchemeContext], np.ndarray] | None = None
    start: bool = False
    metrics: Callable[..., dict] | None = None
    default_run: bool = False
    defaults: Callable[..., Any] | None = None
    not_applicable: Callable[..., str | None] | None = None
    validate: Callable[..., None] | None = None
    budget: Callable[..., tuple[int, int, int]] | None = None
    cost: Callable[..., float] | None = None

    def signal_widths(self, ctx: SchemeContext) -> dict[str, int]:
        return dict(self.signals(ctx) if callable(self.signals) else self.signals)

    @property
    def contestant(self) -> bool:
        """Whether the comparisons race it (the baseline, the bound and ablations are reference lines)."""
        return self.family not in ("baseline", "bound", "ablation")

    @property
    def display(self) -> str:
        return self.label or self.name
