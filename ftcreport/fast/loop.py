r"""The closed loop, compiled once per scheme: the template of every scheme's loop.

``run_steps`` integrates the plant and the scheme's controller state over a range of steps, in
this order: checks, the law, the stream row, the step, the discrete updates (the stops and their
thresholds are in ftcreport.sim's docstring).  It calls the scheme's law and discrete update
through the globals ``LAW`` and ``DISC``, and the kinematic controller's part of every law (the
matched terms, the kinematic signals, its discrete update) through ``TERMS``, ``KEVAL``,
``KSIG``, ``KDISC`` and ``KCACHE``.  :func:`ftcreport.fast.engine.loop_for` writes, for each
scheme, a module that is this file with the line marked ``LOOP-BINDING`` importing that scheme's
law and the scheme interface's kernels (ftcreport.schemes.kernels): numba compiles each such
module on the scheme's first use and caches it beside the module, under a key that is the same in
every process.  So a case compiles only the loops of the schemes it runs, and a plug-in scheme
(ftcreport.schemes) gets a loop as fast as a built-in one.  (Passing the law as an argument
instead would key numba's cache on the law's dispatcher object, which differs in every process:
the loop would be compiled again on every run.)  This module knows a scheme only through the
interface of ftcreport.schemes.api: how a law is called (:func:`_law`), what it is handed
(``Step``, ``Terms``, ``Out``) and the guards after its buffers.

The loop's ``P`` is the pair (the scheme's packed parameters, its law buffers): the buffers are
``(k_v, u, dx, sig, x, fresh)``, each of u, dx, sig, x with ``N_GUARD`` guard cells after the
declared size (fast.engine.law_buffers), checked after every call of the law or discrete update.

This file itself binds a law that does nothing; it is never run as it is.
"""

from __future__ import annotations

import math

import numpy as np

from ftcreport.fast.expo import phi12, phi12_scalar
from ftcreport.fast.kernels import (
    AT_DISCRETE,
    AT_STATE,
    AT_TRIAL,
    E_LAW_WRITE,
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
    plant_rhs,
    reduced,
)
from ftcreport.fast.motor import current_jacobian, driver_voltage, fault_equivalent, motor_plant_rhs, reset_current
from ftcreport.fast.refs import as_ref
from ftcreport.schemes.api import N_GUARD, Out, Step, Terms
from ftcreport.schemes.kernels import engine_terms as TERMS
from ftcreport.schemes.kernels import guards_intact, no_discrete, no_law, readonly
from ftcreport.schemes.kernels import kinematic_discrete as KDISC
from ftcreport.schemes.kernels import kinematic_eval as KEVAL
from ftcreport.schemes.kernels import kinematic_signals as KSIG
from ftcreport.schemes.kernels import new_kinematic_cache as KCACHE

LAW, DISC = no_law, no_discrete  # LOOP-BINDING

#: a round-2 law (13 positionals, returning (u, xcdot); ftcreport.schemes.registry.legacy), run through the
#: adapter in _law and _disc for one deprecation cycle, without the guards
LEGACY = False  # LOOP-LEGACY
#: how the matched terms reach the law (schemes.api.TERMS_MODES; fast.engine.loop_for writes the scheme's)
TERMS_MODE = 0  # LOOP-TERMS
# the loop's variant (fast.engine.loop_for writes the case's): numba prunes the branches these close
# before typing, so a loop without motors or sampled control never compiles their kernels
MOTORS, SAMPLED = True, True  # LOOP-VARIANT


@jit
def _motors(ctx, x, tau_c, fm, v_h, qm, etam):
    """(qdot, etadot, i_dot, tau_w, v_a) of the chain driven by its DC motors, (2.26)-(2.29) with E19.

    The driver turns the commanded torques tau_c into armature voltages by its static inversion at
    the measured wheel speeds (fast.motor.driver_voltage), or holds ``v_h`` (sampled control).
    """
    pc, pp, nq, mo, nm = ctx[3], ctx[4], ctx[5], ctx[8], ctx[9]
    if v_h.shape[0] > 0:
        v = v_h
    else:
        Bm = reduced(pc, qm, etam)[3]
        # the driver's wheel speeds: Bbar(q)^T eta at the measured state
        v = driver_voltage(mo, tau_c, _mv(Bm.T, etam), fm)
    qdot, etadot, idot, tau_w = motor_plant_rhs(pp, mo, x[:nq], x[nq : nq + 2], x[nq + 2 : nq + 2 + nm], v, fm)
    return qdot, etadot, idot, tau_w, v


@jit
def true_faults(ctx, x, sigma, ubar, fm):
    """The (sigma, ubar) the chain sees: the command faults composed with the motors' equivalents.

    tau_w ~ s_m (sigma u + ubar) + u_m, so sigma_true = s_m sigma, ubar_true = s_m ubar + u_m
    (fast.motor.fault_equivalent at the wheel speeds of x); without motors, (sigma, ubar).
    """
    if ctx[9] == 0:
        return sigma, ubar
    pp, nq = ctx[4], ctx[5]
    Bb = reduced(pp, x[:nq], x[nq : nq + 2])[3]
    sm, um = fault_equivalent(ctx[8], fm, _mv(Bb.T, x[nq : nq + 2]))
    return sm * sigma, sm * ubar + um


@jit
def _law(P, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig):
    """(u, dx): the scheme's command at (t, q, eta) (a copy) and its own states' rates (a view).

    The law is handed its parameters, the step (:class:`~ftcreport.schemes.api.Step`), the matched
    terms at the measured state (``TERMS_MODE`` 0), its own states read-only and views of the law
    buffers (``P[1]``) of exactly the declared sizes; the guard cells after them are checked after
    the call (E_LAW_WRITE: info[1] = 0 u, 1 dx, 2 sig; info[2] = t).  When ``sig`` is not empty the
    step is logged: the kinematic signals (of the law's own evaluation, else the engine's at the
    measured state) and then the law's.
    """
    Pp, io = P
    if LEGACY:
        return _legacy_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig)
    else:
        return _contract_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig)


@jit
def _contract_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig):
    """:func:`_law` for a law of the scheme API's contract."""
    k_v, ub, db, sb, _xb, fresh = io
    nw = ub.shape[0] - N_GUARD
    no = db.shape[0] - N_GUARD
    ns = sb.shape[0] - N_GUARD
    nk = xc.shape[0] - no
    xk = xc[:nk]
    u = ub[:nw]
    dx = db[:no]
    s = sb[:ns]
    u[:] = 0.0
    dx[:] = 0.0
    step = Step(t, q, eta, st, ut, pc, info, (Kp, R, C, xk, fresh))
    fresh[0] = 0.0
    if TERMS_MODE == 0:
        terms = TERMS(Kp, R, C, pc, t, q, eta, xk, k_v, info)
        if info[0] != 0:
            return u.copy(), dx
    else:
        z = np.zeros(2)
        terms = Terms(z, np.zeros((2, nw)), z, z)
    LAW(Pp, step, terms, readonly(xc[nk:]), Out(u, dx, s))
    if info[0] != 0:
        return u.copy(), dx
    for which, buf, n in ((0, ub, nw), (1, db, no), (2, sb, ns)):
        if not guards_intact(buf, n):
            info[0] = E_LAW_WRITE
            info[1] = which
            info[2] = t
            return u.copy(), dx
    if sig.shape[0] > 0:
        k = sig.shape[0] - ns
        if TERMS_MODE == 2:
            sig[:k] = np.nan
        else:
            if TERMS_MODE == 1 and fresh[0] == 0.0:
                KEVAL(Kp, R, C, pc, t, q, eta, xk, info)
                if info[0] != 0:
                    return u.copy(), dx
            KSIG(sig, Kp, C)
        sig[k:] = s
    return u.copy(), dx


@jit
def _legacy_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig):
    """:func:`_law` for a round-2 law (13 positionals, (u, xcdot) returned): it writes the whole logged row
    itself (the kinematic signals through matched_terms); no guards (the deprecated form is unchecked)."""
    ub, db = io[1], io[2]
    nw = ub.shape[0] - N_GUARD
    no = db.shape[0] - N_GUARD
    nk = xc.shape[0] - no
    u = ub[:nw]
    dx = db[:no]
    ul, dxl = LAW(Pp, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig)
    if info[0] != 0:
        return u.copy(), dx
    if ul.shape[0] != nw or dxl.shape[0] != xc.shape[0]:
        info[0] = E_LAW_WRITE
        info[1] = 0 if ul.shape[0] != nw else 1
        info[2] = t
        return u.copy(), dx
    u[:] = ul
    dx[:] = dxl[nk:]
    return u.copy(), dx


@jit
def _disc(P, Kp, R, C, pc, t, q, eta, xc, st, ut, info):
    """The scheme's discrete update on its own states (in place), through the guarded state buffer.

    The own states are copied into ``P[1]``'s x buffer, updated there and copied back; the guard
    cells after them are checked (E_LAW_WRITE with info[1] = 3).  A round-2 update gets the whole
    controller state, unguarded.
    """
    Pp, io = P
    if LEGACY:
        DISC(Pp, Kp, R, C, t, q, eta, xc, info)
    else:
        xb, fresh = io[4], io[5]
        no = xb.shape[0] - N_GUARD
        nk = xc.shape[0] - no
        x = xb[:no]
        x[:] = xc[nk:]
        DISC(Pp, Step(t, q, eta, st, ut, pc, info, (Kp, R, C, xc[:nk], fresh)), x)
        if not guards_intact(xb, no):
            info[0] = E_LAW_WRITE
            info[1] = 3
            info[2] = t
            return
        xc[nk:] = x


@jit
def _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, sig):
    """(f, u, tau) of the closed loop: the plant's and the controller's rates at (t, x).

    ``ctx = (Kp, R, C, pc, pp, nq, sat, share, mo, nm)``; ``share``: the controller's
    model is the plant's and there is no noise, so the reduced matrices the
    controller computed at (q, eta) are the plant's; ``nm``: the motors' currents in x
    (0: the ideal torque plant).
    """
    Kp, R, C, pc, pp, nq, sat, share, _mo, nm = ctx
    q = x[:nq]
    eta = x[nq : nq + 2]
    xc = x[nq + 2 + nm :]
    C.f[3] = 0.0
    qm = q + nz[:nq]
    etam = eta + nz[nq:]
    st, ut = sigma, ubar
    if MOTORS and nm > 0:  # the oracle is told the faults the chain sees, motor faults included
        st, ut = true_faults(ctx, x, sigma, ubar, fm)
    u, xcdot = _law(P, Kp, R, C, pc, t, qm, etam, xc, st, ut, info, sig)
    f = np.zeros(x.shape[0])
    if info[0] != 0:
        return f, u, u
    us = u if math.isnan(sat) else _clip(u, -sat, sat)
    tau = sigma * us + ubar
    if MOTORS and nm > 0:
        qdot, etadot, idot, tau, _v = _motors(ctx, x, tau, fm, np.zeros(0), qm, etam)
        f[nq + 2 : nq + 2 + nm] = idot
    elif share and C.f[3] == 1.0:
        qdot = _mv(C.Sm, eta)
        etadot = _solve2(C.M1, _mv(C.Bb, tau) - _mv(C.M2, eta) - C.Cb)
    else:
        qdot, etadot = plant_rhs(pp, q, eta, tau)
    f[:nq] = qdot
    f[nq : nq + 2] = etadot
    f[x.shape[0] - xcdot.shape[0] :] = xcdot  # the kinematic controller's states have no rate
    return f, u, tau


@jit
def _solve_small(A, b):
    """A x = b for the W-method's small system: closed form for 2 x 2, else Gaussian elimination (partial pivoting)."""
    m = b.shape[0]
    if m == 2:
        return _solve2(A, b)
    M = A.copy()
    y = b.copy()
    for c in range(m):
        p = c
        for r in range(c + 1, m):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if p != c:
            for j in range(m):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            y[c], y[p] = y[p], y[c]
        for r in range(c + 1, m):
            f = M[r, c] / M[c, c]
            for j in range(c, m):
                M[r, j] -= f * M[c, j]
            y[r] -= f * y[c]
    out = np.empty(m)
    for c in range(m - 1, -1, -1):
        acc = y[c]
        for j in range(c + 1, m):
            acc -= M[c, j] * out[j]
        out[c] = acc / M[c, c]
    return out


ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@jit
def _plant_deriv(ctx, x, u, sigma, ubar, fm, v_h):
    """(f, u, tau) with the control held (sampled control): the plant's rates, the controller's frozen.

    tau = sigma o sat(u) + ubar (2.102); qdot = S(q) eta, Mbar1 etadot = Bbar tau - Mbar2 eta - Cbar (2.70);
    with motors, the held armature voltages v_h drive (2.28)-(2.29).
    """
    pp, nq, sat, nm = ctx[4], ctx[5], ctx[6], ctx[9]
    us = u if math.isnan(sat) else _clip(u, -sat, sat)
    tau = sigma * us + ubar
    f = np.zeros(x.shape[0])
    if MOTORS and nm > 0:
        qdot, etadot, idot, tau, _v = _motors(ctx, x, tau, fm, v_h, x[:nq], x[nq : nq + 2])
        f[nq + 2 : nq + 2 + nm] = idot
    else:
        qdot, etadot = plant_rhs(pp, x[:nq], x[nq : nq + 2], tau)
    f[:nq] = qdot
    f[nq : nq + 2] = etadot
    return f, u, tau


@jit
def _stage(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h):
    """The rates at a trial stage: the whole loop's (continuous control) or the plant's with u held."""
    if SAMPLED and u_h.shape[0] > 0:
        return _plant_deriv(ctx, x, u_h, sigma, ubar, fm, v_h)[0]
    return _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, np.zeros(0))[0]


@jit
def _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h):
    """d f / d [eta, i_a] at x, (nx, 2 + nm): eta's columns by forward differences (2 evaluations of
    the stage's rates), the currents' exact (fast.motor.current_jacobian: rows eta and i_a; no other
    rate reads a current)."""
    pp, nq, mo, nm = ctx[4], ctx[5], ctx[8], ctx[9]
    F = np.zeros((x.shape[0], 2 + nm))
    for j in range(2):
        c = nq + j
        delta = 1e-7 * max(1.0, abs(x[c]))
        xp = x.copy()
        xp[c] += delta
        fp = _stage(P, ctx, t, xp, sigma, ubar, fm, nz, info, u_h, v_h)
        if info[0] != 0:
            return F
        F[:, j] = (fp - f0) / delta
    if MOTORS and nm > 0:
        F[nq : nq + 2 + nm, 2:] = current_jacobian(pp, mo, x[:nq], x[nq : nq + 2], fm)
    return F


@jit
def _etd2(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag):
    r"""One ETD2RK step (Cox & Matthews 2002, J. Comput. Phys. 176, (22); Hochbruck & Ostermann 2010, (5.8)).

    x' = f(x) is split as L x + N(x), L linear: J, the Jacobian block of the rates of
    [eta, i_a] in [eta, i_a] (eta's columns by forward differences at x, 2 evaluations; the
    currents' exact, fast.motor.current_jacobian), where the stiff
    modes live (the motors' L_a / R_a, the velocity loop); the controller's exact ``diag``
    (its linear filters, as for ROS2); zero elsewhere (q).  With the phi functions of h L::

        a  = x + h phi_1(h L) f(x)                        (= e^{hL} x + h phi_1 N(x))
        x+ = a + h phi_2(h L) (f(a) - f(x) - L (a - x))   (= ... + h phi_2 (N(a) - N(x)))

    Second order for any L, stiff order 2 (Hochbruck & Ostermann, Table 5.2); exact when f is
    linear and L its Jacobian, so a current's transient after each held-voltage step is
    integrated exactly however long the step: its torque impulse reaches eta in full.
    """
    nq, nm = ctx[5], ctx[9]
    nx = x.shape[0]
    m = 2 + nm
    F = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
    if info[0] != 0:
        return x
    J = np.ascontiguousarray(F[nq : nq + m, :])
    P1, P2 = phi12(h * J)
    p1 = np.empty(nx)
    p2 = np.empty(nx)
    for i in range(nx):
        p1[i], p2[i] = phi12_scalar(h * diag[i])
    a = x + h * p1 * f0
    a[nq : nq + m] = x[nq : nq + m] + h * (P1 @ f0[nq : nq + m])
    f1 = _stage(P, ctx, t + h, a, sigma, ubar, fm, nz, info, u_h, v_h)
    if info[0] != 0:
        return x
    g = f1 - f0 - diag * (a - x)
    g[nq : nq + m] = f1[nq : nq + m] - f0[nq : nq + m] - J @ (a[nq : nq + m] - x[nq : nq + m])
    xn = a + h * p2 * g
    xn[nq : nq + m] = a[nq : nq + m] + h * (P2 @ g[nq : nq + m])
    return xn


@jit
def _delayed(mbuf, hold_t, q, eta):
    """The measurement of d = len(mbuf) - 1 samples before: ``mbuf`` is a ring of the last d + 1
    samples' [q, eta], ``hold_t[3]`` counts the samples; before the d-th, the first sample's."""
    nq = q.shape[0]
    d1 = mbuf.shape[0]
    c = int(hold_t[3])
    slot = c % d1
    mbuf[slot, :nq] = q
    mbuf[slot, nq:] = eta
    hold_t[3] = c + 1.0
    src = max(c - (d1 - 1), 0) % d1
    return mbuf[src, :nq].copy(), mbuf[src, nq:].copy()


@jit
def sample(P, ctx, t, x, sigma, ubar, fm, nz, info, hold_t, u_h, dx_h, sig_h, v_h, mbuf):
    """One sample of a discrete-time controller at t (sampled control, period T_s = hold_t[2]).

    The controller's state is advanced over the last sample by a forward-Euler step of its rates
    (held since that sample), then its discrete updates run, then the law: its u is held (zero-order
    hold) until the next sample, its rates and logged signals too, and with motors the driver's
    voltages.  Measurements: q + noise, eta + noise, taken ``len(mbuf) - 1`` samples before
    (:func:`_delayed`; the law and the driver both see them).
    """
    Kp, R, C, pc, nq, sat, nm = ctx[0], ctx[1], ctx[2], ctx[3], ctx[5], ctx[6], ctx[9]
    xc = x[nq + 2 + nm :]
    q = x[:nq] + nz[:nq]
    eta = x[nq : nq + 2] + nz[nq:]
    if mbuf.shape[0] > 1:
        q, eta = _delayed(mbuf, hold_t, q, eta)
    if not math.isnan(hold_t[1]):
        h = t - hold_t[1]
        for i in range(xc.shape[0]):
            # xc(t_j+1) = xc(t_j) + T_s xcdot(t_j)
            xc[i] += h * dx_h[i]
        KDISC(Kp, R, C, t, xc, info)
        if info[0] != 0:
            return
        _disc(P, Kp, R, C, pc, t, q, eta, xc, sigma, ubar, info)
        if info[0] != 0:
            return
    C.f[3] = 0.0
    st, ut = sigma, ubar
    if MOTORS:
        st, ut = true_faults(ctx, x, sigma, ubar, fm)
    u, dx = _law(P, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig_h)
    u_h[:] = u
    dx_h[: dx_h.shape[0] - dx.shape[0]] = 0.0
    dx_h[dx_h.shape[0] - dx.shape[0] :] = dx
    if MOTORS and nm > 0:
        us = u if math.isnan(sat) else _clip(u, -sat, sat)
        v_h[:] = _motors(ctx, x, sigma * us + ubar, fm, np.zeros(0), q, eta)[4]
    hold_t[0] = t + hold_t[2]
    hold_t[1] = t


@jit
def first_law(P, Kp, R, pc, t, q, eta, xc, sigma, ubar, info, sig):
    """The scheme's command at t (the motors' initial currents need it before the first step; the
    scheme checks call it too): u; the rates and signals are left in the law buffers ``P[1]``, and
    ``sig`` (when not empty) gets the logged row."""
    C = as_ref(KCACHE(pc.n))
    return _law(as_ref(P), as_ref(Kp), as_ref(R), C, as_ref(pc), t, q, eta, xc, sigma, ubar, info, sig)[0]


@jit
def first_discrete(P, Kp, R, pc, t, q, eta, xc, info):
    """The scheme's discrete update at t0 (a sampled scheme's first command)."""
    C = as_ref(KCACHE(pc.n))
    nw = 2 * pc.n
    z = np.zeros(nw)
    _disc(as_ref(P), as_ref(Kp), as_ref(R), C, as_ref(pc), t, q, eta, xc, z + 1.0, z, info)


@jit
def run_steps(
    P0, Kp0, R0, pc0, pp0,
    grid, fidx, fsig, fubar, noise, sat, diag, method, lim, max_speed, max_position,
    x, k0, k1, is_logged, li,
    lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lt, n_sig, info, share, grow, growth,
    lia, hold_t, u_h, dx_h, sig_h, mo0, fmot, v_h, mbuf,
):  # fmt: skip
    """Steps k0..k1 of a run (sim.simulate through fast.engine.simulate_compiled); returns (x, k, li, where).

    ``where`` says where an error stopped the loop (AT_STATE, AT_TRIAL, AT_DISCRETE).
    ``grow`` = [max |tau| at the previous step, streak length, max |tau| at the streak start]
    carries the step-growth detector (ftcreport.sim's docstring) across calls; ``growth`` = [GROWTH_FACTOR,
    GROWTH_STEPS, GROWTH_FLOOR, JUMP_FRACTION, sin(JUMP_MARGINS * margin), GROWTH_TOTAL] of ftcreport.sim.

    Sampled control when ``u_h`` is not empty: ``hold_t = [next sample time, last sample time (nan:
    none yet), T_s, samples taken]``; the law runs at the samples (:func:`sample`) and the plant
    integrates with its u held; ``u_h, dx_h, sig_h`` carry the held control, rates and signals
    across calls, ``mbuf`` the last d + 1 samples' measurements (a delay of d samples).

    DC motors when ``mo`` has wheels: the state is [q, eta, i_a, xc]; ``fmot`` holds the motor-fault
    table of each fault segment (fast.motor), ``v_h`` the held armature voltages.
    """
    # the parameter tuples behind one pointer each, for every kernel below (fast.refs)
    P, Kp, R, pc, pp, mo = as_ref(P0), as_ref(Kp0), as_ref(R0), as_ref(pc0), as_ref(pp0), as_ref(mo0)
    nq = pp.n + 2
    nx = x.shape[0]
    sig_buf = np.zeros(n_sig)
    C = as_ref(KCACHE(pp.n))
    nm = mo.R_a.shape[0]
    ctx = (Kp, R, C, pc, pp, nq, sat, share, mo, nm)
    npl = nq + 2 + nm  # the plant's states: q, eta, the motors' currents
    empty = np.zeros(0)
    noisy = noise.shape[0] > 1
    nz = noise[0]
    sampled = u_h.shape[0] > 0
    for k in range(k0, k1 + 1):
        t = grid[k]
        sigma = fsig[fidx[k]]
        ubar = fubar[fidx[k]]
        fm = fmot[fidx[k]]
        if MOTORS and nm > 0 and k > 0 and fidx[k] != fidx[k - 1]:  # a winding opened: its current drops to 0
            x[nq + 2 : npl] = reset_current(fm, x[nq + 2 : npl])
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
        if SAMPLED and sampled:
            if t >= hold_t[0] - 1e-9 * hold_t[2]:
                sample(P, ctx, t, x, sigma, ubar, fm, nz, info, hold_t, u_h, dx_h, sig_h, v_h, mbuf)
                if info[0] != 0:
                    return x, k, li, AT_STATE
            f0, u, tau = _plant_deriv(ctx, x, u_h, sigma, ubar, fm, v_h)
            sig_buf[:] = sig_h
        else:
            f0, u, tau = _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, sig_buf if want else empty)
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
            if MOTORS and nm > 0:  # the faults the chain sees (motor faults by their equivalents) and the currents
                lsig[li], lubar[li] = true_faults(ctx, x, sigma, ubar, fm)
                lia[li] = x[nq + 2 : npl]
            else:
                lsig[li] = sigma
                lubar[li] = ubar
            lxc[li] = x[npl:]
            if lmeas.shape[0] > 0:
                lmeas[li] = x[: nq + 2] + nz
            lsg[li] = sig_buf
            li += 1
        if k == grid.shape[0] - 1:
            return x, k, li, AT_STATE
        h = grid[k + 1] - t
        if method == 0:
            f2 = _stage(P, ctx, t + 0.5 * h, x + 0.5 * h * f0, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            f3 = _stage(P, ctx, t + 0.5 * h, x + 0.5 * h * f2, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            f4 = _stage(P, ctx, t + h, x + h * f3, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            xn = x + (h / 6.0) * (f0 + 2.0 * f2 + 2.0 * f3 + f4)
        elif method == 1:
            # W-method Jacobian: the columns of eta and the motors' currents (_jacobian_columns), the
            # stiff diagonal for the controller's linear filters (Sherman-Morrison-Woodbury solve)
            m = 2 + nm
            F = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            gh = ROS2_GAMMA * h
            dinv = 1.0 / (1.0 - gh * diag)
            DF = np.empty((nx, m))
            for i in range(nx):
                for j in range(m):
                    DF[i, j] = dinv[i] * F[i, j]
            small = np.empty((m, m))
            for i in range(m):
                for j in range(m):
                    small[i, j] = (1.0 if i == j else 0.0) - gh * DF[nq + i, j]
            rd = dinv * f0
            kk1 = rd + gh * (DF @ _solve_small(small, rd[nq : nq + m]))
            f2 = _stage(P, ctx, t + h, x + h * kk1, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            rd = dinv * (f2 - 2.0 * kk1)
            kk2 = rd + gh * (DF @ _solve_small(small, rd[nq : nq + m]))
            xn = x + 1.5 * h * kk1 + 0.5 * h * kk2
        if MOTORS and method == 2:  # the motor variant only (fast.engine.loop_for): others never compile ETD2
            xn = _etd2(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
        kind = _step_jump(pp, x, xn, nq, lim, max_speed, max_position, growth[3], growth[4], info)
        if kind != 0:
            info[0] = E_STEP_JUMP
            info[1] = kind
            return x, k, li, AT_TRIAL
        if SAMPLED and sampled:  # the controller's discrete updates run at its samples
            x = xn
            continue
        # discrete updates on the new state (xn is a new array: updated in place, it becomes the state)
        xcn = xn[npl:]
        KDISC(Kp, R, C, grid[k + 1], xcn, info)
        if info[0] != 0:
            return x, k, li, AT_DISCRETE
        _disc(P, Kp, R, C, pc, grid[k + 1], xn[:nq] + nz[:nq], xn[nq : nq + 2] + nz[nq:], xcn, sigma, ubar, info)
        if info[0] != 0:
            return x, k, li, AT_DISCRETE
        x = xn
    return x, k1, li, AT_STATE
