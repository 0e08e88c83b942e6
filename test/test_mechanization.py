"""ECI strapdown mechanization: a body at rest stays put; forward then inverse returns to the start."""

import math

import numpy as np

from insalign_ros.core import earth as E
from insalign_ros.core import lie
from insalign_ros.core import mechanization as M


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
        C, v, p = M.propagate_eci(C, v, p, w, f, dt)
    t = n * dt
    p_true = E.ecef_to_eci(t, p_e)
    assert np.linalg.norm(p - p_true) < 0.1
    C_true = E.C_e_i(t) @ E.C_n_e(lat, lon) @ C_b_n
    assert np.linalg.norm(lie.so3_log(C_true.T @ C)) < 1e-9
    state = M.NavStateEci(t, C, v, p)
    lat2, lon2, h2, C_b_n2, v_n2 = M.geodetic_from_state_eci(state, 0.0)
    assert np.linalg.norm(v_n2) < 1e-3
    assert np.allclose(C_b_n2, C_b_n, atol=1e-9)


def test_vertical_channel_is_not_hidden():
    """A 1e-4 m/s^2 specific-force error must show up: the integrator is not silently pinned to the truth."""
    lat, lon, C_b_n, p_e, w, f, s0 = _at_rest()
    C, v, p = s0.C_b_i, s0.v_i, s0.p_i
    for _ in range(10_000):
        C, v, p = M.propagate_eci(C, v, p, w, f + C_b_n.T @ [0, 0, 1e-4], 0.01)
    err = np.linalg.norm(p - E.ecef_to_eci(100.0, p_e))
    assert 0.3 < err < 0.7  # ~ 0.5 a t^2 = 0.5 m


def test_forward_then_inverse_returns_to_start():
    rng = np.random.default_rng(7)
    lat, lon, C_b_n, p_e, w, f, s0 = _at_rest()
    dt = 0.01
    samples = [(w + rng.normal(0, 0.05, 3), f + rng.normal(0, 2.0, 3)) for _ in range(3000)]
    C, v, p = s0.C_b_i, s0.v_i, s0.p_i
    for wk, fk in samples:
        C, v, p = M.propagate_eci(C, v, p, wk, fk, dt)
    for wk, fk in reversed(samples):
        C, v, p = M.propagate_eci_inverse(C, v, p, wk, fk, dt)
    assert np.linalg.norm(lie.so3_log(s0.C_b_i.T @ C)) < 1e-10
    assert np.linalg.norm(v - s0.v_i) < 1e-7
    assert np.linalg.norm(p - s0.p_i) < 1e-5
