"""Power balance of the reduced dynamics (2.70) along RK4 trajectories.

The constraint forces do no work, so d/dt T = tau . (wheel angular velocities)
with T = 1/2 eta^T Mbar1 eta; with zero torque T is conserved.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_chain

from ftcreport.model import Chain


def _rk4(chain: Chain, q, eta, tau_fn, dt, steps):
    nq = chain.n_q

    def f(t, x):
        qd, ed = chain.dynamics(x[:nq], x[nq:], tau_fn(t))
        return np.concatenate((qd, ed))

    x = np.concatenate((q, eta))
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


def _start(rng, chain):
    n = chain.n
    th1 = 0.3
    th = th1 - np.cumsum(np.concatenate(([0.0], rng.uniform(-0.4, 0.4, n - 1))))
    return np.concatenate(([0.0, 0.0], th[::-1])), np.array([0.6, 0.3])


@pytest.mark.parametrize("n", [2, 3, 5])
def test_power_balance_random_smooth_torques(n):
    rng = np.random.default_rng(7 + n)
    chain = random_chain(rng, n)
    amp = rng.uniform(-2.0, 2.0, (3, 2 * n))
    freq = rng.uniform(0.3, 2.0, (3, 2 * n))
    phase = rng.uniform(0, 2 * np.pi, (3, 2 * n))

    def tau(t):
        return np.sum(amp * np.sin(freq * t + phase), axis=0)

    q0, eta0 = _start(rng, chain)
    dt, steps = 1e-3, 2000
    xs = _rk4(chain, q0, eta0, tau, dt, steps)
    nq = chain.n_q
    T = np.array([chain.kinetic_energy(x[:nq], x[nq:]) for x in xs])
    power = np.array([tau(k * dt) @ chain.wheel_speeds(x[:nq], x[nq:]) for k, x in enumerate(xs)])
    # central difference of T (error O(dt^2) ~ 1e-7 relative) against the input power
    dTdt = (T[2:] - T[:-2]) / (2 * dt)
    scale = np.abs(power).max()
    assert scale > 1e-2  # the torques do work
    assert np.abs(dTdt - power[1:-1]).max() < 1e-6 * scale
    # and the same in integral form: T(t) - T(0) = int power dt (trapezoid, O(dt^2))
    work = np.concatenate(([0.0], np.cumsum((power[1:] + power[:-1]) * dt / 2)))
    assert np.abs(T - T[0] - work).max() < 1e-6 * np.abs(T).max()


@pytest.mark.parametrize("n", [2, 3, 5])
def test_energy_conserved_without_torque(n):
    rng = np.random.default_rng(70 + n)
    chain = random_chain(rng, n)
    q0, eta0 = _start(rng, chain)
    xs = _rk4(chain, q0, eta0, lambda t: np.zeros(2 * n), 1e-3, 2000)
    nq = chain.n_q
    T = np.array([chain.kinetic_energy(x[:nq], x[nq:]) for x in xs])
    # the chain really moves and reconfigures (articulation angles change)
    assert np.abs(xs[-1, 2:nq] - xs[0, 2:nq]).max() > 1e-2
    assert np.abs(T - T[0]).max() < 1e-8 * T[0]
