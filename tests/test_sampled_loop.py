"""The loop in discrete time (issue 37 item 2): the plant's ZOH and the sampled loop's matrix."""

from __future__ import annotations

from pathlib import Path

import control
import numpy as np
import pytest
import scipy.linalg

from ftcreport.analysis.closed_loop import Faults, SchemeLoop
from ftcreport.analysis.sampled import closed_loop_matrix, parts, plant_zoh, zoh
from ftcreport.cases import load_case
from ftcreport.runner import build

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def motor_case():
    case = load_case(ROOT / "cases" / "motors" / "two_link_switching_motors.toml")
    return case, build(case)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def test_zoh_equals_python_controls_sample_system(motor_case):
    """zoh (the engine's phi_1) against control.sample_system's ZOH, on the motor plant at the reference."""
    case, built = motor_case
    loop = SchemeLoop(case, "nominal", built)
    blk = loop.blocks(loop.point(3.0, Faults.healthy(4, True)))
    for T in (1e-4, 1.371e-3, 5e-3, 0.2):
        Phi, Gam = zoh(blk.Fx, blk.Fa, T)
        n = blk.Fx.shape[0]
        d = control.sample_system(control.ss(blk.Fx, blk.Fa, np.eye(n), np.zeros((n, 4))), T, method="zoh")
        assert _rel(Phi, d.A) < 1e-12 and _rel(Gam, d.B) < 1e-12


def test_motor_plant_discretization_equals_an_independent_derivation(motor_case):
    """At rest (eta = 0, i_a = 0) the chain with motors is linear in [q, eta, i_a], and its matrices follow
    from (2.28)-(2.29), E19 and (2.70) by hand: qdot = S eta, (Mbar1 + Bbar Jw Bbar^T) etadot =
    Bbar (eta_g N k_m i - eta_g N^2 b_m Bbar^T eta), L_a i' = v - R_a i - k_b N Bbar^T eta.  Their exact
    discretization (scipy's expm of [[A, B], [0, 0]] T) equals the analysis's plant ZOH to 1e-10."""
    case, built = motor_case
    loop = SchemeLoop(case, "nominal", built)
    plant = loop.plant
    fz = Faults.healthy(4, True)
    q0 = built.reference.at(2.0).q_d
    xp = np.concatenate((q0, np.zeros(2), np.zeros(4)))
    Fx = plant.state_columns(xp, np.zeros(4), fz)
    Fa = plant.input_columns(xp, np.zeros(4), fz)
    # the derivation, from the chain's matrices and the motor parameters only
    chain = built.plant.chain
    Mbar1, _, _, Bbar = chain.reduced(q0, np.zeros(2))
    mp = case.motor_params()[0]
    gN = mp.eta_g * mp.N
    Jw = mp.eta_g * mp.N**2 * mp.J_m
    Mr = Mbar1 + Jw * Bbar @ Bbar.T
    A = np.zeros((10, 10))
    A[:4, 4:6] = chain.S(q0)
    A[4:6, 4:6] = -np.linalg.solve(Mr, Bbar) @ (gN * mp.N * mp.b_m * Bbar.T)
    A[4:6, 6:] = np.linalg.solve(Mr, Bbar) * gN * mp.k_m
    A[6:, 4:6] = -(mp.k_b * mp.N / mp.L_a) * Bbar.T
    A[6:, 6:] = -(mp.R_a / mp.L_a) * np.eye(4)
    B = np.zeros((10, 4))
    B[6:] = np.eye(4) / mp.L_a
    assert _rel(Fx, A) < 1e-8  # central differences in q and eta (exact to round-off here), currents exact
    for T in (1.371e-3, 5e-3):
        aug = scipy.linalg.expm(np.block([[A, B], [np.zeros((4, 14))]]) * T)
        Phi, Gam = zoh(A, B, T)
        assert _rel(Phi, aug[:10, :10]) < 1e-10 and _rel(Gam, aug[:10, 10:]) < 1e-10
        Phi, Gam = zoh(Fx, Fa, T)  # and the analysis's own blocks
        assert _rel(Phi, aug[:10, :10]) < 1e-8 and _rel(Gam, aug[:10, 10:]) < 1e-10


@pytest.mark.parametrize(("case_file", "scheme"), [("motors/two_link_active_motors.toml", "active"),
                                                   ("motors/two_link_active_motors.toml", "active_ukf")])  # fmt: skip
def test_sampled_loop_matrix_is_the_controllers_recursion(case_file, scheme):
    """M^k z0 equals the sampled controller run by hand from the module's equations (delay 2 samples,
    the scheme's states by forward Euler, the UKF's update as its map), for random z0."""
    case = load_case(ROOT / "cases" / case_file)
    built = build(case)
    loop = SchemeLoop(case, scheme, built)
    T, d = 5e-3, 2
    pt = loop.point(1.0, Faults.healthy(4, True), period=T)
    blk = loop.blocks(pt, T)
    blk.omega = 0.0  # the world frame: the recursion below does not turn
    M = closed_loop_matrix(blk, T, d)
    Phi, Gam = zoh(blk.Fx, blk.Fa, T)
    mp, ny, na, nc = blk.Fx.shape[0], blk.Gy.shape[1], blk.na, blk.nc
    rng = np.random.default_rng(3)
    z = rng.standard_normal(M.shape[0])
    xp, buf, c = z[:mp].copy(), [z[mp + k * ny : mp + (k + 1) * ny].copy() for k in range(d)], z[mp + d * ny :].copy()
    for _ in range(4):
        z = M @ z
        yhat = buf[-1]
        c_now = blk.Dc @ c + blk.Dy @ yhat
        a = blk.Gx[:na] @ xp + blk.Gy[:na] @ yhat + blk.Gc[:na] @ c_now
        rates = blk.Gx[na:] @ xp + blk.Gy[na:] @ yhat + blk.Gc[na:] @ c_now
        buf = [xp[:ny].copy(), *buf[:-1]]
        xp, c = Phi @ xp + Gam @ a, c_now + T * rates
        ref = np.concatenate((xp, *buf, c))
        assert _rel(z, ref) < 1e-12
    assert nc > 0
    M0, Bz, Ka = parts(blk, T, d)
    np.testing.assert_allclose(M0 + Bz @ Ka, M, rtol=0, atol=1e-12 * np.abs(M).max())


def test_small_sample_time_recovers_the_continuous_poles():
    """As T -> 0 the sampled loop's equivalent poles ln(z) / T tend to the continuous loop's (co-moving frame
    included), as the sampled engine converges (tests/test_sampling.py): on the two-link thesis case the
    velocity-loop pole (-10.4) at first order in T (the hold's lag: its error falls tenfold from T = 1e-4 to
    1e-5 s), the kinematic ones within 1e-8 at both (the plant's ZOH taken in the turning frame is exact on
    the circle; the world-frame ZOH turned afterwards left them a first-order error, 3.4e-6 at 1e-4 s)."""
    case = load_case(ROOT / "cases" / "two_link_switching.toml")
    built = build(case)
    loop = SchemeLoop(case, "nominal", built)
    blk = loop.blocks(loop.point(0.0, Faults.healthy(4, False)))
    lam = sorted(np.linalg.eigvals(blk.continuous()), key=lambda v: v.real)[2:]  # all but the two at -3000
    err = {}
    for T in (1e-4, 1e-5):
        s = np.log(np.linalg.eigvals(closed_loop_matrix(blk, T, 0)).astype(complex)) / T
        err[T] = np.array([np.min(np.abs(s - v)) / abs(v) for v in lam])
    assert np.all(err[1e-5] < 1e-6)
    np.testing.assert_allclose(err[1e-4][0] / err[1e-5][0], 10.0, rtol=0.1)  # -10.4: the velocity loop's
    assert np.all(err[1e-4][1:] < 1e-8) and np.all(err[1e-5][1:] < 1e-8)


def test_plant_zoh_on_a_turning_reference_is_the_transition_along_the_sample():
    """On the circle (two_link_active_motors, omega = 0.5 rad/s) the plant's Jacobian in world coordinates
    turns with the reference within a sample.  Its transition over T = 262 ms with the signal held, built
    independently as the product of the augmented matrix's expm over 64 sub-intervals, each linearized at
    its own midpoint on the reference (scipy), then written in the frame the reference has at the sample's
    end, equals plant_zoh (the ZOH of Fx - omega J) to 1e-7 of the largest entry (1.5e-8 measured, 2.5e-7
    with 16 sub-intervals, 1e-9 with 256: the midpoint rule's h^2); the world-frame Jacobian frozen at the
    sample's start and turned afterwards (the model before) is 3.1e-4 off whatever the sub-intervals, which
    moved the slow kinematic pair's |z| at 262 ms from 1.00135 to 0.99878 (the limit from 236 to 292 ms)."""
    case = load_case(ROOT / "cases" / "motors" / "two_link_active_motors.toml")
    built = build(case)
    loop = SchemeLoop(case, "nominal", built)
    fz = Faults.healthy(4, True)
    t0, T, n = 17.5, 0.2624, 64
    pt = loop.point(t0, fz, period=5e-3)
    blk = loop.blocks(pt, 5e-3)
    mp, na = blk.Fx.shape[0], blk.na
    aug = np.eye(mp + na)
    for k in range(n):
        p = loop.point(t0 + (k + 0.5) * T / n, fz, period=5e-3)
        A = loop.plant.state_columns(p.xp, pt.a, fz)  # the signal held at its value of the sample's start
        B = loop.plant.input_columns(p.xp, pt.a, fz)
        step = scipy.linalg.expm(np.block([[A, B], [np.zeros((na, mp + na))]]) * (T / n))
        aug = step @ aug
    c, s = np.cos(blk.omega * T), np.sin(blk.omega * T)
    R = np.eye(mp)
    R[:2, :2] = [[c, s], [-s, c]]  # world -> the frame turned by omega T
    Phi, Gam = R @ aug[:mp, :mp], R @ aug[:mp, mp:]
    Phi_z, Gam_z = plant_zoh(blk, T)
    assert _rel(Phi_z, Phi) < 1e-7 and _rel(Gam_z, Gam) < 1e-7
    Phi_w, _ = zoh(blk.Fx, blk.Fa, T)
    assert _rel(R @ Phi_w, Phi) > 1e-4
