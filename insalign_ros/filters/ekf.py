"""Conventional 15-state error-state EKF in ECI: the non-invariant reference.

Standard multiplicative-attitude / additive-velocity-position error state (Groves, Principles of GNSS,
Inertial and Multisensor Integrated Navigation, 2nd ed., sec. 14.2.1, ECI-frame form), with the same
mechanization as every other core (core/mechanization.py, batched in :mod:`.liekf`):

* truth ``C_b_i = exp(psi_x) C_hat`` (psi: small rotation in ECI), ``v_i = v_hat + dv``, ``p_i = p_hat + dp``,
  ``b = b_hat + db`` (gyro, accelerometer);
* ``psi' = -C_hat db_g - C_hat w_g``, ``dv' = -(C_hat f_hat)_x psi + Gamma dp - C_hat db_a - C_hat w_a``,
  ``dp' = dv``, ``db' = w_b``; discrete ``Phi = I + F dt`` per IMU sample with C_hat at the start of the step;
  Gamma is the gravitation gradient ``GM/r^3 (3 u u^T - I)``.
* GNSS: ``z = p_gps_i - p_hat``, ``H = [0 I 0]`` on the position block, Joseph form; with the antenna lever arm
  and for GNSS velocity see filters/measurements.py, convention ``eci_ekf`` (the gyro-bias term of the lever-arm velocity,
  ``l x db_g``, is neglected: < 1e-3 m/s for a 1.5 m arm and 100 deg/h).

The Jacobian depends on the estimated attitude through ``(C_hat f_hat)_x`` - the linearisation is wrong by
the full attitude error, which is what breaks the EKF at large yaw error (docs/inmotion_cores.md). The frame
(ECI instead of ENU/ECEF) does not change that property; it lets all cores share one mechanization.
Attitude output: ``C_b_n_true = exp((C_i_n psi)_x) C_b_n_hat`` so ``P_att_n = C_i_n P_psi C_i_n^T``.
"""

from __future__ import annotations

import numpy as np

from ..core import earth, lie
from ..core.units import deg_h_to_rad_s, mg_to_m_s2
from .config import EkfConfig
from .iekf import bias_noise_psd
from .liekf import BatchedEciCore

_I3 = np.eye(3)


class ConventionalEkf(BatchedEciCore):
    """15-state error-state EKF (psi-angle attitude error in ECI)."""

    name = "ekf"
    config_class = EkfConfig
    _n_states = 15
    state_names = ("psi_x", "psi_y", "psi_z", "dv_x", "dv_y", "dv_z", "dp_x", "dp_y", "dp_z",
                   "dbg_x", "dbg_y", "dbg_z", "dba_x", "dba_y", "dba_z")

    def __init__(self, config=None):
        super().__init__(config)
        self._q_bg, self._q_ba = bias_noise_psd(self.cfg)

    def _P0(self, C_b_n, P_att_n, sigma_v, sigma_p):
        P = np.zeros((15, 15))
        C_n_i = self.C @ C_b_n.T
        P[0:3, 0:3] = C_n_i @ P_att_n @ C_n_i.T
        P[3:6, 3:6] = sigma_v * sigma_v * _I3
        P[6:9, 6:9] = sigma_p * sigma_p * _I3
        P[9:12, 9:12] = deg_h_to_rad_s(self.cfg.gyro_bias_deg_h) ** 2 * _I3
        P[12:15, 12:15] = mg_to_m_s2(self.cfg.acc_bias_mg) ** 2 * _I3
        return P

    _fused_kernel_transitions = False  # its own (multiplicative-error) transitions: the batched products
    convention = "eci_ekf"  # its own measurement Jacobians (filters/measurements.py)
    state_blocks = frozenset({"gyro_bias", "acc_bias"})

    def _noise_diag(self, dt):
        d = super()._noise_diag(dt)  # isotropic parts: C_hat Q C_hat^T = Q (the velocity block: _transitions)
        d[:, 9:12] = self._q_bg * dt[:, None]
        d[:, 12:15] = self._q_ba * dt[:, None]
        return d

    def _transitions(self, dC, dv_b, dp_b, dt, C_prev, f):
        n = dt.shape[0]
        f_i = np.einsum("nij,nj->ni", C_prev, f)
        r = float(np.linalg.norm(self.p))
        u = self.p / r
        Gamma = earth.GM_M3_S2 / r**3 * (3.0 * np.outer(u, u) - _I3)
        dtt = dt[:, None, None]
        Phi = np.zeros((n, 15, 15))
        Phi[:, np.arange(15), np.arange(15)] = 1.0
        Phi[:, 0:3, 9:12] = -C_prev * dtt
        Phi[:, 3:6, 0:3] = -lie.hat3_batch(f_i) * dtt
        Phi[:, 3:6, 6:9] = Gamma * dtt
        Phi[:, 3:6, 12:15] = -C_prev * dtt
        Phi[:, 6:9, 3:6] = _I3 * dtt
        Qd = np.zeros((n, 15, 15))
        Qd[:, np.arange(15), np.arange(15)] = self._noise_diag(dt)
        if np.ptp(self._q_acc_b) > 0.0:  # the accelerometer noise per body axis, in the inertial frame of dv
            Qd[:, 3:6, 3:6] = np.einsum("nij,j,nkj->nik", C_prev, self._q_acc_b, C_prev) * dtt
        return Phi, Qd

    def _inject(self, dx):
        self.C = lie.so3_exp(dx[0:3]) @ self.C
        self.v = self.v + dx[3:6]
        self.p = self.p + dx[6:9]
        self.b_g = self.b_g + dx[9:12]
        self.b_a = self.b_a + dx[12:15]

    _att_error_inertial = True  # psi_i: P_att_n = C_i_n P C_i_n^T

    def _bias_out(self):
        return self.b_g.copy(), self.b_a.copy()
