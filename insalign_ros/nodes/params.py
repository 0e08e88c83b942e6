"""alignment_node's parameters: the table (name, default, description, read-only), every numeric parameter's range,
and the one validation function the start-up and the run-time changes both go through (docs/nodes.md,
"Parameters"). No node here: :func:`check_value` and :func:`unknown_parameters` are plain functions (tested
in-process for every parameter of every core, test_node_param_ranges.py).
"""

from __future__ import annotations

import math

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from ..session import catalog
from ..session.config import SessionConfig

SESSION_DOC = {  # session parameters the node exposes under the same names (SessionConfig has the meaning)
    "init_mode": "sensors (no guess: position/velocity from the fixes, level from the accelerometers, unknown heading "
                 "-> yaw bank), guess (initial_rpy_deg) or truth (ground_truth/pose; init_from_ground_truth)",
    "vehicle": "car | wheeled_robot | boat | aircraft | unknown (safe for every platform): what the yaw from GNSS "
               "velocity may assume (cars and wheeled robots drive along their x axis)",
    "init_level_window_s": "sensors: accelerometer averaging window for roll and pitch [s]",
    "unknown_heading_hypotheses": "sensors: yaw hypotheses when the heading is unknown (GNSS cores)",
    "init_accel_m_s2": "sensors: vehicle acceleration assumed when the fixes cannot tell it [m/s^2]",
    "initial_rpy_deg": "initial attitude guess roll, pitch, yaw [deg] (yaw from East, CCW)",
    "initial_velocity_enu_m_s": "initial velocity guess, ENU [m/s]",
    "init_rpy_error_deg": "Euler error added to the truth when init_from_ground_truth [deg]",
    "init_sigma_rpy_deg": "initial roll, pitch, yaw 1-sigma [deg] (NaN: the core's own defaults)",
    "static_position_deg_m": "static cores: lat [deg], lon [deg], h [m] (NaN: wait for a fix)",
    "max_rate_rad_s": "reject Imu with |angular_velocity| above this [rad/s] (2000 deg/s)",
    "max_acc_m_s2": "reject Imu with |linear_acceleration| above this [m/s^2] (50 g)",
    "max_gap_s": "an Imu stamp more than this from the newest one is a suspect time jump [s]",
    "time_jump_confirm": "consecutive self-consistent samples that confirm a time jump (then reset)",
    "gap_factor": "an Imu interval longer than this times the median interval is a gap",
    "max_fix_lag_s": "fixes up to this late are fused at their stamp: the filter runs this far behind the IMU [s]",
    "max_fix_ahead_s": "a fix ahead of the IMU by more than this is rejected [s]",
    "zupt_rate_hz": "zero-velocity update rate for static cores [Hz data time]",
    "zupt_sigma_m_s": "zero-velocity update 1-sigma [m/s]",
    "imu_timeout_s": "watchdog: no valid Imu for this long [s wall] drops the flag (0: off)",
    "gnss_timeout_s": "warn in /diagnostics when no fix was accepted for this long [s data time]",
    "idle_drain_s": "no input for this long [s wall]: process the buffered tail",
    "backtrack_passes": "backtracking passes over the stored window (filters/backtrack.py; 0: off)",
    "backtrack_window_s": "backtracking: stored alignment window after initialisation [s data time]",
    "backtrack_covariance": "backtracking: 'reset' (honest sigma) or 'reuse' (the paper's, optimistic)",
    "backtrack_budget_s": "backtracking: wall time per processing tick spent on the passes [s]",
    "imu_spike_rad_s": ("an Imu rate off both neighbours by more than this (and 20x the recent spread) is a spike: "
                        "dropped, bridged as a gap (0: off) [rad/s]"),
    "imu_spike_m_s2": "the same for the specific force [m/s^2]",
    "gnss_gate_nis": ("outlier gate: a fix with NIS above this is rejected without touching the filter once it claims "
                      "its attitude (0: off)"),
    "gnss_gate_max_consecutive": ("that many consecutive gated fixes: the filter (or the GNSS) is lost -> hold or "
                                  "FAULT and re-initialise"),
    "gnss_jump_accel_m_s2": ("a fix off the extrapolation of the two before it beyond this acceleration (+5 sigma) "
                             "is a GNSS jump: hold, not re-initialise [m/s^2]"),
    "gnss_hold_max_s": "the longest hold on the IMU after a GNSS jump before the new fixes are believed [s data time]",
    "gnss_hold_drift_m": ("a held filter whose innovation changes by more than this without a jump is "
                          "re-initialised [m]"),
    "divergence_nis_window": "divergence guard: fixes in the windowed NIS test (0: off)",
    "divergence_nis_mean": ("divergence guard: mean NIS over the window above this is a divergence (FAULT, "
                            "re-initialisation)"),
    "divergence_level_3sigma_deg": "divergence guard: roll or pitch 3-sigma above this is a divergence [deg]",
    "divergence_cusum_ratio": "divergence guard: CUSUM alternative, a covariance this many times too small",
    "divergence_cusum_arm_factor": ("divergence guard: the CUSUM runs while the attitude 3-sigma is within this times "
                                    "the flag's bounds"),
    "divergence_cusum_llr": "divergence guard: CUSUM log-likelihood ratio above this is a divergence (0: off)",
    "divergence_cusum_flag_llr": "divergence guard: CUSUM above this drops the aligned flag (0: off)",
}
#: descriptions of core parameters the node shows (others: "<core> core parameter")
CORE_DOC = {"gnss_lever_arm_b_m": "GNSS antenna position in the body frame FLU relative to the IMU [m] (x forward, "
                                  "y left, z up): the fix and gps/vel models predict the antenna"}
#: node parameters: name -> (default, description, read_only)
NODE_PARAMS = {
    "core": ("auto", "alignment core (filters/registry.py): auto (default: static while parked, in-motion iekf once "
                     "it moves; session/auto.py) or one core; read-only after start", True),
    "imu_grade": (SessionConfig().imu_grade, "IMU noise model, one of " + ", ".join(catalog.GRADES) + " (docs/imu_grades.md): "
                  "the defaults of the core's noise and bias parameters; an explicit core parameter overrides it. "
                  "Read-only after start", True),
    "init_from_ground_truth": (False, "initialise from ground_truth/pose plus init_rpy_error_deg (tests, demos; "
                                      "overrides init_mode)", False),
    "pose_rate_hz": (10.0, "~/pose, ~/euler_error and aligned-flag evaluation rate [Hz data time] (0: every Imu)", False),
    "use_imu_covariance": (False, "take gyro ARW / accel VRW from the Imu message covariances", False),
    "gnss_sigma_m": (1.0, "GNSS 1-sigma per axis [m] when NavSatFix gives no covariance", False),
    "imu_axes": ("flu", "axes of the Imu rates and accelerations: flu (x forward, y left, z up; REP 103) or frd "
                        "(x forward, y right, z down)", True),
    "imu_mount_rpy_deg": ([0.0, 0.0, 0.0], "roll, pitch, yaw [deg] of the IMU's FLU axes (after imu_axes) in the "
                          "vehicle FLU frame, C = Rz(yaw) Ry(pitch) Rx(roll) as a URDF joint base_link -> imu_link; "
                          "rates and specific forces are rotated into the vehicle frame", True),
    "body_frame_id": ("base_link", "frame_id of ~/imu: the vehicle FLU frame whose orientation is estimated", False),
    "imu_frame_id": ("", "required Imu frame_id ('' accepts any: drivers use imu, imu_link, gnss_link, ...; the "
                         "frames seen are logged)", False),
    "gnss_frame_id": ("", "required NavSatFix frame_id ('' accepts any)", False),
    "world_frame": ("map", "frame_id of ~/pose and ~/datum and the parent of the TF (REP 105): the local ENU frame "
                           "anchored at the initial position", False),
    "publish_tf": (False, "broadcast world_frame -> tf_child_frame on /tf (aligned attitude and ENU position) while "
                          "aligned", False),
    "tf_child_frame": ("base_link", "child frame of the TF broadcast (the vehicle FLU frame)", False),
    "publish_imu_before_aligned": (False, "publish ~/imu before the aligned flag rises (risk: robot_localization's "
                                          "navsat_transform latches the heading of the first ~/imu it receives)", False),
    "hardware_id": ("", "/diagnostics hardware_id ('': the frame_id of the Imu messages)", False),
    "diagnostics_period_s": (1.0, "/diagnostics period [s wall]", True),
    "process_rate_hz": (10.0, "rate of the processing timer [Hz wall]: an output is published up to one period after "
                              "its Imu sample arrived; each tick costs CPU (docs/nodes.md, \"CPU share\")", True),
    "imu_qos": ("sensor_data", "Imu and ground-truth subscription QoS: sensor_data (best effort) or reliable", True),
    "imu_qos_depth": (1000, "keep-last depth of the Imu subscription", True),
    "gnss_qos": ("sensor_data", "NavSatFix and gps/vel subscription QoS: sensor_data (best effort) or reliable", True),
    "gnss_qos_depth": (100, "keep-last depth of the NavSatFix and gps/vel subscriptions", True),
    "poll_inputs": (True, "take every input in the processing tick instead of one executor callback per message "
                          "(serialized Imu read in one numpy pass per batch; EventsExecutor only; about half the "
                          "node's CPU at 125 Hz, docs/nodes.md); false: one callback per message", True),
    "log_throttle_s": (2.0, "throttle of the rejection log lines, per kind [s]", False),
}

_INF = math.inf
#: the range of every numeric (double or integer) parameter the node declares, for any core: name -> (lo, hi),
#: inclusive. A name missing here gets DEFAULT_RANGE (non-negative) and test_node_param_ranges.py fails on it.
RANGES = {
    # node
    "pose_rate_hz": (0.0, 1000.0), "gnss_sigma_m": (1e-3, 1e4), "diagnostics_period_s": (0.01, 60.0),
    "process_rate_hz": (1.0, 1000.0), "log_throttle_s": (0.0, 3600.0), "imu_qos_depth": (1, 100000),
    "gnss_qos_depth": (1, 100000),
    # session
    "init_level_window_s": (0.01, 600.0), "unknown_heading_hypotheses": (1, 64), "init_accel_m_s2": (0.0, 100.0),
    "max_rate_rad_s": (0.1, 1000.0), "max_acc_m_s2": (1.0, 10000.0), "max_gap_s": (0.05, 3600.0),
    "time_jump_confirm": (1, 1000), "gap_factor": (1.1, 100.0), "max_fix_lag_s": (0.0, 10.0),
    "max_fix_ahead_s": (0.0, 3600.0), "zupt_rate_hz": (0.0, 1000.0), "zupt_sigma_m_s": (1e-6, 10.0),
    "imu_timeout_s": (0.0, 3600.0), "gnss_timeout_s": (0.0, 3600.0), "idle_drain_s": (0.01, 3600.0),
    "backtrack_passes": (0, 10), "backtrack_window_s": (0.0, 3600.0), "backtrack_budget_s": (0.0, _INF),
    "imu_spike_rad_s": (0.0, 1000.0), "imu_spike_m_s2": (0.0, 10000.0), "gnss_gate_nis": (0.0, 1e12),
    "gnss_gate_max_consecutive": (1, 1000), "gnss_jump_accel_m_s2": (0.0, 1000.0), "gnss_hold_max_s": (0.0, 3600.0),
    "gnss_hold_drift_m": (0.0, 1e6), "divergence_nis_window": (0, 1000), "divergence_nis_mean": (0.0, 1e15),
    "divergence_level_3sigma_deg": (0.0, 360.0), "divergence_cusum_ratio": (1.0, 1e6),
    "divergence_cusum_arm_factor": (0.0, 1e6), "divergence_cusum_llr": (0.0, 1e6),
    "divergence_cusum_flag_llr": (0.0, 1e6),
    # aligned flag
    "aligned.roll_pitch_3sigma_deg": (1e-6, 180.0), "aligned.yaw_3sigma_deg": (1e-6, 360.0),
    "aligned.nis_window": (0, 10000), "aligned.nis_alpha": (1e-12, 0.999999), "aligned.nis_alpha_drop": (1e-12, 0.999999),
    "aligned.hold_s": (0.0, 3600.0), "aligned.max_update_age_s": (1e-3, 3600.0),
    # cores (integers)
    "yaw_hypotheses": (1, 64), "hypothesis_min_updates": (0, 10000), "horizon_p": (1, 10000),
    "lmi_resolve_every_updates": (1, 100000), "lmi_window_updates": (1, 100000), "max_batch_samples": (1, 100000),
    "stop_zero_rate_min_blocks": (0, 10000),
    # cores (doubles with a bound other than DEFAULT_RANGE)
    "hypothesis_prune_weight": (0.0, 1.0), "fading_max_factor": (1.0, 1e6), "init_sigma_roll_deg": (0.0, 180.0),
    "init_sigma_pitch_deg": (0.0, 180.0), "init_sigma_yaw_deg": (0.0, 360.0), "aligned_yaw_3sigma_deg": (0.0, 360.0),
    "azimuth_feedback_sigma_deg": (0.0, 360.0), "azimuth_bootstrap_above_sigma_deg": (0.0, 360.0),
    "max_azimuth_sigma_deg": (0.0, 360.0), "lmi_once_yaw_3sigma_deg": (0.0, 360.0), "heading_floor_max_deg": (0.0, 360.0),
    "heading_trust_sigma_deg": (0.0, 360.0), "hypothesis_merge_deg": (0.0, 180.0), "rho": (0.0, 1e6),
}
#: non-negative physical quantities (noise densities, biases, sigmas, times, rates, weights)
DEFAULT_RANGE = (0.0, 1e15)


def is_numeric(default) -> bool:
    return isinstance(default, (int, float)) and not isinstance(default, bool)


def range_of(name: str, default) -> tuple | None:
    """The inclusive range of a numeric parameter (None: not a numeric scalar)."""
    if not is_numeric(default):
        return None
    return RANGES.get(name, DEFAULT_RANGE if isinstance(default, float) else (0, 2**31 - 1))


def descriptor(name: str, default, text: str, read_only: bool) -> ParameterDescriptor:
    """A description, and a range for every numeric parameter (what `ros2 param describe` shows)."""
    d = ParameterDescriptor(description=text, read_only=read_only)
    rng = range_of(name, default)
    if isinstance(default, float):
        lo, hi = rng
        d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
        d.additional_constraints = f"range [{lo:g}, {hi:g}]"
    elif rng is not None:
        lo, hi = rng
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        d.additional_constraints = f"range [{lo}, {hi}]"
    return d


def coerce(default, value):
    """An int for a float and a list of ints for a list of floats become floats; other type changes: ValueError."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, (list, tuple)) and isinstance(value, (list, tuple)):
        if all(isinstance(x, float) for x in default):
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
                raise ValueError(f"wrong type: expected a list of numbers, got {list(value)!r}")
            return [float(x) for x in value]
        return list(value)
    if type(value) is not type(default):
        raise ValueError(f"wrong type: expected {type(default).__name__}, got {value!r} ({type(value).__name__})")
    return value


def check_value(name: str, default, value):
    """``value`` for parameter ``name`` (declared default ``default``) coerced as :func:`coerce` does and checked
    against its range; ValueError with one line naming the parameter, the value and the range otherwise."""
    try:
        v = coerce(default, value)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    rng = range_of(name, default)
    if rng is not None:
        lo, hi = rng
        if not (lo <= v <= hi):  # NaN fails too
            raise ValueError(f"{name}: value {v!r} outside its range [{lo:g}, {hi:g}]")
    return v


def core_parameter_owners() -> dict:
    """parameter name -> the cores that have it (for naming another core's parameter)."""
    out: dict = {}
    for core in catalog.core_names():
        for name in catalog.core_defaults(core):
            out.setdefault(name, []).append(core)
    return out


def unknown_parameters(given, declared, core: str) -> list[str]:
    """One warning line per parameter ``given`` (set at start: a file or -p) that the node does not declare: a
    misspelling, or a parameter of another core than ``core``."""
    owners = None
    lines = []
    for name in sorted(set(given) - set(declared)):
        if name == "use_sim_time" or name.startswith("qos_overrides.") or name == "start_type_description_service":
            continue
        owners = owners if owners is not None else core_parameter_owners()
        if name in owners:
            lines.append(f"parameter {name!r} is not a parameter of core {core!r} (it belongs to "
                         f"{', '.join(owners[name])}): ignored")
        else:
            lines.append(f"unknown parameter {name!r}: ignored (misspelled?)")
    return lines
