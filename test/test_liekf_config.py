"""Config dataclasses and registry: validation with clear reasons, YAML files agree with the defaults."""

from pathlib import Path

import pytest
import yaml

from insalign_ros.filters import registry
from insalign_ros.filters.base import AlignmentCore
from insalign_ros.filters.config import IekfConfig, PiLiekfConfig
from insalign_ros.filters.imu_grade import GRADE_FIELDS

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", registry.INMOTION_CORE_NAMES)
def test_yaml_matches_dataclass_defaults_and_builds_the_core(name):
    doc = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())
    params = dict(doc["/**"]["ros__parameters"])
    assert params.pop("core") == name
    # the IMU noise and bias fields come from imu_grade (filters/imu_grade.py), not from the core's file
    defaults = {k: v for k, v in registry.CORES[name][1]().to_dict().items() if k not in GRADE_FIELDS}
    assert params == defaults
    core = registry.make_core(name, params)
    assert isinstance(core, AlignmentCore) and core.name == name


def test_registry_names_and_errors():
    assert set(registry.INMOTION_CORE_NAMES) <= set(registry.CORE_NAMES)
    with pytest.raises(ValueError, match="unknown core"):
        registry.make_core("nope")
    with pytest.raises(ValueError, match="unknown parameter"):
        registry.make_core("liekf", {"gyro_arw": 1.0})
    registry.register("liekf_copy", registry.core_class("liekf"), registry.CORES["liekf"][1])
    try:
        assert "liekf_copy" in registry.CORE_NAMES
        assert registry.make_core("liekf_copy").name == "liekf"
    finally:
        del registry.CORES["liekf_copy"]


@pytest.mark.parametrize("name, params", [(n, {}) for n in registry.core_names()] + [
    ("iekf", {"yaw_hypotheses": 4}), ("liekf", {"init_sigma_yaw_deg": 7.5}), ("pkf", {"init_sigma_v_m_s": 0.2}),
    ("auto", {"static_core": "ekf10"})])
def test_registry_declares_what_a_built_core_has(name, params):
    """What the session reads before it builds a core (registry.declared: the models accepted from the
    initialisation on, the initial 1-sigmas) is what the core it builds has, a bank of yaw hypotheses included."""
    import insalign_ros.session  # noqa: F401  (registers core 'auto')

    accepts, sigmas = registry.declared(name, params)
    core = registry.make_core(name, params)
    try:
        assert accepts == core.accepts and sigmas == core.initial_sigmas, name
        assert isinstance(accepts, frozenset) and len(sigmas) == 3 and len(sigmas[0]) == 3
    finally:
        core.close()


def test_a_session_builds_one_core_per_initialisation():
    """No throw-away core: an alignment that initialises once builds exactly one core (the session reads what a
    core accepts and its initial sigmas from the registry, not from a probe)."""
    import insalign_ros as ia

    built = []

    class Counted(registry.core_class("iekf")):
        def __init__(self, cfg):
            super().__init__(cfg)
            built.append(self)

    registry.register("iekf_counted", Counted, registry.CORES["iekf"][1])
    try:
        res = ia.align("car", core="iekf_counted", duration_s=20.0, seed=3, init_mode="guess")
    finally:
        del registry.CORES["iekf_counted"]
    assert len(res.t_s) > 100 and res.status[-1] != "WAITING_FOR_DATA"
    assert len(built) == 1, len(built)


@pytest.mark.parametrize("params, match", [
    ({"gyro_arw_deg_sqrt_h": -1.0}, "gyro_arw_deg_sqrt_h: must be >= 0"),
    ({"init_sigma_yaw_deg": 0}, "init_sigma_yaw_deg: must be > 0"),
    ({"init_sigma_yaw_deg": "60"}, "init_sigma_yaw_deg: expected a number"),
    ({"max_batch_samples": 0}, "max_batch_samples"),
    ({"init_sigma_p_m": float("nan")}, "init_sigma_p_m"),
])
def test_from_dict_rejects_bad_values_with_the_reason(params, match):
    with pytest.raises(ValueError, match=match):
        IekfConfig.from_dict(params)


def test_pi_config_validation():
    assert PiLiekfConfig.from_dict({"rho": 0}).rho == 0.0  # ints accepted for floats
    for bad, match in (({"rho": 0.5}, "rho"), ({"lmi_solver": "MOSEK"}, "lmi_solver"),
                       ({"lmi_structure": "x"}, "lmi_structure"), ({"lmi_resolve_every_updates": 0}, "resolve")):
        with pytest.raises(ValueError, match=match):
            PiLiekfConfig.from_dict(bad)
