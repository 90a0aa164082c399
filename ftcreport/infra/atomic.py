"""A file written whole or not at all: a temporary file in the same directory, synced, then renamed into place.

A reader never sees a half-written file, and an interrupted write leaves the old file as it was (and at
worst a temporary ``.<name>.<random>.partial`` beside it).  The result store's ``write_atomic``
(:mod:`ftcreport.storage.store`) adds its guards around this; the case schema's docs
(:mod:`ftcreport.cases.schema_doc`) write their files with it directly.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["TMP_SUFFIX", "name_os_error", "replace_file"]

TMP_SUFFIX = ".partial"  # a temporary file of replace_file; only a killed process leaves one behind


def replace_file(path: Path, data: bytes, before_rename: Callable[[str], None] | None = None) -> None:
    """Write bytes to ``path`` atomically (temporary file + rename), creating its directory.

    ``before_rename(tmp)``: called with the temporary file's name once it holds the data, before the rename.

    An OS error of the write (through the file's descriptor: a full disk raises ENOSPC with no file name) or
    of the rename (which names the temporary file) is raised naming ``path``, the file being written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent)
    try:
        try:
            os.fchmod(fd, 0o666 & ~_umask())  # what open() would give, not mkstemp's 0600
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            if before_rename is not None:
                before_rename(tmp)
            os.replace(tmp, path)
        except OSError as exc:
            name_os_error(exc, path, tmp)
            raise
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def name_os_error(exc: OSError, path: Path, tmp: str | None = None) -> None:
    """Make ``exc`` name ``path`` when it names no file (a write through a descriptor: a full disk's ENOSPC) or
    only the temporary file ``tmp`` (in place: its type, errno and traceback stay).  An error naming another
    file (a guard's, say) keeps its name."""
    if exc.filename is None or (tmp is not None and exc.filename == tmp):
        exc.filename, exc.filename2 = str(path), None


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
