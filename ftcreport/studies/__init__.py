"""The commands that run many cases and schemes and keep what they find: batch, campaigns on Dask,
coverage maps, FDI evaluation, baselines across commits, and the one gate ``check`` reads."""

from collections.abc import Callable

#: the pages a batch renders once its runs are stored: ``render_all`` (:func:`ftcreport.report.render.render_all`);
#: the package root (ftcreport/__init__.py) fills it, so that studies imports no report module
PAGES: dict[str, Callable] = {}
