r"""The building blocks of the case schema: documented fields, their ranges, the strict table model.

Every table of a case file (``ftcreport.cases``) and every scheme's parameter table (the built-in
schemes' in ``ftcreport/schemes/``, a plug-in's in its own file) is written with these, so that a
field carries its description, unit and documented range into the JSON Schema and
``cases/README.md``, and refuses a boolean or a text where a number belongs.  Nothing here knows
a scheme or a case.
"""

from __future__ import annotations

import difflib
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

__all__ = ["FieldError", "Strict", "did_you_mean", "doc_field", "number"]


def doc_field(default: Any, description: str, unit: str, **kw: Any) -> Any:
    """A documented field: its description and unit appear in the JSON Schema and cases/README.md.

    ``unit`` is an SI unit, ``"1"`` for a dimensionless number, ``"-"`` for a name, flag or table.
    """
    return Field(default, description=description, json_schema_extra={"unit": unit}, **kw)


def _a_number(v: Any) -> Any:
    """Refuse a boolean or a text where a number belongs (pydantic would read ``true`` as 1, ``"12"`` as 12)."""
    if isinstance(v, bool):
        raise ValueError(f"a number is expected, got the boolean {str(v).lower()}")
    if isinstance(v, str):
        try:
            float(v)
        except ValueError:
            raise ValueError(f"a number is expected, got the text {v!r}") from None
        raise ValueError(f"a number is expected, got the text {v!r} (write it without quotes)")
    return v


_NUMBER = BeforeValidator(_a_number)


def number(lo: float | None = None, hi: float | None = None, *, gt: float | None = None, lt: float | None = None):
    """A finite float in a documented range (ge ``lo`` or gt ``gt``; le ``hi`` or lt ``lt``); no boolean or text."""
    return Annotated[float, Field(ge=lo, gt=gt, le=hi, lt=lt, allow_inf_nan=False), _NUMBER]


#: A whole number (its range in the field): no boolean or text either.
Int = Annotated[int, _NUMBER]


#: Documented ranges (issue 23 asks for one on every numeric field; the fuzzer relies on them).
Coord = number(-1e6, 1e6)  # a position [m]; the engine stops a run beyond 1e6 m
Length = number(None, 100.0, gt=0)  # a robot dimension [m]
Signed = number(-100.0, 100.0)  # a signed robot dimension [m]
Mass = number(None, 1e5, gt=0)
Inertia = number(0.0, 1e6)
Angle = number(-360.0, 360.0)  # [deg]
Speed = number(None, 100.0, gt=0)  # [m/s]
Rate = number(-100.0, 100.0)  # [rad/s]
Gain = number(None, 1e6, gt=0)
Gain0 = number(0.0, 1e6)
Torque = number(-1e4, 1e4)  # [N m]
Time = number(0.0, 1e6)  # [s]
Unit = number(0.0, 1.0)
Std = number(0.0, 1e3)
Factor = number(None, 1e3, gt=0)
Limit = number(-1e18, 1e18)  # a threshold on any metric


class Strict(BaseModel):
    """A table: unknown fields refused, values frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class FieldError(ValueError):
    """A validation error with an explicit field path (raised inside validators)."""

    def __init__(self, loc: str, msg: str) -> None:
        super().__init__(msg)
        self.loc = loc
        self.msg = msg


def refuse_unused(table: BaseModel, where: str, what: str, uses: dict[str, tuple[str, ...]]) -> None:
    """FieldError for the first field that ``table``'s kind does not read and that is set to something else
    than its default (``uses``: kind -> the fields it reads; ``kind`` itself is always read).

    A field of another kind would otherwise be dropped without a word (an 'eight' reference with a speed:
    the user's speed never reaches the path).  A default written back (a stored case) is not refused.
    """
    kind = table.kind
    used = set(uses[kind]) | {"kind"}
    for name, field in type(table).model_fields.items():
        if name in used or getattr(table, name) == field.default:
            continue
        readers = [k for k, fields in uses.items() if name in fields]
        article = "an" if kind[0] in "aeio" else "a"  # a 'unicycle'
        raise FieldError(
            f"{where}.{name}",
            f"not used by {article} '{kind}' {what} (used by: {', '.join(readers)}); remove it or change kind",
        )


def did_you_mean(key: str, candidates: list[str]) -> str:
    """`` (did you mean 'k_v'?)`` for the closest of ``candidates`` (difflib), or ''."""
    close = difflib.get_close_matches(key, candidates, n=1, cutoff=0.6)
    if not close:
        close = [c for c in candidates if c.lower() == key.lower()]
    return f" (did you mean '{close[0]}'?)" if close else ""


# the names the case schema has always used
_Strict, _FieldError, _f, _num = Strict, FieldError, doc_field, number
