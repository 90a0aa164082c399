"""The compiled engine (ftcreport.fast), piece by piece, against independent derivations.

The chained form against the sympy derivation, the reference jets against closed forms, the
singular stop, the switching tie rule, the metrics' wheel speeds against the model.  The Python
loop the engine was once compared with is gone (issue 17: each equation once); whole runs are held
by the golden windows (tests/test_golden.py, every case and scheme), the model by its invariants
and the thesis matrices (tests/test_model.py, tests/test_power.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from chained_reference import symbolic_chained_form

from ftcreport.cases import load_case, with_duration
from ftcreport.fast import kernels as F
from ftcreport.fast.engine import compiled_spec
from ftcreport.model import Chain
from ftcreport.references import FlatReference, circle, eight
from ftcreport.runner import build, make_controller
from ftcreport.sim import Plant, SimSettings, simulate

CASES = Path(__file__).resolve().parents[1] / "cases"


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_numeric_chained_form_equals_the_sympy_derivation(n):
    rng = np.random.default_rng(n)
    d = rng.uniform(0.5, 1.5, n - 1)
    f_xi, f_T = symbolic_chained_form(n)
    work = np.zeros((9 * n, n + 2))
    for _ in range(30):
        q = np.concatenate((rng.normal(size=2), rng.uniform(-1.0, 1.0, n)))
        th = q[:1:-1]
        xi = np.array([q[0], *f_xi(th, tuple(d)), q[1]])
        T21, T22 = f_T(th, tuple(d))
        T = np.array([[np.cos(th[-1]), 0.0], [T21, T22]])
        xi2, T2 = np.empty(n + 2), np.empty((2, 2))
        F.xi_T(q, d, work, xi2, T2)
        np.testing.assert_allclose(xi2, xi, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(T2, T, rtol=1e-12, atol=1e-12)


def test_compiled_path_jets_are_the_analytic_derivatives():
    """path_jets (behind TrigPath.jets) against the derivatives of the eight's closed form (3.3.2.3, E11).

    x = 3 sin 0.3t, y = 5 sin 0.15t, rotated by rot: the normalized coefficients are f^(k)(t) / k!.
    Same formula evaluated in another order: round-off (1e-13 absolute on values below 10).
    """
    path = eight()
    c, s = math.cos(path.rotation), math.sin(path.rotation)
    for t in np.linspace(0.0, 40.0, 17):
        X, Y = path.jets(float(t), 3)
        x = [
            3 * math.sin(0.3 * t),
            0.9 * math.cos(0.3 * t),
            -0.27 * math.sin(0.3 * t) / 2,
            -0.081 * math.cos(0.3 * t) / 6,
        ]
        y = [5 * math.sin(0.15 * t), 0.75 * math.cos(0.15 * t), -0.1125 * math.sin(0.15 * t) / 2]
        y.append(-0.016875 * math.cos(0.15 * t) / 6)
        np.testing.assert_allclose(X, c * np.array(x) - s * np.array(y), rtol=0, atol=1e-13)
        np.testing.assert_allclose(Y, s * np.array(x) + c * np.array(y), rtol=0, atol=1e-13)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_compiled_reference_on_a_circle_is_the_rigid_rotation(n):
    """On a circle every robot turns at v / R, v_n = v, eta_d is constant, P_n stays on the circle.

    The chain in steady turning is a rigid body rotating at omega = v / R (each follower on its own
    smaller circle), so omega_1d = thetadot_i = v / R and etadot_d = 0: the jets reproduce it to round-off.
    """
    radius, v = 6.0, 0.7
    ref = FlatReference(circle(radius, v, center=(1.0, -2.0)), [0.9] * (n - 1))
    for t in np.linspace(0.0, 50.0, 11):
        r = ref.at(float(t))
        np.testing.assert_allclose(r.theta_dot, v / radius, rtol=1e-12)
        np.testing.assert_allclose(r.eta_d, [v, v / radius], rtol=1e-12)
        np.testing.assert_allclose(r.eta_d_dot, 0.0, atol=1e-12)
        assert abs(math.hypot(r.q_d[0] - 1.0, r.q_d[1] + 2.0) - radius) < 1e-12


def test_a_singular_trial_stage_stops_the_run_and_keeps_the_log():
    from ftcreport.control.kinematic import ChainedBackstepping
    from ftcreport.control.tracking import TrackingController

    chain = Chain.uniform(3, d=1.0)
    # a reference that turns harder than a 3-robot chain started 60 deg off can follow
    ref = FlatReference(circle(2.0, 0.6), chain.d)
    kin = ChainedBackstepping(chain.d, ref, [0.0, 0.0, 0.0], 1.0, 1.0, 5.0)
    q0 = ref.at(0.0).q_d + np.array([0.0, 0.8, 1.0, 1.0, 1.0])
    run = simulate(Plant(chain), TrackingController(chain, kin, 5.0), q0, np.zeros(2), SimSettings(0.01, 30.0))
    # an RK4 stage of the step from t = 0.13 s reaches the backstepping's singular set, and at dt/4 again at
    # 0.1375 s from an accepted state within the set's band (|kappa - Delta_1| < sin(20 deg) kappa): the law's
    # own singular set (issue 36 item 4), not the step
    assert run.status == "singular", run.reason
    assert "the backstepping law's singular set (kappa = Delta_1, ERRATA E12d)" in run.reason
    assert "reached by a trial stage at dt = 0.01 s (t = 0.13 s) and again at dt/4" in run.reason
    assert 0.0 < run.t_end < 30.0 and run.t[-1] == run.t_end
    assert np.all(np.isfinite(run["q"])) and run.t.size > 10  # the log up to the stop is kept


def test_every_built_in_scheme_has_a_compiled_counterpart():
    """simulate refuses a controller without one (tests/test_sim.py); make_controller builds none such."""
    built = build(with_duration(load_case(CASES / "two_link_active.toml"), 0.1))
    for scheme in ("nominal", "oracle", "switching", "adaptive", "active", "active_ukf"):
        if getattr(built.case.schemes, scheme, None) is not None:
            assert compiled_spec(make_controller(built, scheme)) is not None, scheme


def test_a_run_without_the_ukf_does_not_load_filterpy_or_sympy():
    """The simulation process stays lean (issue 9, peak RSS of a 400 s run <= 200 MB): filterpy pulls
    scipy.stats (about 65 MB resident) and sympy about 30 MB; only the UKF and the derivations need them."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from ftcreport.cases import load_case, with_duration\n"
        "from ftcreport.runner import run_scheme\n"
        f"run_scheme(with_duration(load_case({str(CASES / 'three_link_active.toml')!r}), 1.0), 'active')\n"
        "print(sorted(m for m in ('filterpy', 'sympy', 'scipy.stats', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_switching_ties_go_to_the_lowest_index():
    """Costs within TIE_RTOL of the smallest are a tie and the lowest index wins, whichever of the tied
    models round-off made smaller: argmin alone made runs depend on the order of floating-point operations."""
    from ftcreport.control.switching import TIE_RTOL

    assert F.TIE_RTOL == TIE_RTOL
    built = build(load_case(CASES / "three_link_switching.toml"))
    ctrl = make_controller(built, "switching")
    spec = compiled_spec(ctrl)
    assert ctrl.N >= 4  # models
    q, eta = built.q0, np.array([0.5, 0.1])
    xc = np.asarray(ctrl.initial_state(0.0, q, eta), dtype=float)
    f = 1.0 - ctrl.patterns  # etatilde_k = (eta - h) + sum_j f_kj z_j (superposed filters)
    # one wheel model 1 assumes failed and 3 does not, and one the other way round (z = 0 for the others)
    j1 = int(np.flatnonzero((f[1] == 1) & (f[3] == 0))[0])
    j3 = int(np.flatnonzero((f[3] == 1) & (f[1] == 0))[0])
    h = eta + 1e-2  # every model far off, but 1 and 3 close and tied

    def selected(e1, e3):
        z = np.zeros((ctrl.chain.n_wheels, 2))
        z[j1], z[j3] = e1 - (eta - h), e3 - (eta - h)
        xc[ctrl._filt] = np.concatenate((h, z.ravel()))
        fast = xc.copy()
        F.switching_select(spec.P, 1.0, eta, fast[ctrl.kin.n_states :])  # the rule on the scheme's own states
        return ctrl.costs(eta, xc), round(fast[ctrl._sel])

    # 3 smaller by 1e-11 relative: argmin would pick it
    J, sel = selected(-np.array([3e-5, 4e-5]), -np.array([3e-5, 4e-5 * (1.0 - 1e-11)]))
    assert J[3] < J[1] < J[3] * (1.0 + TIE_RTOL) and J.min() == J[3]
    assert sel == 1
    # a real difference (J[1] 3 % above J[3]): the smaller cost wins
    assert selected(-np.array([3e-5, 4.1e-5]), -np.array([3e-5, 4e-5]))[1] == 3


@pytest.mark.parametrize("n", [2, 3, 5])
def test_compiled_wheel_speeds_rows_equal_the_model(n):
    """The metrics' wheel speeds (one compiled call over every step) equal Chain.wheel_speeds row by row."""
    from ftcreport.fast.engine import wheel_speeds_rows

    rng = np.random.default_rng(40 + n)
    chain = Chain.uniform(n, d=rng.uniform(0.6, 1.4, n - 1).tolist())
    Q = np.array([np.concatenate((rng.normal(size=2), rng.uniform(-0.6, 0.6, n))) for _ in range(25)])
    ETA = rng.normal(size=(25, 2))
    got = wheel_speeds_rows(chain, Q, ETA)
    want = np.array([chain.wheel_speeds(q, e) for q, e in zip(Q, ETA, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
