"""Metrics read every integration step: ``log_every`` changes what is saved, never a metric (issue 18).

The audit's numbers on two_link_adaptive_eight: at the shipped log_every the old metrics read
torque_peak 214 N m and switch_count 121, against 657 N m and 905 at every step.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case
from ftcreport.runner import run_scheme

CASES = Path(__file__).resolve().parents[1] / "cases"


def _run(name: str, scheme: str, duration: float, log_every: int | None, method: str | None = None):
    case = load_case(CASES / f"{name}.toml")
    upd: dict = {"duration": duration} | ({"method": method} if method else {})
    if log_every is not None:
        upd["log_every"] = log_every
    case = case.model_copy(update={"simulation": case.simulation.model_copy(update=upd)})
    return case, *run_scheme(case, scheme)


# three cases, the three engines' paths: the compiled chained/two-link laws, switching's counts and
# delays, and the noisy 400 s active case whose diagnosis reads estimates; one in the Python loop (UKF);
# and error-controlled runs (issue 36: the stream is the accepted steps, unequal; the log every k-th of them)
@pytest.mark.parametrize(
    ("name", "scheme", "duration", "method"),
    [
        ("two_link_adaptive_eight", "switching", 60.0, None),
        ("two_link_adaptive_eight", "adaptive", 20.0, None),
        ("three_link_active", "active", 40.0, None),
        ("two_link_active", "active_ukf", 3.0, None),
        ("two_link_adaptive_eight", "switching", 20.0, "auto"),
        ("three_link_active", "active", 10.0, "auto"),
        ("motors/two_link_switching_motors", "switching", 3.0, "auto"),
    ],
)
def test_metrics_do_not_depend_on_log_every(name, scheme, duration, method):
    case, run_s, shipped = _run(name, scheme, duration, None, method)
    _, run_1, every = _run(name, scheme, duration, 1, method)
    assert case.simulation.log_every > 1  # the shipped value decimates
    assert run_s.t.size < run_1.t.size  # ... so less is saved
    assert run_s.t_stream.size == run_1.t_stream.size == run_1.t.size  # the stream is every step
    ignore = {"wall_time", "compile_time", "log_every", "case_hash"}  # log_every is part of the case's content
    differ = {
        k
        for k in every
        if k not in ignore and json.dumps(every[k], default=str) != json.dumps(shipped.get(k), default=str)
    }
    # bit-identical: the trajectory does not depend on logging and the metrics read the same samples
    assert not differ, differ


def test_the_audit_numbers_at_the_shipped_log_every():
    _, _, m = _run("two_link_adaptive_eight", "switching", 60.0, None)
    # read at every step (exactly the values the audit found with log_every = 1 on the full case)
    assert m["switch_count"] > 500
    _, _, a = _run("two_link_adaptive_eight", "adaptive", 1.0, None)
    # the first-instant transient of the adaptive law: 657 N m at the first steps, missed by decimation
    assert a["torque_peak"] == pytest.approx(656.8, rel=1e-3)


def test_requirements_do_not_depend_on_log_every():
    """Requirement windows read every step too (issue 35): the shipped one on two_link_switching (log_every = 2)
    and a violated one whose first violation falls between logged samples, identical at log_every = 1."""
    from ftcreport.cases import Requirement

    window = {"start": {"after_fault": 0.001}, "end": {"after_fault": 1.0}}
    extra = Requirement.model_validate({"id": "tight", "signal": "torque_abs", "max": 0.05} | window)

    def records(log_every):
        case = load_case(CASES / "two_link_switching.toml")
        sim = case.simulation.model_copy(update={"duration": 60.0, "log_every": log_every or case.simulation.log_every})
        case = case.model_copy(update={"simulation": sim, "requirements": [*case.requirements, extra]})
        run, m = run_scheme(case, "switching")
        return run, m["requirements"]

    run_s, shipped = records(None)
    _, every = records(1)
    assert json.dumps(shipped) == json.dumps(every)
    firsts = [r["first_violation"]["time"] for r in shipped if r["outcome"] == "violated"]
    assert firsts == pytest.approx([20.005, 50.005], abs=1e-9)  # 0.0516 and 0.0899 N m: the first step of each window
    # ... at steps the shipped log (every second step) does not hold: the log alone would have missed them
    assert not any(np.isclose(run_s.t, f, rtol=0, atol=1e-12).any() for f in firsts)
