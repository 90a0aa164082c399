r"""Loop-at-a-time and disk margins at the actuator inputs, with their Bode data (python-control; pure).

The loop is broken at one actuator input j (the torque command on the ideal plant, the armature
voltage with motors), every other input closed, and the controller's own use of its command left as
it is (switching's filters read u).  With the loop ``x' = A_j x + B_j a_j``, ``a_j = K_j x`` (continuous)
or its sampled form (:func:`~ftcreport.analysis.sampled.open_loop_at_input`), the loop transfer
function in python-control's negative-feedback convention is ``L_j = -K_j (sI - A_j)^-1 B_j``; then

* ``control.stability_margins(L_j)``: gain margin (a factor; in dB too), phase margin, the crossover
  frequencies and the stability margin (the least distance of L_j(jw) to -1);
* the disk margin and the gain and phase variations it guarantees together, for each loop
  (:func:`disk_margin_siso`, equal to ``control.disk_margins``) and for all the inputs at once
  (``control.disk_margins`` of the MIMO loop: slycot's ab13md; python-control 0.10.2 and later,
  skipped and said so where the installed version has none);
* the Bode data of the loop with the smallest stability margin, for the page's figure.

Margins are reported only for a stable closed loop.  With the other inputs closed, L_j may itself
have unstable poles (``open_loop_unstable``); its crossover margins are then not a Nyquist certificate.
"""

from __future__ import annotations

import math

import control
import numpy as np

from .blocks import Blocks
from .sampled import open_loop_at_input, parts

__all__ = ["HAS_DISK_MARGINS", "Loops", "frequency_grid", "loop_margins", "loop_systems"]

HAS_DISK_MARGINS = hasattr(control, "disk_margins")
POINTS = 200
#: a pole whose magnitude (|ln z| / T sampled) is below this fraction of the fastest's is at round-off from
#: the origin (1e-16 1/s beside 10 1/s), a constant mode: no frequency of the grid is set by it.  A slow
#: adaptation beside a fast motor is far above it (1.4e-3 beside 2,300 1/s: 6e-7)
ZERO_POLE = 1e-9
#: the MIMO disk margin's grid: slycot's ab13md costs about 3 ms per frequency
MIMO_POINTS = 24
#: the MIMO disk margin for at most this many actuator inputs (three robots)
MIMO_MAX_INPUTS = 6


class Loops:
    r"""Every actuator loop of one closed loop, from one eigendecomposition (Sherman-Morrison).

    With every input closed the loop is ``x' = A x`` (``A = A_0 + B K``); broken at input j,
    ``A_j = A - b_j k_j``, and with ``t_j(s) = k_j (sI - A)^-1 b_j``,
    ``k_j (sI - A_j)^-1 b_j = t_j / (1 + t_j)``, so ``L_j = -t_j / (1 + t_j)``: every loop's response
    at every frequency from ``A = V diag(lambda) V^-1`` alone, instead of a Hessenberg solve per loop
    and frequency.  The response's error grows with the eigenvectors' condition number (3e-12 of |L| at
    330 on two_link_active, 2e-7 at 1e5 on the motor loop): above 1e4 each loop is evaluated by
    python-control instead (:meth:`system`); tests/test_margins.py compares the two.
    """

    def __init__(self, blk: Blocks, T: float | None, delay: int = 0) -> None:
        if T is None:
            A = blk.continuous()
            B, K = blk.feedback()
        else:
            M0, B, K = parts(blk, T, delay)
            A = M0 + B @ K
        self.A, self.B, self.K, self.T = A, B, K, T
        lam, V = np.linalg.eig(A)
        cond = np.linalg.cond(V)
        self.exact = not np.isfinite(cond) or cond > 1e4
        if not self.exact:
            self.lam, self.W, self.KV = lam, np.linalg.solve(V, B), K @ V

    def system(self, j: int) -> control.StateSpace:
        """L_j as a python-control system (``-K_j (sI - A_j)^-1 B_j``, sampled when T is given)."""
        bj, kj = self.B[:, [j]], self.K[[j]]
        kw = {"dt": self.T} if self.T else {}
        return control.ss(self.A - bj @ kj, bj, -kj, np.zeros((1, 1)), **kw)

    def poles(self, j: int) -> np.ndarray:
        """The poles of the loop broken at input j (the other inputs closed)."""
        return np.linalg.eigvals(self.A - self.B[:, [j]] @ self.K[[j]])

    def response(self, j: int, omega) -> np.ndarray:
        """L_j at the frequencies omega [rad/s] (z = e^(j w T) when sampled)."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        if self.exact:
            return control.frequency_response(self.system(j), w).complex.ravel()
        x = np.exp(1j * w * self.T) if self.T else 1j * w
        # a sum over the modes, not a matrix-vector product: 200 frequencies x 60 modes is past OpenBLAS's
        # threading threshold, and its threads waited 1.5 ms a call for the other core on the loaded machine
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.sum((self.KV[j] * self.W[:, j])[None, :] / (x[:, None] - self.lam[None, :]), axis=1)
            return -t / (1.0 + t)

    def at(self, j: int):
        """``w -> L_j(w)`` for the crossover search (scalar)."""
        if self.exact:

            def f(w: float) -> complex:
                return complex(self.response(j, w)[0])

        else:
            kw, lam, T = self.KV[j] * self.W[:, j], self.lam, self.T

            def f(w: float) -> complex:
                x = complex(math.cos(w * T), math.sin(w * T)) if T else 1j * w
                t = complex(np.sum(kw / (x - lam)))
                if 1.0 + t == 0.0:  # a pole of L_j on the axis, met exactly: its gain is infinite there
                    return complex(math.inf, 0.0)
                return -t / (1.0 + t)

        f.dt = self.T  # type: ignore[attr-defined]
        f.many = lambda w: self.response(j, w)  # type: ignore[attr-defined]  (vectorized: the refinements)
        return f


def loop_systems(blk: Blocks, T: float | None, delay: int = 0) -> list[control.StateSpace]:
    """``L_j`` for every actuator input j, as python-control systems (sampled when T is given)."""
    out = []
    if T is None:
        A = blk.continuous()
        B, K = blk.feedback()
        for j in range(blk.na):
            Aj = A - B[:, [j]] @ K[[j]]
            out.append(control.ss(Aj, B[:, [j]], -K[[j]], np.zeros((1, 1))))
    else:
        for j in range(blk.na):
            Aj, Bj, Kj = open_loop_at_input(blk, T, delay, j)
            out.append(control.ss(Aj, Bj, -Kj, np.zeros((1, 1)), dt=T))
    return out


def mimo_loop(blk: Blocks, T: float | None, delay: int = 0) -> control.StateSpace:
    """L = -K (sI - A_0)^-1 B with every actuator input broken at once (na x na)."""
    if T is None:
        A = blk.continuous()
        B, K = blk.feedback()
        return control.ss(A - B @ K, B, -K, np.zeros((blk.na, blk.na)))
    M0, Bz, Ka = parts(blk, T, delay)
    return control.ss(M0, Bz, -Ka, np.zeros((blk.na, blk.na)), dt=T)


def frequency_grid(poles: np.ndarray, T: float | None, points: int = POINTS) -> np.ndarray:
    """rad/s, log-spaced: a decade below the slowest nonzero pole's magnitude (a pole within
    :data:`ZERO_POLE` of the fastest's magnitude counts as zero) to a decade above the
    fastest (continuous), or to the Nyquist frequency pi / T itself (sampled: a loop that loses stability as
    the sample time grows crosses -180 deg there, at z = -1, where L is real)."""
    mags = np.abs(np.log(poles[poles != 0]) / T) if T else np.abs(poles)
    mags = mags[np.isfinite(mags) & (mags > 0)]
    if mags.size:  # a pole at round-off distance from s = 0 (z = 1) is a constant mode, not a frequency
        mags = mags[mags > ZERO_POLE * float(mags.max())]
    lo = 0.1 * float(mags.min()) if mags.size else 1e-2
    hi = math.pi / T if T else 10.0 * float(mags.max()) if mags.size else 1e4
    lo = min(lo, hi / 1e3)
    grid = np.logspace(math.log10(lo), math.log10(hi), points)
    if T:
        grid[-1] = math.pi / T  # exactly: the log of it, raised again, may land above the Nyquist frequency
    return grid


def crossover_margins(L, omega: np.ndarray, Ljw: np.ndarray):
    r"""(gm, pm, sm, w_pc, w_gc, w_sm) of one loop, as ``control.stability_margins`` defines them.

    Phase crossovers (L on the negative real axis) and gain crossovers (|L| = 1) are bracketed on the
    grid and found by Brent's method on L itself; two phase crossovers closer than the grid's spacing
    (the curve touching the axis) show as a local minimum of |angle(-L)|, refined by a bounded
    minimization and kept when it reaches the axis.  The gain margin is the crossover's 1 / |L| closest
    to 1 (in dB), the phase margin ``angle(L) mod 360 - 180`` closest to 0, the stability margin the
    least |1 + L| (the grid's least, refined around it: :func:`refine_least`).  python-control's own
    ``stability_margins`` is not used on these loops: on the 10th-order sampled motor loop its polynomial
    method reports a gain margin of 1.10 from a crossing where angle(-L) is 0.08 rad (scaling the loop's
    gain shows 1.20, as found here), and its interpolated fallback minimizes in every interval of the
    grid (0.3 s a loop, 36 s for a three-link motor case).  tests/test_margins.py checks these against
    its exact results on low-order loops and the gain margins against the gain that loses stability.
    """
    from scipy.optimize import minimize_scalar

    at, many = loop_faces(L)
    dt = getattr(at, "dt", None)

    with np.errstate(all="ignore"):
        im, mag = Ljw.imag, np.abs(Ljw) - 1.0
        w_pc = [
            _root(lambda w: at(w).imag, omega[i], omega[i + 1])
            for i in np.flatnonzero(np.diff(np.sign(im)) != 0)
            if Ljw[i].real < 0.0 or Ljw[i + 1].real < 0.0
        ]
        w_pc = [w for w in w_pc if w is not None]
        dist = np.abs(np.angle(-Ljw))
        for i in np.flatnonzero((dist[1:-1] <= dist[:-2]) & (dist[1:-1] <= dist[2:]) & (dist[1:-1] < 0.2)) + 1:
            r = minimize_scalar(lambda w: abs(np.angle(-at(w))), bounds=(omega[i - 1], omega[i + 1]), method="bounded",
                                options={"xatol": 1e-12 * omega[i]})  # fmt: skip
            if r.fun < 1e-6 and all(abs(r.x - w) > 1e-6 * r.x for w in w_pc):
                w_pc.append(float(r.x))
        if dt and abs(omega[-1] * dt - math.pi) < 1e-9 and Ljw[-1].real < 0.0:
            w_pc.append(float(omega[-1]))  # at the Nyquist frequency L is real: a crossing if negative
        w_pc = [w for w in w_pc if at(w).real <= 0.0]
        gain_cross = np.flatnonzero(np.diff(np.sign(mag)) != 0)
        w_gc = [w for w in (_root(lambda w: abs(at(w)) - 1.0, omega[i], omega[i + 1]) for i in gain_cross) if w]
        gms = [1.0 / abs(at(w)) for w in w_pc]
        pms = [float(np.remainder(np.degrees(np.angle(at(w))), 360.0) - 180.0) for w in w_gc]
        w_sm, sm = refine_least(lambda v: np.abs(1.0 + v), many, omega, np.abs(1.0 + Ljw))
    gm, w1 = (math.inf, math.nan)
    if gms:
        i = int(np.argmin(np.abs(np.log(gms))))
        gm, w1 = gms[i], w_pc[i]
    pm, w2 = (math.inf, math.nan)
    if pms:
        i = int(np.argmin(np.abs(pms)))
        pm, w2 = pms[i], w_gc[i]
    return gm, pm, sm, w1, w2, w_sm


#: the MIMO disk margin's refinement around the grid's least: passes, points per pass (ab13md: 3 ms each)
MIMO_REFINE_PASSES, MIMO_REFINE_POINTS = 3, 9


def _mimo_disk_margins(Lm, omega: np.ndarray) -> tuple[float, float, float]:
    """``control.disk_margins(Lm, omega)``, its least refined between the grid's neighbours of it (log-spaced
    points, the bracket narrowed :data:`MIMO_REFINE_PASSES` times).  ``omega``: :data:`MIMO_POINTS` frequencies,
    each loop's worst (its refined disk-margin peak) and the closed loop's lightly damped modes'
    (:func:`resonant_frequencies`).  On the grid alone the least was missed by a factor of 2.5 to 5 on
    two_link_active_motors (nominal 0.20, active 0.0106, against 0.0814 and 0.00188 on 3,000 frequencies: a
    sharp dip at 0.76 rad/s); with them it is within 2e-5 of the least of 3,000 frequencies on the eight
    loops checked, or below it (two_link_active_motors, three_link_circle_faults, two_link_adaptive_circle;
    tests/test_margins.py)."""
    dm, dgm, dpm = (np.atleast_1d(np.asarray(v, dtype=float)) for v in control.disk_margins(Lm, omega, returnall=True))
    k = int(np.nanargmin(dm))
    best = (float(dm[k]), float(dgm[k]), float(dpm[k]))
    lo, hi = float(omega[max(k - 1, 0)]), float(omega[min(k + 1, omega.size - 1)])
    for _ in range(MIMO_REFINE_PASSES):
        if not (hi > lo > 0.0):
            break
        w = np.geomspace(lo, hi, MIMO_REFINE_POINTS)
        d, g, p = (np.atleast_1d(np.asarray(v, dtype=float)) for v in control.disk_margins(Lm, w, returnall=True))
        i = int(np.nanargmin(d))
        if d[i] < best[0]:
            best = (float(d[i]), float(g[i]), float(p[i]))
        lo, hi = float(w[max(i - 1, 0)]), float(w[min(i + 1, w.size - 1)])
    return best


#: a closed-loop mode below this damping ratio adds its natural frequency to the margins' grids
RESONANT_DAMPING = 0.5


def resonant_frequencies(A: np.ndarray, T: float | None) -> np.ndarray:
    """The natural frequencies [rad/s] of the loop's modes with damping below :data:`RESONANT_DAMPING`
    (``A``: the closed loop's matrix, continuous, or its sampled map with T: ``s = ln z / T``)."""
    if not A.size:
        return np.zeros(0)
    ev = np.linalg.eigvals(A)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.log(ev.astype(complex)) / T if T else ev.astype(complex)
        wn = np.abs(s)
        zeta = -s.real / wn
    keep = np.isfinite(wn) & (wn > 0.0) & (zeta < RESONANT_DAMPING) & (np.abs(s.imag) > 0.0)
    return np.unique(wn[keep])


def _with(omega: np.ndarray, extra) -> np.ndarray:
    """The grid omega with the frequencies ``extra`` that fall inside it, sorted, each once."""
    extra = np.asarray(extra, dtype=float)
    extra = extra[(extra > omega[0]) & (extra < omega[-1])]
    return np.unique(np.concatenate((omega, extra))) if extra.size else omega


def loop_faces(L):
    """(at, many): ``w -> L(w)`` for a scalar frequency (with ``at.dt``, the sample time or None) and for an
    array of them, of ``Loops.at(j)`` or of a python-control system."""
    if callable(L) and not isinstance(L, control.StateSpace):  # Loops.at(j): it carries its array face
        return L, L.many
    dt = L.dt if L.isdtime(strict=True) else None

    def at(w: float) -> complex:
        x = np.exp(1j * w * dt) if dt else 1j * w
        return complex(np.asarray(L(x)).ravel()[0])

    at.dt = dt  # type: ignore[attr-defined]
    return at, lambda w: control.frequency_response(L, np.atleast_1d(np.asarray(w, dtype=float))).complex.ravel()


#: the local refinement of a grid's extremum (:func:`refine_least`): passes, and points per pass
REFINE_PASSES, REFINE_POINTS = 2, 33
_FRACTIONS = np.linspace(0.0, 1.0, REFINE_POINTS)


def refine_least(metric, many, omega: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """(w, value) of the least ``metric(L(w))`` near the grid's least ``values[k]``.

    Log-spaced points between the grid's neighbours of k, evaluated at once (``many``: L at an array of
    frequencies), the bracket narrowed to the best point's neighbours, :data:`REFINE_PASSES` times (each
    divides its log-width by 16), then the vertex of the parabola (in log w) through the best point and
    its two neighbours: a smooth extremum's value to about 1e-9 relative, a resonance of Q = 50 to 1e-7
    (tests/test_margins.py against 20,000 frequencies).  Never above the grid's own least.
    """
    with np.errstate(all="ignore"):
        k = _least(values)
        if k is None:
            return float(omega[0]), math.nan
        w_best, v_best = float(omega[k]), float(values[k])
        lo, hi = float(omega[max(k - 1, 0)]), float(omega[min(k + 1, omega.size - 1)])
        for last in [False] * (REFINE_PASSES - 1) + [True]:
            if not (hi > lo > 0.0):
                break
            x = math.log(lo) + (math.log(hi) - math.log(lo)) * _FRACTIONS
            w = np.exp(x)
            v = np.asarray(metric(np.asarray(many(w))), dtype=float)
            i = _least(v)
            if i is None:
                break
            if v[i] < v_best:
                w_best, v_best = float(w[i]), float(v[i])
            if last and 0 < i < w.size - 1 and all(math.isfinite(float(e)) for e in v[i - 1 : i + 2]):
                # the parabola's vertex through (x, v) at i - 1, i, i + 1 (equally spaced in x)
                den = v[i - 1] - 2.0 * v[i] + v[i + 1]
                if den > 0.0:
                    xv = x[i] + 0.5 * (x[1] - x[0]) * (v[i - 1] - v[i + 1]) / den
                    wv = math.exp(xv)
                    vv = float(metric(np.asarray(many(np.array([wv]))))[0])
                    if vv < v_best:
                        w_best, v_best = wv, vv
            lo, hi = float(w[max(i - 1, 0)]), float(w[min(i + 1, w.size - 1)])
    return w_best, v_best


def _least(v: np.ndarray) -> int | None:
    """The index of v's least value, NaN left out (None when all are NaN): np.argmin, which is 20 times
    cheaper than np.nanargmin, unless it lands on a NaN."""
    i = int(np.argmin(v))
    if not math.isnan(float(v[i])):
        return i
    return None if bool(np.all(np.isnan(v))) else int(np.nanargmin(v))


def _root(f, a: float, b: float) -> float | None:
    """Brent's root of f in [a, b], or None when f has one sign at the ends (the grid's sign change was
    the round-off of a value at zero: the response on the grid and at one point are computed apart)."""
    from scipy.optimize import brentq

    fa, fb = f(a), f(b)
    if fa == 0.0:
        return float(a)
    if fb == 0.0:
        return float(b)
    return float(brentq(f, a, b)) if (fa < 0.0) != (fb < 0.0) else None


def disk_margin_siso(Ljw: np.ndarray) -> dict:
    r"""The balanced disk margin of one loop from its frequency response (skew 0, Blight et al. 1994).

    ``alpha = 1 / max_w |(1 - L) / (2 (1 + L))|`` (the least distance, in that metric, of L(jw) to
    -1); the loop tolerates gain changes in ``[(2 - alpha) / (2 + alpha), (2 + alpha) / (2 - alpha)]``
    and phase changes up to ``2 atan(alpha / 2)``, simultaneously.  This is what
    ``control.disk_margins(L, omega)`` returns for one loop (tests/test_margins.py checks it); the
    closed form avoids its per-frequency call of slycot's ab13md, which one loop does not need.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        peak = float(np.max(np.abs((1.0 - Ljw) / (2.0 * (1.0 + Ljw))), initial=0.0))
    if not peak > 0.0 or not math.isfinite(peak):
        return {"disk_margin": None, "disk_gain_margin_db": None, "disk_phase_margin_deg": None}
    a = 1.0 / peak
    gmax = (2.0 + a) / (2.0 - a) if a < 2.0 else math.inf
    gmin = (2.0 - a) / (2.0 + a)
    dgm = 20.0 * math.log10(min(1.0 / gmin, gmax)) if math.isfinite(gmax) else None
    dpm = math.degrees(math.acos((1.0 + gmin * gmax) / (gmin + gmax))) if math.isfinite(gmax) else 90.0
    return {"disk_margin": a, "disk_gain_margin_db": dgm, "disk_phase_margin_deg": dpm}


def _f(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def loop_margins(blk: Blocks, T: float | None, delay: int, names, unit: str, all_inputs: bool = True) -> dict:
    """Margins of every actuator loop of a stable closed loop (module docstring), as data.

    ``names``: the inputs' names (wheel order); ``unit``: the actuator signal's; ``all_inputs``: also the
    MIMO disk margin (slycot's ab13md at :data:`MIMO_POINTS` frequencies, about 0.1 s).  Infinite
    margins (no crossover) are reported as null.
    """
    lp = Loops(blk, T, delay)
    # the closed loop's lightly damped modes: its sensitivities peak near their frequencies, which a grid
    # can step over (two_link_adaptive_circle's MIMO disk margin: 1.60 on the grid, 1.37 at 0.744 rad/s
    # beside its mode of 0.752 rad/s, damping 0.06)
    resonances = resonant_frequencies(lp.A, T)
    loops = []
    best = None
    worst_w = []  # each loop's refined worst frequencies: where the MIMO loop's least disk margin is looked for
    for j in range(blk.na):
        row = {"input": names[j]}
        if not np.any(lp.B[:, j]) or not np.any(lp.K[j]):
            row["note"] = "no loop through this input (a failed actuator or an unused input)"
            loops.append(row)
            continue
        poles = lp.poles(j)
        unstable = int(np.sum(np.abs(poles) > 1.0 + 1e-9)) if T else int(np.sum(poles.real > 1e-9))
        omega = _with(frequency_grid(poles, T), resonances)
        Ljw = lp.response(j, omega)
        gm, pm, sm, wpc, wgc, _wms = crossover_margins(lp.at(j), omega, Ljw)
        row |= {
            "gain_margin": _f(gm),
            "gain_margin_db": _f(20.0 * math.log10(gm)) if gm and math.isfinite(gm) and gm > 0 else None,
            "phase_margin_deg": _f(pm),
            "stability_margin": _f(sm),
            "phase_crossover": _f(wpc),
            "gain_crossover": _f(wgc),
            "open_loop_unstable": unstable,
        }
        # the disk margin's peak |(1 - L) / (2 (1 + L))| refined off the grid as the stability margin's least
        many = lambda w, j=j: lp.response(j, w)  # noqa: E731
        disk = lambda v: -np.abs((1.0 - v) / (2.0 * (1.0 + v)))  # noqa: E731
        with np.errstate(divide="ignore", invalid="ignore"):
            w_dm, _v = refine_least(disk, many, omega, disk(Ljw))
        row |= disk_margin_siso(np.append(Ljw, many(np.array([w_dm]))))
        worst_w.append(w_dm)
        loops.append(row)
        s = row["stability_margin"]
        if s is not None and (best is None or s < best[0]):
            best = (s, j, Ljw, omega)
    out = {"input": {"V": "voltage", "A": "current target"}.get(unit, "torque"), "unit": unit, "loops": loops,
           "disk_margins": HAS_DISK_MARGINS}  # fmt: skip
    if best is not None:
        _s, j, Ljw, omega = best
        out["worst"] = loops[j]["input"]
        with np.errstate(divide="ignore"):
            out["_bode"] = {
                "input": loops[j]["input"],
                "omega": omega.tolist(),
                "mag_db": (20.0 * np.log10(np.maximum(np.abs(Ljw), 1e-300))).tolist(),
                "phase_deg": np.degrees(np.unwrap(np.angle(Ljw))).tolist(),
                "gain_crossover": loops[j].get("gain_crossover"),
                "phase_crossover": loops[j].get("phase_crossover"),
                "gain_margin_db": loops[j].get("gain_margin_db"),
                "phase_margin_deg": loops[j].get("phase_margin_deg"),
            }
    if all_inputs and blk.na > MIMO_MAX_INPUTS:
        out["all_inputs"] = {"note": f"not computed for more than {MIMO_MAX_INPUTS} inputs (slycot's ab13md: "
                             "about 20 ms per frequency at 12)"}  # fmt: skip
    elif all_inputs and HAS_DISK_MARGINS and blk.na > 1 and any("gain_margin" in r for r in loops):
        Lm = mimo_loop(blk, T, delay)
        omega = frequency_grid(Lm.poles(), T, MIMO_POINTS)
        omega = _with(_with(omega, worst_w), resonances)
        try:
            with np.errstate(all="ignore"):
                dm, dgm, dpm = _mimo_disk_margins(Lm, omega)
            out["all_inputs"] = {
                "disk_margin": _f(dm),
                "disk_gain_margin_db": _f(dgm),
                "disk_phase_margin_deg": _f(dpm),
            }
        except (ValueError, np.linalg.LinAlgError, ImportError) as exc:  # slycot's ab13md missing or failing
            out["all_inputs"] = {"note": f"not computed: {exc}"}
    return out
