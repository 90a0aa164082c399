"""Where ftcreport keeps what it writes for itself: the user's cache directory, never the installed package.

``FTCREPORT_CACHE`` (a directory) overrides the platform's convention (platformdirs'
``user_cache_dir("ftcreport")``: ``~/.cache/ftcreport`` on Linux, ``~/Library/Caches/ftcreport`` on
macOS, ``%LOCALAPPDATA%\\ftcreport\\Cache`` on Windows).  The kinds that hold compiled code (the
generated loop modules and numba's cache of ftcreport's kernels, :data:`COMPILED`) live under one
folder named by ftcreport's version, numba's and llvmlite's versions and the CPU (its name and a hash
of its features): another version or another machine sharing a home directory gets its own folder
instead of overwriting this one's (numba's own index keys each entry on the CPU too; the loop modules
have no such key of their own).  Other kinds (a run cache, for instance) are shared across versions.

Nothing here creates a directory: whoever writes creates it (``mkdir(parents=True, exist_ok=True)``).
"""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

__all__ = ["COMPILED", "cache_dir", "cache_root", "compiled_key"]

#: the kinds of cache that hold compiled code, keyed by versions and CPU (see :func:`compiled_key`)
COMPILED = frozenset({"loops", "numba"})

_KIND = re.compile(r"[a-z][a-z0-9_-]*")


def cache_root() -> Path:
    """``$FTCREPORT_CACHE``, else the platform's user cache directory for ftcreport."""
    env = os.environ.get("FTCREPORT_CACHE")
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("ftcreport", appauthor=False))


def compiled_key() -> str:
    """``ftcreport-<v>_numba-<v>_llvmlite-<v>_<cpu>-<hash of its features>``: what compiled code depends on.

    The CPU is numba's: ``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES`` when set (a portable cache), else the
    host's as LLVM reports it (what numba compiles for by default)."""
    key = getattr(compiled_key, "_value", None)
    if key is None:
        from importlib.metadata import PackageNotFoundError, version

        import llvmlite
        import llvmlite.binding as ll
        import numba

        try:  # the distribution's version, read as the package's __init__ does (importing the package
            __version__ = version("ftcreport")  # itself would tie this core-facing module to its edges)
        except PackageNotFoundError:  # pragma: no cover - running from a source tree
            __version__ = "0.0.0+unknown"
        cpu = numba.config.CPU_NAME or ll.get_host_cpu_name()
        features = numba.config.CPU_FEATURES or ll.get_host_cpu_features().flatten()
        digest = hashlib.sha256(f"{cpu}\0{features}".encode()).hexdigest()[:10]
        key = f"ftcreport-{__version__}_numba-{numba.__version__}_llvmlite-{llvmlite.__version__}_{cpu}-{digest}"
        key = "".join(c if c.isalnum() or c in "._-" else "_" for c in key)
        compiled_key._value = key
    return key


def cache_dir(kind: str) -> Path:
    """The directory of one kind of cache (not created here).

    ``kind``: a lowercase name (``"loops"``, ``"numba"``, ...); the kinds of :data:`COMPILED` are keyed
    by :func:`compiled_key`, the others are ``cache_root() / kind``.
    """
    if not _KIND.fullmatch(kind):
        raise ValueError(f"cache kind {kind!r}: expected a lowercase name (letters, digits, '-', '_')")
    root = cache_root()
    if kind in COMPILED:
        return root / compiled_key() / kind
    return root / kind
