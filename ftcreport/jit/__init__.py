"""The compile machinery every domain's kernels are built with, below every domain.

:mod:`~ftcreport.jit.compiling` (``jit``: numba's ``njit`` with ftcreport's cache and the scoped
compile-time acceleration, docs/ENGINE.md), :mod:`~ftcreport.jit.lazy_link`,
:mod:`~ftcreport.jit.packed` (the packed parameter tuples the loop passes, the error codes, small
numeric helpers) and :mod:`~ftcreport.jit.refs` (kernel references).  Nothing here knows a model, a
law or a scheme: ``model``, ``references``, ``observers`` and ``control`` import from here, and the
engine (``ftcreport.fast``) imports them.
"""
