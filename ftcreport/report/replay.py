"""Data of the animated replay on a case page (the drawing is the inline script of ``_replay.html``).

For each scheme: the logged poses decimated to at most ``max_frames`` frames, the axle
midpoints P_i from :meth:`ftcreport.model.Chain.positions` (to scale: millimetres) and the
headings (milliradians); for the case: the reference path of P_n, the chain's geometry (link
lengths d, half-tracks b, wheel radii r, centre-of-mass offsets a) and the fault events, from
which the page computes every wheel's sigma and ubar at any instant (the schedule is piecewise
constant, so it is exact at every frame).  Integers keep the inline JSON small.
"""

from __future__ import annotations

import numpy as np

from ..model import Chain

__all__ = ["replay_data"]


def _frames(t: np.ndarray, max_frames: int) -> np.ndarray:
    """Indices of at most ``max_frames`` samples, evenly spread in time, first and last kept."""
    if t.size <= max_frames:
        return np.arange(t.size)
    grid = np.linspace(t[0], t[-1], max_frames)
    idx = np.unique(np.clip(np.searchsorted(t, grid), 0, t.size - 1))
    return idx


def replay_data(
    series: dict[str, dict],
    chain: Chain,
    faults: list[dict],
    wheels: list[str],
    statuses: dict[str, str] | None = None,
    max_frames: int = 1000,
) -> dict:
    """The replay's JSON-ready dict.

    Parameters
    ----------
    series : dict
        ``{scheme: timeseries}`` with ``t``, ``q`` and ``q_d``.
    chain : Chain
        The chain drawn (the plant's true geometry).
    faults : list of dict
        Events with ``time``, ``wheel``, ``sigma``, ``ubar`` (sorted by time).
    wheels : list of str
        Wheel names in wheel order (``1r, 1l, ...``).
    statuses : dict, optional
        ``{scheme: "ok" | "singular" | ...}``: shown when a run stopped early.
    """
    p = chain.params
    out: dict = {
        "n": int(chain.n),
        "d": [float(x) for x in p.d],
        "b": [float(x) for x in p.b],
        "r": [float(x) for x in p.r],
        "a": [float(x) for x in p.a],
        "wheels": list(wheels),
        "events": [
            {
                "t": float(f["time"]),
                "w": wheels.index(str(f["wheel"]).strip().lower()),
                "s": float(f["sigma"]),
                "u": float(f["ubar"]),
            }
            for f in faults
        ],
        "schemes": {},
    }
    ref_done = False
    for scheme, ts in series.items():
        t, q = np.asarray(ts["t"], float), np.asarray(ts["q"], float)
        if t.size < 2:
            continue
        idx = _frames(t, max_frames)
        P = np.array([chain.positions(q[k])[0] for k in idx])  # (F, n, 2), robot 1 first
        th = q[idx][:, :1:-1]  # (F, n), robot 1 first
        out["schemes"][scheme] = {
            "t": np.round(t[idx], 3).tolist(),
            "x": np.round(P[:, :, 0] * 1000).astype(int).tolist(),
            "y": np.round(P[:, :, 1] * 1000).astype(int).tolist(),
            "th": np.round(th * 1000).astype(int).tolist(),
            "status": (statuses or {}).get(scheme, "ok"),
        }
        if not ref_done and "q_d" in ts:
            qd = np.asarray(ts["q_d"], float)[_frames(t, 2 * max_frames)]
            out["ref"] = {
                "t": np.round(t[_frames(t, 2 * max_frames)], 3).tolist(),
                "x": np.round(qd[:, 0] * 1000).astype(int).tolist(),
                "y": np.round(qd[:, 1] * 1000).astype(int).tolist(),
            }
            ref_done = True
    return out
