"""Figures of the reports, rendered as inline SVG strings (matplotlib, Agg-free SVG backend).

Each function takes stored time series (dicts of arrays from ``timeseries.npz``)
and returns an ``<svg ...>`` string, so pages are self-contained and work offline.
"""

from __future__ import annotations

import io
import math

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np

from ..control.kinematic import wrap
from ..model.kernels import axle_midpoints
from ..schemes import built_in

__all__ = [
    "PHASE_COLORS",
    "SCHEME_COLORS",
    "articulation_svg",
    "buckets_of",
    "control_torque_svg",
    "decay_svg",
    "estimated_path_svg",
    "event_times",
    "fault_phases",
    "fitted_decay_rate",
    "paths_svg",
    "pole_loci_svg",
    "robot_velocities",
    "robust_range",
    "velocities_svg",
]

SCHEME_COLORS = {name: sc.color for name, sc in built_in().items() if sc.color}  # each scheme's file gives its own
plt.rcParams.update({"font.size": 8, "svg.fonttype": "none", "axes.grid": True, "grid.alpha": 0.3})


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg") :]


#: Fill colors of the fault phases, one per distinct pattern of gains and frictions (legend).
PHASE_COLORS = ("#e8a0a0", "#9fbfe8", "#e8cf8f", "#a9d6a0", "#c9a9e3", "#e3a9cf", "#9fd8d8", "#d8d09f")


def fault_phases(schedule, duration: float, wheels: list[str]) -> list[dict]:
    """The run's phases for shading: ``start``, ``end``, ``label`` (the wheels' gains and frictions),
    ``color`` (one per distinct pattern; ``None`` for a healthy phase, left unshaded) and ``event``
    (the phase starts with a fault event).  Every phase with some gain below 1 or a friction is shaded."""
    out, colors = [], {}
    for start, end in schedule.phases(duration):
        sigma, ubar = schedule.at(start)
        healthy = bool(np.all(sigma == 1.0) and np.all(ubar == 0.0))
        key = (tuple(np.round(sigma, 6)), tuple(np.round(ubar, 6)))
        label = "gains " + " ".join(f"{x:.3g}" for x in sigma)
        if np.any(ubar != 0.0):
            label += "; frictions " + " ".join(f"{x:.3g}" for x in ubar)
        lost = [w for w, x in zip(wheels, sigma, strict=True) if x < 1.0]
        if lost:
            label += f" ({', '.join(lost)} below 1)"
        color = None if healthy else colors.setdefault(key, PHASE_COLORS[len(colors) % len(PHASE_COLORS)])
        out.append(
            {
                "start": float(start),
                "end": float(end),
                "label": label,
                "color": color,
                "event": start > 0 or bool(schedule.times.size and schedule.times[0] == 0),
            }
        )
    return out


def event_times(phases: list[dict]) -> list[float]:
    """The fault event times of :func:`fault_phases` (the phases' starts after 0)."""
    return [p["start"] for p in phases if p["start"] > 0]


def _shade_phases(ax, phases: list[dict]) -> None:
    """Every fault phase shaded in its pattern's color (labelled once, for the legend), events dotted."""
    seen = set()
    for p in phases:
        if p["start"] > 0:
            ax.axvline(p["start"], color="k", lw=0.6, ls=":")
        if p["color"] is None:
            continue
        label = None if p["color"] in seen else p["label"]
        seen.add(p["color"])
        ax.axvspan(p["start"], p["end"], color=p["color"], alpha=0.3, lw=0, zorder=0, label=label)


def buckets_of(t: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(time, min, max, mean) of ``y`` per bucket of about ``t.size / n`` samples (every sample when fewer)."""
    if t.size <= n:
        return t, y, y, y
    edges = np.linspace(0, t.size, n + 1).astype(int)
    lo, hi = np.minimum.reduceat(y, edges[:-1]), np.maximum.reduceat(y, edges[:-1])
    mean = np.add.reduceat(y, edges[:-1]) / np.diff(edges)
    return t[(edges[:-1] + edges[1:]) // 2], lo, hi, mean


def _band(ax, t: np.ndarray, y: np.ndarray, color=None, label: str | None = None, lw: float = 1.0, buckets: int = 600):
    """A signal drawn so that chatter stays readable: above ``buckets`` samples, each bucket's min-max
    range as a light band and its mean as a line (a fast oscillation is a band of its amplitude)."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    if t.size <= 2 * buckets:
        return ax.plot(t, y, lw=lw, color=color, label=label)[0]
    tc, lo, hi, mean = buckets_of(t, y, buckets)
    line = ax.plot(tc, mean, lw=lw, color=color, label=label)[0]
    ax.fill_between(tc, lo, hi, color=line.get_color(), alpha=0.25, lw=0)
    return line


def paths_svg(series: dict[str, dict], d: list[float], events: list[float], b: float = 0.75) -> str:
    """Paths of P_n for every scheme over the reference, the chain drawn at a few instants (``events``:
    the fault times, marked x)."""
    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    ref = next(iter(series.values()))
    ax.plot(ref["q_d"][:, 0], ref["q_d"][:, 1], "k--", lw=1, label="reference")
    for scheme, ts in series.items():
        ax.plot(ts["q"][:, 0], ts["q"][:, 1], color=SCHEME_COLORS.get(scheme), lw=1.2, label=scheme)
        for te in events:
            k = int(np.searchsorted(ts["t"], te))
            if k < ts["t"].size:
                ax.plot(ts["q"][k, 0], ts["q"][k, 1], "x", color=SCHEME_COLORS.get(scheme), ms=6)
    show = next((s for s in series if "selected" in series[s]), next(iter(series)))  # a switching scheme first
    ts = series[show]
    for k in np.linspace(0, ts["t"].size - 1, 5).astype(int):
        P = axle_midpoints(ts["q"][k], d)
        ax.plot(P[:, 0], P[:, 1], "-", color="0.35", lw=1.5)
        th = ts["q"][k, :1:-1]
        for (x, y), t in zip(P, th, strict=True):
            nx, ny = -math.sin(t) * b, math.cos(t) * b
            ax.plot([x - nx, x + nx], [y - ny, y + ny], "-", color="0.2", lw=2.5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"paths of P_n (x: fault events; chain drawn for {show})")
    ax.legend(loc="best")
    return _svg(fig)


def articulation_svg(series: dict[str, dict], phases: list[dict]) -> str:
    """Articulation angles theta_i - theta_(i+1) with the 90 deg singularity; fault phases shaded."""
    fig, ax = plt.subplots(figsize=(6.4, 2.6))
    for scheme, ts in series.items():
        th = ts["q"][:, :1:-1]
        art = np.degrees(wrap(th[:, :-1] - th[:, 1:]))
        for j in range(art.shape[1]):
            ax.plot(
                ts["t"],
                art[:, j],
                color=SCHEME_COLORS.get(scheme),
                lw=0.9,
                alpha=0.5 + 0.5 / (j + 1),
                label=scheme if j == 0 else None,
            )
    for y in (90, -90):
        ax.axhline(y, color="r", lw=1)
    ax.set_ylabel("theta_i - theta_(i+1) [deg]")
    ax.set_xlabel("t [s]")
    _shade_phases(ax, phases)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=6, frameon=False)
    ax.set_title("articulation angles (red: singular at +/-90 deg)")
    return _svg(fig)


def robust_range(
    t: np.ndarray, y: np.ndarray, skip: float = 1.0, pad: float = 0.08, start: float | None = None
) -> tuple[float, float] | None:
    """An axis range from the samples at t >= ``start`` (default t[0] + ``skip``), padded by ``pad`` of
    the span: a start-up transient before then is drawn but does not set the scale.  None without
    such samples."""
    t = np.asarray(t, float)
    y = np.asarray(y, float).reshape(t.size, -1)[t >= (t[0] + skip if start is None else start)]
    y = y[np.isfinite(y)]
    if y.size == 0:
        return None
    lo, hi = float(y.min()), float(y.max())
    span = hi - lo if hi > lo else max(abs(hi), 1e-9)
    return lo - pad * span, hi + pad * span


def _error_norm(ts: dict) -> np.ndarray:
    d = ts["q"] - ts["q_d"]
    d[:, 2:] = np.angle(np.exp(1j * d[:, 2:]))
    return np.linalg.norm(d, axis=1)


def fitted_decay_rate(
    ts: dict, t_end: float, lo: float = 1e-7, hi: float = 1e-1
) -> tuple[float, float, float, bool] | None:
    """Least-squares slope of log |q - q_d| (headings wrapped) where lo < error < hi, before t_end.

    Returns (rate [1/s], window start, window end, decays), or None when the window is too short.
    ``decays``: the error decreases over the window: the slope is negative and the error at its end (the
    median of its last tenth, so an oscillation does not decide it) is below half that at its start and
    below 0.8 of that at its middle; a limit cycle or an offset (the error levelling off) does not, and its
    "rate" is no decay rate.
    """
    t = ts["t"]
    e = _error_norm(ts)
    k = (t < t_end) & (e > lo) & (e < hi)
    if k.sum() < 10 or t[k][-1] - t[k][0] < 1.0:
        return None
    tk, ek = t[k], e[k]
    slope = np.polyfit(tk, np.log(ek), 1)[0]
    tenth = max(1, ek.size // 10)
    mid = ek.size // 2
    start, middle, end = (float(np.median(ek[i : i + tenth])) for i in (0, mid - tenth // 2, ek.size - tenth))
    decays = bool(slope < 0.0 and end < 0.5 * start and end < 0.8 * middle)
    return float(-slope), float(tk[0]), float(tk[-1]), decays


def decay_svg(ts: dict, rate: float, window: tuple[float, float], scheme: str) -> str:
    """Simulated error norm against the predicted envelope e(t_a) exp(-rate (t - t_a))."""
    fig, ax = plt.subplots(figsize=(6.4, 2.6))
    t = ts["t"]
    e = _error_norm(ts)
    ax.semilogy(t, np.maximum(e, 1e-14), lw=1, color=SCHEME_COLORS.get(scheme, "k"), label=f"{scheme}: |q - q_d|")
    ta, tb = window
    ka = int(np.searchsorted(t, ta))
    tt = np.linspace(ta, tb, 50)
    ax.semilogy(tt, e[ka] * np.exp(-rate * (tt - ta)), "k--", lw=1.2, label=f"predicted, rate {rate:.4g} 1/s")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("error norm")
    ax.legend(fontsize=6)
    return _svg(fig)


def pole_loci_svg(loci: list[tuple[float, list[list[float]]]], label: str) -> str:
    """Pole loci in the complex plane, colored by the parameter (time or frame angle)."""
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    vals = [v for v, _ in loci]
    cmap = plt.get_cmap("viridis")
    lo, hi = (min(vals), max(vals)) if vals else (0.0, 1.0)
    for v, poles in loci:
        p = np.asarray(poles, dtype=float)
        c = cmap(0.0 if hi == lo else (v - lo) / (hi - lo))
        ax.plot(p[:, 0], p[:, 1], "x", color=c, ms=4)
    ax.axvline(0.0, color="r", lw=0.8)
    ax.set_xlabel("real part [1/s]")
    ax.set_ylabel("imaginary part [1/s]")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(lo, hi))
    fig.colorbar(sm, ax=ax, label=label)
    return _svg(fig)


def robot_velocities(chain, q: np.ndarray, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear and angular velocity of every robot, (K, n) each, robot 1 first.

    From the logged q and eta through the chain kinematics: the wheel speeds
    ``Bbar^T eta`` (:meth:`ftcreport.model.Chain.wheel_speeds`) give
    v_i = r_i (w_ir + w_il) / 2 and omega_i = r_i (w_ir - w_il) / (2 b_i).
    """
    p = chain.params
    w = np.array([chain.wheel_speeds(qk, ek) for qk, ek in zip(q, eta, strict=True)])
    wr, wl = w[:, 0::2], w[:, 1::2]
    return p.r * (wr + wl) / 2.0, p.r * (wr - wl) / (2.0 * p.b)


def velocities_svg(ts: dict, chain, phases: list[dict], scheme: str) -> str:
    """Linear (top) and angular (bottom) velocity of each robot (thesis Figs 4.7/4.8, 4.17/4.18).

    A chattering signal is drawn as its min-max band with the mean (:func:`_band`); the axes are
    scaled on t >= 1 s, so a start-up transient is drawn but does not flatten the rest."""
    v, w = robot_velocities(chain, ts["q"], ts["eta"])
    fig, axes = plt.subplots(2, 1, figsize=(6.4, 4.2), sharex=True)
    for i in range(v.shape[1]):
        _band(axes[0], ts["t"], v[:, i], label=f"robot {i + 1}")
        _band(axes[1], ts["t"], w[:, i], label=f"robot {i + 1}")
    axes[0].set_ylabel("v_i [m/s]")
    axes[1].set_ylabel("omega_i [rad/s]")
    axes[1].set_xlabel("t [s]")
    for ax, y in zip(axes, (v, w), strict=True):
        lim = robust_range(ts["t"], y)
        if lim is not None:
            ax.set_ylim(*lim)
        _shade_phases(ax, phases)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=3, fontsize=6, frameon=False)
    fig.suptitle(f"linear and angular velocity of each robot, {scheme}", fontsize=8)
    return _svg(fig)


def control_torque_svg(ts: dict, wheels: list[str], phases: list[dict], scheme: str, u_limit=None) -> str:
    """Commanded control u (dashed) against the applied torque tau = sigma sat(u) + ubar (solid), per robot.

    Thesis Figs 4.5/4.6 and 4.14-4.16; the axis is clipped at the 99.5th percentile of both.
    """
    n = len(wheels) // 2
    fig, axes = plt.subplots(n, 1, figsize=(6.4, 1.5 * n + 0.6), sharex=True, squeeze=False)
    u, tau = ts["u"], ts["tau"]
    lim = np.percentile(np.abs(np.concatenate((u.ravel(), tau.ravel()))), 99.5) * 1.2 + 1e-9
    for i in range(n):
        ax = axes[i, 0]
        for j in (2 * i, 2 * i + 1):
            line = ax.plot(ts["t"], tau[:, j], lw=1, label=f"tau {wheels[j]}")[0]
            ax.plot(ts["t"], u[:, j], "--", lw=0.9, color=line.get_color(), label=f"u {wheels[j]}")
        if u_limit is not None:
            for y in (u_limit, -u_limit):
                ax.axhline(y, color="0.5", lw=0.6, ls="-.")
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"robot {i + 1} [N m]")
        _shade_phases(ax, phases)
        # right of the panel, not in it: inside, it sat over the start-up transient at the limit
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=6, frameon=False)
    axes[-1, 0].set_xlabel("t [s]")
    sat = "" if u_limit is None else f"; dash-dot: the {u_limit:g} N m limit"
    axes[0, 0].set_title(f"{scheme}: control u (dashed) and applied torque tau (solid){sat}")
    return _svg(fig)


def estimated_path_svg(ts: dict, scheme: str) -> str:
    """Reference, true and estimated path of P_n in the plane (thesis Fig. 4.9a).

    Equal axes unless the path is more than 4 times longer one way than the other (a long
    sinusoid would be a flat line): then the axes are not to scale and the title says so.
    """
    span = np.ptp(ts["q_d"][:, :2], axis=0) + 1e-9
    stretched = max(span) / min(span) > 4.0
    fig, ax = plt.subplots(figsize=(6.4, 3.0) if stretched else (5.6, 4.0))
    ax.plot(ts["q_d"][:, 0], ts["q_d"][:, 1], "k--", lw=1, label="reference")
    ax.plot(ts["q"][:, 0], ts["q"][:, 1], color=SCHEME_COLORS.get(scheme), lw=1.4, label="true (simulated)")
    ax.plot(ts["q_hat"][:, 0], ts["q_hat"][:, 1], ":", color="0.2", lw=1.2, label="estimated")
    ax.plot(ts["q_hat"][0, 0], ts["q_hat"][0, 1], "o", color="0.2", ms=4)
    ax.plot(ts["q"][0, 0], ts["q"][0, 1], "o", color=SCHEME_COLORS.get(scheme), ms=4)
    if not stretched:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    scale = " (axes not to scale)" if stretched else ""
    ax.set_title(f"{scheme}: reference, true and estimated path of P_n (o: start){scale}")
    ax.legend(loc="best", fontsize=7)
    return _svg(fig)
