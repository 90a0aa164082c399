r"""Schemes: every FTC law, built-in or plug-in, registered the same way and run on the same compiled loop.

A scheme is one file: its parameters (a pydantic model: the case's ``[schemes.<name>]`` table), how
they are packed for the compiled loop, its state, its law and what it logs.  It registers itself
with :func:`register`; from then on ``ftcreport run``, ``batch``, ``campaign`` and the reports run it
like the built-in schemes, which register themselves the same way from their own files in
``ftcreport/control/builtin/`` (``nominal.py``, ``switching.py``, ``adaptive.py``, ``active.py``,
``active_ukf.py``, ``oracle.py``), beside the laws they run.  This package is the interface and the
registry only: it sits below the laws (``control``) and the engine (``fast``), which import it.  The
compiled helpers a law calls (``jit``, ``terms_at``, ...) are lent here by name, on first use, from the
rooms that define them (docs/ARCHITECTURE.md, "Layers").
numba compiles the loop once per law, on the law's first use, and caches it.

The contract (what a law is handed, what it may write, what is checked) is
:mod:`ftcreport.schemes.api`; ``ftcreport schemes check FILE`` runs a new law through a battery of
checks before its first real run (:mod:`ftcreport.fast.scheme_check`).  ``README.md`` ("Write your own
scheme") walks through the shipped example, ``examples/schemes/sliding_mode.py``.
"""

from __future__ import annotations

from .api import GUARD, N_GUARD, TERMS_MODES, Out, Scheme, SchemeContext, Step, Terms
from .controller import SchemeController
from .registry import built_in, every, get, load_plugin, register, registered

__all__ = [
    "GUARD",
    "N_GUARD",
    "TERMS_MODES",
    "Out",
    "Scheme",
    "SchemeContext",
    "SchemeController",
    "Step",
    "Terms",
    "built_in",
    "every",
    "get",
    "load_plugin",
    "register",
    "registered",
]

#: The compiled helpers a law builds on, loaded with numba on first use (not with the package).
_KERNELS = {
    "jit": ("ftcreport.jit.compiling", "jit"),
    "law_for_pattern": ("ftcreport.control.tracking_compiled", "law_for_pattern"),
    "reduced": ("ftcreport.model.compiled", "reduced"),
    "clip": ("ftcreport.jit.packed", "_clip"),
    "no_discrete": ("ftcreport.control.interface_compiled", "no_discrete"),
    "terms_at": ("ftcreport.control.interface_compiled", "terms_at"),
    "terms_with": ("ftcreport.control.interface_compiled", "terms_with"),
    "matched_terms": ("ftcreport.control.interface_compiled", "legacy_matched_terms"),  # the round-2 API's
}


def __getattr__(name: str):
    if name in _KERNELS:
        import importlib

        module, attr = _KERNELS[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(name)
