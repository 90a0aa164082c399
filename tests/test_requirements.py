"""Time-windowed requirements (issue 35 item 11): schema, windows, evaluation from every step, check, JUnit, page.

The run is two_link_switching cut to 30 s (its first fault at 20 s only), the switching scheme alone:
about a second once compiled.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

from ftcreport.cases import parse_case, with_duration
from ftcreport.cli import app
from ftcreport.errors import CaseError
from ftcreport.evaluation.requirements import evaluate_requirements, windows
from ftcreport.runner import run_scheme
from ftcreport.studies.check import requirement_items

CASES = Path(__file__).resolve().parents[1] / "cases"
runner = CliRunner()

HOLDS = {"id": "settled", "signal": "position_error", "start": {"after_fault": 5.0}, "end": "next_fault", "max": 0.01}
# the error at the fault (20 s) is 4.6e-3 m and still 1.2e-3 m at 21.5 s: a 1 mm bound is crossed in the window
VIOLATED = {"id": "tight", "signal": "position_error", "start": 21.0, "end": 23.0, "max": 1e-3}
# 15 s after the fault at 20 s is 35 s, after the end of the 30 s run
EMPTY = {"id": "late", "signal": "torque_abs", "start": {"after_fault": 15.0}, "end": "end", "max": 100.0}


def _data(requirements: list[dict], duration: float = 30.0) -> dict:
    data = tomllib.loads((CASES / "two_link_switching.toml").read_text())
    data["name"] = "req"
    data["faults"] = [f for f in data["faults"] if f["time"] < duration]
    data["simulation"]["duration"] = duration
    data["schemes"] = {"run": ["switching"], "switching": data["schemes"]["switching"]}
    data["claims"], data["thresholds"] = [], {}
    data["requirements"] = requirements
    return data


def _case(requirements: list[dict], **kw):
    return parse_case(_data(requirements, **kw), str(CASES / "req.toml"))


# ---------------------------------------------------------------------------------------- schema
@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"signal": "positon_error"}, "requirements[0].signal", "did you mean 'position_error'"),
        ({"start": {"after_falt": 5.0}}, "requirements[0].start.after_falt", "did you mean 'after_fault'"),
        ({"signal": "torque", "wheel": None}, "requirements[0].wheel", "required for the signed torque"),
        ({"signal": "torque", "wheel": "3r"}, "requirements[0].wheel", "3r"),
        ({"signal": "heading_error", "robot": 3}, "requirements[0].robot", "not in a 2-robot chain"),
        ({"robot": 1}, "requirements[0].robot", "heading_error only"),
        ({"start": 5.0, "end": {"after_fault": 2.0}}, "requirements[0].end", "needs start = { after_fault"),
        ({"end": {"after_fault": 2.0}}, "requirements[0].end.after_fault", "not after start.after_fault"),
        ({"start": 10.0, "end": 5.0}, "requirements[0].end", "not after start"),
        ({"min": 0.1, "max": 0.01}, "requirements[0].max", "the band is empty"),
        ({"max": None}, "requirements[0]", "give a bound"),
        ({"scheme": "swiching"}, "requirements[0].scheme", "did you mean 'switching'"),
        ({"scheme": "oracle"}, "requirements[0].scheme", "not in [schemes] run"),
        ({"max": "0.01"}, "requirements[0].max", "write it without quotes"),
        ({"bound": 0.01}, "requirements[0].bound", "unknown field"),
    ],
)
def test_bad_requirements_are_refused_naming_the_field(change, field, words):
    req = {k: v for k, v in (HOLDS | change).items() if v is not None}
    with pytest.raises(CaseError) as exc:
        _case([req])
    assert f": {field}: " in str(exc.value) and words in str(exc.value), str(exc.value)


def test_ids_are_unique():
    with pytest.raises(CaseError, match=r"requirements\[1\]\.id: 'settled' is already the id of requirements\[0\]"):
        _case([HOLDS, HOLDS | {"max": 0.02}])


def test_requirements_are_in_the_cache_key_and_the_baseline_table_is_not():
    from ftcreport.cases import case_hash

    plain = _case([])
    assert case_hash(plain, "v") != case_hash(_case([HOLDS]), "v")  # evaluated during the run: a new one re-runs
    tolerant = parse_case(_data([]) | {"baseline": {"rel_tol": 0.5}}, str(CASES / "req.toml"))
    assert case_hash(tolerant, "v") == case_hash(plain, "v")  # check's tolerances change no run


# ---------------------------------------------------------------------------------------- windows
def test_windows_from_events():
    ev = [20.0, 50.0, 80.0]
    w = windows(HOLDS, ev, 100.0)
    assert [(x.start, x.end, x.open_end, x.event) for x in w] == [
        (25.0, 50.0, True, 20.0),
        (55.0, 80.0, True, 50.0),
        (85.0, 100.0, False, 80.0),  # no later fault: the end of the run, closed
    ]
    w = windows({"start": {"after_fault": 0.0}, "end": {"after_fault": 2.0}}, ev, 81.0)
    assert [(x.start, x.end) for x in w] == [(20.0, 22.0), (50.0, 52.0), (80.0, 81.0)]
    assert [(x.start, x.end, x.open_end) for x in windows({"start": 10.0, "end": "next_fault"}, ev, 100.0)] == [
        (10.0, 20.0, True)
    ]
    assert windows({"start": {"after_fault": 5.0}, "end": "end"}, [], 100.0) == []  # no event, no window


# ----------------------------------------------------------------------------- evaluation on a run
@pytest.fixture(scope="module")
def run():
    case = _case([HOLDS, VIOLATED, EMPTY])
    r, m = run_scheme(case, "switching")
    assert r.status == "ok"
    return case, r, m


def test_a_window_holds_one_is_violated_one_is_empty(run):
    _, r, m = run
    recs = {x["id"]: x for x in m["requirements"]}
    assert set(recs) == {"settled", "tight", "late"}
    t, q, qd = r.t_stream, r.stream["q"], r.stream["q_d"]
    err = np.hypot(q[:, 0] - qd[:, 0], q[:, 1] - qd[:, 1])  # independent of ftcreport.evaluation.requirements

    held = recs["settled"]  # 25 s to the end (30 s): the only fault is at 20 s
    inside = (t >= 25.0) & (t <= 30.0)
    assert held["outcome"] == "holds" and held["samples"] == int(inside.sum())
    assert held["value_max"] == pytest.approx(err[inside].max(), rel=1e-15) and err[inside].max() < 0.01

    bad = recs["tight"]
    inside = np.flatnonzero((t >= 21.0) & (t <= 23.0))
    first = inside[np.argmax(err[inside] > 1e-3)]
    assert err[first] > 1e-3 and np.all(err[inside[inside < first]] <= 1e-3)
    assert bad["outcome"] == "violated"
    assert bad["first_violation"]["time"] == t[first]  # the step itself, not a logged sample near it
    assert bad["first_violation"]["value"] == pytest.approx(err[first], rel=1e-15)
    assert bad["worst"]["value"] == pytest.approx(err[inside].max(), rel=1e-15)
    assert f"first violation at {t[first]:.6g} s" in bad["reason"]

    empty = recs["late"]
    assert empty["outcome"] == "not evaluated" and empty["samples"] == 0
    assert "empty window" in empty["reason"] and "35 s" in empty["reason"]


def test_a_stopped_run_leaves_its_later_windows_not_evaluated(run):
    """The same stream cut at 22 s as if the run had stopped there: the window up to 30 s is not evaluated."""
    _, r, _ = run
    cut = r.t_stream <= 22.0
    S = {k: v[cut] for k, v in r.stream.items()}
    recs = evaluate_requirements([HOLDS, VIOLATED], "switching", r.t_stream[cut], S, [20.0], 30.0, 22.0, "diverged")
    by = {x["id"]: x for x in recs}
    assert (
        by["settled"]["outcome"] == "not evaluated"
        and "stopped (diverged) at 22 s, before the window" in (by["settled"]["reason"])
    )
    assert by["tight"]["outcome"] == "violated"  # the violation before the stop stands


def test_no_fault_event_is_stated():
    still = {"q": np.zeros((11, 4)), "q_d": np.zeros((11, 4))}
    recs = evaluate_requirements([HOLDS], "s", np.linspace(0, 1, 11), still, [], 1.0, 1.0, "ok")
    assert [(x["outcome"], x["reason"]) for x in recs] == [
        ("not evaluated", "no fault event in the run: the windows start after each fault event")
    ]


def test_gate_items_fail_on_violated_and_not_evaluated(run):
    case, _, m = run
    items = requirement_items("req", case.requirements, {"switching": m})
    assert [(i.testname, i.ok) for i in items] == [
        ("settled [fault at 20 s: 25-30 s]", True),
        ("tight [21-23 s]", False),
        ("late [fault at 20 s: 35-30 s]", False),
    ]
    assert all(i.classname == "req.switching.requirements" for i in items)
    items = requirement_items("req", case.requirements, {"switching": None})
    assert {i.detail for i in items} == {
        f"requirement {r.id}: not evaluated: the scheme was not run" for r in case.requirements
    }


def test_check_run_junit_and_page(tmp_path):
    src = tmp_path / "req.toml"
    src.write_text(tomli_w.dumps(_data([HOLDS, VIOLATED, EMPTY])))
    junit, out = tmp_path / "junit.xml", tmp_path / "r"
    res = runner.invoke(app, ["check", str(src), "--out", str(out), "--junit", str(junit), "-q"])
    assert res.exit_code == 1, res.output
    assert "1/3 requirement windows hold" in res.output
    assert "FAIL  req / switching / requirement tight [21-23 s]: position_error <= 0.001 m: violated" in res.output
    assert (
        "requirement late [fault at 20 s: 35-30 s]: torque_abs (largest wheel) <= 100 N m: not evaluated" in res.output
    )
    root = ET.fromstring(junit.read_bytes())
    cases = {(tc.get("classname"), tc.get("name")): tc for tc in root.iter("testcase")}
    ok = cases[("req.switching.requirements", "settled [fault at 20 s: 25-30 s]")]
    assert ok.find("failure") is None
    bad = cases[("req.switching.requirements", "tight [21-23 s]")].find("failure")
    assert "first violation at" in bad.get("message")
    m = json.loads((out / "req" / "switching" / "metrics.json").read_text())
    first = next(x for x in m["requirements"] if x["id"] == "tight")["first_violation"]
    # the page: a row per window, the window shaded and the first violation marked on the signal's figure
    page = (out / "req" / "index.html").read_text()
    assert 'id="requirements-table"' in page and page.count('data-requirement="') == 3
    spec = json.loads(page.split('id="plot-req-tight-spec">', 1)[1].split("</script>", 1)[0])
    rects = [s for s in spec["layout"]["shapes"] if s["type"] == "rect"]
    assert [(s["x0"], s["x1"]) for s in rects] == [(21.0, 23.0)]
    assert any(s["type"] == "line" and s["y0"] == 1e-3 for s in spec["layout"]["shapes"])
    marks = [d for d in spec["data"] if d.get("mode") == "markers"]
    assert marks[0]["x"] == [first["time"]] and marks[0]["y"] == [first["value"]]
    # run judges the requirements as check does (a gate item per window; exit 1 when one fails) and
    # names the failing one with its field on stderr
    res = runner.invoke(app, ["run", str(src), "--out", str(tmp_path / "r2"), "--no-report"])
    assert res.exit_code == 1, res.output
    assert "FAIL  req / switching / requirement tight [21-23 s]: position_error <= 0.001 m: violated" in res.output
    assert "requirements[1] (id 'tight')" in res.output


def test_shipped_case_requirement_holds_on_its_documented_windows():
    """two_link_switching's requirement over its first 60 s (faults at 20 and 50 s): every window holds."""
    data = tomllib.loads((CASES / "two_link_switching.toml").read_text())
    assert [r["id"] for r in data["requirements"]] == ["settled_between_faults"]
    case = with_duration(parse_case(data, str(CASES / "two_link_switching.toml")), 60.0)
    _, m = run_scheme(case, "switching")
    recs = m["requirements"]
    assert [(x["window_label"], x["outcome"]) for x in recs] == [
        ("fault at 20 s: 25-50 s", "holds"),
        ("fault at 50 s: 55-60 s", "holds"),
    ]
    assert recs[0]["value_max"] == pytest.approx(1.65e-3, rel=0.01)  # the comment's number: a 6x margin


def test_the_verdict_opens_with_the_failed_gate_items(tmp_path):
    """Issue 34 break 11: a threshold, claim or requirement that does not hold showed FAIL only in its table
    lower down; the verdict said nothing.  It now opens with each failed gate item (the same items ``run``
    and ``check`` print): which one, the scheme, the value against the bound; the ones that hold are not
    listed there."""
    data = _data([HOLDS, VIOLATED])
    data["thresholds"] = {
        "switching": {"position_error_final": {"max": 1e-9}, "switching_match_fraction": {"min": 0.5}}
    }
    claim = {"id": "tracks", "source": "3.2.3", "words": "tracks", "scheme": "switching"}
    data["claims"] = [claim | {"metric": "position_error_final", "max": 1e-12, "expect": "reproduced"}]
    src = tmp_path / "req.toml"
    src.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["run", str(src), "--out", str(tmp_path / "r")])
    assert res.exit_code == 1, res.output
    page = (tmp_path / "r" / "req" / "index.html").read_text()
    verdict = page.split('<section id="verdict">', 1)[1].split("</section>", 1)[0]
    gate = verdict.split('id="verdict-gate"', 1)[1].split("</div>", 1)[0]
    assert verdict.index('id="verdict-gate"') < verdict.index('class="verdict-sentence"')
    assert "3 of the case's 5 thresholds, claims and requirement windows do not hold" in gate
    assert "(ftcreport run and check exit 1)" in gate
    final = json.loads((tmp_path / "r" / "req" / "switching" / "metrics.json").read_text())["position_error_final"]
    assert f"threshold switching / position_error_final: {final:.4g} against &lt;= 1e-09" in gate
    assert "claim tracks (3.2.3): not reproduced (expected reproduced)" in gate
    assert "requirement switching / tight [21-23 s]: position_error &lt;= 0.001 m: violated" in gate
    assert "switching_match_fraction" not in gate and "settled" not in gate


def test_a_shortened_run_says_its_gate_is_not_judged(tmp_path):
    """The round-3 screenshots: after `run --duration` the page's verdict opened with the case's claims that
    "do not hold (ftcreport run and check exit 1)", while `run` exited 0 and said they are not judged."""
    data = _data([HOLDS, VIOLATED])
    data["thresholds"] = {"switching": {"position_error_final": {"max": 1e-9}}}
    src = tmp_path / "req.toml"
    src.write_text(tomli_w.dumps(data))
    res = runner.invoke(app, ["run", str(src), "--out", str(tmp_path / "r"), "--duration", "10"])
    assert res.exit_code == 0, res.output
    page = (tmp_path / "r" / "req" / "index.html").read_text()
    verdict = page.split('<section id="verdict">', 1)[1].split("</section>", 1)[0]
    assert 'id="verdict-gate"' not in verdict
    assert "this run was shortened to 10 s (--duration), so they are not judged here" in verdict


def test_cases_readme_says_run_exits_1_on_a_failed_window():
    """cases/README.md said that ``run`` prints the requirements and "does not change its exit code", while
    ``run`` exits 1 when a window is violated or not evaluated (test_check_run_junit_and_page).  The text is
    the behaviour's: the paragraph on outcomes says ``run`` judges them as ``check`` does and exits 1."""
    text = " ".join((CASES / "README.md").read_text().split())
    assert "does not change its exit code" not in text
    assert (
        "`run` judges them as `check` does, on the schemes it ran, and exits 1 when a window is violated or "
        "not evaluated" in text
    )
