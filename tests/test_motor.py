"""DC motors on the wheels (thesis 2.3.3, ERRATA E19, issue 19): the open-loop plant of model/motor_compiled.py.

The loop is not wired yet, so every run here is a fixed-step RK4 over ``motor_plant_rhs`` written in
the test, with the driver evaluated continuously (no sampling) where a torque command is given.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import random_chain, random_q

from ftcreport.errors import FaultError
from ftcreport.fast import kernels as K
from ftcreport.fast.engine import _chain
from ftcreport.model import FaultEvent, FaultSchedule
from ftcreport.model import motor_compiled as M
from ftcreport.model.actuators import MAXON_RE65, MotorParams, pack


def _setup(n: int, seed: int, **motor):
    rng = np.random.default_rng(seed)
    chain = random_chain(rng, n)
    base = dataclasses.replace(MAXON_RE65, **motor)
    # robots get different gears, so a mixed-up wheel index would show
    mo = pack([dataclasses.replace(base, N=base.N * (1.0 + 0.1 * i)) for i in range(n)], n)
    return rng, _chain(chain.params), mo


def _start(rng, n):
    th1 = 0.3
    th = th1 - np.cumsum(np.concatenate(([0.0], rng.uniform(-0.4, 0.4, n - 1))))
    return np.concatenate(([0.0, 0.0], th[::-1])), np.array([0.6, 0.3])


def _omega_w(pc, q, eta):
    Bbar = K.reduced(pc, q, eta)[3]
    return Bbar.T @ eta


def _rk4(f, x, dt, steps):
    xs = [x]
    for k in range(steps):
        t = k * dt
        k1 = f(t, x)
        k2 = f(t + dt / 2, x + dt / 2 * k1)
        k3 = f(t + dt / 2, x + dt / 2 * k2)
        k4 = f(t + dt, x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs.append(x)
    return np.array(xs)


# ------------------------------------------------------------------ structure
@pytest.mark.parametrize("n", [2, 3, 5])
def test_bbar_rate_matches_finite_difference(n, rng):
    pc = _chain(random_chain(rng, n).params)
    for _ in range(5):
        q = random_q(rng, n)
        eta = rng.normal(size=2)
        Bbar, Bbd = M.bbar_and_rate(pc, q, eta)
        qdot = K.s_matrix(pc, q) @ eta
        h = 1e-6
        fd = (K.reduced(pc, q + h * qdot, eta)[3] - K.reduced(pc, q - h * qdot, eta)[3]) / (2 * h)
        # central difference: truncation O(h^2 |B'''|) ~ 1e-12, round-off ~ 1e-16 / h = 1e-10
        np.testing.assert_allclose(Bbd, fd, atol=1e-8 * max(1.0, np.abs(Bbd).max()))
        assert np.abs(Bbd).max() > 1e-3  # the rate is not trivially zero
        np.testing.assert_array_equal(Bbar, K.reduced(pc, q, eta)[3])


@pytest.mark.parametrize("n", [2, 4])
def test_rotor_mass_symmetric_positive_definite_and_rhs_solves_the_explicit_equations(n):
    rng, pc, mo = _setup(n, 11 + n)
    Jw = M.rotor_inertia_wheel(mo)
    np.testing.assert_allclose(Jw, mo.eta_g * mo.N**2 * mo.J_m, rtol=1e-15)
    fault = M.healthy_faults(2 * n)
    for _ in range(5):
        q = random_q(rng, n)
        eta = rng.normal(size=2)
        i_a = rng.normal(size=2 * n) * 5.0
        v_a = rng.normal(size=2 * n) * 10.0
        Mbar1, Mbar2, Cbar, Bbar, S, _ = K.reduced(pc, q, eta)
        A = M.rotor_mass(Mbar1, Bbar, Jw)
        np.testing.assert_allclose(A, A.T, rtol=0, atol=1e-14 * np.abs(A).max())
        lam = np.linalg.eigvalsh(A)
        assert lam.min() > 0 and lam.min() >= np.linalg.eigvalsh(Mbar1).min() * (1 - 1e-12)
        # the rotors add inertia: A - Mbar1 = Bbar Jw Bbar^T is PSD and not zero
        assert np.trace(A - Mbar1) > 1e-3 * np.trace(Mbar1)
        qdot, etadot, i_dot, tau_w = M.motor_plant_rhs(pc, mo, q, eta, i_a, v_a, fault)
        np.testing.assert_allclose(qdot, S @ eta, rtol=1e-14)
        # (2.70) with the wheel torques it returns
        res = Mbar1 @ etadot - (Bbar @ tau_w - Mbar2 @ eta - Cbar)
        scale = np.abs(Bbar @ tau_w).max() + np.abs(Mbar2 @ eta).max() + np.abs(Cbar).max()
        assert np.abs(res).max() < 1e-12 * scale
        # tau_w = eta_g N (k_m i - b_m N omega_w - J_m N domega_w/dt), domega_w/dt = Bbar^T etadot + Bbardot^T eta
        _, Bbd = M.bbar_and_rate(pc, q, eta)
        w = Bbar.T @ eta
        wdot = Bbar.T @ etadot + Bbd.T @ eta
        expect = mo.eta_g * mo.N * (mo.k_m * i_a - mo.b_m * mo.N * w - mo.J_m * mo.N * wdot)
        np.testing.assert_allclose(tau_w, expect, rtol=1e-12, atol=1e-12 * np.abs(expect).max())
        # (2.28)
        np.testing.assert_allclose(i_dot, (v_a - mo.R_a * i_a - mo.k_b * mo.N * w) / mo.L_a, rtol=1e-12)


# ------------------------------------------------------------------ power balance
def _power_run(n, dt, T, seed=5):
    """RK4 over [q, eta, i_a, W] with W the integrals of the power terms (same integrator, so order 4)."""
    rng, pc, mo = _setup(n, seed)
    nq, nw = n + 2, 2 * n
    fault = M.healthy_faults(nw)
    amp = rng.uniform(5.0, 15.0, nw)
    freq = rng.uniform(5.0, 30.0, nw)
    phase = rng.uniform(0, 2 * np.pi, nw)
    g, N = mo.eta_g, mo.N

    def volts(t):
        return amp * np.sin(freq * t + phase)

    def terms(t, x):
        q, eta, i = x[:nq], x[nq : nq + 2], x[nq + 2 : nq + 2 + nw]
        v = volts(t)
        qd, ed, idot, tau_w = M.motor_plant_rhs(pc, mo, q, eta, i, v, fault)
        w = _omega_w(pc, q, eta)
        wm = N * w
        tau_l = tau_w / (g * N)
        p = np.array(
            [
                np.sum(v * i),  # 0 electrical power in
                np.sum(mo.R_a * i**2),  # 1 copper losses
                np.sum(mo.k_b * wm * i),  # 2 back-EMF power (electrical -> mechanical)
                np.sum(mo.k_m * i * wm),  # 3 electromagnetic torque power
                np.sum(mo.b_m * wm**2),  # 4 rotor friction
                np.sum(tau_l * wm),  # 5 power into the gear
                np.sum(tau_w * w),  # 6 power into the chain
                np.sum((1 - g) * tau_l * wm),  # 7 gear losses
            ]
        )
        return np.concatenate((qd, ed, idot, p))

    q0, eta0 = _start(rng, n)
    # start from the quasi-static current of the first voltage
    i0 = M.quasi_static_current(mo, volts(0.0), _omega_w(pc, q0, eta0), fault)
    x0 = np.concatenate((q0, eta0, i0, np.zeros(8)))
    xs = _rk4(terms, x0, dt, round(T / dt))

    def energies(x):
        q, eta, i = x[:nq], x[nq : nq + 2], x[nq + 2 : nq + 2 + nw]
        wm = N * _omega_w(pc, q, eta)
        Mbar1 = K.reduced(pc, q, eta)[0]
        return np.array([np.sum(mo.L_a * i**2 / 2), np.sum(mo.J_m * wm**2 / 2), eta @ Mbar1 @ eta / 2])

    E = np.array([energies(xs[0]), energies(xs[-1])])
    return xs, E, nq + 2 + nw


@pytest.mark.parametrize("n", [2, 3])
def test_power_balance_along_a_run(n):
    """Electrical in = copper + d/dt magnetic + back-EMF; motor shaft; gear; chain (2.28)-(2.29), E19."""
    res = {}
    for dt in (1e-4, 5e-5):
        xs, E, k = _power_run(n, dt, 0.3)
        W = xs[-1, k:]
        dE = E[1] - E[0]
        scale = W[0]  # the electrical energy put in
        assert scale > 1.0  # joules: the run does real work
        assert abs(dE[2]) > 1e-2 * scale and abs(dE[1]) > 1e-4 * scale  # the chain and rotors gain energy
        res[dt] = (
            np.array(
                [
                    dE[0] - (W[0] - W[1] - W[2]),  # electrical: magnetic energy
                    dE[1] - (W[3] - W[4] - W[5]),  # motor shaft: rotor kinetic energy
                    dE[2] - W[6],  # chain: kinetic energy (constraint forces do no work)
                    W[5] - W[6] - W[7],  # gear: in = out + losses
                    W[2] - W[3],  # conversion: lossless with k_m = k_b in SI units
                    (dE.sum()) - (W[0] - W[1] - W[4] - W[7]),  # the whole plant
                ]
            )
            / scale
        )
    coarse, fine = np.abs(res[1e-4]), np.abs(res[5e-5])
    # RK4 on the augmented state (energy integrals included) is 4th order: the residual is the global
    # error, ~1e-8 at dt = 1e-4 (= L_a/R_a / 4.4); halving dt divides it by ~16.  Identities (gear,
    # conversion) hold to round-off at every step.
    assert coarse[[3, 4]].max() < 1e-12
    assert coarse.max() < 1e-8, coarse  # measured: 1.4e-10 (n = 2), 8.9e-11 (n = 3)
    big = coarse > 1e-11  # residuals above round-off must converge at order 4
    assert np.all(fine[big] < coarse[big] / 8), (coarse, fine)


# ------------------------------------------------------------------ the ideal-plant limit
def _driven(pc, mo, fault, tau_c, q0, eta0, dt, T, i0=None):
    """RK4 with the driver evaluated continuously: v = driver_voltage(tau_c(t), omega_w)."""
    nq = pc.n + 2

    def f(t, x):
        q, eta, i = x[:nq], x[nq : nq + 2], x[nq + 2 :]
        w = _omega_w(pc, q, eta)
        v = M.driver_voltage(mo, tau_c(t), w, fault)
        qd, ed, idot, _tau = M.motor_plant_rhs(pc, mo, q, eta, i, v, fault)
        return np.concatenate((qd, ed, idot))

    if i0 is None:
        w0 = _omega_w(pc, q0, eta0)
        i0 = M.quasi_static_current(mo, M.driver_voltage(mo, tau_c(0.0), w0, fault), w0, fault)
    xs = _rk4(f, np.concatenate((q0, eta0, i0)), dt, round(T / dt))
    out = []
    for k, x in enumerate(xs):
        q, eta, i = x[:nq], x[nq : nq + 2], x[nq + 2 :]
        w = _omega_w(pc, q, eta)
        v = M.driver_voltage(mo, tau_c(k * dt), w, fault)
        _qd, ed, _idot, tau_w = M.motor_plant_rhs(pc, mo, q, eta, i, v, fault)
        _, Bbd = M.bbar_and_rate(pc, q, eta)
        Bbar = K.reduced(pc, q, eta)[3]
        wdot = Bbar.T @ ed + Bbd.T @ eta
        out.append((k * dt, q, eta, i, w, tau_w, wdot))
    return xs, out


def _ideal(pc, tau_c, q0, eta0, dt, T):
    nq = pc.n + 2

    def f(t, x):
        qd, ed = K.plant_rhs(pc, x[:nq], x[nq:], tau_c(t))
        return np.concatenate((qd, ed))

    return _rk4(f, np.concatenate((q0, eta0)), dt, round(T / dt))


def test_small_inductance_tends_to_the_ideal_torque_plant():
    """L_a -> 0, V_max -> inf, J_m = 0: the wheel torque tends to the command, the error ~ L_a."""
    n = 2
    rng = np.random.default_rng(3)
    nw = 2 * n
    amp = rng.uniform(1.0, 4.0, nw)
    freq = rng.uniform(2.0, 6.0, nw)
    phase = rng.uniform(0, 2 * np.pi, nw)

    def tau_c(t):
        return amp * np.sin(freq * t + phase)

    dt, T = 2.5e-5, 0.4
    q0, eta0 = _start(rng, n)
    pc = _chain(random_chain(rng, n).params)
    ideal = _ideal(pc, tau_c, q0, eta0, dt, T)
    torque_err, state_err = [], []
    for tau_e in (2e-3, 1e-3, 5e-4):
        mp = dataclasses.replace(MAXON_RE65, J_m=0.0, V_max=np.inf, L_a=tau_e * MAXON_RE65.R_a)
        mo = pack(mp, n)
        xs, out = _driven(pc, mo, M.healthy_faults(nw), tau_c, q0, eta0, dt, T)
        torque_err.append(max(np.abs(o[5] - tau_c(o[0])).max() for o in out))
        state_err.append(np.abs(xs[:, : n + 4] - ideal).max())
    torque_err, state_err = np.array(torque_err), np.array(state_err)
    # first-order lag of the current behind the static inversion: L_a di/dt = R_a (i* - i), so
    # tau_w - tau_c ~ -(L_a/R_a) dtau_c/dt (measured: 0.02668, 0.01334, 0.00667 N m against
    # tau_e max|dtau_c/dt| = 0.02666, 0.01333, 0.00667); the neglected terms are O(tau_e^2)
    t = np.arange(0.0, T + dt / 2, dt)
    rate = np.abs(amp * freq * np.cos(np.outer(t, freq) + phase)).max()
    np.testing.assert_allclose(torque_err, np.array([2e-3, 1e-3, 5e-4]) * rate, rtol=0.02)
    # the trajectories converge to the ideal plant's at the same rate (measured ratios 2.00, 2.00)
    np.testing.assert_allclose(state_err[:-1] / state_err[1:], 2.0, rtol=0.05)
    assert state_err[-1] < 1e-3  # m, rad, m/s, rad/s after 0.4 s (measured 4.6e-4)


# ------------------------------------------------------------------ fault signatures
def _fault_table(nw, j, row):
    f = M.healthy_faults(nw)
    f[j] = row
    return f


def _equivalence_error(pc, mo, fault, tau_c, q0, eta0, T, settle):
    """max over the run after ``settle`` of |tau_w + Jw domega/dt - (sigma tau_c + ubar)| per wheel."""
    _xs, out = _driven(pc, mo, fault, tau_c, q0, eta0, 2e-5, T)
    Jw = M.rotor_inertia_wheel(mo)
    err = np.zeros(2 * pc.n)
    scale = np.zeros(2 * pc.n)
    for t, _q, _eta, _i, w, tau_w, wdot in out:
        if t < settle:
            continue
        sig, ub = M.fault_equivalent(mo, fault, w)
        err = np.maximum(err, np.abs(tau_w + Jw * wdot - (sig * tau_c(t) + ub)))
        scale = np.maximum(scale, np.abs(tau_w))
    return err, scale, out


def _fault_setup():
    n = 2
    rng = np.random.default_rng(9)
    pc = _chain(random_chain(rng, n).params)
    # L_a a tenth of the datasheet's: the quasi-static error ~ (L_a/R_a) / (mechanical time) stays < 1 %
    mo = pack(dataclasses.replace(MAXON_RE65, L_a=MAXON_RE65.L_a / 10), n)
    q0, eta0 = _start(rng, n)
    eta0 = np.array([1.5, 0.4])  # moving: the speed-dependent terms matter

    def tau_c(t):
        return np.array([3.0, 2.0, -1.0, 2.5]) * (1.0 + 0.3 * np.sin(4.0 * t))

    return pc, mo, q0, eta0, tau_c


def test_open_circuit_gives_zero_current_and_zero_motor_torque():
    pc, mo, q0, eta0, tau_c = _fault_setup()
    fault = _fault_table(4, 1, [1.0, 1.0, M.MODE_OPEN, 0.0])
    i0 = M.reset_current(fault, np.full(4, 7.0))
    assert i0[1] == 0.0 and i0[0] == 7.0
    err, scale, out = _equivalence_error(pc, mo, fault, tau_c, q0, eta0, 0.05, 0.0)
    i = np.array([o[3] for o in out])
    assert np.all(i[:, 1] == 0.0)  # held exactly, not by a large resistance
    # no electromagnetic torque: the wheel sees only the rotor's friction and inertia
    for _t, _q, _eta, _i, w, tau_w, wdot in out:
        np.testing.assert_allclose(
            tau_w[1], -mo.eta_g[1] * mo.N[1] ** 2 * (mo.b_m[1] * w[1] + mo.J_m[1] * wdot[1]), rtol=1e-12
        )
    # the open wheel's equivalent holds exactly (no electrical dynamics left)
    assert err[1] < 1e-12 * scale.max()


def test_short_circuit_brakes_with_km_kb_omega_over_R():
    pc, mo, q0, eta0, tau_c = _fault_setup()
    fault = _fault_table(4, 2, [1.0, 1.0, M.MODE_SHORT, 0.0])
    err, scale, out = _equivalence_error(pc, mo, fault, tau_c, q0, eta0, 0.05, 0.01)
    j = 2
    for t, _q, _eta, i, w, _tau_w, _wdot in out:
        if t < 0.01:  # 600 electrical time constants: the start transient is gone
            continue
        shaft = mo.k_m[j] * i[j]
        brake = -mo.k_m[j] * mo.k_b[j] * mo.N[j] * w[j] / mo.R_a[j]
        # quasi-steady lag: (L_a/R_a) d(brake)/dt / brake ~ 4.4e-5 s / (mechanical time ~0.03 s)
        # ~ 1.5e-3 at most; measured 1e-5 (the speed varies slowly once braked)
        assert abs(shaft - brake) < 1e-3 * abs(brake)
        assert abs(brake) > 1.0  # N m at the shaft: a real braking torque
    sig, ub = M.fault_equivalent(mo, fault, out[-1][4])
    assert sig[j] == 0.0 and ub[j] < 0 < out[-1][4][j]
    assert err[j] < 1e-3 * scale[j]  # measured 1e-5


@pytest.mark.parametrize(
    ("kind", "row"),
    [
        ("km_loss", [0.6, 1.0, M.MODE_NORMAL, 0.0]),
        ("resistance", [1.0, 2.5, M.MODE_NORMAL, 0.0]),
        ("both", [0.7, 1.5, M.MODE_NORMAL, 0.0]),
        ("stuck", [1.0, 1.0, M.MODE_STUCK, 6.0]),
        ("stuck_saturated", [1.0, 1.0, M.MODE_STUCK, 480.0]),
    ],
)
def test_faults_match_their_sigma_ubar_equivalent_in_quasi_steady_state(kind, row):
    pc, mo, q0, eta0, tau_c = _fault_setup()
    j = 0
    fault = _fault_table(4, j, row)
    err, scale, out = _equivalence_error(pc, mo, fault, tau_c, q0, eta0, 0.05, 0.005)
    # healthy wheels: sigma = 1, ubar = 0 (the b_m compensation) up to the current lag; the lag
    # error ~ (L_a/R_a) dtau/dt: 4.4e-5 s times <= ~5 N m/s on the healthy wheels (2e-4 N m) and
    # up to ~1e3 N m/s on a stuck wheel braking hard (0.04 N m of 58); measured relative errors
    # 4e-5 .. 6.4e-4 of the largest wheel torque
    assert np.all(err < 3e-3 * scale.max()), (err, scale)
    sig, ub = M.fault_equivalent(mo, fault, out[-1][4])
    s, rho = row[0], row[1]
    if kind in ("km_loss", "resistance", "both"):
        assert sig[j] == pytest.approx(s / rho, rel=1e-15)
        if kind == "km_loss":  # the driver's back-EMF compensation over-estimates e: a speed term
            assert ub[j] > 0
    else:
        assert sig[j] == 0.0
    np.testing.assert_array_equal(sig[1:], 1.0)
    np.testing.assert_allclose(ub[1:], 0.0, atol=1e-15)


def test_km_loss_sigma_seen_from_two_commands():
    """A k_m loss to 0.6 scales the torque's response to the command by sigma = 0.6 (measured)."""
    pc, mo, q0, eta0, tau_c = _fault_setup()
    fault = _fault_table(4, 0, [0.6, 1.0, M.MODE_NORMAL, 0.0])
    w = _omega_w(pc, q0, eta0)
    # quasi-static torque at a fixed state for two commands: d tau_w / d tau_c = sigma
    taus = []
    for scale in (1.0, 2.0):
        tc = tau_c(0.0) * scale
        v = M.driver_voltage(mo, tc, w, fault)
        i = M.quasi_static_current(mo, v, w, fault)
        _qd, ed, _idot, tau_w = M.motor_plant_rhs(pc, mo, q0, eta0, i, v, fault)
        _, Bbd = M.bbar_and_rate(pc, q0, eta0)
        Bbar = K.reduced(pc, q0, eta0)[3]
        taus.append(tau_w + M.rotor_inertia_wheel(mo) * (Bbar.T @ ed + Bbd.T @ eta0))
    gain = (taus[1] - taus[0]) / tau_c(0.0)
    np.testing.assert_allclose(gain, [0.6, 1.0, 1.0, 1.0], rtol=1e-12)


def test_driver_saturates_and_limits_current():
    mo = pack(dataclasses.replace(MAXON_RE65, I_max=10.0), 2)
    f = M.healthy_faults(4)
    w = np.array([0.0, 0.0, 5.0, -5.0])
    v = M.driver_voltage(mo, np.array([1e4, -1e4, 1.0, 0.0]), w, f)
    # i* clipped at 10 A: v = R 10 A (+ back-EMF); the supply clips at 48 V
    np.testing.assert_allclose(v[:2], [3.65, -3.65], rtol=1e-12)
    e = mo.k_b[2:] * mo.N[2:] * w[2:]
    i_star = (np.array([1.0, 0.0]) / (mo.eta_g[2:] * mo.N[2:]) + mo.b_m[2:] * mo.N[2:] * w[2:]) / mo.k_m[2:]
    np.testing.assert_allclose(v[2:], mo.R_a[2:] * i_star + e, rtol=1e-12)
    big = M.driver_voltage(mo, np.zeros(4), np.full(4, 100.0), f)
    np.testing.assert_array_equal(big, 48.0)


# ------------------------------------------------------------------ parameters and schedule
def test_datasheet_defaults_and_time_constants():
    m = MAXON_RE65
    assert m.tau_electrical == pytest.approx(0.161e-3 / 0.365)
    # the datasheet's mechanical time constant is 3.25 ms; ours from R, J, k: 3.23 ms
    assert m.tau_mechanical == pytest.approx(3.25e-3, rel=0.01)
    # speed constant 77.8 rpm/V: k_b within 0.3 % of k_m
    assert 60 / (2 * np.pi * 77.8) == pytest.approx(m.k_b, rel=3e-3)
    with pytest.raises(ValueError, match=r"actuators\.eta_g"):
        MotorParams(eta_g=1.5)
    with pytest.raises(ValueError, match=r"actuators\.L_a"):
        MotorParams(L_a=0.0)
    mo = pack([MAXON_RE65, dataclasses.replace(MAXON_RE65, N=30.0)], 2)
    np.testing.assert_array_equal(mo.N, [20.0, 20.0, 30.0, 30.0])


def test_schedule_motor_table_and_intermittent_motor_faults():
    sched = FaultSchedule(
        2,
        [
            FaultEvent(1.0, "2l", motor="short"),
            FaultEvent(2.0, "2l", motor="none"),
            FaultEvent(1.5, "1r", motor="stuck", value=-12.0),
            FaultEvent(1.5, "2r", sigma=0.5, ubar=0.1),
            FaultEvent(3.0, "1l", motor="km_loss", value=0.4),
        ],
    )
    assert sched.has_motor
    np.testing.assert_array_equal(sched.motor(0.5), M.healthy_faults(4))
    np.testing.assert_array_equal(sched.motor(1.0)[3], [1, 1, M.MODE_SHORT, 0])
    np.testing.assert_array_equal(sched.motor(1.7)[0], [1, 1, M.MODE_STUCK, -12.0])
    np.testing.assert_array_equal(sched.motor(2.0)[3], [1, 1, 0, 0])  # repaired
    np.testing.assert_array_equal(sched.motor(3.0)[1], [0.4, 1, 0, 0])
    # motor events leave sigma/ubar alone
    np.testing.assert_array_equal(sched.sigma(3.5), [1.0, 1.0, 0.5, 1.0])
    np.testing.assert_array_equal(sched.ubar(3.5), [0.0, 0.0, 0.1, 0.0])
    plain = FaultSchedule(2, [FaultEvent(1.0, "2l", 0.0, 0.0)])
    assert not plain.has_motor
    np.testing.assert_array_equal(plain.motor(5.0), M.healthy_faults(4))
    for ev, msg in [
        (FaultEvent(1.0, "1r", motor="open", value=1.0), "takes no value"),
        (FaultEvent(1.0, "1r", motor="stuck"), "needs a value"),
        (FaultEvent(1.0, "1r", motor="resistance", value=0.5), r"in \[1, 1000\]"),
        (FaultEvent(1.0, "1r", motor="melted"), "motor must be one of"),
    ]:
        with pytest.raises(FaultError, match=msg):
            FaultSchedule(2, [ev])


# ------------------------------------------------------------------ the case file
def _case(**extra):
    import tomllib
    from pathlib import Path

    from ftcreport.cases import parse_case

    data = tomllib.loads((Path(__file__).resolve().parents[1] / "cases" / "three_link_switching.toml").read_text())
    t_last = data["faults"][-1]["time"]
    for key, val in extra.items():
        if key == "fault":
            data["faults"].append({"time": t_last + 0.5, "wheel": "2r", **val})
        else:
            data[key] = val
    return parse_case(data, "x.toml")


def test_case_actuators_table_and_motor_faults():
    from ftcreport.errors import CaseError

    plain = _case()
    assert plain.actuators is None and plain.motor_params() is None
    assert not plain.fault_schedule().has_motor
    case = _case(actuators={"N": [20.0, 15.0, 15.0], "I_max": 30.0}, fault={"motor": "km_loss", "value": 0.5})
    mps = case.motor_params()
    assert [m.N for m in mps] == [20.0, 15.0, 15.0] and all(m.I_max == 30.0 for m in mps)
    assert mps[0].R_a == MAXON_RE65.R_a
    sched = case.fault_schedule()
    t = case.faults[-1].time
    np.testing.assert_array_equal(sched.motor(t)[2], [0.5, 1.0, M.MODE_NORMAL, 0.0])
    np.testing.assert_array_equal(sched.motor(t - 1e-9), M.healthy_faults(6))
    for extra, where in [
        ({"fault": {"motor": "open"}}, r"faults\[\d+\]\.motor: motor fault 'open' needs the \[actuators\] table"),
        ({"actuators": {}, "fault": {"motor": "short", "sigma": 1.0}}, r"faults\[\d+\]\.sigma: a motor event"),
        ({"actuators": {}, "fault": {"motor": "stuck"}}, r"faults\[\d+\]\.value: a motor fault 'stuck' needs"),
        ({"actuators": {}, "fault": {"motor": "km_loss", "value": 0.0}}, r"faults\[\d+\]\.value: km_loss value"),
        ({"actuators": {}, "fault": {"value": 2.0}}, r"faults\[\d+\]\.value: a value belongs to a motor fault"),
        ({"actuators": {"R_a": [1.0, 2.0]}}, r"actuators\.R_a: 2 values given, a 3-robot chain needs 3"),
        ({"actuators": {"eta_g": 1.2}}, r"actuators\.eta_g"),
    ]:
        with pytest.raises(CaseError, match=where):
            _case(**extra)


# ------------------------------------------------------------------ the ETD2 step's Jacobian block
@pytest.mark.parametrize("n", [2, 3])
def test_current_jacobian_matches_finite_differences_with_faults(n):
    """model.motor_compiled.current_jacobian (the exact current columns of ETD2's L) against central differences
    of motor_plant_rhs, on healthy, k_m-lost, hot (R_a x 1.8), open, shorted and stuck windings."""
    rng, pc, mo = _setup(n, 11 + n)
    q, eta = _start(rng, n)
    nw = 2 * n
    fault = M.healthy_faults(nw)
    fault[0, M.F_KM] = 0.4
    fault[1, M.F_RA] = 1.8
    fault[2, M.F_MODE] = M.MODE_OPEN
    fault[3, M.F_MODE] = M.MODE_SHORT
    if n > 2:
        fault[4, M.F_MODE] = M.MODE_STUCK
        fault[4, M.F_VSTUCK] = 12.0
    i_a = rng.uniform(-3.0, 3.0, nw)
    v_a = rng.uniform(-20.0, 20.0, nw)
    J = M.current_jacobian(pc, mo, q, eta, fault)

    def rates(i):
        _qd, ed, idot, _tw = M.motor_plant_rhs(pc, mo, q, eta, i, v_a, fault)
        return np.concatenate((ed, idot))

    F = np.empty((2 + nw, nw))
    for j in range(nw):
        d = np.zeros(nw)
        d[j] = 1e-3  # the rates are affine in i_a: central differences are exact up to round-off
        F[:, j] = (rates(i_a + d) - rates(i_a - d)) / 2e-3
    # round-off of (f(i + d) - f(i - d)) / 2d: eps |f| / d ~ 1e-16 * 1e4 / 1e-3 = 1e-9 on the current rows
    np.testing.assert_allclose(J, F, rtol=1e-7, atol=1e-6)
    assert np.all(J[:, 2] == 0.0)  # the open winding's current is 0 whatever it was
    assert J[2 + 1, 1] == pytest.approx(-1.8 * mo.R_a[1] / mo.L_a[1])  # the hot winding's R_a / L_a
    assert abs(J[2, 0]) > 1e3  # the healthy electrical pole -R_a / L_a ~ -2270 1/s is in the block
