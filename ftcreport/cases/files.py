"""Case files: reading, overlays, the JSON schema, the case's hash, TOML writing."""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path
from typing import Any

from ..errors import CaseError
from ..infra.inputs import input_problem, read_input
from .case import Case
from .parse import parse_case


def plugin_digest(case: Case) -> str:
    """Hash of the contents of the case's scheme files and of the user modules they import ('' when it has no
    scheme file): a changed law, or a changed helper module it imports, is a changed case.

    The imported modules are those :func:`ftcreport.schemes.registry.plugin_imports` records when the file
    is loaded (the case's parse loads it): the user's own modules (outside the Python installation,
    site-packages and ftcreport) imported at the file's import, named by its globals.  Not covered: a
    module imported later, inside a function (``pack``, the law), and data files a module reads.
    """
    if not case.plugins:
        return ""
    h = hashlib.sha256()
    for p in case.plugins:
        try:
            h.update(Path(p).name.encode() + b"\0" + read_input(p, "scheme file"))
        except CaseError:
            h.update(f"{p}: unreadable".encode())
        for dep in _imports(p):
            h.update(b"\0import\0" + dep.name.encode() + b"\0" + _read_dep(dep))
    return h.hexdigest()[:16]


def plugin_digests(case: Case) -> dict[str, str]:
    """Each scheme file's own content hash (16 hex digits), by its path, and each user module it imports
    (:func:`plugin_digest`), by its path: which file changed since a run."""
    out = {}
    for p in case.plugins:
        try:
            out[str(p)] = hashlib.sha256(read_input(p, "scheme file")).hexdigest()[:16]
        except CaseError:
            out[str(p)] = "unreadable"
        for dep in _imports(p):
            out.setdefault(str(dep), hashlib.sha256(_read_dep(dep)).hexdigest()[:16])
    return out


def _imports(path) -> tuple[Path, ...]:
    from ..schemes.registry import plugin_imports

    return plugin_imports(path)


def _read_dep(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError:
        return b"unreadable"


def case_schema() -> dict[str, Any]:
    """The JSON Schema of a case file, generated from the models (descriptions, units, ranges).

    ``ftcreport cases schema`` prints it; ``cases/case.schema.json`` is this, written by
    ``python -m ftcreport.cases.schema_doc`` (a test fails when it drifts).
    """
    schema = Case.model_json_schema(mode="validation")
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://ftcreport.invalid/case.schema.json",
        **schema,
        "title": "ftcreport case file",
    }


def load_case(path: str | Path) -> Case:
    """Read and validate a TOML case file (an overlay is resolved over its ``base_case`` first)."""
    path = Path(path)
    data = _read_toml(path)
    if "base_case" not in data:
        return parse_case(data, str(path))
    merged = resolve_overlay(path, data)
    try:
        return parse_case(merged, str(path))
    except CaseError as exc:
        lines = [_name_base_field(line, str(path), data, merged) for line in exc.lines]
        raise CaseError(_name_base_field(str(exc), str(path), data, merged), lines) from None


#: Fields an overlay never takes from its base: they describe the base's own results or identity.
OWN_FIELDS = (
    "name",
    "description",
    "thresholds",
    "claims",
    "requirements",
    "baseline",
    "campaign",
    "expected_status",
    "expected_status_of",
)


def _merge(base: dict, over: dict) -> dict:
    """``over`` on ``base``: tables merged key by key, anything else (values, arrays) replaced whole; a table
    whose ``kind`` the overlay changes (a reference, the kinematic law) is the overlay's whole: the base's
    fields of the other kind would be refused (TOML cannot delete a key)."""
    out = dict(base)
    for key, val in over.items():
        switched = (
            isinstance(val, dict)
            and isinstance(out.get(key), dict)
            and val.get("kind", out[key].get("kind")) != out[key].get("kind")
        )
        if isinstance(val, dict) and isinstance(out.get(key), dict) and not switched:
            out[key] = _merge(out[key], val)
        else:
            out[key] = val
    return out


def resolve_overlay(path: Path, data: dict, _seen: tuple[Path, ...] = ()) -> dict:
    """The full case of an overlay file: its base (resolved in turn), without OWN_FIELDS, then ``data``.

    ``base_case`` stays in the result (provenance; :func:`parse_case` only checks it is a string).
    Errors name the overlay file and its ``base_case`` field.
    """
    ref = data.get("base_case")
    if not isinstance(ref, str) or not ref.strip():
        raise CaseError(f"{path}: base_case: must be the path of a case file (a string), got {ref!r}")
    if (why := input_problem(path.parent / ref)) is not None:  # a FIFO, device, directory, link loop: never opened
        raise CaseError(f"{path}: base_case: '{ref}': {why}")
    base_path = (path.parent / ref).resolve()
    seen = (*_seen, path.resolve())
    if base_path in seen:
        chain = " -> ".join(str(p) for p in (*seen, base_path))
        raise CaseError(f"{path}: base_case: '{ref}' makes a cycle ({chain})")
    if len(seen) > 8:
        raise CaseError(f"{path}: base_case: more than 8 overlays deep")
    try:
        base = _read_toml(base_path)
    except CaseError as exc:
        raise CaseError(f"{path}: base_case: '{ref}': {exc}") from None
    if "base_case" in base:
        base = resolve_overlay(base_path, base, seen)
    base = {k: v for k, v in base.items() if k not in OWN_FIELDS and k != "base_case"}
    return _merge(base, data)


_ABSENT = object()


def _lookup(node: Any, parts: list[str]) -> Any:
    """The value at a field path's parts (``["faults", "[1]", "value"]``) in parsed TOML, or _ABSENT."""
    for part in parts:
        if part.startswith("[") and isinstance(node, list):
            i = int(part.strip("[]"))
            if i >= len(node):
                return _ABSENT
            node = node[i]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            return _ABSENT
    return node


def _name_base_field(message: str, source: str, overlay: dict, merged: dict) -> str:
    """Say so when the field an error names has its value from the base case, not from the overlay.

    A field in neither (a required field missing, an event's value left out) is nobody's: no note.
    """
    rest = message.removeprefix(f"{source}: ")
    loc = rest.split(": ", 1)[0]
    parts = [p for p in loc.replace("[", ".[").split(".") if p]
    if not parts or loc in ("<root>", "name"):
        return message
    if _lookup(overlay, parts) is _ABSENT and _lookup(merged, parts) is not _ABSENT:
        return f"{message} (the value comes from the base case {overlay['base_case']})"
    return message


def overlay_text(path: str | Path) -> str | None:
    """The resolved case of an overlay file as TOML text (None for a plain case file).

    Batch and run store this beside the runs, so the stored copy parses on its own; the overlay's
    own text follows as comments (provenance).
    """
    path = Path(path)
    data = _read_toml(path)
    if "base_case" not in data:
        return None
    merged = resolve_overlay(path, data)
    own = "".join(f"# | {line}\n" for line in read_input(path).decode("utf-8").splitlines())
    body = "".join(f"{_toml_key(k)} = {_toml_value(v)}\n" for k, v in merged.items())
    return f"# {path} resolved over its base case {data['base_case']}; the file itself:\n{own}\n{body}"


def _toml_key(key: str) -> str:
    return key if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key) else _toml_string(key)


def _toml_string(s: str) -> str:
    """A TOML basic string: quote, backslash and control characters escaped (TOML 1.0, "String").

    Not ``json.dumps``: JSON writes a character beyond U+FFFF as a surrogate pair of escapes, which
    TOML refuses (a stored overlay with such a description read back as damaged), and leaves U+007F as is.
    """
    out = []
    for ch in s:
        o = ord(ch)
        if ch in '"\\':
            out.append("\\" + ch)
        elif (o < 0x20 and ch != "\t") or o == 0x7F:
            out.append(f"\\u{o:04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(v: Any) -> str:
    """One TOML value on one line (inline tables and arrays; a case file holds nothing else)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise CaseError(f"cannot write {type(v).__name__} as TOML")


def _read_toml(path: Path) -> dict:
    """A TOML file as a dict; CaseError naming the file when it cannot be read or parsed."""
    raw = read_input(path)  # a regular file of a bounded size, or CaseError naming it (never blocks)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CaseError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); a case file is TOML text"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise CaseError(f"{path}: not valid TOML (nested too deeply)") from None
    return data


def case_hash(case: Case, version: str) -> str:
    """Content hash of a validated case and the package version (result cache key).

    The thesis claims are left out: they are judged on stored metrics and change no run.
    """
    # the motor fields (issue 19) are left out when unused, so older cases keep their hashes
    # [baseline] only sets check's tolerances; [[requirements]] are evaluated during the run (from every
    # step) and so belong to its content, left out when absent so that older cases keep their hashes
    exclude: dict[str, Any] = {"claims": True, "plugins": True, "baseline": True}
    if not case.requirements:
        exclude["requirements"] = True
    if case.actuators is None:
        exclude["actuators"] = True
    if case.base_case is None:  # the overlay field (issue 19 item 4): older cases keep their hashes
        exclude["base_case"] = True
    # the tolerances (issue 36) are content for a fixed step too: a stopped fixed-step run is re-checked by its
    # error-controlled twin at them, which labels the stop (fast.recheck: step_unstable or diverged)
    if case.plant.noise.sample_time is None:  # the sensor's own clock (issue 36): older cases keep their hashes
        exclude["plant"] = {"noise": {"sample_time": True}}
    plain = {i: {"motor", "value"} for i, f in enumerate(case.faults) if f.motor is None and f.value is None}
    if plain:
        exclude["faults"] = plain
    blob = case.model_dump_json(exclude=exclude) + "|" + version
    if case.plugins:  # the scheme files' contents, not where they are
        blob += "|" + plugin_digest(case)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
