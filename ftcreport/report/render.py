"""HTML pages from stored results (Jinja2 templates in ``templates/``).

Reads only what the batch stored under the output directory::

    <case>/case.json            batch record: source, status, error, schemes, key, warnings
    <case>/case.toml            copy of the case file (provenance)
    <case>/<scheme>/metrics.json, timeseries.npz

and writes ``<case>/index.html`` and ``index.html`` atomically.  Pages are
self-contained (inline CSS, SVG, a few lines of JS for sorting): they work offline.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import tomllib
from importlib import metadata, resources
from pathlib import Path

import jinja2
import numpy as np

from .. import __version__
from ..cases import SCHEME_NAMES, parse_case, with_duration
from ..check import evaluate
from ..errors import FtcError
from ..model.faults import wheel_names
from ..store import load_metrics, load_timeseries, write_atomic
from . import plots

__all__ = ["dependency_versions", "render_all", "render_case", "render_index"]


def _env() -> jinja2.Environment:
    loader = jinja2.FileSystemLoader(str(resources.files("ftcreport.templates")))
    env = jinja2.Environment(loader=loader, autoescape=jinja2.select_autoescape(["html"]))
    env.globals["fmt"] = _fmt
    return env


def _fmt(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "-"
    if isinstance(x, int | float):
        return f"{x:.3g}"
    return str(x)


def dependency_versions() -> str:
    names = ["numpy", "scipy", "control", "filterpy", "matplotlib", "jinja2", "pydantic", "sympy", "typer"]
    out = []
    for n in names:
        try:
            out.append(f"{n} {metadata.version(n)}")
        except metadata.PackageNotFoundError:
            out.append(f"{n} ?")
    return f"ftcreport {__version__}; " + ", ".join(out)


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def _after_max(m: dict) -> float | None:
    vals = [p["position_error_max"] for p in (m.get("phases") or [])[1:] if p.get("position_error_max") is not None]
    return max(vals) if vals else None


def _record(out: Path, name: str) -> dict | None:
    try:
        return json.loads((out / name / "case.json").read_text())
    except (OSError, ValueError):
        return None


def render_case(out: Path, name: str) -> Path | None:
    """Render ``<out>/<name>/index.html``; returns its path (None if the case has no record)."""
    out = Path(out)
    rec = _record(out, name)
    if rec is None:
        return None
    env = _env()
    page = out / name / "index.html"
    if rec.get("status") == "error" or not (out / name / "case.toml").exists():
        html = env.get_template("case.html").render(
            root="../",
            version=__version__,
            rendered=_now(),
            name=name,
            description=rec.get("error", ""),
            n="?",
            reference="?",
            kinematic="?",
            duration="?",
            dt="?",
            method="?",
            log_every="?",
            engines="",
            warnings=[],
            faults=[],
            runs=[],
            n_phases=0,
            phase_labels=[],
            checks=[],
            figures=[],
            key=rec.get("key", "-"),
            versions=dependency_versions(),
            simulated=rec.get("time", "-"),
            case_text=rec.get("source_text", ""),
        )
        write_atomic(page, html.encode())
        return page
    stored = out / name / "case.toml"
    try:
        text = stored.read_text(encoding="utf-8")
        case = parse_case(tomllib.loads(text), rec.get("source", name))
    except (FtcError, ValueError) as exc:  # the stored copy, not the user's file, is damaged
        raise FtcError(
            f"{stored}: the stored copy of {rec.get('source', name)} is damaged ({str(exc)[:200]}); "
            "re-run 'ftcreport batch' or 'ftcreport run' on the case to store it again"
        ) from None
    case = case.model_copy(update={"name": name})
    if rec.get("duration_override"):
        case = with_duration(case, rec["duration_override"])
    runs, series = [], {}
    for s in SCHEME_NAMES:
        m = load_metrics(out, name, s)
        if m is None:
            continue
        m = dict(m)
        m["after_max"] = _after_max(m)
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
    faults = []
    for f in case.faults:
        pat = sched.pattern(f.time)
        failed = [w for w, p in zip(names, pat, strict=True) if p == 0]
        faults.append(
            {
                "time": f.time,
                "wheel": f.wheel,
                "sigma": f.sigma,
                "ubar": f.ubar,
                "pattern": " ".join(map(str, pat)) + (f"  (failed: {', '.join(failed)})" if failed else ""),
            }
        )
    phases = sched.phases(case.simulation.duration)
    figures = []
    if series:
        d = case.robots.values("d")
        b = case.robots.values("b")[0]
        figures.append(
            {
                "id": "paths",
                "svg": plots.paths_svg(series, d, events, b),
                "caption": "Path of the last robot's axle midpoint P_n for every scheme over the reference.",
            }
        )
        figures.append(
            {
                "id": "errors",
                "svg": plots.errors_svg(series, events),
                "caption": "Tracking errors (log scale): per scheme, then every coordinate of the main FTC scheme; "
                "fault phases shaded.",
            }
        )
        main = "switching" if "switching" in series else next(iter(series))
        figures.append(
            {
                "id": "torques",
                "svg": plots.torques_svg(series[main], list(names), events, main),
                "caption": f"Wheel torques per robot, {main} scheme.",
            }
        )
        if "switching" in series and "selected" in series["switching"]:
            pats = next((m.get("patterns") for m in runs if m["scheme"] == "switching"), None)
            if pats:
                figures.append(
                    {
                        "id": "switching",
                        "svg": plots.switching_svg(series["switching"], pats, events),
                        "caption": "Applied model index against the true failure pattern.",
                    }
                )
        for ad in ("adaptive", "adaptive_frozen"):
            if ad in series and "chi_hat" in series[ad]:
                pats = next((m.get("patterns") for m in runs if m["scheme"] == ad), None)
                if pats:
                    figures.append(
                        {
                            "id": ad,
                            "svg": plots.adaptive_svg(series[ad], pats, list(names), events, ad),
                            "caption": f"{ad}: weights and friction estimate; they are control variables of the "
                            "adaptive law, not a fault diagnosis (ERRATA P2).",
                        }
                    )
        for act in ("active", "active_ukf"):
            if act in series and "rho_hat" in series[act]:
                est = next((m.get("estimated_parameters") for m in runs if m["scheme"] == act), None) or []
                figures.append(
                    {
                        "id": act,
                        "svg": plots.active_svg(series[act], list(names), events, act, est),
                        "caption": f"{act}: estimated gains and frictions against the truth, and the state "
                        "estimation error. Individual parameters are weakly identifiable in steady tracking; "
                        "the combined effect Mbar1^-1 Bbar (diag(rho) u + ubar) is what the data determine (P3).",
                    }
                )
        figures.append(
            {
                "id": "articulation",
                "svg": plots.articulation_svg(series, events),
                "caption": "Articulation angles with the singular configuration at +/-90 deg.",
            }
        )
    analysis = _analysis(case, names)
    if analysis is not None:
        figures.extend(_analysis_figures(analysis, series, events, case.simulation.duration))
    diagnosis = [m for m in runs if m.get("detection_events") is not None]
    html = env.get_template("case.html").render(
        root="../",
        version=__version__,
        rendered=_now(),
        name=name,
        analysis=analysis,
        diagnosis=diagnosis,
        description=case.description,
        n=case.robots.n,
        reference=case.reference.kind,
        kinematic=case.kinematic.kind,
        duration=case.simulation.duration,
        dt=case.simulation.dt,
        method=case.simulation.method,
        log_every=case.simulation.log_every,
        engines=", ".join(f"{m['scheme']} {m['engine']}" for m in runs if "engine" in m),
        warnings=rec.get("warnings", []),
        faults=faults,
        runs=runs,
        n_phases=len(phases),
        phase_labels=[f"{a:g}-{b:g}" for a, b in phases],
        checks=checks,
        figures=figures,
        key=rec.get("key", "-"),
        versions=dependency_versions(),
        simulated=rec.get("time", "-"),
        case_text=text,
    )
    write_atomic(page, html.encode())
    return page


def _analysis(case, names) -> dict | None:
    """Linearized analyses for the case page (None if they cannot be computed)."""
    from ..analysis import analyze_case
    from ..errors import FtcError

    try:
        res = analyze_case(case)
    except (FtcError, ValueError, np.linalg.LinAlgError):
        return None
    rows = res["controllability"]
    pick = rows[:4] + rows[-4:] if len(rows) > 8 else rows
    res["ctrb_rows"] = [
        {**r, "failed": ", ".join(w for w, p in zip(names, r["pattern"], strict=True) if p == 0) or "none"}
        for r in pick
    ]
    return res


def _analysis_figures(analysis: dict, series: dict, events: list[float], duration: float) -> list[dict]:
    """Pole loci and the predicted envelope against the simulated decay (first fault-free phase)."""
    figs = []
    ft = analysis.get("frozen_time")
    if ft:
        step = max(1, len(ft["times"]) // 60)
        loci = list(zip(ft["times"][::step], ft["poles"][::step], strict=True))
        figs.append(
            {
                "id": "pole-loci",
                "svg": plots.pole_loci_svg(loci, "t [s]"),
                "caption": "Frozen-time poles of the closed-loop error dynamics along the reference "
                "(red line: imaginary axis).",
            }
        )
    ch = analysis.get("chained")
    if ch:
        first = next(iter(ch.values()))
        loci = [(f["phi_deg"], f["poles"]) for f in first["frozen"]]
        figs.append(
            {
                "id": "pole-loci",
                "svg": plots.pole_loci_svg(loci, "theta_nd - psi [deg]"),
                "caption": "Frozen poles of the chained-form loop over one re-anchoring period; the Floquet "
                f"rate of the period is {first['floquet_rate']:.4g} 1/s.",
            }
        )
    rate = analysis.get("predicted_decay_rate")
    if rate and series:
        scheme = "nominal" if "nominal" in series else next(iter(series))
        t_end = min([duration, *[t for t in events if t > 0]])
        fit = plots.fitted_decay_rate(series[scheme], t_end)
        analysis["fitted_decay"] = None
        if fit is not None:
            fitted, ta, tb = fit
            analysis["fitted_decay"] = {"scheme": scheme, "rate": fitted, "from": ta, "to": tb}
            figs.append(
                {
                    "id": "decay",
                    "svg": plots.decay_svg(series[scheme], rate, (ta, tb), scheme),
                    "caption": f"Predicted envelope (rate {rate:.4g} 1/s) against the simulated error of the "
                    f"{scheme} run before the first fault (fitted rate {fitted:.4g} 1/s over {ta:.0f}-{tb:.0f} s).",
                }
            )
    return figs


def render_index(out: Path) -> Path:
    """Render ``<out>/index.html`` from every case record under ``out``."""
    out = Path(out)
    cases = []
    n_runs = n_ok = n_pass = n_fail = 0
    for rec_path in sorted(out.glob("*/case.json")):
        name = rec_path.parent.name
        rec = _record(out, name) or {}
        entry = {
            "name": name,
            "n": rec.get("n", "?"),
            "reference": rec.get("reference", "?"),
            "error": rec.get("error") if rec.get("status") == "error" else None,
            "runs": {},
        }
        metrics = {}
        for s in SCHEME_NAMES:
            m = load_metrics(out, name, s)
            if m is None:
                continue
            metrics[s] = m
            n_runs += 1
            n_ok += m.get("status") == "ok"
        checks = evaluate(name, rec.get("thresholds", {}), metrics) if rec.get("thresholds") else []
        for s, m in metrics.items():
            mine = [c for c in checks if c.scheme == s]
            failed = sum(not c.ok for c in mine)
            n_pass += len(mine) - failed
            n_fail += failed
            entry["runs"][s] = {**m, "after_max": _after_max(m), "checks_total": len(mine), "checks_failed": failed}
        cases.append(entry)
    html = (
        _env()
        .get_template("index.html")
        .render(
            root="",
            version=__version__,
            rendered=_now(),
            cases=cases,
            schemes=list(SCHEME_NAMES),
            n_runs=n_runs,
            n_ok=n_ok,
            n_bad=n_runs - n_ok,
            n_pass=n_pass,
            n_fail=n_fail,
        )
    )
    page = out / "index.html"
    write_atomic(page, html.encode())
    return page


def _page_stamp(out: Path, name: str) -> str:
    """Hash of everything a case page is made of: the record (minus its time stamp), every run's
    metrics and time series, the templates and the package version."""
    h = hashlib.sha256(__version__.encode())
    rec = json.loads((out / name / "case.json").read_text())
    rec.pop("time", None)
    h.update(json.dumps(rec, sort_keys=True).encode())
    for s in SCHEME_NAMES:
        for f in ("metrics.json", "timeseries.npz"):
            p = out / name / s / f
            if p.exists():
                st = p.stat()
                h.update(f"{s}/{f}:{st.st_size}:{st.st_mtime_ns}".encode())
    for t in sorted(resources.files("ftcreport.templates").iterdir(), key=lambda p: p.name):
        if t.name.endswith(".html"):
            h.update(t.read_bytes())
    return h.hexdigest()


def render_all(out: Path, force: bool = False) -> Path:
    """Every case page whose inputs changed (all with ``force``), then the index.

    A page is re-rendered when its stamp (:func:`_page_stamp`) differs from the one stored
    beside it, so a warm batch (every run cached) does not redo the figures and analyses.
    """
    out = Path(out)
    for rec_path in sorted(out.glob("*/case.json")):
        name = rec_path.parent.name
        stamp_path = out / name / "page.stamp"
        try:
            stamp = _page_stamp(out, name)
        except (OSError, ValueError):
            stamp = None
        page = out / name / "index.html"
        unchanged = stamp is not None and page.exists() and stamp_path.exists() and stamp_path.read_text() == stamp
        if unchanged and not force:
            continue
        render_case(out, name)
        if stamp is not None:
            write_atomic(stamp_path, stamp.encode())
    return render_index(out)
