"""10-state EKF baseline of the PKF paper (sec. 5): the 5 states of eq. (34) plus residual accelerometer
(north, east) and gyro (north, east, down) errors in n', modelled as random constants (random walks), with
zero-velocity updates (eq. (32)) and closed-loop feedback of all states into the mechanization.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core import earth
from .static_kernels import model_error_jacobian_nb
from .static_model import DEG_H, MG, StaticConfig, StaticZuptCore  # noqa: F401


@dataclass
class Ekf10Config(StaticConfig):
    """10-state EKF: bias random walks; the initial bias sigmas are StaticConfig's gyro_bias_deg_h, acc_bias_mg
    (PKF Table 1 bias stability)."""

    gyro_bias_rw_deg_h_sqrt_h: float = 0.0
    acc_bias_rw_mg_sqrt_h: float = 0.0

    def validate(self) -> None:
        super().validate()
        for name in ("gyro_bias_deg_h", "acc_bias_mg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")


class Ekf10(StaticZuptCore):
    """10-state closed-loop EKF: [dvN dvE phiN phiE phiD DfN DfE DwN DwE DwD] (NED, n')."""

    name = "ekf10"
    n_bias = 5

    def _init_bias_cov(self) -> None:
        sa = self.cfg.acc_bias_mg * MG
        sg = self.cfg.gyro_bias_deg_h * DEG_H
        self.P[5:7, 5:7] = np.eye(2) * sa**2
        self.P[7:10, 7:10] = np.eye(3) * sg**2

    def _nullspace(self, phiD: float) -> np.ndarray:
        """Unobservable direction at rest (eq. (34) rows 3-4): turning the azimuth by d and the horizontal gyro
        errors by d wN (sin phiD, cos phiD) leaves every level rate, hence every velocity, unchanged."""
        w_h = earth.OMEGA_IE_RAD_S * math.cos(self.mech.lat_rad)
        N = np.zeros(10)
        N[4] = 1.0
        N[7], N[8] = w_h * math.sin(phiD), w_h * math.cos(phiD)
        return N

    def _bootstrap_azimuth_cov(self, s_noise_rad: float, w_h: float) -> None:
        """The bootstrap azimuth a = atan2(rE, wN - rN) carries the horizontal gyro error: its error is
        (sin a epsN + cos a epsE) / wN, correlated with the gyro-error states (covariance below)."""
        sg2 = (self.cfg.gyro_bias_deg_h * DEG_H) ** 2
        a = self.x[4]
        self.P[4, 4] = s_noise_rad**2 + sg2 / w_h**2
        self.P[4, 7] = self.P[7, 4] = math.sin(a) * sg2 / w_h
        self.P[4, 8] = self.P[8, 4] = math.cos(a) * sg2 / w_h

    def _full_jacobian(self, F5: np.ndarray) -> np.ndarray:
        # G = df/dm' at the current state (velocity rows: I; attitude rows: -[Rz^T E]), numerically from eq. (34)
        u = self._u_last
        x5 = self.x[:5]
        G = np.zeros((5, 5))
        model_error_jacobian_nb(np.array(x5, dtype=float), np.asarray(u.f_np_ned, float), float(u.lat_rad),
                                float(u.r_m), G)  # central differences of f_model in m', compiled
        F = np.zeros((10, 10))
        F[:5, :5] = F5
        F[:5, 5:] = G
        return F

    def _q_rate(self) -> np.ndarray:
        qa = (self.cfg.acc_bias_rw_mg_sqrt_h * MG / 60.0) ** 2
        qg = (self.cfg.gyro_bias_rw_deg_h_sqrt_h * DEG_H / 60.0) ** 2
        return np.r_[super()._q_rate(), qa, qa, qg, qg, qg]

    _fused_zupt = True  # G, the nullspace (_oc_w_h) and _feedback_bias are the kernel's 10-state branches

    def _oc_w_h(self) -> float:
        return earth.OMEGA_IE_RAD_S * math.cos(self.mech.lat_rad)

    def _feedback_bias(self) -> None:
        x = self.x
        self.mech.acc_correction_b = self.mech.acc_correction_b + self.body_from_ned(np.array([x[5], x[6], 0.0]))
        self.mech.gyro_correction_b = self.mech.gyro_correction_b + self.body_from_ned(x[7:10])
        self.x[5:] = 0.0

    @property
    def state_names(self) -> tuple[str, ...]:
        return ("dvN", "dvE", "phiN", "phiE", "phiD", "DfN", "DfE", "DwN", "DwE", "DwD")
