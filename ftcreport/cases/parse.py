"""A case from a dict (parsed TOML): validation, field errors, plug-in scheme files."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from ..errors import BIDI, CaseError, FtcError, printable
from ..infra.limits import name_problem
from ..schemes.fields import _FieldError
from .case import Case
from .messages import _format_loc, _message, _rank


def _field_errors(errors: list[dict], root: type[BaseModel]) -> list[tuple[str, str]]:
    """Every field in error once, as (field path, reason): pydantic's errors of a ``root`` model grouped by field.

    A union field reports one error per member (``a = -300`` is neither a valid float nor a list):
    the member that matches the input's type is the reason (:func:`_rank`), and a member whose
    error lies deeper (``a[1]`` of the list member) stands for the field alone.  Typos of keys
    come first, then wrong values, then wrong types; otherwise pydantic's order (the file's).
    """
    groups: dict[str, list[tuple[int, dict]]] = {}
    for err in errors:
        ctx_err = (err.get("ctx") or {}).get("error")
        loc = ctx_err.loc if isinstance(ctx_err, _FieldError) else _format_loc(tuple(err["loc"])) or "<root>"
        groups.setdefault(loc, []).append((_rank(err), err))

    def inside(child: str, parent: str) -> bool:
        return parent == "<root>" or child.startswith((parent + ".", parent + "["))

    def type_only(loc: str) -> bool:
        return all(rank > 0 for rank, _ in groups[loc])

    kept = [loc for loc in groups if not (type_only(loc) and any(inside(o, loc) for o in groups if o != loc))]
    best = {loc: min(groups[loc], key=lambda pair: pair[0]) for loc in kept}  # stable: the first of the best rank
    out = []
    for loc in sorted(kept, key=lambda loc: best[loc][0]):
        err = best[loc][1]
        ctx_err = (err.get("ctx") or {}).get("error")
        out.append((loc, ctx_err.msg if isinstance(ctx_err, _FieldError) else _message(err, root)))
    return out


def parse_case(data: dict, source: str = "<case>") -> Case:
    """Validate a case given as a dict (parsed TOML); raise CaseError naming the field.

    The scheme files of ``plugins`` are loaded first (their schemes register themselves), and the
    case keeps their absolute paths, so a worker that parses the case's JSON loads them too.
    """
    controls = _control_errors(data)  # reported with the other fields in error, the field once
    try:
        data = _load_plugins(data, source)
        case = Case.model_validate(data)
    except ValidationError as exc:
        found = {loc for loc, _ in controls}
        _refuse(source, controls + [(loc, why) for loc, why in _field_errors(exc.errors(), Case) if loc not in found])
    except CaseError:
        if controls:  # a plugins path with a control character is not looked for
            _refuse(source, controls)
        raise
    if controls:
        _refuse(source, controls)
    if case.name is None:
        stem = Path(source).stem
        if (why := name_problem(stem)) is not None:
            raise CaseError(f'{source}: name: taken from the file name: {why}; set name = "..." in the file')
        case = case.model_copy(update={"name": stem})
    from ..evaluation.families import fill_defaults  # every FTC family unless schemes.run narrows the list (issue 21)
    from .case import _check_budget
    from .scheme_tables import configured_schemes

    filled = fill_defaults(case)
    for s in configured_schemes(filled):  # a default table was not validated with the case: its run's memory
        if s not in configured_schemes(case):
            try:
                _check_budget(filled, [s])
            except _FieldError as exc:
                why = f"{s} runs by default, with a default table ([schemes] run does not leave it out)"
                _refuse(source, [(exc.loc, f"{exc.msg}; {why}")])
    return filled


#: Fields of prose that may span lines (a TOML multi-line string): tabs and line ends are allowed there.
_PROSE = ("words", "note")


def _refuse(source: str, errors: list[tuple[str, str]]) -> None:
    """Raise the CaseError of every (field, reason), the first in its message with the count of the others."""
    lines = [f"{printable(source)}: {loc}: {why}" for loc, why in errors]
    more = f" (and {len(lines) - 1} more; 'ftcreport cases validate' lists every one)" if len(lines) > 1 else ""
    raise CaseError(lines[0] + more, lines) from None


def _control_errors(data: Any) -> list[tuple[str, str]]:
    """(field, reason) of every text of the case, keys included, that holds a control character (C0, DEL, C1)
    or a bidirectional control (U+202A..U+202E, U+2066..U+2069: it reorders what a reader sees).

    Every text of a case reaches a terminal line, a page or a JUnit file; an escape sequence rewrites
    the terminal, NUL and most others make XML ill-formed (issue 34 item 7).  Only the claims' prose
    (:data:`_PROSE`) may hold tabs and line ends.
    """
    import unicodedata

    out: list[tuple[str, str]] = []

    def why(text: str, allowed: str = "") -> str | None:
        bad = next(((i, c) for i, c in enumerate(text) if unicodedata.category(c) == "Cc" and c not in allowed), None)
        shown = printable(text[:60]) + ("..." if len(text) > 60 else "")
        if (bidi := BIDI.search(text)) is not None and (bad is None or bidi.start() < bad[0]):
            return (
                f"bidirectional control U+{ord(bidi.group()):04X} at position {bidi.start()} of '{shown}': it "
                "reorders the text around it on a terminal and a page, so what a reader sees is not what the "
                "case says; write the text without it (a right-to-left script needs none)"
            )
        if bad is None:
            return None
        return (
            f"control character U+{ord(bad[1]):04X} at position {bad[0]} of '{shown}': a text of a case holds "
            "printable characters only (a control character breaks the terminal, the pages and the JUnit file)"
        )

    def walk(v: Any, path: str, key: str) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                sub = f"{path}.{printable(k)}" if path else printable(k)
                if isinstance(k, str) and (w := why(k)) is not None:
                    out.append((sub, w))
                walk(x, sub, str(k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, f"{path}[{i}]", key)
        elif isinstance(v, str) and (w := why(v, "\t\n\r" if key in _PROSE else "")) is not None:
            out.append((path or "<root>", w))

    walk(data, "", "")
    return out


def _load_plugins(data: dict, source: str) -> dict:
    """Load the case's scheme files (paths relative to the case file's directory); the absolute paths."""
    plugins = data.get("plugins") if isinstance(data, dict) else None
    if plugins is None:
        return data
    if not isinstance(plugins, list) or not all(isinstance(p, str) for p in plugins):
        raise CaseError(f"{source}: plugins: a list of scheme file paths is expected, got {plugins!r}")
    from ..schemes import load_plugin

    base = Path(source).parent
    resolved = []
    for i, p in enumerate(plugins):
        path = Path(p).expanduser()
        path = path if path.is_absolute() else base / path
        if not os.path.lexists(path):
            raise CaseError(f"{source}: plugins[{i}]: no such scheme file: {path}")
        try:
            load_plugin(path)
        except FtcError as exc:  # a file that fails or calls sys.exit on import (load_plugin names it)
            raise CaseError(f"{source}: plugins[{i}]: {exc}") from None
        resolved.append(str(path.resolve()))
    return {**data, "plugins": resolved}
