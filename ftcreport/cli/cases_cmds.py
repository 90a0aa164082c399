"""Commands on case files and schemes: cases validate/new/schema, schemes (list, check)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..errors import FtcError
from .app import _MAX_ERRORS, app, cases_app


@cases_app.command("validate")
def cases_validate(
    paths: Annotated[
        list[Path] | None,
        typer.Argument(help="Case files or directories, searched recursively (default: cases/ and its subfolders)."),
    ] = None,
) -> None:
    """Validate case files: 'ok' per valid file, every error of the others; exit 0 if all are valid, 2 otherwise.

    Each error is one line 'file: field: reason' (at most 50 per file, then the count of the rest).
    Beyond the file itself: a reference infeasible at t = 0 and a plug-in scheme whose declarations
    raise when bound to the case are errors (no run could start); a reference infeasible later, a warning.
    A directory is searched recursively (cases/ holds cases/motors/).

    Example: ftcreport cases validate
    """
    from ..cases import load_case
    from ..errors import CaseError

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
        from ..runner import start_problems

        errors, warnings = start_problems(c)
        if errors:  # valid as a file, but no run of these schemes can start
            bad += 1
            for line in errors[:_MAX_ERRORS]:
                typer.echo(f"ftcreport: error: {f}: {line}", err=True)
            continue
        typer.echo(f"ok     {f}")
        for w in [*c.warnings(), *warnings]:
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

    from ..cases import TEMPLATE, load_case
    from ..infra.atomic import name_os_error
    from ..infra.limits import name_problem

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
    except BaseException as exc:
        path.unlink(missing_ok=True)
        if isinstance(exc, OSError):  # a write to the descriptor (ENOSPC) names no file
            name_os_error(exc, path)
        raise
    load_case(path)  # the template itself is valid
    typer.echo(f"wrote {path}")


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
    from ..cases.schema_doc import markdown_tables, schema_json

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
    from ..schemes import built_in, load_plugin, registered

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
        from ..cases import configured_schemes, load_case
        from ..runner import build, make_controller

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
    from ..fast.scheme_check import check_file

    typer.echo(f"checking {file} (compiles the laws with and without bounds checks: a minute or two when cold)")
    findings = check_file(file)
    failed = [f for f in findings if not f.ok]
    for f in failed + [f for f in findings if f.ok]:
        typer.echo(("FAIL " if not f.ok else "ok   ") + f.message)
        if f.detail:
            typer.echo("\n".join("     | " + line for line in f.detail.strip().splitlines()))
    if failed:
        raise typer.Exit(code=2)
