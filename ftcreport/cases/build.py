"""Building the simulation objects from a validated case (pure), the template case."""

from __future__ import annotations

import math

import numpy as np
from pydantic import ValidationError

from ..errors import CaseError
from ..model import Chain
from ..schemes.fields import _FieldError
from .case import Case, _check_budget
from .parse import _field_errors
from .tables import Simulation


# ---------------------------------------------------------------------- building (pure)
def build_chain(case: Case) -> Chain:
    """The controllers' model of the chain ([robots])."""
    r = case.robots
    return Chain(**{k: r.values(k) for k in ("a", "b", "r", "m", "I", "d")})


def build_plant_chain(case: Case) -> Chain:
    """The true chain: [robots] times the [plant.mismatch] factors."""
    r, mm = case.robots, case.plant.mismatch
    vals = {}
    for k in ("a", "b", "r", "m", "I", "d"):
        base = np.asarray(r.values(k), dtype=float)
        f = getattr(mm, k)
        vals[k] = (base * (np.asarray(f, dtype=float) if isinstance(f, list) else float(f))).tolist()
    return Chain(**vals)


def initial_state(case: Case, ref) -> tuple[np.ndarray, np.ndarray]:
    """(q0, eta0) from the case's initial block and the reference at t = 0."""
    n = case.robots.n
    ini = case.initial
    r0 = ref.at(0.0)
    if ini.mode == "absolute":
        th = np.radians(ini.headings_deg) if ini.headings_deg is not None else r0.q_d[:1:-1]
        q0 = np.concatenate(([ini.x, ini.y], np.asarray(th, dtype=float)[::-1]))
        eta0 = np.zeros(2) if ini.eta is None else np.asarray(ini.eta, dtype=float)
    else:
        q0 = r0.q_d.copy()
        q0[0] += ini.x
        q0[1] += ini.y
        off = np.zeros(n) if ini.headings_deg is None else np.radians(ini.headings_deg)
        q0[2:] += (off + math.radians(ini.heading_offset_deg))[::-1]
        eta0 = r0.eta_d.copy() if ini.eta is None else np.asarray(ini.eta, dtype=float)
    return q0, eta0


def dropped_faults(case: Case, duration: float) -> str | None:
    """The warning for the events a ``--duration`` drops (those at or after it), each named, or None.

    Not a refusal (issue 34 item 10 allows either): shortening every case is how a batch is smoke-tested
    (``batch cases/ --duration 2``, the README's ``run ... --duration 30``), and the warning names
    what the shortened run no longer covers.  The same event in a case file is an error
    (``faults[i].time``): there nothing says the user chose to cut the run.
    """
    late = [(i, f) for i, f in enumerate(case.faults) if f.time >= duration]
    if not late:
        return None
    named = ", ".join(f"faults[{i}] (t = {f.time:g} s, wheel {f.wheel})" for i, f in late)
    return (
        f"--duration {duration:g}: drops {named}, at or after the end of the shortened run; "
        f"the run covers only the events before {duration:g} s"
    )


def with_duration(case: Case, duration: float) -> Case:
    """The same case simulated for ``duration`` s (events at or after it dropped: :func:`dropped_faults`
    words the warning)."""
    if not (math.isfinite(duration) and duration > 0):
        raise CaseError(f"{case.name}: --duration: must be a finite number of seconds > 0, got {duration}")
    s = case.simulation
    if s.sample_time is not None and duration < s.sample_time:
        raise CaseError(
            f"{case.name}: --duration {duration:g}: shorter than one control sample (simulation.sample_time = "
            f"{s.sample_time:g} s)"
        )
    try:  # validated again: the sampling's limits depend on the duration
        sim = Simulation.model_validate({**s.model_dump(), "duration": float(duration), "dt": min(s.dt, duration)})
    except ValidationError as exc:
        loc, why = _field_errors(exc.errors(), Case)[0]
        loc = loc if loc.startswith("simulation") else f"simulation.{loc}"
        raise CaseError(f"{case.name}: --duration {duration:g}: {loc}: {why}") from None
    faults = [f for f in case.faults if f.time < duration]
    # the campaign table's ranges refer to the full duration; a shortened run is not a campaign base
    short = case.model_copy(update={"simulation": sim, "faults": faults, "campaign": None})
    try:
        _check_budget(short)
    except _FieldError as exc:
        raise CaseError(f"{case.name}: --duration {duration:g}: {exc.loc}: {exc.msg}") from None
    return short


TEMPLATE = """# A case file for ftcreport (documented field by field in cases/README.md).
# Units: SI; angles in degrees where a name ends in _deg.
description = "Three robots on a circle; robot 2 loses its left motor at 20 s"

[robots]
n = 3               # number of robots (robot 1 is the leader)
d = 1.0             # link lengths [m]: a scalar, or a list of n - 1 values leader first
# a, b, r, m, I default to the thesis robots: 0.3 m, 0.75 m, 0.15 m, 30 kg, 15.625 kg m^2

[reference]         # path of the last robot: unicycle | circle | eight | line | sinusoid
kind = "circle"
radius = 5.0        # [m]
speed = 0.5         # [m/s]

[initial]           # offsets from the reference at t = 0 (mode = "absolute" for absolute values)
x = 0.3             # [m]
y = -0.2            # [m]
heading_offset_deg = 10.0

[[faults]]          # from time on, wheel has tau = sigma u + ubar
time = 20.0         # [s]
wheel = "2l"        # "1r", "1l", ..., "nr", "nl"
sigma = 0.0         # effectiveness in [0, 1]
ubar = 0.0          # friction [N m]

[kinematic]         # "two_link" (n = 2: k1, k2, k3) or "chained" (any n)
kind = "chained"
c_chain = 0.3
c_alpha2 = 2.0
c_xi1 = 2.0
kappa = 5.0

[schemes.nominal]   # no FTC
k_v = 5.0
[schemes.switching] # multiple models + switching
k_v = 5.0
gamma = 10.0
T_min = 0.01
[schemes.oracle]    # knows the true faults
k_v = 5.0

[simulation]
method = "auto"     # error-controlled: DOPRI5, or ROS34PW2/ETD3 for a stiff loop (the page says which); "rk4": fixed
dt = 0.02           # [s] the longest step (metrics and figures read the steps); auto takes shorter ones where needed
rtol = 1e-6         # each step's local error at most atol + rtol |x| for every state
atol = 1e-8
duration = 60.0     # [s]
log_every = 5

[thresholds.switching]
position_error_final = { max = 1e-3 }
"""
