"""Data types shared by the simulators, the bag contract and the alignment runners. No ROS import.

Sample timing: arrays are aligned, index k is time ``t_s[k]``. IMU sample k holds the average rate and
specific force over ``(t_{k-1}, t_k]`` (core/mechanization.py); sample 0 covers the interval before the
first truth epoch, so a core initialised at ``t_s[0]`` propagates with samples 1..N-1.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from ..core.types import GnssFix, GnssVelocity, ImuSample


@dataclass(frozen=True)
class ImuSpec:
    """IMU error specification in datasheet units (converted in sim/error_model.py, one place).

    gyro_bias_deg_h: 1-sigma constant-in-run gyro bias [deg/h]; arw_deg_sqrt_h: angle random walk [deg/sqrt(h)];
    acc_bias_mg: 1-sigma constant-in-run accelerometer bias [mg]; vrw_m_s_sqrt_h: velocity random walk
    [m/s/sqrt(h)]; rate_hz: sample rate [Hz].
    """

    name: str
    gyro_bias_deg_h: float
    arw_deg_sqrt_h: float
    acc_bias_mg: float
    vrw_m_s_sqrt_h: float
    rate_hz: float


@dataclass
class ScenarioData:
    """A generated (or converted) run: measured IMU, GNSS fixes and the truth, on aligned time arrays."""

    name: str
    seed: int
    t0_s: float  # ECI epoch: ECI == ECEF at this time (= t_s[0])
    t_s: np.ndarray  # (N,) IMU/truth stamps [s]
    omega_ib_b: np.ndarray  # (N, 3) measured angular rate [rad/s]
    f_ib_b: np.ndarray  # (N, 3) measured specific force [m/s^2]
    # truth at t_s (None when unknown, e.g. a user's bag without ground truth)
    C_b_n: np.ndarray | None  # (N, 3, 3) body FLU -> ENU
    lat_rad: np.ndarray | None  # (N,)
    lon_rad: np.ndarray | None
    h_m: np.ndarray | None
    v_n: np.ndarray | None  # (N, 3) ENU velocity relative to Earth [m/s]
    gnss_t_s: np.ndarray  # (M,)
    gnss_p_e: np.ndarray  # (M, 3) ECEF [m]
    gnss_R_e: np.ndarray  # (M, 3, 3) ECEF covariance [m^2]
    imu_spec: ImuSpec | None = None
    gnss_sigma_m: float = float("nan")
    bias_gyro_b: np.ndarray | None = None  # drawn constant biases [rad/s]
    bias_acc_b: np.ndarray | None = None  # [m/s^2]
    omega_ib_b_true: np.ndarray | None = None  # error-free IMU (simulators only)
    f_ib_b_true: np.ndarray | None = None
    params: dict = field(default_factory=dict)  # scenario parameters, for metadata and docs
    # per-sample validity where the source has one (io/kitti.py fill rows, the bag's *_invalid topics): False =
    # the source flags the sample as not measured (to be treated as a gap); None = every sample valid
    imu_valid: np.ndarray | None = None  # (N,) bool
    gnss_valid: np.ndarray | None = None  # (M,) bool
    # GNSS velocity where the source has it: the antenna's velocity relative to Earth in ENU [m/s], its ENU
    # covariance [m^2/s^2], at its own stamps (None: no velocity)
    gnss_vel_t_s: np.ndarray | None = None  # (K,)
    gnss_vel_n: np.ndarray | None = None  # (K, 3)
    gnss_vel_R_n: np.ndarray | None = None  # (K, 3, 3)
    # wheel speed along the vehicle's x axis [m/s] and its variance [m^2/s^2]; dual-antenna GNSS heading: the
    # baseline's ENU yaw [rad] and its variance [rad^2] (None: the source has none)
    wheel_t_s: np.ndarray | None = None  # (W,)
    wheel_speed_m_s: np.ndarray | None = None  # (W,)
    wheel_var_m2_s2: np.ndarray | None = None  # (W,)
    heading_t_s: np.ndarray | None = None  # (H,)
    heading_yaw_rad: np.ndarray | None = None  # (H,)
    heading_var_rad2: np.ndarray | None = None  # (H,)

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def has_truth(self) -> bool:
        return self.C_b_n is not None

    @property
    def imu_valid_mask(self) -> np.ndarray:
        """(N,) bool: ``imu_valid``, or all True when the source has no per-sample validity."""
        return np.ones(self.n, bool) if self.imu_valid is None else np.asarray(self.imu_valid, bool)

    @property
    def gnss_valid_mask(self) -> np.ndarray:
        """(M,) bool: ``gnss_valid``, or all True."""
        m = self.gnss_t_s.shape[0]
        return np.ones(m, bool) if self.gnss_valid is None else np.asarray(self.gnss_valid, bool)

    def until(self, t_end_s: float) -> "ScenarioData":
        """A copy holding the IMU samples (with truth and validity) and the fixes with stamps <= t_end_s [s]."""
        from dataclasses import replace

        k = int(np.searchsorted(self.t_s, t_end_s, side="right"))
        j = int(np.searchsorted(self.gnss_t_s, t_end_s, side="right"))
        per_imu = ("omega_ib_b", "f_ib_b", "C_b_n", "lat_rad", "lon_rad", "h_m", "v_n", "omega_ib_b_true",
                   "f_ib_b_true", "imu_valid")
        cut = {name: None if getattr(self, name) is None else getattr(self, name)[:k] for name in per_imu}
        cut.update({name: None if getattr(self, name) is None else getattr(self, name)[:j]
                    for name in ("gnss_p_e", "gnss_R_e", "gnss_valid")})
        if self.gnss_vel_t_s is not None:
            m = int(np.searchsorted(self.gnss_vel_t_s, t_end_s, side="right"))
            cut.update({name: getattr(self, name)[:m] for name in ("gnss_vel_t_s", "gnss_vel_n", "gnss_vel_R_n")})
        return replace(self, t_s=self.t_s[:k], gnss_t_s=self.gnss_t_s[:j], **cut)

    @property
    def has_gnss_velocity(self) -> bool:
        return self.gnss_vel_t_s is not None and self.gnss_vel_t_s.shape[0] > 0

    def gnss_velocities(self) -> Iterator[GnssVelocity]:
        if self.gnss_vel_t_s is None:
            return
        for j in range(self.gnss_vel_t_s.shape[0]):
            yield GnssVelocity(float(self.gnss_vel_t_s[j]), self.gnss_vel_n[j], self.gnss_vel_R_n[j])

    def gnss_fixes(self) -> Iterator[GnssFix]:
        for j in range(self.gnss_t_s.shape[0]):
            yield GnssFix(float(self.gnss_t_s[j]), self.gnss_p_e[j], self.gnss_R_e[j])

    def events(self, start: int = 0, stop: int | None = None) -> Iterator[ImuSample | GnssFix]:
        """IMU samples and GNSS fixes merged in time order (a fix at the same stamp comes after the IMU)."""
        stop = self.n if stop is None else stop
        t_end = self.t_s[stop - 1]
        j = int(np.searchsorted(self.gnss_t_s, self.t_s[start], side="left"))
        for k in range(start, stop):
            yield ImuSample(float(self.t_s[k]), self.omega_ib_b[k], self.f_ib_b[k])
            while j < self.gnss_t_s.shape[0] and self.gnss_t_s[j] <= self.t_s[k] and self.gnss_t_s[j] <= t_end:
                yield GnssFix(float(self.gnss_t_s[j]), self.gnss_p_e[j], self.gnss_R_e[j])
                j += 1
