"""Imperfect IEKF (PI-LIEKF paper's baseline, Tables 2 and 5): invariant attitude/velocity/position + EKF biases.

State (15): ``[phi, nu, rho]`` left-invariant on SE2(3) in ECI exactly as in :mod:`.liekf` (truth
``X = X_hat exp(xi)``), plus the bias errors ``db_g = b_g - b_g_hat`` [rad/s], ``db_a = b_a - b_a_hat`` [m/s^2]
of the IMU model of eq. (34). The mechanization uses the bias-corrected input ``omega - b_g_hat``,
``f - b_a_hat``; the error then obeys ``xi' = A xi - [db_g; db_a; 0] - [w_g; w_a; 0]``, so the discrete
transition is ``[[Phi_9, -B dt], [0, I]]`` with ``B = [I 0; 0 I; 0 0]`` (first order in dt in the bias column).
The bias columns break group-affinity: this is the "imperfect" part. The correction adds ``db_hat`` to the
biases; no reset Jacobian is applied to the bias block (standard for the imperfect IEKF).

Q (Table 2): ``diag(ARW^2 I, VRW^2 I, 0, q_bg I, q_ba I) dt`` with small bias random walks (config) so that
the bias covariance does not collapse; P0 bias block ``b_Gyro^2 I``, ``b_Acc^2 I`` (Table 2).

GNSS position and velocity with the antenna lever arm: the LIEKF's models (:mod:`.liekf`) with zero bias columns
(the gyro-bias term of the lever-arm velocity, ``l x db_g``, is neglected: < 1e-3 m/s for 1.5 m and 100 deg/h).
"""

from __future__ import annotations

import numpy as np

from ..core.units import deg_h_to_rad_s, mg_to_m_s2
from .config import IekfConfig
from .eci_batch import liekf_transition_batch
from .liekf import BatchedEciCore

_I3 = np.eye(3)


def bias_noise_psd(cfg) -> tuple[float, float]:
    """Bias random-walk PSDs [rad^2/s^3], [m^2/s^5] from deg/h/sqrt(h) and mg/sqrt(h)."""
    q_bg = (deg_h_to_rad_s(cfg.gyro_bias_rw_deg_h_sqrt_h) / 60.0) ** 2
    q_ba = (mg_to_m_s2(cfg.acc_bias_rw_mg_sqrt_h) / 60.0) ** 2
    return q_bg, q_ba


class ImperfectIekf(BatchedEciCore):
    """15-state imperfect IEKF in ECI."""

    name = "iekf"
    config_class = IekfConfig
    _n_states = 15
    state_names = ("phi_x", "phi_y", "phi_z", "nu_x", "nu_y", "nu_z", "rho_x", "rho_y", "rho_z",
                   "dbg_x", "dbg_y", "dbg_z", "dba_x", "dba_y", "dba_z")

    def __init__(self, config=None):
        super().__init__(config)
        self._q_bg, self._q_ba = bias_noise_psd(self.cfg)

    def _P0(self, C_b_n, P_att_n, sigma_v, sigma_p):
        P = super()._P0(C_b_n, P_att_n, sigma_v, sigma_p)
        P[9:12, 9:12] = deg_h_to_rad_s(self.cfg.gyro_bias_deg_h) ** 2 * _I3
        P[12:15, 12:15] = mg_to_m_s2(self.cfg.acc_bias_mg) ** 2 * _I3
        return P

    #: the bias blocks (the zero angular rate and the gyro bias prior need the gyro bias: filters/measurements.py)
    state_blocks = frozenset({"gyro_bias", "acc_bias"})

    def _noise_diag(self, dt):
        d = super()._noise_diag(dt)
        d[:, 9:12] = self._q_bg * dt[:, None]
        d[:, 12:15] = self._q_ba * dt[:, None]
        return d

    _fused_kernel_transitions = True  # mechanization_numba.eci_invariant_steps builds these transitions (d = 15)

    def _transitions(self, dC, dv_b, dp_b, dt, C_prev, f):
        n = dt.shape[0]
        Phi = np.zeros((n, 15, 15))
        Phi[:, 0:9, 0:9] = liekf_transition_batch(dC, dv_b, dp_b, dt)
        idx3 = np.arange(3)
        Phi[:, idx3, 9 + idx3] = -dt[:, None]  # phi <- -db_g dt
        Phi[:, 3 + idx3, 12 + idx3] = -dt[:, None]  # nu <- -db_a dt
        Phi[:, np.arange(9, 15), np.arange(9, 15)] = 1.0
        Qd = np.zeros((n, 15, 15))
        Qd[:, np.arange(15), np.arange(15)] = self._noise_diag(dt)
        return Phi, Qd

    def _inject(self, dx):
        super()._inject(dx)
        self.b_g = self.b_g + dx[9:12]
        self.b_a = self.b_a + dx[12:15]

    def _bias_out(self):
        return self.b_g.copy(), self.b_a.copy()
