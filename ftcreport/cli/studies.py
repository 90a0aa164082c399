"""Commands of the studies over a case: analyze, campaign, sample, export, coverage, fdi."""

from __future__ import annotations

import contextlib
import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from ..errors import FtcError, printable
from .app import InProcessOpt, QuietOpt, SchedulerOpt, WorkersOpt, _dask, _floats, _names, _running, app


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
    from ..analysis import analyze_case
    from ..cases import load_case
    from ..errors import ReferenceError

    c = load_case(case)
    runs = _current_runs(results, c) if results is not None else None
    # progress on a terminal only (as batch): nothing when piped or -q
    say = None if quiet or not sys.stderr.isatty() else (lambda line: typer.echo(f"  analysed {line}", err=True))
    try:
        res = analyze_case(c, runs=runs, confirm=confirm, progress=say)
    except ReferenceError as exc:  # the reference alone (no scheme's): name the file and the table
        raise ReferenceError(f"{case}: reference: {exc}") from None
    if as_json:
        from ..storage.store import _jsonable

        typer.echo(json.dumps(_jsonable(_public(res)), indent=2))
        return
    from ..analysis.summary import text_summary

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
    """The stored time series of the case's schemes under ``results`` whose run is sound and current (its
    record's key is this case content's, :func:`ftcreport.storage.store.check_run`); a note on stderr names
    the schemes analysed without one.  A ``results`` that is not a directory of case results: FtcError."""
    from ..cases import configured_schemes
    from ..errors import FtcError
    from ..storage.store import check_run, kind_of, load_timeseries
    from ..studies.batch import run_key

    if kind_of(results) != "results":
        raise FtcError(
            f"{results}: --results: not a directory of case results (the --out of 'ftcreport batch' or 'run')"
        )
    out, missing = {}, []
    for scheme in configured_schemes(case):
        stored = check_run(results, case.name, scheme, key=run_key(case, scheme))
        ts = load_timeseries(results, case.name, scheme) if stored.sound else None
        if ts is None:
            missing.append(f"{scheme} ({stored.problem or 'no time series'})")
        else:
            out[scheme] = ts
    if missing:
        typer.echo(
            f"note: no current stored run in {results} for {', '.join(missing)}: analysed from the initial "
            "state (not current: the case changed since the run, or it was never run there)",
            err=True,
        )
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
    another package version or from another case content are refused (--force re-runs them).  A smaller
    --samples reports samples 0 to N-1 only, as a fresh campaign would; the others stay stored.

    Example: ftcreport campaign cases/two_link_campaign.toml --samples 200 --workers 2
    """
    from ..cases import load_case
    from ..errors import note_stored
    from ..report.campaign import render_campaign
    from ..storage.store import output_lock
    from ..studies.campaign import read_table, run_campaign, select_schemes

    base = load_case(case)
    out_dir = out or Path("reports") / "campaigns" / base.name
    chosen = _names(schemes)
    select_schemes(base, chosen)  # a wrong --schemes before the output directory is made
    dask = _dask(scheduler, workers, in_process, quiet, force)  # and a malformed --scheduler
    with output_lock(out_dir, "campaign"):
        res = run_campaign(base, samples, out_dir, seed=seed, schemes=chosen, **dask)
        try:
            page = render_campaign(out_dir, read_table(res.table))
        except KeyboardInterrupt as exc:  # the interrupt message counts the stored samples here too
            note_stored(exc, res.skipped + len(res.completed), "sample")
            raise
    kept = f" ({res.beyond} stored sample{'s' * (res.beyond > 1)} beyond --samples {samples}: kept, not reported)"
    _done(res, "samples run", page, kept if res.beyond else "")


@app.command()
def sample(
    campaign_dir: Annotated[Path, typer.Argument(help="A campaign's output directory (reports/campaigns/<case>).")],
    index: Annotated[list[int], typer.Argument(help="Sample numbers (the 'sample' column of results.csv).")],
) -> None:
    """Render the page of campaign samples: the sample's variant re-simulated from its seeds, as a case page
    (verdict, replay, signals), linked from the campaign's page.

    Example: ftcreport sample reports/campaigns/two_link_campaign 17
    """
    from ..report.campaign import check_sample_index, render_campaign, render_sample
    from ..storage.store import output_lock
    from ..studies.campaign import read_table, stored_table

    if not (campaign_dir / "campaign.json").is_file():
        raise FtcError(f"{campaign_dir}: not a campaign directory (no campaign.json); run 'ftcreport campaign' first")
    for i in index:  # every index before any page: a sample the campaign never ran is bad input
        check_sample_index(campaign_dir, i)
    with output_lock(campaign_dir, "sample"):
        for i in index:
            with _running(f"sample {i}", False):
                page = render_sample(campaign_dir, i)
            typer.echo(f"sample {i}: {page}")
        if (campaign_dir / "results.csv").exists():  # the campaign's page links the new pages
            # from the sealed records, not the table as found (an edited view would reach the page)
            render_campaign(campaign_dir, read_table(stored_table(campaign_dir)), worst=0)


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
    dest: Annotated[
        Path | None,
        typer.Option(
            help="Where to write (default: beside the results, in OUT): a new directory or an earlier export's; "
            "another command's directory (a batch's results, a campaign) is refused."
        ),
    ] = None,
) -> None:
    """Tidy files of stored results: netCDF per run and metrics.parquet (one row per case, scheme, phase).

    Writes DEST/<case>/<scheme>/timeseries.nc (xarray/h5netcdf: dimensions time, coordinate,
    velocity, wheel, robot, parameter, pattern; units in attributes; fault schedule and case hash
    as metadata) and DEST/metrics.parquet.

    Example: ftcreport export --out reports
    """
    from ..storage.store import check_apart, deleted_runs, edited_cases, output_lock, unrecorded_cases
    from ..storage.tidy import export as _export

    if not out.is_dir():
        raise FtcError(f"{out}: no stored results (run 'ftcreport batch' first)")
    if dest is not None:  # never into the results tree (a stored run's folder): refused before anything is written
        check_apart(dest, out)
    with contextlib.ExitStack() as locks:  # the results read and the directory written: no batch meanwhile
        locks.enter_context(output_lock(out, "export"))
        if dest is not None:  # a directory of its own: never another batch's (its metrics.parquet) or family's
            locks.enter_context(output_lock(dest, "export --dest", "--dest"))
        damaged: list[str] = unrecorded_cases(out)  # runs whose case record is gone: not exported, and said so
        damaged += edited_cases(out)  # a stored case file edited after its runs: no fault schedule read from it
        damaged += deleted_runs(out)  # a run directory deleted by hand: not in the exports
        paths = _export(out, dest, damaged)
    n_nc = sum(p.suffix == ".nc" for p in paths)
    typer.echo(f"{n_nc} netCDF file(s) and {paths[-1]} written")
    for problem in damaged:  # left out of the netCDF files (a damaged run: a row with status error in the table)
        tail = "" if "run 'ftcreport batch'" in problem else "; not exported (re-run 'ftcreport batch')"
        typer.echo(printable(f"ftcreport: error: {problem}{tail}"), err=True)
    if damaged:
        raise typer.Exit(code=1)


@app.command()
def coverage(
    case: Annotated[Path, typer.Argument(help="Case file (its faults are replaced by the fault set).")],
    times: Annotated[
        str | None, typer.Option(help="Comma-separated onset times \\[s] (default: 3 along the curvature).")
    ] = None,
    schemes: Annotated[str | None, typer.Option(help="Comma-separated schemes (default: all in the case).")] = None,
    sigmas: Annotated[str, typer.Option(help="Partial-loss gains, comma-separated, in (0, 1).")] = "0.25,0.5",
    friction: Annotated[
        float, typer.Option(help="Friction of the friction faults \\[N m]: nonzero, in [-10000, 10000].")
    ] = 0.5,
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
    from ..cases import load_case
    from ..report.coverage import render_coverage
    from ..storage.store import output_lock
    from ..studies.campaign import select_schemes
    from ..studies.coverage import plan_coverage, run_coverage

    base = load_case(case)
    out_dir = out or Path("reports") / "coverage" / base.name
    options = {
        "times": _floats(times, "--times"),
        "schemes": _names(schemes),
        "sigmas": tuple(_floats(sigmas, "--sigmas") or ()),
        "friction": friction,
        "kinds": tuple(_names(kinds) or ()),
    }
    # every option before out_dir is made (as campaign): a bad one is exit 2, one line, and nothing written
    select_schemes(base, options["schemes"])
    plan_coverage(base, options["times"], options["sigmas"], friction, options["kinds"])
    dask = _dask(scheduler, workers, in_process, quiet, force)  # and a malformed --scheduler
    with output_lock(out_dir, "coverage"):  # a second coverage into out_dir is refused, naming this one
        res = run_coverage(base, out_dir, **options, **dask)
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
    from ..cases import load_case
    from ..report.fdi import render_fdi
    from ..storage.store import output_lock
    from ..studies.fdi import run_fdi

    base = load_case(case)
    out_dir = out or Path("reports") / "fdi" / base.name
    dask = _dask(scheduler, workers, in_process, quiet, force)
    with output_lock(out_dir, "fdi"):
        res = run_fdi(base, samples, out_dir, seed=seed, schemes=_names(schemes), **dask)
        page = render_fdi(out_dir)
    typer.echo(f"{len(res['failed'])} failed; results {out_dir / 'fdi.json'}; report {page}")
    if res["failed"]:
        raise typer.Exit(1)
