"""SE2(3) functions the package does not use, kept for the tests: the hat/vee maps, the logarithm, the inverse, the
adjoints, the left and right Jacobians and their inverses, and the left-invariant error ``box_minus`` (PI-LIEKF
appendix A; Barfoot, State Estimation for Robotics, section 7.1.5). The package's own SE2(3) maps (``se23_from``,
``se23_parts``, ``se23_exp``) are in insalign_ros/core/lie.py; test_lie.py checks both together (exp against
scipy's expm, the adjoint identity, the Jacobians against finite differences)."""

from __future__ import annotations

import math

import numpy as np

from insalign_ros.core.lie import (_C1_SERIES, _C2_SERIES, _SERIES_BELOW_RAD, _taylor, hat3, se23_from,
                                   so3_left_jacobian, so3_left_jacobian_inv, so3_log, vee3)

_C3_SERIES = tuple(0.5 * (-1.0) ** k * (2 * k - 2) / math.factorial(2 * k + 1) for k in range(2, 9))


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
