"""Predictive Kalman filter (PKF paper eqs. (6)-(17)) on the 5-state large-azimuth model (eqs. (18)-(35)).

The 5-state error filter is the one of :class:`StaticZuptCore` (zero-velocity update eq. (32), feedback as in
Fig. 2). After each update the PKF computes the model-error increment from the state increment
``dx_k = x_k - x_{k-1}`` (closed loop: the posterior minus the state the step started from) by the predictive
optimisation over a horizon p, eqs. (11)-(17), with the decisions of docs/static_alignment.md:

* ``C_p = (I_p (x) H) A_p``  (2p x 5),  ``D_p = (I_p (x) H) B_p``  (2p x 5p)    (eq. (12), dimensions)
* ``K_PF = -(D_p^T R_e D_p + Q_m)^-1 D_p^T R_e C_p``  (5p x 5)                  (eq. (16) with C_p/D_p ordered
  so the product is defined; eq. (16) as printed multiplies a (5 x 2p) by a (5p x 2p))
* ``dm_k = [I 0 ... 0] K_PF dx_k``, ``m_k = m_{k-1} + dm_k``                      (eq. (17) without its second
  minus sign: the gain already carries it)
* m_k (a per-step increment of the state) is applied as a correction to the accelerometer and gyro outputs,
  transformed to body axes with C_n'^b (sec. 4.4), so that the mechanised error dynamics gain + m_k per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .static_model import H_ZUPT, expm_taylor, StaticConfig, StaticZuptCore
from .config import param


@dataclass
class PkfConfig(StaticConfig):
    """PKF tuning: horizon p (paper: 10), weights R_e (per output) and Q_m (per model-error increment)."""

    horizon_p: int = param(10, range=(1, 10000))
    #: R_e weight of every predicted velocity output [1/(m/s)^2]
    re_weight_per_m2_s2: float = 1.0
    #: Q_m weights of the velocity-channel increments [1/(m/s)^2] and attitude-channel increments [1/rad^2];
    #: large values make the model error slow (see docs/static_alignment.md for the gyrocompassing trade-off)
    qm_velocity_per_m2_s2: float = 1.0e10
    qm_attitude_north_per_rad2: float = 1.0e10
    #: the east gyro channel is the gyrocompassing signal itself: a fast model error there absorbs the azimuth
    #: information (east gyro bias and azimuth error are indistinguishable at rest), so it is kept slow
    qm_attitude_east_per_rad2: float = 1.0e12
    qm_attitude_down_per_rad2: float = 1.0e10

    def validate(self) -> None:
        super().validate()
        if not isinstance(self.horizon_p, int) or isinstance(self.horizon_p, bool) or not 1 <= self.horizon_p <= 100:
            raise ValueError(f"horizon_p: must be an integer in [1, 100], got {self.horizon_p!r}")
        for name in ("re_weight_per_m2_s2", "qm_velocity_per_m2_s2", "qm_attitude_north_per_rad2",
                     "qm_attitude_east_per_rad2", "qm_attitude_down_per_rad2"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")


def pkf_gain(F_k: np.ndarray, H: np.ndarray, p: int, R_e: np.ndarray, Q_m: np.ndarray) -> np.ndarray:
    """K_PF of eq. (16) (dimension-consistent form), shape (n p, n), from the discrete F_k held over the horizon."""
    n = F_k.shape[0]
    q = H.shape[0]
    powers = [np.eye(n)]
    for _ in range(p):
        powers.append(powers[-1] @ F_k)
    C_p = np.vstack([H @ powers[i] for i in range(1, p + 1)])  # (qp, n)
    D_p = np.zeros((q * p, n * p))
    for i in range(p):
        for j in range(i + 1):
            D_p[q * i:q * (i + 1), n * j:n * (j + 1)] = H @ powers[i - j]
    A = D_p.T @ R_e @ D_p + Q_m
    return -np.linalg.solve(A, D_p.T @ R_e @ C_p)


class Pkf(StaticZuptCore):
    """PKF static alignment core (5 states + predicted model error applied to the sensor outputs)."""

    name = "pkf"

    def initialize(self, *args, **kwargs):
        super().initialize(*args, **kwargs)
        self.m_rate = np.zeros(5)  # model error per second [m/s^2, m/s^2, rad/s, rad/s, rad/s] (n', NED)
        p = self.cfg.horizon_p
        self._R_e = np.eye(2 * p) * self.cfg.re_weight_per_m2_s2
        c = self.cfg
        qm = np.array([c.qm_velocity_per_m2_s2] * 2
                      + [c.qm_attitude_north_per_rad2, c.qm_attitude_east_per_rad2, c.qm_attitude_down_per_rad2])
        self._Q_m = np.diag(np.tile(qm, p))
        self._qm = qm

    def _after_update(self, x_start: np.ndarray, dt: float) -> None:
        dx = self.x - x_start
        # the reference path (the compiled one is the PKF branch of static_model._zupt_step_nb)
        K5 = pkf_gain(expm_taylor(self._F_last * dt), H_ZUPT, self.cfg.horizon_p, self._R_e, self._Q_m)[:5]
        dm = K5 @ dx
        self.m_rate = self.m_rate + dm / dt
        # apply: velocity rows gain +m  -> f_corr = f + C^b m_v ; attitude rows gain +m -> w_corr = w - C^b m_att
        self.mech.acc_correction_b = -self.body_from_ned(np.array([self.m_rate[0], self.m_rate[1], 0.0]))
        self.mech.gyro_correction_b = self.body_from_ned(self.m_rate[2:5])

    def _full_jacobian(self, F5: np.ndarray) -> np.ndarray:
        self._F_last = F5
        return F5

    _fused_zupt = True  # _after_update is the kernel's PKF step (_pkf_args)

    def _pkf_args(self):
        return self.cfg.horizon_p, self.cfg.re_weight_per_m2_s2, self._qm, self.m_rate.copy()
