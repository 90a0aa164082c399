r"""The closed loop, compiled once per scheme: the template of every scheme's loop.

``run_steps`` integrates the plant and the scheme's controller state over a range of steps
(sim.simulate's order of operations: checks, the law, the stream row, the step, the discrete
updates).  It calls the scheme's law and discrete update through the globals ``LAW`` and
``DISC``.  :func:`ftcreport.fast.engine.loop_for` writes, for each scheme, a module that is this
file with the line marked ``LOOP-BINDING`` importing that scheme's law: numba compiles each such
module on the scheme's first use and caches it beside the module, under a key that is the same
in every process.  So a case compiles only the loops of the schemes it runs, and a plug-in scheme
(ftcreport.schemes) gets a loop as fast as a built-in one.  (Passing the law as an argument
instead would key numba's cache on the law's dispatcher object, which differs in every process:
the loop would be compiled again on every run.)

This file itself binds the nominal law; it is never run as it is.
"""

from __future__ import annotations

import math

import numpy as np

from ftcreport.fast.kernels import (
    AT_DISCRETE,
    AT_STATE,
    AT_TRIAL,
    E_NONFINITE_DERIV,
    E_NONFINITE_STATE,
    E_STEP_GROWTH,
    E_STEP_JUMP,
    _check_state,
    _clip,
    _mv,
    _solve2,
    _step_jump,
    jit,
    kin_discrete,
    new_cache,
    no_discrete,
    plant_rhs,
    tracking_law,
)

LAW, DISC = tracking_law, no_discrete  # LOOP-BINDING


@jit
def _deriv(P, ctx, t, x, sigma, ubar, nz, info, sig):
    """(f, u, tau) of the closed loop (sim.simulate's deriv).

    ``ctx = (Kp, R, C, pc, pp, nq, sat, share)``; ``share``: the controller's
    model is the plant's and there is no noise, so the reduced matrices the
    controller computed at (q, eta) are the plant's.
    """
    Kp, R, C, pc, pp, nq, sat, share = ctx
    q = x[:nq]
    eta = x[nq : nq + 2]
    xc = x[nq + 2 :]
    C.f[3] = 0.0
    u, xcdot = LAW(P, Kp, R, C, pc, t, q + nz[:nq], eta + nz[nq:], xc, sigma, ubar, info, sig)
    f = np.zeros(x.shape[0])
    if info[0] != 0:
        return f, u, u
    us = u if math.isnan(sat) else _clip(u, -sat, sat)
    tau = sigma * us + ubar
    if share and C.f[3] == 1.0:
        qdot = _mv(C.Sm, eta)
        etadot = _solve2(C.M1, _mv(C.Bb, tau) - _mv(C.M2, eta) - C.Cb)
    else:
        qdot, etadot = plant_rhs(pp, q, eta, tau)
    f[:nq] = qdot
    f[nq : nq + 2] = etadot
    f[nq + 2 :] = xcdot
    return f, u, tau


ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@jit
def _plant_deriv(ctx, x, u, sigma, ubar):
    """(f, u, tau) with the control held (sampled control): the plant's rates, the controller's frozen.

    tau = sigma o sat(u) + ubar (2.102); qdot = S(q) eta, Mbar1 etadot = Bbar tau - Mbar2 eta - Cbar (2.70).
    """
    pp, nq, sat = ctx[4], ctx[5], ctx[6]
    us = u if math.isnan(sat) else _clip(u, -sat, sat)
    tau = sigma * us + ubar
    qdot, etadot = plant_rhs(pp, x[:nq], x[nq : nq + 2], tau)
    f = np.zeros(x.shape[0])
    f[:nq] = qdot
    f[nq : nq + 2] = etadot
    return f, u, tau


@jit
def _stage(P, ctx, t, x, sigma, ubar, nz, info, u_h):
    """The rates at a trial stage: the whole loop's (continuous control) or the plant's with u held."""
    if u_h.shape[0] > 0:
        return _plant_deriv(ctx, x, u_h, sigma, ubar)[0]
    return _deriv(P, ctx, t, x, sigma, ubar, nz, info, np.zeros(0))[0]


@jit
def sample(P, ctx, t, x, sigma, ubar, nz, info, hold_t, u_h, dx_h, sig_h):
    """One sample of a discrete-time controller at t (sampled control, period T_s = hold_t[2]).

    The controller's state is advanced over the last sample by a forward-Euler step of its rates
    (held since that sample), then its discrete updates run, then the law: its u is held (zero-order
    hold) until the next sample, its rates and logged signals too.  Measurements: q + noise, eta + noise.
    """
    Kp, R, C, pc, nq = ctx[0], ctx[1], ctx[2], ctx[3], ctx[5]
    xc = x[nq + 2 :]
    q = x[:nq] + nz[:nq]
    eta = x[nq : nq + 2] + nz[nq:]
    if not math.isnan(hold_t[1]):
        h = t - hold_t[1]
        for i in range(xc.shape[0]):
            # xc(t_j+1) = xc(t_j) + T_s xcdot(t_j)
            xc[i] += h * dx_h[i]
        kin_discrete(Kp, R, C, t, xc, info)
        if info[0] != 0:
            return
        DISC(P, Kp, R, C, t, q, eta, xc, info)
        if info[0] != 0:
            return
    C.f[3] = 0.0
    u, dx = LAW(P, Kp, R, C, pc, t, q, eta, xc, sigma, ubar, info, sig_h)
    u_h[:] = u
    dx_h[:] = dx
    hold_t[0] = t + hold_t[2]
    hold_t[1] = t


@jit
def run_steps(
    P, Kp, R, pc, pp,
    grid, fidx, fsig, fubar, noise, sat, diag, method, lim, max_speed, max_position,
    x, k0, k1, is_logged, li,
    lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lt, n_sig, info, share, grow, growth,
    hold_t, u_h, dx_h, sig_h,
):  # fmt: skip
    """Steps k0..k1 of sim.simulate (the same order of operations); returns (x, k, li, where).

    ``where`` says where an error stopped the loop (AT_STATE, AT_TRIAL, AT_DISCRETE).
    ``grow`` = [max |tau| at the previous step, streak length, max |tau| at the streak start]
    carries the step-growth detector of sim.simulate across calls; ``growth`` = [GROWTH_FACTOR,
    GROWTH_STEPS, GROWTH_FLOOR, JUMP_FRACTION, sin(JUMP_MARGINS * margin), GROWTH_TOTAL] of ftcreport.sim.

    Sampled control when ``u_h`` is not empty: ``hold_t = [next sample time, last sample time (nan:
    none yet), T_s]``; the law runs at the samples (:func:`sample`) and the plant integrates with
    its u held; ``u_h, dx_h, sig_h`` carry the held control, rates and signals across calls.
    """
    nq = pp.n + 2
    nx = x.shape[0]
    sig_buf = np.zeros(n_sig)
    C = new_cache(pp.n)
    ctx = (Kp, R, C, pc, pp, nq, sat, share)
    empty = np.zeros(0)
    noisy = noise.shape[0] > 1
    nz = noise[0]
    sampled = u_h.shape[0] > 0
    for k in range(k0, k1 + 1):
        t = grid[k]
        sigma = fsig[fidx[k]]
        ubar = fubar[fidx[k]]
        if noisy:
            nz = noise[k]
        for i in range(nx):
            if not math.isfinite(x[i]):
                info[0] = E_NONFINITE_STATE
                info[1] = t
                return x, k, li, AT_STATE
        _check_state(pp, x, nq, lim, max_speed, max_position, info)
        if info[0] != 0:
            return x, k, li, AT_STATE
        want = is_logged[k]
        if sampled:
            if t >= hold_t[0] - 1e-9 * hold_t[2]:
                sample(P, ctx, t, x, sigma, ubar, nz, info, hold_t, u_h, dx_h, sig_h)
                if info[0] != 0:
                    return x, k, li, AT_STATE
            f0, u, tau = _plant_deriv(ctx, x, u_h, sigma, ubar)
            sig_buf[:] = sig_h
        else:
            f0, u, tau = _deriv(P, ctx, t, x, sigma, ubar, nz, info, sig_buf if want else empty)
        if info[0] != 0:
            return x, k, li, AT_STATE
        ok = True
        for i in range(nx):
            if not math.isfinite(f0[i]):
                ok = False
        for i in range(u.shape[0]):
            if not math.isfinite(u[i]):
                ok = False
        if not ok:
            info[0] = E_NONFINITE_DERIV
            info[1] = t
            return x, k, li, AT_STATE
        # step-growth detector (sim.simulate): max |tau| growing geometrically step after step
        g = 0.0
        for i in range(tau.shape[0]):
            g = max(g, abs(tau[i]))
        if grow[0] > 0.0 and g > growth[0] * grow[0]:
            if grow[1] == 0.0:
                grow[2] = grow[0]
            grow[1] += 1.0
        else:
            grow[1] = 0.0
        grow[0] = g
        if grow[1] >= growth[1] and g > growth[2] and g > growth[5] * grow[2]:
            info[0] = E_STEP_GROWTH
            info[1] = t
            info[2] = grow[2]
            info[3] = g
            return x, k, li, AT_STATE
        if want:
            lt[li] = t
            lq[li] = x[:nq]
            leta[li] = x[nq : nq + 2]
            lu[li] = u
            ltau[li] = tau
            lsig[li] = sigma
            lubar[li] = ubar
            lxc[li] = x[nq + 2 :]
            if lmeas.shape[0] > 0:
                lmeas[li] = x[: nq + 2] + nz
            lsg[li] = sig_buf
            li += 1
        if k == grid.shape[0] - 1:
            return x, k, li, AT_STATE
        h = grid[k + 1] - t
        if method == 0:
            f2 = _stage(P, ctx, t + 0.5 * h, x + 0.5 * h * f0, sigma, ubar, nz, info, u_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            f3 = _stage(P, ctx, t + 0.5 * h, x + 0.5 * h * f2, sigma, ubar, nz, info, u_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            f4 = _stage(P, ctx, t + h, x + h * f3, sigma, ubar, nz, info, u_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            xn = x + (h / 6.0) * (f0 + 2.0 * f2 + 2.0 * f3 + f4)
        else:
            F = np.empty((nx, 2))
            for j in range(2):
                c = nq + j
                delta = 1e-7 * max(1.0, abs(x[c]))
                xp = x.copy()
                xp[c] += delta
                fp = _stage(P, ctx, t, xp, sigma, ubar, nz, info, u_h)
                if info[0] != 0:
                    return x, k, li, AT_TRIAL
                F[:, j] = (fp - f0) / delta
            gh = ROS2_GAMMA * h
            dinv = 1.0 / (1.0 - gh * diag)
            DF = np.empty((nx, 2))
            for i in range(nx):
                DF[i, 0] = dinv[i] * F[i, 0]
                DF[i, 1] = dinv[i] * F[i, 1]
            small = np.empty((2, 2))
            small[0, 0] = 1.0 - gh * DF[nq, 0]
            small[0, 1] = -gh * DF[nq, 1]
            small[1, 0] = -gh * DF[nq + 1, 0]
            small[1, 1] = 1.0 - gh * DF[nq + 1, 1]
            rd = dinv * f0
            kk1 = rd + gh * (DF @ _solve2(small, rd[nq : nq + 2]))
            f2 = _stage(P, ctx, t + h, x + h * kk1, sigma, ubar, nz, info, u_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            rd = dinv * (f2 - 2.0 * kk1)
            kk2 = rd + gh * (DF @ _solve2(small, rd[nq : nq + 2]))
            xn = x + 1.5 * h * kk1 + 0.5 * h * kk2
        kind = _step_jump(pp, x, xn, nq, lim, max_speed, max_position, growth[3], growth[4], info)
        if kind != 0:
            info[0] = E_STEP_JUMP
            info[1] = kind
            return x, k, li, AT_TRIAL
        if sampled:  # the controller's discrete updates run at its samples
            x = xn
            continue
        # discrete updates on the new state (xn is a new array: updated in place, it becomes the state)
        xcn = xn[nq + 2 :]
        kin_discrete(Kp, R, C, grid[k + 1], xcn, info)
        if info[0] != 0:
            return x, k, li, AT_DISCRETE
        DISC(P, Kp, R, C, grid[k + 1], xn[:nq] + nz[:nq], xn[nq : nq + 2] + nz[nq:], xcn, info)
        if info[0] != 0:
            return x, k, li, AT_DISCRETE
        x = xn
    return x, k1, li, AT_STATE
