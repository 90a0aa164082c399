"""The case-file documentation generated from the pydantic models (one schema, no second copy).

* :func:`markdown_tables` gives the field tables of ``cases/README.md``: every field with its
  type, documented range, unit, default and meaning, one table per TOML table;
* :func:`update_readme` replaces the text between ``<!-- schema:KEY -->`` and ``<!-- /schema -->``
  markers with the generated table (the prose around the markers is hand-written);
* ``cases/case.schema.json`` is :func:`ftcreport.cases.case_schema` (for editors: ``.taplo.toml``).

``python -m ftcreport.cases.schema_doc`` rewrites both files; ``--check`` exits 1 when they drift
(tests/test_schema.py does the same check).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from pydantic import BaseModel

from .. import cases as C

__all__ = ["SECTIONS", "markdown_tables", "schema_json", "table", "update_readme"]

#: marker key -> (TOML table shown in the heading, model, fields to leave out)
SECTIONS: dict[str, tuple[str, type[BaseModel], tuple[str, ...]]] = {
    "top": ("top level", C.Case, ("robots", "reference", "initial", "faults", "kinematic", "schemes", "simulation",
                                  "plant", "campaign", "thresholds", "actuators", "requirements", "baseline")),
    "robots": ("[robots]", C.Robots, ()),
    "reference": ("[reference]", C.Reference, ()),
    "initial": ("[initial]", C.Initial, ()),
    "faults": ("[[faults]]", C.Fault, ()),
    "actuators": ("[actuators]", C.Actuators, ()),
    "drive_model": ("[actuators.drive_model]", C.DriveModel, ()),
    "kinematic": ("[kinematic]", C.Kinematic, ()),
    "schemes": ("[schemes]", C.Schemes, ()),
    "simulation": ("[simulation]", C.Simulation, ()),
    "plant": ("[plant]", C.Plant, ()),
    "noise": ("[plant.noise]", C.Noise, ()),
    "mismatch": ("[plant.mismatch]", C.Mismatch, ()),
    "bound": ("[thresholds.<scheme>] metric = { min, max }", C.Bound, ()),
    "requirements": ("[[requirements]]", C.Requirement, ()),
    "after_fault": ("start, end = { after_fault = N }", C.AfterFault, ()),
    "baseline": ("[baseline]", C.BaselineSpec, ()),
    "tolerance": ("[baseline.metrics.<name>], [baseline.signals.<name>]", C.Tolerance, ()),
    "campaign": ("[campaign]", C.CampaignSpec, ()),
}  # fmt: skip


def _scheme_sections() -> dict[str, tuple[str, type[BaseModel], tuple[str, ...]]]:
    """One section per built-in scheme's parameter model (schemes sharing a model share its section, keyed
    by the first), then one per table nested in them (``diagnosis``), keyed by the field's name."""
    from ..schemes import built_in

    by_model: dict[type, list[str]] = {}
    for name, sc in built_in().items():
        if sc.params is not None:
            by_model.setdefault(sc.params, []).append(name)
    out: dict[str, tuple[str, type[BaseModel], tuple[str, ...]]] = {}
    nested: dict[tuple[str, type], list[str]] = {}
    for model, names in by_model.items():
        out[names[0]] = (", ".join(f"[schemes.{n}]" for n in names), model, ())
        for field, info in model.model_fields.items():
            sub = info.annotation
            if isinstance(sub, type) and issubclass(sub, BaseModel):
                nested.setdefault((field, sub), []).extend(names)
    for (field, sub), names in nested.items():
        out[field] = (", ".join(f"[schemes.{n}.{field}]" for n in names), sub, ())
    return out


def _with_schemes(sections: dict) -> dict:
    keys = list(sections)
    at = keys.index("schemes") + 1
    merged = {k: sections[k] for k in keys[:at]} | _scheme_sections()
    return merged | {k: sections[k] for k in keys[at:]}


SECTIONS = _with_schemes(SECTIONS)


def schema_json() -> str:
    """The text of ``cases/case.schema.json``."""
    return json.dumps(C.case_schema(), indent=2) + "\n"


def _g(x: float) -> str:
    return f"{x:g}".replace("e+0", "e").replace("e+", "e")


def _range(s: dict) -> str:
    """``[0, 1]``, ``(0, 100]`` ... of a numeric schema ('' when it has none)."""
    if "minimum" in s:
        lo = "[" + _g(s["minimum"])
    elif "exclusiveMinimum" in s:
        lo = "(" + _g(s["exclusiveMinimum"])
    else:
        lo = None
    if "maximum" in s:
        hi = _g(s["maximum"]) + "]"
    elif "exclusiveMaximum" in s:
        hi = _g(s["exclusiveMaximum"]) + ")"
    else:
        hi = None
    if lo is None and hi is None:
        return ""
    return f"{lo or '(-inf'}, {hi or 'inf)'}"


def _numeric(s: dict) -> list[dict]:
    """Every numeric sub-schema of a field's schema."""
    if s.get("type") in ("number", "integer"):
        return [s]
    out = []
    for key in ("anyOf", "prefixItems"):
        for sub in s.get(key, []):
            out += _numeric(sub)
    if isinstance(s.get("items"), dict):
        out += _numeric(s["items"])
    if isinstance(s.get("additionalProperties"), dict):
        out += _numeric(s["additionalProperties"])
    return out


def _type(s: dict, defs: dict) -> str:
    if "$ref" in s:
        return "table"
    if "anyOf" in s:
        parts = [_type(x, defs) for x in s["anyOf"] if x.get("type") != "null"]
        return " or ".join(dict.fromkeys(parts))
    if "const" in s:
        return json.dumps(s["const"])
    if "enum" in s:
        return " or ".join(json.dumps(v) for v in s["enum"])
    t = s.get("type")
    if t == "array":
        if "prefixItems" in s:
            return "[" + ", ".join(_type(x, defs) for x in s["prefixItems"]) + "]"
        return "list of " + _type(s.get("items", {}), defs)
    if t == "object":
        return "table of " + _type(s.get("additionalProperties", {}), defs)
    return {"number": "float", "integer": "int", "string": "string", "boolean": "bool"}.get(t, str(t))


def _default(field, required: bool) -> str:
    if required:
        return "required"
    v = field.default
    if v is None:
        return ""
    if isinstance(v, BaseModel):
        return ""
    if isinstance(v, tuple):
        v = list(v)
    if isinstance(v, float):
        return _g(v)
    if isinstance(v, dict) and not v:
        return ""
    try:
        return json.dumps(v)
    except TypeError:
        return str(v)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def table(model: type[BaseModel], skip: tuple[str, ...] = ()) -> str:
    """The markdown table of one model's fields."""
    schema = model.model_json_schema(mode="validation")
    defs = schema.get("$defs", {})
    props = schema["properties"]
    required = set(schema.get("required", []))
    lines = ["| field | type | range | unit | default | meaning |", "|---|---|---|---|---|---|"]
    for name, field in model.model_fields.items():
        if name in skip:
            continue
        p = props[name]
        ranges = list(dict.fromkeys(r for r in (_range(x) for x in _numeric(p)) if r))
        unit = p.get("unit", "")
        cells = [
            f"`{name}`",
            _type(p, defs),
            " / ".join(ranges),
            "" if unit == "-" else unit,
            _default(field, name in required),
            p.get("description", ""),
        ]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return "\n".join(lines)


def metrics_table() -> str:
    """The metrics a threshold or a claim may name (:data:`ftcreport.evaluation.metrics.METRICS`), one row each."""
    from ..evaluation.metrics import METRICS

    what = {
        "number": "a number: thresholds and claims bound it",
        "table": "numbers by name: a claim reads `name.entry` or the largest",
        "list": "numbers: a claim compares the largest",
        "sequence": "the applied models: a claim's `sequence`",
        "record": "shown on the page, not compared",
    }
    lines = ["| metric | kind | unit | written by |", "|---|---|---|---|"]
    for name, m in METRICS.items():
        who = ", ".join(m.schemes) if m.schemes else "every scheme"
        lines.append(f"| `{name}` | {what[m.kind]} | {m.unit} | {who} |")
    return "\n".join(lines)


def markdown_tables() -> str:
    """Every section's table with its heading (``ftcreport cases schema --markdown``)."""
    parts = []
    for title, model, skip in SECTIONS.values():
        parts.append(f"### {title}\n\n{table(model, skip)}\n")
    return "\n".join(parts)


_MARK = re.compile(r"(<!-- schema:(\w+) -->\n).*?(<!-- /schema -->)", re.S)


def update_readme(text: str) -> str:
    """``text`` with every marked section's table regenerated."""

    def repl(m: re.Match) -> str:
        key = m.group(2)
        if key == "metrics":
            return m.group(1) + metrics_table() + "\n" + m.group(3)
        if key not in SECTIONS:
            raise KeyError(f"cases/README.md: unknown schema section '{key}'")
        _, model, skip = SECTIONS[key]
        return m.group(1) + table(model, skip) + "\n" + m.group(3)

    return _MARK.sub(repl, text)


def _files(root: Path) -> dict[Path, str]:
    readme = root / "cases" / "README.md"
    return {readme: update_readme(readme.read_text()), root / "cases" / "case.schema.json": schema_json()}


def main(argv: list[str] | None = None) -> int:
    """Rewrite cases/README.md tables and cases/case.schema.json (``--check``: exit 1 if they drift)."""
    args = sys.argv[1:] if argv is None else argv
    root = Path(__file__).resolve().parents[2]  # ftcreport/cases/schema_doc.py -> the checkout
    drift = []
    for path, text in _files(root).items():
        old = path.read_text() if path.exists() else ""
        if old != text:
            drift.append(path)
            if "--check" not in args:
                from ..infra.atomic import replace_file

                replace_file(path, text.encode())
    for p in drift:
        print(f"{p}: {'out of date' if '--check' in args else 'rewritten'}")
    return 1 if drift and "--check" in args else 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
