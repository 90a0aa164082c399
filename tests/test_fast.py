"""The compiled engine (ftcreport.fast) against the Python reference implementation.

Piece by piece (chained form, reduced model, reference), then golden runs: the
same case and scheme simulated by both engines, compared signal by signal.

Tolerances.  Both engines evaluate the same equations in a different order of
floating-point operations (closed-form 2 x 2 solves, loops instead of BLAS), so
single evaluations agree to round-off (1e-12 relative here).  Along a run the
closed loops are contracting, so differences stay near round-off: plant states
within 1e-9 absolute.  The control signal multiplies state differences by the
velocity gain (k4 = 3000 in the stiff two-link case) and ROS2's forward-difference
Jacobian divides round-off by its increment (1e-7), so u is compared to 1e-8 of
its largest value.  etadot_c is a central difference of step 1e-5: round-off in
eta_c (1e-12) becomes 1e-7 there.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ftcreport.cases import load_case, with_duration
from ftcreport.control import VelocityController, constant_command
from ftcreport.errors import ModelError
from ftcreport.fast import kernels as F
from ftcreport.fast.engine import compiled_spec
from ftcreport.model import Chain
from ftcreport.model.chained import symbolic_chained_form
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


# (case file, scheme, simulated seconds): every compiled law, both integrators, faults, noise, saturation
GOLDEN = [
    ("two_link_switching.toml", "switching", 3.0),  # ROS2, k4 = 3000
    ("two_link_switching.toml", "nominal", 3.0),
    ("three_link_switching.toml", "switching", 24.0),  # chained form, 46 models, a fault at 20 s
    ("three_link_adaptive.toml", "adaptive", 8.0),
    ("three_link_adaptive.toml", "adaptive_frozen", 4.0),
    ("two_link_adaptive_eight.toml", "adaptive", 6.0),  # two-link law, friction estimate
    ("two_link_active.toml", "active", 8.0),  # Farza observer, saturation
    ("two_link_active.toml", "oracle", 40.0),  # faults at 35 s
    ("three_link_active.toml", "active", 20.0),  # noise, filtered estimates
    ("five_link_cascade.toml", "switching", 2.0),  # 766 models
]


def _both(case_file: str, scheme: str, seconds: float):
    case = with_duration(load_case(CASES / case_file), seconds)
    runs = []
    for engine in ("python", "compiled"):
        built = build(case)
        runs.append(
            simulate(built.plant, make_controller(built, scheme), built.q0, built.eta0, built.settings, engine=engine)
        )
    return runs


@pytest.mark.parametrize(("case_file", "scheme", "seconds"), GOLDEN)
def test_golden_run_compiled_equals_python(case_file, scheme, seconds):
    py, fast = _both(case_file, scheme, seconds)
    assert py.ok and fast.ok, (py.reason, fast.reason)
    assert fast.meta.get("engine") == "compiled" and "engine" not in py.meta
    assert (fast.steps, fast.t_end) == (py.steps, py.t_end)
    np.testing.assert_array_equal(fast.t, py.t)
    assert set(fast.signals) == set(py.signals)
    for name in ("sigma", "ubar"):
        np.testing.assert_array_equal(fast[name], py[name])
    for name in ("q", "eta"):
        np.testing.assert_allclose(fast[name], py[name], rtol=0, atol=1e-9, err_msg=name)
    for name, a in py.signals.items():
        b = fast[name]
        assert b.shape == a.shape, name
        if name in ("q", "eta", "sigma", "ubar"):
            continue
        scale = max(1.0, float(np.max(np.abs(a)))) if a.size else 1.0
        tol = 1e-7 if name == "eta_c_dot" else 1e-8
        np.testing.assert_allclose(b, a, rtol=0, atol=tol * scale, err_msg=name)


def test_singular_stop_is_the_same_in_both_engines():
    from ftcreport.control.kinematic import ChainedBackstepping

    chain = Chain.uniform(3, d=1.0)
    # a reference that turns harder than a 3-robot chain started 60 deg off can follow
    ref = FlatReference(circle(2.0, 0.6), chain.d)
    kin = ChainedBackstepping(chain.d, ref, [0.0, 0.0, 0.0], 1.0, 1.0, 5.0)
    q0 = ref.at(0.0).q_d + np.array([0.0, 0.8, 1.0, 1.0, 1.0])
    runs = []
    for engine in ("python", "compiled"):
        from ftcreport.control.tracking import TrackingController

        ctrl = TrackingController(chain, kin, 5.0)
        runs.append(simulate(Plant(chain), ctrl, q0, np.zeros(2), SimSettings(0.01, 30.0), engine=engine))
    py, fast = runs
    assert py.status == fast.status != "ok"
    assert fast.reason == py.reason
    assert fast.t_end == py.t_end and fast.steps == py.steps
    np.testing.assert_allclose(fast["q"], py["q"], atol=1e-9)


def test_controllers_without_a_compiled_counterpart_run_in_python():
    chain = Chain.uniform(2)
    ctrl = VelocityController(chain, constant_command(0.5, 0.1), k=4.0)
    assert compiled_spec(ctrl) is None
    run = simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(0.01, 0.5))
    assert run.ok and "engine" not in run.meta
    with pytest.raises(ModelError, match="no compiled counterpart"):
        simulate(Plant(chain), ctrl, np.zeros(4), np.zeros(2), SimSettings(0.01, 0.5), engine="compiled")
    case = with_duration(load_case(CASES / "two_link_active.toml"), 0.1)
    built = build(case)
    assert compiled_spec(make_controller(built, "active_ukf")) is not None  # the UKF is compiled (issue 20)
    assert math.isfinite(built.settings.dt)


def test_compiled_ukf_loop_equals_the_filterpy_loop():
    """The compiled UKF scheme (fast/ukf.py) against the Python loop on filterpy, the reference.

    Same equations in another floating-point order: one filter step differs by <= 3e-12 in x
    (tests/test_ukf_compiled.py); over 5 s of closed loop the measured gaps are 7e-12 m in q and
    1e-8 relative in u, so 1e-9 on q, eta and 1e-7 relative on u and the estimates.
    """
    case = with_duration(load_case(CASES / "two_link_active.toml"), 5.0)
    runs = []
    for engine in ("python", "compiled"):
        built = build(case)
        runs.append(simulate(built.plant, make_controller(built, "active_ukf"), built.q0, built.eta0,
                             built.settings, engine=engine))  # fmt: skip
    py, fast = runs
    assert py.ok and fast.ok and fast.meta["engine"] == "compiled"
    for name in ("q", "eta"):
        np.testing.assert_allclose(fast[name], py[name], rtol=0, atol=1e-9)
    for name in ("u", "rho_hat", "ubar_hat", "eta_hat", "P_max"):
        np.testing.assert_allclose(fast[name], py[name], rtol=0, atol=1e-7 * max(1.0, np.abs(py[name]).max()))


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


def test_both_engines_break_switching_ties_alike():
    """Costs within TIE_RTOL of the smallest are a tie and the lowest index wins, in both engines, whichever
    of the tied models round-off made smaller: argmin alone split the engines at full length (golden.py)."""
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
        py = ctrl.discrete(1.0, q, eta, xc)
        fast = xc.copy()
        F.switching_discrete(spec.P, spec.kin, spec.ref, F.new_cache(3), 1.0, q, eta, fast, np.zeros(4))
        return ctrl.costs(eta, xc), (round(py[ctrl._sel]), round(fast[ctrl._sel]))

    # 3 smaller by 1e-11 relative: argmin would pick it
    J, sel = selected(-np.array([3e-5, 4e-5]), -np.array([3e-5, 4e-5 * (1.0 - 1e-11)]))
    assert J[3] < J[1] < J[3] * (1.0 + TIE_RTOL) and J.min() == J[3]
    assert sel == (1, 1)
    # a real difference (J[1] 3 % above J[3]): the smaller cost wins
    assert selected(-np.array([3e-5, 4.1e-5]), -np.array([3e-5, 4e-5]))[1] == (3, 3)


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
