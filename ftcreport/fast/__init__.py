"""The compiled engine (numba).  Importing it makes numba's cache loads keep the linking IR unparsed
until a compile needs it (:mod:`ftcreport.fast.lazy_link`: about 32 MB less for a run's loop), and
keys the cache of every ftcreport kernel on the hash of all compiled sources
(:func:`ftcreport.fast.compiling.install_cache_stamp`: no stale kernel linked after an update)."""

from .compiling import install_cache_stamp
from .lazy_link import install

install()
install_cache_stamp()
