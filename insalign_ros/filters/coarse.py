"""Analytic coarse alignment on a static base (gravity + Earth rate).

Two methods (config ``method``):

- ``inertial`` (default): inertial-frame alignment, immune to angular vibration (engine, sway). The gyros track the
  body's rotation relative to its own attitude at the start in inertial space, ``C_b0_b(t)`` (exact SO(3) steps);
  the specific force integrated in that frozen frame, ``v_b0(t) = int C_b0_b f_b dt``, must equal the integrated
  gravity reaction in the frozen start-ENU frame, known in closed form for a body at rest on the rotating Earth,
  ``v_i0(t) = g [z sin(Wt)/W + (a x z)(1 - cos Wt)/W + a (a.z)(t - sin(Wt)/W)]`` with ``a`` the Earth axis in ENU
  ``[0, cos L, sin L]``, ``z`` = Up. ``C_i0_b0`` is the Wahba solution over the pairs stored every second
  (``scipy Rotation.align_vectors``); the attitude now is ``C_b_n(t) = R(a, Wt)^T C_i0_b0 C_b0_b(t)``, of which the
  heading is used; roll and pitch come from the window-mean specific force (floor b_acc/g), because ``C_b0_b``
  carries the gyro bias times the window into the level (0.1 deg after 100 s of a 5 deg/h gyro). A sway of the
  body is in ``C_b0_b`` and cancels; the averaging method below sees its net rotation over the window as a rate
  error (0.05 deg of azimuth on the navigation-grade static scenario, docs/static_alignment.md).
- ``average``: TRIAD on averaged IMU outputs. Averages f_ib_b and omega_ib_b over the window; in ENU the reference vectors are f_n = [0, 0, g] and
omega_ie_n = [0, W cos(lat), W sin(lat)]. Body axes of Up, East, North:
``u_b = f/|f|``, ``e_b = (omega x f)/|omega x f|``, ``n_b = u_b x e_b`` -> ``C_b_n = [e_b n_b u_b]^T``.

Covariance (first order): level 1-sigma = sqrt(sigma_f^2 + b_acc^2)/g per axis with sigma_f = VRW/sqrt(T); azimuth
1-sigma = sqrt(sigma_w^2 + b_gyro^2)/(W cos(lat)) with sigma_w = ARW/sqrt(T) (the horizontal Earth rate is the
heading reference; the same physical floor as every static core). When that azimuth sigma exceeds
``max_azimuth_sigma_deg`` the core cannot give a heading: status WAITING_FOR_DATA (noise still averaging down) or
FAULT (the bias alone is too large), with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from ..core import earth
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, ImuSample
from .static_model import DEG_H, MG, StaticConfig, usable_step

NO_HEADING = "gyro noise/bias too large for Earth rate at this latitude: cannot give heading"


@dataclass
class CoarseConfig(StaticConfig):
    """Coarse alignment: averaging window and the sensor errors that set its covariance (ADIS16488A defaults)."""

    min_window_s: float = 10.0
    gyro_bias_deg_h: float = 5.1
    acc_bias_mg: float = 0.07
    #: beyond this azimuth 1-sigma the core reports no heading [deg]
    max_azimuth_sigma_deg: float = 30.0
    #: "inertial" (vibration-immune, default) or "average" (TRIAD on averaged outputs); see the module docstring
    method: str = "inertial"

    def validate(self) -> None:
        super().validate()
        if self.method not in ("inertial", "average"):
            raise ValueError(f"method: must be 'inertial' or 'average', got {self.method!r}")


def gravity_reaction_integral_i0(t_s: np.ndarray, lat_rad: float, g: float) -> np.ndarray:
    """(n, 3) int_0^t of the specific force of a body at rest, in the start-ENU frame frozen in inertial space [m/s]."""
    W = earth.OMEGA_IE_RAD_S
    a = np.array([0.0, math.cos(lat_rad), math.sin(lat_rad)])
    z = np.array([0.0, 0.0, 1.0])
    t = np.asarray(t_s, float)[:, None]
    s, c = np.sin(W * t), np.cos(W * t)
    return g * (z * s / W + np.cross(a, z) * (1.0 - c) / W + a * (a @ z) * (t - s / W))


def coarse_align(f_mean_b: np.ndarray, omega_mean_b: np.ndarray) -> np.ndarray:
    """C_b_n (body FLU -> ENU) from mean specific force [m/s^2] and mean angular rate [rad/s] at rest."""
    u = f_mean_b / np.linalg.norm(f_mean_b)
    e = np.cross(omega_mean_b, f_mean_b)
    e = e / np.linalg.norm(e)
    n = np.cross(u, e)
    return np.vstack([e, n, u])


class CoarseAlignment(AlignmentCore):
    """Averaging coarse alignment as a core (no zero-velocity update needed: it uses the averages)."""

    name = "coarse"

    def __init__(self, cfg: CoarseConfig):
        self.cfg = cfg
        self._init = False

    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m):
        self.lat_rad, self.lon_rad, self.h_m = float(lat_rad), float(lon_rad), float(h_m)
        self.C_b_n0 = np.array(C_b_n, dtype=float)
        self.P0 = np.array(P_att_n, dtype=float)
        self.t0_s = self.t_s = float(stamp_s)
        self.sum_f = np.zeros(3)
        self.sum_w = np.zeros(3)
        self.T_s = 0.0
        self.C_b0_b = np.eye(3)  # body now -> body at the start, frozen in inertial space
        self.v_b0 = np.zeros(3)
        self._pairs_t: list[float] = []
        self._pairs_v: list[np.ndarray] = []
        self._init = True

    @property
    def initialized(self) -> bool:
        return self._init

    def propagate(self, imu: ImuSample) -> None:
        dt = usable_step(self, imu)
        if dt is None:
            return
        f = np.asarray(imu.f_ib_b, float)
        w = np.asarray(imu.omega_ib_b, float)
        self.sum_f += f * dt
        self.sum_w += w * dt
        dC = Rotation.from_rotvec(w * dt).as_matrix()
        # the sample is the mean over the step: rotate f by the half step (midpoint) into the start frame
        self.v_b0 += self.C_b0_b @ (Rotation.from_rotvec(0.5 * w * dt).as_matrix() @ f) * dt
        self.C_b0_b = self.C_b0_b @ dC
        self.T_s += dt
        self.t_s = float(imu.stamp_s)
        if not self._pairs_t or self.T_s - self._pairs_t[-1] >= 1.0:
            self._pairs_t.append(self.T_s)
            self._pairs_v.append(self.v_b0.copy())

    def _attitude(self) -> np.ndarray:
        """C_b_n now (body FLU -> ENU) by the configured method."""
        if self.cfg.method == "average" or len(self._pairs_t) < 3:
            return coarse_align(self.sum_f / self.T_s, self.sum_w / self.T_s)
        g = earth.normal_gravity(self.lat_rad, self.h_m)
        t = np.array(self._pairs_t + [self.T_s])
        v_i0 = gravity_reaction_integral_i0(t, self.lat_rad, g)
        v_b0 = np.array(self._pairs_v + [self.v_b0])
        R_i0_b0, _ = Rotation.align_vectors(v_i0, v_b0)  # maps b0 coordinates to i0 coordinates
        a = np.array([0.0, math.cos(self.lat_rad), math.sin(self.lat_rad)])
        C_i0_n = Rotation.from_rotvec(a * earth.OMEGA_IE_RAD_S * self.T_s).as_matrix()
        C = C_i0_n.T @ R_i0_b0.as_matrix() @ self.C_b0_b  # body now -> ENU now
        # level from the window-mean specific force (its floor is b_acc/g; the gyro-tracked C_b0_b carries the gyro
        # bias times the window into roll/pitch: 0.1 deg after 100 s of a 5 deg/h MEMS gyro); heading from above
        rp = earth.rpy_from_C_b_n(coarse_align(self.sum_f / self.T_s, self.sum_w / self.T_s))
        return earth.C_b_n_from_rpy(rp[0], rp[1], earth.rpy_from_C_b_n(C)[2])

    def sigmas_rad(self) -> tuple[float, float]:
        """(level, azimuth) 1-sigma [rad] of the current window."""
        T = max(self.T_s, 1e-9)
        g = earth.normal_gravity(self.lat_rad, self.h_m)
        sf = self.cfg.acc_vrw_m_s_sqrt_h / 60.0 / math.sqrt(T)
        sw = self.cfg.gyro_arw_deg_sqrt_h * math.pi / 180.0 / 60.0 / math.sqrt(T)
        level = math.hypot(sf, self.cfg.acc_bias_mg * MG) / g
        w_h = earth.OMEGA_IE_RAD_S * math.cos(self.lat_rad)
        az = math.hypot(sw, self.cfg.gyro_bias_deg_h * DEG_H) / max(w_h, 1e-12)
        return level, az

    def estimate(self) -> AlignmentEstimate:
        names = ("psiE", "psiN", "psiU")
        if not self._init or self.T_s < self.cfg.min_window_s:
            P = self.P0 if self._init else np.eye(3) * math.pi**2
            C = self.C_b_n0 if self._init else np.eye(3)
            return AlignmentEstimate(self.t_s if self._init else float("nan"), C, np.zeros(3),
                                     getattr(self, "lat_rad", float("nan")), getattr(self, "lon_rad", float("nan")),
                                     getattr(self, "h_m", float("nan")), P, P, names,
                                     status=AlignmentStatus.WAITING_FOR_DATA,
                                     reason=f"averaging: {self.T_s:.1f} of {self.cfg.min_window_s} s")
        C = self._attitude()
        level, az = self.sigmas_rad()
        P = np.diag([level**2, level**2, min(az, math.pi) ** 2])
        status, reason = AlignmentStatus.ALIGNED, "coarse alignment from %.1f s of data" % self.T_s
        lim = self.cfg.max_azimuth_sigma_deg * math.pi / 180.0
        if az > lim:
            w_h = earth.OMEGA_IE_RAD_S * math.cos(self.lat_rad)
            bias_only = self.cfg.gyro_bias_deg_h * DEG_H / max(w_h, 1e-12)
            status = AlignmentStatus.FAULT if bias_only > lim else AlignmentStatus.WAITING_FOR_DATA
            reason = NO_HEADING + " (azimuth 1-sigma %.1f deg > %.1f deg)" % (math.degrees(az),
                                                                             self.cfg.max_azimuth_sigma_deg)
            # level only: keep the initial guess's yaw, levelled by the measured gravity
            C0 = self.C_b_n0
            yaw0 = earth.rpy_from_C_b_n(C0)[2]
            rpy = earth.rpy_from_C_b_n(C)
            C = earth.C_b_n_from_rpy(rpy[0], rpy[1], yaw0)
            P[2, 2] = self.P0[2, 2]
        return AlignmentEstimate(self.t_s, C, np.zeros(3), self.lat_rad, self.lon_rad, self.h_m, P, P, names,
                                 status=status, reason=reason)
