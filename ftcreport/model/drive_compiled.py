r"""Compiled wheel drives: torque command -> armature voltage, beside the motors of model/motor_compiled.py.

The controllers command wheel torques tau_c (thesis 2.3.3); a drive turns each into the voltage
across its motor's winding.  It knows the motor only through its own model (``Drive``: R_a, L_a,
k_m, k_b, N, eta_g, b_m per wheel; the plant's unless the case says otherwise, ``[actuators.drive_model]``)
and it knows no fault.  Wheel order 1r, 1l, 2r, ... as everywhere.

Current target (every driver)
-----------------------------
The torque command becomes a current by the motor's steady state, with the drag the drive
compensates (b_m here is b_m_compensation x the drive's b_m) at the measured wheel speed::

    i* = (tau_c / (eta_g N) + b_m N omega_w) / k_m,       clipped at +-I_max        (2.29) at rest

Static driver (``DRIVER_STATIC``, the default; today's driver)
--------------------------------------------------------------
A voltage-mode drive: the steady state of (2.28) inverted, no current feedback::

    v_a = R_a i* + k_b N omega_w,                            saturated at +-V_max

The current lags its target with the winding's L_a / R_a (0.44 ms for the defaults).  Under sampled
control the voltage of the sample is held, so between samples the back-EMF of the changing speed
moves the current away from i*.

PI current loop (``DRIVER_PI``, continuous; ``DRIVER_PI_SAMPLED``, at its own rate)
----------------------------------------------------------------------------------
A current-mode servo drive, the class of maxon's ESCON (its hardware reference: a PI current
controller sampled at 53.6 kHz, output voltage up to 0.98 of the supply, a peak current limit;
ESCON Module 50/5 Hardware Reference, rel9051, 2.1 Technical Data).  Per wheel, with the current
error e = i* - i_a and the integral part z [V]::

    u   = K_p e + z + c_ff k_b N omega_w          (c_ff = 1: back-EMF feedforward; default 0)
    v_a = sat(u) = min(max(u, -V_max), V_max)
    z'  = K_i e, but 0 while u is beyond a limit and e drives it further (conditional integration)

Gains by pole-zero cancellation, unless given: K_p = L_a 2 pi f, K_i = R_a 2 pi f (the drive's L_a,
R_a).  With the drive's model equal to the plant's and the voltage unsaturated, the PI's zero at
R_a / L_a cancels the winding's pole and the loop from i* to i_a is 2 pi f / (s + 2 pi f): a
first-order lag of time constant 1 / (2 pi f) (0.16 ms at f = 1 kHz).  The back-EMF enters as a
disturbance the integral part removes (no steady-state error for a constant speed).

Anti-windup: conditional integration (clamping; Astrom & Hagglund, Advanced PID Control, 2006,
3.5).  While the output saturates in the direction the error pushes, the integral holds, so when
the saturation ends (a lower target, a lower back-EMF) the integral part is not wound up and the
current reaches its target from below, without overshoot (tests/test_drive.py).  Chosen over
back-calculation because it adds no tracking time constant to choose and keeps z within what the
unsaturated loop needs.

``DRIVER_PI_SAMPLED`` (``drive_rate`` given): the same PI in discrete time at the drive's period
T_d, its voltage held between its samples (zero-order hold)::

    e_k = i*_k - i_a(t_k),   v_k = sat(K_p e_k + z_k + c_ff k_b N omega_k),   z_(k+1) = z_k + T_d K_i e_k

(forward Euler, with the same conditional integration).  The loop calls :func:`pi_sample` at the
drive's samples (fast.loop._drive_tick); between them the winding sees v_k.

Plant states the drives add (after the currents; ``x = [q, eta, i_a, drive states, xc]``): none for
the static driver, z per wheel for the continuous PI, z and the held v per wheel for the sampled
PI (:func:`motor_state_count`).  Stuck driver (motor fault mode 3): its output is v_stuck and its
integral holds.  Nothing here does I/O.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit.compiling import jit
from .motor_compiled import (
    F_KM,
    F_MODE,
    F_RA,
    F_VSTUCK,
    MODE_NORMAL,
    MODE_STUCK,
    _clip,
    current_jacobian,
    fault_equivalent,
    quasi_static_current,
)

__all__ = [
    "DRIVER_PI",
    "DRIVER_PI_SAMPLED",
    "DRIVER_STATIC",
    "Drive",
    "current_target",
    "drive_fault_equivalent",
    "drive_jacobian",
    "drive_output",
    "initial_motor_states",
    "motor_state_count",
    "pi_sample",
    "pi_voltage",
]

DRIVER_STATIC = 0
DRIVER_PI = 1
DRIVER_PI_SAMPLED = 2


class Drive(NamedTuple):
    """Per-wheel drive arrays ((nw,) each, wheel order) and the drive's kind (model.actuators.pack_drive)."""

    kind: int  # DRIVER_STATIC, DRIVER_PI or DRIVER_PI_SAMPLED
    R_a: np.ndarray  # the drive's model: armature resistance [ohm]
    L_a: np.ndarray  # inductance [H]
    k_m: np.ndarray  # torque constant [N m/A]
    k_b: np.ndarray  # back-EMF constant [V s/rad]
    N: np.ndarray  # gear ratio [-]
    eta_g: np.ndarray  # gear efficiency [-]
    b_m: np.ndarray  # the rotor drag it compensates [N m s/rad] (b_m_compensation x its b_m)
    K_p: np.ndarray  # PI proportional gain [V/A]
    K_i: np.ndarray  # PI integral gain [V/(A s)]
    V_max: np.ndarray  # output limit, the supply [V]
    I_max: np.ndarray  # current-target limit [A] (inf: none)
    ff: np.ndarray  # 1.0: back-EMF feedforward, 0.0: none
    T_d: float  # the sampled PI's period [s] (nan: continuous)


@jit
def motor_state_count(nw, kind):
    """How many plant states the motors and their drives add after eta: the currents and the drives' states."""
    return nw * (1 + (0 if kind == DRIVER_STATIC else (1 if kind == DRIVER_PI else 2)))


@jit
def current_target(dr, tau_c, omega_w):
    """i* = (tau_c / (eta_g N) + b_m N omega_w) / k_m clipped at +-I_max, with the drive's model, (nw,) [A]."""
    nw = tau_c.shape[0]
    out = np.empty(nw)
    for j in range(nw):
        N = dr.N[j]
        i_star = (tau_c[j] / (dr.eta_g[j] * N) + dr.b_m[j] * N * omega_w[j]) / dr.k_m[j]
        out[j] = _clip(i_star, dr.I_max[j])
    return out


@jit
def static_voltage(dr, i_star, omega_w, fault):
    """The static driver: v = R_a i* + k_b N omega_w saturated at +-V_max; v_stuck (saturated) when stuck."""
    nw = i_star.shape[0]
    v = np.empty(nw)
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_STUCK:
            v[j] = _clip(fault[j, F_VSTUCK], dr.V_max[j])
            continue
        v[j] = _clip(dr.R_a[j] * i_star[j] + dr.k_b[j] * dr.N[j] * omega_w[j], dr.V_max[j])
    return v


@jit
def _pi_law(dr, j, i_star, i_a, z, omega_w):
    """(u, e, integrate) of wheel j's PI: u = K_p e + z + c_ff k_b N omega, and whether z integrates."""
    e = i_star - i_a
    u = dr.K_p[j] * e + z
    if dr.ff[j] != 0.0:
        u += dr.k_b[j] * dr.N[j] * omega_w
    lim = dr.V_max[j]
    # conditional integration: hold z while the output is beyond a limit the error pushes it past
    hold = (u > lim and e > 0.0) or (u < -lim and e < 0.0)
    return u, e, not hold


@jit
def pi_voltage(dr, i_star, i_a, z, omega_w, fault):
    """The continuous PI: (v_a, z') per wheel, (nw,) each (module docstring); a stuck driver holds z."""
    nw = i_star.shape[0]
    v = np.empty(nw)
    zdot = np.zeros(nw)
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_STUCK:
            v[j] = _clip(fault[j, F_VSTUCK], dr.V_max[j])
            continue
        u, e, integrate = _pi_law(dr, j, i_star[j], i_a[j], z[j], omega_w[j])
        v[j] = _clip(u, dr.V_max[j])
        if integrate:
            # z' = K_i e
            zdot[j] = dr.K_i[j] * e
    return v, zdot


@jit
def pi_sample(dr, xm, i_star, omega_w, fault):
    """The sampled PI at one of its samples, in place on the motor states ``xm = [i_a, z, v_held]``.

    v_k = sat(K_p e_k + z_k + c_ff k_b N omega_k) is held until the next sample and
    z_(k+1) = z_k + T_d K_i e_k (held while saturated, as the continuous PI); a stuck driver
    holds v_stuck and z.
    """
    nw = i_star.shape[0]
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_STUCK:
            xm[2 * nw + j] = _clip(fault[j, F_VSTUCK], dr.V_max[j])
            continue
        u, e, integrate = _pi_law(dr, j, i_star[j], xm[j], xm[nw + j], omega_w[j])
        xm[2 * nw + j] = _clip(u, dr.V_max[j])
        if integrate:
            xm[nw + j] += dr.T_d * dr.K_i[j] * e


@jit
def drive_output(dr, xm, drive_in, omega_w, fault):
    """(v_a, rates of the drive's states) at the motor states ``xm``.

    ``drive_in``: the static driver's voltage, or the PI's current target i*; ``omega_w`` the
    drive's measured wheel speeds (read by the PI only with feedforward).  The sampled PI's voltage
    is its held state (its rates are 0: it changes at its samples only).
    """
    nw = fault.shape[0]
    if dr.kind == DRIVER_STATIC:
        return drive_in, np.zeros(0)
    if dr.kind == DRIVER_PI:
        return pi_voltage(dr, drive_in, xm[:nw], xm[nw : 2 * nw], omega_w, fault)
    return xm[2 * nw : 3 * nw].copy(), np.zeros(2 * nw)


@jit
def drive_jacobian(pc, mo, dr, q, eta, xm, drive_in, omega_w, fault):
    r"""d(etadot, motor-state rates) / d(motor states), (2 + nm, nm): exact, as model.motor_compiled.current_jacobian.

    Columns: the currents, then the drive's states.  The plant part is motor.current_jacobian (the
    plant is affine in i_a).  The continuous PI adds, on a wheel whose winding sees the drive
    (normal mode) with the output unsaturated, d i_dot / d i = -K_p / L_a and d i_dot / d z = 1 / L_a
    (v = K_p (i* - i) + z + ...), and d z' / d i = -K_i while z integrates; the sampled PI's held
    voltage gives d i_dot / d v_held = 1 / L_a.  Nothing else reads a drive state.  At the saturation
    limit itself the one-sided derivative of the side the clamping is on is taken (a set of measure 0).
    """
    nw = fault.shape[0]
    nm = xm.shape[0]
    out = np.zeros((2 + nm, nm))
    out[: 2 + nw, :nw] = current_jacobian(pc, mo, q, eta, fault)
    if dr.kind == DRIVER_STATIC:
        return out
    for j in range(nw):
        mode = int(fault[j, F_MODE])
        if mode == MODE_STUCK:
            continue
        reaches = mode == MODE_NORMAL  # the winding sees the drive's voltage
        if dr.kind == DRIVER_PI:
            u, _e, integrate = _pi_law(dr, j, drive_in[j], xm[j], xm[nw + j], omega_w[j])
            if reaches and abs(u) < dr.V_max[j]:
                out[2 + j, j] -= dr.K_p[j] / mo.L_a[j]
                out[2 + j, nw + j] = 1.0 / mo.L_a[j]
            if integrate:
                out[2 + nw + j, j] = -dr.K_i[j]
        elif reaches:
            out[2 + j, 2 * nw + j] = 1.0 / mo.L_a[j]
    return out


@jit
def _same_model(mo, dr, j):
    """The drive's static model of wheel j is the plant's (L_a does not enter the steady state)."""
    return (
        dr.R_a[j] == mo.R_a[j] and dr.k_m[j] == mo.k_m[j] and dr.k_b[j] == mo.k_b[j] and dr.N[j] == mo.N[j]
        and dr.eta_g[j] == mo.eta_g[j] and dr.b_m[j] == mo.b_m[j]
    )  # fmt: skip


@jit
def drive_fault_equivalent(mo, dr, fault, omega_w):
    r"""Quasi-static (sigma, ubar) of each wheel's drive and motor against the ideal torque plant, (2.102).

    As model.motor_compiled.fault_equivalent (the static driver with the plant's own model: that function's
    numbers, bit for bit), extended to a drive whose model differs from the plant's (hats) and to
    the PI drive.  With g N = eta_g N, i* = (tau_c / (g_h N_h) + b_h N_h omega) / k_h and a winding
    in normal mode (k_m, k_b scaled by s, R_a by rho):

    * static: i = (R_h i* + k_bh N_h omega - s k_b N omega) / (rho R_a), so
      sigma = (g N / (g_h N_h)) (s / rho) (k_m / k_h) (R_h / R_a),
      ubar = g N omega [s k_m (R_h b_h N_h / k_h + k_bh N_h - s k_b N) / (rho R_a) - b_m N];
    * PI (unsaturated, steady state: i = i*, whatever rho and the back-EMF):
      sigma = (g N / (g_h N_h)) s k_m / k_h,  ubar = g N omega (s k_m b_h N_h / k_h - b_m N).

    So a PI drive hides a resistance fault entirely, and a drive that compensates less drag than
    the rotor has (b_h < b_m) leaves a healthy wheel with ubar = -g N^2 (b_m - b_h) omega.  Open,
    short and stuck windings do not depend on the drive (model.motor_compiled.fault_equivalent).  None holds
    while a drive saturates.
    """
    sigma, ubar = fault_equivalent(mo, fault, omega_w)
    for j in range(omega_w.shape[0]):
        if int(fault[j, F_MODE]) != MODE_NORMAL or not math.isfinite(omega_w[j]):
            continue
        if dr.kind == DRIVER_STATIC and _same_model(mo, dr, j):
            continue
        s = fault[j, F_KM]
        rho = fault[j, F_RA]
        gN = mo.eta_g[j] * mo.N[j]
        gNh = dr.eta_g[j] * dr.N[j]
        w = omega_w[j]
        km, kh = mo.k_m[j], dr.k_m[j]
        if dr.kind == DRIVER_STATIC:
            sigma[j] = (gN / gNh) * (s / rho) * (km / kh) * (dr.R_a[j] / mo.R_a[j])
            drive = dr.R_a[j] * dr.b_m[j] * dr.N[j] / kh + dr.k_b[j] * dr.N[j] - s * mo.k_b[j] * mo.N[j]
            ubar[j] = gN * w * (s * km * drive / (rho * mo.R_a[j]) - mo.b_m[j] * mo.N[j])
        else:
            ratio = s * (km / kh)  # 1.0 exactly for a healthy wheel and the plant's k_m
            sigma[j] = (gN / gNh) * ratio
            ubar[j] = gN * w * (ratio * dr.b_m[j] * dr.N[j] - mo.b_m[j] * mo.N[j])
    return sigma, ubar


@jit
def initial_motor_states(mo, dr, tau_c, omega_w, fault):
    """The motor states at t0 for the first command: quasi-static, so the first torque is the command.

    Static: the currents of the first voltage (model.motor_compiled.quasi_static_current).  PI: the loop's
    steady state for the first current target (:func:`pi_steady_states`).
    """
    i_star = current_target(dr, tau_c, omega_w)
    if dr.kind == DRIVER_STATIC:
        return quasi_static_current(mo, static_voltage(dr, i_star, omega_w, fault), omega_w, fault)
    return pi_steady_states(mo, dr, i_star, omega_w, fault)


@jit
def pi_steady_states(mo, dr, i_star, omega_w, fault):
    """A PI drive's motor states in steady state for the current target ``i_star`` at wheel speeds ``omega_w``.

    i = i* where the supply allows (v0 = rho R_a i* + s k_b N omega within +-V_max, else i the
    current of the saturated v0) and z = v0 - c_ff k_b N omega (its output is v0 when e = 0;
    beyond a limit the error keeps it there); the sampled PI holds v0.  The start of a run
    (:func:`initial_motor_states`) and the operating points of the linearized analysis.
    """
    nw = i_star.shape[0]
    v0 = np.empty(nw)
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_STUCK:
            v0[j] = _clip(fault[j, F_VSTUCK], dr.V_max[j])
            continue
        R = fault[j, F_RA] * mo.R_a[j]
        v0[j] = _clip(R * i_star[j] + fault[j, F_KM] * mo.k_b[j] * mo.N[j] * omega_w[j], dr.V_max[j])
    xm = np.zeros(motor_state_count(nw, dr.kind))
    xm[:nw] = quasi_static_current(mo, v0, omega_w, fault)
    for j in range(nw):
        xm[nw + j] = v0[j] - dr.ff[j] * dr.k_b[j] * dr.N[j] * omega_w[j]
        if dr.kind == DRIVER_PI_SAMPLED:
            xm[2 * nw + j] = v0[j]
    return xm
