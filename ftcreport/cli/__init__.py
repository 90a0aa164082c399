"""Command-line interface (Typer): thin commands over the library.

Every command parses its arguments and calls the library; :class:`_ErrorBoundary` turns an
:class:`~ftcreport.errors.FtcError`, or any other exception, into one line on stderr and an
exit code (README, "Errors, exit codes, interruptions").

By role: :mod:`.app` (the Typer app, the error boundary, the options the commands share),
:mod:`.runs` (patterns, demo, batch, run, report, check, baseline), :mod:`.studies` (analyze,
campaign, sample, export, coverage, fdi), :mod:`.cases_cmds` (cases, schemes).  Importing this
package registers every command, in that order.
"""

from __future__ import annotations

# the import order is the order the commands are registered in, and --help lists them in
# isort: off
from .app import (  # noqa: F401 - re-exported
    _CLI_FLOW,
    _MAX_ERRORS,
    InProcessOpt,
    QuietOpt,
    SchedulerOpt,
    WorkersOpt,
    _check_scheduler,
    _classify,
    _cli_flow,
    _crash_log,
    _dask,
    _ErrorBoundary,
    _floats,
    _names,
    _plain_flags,
    _running,
    _version,
    app,
    baseline_app,
    cases_app,
    main,
)
from .runs import (  # noqa: F401 - re-exported
    _dt_table,
    _fmt,
    _render_progress,
    _run_gate,
    _table,
    baseline_save,
    batch,
    check,
    demo,
    patterns,
    report,
    run,
)
from .studies import (  # noqa: F401 - re-exported
    _current_runs,
    _done,
    _public,
    analyze,
    campaign,
    coverage,
    export,
    fdi,
    sample,
)
from .cases_cmds import (  # noqa: F401 - re-exported
    _check_schemes,
    cases_new,
    cases_schema,
    cases_validate,
    schemes_cmd,
)
# isort: on

__all__ = ["app", "main"]
