"""io/datasets.py: the convention conversions against independent constructions (data-free), and the reader
decisions against the real recordings (skipped with the reason when ../shared/data is absent)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth
from insalign_ros.io import datasets as DS
from insalign_ros.io.datasets import shared_data_dir


SHARED = shared_data_dir(__file__)


def _need(name: str) -> Path:
    if SHARED is None or not (SHARED / name).is_dir():
        pytest.skip(f"real data not available: ../shared/data/{name} is absent (read-only shared data, never copied "
                    "into the repo)")
    return SHARED / name


def _matrix(fn) -> np.ndarray:
    """The linear map ``fn`` as a matrix (columns: images of the unit vectors)."""
    return np.column_stack([fn(e) for e in np.eye(3)])


# ------------------------------------------------------------------------------------ data-free
def test_axis_maps_are_rotations_that_put_gravity_up():
    g = 9.81
    for fn, down in ((DS.rbd_to_flu, [0, 0, -g]), (DS.frd_to_flu, [0, 0, -g])):
        M = _matrix(fn)
        assert np.allclose(M @ M.T, np.eye(3)) and np.isclose(np.linalg.det(M), 1.0)  # proper rotation
        assert np.allclose(fn(np.array(down)), [0, 0, g])  # z down reading -g at rest -> FLU +g up
    # rover: sensor x = right -> FLU -y; sensor y = backward -> FLU -x
    assert np.allclose(DS.rbd_to_flu(np.array([1.0, 0, 0])), [0, -1, 0])
    assert np.allclose(DS.rbd_to_flu(np.array([0, 1.0, 0])), [-1, 0, 0])
    assert np.allclose(DS.frd_to_flu(np.array([[1.0, 2.0, 3.0]])), [[1.0, -2.0, -3.0]])


def test_ned_euler_to_enu_euler_matches_the_rotation_matrices():
    """C_flu_enu = T_ned->enu C_frd_ned T_flu->frd, built from matrices, against the closed form."""
    T_ne = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])  # NED -> ENU (its own inverse)
    T_bf = np.diag([1.0, -1.0, -1.0])  # FLU <-> FRD
    rng = np.random.default_rng(3)
    for _ in range(50):
        r, p, y = rng.uniform(-3.1, 3.1), rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1)
        C_frd_ned = Rotation.from_euler("ZYX", [y, p, r]).as_matrix()
        C_flu_enu = T_ne @ C_frd_ned @ T_bf
        expect = earth.rpy_from_C_b_n(C_flu_enu)
        got = DS.ned_rpy_to_enu_rpy_rad(r, p, y)
        assert np.allclose(earth.wrap_angle_rad(got - expect), 0.0, atol=1e-9)


def _tm_sphere(lat, lon, lon0):
    """Transverse Mercator on a unit sphere: (x east, y north) grid coordinates."""
    dl = lon - lon0
    return math.atanh(math.cos(lat) * math.sin(dl)), math.atan2(math.tan(lat), math.cos(dl))


def test_utm_convergence_sign_and_size_against_a_transverse_mercator_projection():
    """Grid azimuth of true north, by finite differences on a spherical TM projection, equals -convergence."""
    for lat_deg, lon_deg, zone in ((45.518, -73.39, 18), (42.337, -71.09, 19), (-33.9, 151.2, 56), (10.0, -76.0, 18)):
        lat, lon = math.radians(lat_deg), math.radians(lon_deg)
        lon0 = math.radians(-183.0 + 6.0 * zone)
        x0, y0 = _tm_sphere(lat, lon, lon0)
        x1, y1 = _tm_sphere(lat + 1e-7, lon, lon0)
        az_true_north_on_grid = math.atan2(x1 - x0, y1 - y0)
        assert DS.utm_convergence_rad(lat, lon, zone) == pytest.approx(-az_true_north_on_grid, abs=1e-6)
    assert math.degrees(DS.utm_convergence_rad(math.radians(45.518), math.radians(-73.39), 18)) == \
        pytest.approx(1.149, abs=0.002)
    # a grid-north heading (grid yaw 90 deg) east of the central meridian points east of true north: ENU yaw < 90
    yaw = DS.utm_grid_yaw_to_enu_rad(math.pi / 2, math.radians(45.5), math.radians(-73.4), 18)
    assert math.degrees(yaw) == pytest.approx(90.0 - 1.149, abs=0.01)


def test_course_over_ground_is_the_tangent_at_the_chord_midpoint_on_a_circle():
    R, w = 11.0, 0.31  # the car's circles: radius [m], rate [rad/s]
    t = np.arange(0.0, 20.0, 1.0)
    th = w * t
    e, n = R * np.cos(th), R * np.sin(th)
    tm, cog, sp = DS.course_over_ground(t, e, n)
    tangent = w * tm + math.pi / 2  # CCW motion: velocity 90 deg ahead of the radius
    assert np.allclose(earth.wrap_angle_rad(cog - tangent), 0.0, atol=1e-12)
    assert np.allclose(sp, 2 * R * math.sin(w / 2))  # chord length / 1 s
    assert DS.course_over_ground(t, 0 * e, 0 * n)[0].size == 0  # parked: no course


def test_clock_offset_recovers_a_known_lag():
    rng = np.random.default_rng(0)
    t_imu = np.arange(0.0, 120.0, 0.005)
    rate = np.convolve(rng.normal(0, 0.2, t_imu.size), np.ones(400) / 400 * 20, mode="same")  # a smooth yaw rate
    lag = 0.37
    t_ref = np.arange(1.0, 118.0, 0.45)  # a 2.2-Hz reference at IMU time + lag
    yaw = np.interp(t_ref - lag, t_imu, np.cumsum(rate) * 0.005)
    est, corr = DS.estimate_clock_offset_s(t_imu, rate + rng.normal(0, 0.05, t_imu.size), t_ref, yaw)
    assert est == pytest.approx(lag, abs=0.03) and corr > 0.9


def test_reference_interpolates_across_180_and_never_across_gaps():
    ref = DS.AttitudeReference("r", np.array([0.0, 1.0, 2.0, 10.0]),
                               np.array([[0, 0, 170.0], [0, 0, -170.0], [0, 0, -160.0], [0, 0, 0.0]]),
                               np.full(3, 0.1), max_gap_s=2.0)
    v = ref.at([0.5, 1.5, 5.0, -1.0, 11.0])
    assert v[0, 2] == pytest.approx(180.0) or v[0, 2] == pytest.approx(-180.0)
    assert v[1, 2] == pytest.approx(-165.0)
    assert np.all(np.isnan(v[2:, 2]))  # across the 8-s gap, before and after the span


def test_fix_covariance_is_the_enu_sigma_in_ecef():
    p_e, R_e = DS.fixes_to_ecef(np.array([45.5]), np.array([-73.4]), np.array([25.0]), 0.6, 1.2)
    lat, lon, h = earth.ecef_to_geodetic(p_e[0])
    assert (math.degrees(lat), math.degrees(lon), h) == pytest.approx((45.5, -73.4, 25.0), abs=1e-6)
    R_n = earth.C_e_n(lat, lon) @ R_e[0] @ earth.C_n_e(lat, lon)
    assert np.allclose(R_n, np.diag([0.36, 0.36, 1.44]), atol=1e-9)


# ------------------------------------------------------------------------------------ the real recordings
def test_rover_axes_and_clock_from_the_data():
    """RBD axes: each FLU accelerometer axis (2-s means) follows the specific force the reference pose predicts in
    its body (correlation > 0.85); the gyro's rate about Up follows the pose's yaw rate at the reader's clock offset
    (recomputed: within 0.05 s, correlation > 0.8)."""
    d = _need("rover_canada")
    data, ref = DS.read_rover_canada(d)
    assert data.n == 73453 and data.gnss_t_s.shape[0] == 7344 and not data.has_truth
    C = Rotation.from_euler("ZYX", np.radians(ref.rpy_deg[:, ::-1])).as_matrix()
    f_pred = np.einsum("kji,j->ki", C, [0.0, 0.0, 9.81])  # C_n_b [0, 0, g]
    inside = (ref.t_s > data.t_s[0] + 2) & (ref.t_s < data.t_s[-1] - 2)
    f_avg = np.array([data.f_ib_b[np.abs(data.t_s - tr) < 1.0].mean(axis=0) for tr in ref.t_s[inside]])
    for i in range(3):
        assert np.corrcoef(f_pred[inside, i], f_avg[:, i])[0, 1] > 0.85
    raw = DS.read_rover_raw(d)
    lag, corr = DS.estimate_clock_offset_s(raw["t"], data.omega_ib_b[:, 2], ref.t_s,
                                           np.radians(ref.rpy_deg[:, 2]), lags_s=np.arange(0.0, 1.0, 0.01))
    assert lag == pytest.approx(DS.ROVER_IMU_CLOCK_OFFSET_S, abs=0.05) and corr > 0.8
    # level mounting: the accelerometer's level vs the pose's, mean over the run, within the 1-deg floor
    lvl = np.degrees(np.arctan2(f_avg[:, :2], f_avg[:, 2:3]) - np.arctan2(f_pred[inside, :2], f_pred[inside, 2:3]))
    assert np.all(np.abs(np.mean(lvl, axis=0)) < ref.floor_deg[:2] + 0.5)


def test_car_two_line_records_frd_axes_and_backward_mount():
    """2,530 two-line IMU records and 66 fixes; the gyro's rate about Up (FRD -> FLU) equals the course's turn rate
    (CCW circles, within 10 %); the VN-100's own yaw is about 180 deg from the course over ground (its x axis points
    to the rear) and the reader's COG reference agrees with the AHRS within 10 deg (circular median)."""
    d = _need("car_circles_vn100")
    data, cog, ahrs = DS.read_car_circles(d)
    assert data.n == 2530 and data.gnss_t_s.shape[0] == 66 and not data.has_gnss_velocity
    assert data.t_s[0] == pytest.approx(2.47, abs=0.01)  # the IMU starts 2.5 s after the GPS (README)
    turn = np.diff(np.unwrap(np.radians(cog.rpy_deg[:, 2]))) / np.diff(cog.t_s)
    assert np.median(turn) > 0.2 and np.median(data.omega_ib_b[:, 2]) == pytest.approx(np.median(turn), rel=0.1)
    diff = np.radians(ahrs.at(cog.t_s)[:, 2] - cog.rpy_deg[:, 2])
    ok = np.isfinite(diff)
    med = math.degrees(math.atan2(np.median(np.sin(diff[ok])), np.median(np.cos(diff[ok]))))
    assert abs(med) < 10.0
    # at rest-like level: gravity up in FLU
    assert np.mean(data.f_ib_b[:, 2]) == pytest.approx(9.6, abs=0.3)


def test_shared_data_dir_takes_the_environment_first_then_an_ancestor(tmp_path, monkeypatch):
    (tmp_path / "shared" / "data").mkdir(parents=True)
    deep = tmp_path / "clone" / "test" / "x.py"
    monkeypatch.delenv("INSALIGN_DATA", raising=False)
    assert shared_data_dir(deep) == tmp_path / "shared" / "data"  # ../shared/data beside the clone
    monkeypatch.setenv("INSALIGN_DATA", str(tmp_path / "elsewhere"))
    assert shared_data_dir(deep) is None  # named but absent: no silent fallback to another copy
    (tmp_path / "elsewhere").mkdir()
    assert shared_data_dir(deep) == tmp_path / "elsewhere"
