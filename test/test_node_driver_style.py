"""Issue 13 acceptance over real DDS: alignment_node with DEFAULT parameters plus topic remaps, fed the way real
drivers publish: best-effort QoS on both topics, frame_ids `imu` and `gps`, orientation_covariance[0] = -1, zero
rate/accel covariances, +-0.5 ms host-stamp jitter, every fix delivered 150 ms (data time) after its stamp, no
ground truth, no initial guess. The test knows the truth and compares the published ~/pose; the flag's transitions
come from the node's log lines (stamped)."""

import math
import re
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.cli.bringup import start_node, stop_nodes
from insalign_ros.core import earth

pytestmark = pytest.mark.ros

ALIGN = "insalign_ros.nodes.alignment_node"
#: after the driver's writer sees the node's reader, the reader's side of the match may still be under way, and a
#: best-effort reader drops what arrives before it (imu_sim_node's match_settle_s): wait this long [s] first
MATCH_SETTLE_S = 0.5
T0_NS = 1_700_000_000 * 1_000_000_000  # a wall-clock-like epoch, as a host-stamped driver would give



class Driver:
    """Publishes a ScenarioData like an IMU driver and a GNSS driver would (see the module docstring)."""

    def __init__(self, data, seed=0, imu_topic="/imu/data_raw", fix_topic="/fix"):
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Imu, NavSatFix

        self.rclpy, self.Imu, self.NavSatFix = rclpy, Imu, NavSatFix
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node("fake_drivers", context=self.ctx)
        self.pub_imu = self.node.create_publisher(Imu, imu_topic, qos_profile_sensor_data)
        self.pub_fix = self.node.create_publisher(NavSatFix, fix_topic, qos_profile_sensor_data)
        self.d = data
        rng = np.random.default_rng(seed)
        self.jitter_ns = rng.integers(-500_000, 500_001, data.n)
        self.geo = [earth.ecef_to_geodetic(p) for p in data.gnss_p_e]

    @staticmethod
    def _stamp(msg, ns):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), 1_000_000_000)

    def imu(self, k):
        m = self.Imu()
        self._stamp(m, T0_NS + int(round(self.d.t_s[k] * 1e9)) + int(self.jitter_ns[k]))
        m.header.frame_id = "imu"
        m.orientation_covariance[0] = -1.0  # no orientation (REP 145); rate/accel covariances all zero: unknown
        w, f = self.d.omega_ib_b[k], self.d.f_ib_b[k]
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in f)
        return m

    def fix(self, j):
        lat, lon, h = self.geo[j]
        m = self.NavSatFix()
        self._stamp(m, T0_NS + int(round(self.d.gnss_t_s[j] * 1e9)))
        m.header.frame_id = "gps"
        m.status.status = 0
        m.latitude, m.longitude, m.altitude = math.degrees(lat), math.degrees(lon), float(h)
        # the receiver's covariance in ENU, as drivers publish it (REP 145 / NavSatFix: East, North, Up): the
        # simulated fixes are 1 m horizontally and 2 m vertically (an isotropic trace/3 would be 1.41 m horizontally)
        C = earth.C_e_n(lat, lon)
        m.position_covariance = [float(x) for x in (C @ self.d.gnss_R_e[j] @ C.T).ravel()]
        m.position_covariance_type = self.NavSatFix.COVARIANCE_TYPE_KNOWN
        return m

    def stream(self, msgs_per_s=1000.0, fix_delay_s=0.15):
        d = self.d
        j = 0
        t_wall = time.monotonic()
        for k in range(d.n):
            self.pub_imu.publish(self.imu(k))
            while j < len(d.gnss_t_s) and d.gnss_t_s[j] + fix_delay_s <= d.t_s[k]:
                self.pub_fix.publish(self.fix(j))
                j += 1
            if k % 50 == 49:  # pace: msgs_per_s on average (the machine is shared)
                t_wall += 50.0 / msgs_per_s
                time.sleep(max(0.0, t_wall - time.monotonic()))

    def close(self):
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)


def _flag_intervals(log: str):
    """[(t_raised, t_lowered or inf)] in data seconds after T0 from the node's 'aligned flag ...' lines."""
    out, up = [], None
    for kind, t in re.findall(r"aligned flag (raised|lowered) at t=([0-9.]+) s", log):
        t = float(t) - T0_NS * 1e-9
        if kind == "raised":
            up = t
        elif up is not None:
            out.append((up, t))
            up = None
    if up is not None:
        out.append((up, math.inf))
    return out


def _stream_and_collect(drv, mon, node, d, nearest: bool):
    """Wait for the node, stream ``d`` as the driver, wait until the node has taken it; return the node's log, its
    poses and diagnostics, the pose stamps [s from T0_NS], the yaw error against the truth [deg] (at the truth sample
    nearest the output stamp when ``nearest``, else the first at or after it), the flag intervals and the flag per
    pose."""
    end = time.monotonic() + 180.0  # imports and the kernels' warm-up on a loaded machine
    while drv.pub_imu.get_subscription_count() < 1 or drv.pub_fix.get_subscription_count() < 1 \
            or mon.node.count_publishers("/alignment_node/pose") < 1 or mon.diag_count < 1:
        assert time.monotonic() < end, "alignment_node did not come up"
        time.sleep(0.05)
    time.sleep(MATCH_SETTLE_S)
    drv.stream()
    assert mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0
                        and int(m.diag.get("imu_received", "0")) > 0.9 * d.n, 90.0), mon.diag
    time.sleep(1.5)
    log = node.output()
    with mon.lock:
        poses, diag = list(mon.poses), dict(mon.diag)
    t = np.array([(p.header.stamp.sec * 1_000_000_000 + p.header.stamp.nanosec - T0_NS) * 1e-9 for p in poses])
    q = np.array([[p.pose.pose.orientation.x, p.pose.pose.orientation.y, p.pose.pose.orientation.z,
                   p.pose.pose.orientation.w] for p in poses])
    k = np.clip(np.searchsorted(d.t_s, t - 0.002), 0, d.n - 1)  # the truth at the (jittered) output stamp
    if nearest:
        k1 = np.clip(k + 1, 0, d.n - 1)
        k = np.where(np.abs(d.t_s[k1] - t) < np.abs(d.t_s[k] - t), k1, k)
    yaw_err = np.degrees([earth.euler_error_rad(C, d.C_b_n[i])[2] for C, i in zip(Rotation.from_quat(q).as_matrix(), k)])
    intervals = _flag_intervals(log)
    flag = np.zeros(len(t), bool)
    for a, b in intervals:
        flag |= (t >= a - 1e-6) & (t < b - 1e-6)
    return log, poses, diag, t, yaw_err, intervals, flag


@pytest.mark.timeout(400)
@pytest.mark.parametrize("scenario,duration_s,overrides,bound_deg,grade", [
    ("car", 150.0, {"heading_deg": -120.0}, 1.0, None),  # (a) already moving at 15 m/s at start-up
    # (b) a ship, moving from the start: the longest DDS run of the suite (240 s of data for a flag at 207 s, 31 s of
    # a 10-min suite), -m slow; in the default run the same data and defaults go through the session offline
    # (test_default_parameters_on_the_ship_offline below; the ship with its grade, paper_ship, 105 s, is -m slow too:
    # offline in test_grade_matched_runs_offline; a ship over DDS with the default core in test_node_demo.py and
    # test_sample_bag.py)
    pytest.param("ship", 240.0, {}, 2.0, None, marks=pytest.mark.slow),
    ("park_drive", 105.0, {"heading_deg": 150.0, "park_s": 40.0}, 1.0, None),  # (c) parked 40 s, then driving
    # the second run of each: the imu_grade matching the IMU (offline, fixes 150 ms late: flag at 29 / 56 / 56 s).
    # -m slow (16-18 s each over DDS, 50 s of a 6-min suite): the driver-style DDS part is the same as in (a) and (c)
    # above, and the grade reaches the node as a parameter in test_imu_grade.py::test_node_imu_grade_parameter; in
    # the default run the same data, grades and late fixes go through the session offline
    # (test_grade_matched_runs_offline below, the same assertions)
    pytest.param("car", 90.0, {"heading_deg": -120.0}, 1.0, "industrial_mems", marks=pytest.mark.slow),
    pytest.param("ship", 105.0, {}, 2.0, "paper_ship", marks=pytest.mark.slow),
    pytest.param("park_drive", 105.0, {"heading_deg": 150.0, "park_s": 40.0}, 1.0, "industrial_mems",
                 marks=pytest.mark.slow),
])
def test_driver_style_stream_with_default_parameters(tmp_path, ros_env, scenario, duration_s, overrides, bound_deg,
                                                     grade):
    """Default parameters only (core auto, imu_grade unknown_mems: a MEMS prior of 360 deg/h and 5 mg on the car's
    5 deg/h, 1 mg IMU and on the ship's 25 deg/h, 0.2 mg one): flag up, never up with |yaw error| > 3 deg, final
    |yaw error| under the bound and inside its 3-sigma. Offline on the same data (docs/imu_grades.md): the flag first
    comes up at 117 s (car), 207 s (ship: the z gyro bias prior of 360 deg/h is hardly observable from a ship's
    motion; with a 25 deg/h prior it is 59 s, hence 240 s of ship data), 69 s (park_drive: 29 s after the drive-off,
    the gyro bias measured while parked carried across the hand-over)."""
    from insalign_ros.nodes.monitor import AlignmentMonitor
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario(scenario, seed=4, duration_s=duration_s, rate_hz=100.0, **overrides)
    node = start_node(ALIGN, ros_env, log_dir=tmp_path, remaps={"imu/data": "/imu/data_raw", "gps/fix": "/fix"},
                      params={"imu_grade": grade} if grade else None)
    mon = AlignmentMonitor(keep_poses=100000)
    drv = Driver(d)
    try:
        log, poses, diag, t, yaw_err, intervals, flag = _stream_and_collect(drv, mon, node, d, nearest=True)
        print(f"{scenario} (default parameters{' + imu_grade ' + grade if grade else ''}, core {diag.get('core')}): {len(t)} poses, flag intervals {intervals}, final yaw error {yaw_err[-1]:+.3f} "
              f"deg, received {diag.get('imu_received')}/{d.n} Imu, gaps {diag.get('imu_gaps')}, "
              f"gnss accepted {diag.get('gnss_accepted')}/{len(d.gnss_t_s)}, stale {diag.get('gnss_stale')}")
        assert "from sensors" in log and "Imu frame_id 'imu' seen" in log, log[-2000:]
        assert flag.any(), (diag.get("aligned_reason"), log[-1500:])
        yaw_3sigma = 3.0 * math.degrees(math.sqrt(poses[-1].pose.covariance[35]))  # REP 145 yaw variance [rad^2]
        assert abs(yaw_err[-1]) < yaw_3sigma, (yaw_err[-1], yaw_3sigma)
        assert not np.any(flag & (np.abs(yaw_err) > 3.0)), yaw_err[flag & (np.abs(yaw_err) > 3.0)]
        assert abs(yaw_err[-1]) < bound_deg, yaw_err[-1]
        assert int(diag["gnss_stale"]) == 0 and int(diag["imu_rejected"]) == 0, diag
    finally:
        drv.close()
        mon.close()
        stop_nodes([node])


@pytest.mark.timeout(400)
@pytest.mark.parametrize("scenario,duration_s,overrides,until_s,bound_s", [
    ("park_drive", 60.0, {"park_s": 30.0, "door_at_s": 15.0}, None, 14.0),  # parked 30 s, then driving
    ("car", 120.0, {}, 45.0, 14.0),  # parked 4.5 s, then driving
])
def test_vehicle_car_flags_seconds_after_the_first_motion_over_dds(tmp_path, ros_env, scenario, duration_s, overrides,
                                                                   until_s, bound_s):
    """Issue 25 over DDS: ``vehicle: car`` (non-holonomic constraint, the GSF's course constraint), 1-Hz fixes only,
    150 ms late, the other parameters default (core auto, imu_grade unknown_mems). Offline on the same drives the flag
    rises 11.7-12.5 s (park_drive) and 10.8 s (car) after the first motion (docs/yaw_gsf.md, "Where the seconds to the
    flag go"; the yaw's information reaches its bound at 9.6 and 8.7 s); over DDS the same within 0.3 s once the
    driver publishes the receiver's ENU covariance (1 m horizontal, 2 m vertical; an isotropic trace/3 made the node's
    fixes 1.41 m horizontally and its flag 1 s later; benchmarks/vehicle_dds.py for many seeds): here within
    ``bound_s`` (room for a loaded machine), never up with abs(yaw error) > 2 deg."""
    from insalign_ros.nodes.monitor import AlignmentMonitor
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario(scenario, seed=4, duration_s=duration_s, rate_hz=100.0, **overrides)
    if until_s is not None:
        d = d.until(until_s)
    speed = np.linalg.norm(np.asarray(d.v_n)[:, :2], axis=1)
    t_motion = float(d.t_s[int(np.argmax(speed > 0.5))])
    node = start_node(ALIGN, ros_env, log_dir=tmp_path, remaps={"imu/data": "/imu/data_raw", "gps/fix": "/fix"},
                      params={"vehicle": "car"})
    mon = AlignmentMonitor(keep_poses=100000)
    drv = Driver(d)
    try:
        log, poses, diag, t, yaw_err, intervals, flag = _stream_and_collect(drv, mon, node, d, nearest=False)
        print(f"{scenario} vehicle car over DDS: first motion {t_motion:.2f} s, flag intervals {intervals}, "
              f"nhc accepted {diag.get('nhc_accepted')} rejected {diag.get('nhc_rejected')}, "
              f"final yaw error {yaw_err[-1]:+.3f} deg")
        assert intervals, (diag.get("aligned_reason"), log[-1500:])
        assert intervals[0][0] - t_motion <= bound_s, (intervals, t_motion)
        assert not np.any(flag & (np.abs(yaw_err) > 2.0)), yaw_err[flag & (np.abs(yaw_err) > 2.0)]
        assert int(diag.get("nhc_accepted", "0")) > 0, diag
        # an angle's 3-sigma is never published above 180 deg: NaN while the heading is unknown (parked, then the
        # yaw bank), numbers once it is known
        with mon.lock:
            s3 = np.array([v for _, v in mon.sigmas3])
        assert np.all(np.isnan(s3) | (s3 <= 180.0)), s3[~np.isnan(s3) & (s3 > 180.0)]
        assert np.isnan(s3[:, 2]).any() and not np.isnan(s3[:, :2]).any() and not np.isnan(s3[-1]).any(), s3[:3]
    finally:
        drv.close()
        mon.close()
        stop_nodes([node])


def test_default_parameters_on_the_ship_offline():
    """The default-parameter ship case of the DDS test above (its slow part, -m slow) through the session offline:
    the same data (seed 4, 240 s at 100 Hz), defaults only (core auto, imu_grade unknown_mems), fixes 150 ms late,
    no ground truth: flag up (first at 207 s, docs/imu_grades.md), never up with |yaw error| > 3 deg, final |yaw
    error| < 2 deg and inside its 3-sigma."""
    from insalign_ros.session.offline import align
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("ship", seed=4, duration_s=240.0, rate_hz=100.0)
    r = align(d, fix_delay_s=0.15)
    yaw_err, yaw_3s = r.rpy_err_deg[:, 2], r.sigma3_deg[:, 2]
    first = r.metrics["aligned_first_raised_at_s"]
    print(f"ship offline, defaults (core {r.core}): flag first raised at {first} s, final yaw error {yaw_err[-1]:+.3f} "
          f"deg (3-sigma {yaw_3s[-1]:.3f} deg)")
    assert r.aligned.any() and first is not None and first > 60.0, first  # not before the grade-matched run's 59 s
    assert not np.any(r.aligned & (np.abs(yaw_err) > 3.0)), yaw_err[r.aligned & (np.abs(yaw_err) > 3.0)]
    assert abs(yaw_err[-1]) < yaw_3s[-1] and abs(yaw_err[-1]) < 2.0, (yaw_err[-1], yaw_3s[-1])


@pytest.mark.parametrize("scenario,duration_s,overrides,bound_deg,grade", [
    ("car", 90.0, {"heading_deg": -120.0}, 1.0, "industrial_mems"),
    ("ship", 105.0, {}, 2.0, "paper_ship"),
    ("park_drive", 105.0, {"heading_deg": 150.0, "park_s": 40.0}, 1.0, "industrial_mems"),
])
def test_grade_matched_runs_offline(scenario, duration_s, overrides, bound_deg, grade):
    """The grade-matched cases of test_driver_style_stream_with_default_parameters (over DDS: -m slow) through the
    session offline: the same data (seed 4, 100 Hz), the imu_grade matching the IMU, the other parameters default
    (core auto), fixes 150 ms late, no ground truth: flag up (first at 29 / 56 / 56 s), never up with |yaw error| >
    3 deg, final |yaw error| under the bound and inside its 3-sigma, nothing rejected or stale."""
    from insalign_ros.session.offline import align
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario(scenario, seed=4, duration_s=duration_s, rate_hz=100.0, **overrides)
    r = align(d, fix_delay_s=0.15, imu_grade=grade)
    yaw_err, yaw_3s = r.rpy_err_deg[:, 2], r.sigma3_deg[:, 2]
    print(f"{scenario} offline, imu_grade {grade} (core {r.core}): flag first raised at "
          f"{r.metrics['aligned_first_raised_at_s']} s, final yaw error {yaw_err[-1]:+.3f} deg (3-sigma "
          f"{yaw_3s[-1]:.3f} deg)")
    assert r.aligned.any(), r.diagnostics.get("message")
    assert abs(yaw_err[-1]) < yaw_3s[-1], (yaw_err[-1], yaw_3s[-1])
    assert not np.any(r.aligned & (np.abs(yaw_err) > 3.0)), yaw_err[r.aligned & (np.abs(yaw_err) > 3.0)]
    assert abs(yaw_err[-1]) < bound_deg, yaw_err[-1]
    assert r.counters["gnss_stale"] == 0 and r.counters["imu_rejected"] == 0, r.counters
