"""Commands that run cases and gate on them: patterns, demo, batch, run, report, check, baseline."""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Annotated

import typer

from ..errors import FtcError, printable
from .app import QuietOpt, _running, app, baseline_app


@app.command()
def patterns(
    robots: Annotated[int, typer.Argument(help="Number of robots in the chain (>= 2).")],
) -> None:
    """List the compensable 0/1 failure patterns of an n-robot chain (rank(Bbar sigma) = 2).

    1 = the wheel works, 0 = it gives no torque; wheel order 1r, 1l, 2r, 2l, ...

    Example: ftcreport patterns 2
    """
    from ..model import compensable_patterns, wheel_names

    if robots < 2:
        raise FtcError(f"robots: a chain needs at least 2 robots, got {robots}")
    if robots > 8:
        raise FtcError(f"robots: {robots} robots give 2^{2 * robots} patterns; list at most 8 robots")
    names = wheel_names(robots)
    pats = compensable_patterns(robots)
    typer.echo(" ".join(f"{w:>3}" for w in names) + "   failed")
    for p in pats:
        failed = [w for w, s in zip(names, p, strict=True) if s == 0]
        typer.echo(" ".join(f"{s:>3}" for s in p) + "   " + (",".join(failed) or "-"))
    typer.echo(f"{len(pats)} of {2 ** (2 * robots)} patterns are compensable (3*2^(2n-2) - 2).")


@app.command()
def demo(
    robots: Annotated[int, typer.Option(help="Number of robots (>= 2).")] = 3,
    duration: Annotated[float, typer.Option(help="Simulated time \\[s].")] = 20.0,
    dt: Annotated[float, typer.Option(help="RK4 step \\[s].")] = 0.01,
    fault_time: Annotated[float, typer.Option(help="When wheel 2l loses its motor \\[s].")] = 10.0,
) -> None:
    """Run the nominal scheme (the matched law (3.35), no FTC) on a thesis-parameter chain that loses motor 2l.

    The chain follows a 5 m circle at 0.5 m/s from its start.  Prints the velocity error before and after
    the fault and the peak torque.

    Example: ftcreport demo --robots 3 --duration 20
    """
    import numpy as np

    from ..control import TrackingController
    from ..evaluation.metrics import singularity_margin
    from ..model import FaultEvent, FaultSchedule
    from ..schemes.budget import budget_problem
    from ..sim import Plant, SimSettings, demo_chain, simulate

    if not 2 <= robots <= 12:
        raise FtcError(f"--robots: must be between 2 and 12, got {robots}")
    if not (math.isfinite(fault_time) and fault_time >= 0.0):
        raise FtcError(f"demo: --fault-time: must be a finite time at or after 0 s, got {fault_time:g}")
    if math.isfinite(duration) and fault_time >= duration:
        raise FtcError(f"demo: --fault-time: {fault_time:g} s is not before --duration ({duration:g} s)")
    if (problem := budget_problem(robots, duration, dt, 1)) is not None:
        opt = "--dt" if problem[0] == "simulation.dt" else "--duration"  # demo logs every step
        raise FtcError(f"demo: {opt}: {problem[1]}")
    chain, kin, q0 = demo_chain(robots)  # 1 m links, a 5 m circle at 0.5 m/s
    faults = FaultSchedule(robots, [FaultEvent(fault_time, "2l", sigma=0.0, ubar=0.0)])
    ctrl = TrackingController(chain, kin, k_v=5.0)
    eta0 = kin.reference.at(0.0).eta_d
    run = simulate(Plant(chain, faults), ctrl, q0, eta0, SimSettings(dt=dt, duration=duration))
    err = np.abs(run["eta"] - run["eta_c"]).max(axis=1)
    before = run.t < fault_time
    typer.echo(f"{robots}-robot chain on a 5 m circle at 0.5 m/s, nominal scheme, wheel 2l lost at {fault_time} s")
    typer.echo(f"status: {run.status} {run.reason}".rstrip())
    if before.any():
        typer.echo(f"velocity error at {run.t[before][-1]:.2f} s: {err[before][-1]:.3e}")
    typer.echo(f"velocity error at {run.t[-1]:.2f} s: {err[-1]:.3e}")
    typer.echo(f"peak |tau|: {np.abs(run['tau']).max():.3f} N m; wall time {run.wall_time:.2f} s")
    margin = singularity_margin(run["q"])
    typer.echo(f"singularity margin min: {math.degrees(margin):.1f} deg")
    if not run.ok:
        raise typer.Exit(code=1)


@app.command()
def batch(
    cases: Annotated[list[Path] | None, typer.Argument(help="Case files or directories (default: cases/).")] = None,
    out: Annotated[Path, typer.Option(help="Output directory.")] = Path("reports"),
    jobs: Annotated[int | None, typer.Option(help="Parallel processes (default: the core count).")] = None,
    force: Annotated[bool, typer.Option("--force", help="Re-simulate cached runs.")] = False,
    duration: Annotated[float | None, typer.Option(help="Override every case's simulated time \\[s].")] = None,
    quiet: QuietOpt = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="One line per run after the summary.")] = False,
) -> None:
    """Run every case x scheme (cached by case content and version) and write OUT/index.html.

    A broken case file or a failing run is recorded and the batch goes on.  A run is cached only when
    its stored record matches its files and key; a failed run is cached as the failure it is.
    Exit 0 when every run ends as its case expects, 1 when some run (cached or not) failed, 2 when a case
    file was refused as bad input (not TOML, not valid, not a regular file), even when a run failed too:
    the valid cases are run and stored first.

    Example: ftcreport batch cases/ --jobs 2
    """
    from ..studies.batch import failures_summary, run_batch

    res = run_batch(cases or [Path("cases")], out, jobs, force, duration, show_progress=not quiet)
    peak = res.worker_peak_rss_mb
    memory = "" if peak is None else f"; worker peak memory {peak:.0f} MB ({len(res.worker_peaks_mb)} worker(s))"
    typer.echo(
        f"{len(res.cases)} case(s): {len(res.simulated)} run(s) simulated, {len(res.cached)} cached, "
        f"{len(res.failed_runs)} failed, {len(res.case_errors)} case file(s) rejected{memory}; "
        f"report: {out / 'index.html'}"
    )
    if verbose:
        from ..storage.store import load_metrics

        for name, scheme in sorted(res.simulated + res.cached):
            m = load_metrics(out, name, scheme) or {}
            typer.echo(
                f"  {name} / {scheme}: {m.get('status', '?')}, final error {_fmt(m.get('position_error_final'))} m, "
                f"wall {_fmt(m.get('wall_time'))} s{' (cached)' if (name, scheme) in res.cached else ''}"
            )
    if res.case_errors or res.failed_runs:
        typer.echo(failures_summary(res), err=True)
        raise typer.Exit(code=2 if res.case_errors else 1)  # bad input outranks a failed run, as for check


@app.command()
def run(
    case: Annotated[Path, typer.Argument(help="One case file (TOML).")],
    out: Annotated[Path, typer.Option(help="Output directory.")] = Path("reports"),
    scheme: Annotated[list[str] | None, typer.Option(help="Run only these schemes (repeatable).")] = None,
    duration: Annotated[float | None, typer.Option(help="Override the simulated time \\[s].")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print only errors.")] = False,
    verify_dt: Annotated[
        bool,
        typer.Option(
            "--verify-dt",
            help="Run each scheme again at dt/2 (an error-controlled method: also at rtol/10 and atol/10) and print "
            "the change of the headline metrics (stored as verify_dt in metrics.json); exit 1 if a change exceeds "
            "1 % (+1e-6 absolute), or if the refined run is bit-identical (the check is empty).",
        ),
    ] = False,
    no_report: Annotated[
        bool, typer.Option("--no-report", help="Store the results only (render later with 'ftcreport report').")
    ] = False,
) -> None:
    """Run one case through its schemes; store metrics.json and time series under OUT/<case>/<scheme>/.

    Prints a comparison table and the case's thresholds and thesis claims (as 'check' judges them).
    Exit 0 when every run ends as the case expects and every threshold and claim holds, 1 when a run
    stopped early (singular, diverged, error) unless the case expects it, a threshold or claim does not
    hold, or --verify-dt finds the step not converged (or its check empty); 2 for a bad case file.

    Example: ftcreport run cases/two_link_switching.toml --scheme switching --duration 30
    """
    from ..cases import configured_schemes, dropped_faults, load_case, option_schemes, with_duration
    from ..errors import RunEnvironmentError
    from ..runner import build, dt_sensitivity, halve_dt, run_scheme
    from ..storage.store import save_run

    notes = []
    try:
        c = load_case(case)
        if duration is not None:
            if (drop := dropped_faults(c, duration)) is not None:
                notes.append(drop)
            c = with_duration(c, duration)
        schemes = configured_schemes(c)
    except FtcError as exc:
        raise (exc if str(exc).startswith(str(case)) else FtcError(f"{case}: {exc}")) from None
    if scheme:  # a mistyped --scheme is the option's fault, not the case file's
        option_schemes("--scheme", scheme, c)
        schemes = [s for s in schemes if s in scheme]
    try:
        built = build(c)
        half = halve_dt(c, str(case)) if verify_dt else None
    except FtcError as exc:
        raise (exc if str(exc).startswith(str(case)) else FtcError(f"{case}: {exc}")) from None
    if not quiet:
        for w in [*notes, *c.warnings()]:
            typer.echo(printable(f"warning: {case}: {w}"), err=True)
    from ..storage.store import output_lock
    from ..studies.batch import record_case, run_key, write_case_manifest

    rows = []
    not_stored: dict[str, str] = {}  # scheme -> why: failures of the environment, never stored as the result
    try:
        with output_lock(out, "run"):
            record_case(out, c, case, duration, notes)
            for s in schemes:
                try:
                    with _running(f"{c.name} / {s}", quiet):
                        r, m = run_scheme(c, s, built)
                        if half is not None:
                            m["verify_dt"] = dt_sensitivity(m, run_scheme(half, s)[1])
                except RunEnvironmentError as exc:
                    not_stored[s] = f"{exc} (not the case's result: not stored; run it again)"
                    continue
                failure = (
                    c.unexpected(s, m["status"], m.get("reason")) if m["status"] not in c.expected_for(s) else None
                )
                save_run(out, c.name, s, r, m, run_key(c, s), c.expected_for(s), failure)
                rows.append(m)
                del r  # stored: the next scheme and the report do not hold this run's arrays too
            write_case_manifest(out, c, {"command": "run", "schemes": schemes, "duration": duration})
            ended = [m["scheme"] for m in rows if m["status"] in c.expected_for(m["scheme"])]
            gate = _run_gate(out, c.name, ended) if duration is None else []
            page = None
            if not no_report:  # matplotlib and jinja2 only for the report (--no-report: about 45 MB less)
                from ..report.render import render_case, render_index

                page = render_case(out, c.name)
                render_index(out)
    except BaseException as exc:  # the interrupt message says how many schemes' runs are stored
        from ..errors import note_stored
        from ..infra.lifetime import interrupt_of

        if (stop := interrupt_of(exc)) is not None:
            note_stored(stop, len(rows))
        raise
    if not quiet:
        typer.echo(_table(rows))
        if half is not None:
            typer.echo(_dt_table(rows))
        for m in rows:
            if (forced := _forced_steps(m)) is not None:
                typer.echo(printable(f"warning: {case}: simulation.min_step: {m['scheme']}: {forced}"), err=True)
        for item in gate:
            typer.echo(printable(item.line()))
        if duration is not None and (c.thresholds or c.claims or c.requirements):
            typer.echo(
                f"note: {case}: --duration {duration:g}: the case's thresholds, claims and requirements are stated "
                "for its own duration and are not judged (run without --duration, or 'ftcreport check', to judge them)",
                err=True,
            )
        typer.echo(f"results in {out / c.name}/" + (f", report {page}" if page else ""))
    failed = [m for m in rows if m["status"] not in c.expected_for(m["scheme"])]
    for m in failed:
        typer.echo(
            printable(
                f"ftcreport: error: {case}: {m['scheme']}: {c.unexpected(m['scheme'], m['status'], m.get('reason'))}"
            ),
            err=True,
        )
    for s, why in not_stored.items():
        typer.echo(printable(f"ftcreport: error: {case}: {s}: {why}"), err=True)
    unheld = [item for item in gate if not item.ok]
    for item in unheld:
        typer.echo(printable(f"ftcreport: error: {case}: {item.field}: {item.message}"), err=True)
    loose = [m for m in rows if not m.get("verify_dt", {}).get("converged", True)]
    for m in loose:
        v = m["verify_dt"]
        g = m.get("integrator") or {}
        field, at, how = ("simulation.dt", f"dt = {v['dt']:g} s", "at dt/2")
        if "rtol" in g:  # an error-controlled run: checked at a tenth of its tolerances and half its longest step
            field = "simulation.rtol"
            at = f"rtol = {g['rtol']:g}, atol = {g['atol']:g}, longest step dt = {v['dt']:g} s"
            how = "at rtol/10, atol/10 and dt/2"
        if v.get("empty"):
            typer.echo(
                f"ftcreport: error: {case}: simulation.dt: {m['scheme']}: the step check is empty: the refined run "
                f"({v['refined']}) is bit-identical to the run on every headline metric, so it tested nothing",
                err=True,
            )
            continue
        typer.echo(
            f"ftcreport: error: {case}: {field}: {m['scheme']}: not converged at {at} "
            f"({v['worst']} changes by {v['worst_rel_change']:.3g} relative {how})",
            err=True,
        )
    if failed or loose or not_stored or unheld:
        raise typer.Exit(code=1)


def _run_gate(out: Path, name: str, schemes: list[str]):
    """The gate items of the runs ``run`` just stored (thresholds, claims and the other kinds of
    ftcreport.studies.check.CASE_ITEMS, not the runs' status: ``run`` reports those itself), restricted to
    ``schemes``: an item that reads a scheme not run (``--scheme``) or a run that failed (already
    reported as such) is not judged."""
    from ..studies.check import CASE_ITEMS, run_items, stored_case

    case = stored_case(out, name)
    items = [item for source in CASE_ITEMS if source is not run_items for item in source(case)]
    return [item for item in items if set(item.schemes) <= set(schemes)]


def _forced_steps(m: dict) -> str | None:
    """The steps an error-controlled run took at min_step with its local error over the tolerance, in words
    (the run went on: docs/ENGINE.md), or None when it took none."""
    g = m.get("integrator") or {}
    if not g.get("forced_steps"):
        return None
    return (
        f"{g['forced_steps']} step(s) were taken at min_step = {g['min_step']:g} s with the local error over the "
        f"tolerance (rtol = {g['rtol']:g}, atol = {g['atol']:g}), the first at t = {g['first_forced_at']:.6g} s: "
        "the accuracy asked for was not met there"
    )


def _dt_table(rows: list[dict]) -> str:
    """The change of each headline metric from dt to dt/2, per scheme (run --verify-dt)."""
    lines = [f"{'dt check':<10} {'metric':<22} {'as run':>11} {'refined':>11} {'change':>10} {'relative':>9}"]
    for m in rows:
        v = m["verify_dt"]
        verdict = "converged" if v["converged"] else "NOT converged"
        if v.get("empty"):
            verdict = "EMPTY check: the refined run is bit-identical (nothing tested)"
        lines.append(f"{m['scheme']:<10} {v.get('refined')}: {verdict} (status {v['status']})")
        for k, r in v["metrics"].items():
            lines.append(
                f"{'':<10} {k:<22} {_fmt(r['dt']):>11} {_fmt(r['dt_half']):>11} {_fmt(r['abs_change']):>10} "
                f"{_fmt(r['rel_change'], '.2%'):>9}"
            )
    return "\n".join(lines)


def _fmt(x, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)


def _table(rows: list[dict]) -> str:
    from ..evaluation.metrics import fault_phases

    w = max([10, *(len(m["scheme"]) for m in rows)])  # a plug-in scheme's name may be longer
    head = (
        f"{'scheme':<{w}} {'status':<9} {'max err after faults':>20} {'final err':>10} {'switches':>8} "
        f"{'match':>6} {'peak tau':>9} {'wall/sim-s':>10}"
    )
    lines = [head, "-" * len(head)]
    for m in rows:
        after = [p["position_error_max"] for p in fault_phases(m.get("phases")) if p["position_error_max"] is not None]
        # compiling (or loading) the engine's loop excluded, as the case page's schemes table has it
        wall = max(0.0, m.get("wall_time", 0.0) - (m.get("compile_time") or 0.0))
        wall /= max(m.get("t_end") or m["duration"], 1e-9)
        lines.append(
            f"{m['scheme']:<{w}} {m['status']:<9} {_fmt(max(after) if after else None):>20} "
            f"{_fmt(m.get('position_error_final')):>10} {_fmt(m.get('switch_count'), 'd'):>8} "
            f"{_fmt(m.get('switching_match_fraction'), '.3f'):>6} {_fmt(m.get('torque_peak')):>9} {wall:>10.3f}"
        )
        if m.get("reason"):
            lines.append(f"{'':<{w}} reason: {m['reason']}")
    return "\n".join(lines)


@app.command()
def report(
    out: Annotated[Path, typer.Option(help="Output directory holding stored results.")] = Path("reports"),
) -> None:
    """Re-render every HTML page from stored results: no case is simulated again, but a page whose case is
    sampled or has motors re-runs its analysis's short confirmation simulations (a few seconds each).

    A stored run that is damaged (its record does not match its files) is shown as such and named here;
    a run that ended in a status its case counts as a failure is named too.  Exit 0 when every stored run
    is sound and ends as its case expects, 1 otherwise.

    Example: ftcreport report --out reports
    """
    from ..report.render import render_all
    from ..studies.check import stored_case

    if not out.is_dir():
        raise FtcError(f"{out}: no stored results (run 'ftcreport batch' first)")
    from ..storage.store import deleted_runs, edited_cases, output_lock, read_json, unrecorded_cases

    with output_lock(out, "report"), _render_progress() as (notify, done):
        page = render_all(out, force=True, notify=notify, done=done)
        bad = unrecorded_cases(out)  # runs whose case record is gone: not shown, and said so
        bad += edited_cases(out)  # a stored case file edited after its runs: its page says so
        bad += deleted_runs(out)  # a run directory deleted by hand
        for rec in sorted(out.glob("*/case.json")):
            if not isinstance(read_json(rec), dict) or read_json(rec).get("status") != "ok":
                continue  # a rejected case file: its page says why (a damaged record: unrecorded_cases)
            for s, run in stored_case(out, rec.parent.name).runs.items():
                if not run.absent and not run.sound:
                    bad.append(run.problem)
                elif run.failed:
                    bad.append(f"{run.case} / {s}: {run.record.get('failure')}")
    typer.echo(f"report: {page}")
    for line in bad:
        typer.echo(printable(f"ftcreport: error: {line}"), err=True)
    if bad:
        raise typer.Exit(code=1)


@contextlib.contextmanager
def _render_progress():
    """A bar of the case pages rendered (on a terminal's stderr; nothing when piped)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True)
    if not console.is_terminal:  # piped: one line, as batch says it (a minute of silence reads as a hang)
        from ..studies.batch import _render_notice

        yield (lambda k: _render_notice(k) if k else None), None
        return
    cols = (
        TextColumn("rendering pages"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[page]}"),
    )
    with Progress(*cols, console=console, transient=True) as bar:
        task = bar.add_task("pages", total=None, page="")

        yield (lambda k: bar.update(task, total=k)), (lambda name: bar.update(task, advance=1, page=name))


def _junit_stopped(junit: Path | None, exc: BaseException, seconds: float, started: str) -> None:
    """A check stopped before judging (bad input, --out busy, Ctrl-C, a bug): its JUnit file says so (a CI
    step that publishes it regardless of the exit code must not show the last run's green), unless the path
    now holds a file that is not JUnit (never overwritten)."""
    if junit is None:
        return
    try:
        _junit_target(junit)
    except FtcError:
        return
    from ..report.junit import write_junit
    from ..studies.check import error_items

    why = str(exc) if isinstance(exc, FtcError) else f"stopped before judging: {type(exc).__name__} {exc}"
    write_junit(junit, error_items({"ftcreport check": why}), time=seconds, timestamp=started)


def _junit_target(path: Path) -> None:
    """Refuse a --junit path that is a directory, or an existing file that is not a JUnit report (a stored
    result, a case file): check writes there, and must not destroy what it judges."""
    if path.is_dir():
        raise FtcError(f"--junit: {path} is a directory: give the XML file's path")
    if path.exists():
        try:
            with path.open("rb") as f:
                head = f.read(512).lstrip()
        except OSError as exc:
            raise FtcError(f"--junit: {path}: cannot read ({exc.strerror})") from None
        if head and b"<testsuite" not in head:  # JUnit's root (testsuite or testsuites), after any declaration
            raise FtcError(f"--junit: {path} exists and is not a JUnit XML file: not overwritten")


@app.command()
def check(
    cases: Annotated[list[Path] | None, typer.Argument(help="Case files or directories (default: cases/).")] = None,
    junit: Annotated[Path | None, typer.Option(help="Write JUnit XML here.")] = None,
    out: Annotated[Path, typer.Option(help="Output directory (results are reused when cached).")] = Path("reports"),
    jobs: Annotated[int | None, typer.Option(help="Parallel processes.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print only failures.")] = False,
    baseline: Annotated[
        Path | None,
        typer.Option(
            help="Also compare every case x scheme with this baseline ('ftcreport baseline save'): metrics and "
            "signals within their tolerances; a change beyond them fails. Writes OUT/baseline.html."
        ),
    ] = None,
) -> None:
    """The CI gate: every run, threshold, thesis claim and requirement of each case (and, with --baseline,
    every run against a saved baseline): exit 0 if all hold, 1 if not, 2 for bad files.

    A run holds when it ends in a status its case expects (a failure cached by an earlier batch fails here
    too); a thesis claim when its outcome (reproduced, not reproduced, not applicable) is the expected one;
    a time-windowed requirement in a window when every step's value is within its bound (a window
    violated or not evaluated, empty or cut by a stopped run, fails).

    Runs what is not cached first (as 'batch' does).  --junit: one testcase per run, threshold and claim.

    Example: ftcreport check cases/ --baseline baselines/main
    """
    import datetime as _dt
    import time as _time

    from ..report.junit import write_junit
    from ..storage.store import output_lock, read_json
    from ..studies.batch import run_batch
    from ..studies.check import exit_code, gate, summary, ungated

    if junit is not None:
        _junit_target(junit)
    started = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    wall0 = _time.perf_counter()
    inputs = cases or [Path("cases")]
    outside: list[str] = []
    if baseline is not None:
        from ..studies.baseline import check_dest

        check_dest(baseline)  # a mistyped --baseline before anything runs
    # one hold of --out's lock from the batch to the last file written: judged in between, the stored runs
    # could be another process's (a `run` of a same-named case), and a failing case would pass
    held = contextlib.ExitStack()
    try:
        held.enter_context(output_lock(out, "check"))  # --out busy: the JUnit file says so too
    except BaseException as exc:
        _junit_stopped(junit, exc, _time.perf_counter() - wall0, started)
        raise
    with held:  # left after the last file written
        try:
            res = run_batch(inputs, out, jobs, show_progress=not quiet)
        except BaseException as exc:  # stopped before judging (bad input, Ctrl-C, a bug): the JUnit file says so
            _junit_stopped(junit, exc, _time.perf_counter() - wall0, started)
            raise
        items = gate(out, res.cases, res.case_errors, res.not_stored)
        baseline_page = None
        if baseline is not None:
            from ..report.baseline_page import render_baseline
            from ..studies.baseline import absent_items, baseline_items

            found, comparisons = baseline_items(out, res.cases, baseline)
            gone, outside = absent_items(baseline, res.cases, res.case_errors, inputs)
            items += found + gone
            baseline_page = render_baseline(out, baseline, comparisons)
            from ..report.render import render_index

            render_index(out)  # the batch rendered it before this page was written: it links the page now
        if junit is not None:
            _junit_target(junit)  # again: the batch may have stored a result at that path since
            write_junit(
                junit,
                items,
                properties=read_json(out / "manifest.json"),
                time=_time.perf_counter() - wall0,
                timestamp=started,
            )
    for item in items:
        if not item.error and (not item.ok or not quiet):
            for line in item.terminal_lines():
                typer.echo(printable(line))
    for msg in res.case_errors.values():
        typer.echo(printable(f"ftcreport: error: {msg}"), err=True)
    for line in summary(items):
        typer.echo(line)
    for line in ungated(items):
        typer.echo(printable(line))
    if outside:
        n = len(outside)
        typer.echo(
            printable(f"{n} case{'s' * (n > 1)} of the baseline not among this check's inputs (not compared): "
                      + ", ".join(outside))
        )  # fmt: skip
    if baseline_page is not None:
        typer.echo(f"baseline comparison: {baseline_page}")
    if (code := exit_code(items)) != 0:
        raise typer.Exit(code=code)


@baseline_app.command("save")
def baseline_save(
    cases: Annotated[list[Path] | None, typer.Argument(help="Case files or directories (default: cases/).")] = None,
    dest: Annotated[
        Path, typer.Option(help="The baseline directory to write (created; a saved case is replaced).")
    ] = ...,
    out: Annotated[Path, typer.Option(help="Output directory of the results (runs what is not cached).")] = Path(
        "reports"
    ),
    jobs: Annotated[int | None, typer.Option(help="Parallel processes.")] = None,
    quiet: QuietOpt = False,
) -> None:
    """Save the baseline of every case x scheme: headline metrics, key signals and their provenance.

    Per case DEST/<case>/baseline.json (git revision, versions, case hash, the case file and its fields,
    per scheme status and metrics) and signals.npz (position error, heading error per robot, torque per
    wheel: minimum and maximum over 500 intervals). 'ftcreport check CASES --baseline DEST' compares
    with it. A case whose runs did not end as it expects is not saved (exit 1).

    Example: ftcreport baseline save cases/ --dest baselines/main
    """
    from ..storage.store import check_apart, output_lock
    from ..studies.baseline import save_baseline
    from ..studies.batch import run_batch

    if dest.exists() and not dest.is_dir():
        raise FtcError(f"{dest}: --dest: exists and is not a directory")
    check_apart(dest, out)  # never into the results tree (or a run's folder): refused before anything runs
    # --dest claimed before the batch runs (a results directory there is refused at once); --out's lock from
    # the batch to the last run read: no other process stores a run in between
    with output_lock(dest, "baseline save", "--dest"), output_lock(out, "batch"):
        res = run_batch(cases or [Path("cases")], out, jobs, show_progress=not quiet)
        refused = save_baseline(out, res.cases, dest)
    for name, why in refused:
        typer.echo(f"ftcreport: error: {name}: not saved: {why}", err=True)
    for msg in res.case_errors.values():
        typer.echo(f"ftcreport: error: {msg}", err=True)
    typer.echo(f"{len(res.cases) - len(refused)} case(s) saved to {dest}, {len(refused)} refused")
    if res.case_errors:
        raise typer.Exit(code=2)
    if refused:
        raise typer.Exit(code=1)
