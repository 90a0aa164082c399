"""Input files (case files, base cases, scheme plug-ins): regular files of a bounded size, read without blocking.

A path given as a case file may name anything the file system holds: a FIFO (opening it for reading
waits for a writer, forever), a device (``/dev/zero`` reads without end), a directory, or a symbolic
link to one of these.  Every input file is therefore checked before it is opened: ``stat`` (through
symbolic links: a link to a regular file is fine) must say a regular file of at most
:data:`MAX_INPUT_BYTES`.  It is then opened with ``O_NONBLOCK`` (a FIFO swapped in after the check
cannot block the open), checked again on the open file (``fstat``) and read with a cap, so a file
that grows, or a ``/proc`` file whose size says 0, still cannot exceed the bound.

The bound, 1 MiB: the largest shipped case file is 5 KB and the largest shipped scheme file 7 KB; a
case listing every compensable failure pattern of a five-robot chain (766 patterns, about 60 bytes
each, 46 KB) fits twenty times over.  1 MiB of TOML parses in about 0.1 s; a file beyond it is not a
case file someone wrote by hand, and reading it is refused at once instead of filling the memory.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import CaseError

__all__ = ["MAX_INPUT_BYTES", "InputFileError", "input_problem", "read_input"]

#: the largest case file, base case or scheme file read (see the module's docstring for why)
MAX_INPUT_BYTES = 1 << 20


class InputFileError(CaseError):
    """An input path that is not a regular file of a bounded size (exit 2, the file named)."""


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "of another type"


def _not_regular(path: Path, mode: int, what: str) -> str:
    link = ""
    if os.path.islink(path):
        try:
            link = f", a symbolic link to {os.readlink(path)}"
        except OSError:
            link = ", a symbolic link"
    return f"{path}: not a regular file ({_kind(mode)}{link}); a {what} must be a regular file"


def _too_large(path: Path, size: int | None, what: str, limit: int) -> str:
    got = f"more than {limit} bytes" if size is None else f"{size} bytes"
    return f"{path}: too large ({got}; a {what} may have {limit / 2**20:g} MiB, the shipped ones under 10 KB)"


def input_problem(path: str | Path, what: str = "case file", limit: int = MAX_INPUT_BYTES) -> str | None:
    """Why ``path`` cannot be read as a ``what`` (``path: reason``), or None when it is a regular file within ``limit``.

    Only ``stat`` (following symbolic links): nothing is opened.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as exc:
        return f"{path}: cannot read ({exc.strerror or type(exc).__name__})"
    if not stat.S_ISREG(st.st_mode):
        return _not_regular(path, st.st_mode, what)
    if st.st_size > limit:
        return _too_large(path, st.st_size, what, limit)
    return None


def read_input(path: str | Path, what: str = "case file", limit: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes; :class:`InputFileError` naming it otherwise.

    Never blocks on a FIFO and never reads more than ``limit`` + 1 bytes (see the module's docstring).
    """
    path = Path(path)
    why = input_problem(path, what, limit)
    if why is not None:
        raise InputFileError(why)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or type(exc).__name__})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced between the check and the open
            raise InputFileError(_not_regular(path, st.st_mode, what))
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 16, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror or type(exc).__name__})") from None
    finally:
        os.close(fd)
    if size > limit:
        raise InputFileError(_too_large(path, None, what, limit))
    return b"".join(chunks)
