"""A digest of the package's own sources: part of the result cache key (studies.batch.run_key).

The key already holds the case's content, the package version, the engine and the libraries that can
change numbers; without the package's code a fix (or a new bug) in a metric or a law would be served
from the cache, and ``check`` would gate the old numbers (the round-3 gate attack).  Every ``.py`` file
under the package, by relative path and content, read once per process (about 250 files, a few ms).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

#: the digest of this process's package (computed on first use; a test may set it)
DIGEST: str | None = None

ROOT = Path(__file__).resolve().parents[1]


def sources() -> list[Path]:
    """Every Python source of the package, sorted (the compiled-loop caches live elsewhere)."""
    return sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)


def code_digest() -> str:
    """sha256 over the package's sources (relative path, then content, of each), 16 hex digits."""
    global DIGEST
    if DIGEST is None:
        h = hashlib.sha256()
        for p in sources():
            h.update(p.relative_to(ROOT).as_posix().encode() + b"\0")
            h.update(p.read_bytes() + b"\0")
        DIGEST = h.hexdigest()[:16]
    return DIGEST
