"""Bad input over real DDS: one alignment_node process, a publisher in the test process, many bad messages.

Every case of issue 7 is injected into a ship run (50 Hz IMU, 1 Hz GNSS, 10 Hz truth); afterwards the node must be
alive, have counted each case under its own diagnostic counter, logged (throttled) and kept aligning: the final
Euler errors are small and inside the published 3-sigma.
"""

import math
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.cli.bringup import start_node, stop_nodes
from insalign_ros.core import earth

pytestmark = pytest.mark.ros

ALIGN = "insalign_ros.nodes.alignment_node"
T0 = 1000.0  # stamp of data time 0 [s]


class Feeder:
    """Publishes a ScenarioData stream (and bad messages) from the test process over DDS."""

    def __init__(self, data):
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, NavSatFix

        self.rclpy = rclpy
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node("bad_input_feeder", context=self.ctx)
        # deeper than the whole stream (13,000 Imu): reliable keep-last loses nothing even when the node lags under
        # load, so the gap/reject counters below are exact (a 2,000-deep history lost samples at load 5 on 2 cores)
        qos = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_imu = self.node.create_publisher(Imu, "imu/data", qos)
        self.pub_fix = self.node.create_publisher(NavSatFix, "gps/fix", qos)
        self.pub_truth = self.node.create_publisher(PoseStamped, "ground_truth/pose", qos)
        self.Imu, self.NavSatFix, self.PoseStamped = Imu, NavSatFix, PoseStamped
        self.d = data
        self.geo = [earth.ecef_to_geodetic(p) for p in data.gnss_p_e]
        self.quat = Rotation.from_matrix(data.C_b_n).as_quat()
        self.anchor = (data.lat_rad[0], data.lon_rad[0], data.h_m[0])
        self.sent = 0

    @staticmethod
    def stamp(msg, t):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)

    def imu(self, k, t_offset=0.0, frame="imu_link"):
        m = self.Imu()
        self.stamp(m, T0 + t_offset + self.d.t_s[k])
        m.header.frame_id = frame
        m.orientation_covariance[0] = -1.0
        w, f = self.d.omega_ib_b[k], self.d.f_ib_b[k]
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in f)
        return m

    def fix(self, j, t_offset=0.0, frame="gps_link"):
        lat, lon, h = self.geo[j]
        m = self.NavSatFix()
        self.stamp(m, T0 + t_offset + self.d.gnss_t_s[j])
        m.header.frame_id = frame
        m.status.status = 0
        m.latitude, m.longitude, m.altitude = math.degrees(lat), math.degrees(lon), h
        m.position_covariance = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
        m.position_covariance_type = self.NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
        return m

    def truth(self, k, t_offset=0.0):
        m = self.PoseStamped()
        self.stamp(m, T0 + t_offset + self.d.t_s[k])
        m.header.frame_id = "enu"
        p_n = earth.ecef_to_enu(earth.geodetic_to_ecef(self.d.lat_rad[k], self.d.lon_rad[k], self.d.h_m[k]),
                                *self.anchor)
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) for x in p_n)
        q = self.quat[k]
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = (float(x) for x in q)
        return m

    def pace(self):
        self.sent += 1
        if self.sent % 100 == 0:
            # ~1,000 messages/s idle (650 at 0.15 s: 6 s more of the test); the node may lag under load: reliable
            # histories deeper than the stream lose nothing and every check below waits on state
            time.sleep(0.1)  # (the machine is shared; throughput is benchmarks/node_latency.py)

    def stream(self, k0, k1, t_offset=0.0, gps=True, inject=None):
        """Publish samples k0..k1-1 (truth every 5th, fixes at their stamps); inject(k) may publish extras."""
        d = self.d
        j = int(np.searchsorted(d.gnss_t_s, d.t_s[k0]))
        for k in range(k0, k1):
            if k % 5 == 0:
                self.pub_truth.publish(self.truth(k, t_offset))
            self.pub_imu.publish(self.imu(k, t_offset))
            while j < len(d.gnss_t_s) and d.gnss_t_s[j] <= d.t_s[k]:
                if gps:
                    self.pub_fix.publish(self.fix(j, t_offset))
                j += 1
            if inject is not None:
                inject(k)
            self.pace()

    def close(self):
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)



def _bad_imu_messages(feed, k):
    """(counter, message) pairs of invalid Imu messages built around sample k (stamps after the last good one)."""
    out = []
    for field, val in (("angular_velocity.x", float("nan")), ("linear_acceleration.z", float("inf")),
                       ("orientation.w", float("nan")), ("angular_velocity.y", -float("inf"))):
        m = feed.imu(k)
        obj, attr = field.split(".")
        setattr(getattr(m, obj), attr, val)
        out.append(("imu_invalid", m))
    for cov in ([-1.0, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6], [0.0, 1e-7, 0, 1e-7, 0, 0, 0, 0, 0],
                [float("nan")] * 9):
        m = feed.imu(k)
        m.angular_velocity_covariance = cov
        out.append(("imu_invalid", m))
    m = feed.imu(k)
    m.linear_acceleration_covariance = [0.0, 0, 0, 0, -1e-3, 0, 0, 0, 1e-3]
    out.append(("imu_invalid", m))
    m = feed.imu(k)
    m.angular_velocity.z = 1e6  # absurd magnitude
    out.append(("imu_invalid", m))
    out.append(("imu_frame", feed.imu(k, frame="camera_link")))
    return out


@pytest.mark.timeout(300)
def test_bad_input_is_rejected_counted_and_the_node_keeps_aligning(tmp_path, ros_env):
    from insalign_ros.nodes.monitor import AlignmentMonitor
    from insalign_ros.sim.scenarios import make_scenario

    rate = 50.0
    data = make_scenario("ship", seed=5, duration_s=160.0, rate_hz=rate)
    node = start_node(ALIGN, ros_env, log_dir=tmp_path, params={
        "core": "liekf", "init_from_ground_truth": True, "init_rpy_error_deg": "[3.0, -3.0, 30.0]",
        "imu_grade": "paper_ship", "gnss_frame_id": "gps_link", "imu_frame_id": "imu_link", "imu_qos": "reliable", "imu_qos_depth": 20000, "gnss_qos": "reliable",
        "gnss_qos_depth": 5000, "log_throttle_s": 5.0, "pose_rate_hz": 10.0,
        "imu_timeout_s": 0.0})  # the feed pauses between segments; the watchdog has its own test
    mon = AlignmentMonitor()
    feed = Feeder(data)
    expected: dict[str, int] = {}

    def count(name, n=1):
        expected[name] = expected.get(name, 0) + n

    try:
        end = time.monotonic() + 180.0  # imports and the kernels' warm-up on a loaded machine
        while feed.pub_imu.get_subscription_count() < 1 or feed.pub_fix.get_subscription_count() < 1:
            assert time.monotonic() < end, "alignment_node did not subscribe"
            time.sleep(0.05)
        assert mon.wait_for(lambda m: m.diag_count > 0, 20.0)
        k_per_s = int(rate)

        def inject(k):
            t = data.t_s[k]
            if k % (5 * k_per_s) == 7 and 1.0 < t < 55.0:  # every 5 s: one of each invalid Imu message
                for name, m in _bad_imu_messages(feed, k):
                    feed.pub_imu.publish(m)
                    count(name)
                feed.pub_imu.publish(feed.imu(k))  # duplicate of the sample just sent
                count("imu_duplicate")
                feed.pub_imu.publish(feed.imu(k - 25))  # sent 0.5 s ago: a duplicate stamp
                count("imu_duplicate")
                # a new stamp 1.5 s old: behind the filter (out of order) or, if the node lags by more than the
                # fusion delay, still put in order (reordered); counted either way
                feed.pub_imu.publish(feed.imu(k - 75, t_offset=0.005))
                count("imu_late")
                feed.pub_imu.publish(feed.imu(k, t_offset=1e6))  # far future (one message)
                count("imu_future")
            if k % k_per_s == 0 and 3.0 < t < 55.0 and k % (2 * k_per_s) == 0:  # every 2 s: bad fixes
                j = int(round(t))
                bad = []
                m = feed.fix(j)
                m.status.status = -1  # NO_FIX
                bad.append(("gnss_no_fix", m))
                for attr, val in (("latitude", float("nan")), ("altitude", float("inf"))):
                    m = feed.fix(j)
                    setattr(m, attr, val)
                    bad.append(("gnss_invalid", m))
                for cov in ([-1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [float("nan")] * 9):  # (all zeros: gnss_sigma_m)
                    m = feed.fix(j)
                    m.position_covariance = cov
                    bad.append(("gnss_invalid", m))
                bad.append(("gnss_frame", feed.fix(j, frame="base_link")))
                bad.append(("gnss_duplicate", feed.fix(j)))  # the good fix at j was sent just before
                bad.append(("gnss_future", feed.fix(j, t_offset=3600.0)))
                bad.append(("gnss_old", feed.fix(j - 1)))  # 1 s old, sent before: stale or duplicate
                for name, m in bad:
                    feed.pub_fix.publish(m)
                    count(name)

        # segment A, 0-60 s: bad messages interleaved, an IMU dropout (0.3 s)
        kA = int(60 * rate)
        k_drop = int(16 * rate)
        feed.stream(0, k_drop, inject=inject)
        feed.stream(k_drop + 15, kA, inject=inject)  # 15 samples = 0.3 s lost
        count("imu_gaps")
        assert mon.wait_for(lambda m: m.aligned is True, 15.0), (mon.diag, mon.aligned_history)
        # segment B, 60-100 s: no GNSS for 40 s, 8 times the flag's 5-s freshness bound (the flag must fall: no fresh
        # update; 140 s before, 7 s of the test for the same assertions)
        kB = int(100 * rate)
        feed.stream(kA, kB, gps=False)
        assert mon.wait_for(lambda m: m.aligned is False, 15.0), mon.diag
        assert mon.wait_for(lambda m: "no GNSS fix for" in m.diag.get("message", ""), 10.0), mon.diag
        # segment C, 100-160 s: GNSS back, the node recovers; a forward jump of 1.5 s (< max_gap_s = 2 s) at 101 s
        # is a gap, not a reset (in a ship's wave motion the one sample after the gap stands for 1.5 s of rotation:
        # the filter inflates its covariance and re-converges)
        k_gap = int(101 * rate)
        feed.stream(kB, k_gap)
        feed.stream(k_gap + 75, data.n)
        count("imu_gaps")
        t_end = T0 + data.t_s[-1]
        assert mon.wait_for(lambda m: float(m.diag.get("filter_time_s", 0)) >= t_end - 0.2, 20.0), mon.diag
        time.sleep(0.5)
        with mon.lock:
            err, s3, diag = mon.euler_error[1].copy(), mon.euler_3sigma[1].copy(), dict(mon.diag)
        print(f"after the bad input and the 40-s GNSS outage: Euler error {np.round(err, 3)} deg, 3-sigma "
              f"{np.round(s3, 3)} deg")
        assert node.alive(), node.output()[-3000:]
        assert abs(err[2]) < 2.5 and np.all(np.abs(err[:2]) < 1.0), (err, s3)
        assert np.all(np.abs(err) < s3), (err, s3)
        got = {k: int(v) for k, v in diag.items() if k.startswith(("imu_", "gnss_")) and v.isdigit()}
        got["imu_late"] = got["imu_out_of_order"] + got["imu_reordered"]
        got["gnss_old"] = got["gnss_stale"] + got["gnss_duplicate"] - expected["gnss_duplicate"]
        for name, n in expected.items():
            if name == "gnss_duplicate":  # re-sent fixes that were still in the fusion window count here
                assert n <= got[name] <= n + expected["gnss_old"], (name, got[name], n, diag)
                continue
            if name == "gnss_future":  # (a fix delivered before the first Imu is checked when that Imu comes)
                assert got[name] == n, (name, got[name], n, {k: v for k, v in sorted(diag.items()) if "gnss" in k})
                continue
            assert got[name] == n, (name, got[name], n, diag)
        assert int(diag["core_faults"]) == 0 and int(diag["time_resets"]) == 0, diag
        assert int(diag["imu_rejected"]) == sum(v for k, v in expected.items() if k.startswith("imu_")
                                                and k not in ("imu_gaps", "imu_late")) + got["imu_out_of_order"]
        # throttled log lines: far fewer lines than rejections, each with its reason
        log = node.output()
        n_lines = log.count("rejected imu sample")
        assert 5 <= n_lines < int(diag["imu_rejected"]) / 4, (n_lines, diag["imu_rejected"])  # one line per kind, throttled
        assert "non-finite" in log and "no fix (status < 0)" in log

        # a time jump backward (a bag played again from the start): reset with a log line, re-initialised
        feed.stream(0, int(15 * rate))
        assert mon.wait_for(lambda m: int(m.diag.get("time_resets", 0)) == 1, 15.0), mon.diag
        assert "time jumped backward" in node.output() and "resetting the alignment" in node.output()
        # and a persistent jump forward by an hour: one more reset, then it aligns again on the new time line
        feed.stream(int(15 * rate), int(60 * rate), t_offset=3600.0)
        assert mon.wait_for(lambda m: int(m.diag.get("time_resets", 0)) == 2, 15.0), mon.diag
        assert node.output().count("initialised liekf") == 3
        assert mon.wait_for(lambda m: float(m.diag.get("filter_time_s", 0)) >= T0 + 3600 + 59.0, 20.0), mon.diag
        with mon.lock:
            err = mon.euler_error[1].copy()
        assert abs(err[2]) < 3.0, err
        assert node.alive()
    finally:
        feed.close()
        mon.close()
        stop_nodes([node])
