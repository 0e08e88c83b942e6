"""alignment_node: runs one alignment core (parameter ``core``) on sensor_msgs/Imu and NavSatFix over DDS.

Topics (relative names, remappable as usual):

- in ``imu/data`` sensor_msgs/Imu (QoS ``imu_qos``: ``sensor_data`` = best effort, by default), ``gps/fix``
  sensor_msgs/NavSatFix (reliable), ``ground_truth/pose`` geometry_msgs/PoseStamped (optional, ``imu_qos``);
- out ``~/pose`` PoseWithCovarianceStamped (frame ``enu_frame_id``: local ENU anchored at the first accepted fix;
  orientation body FLU -> ENU; covariance 6x6 ROS order x y z rot x rot y rot z [m^2, rad^2], attitude block =
  the core's ``P_att_n``), ``~/euler_error`` and ``~/euler_error_3sigma`` geometry_msgs/Vector3Stamped
  (x, y, z = roll, pitch, yaw [deg]; the error estimate minus truth, only when ground truth is present; the
  3-sigma always), ``~/aligned`` std_msgs/Bool (reliable, transient local, depth 1), ``/diagnostics``
  diagnostic_msgs/DiagnosticArray at ``diagnostics_period_s``.

Per message the node does: conversion + validation (nodes/conversions.py), time-consistency checks, then
``EventRunner.feed`` (filters/runner.py, the same per-event code as the offline runner). docs/nodes.md has the
parameters, the aligned-flag criteria (eval/aligned.py) and the bad-input policy.
"""

from __future__ import annotations

import json
import math
import sys
import time
import traceback
from collections import OrderedDict, deque

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Vector3Stamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Bool

from ..core import earth
from ..eval.aligned import AlignedCriteria, AlignedFlag, euler_3sigma_deg
from ..filters import registry
from ..filters.runner import EventRunner, InitialGuess, initial_guess, initial_P_att_n
from . import conversions as cv
from .qos import imu_qos

D2R = math.pi / 180.0

STATE_WAITING = "waiting for data"
STATE_ALIGNING = "aligning"
STATE_ALIGNED = "aligned"
STATE_FAULT = "fault"

#: common parameters: name -> (default, description). Per-core parameters are the fields of the core's config
#: dataclass (filters/config.py), declared flat with the core's defaults (config/<core>.yaml sets them).
COMMON_PARAMS = {
    "core": ("iekf", "alignment core (filters/registry.py); iekf: the flag was never falsely up in the MC (docs)"),
    "initial_rpy_deg": ([0.0, 0.0, 0.0], "initial attitude guess roll, pitch, yaw [deg] (yaw from East, CCW)"),
    "initial_velocity_enu_m_s": ([0.0, 0.0, 0.0], "initial velocity guess, ENU [m/s]"),
    "init_sigma_rpy_deg": ([5.0, 5.0, 100.0], "initial roll, pitch, yaw 1-sigma [deg] for cores whose config has "
                                              "none (static cores)"),
    "init_from_ground_truth": (False, "initialise from ground_truth/pose plus init_rpy_error_deg (tests, demos)"),
    "init_rpy_error_deg": ([0.0, 0.0, 0.0], "Euler error added to the truth when init_from_ground_truth"),
    "use_imu_covariance": (False, "take gyro ARW / accel VRW from the first Imu message's covariances"),
    "gnss_sigma_m": (1.0, "GNSS 1-sigma per axis [m] when NavSatFix gives no covariance"),
    "imu_frame_id": ("imu_link", "required Imu frame_id ('' accepts any)"),
    "gnss_frame_id": ("", "required NavSatFix frame_id ('' accepts any)"),
    "enu_frame_id": ("enu", "frame_id of ~/pose"),
    "max_rate_rad_s": (34.9, "reject Imu with |angular_velocity| above this [rad/s] (2000 deg/s, io/validation.py)"),
    "max_acc_m_s2": (490.0, "reject Imu with |linear_acceleration| above this [m/s^2] (50 g, io/validation.py)"),
    "max_gap_s": (2.0, "an Imu stamp more than this after the previous one is a suspect time jump [s]"),
    "time_jump_confirm": (5, "consecutive self-consistent messages that confirm a time jump (then reset)"),
    "max_fix_ahead_s": (10.0, "a fix ahead of the IMU by more than this is rejected (far future) [s]; "
                               "a fix ahead by less waits for the IMU to reach its stamp"),
    "max_fix_lag_s": (0.05, "a fix older than the filter time by more than this is stale [s]"),
    "pose_rate_hz": (10.0, "~/pose, ~/euler_error, aligned-flag evaluation rate [Hz data time] (0: every Imu)"),
    "diagnostics_period_s": (1.0, "/diagnostics period [s]"),
    "gnss_timeout_s": (5.0, "warn in /diagnostics when no fix was accepted for this long [s data time]"),
    "zupt_rate_hz": (1.0, "zero-velocity update rate for static cores [Hz data time]"),
    "zupt_sigma_m_s": (0.01, "zero-velocity update 1-sigma [m/s]"),
    "static_position_deg_m": ([float("nan"), float("nan"), float("nan")],
                              "static cores: lat [deg], lon [deg], h [m] (NaN: wait for a fix)"),
    "imu_qos": ("sensor_data", "Imu and ground-truth subscription QoS: sensor_data (best effort) or reliable"),
    "imu_qos_depth": (1000, "keep-last depth of the Imu subscription"),
    "log_throttle_s": (2.0, "throttle of the rejection log lines [s]"),
    "backtrack_passes": (0, "backtracking passes over the stored window (filters/backtrack.py; 0: off)"),
    "backtrack_window_s": (60.0, "backtracking: stored alignment window after initialisation [s data time]"),
    "backtrack_covariance": ("reset", "backtracking: 'reset' = last forward pass from the initial covariance (each "
                             "measurement counted once, honest sigma); 'reuse' = the paper's (optimistic)"),
    "backtrack_budget_s": (0.02, "backtracking: wall time per timer tick spent on the passes [s]"),
    "backtrack_timer_hz": (20.0, "backtracking: timer rate of the budgeted pass steps [Hz]"),
    "aligned.roll_pitch_3sigma_deg": (1.0, "aligned flag: 3-sigma roll/pitch bound [deg]"),
    "aligned.yaw_3sigma_deg": (2.5, "aligned flag: 3-sigma yaw bound [deg]"),
    "aligned.nis_window": (10, "aligned flag: NIS window [updates] (0: off)"),
    "aligned.nis_alpha": (0.01, "aligned flag: two-sided chi-square probability"),
    "aligned.nis_lower_check": (False, "aligned flag: also fail on a too-small NIS sum"),
    "aligned.hold_s": (5.0, "aligned flag: criteria must hold this long [s]"),
    "aligned.max_update_age_s": (5.0, "aligned flag: last accepted update at most this old [s]"),
}
READ_ONLY = {"imu_qos", "imu_qos_depth", "backtrack_timer_hz"}
#: cores that filters/backtrack.py can run backward (make_backtrackable)
BACKTRACK_CORES = ("liekf", "liekf_backtrack", "earth_iekf")


def _latched_qos() -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class AlignmentNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("alignment_node", **node_kwargs)
        for name, (default, desc) in COMMON_PARAMS.items():
            self.declare_parameter(name, default)
        self.core_name = str(self.get_parameter("core").value)
        cfg_cls = registry.CORES[self.core_name][1] if self.core_name in registry.CORES else None
        if cfg_cls is None:
            raise ValueError(f"unknown core {self.core_name!r}; choose one of {sorted(registry.core_names())}")
        self.core_param_names = [f for f in cfg_cls().to_dict()]
        for name, default in cfg_cls().to_dict().items():
            if name not in COMMON_PARAMS:
                self.declare_parameter(name, default)
        # validate everything once (a bad start-up value is an error with the reason)
        reason = self._validate(self._param_dict())
        if reason:
            raise ValueError(reason)
        self._load(self._param_dict())
        self.add_on_set_parameters_callback(self._on_set_parameters)

        qos = imu_qos(str(self.get_parameter("imu_qos").value), int(self.get_parameter("imu_qos_depth").value))
        self.create_subscription(Imu, "imu/data", self._on_imu, qos)
        self.create_subscription(NavSatFix, "gps/fix", self._on_fix, 50)
        self.create_subscription(PoseStamped, "ground_truth/pose", self._on_truth, qos)
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "~/pose", 50)
        self.pub_err = self.create_publisher(Vector3Stamped, "~/euler_error", 50)
        self.pub_err3 = self.create_publisher(Vector3Stamped, "~/euler_error_3sigma", 50)
        self.pub_aligned = self.create_publisher(Bool, "~/aligned", _latched_qos())
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)

        self.counters = OrderedDict((k, 0) for k in (
            "imu_received", "imu_processed", "imu_rejected", "imu_invalid", "imu_frame", "imu_duplicate",
            "imu_out_of_order", "imu_future", "imu_gaps", "imu_before_init", "gnss_received", "gnss_accepted",
            "gnss_rejected", "gnss_invalid", "gnss_no_fix", "gnss_frame", "gnss_stale", "gnss_duplicate",
            "gnss_future", "gnss_filter_rejected", "truth_received", "truth_invalid", "time_resets",
            "core_faults", "zupt_accepted"))
        self.last_reject = ""
        self._log_state: dict = {}
        self.flag = AlignedFlag(self.criteria)
        self._reset_state("start")
        self.pub_aligned.publish(Bool(data=False))
        self.timing_s: deque = deque(maxlen=100000)  # per-Imu callback time [s] (benchmarks read it)
        # receive wall time minus header stamp [s]: the DDS end-to-end latency when stamps are wall-clock times
        self.stamp_age_s: deque = deque(maxlen=100000)
        self.create_timer(float(self.get_parameter("diagnostics_period_s").value), self._publish_diagnostics)
        self.create_timer(1.0 / float(self.get_parameter("backtrack_timer_hz").value), self._backtrack_step)
        self.get_logger().info(f"alignment_node: core {self.core_name}, waiting for imu/data and gps/fix")

    # ------------------------------------------------------------------ parameters
    def _param_dict(self) -> dict:
        out = {n: self.get_parameter(n).value for n in COMMON_PARAMS}
        for n in self.core_param_names:
            out[n] = self.get_parameter(n).value
        return out

    def _core_params(self, p: dict, core: str) -> dict:
        fields = registry.CORES[core][1]().to_dict()
        out = {}
        for n in fields:
            if n in p and n not in COMMON_PARAMS:
                out[n] = list(p[n]) if isinstance(p[n], (list, tuple)) else p[n]
        if out.get("lmi_async") == "auto":  # PI-LIEKF: never solve the LMI inside the IMU/GNSS callback
            out["lmi_async"] = "true"
        return out

    def _criteria(self, p: dict) -> AlignedCriteria:
        return AlignedCriteria(**{k.split(".", 1)[1]: p[k] for k in p if k.startswith("aligned.")})

    def _validate(self, p: dict) -> str:
        core = p["core"]
        if core not in registry.CORES:
            return f"core: unknown {core!r}; choose one of {sorted(registry.core_names())}"
        try:
            registry.make_config(core, self._core_params(p, core))
        except (ValueError, TypeError) as exc:
            return f"core parameters: {exc}"
        try:
            self._criteria(p).validate()
        except (ValueError, TypeError) as exc:
            return f"aligned: {exc}"
        for name in ("initial_rpy_deg", "initial_velocity_enu_m_s", "init_rpy_error_deg", "init_sigma_rpy_deg"):
            v = list(p[name])
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                return f"{name}: need 3 finite numbers, got {v}"
        if len(list(p["static_position_deg_m"])) != 3:
            return "static_position_deg_m: need 3 numbers (lat deg, lon deg, h m)"
        for name in ("gnss_sigma_m", "max_rate_rad_s", "max_acc_m_s2", "max_gap_s", "diagnostics_period_s",
                     "gnss_timeout_s", "zupt_sigma_m_s", "log_throttle_s", "max_fix_lag_s", "max_fix_ahead_s"):
            if not (isinstance(p[name], (int, float)) and math.isfinite(p[name]) and p[name] > 0):
                return f"{name}: must be a finite number > 0, got {p[name]!r}"
        for name in ("pose_rate_hz", "zupt_rate_hz"):
            if not (isinstance(p[name], (int, float)) and math.isfinite(p[name]) and p[name] >= 0):
                return f"{name}: must be a finite number >= 0, got {p[name]!r}"
        if not (isinstance(p["backtrack_passes"], int) and 0 <= p["backtrack_passes"] <= 10):
            return f"backtrack_passes: must be an integer in [0, 10], got {p['backtrack_passes']!r}"
        if p["backtrack_passes"] > 0 and (p["core"] not in BACKTRACK_CORES or p.get("yaw_hypotheses", 1) > 1):
            return (f"backtrack_passes > 0 needs one filter of a core with backward propagation "
                    f"({', '.join(BACKTRACK_CORES)}, yaw_hypotheses 1); got core {p['core']!r}, yaw_hypotheses "
                    f"{p.get('yaw_hypotheses', 1)}")
        if p["backtrack_covariance"] not in ("reset", "reuse"):
            return f"backtrack_covariance: must be 'reset' or 'reuse', got {p['backtrack_covariance']!r}"
        for name in ("backtrack_window_s", "backtrack_budget_s", "backtrack_timer_hz"):
            if not (isinstance(p[name], (int, float)) and math.isfinite(p[name]) and p[name] > 0):
                return f"{name}: must be a finite number > 0, got {p[name]!r}"
        if not 1 <= int(p["time_jump_confirm"]) <= 1000:
            return f"time_jump_confirm: must be in [1, 1000], got {p['time_jump_confirm']}"
        return ""

    def _load(self, p: dict) -> None:
        self.params = p
        self.criteria = self._criteria(p)
        self.max_gap_s = float(p["max_gap_s"])
        self.pose_period_s = 1.0 / p["pose_rate_hz"] if p["pose_rate_hz"] > 0 else 0.0
        self.throttle_s = float(p["log_throttle_s"])

    def _on_set_parameters(self, params) -> SetParametersResult:
        p = dict(self.params)
        for prm in params:
            if prm.name in READ_ONLY:
                return SetParametersResult(successful=False, reason=f"{prm.name} is read-only (set it at start)")
            if prm.name not in p:
                return SetParametersResult(successful=False, reason=f"unknown parameter {prm.name}")
            old = p[prm.name]
            new = prm.value
            if isinstance(old, float) and isinstance(new, int) and not isinstance(new, bool):
                new = float(new)
            if type(new) is not type(old) and not (isinstance(old, (list, tuple)) and isinstance(new, (list, tuple))):
                return SetParametersResult(successful=False,
                                           reason=f"{prm.name}: expected {type(old).__name__}, got {new!r}")
            p[prm.name] = new
        reason = self._validate(p)
        if reason:
            self.get_logger().warning(f"parameter change refused: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        core_changed = p["core"] != self.params["core"]
        self._load(p)
        self.flag.set_criteria(self.criteria)
        if core_changed:
            self.core_name = p["core"]
            self.get_logger().warning(f"core changed to {self.core_name}: resetting the alignment")
            self._reset_state("core changed")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ state
    def _reset_state(self, why: str) -> None:
        self.core = None
        self.runner: EventRunner | None = None
        self.state = STATE_WAITING
        self.reason = f"waiting for Imu and a GNSS fix ({why})"
        self.last_imu_t: float | None = None
        self.last_imu_dt: float | None = None
        self.jump_candidates: list[float] = []
        self.last_fix_t: float | None = None
        self.pending_fixes: deque = deque(maxlen=50)
        self.last_accepted_fix_t: float | None = None
        self.anchor = None  # (lat, lon, h) of the ENU frame
        self.next_pose_t = -math.inf
        self.next_zupt_t = -math.inf
        self.last_est = None
        self.last_nis = float("nan")
        self.truth: OrderedDict = OrderedDict()  # stamp_ns -> (C_b_n, p_n)
        self.first_imu_msg = None
        self.init_t = None
        if getattr(self, "flag", None) is not None:
            was = self.flag.aligned
            self.flag.reset()
            if was:
                self.pub_aligned.publish(Bool(data=False))

    def _reject(self, counter: str, reason: str, topic: str) -> None:
        self.counters[counter] += 1
        self.counters[f"{topic}_rejected"] += 1
        self.last_reject = f"{topic}: {reason}"
        self._warn_throttled(counter, f"rejected {topic} message: {reason} ({counter}={self.counters[counter]})")

    def _warn_throttled(self, key: str, text: str) -> None:
        """A warning at most once per log_throttle_s per key (rclpy's throttle is per call site, so one
        kind of rejection would silence all others); says how many were suppressed in between."""
        now = time.monotonic()
        last, suppressed = self._log_state.get(key, (-math.inf, 0))
        if now - last >= self.throttle_s:
            more = f" [{suppressed} more since the last line]" if suppressed else ""
            self.get_logger().warning(text + more)
            self._log_state[key] = (now, 0)
        else:
            self._log_state[key] = (last, suppressed + 1)

    # ------------------------------------------------------------------ callbacks
    def _on_imu(self, msg: Imu) -> None:
        t_start = time.perf_counter()
        self.counters["imu_received"] += 1
        try:
            self._handle_imu(msg)
        except Exception as exc:  # never crash: a core failure is a fault, the alignment restarts
            self._fault(exc)
        self.timing_s.append(time.perf_counter() - t_start)
        st = msg.header.stamp
        self.stamp_age_s.append(time.time() - (st.sec + 1e-9 * st.nanosec))

    def _handle_imu(self, msg: Imu) -> None:
        p = self.params
        sample, reason = cv.imu_from_msg(msg, p["max_rate_rad_s"], p["max_acc_m_s2"], p["imu_frame_id"])
        if sample is None:
            self._reject("imu_frame" if reason.startswith("frame_id") else "imu_invalid", reason, "imu")
            return
        t = sample.stamp_s
        if self.last_imu_t is not None:
            dt = t - self.last_imu_t
            if dt == 0.0:
                self._reject("imu_duplicate", f"duplicate stamp {t:.6f}", "imu")
                return
            if dt < 0.0 or dt > self.max_gap_s:
                if self._time_jump(t, dt):
                    return self._handle_imu(msg)  # state was reset: process this one as the first
                self._reject("imu_out_of_order" if dt < 0 else "imu_future",
                             f"stamp {t:.6f} is {dt:+.3f} s from the previous {self.last_imu_t:.6f}", "imu")
                return
            self.jump_candidates.clear()
            if self.last_imu_dt is not None and dt > 1.5 * self.last_imu_dt:
                self.counters["imu_gaps"] += 1
                self._warn_throttled("imu_gaps", f"IMU gap of {dt:.3f} s before {t:.6f} (dropout): propagating "
                                                 f"across it (imu_gaps={self.counters['imu_gaps']})")
            else:
                self.last_imu_dt = dt
        self.last_imu_t = t
        if self.first_imu_msg is None:
            self.first_imu_msg = msg
        if self.core is None:
            self.counters["imu_before_init"] += 1
            self._try_initialize(msg, t)
            return
        self.runner.feed(sample)
        self.counters["imu_processed"] += 1
        # fixes waiting for the IMU to reach their stamp
        while self.pending_fixes and self.pending_fixes[0].stamp_s <= t:
            self._apply_fix(self.pending_fixes.popleft(), t)
        if self.core.supports_zero_velocity and not self.core.supports_gnss and p["zupt_rate_hz"] > 0 \
                and t >= self.next_zupt_t:
            res = self.core.update_zero_velocity(t, p["zupt_sigma_m_s"])
            self.next_zupt_t = t + 1.0 / p["zupt_rate_hz"]
            if res.accepted:
                self.counters["zupt_accepted"] += 1
            self.flag.on_update(t, res.accepted, res.nis, len(res.innovation) or 3)
        if t >= self.next_pose_t:
            # with ground truth around, publish at a stamp that has a truth pose (within two output periods)
            late = t - self.next_pose_t
            if not self.truth or self._truth_at(msg) is not None or late >= 2.0 * self.pose_period_s:
                self.next_pose_t = t + self.pose_period_s
                self._publish_outputs(msg, t)

    def _time_jump(self, t: float, dt: float) -> bool:
        """Track messages that do not fit the time line; a run of self-consistent ones is a real jump -> reset."""
        c = self.jump_candidates
        if c and not (0.0 < t - c[-1] <= self.max_gap_s):
            c.clear()
        c.append(t)
        if len(c) < int(self.params["time_jump_confirm"]):
            return False
        kind = "backward" if dt < 0 else "forward"
        self.counters["time_resets"] += 1
        self.get_logger().warning(f"time jumped {kind} by {dt:+.3f} s (from {self.last_imu_t:.6f} to {t:.6f}, "
                                  f"{len(c)} consistent messages): resetting the alignment")
        self._reset_state(f"time jumped {kind} by {dt:+.3f} s")
        return True

    def _on_fix(self, msg: NavSatFix) -> None:
        self.counters["gnss_received"] += 1
        try:
            self._handle_fix(msg)
        except Exception as exc:
            self._fault(exc)

    def _handle_fix(self, msg: NavSatFix) -> None:
        p = self.params
        fix, reason = cv.fix_from_msg(msg, p["gnss_sigma_m"], p["gnss_frame_id"])
        if fix is None:
            counter = ("gnss_no_fix" if reason.startswith("no fix") else
                       "gnss_frame" if reason.startswith("frame_id") else "gnss_invalid")
            self._reject(counter, reason, "gnss")
            return
        t = fix.stamp_s
        if self.last_fix_t is not None and t == self.last_fix_t:
            self._reject("gnss_duplicate", f"duplicate stamp {t:.6f}", "gnss")
            return
        if self.last_fix_t is not None and t < self.last_fix_t:
            self._reject("gnss_stale", f"stamp {t:.6f} before the previous fix {self.last_fix_t:.6f}", "gnss")
            return
        if self.last_imu_t is not None and t > self.last_imu_t + p["max_fix_ahead_s"]:
            self._reject("gnss_future", f"stamp {t:.6f} is {t - self.last_imu_t:.3f} s ahead of the IMU", "gnss")
            return
        if self.last_imu_t is not None and t < self.last_imu_t - p["max_fix_lag_s"]:
            self._reject("gnss_stale", f"stamp {t:.6f} is {self.last_imu_t - t:.3f} s behind the IMU", "gnss")
            return
        self.last_fix_t = t
        if self.last_imu_t is not None and t <= self.last_imu_t and self.core is not None:
            self._apply_fix(fix, self.last_imu_t)
        else:
            self.pending_fixes.append(fix)  # applied (or used to initialise) at the next IMU message

    def _apply_fix(self, fix, t_now: float) -> None:
        if self.core is None:
            return
        res = self.runner.feed(fix)
        if res is None:
            return
        self.last_nis = res.nis
        if res.accepted:
            self.counters["gnss_accepted"] += 1
            self.last_accepted_fix_t = fix.stamp_s
        else:
            self.counters["gnss_filter_rejected"] += 1
            self.counters["gnss_rejected"] += 1
            self.last_reject = f"gnss: core: {res.reason}"
            self._warn_throttled("gnss_filter_rejected", f"fix rejected by the core: {res.reason}")
        self.flag.on_update(t_now, res.accepted, res.nis, len(res.innovation) or 3)

    def _on_truth(self, msg: PoseStamped) -> None:
        self.counters["truth_received"] += 1
        val, reason = cv.truth_from_msg(msg)
        if val is None:
            self.counters["truth_invalid"] += 1
            self._warn_throttled("truth_invalid", f"rejected ground truth: {reason}")
            return
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.truth[key] = (val[1], val[2], val[0])
        while len(self.truth) > 2000:
            self.truth.popitem(last=False)

    def _truth_at(self, msg) -> tuple | None:
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        return self.truth.get(key)

    # ------------------------------------------------------------------ initialisation
    def _try_initialize(self, msg: Imu | None, t: float) -> None:
        p = self.params
        core = registry.make_core(self.core_name, self._core_params(p, self.core_name))
        static = not core.supports_gnss
        pos = None
        n_fix = 0
        if static and all(math.isfinite(x) for x in p["static_position_deg_m"]):
            la, lo, h = p["static_position_deg_m"]
            pos = (la * D2R, lo * D2R, float(h))
        else:
            usable = [f for f in self.pending_fixes if f.stamp_s <= t]
            if usable:
                n_fix = len(usable)
                pos = earth.ecef_to_geodetic(usable[-1].p_e)
        if pos is None:
            return
        C0, v0 = None, np.asarray(p["initial_velocity_enu_m_s"], float)
        if p["init_from_ground_truth"]:
            tr = self._truth_at(msg) if msg is not None else None
            if tr is None:
                self.reason = "waiting for a ground-truth pose at an IMU stamp (init_from_ground_truth)"
                return
            C0 = tr[0]
            prev = [v for v in self.truth.values() if v[2] < tr[2]][-2:]
            if len(prev) == 2 and abs((tr[2] - prev[1][2]) - (prev[1][2] - prev[0][2])) < 1e-6:
                # truth velocity: derivative of the parabola through the last three poses (error O(dt^2))
                v0 = (3.0 * tr[1] - 4.0 * prev[1][1] + prev[0][1]) / (2.0 * (tr[2] - prev[1][2]))
            elif prev:
                v0 = (tr[1] - prev[-1][1]) / (tr[2] - prev[-1][2])  # backward difference
            err = np.asarray(p["init_rpy_error_deg"], float)
        else:
            C0 = earth.C_b_n_from_rpy(*(np.asarray(p["initial_rpy_deg"], float) * D2R))
            err = np.zeros(3)
        for _ in range(n_fix):  # the fix that gave the position is consumed (not fused twice)
            self.pending_fixes.popleft()
        if p["use_imu_covariance"] and msg is not None and self.last_imu_dt:
            noise = cv.imu_noise_from_msg(msg, self.last_imu_dt)
            cp = {**self._core_params(p, self.core_name), **{k: v for k, v in noise.items()
                                                              if k in self.core_param_names}}
            core = registry.make_core(self.core_name, cp)
            self.get_logger().info(f"noise from the Imu covariances: {noise}")
        cfg = core.cfg
        if hasattr(cfg, "init_sigma_roll_deg"):
            guess = initial_guess(t, pos[0], pos[1], pos[2], C0, v0, err, cfg)
        else:  # static cores' configs carry no initial attitude sigmas: the node's init_sigma_rpy_deg
            rpy = earth.rpy_from_C_b_n(np.asarray(C0, float)) + err * D2R
            guess = InitialGuess(t, pos[0], pos[1], pos[2], earth.C_b_n_from_rpy(*rpy), np.asarray(v0, float),
                                 initial_P_att_n(p["init_sigma_rpy_deg"]),
                                 float(getattr(cfg, "init_sigma_v_m_s", 0.01)), float(getattr(cfg, "init_sigma_p_m", 1.0)))
        guess.apply(core)
        self.core = core
        if p["backtrack_passes"] > 0:
            from ..filters.backtrack import BacktrackingAligner

            self.runner = BacktrackingAligner(core, t, p["backtrack_window_s"], p["backtrack_passes"],
                                              covariance=p["backtrack_covariance"])
        else:
            self.runner = EventRunner(core, t)
        self.anchor = pos
        self.state = STATE_ALIGNING
        self.reason = "initialised"
        self.next_pose_t = t
        self.next_zupt_t = t
        self.init_t = t
        self.get_logger().info(f"initialised {self.core_name} at t={t:.3f} s, lat {pos[0] / D2R:.6f} deg, "
                               f"lon {pos[1] / D2R:.6f} deg, h {pos[2]:.1f} m, rpy "
                               f"{np.round(earth.rpy_from_C_b_n(guess.C_b_n) / D2R, 2).tolist()} deg")

    # ------------------------------------------------------------------ backtracking (filters/backtrack.py)
    def backtrack_busy(self) -> bool:
        """True while backtracking passes run (in budgeted steps on the timer; the live core keeps going)."""
        return bool(getattr(self.runner, "busy", False))

    def _backtrack_step(self) -> None:
        step = getattr(self.runner, "step_background", None)
        if step is None or getattr(self.runner, "state", "done") == "done":
            return
        try:
            step(self.params["backtrack_budget_s"])
            if self.runner.live is not self.core:
                self.core = self.runner.live
                self.get_logger().info("backtracking: handed over to the re-aligned core")
        except Exception as exc:  # noqa: BLE001 - never crash
            self._fault(exc)

    def _fault(self, exc: Exception) -> None:
        self.counters["core_faults"] += 1
        self.state = STATE_FAULT
        self.last_reject = f"fault: {type(exc).__name__}: {exc}"
        self.get_logger().error(f"core fault ({type(exc).__name__}: {exc}); resetting the alignment\n"
                                f"{traceback.format_exc(limit=3)}", throttle_duration_sec=self.throttle_s)
        self._reset_state(f"after a fault: {exc}")
        self.state = STATE_FAULT

    # ------------------------------------------------------------------ outputs
    def _publish_outputs(self, msg: Imu, t: float) -> None:
        est = self.core.estimate()
        P = est.P_att_n
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(est.C_b_n)) and math.isfinite(est.lat_rad)):
            raise FloatingPointError("non-finite estimate")
        self.last_est = est
        self.pub_pose.publish(cv.pose_msg(est, self.anchor, self.params["enu_frame_id"], ""))
        s3 = euler_3sigma_deg(est.C_b_n, P)
        m3 = Vector3Stamped()
        m3.header = msg.header
        m3.header.frame_id = self.params["enu_frame_id"]
        m3.vector.x, m3.vector.y, m3.vector.z = (float(x) for x in s3)
        tr = self._truth_at(msg)
        if tr is not None:
            e = np.degrees(earth.euler_error_rad(est.C_b_n, tr[0]))
            me = Vector3Stamped()
            me.header = m3.header
            me.vector.x, me.vector.y, me.vector.z = (float(x) for x in e)
            self.pub_err.publish(me)
        self.pub_err3.publish(m3)
        was = self.flag.aligned
        now = self.flag.on_estimate(t, P)
        self.state = STATE_ALIGNED if now else STATE_ALIGNING
        self.reason = self.flag.reason
        if now != was:
            self.pub_aligned.publish(Bool(data=now))
            self.get_logger().info(f"aligned flag {'raised' if now else 'lowered'} at t={t:.3f} s: {self.flag.reason}")

    def _core_diagnostics(self) -> dict:
        """The core's own diagnostics() (PI-LIEKF LMI status, yaw-hypothesis bank, ...) as 'core.<key>' strings."""
        fn = getattr(self.core, "diagnostics", None) if self.core is not None else None
        if not callable(fn):
            return {}
        try:
            return {f"core.{k}": (json.dumps(v) if isinstance(v, (list, tuple, dict)) else str(v))
                    for k, v in fn().items()}
        except Exception as exc:  # noqa: BLE001 - diagnostics must never take the node down
            return {"core.diagnostics_error": f"{type(exc).__name__}: {exc}"}

    def _publish_diagnostics(self) -> None:
        st = DiagnosticStatus()
        st.name = f"{self.get_name()}: alignment"
        st.hardware_id = self.core_name
        st.level = {STATE_ALIGNED: DiagnosticStatus.OK, STATE_FAULT: DiagnosticStatus.ERROR}.get(
            self.state, DiagnosticStatus.WARN)
        st.message = f"{self.state}: {self.reason}"
        vals = {"core": self.core_name, "state": self.state, "reason": self.reason,
                "aligned": str(self.flag.aligned).lower(), "aligned_reason": self.flag.reason}
        if self.last_est is not None:
            s = self.flag.sigma3_deg
            vals.update(yaw_3sigma_deg=f"{s[2]:.4f}", roll_pitch_3sigma_deg=f"{max(s[0], s[1]):.4f}",
                        yaw_sigma_deg=f"{s[2] / 3:.4f}", filter_time_s=f"{self.last_est.stamp_s:.3f}")
        if self.flag.raised_at_s is not None:
            vals["aligned_raised_at_s"] = f"{self.flag.raised_at_s:.3f}"
            vals["aligned_first_raised_at_s"] = f"{self.flag.first_raised_at_s:.3f}"
        if self.init_t is not None:
            vals["initialised_at_s"] = f"{self.init_t:.3f}"
        lo, hi = self.flag.band
        vals.update(nis_last=f"{self.last_nis:.3f}", nis_window_sum=f"{self.flag.nis_sum:.3f}",
                    nis_band=f"[{lo:.2f}, {hi:.2f}]", last_reject=self.last_reject)
        if self.last_imu_t is not None and self.last_accepted_fix_t is not None:
            age = self.last_imu_t - self.last_accepted_fix_t
            vals["gnss_age_s"] = f"{age:.2f}"
            if age > self.params["gnss_timeout_s"] and self.state != STATE_FAULT:
                st.level = max(st.level, DiagnosticStatus.WARN)
                st.message += f"; no GNSS fix for {age:.0f} s"
        if self.timing_s:  # over the last 100,000 Imu messages
            tt = np.asarray(self.timing_s) * 1e6
            age = np.asarray(self.stamp_age_s) * 1e3
            vals.update(imu_callback_median_us=f"{np.median(tt):.1f}", imu_callback_p99_us=f"{np.percentile(tt, 99):.1f}",
                        imu_callback_max_us=f"{np.max(tt):.1f}", imu_callback_total_s=f"{np.sum(tt) * 1e-6:.3f}",
                        imu_stamp_age_median_ms=f"{np.median(age):.3f}",
                        imu_stamp_age_p99_ms=f"{np.percentile(age, 99):.3f}")
        vals.update({k: str(v) for k, v in self.counters.items()})
        vals.update(self._core_diagnostics())
        st.values = [KeyValue(key=k, value=str(v)) for k, v in vals.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self.pub_diag.publish(arr)


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = AlignmentNode()
        rclpy.spin(node)
        return 0
    except KeyboardInterrupt:
        return 0
    except ValueError as exc:
        print(f"alignment_node: bad parameter: {exc}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - shutdown path
        if rclpy.ok():
            raise
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main())
