"""SO(3) and SE2(3) tools: hat/vee, exp/log, inverse, adjoint, Jacobians.

Conventions (say them out loud, as manif does):

* SE2(3) elements are 5x5 matrices ``X = [[C, v, p], [0, 1, 0], [0, 0, 1]]`` (PI-LIEKF eq. (A.1)).
* The tangent vector is ``xi = [phi, nu, rho]`` (9,): attitude, velocity, position, in that order
  (PI-LIEKF eq. (A.2)). Note that manif uses [rho, theta, nu]; we do not.
* Errors are left-invariant: the truth is ``X = X_hat @ exp(xi)``; a perturbation acts on the right
  (in the body frame). The left Jacobian maps a left (global) perturbation, the right Jacobian a right one:
  ``exp(xi + d) ~= exp(J_l(xi) d) exp(xi) ~= exp(xi) exp(J_r(xi) d)``.
* ``exp`` follows PI-LIEKF eq. (A.3); ``log`` follows eq. (A.4) with its typo corrected (the velocity block is
  ``J_l(phi)^-1 nu``, the position block ``J_l(phi)^-1 rho``; the paper writes mu twice).

scipy.spatial.transform.Rotation serves the SO(3) logarithm (robust up to and at pi) and batch operations.
The single-vector SO(3) exponential is written by hand because it sits in every filter's per-sample hot path
(a scipy Rotation round trip costs ~10x more per call); the SE2(3) blocks (Jacobians, Q matrix) are not in
scipy at all.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

_SERIES_BELOW_RAD = 0.1  # below this, Taylor series of the trigonometric coefficients (truncation < 1e-17)
_I3 = np.eye(3)


# ----------------------------------------------------------------------------------------------- SO(3)
def hat3(phi: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``phi_x`` with ``hat3(a) @ b == cross(a, b)``."""
    x, y, z = phi
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for two 3-vectors: ``np.cross``'s products and differences, bit for bit, without its ~15-50 us of
    overhead per call (it runs at the IMU rate in the local-level strapdown)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def vee3(Phi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat3` (takes the antisymmetric part)."""
    return 0.5 * np.array([Phi[2, 1] - Phi[1, 2], Phi[0, 2] - Phi[2, 0], Phi[1, 0] - Phi[0, 1]])


def _taylor(theta2: float, coeffs: tuple[float, ...]) -> float:
    """Horner evaluation of sum_k coeffs[k] * theta2**k."""
    out = 0.0
    for c in reversed(coeffs):
        out = out * theta2 + c
    return out


def _series(sign_fact: int) -> tuple[float, ...]:
    """Coefficients (-1)^k / (2k + sign_fact)! for k = 0..6."""
    return tuple((-1.0) ** k / math.factorial(2 * k + sign_fact) for k in range(7))


_A_SERIES = _series(1)  # sin(t)/t
_B_SERIES = _series(2)  # (1 - cos t)/t^2
_C1_SERIES = _series(3)  # (t - sin t)/t^3
_C2_SERIES = _series(4)  # (t^2/2 + cos t - 1)/t^4
_C3_SERIES = tuple(0.5 * (-1.0) ** k * (2 * k - 2) / math.factorial(2 * k + 1) for k in range(2, 9))
_D_SERIES = (1.0 / 12.0, 1.0 / 720.0, 1.0 / 30240.0, 1.0 / 1209600.0, 1.0 / 47900160.0)


def _so3_coeffs(theta: float) -> tuple[float, float, float]:
    """a = sin(t)/t, b = (1 - cos t)/t^2, c = (t - sin t)/t^3, with small-angle series."""
    if theta < _SERIES_BELOW_RAD:
        t2 = theta * theta
        return _taylor(t2, _A_SERIES), _taylor(t2, _B_SERIES), _taylor(t2, _C1_SERIES)
    s, co = math.sin(theta), math.cos(theta)
    return s / theta, (1.0 - co) / (theta * theta), (theta - s) / (theta * theta * theta)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp(phi_x)`` (Rodrigues), phi [rad] a rotation vector."""
    theta = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    a, b, _ = _so3_coeffs(theta)
    K = hat3(phi)
    return _I3 + a * K + b * (K @ K)


def so3_log(C: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix, |phi| <= pi (scipy: quaternion route, stable near pi)."""
    return Rotation.from_matrix(C).as_rotvec()


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian ``J_l(phi) = sum_n phi_x^n / (n+1)!`` (the tau of PI-LIEKF eq. (A.3))."""
    theta = float(np.linalg.norm(phi))
    _, b, c = _so3_coeffs(theta)
    K = hat3(phi)
    return _I3 + b * K + c * (K @ K)


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse of the SO(3) left Jacobian (the tau^-1 of PI-LIEKF eq. (A.4)); valid for |phi| < 2 pi."""
    theta = float(np.linalg.norm(phi))
    K = hat3(phi)
    if theta < _SERIES_BELOW_RAD:
        d = _taylor(theta * theta, _D_SERIES)
    else:
        d = (1.0 - theta * math.sin(theta) / (2.0 * (1.0 - math.cos(theta)))) / (theta * theta)
    return _I3 - 0.5 * K + d * (K @ K)


def so3_gamma2(phi: np.ndarray) -> np.ndarray:
    """``Gamma_2(phi) = sum_n phi_x^n / (n+2)!``: the double integral of exp over a step of constant rate.

    Used by the strapdown position update (exact for constant body rate and specific force over a step).
    """
    theta = float(np.linalg.norm(phi))
    K = hat3(phi)
    if theta < _SERIES_BELOW_RAD:
        t2 = theta * theta
        c1, c2 = _taylor(t2, _C1_SERIES), _taylor(t2, _C2_SERIES)
    else:
        t2 = theta * theta
        c1 = (theta - math.sin(theta)) / (t2 * theta)
        c2 = (0.5 * t2 + math.cos(theta) - 1.0) / (t2 * t2)
    return 0.5 * _I3 + c1 * K + c2 * (K @ K)


# ---------------------------------------------------------------------------------------------- SE2(3)
def se23_hat(xi: np.ndarray) -> np.ndarray:
    """5x5 Lie-algebra matrix of ``xi = [phi, nu, rho]`` (PI-LIEKF eq. (A.2))."""
    X = np.zeros((5, 5))
    X[:3, :3] = hat3(xi[0:3])
    X[:3, 3] = xi[3:6]
    X[:3, 4] = xi[6:9]
    return X


def se23_vee(Xi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`se23_hat`."""
    return np.concatenate([vee3(Xi[:3, :3]), Xi[:3, 3], Xi[:3, 4]])


def se23_from(C: np.ndarray, v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Build the 5x5 element from attitude C, velocity v [m/s] and position p [m]."""
    X = np.eye(5)
    X[:3, :3] = C
    X[:3, 3] = v
    X[:3, 4] = p
    return X


def se23_parts(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C, v, p) views of a 5x5 element."""
    return X[:3, :3], X[:3, 3], X[:3, 4]


def se23_exp(xi: np.ndarray) -> np.ndarray:
    """Exponential map, PI-LIEKF eq. (A.3): ``[[exp(phi_x), J_l(phi) nu, J_l(phi) rho], ...]``."""
    phi = xi[0:3]
    J = so3_left_jacobian(phi)
    return se23_from(so3_exp(phi), J @ xi[3:6], J @ xi[6:9])


def se23_log(X: np.ndarray) -> np.ndarray:
    """Logarithm map, PI-LIEKF eq. (A.4) corrected: returns ``[phi, J_l^-1 v, J_l^-1 p]`` (|phi| <= pi)."""
    phi = so3_log(X[:3, :3])
    Jinv = so3_left_jacobian_inv(phi)
    return np.concatenate([phi, Jinv @ X[:3, 3], Jinv @ X[:3, 4]])


def se23_inv(X: np.ndarray) -> np.ndarray:
    """Group inverse ``[[C^T, -C^T v, -C^T p], ...]``."""
    C = X[:3, :3]
    Ct = C.T
    return se23_from(Ct, -Ct @ X[:3, 3], -Ct @ X[:3, 4])


def se23_adjoint(X: np.ndarray) -> np.ndarray:
    """9x9 adjoint with ``X exp(xi) X^-1 = exp(Ad_X xi)``; tangent order [phi, nu, rho]."""
    C, v, p = X[:3, :3], X[:3, 3], X[:3, 4]
    Ad = np.zeros((9, 9))
    Ad[0:3, 0:3] = C
    Ad[3:6, 3:6] = C
    Ad[6:9, 6:9] = C
    Ad[3:6, 0:3] = hat3(v) @ C
    Ad[6:9, 0:3] = hat3(p) @ C
    return Ad


def se23_ad(xi: np.ndarray) -> np.ndarray:
    """9x9 small adjoint (matrix of the Lie bracket ``[xi, .]``)."""
    P = hat3(xi[0:3])
    ad = np.zeros((9, 9))
    ad[0:3, 0:3] = P
    ad[3:6, 3:6] = P
    ad[6:9, 6:9] = P
    ad[3:6, 0:3] = hat3(xi[3:6])
    ad[6:9, 0:3] = hat3(xi[6:9])
    return ad


def _se3_q(phi: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Barfoot's Q(phi, rho) block (State Estimation for Robotics, eq. 7.86), with small-angle series."""
    theta = float(np.linalg.norm(phi))
    P, R = hat3(phi), hat3(rho)
    PR, RP = P @ R, R @ P
    PRP = PR @ P
    t2 = theta * theta
    if theta < _SERIES_BELOW_RAD:
        c1, c2, c3 = _taylor(t2, _C1_SERIES), _taylor(t2, _C2_SERIES), _taylor(t2, _C3_SERIES)
    else:
        s, co = math.sin(theta), math.cos(theta)
        c1 = (theta - s) / (t2 * theta)
        c2 = (0.5 * t2 + co - 1.0) / (t2 * t2)
        c3 = (2.0 * theta - 3.0 * s + theta * co) / (2.0 * t2 * t2 * theta)
    return 0.5 * R + c1 * (PR + RP + PRP) + c2 * (P @ PR + RP @ P - 3.0 * PRP) + c3 * (PRP @ P + P @ PRP)


def se23_left_jacobian(xi: np.ndarray) -> np.ndarray:
    """SE2(3) left Jacobian ``J_l(xi) = sum_n ad_xi^n / (n+1)!`` (9x9), closed form by blocks."""
    phi = xi[0:3]
    J3 = so3_left_jacobian(phi)
    J = np.zeros((9, 9))
    J[0:3, 0:3] = J3
    J[3:6, 3:6] = J3
    J[6:9, 6:9] = J3
    J[3:6, 0:3] = _se3_q(phi, xi[3:6])
    J[6:9, 0:3] = _se3_q(phi, xi[6:9])
    return J


def se23_right_jacobian(xi: np.ndarray) -> np.ndarray:
    """SE2(3) right Jacobian ``J_r(xi) = J_l(-xi)``."""
    return se23_left_jacobian(-np.asarray(xi, dtype=float))


def se23_left_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """Inverse of the SE2(3) left Jacobian, by blocks: ``[[Ji, 0, 0], [-Ji Q_v Ji, Ji, 0], [-Ji Q_p Ji, 0, Ji]]``."""
    phi = xi[0:3]
    Ji = so3_left_jacobian_inv(phi)
    J = np.zeros((9, 9))
    J[0:3, 0:3] = Ji
    J[3:6, 3:6] = Ji
    J[6:9, 6:9] = Ji
    J[3:6, 0:3] = -Ji @ _se3_q(phi, xi[3:6]) @ Ji
    J[6:9, 0:3] = -Ji @ _se3_q(phi, xi[6:9]) @ Ji
    return J


def se23_right_jacobian_inv(xi: np.ndarray) -> np.ndarray:
    """Inverse of the SE2(3) right Jacobian."""
    return se23_left_jacobian_inv(-np.asarray(xi, dtype=float))


def se23_box_minus(X: np.ndarray, X_hat: np.ndarray) -> np.ndarray:
    """Left-invariant error vector ``xi = log(X_hat^-1 X)`` so that ``X = X_hat exp(xi)``."""
    return se23_log(se23_inv(X_hat) @ X)


# ------------------------------------------------------------------------------------ batched SO(3)
def _coeff_batch(theta: np.ndarray, series: tuple[float, ...], closed) -> np.ndarray:
    """A trigonometric coefficient for an array of angles: Taylor series below 0.1 rad, closed form above."""
    out = np.polynomial.polynomial.polyval(theta * theta, series)
    big = theta >= _SERIES_BELOW_RAD
    if np.any(big):
        out[big] = closed(theta[big])
    return out


def hat3_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) skew-symmetric matrices."""
    K = np.zeros(phi.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -phi[..., 2], phi[..., 1]
    K[..., 1, 0], K[..., 1, 2] = phi[..., 2], -phi[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -phi[..., 1], phi[..., 0]
    return K


def so3_left_jacobian_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) SO(3) left Jacobians (same series/closed-form split as so3_left_jacobian)."""
    theta = np.linalg.norm(phi, axis=-1)
    b = _coeff_batch(theta, _B_SERIES, lambda t: (1.0 - np.cos(t)) / t**2)
    c = _coeff_batch(theta, _C1_SERIES, lambda t: (t - np.sin(t)) / t**3)
    K = hat3_batch(phi)
    return np.eye(3) + b[:, None, None] * K + c[:, None, None] * (K @ K)


def so3_left_jacobian_inv_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) inverses of the SO(3) left Jacobian."""
    theta = np.linalg.norm(phi, axis=-1)
    d = _coeff_batch(theta, _D_SERIES, lambda t: (1.0 - t * np.sin(t) / (2.0 * (1.0 - np.cos(t)))) / t**2)
    K = hat3_batch(phi)
    return np.eye(3) - 0.5 * K + d[:, None, None] * (K @ K)
