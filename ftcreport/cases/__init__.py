r"""Case files: one documented TOML schema, validated with pydantic.

A case says which chain, reference, initial state, fault schedule, controllers
(schemes) with their gains, simulation settings, plant extras and thresholds.
``cases/README.md`` documents every field with its unit.  Every error names the
file, the field path and the reason, e.g.
``cases/x.toml: faults[2].wheel: '4r' is not a wheel of a 3-robot chain``.

The package reads files (``load_case``) and validates; building the simulation
objects from a validated case is pure (:func:`build`), so campaigns and tests
can build variants in memory.
"""

from __future__ import annotations

from ..schemes.fields import _FieldError, did_you_mean  # noqa: F401 - re-exported (the schema's suggestions)
from .build import (  # noqa: F401 - re-exported
    TEMPLATE,
    build_chain,
    build_plant_chain,
    dropped_faults,
    initial_state,
    with_duration,
)
from .case import (  # noqa: F401 - re-exported
    RK4_REAL_LIMIT,
    Case,
    _check_budget,
    _check_campaign_draws,
    _check_drive_rate,
    _check_initial_articulation,
    _check_motor_fault,
    _check_name,
    _check_requirements,
    _numbers,
    _rk4_on_currents,
    metric_problem,
)
from .files import (  # noqa: F401 - re-exported
    _ABSENT,
    OWN_FIELDS,
    _lookup,
    _merge,
    _name_base_field,
    _read_toml,
    _toml_key,
    _toml_string,
    _toml_value,
    case_hash,
    case_schema,
    load_case,
    overlay_text,
    plugin_digest,
    plugin_digests,
    resolve_overlay,
)
from .messages import (  # noqa: F401 - re-exported
    _BOUND_OPS,
    _EXPECTED,
    _TAGS,
    _choice_message,
    _describe,
    _dict_depth,
    _format_loc,
    _is_tag,
    _message,
    _missing_message,
    _rank,
    _submodel,
    _table_model,
    known_fields,
)
from .parse import (  # noqa: F401 - re-exported
    _PROSE,
    _control_errors,
    _field_errors,
    _load_plugins,
    _refuse,
    parse_case,
)
from .scheme_tables import (  # noqa: F401 - re-exported
    SCHEME_NAMES,
    Kinematic,
    PluginTable,
    Schemes,
    _plugin_table,
    _scheme_file,
    _schemes_model,
    _SchemesBase,
    _unknown_hint,
    _unknown_scheme,
    configured_schemes,
    known_schemes,
    option_schemes,
    ordered_schemes,
)
from .tables import (  # noqa: F401 - re-exported
    _ACT,
    _MAX_RADIUS,
    _MODEL,
    Actuators,
    DriveModel,
    Fault,
    Initial,
    Mismatch,
    Noise,
    Plant,
    Reference,
    Robots,
    Simulation,
    _each,
)
from .thresholds import (  # noqa: F401 - re-exported
    _SIGNAL_NAMES,
    BASELINE_ABS_TOL,
    BASELINE_METRIC_NAMES,
    BASELINE_REL_TOL,
    BASELINE_SIGNAL_FAMILIES,
    AfterFault,
    BaselineSpec,
    Bound,
    CampaignSpec,
    Claim,
    Requirement,
    Status,
    Tolerance,
    _Count,
)

__all__ = [
    "SCHEME_NAMES",
    "Case",
    "case_hash",
    "case_schema",
    "configured_schemes",
    "did_you_mean",
    "dropped_faults",
    "known_schemes",
    "load_case",
    "metric_problem",
    "option_schemes",
    "ordered_schemes",
    "parse_case",
]
