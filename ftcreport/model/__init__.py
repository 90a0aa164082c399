"""Physics of n linked 2WD robots: model, faults (pure, no I/O)."""

from .chain import THESIS_ROBOT, Chain
from .faults import (
    FaultEvent,
    FaultSchedule,
    compensable_patterns,
    is_compensable_at,
    pattern_is_compensable,
    wheel_index,
    wheel_names,
)

__all__ = [
    "THESIS_ROBOT",
    "Chain",
    "FaultEvent",
    "FaultSchedule",
    "compensable_patterns",
    "is_compensable_at",
    "pattern_is_compensable",
    "wheel_index",
    "wheel_names",
]
