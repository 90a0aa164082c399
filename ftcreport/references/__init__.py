r"""Feasible reference motions for n linked robots.

Every reference here is a path of the last robot's axle midpoint,
``p_d(t) = (x_d(t), y_d(t))``, which is a flat output of the chain: from it and
its derivatives the whole reference state follows (thesis 3.59-3.66,
generalized to n)::

    theta_nd = atan2(ydot_d, xdot_d),   v_nd = xdot_d cos theta_nd + ydot_d sin theta_nd
    P_(i)d   = P_(i+1)d + d_i (cos theta_(i+1)d, sin theta_(i+1)d)
    theta_id = direction of Pdot_(i)d,   omega_1d = thetadot_1d

Derivatives are propagated exactly with truncated Taylor series ("jets"),
so q_d(t), eta_d(t) and etadot_d(t) satisfy the kinematics to round-off,
for any n.  The jets are computed once, by the compiled kernels
(``references.compiled.path_jets``, ``ref_jets``, ``ref_point``); :class:`TrigPath` and
:class:`FlatReference` hold and check the parameters and call them.  The
unicycle quantities (x_d, y_d, theta_d, v_d, omega_d and their derivatives) of
the two-link scheme (3.5-3.7) are those of robot n.

Paths are sums of a uniform motion and sinusoids in each coordinate, rotated
and translated (:class:`TrigPath`); the named constructors build the thesis's
references: :func:`circle`, :func:`unicycle` (constant v_d, omega_d),
:func:`eight` (section 3.3.2.3 with ERRATA E11), :func:`line`, :func:`sinusoid`.

A reference whose speed nearly vanishes or whose articulation angles reach
90 deg is refused with :class:`~ftcreport.errors.ReferenceError`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ReferenceError, reference_articulation_reason, reference_speed_reason

__all__ = [
    "FlatReference",
    "RefPoint",
    "TrigPath",
    "circle",
    "eight",
    "line",
    "sinusoid",
    "unicycle",
]


def _F():
    """The compiled twin of this module (numba is loaded on first use, not with the package)."""
    from . import compiled

    return compiled


def _terms(terms) -> np.ndarray:
    return np.array([list(t) for t in terms], dtype=float).reshape(-1, 3)


def _as_ref(packed):
    """The kernels' tuple as the loop passes it to them (``jit.refs.to_ref``): one compile of each
    kernel serves the loop and these calls from Python."""
    from ..jit.refs import to_ref

    return to_ref(packed)


def _pack(path: TrigPath, n: int, d, order: int, max_art: float, min_speed: float):
    """The kernels' ``Ref`` tuple: a path, the link lengths and the jets' order."""
    return _F().Ref(
        int(n),
        float(path.x0),
        float(path.y0),
        float(path.vx),
        float(path.vy),
        _terms(path.x_terms),
        _terms(path.y_terms),
        float(path.rotation),
        float(path.origin[0]),
        float(path.origin[1]),
        np.ascontiguousarray(d, dtype=float).reshape(-1),
        int(order),
        float(max_art),
        float(min_speed),
    )


# --------------------------------------------------------------------------- paths
@dataclass(frozen=True)
class TrigPath:
    r"""A planar path: uniform motion plus sinusoids, then rotated and translated.

    In its own frame ``x(t) = x0 + vx t + sum_j ax_j sin(wx_j t + px_j)`` and the
    same for y; the world path is ``origin + R(rotation) (x, y)``.

    Attributes
    ----------
    x0, y0, vx, vy : float
        Offset [m] and uniform velocity [m/s] in the path frame.
    x_terms, y_terms : tuple of (amplitude [m], frequency [rad/s], phase [rad])
    rotation : float
        Rotation of the path frame [rad].
    origin : (float, float)
        Translation [m].
    kind : str
        Name used in reports (``'circle'``, ``'eight'``, ...).
    """

    x0: float = 0.0
    y0: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    x_terms: tuple[tuple[float, float, float], ...] = ()
    y_terms: tuple[tuple[float, float, float], ...] = ()
    rotation: float = 0.0
    origin: tuple[float, float] = (0.0, 0.0)
    kind: str = "path"

    def jets(self, t: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        """Normalized Taylor coefficients of x_d and y_d at t, each (order + 1,): the compiled ``path_jets``."""
        return _F().path_jets(_as_ref(_pack(self, 1, np.zeros(0), order, math.pi, 0.0)), float(t))


def circle(
    radius: float, speed: float, center: Sequence[float] = (0.0, 0.0), start_angle: float = -np.pi / 2, ccw: bool = True
) -> TrigPath:
    """Circle of given radius [m] run at constant speed [m/s], counter-clockwise by default.

    ``start_angle`` is the polar angle of the start point seen from the centre; the
    default -90 deg starts at the bottom, heading along +x.
    """
    if not radius > 0:
        raise ReferenceError(f"radius: must be > 0 m, got {radius}")
    if not speed > 0:
        raise ReferenceError(f"speed: must be > 0 m/s, got {speed}")
    w = speed / radius * (1.0 if ccw else -1.0)
    # x = R cos(w t + a) = R sin(w t + a + pi/2), y = R sin(w t + a)
    return TrigPath(
        x_terms=((radius, w, start_angle + np.pi / 2),),
        y_terms=((radius, w, start_angle),),
        origin=(float(center[0]), float(center[1])),
        kind="circle",
    )


def unicycle(v_d: float, omega_d: float, x0: float = 0.0, y0: float = 0.0, theta0: float = 0.0) -> TrigPath:
    """Path of a virtual unicycle with constant (v_d, omega_d), thesis (3.5)-(3.7)."""
    if not v_d > 0:
        raise ReferenceError(f"v_d: the reference must move forward (v_d > 0), got {v_d}")
    if omega_d == 0:
        return line(v_d, heading=theta0, start=(x0, y0))
    R = v_d / abs(omega_d)
    side = 1.0 if omega_d > 0 else -1.0
    cx, cy = x0 - side * R * math.sin(theta0), y0 + side * R * math.cos(theta0)
    start = math.atan2(y0 - cy, x0 - cx)
    path = circle(R, v_d, (cx, cy), start_angle=start, ccw=omega_d > 0)
    return TrigPath(**{**path.__dict__, "kind": "unicycle"})


def eight(theta0_deg: float | None = 45.0, origin: Sequence[float] = (0.0, 0.0), scale: float = 1.0) -> TrigPath:
    """Eight-like reference (3 sin 0.3t, 5 sin 0.15t) of section 3.3.2.3 (ERRATA E11).

    Its natural start heading is atan2(0.75, 0.9) = 39.8 deg; the thesis starts
    at theta_d(0) = 45 deg, which only rotates the curve (the default).  Pass
    ``None`` for the unrotated curve.  ``scale`` > 1 gives the same speed profile
    on loops ``scale`` times larger (s (3 sin 0.3t/s, 5 sin 0.15t/s)): the thesis's
    eight turns its heading by 100 deg in 7 s, too tight to recover a 4-robot
    chain started 30 deg off; scale 2 is used for n >= 4.
    """
    if not scale > 0:
        raise ReferenceError(f"scale: must be > 0, got {scale}")
    natural = math.atan2(0.75, 0.9)
    rot = 0.0 if theta0_deg is None else math.radians(theta0_deg) - natural
    return TrigPath(
        x_terms=((3.0 * scale, 0.3 / scale, 0.0),),
        y_terms=((5.0 * scale, 0.15 / scale, 0.0),),
        rotation=rot,
        origin=(float(origin[0]), float(origin[1])),
        kind="eight",
    )


def line(speed: float, heading: float = 0.0, start: Sequence[float] = (0.0, 0.0)) -> TrigPath:
    """Straight line at constant speed [m/s] and heading [rad]."""
    if not speed > 0:
        raise ReferenceError(f"speed: must be > 0 m/s, got {speed}")
    return TrigPath(vx=speed, rotation=heading, origin=(float(start[0]), float(start[1])), kind="line")


def sinusoid(
    speed: float,
    amplitude: float,
    frequency: float,
    heading: float = 0.0,
    start: Sequence[float] = (0.0, 0.0),
    phase: float = 0.0,
) -> TrigPath:
    """x = speed t, y = amplitude (sin(frequency t + phase) - sin(phase)), rotated by heading.

    The path starts at ``start`` whatever the phase; phase = -90 deg gives
    y = amplitude (1 - cos(frequency t)), which starts with heading ``heading``.
    """
    if not speed > 0:
        raise ReferenceError(f"speed: must be > 0 m/s, got {speed}")
    return TrigPath(
        vx=speed,
        y0=-amplitude * math.sin(phase),
        y_terms=((amplitude, frequency, phase),),
        rotation=heading,
        origin=(float(start[0]), float(start[1])),
        kind="sinusoid",
    )


# --------------------------------------------------------------------------- flat reference
@dataclass(frozen=True)
class RefPoint:
    """Reference state at one instant.

    Attributes
    ----------
    t : float
    q_d : (n + 2,) ndarray
        ``[x_d, y_d, theta_nd, ..., theta_1d]``.
    eta_d, eta_d_dot : (2,) ndarrays
        ``[v_nd, omega_1d]`` and its time derivative.
    theta_dot : (n,) ndarray
        Heading rates, robot order.
    v_d, omega_d, v_d_dot, omega_d_dot : float
        Unicycle quantities of robot n (the two-link scheme's v_d, omega_d).
    """

    t: float
    q_d: np.ndarray
    eta_d: np.ndarray
    eta_d_dot: np.ndarray
    theta_dot: np.ndarray
    v_d: float
    omega_d: float
    v_d_dot: float
    omega_d_dot: float

    @property
    def theta_d(self) -> float:
        """Heading of robot n."""
        return float(self.q_d[2])


class FlatReference:
    """The full reference state of an n-robot chain following a path with its last robot.

    Parameters
    ----------
    path : TrigPath
        Path of P_n.
    d : sequence of float
        Link lengths d_1..d_(n-1) (leader first, as in :class:`~ftcreport.model.Chain`).
    max_articulation : float
        Refuse the reference where an articulation angle exceeds this [rad].
    min_speed : float
        Refuse the reference where |pdot_d| falls below this [m/s].
    """

    def __init__(
        self,
        path: TrigPath,
        d: Sequence[float],
        max_articulation: float = math.radians(80.0),
        min_speed: float = 1e-3,
    ) -> None:
        self.path = path
        self.d = np.asarray(d, dtype=float)
        self.n = self.d.shape[0] + 1
        # theta_1 loses one order per robot; omega_1d' needs 3 coefficients of theta_1, and two
        # more keep the Taylor evaluation at t0 + delta (below) exact to round-off
        self.order = self.n + 4
        self.max_articulation = float(max_articulation)
        self.min_speed = float(min_speed)
        self._cache: dict[float, RefPoint] = {}
        self._jets: tuple | None = None  # (t0, the kernels' jets at t0) of the last full evaluation
        self._packed = None
        self._ref = None

    @property
    def kind(self) -> str:
        return self.path.kind

    def packed(self):
        """The reference as the compiled kernels take it (``jit.packed.Ref``; built once)."""
        if self._packed is None:
            self._packed = _pack(self.path, self.n, self.d, self.order, self.max_articulation, self.min_speed)
        return self._packed

    def __getstate__(self) -> dict:
        # the kernels' ref is a pointer into this process's compiled objects: rebuilt on the first use
        return {**self.__dict__, "_ref": None}

    def _kernel_ref(self):
        """:meth:`packed` as the kernels' calls from Python take it (``jit.refs.to_ref``; built once)."""
        if self._ref is None:
            self._ref = _as_ref(self.packed())
        return self._ref

    def _raise(self, info: np.ndarray) -> None:
        F = _F()
        code, a, b, c = int(info[0]), float(info[1]), int(info[2]), float(info[3])
        if code == F.E_REF_SPEED:
            raise ReferenceError(reference_speed_reason(a, b, c, self.min_speed))
        raise ReferenceError(reference_articulation_reason(a, b, c, self.max_articulation))

    def at(self, t: float) -> RefPoint:
        """Reference state at time t; raises ReferenceError where it is infeasible.

        The last few points are memoized (RK4 stages and the etadot_c difference
        ask for the same instants several times).
        """
        t = float(t)
        hit = self._cache.get(t)
        if hit is not None:
            return hit
        F = _F()
        info = np.zeros(4)
        jets = self._jets
        if jets is None or abs(t - jets[0]) > _TAYLOR_REACH:
            # the etadot_c difference asks for t0 +/- 1e-5: the jets at t0 are its Taylor series
            jets = (t, F.ref_jets(self._kernel_ref(), t, info))
            if info[0] != 0:
                self._raise(info)
            self._jets = jets
        n = self.n
        q_d, eta_d, eta_d_dot, sc = np.empty(n + 2), np.empty(2), np.empty(2), np.empty(4)
        work = np.empty((n + 4, max(n, 3)))
        F.ref_point(self._kernel_ref(), jets[1], t, t - jets[0], info, q_d, eta_d, eta_d_dot, sc, work)
        if info[0] != 0:
            self._raise(info)
        # work[:n, :3] holds the first 3 Taylor coefficients of every heading at t
        point = RefPoint(t, q_d, eta_d, eta_d_dot, work[:n, 1].copy(), *(float(v) for v in sc))
        if len(self._cache) >= 16:
            self._cache.clear()
        self._cache[t] = point
        return point

    def rows(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d (k, n + 2), eta_d (k, 2), ok (k,)) at the instants t, in one compiled call: each row as a
        first :meth:`at` at that instant gives it; ``ok`` False (the row NaN) where the reference is
        infeasible (:meth:`at` says why)."""
        t = np.ascontiguousarray(t, dtype=float)
        q_d = np.full((t.size, self.n + 2), np.nan)
        eta_d = np.full((t.size, 2), np.nan)
        ok = np.zeros(t.size, dtype=np.bool_)
        if t.size:
            _F().ref_rows(self._kernel_ref(), t, q_d, eta_d, ok)
        return q_d, eta_d, ok

    def check(self, duration: float, dt: float = 0.05, t0: float = 0.0) -> None:
        """Raise ReferenceError if the reference is infeasible anywhere on [t0, t0 + duration]."""
        found = self.first_infeasible(duration, dt, t0)
        if found is not None:
            raise found[1]

    def first_infeasible(
        self, duration: float, dt: float = 0.05, t0: float = 0.0
    ) -> tuple[float, ReferenceError, float] | None:
        """(the first instant of [t0, t0 + duration] found infeasible, :meth:`at`'s error there, the last
        instant found feasible before it), or None where it is feasible throughout: on a grid of ``dt`` (its
        last point the end, never past it), then of dt / 1000 between the last feasible grid point and the
        first infeasible one (a run stops at its first step past it; ``cases validate`` warns of it and
        ``analyze`` analyses up to the feasible instant, 50 us before at most).  Infeasible at t0: the last
        feasible instant is t0 too."""
        end = t0 + duration
        grid = np.append(np.arange(t0, end, dt), end)
        bad = np.flatnonzero(~self.rows(grid)[2])
        if bad.size == 0:
            return None
        k = int(bad[0])
        t, ok = float(grid[k]), float(grid[max(k - 1, 0)])
        if k > 0:
            fine = np.linspace(ok, t, 1001)
            j = int(np.flatnonzero(~self.rows(fine)[2])[0])
            t, ok = float(fine[j]), float(fine[j - 1])
        try:
            self.at(t)
        except ReferenceError as exc:
            return t, exc, ok
        return t, ReferenceError(f"infeasible reference at t = {t:.6g} s"), ok  # rows and at disagree: say where


_TAYLOR_REACH = 1e-4  # [s] largest shift served from cached jets (truncation ~ delta^5: round-off)
