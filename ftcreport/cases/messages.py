"""Field errors in the file's words: locations, reasons, suggestions (pydantic's errors rewritten)."""

from __future__ import annotations

import re
from typing import Any, get_args, get_origin

from pydantic import BaseModel

from ..schemes.fields import _Strict, did_you_mean


def _is_tag(part: Any) -> bool:
    """A union member's tag in a pydantic error location (``constrained-float``, ``list[...]``, a model name)."""
    if not isinstance(part, str):
        return False
    return "[" in part or part.startswith(("constrained-", "function-")) or part in _TAGS or part in _model_names()


_TAGS = {"float", "int", "str", "bool", "list", "tuple", "dict", "none"}


def _model_names() -> set[str]:
    """Names of the schema's table models (the subclasses of ``_Strict``), read when asked: the tables'
    modules import this one, so they are not defined yet when it loads."""
    names, todo = set(), [_Strict]
    while todo:
        for sub in todo.pop().__subclasses__():
            names.add(sub.__name__)
            todo.append(sub)
    return names


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if _is_tag(part):
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _submodel(annotation: Any) -> type[BaseModel] | None:
    """The model class inside an annotation (``X | None``, ``list[X]``), or None."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in get_args(annotation):
        found = _submodel(arg)
        if found is not None:
            return found
    return None


def known_fields(loc: tuple[Any, ...], root: type[BaseModel]) -> list[str]:
    """Field names of the table at ``loc`` (a pydantic location inside ``root``), [] when it is not a table."""
    model = _table_model(loc, root)
    return [] if model is None else list(model.model_fields)


def _table_model(loc: tuple[Any, ...], root: type[BaseModel]) -> type[BaseModel] | None:
    """The model of the table at ``loc`` (a pydantic location inside ``root``: the case, or a plug-in's
    parameter table), None when it is not a table."""
    model: type[BaseModel] = root
    skip = 0  # keys of dict-valued fields (thresholds.<scheme>.<metric>) are not field names
    for part in loc:
        if isinstance(part, int) or _is_tag(part):
            continue
        if skip:
            skip -= 1
            continue
        field = model.model_fields.get(part)
        sub = None if field is None else _submodel(field.annotation)
        if sub is None:
            return None
        skip = _dict_depth(field.annotation)
        model = sub
    return model


def _dict_depth(annotation: Any) -> int:
    """How many dict levels wrap the model of a field (``dict[str, dict[str, Bound]]``: 2)."""
    depth = 0
    while get_origin(annotation) is dict:
        depth += 1
        annotation = get_args(annotation)[1]
    return depth


_BOUND_OPS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", ">="), "less_than": ("lt", "<")}
_BOUND_OPS["less_than_equal"] = ("le", "<=")


def _message(err: dict, root: type[BaseModel]) -> str:
    """One reason for one pydantic error of a ``root`` model: ranges as 'must be >= 0, got -1', unknown keys with
    a suggestion."""
    kind = err["type"]
    if kind == "extra_forbidden":
        key = str(err["loc"][-1])
        return "unknown field" + did_you_mean(key, known_fields(tuple(err["loc"][:-1]), root))
    if kind in _BOUND_OPS:
        name, op = _BOUND_OPS[kind]
        return f"must be {op} {err['ctx'][name]:g}, got {err['input']}"
    if kind in ("literal_error", "enum"):  # every Literal (and enum) field of the schema
        return _choice_message(err["input"], str((err.get("ctx") or {}).get("expected", "")))
    if kind == "missing":
        return _missing_message(tuple(err["loc"]), root)
    if kind in _EXPECTED:
        return f"{_EXPECTED[kind]} is expected, got {_describe(err['input'])}"
    if kind == "finite_number":
        return f"must be a finite number, got {err['input']}"
    if kind in ("too_long", "too_short"):  # a fixed-length pair ([x, y]) or a bounded list
        ctx = err.get("ctx") or {}
        most, least = ctx.get("max_length"), ctx.get("min_length")
        bound = f"at most {most}" if kind == "too_long" else f"at least {least}"
        return f"{bound} values are expected, got {ctx.get('actual_length', '?')}"
    return err["msg"].removeprefix("Value error, ")


#: pydantic's type errors in the file's words (its own say "a valid dictionary or instance of Simulation")
_EXPECTED = {
    "model_type": "a table",
    "model_attributes_type": "a table",
    "dict_type": "a table",
    "list_type": "a list",
    "tuple_type": "a list",
    "string_type": "a text (in quotes)",
    "float_type": "a number",
    "float_parsing": "a number",
    "int_type": "a whole number",
    "int_parsing": "a whole number",
    "int_parsing_size": "a whole number of at most 19 digits",
    "int_from_float": "a whole number",
    "bool_type": "true or false",
    "bool_parsing": "true or false",
}


def _describe(v: Any) -> str:
    """A TOML value as the user wrote it: ``the number 1.5``, ``the text 'x'``, ``a table``."""
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, int | float):
        return f"the number {v!r}"
    if isinstance(v, str):
        return f"the text {v[:60]!r}" + ("..." if len(v) > 60 else "")
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list | tuple):
        return "a list"
    return f"a {type(v).__name__}"  # a TOML date or time


def _missing_message(loc: tuple[Any, ...], root: type[BaseModel]) -> str:
    """``required and missing: <the field's description>; add it to [table]`` (the schema's own words)."""
    if isinstance(loc[-1], int):  # an item of a fixed-length list ([x, y]) left out
        return f"item {loc[-1]} is missing: {_format_loc(loc[:-1])} needs {loc[-1] + 1} values or more"
    model = _table_model(loc[:-1], root)
    field = None if model is None else model.model_fields.get(str(loc[-1]))
    what = f": {field.description.rstrip('.')}" if field is not None and field.description else ""
    table = _format_loc(loc[:-1])
    where = f"; add it to [{table}]" if table and not isinstance(loc[-2], int) else ""
    return f"required and missing{what}{where}"


def _choice_message(value: Any, expected: str) -> str:
    """``got 'circel'; expected one of 'unicycle', 'circle', ... (did you mean 'circle'?)``.

    ``expected`` is pydantic's list of the allowed values (``'a', 'b' or 'c'``); the closest one
    to a string value is suggested (difflib, :func:`did_you_mean`).
    """
    allowed = re.findall(r"'([^']*)'", expected)
    if not allowed:  # not strings (numbers): pydantic's own list
        return f"got {value!r}; expected one of {expected}"
    hint = did_you_mean(value, allowed) if isinstance(value, str) else ""
    return f"got {value!r}; expected one of {', '.join(repr(a) for a in allowed)}{hint}"


def _rank(err: dict) -> int:
    """Errors of the union member that matches the input's type first (a type mismatch is the other member)."""
    kind = err["type"]
    if kind == "extra_forbidden":  # a misspelt key also makes its field "missing": name the typo first
        return -1
    return int(kind.endswith("_type") or kind == "literal_error" or kind.endswith("_parsing"))
