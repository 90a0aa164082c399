"""Pieces of the case page: replay data to scale, decimation that keeps peaks, grouped tables."""

from __future__ import annotations

import json

import numpy as np

from ftcreport.model import Chain
from ftcreport.report.interactive import decimate, errors_fig
from ftcreport.report.render import _group_tables, _script_json
from ftcreport.report.replay import replay_data


def _series(chain: Chain, k: int = 3001) -> dict:
    t = np.linspace(0.0, 30.0, k)
    q = np.zeros((k, chain.n + 2))
    q[:, 0] = 0.5 * t
    q[:, 1] = np.sin(0.2 * t)
    q[:, 2:] = 0.3 * np.sin(0.1 * t)[:, None] * np.arange(1, chain.n + 1)
    return {"t": t, "q": q, "q_d": q + 0.01}


def test_replay_positions_are_the_chain_geometry_to_the_millimetre():
    chain = Chain.uniform(3, d=1.2)
    ts = _series(chain)
    faults = [{"time": 10.0, "wheel": "2L", "sigma": 0.0, "ubar": -2.0}]
    data = replay_data({"switching": ts}, chain, faults, ["1r", "1l", "2r", "2l", "3r", "3l"], max_frames=500)
    s = data["schemes"]["switching"]
    assert 400 <= len(s["t"]) <= 500 and s["t"][0] == 0.0 and s["t"][-1] == 30.0
    k = int(np.searchsorted(ts["t"], s["t"][123]))
    P, _ = chain.positions(ts["q"][k])
    np.testing.assert_allclose(np.array([s["x"][123], s["y"][123]]).T / 1000, P, atol=5e-4)
    np.testing.assert_allclose(np.array(s["th"][123]) / 1000, ts["q"][k, :1:-1], atol=5e-4)
    assert data["events"] == [{"t": 10.0, "w": 3, "s": 0.0, "u": -2.0}]  # wheel order, name normalised
    assert data["d"] == [1.2, 1.2] and data["b"] == [0.75] * 3
    # consecutive axle midpoints are one link apart: drawn to scale
    link = np.hypot(np.diff(s["x"][200]), np.diff(s["y"][200])) / 1000
    np.testing.assert_allclose(link, 1.2, atol=2e-3)


def test_decimation_keeps_every_peak_and_bounds_the_size():
    t = np.linspace(0, 100, 100_001)
    y = np.exp(-t / 30) * np.sin(3 * t)
    y[71_234] = 5.0  # a one-sample spike
    td, yd = decimate(t, y, max_points=1000)
    assert td.size <= 1002 and td[0] == 0 and td[-1] == 100
    assert yd.max() == 5.0 and yd.min() == y.min()
    assert np.all(np.diff(td) > 0)
    short = np.arange(10.0)
    assert decimate(short, short)[0].size == 10  # short series are kept whole


def test_error_figure_is_small_and_json_safe():
    chain = Chain.uniform(2)
    fig = errors_fig({"nominal": _series(chain, 40_001), "oracle": _series(chain, 40_001)}, [10.0, 20.0])
    text = json.dumps(fig)
    assert len(text) < 400_000  # 4 traces of at most 1,500 points
    assert sum(s["type"] == "rect" for s in fig["layout"]["shapes"]) == 1  # phase 10-20 s shaded
    assert "</" not in _script_json({"a": "</script><script>alert(1)"})


def test_identical_tables_are_shown_once_with_every_scheme():
    rows = [{"re": -1.0, "im": 0.0}, {"re": -0.2, "im": 0.786}]
    other = [{"re": -3.0, "im": 0.0}]
    groups = _group_tables({"nominal": rows, "switching": list(rows), "oracle": rows, "active": other})
    assert [g["schemes"] for g in groups] == [["nominal", "switching", "oracle"], ["active"]]
    assert groups[0]["rows"] == rows
