"""ECI strapdown mechanization: a body at rest stays put; forward then inverse returns to the start."""

import math

import numpy as np

from insalign_ros.core import earth as E
from insalign_ros.core import lie
from insalign_ros.core import mechanization as M
from oracles import geodetic_from_state_eci, propagate_eci, propagate_eci_inverse


def _at_rest(lat_deg=35.0, lon_deg=139.0, h_m=50.0):
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    C_b_n = E.C_b_n_from_rpy(0.02, -0.01, 1.0)
    p_e = E.geodetic_to_ecef(lat, lon, h_m)
    C_e_b = C_b_n.T @ E.C_e_n(lat, lon)
    omega_ib_b = C_e_b @ E.OMEGA_IE_E  # Earth rate seen by the body
    f_ib_b = -C_e_b @ E.gravity_e(p_e)  # at rest the accelerometers read minus gravity
    s0 = M.state_eci_from_geodetic(0.0, 0.0, lat, lon, h_m, C_b_n, np.zeros(3))
    return lat, lon, C_b_n, p_e, omega_ib_b, f_ib_b, s0


def test_body_at_rest_600s_stays_within_0p1m():
    lat, lon, C_b_n, p_e, w, f, s0 = _at_rest()
    dt = 0.01
    C, v, p = s0.C_b_i, s0.v_i, s0.p_i
    n = 60_000
    for _ in range(n):
        C, v, p = propagate_eci(C, v, p, w, f, dt)
    t = n * dt
    p_true = E.ecef_to_eci(t, p_e)
    assert np.linalg.norm(p - p_true) < 0.1
    C_true = E.C_e_i(t) @ E.C_n_e(lat, lon) @ C_b_n
    assert np.linalg.norm(lie.so3_log(C_true.T @ C)) < 1e-9
    state = M.NavStateEci(t, C, v, p)
    lat2, lon2, h2, C_b_n2, v_n2 = geodetic_from_state_eci(state, 0.0)
    assert np.linalg.norm(v_n2) < 1e-3
    assert np.allclose(C_b_n2, C_b_n, atol=1e-9)


def test_vertical_channel_is_not_hidden():
    """A 1e-4 m/s^2 specific-force error must show up: the integrator is not silently pinned to the truth."""
    lat, lon, C_b_n, p_e, w, f, s0 = _at_rest()
    C, v, p = s0.C_b_i, s0.v_i, s0.p_i
    for _ in range(10_000):
        C, v, p = propagate_eci(C, v, p, w, f + C_b_n.T @ [0, 0, 1e-4], 0.01)
    err = np.linalg.norm(p - E.ecef_to_eci(100.0, p_e))
    assert 0.3 < err < 0.7  # ~ 0.5 a t^2 = 0.5 m


def test_forward_then_inverse_returns_to_start():
    rng = np.random.default_rng(7)
    lat, lon, C_b_n, p_e, w, f, s0 = _at_rest()
    dt = 0.01
    samples = [(w + rng.normal(0, 0.05, 3), f + rng.normal(0, 2.0, 3)) for _ in range(3000)]
    C, v, p = s0.C_b_i, s0.v_i, s0.p_i
    for wk, fk in samples:
        C, v, p = propagate_eci(C, v, p, wk, fk, dt)
    for wk, fk in reversed(samples):
        C, v, p = propagate_eci_inverse(C, v, p, wk, fk, dt)
    assert np.linalg.norm(lie.so3_log(s0.C_b_i.T @ C)) < 1e-10
    assert np.linalg.norm(v - s0.v_i) < 1e-7
    assert np.linalg.norm(p - s0.p_i) < 1e-5


def test_navigation_outputs_of_an_eci_state_match_the_frame_chain():
    """``navigation_from_state_eci`` (one compiled call per estimate) against the frame chain of core/earth.py written
    out: ECI -> ECEF, geodetic, ENU; the attitude covariance of an error kept in the body frame (C_b_n P C_b_n^T) and
    in ECI (C_i_n P C_i_n^T); within 1 km of the Earth's centre the position is NaN (a lost filter)."""
    rng = np.random.default_rng(3)
    for k in range(20):
        lat, lon, h = rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1), rng.uniform(-100.0, 9000.0)
        t, t0 = rng.uniform(0.0, 5000.0), rng.uniform(-100.0, 100.0)
        C_b_n = E.C_b_n_from_rpy(*rng.uniform(-3.0, 3.0, 3))
        s = M.state_eci_from_geodetic(t, t0, lat, lon, h, C_b_n, rng.normal(0.0, 20.0, 3))
        A = rng.normal(0.0, 1e-3, (3, 3))
        P = A @ A.T
        p_e, v_e = E.eci_to_ecef(t, s.p_i, s.v_i, t0)
        lat_r, lon_r, h_r = E.ecef_to_geodetic(p_e)
        C_i_n = E.C_e_n(lat_r, lon_r) @ E.C_e_i(t, t0).T
        for inertial in (False, True):
            la, lo, hh, Cbn, vn, Patt = M.navigation_from_state_eci(s, t0, P, inertial)
            assert abs(la - lat_r) < 1e-14 and abs(lo - lon_r) < 1e-14 and abs(hh - h_r) < 1e-8
            assert abs(la - lat) < 1e-12 and abs(hh - h) < 1e-6  # and the geodetic position it started from
            assert np.allclose(Cbn, C_i_n @ s.C_b_i, rtol=0, atol=1e-14)
            assert np.allclose(Cbn, C_b_n, rtol=0, atol=1e-12)
            assert np.allclose(vn, E.C_e_n(lat_r, lon_r) @ v_e, rtol=0, atol=1e-11)
            R = C_i_n if inertial else Cbn
            assert np.allclose(Patt, R @ P @ R.T, rtol=1e-12, atol=1e-20)
            assert np.array_equal(Patt, Patt.T)
    centre = M.NavStateEci(0.0, np.eye(3), np.zeros(3), np.array([300.0, 0.0, 0.0]))
    assert all(math.isnan(x) for x in M.navigation_from_state_eci(centre, 0.0, np.eye(3), False)[:3])
