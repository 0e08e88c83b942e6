"""The accelerometer noise along the vehicle's vertical (``acc_vrw_up_m_s_sqrt_h``; filters/base.accel_noise_b): a
vehicle's vibration in motion is mostly along its own vertical, so the in-motion cores take a larger velocity random
walk on the body axis that points Up (the default grade unknown_mems: 1.0 m/s/sqrt(h) there, 0.2 on the others;
docs/imu_grades.md "Vibration in motion").

Closed form: in a prediction of T seconds the velocity-error variance along Up grows by (q_up - q) T more than with
the isotropic noise, and along East and North by the same as without it, for the left-invariant core (the noise in
the body frame) and for the conventional EKF (the noise rotated into its inertial frame) alike."""

import math

import numpy as np
import pytest

from insalign_ros.core import earth
from insalign_ros.core.units import m_s_sqrt_h_to_m_s_sqrt_s
from insalign_ros.filters import registry
from insalign_ros.filters.base import accel_noise_b
from insalign_ros.filters.imu_grade import GRADES


def test_the_vertical_body_axis_gets_the_vertical_noise():
    q, q_up = 1.0, 9.0
    level = earth.C_b_n_from_rpy(math.radians(3.0), math.radians(-4.0), math.radians(70.0))
    assert list(accel_noise_b(level, q, q_up)) == [q, q, q_up]
    on_its_side = earth.C_b_n_from_rpy(math.radians(88.0), 0.0, 0.0)  # body y points Up (a robot's side mount)
    assert list(accel_noise_b(on_its_side, q, q_up)) == [q, q_up, q]
    odd = earth.C_b_n_from_rpy(math.radians(45.0), math.radians(30.0), 0.0)  # no axis within 25 deg of Up
    assert list(accel_noise_b(odd, q, q_up)) == [q_up] * 3
    assert list(accel_noise_b(level, q, 0.0)) == [q] * 3  # 0: the isotropic noise
    assert GRADES["unknown_mems"].acc_vrw_up_m_s_sqrt_h == 1.0 and GRADES["tactical"].acc_vrw_up_m_s_sqrt_h == 0.0


def _velocity_cov_enu(core_name: str, vrw_up: float, T_s: float = 10.0) -> np.ndarray:
    """The ENU velocity-error covariance [m^2/s^2] of ``core_name`` after T_s of a level IMU at rest, from a zero
    velocity covariance (the attitude's kept small, so gravity's tilt coupling stays below the noise terms)."""
    core = registry.make_core(core_name, {"acc_vrw_m_s_sqrt_h": 0.2, "acc_vrw_up_m_s_sqrt_h": vrw_up,
                                          "gyro_arw_deg_sqrt_h": 1e-6})
    lat, lon = math.radians(45.0), math.radians(7.0)
    C_b_n = earth.C_b_n_from_rpy(0.0, 0.0, math.radians(30.0))
    core.initialize(0.0, lat, lon, 100.0, C_b_n, np.zeros(3), np.eye(3) * 1e-12, 1e-9, 1.0)
    if "dbg_x" in core.state_names:  # no bias uncertainty: the noise alone
        b = [core.state_names.index(n) for n in core.state_names if n[:3] in ("dbg", "dba")]
        core.P[np.ix_(b, b)] = np.eye(len(b)) * 1e-30
    g_b = C_b_n.T @ (-earth.gravity_n(lat, 100.0))  # specific force at rest (level: [0, 0, g])
    omega_b = C_b_n.T @ earth.omega_ie_n(lat)
    t = np.arange(1, int(T_s * 100) + 1) * 0.01
    core.propagate(t, np.tile(omega_b, (t.size, 1)), np.tile(g_b, (t.size, 1)))
    core.flush()
    P_v = core.P[3:6, 3:6]
    C_i_n = C_b_n @ core.C.T  # body to ENU times inertial to body
    if core_name == "ekf":  # dv in the inertial frame
        return C_i_n @ P_v @ C_i_n.T
    return C_b_n @ P_v @ C_b_n.T  # nu in the body frame


@pytest.mark.parametrize("core_name", ["iekf", "liekf", "ekf"])
def test_vertical_velocity_variance_grows_by_the_vertical_noise(core_name):
    T = 10.0
    iso, up = _velocity_cov_enu(core_name, 0.0, T), _velocity_cov_enu(core_name, 1.0, T)
    q, q_up = (m_s_sqrt_h_to_m_s_sqrt_s(v) ** 2 for v in (0.2, 1.0))
    d = np.diag(up - iso)
    assert d[2] == pytest.approx((q_up - q) * T, rel=0.02), (d, (q_up - q) * T)
    assert abs(d[0]) < 1e-3 * (q_up - q) * T and abs(d[1]) < 1e-3 * (q_up - q) * T, d
    assert np.diag(iso)[2] == pytest.approx(q * T, rel=0.05)  # the isotropic run: q T on every axis
