"""The plant side of the closed loop, the same for every law: the motors and their drive on the wheels,
the faults the chain sees, the measurement delay.

Compiled once and linked into every generated loop (``fast/loop.py``); ``ctx`` is the loop's context
tuple ``(Kp, R, C, pc, pp, nq, sat, share, mo, nm, dr)`` (``fast/loop.run_steps`` documents it): here
``pc``, ``pp`` the controller's and the plant's chain, ``nq`` the length of q, ``sat`` the torque
limit, ``mo`` the motors, ``nm`` the plant states the motors add (0: the ideal torque plant), ``dr``
the drives.
"""

from __future__ import annotations

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import _mv
from ..model.compiled import reduced
from ..model.drive_compiled import (
    DRIVER_PI_SAMPLED,
    DRIVER_STATIC,
    current_target,
    drive_fault_equivalent,
    drive_output,
    static_voltage,
)
from ..model.motor_compiled import motor_plant_rhs


@jit
def _drive_speeds(ctx, qm, etam):
    """The drive's wheel speeds: Bbar(q)^T eta at the measured state (the controller's chain model)."""
    Bm = reduced(ctx[3], qm, etam)[3]
    return _mv(Bm.T, etam)


@jit
def _drive_input(ctx, tau_c, fm, om):
    """What a drive makes of the commanded torques at its measured wheel speeds ``om`` (held under
    sampled control): the static driver's voltage (model.drive_compiled.static_voltage of the current
    target), or the PI's current target i* (model.drive_compiled.current_target)."""
    dr = ctx[10]
    i_star = current_target(dr, tau_c, om)
    if dr.kind == DRIVER_STATIC:
        return static_voltage(dr, i_star, om, fm)
    return i_star


@jit
def _reads_speed(dr):
    """A PI drive with back-EMF feedforward reads the wheel speeds between control samples too."""
    return dr.kind != DRIVER_STATIC and dr.ff.shape[0] > 0 and dr.ff.max() != 0.0


@jit
def _motors(ctx, x, tau_c, fm, v_h, qm, etam):
    """(qdot, etadot, motor-state rates, tau_w, v_a) of the chain driven by its DC motors and drives.

    The plant is (2.26)-(2.29) with E19 (model.motor_compiled.motor_plant_rhs); the motor states after eta are
    the currents and the drives' states (model.drive_compiled).  The drive turns the commanded torques tau_c
    at the measured wheel speeds into its input (:func:`_drive_input`), or holds ``v_h`` (sampled
    control: the static driver's voltage, the PI's current target), and its output into v_a.
    """
    pp, nq, mo, nm, dr = ctx[4], ctx[5], ctx[8], ctx[9], ctx[10]
    nw = mo.R_a.shape[0]
    xm = x[nq + 2 : nq + 2 + nm]
    held = dr.kind == DRIVER_PI_SAMPLED or v_h.shape[0] > 0
    om = _drive_speeds(ctx, qm, etam) if not held or _reads_speed(dr) else np.zeros(nw)
    if dr.kind == DRIVER_PI_SAMPLED:  # its own samples hold its voltage (_drive_tick)
        din = np.zeros(0)
    elif v_h.shape[0] > 0:
        din = v_h
    else:
        din = _drive_input(ctx, tau_c, fm, om)
    v, ddot = drive_output(dr, xm, din, om, fm)
    qdot, etadot, idot, tau_w = motor_plant_rhs(pp, mo, x[:nq], x[nq : nq + 2], xm[:nw], v, fm)
    if nm == nw:
        return qdot, etadot, idot, tau_w, v
    xmdot = np.empty(nm)
    xmdot[:nw] = idot
    xmdot[nw:] = ddot
    return qdot, etadot, xmdot, tau_w, v


@jit
def true_faults(ctx, x, sigma, ubar, fm):
    """The (sigma, ubar) the chain sees: the command faults composed with the motors' equivalents.

    tau_w ~ s_m (sigma u + ubar) + u_m, so sigma_true = s_m sigma, ubar_true = s_m ubar + u_m
    (model.drive_compiled.drive_fault_equivalent at the wheel speeds of x: the motors' faults, and what the
    drive's model of a healthy motor gets wrong); without motors, (sigma, ubar).
    """
    if ctx[9] == 0:
        return sigma, ubar
    pp, nq = ctx[4], ctx[5]
    Bb = reduced(pp, x[:nq], x[nq : nq + 2])[3]
    sm, um = drive_fault_equivalent(ctx[8], ctx[10], fm, _mv(Bb.T, x[nq : nq + 2]))
    return sm * sigma, sm * ubar + um


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
