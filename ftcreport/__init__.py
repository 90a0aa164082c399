"""ftcreport: fault-tolerant control of linked 2WD robots, simulated and reported."""

from importlib.metadata import PackageNotFoundError, version

from . import _moved

try:
    __version__ = version("ftcreport")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__", "load_results"]


def _view(module: str, name: str):
    """A conversion of ftcreport.sim.Run that lives at the edges (imported on first use)."""

    def convert(run):
        from importlib import import_module

        return getattr(import_module(module, __name__), name)(run)

    return convert


def _install_views() -> None:
    """Run.to_xarray, to_pandas and _repr_html_: the core (sim) names no edge module; the package wires them."""
    from .runs import Run

    Run.views["xarray"] = _view(".storage.tidy", "run_dataset")
    Run.views["pandas"] = _view(".storage.tidy", "run_frame")
    Run.views["html"] = _view(".report.notebook", "run_html")


def __getattr__(name: str):
    """``ftcreport.load_results`` without importing pandas with the package."""
    if name == "load_results":
        from .storage.results import load_results

        return load_results
    raise AttributeError(f"module 'ftcreport' has no attribute {name!r}")


_install_views()
_moved.install(__name__)
