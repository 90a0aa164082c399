"""ftcreport: fault-tolerant control of linked 2WD robots, simulated and reported."""

from importlib.metadata import PackageNotFoundError, version

from . import _moved

try:
    __version__ = version("ftcreport")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__", "load_results"]


def _view(module: str, name: str):
    """A function that lives at the edges (imported on first use)."""

    def convert(*args, **kwargs):
        from importlib import import_module

        return getattr(import_module(module, __name__), name)(*args, **kwargs)

    return convert


def _install_views() -> None:
    """Run.to_xarray, to_pandas and _repr_html_, a case's stored results in a notebook, the pages a batch
    renders: the rooms below (sim, storage, studies) name no edge module above them; the package wires them."""
    from . import storage, studies
    from .runs import Run

    Run.views["xarray"] = _view(".storage.tidy", "run_dataset")
    Run.views["pandas"] = _view(".storage.tidy", "run_frame")
    Run.views["html"] = _view(".report.notebook", "run_html")
    storage.VIEWS["case_html"] = _view(".report.notebook", "case_html")
    studies.PAGES["render_all"] = _view(".report.render", "render_all")


def __getattr__(name: str):
    """``ftcreport.load_results`` without importing pandas with the package."""
    if name == "load_results":
        from .storage.results import load_results

        return load_results
    raise AttributeError(f"module 'ftcreport' has no attribute {name!r}")


_install_views()
_moved.install(__name__)
