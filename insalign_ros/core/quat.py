"""Scalar quaternion helpers on plain floats, q = (w, x, y, z) (Hamilton, body -> reference), for per-sample Python
loops where numpy's per-call overhead would dominate (the GSF's AHRS, filters/yaw_gsf.py). Imports only math and
numpy (scipy for ``from_C``)."""

from __future__ import annotations

import math

import numpy as np


def to_C(q):
    """C (3x3) of the unit quaternion q = (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def mul(a, b):
    """Hamilton product a b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def from_rotvec(r0, r1, r2):
    """exp of the rotation vector (r0, r1, r2) [rad] (first order below 1e-9 rad)."""
    a = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if a < 1e-9:
        return (1.0, 0.5 * r0, 0.5 * r1, 0.5 * r2)
    s = math.sin(0.5 * a) / a
    return (math.cos(0.5 * a), r0 * s, r1 * s, r2 * s)


def normalize(q):
    w, x, y, z = q
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return (w * n, x * n, y * n, z * n)


def from_C(C):
    """(w, x, y, z) of a rotation matrix (scipy's quaternion route)."""
    from scipy.spatial.transform import Rotation  # scipy is a core dependency (used once per alignment)

    x, y, z, w = Rotation.from_matrix(C).as_quat()
    return (w, x, y, z)
