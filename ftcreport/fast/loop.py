r"""The closed loop, compiled once per scheme: the template of every scheme's loop.

``run_steps`` integrates the plant and the scheme's controller state over a range of steps, in
this order: checks, the law, the stream row, the step, the discrete updates (the stops and their
thresholds are in ftcreport.sim's docstring).  It calls the scheme's law and discrete update
through the globals ``LAW`` and ``DISC``, and the kinematic controller's part of every law (the
matched terms, the kinematic signals, its discrete update) through ``TERMS``, ``KEVAL``,
``KSIG``, ``KDISC`` and ``KCACHE``.  :func:`ftcreport.fast.engine.loop_for` writes, for each
scheme, a module that is this file with the line marked ``LOOP-BINDING`` importing that scheme's
law and the scheme interface's kernels (ftcreport.control.interface_compiled): numba compiles each such
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

from ftcreport.control.interface_compiled import engine_terms as TERMS
from ftcreport.control.interface_compiled import guards_intact, no_discrete, no_law, readonly
from ftcreport.control.interface_compiled import kinematic_discrete as KDISC
from ftcreport.control.interface_compiled import kinematic_eval as KEVAL
from ftcreport.control.interface_compiled import kinematic_event_time as KEVENT
from ftcreport.control.interface_compiled import kinematic_events as KEVENTS
from ftcreport.control.interface_compiled import kinematic_signals as KSIG
from ftcreport.control.interface_compiled import new_kinematic_cache as KCACHE
from ftcreport.fast.checks import _check_state, _finite, _step_jump
from ftcreport.fast.integrators import (
    DP_A,
    DP_B,
    DP_C,
    DP_E,
    ROSW_C,
    ROSW_GAMMA,
    erk_solution,
    erk_stage_point,
    error_ratio,
    etd2_dense,
    etd2_first,
    etd2_second,
    etd3_end,
    etd3_half,
    etd3_mid,
    etd3_phis,
    etd3_solution,
    first_guess,
    power_step,
    ros2_first,
    ros2_second,
    rosw_solution,
    rosw_stage,
    rosw_stage_point,
    starting_step,
    step_factor,
    w_factor,
)
from ftcreport.fast.loop_plant import _delayed, _drive_input, _drive_speeds, _motors, true_faults
from ftcreport.jit.compiling import jit
from ftcreport.jit.packed import (
    AT_DISCRETE,
    AT_STATE,
    AT_TRIAL,
    E_LAW_NONFINITE,
    E_LAW_RAISED,
    E_LAW_SIGNAL,
    E_LAW_WRITE,
    E_MIN_STEP,
    E_NONFINITE_DERIV,
    E_NONFINITE_STATE,
    E_STEP_GROWTH,
    E_STEP_JUMP,
    _clip,
    _mv,
    _solve2,
)
from ftcreport.jit.refs import as_ref
from ftcreport.model.compiled import plant_rhs
from ftcreport.model.drive_compiled import (
    DRIVER_PI,
    DRIVER_PI_SAMPLED,
    current_target,
    drive_jacobian,
    motor_state_count,
    pi_sample,
)
from ftcreport.model.motor_compiled import reset_current
from ftcreport.schemes.api import N_GUARD, Out, Step, Terms

LAW, DISC = no_law, no_discrete  # LOOP-BINDING

#: a round-2 law (13 positionals, returning (u, xcdot); ftcreport.schemes.registry.legacy), run through the
#: adapter in _law and _disc for one deprecation cycle, without the guards
LEGACY = False  # LOOP-LEGACY
#: how the matched terms reach the law (schemes.api.TERMS_MODES; fast.engine.loop_for writes the scheme's)
TERMS_MODE = 0  # LOOP-TERMS
#: a plug-in's law (not ftcreport's own): its logged signals are checked finite (E_LAW_SIGNAL), and (CATCH, a
#: real run's loop) an exception it raises (numba's boundscheck, which compiles every plug-in function:
#: jit.compiling.jit) stops the run as E_LAW_RAISED with its inputs recorded; the built-in laws' loops do not
#: compile either, 'schemes check's bounds-checked loop lets the exception through (it names the line)
PLUGIN, CATCH = False, False  # LOOP-PLUGIN
# the loop's variant (fast.engine.loop_for writes the case's): numba prunes the branches these close
# before typing, so a loop without motors or sampled control never compiles their kernels
MOTORS, SAMPLED = True, True  # LOOP-VARIANT


@jit
def _drive_tick(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h):
    """A sampled PI drive's sample at t (model.drive_compiled.pi_sample), in place on x's drive states.

    The current target: the one held at the last control sample (sampled control), or the law's
    command at t (continuous control); the drive measures its current and the wheel speeds now.
    """
    nq, sat, nm, dr = ctx[5], ctx[6], ctx[9], ctx[10]
    qm = x[:nq] + nz[:nq]
    etam = x[nq : nq + 2] + nz[nq:]
    om = _drive_speeds(ctx, qm, etam)
    if v_h.shape[0] > 0:
        i_star = v_h
    else:
        u = _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, np.zeros(0))[1]
        if info[0] != 0:
            return
        us = u if math.isnan(sat) else _clip(u, -sat, sat)
        i_star = current_target(dr, sigma * us + ubar, om)
    pi_sample(dr, x[nq + 2 : nq + 2 + nm], i_star, om, fm)


@jit
def _motor_columns(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h):
    """d(etadot, motor-state rates) / d(motor states) at x, exact (model.drive_compiled.drive_jacobian).

    The continuous PI's columns depend on whether its output saturates, so on its current target:
    held (sampled control), or from the law's command at x (one more evaluation of the law).
    """
    pp, nq, mo, nm, dr = ctx[4], ctx[5], ctx[8], ctx[9], ctx[10]
    nw = mo.R_a.shape[0]
    din = np.zeros(0)
    om = np.zeros(nw)
    if dr.kind == DRIVER_PI:  # the others' columns do not depend on their input
        if v_h.shape[0] > 0:  # sampled control holds i*; the drive reads the true speeds (_plant_deriv)
            om = _drive_speeds(ctx, x[:nq], x[nq : nq + 2])
            din = v_h
        else:  # continuous control: the measured state, as _deriv
            om = _drive_speeds(ctx, x[:nq] + nz[:nq], x[nq : nq + 2] + nz[nq:])
            u = _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, np.zeros(0))[1]
            sat = ctx[6]
            us = u if math.isnan(sat) else _clip(u, -sat, sat)
            din = current_target(dr, sigma * us + ubar, om)
    return drive_jacobian(pp, mo, dr, x[:nq], x[nq : nq + 2], x[nq + 2 : nq + 2 + nm], din, om, fm)


@jit
def _law(P, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig):
    """(u, dx): the scheme's command at (t, q, eta) (a copy) and its own states' rates (a view).

    The law is handed its parameters, the step (:class:`~ftcreport.schemes.api.Step`), the matched
    terms at the measured state (``TERMS_MODE`` 0), its own states read-only and views of the law
    buffers (``P[1]``) of exactly the declared sizes; the guard cells after them are checked after
    the call (E_LAW_WRITE: info[1] = 0 u, 1 dx, 2 sig; info[2] = t).  When ``sig`` is not empty the
    step is logged: the kinematic signals (of the law's own evaluation, else the engine's at the
    measured state) and then the law's, which a plug-in's must be finite (E_LAW_SIGNAL: info[1] = t,
    info[2] = the index into out.sig, info[3] = the value).
    """
    Pp, io = P
    if LEGACY:
        u, dx = _legacy_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig)
    else:
        u, dx = _contract_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig)
    if info[0] == 0:  # a non-finite command from a finite state stops here, named
        for j in range(u.shape[0]):
            # the inputs (xc: up to tens of thousands of adaptive weights) are scanned only for a bad command
            if not math.isfinite(u[j]) and _all_finite(q, eta, xc):
                info[0] = E_LAW_NONFINITE
                info[1] = t
                info[2] = j
                info[3] = u[j]
                break
    return u, dx


@jit
def _all_finite(q, eta, xc):
    """Whether the law's inputs are finite (a trial stage of a diverging step may not be: its NaN command is
    then the step's, which the step detectors name)."""
    for v in (q, eta, xc):
        for i in range(v.shape[0]):
            if not math.isfinite(v[i]):
                return False
    return True


@jit
def _contract_law(Pp, io, Kp, R, C, pc, t, q, eta, xc, st, ut, info, sig):
    """:func:`_law` for a law of the scheme API's contract."""
    k_v, ub, db, sb, _xb, fresh, rec = io
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
    if CATCH:
        try:
            LAW(Pp, step, terms, readonly(xc[nk:]), Out(u, dx, s))
        except Exception:  # numba catches no narrower class; Python runs the call again to name it
            _raised(rec, info, 0, t, q, eta, xc, st, ut)
            _record_terms(rec, q.shape[0] + 4 + xc.shape[0] + 2 * nw, terms.w, terms.MB, terms.g, terms.eta_e)
            return u.copy(), dx
    else:
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
        if PLUGIN:  # a logged step: a non-finite signal from finite inputs stops here, named (not stored as ok)
            for j in range(ns):
                if not math.isfinite(s[j]) and _all_finite(q, eta, xc):
                    info[0] = E_LAW_SIGNAL
                    info[1] = t
                    info[2] = j
                    info[3] = s[j]
                    return u.copy(), dx
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
def _raised(rec, info, which, t, q, eta, xc, st, ut):
    """A plug-in's law (``which`` 0) or discrete update (1) raised at t: E_LAW_RAISED, and its inputs in ``rec``
    (the law buffers' last, fast.engine.law_buffers: which, t, q, eta, xc, sigma, ubar, then the law's terms),
    from which Python runs it again to name the exception, the output, the index and the line
    (fast.stops.law_raised_reason)."""
    info[0] = E_LAW_RAISED
    info[1] = which
    info[2] = t
    info[3] = 0.0
    rec[0] = which
    rec[1] = t
    k = 2
    for v in (q, eta, xc, st, ut):
        n = v.shape[0]
        rec[k : k + n] = v
        k += n


@jit
def _record_terms(rec, k, w, MB, g, eta_e):
    """The law's terms after its inputs in ``rec`` (:func:`_raised`), from index k: w, MB by rows, g, eta_e."""
    rec[k : k + 2] = w
    k += 2
    for i in range(MB.shape[0]):
        for j in range(MB.shape[1]):
            rec[k] = MB[i, j]
            k += 1
    rec[k : k + 2] = g
    rec[k + 2 : k + 4] = eta_e


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
        if CATCH:
            try:
                DISC(Pp, Step(t, q, eta, st, ut, pc, info, (Kp, R, C, xc[:nk], fresh)), x)
            except Exception:  # as in _contract_law
                _raised(io[6], info, 1, t, q, eta, xc, st, ut)
                return
        else:
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

    ``ctx = (Kp, R, C, pc, pp, nq, sat, share, mo, nm, dr)``; ``share``: the controller's
    model is the plant's and there is no noise, so the reduced matrices the
    controller computed at (q, eta) are the plant's; ``nm``: the plant states the motors add
    after eta, their currents and their drives' states (model.drive_compiled.motor_state_count; 0: the
    ideal torque plant); ``dr`` the drives (model.drive_compiled.Drive).
    """
    Kp, R, C, pc, pp, nq, sat, share, _mo, nm, _dr = ctx
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
    """d f / d [eta, motor states] at x, (nx, 2 + nm): eta's columns by forward differences (2
    evaluations of the stage's rates), the motor states' (currents, drive states) exact
    (:func:`_motor_columns`: rows eta and the motor states; no other rate reads them)."""
    nq, nm = ctx[5], ctx[9]
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
        F[nq : nq + 2 + nm, 2:] = _motor_columns(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h)
    return F


@jit
def _plant_jacobian(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h):
    """d f / d [q, eta, i_a] at x, (nx, nq + 2 + nm): q's columns by forward differences (nq evaluations),
    then :func:`_jacobian_columns`' (ros2ec's W: fast.integrators' module docstring)."""
    nq = ctx[5]
    G = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
    F = np.zeros((x.shape[0], nq + G.shape[1]))
    if info[0] != 0:
        return F
    for j in range(nq):
        delta = 1e-7 * max(1.0, abs(x[j]))
        xp = x.copy()
        xp[j] += delta
        fp = _stage(P, ctx, t, xp, sigma, ubar, fm, nz, info, u_h, v_h)
        if info[0] != 0:
            return F
        F[:, j] = (fp - f0) / delta
    F[:, nq:] = G
    return F


@jit
def _etd2(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, mid):
    r"""(x+, x(t + h / 2) if ``mid`` else x): one ETD2RK step (Cox & Matthews 2002, J. Comput. Phys. 176,
    (22); Hochbruck & Ostermann 2010, (5.8)).

    x' = f(x) is split as L x + N(x), L linear: J, the Jacobian block of the rates of
    [eta, i_a] in [eta, i_a] (eta's columns by forward differences at x, 2 evaluations; the
    currents' exact, model.motor_compiled.current_jacobian), where the stiff
    modes live (the motors' L_a / R_a, the velocity loop); the controller's exact ``diag``
    (its linear filters, as for ROS2); zero elsewhere (q).  With the phi functions of h L::

        a  = x + h phi_1(h L) f(x)                        (= e^{hL} x + h phi_1 N(x))
        x+ = a + h phi_2(h L) (f(a) - f(x) - L (a - x))   (= ... + h phi_2 (N(a) - N(x)))

    Second order for any L, stiff order 2 (Hochbruck & Ostermann, Table 5.2); exact when f is
    linear and L its Jacobian, so a current's transient after each held-voltage step is
    integrated exactly however long the step: its torque impulse reaches eta in full.  With ``mid``
    also its continuous extension at the midpoint (fast.integrators.etd2_dense), for the metric stream.
    """
    nq, nm = ctx[5], ctx[9]
    m = 2 + nm
    F = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
    if info[0] != 0:
        return x, x
    J = np.ascontiguousarray(F[nq : nq + m, :])
    return _etd2_with(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, J, mid)


@jit
def _mid_torque(ctx, x, sigma, ubar, fm, u_h, v_h):
    """The wheel torques at a step's midpoint state x under sampled control (the plant's, the control
    and the drives' inputs held: no law call, so nothing the loop holds is touched)."""
    return _plant_deriv(ctx, x, u_h, sigma, ubar, fm, v_h)[2]


@jit
def _etd2_with(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, J, mid):
    """(x+, x(t + h / 2) if ``mid`` else x): one ETD2RK step (:func:`_etd2`) with its linear block J given
    (the algebra in fast.integrators)."""
    nq = ctx[5]
    a, P2, p2 = etd2_first(J, diag, x, f0, h, nq)
    f1 = _stage(P, ctx, t + h, a, sigma, ubar, fm, nz, info, u_h, v_h)
    if info[0] != 0:
        return x, x
    xn = etd2_second(J, diag, x, a, f0, f1, P2, p2, h, nq)
    if mid:
        return xn, etd2_dense(J, diag, x, a, f0, f1, h, 0.5, nq)
    return xn, x


@jit
def _ros2_with(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, F, ft):
    """One ROS2 step whose W holds the whole plant's columns F and the time derivative ft (``ros2ec``)."""
    kk1, DF, small, dinv = ros2_first(F, diag, f0, ft, h, 0)
    f2 = _stage(P, ctx, t + h, x + h * kk1, sigma, ubar, fm, nz, info, u_h, v_h)
    if info[0] != 0:
        return x
    kk2 = ros2_second(DF, small, dinv, kk1, f2, ft, h, 0)
    # x+ = x + 3/2 h k1 + 1/2 h k2
    return x + 1.5 * h * kk1 + 0.5 * h * kk2


@jit
def sample(P, ctx, t, x, sigma, ubar, fm, nz, info, hold_t, u_h, dx_h, sig_h, v_h, mbuf):
    """One sample of a discrete-time controller at t (sampled control, period T_s = hold_t[2]).

    The controller's state is advanced over the last sample by a forward-Euler step of its rates
    (held since that sample), then its discrete updates run, then the law: its u is held (zero-order
    hold) until the next sample, its rates and logged signals too, and with motors the driver's
    voltages (the PI drive's current targets).  Measurements: q + noise, eta + noise, taken
    ``len(mbuf) - 1`` samples before (:func:`_delayed`; the law and the driver both see them).
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
    if MOTORS and nm > 0:  # the drive's input of this sample: the static voltage or the PI's i*
        us = u if math.isnan(sat) else _clip(u, -sat, sat)
        v_h[:] = _drive_input(ctx, sigma * us + ubar, fm, _drive_speeds(ctx, q, eta))
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
def law_rows(P, Kp, R, pc, t, Q, ETA, XC, ST, UT, info, OUT):
    """:func:`first_law` at each row r of (Q, ETA, XC, ST, UT) in turn (an input of one row serves every
    row): the command in ``OUT[r, :nw]`` and, when OUT is wider, the own states' rates after it.  The
    linearized analysis's central differences (ftcreport.analysis.closed_loop) take many evaluations at
    one instant; one call for all of them saves each its entry from Python, which costs more than a
    small law.  Returns the rows done: all of them, or the row whose call stopped (info says why)."""
    Pr, Kr, Rr, pr = as_ref(P), as_ref(Kp), as_ref(R), as_ref(pc)
    none = np.zeros(0)
    m = OUT.shape[0]
    for r in range(m):
        C = as_ref(KCACHE(pc.n))  # a new kinematic cache per row, as first_law's per call
        u, dx = _law(
            Pr, Kr, Rr, C, pr, t, Q[r if Q.shape[0] > 1 else 0], ETA[r if ETA.shape[0] > 1 else 0],
            XC[r if XC.shape[0] > 1 else 0], ST[r if ST.shape[0] > 1 else 0], UT[r if UT.shape[0] > 1 else 0],
            info, none,
        )  # fmt: skip
        if info[0] != 0:
            return r
        nw = u.shape[0]
        OUT[r, :nw] = u
        if OUT.shape[1] > nw:
            OUT[r, nw:] = dx
    return m


@jit
def discrete_rows(P, Kp, R, pc, t, Q, ETA, XC, info):
    """:func:`first_discrete` on each row r of XC in place, at (Q[r], ETA[r]) (one row serves every row).
    Returns the rows done: all of them, or the row whose update stopped (info says why)."""
    Pr, Kr, Rr, pr = as_ref(P), as_ref(Kp), as_ref(R), as_ref(pc)
    nw = 2 * pc.n
    m = XC.shape[0]
    for r in range(m):
        C = as_ref(KCACHE(pc.n))
        z = np.zeros(nw)  # as first_discrete's per call: an update that writes its inputs spoils no other row
        _disc(Pr, Kr, Rr, C, pr, t, Q[r if Q.shape[0] > 1 else 0], ETA[r if ETA.shape[0] > 1 else 0], XC[r],
              z + 1.0, z, info)  # fmt: skip
        if info[0] != 0:
            return r
    return m


@jit
def run_steps(
    P0, Kp0, R0, pc0, pp0,
    grid, fidx, fsig, fubar, noise, sat, diag, method, lim, max_speed, max_position,
    x, k0, k1, is_logged, disc_on, li,
    lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lt, n_sig, info, share, grow, growth,
    lia, hold_t, u_h, dx_h, sig_h, mo0, fmot, v_h, mbuf, dr0,
):  # fmt: skip
    """Steps k0..k1 of a run (sim.simulate through fast.simulate.simulate_compiled); returns (x, k, li, where).

    ``where`` says where an error stopped the loop (AT_STATE, AT_TRIAL, AT_DISCRETE).
    ``grow`` = [max |tau| at the previous step, streak length, max |tau| at the streak start]
    carries the step-growth detector (ftcreport.sim's docstring) across calls; ``growth`` = [GROWTH_FACTOR,
    GROWTH_STEPS, GROWTH_FLOOR, JUMP_FRACTION, sin(JUMP_MARGINS * margin), GROWTH_TOTAL] of ftcreport.sim.

    Sampled control when ``u_h`` is not empty: ``hold_t = [next sample time, last sample time (nan:
    none yet), T_s, samples taken]``; the law runs at the samples (:func:`sample`) and the plant
    integrates with its u held; ``u_h, dx_h, sig_h`` carry the held control, rates and signals
    across calls, ``mbuf`` the last d + 1 samples' measurements (a delay of d samples).

    DC motors when ``mo`` has wheels: the state is [q, eta, i_a, drive states, xc]; ``fmot`` holds the
    motor-fault table of each fault segment (model.motor_compiled), ``dr0`` the drives (model.drive_compiled), ``v_h``
    the drive inputs held by sampled control; a sampled PI drive runs at ``hold_t[4]`` (its next
    sample time), period ``hold_t[5]``.
    """
    # the parameter tuples behind one pointer each, for every kernel below (jit.refs)
    P, Kp, R, pc, pp, mo, dr = as_ref(P0), as_ref(Kp0), as_ref(R0), as_ref(pc0), as_ref(pp0), as_ref(mo0), as_ref(dr0)
    nq = pp.n + 2
    nx = x.shape[0]
    sig_buf = np.zeros(n_sig)
    C = as_ref(KCACHE(pp.n))
    nm = motor_state_count(mo.R_a.shape[0], dr.kind)  # the one place: the plant states the motors add
    ctx = (Kp, R, C, pc, pp, nq, sat, share, mo, nm, dr)
    npl = nq + 2 + nm  # the plant's states: q, eta, the motors' currents and drive states
    empty = np.zeros(0)
    noisy = noise.shape[0] > 1
    nz = noise[0]
    sampled = u_h.shape[0] > 0
    empty_ft = np.zeros(nx)
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
        if SAMPLED and sampled and t >= hold_t[0] - 1e-9 * hold_t[2]:
            sample(P, ctx, t, x, sigma, ubar, fm, nz, info, hold_t, u_h, dx_h, sig_h, v_h, mbuf)
            if info[0] != 0:
                return x, k, li, AT_STATE
        if MOTORS and nm > 0 and dr.kind == DRIVER_PI_SAMPLED and t >= hold_t[4] - 1e-9 * hold_t[5]:
            _drive_tick(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h)  # after the control's sample
            if info[0] != 0:
                return x, k, li, AT_STATE
            hold_t[4] = t + hold_t[5]
        if SAMPLED and sampled:
            f0, u, tau = _plant_deriv(ctx, x, u_h, sigma, ubar, fm, v_h)
            sig_buf[:] = sig_h
        else:
            f0, u, tau = _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, sig_buf if want else empty)
        if info[0] != 0:
            return x, k, li, AT_STATE
        if not _finite(f0, u):
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
                lia[li, :nm] = x[nq + 2 : npl]
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
        # sampled control with motors: the stream also holds each step's torques at its midpoint (the
        # metrics' quadrature of the currents' transient after each held voltage step: evaluation.metrics)
        mid = MOTORS and nm > 0 and SAMPLED and sampled and want and lia.shape[1] > nm
        xm = x
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
            if mid:  # RK4's continuous extension at theta = 1/2 (third order): b = 5/24, 1/6, 1/6, -1/24
                xm = x + h * ((5.0 / 24.0) * f0 + (1.0 / 6.0) * (f2 + f3) - (1.0 / 24.0) * f4)
        elif method == 1:
            # W-method Jacobian: the columns of eta and the motors' currents (_jacobian_columns), the
            # stiff diagonal for the controller's linear filters (fast.integrators.ros2_first)
            F = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            # the shipped ROS2 leaves out the rates' time derivative (ros2ec has it, _attempt)
            kk1, DF, small, dinv = ros2_first(F, diag, f0, empty_ft, h, nq)
            f2 = _stage(P, ctx, t + h, x + h * kk1, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
            kk2 = ros2_second(DF, small, dinv, kk1, f2, empty_ft, h, nq)
            xn = x + 1.5 * h * kk1 + 0.5 * h * kk2
        if MOTORS and method == 2:  # the motor variant only (fast.engine.loop_for): others never compile ETD2
            xn, xm = _etd2(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, mid)
            if info[0] != 0:
                return x, k, li, AT_TRIAL
        kind = _step_jump(pp, x, xn, nq, lim, max_speed, max_position, growth[3], growth[4], info)
        if kind != 0:
            info[0] = E_STEP_JUMP
            info[1] = kind
            return x, k, li, AT_TRIAL
        if mid and method != 1:  # ROS2 has no interpolant here: its steps keep the trapezoid
            lia[li - 1, nm:] = _mid_torque(ctx, xm, sigma, ubar, fm, u_h, v_h)
        if SAMPLED and sampled:  # the controller's discrete updates run at its samples
            x = xn
            continue
        if not disc_on[k + 1]:  # a discrete-time filter (the UKF) runs on the sensor's ticks only
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


# =========================================================================== error-controlled steps
# ``opt`` (run_auto's settings, written by fast.auto_run._simulate_auto):
O_RTOL, O_ATOL, O_HMAX, O_HMIN, O_TEND, O_TCHUNK, O_CLOCK, O_T0, O_DWELL, O_TMIN, O_METHOD, O_CLOCK_DISC = range(12)
# ``ctl`` (its state, carried across calls; fast.engine reads the counts and the method):
C_T, C_H, C_RPREV, C_ACCEPTED, C_REJECTED, C_EVALS, C_SEG, C_REANCHOR, C_METHOD, C_RHO, C_CAUSE = range(11)
C_FORCED, C_FORCED_T, C_STREAK = 15, 16, 17  # steps taken at min_step over the tolerance, the first's t, in a row
#: etd3ec's linear block: accepted steps since its eta columns were taken (-1: take them at the next trial),
#: how many times they were taken, then the block as taken, (2 + nm) x (2 + nm) row by row
#: (fast.auto_run._auto_arrays sizes ctl for it)
C_JAGE, C_JTAKEN, C_JCOLS = 18, 19, 20
#: etd3ec takes the eta columns of its linear block again after this many accepted steps (_etd3_attempt)
JAC_REUSE = 10
#: ... or sooner, when the torque coupling (its eta rows of the motor columns, exact at every step) has moved
#: by more than this fraction of its size since: a single-step study (session 12) with the torque and
#: back-EMF couplings forming a stiff speed mode kept the estimate 4-9x above the error at 5 % stale and
#: brought it down to the error itself at 20 %; 1 % keeps the staleness well inside the safe side
COUPLING_DRIFT = 0.01
#: this many steps in a row at min_step with the error over the tolerance stop the run (E_MIN_STEP)
FORCED_STREAK = 100
#: stiffness: the real stability boundary of DOPRI5 (R(z) = 1 at z = -3.31 on the negative axis)
DOPRI5_REAL_BOUND = 3.3
#: auto picks the stiff method when rho h_max exceeds this: stability alone would hold DOPRI5 below a third
#: of the longest step.  Measured over 5 s of a two-link computed-torque loop (tests/test_step_unstable.py's):
#: k_v = 3000 at h_max = 5 ms (rho h_max = 18), DOPRI5 32,831 rate evaluations, ros2ec 19,008; k_v = 225 at
#: 20 ms (5.4), DOPRI5 4,145, ros2ec 12,302 (ros2ec costs 12 evaluations per step, DOPRI5 7)
STIFF_BOUND = 3.0 * DOPRI5_REAL_BOUND
#: a step whose trial stage leaves the domain (or jumps past a check) is retried this much shorter
REJECT_SHRINK = 0.25


@jit
def _attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, K, ctl, PH):
    """One trial step of an error-controlled method: (x+, err, rate evaluations, x(t + h / 2) or x itself when
    the method has none: DOPRI5); info set if a stage failed.

    3 = dopri5: the stages by fast.integrators.erk_stage_point, the solution and its embedded error by
    erk_solution.  4 = ros2ec, 5 = etd2ec: the step once and as two halves with the same linear part
    (W or L at x), err = (two halves - once) / 3, Richardson's estimate of the two halves' error (both
    second order: err = O(h^3)); the two halves are the solution.  An embedded first-order estimate
    (x + h k1, ETD1) is O(h^2): at rtol = 1e-6 it held the step of a k_v = 3000 loop to 0.35 ms, where
    the second-order solution is accurate at 5 ms.
    """
    nq, nm = ctx[5], ctx[9]
    if MOTORS and method == 6:
        return _etd3_attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, ctl, PH)
    if method == 7:
        return _rosw_attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, K)
    if method == 3:
        K[0] = f0
        for s in range(1, 7):
            y = erk_stage_point(x, K, s, h, DP_A)
            K[s] = _stage(P, ctx, t + DP_C[s] * h, y, sigma, ubar, fm, nz, info, u_h, v_h)
            if info[0] != 0:
                return x, x, s, x
        xn, err = erk_solution(x, K, h, DP_B, DP_E)
        return xn, err, 6, x
    # the linear part at x: ETD2's block J of [eta, i_a]; ROS2's W of the whole plant and f_t
    sampled = SAMPLED and u_h.shape[0] > 0
    J = np.zeros((0, 0))
    F = np.zeros((0, 0))
    ft = np.zeros(x.shape[0])
    if MOTORS and method == 5:
        G = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
        J = np.ascontiguousarray(G[nq : nq + 2 + nm, :])
        ev = 2
    else:
        F = _plant_jacobian(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
        ev = nq + 2
        if info[0] == 0 and not sampled:  # the law reads t (the reference): f_t by a forward difference
            dt = 1e-7 * max(1.0, abs(t))
            ft = (_stage(P, ctx, t + dt, x, sigma, ubar, fm, nz, info, u_h, v_h) - f0) / dt
            ev += 1
    if info[0] != 0:
        return x, x, ev, x
    one = _linear_step(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, J, F, ft)
    ev += 1
    if info[0] != 0:
        return x, x, ev, x
    half = 0.5 * h
    mid = _linear_step(P, ctx, t, half, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, J, F, ft)
    ev += 1
    if info[0] != 0:
        return x, x, ev, x
    fmid = _stage(P, ctx, t + half, mid, sigma, ubar, fm, nz, info, u_h, v_h)
    ev += 1
    if info[0] != 0:
        return x, x, ev, x
    two = _linear_step(P, ctx, t + half, half, mid, fmid, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, J, F, ft)
    ev += 1
    return two, (two - one) / 3.0, ev, mid


@jit
def _rosw_attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, K):
    r"""``ros34pw2``'s trial step: (x+, err, evaluations, x itself: no midpoint); info set if a stage failed.

    ROS34PW2 (fast.integrators: Rang & Angermann 2005), a Rosenbrock W-method: third order for any W,
    its error the embedded second order's (O(h^3)) from the same four stages, L-stable.  W holds the whole
    plant's columns (:func:`_plant_jacobian`, nq + 2 forward differences: q's carry the law's stiff coupling
    k_v d eta_c / dq, without which a stiff velocity loop's stages lag its moving equilibrium) and the
    controller's exact linear filters (``diag``); under continuous control the rates' time derivative f_t
    (one forward difference: the reference moves).  Three stage evaluations beside f(x) and the Jacobian's:
    nq + 6 evaluations a step with f(x) and f_t, against ros2ec's nq + 8 (step doubling) at one order more.
    Measured on two_link_switching (k4 = 3000, nominal, 25 s, longest step 50 ms): 5.2e-8 m from a tight
    reference at rtol = 1e-2 for 5,599 evaluations, where the fixed ROS2 at 5 ms reaches 3.8e-7 m for
    20,000 (README, "Accuracy against cost").
    """
    F = _plant_jacobian(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
    ev = ctx[5] + 2
    ft = np.zeros(x.shape[0])
    if info[0] == 0 and not (SAMPLED and u_h.shape[0] > 0):  # the law reads t: f_t by a forward difference
        dt = 1e-7 * max(1.0, abs(t))
        ft = (_stage(P, ctx, t + dt, x, sigma, ubar, fm, nz, info, u_h, v_h) - f0) / dt
        ev += 1
    if info[0] != 0:
        return x, x, ev, x
    DF, small, dinv = w_factor(F, diag, ROSW_GAMMA * h, 0)
    K[0] = rosw_stage(F, diag, DF, small, dinv, K, 0, f0, ft, h, 0)
    for i in range(1, 4):
        y = rosw_stage_point(x, K, i)
        fi = _stage(P, ctx, t + ROSW_C[i] * h, y, sigma, ubar, fm, nz, info, u_h, v_h)
        ev += 1
        if info[0] != 0:
            return x, x, ev, x
        K[i] = rosw_stage(F, diag, DF, small, dinv, K, i, fi, ft, h, 0)
    xn, err = rosw_solution(x, K)
    return xn, err, ev, x


@jit
def _etd3_attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, ctl, PH):
    """``etd3ec``'s trial step: ETD3RK with its embedded ETD2 (fast.integrators.etd3_solution) on the linear
    block of ETD2, 2 stages (2 evaluations) and f(x): (x+, err, evaluations, x(t + h / 2) by ETD2's continuous
    extension through the stage at t + h).

    The block's eta columns (2 evaluations, :func:`_jacobian_columns`) are kept in ``ctl`` and, under sampled
    control (auto's case for this method), used again for up to JAC_REUSE accepted steps (its motor columns,
    exact and free, are taken at x every step).  Any L splits f exactly (N = f - L x; exponential Runge-Kutta
    methods, unlike exponential Rosenbrock ones, do not need the exact Jacobian: Hochbruck & Ostermann 2010,
    "Exponential integrators", Acta Numerica 19): the step stays consistent, and its estimate is the embedded
    ETD2's error with this L.  A stale stiff entry
    (the back-EMF's coupling through the chain's geometry, which moves with q) puts a stiff term in N and
    lowers the solution's order as h shrinks.  On a slow speed mode the estimate still bounds the error by
    two orders of magnitude with the speed's column 20 % off (tests/test_integrators.py); where the torque
    and back-EMF couplings form a stiff speed mode (strong motors) a single-step study (session 12) kept it
    4-9x above the error at 5 % stale and brought it down to the error itself at 20 %.  So the block is
    taken again as soon as the torque coupling, exact at every step, has moved by COUPLING_DRIFT (1 %), as
    well as after a rejected step (run_auto sets ctl[C_JAGE] to -1) and at a new fault segment.  Measured
    (benchmarks/accuracy.py, the motor cases at rtol = 1e-2; README, "Accuracy against cost"): errors as
    small as with the block taken at every step (1.0e-7 m against 2.5e-7 m on three_link_adaptive_motors),
    at 3.2 evaluations a step against 5, and 0.45-0.83x the fixed ETD2's wall time against 1.08-1.17x.
    """
    nq, nm = ctx[5], ctx[9]
    m = 2 + nm
    ev = 0
    J = np.empty((m, m))
    # reused under sampled control only: the law is held there, so eta's columns carry the plant's own mild
    # terms and the back-EMF's coupling, while every stiff diagonal (the currents, a PI drive's states) is in
    # the exact motor columns; under continuous control eta's columns hold the law's -k_v, a stiff diagonal
    # whose staleness the estimate does not see (docs/ENGINE.md: Prothero-Robinson with L = 0.9 lambda)
    held = SAMPLED and u_h.shape[0] > 0
    fresh = not held or ctl[C_JAGE] < 0.0 or ctl[C_JAGE] >= JAC_REUSE
    if not fresh:
        for i in range(m):
            for j in range(m):
                J[i, j] = ctl[C_JCOLS + m * i + j]
        if nm > 0:
            # the motor columns at x; their rows of the motor states hold every stiff entry (the currents'
            # -R_a / L_a, a PI drive's gains as its saturation switches them): when those are the kept
            # block's exactly (the static driver: constant within a fault segment), the whole kept block
            # serves, its eta rows' torque coupling (which moves with q) as stale as its eta columns, and the
            # phi functions of the last step are taken again; else the motor columns at x.  The torque
            # coupling at x (free, in the motor columns) measures how far the geometry has moved: beyond
            # COUPLING_DRIFT of it the whole block is taken again (with the back-EMF's coupling in eta's
            # columns, it can make a stiff speed mode whose staleness the estimate would not see)
            Mc = _motor_columns(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h)
            same = True
            for i in range(2, m):
                for j in range(nm):
                    if Mc[i, j] != J[i, 2 + j]:
                        same = False
            drift, size = 0.0, 0.0
            for i in range(2):
                for j in range(nm):
                    drift = max(drift, abs(Mc[i, j] - J[i, 2 + j]))
                    size = max(size, abs(Mc[i, j]))
            if drift > COUPLING_DRIFT * size:
                fresh = True
            elif not same:
                J[:, 2:] = Mc
    if fresh:
        G = _jacobian_columns(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
        ev = 2
        if info[0] != 0:
            return x, x, ev, x
        J[:, :] = G[nq : nq + m, :]
        ctl[C_JTAKEN] += 1.0
        for i in range(m):
            for j in range(m):
                ctl[C_JCOLS + m * i + j] = J[i, j]
        ctl[C_JAGE] = 0.0
    Q1, Q2, q1, q2, P1, P2, P3, p1, p2, p3 = _etd3_phis_of(J, diag, h, PH)
    a = etd3_half(Q1, q1, x, f0, h, nq)
    fa = _stage(P, ctx, t + 0.5 * h, a, sigma, ubar, fm, nz, info, u_h, v_h)
    ev += 1
    if info[0] != 0:
        return x, x, ev, x
    b, Da = etd3_end(J, diag, x, a, f0, fa, P1, p1, h, nq)
    fb = _stage(P, ctx, t + h, b, sigma, ubar, fm, nz, info, u_h, v_h)
    ev += 1
    if info[0] != 0:
        return x, x, ev, x
    xn, err, Db = etd3_solution(J, diag, x, b, f0, fb, Da, P1, P2, P3, p1, p2, p3, h, nq)
    return xn, err, ev, etd3_mid(x, f0, Db, Q1, Q2, q1, q2, h, nq)


@jit
def _etd3_phis_of(J, diag, h, PH):
    """fast.integrators.etd3_phis(J, diag, h), taken from ``PH`` (matrices, vectors, their J, their h) when J
    and h are those it holds exactly, else computed and kept there: the same numbers either way."""
    M, V, JK, hk = PH
    same = hk[0] == h
    if same:
        for i in range(J.shape[0]):
            for j in range(J.shape[1]):
                if J[i, j] != JK[i, j]:
                    same = False
                    break
            if not same:
                break
    if not same:
        Q1, Q2, q1, q2, P1, P2, P3, p1, p2, p3 = etd3_phis(J, diag, h)
        M[0], M[1], M[2], M[3], M[4] = Q1, Q2, P1, P2, P3
        V[0], V[1], V[2], V[3], V[4] = q1, q2, p1, p2, p3
        JK[:, :] = J
        hk[0] = h
    return M[0], M[1], V[0], V[1], M[2], M[3], M[4], V[2], V[3], V[4]


@jit
def _linear_step(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, J, F, ft):
    """One ETD2 (method 5) or ROS2 (4) step with the linear part given."""
    if MOTORS and method == 5:
        return _etd2_with(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, J, False)[0]
    return _ros2_with(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, F, ft)


@jit
def _spectral_radius(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h):
    """(rho, evaluations): an estimate of the largest |eigenvalue| of the loop's Jacobian at (t, x).

    The nonlinear power method of fast.integrators.power_step from the direction of f0 (plus a
    small constant so that no mode starts at zero), 20 iterations, the largest of the last five
    ratios times 1.2 (RKC's safety factor); a stage outside the domain ends it early.
    """
    nx = x.shape[0]
    v = f0.copy()
    for i in range(nx):
        v[i] += 1e-3 * (1.0 + abs(f0[i]))
    v /= math.sqrt(np.sum(v * v))
    eps = 1e-7 * (1.0 + math.sqrt(np.sum(x * x)))
    rho = 0.0
    last = 0.0
    evals = 0
    for it in range(20):
        fv = _stage(P, ctx, t, x + eps * v, sigma, ubar, fm, nz, info, u_h, v_h)
        evals += 1
        if info[0] != 0:
            info[:] = 0.0
            break
        last, v = power_step(v, fv, f0, eps)
        if it >= 15:
            rho = max(rho, last)
    return 1.2 * max(rho, last), evals


@jit
def _next_event(events, seg, t, opt, hold_t, sampled, x, npl, ctl):
    """The first instant after t that a step must land on: a fault time, a sample, a tick of the clock
    (sensor noise, a discrete-time filter), the end of a switching dwell, the chained frame's
    re-anchoring (located by ``KEVENT``, the scheme interface's :func:`kinematic_event_time`), the run's end."""
    t_ev = opt[O_TEND]
    if ctl[C_REANCHOR] > t:
        t_ev = min(t_ev, ctl[C_REANCHOR])
    if seg < events.shape[0]:
        t_ev = min(t_ev, events[seg])
    if SAMPLED and sampled and hold_t[0] > t:
        t_ev = min(t_ev, hold_t[0])
    clock = opt[O_CLOCK]
    if not math.isnan(clock):  # the sensor's next draw
        j = math.floor((t - opt[O_T0]) / clock + 1e-9) + 1.0
        t_ev = min(t_ev, opt[O_T0] + j * clock)
    clock = opt[O_CLOCK_DISC]
    if clock > 0.0:  # a discrete-time filter's next tick (the UKF at dt)
        j = math.floor((t - opt[O_T0]) / clock + 1e-9) + 1.0
        t_ev = min(t_ev, opt[O_T0] + j * clock)
    if opt[O_DWELL] >= 0.0:
        end = x[npl + int(opt[O_DWELL])] + opt[O_TMIN]
        if end > t + 1e-12 * max(1.0, abs(t)):
            t_ev = min(t_ev, end)
    return t_ev


@jit
def run_auto(
    P0, Kp0, R0, pc0, pp0,
    events, fsig, fubar, noise, sat, diag, lim, max_speed, max_position,
    x, opt, ctl, rows,
    lq, leta, lu, ltau, lsig, lubar, lxc, lmeas, lsg, lt, n_sig, info, share,
    lia, hold_t, u_h, dx_h, sig_h, mo0, fmot, v_h, mbuf, growth, dr0,
):  # fmt: skip
    r"""Accepted steps of an error-controlled run, from t = ctl[C_T] to the chunk's end; returns (x, li, where).

    The order of each accepted step is run_steps': checks, the law, the stream row, the step, the
    discrete updates.  The step: h from the controller (fast.integrators.step_factor), clipped to
    the longest step and to the next instant it must land on (:func:`_next_event`: faults, samples,
    the clock of noise and discrete-time filters, dwell ends, the end); a trial step whose error
    ratio exceeds 1 is rejected and retried shorter, and one whose stage leaves the domain (or whose
    new state jumps past a check, fast.checks._step_jump) is retried at a quarter of its length.
    At the minimum step a step whose error estimate is still over the tolerance (a discontinuity of
    the rates inside it: the adaptive law's projection at its bounds) is taken and counted
    (ctl[C_FORCED]); FORCED_STREAK of them in a row, or a trial stage that leaves the domain at the
    minimum step, stop the run (E_MIN_STEP, the last rejection's cause in ctl[C_CAUSE:]).

    At the first step of ``method`` auto (opt[O_METHOD] < 0) the loop's spectral radius rho at
    (t0, x0) decides: stiff when rho h_max > STIFF_BOUND = 3 x 3.3, three times DOPRI5's stability
    boundary on the real axis (stability, not accuracy, would hold the explicit method below a third
    of its longest step): then ETD3RK (etd3ec) for motors whose voltages are held between samples (sampled
    control, or a PI drive sampled at its own rate), the Rosenbrock W-method ROS34PW2 otherwise; else DOPRI5.

    Logs every accepted step into the chunk buffers (``rows`` of them; the engine keeps the stream
    and the decimated log); returns when the buffers are full, past opt[O_TCHUNK], at the end
    (t = opt[O_TEND], its row logged) or at a stop (``where`` as in run_steps).
    """
    P, Kp, R, pc, pp, mo, dr = as_ref(P0), as_ref(Kp0), as_ref(R0), as_ref(pc0), as_ref(pp0), as_ref(mo0), as_ref(dr0)
    nq = pp.n + 2
    nx = x.shape[0]
    sig_buf = np.zeros(n_sig)
    C = as_ref(KCACHE(pp.n))
    nm = motor_state_count(mo.R_a.shape[0], dr.kind)  # the plant states the motors add (run_steps')
    ctx = (Kp, R, C, pc, pp, nq, sat, share, mo, nm, dr)
    pi_sampled = MOTORS and nm > 0 and dr.kind == DRIVER_PI_SAMPLED
    npl = nq + 2 + nm
    noisy = noise.shape[0] > 1
    nz = noise[0]
    sampled = u_h.shape[0] > 0
    K = np.zeros((7, nx))
    # etd3ec's phi functions of the last (h, L): a step of the same length on the same block takes them again
    # (the held-voltage motor block and a step pinned to the sample: most steps); this call's own, so that a
    # cache hit gives the numbers a recomputation would (no result depends on the chunks)
    mb = 2 + nm if MOTORS else 0
    PH = (np.zeros((5, mb, mb)), np.zeros((5, nx)), np.full((mb, mb), np.nan), np.full(1, np.nan))
    rtol, atol, h_max, h_min = opt[O_RTOL], opt[O_ATOL], opt[O_HMAX], opt[O_HMIN]
    t = ctl[C_T]
    seg = int(ctl[C_SEG])
    li = 0
    while True:
        if li >= rows or (li > 0 and t >= opt[O_TCHUNK]):
            ctl[C_T] = t
            return x, li, AT_STATE
        new_seg = seg
        while new_seg < events.shape[0] and t >= events[new_seg]:
            new_seg += 1
        if MOTORS and nm > 0 and new_seg != seg:  # a winding opened: its current drops to 0
            x[nq + 2 : npl] = reset_current(fmot[new_seg], x[nq + 2 : npl])
        if new_seg != seg:  # another plant: etd3ec's linear block is taken again
            ctl[C_JAGE] = -1.0
        seg = new_seg
        ctl[C_SEG] = seg
        sigma, ubar, fm = fsig[seg], fubar[seg], fmot[seg]
        if noisy:  # the sensor's draw of the clock tick at or before t
            nz = noise[min(math.floor((t - opt[O_T0]) / opt[O_CLOCK] + 1e-9), noise.shape[0] - 1)]
        for i in range(nx):
            if not math.isfinite(x[i]):
                info[0] = E_NONFINITE_STATE
                info[1] = t
                return x, li, AT_STATE
        _check_state(pp, x, nq, lim, max_speed, max_position, info)
        if info[0] != 0:
            return x, li, AT_STATE
        if SAMPLED and sampled and t >= hold_t[0] - 1e-9 * hold_t[2]:
            sample(P, ctx, t, x, sigma, ubar, fm, nz, info, hold_t, u_h, dx_h, sig_h, v_h, mbuf)
            if info[0] != 0:
                return x, li, AT_STATE
        if pi_sampled and t >= hold_t[4] - 1e-9 * hold_t[5]:
            _drive_tick(P, ctx, t, x, sigma, ubar, fm, nz, info, u_h, v_h)  # after the control's sample
            if info[0] != 0:
                return x, li, AT_STATE
            hold_t[4] = t + hold_t[5]
        if SAMPLED and sampled:
            f0, u, tau = _plant_deriv(ctx, x, u_h, sigma, ubar, fm, v_h)
            sig_buf[:] = sig_h
        else:
            f0, u, tau = _deriv(P, ctx, t, x, sigma, ubar, fm, nz, info, sig_buf)
        ctl[C_EVALS] += 1.0
        if info[0] != 0:
            return x, li, AT_STATE
        if not _finite(f0, u):
            info[0] = E_NONFINITE_DERIV
            info[1] = t
            return x, li, AT_STATE
        lt[li] = t
        lq[li] = x[:nq]
        leta[li] = x[nq : nq + 2]
        lu[li] = u
        ltau[li] = tau
        if MOTORS and nm > 0:
            lsig[li], lubar[li] = true_faults(ctx, x, sigma, ubar, fm)
            lia[li, :nm] = x[nq + 2 : npl]
        else:
            lsig[li] = sigma
            lubar[li] = ubar
        lxc[li] = x[npl:]
        if lmeas.shape[0] > 0:
            lmeas[li] = x[: nq + 2] + nz
        lsg[li] = sig_buf
        li += 1
        if t >= opt[O_TEND]:
            ctl[C_T] = t
            return x, li, AT_STATE
        if ctl[C_METHOD] < 0.0:  # the first step: the method (auto) and the starting step
            method = opt[O_METHOD]
            if method < 0.0:
                rho, ev = _spectral_radius(P, ctx, t, x, f0, sigma, ubar, fm, nz, info, u_h, v_h)
                ctl[C_EVALS] += ev
                ctl[C_RHO] = rho
                method = 3.0
                if rho * h_max > STIFF_BOUND:
                    # ETD3RK with its embedded ETD2 when the voltages are held between samples, the control's
                    # or a sampled PI drive's (the stiff currents linear there: 59k evaluations against
                    # ros34pw2's 4.1M on three_link_switching_pi under continuous control, test_auto); the
                    # Rosenbrock W-method ROS34PW2 (with the time derivative) otherwise
                    method = 6.0 if MOTORS and nm > 0 and (sampled or pi_sampled) else 7.0
            ctl[C_METHOD] = method
            h0 = min(first_guess(x, f0, rtol, atol), h_max)
            f1 = _stage(P, ctx, t + h0, x + h0 * f0, sigma, ubar, fm, nz, info, u_h, v_h)
            ctl[C_EVALS] += 1.0
            if info[0] != 0:
                info[:] = 0.0
                ctl[C_H] = h0
            else:
                order = 5.0 if method == 3.0 else (3.0 if method == 7.0 else 2.0)
                ctl[C_H] = starting_step(x, f0, f1, h0, order, rtol, atol)
        method = int(ctl[C_METHOD])
        # the chained frame re-anchors after the steps (continuous control, discrete updates every step)
        reanchors = KEVENTS(Kp) and not (SAMPLED and sampled) and opt[O_CLOCK_DISC] == 0.0
        k_err = 5.0 if method == 3 else 3.0  # err = O(h^k)
        beta = 0.04 if method == 3 else 0.0  # PI control for DOPRI5 (Hairer's code), elementary otherwise
        rejected = False
        while True:
            t_ev = _next_event(events, seg, t, opt, hold_t, sampled, x, npl, ctl)
            if pi_sampled and hold_t[4] > t:  # the sampled drive's next sample
                t_ev = min(t_ev, hold_t[4])
            h = min(max(ctl[C_H], h_min), h_max)
            land = t + h >= t_ev - 1e-12 * max(1.0, abs(t_ev))
            if land:
                h = t_ev - t
            elif t + 2.0 * h > t_ev:  # two equal steps to the event, not one long and one short
                h = 0.5 * (t_ev - t)
            xn, err, ev, xm = _attempt(P, ctx, t, h, x, f0, sigma, ubar, fm, nz, info, u_h, v_h, diag, method, K, ctl,
                                       PH)  # fmt: skip
            ctl[C_EVALS] += ev
            r = math.inf
            cause = 0
            if PLUGIN and (info[0] == E_LAW_RAISED or info[0] == E_LAW_WRITE):  # the law's fault: no shorter step
                ctl[C_T] = t
                return x, li, AT_TRIAL
            if info[0] != 0:
                cause = 1
            else:
                r = error_ratio(err, x, xn, rtol, atol)
                kind = _step_jump(pp, x, xn, nq, lim, max_speed, max_position, growth[3], growth[4], info)
                if kind != 0:
                    info[0] = E_STEP_JUMP
                    info[1] = kind
                    cause = 1
                elif r <= 1.0:
                    t_try = t_ev if land else t + h
                    if reanchors:  # a re-anchoring inside the step: land on it instead (not a rejection)
                        t_star = KEVENT(Kp, R, C, t, t_try, xn[npl], info)
                        if t_star < t_try:
                            ctl[C_REANCHOR] = t_star
                            continue
                    ctl[C_STREAK] = 0.0
                    break
            at_min = h <= h_min * (1.0 + 1e-9)
            if not cause and at_min and math.isfinite(r) and ctl[C_STREAK] < FORCED_STREAK:
                # the error estimate is over the tolerance at the minimum step: a discontinuity of the
                # rates inside the step (the adaptive law's projection, a bound), whose error is O(h jump):
                # the step is taken, counted and reported; FORCED_STREAK of them in a row stop the run
                ctl[C_FORCED] += 1.0
                if ctl[C_FORCED] == 1.0:
                    ctl[C_FORCED_T] = t
                ctl[C_STREAK] += 1.0
                break
            if cause:
                ctl[C_CAUSE : C_CAUSE + 4] = info
                info[:] = 0.0
                h_new = REJECT_SHRINK * h
            else:
                ctl[C_CAUSE] = 0.0
                ctl[C_CAUSE + 1] = r
                h_new = h * step_factor(r, ctl[C_RPREV], k_err, beta, True)
            ctl[C_REJECTED] += 1.0
            rejected = True
            if ctl[C_JAGE] != 0.0:  # etd3ec's block was not taken at x: fresh columns before a shorter step
                ctl[C_JAGE] = -1.0
            if h_new < h_min and at_min:
                info[0] = E_MIN_STEP
                info[1] = t
                info[2] = h_new
                ctl[C_T] = t
                return x, li, AT_TRIAL
            ctl[C_H] = max(h_new, h_min)  # the last try is at the minimum step itself
        t_new = t_ev if land else t + h
        if MOTORS and nm > 0 and SAMPLED and sampled and method != 3 and method != 7 and lia.shape[1] > nm:
            lia[li - 1, nm:] = _mid_torque(ctx, xm, sigma, ubar, fm, u_h, v_h)  # the first half ends there
        h_next = h * step_factor(r, ctl[C_RPREV], k_err, beta, rejected)
        if land and h < ctl[C_H]:  # a step cut short by an event does not shorten the next
            h_next = max(h_next, ctl[C_H])
        ctl[C_H] = h_next
        ctl[C_RPREV] = max(r, 1e-4)
        ctl[C_ACCEPTED] += 1.0
        if ctl[C_JAGE] >= 0.0:
            ctl[C_JAGE] += 1.0
        if not (SAMPLED and sampled):
            on_clock = True
            if opt[O_CLOCK_DISC] > 0.0:  # a discrete-time filter (the UKF) runs on its clock only
                tick = (t_new - opt[O_T0]) / opt[O_CLOCK_DISC]
                on_clock = abs(tick - round(tick)) <= 1e-9 * max(1.0, tick) or t_new >= opt[O_TEND]
            if on_clock:
                xcn = xn[npl:]
                KDISC(Kp, R, C, t_new, xcn, info)
                if info[0] != 0:
                    ctl[C_T] = t
                    return x, li, AT_DISCRETE
                # the scheme's update through its guarded buffer (run_steps' _disc)
                _disc(P, Kp, R, C, pc, t_new, xn[:nq] + nz[:nq], xn[nq : nq + 2] + nz[nq:], xcn, sigma, ubar, info)
                if info[0] != 0:
                    ctl[C_T] = t
                    return x, li, AT_DISCRETE
        x = xn
        t = t_new
