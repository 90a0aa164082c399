"""The compiled engine (numba).  Its kernels are made by :func:`ftcreport.jit.compiling.jit`: numba's
dispatcher, compiler and code library through ftcreport's own subclasses, cached in the user's cache
directory (:mod:`ftcreport.infra.paths`); importing it changes nothing of numba."""
