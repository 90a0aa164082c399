"""JUnit XML of threshold checks (one testcase per case x scheme x threshold).

The suite carries ``time`` (seconds the check took), ``timestamp`` (when it started, ISO 8601
UTC) and the provenance manifest as ``<properties>`` (flattened: ``ftcreport.git.revision``,
``dependencies.numba``, ``platform.cpu``, ...); a testcase's ``time`` is its run's wall time.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from ..check import ThresholdResult
from ..claims import bound_text
from ..store import write_atomic

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


def junit_xml(
    results: list[ThresholdResult],
    errors: dict[str, str] | None = None,
    claims=None,
    *,
    properties: Mapping[str, Any] | None = None,
    time: float | None = None,
    timestamp: str | None = None,
    run_times: Mapping[tuple[str, str], float] | None = None,
    items=(),
) -> bytes:
    """JUnit XML; case files that failed to load appear as errored testcases.

    ``claims`` (ftcreport.claims.ClaimResult): one testcase per thesis claim, classname
    ``<case>.claims``, failed when its outcome differs from the expected one.

    ``properties``: the manifest (nested; flattened into ``<property name value>``); ``time`` [s] and
    ``timestamp`` of the suite; ``run_times``: wall time per (case, scheme) for the testcases.
    ``items``: further gate items (ftcreport.requirements.GateItem: requirement windows, baseline
    deltas), one testcase each, failed with its message when it does not pass.
    """
    errors = errors or {}
    run_times = run_times or {}
    suite = ET.Element("testsuite", name="ftcreport.check")
    if timestamp is not None:
        suite.set("timestamp", timestamp)
    if properties:
        props = ET.SubElement(suite, "properties")
        for name, value in flatten(properties).items():
            ET.SubElement(props, "property", name=name, value=value)
    n_fail = 0
    for r in results:
        tc = ET.SubElement(
            suite,
            "testcase",
            classname=f"{r.case}.{r.scheme}",
            name=r.metric,
            time=f"{float(run_times.get((r.case, r.scheme)) or 0.0):.3f}",
        )
        expected = bound_text(r.min, r.max)
        actual = "n/a" if r.actual is None else f"{r.actual:.6g}"
        ET.SubElement(tc, "system-out").text = f"expected {expected}; actual {actual}"
        if not r.ok:
            n_fail += 1
            f = ET.SubElement(tc, "failure", message=f"{r.metric}: {r.reason}; expected {expected}, actual {actual}")
            f.text = f"{r.case} / {r.scheme} / {r.metric}: {r.reason}"
    claims = list(claims or [])
    for c in claims:
        tc = ET.SubElement(suite, "testcase", classname=f"{c.case}.claims", name=c.id)
        ET.SubElement(tc, "system-out").text = f"{c.source}: {c.outcome} (expected {c.expect}); {c.reason}"
        if not c.ok:
            n_fail += 1
            msg = f"claim {c.id}: {c.outcome}, expected {c.expect}: {c.reason}"
            ET.SubElement(tc, "failure", message=msg).text = f"{c.case} / claim {c.id}: {msg}"
    items = list(items)
    for it in items:
        tc = ET.SubElement(suite, "testcase", classname=it.classname, name=it.name)
        ET.SubElement(tc, "system-out").text = "\n".join([it.message, *it.details])
        if not it.passed:
            n_fail += 1
            ET.SubElement(tc, "failure", message=it.message).text = "\n".join(it.details) or it.message
    for name, msg in errors.items():
        tc = ET.SubElement(suite, "testcase", classname=name, name="load")
        ET.SubElement(tc, "error", message=msg).text = msg
    suite.set("tests", str(len(results) + len(claims) + len(items) + len(errors)))
    suite.set("failures", str(n_fail))
    suite.set("errors", str(len(errors)))
    suite.set("time", f"{0.0 if time is None else float(time):.3f}")
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def write_junit(
    path: Path, results: list[ThresholdResult], errors: dict[str, str] | None = None, claims=None, **suite: Any
) -> None:
    """Write :func:`junit_xml` atomically (``suite``: its keyword arguments)."""
    write_atomic(Path(path), junit_xml(results, errors, claims, **suite))
