"""Compiled (numba) checks of the loop's accepted state and of a step's jump (the engine's statuses)."""

from __future__ import annotations

import math

from ..jit.compiling import jit
from ..jit.packed import E_POSITION, E_SPEED, E_STATE_SINGULAR


@jit
def _check_state(pp, x, nq, lim, max_speed, max_position, info):
    n = pp.n
    worst = 2.0
    iw = 0
    for i in range(n - 1):
        c = abs(math.cos(x[nq - 1 - i] - x[nq - 2 - i]))
        if c < worst:
            worst = c
            iw = i
    if n > 1 and worst <= lim:
        info[0] = E_STATE_SINGULAR
        info[1] = iw
        info[2] = math.degrees(math.acos(min(1.0, worst)))
        return
    if abs(x[nq]) > max_speed or abs(x[nq + 1]) > max_speed:
        info[0] = E_SPEED
        info[1] = x[nq]
        info[2] = x[nq + 1]
        return
    if abs(x[0]) > max_position or abs(x[1]) > max_position:
        info[0] = E_POSITION
        info[1] = x[0]
        info[2] = x[1]


@jit
def _min_art_cos(pp, x, nq):
    worst = 2.0
    for i in range(pp.n - 1):
        worst = min(worst, abs(math.cos(x[nq - 1 - i] - x[nq - 2 - i])))
    return worst


@jit
def _step_jump(pp, x, xn, nq, lim, max_speed, max_position, frac, lim_far, info):
    """A step's blow-up (ftcreport.sim's docstring): kind (0 = none) with before/after in info[2:4]."""
    for i in range(xn.shape[0]):
        if not math.isfinite(xn[i]):
            return 1
    e0 = max(abs(x[nq]), abs(x[nq + 1]))
    e1 = max(abs(xn[nq]), abs(xn[nq + 1]))
    if e1 > max_speed and e0 < frac * max_speed:
        info[2] = e0
        info[3] = e1
        return 2
    p0 = max(abs(x[0]), abs(x[1]))
    p1 = max(abs(xn[0]), abs(xn[1]))
    if p1 > max_position and p0 < frac * max_position:
        info[2] = p0
        info[3] = p1
        return 3
    if pp.n > 1:
        c0 = _min_art_cos(pp, x, nq)
        c1 = _min_art_cos(pp, xn, nq)
        if c1 <= lim and c0 > lim_far:
            info[2] = math.degrees(math.acos(min(1.0, c0)))
            info[3] = math.degrees(math.acos(min(1.0, c1)))
            return 4
    return 0


@jit
def _finite(f0, u):
    """Whether the rates and the command of a step's first evaluation are all finite."""
    for i in range(f0.shape[0]):
        if not math.isfinite(f0[i]):
            return False
    for i in range(u.shape[0]):  # noqa: SIM110 - a loop, no temporary array, in the step
        if not math.isfinite(u[i]):
            return False
    return True
