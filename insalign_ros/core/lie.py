"""SO(3) and SE2(3) tools: hat/vee, exp/log, Jacobians; for SE2(3) what the package uses (element, parts, exp);
the rest of SE2(3) (log, inverse, adjoints, Jacobians, box-minus) is in test/lie_ref.py, where the tests use it.

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
(a scipy Rotation round trip costs ~10x more per call).
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


def so3_left_jacobian_inv_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) inverses of the SO(3) left Jacobian."""
    theta = np.linalg.norm(phi, axis=-1)
    d = _coeff_batch(theta, _D_SERIES, lambda t: (1.0 - t * np.sin(t) / (2.0 * (1.0 - np.cos(t)))) / t**2)
    K = hat3_batch(phi)
    return np.eye(3) - 0.5 * K + d[:, None, None] * (K @ K)
