r"""Compiled DC motor per wheel: the plant of thesis section 2.3.3, its driver and its faults.

Each driven wheel j (order 1r, 1l, 2r, 2l, ..., as ``model.faults.wheel_names``) has an
armature-controlled brushed DC motor behind a gear of ratio N and efficiency eta_g, thesis
(2.26)-(2.29) with ERRATA E19:

    L_a di/dt = v_a - R_a i - k_b omega_m,           omega_m = N omega_w       (2.28), (2.27)
    J_m domega_m/dt = k_m i - tau_l - b_m omega_m                              (2.29)
    tau_w = eta_g N tau_l                                                      (gear, E19)

The wheel speeds come from the chain's state, omega_w = Bbar(q)^T eta (virtual work, as
``model.compiled.wheel_speeds_rows``).  The rotor inertia seen on the wheel axis makes the chain's
equation implicit: with

    tau_w = eta_g N k_m i - eta_g N^2 b_m omega_w - eta_g N^2 J_m domega_w/dt,
    domega_w/dt = Bbar^T etadot + Bbardot^T eta,

(2.70) ``Mbar1 etadot = Bbar tau_w - Mbar2 eta - Cbar`` becomes the 2 x 2 system

    (Mbar1 + Bbar Jw Bbar^T) etadot = Bbar (eta_g N k_m i - eta_g N^2 b_m omega_w - Jw Bbardot^T eta)
                                      - Mbar2 eta - Cbar,       Jw = diag(eta_g N^2 J_m),

solved exactly (:func:`motor_plant_rhs`).  Its matrix is symmetric positive definite (Mbar1 is,
Jw >= 0).  Bbardot = Sdot^T B + S^T Bdot along qdot = S eta (:func:`bbar_and_rate`).

The gear model ``tau_w = eta_g N tau_l`` holds in both directions of power flow, so when the wheel
drives the motor the "gear loss" (1 - eta_g) tau_l omega_m is negative.  That is the model of E19,
kept as it is; the power balance (tests/test_motor.py) holds as an identity either way.

Driver (command -> voltage): the static inversion
-------------------------------------------------
The drives (the static inversion, a PI current loop, each with its own model of the motor) are in
model/drive_compiled.py; :func:`driver_voltage` here is the static driver with the plant's own model, the
default drive (model.drive_compiled.static_voltage gives its bits when the drive's model is the plant's).
The controllers command wheel torque tau_c, as in the thesis.  :func:`driver_voltage` inverts the
motor's steady state with its nominal parameters (it knows no fault):

    i* = (tau_c / (eta_g N) + b_m N omega_w) / k_m,    clipped at +-I_max
    v_a = R_a i* + k_b N omega_w,                       saturated at +-V_max

The b_m term compensates the rotor's viscous friction (measured speed, datasheet b_m), so that the
quasi-static wheel torque is exactly tau_c: the healthy motor plant then tends to today's ideal plant
as L_a -> 0, apart from the rotor inertia eta_g N^2 J_m, which is not compensated (a real plant has
it; the controllers' M(q) does not).  There is no current feedback: with L_a > 0 the current lags its
target with the time constant L_a / R_a, and I_max limits the target current, not the transient
current.

Faults, per wheel: a table ``fault`` of shape (nw, 4)
------------------------------------------------------
Columns ``[k_m scale s, R_a scale rho, mode, v_stuck]``; healthy is ``[1, 1, 0, 0]``
(:func:`healthy_faults`).  The loop keeps one table per fault segment, as for sigma/ubar.

* s < 1: partial loss of the torque constant (demagnetisation, flux loss): k_m and k_b are both
  scaled by s, because both are the same flux linkage (k_m = k_b in SI units).
* rho > 1: increased winding resistance (R_a scaled).
* mode 1, open circuit: i = 0, no electromagnetic torque; the current is held at 0 (i_dot = 0).
  The state must be 0 when the fault starts: :func:`reset_current` does it at a segment start
  (the energy L_a i^2 / 2 is lost in the arc at the opening).
* mode 2, shorted winding: v_a = 0 across the winding whatever the driver does; in steady state
  i = -k_b omega_m / R_a, a braking torque -k_m k_b omega_m / R_a at the motor shaft.
* mode 3, driver stuck at v_stuck (saturated at +-V_max): applied by the driver and by the plant
  (so a fault starting between control samples acts at once).

Quasi-static (sigma, ubar) equivalents: :func:`fault_equivalent`.  Nothing here does I/O.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit.compiling import jit
from ..jit.packed import _mv, _solve2
from .compiled import bbar_rate, reduced, rotor_mass

MODE_NORMAL = 0
MODE_OPEN = 1
MODE_SHORT = 2
MODE_STUCK = 3

# columns of a fault table
F_KM = 0
F_RA = 1
F_MODE = 2
F_VSTUCK = 3


class Motors(NamedTuple):
    """Per-wheel motor parameters, each a (nw,) float array in wheel order (1r, 1l, 2r, ...)."""

    R_a: np.ndarray  # armature resistance [ohm]
    L_a: np.ndarray  # armature inductance [H], > 0
    k_m: np.ndarray  # torque constant [N m/A]
    k_b: np.ndarray  # back-EMF constant [V s/rad]
    N: np.ndarray  # gear ratio omega_m / omega_wheel [-]
    eta_g: np.ndarray  # gear efficiency [-]
    J_m: np.ndarray  # rotor inertia [kg m^2]
    b_m: np.ndarray  # rotor viscous damping [N m s/rad]
    V_max: np.ndarray  # supply voltage [V]
    I_max: np.ndarray  # target-current limit [A] (inf: none)


def healthy_faults(nw: int) -> np.ndarray:
    """The fault table of healthy motors, (nw, 4): rows ``[1, 1, 0, 0]``."""
    out = np.zeros((nw, 4))
    out[:, F_KM] = 1.0
    out[:, F_RA] = 1.0
    return out


@jit
def bbar_and_rate(p, q, eta):
    r"""(Bbar, Bbardot): Bbar = S^T B (2.74) and d/dt Bbar = Sdot^T B + S^T Bdot along qdot = S eta.

    Both (2, nw).  Bdot: the entries of B (C.8) are cos/sin of headings and of heading differences
    over r_i, so their rates are the thetadot of S eta (2.63)-(2.64) times the other function.
    """
    _M1, _M2, _C, Bbar, S, Sd = reduced(p, q, eta)
    return Bbar, bbar_rate(p, q, eta, S, Sd)


@jit
def _clip(x, lim):
    return min(max(x, -lim), lim)


@jit
def winding_voltage(mo, v_a, fault):
    """Voltage across each winding: the driver's v_a, 0 on a short, v_stuck (saturated) when stuck."""
    nw = v_a.shape[0]
    out = np.empty(nw)
    for j in range(nw):
        mode = int(fault[j, F_MODE])
        if mode in (MODE_SHORT, MODE_OPEN):
            out[j] = 0.0
        elif mode == MODE_STUCK:
            out[j] = _clip(fault[j, F_VSTUCK], mo.V_max[j])
        else:
            out[j] = v_a[j]
    return out


@jit
def rotor_inertia_wheel(mo):
    """eta_g N^2 J_m per wheel [kg m^2]: the rotor inertia seen on the wheel axis (ERRATA E19)."""
    return mo.eta_g * mo.N * mo.N * mo.J_m


@jit
def motor_plant_rhs(pc, mo, q, eta, i_a, v_a, fault):
    r"""Chain + motors: (qdot, etadot, i_dot, tau_w), thesis (2.28)-(2.29), (2.70) with E19.

    Parameters
    ----------
    pc : jit.packed.Chain
    mo : Motors
    q : (n + 2,) ndarray
        Configuration [x_n, y_n, theta_n, ..., theta_1] (as kernels.reduced).
    eta : (2,) ndarray
        [v_n, omega_1].
    i_a : (nw,) ndarray
        Armature currents [A], wheel order.
    v_a : (nw,) ndarray
        Driver output voltages [V] (held between control samples); ignored on open/short/stuck wheels.
    fault : (nw, 4) ndarray
        Fault table ``[k_m scale, R_a scale, mode, v_stuck]`` per wheel.

    Returns
    -------
    qdot : (n + 2,) ndarray
        S(q) eta.
    etadot : (2,) ndarray
        From the implicit (2.70) with the rotor inertias on the wheel axes (module docstring).
    i_dot : (nw,) ndarray
        (v - R i - k_b N omega_w) / L_a with the faulted R, k_b; 0 on an open winding.
    tau_w : (nw,) ndarray
        Wheel torques [N m], eta_g N tau_l.
    """
    nw = 2 * pc.n
    Mbar1, Mbar2, Cbar, Bbar, S, Sd = reduced(pc, q, eta)
    Bbd = bbar_rate(pc, q, eta, S, Sd)
    v = winding_voltage(mo, v_a, fault)
    Jw = rotor_inertia_wheel(mo)
    # (Mbar1 + Bbar Jw Bbar^T) etadot = Bbar (tau0 - Jw Bbardot^T eta) - Mbar2 eta - Cbar
    A = rotor_mass(Mbar1, Bbar, Jw)
    rhs = -_mv(Mbar2, eta) - Cbar
    i_dot = np.zeros(nw)
    tau0 = np.empty(nw)  # wheel torque without the rotor-inertia term
    wdot0 = np.empty(nw)  # Bbardot^T eta
    for j in range(nw):
        s = fault[j, F_KM]
        R = fault[j, F_RA] * mo.R_a[j]
        mode = int(fault[j, F_MODE])
        omega_w = Bbar[0, j] * eta[0] + Bbar[1, j] * eta[1]
        gN = mo.eta_g[j] * mo.N[j]
        if mode == MODE_OPEN:
            i = 0.0
        else:
            i = i_a[j]
            # L_a di/dt = v - R_a i - k_b N omega_w                       (2.28)
            i_dot[j] = (v[j] - R * i - s * mo.k_b[j] * mo.N[j] * omega_w) / mo.L_a[j]
        # eta_g N (k_m i - b_m N omega_w)                                 (2.29) without J_m
        tau0[j] = gN * (s * mo.k_m[j] * i - mo.b_m[j] * mo.N[j] * omega_w)
        wdot0[j] = Bbd[0, j] * eta[0] + Bbd[1, j] * eta[1]
        for a in range(2):
            rhs[a] += Bbar[a, j] * (tau0[j] - Jw[j] * wdot0[j])
    etadot = _solve2(A, rhs)
    tau_w = np.empty(nw)
    for j in range(nw):
        # tau_w = eta_g N (k_m i - b_m omega_m - J_m domega_m/dt)
        tau_w[j] = tau0[j] - Jw[j] * (Bbar[0, j] * etadot[0] + Bbar[1, j] * etadot[1] + wdot0[j])
    return _mv(S, eta), etadot, i_dot, tau_w


@jit
def current_jacobian(pc, mo, q, eta, fault):
    r"""d(etadot, i_dot) / d i_a of :func:`motor_plant_rhs`, (2 + nw, nw): exact, the plant is affine in i_a.

    From (2.29) and the implicit (2.70) with E19, etadot = A^-1 (Bbar tau0 + ...) with
    tau0_j = eta_g N s k_m i_j + ..., so d etadot / d i_j = A^-1 Bbar[:, j] eta_g N s k_m, where
    A = Mbar1 + Bbar diag(J_w) Bbar^T (:func:`rotor_mass`); from (2.28), d i_dot_j / d i_j =
    -rho R_a / L_a.  An open winding carries no current whatever its state: its column is 0.
    No other rate reads the currents (the driver and the laws see the commands and the speeds).
    """
    nw = 2 * pc.n
    Mbar1, _M2, _C, Bbar, _S, _Sd = reduced(pc, q, eta)
    A = rotor_mass(Mbar1, Bbar, rotor_inertia_wheel(mo))
    out = np.zeros((2 + nw, nw))
    b = np.empty(2)
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_OPEN:
            continue
        g = mo.eta_g[j] * mo.N[j] * fault[j, F_KM] * mo.k_m[j]
        b[0] = Bbar[0, j] * g
        b[1] = Bbar[1, j] * g
        col = _solve2(A, b)
        out[0, j] = col[0]
        out[1, j] = col[1]
        out[2 + j, j] = -fault[j, F_RA] * mo.R_a[j] / mo.L_a[j]
    return out


@jit
def driver_voltage(mo, tau_c, omega_w, fault):
    r"""Armature voltages for commanded wheel torques: static inversion with nominal parameters.

    i* = (tau_c / (eta_g N) + b_m N omega_w) / k_m clipped at +-I_max, v = R_a i* + k_b N omega_w
    saturated at +-V_max; a stuck driver outputs v_stuck (saturated).  tau_c, omega_w: (nw,);
    returns (nw,) [V].  The driver knows no other fault (k_m loss, resistance, open, short).
    """
    nw = tau_c.shape[0]
    v = np.empty(nw)
    for j in range(nw):
        if int(fault[j, F_MODE]) == MODE_STUCK:
            v[j] = _clip(fault[j, F_VSTUCK], mo.V_max[j])
            continue
        N = mo.N[j]
        i_star = (tau_c[j] / (mo.eta_g[j] * N) + mo.b_m[j] * N * omega_w[j]) / mo.k_m[j]
        i_star = _clip(i_star, mo.I_max[j])
        v[j] = _clip(mo.R_a[j] * i_star + mo.k_b[j] * N * omega_w[j], mo.V_max[j])
    return v


@jit
def quasi_static_current(mo, v_a, omega_w, fault):
    """Steady-state currents (v - k_b N omega_w) / R_a with the faulted R_a, k_b; 0 when open.

    The initial current of a run: with v_a the driver's first output, the motor starts in the
    quasi-static state, so its first wheel torque is the first command (up to saturation and J_m).
    """
    nw = v_a.shape[0]
    v = winding_voltage(mo, v_a, fault)
    out = np.zeros(nw)
    for j in range(nw):
        if int(fault[j, F_MODE]) != MODE_OPEN:
            out[j] = (v[j] - fault[j, F_KM] * mo.k_b[j] * mo.N[j] * omega_w[j]) / (fault[j, F_RA] * mo.R_a[j])
    return out


@jit
def reset_current(fault, i_a):
    """The currents at a fault-segment start: 0 on open windings, unchanged elsewhere.

    ``i_a`` may be the whole motor-state vector ``[i_a, drive states]`` (model.drive_compiled): only its first
    nw entries (the currents) are touched.
    """
    out = i_a.copy()
    for j in range(fault.shape[0]):
        if int(fault[j, F_MODE]) == MODE_OPEN:
            out[j] = 0.0
    return out


@jit
def fault_equivalent(mo, fault, omega_w):
    r"""Quasi-static (L_a -> 0) equivalent (sigma, ubar) of each wheel's motor fault, (2.101)-(2.102).

    With the driver's static inversion (nominal parameters, unsaturated: |i*| < I_max,
    |v| < V_max), the faulted motor (k_m, k_b scaled by s, R_a by rho) gives, with
    g = eta_g, e = k_b N omega_w and the current i = (v - s e) / (rho R_a),

    * normal mode (k_m loss s, resistance rho, or both):
      tau_w = (s / rho) tau_c + g N^2 omega_w [b_m (s / rho - 1) + s (1 - s) k_m k_b / (rho R_a)],
      so sigma = s / rho and ubar is the bracket (zero when healthy).  A pure k_m loss gives
      sigma = s plus a speed-proportional ubar: the driver's back-EMF compensation over-estimates e.
    * open circuit: sigma = 0, ubar = -g N^2 b_m omega_w (only the rotor's friction is left).
    * short: sigma = 0, ubar = -g N^2 omega_w (s^2 k_m k_b / (rho R_a) + b_m).
    * stuck at v_s: sigma = 0, ubar = g N s k_m v_s / (rho R_a) - g N^2 omega_w (s^2 k_m k_b / (rho R_a) + b_m).

    Every fault has an equivalent, but ubar depends on the wheel speed (a viscous term) wherever
    the fault is not a pure resistance change with b_m = 0: (2.102) with ubar evaluated at the
    current speed, not a constant.  No equivalent holds while the driver saturates (the torque is
    then not affine in tau_c); the rotor inertia is in the healthy plant too and is not part of
    the map.  The equivalent is nan on wheels with a non-finite speed.

    Parameters
    ----------
    mo : Motors
    fault : (nw, 4) ndarray
    omega_w : (nw,) ndarray
        Wheel speeds [rad/s].

    Returns
    -------
    sigma, ubar : (nw,) ndarrays
    """
    nw = omega_w.shape[0]
    sigma = np.empty(nw)
    ubar = np.empty(nw)
    for j in range(nw):
        w = omega_w[j]
        if not math.isfinite(w):
            sigma[j] = math.nan
            ubar[j] = math.nan
            continue
        s = fault[j, F_KM]
        rho = fault[j, F_RA]
        R = rho * mo.R_a[j]
        g = mo.eta_g[j]
        N = mo.N[j]
        km, kb, b = mo.k_m[j], mo.k_b[j], mo.b_m[j]
        mode = int(fault[j, F_MODE])
        brake = g * N * N * w * (s * s * km * kb / R + b)  # short-circuit braking + friction
        if mode == MODE_NORMAL:
            sigma[j] = s / rho
            ubar[j] = g * N * N * w * (b * (s / rho - 1.0) + s * (1.0 - s) * km * kb / R)
        elif mode == MODE_OPEN:
            sigma[j] = 0.0
            ubar[j] = -g * N * N * b * w
        elif mode == MODE_SHORT:
            sigma[j] = 0.0
            ubar[j] = -brake
        else:
            vs = _clip(fault[j, F_VSTUCK], mo.V_max[j])
            sigma[j] = 0.0
            ubar[j] = g * N * s * km * vs / R - brake
    return sigma, ubar
