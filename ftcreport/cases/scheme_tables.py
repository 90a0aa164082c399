"""The case file's ``[schemes]`` table, generated from the registry (ftcreport.schemes), and the scheme names."""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, ValidationError, create_model, field_validator, model_validator

from ..errors import FtcError
from ..schemes import built_in as _built_in_schemes
from ..schemes.fields import Gain, Gain0, _f, _FieldError, _num, _Strict, did_you_mean, refuse_unused
from .messages import _format_loc, _message, _rank

if TYPE_CHECKING:
    from .case import Case


SCHEME_NAMES = tuple(_built_in_schemes())  # the built-in schemes, in the registry's order (ftcreport.schemes)


class Kinematic(_Strict):
    """Kinematic controller shared by every scheme."""

    kind: Literal["two_link", "chained"] = _f(
        ..., '"two_link" (n = 2 only, thesis 3.2) or "chained" (any n, thesis 3.3)', "-"
    )
    k1: Gain | None = _f(None, "two_link: gain k1 of (3.27)-(3.28) (required)", "1/s")
    k2: Gain | None = _f(None, "two_link: gain k2 of (3.27)-(3.28) (required)", "see (3.28)")
    k3: Gain | None = _f(None, "two_link: gain k3 of (3.27)-(3.28) (required)", "1/s")
    c_chain: Gain0 | list[Gain0] = _f(
        0.3, "chained: gain of every virtual control, scalar or n values (ERRATA E12d)", "1/s"
    )
    c_alpha2: Gain = _f(2.0, "chained: the thesis's c4", "1/s")
    c_xi1: Gain = _f(2.0, "chained: the thesis's c5", "1/s")
    kappa: Gain = _f(5.0, "chained: weight of the x error in the Lyapunov function", "1")
    mu: Gain = _f(1.0, "chained: length scale of the chain dynamics (1: the thesis design)", "1/m")
    band_deg: _num(gt=0, lt=90) = _f(
        45.0, "chained: re-anchor the chained-form frame when the reference heading leaves +/- band", "deg"
    )

    @model_validator(mode="after")
    def _unused(self) -> Kinematic:
        chained = ("c_chain", "c_alpha2", "c_xi1", "kappa", "mu", "band_deg")
        refuse_unused(self, "kinematic", "kinematic law", {"two_link": ("k1", "k2", "k3"), "chained": chained})
        return self


class _SchemesBase(_Strict):
    """The schemes to run; every scheme present is run with the shared kinematic controller.

    Issue 21: every family runs unless ``run`` narrows the list; a family without its table gets
    the defaults of :mod:`ftcreport.evaluation.families` (k_v: this table's ``k_v``, else the first table's,
    else the thesis's).  A registered (plug-in) scheme's table, ``[schemes.<name>]``, is validated
    with that scheme's parameter model and kept as an extra field (:func:`configured_schemes`).
    """

    model_config = ConfigDict(
        extra="allow",  # [schemes.<name>] of a registered (plug-in) scheme, validated by _plugin_tables
        frozen=True,
        json_schema_extra={
            "additionalProperties": {
                "type": "object",
                "description": "the table of a registered scheme (a file listed in plugins), validated by its "
                "parameter model",
                "unit": "-",
            }
        },
    )

    run: list[str] | None = _f(
        None,
        "the schemes to run (default: every family, adaptive_frozen only when its table is given); built-in or "
        "registered (plugins) names",
        "-",
    )
    k_v: Gain | None = _f(None, "velocity-error gain of the default tables (default: the first table's)", "1/s")

    @field_validator("run")
    @classmethod
    def _known_run(cls, v: list[str] | None) -> list[str] | None:
        known = known_schemes()
        for i, name in enumerate(v or ()):
            if name not in known:
                raise _FieldError(f"schemes.run[{i}]", _unknown_scheme(name))
        return v

    @model_validator(mode="before")
    @classmethod
    def _plugin_tables(cls, data: Any) -> Any:
        """Validate ``[schemes.<name>]`` of a registered scheme with its parameter model; refuse other names.

        A registered scheme listed in ``run`` without a table gets its parameter model's defaults.
        """
        if not isinstance(data, dict):
            return data
        from ..schemes import registered

        reg = registered()
        out = dict(data)
        for key, table in data.items():
            if key in cls.model_fields:
                continue
            if key not in reg:
                raise _FieldError(f"schemes.{key}", "unknown field" + _unknown_hint(key, [*cls.model_fields, *reg]))
            out[key] = _plugin_table(key, reg[key], table)
        run = data.get("run")
        for name in run if isinstance(run, list) else ():
            if isinstance(name, str) and name in reg and name not in data:
                out[name] = _plugin_table(name, reg[name], {})
        return out


def _schemes_model() -> type[BaseModel]:
    """The ``[schemes]`` table: ``run``, ``k_v`` and one optional field per built-in scheme, its parameter
    model (the registry's order; the field's description is the scheme's summary)."""
    fields: dict[str, Any] = {}
    for name, sc in _built_in_schemes().items():
        fields[name] = (sc.params | None, _f(None, sc.summary or sc.description, "-"))
    return create_model("Schemes", __base__=_SchemesBase, __doc__=_SchemesBase.__doc__, **fields)


Schemes = _schemes_model()


class PluginTable(_Strict):
    """The table of a registered scheme that declares no parameter model."""

    k_v: Gain | None = _f(
        None,
        "velocity-error gain of the dynamic law (the thesis's k4 or c6) (default: schemes.k_v, else the case's "
        "default)",
        "1/s",
    )


def _unknown_hint(key: str, known: list[str]) -> str:
    """A did-you-mean, else how a plug-in scheme's name becomes known."""
    hint = did_you_mean(key, known)
    if hint:
        return hint
    return (
        ": neither a built-in scheme nor a registered one (a plug-in scheme's file must be listed in plugins = [...])"
    )


def _unknown_scheme(name: str) -> str:
    known = known_schemes()
    return f"unknown scheme '{name}'" + _unknown_hint(name, known) + f" (known: {', '.join(known)})"


def _plugin_table(name: str, scheme: Any, table: Any) -> BaseModel:
    """``[schemes.<name>]`` of a registered scheme, validated by its parameter model (field errors named)."""
    model = scheme.params or PluginTable
    if isinstance(table, model):
        return table
    if isinstance(table, BaseModel):
        table = table.model_dump()
    if not isinstance(table, dict):
        raise _FieldError(f"schemes.{name}", f"a table is expected, got {type(table).__name__}")
    try:
        return model.model_validate(table)
    except ValidationError as exc:
        err = min(exc.errors(), key=_rank)
        loc = _format_loc(tuple(err["loc"]))
        if err["type"] == "extra_forbidden":
            why = "unknown field" + did_you_mean(str(err["loc"][-1]), list(model.model_fields))
        else:
            why = _message(err, model)
        raise _FieldError(f"schemes.{name}" + (f".{loc}" if loc else ""), why) from None
    except ValueError as exc:  # a validator of the plug-in's model raising outside pydantic's wrapping
        raise _FieldError(f"schemes.{name}", str(exc)) from None


def _scheme_file(name: str) -> str | None:
    """The file a registered scheme's law is defined in (resolved), None when it is not a file (a notebook)."""
    from ..schemes import registered

    sc = registered().get(name)
    code = getattr(getattr(sc.law, "py_func", sc.law), "__code__", None) if sc is not None else None
    if code is None or not Path(code.co_filename).is_file():
        return None
    return str(Path(code.co_filename).resolve())


def known_schemes() -> list[str]:
    """The built-in scheme names, then the registered (plug-in) ones."""
    from ..schemes import registered

    return [*SCHEME_NAMES, *sorted(registered())]


def configured_schemes(case: Case) -> list[str]:
    """The schemes a case runs: its built-in tables (in :data:`SCHEME_NAMES` order), then its plug-in tables."""
    return [s for s in SCHEME_NAMES if getattr(case.schemes, s) is not None] + list(case.schemes.model_extra or {})


def option_schemes(option: str, names: list[str], case: Case, among: list[str] | None = None) -> list[str]:
    """The schemes a CLI option names (``--scheme``, ``--schemes``), checked against ``case``.

    ``among``: the schemes the command can run (default: those the case configures).  A name that
    is no scheme at all is blamed on the option, with the known schemes and the closest one
    (``--scheme: got 'swiching'; known schemes: ...; did you mean 'switching'?``); a scheme the
    case does not run says so with the reason of :func:`ftcreport.evaluation.families.not_applicable`;
    no name at all (``--schemes ,``) or one named twice (a scheme run twice per sample) is refused too.
    Raises :class:`FtcError` (exit 2); returns ``names``.
    """
    from ..evaluation.families import not_applicable

    known = known_schemes()
    among = configured_schemes(case) if among is None else among
    if not names:
        raise FtcError(f"{option}: names no scheme; give one or more of {', '.join(among) or 'none'}, comma-separated")
    for i, name in enumerate(names):
        if name in names[:i]:
            raise FtcError(f"{option}: '{name}' is named twice; name each scheme once")
        if name not in known:
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise FtcError(f"{option}: got '{name}'; known schemes: {', '.join(known)}{hint}")
        if name not in among:
            why = not_applicable(case).get(name)
            reason = f": {why}" if why else ""
            runs = ", ".join(among) or "none"
            raise FtcError(f"{option}: '{name}' is not run on case '{case.name}' (this command runs {runs}){reason}")
    return names


def ordered_schemes(names) -> list[str]:
    """``names`` without repeats, the built-in schemes first in :data:`SCHEME_NAMES` order, the others as met."""
    names = list(dict.fromkeys(names))
    return [s for s in SCHEME_NAMES if s in names] + [s for s in names if s not in SCHEME_NAMES]
