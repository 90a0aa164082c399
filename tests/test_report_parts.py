"""Pieces of the case page: replay data to scale, decimation that keeps peaks, grouped tables."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ftcreport.model import Chain
from ftcreport.model.faults import FaultEvent, FaultSchedule
from ftcreport.report.analysis_figs import group_tables as _group_tables
from ftcreport.report.interactive import decimate, errors_fig, torques_fig
from ftcreport.report.plots import fault_phases
from ftcreport.report.render import _script_json
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


WHEELS = ["1r", "1l", "2r", "2l"]


def _schedule(*events) -> FaultSchedule:
    return FaultSchedule(2, [FaultEvent(t, w, s, u) for t, w, s, u in events])


def test_error_figure_is_small_and_json_safe():
    chain = Chain.uniform(2)
    phases = fault_phases(_schedule((10.0, "1l", 0.0, 0.0), (20.0, "1l", 1.0, 0.0)), 30.0, WHEELS)
    fig = errors_fig({"nominal": _series(chain, 40_001), "oracle": _series(chain, 40_001)}, phases)
    text = json.dumps(fig)
    assert len(text) < 400_000  # 4 traces of at most 1,500 points
    assert sum(s["type"] == "rect" for s in fig["layout"]["shapes"]) == 1  # phase 10-20 s shaded
    assert "</" not in _script_json({"a": "</script><script>alert(1)"})


def test_every_fault_phase_is_shaded_in_its_patterns_color():
    """Issue 35 item 6: shading alternated, so 50-80 s with two wheels failed was unshaded under a caption
    'fault phases shaded'; partial gains showed as 1.  Now every phase with a fault is shaded, one color
    per pattern of gains (a repeated pattern keeps its color), and the label gives the gains as they are."""
    sched = _schedule(
        (20.0, "1r", 0.0, 0.0), (50.0, "2l", 0.1, 0.0), (80.0, "1r", 1.0, 0.0), (110.0, "2l", 1.0, 0.0),
        (120.0, "2l", 0.1, 0.0), (130.0, "2r", 1.0, 0.5),
    )  # fmt: skip
    ph = fault_phases(sched, 140.0, WHEELS)
    assert [(p["start"], p["end"]) for p in ph] == [(0, 20), (20, 50), (50, 80), (80, 110), (110, 120),
                                                    (120, 130), (130, 140)]  # fmt: skip
    colors = [p["color"] for p in ph]
    assert colors[0] is None and colors[4] is None  # healthy: before the first fault, and 110-120 s
    assert all(c is not None for i, c in enumerate(colors) if i not in (0, 4))  # every fault phase shaded
    assert len({colors[1], colors[2], colors[3]}) == 3 and colors[5] == colors[3]  # one color per pattern
    assert ph[2]["label"] == "gains 0 1 1 0.1 (1r, 2l below 1)"
    assert ph[6]["label"] == "gains 1 1 1 0.1; frictions 0 0 0.5 0 (2l below 1)"


def test_the_start_up_transient_does_not_set_the_torque_axis():
    """Issue 35 item 2: a 4,320 N m spike at t = 0 flattened the torques during the faults; the whole-run
    panel takes its scale from the first fault on, the first-second panel keeps the spike."""
    t = np.linspace(0.0, 40.0, 8001)
    tau = np.zeros((t.size, 4))
    tau[:5] = 4320.0  # start-up
    tau[:, 1] += np.where(t >= 20.0, 3.0 * np.sin(50 * t), 0.0)  # chatter after the fault, +-3 N m
    ts = {"t": t, "tau": tau}
    phases = fault_phases(_schedule((20.0, "1l", 0.2, 0.0)), 40.0, WHEELS)
    fig = torques_fig({"switching": ts}, WHEELS, phases, "switching")
    lo, hi = fig["layout"]["yaxis2"]["range"]
    assert -3.5 < lo < -2.9 and 2.9 < hi < 3.5
    first = [v for tr in fig["data"] if tr.get("yaxis") == "y" for v in tr["y"] if v is not None]
    assert max(first) == 4320.0  # drawn, in its own panel
    zoom = [tr for tr in fig["data"] if tr.get("yaxis") == "y3"]
    assert zoom and all(20.0 <= x <= 20.3 for tr in zoom for x in tr["x"])  # 60 samples from the fault


def test_identical_tables_are_shown_once_with_every_scheme():
    rows = [{"re": -1.0, "im": 0.0}, {"re": -0.2, "im": 0.786}]
    other = [{"re": -3.0, "im": 0.0}]
    groups = _group_tables({"nominal": rows, "switching": list(rows), "oracle": rows, "active": other})
    assert [g["schemes"] for g in groups] == [["nominal", "switching", "oracle"], ["active"]]
    assert groups[0]["rows"] == rows


def test_fault_timeline_shows_partial_gains():
    """Issue 35 item 6: the timeline's pattern column showed '1 1 1 1 1 1' for gains down to 0.1."""
    from pathlib import Path

    from ftcreport.cases import load_case
    from ftcreport.model import wheel_names
    from ftcreport.report.render import _fault_rows

    case = load_case(Path(__file__).resolve().parents[1] / "cases" / "three_link_active.toml")
    rows = _fault_rows(case, case.fault_schedule(), wheel_names(3))
    assert rows[-1]["pattern"].startswith("0.8 0.3 0.4 0.2 0.1 0.7")
    assert "partial: 1r 0.8" in rows[-1]["pattern"] and "failed" not in rows[-1]["pattern"]


def test_every_series_of_the_error_figure_has_its_own_colour():
    """Issue 35 item 8: the motor page's comparison with its base case drew 'switching (this case)' and
    'switching (base)' (names without a scheme colour) in the same blue.  Every legend entry now has a colour
    of its own, none repeated, the schemes' own colours kept where a series is a scheme."""
    from ftcreport.report.plots import SCHEME_COLORS

    chain = Chain.uniform(2)
    phases = fault_phases(_schedule((10.0, "1l", 0.0, 0.0)), 30.0, WHEELS)
    names = ["switching (this case)", "switching (base)", "nominal (this case)", "nominal (base)", "oracle"]
    fig = errors_fig({n: _series(chain) for n in names}, phases)
    shown = [tr for tr in fig["data"] if tr.get("showlegend", True)]
    colors = [tr["line"]["color"] for tr in shown]
    assert [tr["name"] for tr in shown] == names
    assert all(colors) and len(set(colors)) == len(colors), colors
    assert colors[-1] == SCHEME_COLORS["oracle"]
    for tr in fig["data"]:  # each heading trace in its position trace's colour
        assert tr["line"]["color"] == colors[names.index(tr["name"])]


def test_a_near_zero_start_does_not_set_the_error_figures_log_scale():
    """The page audit: a chain that starts on its reference has a position error of 1e-12 m at t = 0, and
    the log axis ran from 1 pm to 0.1 m, the whole run (1 mm to 80 mm) squeezed into its top fifth.  The
    axes now take their lower end from the errors after the start (from 1 s on), as the other figures do."""
    chain = Chain.uniform(2)
    ts = _series(chain, 3001)
    err = 1e-3 + 0.08 * (ts["t"] / 30.0)  # 1 mm rising to 81 mm; zero at the very start
    err[0] = 0.0
    ts["q_d"] = ts["q"].copy()
    ts["q_d"][:, 0] = ts["q"][:, 0] - err
    ts["q_d"][:, 2:] = ts["q"][:, 2:] - 10.0 * err[:, None]
    fig = errors_fig({"nominal": ts}, fault_phases(_schedule((10.0, "1l", 0.0, 0.0)), 30.0, WHEELS))
    lay = fig["layout"]
    lo, hi = lay["yaxis"]["range"]
    # log10 of the errors from 1 s on (3.7 mm to 81 mm) with 0.15 decade of room: not 1 pm
    assert lo == pytest.approx(math.log10(1e-3 + 0.08 / 30) - 0.15, abs=2e-3)
    assert hi == pytest.approx(math.log10(0.081) + 0.15, abs=2e-3)
    lo2 = lay["yaxis2"]["range"][0]  # the headings: ten times the position error, in rad
    assert lo2 == pytest.approx(math.log10(10 * (1e-3 + 0.08 / 30)) - 0.15, abs=2e-3)


def _switching_run(**extra) -> dict:
    """A stored switching run's metrics, the few entries the case page's checks read."""
    return {"scheme": "switching", "status": "ok", "position_error_final": 2e-7, "phases": [], **extra}


def _verify_dt(energy: tuple[float, float], torque_rms: tuple[float, float]) -> dict:
    from ftcreport.runner import dt_sensitivity

    full = {"status": "ok", "dt": 0.01, "energy": energy[0], "torque_rms": torque_rms[0], "position_error_max": 0.05}
    half = {"status": "ok", "dt": 0.005, "energy": energy[1], "torque_rms": torque_rms[1], "position_error_max": 0.05}
    return dt_sensitivity(full, half)


def _page(**context) -> str:
    from ftcreport.report.render import _env

    return (
        _env()
        .get_template("case.html")
        .render(**({"name": "c", "n_phases": 0, "figures": [], "not_run": {}, "warnings": []} | context))
    )


def test_the_step_check_of_run_verify_dt_is_on_the_case_page():
    """The page audit: `run --scheme switching --verify-dt` stored verify_dt (energy and torque_rms moving
    ~30 % between dt and dt/2: not converged, exit 1), README says it is shown on the page, and the page
    did not show it.  The schemes table is now followed by each scheme's step check: which metrics moved,
    from what to what and by how much, in the warning colour when not converged."""
    from ftcreport.report.checks import step_checks

    loose = _switching_run(verify_dt=_verify_dt((10.0, 13.0), (2.0, 2.5)))
    firm = _switching_run(verify_dt=_verify_dt((10.0, 10.01), (2.0, 2.0)))
    firm["scheme"] = "nominal"
    rows = step_checks([loose, firm, _switching_run() | {"scheme": "oracle"}])  # the oracle: no --verify-dt
    assert [r["scheme"] for r in rows] == ["switching", "nominal"]
    assert rows[0]["converged"] is False and rows[1]["converged"] is True
    assert rows[0]["moved"] == [
        "energy 10 -> 13 J (+30.0% at the refined step)",
        "torque_rms 2 -> 2.5 N m (+25.0% at the refined step)",
    ]
    assert "NOT converged" in rows[0]["text"] and "dt = 0.01 s vs 0.005 s" in rows[0]["text"]
    assert "converged" in rows[1]["text"] and "energy 10 -> 10.01 J (+0.1% at the refined step)" in rows[1]["text"]
    html = _page(runs=[loose, firm], step_checks=rows)
    item = html[html.index('<li data-scheme="switching"') :].split("</li>")[0]
    assert 'class="warn"' in item and "energy 10 -&gt; 13 J (+30.0% at the refined step)" in item
    assert 'data-scheme="nominal" class="ok"' in html


def test_a_claim_on_a_scheme_run_scheme_did_not_run_is_not_a_failure_on_the_page():
    """The page audit: `run two_link_switching.toml --scheme switching` rendered a red banner giving as
    exit 1's reason "claim single_law_insufficient ... not evaluated ... the nominal scheme was not run".
    `run` judges only the items on the schemes it ran (README, exit codes; cli.runs._run_gate), so that
    claim did not fail its gate.  The page now says "not judged (needs nominal, not run here)" in a
    neutral note and badge; after a batch or check (every scheme to run) a missing run still fails it."""
    from ftcreport.cases import load_case
    from ftcreport.evaluation.claims import evaluate_claims
    from ftcreport.report.render import _claims_shown, _gate_failures

    case = load_case(Path(__file__).parent.parent / "cases" / "two_link_switching.toml")
    runs = [_switching_run()]
    claims = evaluate_claims(case.name, case.claims, {"switching": runs[0]})
    gate = _gate_failures(case.name, case, runs, [], claims, {"switching"})
    assert not any("single_law_insufficient" in line for line in gate["lines"])
    why = "not judged (needs nominal, not run here)"
    assert gate["not_judged"] == [f"claim single_law_insufficient (3.2.2, simulated in 3.2.3): {why}"]
    shown = _claims_shown(case, claims, {"switching"})
    html = _page(verdict={"sentences": []}, gate=gate, claims=shown, runs=runs)
    note = html[html.index('id="verdict-not-judged"') :].split("</div>")[0]
    assert "not judged (needs nominal, not run here)" in note and "ran switching only" in note
    row = html[html.index('id="claim-single_law_insufficient"') :].split("</tr>")[0]
    assert '<span class="badge none">not judged (needs nominal, not run here)</span>' in row
    assert "expected" not in row
    batch = _gate_failures(case.name, case, runs, [], claims, None)  # a batch: nominal's run is missing
    assert any(line.startswith("claim single_law_insufficient") for line in batch["lines"])
    assert batch["not_judged"] == []


def test_the_recovery_band_is_stated_and_never_is_not_a_dash():
    """The page audit: "settles within the recovery band" and "never settles" never gave the band as a number
    (the case's recovery_band, 0.01 m by default), and the schemes table showed a recovery that never happens
    as "-", the mark of "not measured".  The verdict's sentence, its recovery row, the schemes table's column
    and the per-phase note now state the band; the table says "never" (sorted as the worst)."""
    from ftcreport.evaluation import compare
    from ftcreport.report.render import _verdict_rows

    phases = [{"start": 0.0, "end": 10.0, "fault": False}, {"start": 10.0, "end": 20.0, "fault": True}]

    def run(scheme: str, rec: float | None) -> dict:
        return {"scheme": scheme, "status": "ok", "recovery_time_max": rec, "position_error_final": 1e-3,
                "phases": [p | {"position_error_max": 0.02, "recovery_time": rec if p["fault"] else 0.0}
                           for p in phases]}  # fmt: skip

    runs = [run("switching", 2.5), run("nominal", None)]
    v = compare.compare_case("c", {m["scheme"]: m for m in runs}, fault_times=[10.0], facts={"recovery_band": 0.01})
    said = " ".join(v.sentences)
    assert "Switching settles within the recovery band (position error <= 0.01 m) in 2.5 s at worst" in said
    alone = {"switching": run("switching", None)}
    never = compare.compare_case("c", alone, fault_times=[10.0], facts={"recovery_band": 0.02})
    said = " ".join(never.sentences)
    assert "Switching never settles within the recovery band (position error <= 0.02 m)" in said
    row = next(r for r in _verdict_rows(v, 0.01) if r["key"] == "recovery_time_max")
    assert "recovery band: position error <= 0.01 m" in row["note"]
    html = _page(runs=runs, recovery_band=0.01, n_phases=2, phase_labels=["0-10", "10-20"])
    table = html[html.index('id="schemes"') :].split("</table>")[0]
    assert '<td class="rec-never" data-v="1e308">never</td>' in table and "band 0.01 m" in table
    assert "<td>2.5</td>" in table
    assert "position error &lt;= 0.01 m, <code>recovery_band</code>" in html
    phase = html[html.index('id="phases"') :].split("</table>")[0]
    assert phase.count("rec. never") == 1 and phase.count("rec. 2.5") == 1


def _decay_series(err) -> dict:
    """A run whose position error (the first coordinate) is ``err(t)``, over 0-20 s."""
    t = np.linspace(0.0, 20.0, 2001)
    q = np.zeros((t.size, 4))
    q_d = q.copy()
    q_d[:, 0] = -err(t)
    return {"t": t, "q": q, "q_d": q_d}


def _analysis_text(res: dict) -> str:
    from ftcreport.report.render import _env

    analysis = {"pole_tables": True, "pole_groups": [], "actuator_input": "torque", "not_analyzed": {}} | res
    html = _env().get_template("_analysis.html").render(analysis=analysis)
    return " ".join(html[html.index('id="fitted-decay"') :].split("</p>")[0].split())


def test_the_decay_fit_is_stated_once_and_not_for_an_error_that_does_not_decay():
    """The page audit: the decay figure's caption said "fitted rate 0.09581 1/s over 2-20 s" and the text below it
    "fitted rate 0.0958 1/s over 1.61-20 s" (one fit, two roundings of its window); and a run whose error
    does not decay (a limit cycle at ~0.05 m) still got a "fitted rate ... against the predicted 0.155".  Caption
    and text now share one phrase; an error that does not decrease over the window gets no rate."""
    from ftcreport.report.analysis_figs import _classic_figures

    decaying = _decay_series(lambda t: np.where(t < 1.61, 0.2, 0.09 * np.exp(-0.0958 * (t - 1.61))))
    res = {"predicted_decay_rate": 0.155}
    (fig,) = _classic_figures(res, {"nominal": decaying}, [20.0], 20.0)
    words = "fitted rate 0.0958 1/s over 1.61-20 s"
    assert res["fitted_decay"]["decays"] and words in fig["caption"]
    assert res["fitted_decay"]["rate"] == pytest.approx(0.0958, rel=1e-3)  # the exact exponential
    assert f"(nominal): {words}, against the predicted 0.155 1/s." in _analysis_text(res)
    cycle = _decay_series(lambda t: 0.05 + 0.01 * np.sin(2.0 * t) + 0.03 * np.exp(-t))  # levels off at 5 cm
    res = {"predicted_decay_rate": 0.155}
    (fig,) = _classic_figures(res, {"nominal": cycle}, [20.0], 20.0)
    no = "the error does not decay here (limit cycle or offset): no rate fitted"
    assert no in fig["caption"] and "fitted rate" not in fig["caption"]
    assert res["fitted_decay"]["rate"] is None and not res["fitted_decay"]["decays"]
    text = _analysis_text(res)
    assert no in text and "against the predicted" not in text
    offset = _decay_series(lambda t: 0.02 + 0.0 * t)  # a constant offset: slope 0
    res = {"predicted_decay_rate": 0.155}
    _classic_figures(res, {"nominal": offset}, [20.0], 20.0)
    assert not res["fitted_decay"]["decays"]


def test_the_phase_crossover_marker_sits_on_the_wrapped_phase_curve():
    """The page audit: the Bode plot's phase-crossover circle was drawn at -180 deg while the curve, wrapped,
    was at +180 deg there, so the circle floated off the curve.  It is now drawn at the curve's own phase at
    that frequency (a wrapped curve: the value beside the wrap, not a point inside the jump)."""
    from ftcreport.report.analysis_figs import bode_fig

    omega = np.logspace(-1, 2, 61)
    unwrapped = -90.0 - 60.0 * np.log10(omega / 0.1)  # -180 deg at 0.1 * 10**1.5 = 3.16 rad/s
    w180 = 0.1 * 10**1.5 * 1.08  # the crossover a little past the sample at 3.16 rad/s: beside +180 deg

    def marker(phase: np.ndarray) -> tuple[float, float]:
        b = {"input": "1r", "omega": omega.tolist(), "mag_db": (-20 * np.log10(omega)).tolist(),
             "phase_deg": phase.tolist(), "phase_crossover": w180, "gain_margin_db": 6.0}  # fmt: skip
        res = {"phases": {"switching": [{"t_start": 0.0, "t_end": 10.0, "margins": {"_bode": b}}]}}
        fig = bode_fig(res)
        (gm,) = [t for t in fig["plotly"]["data"] if t["mode"] == "markers" and t.get("xaxis") == "x2"]
        curve = np.interp(np.log(w180), np.log(omega), phase)
        return gm["y"][0], curve

    wrapped = (unwrapped + 180.0) % 360.0 - 180.0  # numpy/python-control style: +180 just past -180
    y, _ = marker(wrapped)
    j = int(np.argmin(np.abs(np.log(omega) - np.log(w180))))
    assert wrapped[j] > 170.0  # the curve is at +180 there
    assert y == pytest.approx(wrapped[j], abs=0.06)  # on the curve (4 digits), not at -180
    y, curve = marker(unwrapped)  # no wrap: the interpolated value, about -180
    assert y == pytest.approx(curve, abs=0.06) and curve == pytest.approx(-180.0 - 60 * np.log10(1.08), abs=0.1)


def _captured_figure(monkeypatch, draw):
    """The matplotlib figure a plots.*_svg function builds (drawn, so its artists have their extents)."""
    from ftcreport.report import plots

    figs = []
    monkeypatch.setattr(plots, "_svg", lambda fig: figs.append(fig) or "<svg/>")
    draw()
    fig = figs[0]
    fig.canvas.draw()
    return fig


def test_the_u_tau_legend_hides_no_data(monkeypatch):
    """The page audit: on the motor case pages the legend of the u/tau figure sat inside each robot's panel,
    upper right, over the start-up saturation at the limit.  Each panel's legend is now outside its axes."""
    from ftcreport.report import plots

    t = np.linspace(0.0, 5.0, 1001)
    u = np.column_stack([5.0 * np.exp(-t), -3.0 * np.exp(-t), 4.0 * np.cos(t), 5.0 * np.ones_like(t)])
    ts = {"t": t, "u": u, "tau": 0.9 * u}
    sched = _schedule((0.0, "2l", 0.5, 0.0))
    shading = fault_phases(sched, 5.0, ["1r", "1l", "2r", "2l"])
    fig = _captured_figure(
        monkeypatch, lambda: plots.control_torque_svg(ts, ["1r", "1l", "2r", "2l"], shading, "active", 5.0)
    )
    panels = [ax for ax in fig.axes if ax.get_legend() is not None]
    assert len(panels) == 2
    for ax, robot in zip(panels, (1, 2), strict=True):
        box, leg = ax.get_window_extent(), ax.get_legend().get_window_extent()
        assert leg.x0 >= box.x1, (leg, box)  # right of the plot area: over no data
        texts = {x.get_text() for x in ax.get_legend().get_texts()}
        assert {f"tau {robot}r", f"u {robot}r", f"tau {robot}l", f"u {robot}l"} <= texts


def _adaptive_series(n_models: int = 10, nw: int = 4, k: int = 501) -> tuple[dict, list[list[int]]]:
    """An adaptive run's logged estimates: weights per model and wheel, friction estimate per wheel."""
    t = np.linspace(0.0, 5.0, k)
    patterns = [[int(x) for x in f"{(2**nw - 1) - i:0{nw}b}"] for i in range(n_models)]  # 1111, 1110, 1101, ...
    chi = np.repeat(np.linspace(0.0, 1.0, n_models)[None, :, None], k, axis=0) * np.ones((k, n_models, nw))
    ts = {"t": t, "chi_hat": chi, "uf_hat": 0.1 * np.sin(t)[:, None] * np.ones(nw), "ubar": np.zeros((k, nw))}
    return ts, patterns


def test_a_colour_means_one_thing_in_the_adaptive_figure():
    """The page audit: the adaptive figure drew the model weights in plotly's default colours and the friction
    estimate of each wheel in a hue of its own, so model 3 and wheel 1r were both red, model 2 and wheel 1l both
    green: one colour, two quantities.  Every weight and every wheel now has its own colour; a wheel's estimate
    and its truth (dashed) share the wheel's."""
    from ftcreport.report.interactive import estimates_fig

    ts, patterns = _adaptive_series()
    wheels = ["1r", "1l", "2r", "2l"]
    fig = estimates_fig(ts, "adaptive", wheels, [], patterns)
    models = [d for d in fig["data"] if d["name"].startswith("model ")]
    estimates = [d for d in fig["data"] if d.get("legendgroup") in wheels and d.get("showlegend", True)]
    truths = [d for d in fig["data"] if d["name"].startswith("true ")]
    assert len(models) == 10 and len(estimates) == 4 and len(truths) == 4
    colours = [d["line"].get("color") for d in models + estimates]
    assert None not in colours and len(set(colours)) == len(colours)  # 14 series, 14 colours
    for est, true in zip(estimates, truths, strict=True):
        assert true["line"]["color"] == est["line"]["color"] and true["line"]["dash"] == "dash"


def test_the_friction_estimate_has_one_name_on_the_page():
    """The page audit: a case page named the friction estimate ubar_hat in the active schemes' figures and
    uf_hat in the adaptive one (the logged array's name), both against the same true ubar.  The README and the
    rest of the pages say ubar_hat; every figure now does."""
    from ftcreport.report.interactive import estimates_fig

    ts, patterns = _adaptive_series(n_models=3, nw=2)
    adaptive = estimates_fig(ts, "adaptive", ["1r", "1l"], [], patterns)
    k = ts["t"].size
    active_ts = {"t": ts["t"], "rho_hat": np.ones((k, 2)), "sigma": np.ones((k, 2))}
    active = estimates_fig(active_ts | {"ubar_hat": ts["uf_hat"], "ubar": ts["ubar"]}, "active", ["1r", "1l"], [])
    names = {f: [d["name"] for d in fig["data"]] for f, fig in (("adaptive", adaptive), ("active", active))}
    assert [n for n in names["adaptive"] if not n.startswith(("model", "true"))] == ["ubar_hat 1r", "ubar_hat 1l"]
    assert {"ubar_hat 1r", "ubar_hat 1l"} <= set(names["active"])
    assert not any("uf_hat" in json.dumps(fig) for fig in (adaptive, active))


def test_the_provenance_case_file_wraps_inside_its_box():
    """The page audit: the provenance's copy of the case file (a <pre>) kept its lines whole on screen, so a
    claim's words or the resolved [schemes] table ran thousands of pixels past the page's 1100 px column (cut at
    the box's edge, behind a scroll bar at its foot).  On screen as in print it now wraps inside its box."""
    import re

    html = _page(case_text='words = "' + "their effect on the system dynamic " * 40 + '"\n')
    assert '<pre class="case-file">words = &#34;their effect' in html
    screen = html[html.index("<style>") : html.index("@media print")]
    rule = re.search(r"\npre[^{]*\{([^}]*)\}", screen).group(1)
    decl = dict(d.split(":", 1) for d in (x.strip() for x in rule.split(";")) if d)
    assert decl["white-space"].strip() == "pre-wrap" and decl["overflow-wrap"].strip() == "anywhere"
    assert decl["max-width"].strip() == "100%" and decl["box-sizing"].strip() == "border-box"


def test_a_claims_note_on_a_shortened_run_says_what_that_run_shows():
    """The page audit: after `batch cases/motors --duration 5` the claims table of two_link_active_motors
    printed the case file's note, "Measured 0.147 m (ideal plant 0.062 m): the Farza observer's estimates
    drift ...", written for the full 70 s run, beside the 5 s run's value and a red "expected reproduced",
    while the verdict said the claims are not judged on a shortened run.  The note now says it was written
    for the full run and what the shortened run does not show, and the claim is marked not judged."""
    from ftcreport.cases import load_case, with_duration
    from ftcreport.evaluation.claims import evaluate_claims
    from ftcreport.report.render import _claims_shown

    full = load_case(Path(__file__).parent.parent / "cases" / "motors" / "two_link_active_motors.toml")
    case = with_duration(full, 5.0)
    run = {"scheme": "active", "status": "ok", "position_error_final": 0.774}
    claims = evaluate_claims(case.name, case.claims, {"active": run, "active_ukf": run | {"scheme": "active_ukf"}})
    shown = _claims_shown(case, claims, None, shortened=(5.0, full.simulation.duration))
    html = _page(claims=shown, runs=[run])
    row = html[html.index('id="claim-motor_dynamics_negligible"') :].split("</tr>")[0]
    assert "Measured 0.147 m (ideal plant 0.062 m)" in row  # the case's note, kept
    assert (
        "Written for the full 70 s run. This run was shortened to 5 s (--duration): the value above is at 5 s, "
        "so it does not show what the note describes, and the claim is not judged here"
    ) in row
    assert '<span class="badge none">not judged (run shortened to 5 s of 70 s)</span>' in row
    assert "expected reproduced" not in row
    unshortened = _claims_shown(full, claims, None)
    assert unshortened[0]["note"].startswith("Measured 0.147 m") and unshortened[0]["not_judged"] is None


def test_no_base_case_ratio_over_a_base_run_that_did_not_converge(tmp_path, monkeypatch):
    """The page audit: "Against the base case" divided this case's energy by the base run's although that run's
    step check (``run --verify-dt``, runner.dt_sensitivity: converged when every headline metric moves by at most
    1 % from dt to dt/2) did not converge: the ratio's denominator is the step's error as much as the scheme's.
    A ratio over a base run that did not converge is now withheld, the cell saying why and what moved; over a
    numerator that did not converge it is shown with that caveat."""
    from ftcreport.report import render

    (tmp_path / "base").mkdir()
    loose = _switching_run(energy=10.0, torque_peak_after_fault=4.0, verify_dt=_verify_dt((10.0, 13.0), (2.0, 2.5)))
    firm = _switching_run(energy=10.0, torque_peak_after_fault=4.0, verify_dt=_verify_dt((10.0, 10.01), (2.0, 2.0)))
    base = {"switching": loose, "nominal": firm | {"scheme": "nominal"}}
    monkeypatch.setattr(render, "stored_metrics", lambda out, name: base)
    this = [
        _switching_run(energy=20.0, torque_peak_after_fault=5.0),
        _switching_run(energy=20.0, torque_peak_after_fault=5.0, verify_dt=loose["verify_dt"]) | {"scheme": "nominal"},
    ]
    cmp = render.motor_comparison(tmp_path, "base", this)
    rows = {r["scheme"]: r for r in cmp["rows"]}
    energy = [k for k, *_ in render.BASE_METRICS].index("energy")
    cell = rows["switching"]["cells"][energy]
    assert cell["ratio"] is None and cell["relative"] == "withheld"
    assert "base run's step check did not converge" in rows["switching"]["caveat"]
    assert "energy 10 -> 13 J (+30.0% at the refined step)" in rows["switching"]["caveat"]
    assert rows["nominal"]["cells"][energy]["ratio"] == pytest.approx(2.0)  # a converged denominator
    assert "this run's step check did not converge" in rows["nominal"]["caveat"]
    html = _page(base_cmp=cmp, runs=this)
    table = html[html.index('id="base-compare"') :].split("</table>")[0]
    switching = table[table.index('<td class="l">switching</td>') :].split("</tr>")[0]
    assert "<b>2</b>" not in switching and "<td>10<br>20<br><b>withheld</b></td>" in switching
    assert "Ratio withheld: the base run&#39;s step check did not converge" in switching
    assert "energy 10 -&gt; 13 J (+30.0% at the refined step)" in switching
    nominal = table[table.index('<td class="l">nominal</td>') :].split("</tr>")[0]
    assert "<b>2</b>" in nominal and "this run&#39;s step check did not converge" in nominal


def test_the_estimates_figure_has_its_time_axis_under_the_lower_panel():
    """The session-11 look at the adaptive figure: its x axis was anchored to the upper panel, so its ticks and
    "t [s]" sat between the two panels, over the friction panel's top.  It is anchored to the lower one."""
    from ftcreport.report.interactive import estimates_fig

    ts, patterns = _adaptive_series(n_models=3, nw=2)
    fig = estimates_fig(ts, "adaptive", ["1r", "1l"], [], patterns)
    lay = fig["layout"]
    lower = min(("yaxis", "yaxis2"), key=lambda a: lay[a]["domain"][0])
    assert lower == "yaxis2" and lay["xaxis"].get("anchor") == "y2", lay["xaxis"]


def test_the_errors_figure_has_its_time_axis_under_the_lower_panel_with_room_for_its_title():
    """Session 12's new user: the tracking-errors figure's time axis sat between its two panels (the heading
    panel without time ticks), and in every two-panel time figure "t [s]" was drawn over the tick labels (the
    title kept inside the fixed bottom margin, the legend below it).  The axis is under the lower panel, and
    its margin grows to hold the title below the ticks (plotly's automargin, with a standoff)."""
    from ftcreport.report.interactive import errors_fig, estimates_fig

    t = np.linspace(0.0, 10.0, 50)
    q = np.zeros((50, 4))
    series = {"nominal": {"t": t, "q": q, "q_d": q + 0.1}}
    ts, patterns = _adaptive_series(n_models=3, nw=2)
    for fig in (errors_fig(series, []), estimates_fig(ts, "adaptive", ["1r", "1l"], [], patterns)):
        lay = fig["layout"]
        lower = min(("yaxis", "yaxis2"), key=lambda a: lay[a]["domain"][0])
        assert lower == "yaxis2" and lay["xaxis"].get("anchor") == "y2", lay["xaxis"]
        assert lay["xaxis"]["automargin"] is True and lay["xaxis"]["title"]["standoff"] > 0


def test_a_metric_from_the_first_fault_on_says_so_when_that_fault_acts_at_the_start():
    """Session 12's new user: on three_link_active (every fault at t = 0) the page said "the peak torque is
    ranked from the first fault on, so the start-up transient does not decide it", and the start-up decided
    it.  A metric taken from the first fault on says, under its name, that it includes the start-up when the
    first fault acts at 0 s; the caption no longer claims it never does."""
    from ftcreport.evaluation import compare
    from ftcreport.report.render import _verdict_rows

    runs = {
        s: {"status": "ok", "position_error_final": e, "torque_peak_after_fault": 2.0 + e,
            "phases": [{"t_start": 0.0, "t_end": 10.0, "position_error_max": e, "sigma": [1.0, 0.5]}]}
        for s, e in (("nominal", 0.01), ("adaptive", 0.05))
    }  # fmt: skip
    verdict = compare.compare_case("c", runs, {"ok"}, [0.0], {})
    notes = {r["key"]: r["note"] for r in _verdict_rows(verdict, 0.01, first_fault=0.0)}
    for key in ("after_fault_error_max", "torque_peak_after_fault"):
        assert "the first fault acts at 0 s: the start-up transient included" in notes[key], notes[key]
    later = {r["key"]: r["note"] for r in _verdict_rows(verdict, 0.01, first_fault=5.0)}
    assert "start-up transient included" not in later["torque_peak_after_fault"]
    html = (Path(__file__).resolve().parents[1] / "templates" / "case.html").read_text()
    assert "so the start-up transient does not decide it)" not in html


def test_a_metric_from_the_first_fault_on_says_when_the_start_up_has_not_settled_by_then():
    """Session 12's new user (M1): five_link_cascade's first fault (15 s) strikes before the start-up transient
    has decayed into the band, so the "max error after faults" ranks that decay.  The runs' error at the first
    fault (the end of the phase before it) above the recovery band is said under each metric taken from the
    first fault on; within the band, nothing is said."""
    from ftcreport.evaluation import compare
    from ftcreport.report.render import _verdict_rows, unsettled_at_first_fault

    def runs(before):
        return {
            s: {"status": "ok", "position_error_final": e, "torque_peak_after_fault": 2.0 + e, "phases": [
                {"start": 0.0, "end": 15.0, "fault": False, "position_error_final": b, "position_error_max": 0.3},
                {"start": 15.0, "end": 40.0, "fault": True, "position_error_final": e, "position_error_max": e}]}
            for s, e, b in (("nominal", 0.01, before), ("adaptive", 0.05, before / 2), ("active", 0.02, None))
        }  # fmt: skip

    late = runs(0.052)
    assert unsettled_at_first_fault(list(late.values()), 15.0, 0.01) == (0.052, 15.0)
    verdict = compare.compare_case("c", late, {"ok"}, [15.0], {})
    notes = {r["key"]: r["note"] for r in _verdict_rows(verdict, 0.01, 15.0, (0.052, 15.0))}
    said = "the start-up has not settled at the first fault (position error up to 0.052 m at 15 s, band 0.01 m)"
    for key in ("after_fault_error_max", "torque_peak_after_fault"):
        assert said in notes[key], notes[key]
    assert said not in notes["position_error_final"]
    assert unsettled_at_first_fault(list(runs(0.008).values()), 15.0, 0.01) is None
    assert unsettled_at_first_fault(list(late.values()), 0.0, 0.01) is None  # at 0 s: the note above says it
    assert unsettled_at_first_fault(list(late.values()), None, 0.01) is None


def test_page_numbers_between_1000_and_a_million_are_written_out():
    """The case page's analysis table read k_v "3e+03" (three significant digits in exponent form); a number from
    1,000 to a million reads as the whole number, others keep three significant digits."""
    from ftcreport.report.render import _fmt

    assert [_fmt(v) for v in (3000.0, 12345.6, -2500.0, 999.94, 2.5, 0.000123, 1.5e7, 559)] == [
        "3000", "12346", "-2500", "1000", "2.5", "0.000123", "1.5e+07", "559",
    ]  # fmt: skip
