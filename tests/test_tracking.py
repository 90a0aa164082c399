"""References, kinematic controllers and the nominal closed loop (healthy wheels)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcreport.control.kinematic import ChainedBackstepping, TwoLinkKinematic, wrap
from ftcreport.control.tracking import TrackingController
from ftcreport.errors import ReferenceError
from ftcreport.model import Chain
from ftcreport.references import FlatReference, circle, eight, line, sinusoid, unicycle
from ftcreport.sim import Plant, SimSettings, simulate

PATHS = {
    "circle": lambda: circle(5.0, 0.5),
    "eight": lambda: eight(),
    "sinusoid": lambda: sinusoid(0.5, 1.0, 0.2),
}


def _offset_start(ref: FlatReference) -> tuple[np.ndarray, np.ndarray]:
    """Start 0.5 m off the reference position and 30 deg off every heading."""
    r0 = ref.at(0.0)
    q0 = r0.q_d.copy()
    q0[0] += 0.5 * math.cos(0.5)
    q0[1] += 0.5 * math.sin(0.5)
    q0[2:] += math.radians(30.0)
    return q0, r0.eta_d


def _errors(run) -> np.ndarray:
    e = run["q"] - run["q_d"]
    e[:, 2:] = wrap(e[:, 2:])
    return np.abs(e)


# ------------------------------------------------------------------ references
@pytest.mark.parametrize("kind", ["circle", "eight", "sinusoid", "line"])
def test_flat_reference_satisfies_kinematics_n3(kind):
    """q_d' - S(q_d) eta_d < 1e-6 (central differences, step 1e-5) along the reference."""
    chain = Chain.uniform(3, d=1.0)
    path = line(0.5, 0.3) if kind == "line" else PATHS[kind]()
    ref = FlatReference(path, chain.d)
    h = 1e-5
    for t in np.linspace(0.0, 60.0, 41):
        r = ref.at(t)
        qd_dot = (ref.at(t + h).q_d - ref.at(t - h).q_d) / (2 * h)
        assert np.abs(qd_dot - chain.S(r.q_d) @ r.eta_d).max() < 1e-6
        eta_dot = (ref.at(t + h).eta_d - ref.at(t - h).eta_d) / (2 * h)
        assert np.abs(eta_dot - r.eta_d_dot).max() < 1e-6


def test_unicycle_reference_is_the_thesis_one():
    """(3.5)-(3.7) with v_d = 0.5, omega_d = 0.1 from the origin, heading 0."""
    ref = FlatReference(unicycle(0.5, 0.1), [1.7])
    for t in (0.0, 7.0, 31.0):
        r = ref.at(t)
        th = 0.1 * t
        np.testing.assert_allclose(r.q_d[:3], [5 * math.sin(th), 5 * (1 - math.cos(th)), float(wrap(th))], atol=1e-12)
        assert r.v_d == pytest.approx(0.5) and r.omega_d == pytest.approx(0.1)


def test_eight_curvature_is_errata_e11():
    """omega_d = (f1 + f2) / v_d^2 with the corrected sign (ERRATA E11)."""
    ref = FlatReference(eight(theta0_deg=None), [1.7])
    for t in np.linspace(0, 40, 9):
        f1 = 0.2025 * math.sin(0.3 * t) * math.cos(0.15 * t)
        f2 = -0.10125 * math.sin(0.15 * t) * math.cos(0.3 * t)
        r = ref.at(t)
        assert r.omega_d == pytest.approx((f1 + f2) / r.v_d**2, rel=1e-9, abs=1e-12)
    assert math.degrees(ref.at(0).theta_d) == pytest.approx(39.8, abs=0.05)
    assert math.degrees(FlatReference(eight(), [1.7]).at(0).theta_d) == pytest.approx(45.0, abs=1e-9)


def test_infeasible_references_are_refused():
    # on-axle hitching: the steady articulation on a circle of radius R is atan(d / R)
    with pytest.raises(ReferenceError, match="articulation angle"):
        FlatReference(circle(0.15, 0.1), [1.0, 1.0]).check(20.0)
    FlatReference(circle(0.25, 0.1), [1.0]).check(20.0)  # atan(4) = 76 deg: feasible
    with pytest.raises(ReferenceError, match="speed"):
        # x = 5 sin(0.1 t): the path stops and turns back at t = 5 pi
        from ftcreport.references import TrigPath

        FlatReference(TrigPath(x_terms=((5.0, 0.1, 0.0),)), [1.0]).check(40.0)
    with pytest.raises(ReferenceError, match="v_d > 0"):
        unicycle(0.0, 0.1)


# ------------------------------------------------------------------ two-link z-dynamics
def test_two_link_z_dynamics_match_finite_differences():
    """(3.19)-(3.22) with ERRATA E7 and alpha = T_alpha eta + f_alpha, to 1e-6 relative."""
    rng = np.random.default_rng(11)
    ref = FlatReference(eight(), [1.7])
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    chain = Chain.uniform(2, d=1.7)
    h = 1e-6
    for _ in range(25):
        t = rng.uniform(0, 40)
        r = ref.at(t)
        q = r.q_d + np.concatenate((rng.normal(scale=0.3, size=2), rng.normal(scale=0.3, size=2)))
        eta = rng.normal(size=2)
        qd = chain.S(q) @ eta
        z = kin.zcoords(q, r)
        zp = kin.zcoords(q + h * qd, ref.at(t + h))
        zm = kin.zcoords(q - h * qd, ref.at(t - h))
        zdot = (zp - zm) / (2 * h)
        out = kin.law(t, q, np.zeros(0))
        alpha = out.T_alpha @ eta + kin.f_alpha(t, q)
        z1, z2, z3, z4 = z
        vd, wd = r.v_d, r.omega_d
        expected = np.array(
            [
                wd * z2 + alpha[0],
                -wd * z1 + (vd + alpha[0]) * z3,
                vd * (z4 - z2) + alpha[0] * (z4 - z2 + (wd / vd) * (1 + z3**2)),
                alpha[1],
            ]
        )
        np.testing.assert_allclose(zdot, expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


# ------------------------------------------------------------------ etadot_c along the closed loop
@pytest.mark.parametrize("scheme", ["two_link", "chained"])
def test_eta_c_dot_is_the_derivative_along_the_closed_loop(scheme):
    """Logged etadot_c == central difference of logged eta_c along the trajectory (1e-5 relative)."""
    if scheme == "two_link":
        chain = Chain.uniform(2, d=1.7)
        ref = FlatReference(unicycle(0.5, 0.1), chain.d)
        kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    else:
        chain = Chain.uniform(3, d=1.0)
        ref = FlatReference(eight(), chain.d)
        kin = ChainedBackstepping(chain.d, ref, [0.3] * 3, 2.0, 2.0, 5.0)
    ctrl = TrackingController(chain, kin, k_v=5.0)
    r0 = ref.at(0.0)
    q0 = r0.q_d + np.concatenate(([0.2, -0.1], np.full(chain.n, math.radians(10))))
    # the reference difference has error dt^2 / 6 * (third derivative), ~1e-8 relative at dt = 1e-4
    dt = 1e-4
    run = simulate(Plant(chain), ctrl, q0, r0.eta_d, SimSettings(dt=dt, duration=0.25))
    assert run.ok
    ec = run["eta_c"]
    fd = (ec[2:] - ec[:-2]) / (2 * dt)
    logged = run["eta_c_dot"][1:-1]
    scale = np.abs(logged).max()
    assert scale > 1e-2
    assert np.abs(fd - logged).max() < 1e-5 * scale


@pytest.mark.parametrize("n", [2, 3, 4])
def test_law_and_rate_is_the_derivative_along_qdot(n):
    """kin.law_and_rate: eta_c equals kin.law, and etadot_c equals a wider central difference of kin.law
    along (S(q) eta, 1).  Step H = 1e-3 has truncation ~H^2/6 times the third derivative (about 1e-7
    relative here) and the compiled step 1e-5 has round-off ~1e-12/1e-5: agreement to 1e-5 relative."""
    rng = np.random.default_rng(20 + n)
    chain = Chain.uniform(n, d=1.0)
    ref = FlatReference(eight(scale=2.0), chain.d)
    if n == 2:
        kin = TwoLinkKinematic(1.0, ref, k1=10, k2=2, k3=0.5)
    else:
        kin = ChainedBackstepping(chain.d, ref, [0.3] * n, 2.0, 2.0, 5.0, mu=0.7)
    H = 1e-3
    for _ in range(10):
        t = rng.uniform(0.0, 30.0)
        r = ref.at(t)
        q = r.q_d + rng.normal(scale=0.05, size=n + 2)
        eta = r.eta_d + rng.normal(scale=0.05, size=2)
        xc = kin.initial_state(t, q)
        qdot = chain.S(q) @ eta
        out, rate = kin.law_and_rate(t, q, eta, xc, chain.S(q))
        np.testing.assert_allclose(out.eta_c, kin.law(t, q, xc).eta_c, rtol=1e-14, atol=1e-14)
        fd = (kin.law(t + H, q + H * qdot, xc).eta_c - kin.law(t - H, q - H * qdot, xc).eta_c) / (2 * H)
        np.testing.assert_allclose(rate, fd, rtol=0, atol=1e-5 * max(1.0, np.abs(fd).max()))


# ------------------------------------------------------------------ closed loops, healthy wheels
# Documented gains of the chained-form scheme (healthy closed loop): a gain of 0.3 on every
# virtual control (ERRATA E12d), c4 = c5 = 2, kappa = 5 as in thesis 3.3.1.4, velocity gain 5.
CHAINED_GAINS = {"c_chain": 0.3, "c_alpha2": 2.0, "c_xi1": 2.0, "kappa": 5.0, "k_v": 5.0}


CLOSED_LOOP_CASES = [(n, 1.0, kind) for n in (2, 3, 4) for kind in ("circle", "eight", "sinusoid")]
CLOSED_LOOP_CASES.append((3, 0.7, "circle"))  # the length scale mu < 1


@pytest.mark.slow
@pytest.mark.parametrize(("n", "mu", "kind"), CLOSED_LOOP_CASES)
def test_chained_closed_loop_converges(n, mu, kind):
    """From (0.5 m, 30 deg) offsets every coordinate's error falls below 1e-3, through re-anchoring.

    For n = 4 the eight is scaled 2x (same speeds, larger loops): the thesis's eight
    turns by 100 deg in 7 s, too tight to recover a 4-robot chain started 30 deg off.
    """
    chain = Chain.uniform(n, d=1.0)
    path = eight(scale=2.0) if (kind == "eight" and n >= 4) else PATHS[kind]()
    ref = FlatReference(path, chain.d)
    g = CHAINED_GAINS
    kin = ChainedBackstepping(chain.d, ref, [g["c_chain"]] * n, g["c_alpha2"], g["c_xi1"], g["kappa"], mu=mu)
    ctrl = TrackingController(chain, kin, k_v=g["k_v"])
    q0, eta0 = _offset_start(ref)
    run = simulate(Plant(chain), ctrl, q0, eta0, SimSettings(dt=0.02, duration=100.0, log_every=25))
    assert run.ok, run.reason
    err = _errors(run)
    assert err[0].max() > 0.4  # it really started off the reference
    assert err[-1].max() < 1e-3
    # bounded through the transient and every re-anchoring
    assert err.max() < 2.0
    if kind in ("circle", "eight"):
        assert np.unique(run["xc"][:, 0]).size >= 4  # the frame was re-anchored several times


@pytest.mark.slow
def test_two_link_controller_converges_on_unicycle_reference():
    chain = Chain.uniform(2, d=1.7)
    ref = FlatReference(unicycle(0.5, 0.1), chain.d)
    kin = TwoLinkKinematic(1.7, ref, k1=10, k2=2, k3=0.5)
    ctrl = TrackingController(chain, kin, k_v=5.0)
    q0, eta0 = _offset_start(ref)
    run = simulate(Plant(chain), ctrl, q0, eta0, SimSettings(dt=0.01, duration=60.0, log_every=50))
    assert run.ok, run.reason
    err = _errors(run)
    assert err[0].max() > 0.4
    assert err[-1].max() < 1e-3
