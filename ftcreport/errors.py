"""Exception hierarchy of ftcreport.

Every error the package raises on purpose derives from :class:`FtcError`; the
CLI turns these into a one-line message and an exit code, never a traceback.
"""

from __future__ import annotations

__all__ = [
    "CaseError",
    "DivergenceError",
    "FaultError",
    "FtcError",
    "ModelError",
    "NotBuiltError",
    "SingularityError",
    "UncompensableError",
]


class FtcError(Exception):
    """Base class of the errors ftcreport raises deliberately."""

    exit_code = 2


class CaseError(FtcError):
    """A case file is malformed or names something impossible.

    The message names the file, the field path and the reason, e.g.
    ``cases/x.toml: faults[2].wheel: '4r' is not a wheel of a 3-robot chain``.
    """


class ModelError(FtcError, ValueError):
    """Impossible physical parameters or inconsistent array shapes."""


class FaultError(FtcError, ValueError):
    """A fault schedule that cannot be applied (bad wheel, time or value)."""


class UncompensableError(FtcError):
    """A failure pattern violates the redundancy condition rank(Bbar sigma) = 2."""


class SingularityError(FtcError):
    """The state approaches a singular configuration (ERRATA P4)."""


class DivergenceError(FtcError):
    """A simulation produced a non-finite value or left its bounds."""


class NotBuiltError(FtcError):
    """A CLI command that is registered but not implemented yet."""


class ReferenceError(FtcError, ValueError):
    """An infeasible reference (speed near 0, articulation angle near 90 deg)."""
