r"""The scheme API: plug a new FTC law into ftcreport, compiled, beside the built-in schemes.

A scheme is one file: its parameters (a pydantic model: the case's ``[schemes.<name>]`` table),
how they are packed for the compiled loop, its state, its law and what it logs. It registers
itself with :func:`register`; from then on ``ftcreport run``, ``batch``, ``campaign`` and the
reports run it like the built-in schemes, on the same compiled loop (``fast.kernels.run_steps``)
and at the same speed: numba compiles the loop once per law, on the law's first use, and caches
the machine code beside the scheme's file.

The law is a numba function with the signature every built-in law has::

    @jit
    def law(P, Kp, R, C, pc, t, q, eta, xc, sig_true, ubar_true, info, sig):
        ...
        return u, xcdot          # (2n,) wheel torque command, (n_states,) state derivative

- ``P``: the tuple :attr:`Scheme.pack` returned (arrays and numbers; a NamedTuple reads best);
- ``Kp, R, C``: the kinematic controller, the reference and their per-step cache: pass them on to
  :func:`matched_terms`, which runs the case's kinematic controller and returns the matched
  dynamic law's terms ``(w, MB, g, eta_e)`` of (3.35)-(3.37);
- ``pc``: the controller's chain model (``kernels.reduced(pc, q, eta)`` gives Mbar1, Mbar2, Cbar,
  Bbar, S, Sdot of (2.70));
- ``t, q, eta``: time and the measured state; ``xc``: the controller state, the kinematic
  controller's ``Kp.nk`` states first, the scheme's own after them (``xc[Kp.nk:]``);
- ``sig_true, ubar_true``: the true faults (for an oracle only; a real scheme must not read them);
- ``info``: the error flag (``info[0] != 0`` after :func:`matched_terms` means stop, return at once);
- ``sig``: the logged signals; when not empty, :func:`matched_terms` writes the kinematic ones
  first, and the scheme's own :attr:`Scheme.signals` follow at index ``Scheme.pack``'s
  ``ctx.n_kin_signals``.

An optional discrete update ``disc(P, Kp, R, C, t, q, eta, xc, info)`` runs after every step and
changes ``xc`` in place (switching rules, projections). ``README.md`` ("Write your own scheme")
walks through the shipped example, ``examples/schemes/sliding_mode.py``.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ModelError

__all__ = ["Scheme", "SchemeContext", "SchemeController", "get", "load_plugin", "register", "registered"]


def __getattr__(name: str):
    """The kernels a law builds on (numba is loaded on first use, not with the package)."""
    if name in ("matched_terms", "no_discrete", "law_for_pattern", "reduced", "jit", "clip"):
        from .fast import kernels as F

        return {"clip": F._clip}.get(name) or getattr(F, name)
    raise AttributeError(name)


@dataclass(frozen=True)
class SchemeContext:
    """What a scheme's ``pack``, ``n_states`` and ``initial_state`` may read.

    chain : the controller's model (``ftcreport.model.Chain``); kin : the case's kinematic
    controller; k_v : the velocity-error gain; params : the validated ``[schemes.<name>]``
    table (the scheme's pydantic model) or None; saturation : the plant's torque limit [N m]
    or None; n_kin_states : the kinematic controller's states (the scheme's start after them);
    n_kin_signals : the kinematic signals' length (the scheme's signals start after them).
    """

    chain: Any
    kin: Any
    k_v: float
    params: Any
    saturation: float | None
    n_kin_states: int
    n_kin_signals: int


@dataclass(frozen=True)
class Scheme:
    """A registered FTC scheme.

    name : its key in case files (``[schemes.<name>]``) and reports;
    law : the compiled law (see the module docstring);
    pack : ``ctx -> P``, the law's parameters;
    params : the pydantic model of its case table (None: no parameters);
    n_states : ``ctx -> int``, the scheme's own states (after the kinematic ones);
    initial_state : ``(ctx, q0, eta0) -> (n_states,)``, default zeros;
    discrete : the compiled discrete update (default none);
    signals : ``{name: width}`` of what the law logs into ``sig`` after the kinematic signals,
        or ``ctx -> {name: width}``;
    family : how the reports group it (``"passive"``, ``"active"``, ...);
    description, reference : one line each, shown on the report pages.
    """

    name: str
    law: Any
    pack: Callable[[SchemeContext], tuple]
    params: Any = None
    n_states: Callable[[SchemeContext], int] = lambda ctx: 0
    initial_state: Callable[[SchemeContext, np.ndarray, np.ndarray], np.ndarray] | None = None
    discrete: Any = None
    signals: dict[str, int] | Callable[[SchemeContext], dict[str, int]] = field(default_factory=dict)
    family: str = "user"
    description: str = ""
    reference: str = ""

    def signal_widths(self, ctx: SchemeContext) -> dict[str, int]:
        return dict(self.signals(ctx) if callable(self.signals) else self.signals)


_REGISTRY: dict[str, Scheme] = {}

#: The built-in schemes as ``ftcreport schemes`` lists them: (family, description, reference).
BUILT_IN: dict[str, tuple[str, str, str]] = {
    "nominal": ("baseline", "the matched law (3.35) assuming healthy wheels: no FTC", "thesis 3.2.2, (3.35)"),
    "switching": (
        "multiple models",
        "one law per failure pattern, switched by the cost of reconstructed velocities",
        "thesis 3.2 and 3.3.1, (3.42)-(3.48)",
    ),
    "adaptive": ("adaptive", "adaptive pattern weights and friction estimate", "thesis 3.3.2"),
    "adaptive_frozen": ("ablation", "the adaptive law with its weights and friction frozen", "thesis 3.3.2"),
    "active": (
        "active",
        "Farza adaptive observer of q, eta, gains and frictions + the compensating law (4.14)",
        "thesis chapter 4; Farza et al. 2009",
    ),
    "active_ukf": (
        "active",
        "augmented-state unscented Kalman filter + (4.14), both at the samples (the law held in between)",
        "Julier & Uhlmann 1997; thesis (4.14)",
    ),
    "oracle": ("bound", "(3.35) told the true sigma and ubar at every instant", "thesis (3.35) with the true pattern"),
}


def register(scheme: Scheme) -> Scheme:
    """Register a scheme under its name (a safe name, not a built-in one); returns it."""
    from .limits import NAME_PATTERN

    if not NAME_PATTERN.fullmatch(scheme.name):
        rule = "a letter or digit, then letters, digits, '_', '.', '-' (at most 64)"
        raise ModelError(f"scheme name {scheme.name!r}: {rule}")
    if scheme.name in BUILT_IN:
        raise ModelError(f"scheme name {scheme.name!r} is a built-in scheme")
    old = _REGISTRY.get(scheme.name)
    if old is not None and old.law is not scheme.law and old.law.py_func.__code__ != scheme.law.py_func.__code__:
        raise ModelError(f"scheme {scheme.name!r} is registered twice, by two different laws")
    _REGISTRY[scheme.name] = scheme
    return scheme


def registered() -> dict[str, Scheme]:
    """The registered (plug-in) schemes by name."""
    return dict(_REGISTRY)


def get(name: str) -> Scheme:
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY)) or "none"
        raise ModelError(f"no scheme {name!r} is registered (registered: {known})") from None


def load_plugin(path: str | Path) -> None:
    """Import a scheme file (it registers its schemes when imported); idempotent per file."""
    from .inputs import input_problem

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
    spec = importlib.util.spec_from_file_location(name, p)
    if spec is None or spec.loader is None:
        raise ModelError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    before = dict(_REGISTRY)
    try:
        spec.loader.exec_module(module)
    except SystemExit as exc:  # not an Exception; the half-imported module must not stay loaded either
        del sys.modules[name]
        raise ModelError(f"{path}: the scheme file called sys.exit({exc.code!r}) on import") from None
    except Exception as exc:
        del sys.modules[name]
        raise ModelError(f"{path}: the scheme file failed to import: {type(exc).__name__}: {exc}") from exc
    if all(before.get(k) is v for k, v in _REGISTRY.items()):  # nothing new: a wrong file, or a typo in it
        del sys.modules[name]
        raise ModelError(
            f"{path}: registers no scheme (a scheme file calls ftcreport.schemes.register(Scheme(...)) when imported)"
        )


class SchemeController:
    """A registered scheme bound to a case's chain and kinematic controller (what the engine runs).

    It has no law of its own in Python: the engine runs ``scheme.law`` on the compiled loop.
    """

    def __init__(self, scheme: Scheme, chain, kinematic, k_v: float, params=None, saturation=None) -> None:
        from .control.tracking import TrackingController

        self.scheme = scheme
        self.name = scheme.name
        self.chain = chain
        self.kin = kinematic
        self.k_v = float(k_v)
        self.tracking = TrackingController(chain, kinematic, k_v)
        self.u_limit = saturation
        nz, nq = len(kinematic.z_names), chain.n_q
        self.ctx = SchemeContext(chain, kinematic, self.k_v, params, saturation, kinematic.n_states, 6 + nz + nq)
        self.n_own = int(scheme.n_states(self.ctx))
        if self.n_own < 0:
            raise ModelError(f"scheme {scheme.name}: n_states must be >= 0, got {self.n_own}")
        self.n_states = kinematic.n_states + self.n_own
        self.widths = scheme.signal_widths(self.ctx)
        self.signal_names = ("eta_c", "z", "q_d", "eta_d", *self.widths)
        self.P = scheme.pack(self.ctx)

    def initial_state(self, t: float, q: np.ndarray, eta: np.ndarray) -> np.ndarray:
        own = np.zeros(self.n_own)
        if self.scheme.initial_state is not None:
            own = np.asarray(self.scheme.initial_state(self.ctx, q, eta), dtype=float).reshape(self.n_own)
        return np.concatenate((np.asarray(self.kin.initial_state(t, q), dtype=float).reshape(-1), own))
