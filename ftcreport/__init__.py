"""ftcreport: fault-tolerant control of linked 2WD robots, simulated and reported."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ftcreport")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__", "load_results"]


def __getattr__(name: str):
    """``ftcreport.load_results`` without importing pandas with the package."""
    if name == "load_results":
        from .results import load_results

        return load_results
    raise AttributeError(f"module 'ftcreport' has no attribute {name!r}")
