"""Local-level (ENU) strapdown mechanization for static alignment, with feedback correction.

Frames: n = local ENU at a known, fixed position (static alignment: the position is known and held), b = body FLU.
One IMU sample stamped t_k holds the average rate/specific force over (t_{k-1}, t_k] (core/mechanization.py).

Step (first order in the transport/Earth rate, exact body rotation over the step):
  ``C_b_n <- exp(-omega_in_n dt) C_b_n exp(omega_ib_b dt)``
  ``v_n   <- v_n + (C_b_n_mid f_ib_b + g_n - (2 omega_ie_n + omega_en_n) x v_n) dt``
with ``omega_in_n = omega_ie_n + omega_en_n(v_n)`` (PKF paper eqs. (19)-(20), (25), (27) in ENU).
Sensor corrections (biases or the PKF model error) are subtracted from the samples before the step.
"""

from __future__ import annotations

import math

import numpy as np

from . import earth
from .lie import cross3


def rodrigues_ab(t2: float) -> tuple[float, float]:
    """(sin t / t, (1 - cos t) / t^2) of a rotation angle t with t^2 = t2 (second-order series below 1e-6 rad)."""
    if t2 < 1e-12:
        return 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    t = math.sqrt(t2)
    return math.sin(t) / t, (1.0 - math.cos(t)) / t2


def _rodrigues(phi: np.ndarray) -> np.ndarray:
    """exp(phi_x) for a small rotation vector phi [rad] (inline for speed at the IMU rate)."""
    x, y, z = phi
    a, b = rodrigues_ab(x * x + y * y + z * z)
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + a * K + b * (K @ K)


class LocalLevelMechanization:
    """ENU strapdown at a fixed known position: attitude ``C_b_n`` (body FLU -> ENU) and velocity ``v_n`` [m/s]."""

    def __init__(self, lat_rad: float, lon_rad: float, h_m: float, C_b_n: np.ndarray, v_n: np.ndarray):
        self.lat_rad, self.lon_rad, self.h_m = float(lat_rad), float(lon_rad), float(h_m)
        self.C_b_n = np.array(C_b_n, dtype=float)
        self.v_n = np.array(v_n, dtype=float)
        self.omega_ie_n = earth.omega_ie_n(lat_rad)
        self.g_n = earth.gravity_n(lat_rad, h_m)
        R_N, R_E = earth.radii_of_curvature(lat_rad)
        self.R_N_m, self.R_E_m = R_N + h_m, R_E + h_m
        self.tan_lat = math.tan(lat_rad)
        #: sensor corrections subtracted from every sample (body frame)
        self.gyro_correction_b = np.zeros(3)  # [rad/s]
        self.acc_correction_b = np.zeros(3)  # [m/s^2]

    def omega_en_n(self, v_n: np.ndarray) -> np.ndarray:
        """Transport rate [rad/s] in ENU: [-vN/R_N, vE/R_E, vE tan(lat)/R_E] (PKF eq. (25) in ENU)."""
        return np.array([-v_n[1] / self.R_N_m, v_n[0] / self.R_E_m, v_n[0] * self.tan_lat / self.R_E_m])

    def step(self, omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: float) -> np.ndarray:
        """One step; returns the specific force resolved in ENU, C_b_n_mid f [m/s^2] (for the error model)."""
        w = np.asarray(omega_ib_b) - self.gyro_correction_b
        f = np.asarray(f_ib_b) - self.acc_correction_b
        w_en = self.omega_en_n(self.v_n)
        w_in = self.omega_ie_n + w_en
        dC_b = _rodrigues(w * dt_s)
        C_mid = _rodrigues(-0.5 * dt_s * w_in) @ self.C_b_n @ _rodrigues(0.5 * dt_s * w)
        self.C_b_n = _rodrigues(-dt_s * w_in) @ self.C_b_n @ dC_b
        f_n = C_mid @ f
        self.v_n = self.v_n + (f_n + self.g_n - cross3(2.0 * self.omega_ie_n + w_en, self.v_n)) * dt_s
        return f_n

    def correct_attitude(self, E_n: np.ndarray) -> None:
        """Feedback: ``C_b_n <- E_n C_b_n`` with E_n = C_true C_est^T in ENU (re-orthonormalised)."""
        u, _, vt = np.linalg.svd(E_n @ self.C_b_n)
        self.C_b_n = u @ vt
