"""HTML pages from stored results (Jinja2 templates in ``templates/``).

Reads only what the batch stored under the output directory::

    <case>/case.json            batch record: source, status, error, schemes, key, warnings
    <case>/case.toml            copy of the case file (provenance)
    <case>/<scheme>/metrics.json, timeseries.npz

and writes ``<case>/index.html`` and ``index.html`` atomically.  Pages are
self-contained (inline CSS, SVG, a few lines of JS for sorting): they work offline.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import functools
import hashlib
import json
import math
from importlib import resources
from pathlib import Path

import jinja2
import numpy as np

from .. import __version__
from ..cases import ordered_schemes
from ..errors import FtcError, StoredCaseChangedError, printable
from ..evaluation import compare
from ..evaluation.claims import bound_text
from ..evaluation.metrics import fault_phases
from ..evaluation.verdict_analysis import limit_words
from ..model.faults import wheel_names
from ..runner import integrator_words
from ..storage.store import load_timeseries, read_json, stored_metrics, stored_schemes, write_atomic
from ..studies.check import claim_item, evaluate, requirement_items, threshold_item
from . import interactive, plots
from .analysis_figs import analysis_section
from .checks import not_judged, ran_here, step_checks
from .plant import plant_block
from .replay import replay_data

__all__ = ["dependency_versions", "render_all", "render_case", "render_index"]


def _env() -> jinja2.Environment:
    loader = jinja2.FileSystemLoader(str(resources.files("ftcreport.templates")))
    env = jinja2.Environment(loader=loader, autoescape=jinja2.select_autoescape(["html"]), finalize=_no_controls)
    env.globals["fmt"] = _fmt
    return env


def _no_controls(value):
    """Every value a page prints with its control characters escaped (a file name or a stored reason may
    hold them; HTML shows them as nothing or breaks on them: issue 34 item 7); markup stays markup."""
    if hasattr(value, "__html__"):  # markupsafe.Markup (jinja2's): built again as markup
        return type(value)(printable(value, keep="\t\n\r"))
    return printable(value, keep="\t\n\r") if isinstance(value, str) else value


def _fmt(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "-"
    if isinstance(x, int | float):
        text = f"{x:.3g}"
        # 1,000 up to a million as the whole number: "3e+03" read as a code, not as a gain of 3000
        return f"{x:.0f}" if "e+" in text and abs(x) < 999_999.5 else text
    return str(x)


@functools.cache  # one lookup per process: every page of a report shows the same versions
def dependency_versions() -> str:
    from ..storage.manifest import _dist_version

    names = ["numpy", "scipy", "control", "numba", "matplotlib", "jinja2", "pydantic", "typer"]
    return f"ftcreport {__version__}; " + ", ".join(f"{n} {_dist_version(n) or '?'}" for n in names)


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def write_page(page: Path, template: str, root: str | None, **context) -> Path:
    """Render ``template`` with ``context``, the versions and the time, and write it to ``page`` atomically.

    ``root`` is the relative path from the page to the output directory (shared assets, links); None: the
    page has no index to link to (:func:`index_root`).
    """
    context.setdefault("versions", dependency_versions())
    html = _env().get_template(template).render(root=root, version=__version__, rendered=_now(), **context)
    write_atomic(page, html.encode())
    return page


def index_root(page_dir: Path, root: str = "../../") -> str | None:
    """``root`` when an index page exists there relative to ``page_dir``, else None (no link).

    A campaign, coverage or FDI page written into ``reports/<kind>/<case>/`` links the batch's index two
    levels up; under a custom ``--out`` there may be none, and a link to it would be broken.
    """
    return root if (Path(page_dir) / root / "index.html").is_file() else None


def figure(fig_id: str, caption: str, **drawing) -> dict:
    """A page figure: its id, its drawing (``svg=`` an SVG string or ``plotly=`` a figure spec), its caption."""
    return {"id": fig_id, **drawing, "caption": caption}


#: Captions' sentence on the shading (plots.fault_phases): every figure over time shades the same phases.
SHADING = (
    "Every phase with a fault is shaded, one color per pattern of wheel gains (the legend gives the gains), "
    "events dotted; an unshaded phase after a fault has every wheel healthy again."
)
#: Captions' sentence on the three columns of the per-wheel figures (interactive.band_fig).
BAND_COLUMNS = (
    "Left: the first second (the start-up transient at its own scale); middle: the whole run, each "
    "line the mean of a bucket of samples with its min-max range as a band (chatter reads as a band "
    "of its amplitude), the axis scaled on the samples from the first fault on (from t = 1 s without a "
    "fault), so what comes before may run off it; right: 60 logged samples from the first fault, every "
    "sample (the chatter's shape)."
)


def _fault_rows(case, sched, names) -> list[dict]:
    """The fault timeline: each event and the gain of every wheel from then on (partial gains as they are)."""
    rows = []
    for f in case.faults:
        sigma, ubar = sched.at(f.time)
        failed = [w for w, x in zip(names, sigma, strict=True) if x == 0.0]
        partial = [f"{w} {x:.3g}" for w, x in zip(names, sigma, strict=True) if 0.0 < x < 1.0]
        notes = [f"{what}: {', '.join(ws)}" for what, ws in (("failed", failed), ("partial", partial)) if ws]
        rows.append(
            {
                "time": f.time,
                "wheel": f.wheel,
                "sigma": f.sigma,
                "ubar": f.ubar,
                "motor": f.motor,
                "pattern": " ".join(f"{x:.3g}" for x in sigma) + (f"  ({'; '.join(notes)})" if notes else ""),
                "frictions": " ".join(f"{x:.3g}" for x in ubar) if any(ubar != 0.0) else "",
            }
        )
    return rows


def armature_voltages(case, series: dict) -> dict:
    """The drive's armature voltages per scheme on its log times, (K, 2n) [V], for a case with motors.

    Rebuilt from what is logged through the functions the loop calls (model.drive_compiled): the command u with
    the fault gains and frictions gives tau_c; the wheel speeds Bbar(q)^T eta give the drive's current
    target i* (``current_target``, with the drive's own model of the motor, [actuators.drive_model]); the
    static driver's voltage is ``static_voltage`` of it, a PI drive's is ``drive_output`` of i* and its
    logged states (the current and the integral part; the sampled PI's held voltage is itself a logged
    state, exact at every instant).  Exact at a logged instant that is a sample instant (or every
    instant with continuous control) of a noise-free run with no measurement delay and the controller's
    model equal to the plant's; otherwise the drive saw the state of its last sample, measured, so the
    figure's caption says it is approximate.
    """
    from ..fast.engine import wheel_speeds_rows
    from ..model.actuators import pack_drive
    from ..model.drive_compiled import DRIVER_PI_SAMPLED, DRIVER_STATIC, current_target, drive_output, static_voltage
    from ..runner import build

    if case.actuators is None:
        return {}
    built = build(case)
    dr = pack_drive(case.drive_params(), case.motor_params(), case.robots.n)
    sched = built.faults
    sat = case.plant.saturation
    out = {}
    for s, ts in series.items():
        if "i_a" not in ts or "u" not in ts:
            continue
        u = np.asarray(ts["u"], float)
        us = u if sat is None else np.clip(u, -sat, sat)
        tau_c = np.asarray(ts["sigma"], float) * us + np.asarray(ts["ubar"], float)
        omega = wheel_speeds_rows(built.chain, ts["q"], ts["eta"])
        xm = np.asarray(ts["i_a"], float)
        if "z_drive" in ts:
            xm = np.concatenate((xm, np.asarray(ts["z_drive"], float)), axis=1)
        volts = []
        for k, t in enumerate(ts["t"]):
            fault = sched.motor(float(t))
            i_star = current_target(dr, tau_c[k], omega[k]) if dr.kind != DRIVER_PI_SAMPLED else np.zeros(0)
            if dr.kind == DRIVER_STATIC:
                volts.append(static_voltage(dr, i_star, omega[k], fault))
            else:
                volts.append(drive_output(dr, np.ascontiguousarray(xm[k]), i_star, omega[k], fault)[0])
        out[s] = np.array(volts)
    return out


def _motor_figure(case, series: dict, names: list[str], shading: list[dict], main: str) -> dict | None:
    """Armature voltage and current per wheel with the driver's limits (a case with [actuators])."""
    if case.actuators is None or not any("i_a" in ts for ts in series.values()):
        return None
    volts = armature_voltages(case, series)
    motors = case.motor_params()
    v_max = max(float(m.V_max) for m in motors)
    i_lim = [float(m.I_max) for m in motors if m.I_max is not None and math.isfinite(m.I_max)]
    i_max = max(i_lim) if i_lim else None
    noise = case.plant.noise
    exact = case.simulation.measurement_delay == 0 and not (noise.position or noise.heading or noise.velocity)
    sampled = case.simulation.sample_time is not None
    how = (
        "rebuilt from the logged command, wheel speeds and drive states through the drive's own functions "
        "(those the engine calls; not logged)"
        + (
            ", exact at the sample instants"
            if exact and sampled
            else ", exact at every logged instant"
            if exact
            else ", approximate: the driver saw noisy or delayed measurements"
        )
    )
    limits = f"+-{v_max:g} V" + (f" and +-{i_max:g} A" if i_max is not None else " (no current limit set)")
    return figure(
        "motors",
        f"Armature voltage (top; {how}) and current (bottom, logged) per wheel, with the driver's limits {limits} "
        f"dashed in red; the menu picks the scheme. {BAND_COLUMNS} {SHADING}",
        plotly=interactive.motors_fig(series, volts, names, shading, main, v_max, i_max),
    )


def _after_max(m: dict) -> float | None:
    vals = [p["position_error_max"] for p in fault_phases(m.get("phases")) if p.get("position_error_max") is not None]
    return max(vals) if vals else None


def _after_na(m: dict) -> str:
    """Why a run has no "max error after faults" when it applies to no fault ('' otherwise): the page
    says "n/a" with it, as the verdict does (compare.NOT_APPLICABLE), rather than a bare "-"."""
    return compare.NOT_APPLICABLE if compare.fault_free(m) else ""


def _run_files(out: Path, name: str, scheme: str) -> list[str]:
    """The files of a stored run, relative to its case page (``<scheme>/<file>``), by name."""
    folder = out / name / scheme
    return sorted(f"{scheme}/{f.name}" for f in folder.iterdir() if f.is_file()) if folder.is_dir() else []


def _record(out: Path, name: str) -> dict | None:
    """The case record, or None when missing or not a record (``report`` names it: store.unrecorded_cases)."""
    rec = read_json(out / name / "case.json")
    return rec if isinstance(rec, dict) else None


#: What the index and the case page say of a case whose record is a rejection (``case.json``'s status
#: ``error``) while runs of an earlier version of its file are still stored beside it (:func:`stale_runs`).
STALE_RUNS = (
    "case file rejected by the last batch that read it: its stored runs are from an earlier version of the file"
)


def stale_runs(out: Path, name: str, rec: dict) -> dict[str, dict]:
    """The runs stored under a case whose current file was rejected: ``{scheme: metrics}``, or ``{}``.

    The rule: a batch that rejects a case file overwrites the case's record (``case.json``) with the
    rejection (status ``error``: studies.batch._record_error; under the file's stem and under every case
    stored from that file, as its ``name`` field named it) and leaves its stored runs alone (results are
    never deleted).  So a record whose status is ``error`` means the last batch that read the file rejected
    it, and any runs stored beside that record were made from an earlier version of the file: they are
    *stale*.  The index leaves them out of its headline counts, thresholds, claims, scoreboard and winners
    and lists them marked :data:`STALE_RUNS`; the case page links their files.  A later batch that accepts
    the file writes a valid record again, and the runs count again (re-run when the file changed: their key).
    """
    if rec.get("status") != "error":
        return {}
    return stored_metrics(out, name)


def render_case(out: Path, name: str, root: str = "../", nav: str = "all cases") -> Path | None:
    """Render ``<out>/<name>/index.html``; returns its path (None if the case has no record).

    ``root``: the page's way to the top of the report (its navigation link, ``nav``, goes there).
    """
    out = Path(out)
    rec = _record(out, name)
    if rec is None:
        return None
    page = out / name / "index.html"
    if rec.get("status") == "error" or not (out / name / "case.toml").exists():
        old = stale_runs(out, name, rec)
        return write_page(
            page,
            "case.html",
            root,
            nav_label=nav,
            name=name,
            description=rec.get("error", ""),
            n_phases=0,
            key=rec.get("key", "-"),
            simulated=rec.get("time", "-"),
            case_text=rec.get("source_text", ""),
            stale_runs={s: m | {"files": _run_files(out, name, s)} for s, m in old.items()},
            stale_note=STALE_RUNS,
            stale_copy=(out / name / "case.toml").is_file(),
        )
    from ..storage.store import load_stored_case

    try:
        case = load_stored_case(out, name, rec)
    except StoredCaseChangedError as exc:  # (damaged: FtcError, named, the report stops)
        # edited after its runs, or hashed otherwise by other code: the page says so and shows nothing of the
        # stored file as the runs' (report and export name it and exit 1: store.edited_cases)
        return write_page(page, "case.html", root, nav_label=nav, name=name, description=str(exc), n_phases=0,
                          key=rec.get("key", "-"), simulated=rec.get("time", "-"), case_text="")  # fmt: skip
    text = (out / name / "case.toml").read_text(encoding="utf-8")  # read by load_stored_case just now
    runs, series = [], {}
    for s, m in stored_metrics(out, name).items():
        m = dict(m)
        m["after_max"] = _after_max(m)
        m["after_na"] = _after_na(m)
        sm = m.get("singularity_margin_min")
        m["margin_deg"] = None if sm is None else math.degrees(sm)
        runs.append(m)
        ts = load_timeseries(out, name, s)
        if ts is not None and ts.get("t") is not None and ts["t"].size > 1:
            series[s] = ts
    checks = evaluate(name, case.thresholds, {m["scheme"]: m for m in runs})
    sched = case.fault_schedule()
    events = [float(t) for t in sched.times]
    names = wheel_names(case.robots.n)
    faults = _fault_rows(case, sched, names)
    phases = sched.phases(case.simulation.duration)
    shading = plots.fault_phases(sched, case.simulation.duration, list(names))
    figures = []
    if series:
        d = case.robots.values("d")
        b = case.robots.values("b")[0]
        figures.append(
            figure(
                "paths",
                "Path of the last robot's axle midpoint P_n for every scheme over the reference.",
                svg=plots.paths_svg(series, d, events, b),
            )
        )
        figures.append(
            figure(
                "errors",
                "Tracking errors per scheme (log scale; hover for values, drag to zoom, double-click to "
                f"reset). {SHADING}",
                plotly=interactive.errors_fig(series, shading),
            )
        )
        main = next((s for s in (*compare.CONTESTANTS, compare.BOUND) if s in series), next(iter(series)))
        figures.append(
            figure(
                "torques",
                f"Applied wheel torques; the menu at the top right picks the scheme. {BAND_COLUMNS} {SHADING}",
                plotly=interactive.torques_fig(series, list(names), shading, main),
            )
        )
        motors = _motor_figure(case, series, list(names), shading, main)
        if motors is not None:
            figures.append(motors)
        for sw in [s for s in series if "selected" in series[s]]:  # a scheme that switches between models
            pats = next((m.get("patterns") for m in runs if m["scheme"] == sw), None)
            if pats:
                figures.append(
                    figure(
                        sw,
                        "Applied model index against the true failure pattern.",
                        plotly=interactive.switching_fig(series[sw], pats, shading, sw),
                    )
                )
        for est in [s for s in series if "chi_hat" in series[s] or "rho_hat" in series[s]]:  # weights, estimates
            pats = next((m.get("patterns") for m in runs if m["scheme"] == est), None)
            spec = interactive.estimates_fig(series[est], est, list(names), shading, pats)
            if spec is None:
                continue
            cap = (
                f"{est}: weights and friction estimate ubar_hat against the true ubar (dashed); they are control "
                "variables of the adaptive law, not a fault diagnosis (ERRATA P2)."
                if "chi_hat" in series[est]
                else f"{est}: estimated gains and frictions against the truth (dashed). Individual parameters are "
                "weakly identifiable in steady tracking; the combined effect Mbar1^-1 Bbar (diag(rho) u + ubar) is "
                "what the data determine (P3)."
            )
            figures.append(figure(est, cap, plotly=spec))
        figures.extend(_thesis_figures(case, series, list(names), shading))
        figures.append(
            figure(
                "articulation",
                f"Articulation angles with the singular configuration at +/-90 deg. {SHADING}",
                svg=plots.articulation_svg(series, shading),
            )
        )
    base_cmp = motor_comparison(out, rec.get("base"), runs) if rec.get("base") else None
    if base_cmp and base_cmp["rows"] and series:
        both = {}
        for s in series:
            ts = load_timeseries(out, base_cmp["base"], s)
            if ts is not None and ts.get("t") is not None and ts["t"].size > 1:
                both[f"{s} (this case)"] = series[s]
                both[f"{s} (base)"] = ts
        if both:
            figures.append(
                figure(
                    "base",
                    f"Tracking errors of this case and of its base case {base_cmp['base']}, scheme by scheme "
                    "(the legend toggles a trace).",
                    plotly=interactive.errors_fig(both, shading),
                )
            )
    analysis = analysis_section(case, names, series, events)  # templates/_analysis.html (issue 37)
    diagnosis = [m for m in runs if m.get("detection_events") is not None]
    from .requirements_page import requirements_section

    requirements = requirements_section(case, runs, series)
    claims = _claims(name, case, runs)
    verdict = _verdict(case, name, runs, analysis)
    manifest = _manifest(out, name)
    ran = ran_here(manifest)  # `run --scheme`: the items on other schemes are not judged (as run does)
    gate = _gate_failures(name, case, runs, checks, claims, ran)
    gate_skipped = None
    if gate and rec.get("duration_override") is not None:  # `run --duration`: the gate is not judged
        gate, gate_skipped = (
            None,
            (
                f"The case's thresholds, claims and requirement windows are stated for its own duration; this run "
                f"was shortened to {rec['duration_override']:g} s (--duration), so they are not judged here "
                "(ftcreport check judges them)."
            ),
        )
    shortened = None  # `--duration`: the claims' notes are written for the case's own duration
    if rec.get("duration_override") is not None:
        shortened = (float(rec["duration_override"]), _full_duration(text, rec.get("source", name)))
    base_verdict = None
    if verdict and rec.get("base") and (out / rec["base"]).is_dir():
        base_case = _stored_case(out, rec["base"], _record(out, rec["base"]) or {})
        base_runs = [m | {"scheme": s} for s, m in stored_metrics(out, rec["base"]).items()]
        if base_case is not None and base_runs:
            base_verdict = _verdict(base_case, rec["base"], base_runs)
    for m in runs:  # the schemes table: simulation without compiling, compiling apart (fast.engine)
        c = m.get("compile_time")
        m["compile_s"] = c
        m["run_s"] = None if m.get("wall_time") is None or c is None else max(0.0, m["wall_time"] - c)
    replay = None
    if series:
        from ..cases import build_plant_chain

        replay = replay_data(
            series, build_plant_chain(case), faults, list(names), {m["scheme"]: m["status"] for m in runs}
        )
    plant = plant_block(case, runs, series, out, rec.get("base"))  # templates/_plant.html (issue 36)
    first = min((float(f.time) for f in case.faults), default=None)
    return write_page(
        page,
        "case.html",
        root,
        nav_label=nav,
        verdict=verdict,
        gate=gate,
        gate_skipped=gate_skipped,
        verdict_rows=_verdict_rows(
            verdict, case.recovery_band, first, unsettled_at_first_fault(runs, first, case.recovery_band)
        )
        if verdict
        else [],
        recovery_band=case.recovery_band,
        not_run=rec.get("not_run", {}),
        plugin_schemes=rec.get("plugin_schemes", {}),
        replay_json=_script_json(replay) if replay else None,
        replay_schemes=list(replay["schemes"]) if replay else [],
        scheme_colors=plots.SCHEME_COLORS,
        plotly_inline=interactive.inline_plotly()
        if any(f.get("plotly") for f in [*figures, *((requirements or {}).get("figures") or [])])
        or ((plant or {}).get("identification") or {}).get("figure")
        else None,
        oracle_notes=oracle_notes(verdict, case, base_verdict) if verdict else [],
        shading=shading,
        name=name,
        analysis=analysis,
        diagnosis=diagnosis,
        claims=_claims_shown(case, claims, ran, shortened),
        description=case.description,
        n=case.robots.n,
        reference=case.reference.kind,
        kinematic=case.kinematic.kind,
        duration=case.simulation.duration,
        dt=case.simulation.dt,
        method=case.simulation.method,
        log_every=case.simulation.log_every,
        engines=", ".join(f"{m['scheme']} {m['engine']}" for m in runs if "engine" in m),
        integrators="; ".join(f"{m['scheme']}: {integrator_words(m)}" for m in runs if m.get("integrator")),
        warnings=rec.get("warnings", []),
        faults=faults,
        runs=runs,
        n_phases=len(phases),
        phase_labels=[f"{a:g}-{b:g}" for a, b in phases],
        checks=checks,
        requirements=requirements,
        figures=figures,
        key=rec.get("key", "-"),
        simulated=rec.get("time", "-"),
        case_text=text,
        manifest=manifest,
        step_checks=step_checks(runs),
        base_cmp=base_cmp,
        plant=plant,
    )


#: Headline metrics of the motors-on / motors-off comparison: key, label, unit.
BASE_METRICS = (
    ("after_max", "max position error after the first fault", "m", "after_fault_error_max"),
    ("position_error_final", "final position error", "m", "position_error_final"),
    ("torque_peak_after_fault", "peak wheel torque after the first fault", "N m", "torque_peak_after_fault"),
    ("energy", "mechanical energy at the wheels, integral of sum |tau omega| (start-up included)", "J", "energy"),
)


def motor_comparison(out: Path, base: str, runs: list[dict]) -> dict:
    """This case (an overlay, e.g. motors on) against its base case's stored runs, scheme by scheme.

    Rows: every scheme both ran; per headline metric the base's value, this case's and the ratio
    this / base, or the difference this - base when the base's value is below the metric's resolution
    floor (compare.MetricSpec.floor).  ``missing`` says why there is nothing to compare.
    """
    theirs = stored_metrics(Path(out), base) if (Path(out) / base).is_dir() else {}
    if not theirs:
        return {"base": base, "rows": [], "missing": f"the base case '{base}' has no runs in this report"}
    rows = []
    for m in runs:
        b = theirs.get(m["scheme"])
        if b is None:
            continue
        b = dict(b) | {"after_max": _after_max(b)}
        # a run whose step check (run --verify-dt: runner.dt_sensitivity) did not converge: its metrics are the
        # step's error as much as the scheme's; no ratio over such a denominator, a caveat over a numerator
        loose = {side: _not_converged(run | {"scheme": m["scheme"]}) for side, run in (("base", b), ("this", m))}
        cells = []
        for key, _label, unit, spec_key in BASE_METRICS:
            x, y = m.get(key), b.get(key)
            x, y = (v if isinstance(v, int | float) else None for v in (x, y))
            spec = compare.SPECS[spec_key]
            r, tie = compare.ratio(x, y, spec)  # None when the base is below the metric's resolution floor
            d = compare.difference(x, y) if r is None and not tie else None
            if loose["base"] is not None:
                r, tie, d = None, False, None
            rel = compare.fmt_ratio(r, tie) if r is not None or tie else (f"{d:+.3g} {unit}" if d is not None else "-")
            if loose["base"] is not None and x is not None and y is not None:
                rel = "withheld"
            cells.append({"base": y, "this": x, "ratio": r, "relative": rel, "difference": d is not None})
        caveat = " ".join(
            f"{'Ratio withheld: the base' if side == 'base' else 'Caveat: this'} run's step check did not converge "
            f"({why})."
            for side, why in loose.items()
            if why is not None
        )
        rows.append(
            {
                "scheme": m["scheme"],
                "status": m["status"],
                "base_status": b.get("status"),
                "cells": cells,
                "caveat": caveat or None,
            }
        )
    return {"base": base, "rows": rows, "metrics": BASE_METRICS, "missing": None if rows else "no scheme in common"}


def _not_converged(m: dict) -> str | None:
    """What moved in a run's step check (``run --verify-dt``) that did not converge, or None: no check, or it
    converged (runner.dt_sensitivity decides; report.checks.step_checks words it)."""
    check = step_checks([m])
    if not check or check[0]["converged"]:
        return None
    return "; ".join(check[0]["moved"]) or check[0]["text"]


def _thesis_figures(case, series: dict, names: list[str], shading: list[dict]) -> list[dict]:
    """Per-robot velocities (Figs 4.7/4.8, 4.17/4.18), u against tau and the estimated path for the
    active schemes (Figs 4.5/4.6, 4.14-4.16, 4.9a)."""
    from ..cases import build_plant_chain

    figs = []
    active = [s for s in series if "q_hat" in series[s]]  # the schemes with an estimator of q and eta
    main = active[0] if active else next((s for s in compare.CONTESTANTS if s in series), next(iter(series)))
    figs.append(
        figure(
            "velocities",
            f"Linear and angular velocity of each robot, {main} scheme, from the logged q and eta "
            "through the chain kinematics (thesis Figs 4.7/4.8, 4.17/4.18). Above 1200 samples a line is "
            "each bucket's mean with its min-max band (chatter reads as a band of its amplitude); the "
            f"axes are scaled on t >= 1 s, so the start-up transient may run off them. {SHADING}",
            svg=plots.velocities_svg(series[main], build_plant_chain(case), shading, main),
        )
    )
    for act in active:
        figs.append(
            figure(
                f"{act}-control",
                f"{act}: commanded control u against the applied torque tau = sigma sat(u) + ubar, "
                "per robot (thesis Figs 4.5/4.6, 4.14-4.16).",
                svg=plots.control_torque_svg(series[act], names, shading, act, case.plant.saturation),
            )
        )
        figs.append(
            figure(
                f"{act}-path",
                f"{act}: reference, true and estimated (q_hat) path of P_n (thesis Fig. 4.9a).",
                svg=plots.estimated_path_svg(series[act], act),
            )
        )
    return figs


def _claims(name: str, case, runs: list[dict]) -> list:
    """The case's thesis claims evaluated against its runs (ftcreport.evaluation.claims), for the page."""
    from ..evaluation.claims import evaluate_claims

    return evaluate_claims(name, case.claims, {m["scheme"]: m for m in runs})


def _manifest(out: Path, name: str) -> dict | None:
    """The case's provenance manifest (``<case>/manifest.json``, written by batch and run), or None."""
    m = read_json(out / name / "manifest.json")
    return m if isinstance(m, dict) and "ftcreport" in m else None


def _manifest_stamp(out: Path, name: str) -> bytes:
    """What of the manifest a page shows, without the times and cache flags that change every batch."""
    m = _manifest(out, name)
    if m is None:
        return b"-"
    keep = {k: v for k, v in m.items() if k not in ("created", "runs", "settings")}
    keep["runs"] = [{k: r.get(k) for k in ("scheme", "engine", "status", "key", "seed")} for r in m.get("runs", [])]
    settings = m.get("settings") or {}
    keep["ran"] = [settings.get("command"), settings.get("schemes")]  # `run --scheme`: what the page judges
    return json.dumps(keep, sort_keys=True).encode()


def _gate_failures(name: str, case, runs: list[dict], checks: list, claims: list, ran: set[str] | None = None):
    """The case's thresholds, claims and requirement windows that do not hold, for the verdict's opening.

    The same gate items ``run`` and ``check`` judge (:mod:`ftcreport.studies.check`): ``{"n", "lines",
    "not_judged"}`` with the number of items judged, one line per failed item (which item, the scheme, the
    value against the bound) and one per item not judged, or None when none is stated.  ``ran``: the
    schemes of the ``ftcreport run`` that stored the page (:func:`ran_here`); an item reading another
    scheme is not judged, as ``run`` does not judge it (README, exit codes).
    """
    metrics = {m["scheme"]: m for m in runs}
    items = [(threshold_item(r), r) for r in checks]
    items += [(claim_item(c, i, _relative_to(case, i)), None) for i, c in enumerate(claims)]
    items += [(item, None) for item in requirement_items(name, case.requirements, metrics)]
    if not items:
        return None
    lines, skipped, n = [], [], 0
    for item, r in items:
        why = not_judged(item.schemes, ran)
        if why is not None:
            skipped.append(f"{item.name if r is None else f'threshold {r.scheme} / {r.metric}'}: {why}")
            continue
        n += 1
        if item.ok:
            continue
        if r is not None:
            got = r.reason if r.actual is None else f"{r.actual:.4g} against {bound_text(r.min, r.max)}"
            lines.append(f"threshold {r.scheme} / {r.metric}: {got}")
        elif item.kind == "claim":
            lines.append(f"{item.name}: {item.message}")
        elif item.kind == "requirement":
            lines.append(f"requirement {item.name.replace(' / requirement ', ' / ', 1)}: {item.message}")
    return {"n": n, "lines": lines, "not_judged": skipped, "ran": sorted(ran or ())}


def _relative_to(case, index: int) -> str | None:
    """The other scheme claim ``index`` of the case reads (its ``relative_to``), or None."""
    return getattr(case.claims[index], "relative_to", None) if index < len(case.claims) else None


def _claims_shown(
    case, claims: list, ran: set[str] | None, shortened: tuple[float, float | None] | None = None
) -> list[dict]:
    """The evaluated claims for the page's table, each with ``not_judged`` (:func:`not_judged`).

    ``shortened``: (the run's duration, the case's own or None) of a run shortened by ``--duration``: a
    claim's note is written for the case's own duration, so each claim gets ``duration_note`` saying so and
    what the shortened run does not show, and is not judged (as the verdict's gate)."""
    shown = []
    for i, c in enumerate(claims):
        schemes = [s for s in (c.scheme, _relative_to(case, i)) if s]
        row = dataclasses.asdict(c) | {"not_judged": not_judged(schemes, ran), "duration_note": None}
        if shortened is not None:
            d, full = shortened
            of = f" of {full:g} s" if full is not None else ""
            row["not_judged"] = row["not_judged"] or f"not judged (run shortened to {d:g} s{of})"
            whole = f"the full {full:g} s run" if full is not None else "the case's full duration"
            row["duration_note"] = (
                f"{'Written for ' + whole + '. ' if c.note else ''}This run was shortened to {d:g} s (--duration): "
                f"the value above is at {d:g} s, so it does not show what "
                f"{'the note describes' if c.note else 'the claim is about over ' + whole}, and the claim is not "
                "judged here (ftcreport check judges it on the full run)."
            )
        shown.append(row)
    return shown


def _full_duration(text: str, source: str) -> float | None:
    """The duration of a stored case file as written (before ``--duration``), or None if it does not parse."""
    import tomllib

    from ..cases import parse_case

    try:
        return float(parse_case(tomllib.loads(text), source).simulation.duration)
    except (ValueError, FtcError):
        return None


def _facts(case) -> dict:
    """Facts of a case the verdict's sentences may explain with (compare.compare_case)."""
    return {
        "friction": any(f.ubar != 0 for f in case.faults),
        "fractional": any(0 < f.sigma < 1 for f in case.faults),
        "uncompensable": bool(case.warnings()),
        "follower_only": bool(case.faults) and all(not f.wheel.strip().startswith("1") for f in case.faults),
        "limit": limit_words(case),
        "recovery_band": case.recovery_band,
    }


def _verdict(case, name: str, runs: list[dict], analysis: dict | None = None):
    if not runs:
        return None
    events = sorted({float(f.time) for f in case.faults})
    by_scheme = {m["scheme"]: m for m in runs}
    expected = {s: case.expected_for(s) for s in by_scheme}
    facts = _facts(case) | ({"analysis": analysis} if analysis and not analysis.get("error") else {})
    return compare.compare_case(name, by_scheme, expected, events, facts)


#: a metric taken "from the first fault on" includes the start-up transient when that fault acts at the start
FROM_FIRST_FAULT = "from the first fault on"


def unsettled_at_first_fault(runs: list[dict], first_fault: float | None, band: float | None):
    """(the largest position error [m] of the runs at the first fault, its time [s]) when it is above the
    recovery band (``compare.startup_at_first_fault``): a metric taken from the first fault on then includes the
    start-up's decay; else None (also for a first fault at 0 s, which :func:`_verdict_rows` says otherwise)."""
    if first_fault is None or first_fault <= 0.0:
        return None
    got = compare.startup_at_first_fault({str(i): m for i, m in enumerate(runs)}, band)
    return (got["error"], got["t"]) if got and got["above_band"] else None


def _verdict_rows(
    v, band: float | None = None, first_fault: float | None = None, unsettled: tuple[float, float] | None = None
) -> list[dict]:
    """One row per headline metric: winners, their value, regret, benefit, the ranking in words
    (``band``: the case's recovery band [m], stated under the recovery time; ``first_fault``: the first
    fault's time [s], under a metric taken from it on when it is 0: the start-up is in it then; ``unsettled``:
    :func:`unsettled_at_first_fault`, said under such a metric: the start-up's decay is in it)."""
    rows = []
    at_start = first_fault is not None and first_fault <= 0.0
    decay = (
        f"; the start-up has not settled at the first fault (position error up to {unsettled[0]:.3g} m at "
        f"{unsettled[1]:g} s, band {band:g} m): its decay included"
        if unsettled and band
        else ""
    )
    for spec in compare.HEADLINE:
        mv = v.metrics.get(spec.key)
        if mv is None:
            continue
        rank = "; ".join(
            f"{r.rank}. {r.scheme} {compare.fmt_value(r.value)}" + (f" ({r.note})" if r.note and r.scheme else "")
            for r in mv.ranking
        )
        extra = [f"{s}: {st}" for s, st in mv.failed] + [f"{s}: {why}" for s, why in mv.missing]
        if mv.not_applicable:  # one reason for every run: said once, as the winner's cell
            extra = [f"{s}: {st}" for s, st in mv.failed]
        rows.append(
            {
                "key": spec.key,
                "label": spec.label + (f" [{spec.unit}]" if spec.unit else ""),
                "winners": f"n/a ({mv.not_applicable})" if mv.not_applicable else ", ".join(mv.winners) or "none",
                "tie": len(mv.winners) > 1,
                "best": compare.fmt_best(mv),
                "regret": compare.fmt_relative(mv, "regret"),
                "benefit": compare.fmt_relative(mv, "benefit"),
                "note": spec.note
                + (f"; recovery band: position error <= {band:g} m" if band and spec.key == "recovery_time_max" else "")
                + (
                    "; the first fault acts at 0 s: the start-up transient included"
                    if at_start and spec.note.startswith(FROM_FIRST_FAULT)
                    else ""
                )
                + (decay if spec.note.startswith(FROM_FIRST_FAULT) else ""),
                "ranking": rank,
                "unranked": "; ".join(extra),
                "tolerance": f"{100 * spec.rel_tol:g} % or {spec.abs_tol:g}" if spec.rel_tol else "exact",
            }
        )
    return rows


def oracle_notes(v, case, base_verdict=None) -> list[str]:
    """Why the oracle is beaten (regret < 1 beyond the tolerance), from the data.

    The oracle knows the true faults at once and applies the law matched to them (for the ideal plant:
    torques applied as commanded, continuous control).  With a base case (the same case on the ideal
    plant) the note says on which of these metrics the oracle led there: the evidence that this case's
    plant (motors, sampling) is what makes it no bound.  Otherwise it says only what holds for every
    case: the matched law is a reference, not the optimum of each metric.
    """
    plant = []
    if case.actuators is not None:
        plant.append("DC motors behind a voltage-limited driver")
    if case.simulation.sample_time is not None:
        plant.append(f"control sampled every {case.simulation.sample_time * 1e3:g} ms")
    beaten = [
        mv
        for mv in v.metrics.values()
        if mv.regret is not None and not mv.regret_tie and mv.regret < 1.0 and mv.winners
    ]
    if not beaten:
        return []

    def one(mv) -> str:
        u = mv.spec.unit
        return (
            f"{mv.spec.label} ({_names(mv.winners)} {compare.fmt_best(mv, u)} against the oracle's "
            f"{compare.fmt_value(mv.oracle, u)}, regret {compare.fmt_ratio(mv.regret)})"
        )

    def there(mv) -> str:
        b, u = base[mv.spec.key], mv.spec.unit
        return f"{mv.spec.label}: oracle {compare.fmt_value(b.oracle, u)}, best other {compare.fmt_value(b.best, u)}"

    base = {mv.spec.key: base_verdict.metrics.get(mv.spec.key) for mv in beaten} if base_verdict and plant else {}
    led = [
        mv
        for mv in beaten
        if (b := base.get(mv.spec.key)) is not None
        and b.oracle is not None
        and (b.regret_tie or b.regret is None or b.regret >= 1.0)
    ]
    rest = [mv for mv in beaten if mv not in led]
    out = []
    if led:
        out.append(
            f"The oracle is beaten here on {'; '.join(one(mv) for mv in led)}. On the base case {base_verdict.case} "
            f"(ideal torques, continuous control) it leads or ties on each ({'; '.join(there(mv) for mv in led)}): "
            f"its law is matched to that plant, and with {' and '.join(plant)} it is no bound."
        )
    if rest:
        why = f"; and it was derived for the ideal plant, not for {' and '.join(plant)}" if plant and not led else ""
        out.append(
            f"The oracle is beaten on {'; '.join(one(mv) for mv in rest)}: its law, matched to the true faults, is a "
            f"reference for tracking, not the optimum of every metric{why}."
        )
    return out


def _names(schemes) -> str:
    return ", ".join(compare.LABEL.get(s, s) for s in schemes)


def _script_json(obj) -> str:
    """JSON safe inside a <script> element."""
    return json.dumps(obj, separators=(",", ":")).replace("</", "<\\/")


def render_index(out: Path) -> Path:
    """Render ``<out>/index.html`` from every case record under ``out``, with links to every other
    page there (campaign, coverage, FDI, baseline pages: :func:`other_pages`).

    A case whose file the last batch that read it rejected keeps its row, but the runs stored beside it
    are of an earlier version of that file (:func:`stale_runs`): they are listed marked stale, and left out
    of the headline counts, the thresholds, the claims, the scoreboard and the winners."""
    out = Path(out)
    cases = []
    verdicts = []
    claims: list = []
    plugins: dict[str, dict] = {}  # plug-in schemes' family, description, reference (batch.plugin_info)
    n_runs = n_ok = n_pass = n_fail = n_expected_stop = n_unexpected = 0
    n_req_pass = n_req_fail = n_req_unjudged = 0  # requirement windows
    n_unjudged = claims_unjudged = 0  # a shortened run's gate (`run --duration`): its case page does not judge it
    rejected: set[str] = set()  # case files the last batch that read them rejected (their records' source)
    n_stale = 0  # runs stored of their earlier versions
    for rec_path in sorted(out.glob("*/case.json")):
        name = rec_path.parent.name
        rec = _record(out, name)
        if rec is None:  # not a case record: `report` names it (store.unrecorded_cases)
            continue
        entry = {
            "name": name,
            "n": rec.get("n", "?"),
            "reference": rec.get("reference", "?"),
            "error": rec.get("error") if rec.get("status") == "error" else None,
            "runs": {},
        }
        if entry["error"] is not None:  # its runs, if any, are of an earlier version of the file: not counted
            old = stale_runs(out, name, rec)
            entry["stale_runs"] = {
                s: m | {"after_max": _after_max(m), "after_na": _after_na(m)} for s, m in old.items()
            }
            rejected.add(str(rec.get("source", name)))
            n_stale += len(old)
            cases.append(entry | {"not_run": {}})
            continue
        metrics = stored_metrics(out, name)
        n_runs += len(metrics)
        n_ok += sum(m.get("status") == "ok" for m in metrics.values())
        # the gate's items from the stored case file (its content hash checked against its runs'), not from
        # case.json's copy, which nothing seals: as the case page and check read them
        case = _stored_case(out, name, rec) if (out / name / "case.toml").exists() else None
        thresholds = case.thresholds if case is not None else rec.get("thresholds") or {}
        checks = evaluate(name, thresholds, metrics) if thresholds else []
        windows = requirement_items(name, case.requirements, metrics) if case is not None else []
        shortened = rec.get("duration_override") is not None
        for s, m in metrics.items():
            mine = [c for c in checks if c.scheme == s]
            failed = sum(not c.ok for c in mine)
            reqs = [w for w in windows if w.schemes == (s,)]
            reqs_failed = sum(not w.ok for w in reqs)
            if shortened:  # stated for the case's own duration, as the case page says: neither held nor violated
                n_unjudged += len(mine)
                n_req_unjudged += len(reqs)
            else:
                n_pass += len(mine) - failed
                n_fail += failed
                n_req_pass += len(reqs) - reqs_failed
                n_req_fail += reqs_failed
            entry["runs"][s] = {
                **m, "after_max": _after_max(m), "after_na": _after_na(m), "checks_total": len(mine),
                "checks_failed": failed, "checks_unjudged": shortened, "windows_total": len(reqs),
                "windows_failed": reqs_failed,
            }  # fmt: skip
        entry["not_run"] = rec.get("not_run", {})
        plugins |= rec.get("plugin_schemes", {})
        if metrics:
            if case is not None:
                v = _verdict(case, name, [metrics[s] | {"scheme": s} for s in metrics])
            else:
                v = compare.compare_case(name, metrics)
            verdicts.append(v)
            entry["verdict"] = v
            outside = {s for s, _ in v.outside_expected}
            for s, m in metrics.items():
                if m.get("status") != "ok":
                    entry["runs"][s]["expected_stop"] = s not in outside
            n_unexpected += len(outside)
            n_expected_stop += sum(m.get("status") != "ok" and s not in outside for s, m in metrics.items())
        if case is not None and case.claims and shortened:
            claims_unjudged += len(case.claims)
        elif case is not None and case.claims:
            claims += _claims(name, case, [m | {"scheme": s} for s, m in metrics.items()])
        cases.append(entry)
    families = {s: p["family"] for s, p in plugins.items() if isinstance(p, dict) and p.get("family")}
    board = compare.scoreboard(verdicts, ordered_schemes(s for c in cases for s in c["runs"]), families)
    batch = read_json(out / "manifest.json")  # the merged manifest of the batches into this directory
    memory = batch.get("memory") if isinstance(batch, dict) and batch.get("kind") == "batch" else None
    outcomes = {
        o: sum(c.outcome == o for c in claims)
        for o in ("reproduced", "not reproduced", "not applicable", "not evaluated")
    }
    return write_page(
        out / "index.html",
        "index.html",
        "",
        batch_memory=memory if isinstance(memory, dict) else None,
        batch_created=batch.get("created") if memory else None,
        batches=batch.get("batches", []) if isinstance(batch, dict) else [],
        cases=cases,
        board=board,
        not_applicable=compare.NOT_APPLICABLE,
        specs=compare.HEADLINE,
        fmt_ratio=compare.fmt_ratio,
        schemes=ordered_schemes(
            s for c in cases for s in (*c["runs"], *c.get("not_run", {}), *c.get("stale_runs", {}))
        ),
        n_runs=n_runs,
        n_ok=n_ok,
        n_expected_stop=n_expected_stop,
        n_unexpected=n_unexpected,
        n_pass=n_pass,
        n_fail=n_fail,
        n_req_pass=n_req_pass,
        n_req_fail=n_req_fail,
        n_req_unjudged=n_req_unjudged,
        n_unjudged=n_unjudged,
        claims_unjudged=claims_unjudged,
        n_rejected=len(rejected),
        n_stale=n_stale,
        stale_note=STALE_RUNS,
        plugins=plugins,
        claims=claims,
        claim_outcomes=outcomes,
        claims_off=sum(not c.ok for c in claims),
        other_pages=other_pages(out),
    )


#: Kinds of page under an output directory besides the case pages, by the first folder of their path.
PAGE_KINDS = {"campaigns": "campaign", "coverage": "coverage", "fdi": "FDI", "baselines": "baseline"}


def other_pages(out: Path) -> list[dict]:
    """Every HTML page under ``out`` that is not a case page or the index, found in the directory (a
    campaign's, a coverage map's, an FDI evaluation's, a baseline comparison's...): ``href``, ``kind``,
    ``title`` (from its ``<title>``), ``modified``.  A campaign's per-sample pages are linked from its page.
    ``OUT/baseline.html`` compares runs: when they are no longer the stored ones it is listed with ``stale``
    (why) and not linked (:func:`ftcreport.report.baseline_stamp.stale_reason`)."""
    from .baseline_stamp import PAGE, stale_reason

    out = Path(out)
    cases = {p.parent for p in out.glob("*/case.json")}
    pages = []
    for page in sorted(out.rglob("*.html")):
        rel = page.relative_to(out)
        if page == out / "index.html" or page.parent in cases or "sample_pages" in rel.parts[:-1]:
            continue
        if any(part.startswith(".") for part in rel.parts):
            continue
        try:
            head = page.read_text(encoding="utf-8", errors="replace")[:4000]
        except OSError:
            continue
        title = head.split("<title>", 1)[1].split("</title>", 1)[0] if "<title>" in head else rel.as_posix()
        title = title.removeprefix("ftcreport").lstrip(" :")
        kind = PAGE_KINDS.get(rel.parts[0], rel.parts[0] if len(rel.parts) > 1 else "page")
        stamp = _dt.datetime.fromtimestamp(page.stat().st_mtime, _dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        entry = {"href": rel.as_posix(), "kind": kind, "title": title, "modified": stamp}
        if rel.as_posix() == PAGE:
            entry["kind"] = "baseline"
            if (why := stale_reason(out)) is not None:
                entry["stale"] = why
        pages.append(entry)
    return pages


def _stored_case(out: Path, name: str, rec: dict):
    """The case as stored beside its runs (None when it cannot be read, or was changed after its runs:
    storage.store.load_stored_case)."""
    from ..storage.store import load_stored_case

    try:
        return load_stored_case(out, name, rec)
    except FtcError:
        return None


def _page_stamp(out: Path, name: str) -> str:
    """Hash of everything a case page is made of: the record (minus its time stamp), every run's
    metrics and time series, the templates and the package version."""
    h = hashlib.sha256(__version__.encode())
    rec = json.loads((out / name / "case.json").read_text())
    if not isinstance(rec, dict):
        raise ValueError(f"{out / name / 'case.json'}: not a case record")
    rec.pop("time", None)
    h.update(json.dumps(rec, sort_keys=True).encode())
    for s in stored_schemes(out, name):
        for f in ("metrics.json", "timeseries.npz"):
            p = out / name / s / f
            if p.exists():
                st = p.stat()
                h.update(f"{s}/{f}:{st.st_size}:{st.st_mtime_ns}".encode())
    h.update(_manifest_stamp(out, name))
    if rec.get("base"):  # an overlay's page shows its base's metrics too
        for s in stored_schemes(out, rec["base"]):
            p = out / rec["base"] / s / "metrics.json"
            if p.exists():
                st = p.stat()
                h.update(f"base/{s}:{st.st_size}:{st.st_mtime_ns}".encode())
    for t in sorted(resources.files("ftcreport.templates").iterdir(), key=lambda p: p.name):
        if t.name.endswith(".html"):
            h.update(t.read_bytes())
    return h.hexdigest()


def stale_pages(out: Path, force: bool = False) -> list[tuple[str, str | None]]:
    """The case pages whose inputs changed (all with ``force``): (name, stamp) pairs, by name.

    A page is re-rendered when its stamp (:func:`_page_stamp`) differs from the one stored beside
    it, so a warm batch (every run cached) does not redo the figures and analyses.
    """
    out = Path(out)
    todo = []
    for rec_path in sorted(out.glob("*/case.json")):
        name = rec_path.parent.name
        if _record(out, name) is None:  # not a case record: no page (report names it)
            continue
        stamp_path = out / name / "page.stamp"
        try:
            stamp = _page_stamp(out, name)
        except (OSError, ValueError):
            stamp = None
        page = out / name / "index.html"
        unchanged = stamp is not None and page.exists() and stamp_path.exists() and stamp_path.read_text() == stamp
        if force or not unchanged:
            todo.append((name, stamp))
    return todo


def render_page(out: str | Path, name: str, stamp: str | None) -> str:
    """Render one case page and store its stamp (a batch's worker processes call this)."""
    render_case(Path(out), name)
    if stamp is not None:
        write_atomic(Path(out) / name / "page.stamp", stamp.encode())
    return name


def render_all(out: Path, force: bool = False, pool=None, notify=None, done=None) -> Path:
    """Every case page whose inputs changed (all with ``force``), then the index.

    ``pool``: an executor (a batch's worker processes) to render the pages in, side by side; the
    index is rendered here, after them.  ``notify(k)``: told how many pages are about to render;
    ``done(name)``: told each page as it is done.
    """
    out = Path(out)
    todo = stale_pages(out, force)
    if notify is not None and todo:
        notify(len(todo))
    if pool is None:
        for name, stamp in todo:
            render_page(out, name, stamp)
            if done is not None:
                done(name)
    else:
        for fut in [pool.submit(render_page, str(out), name, stamp) for name, stamp in todo]:
            name = fut.result()  # a page's error is raised here, as without a pool
            if done is not None:
                done(name)
    return render_index(out)
