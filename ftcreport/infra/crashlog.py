"""The crash log of a bug (edge: a file in FTCREPORT_LOG_DIR or the temporary directory)."""

from __future__ import annotations

import datetime as _dt
import os
import tempfile
import traceback
from pathlib import Path

from .. import __version__

__all__ = ["write_crash_log"]


def write_crash_log(exc: BaseException) -> str:
    """Write the traceback of a bug to a log file (FTCREPORT_LOG_DIR or the temp directory); return its path.

    The CLI's error boundary names it in its one line (exit 3); a batch names it for a run whose worker met
    a bug (the run is not stored)."""
    text = "".join(traceback.format_exception(exc))
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    for d in (os.environ.get("FTCREPORT_LOG_DIR"), tempfile.gettempdir()):
        if not d:
            continue
        try:
            path = Path(d) / f"ftcreport-crash-{stamp}-{os.getpid()}.log"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(f"ftcreport {__version__}\n{text}")
            return str(path)
        except OSError:
            continue
    return "<no writable log directory>"
