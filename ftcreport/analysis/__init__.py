r"""Linearized analyses of a case with python-control (pure: no I/O).

``from ftcreport.analysis import ...`` gives every public function of the modules below.

* :mod:`.classic`: the two-link error dynamics at zero error, frozen-time and Floquet poles of the
  chained-form loop, controllability per fault pattern, observability and the Farza observer's poles;
* :mod:`.closed_loop`: one scheme's closed loop (plant, motors, drive, kinematic and dynamic laws, the
  scheme's own states) linearized through the scheme interface at an operating point on the reference;
* :mod:`.sampled`: the same loop in discrete time as a sampled controller runs it (ZOH, delay, held command);
"""

from .case import analyze_case
from .classic import (
    _TwoLinkError,
    central_jacobian,
    chained_circle_analysis,
    chained_frozen_time_poles,
    classic_analyses,
    closed_loop_jacobian,
    default_max_failed,
    farza_error_poles,
    farza_linearized_poles,
    fault_patterns,
    frozen_time_poles,
    healthy_torque,
    kinematic_error_matrix,
    measured_q_model,
    observability,
    observer_analysis,
    pattern_controllability,
    pole_table,
    scheme_gain,
    two_link_error_jacobian,
    two_link_error_system,
    velocity_loop,
)
from .closed_loop import Blocks, Faults, Plant, Point, SchemeLoop, central_columns, operating_state, relevant_states
from .sampled import closed_loop_matrix, open_loop_at_input, spectral_radius, zoh

__all__ = [
    "Blocks",
    "Faults",
    "Plant",
    "Point",
    "SchemeLoop",
    "_TwoLinkError",
    "analyze_case",
    "central_columns",
    "central_jacobian",
    "chained_circle_analysis",
    "chained_frozen_time_poles",
    "classic_analyses",
    "closed_loop_jacobian",
    "closed_loop_matrix",
    "default_max_failed",
    "farza_error_poles",
    "farza_linearized_poles",
    "fault_patterns",
    "frozen_time_poles",
    "healthy_torque",
    "kinematic_error_matrix",
    "measured_q_model",
    "observability",
    "observer_analysis",
    "open_loop_at_input",
    "operating_state",
    "pattern_controllability",
    "pole_table",
    "relevant_states",
    "scheme_gain",
    "spectral_radius",
    "two_link_error_jacobian",
    "two_link_error_system",
    "velocity_loop",
    "zoh",
]
