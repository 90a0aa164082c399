"""JUnit XML of the gate: one testcase per gate item (:mod:`ftcreport.studies.check`).

A run is the testcase ``<case>.<scheme>`` / ``status``; a threshold ``<case>.<scheme>`` / ``<metric>``;
a thesis claim ``<case>.claims`` / ``<id>``; a case file that could not be read ``<file>`` / ``load``
(an errored testcase).  The suite carries ``time`` (seconds the check took), ``timestamp`` (when it
started, ISO 8601 UTC) and the provenance manifest as ``<properties>`` (flattened:
``ftcreport.git.revision``, ``dependencies.numba``, ``platform.cpu``, ...); a testcase's ``time`` is
its run's wall time.

Every text is written with its control characters escaped (:func:`ftcreport.errors.printable`): XML 1.0
cannot hold most of them, and the file is always well-formed whatever a name or a reason holds.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from ..errors import printable
from ..storage.store import write_atomic
from ..studies.check import GateItem

__all__ = ["flatten", "junit_xml", "write_junit"]


def flatten(obj: Any, prefix: str = "") -> dict[str, str]:
    """A nested manifest as ``{"a.b.c": "value"}`` (lists of records as JSON text)."""
    out: dict[str, str] = {}
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            out |= flatten(v, f"{prefix}{k}.")
        return out
    key = prefix.removesuffix(".")
    if isinstance(obj, list | tuple):
        out[key] = json.dumps(obj, default=str)
    else:
        out[key] = "" if obj is None else str(obj)
    return out


def _x(text: object) -> str:
    """Text XML 1.0 can hold: control characters, lone surrogates and non-characters escaped."""
    return printable(text)


def junit_xml(
    items: Iterable[GateItem],
    *,
    properties: Mapping[str, Any] | None = None,
    time: float | None = None,
    timestamp: str | None = None,
) -> bytes:
    """JUnit XML of the gate items: a failed item is a ``<failure>``, a case file in error an ``<error>``.

    ``properties``: the manifest (nested; flattened into ``<property name value>``); ``time`` [s] and
    ``timestamp`` of the suite.
    """
    items = list(items)
    suite = ET.Element("testsuite", name="ftcreport.studies.check")
    if timestamp is not None:
        suite.set("timestamp", _x(timestamp))
    if properties:
        props = ET.SubElement(suite, "properties")
        for name, value in flatten(properties).items():
            ET.SubElement(props, "property", name=_x(name), value=_x(value))
    for it in items:
        tc = ET.SubElement(
            suite, "testcase", classname=_x(it.junit_class), name=_x(it.junit_name), time=f"{float(it.time):.3f}"
        )
        if it.detail:
            ET.SubElement(tc, "system-out").text = _x(it.detail)
        if it.error:
            ET.SubElement(tc, "error", message=_x(it.message)).text = _x(it.message)
        elif not it.ok:
            msg = f"{it.name}: {it.message}" + (f"; {it.detail}" if it.detail and it.detail not in it.message else "")
            ET.SubElement(tc, "failure", message=_x(msg)).text = _x(f"{it.case} / {msg}")
    suite.set("tests", str(len(items)))
    suite.set("failures", str(sum(not i.ok and not i.error for i in items)))
    suite.set("errors", str(sum(i.error for i in items)))
    suite.set("time", f"{0.0 if time is None else float(time):.3f}")
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def write_junit(path: Path, items: Iterable[GateItem], **suite: Any) -> None:
    """Write :func:`junit_xml` atomically (``suite``: its keyword arguments)."""
    write_atomic(Path(path), junit_xml(items, **suite))
