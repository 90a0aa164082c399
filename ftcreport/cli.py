"""Command-line interface (Typer): thin commands over the library.

Every command parses its arguments and calls the library; :class:`_ErrorBoundary` turns an
:class:`~ftcreport.errors.FtcError`, or any other exception, into one line on stderr and an
exit code (README, "Errors, exit codes, interruptions").
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from pathlib import Path
from typing import Annotated

import typer
from typer.core import TyperGroup

from . import __version__
from .errors import FtcError, printable


class _ErrorBoundary(TyperGroup):
    """The one error boundary of every command (issue 23).

    Expected failures become ``ftcreport: error: <file>: <field>: <reason>`` on stderr:
    bad input (case files, arguments, unreadable or unwritable paths) exits 2, a numeric
    failure exits 1.  Anything else is a bug: one line naming a log file that holds the
    traceback, exit 3.  ``ftcreport --debug`` re-raises instead (full traceback).
    """

    def get_command(self, ctx: typer.Context, cmd_name: str):
        cmd = super().get_command(ctx, cmd_name)
        if cmd is not None:
            _plain_flags(cmd, ctx)
        return cmd

    def get_params(self, ctx: typer.Context):
        params = super().get_params(ctx)
        _plain_flags(self, ctx)
        return params

    def invoke(self, ctx: typer.Context):
        protected = ctx._protected_args if hasattr(ctx, "_protected_args") else getattr(ctx, "protected_args", [])
        argv = [*protected, *ctx.args]
        if ctx.params.get("debug"):
            return self._invoke(ctx, argv)
        import warnings

        from .lifetime import handle_stop_signals

        # SIGINT, SIGTERM, SIGHUP: Interrupted inside the command, ignored once it is over (ftcreport.lifetime)
        with warnings.catch_warnings(record=True) as caught, handle_stop_signals():
            warnings.simplefilter("default")  # library warnings: one summary line, not a dump
            for quiet in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.simplefilter("ignore", quiet)  # Python's own default for these
            try:
                return self._invoke(ctx, argv)
            finally:
                if caught:
                    w = caught[0]
                    more = f" (and {len(caught) - 1} more)" if len(caught) > 1 else ""
                    typer.echo(
                        f"ftcreport: warning: {w.category.__name__} in {Path(w.filename).name}: "
                        f"{str(w.message).splitlines()[0][:160]}{more}; --debug shows every warning",
                        err=True,
                    )

    def _invoke(self, ctx: typer.Context, argv: list):
        try:
            return super().invoke(ctx)
        except _CLI_FLOW as exc:  # --help, Exit, usage errors: the CLI framework's own exits
            names = [c.__name__ for c in type(exc).__mro__]
            if "UsageError" in names and "NoArgsIsHelpError" not in names:  # one line, not a box
                sub = getattr(getattr(exc, "ctx", None), "command_path", None) or ctx.command_path
                typer.echo(f"ftcreport: error: {sub}: {exc.format_message()} (see '{sub} --help')", err=True)
                raise typer.Exit(code=2) from None
            raise
        except BaseException as exc:
            from .lifetime import interrupt_of

            exc = interrupt_of(exc) or exc  # a stop signal that came back wrapped (compiled code) is one
            if ctx.params.get("debug") and not isinstance(exc, KeyboardInterrupt | FtcError):
                raise
            line, code = _classify(exc)
            files = [a for a in argv if isinstance(a, str) and a.endswith(".toml")]
            for unnamed in ("<run>: ", "<input>: "):  # name the case file the failing command was given
                if line.startswith(unnamed) and files:
                    line = f"{files[0]}: " + line.removeprefix(unnamed)
            if code == 3:
                line += f" (a bug: traceback in {_crash_log(exc)}; --debug shows it)"
            with contextlib.suppress(OSError):  # a hung-up terminal (SIGHUP): the exit code still tells
                typer.echo(f"ftcreport: error: {printable(line)}", err=True)
            raise typer.Exit(code=code) from None


def _plain_flags(cmd, ctx) -> None:
    """Flags (``--force``, ``--help``) listed bare in ``--help``: typer 0.2x writes each option's type,
    ``<bool>`` for a flag that takes no value; an empty metavar (click's ``Parameter.metavar``) says none.
    A group's commands too (``cases validate``)."""
    help_opt = cmd.get_help_option(ctx)
    for p in [*cmd.params, *([help_opt] if help_opt is not None else [])]:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
    for sub in getattr(cmd, "commands", {}).values():
        _plain_flags(sub, ctx)


def _cli_flow() -> tuple[type[BaseException], ...]:
    """Exceptions the CLI framework turns into its own message and exit code (typer vendors click)."""
    flow: list[type[BaseException]] = [SystemExit, typer.Exit, typer.Abort]
    for name in ("TyperException",):
        if hasattr(typer, name):
            flow.append(getattr(typer, name))
    try:
        import click

        flow += [click.exceptions.Exit, click.ClickException, click.Abort]
    except ImportError:  # pragma: no cover - typer without click
        pass
    return tuple(flow)


_CLI_FLOW = _cli_flow()


def _classify(exc: BaseException) -> tuple[str, int]:
    """(message, exit code) of an exception reaching the boundary."""
    import errno

    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, SIGTERM, SIGHUP: 128 + the signal's number
        from .errors import interrupted_message
        from .lifetime import exit_code

        return interrupted_message(exc), exit_code(exc)
    if isinstance(exc, FtcError):
        return str(exc), getattr(exc, "exit_code", 2)
    if isinstance(exc, UnicodeDecodeError):
        return f"<input>: not UTF-8 text ({exc.reason} at byte {exc.start})", 2
    if isinstance(exc, OSError):
        where = exc.filename if exc.filename is not None else "<output>"
        why = {
            errno.ENOSPC: "no space left on the device",
            errno.ENAMETOOLONG: "file name too long",
            errno.EROFS: "read-only file system",
            errno.EACCES: "permission denied",
            errno.EPERM: "operation not permitted",
        }.get(exc.errno, exc.strerror or type(exc).__name__)
        return f"{where}: {why}", 2
    if isinstance(exc, MemoryError):
        return "<run>: out of memory (see the limits in cases/README.md)", 1
    if isinstance(exc, ArithmeticError | FloatingPointError):
        return f"<run>: numeric error: {type(exc).__name__}: {exc}", 1
    try:
        import numpy as np

        if isinstance(exc, np.linalg.LinAlgError):
            return f"<run>: numeric error: LinAlgError: {exc}", 1
    except ImportError:  # pragma: no cover
        pass
    return f"unexpected {type(exc).__name__}: {str(exc)[:200]}", 3


def _crash_log(exc: BaseException) -> str:
    """Write the traceback to a log file (FTCREPORT_LOG_DIR or the temp directory); return its path."""
    from .crashlog import write_crash_log

    return write_crash_log(exc)


# Help text is rich markup: a unit such as [s] or a table such as [campaign] is written \\[s] in it,
# or it vanishes as an unknown style tag (tests/test_cli.py checks every command's help).
app = typer.Typer(
    cls=_ErrorBoundary,
    name="ftcreport",
    help=(
        "Fault-tolerant control of linked 2WD robots: simulate fault cases through "
        "switching, adaptive and active FTC, compare against nominal and oracle, report.\n\n"
        "Examples:\n\n"
        "  ftcreport patterns 3            # compensable failure patterns of a 3-robot chain\n\n"
        "  ftcreport demo --robots 3       # nominal velocity loop with a motor lost at 10 s"
    ),
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
)
cases_app = typer.Typer(help="Validate case files or start a new one.", no_args_is_help=True)
app.add_typer(cases_app, name="cases")
baseline_app = typer.Typer(
    help="Baselines for 'check --baseline': headline metrics and key signals of every case x scheme.",
    no_args_is_help=True,
)
app.add_typer(baseline_app, name="baseline")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"ftcreport {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the full traceback of an unexpected error instead of logging it.")
    ] = False,
) -> None:
    """ftcreport command-line interface."""


# options shared by the commands that run on Dask (campaign, coverage, fdi)
SchedulerOpt = Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler, e.g. tcp://host:8786.")]
WorkersOpt = Annotated[int, typer.Option(help="Worker processes of the local Dask cluster.")]
InProcessOpt = Annotated[bool, typer.Option("--in-process", help="Run in this process, without Dask.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")]


def _dask(scheduler: str | None, workers: int, in_process: bool, quiet: bool, force: bool) -> dict:
    """The keywords a Dask command passes on to run_campaign, run_coverage or run_fdi (``--scheduler``
    checked first: a malformed address is bad input, exit 2)."""
    if scheduler is not None:
        _check_scheduler(scheduler)
    return {
        "scheduler": scheduler,
        "workers": workers,
        "in_process": in_process,
        "show_progress": not quiet,
        "force": force,
    }


def _check_scheduler(address: str) -> None:
    """A Dask scheduler address ``[protocol://]host:port`` (distributed's own parser); FtcError naming
    ``--scheduler`` when it is malformed.  Whether a scheduler answers there is found when connecting."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address, strict=False)
        if protocol in ("tcp", "tls", "ws", "wss"):
            host, port = parse_host_port(location)
            if not host or port is None or not 0 < int(port) < 65536:
                raise ValueError(f"a host and a port in 1..65535 are expected, got '{location}'")
        elif not location:
            raise ValueError(f"no location after '{protocol}://'")
    except (ValueError, TypeError) as exc:
        raise FtcError(
            f"--scheduler: '{address}' is not a scheduler address ({exc}); give tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786"
        ) from None


@app.command()
def patterns(
    robots: Annotated[int, typer.Argument(help="Number of robots in the chain (>= 2).")],
) -> None:
    """List the compensable 0/1 failure patterns of an n-robot chain (rank(Bbar sigma) = 2).

    1 = the wheel works, 0 = it gives no torque; wheel order 1r, 1l, 2r, 2l, ...

    Example: ftcreport patterns 2
    """
    from .model import compensable_patterns, wheel_names

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

    from .control import TrackingController
    from .limits import budget_problem
    from .metrics import singularity_margin
    from .model import FaultEvent, FaultSchedule
    from .sim import Plant, SimSettings, demo_chain, simulate

    if not 2 <= robots <= 12:
        raise FtcError(f"--robots: must be between 2 and 12, got {robots}")
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
    Exit 0 when every run ends as its case expects, 1 when some run (cached or not) or case failed.

    Example: ftcreport batch cases/ --jobs 2
    """
    from .batch import failures_summary, run_batch

    res = run_batch(cases or [Path("cases")], out, jobs, force, duration, show_progress=not quiet)
    peak = res.worker_peak_rss_mb
    memory = "" if peak is None else f"; worker peak memory {peak:.0f} MB ({len(res.worker_peaks_mb)} worker(s))"
    typer.echo(
        f"{len(res.cases)} case(s): {len(res.simulated)} run(s) simulated, {len(res.cached)} cached, "
        f"{len(res.failed_runs)} failed, {len(res.case_errors)} case file(s) rejected{memory}; "
        f"report: {out / 'index.html'}"
    )
    if verbose:
        from .store import load_metrics

        for name, scheme in sorted(res.simulated + res.cached):
            m = load_metrics(out, name, scheme) or {}
            typer.echo(
                f"  {name} / {scheme}: {m.get('status', '?')}, final error {_fmt(m.get('position_error_final'))} m, "
                f"wall {_fmt(m.get('wall_time'))} s{' (cached)' if (name, scheme) in res.cached else ''}"
            )
    if res.case_errors or res.failed_runs:
        typer.echo(failures_summary(res), err=True)
        raise typer.Exit(code=1)


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
            help="Run each scheme again at dt/2 (an error-controlled method: at rtol/10 and atol/10) and print the "
            "change of the headline metrics (stored as verify_dt in metrics.json); exit 1 if a change exceeds "
            "1 %% (+1e-6 absolute).",
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
    hold, or --verify-dt finds the step not converged; 2 for a bad case file.

    Example: ftcreport run cases/two_link_switching.toml --scheme switching --duration 30
    """
    from .cases import configured_schemes, dropped_faults, load_case, option_schemes, with_duration
    from .errors import RunEnvironmentError
    from .runner import build, dt_sensitivity, halve_dt, run_scheme
    from .store import save_run

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
    from .batch import record_case, run_key, write_case_manifest
    from .store import output_lock

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
                from .report.render import render_case, render_index

                page = render_case(out, c.name)
                render_index(out)
    except BaseException as exc:  # the interrupt message says how many schemes' runs are stored
        from .errors import note_stored
        from .lifetime import interrupt_of

        if (stop := interrupt_of(exc)) is not None:
            note_stored(stop, len(rows))
        raise
    if not quiet:
        typer.echo(_table(rows))
        if half is not None:
            typer.echo(_dt_table(rows))
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
        if "rtol" in g:  # an error-controlled run: checked at a tenth of its tolerances
            field, at, how = ("simulation.rtol", f"rtol = {g['rtol']:g}", "at rtol/10")
        typer.echo(
            f"ftcreport: error: {case}: {field}: {m['scheme']}: not converged at {at} "
            f"({v['worst']} changes by {v['worst_rel_change']:.3g} relative {how})",
            err=True,
        )
    if failed or loose or not_stored or unheld:
        raise typer.Exit(code=1)


def _run_gate(out: Path, name: str, schemes: list[str]):
    """The gate items of the runs ``run`` just stored (thresholds, claims and the other kinds of
    ftcreport.check.CASE_ITEMS, not the runs' status: ``run`` reports those itself), restricted to
    ``schemes``: an item that reads a scheme not run (``--scheme``) or a run that failed (already
    reported as such) is not judged."""
    from .check import CASE_ITEMS, run_items, stored_case

    case = stored_case(out, name)
    items = [item for source in CASE_ITEMS if source is not run_items for item in source(case)]
    return [item for item in items if set(item.schemes) <= set(schemes)]


@contextlib.contextmanager
def _running(what: str, quiet: bool):
    """A spinner on a terminal's stderr while a scheme runs (its first run on a machine compiles its
    loop for about a minute: the user sees why nothing else moves).  Nothing when piped or quiet."""
    if quiet or not sys.stderr.isatty():
        yield
        return
    from rich.console import Console

    note = " (a scheme's first run on this machine compiles it: about a minute; later runs load it)"
    with Console(stderr=True).status(f"{what}: simulating{note}"):
        yield


def _dt_table(rows: list[dict]) -> str:
    """The change of each headline metric from dt to dt/2, per scheme (run --verify-dt)."""
    lines = [f"{'dt check':<10} {'metric':<22} {'as run':>11} {'refined':>11} {'change':>10} {'relative':>9}"]
    for m in rows:
        v = m["verify_dt"]
        verdict = "converged" if v["converged"] else "NOT converged"
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
    w = max([10, *(len(m["scheme"]) for m in rows)])  # a plug-in scheme's name may be longer
    head = (
        f"{'scheme':<{w}} {'status':<9} {'max err after faults':>20} {'final err':>10} {'switches':>8} "
        f"{'match':>6} {'peak tau':>9} {'wall/sim-s':>10}"
    )
    lines = [head, "-" * len(head)]
    for m in rows:
        after = [p["position_error_max"] for p in m.get("phases", [])[1:] if p["position_error_max"] is not None]
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
    """Re-render every HTML page from stored results (no simulation).

    A stored run that is damaged (its record does not match its files) is shown as such and named here;
    a run that ended in a status its case counts as a failure is named too.  Exit 0 when every stored run
    is sound and ends as its case expects, 1 otherwise.

    Example: ftcreport report --out reports
    """
    from .check import stored_case
    from .report.render import render_all

    if not out.is_dir():
        raise FtcError(f"{out}: no stored results (run 'ftcreport batch' first)")
    from .store import output_lock, read_json

    with output_lock(out, "report"), _render_progress() as (notify, done):
        page = render_all(out, force=True, notify=notify, done=done)
        bad = []
        for rec in sorted(out.glob("*/case.json")):
            if (read_json(rec) or {}).get("status") != "ok":
                continue  # a rejected case file: its page says why
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
    if not console.is_terminal:
        yield None, None
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

    from .batch import run_batch
    from .check import exit_code, gate, summary
    from .report.junit import write_junit
    from .store import read_json

    if baseline is not None:
        from .baseline import check_dest

        check_dest(baseline)  # a mistyped --baseline before anything runs
    started = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    wall0 = _time.perf_counter()
    res = run_batch(cases or [Path("cases")], out, jobs, show_progress=not quiet)
    items = gate(out, res.cases, res.case_errors, res.not_stored)
    baseline_page = None
    if baseline is not None:
        from .baseline import baseline_items
        from .report.baseline_page import render_baseline
        from .store import output_lock

        found, comparisons = baseline_items(out, res.cases, baseline)
        items += found
        with output_lock(out, "check"):
            baseline_page = render_baseline(out, baseline, comparisons)
    if junit is not None:
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
    from .baseline import save_baseline
    from .batch import run_batch
    from .store import output_lock

    if dest.exists() and not dest.is_dir():
        raise FtcError(f"{dest}: --dest: exists and is not a directory")
    res = run_batch(cases or [Path("cases")], out, jobs, show_progress=not quiet)
    with output_lock(dest, "baseline save"):
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


@app.command()
def analyze(
    case: Annotated[Path, typer.Argument(help="One case file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print the results as one JSON object.")] = False,
    confirm: Annotated[
        bool,
        typer.Option(
            "--confirm/--no-confirm",
            help="Confirm each stability limit by two short simulations at 0.9x and 1.1x (cases with sampled "
            "control or motors; a few seconds, more if the engine's loop must first be compiled).",
        ),
    ] = True,
    results: Annotated[
        Path | None,
        typer.Option(
            "--results",
            help="A results directory (as batch writes): the stored runs of this case, if current, give the "
            "states each scheme held and the model switching selected, phase by phase.",
        ),
    ] = None,
    quiet: QuietOpt = False,
) -> None:
    """Linearized analyses: every scheme in every fault phase, sampled where the case is, with limits.

    Per scheme and fault phase: the true and applied failure pattern, the closed loop's poles (z-plane
    where the controller is sampled), stability, loop-at-a-time and disk margins at the actuator inputs;
    per scheme the largest stable sample time and velocity gain, confirmed by simulation; and the
    case-wide analyses (error poles, controllability per pattern, observer).  README, "Linearized
    analysis", documents every key of --json.

    Example: ftcreport analyze cases/motors/two_link_switching_motors.toml --json
    """
    from .analysis import analyze_case
    from .cases import load_case

    c = load_case(case)
    runs = _current_runs(results, c) if results is not None else None
    # progress on a terminal only (as batch): nothing when piped or -q
    say = None if quiet or not sys.stderr.isatty() else (lambda line: typer.echo(f"  analysed {line}", err=True))
    res = analyze_case(c, runs=runs, confirm=confirm, progress=say)
    if as_json:
        from .store import _jsonable

        typer.echo(json.dumps(_jsonable(_public(res)), indent=2))
        return
    from .analysis.summary import text_summary

    for line in text_summary(res):
        typer.echo(line)


def _public(obj):
    """The analysis without its private keys (``_bode``: the figures' frequency responses)."""
    if isinstance(obj, dict):
        return {k: _public(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, list):
        return [_public(v) for v in obj]
    return obj


def _current_runs(results: Path, case) -> dict:
    """The stored time series of the case's schemes under ``results`` whose cache key is current."""
    from .batch import run_key
    from .cases import configured_schemes
    from .store import cached_key, load_timeseries

    out = {}
    for scheme in configured_schemes(case):
        if cached_key(results, case.name, scheme) == run_key(case, scheme):
            ts = load_timeseries(results, case.name, scheme)
            if ts is not None:
                out[scheme] = ts
    return out


@app.command()
def campaign(
    case: Annotated[Path, typer.Argument(help="Base case file with a \\[campaign] table.")],
    samples: Annotated[int, typer.Option("--samples", "-n", help="Number of samples (variants).")] = 100,
    seed: Annotated[int, typer.Option(help="Campaign seed; sample i uses a seed derived from (seed, i).")] = 0,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
    out: Annotated[Path | None, typer.Option(help="Output directory (default reports/campaigns/<case>).")] = None,
    schemes: Annotated[str | None, typer.Option(help="Comma-separated schemes (default: all in the case).")] = None,
    in_process: InProcessOpt = False,
    quiet: QuietOpt = False,
    force: Annotated[
        bool, typer.Option("--force", help="Re-run stored samples of another version or case content.")
    ] = False,
) -> None:
    """Monte Carlo fault campaign: draw variants of CASE, run every scheme on Dask, write a table and report.

    Resumable: re-running with the same --out skips the samples already there; samples stored by
    another package version or from another case content are refused (--force re-runs them).

    Example: ftcreport campaign cases/two_link_campaign.toml --samples 200 --workers 2
    """
    from .campaign import read_table, run_campaign, select_schemes
    from .cases import load_case
    from .report.campaign import render_campaign
    from .store import output_lock

    base = load_case(case)
    out_dir = out or Path("reports") / "campaigns" / base.name
    chosen = _names(schemes)
    select_schemes(base, chosen)  # a wrong --schemes before the output directory is made
    dask = _dask(scheduler, workers, in_process, quiet, force)  # and a malformed --scheduler
    with output_lock(out_dir, "campaign"):
        res = run_campaign(base, samples, out_dir, seed=seed, schemes=chosen, **dask)
        page = render_campaign(out_dir, read_table(res.table))
    _done(res, "samples run", page)


@app.command()
def sample(
    campaign_dir: Annotated[Path, typer.Argument(help="A campaign's output directory (reports/campaigns/<case>).")],
    index: Annotated[list[int], typer.Argument(help="Sample numbers (the 'sample' column of results.csv).")],
) -> None:
    """Render the page of campaign samples: the sample's variant re-simulated from its seeds, as a case page
    (verdict, replay, signals), linked from the campaign's page.

    Example: ftcreport sample reports/campaigns/two_link_campaign 17
    """
    from .campaign import read_table
    from .report.campaign import render_campaign, render_sample
    from .store import output_lock

    if not (campaign_dir / "campaign.json").is_file():
        raise FtcError(f"{campaign_dir}: not a campaign directory (no campaign.json); run 'ftcreport campaign' first")
    with output_lock(campaign_dir, "sample"):
        for i in index:
            with _running(f"sample {i}", False):
                page = render_sample(campaign_dir, i)
            typer.echo(f"sample {i}: {page}")
        if (campaign_dir / "results.csv").exists():  # the campaign's page links the new pages
            render_campaign(campaign_dir, read_table(campaign_dir / "results.csv"), worst=0)


def _done(res, runs: str, page: Path, detail: str = "") -> None:
    """The summary line of a resumable Dask command (campaign, coverage); exit 1 when a task failed."""
    typer.echo(
        f"{len(res.completed)} {runs}, {res.skipped} already done, {len(res.failed)} failed "
        f"in {res.wall_time:.1f} s{detail}; table {res.table}; report {page}"
    )
    if res.failed:
        raise typer.Exit(1)


@app.command()
def export(
    out: Annotated[Path, typer.Option(help="Output directory holding stored results.")] = Path("reports"),
    dest: Annotated[Path | None, typer.Option(help="Where to write (default: beside the results, in OUT).")] = None,
) -> None:
    """Tidy files of stored results: netCDF per run and metrics.parquet (one row per case, scheme, phase).

    Writes DEST/<case>/<scheme>/timeseries.nc (xarray/h5netcdf: dimensions time, coordinate,
    velocity, wheel, robot, parameter, pattern; units in attributes; fault schedule and case hash
    as metadata) and DEST/metrics.parquet.

    Example: ftcreport export --out reports
    """
    from .store import output_lock
    from .tidy import export as _export

    if not out.is_dir():
        raise FtcError(f"{out}: no stored results (run 'ftcreport batch' first)")
    damaged: list[str] = []
    with contextlib.ExitStack() as locks:  # the results read and the directory written: no batch meanwhile
        locks.enter_context(output_lock(out, "export"))
        if dest is not None:
            locks.enter_context(output_lock(dest, "export"))
        paths = _export(out, dest, damaged)
    n_nc = sum(p.suffix == ".nc" for p in paths)
    typer.echo(f"{n_nc} netCDF file(s) and {paths[-1]} written")
    for problem in damaged:  # left out of the netCDF files, a row with status error in the table
        typer.echo(printable(f"ftcreport: error: {problem}; not exported (re-run 'ftcreport batch')"), err=True)
    if damaged:
        raise typer.Exit(code=1)


_MAX_ERRORS = 50  # errors shown per case file by 'cases validate'


@cases_app.command("validate")
def cases_validate(
    paths: Annotated[
        list[Path] | None,
        typer.Argument(help="Case files or directories, searched recursively (default: cases/ and its subfolders)."),
    ] = None,
) -> None:
    """Validate case files: 'ok' per valid file, every error of the others; exit 0 if all are valid, 2 otherwise.

    Each error is one line 'file: field: reason' (at most 50 per file, then the count of the rest).
    A directory is searched recursively (cases/ holds cases/motors/).

    Example: ftcreport cases validate
    """
    from .cases import load_case
    from .errors import CaseError

    paths = paths or [Path("cases")]
    files = [f for p in paths for f in (sorted(p.rglob("*.toml")) if p.is_dir() else [p])]
    if not files:
        raise FtcError(f"no case files (*.toml) in {', '.join(map(str, paths))}")
    bad = 0
    for f in files:
        try:
            c = load_case(f)
        except FtcError as exc:
            bad += 1
            lines = exc.lines if isinstance(exc, CaseError) else (str(exc),)
            for line in lines[:_MAX_ERRORS]:
                typer.echo(f"ftcreport: error: {line}", err=True)
            if len(lines) > _MAX_ERRORS:
                typer.echo(f"ftcreport: error: {f}: and {len(lines) - _MAX_ERRORS} more error(s)", err=True)
            continue
        typer.echo(f"ok     {f}")
        for w in c.warnings():
            typer.echo(f"warning: {f}: {w}", err=True)
    if bad:
        raise typer.Exit(code=2)


@cases_app.command("new")
def cases_new(
    name: Annotated[str, typer.Argument(help="Name of the new case (file NAME.toml).")],
    directory: Annotated[Path, typer.Option("--dir", help="Where to write it.")] = Path("cases"),
) -> None:
    """Write a commented case template (three links on a circle, one motor lost) to DIR/NAME.toml.

    Example: ftcreport cases new my_case
    """
    import os

    from .cases import TEMPLATE, load_case
    from .limits import name_problem

    if (why := name_problem(name)) is not None:
        raise FtcError(f"{directory}: name: {why}")
    path = directory / f"{name}.toml"
    if directory.exists() and not directory.is_dir():
        raise FtcError(f"{directory}: --dir: exists and is not a directory")
    directory.mkdir(parents=True, exist_ok=True)
    try:  # O_EXCL: never overwrite, even when another process creates the file meanwhile
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        raise FtcError(f"{path}: exists already; not overwritten") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(TEMPLATE)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    load_case(path)  # the template itself is valid
    typer.echo(f"wrote {path}")


def _names(text: str | None) -> list[str] | None:
    """A comma-separated option as a list of names (None when the option is not given)."""
    return None if text is None else [x.strip() for x in text.split(",") if x.strip()]


def _floats(text: str | None, option: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise FtcError(f"{option}: expected comma-separated numbers, got '{text}'") from None


@app.command()
def coverage(
    case: Annotated[Path, typer.Argument(help="Case file (its faults are replaced by the fault set).")],
    times: Annotated[
        str | None, typer.Option(help="Comma-separated onset times \\[s] (default: 3 along the curvature).")
    ] = None,
    schemes: Annotated[str | None, typer.Option(help="Comma-separated schemes (default: all in the case).")] = None,
    sigmas: Annotated[str, typer.Option(help="Partial-loss gains, comma-separated, in (0, 1).")] = "0.25,0.5",
    friction: Annotated[float, typer.Option(help="Friction of the friction faults \\[N m].")] = 0.5,
    kinds: Annotated[str, typer.Option(help="Fault kinds: loss,pair,partial,friction.")] = "loss,pair,partial,friction",
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
    out: Annotated[Path | None, typer.Option(help="Output directory (default reports/coverage/<case>).")] = None,
    in_process: InProcessOpt = False,
    quiet: QuietOpt = False,
    force: Annotated[bool, typer.Option("--force", help="Re-run stored items of another version or case.")] = False,
) -> None:
    """Fault-coverage map: every scheme on every single and paired wheel loss, partial loss and friction.

    Each fault runs at several onset times; the page shows per scheme which faults it survives beside
    the redundancy rule's prediction (heatmaps). Same Dask path and resumption as campaign.

    Example: ftcreport coverage cases/two_link_campaign.toml --times 5,10,15
    """
    from .cases import load_case
    from .coverage import run_coverage
    from .report.coverage import render_coverage
    from .store import output_lock

    base = load_case(case)
    out_dir = out or Path("reports") / "coverage" / base.name
    options = {
        "times": _floats(times, "--times"),
        "schemes": _names(schemes),
        "sigmas": tuple(_floats(sigmas, "--sigmas") or ()),
        "friction": friction,
        "kinds": tuple(_names(kinds) or ()),
    }
    with output_lock(out_dir, "coverage"):  # a second coverage into out_dir is refused, naming this one
        res = run_coverage(base, out_dir, **options, **_dask(scheduler, workers, in_process, quiet, force))
        page = render_coverage(out_dir)
    _done(res, "fault runs", page, f" (onsets {', '.join(f'{t:g}' for t in res.times)} s)")


@app.command()
def fdi(
    case: Annotated[Path, typer.Argument(help="Base case with a \\[campaign] table and an active scheme.")],
    samples: Annotated[int, typer.Option("--samples", "-n", help="Campaign samples per active scheme.")] = 50,
    seed: Annotated[int, typer.Option(help="Campaign seed (the same samples as campaign --seed).")] = 0,
    schemes: Annotated[str | None, typer.Option(help="Active schemes, comma-separated (default: all).")] = None,
    scheduler: SchedulerOpt = None,
    workers: WorkersOpt = 2,
    out: Annotated[Path | None, typer.Option(help="Output directory (default reports/fdi/<case>).")] = None,
    in_process: InProcessOpt = False,
    quiet: QuietOpt = False,
    force: Annotated[bool, typer.Option("--force", help="Re-run stored traces of another version or case.")] = False,
) -> None:
    """FDI evaluation: ROC, delay and isolation of the estimate-based and a CUSUM residual detector.

    Example: ftcreport fdi cases/two_link_campaign.toml -n 20
    """
    from .cases import load_case
    from .fdi import run_fdi
    from .report.fdi import render_fdi
    from .store import output_lock

    base = load_case(case)
    out_dir = out or Path("reports") / "fdi" / base.name
    dask = _dask(scheduler, workers, in_process, quiet, force)
    with output_lock(out_dir, "fdi"):
        res = run_fdi(base, samples, out_dir, seed=seed, schemes=_names(schemes), **dask)
        page = render_fdi(out_dir)
    typer.echo(f"{len(res['failed'])} failed; results {out_dir / 'fdi.json'}; report {page}")
    if res["failed"]:
        raise typer.Exit(1)


@cases_app.command("schema")
def cases_schema(
    markdown: Annotated[
        bool, typer.Option("--markdown", help="Print the field tables of cases/README.md instead.")
    ] = False,
) -> None:
    """Print the JSON Schema of case files (descriptions, units, ranges), generated from the models.

    Editors validate cases with it (taplo: the repository's .taplo.toml points at cases/case.schema.json).

    Example: ftcreport cases schema > case.schema.json
    """
    from .schema_doc import markdown_tables, schema_json

    typer.echo(markdown_tables() if markdown else schema_json(), nl=False)


@app.command("schemes")
def schemes_cmd(
    source: Annotated[
        str | None,
        typer.Argument(
            help="A case file (its plug-in schemes are loaded and state sizes given), a scheme file, or 'check'."
        ),
    ] = None,
    file: Annotated[Path | None, typer.Argument(help="With 'check': the scheme file to check.")] = None,
) -> None:
    """List the built-in and registered (plug-in) schemes: name, family, description, reference; or check one.

    Given a case file, its plugins are loaded and the schemes it runs are marked with their state
    size (the controller's states: kinematic and the scheme's own); given a scheme file (.py), it is
    loaded first.

    'ftcreport schemes check FILE' (e.g. 'ftcreport schemes check examples/schemes/sliding_mode.py')
    runs the scheme file's laws through a battery of checks before their first real run (shapes, finite
    outputs on healthy and faulty patterns, determinism, declared signals written, writes within the
    declared widths under numba's bounds checks, parameter defaults): one line per failure naming the
    file, the line, the function and what to fix; exit 2 when one fails.

    Example: ftcreport schemes cases/two_link_sliding_mode.toml
    """
    from .schemes import built_in, load_plugin, registered

    if source == "check":
        if file is None:
            raise FtcError("schemes check: give the scheme file to check (ftcreport schemes check FILE)")
        _check_schemes(file)
        return
    if file is not None:
        raise FtcError(f"schemes: one argument (a case or scheme file) expected, got {source} and {file}")
    path = None if source is None else Path(source)
    sizes: dict[str, int] = {}
    if path is not None and path.suffix == ".py":
        load_plugin(path)
    elif path is not None:
        from .cases import configured_schemes, load_case
        from .runner import build, make_controller

        case = load_case(path)
        built = build(case)
        for s in configured_schemes(case):
            sizes[s] = int(getattr(make_controller(built, s), "n_states", 0))
    rows = [(name, sc.family, sc.description, sc.reference, "built-in") for name, sc in built_in().items()]
    for name, sc in sorted(registered().items()):
        law = getattr(sc.law, "py_func", sc.law)
        code = getattr(law, "__code__", None)
        rows.append((name, sc.family, sc.description, sc.reference, code.co_filename if code else "registered"))
    for name, family, description, reference, where in rows:
        state = f"  [runs in this case, {sizes[name]} states]" if name in sizes else ""
        typer.echo(f"{name:16s} {family:16s} {description}{state}")
        typer.echo(f"{'':16s} {'':16s} reference: {reference}; {where}")


def _check_schemes(file: Path) -> None:
    """``schemes check FILE``: the battery's lines (failures first, numba's message after a TypingError)."""
    from .schemes.check import check_file

    typer.echo(f"checking {file} (compiles the laws with and without bounds checks: a minute or two when cold)")
    findings = check_file(file)
    failed = [f for f in findings if not f.ok]
    for f in failed + [f for f in findings if f.ok]:
        typer.echo(("FAIL " if not f.ok else "ok   ") + f.message)
        if f.detail:
            typer.echo("\n".join("     | " + line for line in f.detail.strip().splitlines()))
    if failed:
        raise typer.Exit(code=2)


if __name__ == "__main__":  # pragma: no cover
    app()
