"""alignment_node: the ROS 2 adapter of :class:`insalign_ros.session.AlignmentSession`.

Topics (relative names, remappable as usual):

- in ``imu/data`` sensor_msgs/Imu, ``gps/fix`` sensor_msgs/NavSatFix (QoS ``imu_qos`` / ``gnss_qos``: the
  sensor-data profile by default, which matches reliable and best-effort publishers), ``ground_truth/pose``
  geometry_msgs/PoseStamped (optional: initialisation in tests and the Euler errors), ``gps/vel``
  geometry_msgs/TwistWithCovarianceStamped (optional: the GNSS antenna's ENU velocity relative to Earth, as u-blox,
  NovAtel and MicroStrain drivers publish it; QoS ``gnss_qos``; fused at its stamp like a fix by the cores that
  accept the GNSS velocity model; the antenna offset is the core parameter ``gnss_lever_arm_b_m``), ``wheel/odom``
  nav_msgs/Odometry (optional: wheel speed, twist.linear.x in the child frame) and ``gps/heading`` sensor_msgs/Imu
  (optional: a dual-antenna heading as ublox_gps publishes it, the orientation's ENU yaw), QoS ``gnss_qos``, counted
  and queued by the session (conversions.wheel_speed_from_odometry, gnss_heading_from_imu_msg). The Imu's rates and specific
  forces are turned into the vehicle FLU frame once, in the callback (``imu_axes``, ``imu_mount_rpy_deg``:
  conversions.imu_to_vehicle_matrix; the convention is written there and in docs/nodes.md);
- out ``~/pose`` PoseWithCovarianceStamped (frame ``world_frame``, REP 105: local ENU anchored at the initial position;
  orientation body FLU -> ENU; covariance in the ROS order x y z rot x rot y rot z [m^2, rad^2]),
  ``~/euler_error`` and ``~/euler_error_3sigma`` geometry_msgs/Vector3Stamped (roll, pitch, yaw [deg]; the error
  only when ground truth is present), ``~/aligned`` std_msgs/Bool (reliable, transient local), ``/diagnostics``;
  ``~/imu`` sensor_msgs/Imu (frame ``body_frame_id``: the estimated orientation vehicle FLU -> ENU with the REP 145
  orientation covariance, and the measured rate and specific force of the IMU sample at that stamp:
  conversions.imu_msg), ``~/datum`` sensor_msgs/NavSatFix (reliable, transient local: the ENU origin of ``~/pose``,
  published at each initialisation);
- service ``~/reset`` std_srvs/Trigger: drop the estimate and every buffered input, start the alignment over;
- /tf world_frame -> tf_child_frame (``publish_tf``). The outputs, the flag before them, the ~/imu gating and the
  restarts: nodes/publishing.py; the parameter table, ranges and validation: nodes/params.py.

Start-up: the parameters are checked (one line and exit 2 on a bad value), the numba kernels compiled
(session.warmup: "ready (kernels compiled in X s)"), and only then the node subscribes.

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
from geometry_msgs.msg import PoseStamped, TwistWithCovarianceStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, NavSatFix
from std_srvs.srv import Trigger

from ..core.types import GnssVelocity, ImuSample
from ..session.flag import AlignedCriteria
from ..session import catalog
from ..session.config import SessionConfig
from ..session.session import AlignmentSession, Ring, TruthSample
from . import conversions as cv
from .params import (NODE_PARAMS, SESSION_DOC, SPECS, check_value, coerce, descriptor, rename_deprecated,
                     unknown_parameters)
from .publishing import OutputPublisher, quantiles as _quantiles  # noqa: F401  (re-exported for tests)
from .qos import QOS_CHOICES, imu_qos

_SESSION_DOC = SESSION_DOC  # re-exported (test_imu_grade)

#: Imu messages over which /diagnostics reports the node's time per message and the stamp age
_STATS_WINDOW = 20000


class AlignmentNode(Node):
    def __init__(self, warm_up: bool = True, **node_kwargs) -> None:
        super().__init__("alignment_node", **node_kwargs)
        self.defaults: dict = {}
        for spec in SPECS.values():  # node, session and flag parameters (descriptions and ranges: field metadata)
            self._declare(spec.name, spec.default, spec.doc, spec.read_only)
        core = self.get_parameter("core").value
        core_defaults = catalog.core_defaults(core)  # ValueError: unknown core, exit 2
        self.core_name = core
        self.core_param_names = list(core_defaults)
        grade = self.get_parameter("imu_grade").value
        for line in rename_deprecated(self._parameter_overrides, core_defaults):
            self.get_logger().warning(line)
        for spec in catalog.core_parameter_specs(core, grade):  # ValueError: unknown grade, exit 2
            if spec.name not in self.defaults:
                self._declare(spec.name, spec.default, spec.doc, spec.read_only)
        for line in unknown_parameters(self._parameter_overrides, self.defaults, core):
            self.get_logger().warning(line)
        p = {n: self._coerced(n) for n in self.defaults}
        self.session = AlignmentSession(*self._session_args(p), log=self._log)  # ValueError: bad value, exit 2
        self.imu_sub = None  # the Imu subscription, polled by _take_inputs (not dispatched per message by the executor)
        self._polled: list = []  # subscriptions the executor does not see (_poll_only), destroyed with the node
        self._apply_node_params(p)
        self.add_pre_set_parameters_callback(self._pre_set_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        #: measured samples (vehicle FLU) by stamp, for ~/imu: stamp -> (omega, f, cov omega, cov f), arrival order
        self._recent_imu: OrderedDict = OrderedDict()
        self._log_state: dict = {}
        self.out = OutputPublisher(self)  # every publisher, the flag, the restarts (nodes/publishing.py)
        self.pub_pose, self.pub_imu, self.pub_aligned = self.out.pub_pose, self.out.pub_imu, self.out.pub_aligned
        self.process_s = self.out.process_s
        self.create_service(Trigger, "~/reset", self._on_reset)
        # over the last _STATS_WINDOW Imu messages: /diagnostics reads their quantiles every second (deques of 100,000
        # cost 9-12 ms, 1 % of a core, once full after 13 min at 125 Hz; of 20,000 ~3 ms; rings of 20,000 ~0.7 ms)
        self.timing_s = Ring(_STATS_WINDOW)  # node time per Imu message [s] (benchmarks read it)
        self.stamp_age_s = Ring(_STATS_WINDOW)  # DDS reception time minus header stamp [s]
        self.imu_messages_taken = 0  # every Imu message the node received (taken or dispatched), valid or not
        self._cov_ok: dict = {}
        self._imu_ok: set = set()  # conversions.imu_cdr_key of Imu messages that passed the message-level checks
        self._prev_imu_stamp: float | None = None
        self._noise_done = False
        self.epoch_s: int | None = None
        self.frames_seen: set = set()
        self.imu_frame = ""  # the first Imu frame_id seen: /diagnostics hardware_id unless the parameter names one
        # compile the numba kernels before subscribing: a first sample must not wait 30-90 s in a stalled executor
        t0 = time.perf_counter()
        if warm_up:
            from ..session.warmup import warm_up as _warm

            _warm((core,))
        self.ready_s = time.perf_counter() - t0
        self.get_logger().info(f"ready (kernels compiled in {self.ready_s:.1f} s)")
        qi = imu_qos(p["imu_qos"], p["imu_qos_depth"])
        self.imu_sub = self.create_subscription(Imu, "imu/data", self._on_imu, qi)
        self.fix_sub = self.create_subscription(NavSatFix, "gps/fix", self._on_fix,
                                                imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.vel_sub = self.create_subscription(TwistWithCovarianceStamped, "gps/vel", self._on_vel,
                                                imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.odom_sub = self.create_subscription(Odometry, "wheel/odom", self._on_odom,
                                                 imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.heading_sub = self.create_subscription(Imu, "gps/heading", self._on_heading,
                                                    imu_qos(p["gnss_qos"], p["gnss_qos_depth"]))
        self.truth_sub = self.create_subscription(PoseStamped, "ground_truth/pose", self._on_truth, qi)
        self.create_timer(1.0 / p["process_rate_hz"], self._process)
        self.create_timer(p["diagnostics_period_s"], self._publish_diagnostics)
        self.get_logger().info(f"alignment_node: core {self.core_name}, waiting for imu/data and gps/fix")

    # ------------------------------------------------------------------ parameters
    def _declare(self, name: str, default, text: str, read_only: bool) -> None:
        """Declare with the range (params.descriptor); a value given at start is checked first (params.check_value:
        one line naming the parameter, its value and its range) and stored with the declared type (an int for a
        double stays a double, an integer array for a double array is taken)."""
        self.defaults[name] = default
        given = self._parameter_overrides.get(name)
        if given is not None and given.type_ != Parameter.Type.NOT_SET:
            self._parameter_overrides[name] = Parameter(name, value=check_value(name, default, given.value))
        self.declare_parameter(name, default, descriptor(name, default, text, read_only))

    def _coerced(self, name: str):
        return check_value(name, self.defaults[name], self.get_parameter(name).value)

    def _pre_set_parameters(self, params: list) -> list:
        """Run-time changes: an int for a double (an integer array for a double array) becomes a double, so the
        parameter keeps its declared type (rclpy's range and type checks follow)."""
        out = []
        for prm in params:
            d = self.defaults.get(prm.name)
            try:
                out.append(Parameter(prm.name, value=coerce(d, prm.value)) if d is not None else prm)
            except ValueError:
                out.append(prm)  # refused with rclpy's reason (wrong type) or ours
        return out

    def _session_args(self, p: dict):
        sp = {k: p[k] for k in SESSION_DOC}
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
        self._guarded("take_inputs", self._take_inputs)
        p = dict(self.params)
        try:
            for prm in params:
                if prm.name not in p:
                    return SetParametersResult(successful=False, reason=f"unknown parameter {prm.name}")
                if NODE_PARAMS.get(prm.name, (None, None, False))[2]:
                    return SetParametersResult(successful=False, reason=f"{prm.name} is read-only (set it at start; "
                                                                        "restart the node to change it)")
                p[prm.name] = check_value(prm.name, self.defaults[prm.name], prm.value)
            cfg, core_params, crit = self._session_args(p)
        except (ValueError, TypeError) as exc:
            reason = str(exc) if any(prm.name in str(exc) for prm in params) else f"{params[0].name}: {exc}"
            self.get_logger().warning(f"parameter change refused: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        restarted = self.session.reconfigure(cfg, core_params, crit)
        self._apply_node_params(p)
        if restarted:
            self.get_logger().warning("core parameters changed: the alignment restarts")
            self.out.restart("core parameters changed")
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
        for sub in (self.imu_sub, self.fix_sub, self.vel_sub, self.odom_sub, self.heading_sub, self.truth_sub):
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
            self.imu_messages_taken += len(raws)
        others = []
        for sub, on_msg in ((self.fix_sub, self._on_fix), (self.vel_sub, self._on_vel), (self.odom_sub, self._on_odom),
                            (self.heading_sub, self._on_heading)):
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
        if received_ns is None:  # one executor callback per message (the polled path counts its batch)
            self.imu_messages_taken += 1
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

    def _on_odom(self, msg: Odometry) -> None:
        ws, reason = cv.wheel_speed_from_odometry(msg, self._epoch(msg))
        if ws is None:
            return self.session.reject_input("wheel_speed", "wheel_speed_invalid", reason, time.monotonic())
        self.session.push_wheel_speed(ws, time.monotonic())

    def _on_heading(self, msg: Imu) -> None:
        hd, reason = cv.gnss_heading_from_imu_msg(msg, self._epoch(msg))
        if hd is None:
            return self.session.reject_input("gnss_heading", "gnss_heading_invalid", reason, time.monotonic())
        self.session.push_gnss_heading(hd, time.monotonic())

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
        self.imu_frame = self.imu_frame or frame_id
        text = f"{kind} frame_id {frame_id!r} seen (imu_frame_id {self.params['imu_frame_id']!r}: " + (
            "any accepted)" if not self.params["imu_frame_id"] else "only that one accepted)")
        if len(self.frames_seen) > 1:
            self.get_logger().warning(text + f"; frames seen so far: {sorted(self.frames_seen)}")
        else:
            self.get_logger().info(text)

    def _epoch(self, msg) -> int:
        """A whole second a minute before the first stamp seen (0 for stamps that start within the first minute): the
        session works in seconds after it (float resolution). The minute keeps messages a little older than the first
        one (an IMU sample that arrives after the first fix, a reordered batch) at positive times."""
        if self.epoch_s is None:
            self.epoch_s = max(int(msg.header.stamp.sec) - 60, 0)
            self.session.stamp_offset_s = float(self.epoch_s)
        return self.epoch_s

    # ------------------------------------------------------------------ processing and outputs
    def _process(self) -> None:
        """The processing tick: take the inputs, let the session process them, publish what comes out; all of it
        inside one guard (the node never dies on the session's data: counted, logged throttled, carried on)."""
        self._guarded("take_inputs", self._take_inputs)
        self._guarded("processing", self._process_and_publish)

    def _guarded(self, where: str, fn, *args):
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - the guard: counted in /diagnostics (node_errors), logged, survived
            self.out.guard_error(where, exc)
            return None

    def _process_and_publish(self) -> None:
        t0 = time.perf_counter()
        outs = self.session.process(time.monotonic())
        self.out.publish(outs, t0)
        self._forget_samples()

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

    def _on_reset(self, request, response):
        """~/reset (std_srvs/Trigger): restart the alignment from nothing (the session's reset)."""
        self._guarded("take_inputs", self._take_inputs)
        was = self.session.status.value
        self.session.reset("reset service")
        self.out.restart("~/reset")
        self.get_logger().warning(f"alignment restarted by ~/reset (was: {was})")
        response.success = True
        response.message = (f"alignment restarted (core {self.core_name}; was {was}); buffered inputs dropped, "
                            f"~/datum is published again at the next initialisation")
        return response

    @property
    def published_aligned(self) -> bool:
        return self.out.published_aligned

    # ------------------------------------------------------------------ status (read by tests and benchmarks)
    @property
    def state(self) -> str:
        return self.session.status.value

    @property
    def flag(self):
        return self.session.flag

    def _publish_diagnostics(self) -> None:
        self._guarded("take_inputs", self._take_inputs)
        self._guarded("diagnostics", self.out.publish_diagnostics)

    def destroy_node(self):
        self.session.close()
        self._subscriptions.extend(self._polled)  # back in the node's list: rclpy destroys them with the node
        self._polled = []
        self.imu_sub = None
        return super().destroy_node()


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
        except (ValueError, TypeError, rclpy.exceptions.InvalidParameterValueException,
                rclpy.exceptions.InvalidParameterTypeException) as exc:
            print(f"alignment_node: bad parameter: {' '.join(str(exc).split())}", file=sys.stderr)
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
