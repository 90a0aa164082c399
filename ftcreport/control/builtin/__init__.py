"""The built-in schemes, one file each, registered through the same API as a plug-in (issue 38 item 4).

The registry (:mod:`ftcreport.schemes.registry`) imports every module of this package on its first
use; each registers its schemes with ``register_built_in``.  Adding a built-in scheme is one file
here (its parameters, state, signals and law) and its tests.
"""
