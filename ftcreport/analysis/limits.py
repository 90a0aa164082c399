r"""Stability limits of a scheme's loop: the largest sample time and the largest velocity gain (pure).

Per scheme, with the healthy pattern and the case's gains (issue 37 item 3):

* ``sample_time_max``: the largest zero-order-hold sample time T at which the sampled loop
  (:mod:`.sampled`: the plant's ZOH, the case's measurement delay in samples, the command held) is
  stable, i.e. every T below it is stable: the first T at which the spectral radius reaches 1;
* ``k_v_max``: the largest velocity gain at the case's sample time (the continuous loop when the case
  is not sampled) such that every gain between the case's and it is stable; when the loop is unstable at
  the case's own gain, the largest stable gain below it.

On a time-varying loop along a periodic reference (the sinusoid, the eight; the chained law on a
circle), the sample-time limit of a loop the case samples is that of the loop over one period of
the reference (:func:`periodic_growth`: the sampled matrices at instants spread over the period,
multiplied over it, Floquet's criterion for a periodic loop), not the worst frozen instant's, which
is evidence only: on three_link_switching_pi (the sinusoid, 31.4 s) the worst frozen instant of the
phases gave 738 ms, the product over the period 715 ms, and the engine's runs are bounded at 710 ms
and leave the reference at 720 ms.

Both by a walk (factors of 2) that brackets the change of stability, then Brent's method on the
spectral radius minus 1 (or the largest real part) to a relative 1e-9; null when the walk ends
stable (no finite limit up to :data:`T_MAX` or :data:`K_MAX`), or when no point is stable: a loop
unstable in continuous time has no sample-time limit, and a case gain that is unstable is searched
down to :data:`K_MIN` (or a 1e-4th of the case's gain, if lower).  A stable set that is not an interval
(stable again beyond an unstable window) is not searched further.

Closed form, for checking: the ideal plant's velocity loop at rest under the matched law (3.35),
sampled with a held torque, is ``eta_e(j+1) = (1 - k_v T) eta_e(j)``: stable iff ``k_v T < 2``, so
``T_max = 2 / k_v`` and ``k_v_max = 2 / T`` (tests/test_limits.py finds them by the bisection, to
1e-6).  On a moving reference the plant's own velocity terms (Coriolis, Mbar2) shift the limit by
about ``a T / 2`` relative (a their rate, ~0.1 1/s): 3e-5 for k_v = 3000.  With motors the held
voltage drives the current through L_a / R_a and the back-EMF within the sample, which moves the
limit (two_link_switching_motors: 1.3 ms at k_v = 3000, twice the ideal plant's 0.67 ms).

The scheme's Jacobians are affine in k_v (k_v multiplies eta_e in (3.37), and nothing else reads it):
they are computed at two gains and checked at a third (:func:`gain_family`; not for a built-in law on a
plant with no torque limit and no motors, affine in k_v by construction, which tests/test_limits.py
checks); a loop whose Jacobians are not affine in its k_v (a plug-in's, a clipped command's) is linearized
again at every gain tried.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .blocks import Blocks
from .sampled import closed_loop_matrix, plant_zoh, spectral_radius

__all__ = ["K_MAX", "T_MAX", "T_MIN", "boundary", "continuous_margin", "fastest_pole", "gain_family", "largest_gain"]
__all__ += ["MARGINAL_S", "MARGINAL_Z", "largest_sample_time", "periodic_growth", "sampled_radius", "stability"]
__all__ += [
    "KINDS",
    "RESOLUTION",
    "VISIBLE",
    "boundary_modes",
    "gain_domain",
    "gain_floor",
    "limit_words",
    "pole_bands",
]

T_MIN = 1e-6  # s: the smallest sample time searched
T_MAX = 10.0  # s: beyond it a "sample time" is no longer a control loop's
K_MIN = 1e-3  # 1/s: the search for k_v goes down to this gain (or a 1e-4th of the case's, if lower)
K_MIN_FACTOR = 1e-4
K_MAX = 1e6  # 1/s: the largest k_v a case file gives (schemes.fields.Gain): no search beyond what a case can set
STEP = 2.0  # the bracketing walk's ratio
#: |z| within this of 1 is marginal, not a loss of stability: a time constant beyond T / 1e-6 (83 min at
#: 5 ms).  Poles that sit on the boundary by structure (an estimate of a parameter the measurements do
#: not see, ERRATA P3: the UKF's at 1 + 2e-8 from central differences of its whole step, at 1 + 5e-11
#: through the step's derivative) come out of the central differences that far off it, and a double one
#: as far as the square root of the differences' error
MARGINAL_Z = 1e-6
#: a continuous pole within this fraction of the fastest pole's magnitude of the imaginary axis is marginal
#: (the Farza observer's unseen parameter directions come out at +2e-7 1/s with poles of 20 1/s)
MARGINAL_S = 1e-6
RTOL = 1e-9
#: a mode on the boundary holds a perturbation of the plant in the plant when both its unit right eigenvector
#: (where it shows) and its unit left eigenvector (what excites it) have at least this much of their norm in
#: the plant's states (and the delay line's copies of them).  Measured, the smaller of the two shares: the
#: structural modes, estimates the measurements do not see, at 0 to 5e-10 (the adaptive law's and the Farza
#: observer's: they show nowhere in the plant) and at most 7.6e-5 (the UKF's, two_link_active and its motor
#: twin: the plant does not excite them, though they show in it by up to 7 %); the plant's own integrators
#: and its turning pair under a law saturated everywhere at 0.59 to 1.  1e-2 is 130x above the first and 58x
#: below the second (tests/test_limits.py)
VISIBLE = 1e-2
#: what a limit's value is (``limit_kinds`` in the analysis): a finite limit; none up to the search's end
#: (stable at every point searched); none up to the gains the scheme accepts (stable at every gain searched
#: below one its table or its ``pack`` refuses); none because the loop is unstable at every point searched; none because
#: the case's own loop is marginal with modes that move the plant (its tracking error does not converge, so
#: there is no stable range to bound); not computed (the linearization failed); not searched (the UKF's
#: sample time); not applicable (a velocity loop alone for a law that does not read eta)
KINDS = ("limit", "unbounded", "beyond_range", "unstable", "marginal", "not_computed", "not_searched", "not_applicable")


def boundary(margin: Callable[[float], float], lo: float, hi: float, rtol: float = RTOL) -> float:
    """The root of ``margin`` (< 0 stable, > 0 not) between ``lo`` (stable) and ``hi`` (not), to ``rtol``.

    Brent's method (``scipy.optimize.brentq``: bisection steps whenever interpolation does not
    help), so 10-15 evaluations where bisection needs 35; the returned value is on the stable side.
    """
    from scipy.optimize import brentq

    root = float(brentq(margin, lo, hi, xtol=1e-300, rtol=max(rtol, 4.0 * np.finfo(float).eps)))
    while margin(root) >= 0.0 and root > lo:  # brentq stops within rtol of the sign change, on either side
        root -= rtol * root
    return root


def _bracket(margin: Callable[[float], float], start: float, limit: float) -> tuple[float, float] | None:
    """Walk from ``start`` (whose side is kept) toward ``limit`` by factors of STEP; the first pair of
    points on opposite sides, ordered (stable, not); None when the walk ends on the start's side."""
    up = limit > start
    stable0 = margin(start) < 0.0
    prev = x = start
    while (x < limit) if up else (x > limit):
        x = min(x * STEP, limit) if up else max(x / STEP, limit)
        if (margin(x) < 0.0) != stable0:
            return (prev, x) if stable0 else (x, prev)
        prev = x
    return None


def largest_sample_time(rho: Callable[[float], float], guess: float, t_min: float = T_MIN,
                        t_max: float = T_MAX) -> dict:  # fmt: skip
    """The sample-time limit of a loop whose spectral radius at T is ``rho(T)``: ``{"value", "note"}``.

    The walk starts at ``guess`` (2 / the fastest continuous pole's magnitude: the ideal velocity
    loop's limit) and goes up while stable, or down until stable; the limit is then the first loss of
    stability above the stable point found (a window of instability below it, not seen by the walk,
    is not searched for).

    A loop unstable in continuous time has no limit.  That is decided at ``t_min`` by the growth rate
    ln rho / T (the continuous loop's largest real part as T -> 0) against the continuous marginal band,
    MARGINAL_S times the fastest pole (2 / ``guess``), as :func:`stability` decides a continuous phase:
    the discrete band MARGINAL_Z would count a pole at +0.14 1/s as marginal up to T = 7 us.
    """
    margin = lambda T: rho(T) - (1.0 + MARGINAL_Z)  # noqa: E731
    r0 = rho(t_min)
    rate = math.log(max(r0, 1e-300)) / t_min
    if rate > MARGINAL_S * max(1.0, 2.0 / guess) or r0 - (1.0 + MARGINAL_Z) >= 0.0:
        return {
            "value": None,
            "kind": "unstable",
            "note": f"the loop is unstable in continuous time (growth rate {rate:.4g} 1/s as T -> 0): no sample "
            "time stabilizes it",
        }
    guess = min(max(guess, t_min), t_max)
    if margin(guess) < 0.0:
        pair = _bracket(margin, guess, t_max)
        if pair is None:
            return {"value": None, "kind": "unbounded", "note": f"stable at every sample time up to {t_max:g} s"}
    else:
        pair = _bracket(margin, guess, t_min)
        if pair is None:
            pair = (t_min, guess)
    return {"value": boundary(margin, *pair), "kind": "limit", "note": ""}


def largest_gain(margin_at: Callable[[float], float], k_v: float, domain: dict | None = None) -> dict:
    """The largest stable k_v from the case's gain (module docstring): ``{"value", "kind", "note"}``.

    ``margin_at(k)``: < 0 where the loop with gain k is stable (the spectral radius minus 1, or the
    largest real part).  ``domain``: the gains the scheme accepts (:func:`gain_domain`), which bound the
    walk: kind ``beyond_range`` when the loop is stable at every gain tried up to the largest the scheme
    accepts (the limit, if any, lies beyond it); a walk down that ends at the smallest it accepts says so.
    """
    domain = domain or {}
    top, bottom = domain.get("top", K_MAX), domain.get("bottom")
    if margin_at(k_v) < 0.0:
        pair = _bracket(margin_at, k_v, top)
        if pair is not None:
            return {"value": boundary(margin_at, *pair), "kind": "limit", "note": ""}
        if domain.get("why_top") is None:
            return {"value": None, "kind": "unbounded", "note": f"stable at every gain up to {K_MAX:g} 1/s"}
        return {
            "value": None,
            "kind": "beyond_range",
            "note": f"stable at every gain tried from the case's {k_v:.4g} up to {top:.6g} 1/s, the largest the "
            f"scheme accepts (above it: {domain['why_top']})",
        }
    k_lo = gain_floor(k_v) if bottom is None else max(gain_floor(k_v), bottom)
    pair = _bracket(margin_at, k_v, k_lo)
    if pair is None:
        end = f", the smallest the scheme accepts (below it: {domain['why_bottom']})" if k_lo == bottom else ""
        return {"value": None, "kind": "unstable", "note": f"unstable at every gain down to {k_lo:g} 1/s{end}"}
    return {"value": boundary(margin_at, *pair), "kind": "limit", "note": "the loop is unstable at the case's own gain"}


def gain_floor(k_v: float) -> float:
    """The smallest gain the search goes down to: K_MIN, or a 1e-4th of the case's gain if lower."""
    return min(k_v * K_MIN_FACTOR, K_MIN)


def gain_domain(refuses: Callable[[float], str | None], k_v: float) -> dict:
    """The interval of gains a scheme accepts around its case's gain k_v, as the k_v search walks it.

    ``refuses(k)``: why the scheme does not accept gain k, else None.  Along the walk's points (factors of 2
    from k_v up to K_MAX and down to :func:`gain_floor`), the first refused one ends the interval when every
    point past it is refused too: its edge is then found by bisection to a relative 1e-6, ``{"top",
    "why_top", "bottom", "why_bottom"}`` (a side without a refusal: K_MAX, or no bottom, and no why).  A
    refused point with an accepted one past it is a hole, not an end (``pack`` refusing only k_v = 40):
    ``{"hole": words}``, and the gains are not searched (the line through a hole would claim stability
    where the scheme never runs).
    """
    out: dict = {}
    for end, key in ((K_MAX, "top"), (gain_floor(k_v), "bottom")):
        walk = []
        x = k_v
        while (x < end) if key == "top" else (x > end):
            x = min(x * STEP, end) if key == "top" else max(x / STEP, end)
            walk.append(x)
        for i, x in enumerate(walk):
            if (why := refuses(x)) is None:
                continue
            if (back := next((y for y in walk[i + 1 :] if refuses(y) is None), None)) is not None:
                return {"hole": f"the scheme refuses k_v = {x:.4g} 1/s ({why}) but accepts {back:.4g} 1/s"}
            ok = walk[i - 1] if i else k_v
            bad = x
            while abs(bad - ok) > 1e-6 * ok:
                mid = math.sqrt(ok * bad)
                ok, bad = (mid, bad) if refuses(mid) is None else (ok, mid)
            out[key], out[f"why_{key}"] = ok, refuses(bad)
            break
    return out


def gain_family(blocks_at: Callable[[float], Blocks], k_v: float, checked: bool = True) -> Callable[[float], Blocks]:
    """Blocks as a function of k_v: linear interpolation when the Jacobians are affine in k_v.

    ``blocks_at(k)`` linearizes the loop with gain k.  The blocks at k_v and 2 k_v give the line; the
    blocks at k_v / 2 check it (every controller block within 1e-6 of its largest entry).  When the
    check fails, ``blocks_at`` itself is returned (linearized again at every gain).  ``checked`` False:
    the law is known affine in k_v at the operating point, and the line is not checked: a built-in law on
    a plant with no torque limit and no motors (k_v multiplies eta_e, zero there, in (3.35), (3.37),
    (3.117) and (4.14), so the command and every rate are affine in it and the states' values do not
    depend on it).  A limit breaks that: with a drive saturated everywhere (I_max = 1e-6 A) the line
    through k_v and 2 k_v misses the loop at k_v / 2 by 0.16 of 18.9 (tests/test_analysis_inputs.py), so
    there the check stays; tests/test_limits.py checks every built-in scheme at k_v / 2 on ideal, motor,
    PI-drive, adaptive and chained cases.
    """
    b0, b1 = blocks_at(k_v), blocks_at(2.0 * k_v)
    names = ("Gx", "Gy", "Gc", "Dc", "Dy")
    if not checked:
        if all(getattr(b0, n).shape == getattr(b1, n).shape for n in names):
            return _line(b0, b1, k_v, names)
        return blocks_at
    bh = blocks_at(0.5 * k_v)
    same = all(getattr(b0, n).shape == getattr(b1, n).shape == getattr(bh, n).shape for n in names)

    at = _line(b0, b1, k_v, names)
    if same:
        guess = at(0.5 * k_v)
        scale = {n: 1e-6 * max(1.0, float(np.abs(getattr(bh, n)).max(initial=0.0))) for n in names}
        ok = all(np.allclose(getattr(guess, n), getattr(bh, n), rtol=0.0, atol=scale[n]) for n in names)
        if ok:
            return at
    return blocks_at


def _line(b0: Blocks, b1: Blocks, k_v: float, names) -> Callable[[float], Blocks]:
    """The blocks at gain k on the line through b0 (at k_v) and b1 (at 2 k_v)."""

    def at(k: float) -> Blocks:
        s = (k - k_v) / k_v
        out = {n: getattr(b0, n) + s * (getattr(b1, n) - getattr(b0, n)) for n in names}
        return Blocks(b0.Fx, b0.Fa, out["Gx"], out["Gy"], out["Gc"], out["Dc"], out["Dy"], b0.na, b0.kept,
                      b0.dropped, b0.parameter_block, b0.omega, b0.frame, internal=b0.internal,
                      internal_map=b0.internal_map)  # fmt: skip

    return at


def boundary_modes(M: np.ndarray, n_plant: int, discrete: bool) -> dict:
    """The loop's modes on the stability boundary (within the marginal band of :func:`stability`) and how
    many of them hold a perturbation of the plant in the plant: ``{"count", "in_plant", "largest"}``.

    ``M``: the continuous loop's A or the sampled loop's matrix; its first ``n_plant`` states are the
    plant's (and the delay line's).  A perturbation ``dx`` of the state excites mode i by ``y_i^H dx`` (its
    left eigenvector) and the mode shows as ``v_i`` (its right one): a mode whose unit ``y_i`` and ``v_i``
    both have at least :data:`VISIBLE` of their norm in the plant's states keeps part of any plant
    perturbation in the plant for ever (it neither decays nor grows): the tracking error does not converge
    (the plant's own integrators under a law that saturates everywhere, a drive too slow to act).  The
    others are the scheme's own directions (an estimate the measurements do not reach): the plant does not
    excite them or does not see them, the loop tracks, and its limits are where it turns unstable.
    ``largest``: the largest |z| - 1 (or Re) of those that hold the plant (None without any).
    """
    from scipy.linalg import eig

    if not M.size:
        return {"count": 0, "in_plant": 0, "largest": None}
    w, left, right = eig(M, left=True, right=True)
    if discrete:
        d, band = np.abs(w) - 1.0, MARGINAL_Z
    else:
        d, band = w.real, MARGINAL_S * max(1.0, float(np.abs(w).max()))
    # the stable side held to each pole's own resolution, as stability() does a continuous loop's: at a
    # sample time of 1.8 us the stiff loop's kinematic poles (-0.155 1/s) sit at |z| - 1 = -2.8e-7, inside
    # MARGINAL_Z, and are resolved to 1e-9
    band = np.where(d < 0.0, _resolved(M, left, right, band), band)
    on = np.abs(d) <= band

    def share(V: np.ndarray) -> np.ndarray:
        return np.linalg.norm(V[:n_plant], axis=0) / np.maximum(np.linalg.norm(V, axis=0), 1e-300)

    seen = on & (np.minimum(share(left), share(right)) >= VISIBLE)
    largest = float(d[seen].max()) if seen.any() else None
    return {"count": int(on.sum()), "in_plant": int(seen.sum()), "largest": largest}


def limit_words(value: float | None, kind: str | None, unit: str) -> str:
    """A limit as the text summary and the page write it: '12.3 ms', '250 1/s', or what a null one means
    (:data:`KINDS`): 'no finite limit (stable up to 10 s)', 'no stable value (unstable throughout the
    search)', 'no stable range (the loop is marginal)', 'no limit in the gains the scheme accepts (...)', 'not
    computed', 'not searched', 'n/a'; a null of
    no known kind (a result written before the kinds): 'no finite limit'."""
    if value is not None:
        return f"{value * 1e3:.4g} ms" if unit == "s" else f"{value:.4g} 1/s"
    end = f"{T_MAX:g} s" if unit == "s" else f"{K_MAX:g} 1/s"
    return {
        "unbounded": f"no finite limit (stable up to {end})",
        "beyond_range": "no limit in the gains the scheme accepts (stable up to where it refuses them)",
        "unstable": "no stable value (unstable throughout the search)",
        "marginal": "no stable range (the loop is marginal)",
        "not_computed": "not computed",
        "not_searched": "not searched",
        "not_applicable": "n/a",
    }.get(kind or "", "no finite limit")


def stability(measure: float, poles: np.ndarray, discrete: bool, A: np.ndarray | None = None,
              internal: float | None = None) -> str:  # fmt: skip
    """'stable', 'marginal' or 'unstable' from the spectral radius (discrete) or the largest real part.

    Continuous time: a pole within MARGINAL_S of the fastest pole's magnitude of the imaginary axis is
    marginal.  In a stiff loop (k_v = 1e6: a pole at -1e6 1/s beside the kinematic ones at -0.16) that band
    swallows poles the linearization resolves, so with the loop's matrix ``A`` a pole on the stable side
    is held to its own resolution instead, :func:`pole_bands` (never a wider band than MARGINAL_S's):
    -0.155 1/s there is stable.  ``internal``: the left-out states' largest real part (their own modes,
    within ``measure``), judged on MARGINAL_S's band.
    """
    band = MARGINAL_Z if discrete else MARGINAL_S * max(1.0, float(np.abs(poles).max(initial=0.0)))
    edge = 1.0 if discrete else 0.0
    if measure < edge - band:
        return "stable"
    if measure > edge + band:
        return "unstable"
    if discrete or A is None or not A.size:
        return "marginal"
    if internal is not None and internal >= -band:
        return "marginal"
    w, bands = pole_bands(A, band)
    return "marginal" if np.any(w.real >= -bands) else "stable"


#: the relative accuracy of the loop's Jacobians by central differences (closed_loop.STEP = 1e-6: round-off
#: about 2e-16 / 1e-6 = 2e-10 of an entry, truncation 1e-12), with a factor 5 above the round-off
RESOLUTION = 1e-9


def pole_bands(A: np.ndarray, band: float) -> tuple[np.ndarray, np.ndarray]:
    """The poles of ``A`` and how far each is resolved: ``min(band, RESOLUTION kappa_i |A|_2)``, with
    ``kappa_i = |y_i| |v_i| / |y_i^H v_i|`` its condition number (left and right eigenvectors: the first-order
    bound on how far an error dA of the Jacobian, |dA| <= RESOLUTION |A|, moves it).  A defective cluster
    (the adaptive law's weights the torque does not see: kappa 1e10 and more) keeps the wide band."""
    from scipy.linalg import eig

    w, left, right = eig(A, left=True, right=True)
    return w, _resolved(A, left, right, band)


def _resolved(A: np.ndarray, left: np.ndarray, right: np.ndarray, band: float) -> np.ndarray:
    """:func:`pole_bands` from the eigenvectors already computed."""
    dots = np.abs(np.sum(left.conj() * right, axis=0))
    norms = np.linalg.norm(left, axis=0) * np.linalg.norm(right, axis=0)
    kappa = np.where(dots > 0.0, norms / np.maximum(dots, 1e-300), np.inf)
    return np.minimum(band, RESOLUTION * kappa * float(np.linalg.norm(A, 2)))


def sampled_radius(blk: Blocks, T: float, delay: int) -> float:
    """Spectral radius of the sampled loop at T (in the frame turning with the reference), the left-out
    states' own modes included (:meth:`Blocks.internal_measure`: the run is bounded only if they are)."""
    return max(spectral_radius(closed_loop_matrix(blk, T, delay, plant_zoh(blk, T))), blk.internal_measure(T))


def periodic_growth(blocks: list[Blocks], T: float, delay: int, period: float) -> float:
    """The sampled loop's growth per sample over one period of a periodic reference, the left-out states'
    own modes included.

    ``blocks``: the loop linearized at M instants spread evenly over the period, the k-th standing for
    the k-th M-th of it.  The period holds ``N = round(period / T)`` samples, shared among the instants
    in order (``n_k`` each, summing to N); the loop over the period is the product ``M_M^n_M ... M_1^n_1``
    of the sampled matrices (:func:`closed_loop_matrix`), its spectral radius to the power 1/N the
    growth per sample (a Floquet multiplier per sample: below 1 the periodic loop is stable, whatever
    its frozen instants say).  Each power by squaring, every product rescaled to norm 1 with its
    logarithm kept (a radius of 1.03 over 20,000 samples would overflow).  Freezing the loop over each
    M-th of the period is what limits the accuracy: on the three-link sinusoid 12, 24 and 48 instants
    put the limit at 715.13, 715.02 and 715.07 ms.
    """
    n = max(1, round(period / T))
    m = len(blocks)
    edges = [round(k * n / m) for k in range(m + 1)]
    X, logs = None, 0.0
    for blk, count in zip(blocks, np.diff(edges), strict=True):
        if count == 0:
            continue
        P, log_p = _scaled_power(closed_loop_matrix(blk, T, delay, plant_zoh(blk, T)), int(count))
        X = P if X is None else P @ X
        s = max(float(np.linalg.norm(X)), 1e-300)
        X, logs = X / s, logs + log_p + math.log(s)
    radius = spectral_radius(X) if X is not None and X.size else 0.0
    loop = math.exp((logs + math.log(radius)) / n) if radius > 0.0 else 0.0
    return max(loop, max(b.internal_measure(T) for b in blocks))


def _scaled_power(A: np.ndarray, n: int) -> tuple[np.ndarray, float]:
    """(P, l) with ``A^n = P e^l`` and |P| = 1 (or A^n itself when it vanishes): squaring with rescaling."""
    R, log_r = np.eye(len(A)), 0.0
    B, log_b = A, 0.0
    while n:
        if n & 1:
            R = B @ R
            s = max(float(np.linalg.norm(R)), 1e-300)
            R, log_r = R / s, log_r + log_b + math.log(s)
        n >>= 1
        if n:
            B = B @ B
            s = max(float(np.linalg.norm(B)), 1e-300)
            B, log_b = B / s, 2.0 * log_b + math.log(s)
    return R, log_r


def dominant_pole(blk: Blocks, T: float, delay: int) -> complex:
    """The sampled loop's eigenvalue of largest modulus at T (the mode that crosses at the limit), the
    left-out states' own modes included."""
    loop = np.linalg.eigvals(closed_loop_matrix(blk, T, delay, plant_zoh(blk, T)))
    ev = np.concatenate((loop, blk.internal_modes(T)))
    return complex(ev[np.argmax(np.abs(ev))])


def continuous_margin(blk: Blocks) -> float:
    """The largest real part of the continuous loop's poles beyond the marginal band (< 0: not unstable),
    the left-out states' own modes included."""
    A = blk.continuous()
    ev = np.concatenate((np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex), blk.internal_modes()))
    if not ev.size:
        return -math.inf
    return float(ev.real.max()) - MARGINAL_S * max(1.0, float(np.abs(ev).max()))


def fastest_pole(blk: Blocks) -> float:
    """|lambda| of the continuous loop's fastest pole (1 when it has none)."""
    A = blk.continuous()
    return float(np.abs(np.linalg.eigvals(A)).max(initial=1.0)) if A.size else 1.0
