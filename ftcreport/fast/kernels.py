r"""The compiled kernels of every domain under one name, for Python callers that want them all.

Each compiled function lives beside its readable face, by domain (issue 38 item 6):

* :mod:`ftcreport.jit.packed`: the packed parameter tuples, the error codes, small helpers;
* :mod:`ftcreport.model.compiled`: the chain model (S, M, C, B, the reduced model, the plant);
* :mod:`ftcreport.model.chained_compiled`: the chained-form coordinates (Theorem 2.1);
* :mod:`ftcreport.references.compiled`: the references' jets and points;
* :mod:`ftcreport.control.kinematic_compiled`, ``tracking_compiled``, ``switching_compiled``,
  ``active_compiled``: the laws;
* :mod:`ftcreport.observers.farza_compiled`: the Farza observer;
* :mod:`ftcreport.fast.checks`: the loop's state checks.

This module only gathers their names (``from ftcreport.fast import kernels as F``; ``F.reduced``) for the
linearized analysis, the tests and a notebook.  The package's own modules import each kernel from its
domain (the faces their twin, the engine what the loop binds), so that no room below the engine depends on
this list.
Each function cites its thesis equation and erratum (docs/ERRATA.md).  Nothing here does I/O.
"""

from __future__ import annotations

from ..control.active_compiled import (  # noqa: F401 - re-exported
    active_signals,
    estimate_filters,
    midpoint_sigmas,
)
from ..control.kinematic_compiled import (  # noqa: F401 - re-exported
    _chained_law,
    _reanchor_time,
    _two_link_law,
    eta_c_and_dot,
    kin_discrete,
    kin_law,
)
from ..control.switching_compiled import (  # noqa: F401 - re-exported
    _best_cost,
    _good_cost,
    _model_cost,
    _walk,
    _walk_core,
    rotor_filter_terms,
    switching_costs,
    switching_costs_rows,
    switching_rates,
    switching_select,
)
from ..control.tracking_compiled import (  # noqa: F401 - re-exported
    _gram,
    _kin_signals,
    _right_inverse,
    law_for_pattern,
    law_terms,
    matched_terms,
)
from ..jit.compiling import jit  # noqa: F401 - re-exported
from ..jit.packed import (  # noqa: F401 - re-exported
    AT_DISCRETE,
    AT_STATE,
    AT_TRIAL,
    E_CHAINED_ART,
    E_CHAINED_THN,
    E_KAPPA,
    E_LAW_WRITE,
    E_MIN_STEP,
    E_NONFINITE_DERIV,
    E_NONFINITE_STATE,
    E_POSITION,
    E_REF_ART,
    E_REF_SPEED,
    E_SPEED,
    E_STATE_SINGULAR,
    E_STEP_GROWTH,
    E_STEP_JUMP,
    E_TWO_LINK_ETH,
    E_TWO_LINK_PHI,
    E_UKF,
    KIN_CHAINED,
    KIN_TWO_LINK,
    LAW_ACTIVE,
    LAW_ADAPTIVE,
    LAW_ORACLE,
    LAW_SWITCHING,
    LAW_TRACKING,
    TIE_RTOL,
    Cache,
    Chain,
    Kin,
    Law,
    Obs,
    Ref,
    _clip,
    _inv2,
    _mv,
    _solve2,
    _tri,
    _wrap,
    law_params,
    new_cache,
)
from ..model.chained_compiled import (  # noqa: F401 - re-exported
    chained_xi_T,
    to_frame,
    xi_T,
)
from ..model.compiled import (  # noqa: F401 - re-exported
    _coriolis,
    _mass,
    bbar_rate,
    input_matrices_rows,
    input_matrix,
    input_matrix_and_rate,
    mass_and_coriolis,
    plant_rhs,
    plant_rhs_rows,
    reduced,
    rotor_mass,
    s_column,
    s_matrix,
    wheel_speeds_rows,
)
from ..observers.farza_compiled import (  # noqa: F401 - re-exported
    farza_derivative,
    farza_estimates,
)
from ..references.compiled import (  # noqa: F401 - re-exported
    _conv,
    _shift3,
    path_jets,
    ref_jets,
    ref_point,
    ref_side,
)
from .checks import (  # noqa: F401 - re-exported
    _check_state,
    _finite,
    _min_art_cos,
    _step_jump,
)
