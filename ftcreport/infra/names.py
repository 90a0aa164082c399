"""The one rule for the names a user gives (cases, schemes): a leaf module, so that every reader
(``ftcreport.infra.limits``, the scheme registry) imports it without importing the others."""

from __future__ import annotations

import re

__all__ = ["NAME_PATTERN"]

#: a letter or digit, then letters, digits, '_', '.', '-' (at most 64): a folder name on every platform
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
