"""A plug-in's declaration hooks called under one rule (:func:`hook`): what its own code raises, or returns that
cannot be used, becomes a :class:`~ftcreport.errors.PluginError` naming its file and line, the scheme and the
hook.  Used by the scheme's binding to a case (:mod:`.controller`), its budget (:mod:`.budget`), the case's
validation, the runner (controller faces, metrics, cost) and the analysis."""

from __future__ import annotations

from ..errors import FtcError, PluginError
from .api import Scheme

__all__ = ["ResultError", "hook", "hook_where", "one_line"]


def hook(scheme: Scheme, role: str, fn, *args, convert=None, passes: tuple[type[BaseException], ...] = ()):
    """``fn(*args)``, one of a scheme's declaration hooks; what a plug-in's own code raises becomes a
    :class:`~ftcreport.errors.PluginError` naming its file and line, the scheme and the hook (a run of it
    then ends with status error and that reason; the analysis lists it under ``not_analyzed``); an
    ftcreport error it raises (or an ftcreport call in it raises) keeps its message, prefixed so.  An
    error raised in ftcreport's own code alone is not the plug-in's and propagates as it is.

    ``convert``: what is done with the hook's result (a shape, a type), under the same rule: a plug-in's
    hook that returns what cannot be converted is named the same way.  For a plug-in (a scheme not one of
    ftcreport's own) every exception counts, even one raised in a library its hook called (a builtin or a
    numpy function given as the hook: the hook itself is named) and ``sys.exit`` in it.  ``passes``: what
    the hook raises by design and its caller reads (``Scheme.validate``'s ``fields.FieldError``), as it is.
    """
    from .registry import is_built_in, user_frame

    plugin = not is_built_in(scheme)
    try:
        out = fn(*args)
        return out if convert is None else convert(out)
    except (PluginError, *passes):
        raise
    except (Exception, SystemExit) as exc:
        where = user_frame(exc) if isinstance(exc, Exception) else None
        if where is None and not plugin:
            raise
        where = f"{where}: " if where else hook_where(scheme, fn)
        if isinstance(exc, SystemExit):
            what = f"{role} called sys.exit({one_line(repr(exc.code))})"
        elif isinstance(exc, ResultError):
            what = f"{role} {exc.args[0]}"
        elif isinstance(exc, FtcError):
            what = f"{role}: {one_line(exc)}"
        else:
            what = f"{role} raised {type(exc).__name__}: {one_line(exc)}"
        raise PluginError(f"{where}scheme {scheme.name}: {what}") from exc


class ResultError(ValueError):
    """A hook's result that is not what the hook must return (its words: 'returned ...')."""


def one_line(obj) -> str:
    """``str(obj)`` on one line, at most 300 characters; an object whose ``__str__`` raises, by its type."""
    try:
        text = str(obj)
    except Exception:
        text = f"<{type(obj).__name__} whose str() raised>"
    return " ".join(text.split())[:300]


def hook_where(scheme: Scheme, fn) -> str:
    """``file:line: `` of a hook's definition, else of the scheme's signals or law (its file), else nothing;
    never one of ftcreport's own functions (a bound ``Scheme.signal_widths``)."""
    from pathlib import Path

    from .registry import _where

    package = Path(__file__).resolve().parents[1]
    for f in (fn, scheme.signals, scheme.law):
        code = getattr(getattr(f, "py_func", f), "__code__", None)
        if code is not None and not Path(code.co_filename).resolve().is_relative_to(package):
            return f"{_where(f)}: "
    return ""
