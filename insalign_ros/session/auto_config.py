"""``core: auto``'s parameters (session/auto.py): the IMU grade's noise and bias fields shared by its static and
in-motion cores, the motion detector's, the hand-over's and the stops'; the level and azimuth floors of the grade."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from ..core import earth
from ..filters import imu_grade, registry
from ..filters.config import ConfigDict, param

D2R = math.pi / 180.0


@dataclass
class AutoConfig(ConfigDict):
    """Parameters of ``core: auto``. The IMU grade (bias 1-sigmas, noise densities) sets the static core's
    tuning, the physical floors in the status and the motion detector's thresholds."""

    #: zero-velocity core for the parked states (pkf, ekf10, ...) and the in-motion core for driving. pkf: its biases
    #: are consider parameters, so its level covariance stays at the b_acc/g floor when the heading is unobservable;
    #: ekf10 estimates the body-frame accelerometer bias and, with a large bias prior (unknown_mems: 5 mg) and the
    #: azimuth error state wandering, reported the level 0.6-1.3 deg off at a 0.12-deg 3-sigma (docs/session.md)
    static_core: str = param("pkf", 'zero-velocity core while parked (honest level covariance with an unknown heading)')
    motion_core: str = param(
        "iekf",
        'in-motion core after the hand-over (a bank of unknown_heading_hypotheses when the heading is '
        'not trusted)')
    #: IMU grade (the session fills these from ``imu_grade``, filters/imu_grade.py; defaults: industrial_mems):
    #: gyro and accelerometer bias 1-sigma, angle and velocity random walks, bias random walks
    gyro_bias_deg_h: float = 10.0
    acc_bias_mg: float = 1.0
    gyro_arw_deg_sqrt_h: float = 0.4
    acc_vrw_m_s_sqrt_h: float = 0.1
    acc_vrw_up_m_s_sqrt_h: float = 0.0
    gyro_bias_rw_deg_h_sqrt_h: float = 10.0
    acc_bias_rw_mg_sqrt_h: float = 0.03
    #: in-motion core: floor of the fix sigma [m] (its ``gnss_sigma_floor_m``; e.g. 1 m for KITTI's RT3003, which
    #: reports centimetres)
    gnss_sigma_floor_m: float = param(0.0, 'in-motion core: floor of the fix sigma [m]')
    #: in-motion core: GNSS antenna position in the body frame FLU relative to the IMU [m] (its ``gnss_lever_arm_b_m``)
    gnss_lever_arm_b_m: list = param(
        [0.0, 0.0, 0.0],
        'in-motion core: GNSS antenna in the body frame FLU relative to the IMU [m]')
    #: gyrocompassing is trusted for the heading only where the azimuth floor eps/(omega_ie cos lat) is below this
    heading_floor_max_deg: float = param(
        1.0,
        "gyrocompassing gives the heading only where the grade's azimuth floor is below this [deg]",
        range=(0.0, 360.0))
    #: ... and the static yaw 1-sigma at the hand-over below this (else the yaw bank is used)
    heading_trust_sigma_deg: float = param(
        10.0,
        '... and the static yaw 1-sigma at the hand-over below this [deg]',
        range=(0.0, 360.0))
    #: yaw hypotheses of the in-motion bank when the heading is not trusted
    unknown_heading_hypotheses: int = param(
        8,
        'yaw hypotheses of the in-motion bank when the heading is not trusted',
        range=(2, 36))  # the session's (catalog.SHARED_WITH_CORES)
    #: the static snapshot the in-motion core starts from is at least this long before the motion onset [s]
    handover_margin_s: float = param(
        0.3,
        'the static snapshot the in-motion core starts from is this long before the motion onset [s]')
    #: the in-motion core starts from the gyro bias measured at rest (:func:`gyro_bias_from_rest`) when the rest
    #: window before the hand-over is at least this long [s]; else from the grade's bias prior. Four 1-s blocks: a
    #: car parked for seconds starts with its bias known to ~ARW/sqrt(4 s) instead of the grade's turn-on bias (360
    #: deg/h for unknown_mems, which tilts the level by 0.1 deg/s); below SHORT_REST_BLOCKS the variance is at least
    #: the grade's white noise (the spread of a few blocks is not a variance)
    gyro_rest_min_s: float = param(
        4.0,
        'the in-motion core starts from the gyro bias measured at rest when the rest window is this long '
        '[s]')
    #: zero-velocity constraint of the in-motion core at stops: position hold 1-sigma [m] and rate [Hz]
    stop_hold_sigma_m: float = param(0.05, 'stops: position hold 1-sigma [m]')
    stop_hold_rate_hz: float = param(10.0, 'stops: position hold rate [Hz]')
    #: stops: zero-angular-rate updates from 1-s gyro means once this many blocks of the stop are in (their spread
    #: is the update's noise); 0 turns them off
    stop_zero_rate_min_blocks: int = param(
        5,
        'stops: zero-angular-rate updates from this many 1-s gyro means on (0: off)',
        range=(0, 10000))
    #: ... only when the in-motion core's own horizontal speed agrees: below this [m/s] (the IMU-only detector can
    #: take a smooth constant acceleration for rest: a position hold while driving would wreck the attitude)
    stop_speed_max_m_s: float = param(
        0.5,
        "a stop is declared only when the in-motion core's speed is below this [m/s]")

    def validate(self) -> None:
        self.check_field_types(non_negative=True)
        values = self.to_dict()
        for name in ("static_core", "motion_core"):
            v = values[name]
            if v == "auto" or v not in registry.CORES:
                raise ValueError(f"{name}: unknown core {v!r}; choose one of {sorted(set(registry.CORES) - {'auto'})}")
        if self.stop_zero_rate_min_blocks in (1, 2):
            raise ValueError("stop_zero_rate_min_blocks: 0 (off) or >= 3 (the spread needs blocks), got "
                             f"{self.stop_zero_rate_min_blocks}")
        if not 2 <= self.unknown_heading_hypotheses <= 36:
            raise ValueError(f"unknown_heading_hypotheses: must be in [2, 36], got {self.unknown_heading_hypotheses}")
        for name in ("heading_floor_max_deg", "heading_trust_sigma_deg", "stop_hold_sigma_m", "stop_hold_rate_hz",
                     "stop_speed_max_m_s"):
            if not values[name] > 0:
                raise ValueError(f"{name}: must be > 0, got {values[name]}")

    def grade_params(self, core: str) -> dict:
        """The parameters of ``core`` (the static or the in-motion one) that the IMU grade sets (only the fields its
        config has): noise, bias priors, bias random walks, consider floors."""
        values = self.to_dict()
        grade = {k: values[k] for k in imu_grade.GRADE_FIELDS}  # the same names in every core config
        grade["gnss_sigma_floor_m"] = self.gnss_sigma_floor_m
        known = {f.name for f in fields(registry.CORES[core][1])}
        if any(self.gnss_lever_arm_b_m):
            grade["gnss_lever_arm_b_m"] = list(self.gnss_lever_arm_b_m)
        return {k: v for k, v in grade.items() if k in known}

    def static_params(self) -> dict:
        return self.grade_params(self.static_core)

    @property
    def initial_sigmas(self) -> tuple:
        """The static core's (``AlignmentCore.initial_sigmas``): ``auto`` starts static."""
        return registry.make_config(self.static_core, self.static_params()).initial_sigmas

    def level_floor_rad(self) -> float:
        """Level floor b_acc/g [rad] (imu_grade.level_floor_rad)."""
        return imu_grade.level_floor_rad(self.acc_bias_mg)

    def azimuth_floor_rad(self, lat_rad: float) -> float:
        """Gyrocompassing floor eps/(omega_ie cos lat) [rad] (inf at the poles)."""
        c = math.cos(lat_rad) * earth.OMEGA_IE_RAD_S
        return math.inf if c <= 1e-12 else self.gyro_bias_deg_h * D2R / 3600.0 / c
