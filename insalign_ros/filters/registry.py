"""Core registry: ``make_core(name, params) -> AlignmentCore``, ``declared(name, params)`` and ``CORE_NAMES``.

Registration is a plain dict: ``CORES[name] = (load, config_class)`` where ``load()`` returns the core's class
(imported on first use), ``core_class(config)`` builds a core and ``config_class.from_dict(params)`` validates the
parameters (ValueError with the reason). Other cores (static PKF/EKF10, coarse, ``auto``) add themselves with
:func:`register`. What a core accepts and its initial 1-sigmas are read from its class and configuration
(:func:`declared`): nothing builds a core to find out.
"""

from __future__ import annotations

from typing import Callable

from .base import AlignmentCore
from .config import EkfConfig, IekfConfig, LiekfConfig, PiLiekfConfig
from .imu_grade import apply_aliases, grade_params


def _liekf():
    from .liekf import Liekf

    return Liekf


def _pi_liekf():
    from .pi_liekf import PiLiekf

    return PiLiekf


def _iekf():
    from .iekf import ImperfectIekf

    return ImperfectIekf


def _ekf():
    from .ekf import ConventionalEkf

    return ConventionalEkf


def _earth_iekf():
    from .earth_iekf import EarthIekf

    return EarthIekf


def _liekf_backtrack():
    from .backtrack import BacktrackLiekf

    return BacktrackLiekf


#: name -> (load() -> the AlignmentCore class, config dataclass with from_dict)
CORES: dict[str, tuple[Callable, type]] = {
    "liekf": (_liekf, LiekfConfig),
    "pi_liekf": (_pi_liekf, PiLiekfConfig),
    "iekf": (_iekf, IekfConfig),
    "ekf": (_ekf, EkfConfig),
}
# forward-backward alignment (issue 8): the Earth-frame IEKF and the LIEKF with backward propagation
from .earth_iekf import EarthIekfConfig  # noqa: E402

CORES["earth_iekf"] = (_earth_iekf, EarthIekfConfig)
CORES["liekf_backtrack"] = (_liekf_backtrack, LiekfConfig)

#: the in-motion (GNSS-aided) cores of issue 5
INMOTION_CORE_NAMES: tuple[str, ...] = ("liekf", "pi_liekf", "iekf", "ekf")


def register(name: str, core: type[AlignmentCore], config_class: type) -> None:
    """Add a core: ``core(config_class.from_dict(params))`` builds it."""
    CORES[name] = (lambda: core, config_class)


def core_names() -> tuple[str, ...]:
    return tuple(CORES)


def make_config(name: str, params: dict | None = None):
    if name not in CORES:
        raise ValueError(f"unknown core {name!r}; choose one of {sorted(CORES)}")
    return CORES[name][1].from_dict(params)


def core_class(name: str) -> type[AlignmentCore]:
    if name not in CORES:
        raise ValueError(f"unknown core {name!r}; choose one of {sorted(CORES)}")
    return CORES[name][0]()


def make_core(name: str, params: dict | None = None) -> AlignmentCore:
    """Build a core by name with validated parameters (ValueError on an unknown name or a bad parameter)."""
    cfg = make_config(name, params)
    cls = core_class(name)
    if getattr(cfg, "yaw_hypotheses", 1) > 1:  # unknown heading: a bank of yaw hypotheses (filters/hypotheses.py)
        from .hypotheses import YawHypothesisBank

        return YawHypothesisBank(cls, cfg)
    return cls(cfg)


def declared(name: str, params: dict | None = None) -> tuple[frozenset, tuple]:
    """What the core ``name`` with ``params`` declares before it is built: (the measurement model types it accepts
    from its initialisation on, its initial 1-sigmas ((roll, pitch, yaw) [deg], velocity [m/s], position [m])). A
    bank of yaw hypotheses declares what each of its members does."""
    cfg = make_config(name, params)
    return core_class(name).declared_accepts(), cfg.initial_sigmas


def __getattr__(attr):  # CORE_NAMES stays current when others register()
    if attr == "CORE_NAMES":
        return core_names()
    raise AttributeError(attr)


# ------------------------------------------------------------------ static cores (issue 6)
def _register_static() -> None:
    from .coarse import CoarseAlignment, CoarseConfig
    from .ekf10 import Ekf10, Ekf10Config
    from .pkf import Pkf, PkfConfig

    register("pkf", Pkf, PkfConfig)
    register("ekf10", Ekf10, Ekf10Config)
    register("coarse", CoarseAlignment, CoarseConfig)


_register_static()


def resolve_core_params(grade, core: str, core_params: dict | None = None) -> dict:
    """Core parameters of ``core`` (filters/registry.py) for an IMU grade: the grade's fields, overridden by the
    explicit ``core_params`` (a per-core parameter always wins over the preset)."""
    if core not in CORES:
        raise ValueError(f"core: unknown core {core!r}; choose one of {sorted(core_names())}")
    return {**grade_params(grade, CORES[core][1]), **apply_aliases(dict(core_params or {}))}
