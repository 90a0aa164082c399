"""The switching bank by superposition (issue 20 item 5) against the per-model bank it replaces.

The reference here is the bank as it was before: one filter (3.42) and one cost integral per model,
integrated separately, and the exhaustive rule (3.46)-(3.47) (every cost, the lowest index within
TIE_RTOL of the least one, dwell time, hysteresis): in plain numpy for the single evaluations, and as
a plug-in scheme (tests/data/bank_reference_scheme.py) for the closed loops.  It shares with the
package only what is not under test: the kinematic law and the matched law's terms.

Tolerances.  The superposed filters are the same linear ODEs summed in another order, so they agree
with the per-model ones to round-off: values of O(1) after 300 RK4 steps agree to 1e-15 (measured),
held to 1e-13.
In the closed loops the two banks differ at round-off as well (the plant state held to 1e-9).  The
costs, up to 1.1e-4 (m/s)^2 in these runs, differed by at most 1.4e-18 (measured when the reference
ran in the Python loop): they are held to 1e-8 of the largest cost, 10^4 above that and far below
any cost difference the rule acts on (the hysteresis is 1e-10).  The selected model is an integer
sequence and must be identical (28 to 76 switches in these runs).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ftcreport.control import switching as S
from ftcreport.control.switching import TIE_RTOL, SwitchingController
from ftcreport.fast import kernels as F
from ftcreport.model import FaultEvent, FaultSchedule, compensable_patterns
from ftcreport.schemes import load_plugin
from ftcreport.sim import Plant, SimSettings, demo_chain, simulate


def _state(ctrl: SwitchingController, h, Z, M=None) -> np.ndarray:
    xc = np.zeros(ctrl.n_states)
    xc[ctrl._filt] = np.concatenate((h, np.asarray(Z).ravel()))
    if M is not None:
        iu = np.triu_indices(M.shape[0])
        xc[ctrl._int] = M[iu]  # row by row, as fast.kernels._tri
    xc[ctrl._tsw] = -1e9
    return xc


def _exhaustive(ctrl, J, cur, t_since, T_min):
    """The rule (3.47) with ties, dwell time and hysteresis on a cost vector: the next selected index."""
    ties = np.flatnonzero(np.less_equal(J, J.min() * (1.0 + TIE_RTOL)))
    cand = int(ties[0]) if ties.size else int(np.argmin(J))
    if cand != cur and t_since >= T_min - 1e-12 and J[cand] < J[cur] - ctrl.hysteresis:
        return cand
    return cur


# ------------------------------------------------------------------ superposition, open loop
def test_superposed_filters_equal_the_per_model_filters():
    """Random smooth MB(t), g(t), u(t), eta(t): RK4 on the per-model bank and on (h, z, M) give the same
    etahat_k and J_k (inst. and integral) for every model, to round-off."""
    n, gamma, lam = 3, 7.0, 0.8
    nw = 2 * n
    chain, kin, _q0 = demo_chain(n)
    ctrl = SwitchingController(chain, kin, 2.0, gamma=gamma, c_int=0.7, forgetting=lam)
    Lw = ctrl.packed()
    P = ctrl.patterns
    N = len(P)
    rng = np.random.default_rng(7)
    a = rng.normal(size=(3, 3 * nw + 4))
    w = rng.uniform(0.5, 3.0, size=a.shape[1])

    def inputs(t):
        v = a[0] * np.sin(w * t) + a[1] * np.cos(0.5 * w * t) + a[2]
        return v[: 2 * nw].reshape(2, nw), v[2 * nw : 3 * nw], v[3 * nw : 3 * nw + 2], v[3 * nw + 2 : 3 * nw + 4]

    def bank(t, x):
        MB, u, g, eta = inputs(t)
        hat = x[: 2 * N].reshape(N, 2)
        dhat = -gamma * hat + gamma * eta + g + (P * u[None, :]) @ MB.T
        err = eta[None, :] - hat
        dint = -lam * x[2 * N :] + np.sum(err * err, axis=1)
        return np.concatenate((dhat.ravel(), dint))

    def superposed(t, x):
        MB, u, g, eta = inputs(t)
        dx = np.zeros_like(x)
        nk = kin.n_states  # the kernels' offsets are in the scheme's own states, after the kinematic ones
        F.switching_rates(Lw, np.ascontiguousarray(MB), u, g, eta, x[nk:], dx[nk:])
        return dx

    def rk4(f, x, t, dt):
        k1 = f(t, x)
        k2 = f(t + dt / 2, x + dt / 2 * k1)
        k3 = f(t + dt / 2, x + dt / 2 * k2)
        k4 = f(t + dt, x + dt * k3)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    eta0 = inputs(0.0)[3]
    xb = np.concatenate((np.tile(eta0, N), np.zeros(N)))
    xs = ctrl.initial_state(0.0, _q0, eta0)
    dt = 0.01
    for i in range(300):
        xb = rk4(bank, xb, i * dt, dt)
        xs = rk4(superposed, xs, i * dt, dt)
    eta = inputs(300 * dt)[3]
    hat_ref = xb[: 2 * N].reshape(N, 2)
    assert np.abs(hat_ref).max() > 0.1 and np.ptp(hat_ref[:, 0]) > 0.1  # the models really differ
    np.testing.assert_allclose(ctrl.filters(xs), hat_ref, rtol=0, atol=1e-13)
    J_ref = np.sum((eta[None, :] - hat_ref) ** 2, axis=1) + 0.7 * xb[2 * N :]
    assert J_ref.min() > 1e-3  # so that 1e-13 is a real test of the integral part
    np.testing.assert_allclose(ctrl.costs(eta, xs), J_ref, rtol=0, atol=1e-13)


# ------------------------------------------------------------------ the rule on given states
@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("c_int", [0.0, 0.3])
@pytest.mark.parametrize("n", [3, 4, 5])
def test_walk_selects_what_the_exhaustive_rule_selects(n, c_int, reverse):
    """Random superposed states, many with exact ties (wheels never driven: z_j = 0) and near-ties:
    switching_select (the walk) picks the exhaustive rule's model every time, also for the bank in
    reverse order (not monotone: no skipping of the never-driven wheels' branches)."""
    chain, kin, _q0 = demo_chain(n)
    pats = compensable_patterns(n)
    ctrl = SwitchingController(chain, kin, 2.0, c_int=c_int, T_min=0.0, patterns=pats[::-1] if reverse else pats)
    Lw = ctrl.packed()
    assert Lw.codes.shape[0] == 4**n  # the walk is used
    assert Lw.trie[0] == (0 if reverse else 1)  # monotone bank
    nw = 2 * n
    rng = np.random.default_rng(100 + n)
    eta = np.array([0.5, 0.1])
    f = 1.0 - ctrl.patterns
    switched = 0
    for trial in range(60):
        Z = rng.normal(scale=10.0 ** rng.uniform(-4, -1), size=(nw, 2))
        idle = rng.random(nw) < 0.4
        Z[idle] = 0.0  # exact ties among models differing in these wheels
        true = rng.integers(ctrl.N)
        h = eta + f[true] @ Z + rng.normal(scale=10.0 ** rng.uniform(-9, -3), size=2)  # model `true` near exact
        M = None
        if c_int > 0:
            A = rng.normal(scale=1e-2, size=(5, 2, nw + 1))
            A[:, :, 1:][:, :, idle] = 0.0  # never driven: their integrals are 0 too
            M = np.einsum("tia,tib->ab", A, A)
        xc = _state(ctrl, h, Z, M)
        cur = int(rng.integers(ctrl.N))
        xc[ctrl._sel] = cur
        # independent costs: etahat_k = h - Z^T f_k, int_k = sum_t |A_t (1, f_k)|^2
        err = eta[None, :] - (h[None, :] - f @ Z)
        J = np.sum(err * err, axis=1)
        if M is not None:
            v = np.hstack((np.ones((ctrl.N, 1)), f))
            J = J + c_int * np.einsum("ka,ab,kb->k", v, M, v)
        np.testing.assert_allclose(ctrl.costs(eta, xc), J, rtol=1e-12, atol=1e-15)
        want = _exhaustive(ctrl, ctrl.costs(eta, xc), cur, 1e9, 0.0)
        F.switching_select(Lw, 1.0, eta, xc[ctrl.kin.n_states :])
        assert round(xc[ctrl._sel]) == want, trial
        switched += want != cur
    assert switched > 40  # the rule really moved


def test_ties_go_to_the_lowest_index_also_in_the_walk():
    """Costs within TIE_RTOL of the least are ties (the lowest index wins), a real difference is not."""
    chain, kin, _q0 = demo_chain(3)
    ctrl = SwitchingController(chain, kin, 2.0)
    P = ctrl.patterns.tolist()
    i5, i3 = P.index([1, 1, 1, 1, 1, 0]), P.index([1, 1, 1, 0, 1, 1])  # 3l failed, 2l failed
    assert i5 < i3
    eta = np.array([0.5, 0.1])
    h = eta + np.array([1e-2, 1e-2])  # every model far off (z = 0 elsewhere) ...
    Z = np.zeros((6, 2))
    Z[5] = -np.array([3e-5, 4e-5]) - (eta - h)  # ... but 3l-failed: etatilde = -(3e-5, 4e-5)
    Z[3] = -np.array([3e-5, 4e-5 * (1.0 - 1e-11)]) - (eta - h)  # 2l-failed smaller by 1e-11 relative
    xc = _state(ctrl, h, Z)
    J = ctrl.costs(eta, xc)
    assert J[i3] < J[i5] < J[i3] * (1.0 + TIE_RTOL) and J.min() == J[i3]
    F.switching_select(ctrl.packed(), 1.0, eta, xc[ctrl.kin.n_states :])
    assert round(xc[ctrl._sel]) == i5
    Z[3] = -np.array([3e-5, 3.9e-5]) - (eta - h)  # a real difference: the smaller cost wins
    xc = _state(ctrl, h, Z)
    F.switching_select(ctrl.packed(), 1.0, eta, xc[ctrl.kin.n_states :])
    assert round(xc[ctrl._sel]) == i3


def test_banks_that_are_not_every_pattern_are_evaluated_pattern_by_pattern():
    """A short list and a fractional one: no walk tables, the same rule."""
    chain, kin, _q0 = demo_chain(3)
    eta = np.array([0.5, 0.1])
    rng = np.random.default_rng(3)
    for pats in ([(1, 1, 1, 1, 1, 1), (1, 1, 0, 1, 1, 1), (0, 1, 1, 1, 0, 1)],):
        ctrl = SwitchingController(chain, kin, 2.0, patterns=pats, c_int=0.5)
        assert ctrl.packed().codes.shape[0] == 0
        for _ in range(20):
            Z = rng.normal(scale=1e-2, size=(6, 2))
            A = rng.normal(scale=1e-2, size=(3, 2, 7))
            xc = _state(ctrl, eta + rng.normal(scale=1e-2, size=2), Z, np.einsum("tia,tib->ab", A, A))
            want = _exhaustive(ctrl, ctrl.costs(eta, xc), 0, 1e9, ctrl.T_min)
            F.switching_select(ctrl.packed(), 1.0, eta, xc[ctrl.kin.n_states :])
            assert round(xc[ctrl._sel]) == want
    # fractional sigma: the kernel's cost is the quadratic form of the per-model filter
    ctrl = SwitchingController(chain, kin, 2.0, c_int=0.5)
    frac = ctrl.patterns.copy()
    frac[:, 2] *= 0.4
    ctrl.patterns = frac
    ctrl._packed = None
    assert ctrl.packed().codes.shape[0] == 0
    Z = rng.normal(scale=1e-2, size=(6, 2))
    A = rng.normal(scale=1e-2, size=(3, 2, 7))
    xc = _state(ctrl, eta, Z, np.einsum("tia,tib->ab", A, A))
    err = (1.0 - frac) @ Z  # eta - etahat_k with h = eta
    v = np.hstack((np.ones((ctrl.N, 1)), 1.0 - frac))
    J = np.sum(err * err, axis=1) + 0.5 * np.sum(np.einsum("tia,ka->tki", A, v) ** 2, axis=(0, 2))
    np.testing.assert_allclose(ctrl.costs(eta, xc), J, rtol=1e-12, atol=1e-16)


# ------------------------------------------------------------------ closed loop against the per-model bank
CLOSED = [
    (3, 0.0, [FaultEvent(1.0, "2r"), FaultEvent(2.5, "1l")]),
    (3, 0.5, [FaultEvent(1.0, "3l"), FaultEvent(2.5, "1r")]),
    (4, 0.0, [FaultEvent(1.0, "4r"), FaultEvent(2.0, "2l"), FaultEvent(3.0, "1l")]),
]


@pytest.mark.slow
@pytest.mark.parametrize(("n", "c_int", "events"), CLOSED)
def test_engine_selects_the_per_model_banks_sequence(n, c_int, events):
    """The built-in switching scheme (superposition + walk) and the per-model bank (a plug-in scheme): the
    same selected model at every step, the same costs (module docstring)."""
    load_plugin(Path(__file__).parent / "data" / "bank_reference_scheme.py")
    bank = sys.modules["ftcreport_plugin_bank_reference_scheme"]
    chain, kin, q0 = demo_chain(n)
    eta0 = np.array([0.5, 0.0])
    settings = SimSettings(0.01, 4.0)
    runs = []
    for ctrl in (SwitchingController(chain, kin, 2.0, c_int=c_int), bank.controller(chain, kin, 2.0, c_int)):
        plant = Plant(chain, FaultSchedule(n, events))
        runs.append(simulate(plant, ctrl, q0, eta0, settings))
    fast, ref = runs
    assert fast.ok and ref.ok, (fast.reason, ref.reason)
    nk, N = kin.n_states, fast["cost"].shape[1]
    xc = ref["xc"]
    sel = xc[:, nk + 3 * N]
    err = ref["eta"][:, None, :] - xc[:, nk : nk + 2 * N].reshape(-1, N, 2)
    cost = np.sum(err * err, axis=2) + c_int * xc[:, nk + 2 * N : nk + 3 * N]  # (3.46), c_inst = 1
    assert len(np.flatnonzero(np.diff(sel))) >= 10  # it switches, after every fault (28 to 76 times)
    np.testing.assert_array_equal(fast["selected"], sel)
    np.testing.assert_allclose(fast["cost"], cost, rtol=0, atol=1e-8 * np.abs(cost).max())
    np.testing.assert_allclose(fast["q"], ref["q"], rtol=0, atol=1e-9)


def test_large_banks_log_the_selected_and_least_cost_only():
    chain, kin, q0 = demo_chain(7)  # 12286 models > MAX_LOGGED_COSTS
    ctrl = SwitchingController(chain, kin, 2.0)
    assert ctrl.N > S.MAX_LOGGED_COSTS and "cost" not in ctrl.signal_names
    run = simulate(Plant(chain), ctrl, q0, np.array([0.5, 0.0]), SimSettings(0.01, 0.3))
    assert run.ok
    xc = run["xc"][-1]
    eta = run["eta"][-1]
    J = ctrl.costs(eta, xc)
    assert run["cost_best"][-1] == J.min()
    assert run["cost_selected"][-1] == J[int(run["selected"][-1])]
