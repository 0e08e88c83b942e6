"""Session configuration: one dataclass, units in the names, validated once (ValueError with the field and reason).

The node declares these as ROS parameters (``config/alignment_node.yaml``), ``insalign-align`` and
:func:`insalign_ros.align` take them as keyword arguments. docs/session.md explains each choice.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from ..filters.config import check_ranges, param
from ..filters.imu_grade import DEFAULT_IMU_GRADE, GRADES

NAN3 = [float("nan")] * 3


@dataclass
class SessionConfig:
    """What the session does around the core: initialisation, time-line hygiene, schedule, outputs."""

    #: alignment core (filters/registry.py). Default ``auto`` (session/auto.py): static while parked, the in-motion
    #: iekf (a yaw bank when the heading is unknown) once it moves, whatever the vehicle does at start-up
    core: str = param(
        "auto",
        'alignment core (filters/registry.py): auto (default: static while parked, in-motion iekf once it '
        'moves; session/auto.py) or one core; read-only after start',
        read_only=True)
    #: IMU noise model (filters/imu_grade.py, docs/imu_grades.md): the core's process noise and bias priors come from
    #: this preset; an explicit core parameter overrides it. Default: a conservative prior for an unknown MEMS IMU
    imu_grade: str = param(
        DEFAULT_IMU_GRADE,
        f"IMU noise model, one of {', '.join(GRADES)} (docs/imu_grades.md): the defaults of the core's noise and "
        "bias parameters; an explicit core parameter overrides it. Read-only after start",
        read_only=True)
    #: initial state: "sensors" (no guess needed: position and velocity from the first fixes, roll and pitch from
    #: the accelerometers, heading unknown -> a bank of ``unknown_heading_hypotheses`` yaw hypotheses), "guess"
    #: (``initial_rpy_deg``, ``initial_velocity_enu_m_s``) or "truth" (a ground-truth pose at an IMU stamp plus
    #: ``init_rpy_error_deg``: simulations and tests)
    init_mode: str = param(
        "sensors",
        'sensors (no guess: position/velocity from the fixes, level from the accelerometers, unknown heading '
        '-> yaw bank), guess (initial_rpy_deg) or truth (ground_truth/pose; init_from_ground_truth)')
    #: the platform (car | wheeled_robot | boat | aircraft | unknown): what the yaw from GNSS velocity may assume
    #: (session/yaw_seed.py): cars and wheeled robots drive along their x axis up to a side-slip; the default
    #: ``unknown`` assumes nothing about the motion (safe for every platform)
    vehicle: str = param(
        "unknown",
        'car | wheeled_robot | boat | aircraft | unknown (safe for every platform): what the yaw from GNSS velocity '
        'may assume (cars and wheeled robots drive along their x axis)')
    #: wheel speed (``vehicle`` car | wheeled_robot): prior 1-sigma of the odometry's scale factor (a fraction; the
    #: prior mean is 1), estimated against the GNSS fixes while they come (session/wheel_scale.py)
    wheel_scale_sigma: float = param(
        0.05,
        'wheel speed (vehicle car | wheeled_robot): prior 1-sigma of the odometry scale factor (0.05: 5 %), '
        'estimated against the GNSS fixes. Read-only after start', range=(1e-4, 0.5), read_only=True)
    #: dual-antenna GNSS heading: yaw of the antenna baseline (primary -> secondary) in the body frame FLU [deg]
    gnss_heading_baseline_yaw_deg: float = param(
        0.0,
        'dual-antenna GNSS heading: yaw of the antenna baseline (primary -> secondary antenna) in the body frame, '
        'counter-clockwise from x [deg] (0: along x; 90: along y, an athwartships baseline)', range=(-180.0, 180.0))
    #: sensors: accelerometer averaging window for roll and pitch before the initialisation stamp [s]
    init_level_window_s: float = param(
        1.0,
        'sensors: accelerometer averaging window for roll and pitch [s]', range=(0.01, 600.0))
    #: sensors: yaw hypotheses of the bank when the heading is unknown (GNSS cores whose yaw_hypotheses is 1)
    unknown_heading_hypotheses: int = param(
        8,
        'sensors: yaw hypotheses when the heading is unknown (GNSS cores)', range=(1, 36))
    #: sensors: vehicle acceleration assumed when the fixes cannot tell it (velocity and level sigmas) [m/s^2]
    init_accel_m_s2: float = param(
        1.0,
        'sensors: vehicle acceleration assumed when the fixes cannot tell it [m/s^2]', range=(0.0, 100.0))
    #: initial attitude guess roll, pitch, yaw [deg] (yaw from East, counter-clockwise)
    initial_rpy_deg: list = param(
        [0.0, 0.0, 0.0],
        'initial attitude guess roll, pitch, yaw [deg] (yaw from East, CCW)')
    #: initial velocity guess, ENU [m/s]
    initial_velocity_enu_m_s: list = param([0.0, 0.0, 0.0], 'initial velocity guess, ENU [m/s]')
    #: Euler error added to the truth in init_mode "truth" [deg]
    init_rpy_error_deg: list = param(
        [0.0, 0.0, 0.0],
        'Euler error added to the truth when init_from_ground_truth [deg]')
    #: initial roll, pitch, yaw 1-sigma [deg]; NaN: the core's own defaults (AlignmentCore.initial_sigmas)
    init_sigma_rpy_deg: list = param(
        NAN3,
        "initial roll, pitch, yaw 1-sigma [deg] (NaN: the core's own defaults)")
    #: static cores: lat [deg], lon [deg], h [m] of the site (NaN: wait for a GNSS fix)
    static_position_deg_m: list = param(
        NAN3,
        'static cores: lat [deg], lon [deg], h [m] (NaN: wait for a fix)')
    #: plausibility bounds of an IMU sample (io/validation.py)
    max_rate_rad_s: float = param(
        34.9,
        'reject Imu with |angular_velocity| above this [rad/s] (2000 deg/s)', range=(0.1, 1000.0))
    max_acc_m_s2: float = param(
        490.0,
        'reject Imu with |linear_acceleration| above this [m/s^2] (50 g)', range=(1.0, 10000.0))
    #: an IMU stamp more than this away from the newest one is a suspect time jump [s]
    max_gap_s: float = param(
        2.0,
        'an Imu stamp more than this from the newest one is a suspect time jump [s]', range=(0.05, 3600.0))
    #: consecutive self-consistent samples that confirm a time jump (then the session resets)
    time_jump_confirm: int = param(
        5,
        'consecutive self-consistent samples that confirm a time jump (then reset)', range=(1, 1000))
    #: an IMU interval longer than this factor times the median interval is a gap (counted, covariance inflated)
    gap_factor: float = param(
        1.5,
        'an Imu interval longer than this times the median interval is a gap', range=(1.1, 100.0))
    #: fixes up to this far behind the newest IMU sample are fused at their own stamp: the filter runs this far
    #: behind the newest IMU sample (fusion delay) [s data time]
    max_fix_lag_s: float = param(
        0.5,
        'fixes up to this late are fused at their stamp: the filter runs this far behind the IMU [s]',
        range=(0.0, 10.0))
    #: a fix ahead of the newest IMU sample by more than this is rejected [s]; nearer ones wait in the buffer
    max_fix_ahead_s: float = param(
        10.0,
        'a fix ahead of the IMU by more than this is rejected [s]', range=(0.0, 3600.0))
    #: estimate output period [s data time] (0: every IMU sample)
    output_period_s: float = param(0.1, 'estimate output period [s data time] (0: every IMU sample)',
                                   range=(0.0, 3600.0), node=False)  # the node: pose_rate_hz
    #: zero-velocity updates for static cores [Hz data time] and their 1-sigma [m/s]
    zupt_rate_hz: float = param(10.0, 'zero-velocity update rate for static cores [Hz data time]', range=(0.0, 1000.0))
    zupt_sigma_m_s: float = param(0.01, 'zero-velocity update 1-sigma [m/s]', range=(1e-06, 10.0))
    #: watchdog: no IMU sample pushed for this long [s wall time] drops the flag (0: off)
    imu_timeout_s: float = param(
        1.0,
        'watchdog: no valid Imu for this long [s wall] drops the flag (0: off)', range=(0.0, 3600.0))
    #: warn when no fix was accepted for this long [s data time] (GNSS cores)
    gnss_timeout_s: float = param(
        5.0,
        'warn in /diagnostics when no fix was accepted for this long [s data time]', range=(0.0, 3600.0))
    #: no input for this long [s wall time]: process the buffered tail (the fusion delay holds otherwise)
    idle_drain_s: float = param(0.5, 'no input for this long [s wall]: process the buffered tail', range=(0.01, 3600.0))
    #: outlier gate: a fix whose NIS exceeds this is rejected without touching the core, once the core claims to
    #: know its attitude (3-sigma within twice the flag's bounds); 0: off. 100 is p < 1e-20 for a consistent filter
    #: (chi-square, 3 dof) and rejects a fix 200 m off at a 1-m sigma
    gnss_gate_nis: float = param(
        100.0,
        'outlier gate: a fix with NIS above this is rejected without touching the filter once it claims its '
        'attitude (0: off)',
        range=(0.0, 1000000000000.0))
    #: that many consecutive gated fixes: the filter is lost (or the GNSS is): FAULT and re-initialisation (sooner
    #: while the NIS CUSUM is armed: gated fixes feed it from the second of a run on, capped at the gate)
    gnss_gate_max_consecutive: int = param(
        5,
        'that many consecutive gated fixes: the filter (or the GNSS) is lost -> hold or FAULT and '
        're-initialise',
        range=(1, 1000))
    # -- divergence guard (issue 15; docs/session.md "Outliers and divergence") --
    #: a fix off the straight-line extrapolation of the two fixes before it by more than this acceleration allows
    #: (plus 5 sigma of the fix noise) is a GNSS jump [m/s^2]; gated fixes that start with a jump are bad fixes,
    #: not a lost filter: the session holds the filter (IMU only, flag down) instead of re-initialising. A GNSS
    #: velocity off the one before it (or the fixes' velocity) beyond it is NIS-gated before the attitude is claimed
    gnss_jump_accel_m_s2: float = param(
        10.0,
        'a fix off the extrapolation of the two before it beyond this acceleration (+5 sigma) is a GNSS '
        'jump: hold, not re-initialise; a GNSS velocity beyond it is gated even before the claim [m/s^2]',
        range=(0.0, 1000.0))
    #: the longest such hold [s data time]: fixes that still disagree with the held filter after it are believed
    #: (divergence, re-initialisation from the new fixes); also the window after a re-initialisation in which a GNSS
    #: jump before the new filter claims its attitude restarts it from the fixes after the jump
    gnss_hold_max_s: float = param(
        30.0,
        'the longest hold on the IMU after a GNSS jump before the new fixes are believed [s data time]',
        range=(0.0, 3600.0))
    #: ... or sooner, when the held filter drifts away from fixes consistent with each other: |innovation| changed by
    #: more than this since the hold began without a jump [m] (a filter that absorbed a slowly walking bias)
    gnss_hold_drift_m: float = param(
        20.0,
        'a held filter whose innovation changes by more than this without a jump is re-initialised [m]',
        range=(0.0, 1000000.0))
    #: windowed NIS test of every filter (claimed or not): the mean NIS of the last ``divergence_nis_window``
    #: fused fixes above ``divergence_nis_mean`` (chi-square(3) mean: 3) is a divergence; window 0: off. 1000
    #: (innovations ~30 sigma for 10 s): measured at most 446 while a core converges from 179 deg and 1e3-1e10 for
    #: one that has lost its attitude (docs/session.md)
    divergence_nis_window: int = param(10, 'divergence guard: fixes in the windowed NIS test (0: off)', range=(0, 1000))
    divergence_nis_mean: float = param(
        1000.0,
        'divergence guard: mean NIS over the window above this is a divergence (FAULT, re-initialisation)',
        range=(0.0, 1000000000000000.0))
    #: attitude-covariance sanity: roll or pitch 3-sigma above this is a divergence (up is not known any more; the
    #: initialisation from sensors on a rolling ship starts near 45 deg) [deg]; P not symmetric positive definite
    #: or not finite is one too
    divergence_level_3sigma_deg: float = param(
        90.0,
        'divergence guard: roll or pitch 3-sigma above this is a divergence [deg]', range=(0.0, 360.0))
    #: sequential test (CUSUM of the log-likelihood ratio) on the NIS of the fixes fused while the attitude 3-sigma is
    #: within ``divergence_cusum_arm_factor`` times the aligned flag's bounds (small angles): H0 NIS ~ chi-square(3), H1 NIS ~ ``divergence_cusum_ratio`` x chi-square(3) (a filter whose
    #: covariance is that many times too small: the quiet EKF failure from a large yaw error). Above
    #: ``divergence_cusum_llr`` -> divergence (0: off); above ``divergence_cusum_flag_llr`` the flag drops (the first
    #: inconsistent innovation). Log-likelihood units (a consistent filter: false alarm after ~exp(llr) fixes)
    divergence_cusum_ratio: float = param(
        4.0,
        'divergence guard: CUSUM alternative, a covariance this many times too small', range=(1.0, 1000000.0))
    divergence_cusum_arm_factor: float = param(
        4.0,
        "divergence guard: the CUSUM runs while the attitude 3-sigma is within this times the flag's bounds",
        range=(0.0, 1000000.0))
    divergence_cusum_llr: float = param(
        40.0,
        'divergence guard: CUSUM log-likelihood ratio above this is a divergence (0: off)', range=(0.0, 1000000.0))
    divergence_cusum_flag_llr: float = param(
        8.0,
        'divergence guard: CUSUM above this drops the aligned flag (0: off)', range=(0.0, 1000000.0))
    # -- end divergence guard --
    #: an IMU sample off both of its neighbours by more than this (and 20 times the recent spread) is a
    #: spike: dropped (a gap, bridged); 0: off [rad/s, m/s^2]
    imu_spike_rad_s: float = param(
        3.0,
        'an Imu rate off both neighbours by more than this (and 20x the recent spread) is a spike: dropped, '
        'bridged as a gap (0: off) [rad/s]',
        range=(0.0, 1000.0))
    imu_spike_m_s2: float = param(30.0, 'the same for the specific force [m/s^2]', range=(0.0, 10000.0))
    #: backtracking passes over the stored window (filters/backtrack.py; 0: off) and its options
    backtrack_passes: int = param(
        0,
        'backtracking passes over the stored window (filters/backtrack.py; 0: off)', range=(0, 10))
    backtrack_window_s: float = param(
        60.0,
        'backtracking: stored alignment window after initialisation [s data time]', range=(0.0, 3600.0))
    backtrack_covariance: str = param(
        "reset",
        "backtracking: 'reset' (honest sigma) or 'reuse' (the paper's, optimistic)")
    #: wall time per process() call spent on backtracking passes [s] (inf offline: run them at once)
    backtrack_budget_s: float = param(
        0.02,
        'backtracking: wall time per processing tick spent on the passes [s]', range=(0.0, math.inf))

    @classmethod
    def from_dict(cls, params: dict | None = None) -> "SessionConfig":
        params = dict(params or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(params) - known)
        if unknown:
            raise ValueError(f"unknown session parameter(s) {unknown}; known: {sorted(known)}")
        cfg = cls(**params)
        cfg.validate()
        return cfg

    def to_dict(self) -> dict:
        return asdict(self)

    def validate(self) -> None:
        """Raise ValueError naming the field when a value would disable or break the session."""
        from ..filters import registry

        if self.core not in registry.CORES:
            raise ValueError(f"core: unknown core {self.core!r}; choose one of {sorted(registry.core_names())}")
        from ..filters.imu_grade import get_grade

        get_grade(self.imu_grade)  # ValueError "imu_grade: unknown IMU grade ..."
        if self.init_mode not in ("sensors", "guess", "truth"):
            raise ValueError(f"init_mode: must be 'sensors', 'guess' or 'truth', got {self.init_mode!r}")
        if self.vehicle not in ("car", "wheeled_robot", "boat", "aircraft", "unknown"):
            raise ValueError(f"vehicle: must be 'car', 'wheeled_robot', 'boat', 'aircraft' or 'unknown', got "
                             f"{self.vehicle!r}")
        if not (isinstance(self.unknown_heading_hypotheses, int) and 1 <= self.unknown_heading_hypotheses <= 36):
            raise ValueError(f"unknown_heading_hypotheses: must be an integer in [1, 36], got "
                             f"{self.unknown_heading_hypotheses!r}")
        values = self.to_dict()
        for name in ("initial_rpy_deg", "initial_velocity_enu_m_s", "init_rpy_error_deg"):
            v = list(values[name])
            if len(v) != 3 or not all(_is_num(x) and math.isfinite(x) for x in v):
                raise ValueError(f"{name}: need 3 finite numbers, got {v}")
            setattr(self, name, [float(x) for x in v])
        for name in ("init_sigma_rpy_deg", "static_position_deg_m"):
            v = list(values[name])
            if len(v) != 3 or not all(_is_num(x) for x in v):
                raise ValueError(f"{name}: need 3 numbers (NaN = unset), got {v}")
            setattr(self, name, [float(x) for x in v])
        if any(math.isfinite(x) and not x > 0 for x in self.init_sigma_rpy_deg):
            raise ValueError(f"init_sigma_rpy_deg: must be > 0 (or NaN), got {self.init_sigma_rpy_deg}")
        positive = ("init_level_window_s", "init_accel_m_s2", "max_rate_rad_s", "max_acc_m_s2", "max_gap_s", "gap_factor", "max_fix_ahead_s",
                    "zupt_sigma_m_s", "gnss_timeout_s", "backtrack_window_s", "backtrack_budget_s", "idle_drain_s")
        for name in positive:
            v = values[name]
            if not (_is_num(v) and v > 0) or (math.isinf(v) and name != "backtrack_budget_s"):
                raise ValueError(f"{name}: must be a finite number > 0, got {v!r}")
        if not (isinstance(self.gnss_gate_max_consecutive, int) and 1 <= self.gnss_gate_max_consecutive <= 1000):
            raise ValueError(f"gnss_gate_max_consecutive: must be an integer in [1, 1000], got "
                             f"{self.gnss_gate_max_consecutive!r}")
        # -- divergence guard --
        if not (isinstance(self.divergence_nis_window, int) and 0 <= self.divergence_nis_window <= 1000):
            raise ValueError(f"divergence_nis_window: must be an integer in [0, 1000], got "
                             f"{self.divergence_nis_window!r}")
        for name, lo in (("gnss_jump_accel_m_s2", 0.0), ("gnss_hold_max_s", 0.0), ("gnss_hold_drift_m", 0.0), ("divergence_nis_mean", 10.0),
                         ("divergence_level_3sigma_deg", 5.0), ("divergence_cusum_ratio", 1.5),
                         ("divergence_cusum_arm_factor", 0.0)):
            v = values[name]
            if not (_is_num(v) and math.isfinite(v) and v > lo):
                raise ValueError(f"{name}: must be a finite number > {lo:g}, got {v!r}")
        for name in ("divergence_cusum_llr", "divergence_cusum_flag_llr"):  # 0: off
            v = values[name]
            if not (_is_num(v) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: must be a finite number >= 0 (0: off), got {v!r}")
        # -- end divergence guard --
        if 0 < self.gnss_gate_nis < 16.3:  # chi-square(3) at p = 1e-3: a tighter gate rejects good fixes
            raise ValueError(f"gnss_gate_nis: {self.gnss_gate_nis} would reject good fixes (0 = off, or >= 16.3)")
        for name in ("max_fix_lag_s", "output_period_s", "zupt_rate_hz", "imu_timeout_s", "gnss_gate_nis",
                     "imu_spike_rad_s", "imu_spike_m_s2"):
            v = values[name]
            if not (_is_num(v) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: must be a finite number >= 0, got {v!r}")
        # values that would silently disable the pipeline are refused with the reason
        if self.max_gap_s < 0.05:
            raise ValueError(f"max_gap_s: {self.max_gap_s} s would make every IMU interval a time jump "
                             "(must be >= 0.05 s, well above the IMU period)")
        if self.gap_factor < 1.1:
            raise ValueError(f"gap_factor: {self.gap_factor} would count ordinary stamp jitter as gaps (>= 1.1)")
        if self.max_fix_lag_s > 10.0:
            raise ValueError(f"max_fix_lag_s: {self.max_fix_lag_s} s delays every output that long (<= 10 s)")
        if not (isinstance(self.time_jump_confirm, int) and 1 <= self.time_jump_confirm <= 1000):
            raise ValueError(f"time_jump_confirm: must be an integer in [1, 1000], got {self.time_jump_confirm!r}")
        if not (isinstance(self.backtrack_passes, int) and 0 <= self.backtrack_passes <= 10):
            raise ValueError(f"backtrack_passes: must be an integer in [0, 10], got {self.backtrack_passes!r}")
        if self.backtrack_covariance not in ("reset", "reuse"):
            raise ValueError(f"backtrack_covariance: must be 'reset' or 'reuse', got {self.backtrack_covariance!r}")
        check_ranges(self)  # every other bound: the field's metadata (the node's descriptors show the same range)


@dataclass
class NodeConfig:
    """alignment_node's own parameters (the ROS adapter: frames, QoS, rates, logging); the offline tools have no
    equivalent. Declared with these descriptions, ranges and read-only flags (session/catalog.py)."""

    init_from_ground_truth: bool = param(
        False,
        'initialise from ground_truth/pose plus init_rpy_error_deg (tests, demos; overrides init_mode)')
    pose_rate_hz: float = param(
        10.0,
        '~/pose, ~/euler_error and aligned-flag evaluation rate [Hz data time] (0: every Imu)',
        range=(0.0, 1000.0))
    use_imu_covariance: bool = param(False, 'take gyro ARW / accel VRW from the Imu message covariances')
    gnss_sigma_m: float = param(
        1.0,
        'GNSS 1-sigma per axis [m] when NavSatFix gives no covariance',
        range=(0.001, 10000.0))
    imu_axes: str = param(
        'flu',
        'axes of the Imu rates and accelerations: flu (x forward, y left, z up; REP 103) or frd (x forward, '
        'y right, z down)',
        read_only=True)
    imu_mount_rpy_deg: list = param(
        [0.0, 0.0, 0.0],
        "roll, pitch, yaw [deg] of the IMU's FLU axes (after imu_axes) in the vehicle FLU frame, C = Rz(yaw) "
        'Ry(pitch) Rx(roll) as a URDF joint base_link -> imu_link; rates and specific forces are rotated '
        'into the vehicle frame',
        read_only=True)
    body_frame_id: str = param('base_link', 'frame_id of ~/imu: the vehicle FLU frame whose orientation is estimated')
    imu_frame_id: str = param(
        '',
        "required Imu frame_id ('' accepts any: drivers use imu, imu_link, gnss_link, ...; the frames seen "
        'are logged)')
    gnss_frame_id: str = param('', "required NavSatFix frame_id ('' accepts any)")
    world_frame: str = param(
        'map',
        'frame_id of ~/pose and ~/datum and the parent of the TF (REP 105): the local ENU frame anchored at '
        'the initial position')
    publish_tf: bool = param(
        False,
        'broadcast world_frame -> tf_child_frame on /tf (aligned attitude and ENU position) while aligned')
    tf_child_frame: str = param('base_link', 'child frame of the TF broadcast (the vehicle FLU frame)')
    publish_imu_before_aligned: bool = param(
        False,
        "publish ~/imu before the aligned flag rises (risk: robot_localization's navsat_transform latches "
        'the heading of the first ~/imu it receives)')
    hardware_id: str = param('', "/diagnostics hardware_id ('': the frame_id of the Imu messages)")
    diagnostics_period_s: float = param(1.0, '/diagnostics period [s wall]', range=(0.01, 60.0), read_only=True)
    process_rate_hz: float = param(
        10.0,
        'rate of the processing timer [Hz wall]: an output is published up to one period after its Imu '
        'sample arrived; each tick costs CPU (docs/nodes.md, "CPU share")',
        range=(1.0, 1000.0), read_only=True)
    imu_qos: str = param(
        'sensor_data',
        'Imu and ground-truth subscription QoS: sensor_data (best effort) or reliable',
        read_only=True)
    imu_qos_depth: int = param(1000, 'keep-last depth of the Imu subscription', range=(1, 100000), read_only=True)
    gnss_qos: str = param(
        'sensor_data',
        'NavSatFix and gps/vel subscription QoS: sensor_data (best effort) or reliable',
        read_only=True)
    gnss_qos_depth: int = param(
        100,
        'keep-last depth of the NavSatFix and gps/vel subscriptions',
        range=(1, 100000), read_only=True)
    poll_inputs: bool = param(
        True,
        'take every input in the processing tick instead of one executor callback per message (serialized '
        "Imu read in one numpy pass per batch; EventsExecutor only; about half the node's CPU at 125 Hz, "
        'docs/nodes.md); false: one callback per message',
        read_only=True)
    log_throttle_s: float = param(2.0, 'throttle of the rejection log lines, per kind [s]', range=(0.0, 3600.0))


def _is_num(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)
