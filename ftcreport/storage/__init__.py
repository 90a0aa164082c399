"""Results at rest: the store's atomic files, tidy views (xarray, pandas, netCDF, Parquet), the
provenance manifest, and stored results read back for notebooks."""

from collections.abc import Callable

#: views of stored results that live at the edges: ``case_html`` (:func:`ftcreport.report.notebook.case_html`,
#: what a notebook shows for :class:`~ftcreport.storage.results.CaseResults`); the package root
#: (ftcreport/__init__.py) fills it, so that storage imports no report module
VIEWS: dict[str, Callable] = {}
