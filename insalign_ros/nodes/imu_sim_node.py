"""imu_sim_node: publishes sensor_msgs/Imu, sensor_msgs/NavSatFix and the ground-truth pose from a scenario or a bag.

Sources (parameter ``source``):

- ``scenario``: ``make_scenario(scenario, seed, duration_s, rate_hz=rate_hz, gnss_rate_hz=gps_rate_hz)``
  (sim/scenarios.py: ship, car, static, static_navgrade, two_position, park_drive, park_drive_navgrade,
  drive_stop_drive), generated before publishing (a 300 s ship run at 100 Hz takes ~0.1 s);
- ``bag``: a contract rosbag2 (docs/bag_contract.md), or any bag with an Imu topic, read with ``io.bag.read_bag``:
  topic names ``bag_imu_topic``, ``bag_gps_topic``, ``bag_truth_topic`` (a pose topic at any rate, interpolated to
  the IMU stamps), ``unknown_fix_sigma_m`` (1-sigma per axis [m] for fixes with UNKNOWN covariance, the rule of
  alignment_node's ``gnss_sigma_m``; 0 drops them). Samples the bag flags invalid (``<topic>_invalid``, e.g. KITTI
  fill rows) are not published as Imu (a gap, as the session treats them); flagged fixes go out with STATUS_NO_FIX;
- ``rest``: a body at rest on the rotating Earth at (lat_deg, lon_deg, h_m) with attitude (roll_deg, pitch_deg,
  yaw_deg), Imu only, timer-driven (the transport check of ``insalign-demo --count``).

Topics (relative, remappable): ``imu/data`` sensor_msgs/Imu (frame ``frame_id``, default ``imu_link``; covariances
from the IMU specification's noise densities, orientation_covariance[0] = -1), ``gps/fix`` sensor_msgs/NavSatFix
(frame ``gps_frame_id``, ENU covariance, 1 Hz by default), ``ground_truth/pose`` geometry_msgs/PoseStamped (frame
``enu``: local ENU at the first truth sample, orientation body FLU -> ENU; only when the source knows the truth; on IMU stamps every 1/
``truth_rate_hz``, 10 Hz by default: 0 = every IMU sample), ``gps/vel`` geometry_msgs/TwistWithCovarianceStamped (the
antenna's ENU velocity relative to Earth, when the source has it: a bag's ``bag_vel_topic``, or a scenario with
``gnss_vel_sigma_m_s`` > 0; delayed like the fixes; ``gnss_lever_arm_b_m`` puts a scenario's antenna at that body
FLU offset [m]), ``/clock`` rosgraph_msgs/Clock (data time, every ``clock_period_s``), so ``use_sim_time`` works.

Timing: stamps are data time: ``start_stamp_s`` (0: the wall clock at the first message) + the scenario time.
Message k is published at wall time ``start + t_k / rate_factor`` (1.0 = real time, > 1 faster).

Backpressure (``pace_topic``, scenario and bag sources): with ``pace_topic`` set (e.g. ``/alignment_node/pose``, a
geometry_msgs/PoseWithCovarianceStamped the consumer publishes with its filter time as the stamp), the replay never
runs more than ``max_lead_s`` of data time ahead of the newest stamp seen there: it pauses (the wall-time schedule
shifts) instead of letting a slow consumer drop messages. Before the first pace message it may lead by
``max_lead_s`` past the first GNSS fix (the consumer initialises there); if no pace message arrives for
``pace_timeout_s`` of wall time while paused, it logs a warning and stops pacing (never hangs).

Start: with ``wait_for_subscribers`` > 0 it waits for that many subscriptions of ``imu/data`` (then up to 2 s for the
other topics'), then ``match_settle_s`` (0.5 s) more: a best-effort reader drops the messages that arrive before it
has matched the writer, and the writer cannot see that side of the match.

QoS (nodes/qos.py, REP 2003): ``qos`` = ``reliable`` by default for every data topic: a reliable writer serves both
the sensor-data (best-effort) subscription of alignment_node and a user's reliable subscriber; a best-effort writer
would leave a reliable subscriber with nothing. ``sensor_data`` makes the writer best effort.

At the end the node prints ``SIM_SUMMARY {json}`` (messages sent per topic, wall time) and exits 0; 3 when no
subscriber matched within ``wait_timeout_s``; 2 on a bad parameter.
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistWithCovarianceStamped
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from ..core import earth
from .qos import imu_qos

SUMMARY_PREFIX = "SIM_SUMMARY "
SOURCES = ("scenario", "bag", "rest")


def rest_imu(lat_deg: float, lon_deg: float, h_m: float, rpy_deg) -> tuple[np.ndarray, np.ndarray]:
    """(omega_ib_b [rad/s], f_ib_b [m/s^2]) of a body at rest relative to the Earth."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    C_b_n = earth.C_b_n_from_rpy(*np.radians(rpy_deg))
    C_e_b = C_b_n.T @ earth.C_e_n(lat, lon)
    p_e = earth.geodetic_to_ecef(lat, lon, h_m)
    return C_e_b @ earth.OMEGA_IE_E, -C_e_b @ earth.gravity_e(p_e)


def _set_stamp_ns(msg, ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), 1_000_000_000)


def load_data(source: str, scenario: str, seed: int, duration_s: float, rate_hz: float, gps_rate_hz: float,
              bag_path: str, bag_options: dict | None = None, scenario_options: dict | None = None):
    """ScenarioData of the source (scenario generated, or bag read; ``bag_options``: read_bag keyword arguments;
    ``scenario_options``: make_scenario parameter overrides)."""
    if source == "bag":
        from ..io.bag import read_bag

        data = read_bag(bag_path, **(bag_options or {}))
        if duration_s > 0:
            data = _truncate(data, duration_s)
        return data
    from ..sim.scenarios import make_scenario

    kw = {"rate_hz": rate_hz, **(scenario_options or {})}
    if gps_rate_hz > 0:
        kw["gnss_rate_hz"] = gps_rate_hz
    return make_scenario(scenario, seed=seed, duration_s=duration_s if duration_s > 0 else None, **kw)


def _truncate(data, duration_s: float):
    return data.until(data.t_s[0] + duration_s)


class ImuSimNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("imu_sim_node", **node_kwargs)
        p = self.declare_parameter
        self.source = str(p("source", "scenario").value)
        self.scenario = str(p("scenario", "ship").value)
        self.seed = int(p("seed", 0).value)
        self.bag_path = str(p("bag_path", "").value)
        self.rate_hz = float(p("rate_hz", 100.0).value)
        self.gps_rate_hz = float(p("gps_rate_hz", 1.0).value)
        self.rate_factor = float(p("rate_factor", 1.0).value)
        self.start_stamp_s = float(p("start_stamp_s", 0.0).value)
        self.clock_period_s = float(p("clock_period_s", 0.01).value)
        self.count = int(p("count", 0).value)  # 0: unlimited
        self.duration_s = float(p("duration_s", 0.0).value)  # 0: unlimited (rest) / the preset's (scenario)
        self.wait_for_subscribers = int(p("wait_for_subscribers", 0).value)
        self.wait_timeout_s = float(p("wait_timeout_s", 20.0).value)
        self.frame_id = str(p("frame_id", "imu_link").value)
        self.gps_frame_id = str(p("gps_frame_id", "gps_link").value)
        self.publish_truth = bool(p("publish_ground_truth", True).value)
        self.truth_rate_hz = float(p("truth_rate_hz", 10.0).value)  # 0: every IMU sample
        lat, lon, h = (float(p(n, d).value) for n, d in (("lat_deg", 49.0), ("lon_deg", 8.4), ("h_m", 120.0)))
        rpy = [float(p(n, 0.0).value) for n in ("roll_deg", "pitch_deg", "yaw_deg")]
        qos_kind, depth = str(p("qos", "reliable").value), int(p("qos_depth", 200).value)
        self.pace_topic = str(p("pace_topic", "").value)
        self.max_lead_s = float(p("max_lead_s", 2.0).value)
        #: publish each fix when the IMU stream has reached its stamp plus this [s data time] (receiver latency)
        self.fix_delay_s = float(p("fix_delay_s", 0.0).value)
        #: at the end, wait this long at most for reliable readers to acknowledge everything [s wall]
        self.drain_timeout_s = float(p("drain_timeout_s", 60.0).value)
        self.pace_timeout_s = float(p("pace_timeout_s", 5.0).value)
        #: after the subscribers matched, wait this long [s wall] before the first message: a best-effort reader
        #: drops what arrives before it has matched this writer, a match the writer cannot see
        self.match_settle_s = float(p("match_settle_s", 0.5).value)
        from rcl_interfaces.msg import ParameterDescriptor

        from ..io import bag as bag_io

        any_number = ParameterDescriptor(dynamic_typing=True)  # 2 and 2.0 both accepted
        unknown_sigma = float(p("unknown_fix_sigma_m", bag_io.DEFAULT_UNKNOWN_FIX_SIGMA_M, any_number).value)
        if not (math.isfinite(unknown_sigma) and unknown_sigma >= 0):
            raise ValueError(f"unknown_fix_sigma_m must be >= 0 (0: drop such fixes), got {unknown_sigma}")
        self.bag_options = {"imu_topic": str(p("bag_imu_topic", bag_io.IMU_TOPIC).value),
                            "gps_topic": str(p("bag_gps_topic", bag_io.GPS_TOPIC).value),
                            "truth_topic": str(p("bag_truth_topic", bag_io.TRUTH_TOPIC).value),
                            "unknown_fix_sigma_m": unknown_sigma if unknown_sigma > 0 else None,
                            "vel_topic": str(p("bag_vel_topic", bag_io.VEL_TOPIC).value)}
        vel_sigma = float(p("gnss_vel_sigma_m_s", 0.0, any_number).value)  # scenario: GNSS velocity 1-sigma (0: none)
        lever = [float(x) for x in p("gnss_lever_arm_b_m", [0.0, 0.0, 0.0]).value]  # scenario: antenna, body FLU [m]
        if len(lever) != 3 or not all(math.isfinite(x) for x in lever) or not vel_sigma >= 0:
            raise ValueError(f"gnss_lever_arm_b_m must be 3 finite numbers and gnss_vel_sigma_m_s >= 0, got {lever}, "
                             f"{vel_sigma}")
        self.scenario_options = {"gnss_vel_sigma_m_s": vel_sigma, **dict(zip(
            ("gnss_lever_x_m", "gnss_lever_y_m", "gnss_lever_z_m"), lever))}
        if self.source not in SOURCES:
            raise ValueError(f"source must be one of {SOURCES}, got {self.source!r}")
        if not (0.0 < self.rate_hz <= 2000.0):
            raise ValueError(f"rate_hz must be in (0, 2000], got {self.rate_hz}")
        if not (0.0 < self.rate_factor <= 1000.0):
            raise ValueError(f"rate_factor must be in (0, 1000], got {self.rate_factor}")
        if self.gps_rate_hz < 0 or self.duration_s < 0 or self.truth_rate_hz < 0 or self.clock_period_s <= 0:
            raise ValueError("gps_rate_hz and duration_s must be >= 0, clock_period_s > 0")
        if not (math.isfinite(self.max_lead_s) and self.max_lead_s > 0 and math.isfinite(self.pace_timeout_s)
                and self.pace_timeout_s > 0):
            raise ValueError(f"max_lead_s and pace_timeout_s must be > 0, got {self.max_lead_s}, {self.pace_timeout_s}")
        if self.source == "bag" and not self.bag_path:
            raise ValueError("source bag needs bag_path")
        qos = imu_qos(qos_kind, depth)
        self.pub = self.create_publisher(Imu, "imu/data", qos)
        self.sent = 0
        self.t_start_ns: int | None = None
        self.paused_s = 0.0  # wall time spent waiting for the consumer (backpressure)
        self._wait_start = time.monotonic()
        self.done = False
        self.gave_up = False  # no subscriber matched within wait_timeout_s
        self.data = None
        self.sent_fix = self.sent_truth = self.sent_vel = 0
        self.skipped_flagged = 0  # Imu samples the source flags invalid: not published (a gap)
        if self.source == "rest":
            self.omega_ib_b, self.f_ib_b = rest_imu(lat, lon, h, rpy)
            self.timer = self.create_timer(1.0 / self.rate_hz, self._tick)
            return
        t0 = time.monotonic()
        self.data = load_data(self.source, self.scenario, self.seed, self.duration_s, self.rate_hz,
                              self.gps_rate_hz, self.bag_path, self.bag_options, self.scenario_options)
        self.get_logger().info(f"{self.source} {self.data.name!r}: {self.data.n} IMU samples, "
                               f"{len(self.data.gnss_t_s)} fixes, truth {'yes' if self.data.has_truth else 'no'}; "
                               f"ready in {time.monotonic() - t0:.2f} s; rate factor {self.rate_factor:g}")
        self.pub_fix = self.create_publisher(NavSatFix, "gps/fix", qos)
        self.pub_vel = self.create_publisher(TwistWithCovarianceStamped, "gps/vel", qos) if (
            self.data.has_gnss_velocity) else None
        self.pub_truth = self.create_publisher(PoseStamped, "ground_truth/pose", qos) if (
            self.publish_truth and self.data.has_truth) else None
        self.pub_clock = self.create_publisher(Clock, "/clock", 10)
        self.paced_stamp_s: float | None = None  # newest consumer stamp on pace_topic [s]
        self.paused_s = 0.0  # wall time spent waiting for the consumer
        self._paused_since: float | None = None
        self._pace_msg_wall = time.monotonic()
        if self.pace_topic:
            self.create_subscription(PoseWithCovarianceStamped, self.pace_topic, self._on_pace, 50)
        self._prepare()

    # ------------------------------------------------------------------ scenario / bag source
    def _prepare(self) -> None:
        d = self.data
        spec = d.imu_spec
        self.cov_gyro = self.cov_acc = 0.0  # REP 145: all zeros = unknown
        if spec is not None:
            from ..sim.error_model import deg_sqrt_h_to_rad_sqrt_s, m_s_sqrt_h_to_m_s_sqrt_s

            dt = 1.0 / spec.rate_hz
            self.cov_gyro = deg_sqrt_h_to_rad_sqrt_s(spec.arw_deg_sqrt_h) ** 2 / dt
            self.cov_acc = m_s_sqrt_h_to_m_s_sqrt_s(spec.vrw_m_s_sqrt_h) ** 2 / dt
        self.imu_valid, self.gnss_valid = d.imu_valid_mask, d.gnss_valid_mask
        self.fix_geo = [earth.ecef_to_geodetic(p) for p in d.gnss_p_e]
        self.fix_cov_n = [earth.C_e_n(la, lo) @ R @ earth.C_e_n(la, lo).T
                          for (la, lo, _), R in zip(self.fix_geo, d.gnss_R_e)]
        if d.has_truth:
            self.anchor = (float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]))
            self.quat = Rotation.from_matrix(d.C_b_n).as_quat()
            import pymap3d

            x, y, z = pymap3d.geodetic2ecef(d.lat_rad, d.lon_rad, d.h_m, deg=False)
            e, n, u = pymap3d.ecef2enu(x, y, z, *self.anchor, deg=False)
            self.truth_p_n = np.stack([e, n, u], axis=1)
        self.k = 0
        self.j = 0
        self.jv = 0
        self.vel_t = d.gnss_vel_t_s if d.has_gnss_velocity else np.zeros(0)
        self.next_clock_t = -math.inf
        self.next_truth_t = -math.inf

    def subscribers_ready(self) -> bool:
        return self.pub.get_subscription_count() >= self.wait_for_subscribers

    def _ready(self) -> bool:
        if self.subscribers_ready():
            return True
        if time.monotonic() - self._wait_start > self.wait_timeout_s:
            self.get_logger().error(f"no subscriber matched after {self.wait_timeout_s:g} s (none running, or QoS "
                                    "incompatible: a best-effort publisher cannot serve a reliable subscriber); giving up")
            self.done = self.gave_up = True
        return False

    def _on_pace(self, msg) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self.paced_stamp_s is None or t > self.paced_stamp_s:
            self.paced_stamp_s = t
        self._pace_msg_wall = time.monotonic()

    def _lead_limit_s(self) -> float:
        """Latest data time (scenario time) that may be published now under backpressure (inf: no pacing)."""
        if not self.pace_topic:
            return math.inf
        d = self.data
        if self.paced_stamp_s is None:  # the consumer initialises at the first fix: let it get there
            first_fix = float(d.gnss_t_s[0]) if len(d.gnss_t_s) else float(d.t_s[0])
            return first_fix + self.max_lead_s
        return self.paced_stamp_s - self.stamp0_s + self.max_lead_s

    def publish_due(self, wall_s: float) -> float | None:
        """Publish every message whose wall time has come; return the wall time of the next one (None: done)."""
        d = self.data
        if self.t_start_ns is None:
            self.wall0 = wall_s
            base = self.start_stamp_s if self.start_stamp_s > 0 else time.time()
            self.t_start_ns = int(round(base * 1e9))
            self.stamp0_s = self.t_start_ns * 1e-9 - float(d.t_s[0])
        limit = d.n if not self.count else min(d.n, self.count)
        lead = self._lead_limit_s()
        if self._paused_since is not None and (self.k >= limit or d.t_s[self.k] <= lead):
            # the consumer caught up: resume, shifting the wall-time schedule by the pause
            self.wall0 += wall_s - self._paused_since
            self.paused_s += wall_s - self._paused_since
            self._paused_since = None
        elapsed_data = (wall_s - self.wall0) * self.rate_factor
        while self.k < limit and d.t_s[self.k] - d.t_s[0] <= elapsed_data and d.t_s[self.k] <= lead:
            self._publish_sample(self.k)
            self.k += 1
        if self.k >= limit:
            while self.j < len(d.gnss_t_s) and d.gnss_t_s[self.j] <= d.t_s[limit - 1]:  # delayed fixes still due
                self._publish_fix(self.j)
                self.j += 1
            self._publish_velocities_until(float(d.t_s[limit - 1]))
            self.done = True
            return None
        if d.t_s[self.k] > lead and d.t_s[self.k] - d.t_s[0] <= elapsed_data:  # due, but the consumer lags: pause
            if self._paused_since is None:
                self._paused_since = wall_s
            if wall_s - max(self._pace_msg_wall, self._paused_since) > self.pace_timeout_s:
                self.get_logger().warning(f"no message on {self.pace_topic} for {self.pace_timeout_s:g} s while "
                                          "paused: backpressure off, replaying on the wall-time schedule")
                self.pace_topic = ""
            return wall_s + 0.005  # the stream loop spins (pace messages arrive) until then
        return self.wall0 + (d.t_s[self.k] - d.t_s[0]) / self.rate_factor

    def _stamp_ns(self, t_s: float) -> int:
        """Header stamp [ns] of data time ``t_s``: integer arithmetic from the first stamp, so stamps keep the data's
        nanosecond spacing (a float of an absolute stamp resolves only ~0.24 us)."""
        return self.t_start_ns + int(round((t_s - float(self.data.t_s[0])) * 1e9))

    def _publish_sample(self, k: int) -> None:
        d = self.data
        t = float(d.t_s[k])
        stamp = self._stamp_ns(t)
        if self.pub_truth is not None and t >= self.next_truth_t - 1e-9:
            if self.truth_rate_hz > 0:
                self.next_truth_t = max(self.next_truth_t + 1.0 / self.truth_rate_hz, t) if self.next_truth_t > -math.inf \
                    else t + 1.0 / self.truth_rate_hz
            m = PoseStamped()
            _set_stamp_ns(m, stamp)
            m.header.frame_id = "enu"
            p_n = self.truth_p_n[k]
            m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) for x in p_n)
            q = self.quat[k]
            o = m.pose.orientation
            o.x, o.y, o.z, o.w = (float(x) for x in q)
            self.pub_truth.publish(m)
            self.sent_truth += 1
        if self.imu_valid[k]:
            msg = Imu()
            _set_stamp_ns(msg, stamp)
            msg.header.frame_id = self.frame_id
            msg.orientation_covariance[0] = -1.0
            w, f = d.omega_ib_b[k], d.f_ib_b[k]
            msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(w[0]), float(w[1]),
                                                                                      float(w[2]))
            a = msg.linear_acceleration
            a.x, a.y, a.z = float(f[0]), float(f[1]), float(f[2])
            for i in (0, 4, 8):
                msg.angular_velocity_covariance[i] = self.cov_gyro
                msg.linear_acceleration_covariance[i] = self.cov_acc
            self.pub.publish(msg)
            self.sent += 1
        else:  # flagged by the source (e.g. a KITTI fill row): a gap, as the session treats it
            self.skipped_flagged += 1
        while self.j < len(d.gnss_t_s) and d.gnss_t_s[self.j] + self.fix_delay_s <= t:
            self._publish_fix(self.j)
            self.j += 1
        self._publish_velocities_until(t - self.fix_delay_s)
        if t >= self.next_clock_t:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(int(round(stamp * 1e9)), 1_000_000_000)
            self.pub_clock.publish(c)
            self.next_clock_t = t + self.clock_period_s

    def _publish_fix(self, j: int) -> None:
        lat, lon, h = self.fix_geo[j]
        m = NavSatFix()
        _set_stamp_ns(m, self._stamp_ns(float(self.data.gnss_t_s[j])))
        m.header.frame_id = self.gps_frame_id
        m.status.status = NavSatStatus.STATUS_FIX if self.gnss_valid[j] else NavSatStatus.STATUS_NO_FIX
        m.status.service = NavSatStatus.SERVICE_GPS
        m.latitude, m.longitude, m.altitude = math.degrees(lat), math.degrees(lon), float(h)
        m.position_covariance = [float(x) for x in self.fix_cov_n[j].reshape(-1)]
        m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_KNOWN
        self.pub_fix.publish(m)
        self.sent_fix += 1

    def _publish_velocities_until(self, t_s: float) -> None:
        """GNSS velocities stamped up to ``t_s`` [s data time]: ENU twist.linear, ENU covariance in the linear block
        (angular not measured: variance -1)."""
        d = self.data
        while self.jv < len(self.vel_t) and self.vel_t[self.jv] <= t_s:
            j = self.jv
            m = TwistWithCovarianceStamped()
            _set_stamp_ns(m, self._stamp_ns(float(self.vel_t[j])))
            m.header.frame_id = self.gps_frame_id
            lin = m.twist.twist.linear
            lin.x, lin.y, lin.z = (float(x) for x in d.gnss_vel_n[j])
            cov = np.zeros((6, 6))
            cov[:3, :3] = d.gnss_vel_R_n[j]
            cov[3:, 3:] = -np.eye(3)
            m.twist.covariance = [float(x) for x in cov.reshape(-1)]
            self.pub_vel.publish(m)
            self.sent_vel += 1
            self.jv += 1

    def summary(self) -> dict:
        return {"source": self.source, "scenario": self.data.name if self.data is not None else "rest", "imu_sent": self.sent,
                "fix_sent": self.sent_fix, "vel_sent": self.sent_vel, "truth_sent": self.sent_truth,
                "imu_flagged_skipped": self.skipped_flagged, "rate_factor": self.rate_factor,
                "first_stamp_ns": self.t_start_ns, "gave_up": self.gave_up,
                "paused_s": round(self.paused_s, 3)}

    # ------------------------------------------------------------------ rest source (timer)
    def _tick(self) -> None:
        if self.done or (self.t_start_ns is None and not self._ready()):
            return
        now_ns = self.get_clock().now().nanoseconds
        if self.t_start_ns is None:
            self.t_start_ns = now_ns
        msg = Imu()
        msg.header.frame_id = self.frame_id
        stamp_ns = self.t_start_ns + round(self.sent * 1e9 / self.rate_hz)  # data time on an exact grid
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.orientation_covariance[0] = -1.0  # no orientation estimate (REP 145)
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, self.omega_ib_b)
        a = msg.linear_acceleration
        a.x, a.y, a.z = map(float, self.f_ib_b)
        self.pub.publish(msg)
        self.sent += 1
        elapsed = self.sent / self.rate_hz
        if (self.count and self.sent >= self.count) or (self.duration_s and elapsed >= self.duration_s):
            self.get_logger().info(f"published {self.sent} Imu messages; done")
            self.done = True


def _run_stream(node: ImuSimNode) -> None:
    """Scenario/bag source: wait for subscribers, then publish on the wall-time schedule, spinning in between."""
    while rclpy.ok() and not node.done and not node._ready():
        rclpy.spin_once(node, timeout_sec=0.05)
    if node.done:
        return
    # the consumer's other subscriptions (fixes, velocities, truth) are discovered with its Imu one: wait until they
    # match too, at most 2 s (a consumer that takes only Imu)
    others = [p for p in (node.pub_fix, node.pub_vel, node.pub_truth) if p is not None]
    end = time.monotonic() + 2.0
    while rclpy.ok() and time.monotonic() < end and any(
            p.get_subscription_count() < node.wait_for_subscribers for p in others):
        rclpy.spin_once(node, timeout_sec=0.05)
    if node.wait_for_subscribers > 0:  # the readers' side of the match (not observable here) settles meanwhile
        end = time.monotonic() + max(0.0, node.match_settle_s)
        while rclpy.ok() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
    t_report = time.monotonic() + 5.0
    spun = time.monotonic()
    while rclpy.ok() and not node.done:
        nxt = node.publish_due(time.monotonic())
        if nxt is None:
            break
        now = time.monotonic()
        wait = nxt - now
        if wait > 0.002:
            rclpy.spin_once(node, timeout_sec=min(wait, 0.05))
            spun = time.monotonic()
        else:
            # messages closer than 2 ms (above ~500 Hz of wall time): sleep to the next one instead of looping on
            # it (the loop kept a core busy: the demo's 600 Imu/s cost 100 % of one), and take the callbacks
            # (pace messages) every 20 ms
            if now - spun > 0.02:
                rclpy.spin_once(node, timeout_sec=0.0)
                spun = time.monotonic()
            if wait > 0.0:
                time.sleep(wait)
        if time.monotonic() > t_report:
            t_report += 5.0
            node.get_logger().info(f"sent {node.sent}/{node.data.n} Imu, {node.sent_fix} fixes")
    node.get_logger().info(f"published {node.sent} Imu, {node.sent_fix} NavSatFix, {node.sent_truth} truth poses; done")


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = ImuSimNode()
        if node.data is None:
            while rclpy.ok() and not node.done:
                rclpy.spin_once(node, timeout_sec=0.1)
        else:
            _run_stream(node)
        delivered = False
        if node.data is not None:  # reliable readers: wait until they acknowledged everything (a lagging reader
            from rclpy.duration import Duration  # gets its tail: drain_timeout_s, 60 s by default)
            from rclpy.qos import ReliabilityPolicy

            end = time.monotonic() + node.drain_timeout_s
            pubs = [p for p in (node.pub, node.pub_fix, node.pub_vel, node.pub_truth) if p is not None]
            delivered = all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in pubs)
            for pub in pubs:
                left = max(0.1, end - time.monotonic())
                if not pub.wait_for_all_acked(Duration(seconds=left)):
                    delivered = False
                    node.get_logger().warning(f"{pub.topic_name}: not all messages acknowledged within "
                                              f"{node.drain_timeout_s:g} s")
        # best effort (no acknowledgements to wait for) or not all acknowledged: give the writer 2 s to deliver what
        # is queued before the process goes away; every reader acknowledged every message: nothing is left to deliver
        end = time.monotonic() + (0.0 if delivered else 2.0)
        while rclpy.ok() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        print(SUMMARY_PREFIX + json.dumps(node.summary()), flush=True)
        return 3 if node.gave_up else 0
    except KeyboardInterrupt:
        if node is not None:
            print(SUMMARY_PREFIX + json.dumps(node.summary()), flush=True)
        return 0
    except ValueError as exc:
        print(f"imu_sim_node: bad parameter: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main())
