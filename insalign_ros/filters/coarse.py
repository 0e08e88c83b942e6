"""Analytic coarse alignment on a static base (gravity + Earth rate).

Two methods (config ``method``):

- ``inertial`` (default): inertial-frame alignment, immune to angular vibration (engine, sway). The gyros track the
  body's rotation relative to its own attitude at the start in inertial space, ``C_b0_b(t)`` (exact SO(3) steps);
  the specific force integrated in that frozen frame, ``v_b0(t) = int C_b0_b f_b dt``, must equal the integrated
  gravity reaction in the frozen start-ENU frame, known in closed form for a body at rest on the rotating Earth,
  ``v_i0(t) = g [z sin(Wt)/W + (a x z)(1 - cos Wt)/W + a (a.z)(t - sin(Wt)/W)]`` with ``a`` the Earth axis in ENU
  ``[0, cos L, sin L]``, ``z`` = Up. ``C_i0_b0`` is the Wahba solution over the pairs stored every 0.1 s, centred
  (``scipy Rotation.align_vectors``); the attitude now is ``C_b_n(t) = R(a, Wt)^T C_i0_b0 C_b0_b(t)``, of which the
  heading is used; roll and pitch come from the window-mean specific force (floor b_acc/g), because ``C_b0_b``
  carries the gyro bias times the window into the level (0.1 deg after 100 s of a 5 deg/h gyro). A sway of the
  body is in ``C_b0_b`` and cancels; the averaging method below sees its net rotation over the window as a rate
  error (0.05 deg of azimuth on the navigation-grade static scenario, docs/static_alignment.md).
- ``average``: TRIAD on averaged IMU outputs. Averages f_ib_b and omega_ib_b over the window; in ENU the reference vectors are f_n = [0, 0, g] and
omega_ie_n = [0, W cos(lat), W sin(lat)]. Body axes of Up, East, North:
``u_b = f/|f|``, ``e_b = (omega x f)/|omega x f|``, ``n_b = u_b x e_b`` -> ``C_b_n = [e_b n_b u_b]^T``.

Covariance (first order, docs/static_alignment.md "Honest coarse covariance"): the datasheet terms (white noise
over the window and the bias floor) plus the disturbance the window itself shows. A parked car rocks (wind, people,
suspension) and vibrates; the integral of the disturbance is bounded (an angle for the rates, a velocity for the
specific force), and it is measured from the data: the gyro-tracked rotation ``C_b0_b`` sampled every 0.1 s, and the
frozen-frame velocity's residual from the closed-form gravity integral, each detrended by a quadratic (Earth rate,
biases), give the rocking angle spread ``S_theta`` and the velocity spread ``sigma_v`` with its autocovariance. Propagated through the equations:

- level (both methods, from the window-mean specific force): ``(VRW^2/T + b_acc^2 + 2 sigma_v^2/T^2)/g^2`` plus the
  larger rocking angle spread of East/North on both (the attitude now differs from the window mean by the rocking);
- azimuth, ``average``: the window-mean horizontal rate is wrong by the rocking's net rotation ``(theta(T) -
  theta(0))/T``, variance ``2 S_int,E / T^2`` (integrated rate): ``(ARW^2/T + b_gyro^2 + 2 S_int,E/T^2)/(W cos lat)^2`` plus
  ``tan^2(lat)`` times the mean-f level term (the tilt enters ``omega x f``) plus the yaw rocking spread;
- azimuth, ``inertial``: the Wahba rotation's linearised covariance, ``H = sum_j [v_j x]^T [v_j x]`` over the
  pairs with the measured velocity autocovariance (Bartlett, to 10 s: the disturbance) plus the exact random-walk term
  (``VRW^2 min(t_j, t_k)``), plus the ARW and gyro-bias terms above.

When the azimuth sigma exceeds ``max_azimuth_sigma_deg`` the core cannot give a heading: status WAITING_FOR_DATA
(noise or the measured disturbance still averaging down; the reason says which) or FAULT (the bias alone is too
large), with the reason; the yaw is then the initial guess with its own sigma, never a confident wrong number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scipy.spatial.transform import Rotation

from ..core import earth, lie
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, ImuSample
from .static_model import DEG_H, MG, StaticConfig, usable_step
from .config import param

NO_HEADING = "gyro noise/bias too large for Earth rate at this latitude: cannot give heading"
#: added to the reason when the measured disturbance, not the datasheet noise, dominates the horizontal-rate error
DISTURBED = "measured rocking/vibration"
#: spacing of the disturbance samples (rotation and velocity) [s]: resolves rocking up to a few Hz
BLOCK_S = 0.1
#: the disturbance autocovariance is summed up to this lag [s] (Bartlett taper: resolves 0.1 Hz, so a 0.5 Hz rocking
#: cancels itself as it does in the fit), and to at most a fifth of the window
MAX_LAG_S = 10.0


@dataclass
class CoarseConfig(StaticConfig):
    """Coarse alignment: averaging window and the sensor errors that set its covariance (ADIS16488A defaults)."""

    min_window_s: float = 10.0
    #: beyond this azimuth 1-sigma the core reports no heading [deg]
    max_azimuth_sigma_deg: float = param(30.0, range=(0.0, 360.0))
    #: "inertial" (vibration-immune, default) or "average" (TRIAD on averaged outputs); see the module docstring
    method: str = param("inertial", 'inertial (vibration-immune heading) or average (TRIAD on means)')

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


def detrend(t_s: np.ndarray, x: np.ndarray, degree: int = 2) -> np.ndarray:
    """Residuals of a per-column least-squares polynomial in (scaled) time: the disturbance left after the slow model
    terms (Earth rate, biases, the second order of their composition)."""
    t = np.asarray(t_s, float)
    s = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
    V = np.vander(s, degree + 1)
    coef, *_ = np.linalg.lstsq(V, x, rcond=None)
    return x - V @ coef


def autocovariance_at_lags(res: np.ndarray, step: int, n_lags: int) -> np.ndarray:
    """(n_lags + 1,) autocovariance of zero-mean residual columns at lags 0, step, 2 step, ... samples, averaged over
    the columns (biased estimator: divided by the number of samples, so the tapered Toeplitz form stays PSD)."""
    x = np.asarray(res, float)
    n = x.shape[0]
    return np.array([float(np.sum(x[: n - l * step] * x[l * step:])) / (n * x.shape[1])
                     for l in range(n_lags + 1)])


def wahba_covariance_rad2(v_i0: np.ndarray, t_s: np.ndarray, gamma_m2_s2: np.ndarray,
                          vrw_m_s_sqrt_s: float) -> np.ndarray:
    """(3, 3) covariance [rad^2] (i0 frame) of the Wahba rotation fitted to the centred pairs ``v_i0[j]`` (model
    vectors at times ``t_s[j]``, about uniformly spaced) when the measured vectors carry (a) a stationary disturbance
    with per-axis autocovariance ``gamma[l]`` at lag l pairs (l = 0..M) and (b) a velocity random walk of density VRW.
    Linearisation: ``dphi = H^-1 sum_j A_j^T u_j``, ``A_j = [v_j x]``, ``H = sum_j A_j^T A_j = sum_j (|v_j|^2 I -
    v_j v_j^T)``; (a) ``H^-1 (sum_l w_l gamma_l sum_j (A_j^T A_{j+l} + T)) H^-1`` with the Bartlett taper w_l (Newey-
    West: PSD; an oscillation's negative lags cancel its positive ones, as they do in the fit), (b) ``q^2 H^-1 (sum_i
    dt_i [S_i x]^T [S_i x]) H^-1`` with ``S_i`` the suffix sums of ``v_j`` (``q^2 min(t_j, t_k)`` summed in O(n))."""
    v = np.asarray(v_i0, float)
    eye = np.eye(3)

    def cross_sum(a, b):  # sum_j [a_j x]^T [b_j x] = sum_j (a_j . b_j) I - b_j a_j^T
        return float(np.sum(a * b)) * eye - b.T @ a

    H = cross_sum(v, v)
    Hi = np.linalg.inv(H)
    M = len(gamma_m2_s2) - 1
    Q = gamma_m2_s2[0] * H
    for l in range(1, min(M, len(v) - 1) + 1):
        C = cross_sum(v[:-l], v[l:])
        Q = Q + (1.0 - l / (M + 1.0)) * gamma_m2_s2[l] * (C + C.T)
    S = np.cumsum(v[::-1], axis=0)[::-1]
    dt = np.diff(np.concatenate([[0.0], np.asarray(t_s, float)]))
    R = float(np.sum(dt * np.einsum("ia,ia->i", S, S))) * eye - (S * dt[:, None]).T @ S
    return Hi @ Q @ Hi + vrw_m_s_sqrt_s**2 * Hi @ R @ Hi


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
        self.initial_sigmas = cfg.initial_sigmas
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
        # samples every BLOCK_S: time, rotation vector of C_b0_b, frozen-frame velocity v_b0 (the Wahba pairs and the
        # disturbance)
        self._blk_t: list[float] = []
        self._blk_r: list[np.ndarray] = []
        self._blk_v: list[np.ndarray] = []
        self._blk_w: list[np.ndarray] = []  # integral of the measured rate (the averaging method's numerator) [rad]
        self._wahba_at = None  # (T_s, fit) of the last inertial-frame fit
        self._init = True

    @property
    def initialized(self) -> bool:
        return self._init

    def _propagate_sample(self, imu: ImuSample) -> None:
        dt = usable_step(self, imu)
        if dt is None:
            return
        f = np.asarray(imu.f_ib_b, float)
        w = np.asarray(imu.omega_ib_b, float)
        self.sum_f += f * dt
        self.sum_w += w * dt
        dC = lie.so3_exp(w * dt)  # Rodrigues in numpy: scipy's Rotation costs ~10x more per sample
        # the sample is the mean over the step: rotate f by the half step (midpoint) into the start frame
        self.v_b0 += self.C_b0_b @ (lie.so3_exp(0.5 * w * dt) @ f) * dt
        self.C_b0_b = self.C_b0_b @ dC
        self.T_s += dt
        self.t_s = float(imu.stamp_s)
        if not self._blk_t or self.T_s - self._blk_t[-1] >= BLOCK_S - 1e-9:
            self._blk_t.append(self.T_s)
            self._blk_r.append(Rotation.from_matrix(self.C_b0_b).as_rotvec())
            self._blk_v.append(self.v_b0.copy())
            self._blk_w.append(self.sum_w.copy())

    def _wahba(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R_i0_b0 (3, 3), pair times [s], model vectors v_i0 of the pairs [m/s]) of the inertial-frame fit."""
        if self._wahba_at is not None and self._wahba_at[0] == self.T_s:
            return self._wahba_at[1]
        g = earth.normal_gravity(self.lat_rad, self.h_m)
        t = np.array(self._blk_t + [self.T_s])
        v_i0 = gravity_reaction_integral_i0(t, self.lat_rad, g)
        v_b0 = np.array(self._blk_v + [self.v_b0])
        # centred (Kabsch with translation): v_b0 starts at 0 while the IMU's own velocity at the start of the window
        # (a rocking car's lever arm: ~1 cm/s) is unknown; uncentred, that constant offset turned the heading by
        # 6 deg at 60 s on a rocking car (simulated, 0.2 deg at 0.5-2 Hz, 0.5 m above the rocking centre)
        v_i0 = v_i0 - v_i0.mean(axis=0)
        R_i0_b0, _ = Rotation.align_vectors(v_i0, v_b0 - v_b0.mean(axis=0))  # maps b0 coordinates to i0 coordinates
        self._wahba_at = (self.T_s, (R_i0_b0.as_matrix(), t, v_i0))
        return self._wahba_at[1]

    def _C_i0_n(self) -> np.ndarray:
        """Start-ENU frozen in inertial space -> ENU now: the Earth's rotation over the window about its axis."""
        a = np.array([0.0, math.cos(self.lat_rad), math.sin(self.lat_rad)])
        return Rotation.from_rotvec(a * earth.OMEGA_IE_RAD_S * self.T_s).as_matrix()

    def _attitude(self) -> np.ndarray:
        """C_b_n now (body FLU -> ENU) by the configured method."""
        if self.cfg.method == "average" or len(self._blk_t) < 3:
            return coarse_align(self.sum_f / self.T_s, self.sum_w / self.T_s)
        R_i0_b0, _, _ = self._wahba()
        C = self._C_i0_n().T @ R_i0_b0 @ self.C_b0_b  # body now -> ENU now
        # level from the window-mean specific force (its floor is b_acc/g; the gyro-tracked C_b0_b carries the gyro
        # bias times the window into roll/pitch: 0.1 deg after 100 s of a 5 deg/h MEMS gyro); heading from above
        rp = earth.rpy_from_C_b_n(coarse_align(self.sum_f / self.T_s, self.sum_w / self.T_s))
        return earth.C_b_n_from_rpy(rp[0], rp[1], earth.rpy_from_C_b_n(C)[2])

    def disturbance(self, C_b_n: np.ndarray) -> dict:
        """The disturbance the window shows (module docstring), beyond the slow model terms:
        'S_theta_n' (3, 3) [rad^2] covariance of the rocking angle in ENU (gyro-tracked rotation, quadratic detrend),
        'S_int_rate_n' the same of the integrated measured rate (rotation + coning),
        'sigma_v_m_s' [m/s] rms horizontal frozen-frame velocity residual from the gravity integral (quadratic
        detrend), 'gamma_v_m2_s2' its autocovariance at lags of 0..M samples (M: MAX_LAG_S, <= a fifth of them).
        Zeros while fewer than 8 samples."""
        out = {"S_theta_n": np.zeros((3, 3)), "S_int_rate_n": np.zeros((3, 3)), "sigma_v_m_s": 0.0, "gamma_v_m2_s2": np.zeros(1)}
        if len(self._blk_t) < 8 or len(self._blk_t) < 3:
            return out
        t = np.array(self._blk_t)
        r = detrend(t, np.array(self._blk_r))
        out["S_theta_n"] = C_b_n @ (r.T @ r / len(t)) @ C_b_n.T
        # the integrated rate differs from the rotation by the coning of the rocking (not a rotation, but in the mean)
        w = detrend(t, np.array(self._blk_w))
        out["S_int_rate_n"] = C_b_n @ (w.T @ w / len(t)) @ C_b_n.T
        R_i0_b0, _, _ = self._wahba()
        g = earth.normal_gravity(self.lat_rad, self.h_m)
        res = np.array(self._blk_v) @ R_i0_b0.T - gravity_reaction_integral_i0(t, self.lat_rad, g)
        res_h = detrend(t, res[:, :2])  # start-East, start-North; the quadratic takes the offset, tilt and heading
        out["sigma_v_m_s"] = float(np.sqrt(np.mean(res_h**2)))
        dt = float(np.median(np.diff(t)))
        out["gamma_v_m2_s2"] = autocovariance_at_lags(res_h, 1, max(1, min(int(round(MAX_LAG_S / dt)), len(t) // 5)))
        return out

    def covariance(self, C_b_n: np.ndarray) -> tuple[np.ndarray, dict]:
        """(P_att_n (3, 3) [rad^2] diagonal, parts) of the estimate C_b_n: datasheet noise + biases + the measured
        disturbance, propagated through the method's equations (module docstring). parts: the 1-sigma terms [rad] and
        the horizontal-rate sigmas [rad/s] for the reason."""
        cfg = self.cfg
        T = max(self.T_s, 1e-9)
        g = earth.normal_gravity(self.lat_rad, self.h_m)
        q_a = cfg.acc_vrw_m_s_sqrt_h / 60.0
        q_g = cfg.gyro_arw_deg_sqrt_h * math.pi / 180.0 / 60.0
        b_a, b_g = cfg.acc_bias_mg * MG, cfg.gyro_bias_deg_h * DEG_H
        w_h = max(earth.OMEGA_IE_RAD_S * math.cos(self.lat_rad), 1e-12)
        d = self.disturbance(C_b_n)
        S = d["S_theta_n"]
        mean_f_var = (q_a**2 / T + b_a**2 + 2.0 * d["sigma_v_m_s"] ** 2 / T**2) / g**2  # tilt of the mean f
        # isotropic: the East/North split of S rides on the estimated heading, which may be the initial guess
        lvl = np.full(2, mean_f_var + max(S[0, 0], S[1, 1]))
        rate_sheet = q_g**2 / T + b_g**2  # [rad^2/s^2] of the horizontal rate (datasheet)
        if self.cfg.method == "average" or len(self._blk_t) < 3:
            rate_dist = 2.0 * d["S_int_rate_n"][0, 0] / T**2  # net rocking rotation over the window, about East
            az_var = (rate_sheet + rate_dist) / w_h**2 + math.tan(self.lat_rad) ** 2 * mean_f_var + S[2, 2]
        else:
            R_i0_b0, t, v_i0 = self._wahba()
            P_phi = wahba_covariance_rad2(v_i0, t, d["gamma_v_m2_s2"], q_a)
            m = self._C_i0_n()[:, 2]  # Up now, in i0
            wahba_var = float(m @ P_phi @ m)
            rate_dist = wahba_var * w_h**2  # the same, as an equivalent horizontal-rate error
            az_var = rate_sheet / w_h**2 + wahba_var
        parts = {"rate_sheet_rad_s": math.sqrt(rate_sheet), "rate_dist_rad_s": math.sqrt(rate_dist),
                 "sigma_v_m_s": d["sigma_v_m_s"], "rock_level_rad": float(np.sqrt(max(S[0, 0], S[1, 1]))),
                 "w_h_rad_s": w_h}
        return np.diag([lvl[0], lvl[1], az_var]), parts

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
        P, parts = self.covariance(C)
        az = math.sqrt(P[2, 2])
        P[2, 2] = min(az, math.pi) ** 2
        status, reason = AlignmentStatus.ALIGNED, "coarse alignment from %.1f s of data" % self.T_s
        lim = self.cfg.max_azimuth_sigma_deg * math.pi / 180.0
        if az > lim:
            w_h = parts["w_h_rad_s"]
            bias_only = self.cfg.gyro_bias_deg_h * DEG_H / w_h
            status = AlignmentStatus.FAULT if bias_only > lim else AlignmentStatus.WAITING_FOR_DATA
            reason = NO_HEADING + " (azimuth 1-sigma %.1f deg > %.1f deg)" % (math.degrees(az),
                                                                             self.cfg.max_azimuth_sigma_deg)
            if parts["rate_dist_rad_s"] > parts["rate_sheet_rad_s"]:
                reason += ("; %s: %.3g deg/h of horizontal-rate error against %.3g deg/h of horizontal Earth rate, "
                           "averaging down with the window" % (DISTURBED, parts["rate_dist_rad_s"] / DEG_H,
                                                               w_h / DEG_H))
            # level only: keep the initial guess's yaw, levelled by the measured gravity
            yaw0 = earth.rpy_from_C_b_n(self.C_b_n0)[2]
            rpy = earth.rpy_from_C_b_n(C)
            C = earth.C_b_n_from_rpy(rpy[0], rpy[1], yaw0)
            P[2, 2] = self.P0[2, 2]
        return AlignmentEstimate(self.t_s, C, np.zeros(3), self.lat_rad, self.lon_rad, self.h_m, P, P, names,
                                 status=status, reason=reason)
