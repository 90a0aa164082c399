r"""Actuator fault model and redundancy condition, thesis section 2.6.

Per wheel j (order 1r, 1l, 2r, 2l, ..., nr, nl) the applied torque is

    tau_j = sigma_j u_j + ubar_j,          (2.101); vector form (2.102)

with effectiveness 0 <= sigma_j <= 1 and an additive friction ubar_j [N m] (the compiled
loop applies it: ``fast.loop``).
A :class:`FaultSchedule` holds time-stamped events, each setting (sigma, ubar)
of one wheel from its time on; a later event on the same wheel replaces it,
so intermittent faults (a wheel that recovers) are two events.

Motor faults (issue 19, plants with DC motors: ``model.motor_compiled``) sit in the same schedule: an event
with ``motor`` set (one of :data:`MOTOR_KINDS`) sets that wheel's motor state instead of its
(sigma, ubar); ``motor = "none"`` repairs the motor.  :meth:`FaultSchedule.motor` gives the table
``(2n, 4)`` of ``[k_m scale, R_a scale, mode, v_stuck]`` rows that ``model.motor_compiled`` reads.

Redundancy rule (2.103), derived from the structure of Bbar = S^T B
------------------------------------------------------------------
Row 2 of Bbar is the omega_1 row of B: only robot 1's wheels enter it, with
``+b_1/r_1`` (1r) and ``-b_1/r_1`` (1l).  Row 1 (v_n) has the same entry
``1/(r_1 prod cos(phi_i))`` for both leader wheels, never zero, and for the
followers' wheels entries ``p_ir != p_il`` that are non-zero at a generic pose,
with 0 in row 2.  The columns of the working wheels span R^2 exactly when

    at least one of robot 1's two wheels works, and at least two wheels work.

(the two leader columns are independent; a leader column and any follower
column are independent).  Hence 3 * 2^(2n-2) - 2 compensable 0/1 patterns:
10 of 16 for n = 2 (Remark 2.1), 46 of 64 for n = 3, 190 of 256 for n = 4.
The rule is generic (ERRATA E5d): at particular poses a follower entry can
vanish, e.g. with only 1r and 2r working at tan(phi) = -d/b_2;
:func:`is_compensable_at` checks one pose numerically.
"""

from __future__ import annotations

import functools
import itertools
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import FaultError

__all__ = [
    "MOTOR_KINDS",
    "FaultEvent",
    "FaultSchedule",
    "compensable_patterns",
    "is_compensable_at",
    "motor_row",
    "pattern_is_compensable",
    "wheel_index",
    "wheel_names",
]

#: Motor-fault kinds of a FaultEvent and their value: "none" (repaired), "km_loss" (k_m and k_b
#: scaled by value in (0, 1]), "resistance" (R_a scaled by value >= 1), "open", "short" (no value),
#: "stuck" (driver stuck at value [V]).
MOTOR_KINDS = ("none", "km_loss", "resistance", "open", "short", "stuck")
_MOTOR_MODE = {"none": 0, "km_loss": 0, "resistance": 0, "open": 1, "short": 2, "stuck": 3}

_WHEEL_RE = re.compile(r"^\s*(\d+)\s*([rlRL])\s*$")


def wheel_names(n: int) -> tuple[str, ...]:
    """Wheel names in torque order for n robots: ``('1r', '1l', ..., 'nr', 'nl')``."""
    return tuple(f"{i}{side}" for i in range(1, n + 1) for side in "rl")


def wheel_index(wheel: str | int, n: int) -> int:
    """Index in the torque vector of a wheel named like ``'2l'`` (or an index).

    Raises
    ------
    FaultError
        If the wheel does not exist in an n-robot chain.
    """
    if isinstance(wheel, bool):
        raise FaultError(f"{wheel!r} is not a wheel name")
    if isinstance(wheel, int | np.integer):
        if 0 <= int(wheel) < 2 * n:
            return int(wheel)
        raise FaultError(f"wheel index {wheel} is out of range for a {n}-robot chain (0..{2 * n - 1})")
    match = _WHEEL_RE.match(str(wheel))
    if not match:
        raise FaultError(f"{wheel!r} is not a wheel name (expected e.g. '1r' or '2l')")
    robot, side = int(match.group(1)), match.group(2).lower()
    if not 1 <= robot <= n:
        raise FaultError(f"{wheel!r} is not a wheel of a {n}-robot chain")
    return 2 * (robot - 1) + (0 if side == "r" else 1)


def pattern_is_compensable(pattern: Sequence[float]) -> bool:
    """The redundancy rule on a 0/1 (or sigma) pattern: a leader wheel and two wheels work."""
    works = [float(s) > 0.0 for s in pattern]
    return (works[0] or works[1]) and sum(works) >= 2


def compensable_patterns(n: int) -> list[tuple[int, ...]]:
    """All compensable 0/1 patterns of an n-robot chain (1 = wheel works).

    Ordered by the number of failed wheels, then lexicographically with the
    healthy pattern first.  Length 3 * 2^(2n-2) - 2.
    """
    return list(_compensable_patterns(n))


@functools.cache
def _compensable_patterns(n: int) -> tuple[tuple[int, ...], ...]:
    """:func:`compensable_patterns` once per n (3,070 of 4,096 for six robots, 15 ms; each multi-model
    controller built asks for them, the analysis's limits build several)."""
    pats = [p for p in itertools.product((1, 0), repeat=2 * n) if pattern_is_compensable(p)]
    pats.sort(key=lambda p: (2 * n - sum(p), tuple(-x for x in p)))
    return tuple(pats)


def model_patterns(n: int, patterns=None) -> list[tuple[int, ...]]:
    """The failure patterns of a multi-model scheme: all compensable ones, or a checked list.

    Raises
    ------
    FaultError
        A pattern of the wrong length.
    UncompensableError
        A pattern that violates the redundancy rule.
    """
    from ..errors import UncompensableError

    pats = compensable_patterns(n) if patterns is None else [tuple(int(x) for x in p) for p in patterns]
    if not pats:
        raise FaultError("patterns: at least one failure pattern is needed")
    if patterns is None:
        return pats  # compensable and 2n long by construction
    for p in pats:
        if len(p) != 2 * n:
            raise FaultError(f"patterns: {p} has {len(p)} entries, the chain has {2 * n} wheels")
        if not pattern_is_compensable(p):
            raise UncompensableError(
                f"patterns: {p} violates rank(Bbar sigma) = 2 (a leader wheel and two wheels must work)"
            )
    return pats


def is_compensable_at(Bbar: np.ndarray, sigma: Sequence[float], tol: float = 1e-9) -> bool:
    """rank(Bbar diag(sigma)) = 2 numerically (relative singular-value tolerance)."""
    Bs = np.asarray(Bbar, dtype=float) * np.asarray(sigma, dtype=float)[None, :]
    sv = np.linalg.svd(Bs, compute_uv=False)
    return bool(sv[0] > 0 and sv[1] > tol * max(1.0, sv[0]))


@dataclass(frozen=True)
class FaultEvent:
    """From ``time`` on, wheel ``wheel`` has effectiveness ``sigma`` and friction ``ubar``.

    Attributes
    ----------
    time : float
        Event time [s], >= 0.
    wheel : str
        Wheel name such as ``'1r'`` or ``'3l'``.
    sigma : float
        Effectiveness in [0, 1] (1 healthy, 0 no torque).
    ubar : float
        Additive torque (friction) [N m].
    motor : str or None
        A motor fault (one of :data:`MOTOR_KINDS`) instead of (sigma, ubar), which it leaves as
        they are: a motor event sets only the wheel's motor state.
    value : float or None
        The motor fault's value: k_m scale (km_loss), R_a scale (resistance), voltage [V] (stuck).
    """

    time: float
    wheel: str
    sigma: float = 0.0
    ubar: float = 0.0
    motor: str | None = None
    value: float | None = None


class FaultSchedule:
    """Piecewise-constant sigma(t), ubar(t) for the 2n wheels of a chain.

    Values are right-continuous: at an event time the new value applies.
    Evaluation is a binary search in precomputed tables (hot-path safe).

    Parameters
    ----------
    n : int
        Number of robots.
    events : iterable of FaultEvent
        In any order; two events on the same wheel at the same time are refused.
    """

    def __init__(self, n: int, events: Iterable[FaultEvent] = ()) -> None:
        self.n = int(n)
        evs = list(events)
        nw = 2 * self.n
        seen: set[tuple[float, int]] = set()
        parsed = []
        for k, ev in enumerate(evs):
            where = f"event {k} (t={ev.time}, wheel={ev.wheel!r})"
            try:
                j = wheel_index(ev.wheel, self.n)
            except FaultError as exc:
                raise FaultError(f"{where}: {exc}") from None
            t, s, ub = float(ev.time), float(ev.sigma), float(ev.ubar)
            if not math.isfinite(t) or t < 0:
                raise FaultError(f"{where}: time must be finite and >= 0, got {ev.time}")
            if not 0.0 <= s <= 1.0:
                raise FaultError(f"{where}: sigma must be in [0, 1], got {ev.sigma}")
            if not math.isfinite(ub):
                raise FaultError(f"{where}: ubar must be finite, got {ev.ubar}")
            if (t, j) in seen:
                raise FaultError(f"{where}: a second event on the same wheel at the same time")
            seen.add((t, j))
            try:
                row = None if ev.motor is None else motor_row(ev.motor, ev.value)
            except FaultError as exc:
                raise FaultError(f"{where}: {exc}") from None
            parsed.append((t, j, s, ub, row, ev))
        parsed.sort(key=lambda e: e[0])
        self.events: tuple[FaultEvent, ...] = tuple(
            FaultEvent(t, wheel_names(self.n)[j], s, ub, ev.motor, None if ev.value is None else float(ev.value))
            for t, j, s, ub, _row, ev in parsed
        )
        self.times = np.array(sorted({e[0] for e in parsed}), dtype=float)
        k = self.times.shape[0]
        self._sigma = np.ones((k + 1, nw))
        self._ubar = np.zeros((k + 1, nw))
        #: True when some event is a motor fault (the plant then needs motors).
        self.has_motor = any(e[4] is not None for e in parsed)
        self._motor = np.zeros((k + 1, nw, 4))
        self._motor[:, :, 0] = 1.0
        self._motor[:, :, 1] = 1.0
        cur_s, cur_u = np.ones(nw), np.zeros(nw)
        cur_m = self._motor[0].copy()
        idx = 0
        for row, tk in enumerate(self.times, start=1):
            while idx < len(parsed) and parsed[idx][0] == tk:
                _, j, s, ub, mrow, _ev = parsed[idx]
                if mrow is None:
                    cur_s[j], cur_u[j] = s, ub
                else:
                    cur_m[j] = mrow
                idx += 1
            self._sigma[row] = cur_s
            self._ubar[row] = cur_u
            self._motor[row] = cur_m

    def _row(self, t: float) -> int:
        return int(np.searchsorted(self.times, t, side="right"))

    def sigma(self, t: float) -> np.ndarray:
        """Effectiveness of every wheel at time t, (2n,)."""
        return self._sigma[self._row(t)]

    def ubar(self, t: float) -> np.ndarray:
        """Additive friction of every wheel at time t [N m], (2n,)."""
        return self._ubar[self._row(t)]

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(sigma, ubar)`` at time t."""
        row = self._row(t)
        return self._sigma[row], self._ubar[row]

    def motor(self, t: float) -> np.ndarray:
        """Motor-fault table at time t, (2n, 4): rows ``[k_m scale, R_a scale, mode, v_stuck]``.

        mode: 0 normal, 1 open circuit, 2 shorted winding, 3 driver stuck (``model.motor_compiled``).
        Healthy rows are ``[1, 1, 0, 0]``; without motor events every row is.
        """
        return self._motor[self._row(t)]

    def pattern(self, t: float) -> tuple[int, ...]:
        """0/1 failure pattern at time t: 0 where sigma = 0 (the wheel gives no torque)."""
        return tuple(int(s > 0.0) for s in self.sigma(t))

    def phases(self, duration: float) -> list[tuple[float, float]]:
        """Intervals ``[start, end)`` between event times, covering [0, duration]."""
        cuts = [0.0] + [float(t) for t in self.times if 0.0 < t < duration] + [float(duration)]
        return list(itertools.pairwise(cuts))

    def uncompensable_intervals(self, duration: float) -> list[tuple[float, float, tuple[int, ...]]]:
        """Phases whose pattern violates the redundancy rule, with that pattern."""
        out = []
        for start, end in self.phases(duration):
            pat = self.pattern(start)
            if not pattern_is_compensable(pat):
                out.append((start, end, pat))
        return out

    def __repr__(self) -> str:
        return f"FaultSchedule(n={self.n}, events={list(self.events)!r})"


def motor_row(kind: str, value: float | None) -> np.ndarray:
    """The fault-table row ``[k_m scale, R_a scale, mode, v_stuck]`` of one motor event.

    Raises
    ------
    FaultError
        An unknown kind, or a value missing, superfluous or out of range.
    """
    if kind not in MOTOR_KINDS:
        raise FaultError(f"motor must be one of {', '.join(MOTOR_KINDS)}, got {kind!r}")
    row = np.array([1.0, 1.0, float(_MOTOR_MODE[kind]), 0.0])
    if kind in ("none", "open", "short"):
        if value is not None:
            raise FaultError(f"a motor fault {kind!r} takes no value, got {value}")
        return row
    if value is None:
        raise FaultError(f"a motor fault {kind!r} needs a value")
    v = float(value)
    if kind == "km_loss" and not 0.0 < v <= 1.0:
        raise FaultError(f"km_loss value is the remaining fraction of k_m, in (0, 1], got {value}")
    if kind == "resistance" and not 1.0 <= v <= 1e3:
        raise FaultError(f"resistance value is the factor on R_a, in [1, 1000], got {value}")
    if kind == "stuck" and not math.isfinite(v):
        raise FaultError(f"stuck value is a voltage and must be finite, got {value}")
    row[{"km_loss": 0, "resistance": 1, "stuck": 3}[kind]] = v
    return row
