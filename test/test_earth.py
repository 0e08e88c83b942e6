"""Earth model: WGS84 gravity, frames, Euler conventions (REP 103)."""

import math

import numpy as np
import pytest

from insalign_ros.core import earth as E


def test_normal_gravity_equator_and_pole():
    assert abs(E.normal_gravity(0.0) - 9.7803253359) < 1e-6
    assert abs(E.normal_gravity(math.pi / 2) - 9.8321849378) < 1e-6
    assert abs(E.normal_gravity(-math.pi / 2) - 9.8321849378) < 1e-6
    # free-air gradient ~ -3.086e-6 (m/s^2)/m
    assert abs((E.normal_gravity(0.7, 1000.0) - E.normal_gravity(0.7)) / 1000.0 + 3.086e-6) < 1e-8


@pytest.mark.parametrize("lat_deg", [-89.0, -45.0, -10.0, 0.0, 23.0, 35.0, 52.0, 80.0, 90.0])
@pytest.mark.parametrize("h_m", [0.0, 120.0, 450.0])
def test_ecef_gravity_equals_normal_gravity_in_enu(lat_deg, h_m):
    lat, lon = math.radians(lat_deg), math.radians(-71.0 + lat_deg)
    g_e = E.gravity_e(E.geodetic_to_ecef(lat, lon, h_m))
    g_n = E.C_e_n(lat, lon) @ g_e
    assert np.max(np.abs(g_n - E.gravity_n(lat, h_m))) < 1e-5


def test_j2_only_would_fail_the_bar():
    """The J4/J6 terms matter at the 1e-5 level: removing them must break the normal-gravity agreement."""
    lat, lon = math.radians(45.0), 0.3
    p_e = E.geodetic_to_ecef(lat, lon, 0.0)
    full = E.C_e_n(lat, lon) @ E.gravity_e(p_e)
    saved = E._ZONAL
    try:
        E._ZONAL = saved[:1]
        j2 = E.C_e_n(lat, lon) @ E.gravity_e(p_e)
    finally:
        E._ZONAL = saved
    assert np.max(np.abs(j2 - full)) > 1e-5


def test_frames_round_trip():
    lat, lon, h = math.radians(48.8), math.radians(2.35), 80.0
    p_e = E.geodetic_to_ecef(lat, lon, h)
    assert np.allclose(E.ecef_to_geodetic(p_e), (lat, lon, h), atol=1e-9)
    C = E.C_e_n(lat, lon)
    assert np.allclose(C @ C.T, np.eye(3), atol=1e-15)
    # Up axis equals the ellipsoid normal; ENU of a point 10 m north
    assert np.allclose(C[2], [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    assert np.allclose(E.ecef_to_enu(E.enu_to_ecef(np.array([3.0, -7.0, 2.0]), lat, lon, h), lat, lon, h),
                       [3.0, -7.0, 2.0], atol=1e-6)
    # ECEF <-> ECI: velocity of a point at rest in ECEF is omega x r in ECI
    t = 1234.5
    p_i, v_i = E.ecef_to_eci(t, p_e, np.zeros(3), t0_s=1000.0)
    assert np.allclose(np.linalg.norm(v_i), E.OMEGA_IE_RAD_S * np.hypot(p_e[0], p_e[1]), rtol=1e-12)
    back_p, back_v = E.eci_to_ecef(t, p_i, v_i, t0_s=1000.0)
    assert np.allclose(back_p, p_e, atol=1e-6) and np.allclose(back_v, 0, atol=1e-9)
    # after one sidereal day the frames coincide again
    sidereal = 2 * math.pi / E.OMEGA_IE_RAD_S
    assert np.allclose(E.C_e_i(sidereal), np.eye(3), atol=1e-12)


def test_earth_rate_in_enu():
    lat = math.radians(35.0)
    w = E.omega_ie_n(lat)
    lon = 0.4
    assert np.allclose(E.C_e_n(lat, lon) @ E.OMEGA_IE_E, w, atol=1e-18)
    assert abs(w[1] - 7.292115e-5 * math.cos(lat)) < 1e-15


def test_euler_convention_rep103():
    # yaw 90 deg: body x (forward) points North; yaw from East counter-clockwise
    C = E.C_b_n_from_rpy(0.0, 0.0, math.pi / 2)
    assert np.allclose(C @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # positive pitch: nose down (forward axis gets a negative Up component)
    C = E.C_b_n_from_rpy(0.0, 0.1, 0.0)
    assert (C @ [1, 0, 0])[2] < 0
    # positive roll: left side (y) goes up
    C = E.C_b_n_from_rpy(0.1, 0.0, 0.0)
    assert (C @ [0, 1, 0])[2] > 0
    rng = np.random.default_rng(1)
    for _ in range(100):
        rpy = rng.uniform([-math.pi, -1.5, -math.pi], [math.pi, 1.5, math.pi])
        assert np.allclose(E.rpy_from_C_b_n(E.C_b_n_from_rpy(*rpy)), rpy, atol=1e-12)


def test_euler_error_wraps_and_small_rotation():
    a = E.C_b_n_from_rpy(0.0, 0.0, math.radians(179.0))
    b = E.C_b_n_from_rpy(0.0, 0.0, math.radians(-179.0))
    assert np.allclose(np.degrees(E.euler_error_rad(a, b)), [0, 0, -2.0], atol=1e-9)
    psi = E.heading_error_enu_rad(a, b)
    assert np.allclose(np.degrees(psi), [0, 0, -2.0], atol=1e-9)


def test_ecef_to_geodetic_closed_form_round_trip_and_agrees_with_pymap3d():
    """Heikkinen's closed form (earth.ecef_to_geodetic, ~2 us a call) inverts geodetic_to_ecef to rounding from
    -10 km to 1,000 km of height, poles included, and agrees with pymap3d's ecef2geodetic near the surface."""
    import pymap3d

    rng = np.random.default_rng(3)
    lat = np.r_[rng.uniform(-np.pi / 2, np.pi / 2, 2000), np.pi / 2, -np.pi / 2, 0.0]
    lon = rng.uniform(-np.pi, np.pi, lat.size)
    h = np.r_[rng.uniform(-1e4, 1e6, lat.size - 3), 50.0, -50.0, 0.0]
    for la, lo, hh in zip(lat, lon, h):
        got = E.ecef_to_geodetic(E.geodetic_to_ecef(la, lo, hh))
        assert abs(got[0] - la) < 1e-14 and abs(got[2] - hh) < 1e-7
        assert abs(np.angle(np.exp(1j * (got[1] - lo)))) < 1e-14 or abs(abs(la) - np.pi / 2) < 1e-12
        if abs(hh) < 1e4:
            ref = pymap3d.ecef2geodetic(*E.geodetic_to_ecef(la, lo, hh), deg=False)
            assert abs(got[0] - float(ref[0])) < 1e-14 and abs(got[2] - float(ref[2])) < 1e-7


def _rolling_body(accel_n=(0.0, 0.0, 0.0), T=3.0, dt=0.01):
    """A body rolling 10 deg at 5 s, pitching 3 +- 2 deg at 7 s and turning 2 deg/s, accelerating by ``accel_n``
    (ENU, constant) under g = 9.8 up: exact rates (the rotation between samples) and specific forces."""
    from scipy.spatial.transform import Rotation

    t = np.arange(0.0, T + 1e-9, dt)
    rpy = np.stack([np.radians(10 * np.sin(2 * np.pi * t / 5)), np.radians(3 + 2 * np.cos(2 * np.pi * t / 7)),
                    np.radians(2 * t)], 1)
    C = np.array([E.C_b_n_from_rpy(*x) for x in rpy])
    F = np.einsum("kji,j->ki", C, np.array([0.0, 0.0, 9.8]) + np.asarray(accel_n))
    W = np.zeros_like(F)
    for k in range(1, len(t)):
        W[k] = Rotation.from_matrix(C[k - 1].T @ C[k]).as_rotvec() / dt
    return t, W, F, rpy


def test_level_from_window_turns_every_sample_into_the_last_body_frame():
    t, W, F, rpy = _rolling_body()
    r, p, sig = E.level_from_window(t, W, F, 0.0)
    assert abs(r - rpy[-1, 0]) < 1e-9 and abs(p - rpy[-1, 1]) < 1e-9  # exact: no acceleration, exact rates
    assert sig == pytest.approx(math.radians(1.0), rel=1e-6)  # the accelerometer-bias term alone
    r0, p0, _ = E.level_from_specific_force(F, 0.0)  # the plain mean averages the roll away: degrees off
    assert max(abs(r0 - rpy[-1, 0]), abs(p0 - rpy[-1, 1])) > math.radians(3.0)


def test_level_from_window_sigma_covers_a_mean_acceleration_it_is_told():
    a = 1.5  # [m/s^2] East: tilts the level by atan(a / g) = 8.7 deg
    t, W, F, rpy = _rolling_body(accel_n=(a, 0.0, 0.0))
    r, p, sig = E.level_from_window(t, W, F, a)
    err = math.hypot(r - rpy[-1, 0], p - rpy[-1, 1])
    assert math.radians(8.0) < err <= 1.05 * sig  # a 1-sigma bound of the magnitude: the error is at most ~1 sigma
