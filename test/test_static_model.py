"""The large-azimuth model (PKF paper eqs. (18)-(35)), the NED/ENU boundary, the PKF gain (eqs. (11)-(17))."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth, lie
from insalign_ros.filters.pkf import pkf_gain
from insalign_ros.filters.static_model import (
    H_ZUPT, T_NED_ENU, Rz, StaticModelInputs, enu_psi_from_ned_phi, f_model, jacobian, misalignment_matrix,
    ned_from_enu)
from oracles import misalignment_rotation_enu

LAT = math.radians(35.0)
G = 9.8
W = earth.OMEGA_IE_RAD_S
wN, wD = W * math.cos(LAT), -W * math.sin(LAT)
R_M = 6.37e6


def test_ned_enu_boundary():
    assert np.allclose(ned_from_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    assert np.isclose(np.linalg.det(T_NED_ENU), 1.0) and np.allclose(T_NED_ENU @ T_NED_ENU, np.eye(3))
    # a rotation by a about Down is a rotation by -a about Up
    a = 0.7
    assert np.allclose(T_NED_ENU @ Rz(a) @ T_NED_ENU, Rotation.from_rotvec([0, 0, -a]).as_matrix())
    psi = enu_psi_from_ned_phi([0.01, -0.02, 0.3])
    assert np.allclose(psi, [-0.02, 0.01, -0.3])
    # small angles: misalignment_rotation_enu == exp(psi_x)
    phi = np.array([1e-4, -2e-4, 3e-4])
    assert np.allclose(misalignment_rotation_enu(phi), lie.so3_exp(enu_psi_from_ned_phi(phi)), atol=1e-7)


def test_eq23_is_Rz_times_small_tilt():
    pN, pE, pD = 0.01, -0.02, 2.5
    expected = Rz(pD) @ (np.eye(3) + lie.hat3(np.array([pN, pE, 0.0])))
    assert np.allclose(misalignment_matrix(np.array([pN, pE, pD])), expected, atol=1e-15)


def test_attitude_rows_match_exact_error_kinematics():
    """phi' of f_model against the exact E' = E[w_in'] - [w_ie]E - [E dw]E (E = C_true C_est^T), rest, by FD."""
    phi = np.array([2e-3, -3e-3, 2.4])
    dw = np.array([1e-6, -2e-6, 3e-6])  # residual gyro error in n' (NED)
    w = np.array([wN, 0.0, wD])
    u = StaticModelInputs(np.array([0.0, 0.0, -G]), LAT, R_M)
    E = Rz(phi[2]) @ lie.so3_exp(np.array([phi[0], phi[1], 0.0]))
    h = 1.0
    Edot = E @ lie.hat3(w) - lie.hat3(w) @ E - lie.hat3(E @ dw) @ E
    E2 = lie.so3_exp(h * lie.vee3(Edot @ E.T)) @ E  # exact flow of E' E^T = [zeta x] over h

    def params(Em):  # (phiN, phiE, phiD) of Rz(phiD) exp([phiN, phiE, 0])
        pD_ = math.atan2(Em[1, 0], Em[0, 0])
        r = lie.so3_log(Rz(pD_).T @ Em)
        return np.array([r[0], r[1], pD_])

    num = (params(E2) - params(E)) / h
    model = f_model(np.r_[0.0, 0.0, phi], u, np.r_[0.0, 0.0, dw])[2:5]
    # equal to first order in the level angles: the residual is O(|rho| omega_ie) = 3e-3 * W here
    assert np.allclose(model, num, atol=1e-2 * W)
    assert np.allclose(model[:2], num[:2], atol=1e-3 * W)


def test_jacobian_matches_eq35():
    fN, fE, fD = 0.05, -0.03, -G
    pN, pE, pD = 1e-3, -2e-3, 1.1
    x = np.array([0.0, 0.0, pN, pE, pD])
    u = StaticModelInputs(np.array([fN, fE, fD]), LAT, R_M)
    c, s = math.cos(pD), math.sin(pD)
    F = jacobian(x, u)
    t = math.tan(LAT) / R_M
    paper = np.array([
        [0, 2 * wD, -s * fD, -c * fD, fE * c + fN * s + (pE * s - pN * c) * fD],
        [-2 * wD, 0, c * fD, -s * fD, fE * s - fN * c - (pE * c + pN * s) * fD],
        [0, 1 / R_M, 0, wD, wN * s],
        [-1 / R_M, 0, -wD, 0, wN * c],
        [0, -t, -wN * s, -wN * c, (-pN * c + pE * s) * wN],
    ])
    # velocity rows: identical to eq. (35); level-attitude rows: equal to first order in the level angles
    assert np.allclose(F[0:2], paper[0:2], rtol=1e-6, atol=1e-8)
    assert np.allclose(F[2:4], paper[2:4], atol=5e-3 * W)
    # the azimuth row agrees with eq. (35) at phiD = 0 (documented difference at large phiD)
    F0 = jacobian(np.zeros(5), u)
    paper0 = np.array([0, -t, 0, -wN, 0])
    assert np.allclose(F0[4], paper0, atol=1e-3 * W)


def test_pkf_gain_dimensions_and_deadbeat_limit():
    """K_PF (eq. (16), dimension-consistent) is (n p x n); with Q_m -> 0 and p = 1 the first increment cancels the
    predicted output exactly: H (F dx + dm) = 0 (eq. (13) at its minimum)."""
    rng = np.random.default_rng(0)
    F = np.eye(5) + 0.1 * rng.normal(size=(5, 5))
    for p in (1, 10):
        K = pkf_gain(F, H_ZUPT, p, np.eye(2 * p), np.eye(5 * p) * 1e-3)
        assert K.shape == (5 * p, 5)
    K1 = pkf_gain(F, H_ZUPT, 1, np.eye(2), np.eye(5) * 1e-12)
    dx = rng.normal(size=5)
    assert np.allclose(H_ZUPT @ (F @ dx + K1 @ dx), 0.0, atol=1e-6)
    # heavy Q_m -> no model error
    K_heavy = pkf_gain(F, H_ZUPT, 10, np.eye(20), np.eye(50) * 1e12)
    assert np.abs(K_heavy).max() < 1e-9


def test_compiled_misaligned_attitude_is_the_misalignment_rotation_applied():
    """The static cores' attitude estimate (static_kernels.misaligned_attitude_nb, compiled) is eq. (23)'s rotation
    ``misalignment_rotation_enu(phi)`` applied to C_b_n, for small and large misalignments."""
    from insalign_ros.core import earth
    from insalign_ros.filters.static_kernels import misaligned_attitude_nb

    rng = np.random.default_rng(11)
    for scale in (1e-4, 0.05, 1.0):
        for _ in range(10):
            phi = rng.normal(0.0, scale, 3)
            C = earth.C_b_n_from_rpy(*rng.uniform(-3.0, 3.0, 3))
            got = misaligned_attitude_nb(float(phi[0]), float(phi[1]), float(phi[2]), np.ascontiguousarray(C))
            assert np.allclose(got, misalignment_rotation_enu(phi) @ C, rtol=0, atol=1e-14)
