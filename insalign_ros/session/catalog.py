"""What the layers above the session (the node, the command-line tools) may know about the cores and IMU grades:
their names, their parameters and defaults, and whether a configuration can run. The node imports nothing from
filters/ (.importlinter); this module is its one door.
"""

from __future__ import annotations

from ..filters import registry
from ..filters.imu_grade import DEFAULT_IMU_GRADE, DEPRECATED_ALIASES, GRADES, deprecation_message, grade_params
from . import auto as _auto  # noqa: F401  the composed core 'auto' registers itself with filters.registry

__all__ = ["DEFAULT_IMU_GRADE", "DEPRECATED_ALIASES", "GRADES", "deprecation_message", "backtracking_core", "check_core_config", "core_names", "core_defaults",
           "grade_defaults"]


def core_names() -> tuple[str, ...]:
    return registry.core_names()


def _config_class(core: str):
    if core not in core_names():
        raise ValueError(f"core: unknown core {core!r}; choose one of {sorted(core_names())}")
    return registry.CORES[core][1]


def core_defaults(core: str) -> dict:
    """Every parameter of ``core`` with its default (ValueError: unknown core)."""
    return _config_class(core)().to_dict()


def grade_defaults(grade, core: str) -> dict:
    """The parameters of ``core`` an IMU grade (a name, or an ImuGrade) sets (ValueError: unknown grade)."""
    return grade_params(grade, _config_class(core))


#: cores that run backtracking passes, under the name of the backtrackable core the session builds for them
BACKTRACKING_CORES = {"earth_iekf": "earth_iekf", "liekf": "liekf_backtrack", "liekf_backtrack": "liekf_backtrack"}


def backtracking_core(core: str, core_params: dict) -> str:
    """The core the session builds for ``core`` when backtracking passes are asked for (ValueError: none can)."""
    if core not in BACKTRACKING_CORES or int(core_params.get("yaw_hypotheses", 1)) > 1:
        raise ValueError(f"backtrack_passes > 0 needs one filter of a core with backward propagation "
                         f"({', '.join(BACKTRACKING_CORES)}; yaw_hypotheses 1); got core {core!r}, "
                         f"yaw_hypotheses {core_params.get('yaw_hypotheses', 1)}")
    return BACKTRACKING_CORES[core]


def check_core_config(config, core_params: dict) -> None:
    """ValueError (with the reason) when the session configuration ``config`` and the core parameters cannot run:
    a bad core parameter, or backtracking asked of a core without backward propagation. The node and the offline
    tools refuse the same configurations through this one check."""
    registry.make_config(config.core, core_params)
    if config.backtrack_passes > 0:
        backtracking_core(config.core, core_params)
