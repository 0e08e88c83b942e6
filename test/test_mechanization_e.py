"""Earth-frame mechanization with the auxiliary velocity (inverse-alignment paper eqs. (21)-(33), (6)-(10))."""

import numpy as np

from insalign_ros.core import earth, lie
from insalign_ros.core.mechanization_e import v_e_from_vbar, vbar_from_v_e
from oracles import propagate_e, propagate_e_inverse, vector_field_e
from insalign_ros.sim.scenarios import make_scenario
import lie_ref  # noqa: E402  (test/lie_ref.py: the SE2(3) functions only the tests use)


def _random_element(rng):
    return lie.se23_from(lie.so3_exp(rng.normal(size=3)), rng.normal(size=3) * 100, rng.normal(size=3) * 1e6)


def test_group_affine_identity_on_random_elements():
    """f(AB) = f(A) B + A f(B) - A f(I) B (eq. (33), docs/backtracking.md) for random A, B, inputs, gravity."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        A, B = _random_element(rng), _random_element(rng)
        w, f, g = rng.normal(size=3), rng.normal(size=3) * 10, rng.normal(size=3) * 10
        lhs = vector_field_e(A @ B, w, f, g)
        rhs = vector_field_e(A, w, f, g) @ B + A @ vector_field_e(B, w, f, g) - A @ vector_field_e(np.eye(5), w, f, g) @ B
        assert np.max(np.abs(lhs - rhs)) < 1e-6 * max(1.0, np.max(np.abs(lhs)))


def test_left_invariant_error_dynamics_trajectory_independent():
    """eta = X_hat^-1 X obeys d eta/dt = g(eta) = f(eta) - f(I) eta (eq. (35)): independent of X_hat."""
    rng = np.random.default_rng(4)
    w, f, g = rng.normal(size=3) * 0.1, rng.normal(size=3), np.array([0.0, 0.0, -9.8])
    eta = _random_element(rng)
    for _ in range(5):
        Xh = _random_element(rng)
        X = Xh @ eta
        d_eta = lie_ref.se23_inv(Xh) @ (vector_field_e(X, w, f, g) - vector_field_e(Xh, w, f, g) @ eta)
        expect = vector_field_e(eta, w, f, g) - vector_field_e(np.eye(5), w, f, g) @ eta
        assert np.max(np.abs(d_eta - expect)) < 1e-6 * max(1.0, np.max(np.abs(expect)))


def test_auxiliary_velocity_roundtrip():
    p = earth.geodetic_to_ecef(0.5, 2.0, 100.0)
    vbar = vbar_from_v_e(np.zeros(3), p)
    assert abs(np.linalg.norm(vbar) - earth.OMEGA_IE_RAD_S * np.linalg.norm(p[:2])) < 1e-9
    assert np.allclose(v_e_from_vbar(vbar, p), 0.0, atol=1e-12)


def test_forward_reproduces_truth_then_inverse_returns_to_start_300s():
    """Noise-free two_position (100 Hz, 300 s, 180-deg turn): forward matches the truth, inverse returns to start
    (issue 8: attitude < 1e-8 rad, position < 1e-3 m)."""
    d = make_scenario("two_position", seed=0, noise=False, duration_s=300.0)
    C_n_e = earth.C_n_e(d.lat_rad[0], d.lon_rad[0])
    C0 = C_n_e @ d.C_b_n[0]
    p0 = earth.geodetic_to_ecef(d.lat_rad[0], d.lon_rad[0], d.h_m[0])
    v0 = vbar_from_v_e(C_n_e @ d.v_n[0], p0)
    C, v, p = C0, v0, p0
    for k in range(1, d.n):
        C, v, p = propagate_e(C, v, p, d.omega_ib_b[k], d.f_ib_b[k], d.t_s[k] - d.t_s[k - 1])
    C_true = earth.C_n_e(d.lat_rad[-1], d.lon_rad[-1]) @ d.C_b_n[-1]
    p_true = earth.geodetic_to_ecef(d.lat_rad[-1], d.lon_rad[-1], d.h_m[-1])
    assert np.linalg.norm(lie.so3_log(C_true.T @ C)) < 1e-9
    assert np.linalg.norm(p - p_true) < 1e-4
    assert np.linalg.norm(v_e_from_vbar(v, p)) < 1e-6
    for k in range(d.n - 1, 0, -1):
        C, v, p = propagate_e_inverse(C, v, p, d.omega_ib_b[k], d.f_ib_b[k], d.t_s[k] - d.t_s[k - 1])
    assert np.linalg.norm(lie.so3_log(C0.T @ C)) < 1e-8
    assert np.linalg.norm(p - p0) < 1e-3
    assert np.linalg.norm(v - v0) < 1e-5
