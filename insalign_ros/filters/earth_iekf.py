"""Earth-frame left-invariant EKF for static (two-position) alignment, with backward propagation.

Inverse-alignment paper (Liu et al. 2025), sec. 2.3-3.3. docs/backtracking.md has the derivations and decisions.

* State ``X = [[C_b_e, vbar_e, p_e], [0,1,0], [0,0,1]]`` (eq. (32)), ``vbar_e = v_e + omega_ie x p_e`` (eq. (23)),
  plus gyro drift ``b_g`` [rad/s], accelerometer bias ``b_a`` [m/s^2] and lever arm ``L_b`` [m] (IMU relative to
  the rotation centre, body frame): 18 error states ``[phi, nu, rho, db_g, db_a, dL]`` (eq. (47) order).
* Error: truth ``X = X_hat exp(xi)`` (left-invariant, the paper's ``eta = X_hat^-1 X``, eq. (34)); bias and
  lever-arm errors are ``true - estimate``.
* Propagation: the Earth-frame mechanization (core/mechanization_e.py) is the ECI one in a frame frozen at the
  start of each batch followed by ``exp(-omega_ie dt)``; a left multiplication by a world rotation leaves the
  left-invariant error unchanged, so the error transition is that of the ECI LIEKF (eq. (48) nav block; the
  Earth rate cancels, eq. (35)): ``xi_k = Ad(U_k^-1) F_dt xi_{k-1}`` plus ``phi -= db_g dt``, ``nu -= db_a dt``,
  ``rho -= db_a dt^2/2``. IMU samples are propagated in vectorised batches (filters/liekf.py helpers).
* Zero-velocity observation, eqs. (50)-(55), transformed by ``C_b_e^T`` (eq. (54)):
  ``z = C^T v_e_hat - omega_ib_b x L_hat = H xi + n`` with
  ``H = [0, -I, C^T (omega_ie)_x C, 0, 0, (omega_ib_b)_x]`` (our sign convention: truth = estimate + error).
  The core applies it itself every ``auto_zupt_period_s`` (the vehicle is static during alignment), and on
  ``update(ZeroVelocity(...))``.
* P0, eq. (56): ``P_l0 = T P0 T^T`` with ``T = [[C_b_n^T, 0, 0], [0, C_b_n^T, C_e_b (omega_ie)_x C_n_e],
  [0, 0, C_b_n^T]]`` from ENU (attitude psi_n, dv_n, dp_n). The paper's T has I on the attitude block because its
  attitude error is already in the error frame; ours is the body-frame phi, psi_n = C_b_n phi.
* Backward (inverse) propagation: ``propagate(t, omega, f, backward=True)`` runs the inverse mechanization
  (eqs. (6)-(10)) and the covariance backward by the time-reversal of the continuous model: with
  ``v -> -v`` and ``omega -> -omega`` (so ``b_g -> -b_g``) the reversed motion obeys the same forward equations;
  the error of the reversed state is ``D xi`` with ``D`` flipping nu and db_g.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import earth, lie
from ..core.mechanization_e import OMEGA_IE_E, v_e_from_vbar, vbar_from_v_e
from ..core.units import (
    deg_h_to_rad_s, deg_sqrt_h_to_rad_sqrt_s, m_s_sqrt_h_to_m_s_sqrt_s, ug_sqrt_hz_to_m_s_sqrt_h, ug_to_m_s2,
)
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, ImuSample, UpdateResult, accel_noise_b
from .config import InMotionConfig
from .checks import check_imu, usable_imu_arrays
from .eci_batch import eci_steps, liekf_transition_batch, prefix_products
from .kalman import joseph_update
from . import measurements  # noqa: F401  (registers its zero-velocity model)

_I3 = np.eye(3)
N_STATES = 18
#: flips the error of the time-reversed system: nu -> -nu, db_g -> -db_g
D_REVERSE = np.ones(N_STATES)
D_REVERSE[3:6] = -1.0
D_REVERSE[9:12] = -1.0


@dataclass
class EarthIekfConfig(InMotionConfig):
    """Defaults: the inverse-alignment paper's Table 1 IMU (0.002 deg/h, 20 ug; 0.0003 deg/sqrt(h), 20 ug/sqrt(Hz))."""

    gyro_arw_deg_sqrt_h: float = 0.0003
    acc_vrw_m_s_sqrt_h: float = ug_sqrt_hz_to_m_s_sqrt_h(20.0)
    init_sigma_roll_deg: float = 1.0
    init_sigma_pitch_deg: float = 1.0
    init_sigma_yaw_deg: float = 10.0
    init_sigma_v_m_s: float = 0.01
    init_sigma_p_m: float = 1.0
    #: initial 1-sigma gyro drift [deg/h] and accelerometer bias [mg] (P0 of the bias states; 0.020 mg = 20 ug)
    gyro_bias_deg_h: float = 0.002
    acc_bias_mg: float = 0.020
    #: initial 1-sigma of each lever-arm component [m] (eq. (47))
    init_sigma_lever_arm_m: float = 0.05
    #: zero-velocity observation: period [s] of the automatic update (0: only on update(ZeroVelocity)) and std [m/s]
    auto_zupt_period_s: float = 0.5
    auto_zupt_sigma_m_s: float = 0.001
    status_yaw_3sigma_deg: float = 0.05
    fading_nis_threshold: float = 0.0

    def validate(self) -> None:
        super().validate()
        for name in ("gyro_bias_deg_h", "acc_bias_mg", "init_sigma_lever_arm_m",
                     "auto_zupt_sigma_m_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")
        if not self.auto_zupt_period_s >= 0:
            raise ValueError(f"auto_zupt_period_s: must be >= 0 (0 = external updates only), got {self.auto_zupt_period_s}")


def bias_transitions(Phi_nav: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(N, 18, 18) per-step transitions: nav block Phi_nav, ``phi -= db_g dt``, ``nu -= db_a dt``,
    ``rho -= db_a dt^2/2`` (first order in dt, in the frame at the step end), constant biases and lever arm."""
    n = dt.shape[0]
    Phi = np.zeros((n, N_STATES, N_STATES))
    Phi[:, 0:9, 0:9] = Phi_nav
    idx = np.arange(9, N_STATES)
    Phi[:, idx, idx] = 1.0
    d = np.arange(3)
    Phi[:, d, 9 + d] = -dt[:, None]
    Phi[:, 3 + d, 12 + d] = -dt[:, None]
    Phi[:, 6 + d, 12 + d] = -0.5 * (dt * dt)[:, None]
    return Phi


def covariance_batch_diag(P: np.ndarray, Phi: np.ndarray, q6: np.ndarray) -> np.ndarray:
    """``P_N = Phi_N..Phi_1 P (..)^T + sum_k (Phi_N..Phi_{k+1}) Q_k (..)^T`` with Q_k diagonal and non-zero only on
    the first 6 states (``q6`` (N, 6)); batched matmuls (an einsum over 18x18 blocks costs ~10x more)."""
    U = prefix_products(Phi[::-1])  # U[j] = Phi_N ... Phi_{N-j}
    q_rev = q6[::-1]
    Qsum = np.zeros_like(P)
    Qsum[np.arange(6), np.arange(6)] = q_rev[0]
    if Phi.shape[0] > 1:
        T = U[:-1, :, 0:6]  # multiplies Q_{N-j-1}
        Qsum += np.matmul(T * q_rev[1:, None, :], np.transpose(T, (0, 2, 1))).sum(axis=0)
    Phi_tot = U[-1]
    P_new = Phi_tot @ P @ Phi_tot.T + Qsum
    return 0.5 * (P_new + P_new.T)


class EarthIekf(AlignmentCore):
    """Earth-frame left-invariant EKF with zero-velocity updates, 18 states (eq. (47)); supports backtracking."""

    name = "earth_iekf"
    config_class = EarthIekfConfig
    needs_motion = False
    convention = "earth_left"  # its zero-velocity model (filters/measurements.py)
    supports_backtracking = True
    att_index = (0, 1, 2)
    vel_index = (3, 4, 5)
    pos_index = (6, 7, 8)

    @property
    def schedules_own_zero_velocity(self) -> bool:  # its backward passes need the ZUPTs inside the passes
        return self.cfg.auto_zupt_period_s > 0
    state_names = ("phi_x", "phi_y", "phi_z", "nu_x", "nu_y", "nu_z", "rho_x", "rho_y", "rho_z",
                   "bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z", "L_x", "L_y", "L_z")

    def __init__(self, config: EarthIekfConfig | None = None):
        self.cfg = config if config is not None else EarthIekfConfig()
        self.cfg.validate()
        self.initial_sigmas = self.cfg.initial_sigmas
        self._init = False
        self.counters = {"imu": 0, "imu_rejected": 0, "zupt": 0, "backward": 0}
        self.last_reject_reason = ""
        self._q_gyro = deg_sqrt_h_to_rad_sqrt_s(self.cfg.gyro_arw_deg_sqrt_h) ** 2
        self._q_acc = m_s_sqrt_h_to_m_s_sqrt_s(self.cfg.acc_vrw_m_s_sqrt_h) ** 2
        self._q_acc_up = m_s_sqrt_h_to_m_s_sqrt_s(self.cfg.acc_vrw_up_m_s_sqrt_h) ** 2
        self._q_acc_b = np.full(3, self._q_acc)  # per body axis (left-invariant: body frame; base.accel_noise_b)

    @property
    def initialized(self) -> bool:
        return self._init

    # ------------------------------------------------------------------ life cycle
    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m) -> None:
        C_b_n = np.asarray(C_b_n, float)
        self._q_acc_b = accel_noise_b(C_b_n, self._q_acc, self._q_acc_up)
        C_n_e = earth.C_n_e(lat_rad, lon_rad)
        self.t_s = float(stamp_s)
        self.C = C_n_e @ C_b_n
        self.p = earth.geodetic_to_ecef(lat_rad, lon_rad, h_m)
        self.v = vbar_from_v_e(C_n_e @ np.asarray(v_n, float), self.p)
        self.b_g = np.zeros(3)
        self.b_a = np.zeros(3)
        self.L = np.zeros(3)
        self._w_last = np.zeros(3)
        # eq. (56): conventional ENU P0 -> left-invariant P0
        P0 = np.zeros((9, 9))
        P0[0:3, 0:3] = np.asarray(P_att_n, float)
        P0[3:6, 3:6] = sigma_v_m_s**2 * _I3
        P0[6:9, 6:9] = sigma_p_m**2 * _I3
        T = np.zeros((9, 9))
        Cnb = C_b_n.T
        T[0:3, 0:3] = Cnb
        T[3:6, 3:6] = Cnb
        T[3:6, 6:9] = self.C.T @ lie.hat3(OMEGA_IE_E) @ C_n_e
        T[6:9, 6:9] = Cnb
        P = np.zeros((N_STATES, N_STATES))
        P[0:9, 0:9] = T @ P0 @ T.T
        P[9:12, 9:12] = deg_h_to_rad_s(self.cfg.gyro_bias_deg_h) ** 2 * _I3
        P[12:15, 12:15] = ug_to_m_s2(1000.0 * self.cfg.acc_bias_mg) ** 2 * _I3
        P[15:18, 15:18] = self.cfg.init_sigma_lever_arm_m**2 * _I3
        self.P = P
        self._buf: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._dir = 0  # +1 forward, -1 backward (direction of the last sample)
        self._t_next_zupt = self.t_s + self.cfg.auto_zupt_period_s
        self._init = True

    # ------------------------------------------------------------------ propagation
    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        """IMU rows buffered, as one sample at a time would be: a batch ends at ``max_batch_samples``, at an automatic
        zero-velocity update and at a change of direction (``flush`` ends it by hand), so a block gives the numbers of
        its rows fed one by one. Forward: an unusable row sends the call through the per-sample step (which rejects
        and counts it). Backward (the backtracking passes, paper eqs. (6)-(10)): ``t_s`` are the times after each
        inverse step (decreasing), sample j covering ``(t_s[j], t_before]``; the covariance is propagated by time
        reversal and the automatic zero-velocity updates run at the same period as forward."""
        t_last = self._buf[-1][0] if self._buf else self.t_s
        if backward:
            t, w, f = (np.asarray(x, float) for x in (t_s, omega_ib_b, f_ib_b))
            n = t.shape[0] if t.ndim == 1 else 0
            ok = self._init and n and w.shape == (n, 3) and f.shape == (n, 3) and bool(
                np.all(np.isfinite(w)) and np.all(np.isfinite(f)) and np.all(np.diff(t, prepend=t_last) < 0))
            if not ok:
                if n:
                    self.counters["imu_rejected"] += n
                    self.last_reject_reason = "IMU: backward rows not finite or not decreasing from the core's time" \
                        if self._init else "IMU: not initialised"
                return
        else:
            arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, t_last) if self._init else None
            if arr is None:
                super()._propagate_arrays(t_s, omega_ib_b, f_ib_b)
                return
            t, w, f, _ = arr
        self._buffer(t, w, f, -1 if backward else 1, t_last)

    def _buffer(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, d: int, t_last: float) -> None:
        """Usable rows into the buffer in direction ``d`` (+1 forward, -1 backward) from ``t_last``."""
        n = t.shape[0]
        if self._dir == -d:
            self.flush()
        per, mb = self.cfg.auto_zupt_period_s, self.cfg.max_batch_samples
        if self._dir != d:
            self._t_next_zupt = t_last + d * per
        self._dir = d
        self.counters["backward" if d < 0 else "imu"] += n
        dt = d * t  # increasing in both directions: a zero-velocity update is due at dt >= d t_next - 1e-9
        i = 0
        while i < n:
            j = min(n, i + max(mb - len(self._buf), 1))
            k = i + int(np.searchsorted(dt[i:j], d * self._t_next_zupt - 1e-9, side="left")) if per > 0 else j
            if k < j:
                j = k + 1
            self._buf.extend((float(t[m]), w[m], f[m]) for m in range(i, j))
            if k < j:
                self.flush()
                self._zupt(self.cfg.auto_zupt_sigma_m_s)
                self._t_next_zupt = float(t[k]) + d * per
            elif len(self._buf) >= mb:
                self.flush()
            i = j

    def _propagate_sample(self, imu: ImuSample) -> None:
        if not self._init:
            self._reject("not initialised")
            return
        reason = check_imu(imu)
        t_last = self._buf[-1][0] if self._buf else self.t_s
        if not reason and not imu.stamp_s > t_last:
            reason = f"stamp {imu.stamp_s:.6f} not after {t_last:.6f}"
        if reason:
            self._reject(reason)
            return
        self._buffer(np.array([float(imu.stamp_s)]), np.asarray(imu.omega_ib_b, float)[None],
                     np.asarray(imu.f_ib_b, float)[None], 1, t_last)

    def _reject(self, reason: str) -> None:
        self.counters["imu_rejected"] += 1
        self.last_reject_reason = f"IMU: {reason}"

    def flush(self) -> None:
        """Propagate the buffered samples (forward or backward) in one vectorised batch."""
        if not self._buf:
            return
        t = np.array([b[0] for b in self._buf])
        w = np.array([b[1] for b in self._buf])
        f = np.array([b[2] for b in self._buf])
        self._buf = []
        self._flush_arrays(t, w, f, self._dir)

    def _flush_arrays(self, t, w, f, direction: int) -> None:
        """One batch: ``t`` are the times after each step (increasing forward, decreasing backward)."""
        w = w - self.b_g
        f = f - self.b_a
        if direction > 0:
            dt = np.diff(t, prepend=self.t_s)
            C, v, p, self.P = self._batch(self.C, self.v, self.p, w, f, dt, self.P)
            R = lie.so3_exp(-OMEGA_IE_E * (t[-1] - self.t_s))
            self.C, self.v, self.p = R @ C, R @ v, R @ p
        else:
            # time reversal: state (C, -v, p), inputs (-w, f), error D xi; the Earth frame is frozen at the
            # current (later) time, so the reversed ECEF is recovered by exp(+omega_ie (t_cur - t_prev))
            dt = -np.diff(t, prepend=self.t_s)
            Pr = self.P * np.outer(D_REVERSE, D_REVERSE)
            C, vr, p, Pr = self._batch(self.C, -self.v, self.p, -w, f, dt, Pr)
            self.P = Pr * np.outer(D_REVERSE, D_REVERSE)
            R = lie.so3_exp(OMEGA_IE_E * (self.t_s - t[-1]))
            self.C, self.v, self.p = R @ C, -(R @ vr), R @ p
        self.C = Rotation.from_matrix(self.C).as_matrix()
        self._w_last = w[-1]
        self.t_s = float(t[-1])

    def _batch(self, C, v, p, w, f, dt, P):
        dC, dv_b, dp_b, _, C1, v1, p1 = eci_steps(C, v, p, w, f, dt)
        Phi = bias_transitions(liekf_transition_batch(dC, dv_b, dp_b, dt), dt)
        q = np.zeros((dt.shape[0], 6))
        q[:, 0:3] = self._q_gyro * dt[:, None]
        q[:, 3:6] = self._q_acc_b * dt[:, None]
        return C1, v1, p1, covariance_batch_diag(P, Phi, q)

    # ------------------------------------------------------------------ zero-velocity update
    def zupt_model(self):
        """(z, H) of eqs. (50)-(55) transformed by C^T (eq. (54)); see the module docstring for the signs."""
        Ct = self.C.T
        v_e = v_e_from_vbar(self.v, self.p)
        z = Ct @ v_e - np.cross(self._w_last, self.L)
        H = np.zeros((3, N_STATES))
        H[:, 3:6] = -_I3
        H[:, 6:9] = Ct @ lie.hat3(OMEGA_IE_E) @ self.C
        H[:, 15:18] = lie.hat3(self._w_last)
        return z, H

    def _zupt(self, sigma_v_m_s: float) -> UpdateResult:
        """The automatic zero-velocity update inside propagation (no flush: the passes need it where it falls)."""
        z, H = self.zupt_model()
        N = sigma_v_m_s**2 * _I3
        K, P_new, S = joseph_update(self.P, H, N)
        self.P = P_new
        self._inject(K @ z)
        self.counters["zupt"] += 1
        return UpdateResult(True, z, S, float(z @ np.linalg.solve(S, z)), "")

    def _inject(self, dx: np.ndarray) -> None:
        """Retraction X_hat exp(dxi) and the additive biases and lever arm."""
        X = lie.se23_from(self.C, self.v, self.p) @ lie.se23_exp(dx[0:9])
        C, v, p = lie.se23_parts(X)
        self.C, self.v, self.p = C.copy(), v.copy(), p.copy()
        self.b_g = self.b_g + dx[9:12]
        self.b_a = self.b_a + dx[12:15]
        self.L = self.L + dx[15:18]

    # ------------------------------------------------------------------ output
    def estimate(self) -> AlignmentEstimate:
        if not self._init:
            raise RuntimeError("estimate() before initialize()")
        self.flush()
        lat, lon, h = earth.ecef_to_geodetic(self.p)
        C_e_n = earth.C_e_n(lat, lon)
        C_b_n = C_e_n @ self.C
        P_att = C_b_n @ self.P[0:3, 0:3] @ C_b_n.T
        P_att = 0.5 * (P_att + P_att.T)
        sig3 = 3.0 * math.degrees(math.sqrt(max(P_att[2, 2], 0.0)))
        status = AlignmentStatus.ALIGNED if sig3 < self.cfg.status_yaw_3sigma_deg else AlignmentStatus.CONVERGING
        return AlignmentEstimate(
            stamp_s=self.t_s, C_b_n=C_b_n, v_n=C_e_n @ v_e_from_vbar(self.v, self.p), lat_rad=lat, lon_rad=lon,
            h_m=h, P_att_n=P_att, P=self.P.copy(), state_names=self.state_names, bias_gyro_b=self.b_g.copy(),
            bias_acc_b=self.b_a.copy(), status=status, reason=f"3-sigma yaw {sig3:.4f} deg",
        )
