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
    p = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())["alignment_node"]["ros__parameters"]
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
