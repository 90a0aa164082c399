"""Stored results for notebooks and scripts: metrics as a DataFrame, time series on demand.

``ftcreport.load_results("reports")`` returns a :class:`Results` table (a ``pandas.DataFrame``),
one row per stored run (case, scheme) with the run-level metrics of
:data:`ftcreport.storage.tidy.METRICS_DTYPES`; ``res.run(case, scheme)`` loads that run's time series as a
:class:`~ftcreport.sim.Run` (``.to_xarray()``, ``.to_pandas()``), ``res.case(name)`` gives a
:class:`CaseResults` that shows itself in a notebook (scheme table and one figure).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import pandas as pd

from ..errors import FtcError
from ..sim import Run
from . import VIEWS
from .store import load_metrics, stored_schemes
from .tidy import METRICS_DTYPES, metrics_table, read_run

__all__ = ["CaseResults", "Results", "load_results"]


class CaseResults:
    """The stored runs of one case under ``root``."""

    def __init__(self, root: Path, name: str) -> None:
        self.root = Path(root)
        self.name = name
        if not (self.root / name / "case.json").exists():
            raise FtcError(f"{self.root / name}: no stored case '{name}'")
        self.schemes = stored_schemes(self.root, name)

    def metrics_by_scheme(self) -> dict[str, dict]:
        """``{scheme: metrics.json content}``."""
        return {s: load_metrics(self.root, self.name, s) or {} for s in self.schemes}

    def run(self, scheme: str) -> Run | None:
        """The stored run of ``scheme`` (its time series), or None when it has none."""
        return read_run(self.root, self.name, scheme)

    def fault_schedule(self) -> list[dict]:
        for s in self.schemes:
            run = self.run(s)
            if run is not None:
                return list(run.meta.get("fault_schedule") or [])
        return []

    def _repr_html_(self) -> str:
        """Notebook view: scheme table and one figure (:func:`ftcreport.report.notebook.case_html`)."""
        return VIEWS["case_html"](self)

    def __repr__(self) -> str:
        return f"CaseResults({str(self.root)!r}, {self.name!r}: {', '.join(self.schemes) or 'no runs'})"


class Results(pd.DataFrame):
    """Metrics of every stored run (one row per case and scheme) with the time series on demand."""

    _metadata: ClassVar[list[str]] = ["root"]

    @property
    def _constructor(self) -> type[Results]:
        return Results

    def run(self, case: str, scheme: str) -> Run:
        """The stored run of (case, scheme) with its time series and metadata."""
        run = read_run(Path(self.root), case, scheme)
        if run is None:
            raise FtcError(f"{Path(self.root) / case / scheme}: no stored run")
        return run

    def case(self, name: str) -> CaseResults:
        """One case's stored results (shows a table and a figure in a notebook)."""
        return CaseResults(Path(self.root), name)


_RUN_COLUMNS = [c for c in METRICS_DTYPES if not c.startswith("phase")]


def load_results(reports_dir: str | Path = "reports") -> Results:
    """Every stored run under ``reports_dir`` as a :class:`Results` table (typed columns).

    Per-phase metrics are in ``metrics.parquet`` (:func:`ftcreport.storage.tidy.metrics_table`).
    """
    root = Path(reports_dir)
    if not root.is_dir():
        raise FtcError(f"{root}: no stored results (run 'ftcreport batch' first)")
    table = metrics_table(root)
    runs = table.drop_duplicates(["case", "scheme"])[_RUN_COLUMNS].reset_index(drop=True)
    res = Results(runs)
    res.root = str(root)
    return res
