"""JUnit XML of threshold checks (one testcase per case x scheme x threshold)."""

from __future__ import annotations

from pathlib import Path
from xml.etree import ElementTree as ET

from ..check import ThresholdResult
from ..store import write_atomic

__all__ = ["junit_xml", "write_junit"]


def junit_xml(results: list[ThresholdResult], errors: dict[str, str] | None = None, claims=None) -> bytes:
    """JUnit XML; case files that failed to load appear as errored testcases.

    ``claims`` (ftcreport.claims.ClaimResult): one testcase per thesis claim, classname
    ``<case>.claims``, failed when its outcome differs from the expected one.
    """
    errors = errors or {}
    suite = ET.Element("testsuite", name="ftcreport.check")
    n_fail = 0
    for r in results:
        tc = ET.SubElement(
            suite,
            "testcase",
            classname=f"{r.case}.{r.scheme}",
            name=r.metric,
        )
        expected = " and ".join(
            x for x in (f">= {r.min:g}" if r.min is not None else "", f"<= {r.max:g}" if r.max is not None else "") if x
        )
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
    for name, msg in errors.items():
        tc = ET.SubElement(suite, "testcase", classname=name, name="load")
        ET.SubElement(tc, "error", message=msg).text = msg
    suite.set("tests", str(len(results) + len(claims) + len(errors)))
    suite.set("failures", str(n_fail))
    suite.set("errors", str(len(errors)))
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def write_junit(path: Path, results: list[ThresholdResult], errors: dict[str, str] | None = None, claims=None) -> None:
    write_atomic(Path(path), junit_xml(results, errors, claims))
