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
for any n.  The unicycle quantities (x_d, y_d, theta_d, v_d, omega_d and
their derivatives) of the two-link scheme (3.5-3.7) are those of robot n.

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

from .errors import ReferenceError, reference_articulation_reason, reference_speed_reason

__all__ = [
    "FlatReference",
    "RefPoint",
    "TrigPath",
    "circle",
    "eight",
    "jet_div",
    "jet_mul",
    "jet_sincos",
    "line",
    "sinusoid",
    "unicycle",
]


# --------------------------------------------------------------------------- Taylor jets
# A jet is the array of normalized Taylor coefficients a_k = f^(k)(t) / k!.
def jet_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product of two jets of equal length (Cauchy product, truncated)."""
    n = min(a.shape[0], b.shape[0])
    return np.convolve(a[:n], b[:n])[:n]


def jet_div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quotient a / b of jets: w_k = (a_k - sum_(j>=1) b_j w_(k-j)) / b_0."""
    n = min(a.shape[0], b.shape[0])
    w = np.empty(n)
    for k in range(n):
        w[k] = (a[k] - np.dot(b[1 : k + 1], w[k - 1 :: -1] if k else w[:0])) / b[0]
    return w


def jet_sincos(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sin u, cos u) of a jet: k s_k = sum j u_j c_(k-j), k c_k = -sum j u_j s_(k-j)."""
    n = u.shape[0]
    s, c = np.empty(n), np.empty(n)
    s[0], c[0] = math.sin(u[0]), math.cos(u[0])
    j = np.arange(1, n)
    for k in range(1, n):
        ju = j[:k] * u[1 : k + 1]
        s[k] = np.dot(ju, c[k - 1 :: -1]) / k
        c[k] = -np.dot(ju, s[k - 1 :: -1]) / k
    return s, c


def _jet_deriv(a: np.ndarray) -> np.ndarray:
    return a[1:] * np.arange(1, a.shape[0])


def _jet_integ(a: np.ndarray, c0: float) -> np.ndarray:
    return np.concatenate(([c0], a / np.arange(1, a.shape[0] + 1)))


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
        """Normalized Taylor coefficients of x_d and y_d at t, each (order + 1,)."""
        k = np.arange(order + 1)
        fact = np.array([math.factorial(i) for i in k], dtype=float)
        X = np.zeros(order + 1)
        Y = np.zeros(order + 1)
        X[0], Y[0] = self.x0 + self.vx * t, self.y0 + self.vy * t
        if order >= 1:
            X[1] += self.vx
            Y[1] += self.vy
        for arr, terms in ((X, self.x_terms), (Y, self.y_terms)):
            for amp, w, ph in terms:
                # d^k/dt^k A sin(w t + ph) = A w^k sin(w t + ph + k pi / 2)
                arr += amp * w**k * np.sin(w * t + ph + k * np.pi / 2) / fact
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        Xw = c * X - s * Y
        Yw = s * X + c * Y
        Xw[0] += self.origin[0]
        Yw[0] += self.origin[1]
        return Xw, Yw


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
        self._jets: tuple | None = None  # (t0, X, Y, theta jets, v jet) of the last full evaluation

    @property
    def kind(self) -> str:
        return self.path.kind

    def _headings(self, t: float):
        """Jets of every heading (robot order) and the speed jet of robot n."""
        X, Y = self.path.jets(t, self.order)
        n = self.n
        th_jets: list[np.ndarray] = [np.empty(0)] * n
        v_jet = None
        for i in range(n - 1, -1, -1):  # robot i+1, from the last robot to the leader
            Xd, Yd = _jet_deriv(X), _jet_deriv(Y)
            speed = math.hypot(Xd[0], Yd[0])
            if speed < self.min_speed:
                raise ReferenceError(reference_speed_reason(t, i + 1, speed, self.min_speed))
            Xdd, Ydd = _jet_deriv(Xd), _jet_deriv(Yd)
            m = Xdd.shape[0]
            # thetadot = (xdot yddot - ydot xddot) / (xdot^2 + ydot^2)
            num = jet_mul(Xd[:m], Ydd) - jet_mul(Yd[:m], Xdd)
            den = jet_mul(Xd[:m], Xd[:m]) + jet_mul(Yd[:m], Yd[:m])
            th = _jet_integ(jet_div(num, den), math.atan2(Yd[0], Xd[0]))
            th_jets[i] = th
            s, c = jet_sincos(th)
            if i == n - 1:
                v_jet = jet_mul(Xd, c) + jet_mul(Yd, s)
            if i > 0:
                L = th.shape[0]
                X = X[:L] + self.d[i - 1] * c
                Y = Y[:L] + self.d[i - 1] * s
        return th_jets, v_jet

    def at(self, t: float) -> RefPoint:
        """Reference state at time t; raises ReferenceError where it is infeasible.

        The last few points are memoized (RK4 stages and the etadot_c difference
        ask for the same instants several times).
        """
        hit = self._cache.get(t)
        if hit is not None:
            return hit
        jets = self._jets
        if jets is not None and abs(t - jets[0]) <= _TAYLOR_REACH:
            # the etadot_c difference asks for t0 +/- 1e-5: the jets at t0 are its Taylor series
            point = self._point(t, jets, t - jets[0])
        else:
            point = self._at(t)
        if len(self._cache) >= 16:
            self._cache.clear()
        self._cache[t] = point
        return point

    def _at(self, t: float) -> RefPoint:
        th_jets, v_jet = self._headings(t)
        X, Y = self.path.jets(t, self.order)
        self._jets = (t, X, Y, th_jets, v_jet)
        return self._point(t, self._jets, 0.0)

    def _point(self, t: float, jets: tuple, delta: float) -> RefPoint:
        """RefPoint at t = t0 + delta from the jets at t0 (Taylor series, shifted)."""
        _, X, Y, th_jets, v_jet = jets
        if delta != 0.0:
            X, Y, v_jet = (_shift(a, delta, 3) for a in (X, Y, v_jet))
            th_jets = [_shift(a, delta, 3) for a in th_jets]
        th = np.array([j[0] for j in th_jets])
        # unwrap the leader side relative to robot n so articulation angles are small
        for i in range(self.n - 2, -1, -1):
            th[i] = th[i + 1] + _wrap(th[i] - th[i + 1])
        art = th[:-1] - th[1:]
        if np.any(np.abs(art) > self.max_articulation):
            i = int(np.argmax(np.abs(art)))
            raise ReferenceError(reference_articulation_reason(t, i, math.degrees(art[i]), self.max_articulation))
        thdot = np.array([j[1] for j in th_jets])
        q_d = np.concatenate(([X[0], Y[0]], th[::-1]))
        om1 = th_jets[0]
        eta_d = np.array([v_jet[0], om1[1]])
        eta_d_dot = np.array([v_jet[1], 2.0 * om1[2]])
        thn = th_jets[-1]
        return RefPoint(
            t=float(t),
            q_d=q_d,
            eta_d=eta_d,
            eta_d_dot=eta_d_dot,
            theta_dot=thdot,
            v_d=float(v_jet[0]),
            omega_d=float(thn[1]),
            v_d_dot=float(v_jet[1]),
            omega_d_dot=float(2.0 * thn[2]),
        )

    def check(self, duration: float, dt: float = 0.05, t0: float = 0.0) -> None:
        """Raise ReferenceError if the reference is infeasible anywhere on [t0, t0 + duration]."""
        for t in np.arange(t0, t0 + duration + 0.5 * dt, dt):
            self.at(float(t))


_TAYLOR_REACH = 1e-4  # [s] largest shift served from cached jets (truncation ~ delta^5: round-off)


def _shift(a: np.ndarray, delta: float, m: int) -> np.ndarray:
    """First m normalized Taylor coefficients at t0 + delta of the jet a at t0."""
    k = np.arange(a.shape[0])
    out = np.empty(m)
    for i in range(m):
        # b_i = sum_(j >= i) C(j, i) a_j delta^(j - i)
        j = k[i:]
        coef = np.array([math.comb(int(jj), i) for jj in j], dtype=float)
        out[i] = np.sum(coef * a[i:] * delta ** (j - i))
    return out


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi
