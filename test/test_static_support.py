"""core auto while parked (issue 24, item 4): the heading 3-sigma the flag sees knows its gyrocompassing floor and
what the zero-velocity updates say about the model."""

import math

import numpy as np

from insalign_ros.session.auto import AutoConfig, AutoCore
from insalign_ros.session.rest import static_heading_support

D2R = math.pi / 180.0


def _core(lat_deg=49.0, gyro_bias_deg_h=0.01):
    """A navigation-grade gyro (0.01 deg/h: a 0.06-deg floor at 49 deg; industrial MEMS: 58 deg, heading needs
    motion)."""
    core = AutoCore(AutoConfig(gyro_bias_deg_h=gyro_bias_deg_h))
    core.initialize(0.0, lat_deg * D2R, 8.4 * D2R, 100.0, np.eye(3), np.zeros(3), np.diag([1e-4, 1e-4, 1.0]),
                    0.1, 1.0)
    return core


def _support(core, P):
    """The heading support the auto core applies to its parked estimates (session/rest.py), with its statistics."""
    return static_heading_support(P, core._zupt_support, core._zupt_nis, core.cfg.azimuth_floor_rad(core.lat))


def test_heading_variance_follows_the_zero_velocity_support():
    """The real case: 992 of 2,991 zero-velocity updates accepted and a yaw 3-sigma of 2.24 deg at a 3.7-deg error:
    scaled by 2991/992 the 3-sigma is 3.89 deg, it covers the error (and is over the 2.5-deg flag bound)."""
    core = _core()
    sig = 2.24 / 3.0 * D2R
    P = np.diag([1e-6, 1e-6, sig * sig])
    core._zupt_support = [2991, 992]
    P2, why = _support(core, P.copy())
    s3 = 3.0 * math.sqrt(P2[2, 2]) / D2R
    assert abs(s3 - 2.24 * math.sqrt(2991 / 992)) < 1e-9 and s3 > 3.7, s3
    assert "accepted 992 of 2991" in why
    assert np.all(np.linalg.eigvalsh(P2) > 0)
    core._zupt_support = [2991, 2991]  # all accepted, NIS normal: unchanged
    P3, why = _support(core, P.copy())
    assert P3[2, 2] == P[2, 2] and why == ""


def test_heading_variance_is_never_below_the_gyrocompassing_floor():
    """eps_east / (omega_ie cos lat) at 49 deg: 0.058 deg for 0.01 deg/h."""
    core = _core()
    floor = core.cfg.azimuth_floor_rad(49.0 * D2R)
    expected = core.cfg.gyro_bias_deg_h / (15.0411 * math.cos(49.0 * D2R))  # [rad] = deg/h over deg/h
    assert abs(floor - expected) < 1e-3 * expected and abs(floor / D2R - 0.0582) < 1e-3
    P, _ = _support(core, np.diag([1e-6, 1e-6, 1e-10]))
    assert abs(math.sqrt(P[2, 2]) - floor) < 1e-12
