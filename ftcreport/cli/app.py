"""The Typer app: the error boundary (one line and an exit code per failure), the options the commands share."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Annotated

import typer
from typer.core import TyperGroup

from .. import __version__
from ..errors import FtcError, printable


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

        from ..infra.lifetime import handle_stop_signals

        # SIGINT, SIGTERM, SIGHUP: Interrupted inside the command, ignored once it is over (ftcreport.infra.lifetime)
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
            from ..infra.lifetime import interrupt_of

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
        from ..errors import interrupted_message
        from ..infra.lifetime import exit_code

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
        from ..errors import stored_note

        return f"{where}: {why}{stored_note(exc)}", 2
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
    from ..infra.crashlog import write_crash_log

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
    and ``--workers`` checked first: a malformed address or a count below 1 is bad input, exit 2)."""
    if scheduler is not None:
        _check_scheduler(scheduler)
    from ..infra.limits import worker_count

    worker_count(workers, 1, "--workers")  # below 1 refused; the cap is applied once the tasks are known
    return {
        "scheduler": scheduler,
        "workers": workers,
        "in_process": in_process,
        "show_progress": not quiet,
        "force": force,
    }


#: the protocols a scheduler address may name: those of distributed that reach another process
#: (inproc is this process only; ucx needs a transport ftcreport does not install)
SCHEDULER_PROTOCOLS = ("tcp", "tls", "ws", "wss")


def _check_scheduler(address: str) -> None:
    """A Dask scheduler address ``[protocol://]host:port`` (distributed's own parser) of one of
    :data:`SCHEDULER_PROTOCOLS`; FtcError naming ``--scheduler`` and the accepted forms when it is
    malformed.  Whether a scheduler answers there is found when connecting."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address, strict=False)
        if protocol not in SCHEDULER_PROTOCOLS:
            raise ValueError(f"unsupported protocol '{protocol}://'")
        host, port = parse_host_port(location)
        if not host or port is None or not 0 < int(port) < 65536:
            raise ValueError(f"a host and a port in 1..65535 are expected, got '{location}'")
    except (ValueError, TypeError) as exc:
        forms = ", ".join(f"{p}://HOST:PORT" for p in SCHEDULER_PROTOCOLS)
        raise FtcError(
            f"--scheduler: '{address}' is not a scheduler address ({exc}); give tcp://HOST:PORT "
            f"(or {forms.split(', ', 1)[1]}; HOST:PORT means tcp), e.g. tcp://127.0.0.1:8786"
        ) from None


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


_MAX_ERRORS = 50  # errors shown per case file by 'cases validate'


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
