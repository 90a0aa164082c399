"""What a simulation returns (:class:`Run`), its statuses, the metric stream, and the stop detectors' constants.

Shared by ftcreport.sim (the front of the engine) and ftcreport.fast.engine (the compiled loop),
so that neither imports the other's module; pure Python and numpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

STATUS_OK = "ok"
STATUS_SINGULAR = "singular"
STATUS_DIVERGED = "diverged"
STATUS_ERROR = "error"
STATUS_STEP_UNSTABLE = "step_unstable"

#: the integrators: fixed step, and error-controlled (ftcreport.fast.integrators; "auto" picks one at t0)
FIXED_METHODS = ("rk4", "ros2", "etd2")
AUTO_METHODS = ("auto", "dopri5", "ros2ec", "etd2ec", "etd3ec", "ros34pw2")
METHODS = FIXED_METHODS + AUTO_METHODS

#: step-growth detector (see the module docstring); the compiled engine takes the same values
GROWTH_FACTOR = math.e
GROWTH_STEPS = 3
GROWTH_TOTAL = 20.0
GROWTH_FLOOR = 1.0  # N m
JUMP_FRACTION = 0.1  # a bound crossed in one step from within this fraction of it is a step blow-up
JUMP_MARGINS = 10.0  # ... and the singular set reached in one step from this many margins away


@dataclass
class Run:
    """Result of one simulation: logged time series and outcome.

    Attributes
    ----------
    t : (K,) ndarray
        Logged instants [s].
    signals : dict of str to ndarray
        ``'q'`` (K, n+2), ``'eta'`` (K, 2), ``'u'`` (K, 2n) commanded control,
        ``'tau'`` (K, 2n) applied torque, ``'sigma'``, ``'ubar'`` (K, 2n) true
        faults, ``'xc'`` (K, n_states), then the controller's own signals.
    status : str
        ``'ok'``, ``'singular'``, ``'diverged'``, ``'step_unstable'`` or ``'error'``.
    reason : str
        Why the run stopped early ('' when it completed).
    t_end : float
        Last simulated instant [s].
    steps : int
        RK4 steps taken.
    wall_time : float
        Wall-clock seconds spent in the loop.
    t_stream : (S,) ndarray
        Every accepted step's instant [s] (the metric stream; S >= K).
    stream : dict of str to ndarray
        The metric stream: the signals of :func:`stream_of` at every accepted
        step, whatever ``log_every`` is.  Metrics read it (ftcreport.runner), so
        ``log_every`` changes what is saved, never a metric.  It holds the names of
        :data:`STREAM_SIGNALS` and the per-step minimum and maximum of the wide
        ones of :data:`REDUCED_SIGNALS` (``chi_hat_min``, ``chi_hat_max``).
    """

    t: np.ndarray
    signals: dict[str, np.ndarray]
    status: str = STATUS_OK
    reason: str = ""
    t_end: float = 0.0
    steps: int = 0
    wall_time: float = 0.0
    meta: dict = field(default_factory=dict)
    t_stream: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stream: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    @property
    def ok(self) -> bool:
        """True when the run completed without stopping early."""
        return self.status == STATUS_OK

    #: conversions the package's edges provide (ftcreport/__init__.py fills it: tidy, report.notebook),
    #: so that this core module imports nothing from them
    views: ClassVar[dict[str, Callable]] = {}

    def to_xarray(self):
        """The run as an ``xarray.Dataset``: dimensions time, coordinate, velocity, wheel, robot, ...

        Units in each variable's ``units`` attribute; status, engine, case hash and the fault
        schedule as metadata (:func:`ftcreport.storage.tidy.run_dataset`; xarray is imported only then).
        """
        return self.views["xarray"](self)

    def to_pandas(self):
        """The run as a wide ``pandas.DataFrame`` indexed by time, columns ``q[x]``, ``tau[2l]``, ...

        (:func:`ftcreport.storage.tidy.run_frame`; pandas is imported only then).
        """
        return self.views["pandas"](self)

    def _repr_html_(self) -> str:
        """Notebook view: summary table and a small figure (:mod:`ftcreport.report.notebook`)."""
        return self.views["html"](self)


#: the signals the metrics read (ftcreport.runner, metrics, diagnosis): kept at every accepted step
STREAM_SIGNALS = (
    "q", "eta", "u", "tau", "tau_mid", "sigma", "ubar", "q_d", "selected", "uf_hat",
    "q_hat", "eta_hat", "rho_hat", "ubar_hat", "P_max",
)  # fmt: skip
#: wide signals of which the stream keeps the per-step minimum and maximum only (the metrics read
#: chi_hat_min/max; the switching costs, one per model, are in the saved log only)
REDUCED_SIGNALS = ("chi_hat",)


def stream_of(signals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The metric-stream part of logged rows.

    ``signals`` holds K rows of every logged name; the result holds the same K rows of the
    names in :data:`STREAM_SIGNALS`, plus ``<name>_min`` and ``<name>_max`` (K,) for each name
    of :data:`REDUCED_SIGNALS` present.
    """
    out = {name: signals[name] for name in STREAM_SIGNALS if name in signals}
    for name in REDUCED_SIGNALS:
        if name in signals:
            v = signals[name]
            flat = v.reshape(v.shape[0], -1)
            empty = flat.shape[1] == 0
            out[f"{name}_min"] = np.full(v.shape[0], np.nan) if empty else flat.min(axis=1)
            out[f"{name}_max"] = np.full(v.shape[0], np.nan) if empty else flat.max(axis=1)
    return out


def step_jump_words(kind: int, before: float, after: float) -> str:
    """The words of a ``_step_jump`` triple (fast.checks._step_jump: kind, before, after)."""
    if kind == 1:
        return "non-finite new state"
    what = {2: ("velocity", ""), 3: ("position", " m"), 4: ("an articulation angle's distance from 90 deg", " deg")}
    label, unit = what[kind]
    if kind == 4:
        before, after = 90.0 - before, 90.0 - after
    return f"{label} jumped from {before:.3g}{unit} to {after:.3g}{unit} in one step"
