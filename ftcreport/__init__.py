"""ftcreport: fault-tolerant control of linked 2WD robots, simulated and reported."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ftcreport")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
