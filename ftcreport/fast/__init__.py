"""The compiled engine (numba).  Importing it makes numba's cache loads keep the linking IR unparsed
until a compile needs it (:mod:`ftcreport.fast.lazy_link`: about 32 MB less for a run's loop)."""

from .lazy_link import install

install()
