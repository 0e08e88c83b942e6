"""Static cores' config dataclasses: config/*.yaml equal the defaults; from_dict rejects bad input with a reason."""

from pathlib import Path

import pytest
import yaml

from insalign_ros.filters.coarse import CoarseConfig
from insalign_ros.filters.ekf10 import Ekf10Config
from insalign_ros.filters.pkf import PkfConfig

ROOT = Path(__file__).resolve().parents[1]
CASES = [("pkf", PkfConfig), ("ekf10", Ekf10Config), ("coarse", CoarseConfig)]


@pytest.mark.parametrize("name,cls", CASES)
def test_yaml_equals_dataclass_defaults(name, cls):
    p = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())["/**"]["ros__parameters"]
    assert p.pop("core") == name
    assert cls.from_dict(p) == cls()


@pytest.mark.parametrize("name,cls", CASES)
def test_from_dict_rejects_bad_input(name, cls):
    with pytest.raises(ValueError, match="unknown parameter"):
        cls.from_dict({"nope": 1.0})
    with pytest.raises(ValueError, match="gyro_arw_deg_sqrt_h"):
        cls.from_dict({"gyro_arw_deg_sqrt_h": -1.0})
    with pytest.raises(ValueError, match="expected a number"):
        cls.from_dict({"init_sigma_v_m_s": "x"})


def test_pkf_horizon_validated():
    assert PkfConfig.from_dict({"horizon_p": 5}).horizon_p == 5
    with pytest.raises(ValueError, match="horizon_p"):
        PkfConfig.from_dict({"horizon_p": 0})
    with pytest.raises(ValueError, match="horizon_p"):
        PkfConfig.from_dict({"horizon_p": 2.5})


def test_registered():
    from insalign_ros.filters.registry import CORE_NAMES, make_core

    for name, _ in CASES:
        assert name in CORE_NAMES
        assert make_core(name).name == name
    with pytest.raises(ValueError, match="horizon_p"):
        make_core("pkf", {"horizon_p": -1})


@pytest.mark.parametrize("name,cls", CASES)
def test_yaml_per_imu_grade_is_config_for_imu(name, cls):
    """config/<core>.yaml is the ADIS16488A (scenario 'static'), config/<core>_navgrade.yaml the navigation-grade IMU
    (scenario 'static_navgrade'): process noise and bias priors from the IMU spec (config_for_imu), not one number."""
    from insalign_ros.filters.static_model import config_for_imu
    from insalign_ros.sim.error_model import ADIS16488A, NAVGRADE

    for suffix, spec in (("", ADIS16488A), ("_navgrade", NAVGRADE)):
        p = yaml.safe_load((ROOT / "config" / f"{name}{suffix}.yaml").read_text())["/**"]["ros__parameters"]
        assert p.pop("core") == name
        assert cls.from_dict(p) == config_for_imu(cls, spec), suffix
    nav = config_for_imu(cls, NAVGRADE)
    assert nav.gyro_arw_deg_sqrt_h == pytest.approx(0.002) and nav.gyro_bias_deg_h == pytest.approx(0.01)
