"""SO(3)/SE2(3) invariants: exp/log round trip, adjoint identity, group axioms, Jacobians vs finite differences."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from insalign_ros.core import lie
import lie_ref  # noqa: E402  (test/lie_ref.py: the SE2(3) functions only the tests use)

RNG = np.random.default_rng(20261123)


def _random_tangents(n):
    """Random xi with |phi| spread over tiny, small, moderate and near-pi magnitudes."""
    xi = RNG.normal(size=(n, 9)) * np.array([1, 1, 1, 20, 20, 20, 1e3, 1e3, 1e3])
    u = xi[:, :3] / np.linalg.norm(xi[:, :3], axis=1, keepdims=True)
    groups = np.array_split(np.arange(n), 5)
    mags = [
        10.0 ** RNG.uniform(-12, -9, len(groups[0])),  # |phi| < 1e-9
        10.0 ** RNG.uniform(-9, -1, len(groups[1])),  # across the series threshold
        RNG.uniform(0.1, 3.0, len(groups[2])),
        math.pi - 10.0 ** RNG.uniform(-7, -3, len(groups[3])),  # close to pi
        RNG.uniform(0.0, math.pi - 1e-3, len(groups[4])),
    ]
    for g, m in zip(groups, mags):
        xi[g, :3] = u[g] * m[:, None]
    return xi


def test_hat_vee_round_trip():
    for xi in _random_tangents(50):
        assert np.allclose(lie_ref.se23_vee(lie_ref.se23_hat(xi)), xi, atol=0)
        assert np.allclose(lie.vee3(lie.hat3(xi[:3])), xi[:3], atol=0)
        assert np.allclose(lie.hat3(xi[:3]) @ xi[3:6], np.cross(xi[:3], xi[3:6]))


def test_exp_log_round_trip_10000():
    xis = _random_tangents(10_000)
    worst = 0.0
    for xi in xis:
        back = lie_ref.se23_log(lie.se23_exp(xi))
        scale = np.array([1, 1, 1] + [max(1.0, np.abs(xi[3:]).max())] * 6)
        worst = max(worst, float(np.max(np.abs(back - xi) / scale)))
    assert worst < 1e-9, worst


def test_exp_matches_matrix_exponential():
    for xi in _random_tangents(200):
        assert np.allclose(lie.se23_exp(xi), expm(lie_ref.se23_hat(xi)), atol=1e-9 * max(1, np.abs(xi).max()))


def test_group_axioms():
    X, Y, Z = (lie.se23_exp(xi) for xi in _random_tangents(3))
    I5 = np.eye(5)
    assert np.allclose((X @ Y) @ Z, X @ (Y @ Z), atol=1e-9)
    assert np.allclose(X @ lie_ref.se23_inv(X), I5, atol=1e-12)
    assert np.allclose(lie_ref.se23_inv(X) @ X, I5, atol=1e-12)
    assert np.allclose(X @ I5, X)
    C = (X @ Y)[:3, :3]
    assert np.allclose(C.T @ C, np.eye(3), atol=1e-12)  # closure: the product stays in SE2(3)
    assert np.allclose((X @ Y)[3:, :], I5[3:, :])
    assert abs(np.linalg.det(C) - 1.0) < 1e-12


def test_adjoint_identity():
    for xi_x, xi in zip(_random_tangents(100), _random_tangents(100)):
        X = lie.se23_exp(xi_x)
        lhs = lie.se23_exp(lie_ref.se23_adjoint(X) @ xi)
        rhs = X @ lie.se23_exp(xi) @ lie_ref.se23_inv(X)
        assert np.allclose(lhs, rhs, atol=1e-8 * max(1.0, np.abs(rhs).max()))
        # ad is the derivative of Ad: Ad_exp(xi) = expm(ad_xi)
        assert np.allclose(lie_ref.se23_adjoint(lie.se23_exp(xi)), expm(lie_ref.se23_ad(xi)),
                           atol=1e-7 * max(1, np.abs(xi).max()))


def _fd_left_jacobian(xi, h=1e-6):
    """J_l by central differences: exp(xi + d) = exp(J_l d) exp(xi)."""
    J = np.zeros((9, 9))
    X_inv = lie_ref.se23_inv(lie.se23_exp(xi))
    for k in range(9):
        d = np.zeros(9)
        d[k] = h
        plus = lie_ref.se23_log(lie.se23_exp(xi + d) @ X_inv)
        minus = lie_ref.se23_log(lie.se23_exp(xi - d) @ X_inv)
        J[:, k] = (plus - minus) / (2 * h)
    return J


@pytest.mark.parametrize("phi_norm", [1e-10, 1e-3, 0.09, 0.11, 1.0, 2.5])
def test_left_and_right_jacobians_vs_finite_differences(phi_norm):
    xi = RNG.normal(size=9)
    xi[:3] *= phi_norm / np.linalg.norm(xi[:3])
    Jl = lie_ref.se23_left_jacobian(xi)
    assert np.allclose(Jl, _fd_left_jacobian(xi), atol=1e-6)
    # right Jacobian: exp(xi + d) = exp(xi) exp(J_r d)
    X_inv = lie_ref.se23_inv(lie.se23_exp(xi))
    h = 1e-6
    Jr_fd = np.column_stack([
        (lie_ref.se23_log(X_inv @ lie.se23_exp(xi + h * e))
         - lie_ref.se23_log(X_inv @ lie.se23_exp(xi - h * e))) / (2 * h)
        for e in np.eye(9)
    ])
    assert np.allclose(lie_ref.se23_right_jacobian(xi), Jr_fd, atol=1e-6)
    assert np.allclose(lie_ref.se23_left_jacobian_inv(xi) @ Jl, np.eye(9), atol=1e-10)
    assert np.allclose(lie_ref.se23_right_jacobian_inv(xi) @ lie_ref.se23_right_jacobian(xi), np.eye(9), atol=1e-10)
    # J_l = J_r Ad_exp(xi)^T ... equivalently J_l = Ad_exp(xi) J_r
    assert np.allclose(Jl, lie_ref.se23_adjoint(lie.se23_exp(xi)) @ lie_ref.se23_right_jacobian(xi), atol=1e-9)


def test_so3_blocks_against_series():
    for n in [1e-12, 1e-5, 0.05, 0.099, 0.1, 0.5, 3.0]:
        phi = RNG.normal(size=3)
        phi *= n / np.linalg.norm(phi)
        K = lie.hat3(phi)
        # sums of phi_x^k/(k+1)! and /(k+2)! to high order
        S1 = sum(np.linalg.matrix_power(K, k) / float(math.factorial(k + 1)) for k in range(30))
        S2 = sum(np.linalg.matrix_power(K, k) / float(math.factorial(k + 2)) for k in range(30))
        assert np.allclose(lie.so3_left_jacobian(phi), S1, atol=1e-14)
        assert np.allclose(lie.so3_gamma2(phi), S2, atol=1e-14)
        assert np.allclose(lie.so3_left_jacobian_inv(phi) @ S1, np.eye(3), atol=1e-13)
        assert np.allclose(lie.so3_exp(phi), expm(K), atol=1e-14)
