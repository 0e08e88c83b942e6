"""alignment_node: the ROS 2 adapter of :class:`insalign_ros.session.AlignmentSession`.

Topics (relative names, remappable as usual):

- in ``imu/data`` sensor_msgs/Imu, ``gps/fix`` sensor_msgs/NavSatFix (QoS ``imu_qos`` / ``gnss_qos``: the
  sensor-data profile by default, which matches reliable and best-effort publishers), ``ground_truth/pose``
  geometry_msgs/PoseStamped (optional: initialisation in tests and the Euler errors), ``gps/vel``
  geometry_msgs/TwistWithCovarianceStamped (optional: the GNSS antenna's ENU velocity relative to Earth, as u-blox,
  NovAtel and MicroStrain drivers publish it; QoS ``gnss_qos``; fused at its stamp like a fix by the cores that
  declare ``supports_gnss_velocity``; the antenna offset is the core parameter ``gnss_lever_arm_b_m``). The Imu's rates and specific
  forces are turned into the vehicle FLU frame once, in the callback (``imu_axes``, ``imu_mount_rpy_deg``:
  conversions.imu_to_vehicle_matrix; the convention is written there and in docs/nodes.md);
- out ``~/pose`` PoseWithCovarianceStamped (frame ``enu_frame_id``: local ENU anchored at the initial position;
  orientation body FLU -> ENU; covariance in the ROS order x y z rot x rot y rot z [m^2, rad^2]),
  ``~/euler_error`` and ``~/euler_error_3sigma`` geometry_msgs/Vector3Stamped (roll, pitch, yaw [deg]; the error
  only when ground truth is present), ``~/aligned`` std_msgs/Bool (reliable, transient local), ``/diagnostics``;
  ``~/imu`` sensor_msgs/Imu (frame ``body_frame_id``: the estimated orientation vehicle FLU -> ENU with the REP 145
  orientation covariance, and the measured rate and specific force of the IMU sample at that stamp:
  conversions.imu_msg), ``~/datum`` sensor_msgs/NavSatFix (reliable, transient local: the ENU origin of ``~/pose``,
  published at each initialisation);
- service ``~/reset`` std_srvs/Trigger: drop the estimate and every buffered input, start the alignment over.

The node only converts messages to samples and pushes them into the session; a timer (``process_rate_hz``) takes
the Imu and ground-truth messages waiting in their readers (polled: one wake-up per tick, not one per message; the
Imu read from the serialized bytes in one numpy pass, conversions.imu_records_from_cdr), lets the session process the
buffered inputs in stamp order and publishes what comes out (docs/nodes.md, "CPU share"). The node decides
nothing the session could (docs/session.md, docs/nodes.md). ``core`` and ``imu_grade`` are read-only after start: a different core
means a different parameter set (restart the node, or call the reset with a new configuration file).
"""

from __future__ import annotations

import bisect
import gc
import math
import sys
import time
from collections import OrderedDict, deque

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistWithCovarianceStamped, Vector3Stamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ..core.types import GnssVelocity, ImuSample
from ..session.flag import AlignedCriteria
from ..session import catalog
from ..session.config import SessionConfig
from ..session.session import AlignmentSession, Ring, TruthSample
from . import conversions as cv
from .qos import QOS_CHOICES, imu_qos

_SESSION_DOC = {  # session parameters the node exposes under the same names (SessionConfig has the meaning)
    "init_mode": "sensors (no guess: position/velocity from the fixes, level from the accelerometers, unknown heading "
                 "-> yaw bank), guess (initial_rpy_deg) or truth (ground_truth/pose; init_from_ground_truth)",
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
_CORE_DOC = {"gnss_lever_arm_b_m": "GNSS antenna position in the body frame FLU relative to the IMU [m] (x forward, "
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
    "enu_frame_id": ("enu", "frame_id of ~/pose", False),
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
_RANGES = {"pose_rate_hz": (0.0, 1000.0), "gnss_sigma_m": (1e-3, 1e4), "diagnostics_period_s": (0.01, 60.0),
           "process_rate_hz": (1.0, 1000.0), "log_throttle_s": (0.0, 3600.0), "max_gap_s": (0.05, 3600.0),
           "max_fix_lag_s": (0.0, 10.0), "gap_factor": (1.1, 100.0), "imu_timeout_s": (0.0, 3600.0)}
#: Imu messages over which /diagnostics reports the node's time per message and the stamp age
_STATS_WINDOW = 20000
_INT_RANGES = {"imu_qos_depth": (1, 100000), "gnss_qos_depth": (1, 100000), "time_jump_confirm": (1, 1000),
               "backtrack_passes": (0, 10)}


def _latched_qos() -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _descriptor(name: str, default, text: str, read_only: bool) -> ParameterDescriptor:
    d = ParameterDescriptor(description=text, read_only=read_only)
    if isinstance(default, float) and not isinstance(default, bool):
        d.dynamic_typing = True  # an integer given for a double (-p gnss_sigma_m:=2) is accepted, then coerced
        if name in _RANGES:
            lo, hi = _RANGES[name]
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
            d.additional_constraints = f"range [{lo:g}, {hi:g}]"
    elif isinstance(default, int) and not isinstance(default, bool) and name in _INT_RANGES:
        lo, hi = _INT_RANGES[name]
        d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=1)]
    return d


def _coerce(old, new):
    """An int for a float (and a list of ints for a list of floats) is accepted; other type changes are errors."""
    if isinstance(old, float) and isinstance(new, int) and not isinstance(new, bool):
        return float(new)
    if isinstance(old, (list, tuple)) and isinstance(new, (list, tuple)):
        return [float(x) if isinstance(x, int) and not isinstance(x, bool) else x for x in new]
    if type(new) is not type(old):
        raise ValueError(f"wrong type: expected {type(old).__name__}, got {new!r}")
    return new


class AlignmentNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("alignment_node", **node_kwargs)
        self.defaults: dict = {}
        for name, (default, text, ro) in NODE_PARAMS.items():
            self._declare(name, default, text, ro)
        for name, default in SessionConfig().to_dict().items():
            if name in _SESSION_DOC:
                self._declare(name, default, _SESSION_DOC[name], False)
        for name, default in AlignedCriteria().to_dict().items():
            self._declare(f"aligned.{name}", default, f"aligned flag criterion {name} (session/flag.py)", False)
        core = self.get_parameter("core").value
        core_defaults = catalog.core_defaults(core)  # ValueError: unknown core, exit 2
        self.core_name = core
        self.core_param_names = list(core_defaults)
        grade = self.get_parameter("imu_grade").value
        from_grade = catalog.grade_defaults(grade, core)  # ValueError: unknown grade, exit 2
        for name, default in core_defaults.items():
            if name in from_grade:
                self._declare(name, from_grade[name], f"{core} core parameter, default from imu_grade {grade} "
                                                      "(docs/imu_grades.md)", False)
            elif name not in self.defaults:
                self._declare(name, default, _CORE_DOC.get(name, f"{core} core parameter (config/{core}.yaml)"), False)
        p = {n: self._coerced(n) for n in self.defaults}
        self.session = AlignmentSession(*self._session_args(p), log=self._log)  # ValueError: bad value, exit 2
        self.imu_sub = None  # the Imu subscription, polled by _take_inputs (not dispatched per message by the executor)
        self._polled: list = []  # subscriptions the executor does not see (_poll_only), destroyed with the node
        self._apply_node_params(p)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        qi = imu_qos(p["imu_qos"], p["imu_qos_depth"])
        self.imu_sub = self.create_subscription(Imu, "imu/data", self._on_imu, qi)
        self.fix_sub = self.create_subscription(NavSatFix, "gps/fix", self._on_fix,
                                                imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.vel_sub = self.create_subscription(TwistWithCovarianceStamped, "gps/vel", self._on_vel,
                                                imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.truth_sub = self.create_subscription(PoseStamped, "ground_truth/pose", self._on_truth, qi)
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "~/pose", 50)
        self.pub_err = self.create_publisher(Vector3Stamped, "~/euler_error", 50)
        self.pub_err3 = self.create_publisher(Vector3Stamped, "~/euler_error_3sigma", 50)
        self.pub_aligned = self.create_publisher(Bool, "~/aligned", _latched_qos())
        self.pub_imu = self.create_publisher(Imu, "~/imu", 50)
        self.pub_datum = self.create_publisher(NavSatFix, "~/datum", _latched_qos())
        self.create_service(Trigger, "~/reset", self._on_reset)
        self._datum_anchor = None  # the session anchor last published on ~/datum
        #: measured samples (vehicle FLU) by stamp, for ~/imu: stamp -> (omega, f, cov omega, cov f), arrival order
        self._recent_imu: OrderedDict = OrderedDict()
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._log_state: dict = {}
        self.published_aligned = False
        self.pub_aligned.publish(Bool(data=False))
        # over the last _STATS_WINDOW Imu messages: /diagnostics reads their quantiles every second (deques of 100,000
        # cost 9-12 ms, 1 % of a core, once full after 13 min at 125 Hz; of 20,000 ~3 ms; rings of 20,000 ~0.7 ms)
        self.timing_s = Ring(_STATS_WINDOW)  # node time per Imu message [s] (benchmarks read it)
        self.stamp_age_s = Ring(_STATS_WINDOW)  # DDS reception time minus header stamp [s]
        self.process_s: deque = deque(maxlen=10000)
        self._cov_ok: dict = {}
        self._imu_ok: set = set()  # conversions.imu_cdr_key of Imu messages that passed the message-level checks
        self._prev_imu_stamp: float | None = None
        self._noise_done = False
        self.epoch_s: int | None = None
        self.frames_seen: set = set()
        self.create_timer(1.0 / p["process_rate_hz"], self._process)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics)
        self.get_logger().info(f"alignment_node: core {self.core_name}, waiting for imu/data and gps/fix")

    # ------------------------------------------------------------------ parameters
    def _declare(self, name: str, default, text: str, read_only: bool) -> None:
        self.defaults[name] = default
        self.declare_parameter(name, default, _descriptor(name, default, text, read_only))

    def _coerced(self, name: str):
        try:
            return _coerce(self.defaults[name], self.get_parameter(name).value)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None

    def _session_args(self, p: dict):
        sp = {k: p[k] for k in _SESSION_DOC}
        sp["core"], sp["imu_grade"] = p["core"], p["imu_grade"]
        if p["init_from_ground_truth"]:
            sp["init_mode"] = "truth"
        sp["output_period_s"] = 1.0 / p["pose_rate_hz"] if p["pose_rate_hz"] > 0 else 0.0
        core_params = {n: p[n] for n in self.core_param_names}
        if core_params.get("lmi_async") == "auto":  # PI-LIEKF: never solve the LMI inside the processing timer
            core_params["lmi_async"] = "true"
        crit = AlignedCriteria(**{k.split(".", 1)[1]: p[k] for k in p if k.startswith("aligned.")})
        crit.validate()
        cfg = SessionConfig.from_dict(sp)
        catalog.check_core_config(cfg, core_params)  # the session checks again; this gives the reason at start-up
        return cfg, core_params, crit

    def _apply_node_params(self, p: dict) -> None:
        for name in ("imu_qos", "gnss_qos"):
            if p[name] not in QOS_CHOICES:
                raise ValueError(f"{name}: must be one of {QOS_CHOICES}, got {p[name]!r}")
        if p["imu_axes"] not in cv.IMU_AXES:
            raise ValueError(f"imu_axes: must be one of {cv.IMU_AXES}, got {p['imu_axes']!r}")
        C = cv.imu_to_vehicle_matrix(p["imu_axes"], p["imu_mount_rpy_deg"])
        self.C_s_v = None if np.array_equal(C, np.eye(3)) else C  # driver axes -> vehicle FLU (None: identity)
        self._imu_ok = set()  # imu_frame_id may have changed: every kind of Imu message is checked again
        self.params = p
        self.throttle_s = float(p["log_throttle_s"])
        self.criteria = self.session.flag.criteria
        self.pose_period_s = self.session.cfg.output_period_s

    def _on_set_parameters(self, params) -> SetParametersResult:
        self._take_inputs()
        p = dict(self.params)
        try:
            for prm in params:
                if prm.name not in p:
                    return SetParametersResult(successful=False, reason=f"unknown parameter {prm.name}")
                if NODE_PARAMS.get(prm.name, (None, None, False))[2]:
                    return SetParametersResult(successful=False, reason=f"{prm.name} is read-only (set it at start; "
                                                                        "restart the node to change it)")
                p[prm.name] = _coerce(self.defaults[prm.name], prm.value)
            cfg, core_params, crit = self._session_args(p)
        except (ValueError, TypeError) as exc:
            reason = str(exc) if any(prm.name in str(exc) for prm in params) else f"{params[0].name}: {exc}"
            self.get_logger().warning(f"parameter change refused: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        restarted = self.session.reconfigure(cfg, core_params, crit)
        self._apply_node_params(p)
        if restarted:
            self.get_logger().warning("core parameters changed: the alignment restarts")
            self._publish_flag()
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ logging
    def _log(self, level: str, key: str, text: str) -> None:
        if level == "info":
            self.get_logger().info(text)
        elif level == "error":
            self.get_logger().error(text, throttle_duration_sec=max(self.throttle_s, 1e-3))
        else:
            self._warn_throttled(key, text)

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

    # ------------------------------------------------------------------ callbacks: convert and push, nothing else
    def poll_inputs(self) -> None:
        """Every input taken by the processing tick (:meth:`_take_inputs`) instead of one executor dispatch per
        message. For the EventsExecutor (``main``): with rclpy's SingleThreadedExecutor the polled subscriptions'
        QoS-event waitables kept its wait set busy (69 % of a core, measured), so there the executor dispatches every
        message to its callback as before."""
        for sub in (self.imu_sub, self.fix_sub, self.vel_sub, self.truth_sub):
            if sub not in self._polled:
                self._poll_only(sub)

    def _poll_only(self, sub) -> None:
        """Take ``sub`` out of the executor's view: its messages wait in the DDS reader (keep-last ``imu_qos_depth``)
        until :meth:`_take_inputs` takes them, instead of one executor dispatch (take, Python message, callback) per
        message, the largest share of the node's Python work at 125 Hz (docs/nodes.md, "CPU share"); taken
        serialized, a batch is read in one numpy pass. rclpy has no public switch for
        this: the subscription stays in the node's graph, QoS and remaps, only the node's list the executors read
        (``Node._subscriptions``) loses it, and :meth:`destroy_node` destroys it."""
        self._subscriptions.remove(sub)
        self._polled.append(sub)
        self._wake_executor()

    def _take_inputs(self) -> None:
        """Every message waiting in the polled readers, to the session in DDS reception order (``received_timestamp``),
        as one callback per message would have given them: the Imu messages first (serialized, :meth:`_on_imu_batch`
        for each run between two fixes or velocities), then the fixes and velocities, which arrived after the Imu
        messages taken before them are handed over, then the ground truth. Called by the processing tick and before a
        reset, a parameter change and diagnostics."""
        t0 = time.perf_counter()
        raws, recv = [], []
        if self.imu_sub in self._polled:
            for raw, info in _take_all(self.imu_sub, raw=True):
                raws.append(raw)
                recv.append(info["received_timestamp"])
        others = []
        for sub, on_msg in ((self.fix_sub, self._on_fix), (self.vel_sub, self._on_vel)):
            if sub in self._polled:
                others += [(got[1]["received_timestamp"], on_msg, got[0]) for got in _take_all(sub)]
        others.sort(key=lambda e: e[0])
        i = 0
        for received_ns, on_msg, msg in others:
            j = bisect.bisect_right(recv, received_ns, lo=i)
            if j > i:
                self._on_imu_batch(raws[i:j], recv[i:j], t0)
                t0 = time.perf_counter()
            i = j
            on_msg(msg)
        if i < len(raws):
            self._on_imu_batch(raws[i:], recv[i:], t0)
        if self.truth_sub in self._polled:
            for got in _take_all(self.truth_sub):
                self._on_truth(got[0])

    def _on_imu_batch(self, raws: list, received_ns: list, t0: float) -> None:
        """Serialized Imu messages in arrival order -> the session, as :meth:`_on_imu` one by one would. A message
        whose frame_id and covariances already passed the message-level checks (:func:`conversions.imu_cdr_key` in
        ``_imu_ok``), with a stamp and a finite orientation, is read from numpy records
        (:func:`conversions.imu_records_from_cdr`, one pass per batch); any other goes through rclpy's
        deserialisation and :meth:`_on_imu` (the first of a kind, and every rejection with its reason)."""
        n = len(raws)
        fast = [None] * n
        if self.epoch_s is not None and not (self.params["use_imu_covariance"] and not self._noise_done):
            ok_keys = self._imu_ok
            for rows, rec in cv.imu_records_from_cdr(raws):
                sec, nsec, q = rec["sec"], rec["nanosec"], rec["q"]
                t = (sec - self.epoch_s).astype(float) + 1e-9 * nsec  # as conversions.imu_sample_fast, per message
                stamp = sec + 1e-9 * nsec
                good = ((sec > 0) | (nsec > 0)) & np.isfinite(q[:, 0] + q[:, 1] + q[:, 2] + q[:, 3])
                # copies: the records are read-only views of the message bytes
                w, f = cv.imu_to_vehicle(np.array(rec["w"]), np.array(rec["f"]), self.C_s_v)
                cw, cf = np.array(rec["cov_w"]), np.array(rec["cov_f"])
                for i, k in enumerate(rows):
                    if good[i] and cv.imu_cdr_key(raws[k]) in ok_keys:
                        fast[k] = (float(t[i]), w[i], f[i], cw[i], cf[i], float(stamp[i]))
        session, recent, ages = self.session, self._recent_imu, []
        n_fast = 0
        t_slow = 0.0
        for k in range(n):
            s = fast[k]
            if s is None:
                t1 = time.perf_counter()
                if self._on_imu(deserialize_message(raws[k], Imu), received_ns[k]):
                    if len(self._imu_ok) > 1000:
                        self._imu_ok.clear()
                    self._imu_ok.add(cv.imu_cdr_key(raws[k]))
                t_slow += time.perf_counter() - t1
                continue
            n_fast += 1
            if session.push_imu(ImuSample(s[0], s[1], s[2]), time.monotonic()):
                recent[s[0]] = s[1:5]
            ages.append(1e-9 * received_ns[k] - s[5])
        if n_fast:  # the node's time per Imu message of the batch (take, records, push), for /diagnostics
            self.timing_s.extend(np.full(n_fast, (time.perf_counter() - t0 - t_slow) / n_fast))
            self.stamp_age_s.extend(np.asarray(ages))

    def _on_imu(self, msg: Imu, received_ns: int | None = None) -> bool:
        """One Imu message (``received_ns``: its DDS reception time [ns, system clock]; None: now). True when it
        passed the message-level checks (frame_id, stamp, orientation, covariances), whatever the session did."""
        t0 = time.perf_counter()
        wall = time.monotonic()
        p = self.params
        frame = p["imu_frame_id"]
        h = msg.header
        if h.frame_id not in self.frames_seen:
            self._note_frame("Imu", h.frame_id)
        passed = False
        if frame and h.frame_id != frame:
            self.session.reject_input("imu", "imu_frame", f"frame_id {h.frame_id!r} is not {frame!r}", wall)
        else:
            sample, reason = cv.imu_sample_fast(msg, self._cov_ok, self._epoch(msg), self.C_s_v)
            if sample is None:
                self.session.reject_input("imu", "imu_invalid", reason, wall)
            else:
                passed = True
                if p["use_imu_covariance"] and not self._noise_done:
                    self._noise_from(msg, sample.stamp_s)
                if self.session.push_imu(sample, wall):
                    self._recent_imu[sample.stamp_s] = (sample.omega_ib_b, sample.f_ib_b,
                                                        msg.angular_velocity_covariance,
                                                        msg.linear_acceleration_covariance)
        self.timing_s.append(time.perf_counter() - t0)
        received = time.time() if received_ns is None else 1e-9 * received_ns
        self.stamp_age_s.append(received - (h.stamp.sec + 1e-9 * h.stamp.nanosec))
        return passed

    def _noise_from(self, msg: Imu, t: float) -> None:
        """use_imu_covariance: the noise densities from the Imu covariances and the interval of two messages."""
        prev, self._prev_imu_stamp = self._prev_imu_stamp, t
        if prev is None or not t > prev:
            return
        noise = {k: v for k, v in cv.imu_noise_from_msg(msg, t - prev).items() if k in self.core_param_names}
        self._noise_done = True
        if noise:
            self.session.core_params.update(noise)
            self.get_logger().info(f"noise from the Imu covariances: {noise}")

    def _on_fix(self, msg: NavSatFix) -> None:
        wall = time.monotonic()
        fix, reason = cv.fix_from_msg(msg, self.params["gnss_sigma_m"], self.params["gnss_frame_id"],
                                      self._epoch(msg))
        if fix is None:
            counter = ("gnss_no_fix" if reason.startswith("no fix") else
                       "gnss_frame" if reason.startswith("frame_id") else "gnss_invalid")
            self.session.reject_input("gnss", counter, reason, wall)
            return
        self.session.push_fix(fix, wall)

    def _on_vel(self, msg: TwistWithCovarianceStamped) -> None:
        """gps/vel: the ENU linear velocity and the linear block of the covariance, as they are (the session
        validates: non-finite values, a zero or unknown covariance and implausible speeds are counted and rejected)."""
        lin = msg.twist.twist.linear
        R = np.asarray(msg.twist.covariance, float).reshape(6, 6)[:3, :3]
        self.session.push_velocity(GnssVelocity(cv.stamp_s(msg, self._epoch(msg)), np.array([lin.x, lin.y, lin.z]), R),
                                   time.monotonic())

    def _on_truth(self, msg: PoseStamped) -> None:
        val, reason = cv.truth_from_msg(msg, self._epoch(msg))
        if val is None:
            self.session.counters["truth_invalid"] += 1
            self._warn_throttled("truth_invalid", f"rejected ground truth: {reason}")
            return
        self.session.push_truth(TruthSample(val[0], val[1], val[2]))

    def _note_frame(self, kind: str, frame_id: str) -> None:
        """Log each frame_id once (a second one on the same topic is worth a warning: two publishers?)."""
        self.frames_seen.add(frame_id)
        text = f"{kind} frame_id {frame_id!r} seen (imu_frame_id {self.params['imu_frame_id']!r}: " + (
            "any accepted)" if not self.params["imu_frame_id"] else "only that one accepted)")
        if len(self.frames_seen) > 1:
            self.get_logger().warning(text + f"; frames seen so far: {sorted(self.frames_seen)}")
        else:
            self.get_logger().info(text)

    def _epoch(self, msg) -> int:
        """The whole second of the first stamp seen: the session works in seconds after it (float resolution)."""
        if self.epoch_s is None:
            self.epoch_s = int(msg.header.stamp.sec)
            self.session.stamp_offset_s = float(self.epoch_s)
        return self.epoch_s

    # ------------------------------------------------------------------ processing and outputs
    def _process(self) -> None:
        self._take_inputs()
        t0 = time.perf_counter()
        try:
            outs = self.session.process(time.monotonic())
        except Exception as exc:  # noqa: BLE001 - the session guards the core; this is a last resort
            self.get_logger().error(f"session error {type(exc).__name__}: {exc}", throttle_duration_sec=5.0)
            outs = []
        frame = self.params["enu_frame_id"]
        if self.session.anchor is not self._datum_anchor:
            self._publish_datum()
        # the volatile outputs are built only for a publisher with a matched subscription: a message published
        # without one is dropped by DDS anyway (~/aligned, ~/datum: transient local, always; docs/nodes.md, "CPU share")
        pose, imu, err, err3 = ((p.get_subscription_count() > 0 for p in (self.pub_pose, self.pub_imu, self.pub_err,
                                                                          self.pub_err3)) if outs else (False,) * 4)
        for o in outs:
            est = o.estimate
            if pose or imu:
                q = cv.quat_xyzw(est.C_b_n)  # once for ~/pose and ~/imu
            if pose:
                self.pub_pose.publish(cv.pose_msg(est, self.session.anchor, frame, "", self.epoch_s, q))
            if imu:
                self.pub_imu.publish(cv.imu_msg(est, self.params["body_frame_id"], self.epoch_s,
                                                self._measured_sample(o.stamp_s), q))
            err_o = err and o.euler_error_deg is not None
            if not (err3 or err_o):
                continue
            m3 = Vector3Stamped()
            cv.set_stamp(m3, o.stamp_s, self.epoch_s)
            m3.header.frame_id = frame
            if err_o:
                me = Vector3Stamped()
                me.header = m3.header
                me.vector.x, me.vector.y, me.vector.z = (float(x) for x in o.euler_error_deg)
                self.pub_err.publish(me)
            if err3:
                m3.vector.x, m3.vector.y, m3.vector.z = (float(x) for x in o.euler_3sigma_deg)
                self.pub_err3.publish(m3)
        self._publish_flag()
        self._forget_samples()
        if outs:
            self.process_s.append(time.perf_counter() - t0)

    def _measured_sample(self, t: float):
        """The measured sample at output stamp ``t`` for ~/imu, covariances in vehicle FLU; None when there is none
        (a sample bridging a gap)."""
        s = self._recent_imu.get(t)
        if s is None:
            return None
        return s[0], s[1], cv.covariance_to_vehicle(s[2], self.C_s_v), cv.covariance_to_vehicle(s[3], self.C_s_v)

    def _forget_samples(self) -> None:
        """Drop the samples the session has processed (their outputs are out), and keep the store bounded."""
        t = self.session.filter_time_s
        d = self._recent_imu
        while d and ((t is not None and next(iter(d)) < t) or len(d) > self.session.MAX_BUFFER):
            d.popitem(last=False)

    def _publish_datum(self) -> None:
        """~/datum: the ENU origin of ~/pose, once per initialisation (transient local: late joiners get it)."""
        s = self.session
        self._datum_anchor = s.anchor
        if s.anchor is None:
            return
        self.pub_datum.publish(cv.datum_msg(s.anchor, s.init_t, self.params["enu_frame_id"], self.epoch_s))
        self.get_logger().info(f"datum (ENU origin of ~/pose): lat {math.degrees(s.anchor[0]):.7f} deg, lon "
                               f"{math.degrees(s.anchor[1]):.7f} deg, h {s.anchor[2]:.2f} m")

    def _on_reset(self, request, response):
        """~/reset (std_srvs/Trigger): restart the alignment from nothing (the session's reset)."""
        self._take_inputs()
        was = self.session.status.value
        self.session.reset("reset service")
        self._recent_imu.clear()
        self._publish_datum()
        self._publish_flag()
        self.get_logger().warning(f"alignment restarted by ~/reset (was: {was})")
        response.success = True
        response.message = (f"alignment restarted (core {self.core_name}; was {was}); buffered inputs dropped, "
                            f"~/datum is published again at the next initialisation")
        return response

    def _publish_flag(self) -> None:
        now = self.session.aligned
        if now != self.published_aligned:
            self.published_aligned = now
            self.pub_aligned.publish(Bool(data=now))

    # ------------------------------------------------------------------ status (read by tests and benchmarks)
    @property
    def state(self) -> str:
        return self.session.status.value

    @property
    def flag(self):
        return self.session.flag

    def _publish_diagnostics(self) -> None:
        self._take_inputs()
        s = self.session
        st = DiagnosticStatus()
        st.name = f"{self.get_name()}: alignment"
        st.hardware_id = self.core_name
        st.level = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)[s.level()]
        st.message = s.message()
        vals = s.diagnostics()
        vals.pop("message", None)
        if len(self.timing_s):  # over the last _STATS_WINDOW Imu messages
            tt = self.timing_s.view()
            t50, t99, tmax = _quantiles(tt, (50.0, 99.0, 100.0))
            a50, a99 = _quantiles(self.stamp_age_s.view(), (50.0, 99.0))
            vals.update(imu_callback_median_us=f"{t50 * 1e6:.1f}", imu_callback_p99_us=f"{t99 * 1e6:.1f}",
                        imu_callback_max_us=f"{tmax * 1e6:.1f}", imu_callback_total_s=f"{np.sum(tt):.3f}",
                        imu_stamp_age_median_ms=f"{a50 * 1e3:.3f}", imu_stamp_age_p99_ms=f"{a99 * 1e3:.3f}")
        vals.update(session_process_total_s=f"{s.timing['process_s']:.3f}",
                    session_samples=str(s.timing["samples"]))
        st.values = [KeyValue(key=k, value=v if isinstance(v, str) else _json(v)) for k, v in vals.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self.pub_diag.publish(arr)

    def destroy_node(self):
        self.session.close()
        self._subscriptions.extend(self._polled)  # back in the node's list: rclpy destroys them with the node
        self._polled = []
        self.imu_sub = None
        return super().destroy_node()


def _quantiles(x: np.ndarray, qs) -> list[float]:
    """``np.percentile(x, qs)`` (linear interpolation) from one ``np.partition`` (~2x cheaper than percentile for
    20,000 values)."""
    n = x.shape[0]
    pos = [q / 100.0 * (n - 1) for q in qs]
    lo = [min(int(p), n - 1) for p in pos]
    y = np.partition(x, sorted({k for j in lo for k in (j, min(j + 1, n - 1))}))
    return [float(y[j] + (p - j) * (y[min(j + 1, n - 1)] - y[j])) for p, j in zip(pos, lo)]


def _take_all(sub, raw: bool = False) -> list:
    """Every message waiting in a polled subscription's reader: [(msg, info), ...] in reception order (``raw``: the
    serialized CDR bytes instead of a Python message)."""
    out = []
    with sub.handle:
        for _ in range(sub.qos_profile.depth + 1):  # bounded: a reader holds at most depth messages
            got = sub.handle.take_message(sub.msg_type, raw)
            if got is None:
                break
            out.append(got)
    return out


def _json(v) -> str:
    import json

    try:
        return json.dumps(v, default=str)
    except (TypeError, ValueError):
        return str(v)


def make_executor(kind: str, context=None):
    """``events``: rclpy.experimental.EventsExecutor (measured faster: docs/nodes.md); ``single``: the default."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor(context=context)
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor(context=context)


def spin(executor, context=None) -> None:
    """spin_once with a timeout until shutdown: EventsExecutor.spin() busy-waits (58 % of a core with the node
    idle, measured) and does not return on SIGINT with the PyPI wheels; spin_once(0.1) idles at ~0 % and
    processes every ready event per call (docs/nodes.md, "Executor")."""
    while rclpy.ok(context=context):
        executor.spin_once(timeout_sec=0.1)


def main(args=None) -> int:
    from ..eval.parallel import pin_solver_threads

    pin_solver_threads()  # PI-LIEKF's LMI solver: one rayon thread (no os-wide pool of idle spinning threads)
    rclpy.init(args=args)
    node = None
    try:
        try:
            node = AlignmentNode()
        except (ValueError, TypeError) as exc:
            print(f"alignment_node: bad parameter: {exc}", file=sys.stderr)
            return 2
        except rclpy.exceptions.InvalidParameterTypeException as exc:
            print(f"alignment_node: bad parameter type: {exc}", file=sys.stderr)
            return 2
        import os

        kind = os.environ.get("INSALIGN_EXECUTOR", "events")
        if kind == "events" and node.params["poll_inputs"]:
            node.poll_inputs()
        ex = make_executor(kind)
        ex.add_node(node)
        # the ~140,000 objects of the imports and the set-up never die: out of the cyclic collector's full passes
        # (~0.1-0.2 s each, measured; docs/nodes.md, "CPU share")
        gc.freeze()
        spin(ex)
        return 0
    except KeyboardInterrupt:
        return 0
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
