"""Wheel speed and dual-antenna GNSS heading: the node's conversions (one per convention), the session's entry points
(validation counted per reason, never raised, queued and taken at their stamps), the ``vehicle`` option."""

import math

import numpy as np
import pytest
from geometry_msgs.msg import QuaternionStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu

from insalign_ros.core.types import GnssHeading, ImuSample, WheelSpeed
from insalign_ros.nodes import conversions as cv
from insalign_ros.session.config import SessionConfig
from insalign_ros.session.session import AlignmentSession


def _quat_yaw(yaw):
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


@pytest.mark.parametrize("heading_ned_deg, yaw_enu_deg", [(0.0, 90.0), (90.0, 0.0), (180.0, -90.0), (270.0, -180.0),
                                                          (45.0, 45.0), (-30.0, 120.0)])
def test_ned_heading_is_the_enu_yaw_from_east_counter_clockwise(heading_ned_deg, yaw_enu_deg):
    """North (NED heading 0) is ENU yaw +90; East (heading 90) is yaw 0; a heading increases clockwise."""
    yaw = math.degrees(cv.yaw_enu_from_heading_ned(math.radians(heading_ned_deg)))
    assert abs(math.remainder(yaw - yaw_enu_deg, 360.0)) < 1e-9


def test_imu_heading_message_gives_the_orientation_yaw_and_its_variance():
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = 100, 500_000_000
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = _quat_yaw(math.radians(-120.0))
    m.orientation_covariance[8] = math.radians(0.2) ** 2
    h, reason = cv.gnss_heading_from_imu_msg(m)
    assert reason == "" and abs(h.stamp_s - 100.5) < 1e-12
    assert abs(math.degrees(h.yaw_rad) + 120.0) < 1e-9 and abs(math.degrees(math.sqrt(h.var_rad2)) - 0.2) < 1e-12
    m.orientation_covariance[8] = 0.0  # unset: refused with the reason
    assert cv.gnss_heading_from_imu_msg(m)[0] is None
    m.orientation_covariance[0], m.orientation_covariance[8] = -1.0, 1e-4  # "no orientation" (REP 145)
    assert "-1" in cv.gnss_heading_from_imu_msg(m)[1]


def test_quaternion_stamped_heading_takes_the_given_sigma():
    m = QuaternionStamped()
    m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w = _quat_yaw(math.radians(30.0))
    h, reason = cv.gnss_heading_from_quaternion_msg(m, math.radians(0.5))
    assert reason == "" and abs(math.degrees(h.yaw_rad) - 30.0) < 1e-9
    assert abs(h.var_rad2 - math.radians(0.5) ** 2) < 1e-15


def test_odometry_twist_in_the_child_frame_is_the_speed_along_x():
    """REP 105: the twist of an Odometry is in child_frame_id (the vehicle); reversing is negative; an unset
    variance takes the default sigma."""
    m = Odometry()
    m.child_frame_id = "base_link"
    m.twist.twist.linear.x, m.twist.twist.linear.y = -2.5, 0.3
    ws, reason = cv.wheel_speed_from_odometry(m)
    assert reason == "" and ws.speed_m_s == -2.5
    assert abs(ws.var_m2_s2 - cv.WHEEL_SPEED_DEFAULT_SIGMA_M_S ** 2) < 1e-15
    m.twist.covariance[0] = 0.04
    assert cv.wheel_speed_from_odometry(m)[0].var_m2_s2 == 0.04
    m.twist.twist.linear.x = float("nan")
    assert cv.wheel_speed_from_odometry(m)[0] is None


def test_session_counts_queues_and_takes_wheel_speed_and_heading_at_their_stamps():
    s = AlignmentSession(SessionConfig(core="iekf", init_mode="guess"))
    g = np.array([0.0, 0.0, 9.81])
    assert s.push_wheel_speed(WheelSpeed(0.5, 3.0, 0.01))
    assert s.push_gnss_heading(GnssHeading(0.5, 0.3, 1e-4))
    # bad inputs: counted per reason, never raised
    assert not s.push_wheel_speed(WheelSpeed(0.6, float("nan"), 0.01))
    assert not s.push_wheel_speed(WheelSpeed(0.7, 1.0, 0.0))
    assert not s.push_gnss_heading(GnssHeading(0.5, 0.1, 1e-4))  # duplicate stamp
    assert not s.push_gnss_heading(GnssHeading(0.8, 0.1, 100.0))  # 1-sigma above 180 deg
    c = s.counters
    assert (c["wheel_speed_received"], c["wheel_speed_invalid"], c["wheel_speed_rejected"]) == (3, 2, 2)
    assert (c["gnss_heading_received"], c["gnss_heading_duplicate"], c["gnss_heading_invalid"]) == (3, 1, 1)
    for k in range(200):
        s.push_imu(ImuSample(0.01 * k, np.zeros(3), g))
    from insalign_ros.core import earth
    from insalign_ros.core.types import GnssFix
    s.push_fix(GnssFix(0.05, earth.geodetic_to_ecef(0.8, 0.2, 100.0), np.eye(3)))
    s.finish()
    # taken at their stamps: the wheel speed has no model yet; the heading is fused (iekf accepts GnssHeading)
    assert c["wheel_speed_unused"] == 1 and c["gnss_heading_fused"] == 1 and c["gnss_heading_unused"] == 0
    d = s.diagnostics()
    assert d["vehicle"] == "unknown" and "no course constraint" in d["vehicle_assumes"]


def test_vehicle_option_is_validated_and_defaults_to_unknown():
    assert SessionConfig().vehicle == "unknown"
    SessionConfig(vehicle="car").validate()
    with pytest.raises(ValueError, match="vehicle"):
        SessionConfig(vehicle="tank").validate()


def test_gsf_seeds_the_in_motion_core_of_a_car_and_assumes_nothing_by_default(monkeypatch):
    """Simulated car (moving from 1.8 s, 1-Hz fixes only, no velocity topic), 40 s, fixed seed: with ``vehicle: car``
    the GSF (course constraint) seeds the in-motion core of ``core: auto`` with its yaw within 10 s (measured: 9 s,
    yaw 2.3 deg off at a 1-sigma of 4.4 deg) and the yaw stays inside its 3-sigma; with the default (``unknown``: pure
    GSF on fix differences, which never gets confident) nothing is seeded. The non-holonomic constraint is off here
    (with it the core finds its yaw first: the next test)."""
    from insalign_ros.session import fusion
    from insalign_ros.session.offline import align

    monkeypatch.setattr(fusion, "NHC_SIGMA_M_S", {})

    car = align("car", seed=0, duration_s=40.0, vehicle="car")
    d = car.diagnostics
    assert d["yaw_seeded_by"].startswith("GNSS velocity (fix differences)"), d["yaw_seeded_by"]
    assert d["gsf_seeds"] == "1" and "side-slip 3 deg" in d["vehicle_assumes"]
    late = car.t_s >= 12.0
    assert np.all(np.abs(car.rpy_err_deg[late, 2]) <= car.sigma3_deg[late, 2])
    assert not np.any(car.aligned & (np.abs(car.rpy_err_deg[:, 2]) > 2.0))
    unknown = align("car", seed=0, duration_s=40.0)
    assert unknown.diagnostics["gsf_seeds"] == "0"
    assert unknown.diagnostics["yaw_seeded_by"] != d["yaw_seeded_by"]


def test_a_message_the_node_refuses_is_counted_under_its_own_topic():
    s = AlignmentSession(SessionConfig())
    s.reject_input("wheel_speed", "wheel_speed_invalid", "NaN/Inf in the twist's linear.x or its covariance")
    s.reject_input("gnss_heading", "gnss_heading_invalid", "orientation_covariance[0] is -1 (no orientation)")
    c = s.counters
    assert (c["wheel_speed_received"], c["wheel_speed_invalid"], c["wheel_speed_rejected"]) == (1, 1, 1)
    assert (c["gnss_heading_received"], c["gnss_heading_invalid"], c["gnss_heading_rejected"]) == (1, 1, 1)
    assert c["gnss_rejected"] == 0


@pytest.mark.ros
@pytest.mark.timeout(90)
def test_node_takes_wheel_odometry_and_gnss_heading_over_dds(monkeypatch):
    """alignment_node subscribes wheel/odom (nav_msgs/Odometry) and gps/heading (sensor_msgs/Imu, ublox-style): every
    message reaches the session's counters, a bad one under its own reason (waits on the counters, not on time)."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from insalign_ros.cli.bringup import isolated_ros_env
    from insalign_ros.nodes.alignment_node import AlignmentNode

    for k, v in isolated_ros_env(base={}).items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = AlignmentNode(context=ctx, parameter_overrides=[Parameter("core", value="iekf"),
                                                           Parameter("poll_inputs", value=False)])
    pub = Node("vehicle_inputs_pub", context=ctx)
    po, ph = pub.create_publisher(Odometry, "wheel/odom", 10), pub.create_publisher(Imu, "gps/heading", 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node), ex.add_node(pub)
    try:
        end = time.monotonic() + 30.0
        while (po.get_subscription_count() == 0 or ph.get_subscription_count() == 0) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        for k in range(4):
            o, h = Odometry(), Imu()
            for m in (o, h):
                m.header.stamp.sec, m.header.stamp.nanosec = 1000 + k, 0
            o.twist.twist.linear.x = float("nan") if k == 3 else 5.0
            h.orientation.z, h.orientation.w = math.sin(0.25), math.cos(0.25)
            h.orientation_covariance[8] = 0.0 if k == 3 else 1e-4
            po.publish(o), ph.publish(h)
        c = node.session.counters
        while (c["wheel_speed_received"] < 4 or c["gnss_heading_received"] < 4) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        got = {k: v for k, v in c.items() if k.startswith(("wheel_speed", "gnss_heading"))}
        assert got["wheel_speed_received"] == 4 and got["wheel_speed_invalid"] == 1, got
        assert got["gnss_heading_received"] == 4 and got["gnss_heading_invalid"] == 1, got
    finally:
        ex.shutdown()
        node.destroy_node()
        pub.destroy_node()
        rclpy.shutdown(context=ctx)


@pytest.mark.parametrize("kind", ["enu", "ned", "course"])
def test_import_reads_gnss_velocity_wheel_speed_and_heading_columns(tmp_path, kind):
    """insalign-import: a GNSS velocity of (E, N, U) = (3, 4, 0) m/s given as ENU or NED components or as speed 5 m/s
    on a course of 36.87 deg from North; a wheel speed; a heading 30 deg from North (ENU yaw 60 deg); the rows
    without a value have none; ia.align hands them to the session (counted)."""
    from insalign_ros.io.importer import import_table, write_csv
    from insalign_ros.session.offline import align

    n = 400
    t = 0.01 * np.arange(n)
    nan = np.full(n, np.nan)
    cols = {"t_s": t, "wx_rad_s": np.zeros(n), "wy_rad_s": np.zeros(n), "wz_rad_s": np.zeros(n),
            "fx_m_s2": np.zeros(n), "fy_m_s2": np.zeros(n), "fz_m_s2": np.full(n, 9.81),
            "lat_deg": nan.copy(), "lon_deg": nan.copy(), "h_m": nan.copy(), "sigma_h_m": nan.copy()}
    every = np.arange(0, n, 100)
    cols["lat_deg"][every], cols["lon_deg"][every], cols["h_m"][every], cols["sigma_h_m"][every] = 49.0, 8.4, 115.0, 1.0
    vel = {"enu": {"vel_e_m_s": 3.0, "vel_n_m_s": 4.0, "vel_u_m_s": 0.0},
           "ned": {"vel_north_m_s": 4.0, "vel_east_m_s": 3.0, "vel_down_m_s": 0.0},
           "course": {"speed_m_s": 5.0, "course_deg": math.degrees(math.atan2(3.0, 4.0))}}[kind]
    for name, v in {**vel, "sigma_vel_m_s": 0.1, "wheel_speed_m_s": 5.0, "gnss_heading_deg": 30.0,
                    "sigma_heading_deg": 0.5}.items():
        cols[name] = nan.copy()
        cols[name][every] = v
    data, report = import_table(write_csv(tmp_path / "log.csv", cols))
    assert report["gnss_velocities"] == 4 and report["wheel_speeds"] == 4 and report["gnss_headings"] == 4
    assert np.allclose(data.gnss_vel_n, [3.0, 4.0, 0.0], atol=1e-9)
    assert np.allclose(data.gnss_vel_R_n[0], 0.01 * np.eye(3))
    assert np.allclose(np.degrees(data.heading_yaw_rad), 60.0) and np.allclose(data.wheel_speed_m_s, 5.0)
    assert np.allclose(data.wheel_var_m2_s2, 0.01)  # the default 1-sigma 0.1 m/s
    c = align(data, core="iekf", init_mode="guess").counters
    assert c["wheel_speed_received"] == 4 and c["gnss_heading_received"] == 4 and c["gnss_vel_received"] == 4


def test_wheel_speed_and_heading_are_written_to_the_bag_as_drivers_publish_them(tmp_path):
    """write_bag: /wheel/odom nav_msgs/Odometry (twist.linear.x, covariance[0]) and /gps/heading sensor_msgs/Imu
    (ENU yaw in the orientation, orientation_covariance[8]); read back with the node's conversions."""
    from rosbags.highlevel import AnyReader

    from insalign_ros.io.bag import typestore, write_bag
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("car", seed=1, duration_s=3.0)
    d.wheel_t_s, d.wheel_speed_m_s, d.wheel_var_m2_s2 = np.array([1.0, 2.0]), np.array([4.0, -1.0]), np.full(2, 0.01)
    d.heading_t_s, d.heading_yaw_rad, d.heading_var_rad2 = np.array([1.5]), np.array([2.5]), np.array([1e-4])
    bag = write_bag(d, tmp_path / "b")
    got = {}
    with AnyReader([bag], default_typestore=typestore()) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        assert types["/wheel/odom"] == "nav_msgs/msg/Odometry" and types["/gps/heading"] == "sensor_msgs/msg/Imu"
        conns = [c for c in r.connections if c.topic in ("/wheel/odom", "/gps/heading")]
        for c, _, raw in r.messages(connections=conns):
            got.setdefault(c.topic, []).append(r.deserialize(raw, c.msgtype))
    ws = [cv.wheel_speed_from_odometry(m)[0] for m in got["/wheel/odom"]]
    assert [w.speed_m_s for w in ws] == [4.0, -1.0] and [w.stamp_s for w in ws] == [1.0, 2.0]
    assert ws[0].var_m2_s2 == 0.01
    h, reason = cv.gnss_heading_from_imu_msg(got["/gps/heading"][0])
    assert reason == "" and abs(h.yaw_rad - 2.5) < 1e-12 and h.var_rad2 == 1e-4
    # read_bag reads them back; ia.align on the bag hands them to the session
    from insalign_ros.io.bag import read_bag
    from insalign_ros.session.offline import align

    back = read_bag(bag)
    assert back.wheel_t_s.tolist() == [1.0, 2.0] and back.wheel_speed_m_s.tolist() == [4.0, -1.0]
    assert abs(back.heading_yaw_rad[0] - 2.5) < 1e-12 and back.heading_var_rad2.tolist() == [1e-4]
    c = align(str(bag), core="iekf", init_mode="truth").counters
    assert c["wheel_speed_received"] == 2 and c["gnss_heading_received"] == 1


def test_simulated_wheel_speed_and_dual_antenna_heading():
    """make_scenario: wheel speed = the body-x velocity times (1 + scale error) plus noise, at wheel_rate_hz; heading =
    the ENU yaw of the body baseline plus noise at the fix stamps; off by default (the other signals unchanged)."""
    from insalign_ros.core import earth
    from insalign_ros.sim.scenarios import make_scenario

    kw = dict(seed=3, duration_s=30.0)
    base = make_scenario("car", **kw)
    assert base.wheel_t_s is None and base.heading_t_s is None
    d = make_scenario("car", wheel_speed_sigma_m_s=0.05, wheel_scale_error=0.02, gnss_heading_sigma_deg=0.2,
                      gnss_heading_baseline_yaw_deg=90.0, **kw)
    assert np.array_equal(d.omega_ib_b, base.omega_ib_b) and np.array_equal(d.gnss_p_e, base.gnss_p_e)
    assert len(d.wheel_t_s) == 301 and np.allclose(np.diff(d.wheel_t_s), 0.1)
    k = np.searchsorted(d.t_s, d.wheel_t_s)
    v_x = np.einsum("nj,nj->n", d.C_b_n[k][:, :, 0], d.v_n[k])
    err = d.wheel_speed_m_s - 1.02 * v_x
    assert abs(np.std(err) - 0.05) < 0.01 and abs(np.mean(err)) < 0.01
    kh = np.searchsorted(d.t_s, d.heading_t_s)
    yaw_x = earth.rpy_from_C_b_n(d.C_b_n[kh])[:, 2]
    e = np.degrees(np.remainder(d.heading_yaw_rad - yaw_x - np.pi / 2 + np.pi, 2 * np.pi) - np.pi)
    assert np.max(np.abs(e)) < 1.0 and abs(np.std(e) - 0.2) < 0.08  # baseline 90 deg left of x (small roll/pitch)


def test_the_benchmark_shortened():
    """benchmarks/vehicle_yaw_seed.py on one 40-s car run: seeded by the GSF, no flag up with abs(yaw err) > 2 deg,
    coverage 1 (the full benchmark: docs/yaw_gsf.md, "In the session")."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "vehicle_yaw_seed.py"
    spec = importlib.util.spec_from_file_location("vehicle_yaw_seed", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    row = bench.run("car", 0, "car", 40.0)
    # with the non-holonomic constraint the core finds its yaw before the GSF is confident (no seed needed)
    assert row["seeded_by"] in ("the core itself",) or row["seeded_by"].startswith("GNSS velocity"), row
    assert row["max_err_up_deg"] <= 2.0 and row["coverage"] == 1.0, row
    assert row["t_flag_s"] <= 40.0, row


def _bench():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "vehicle_yaw_seed.py"
    spec = importlib.util.spec_from_file_location("vehicle_yaw_seed", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


@pytest.mark.parametrize("seed", [2, 3])
def test_parked_then_driving_car_flags_when_its_heading_is_certain(seed):
    """Issue 25, shortened (benchmarks/vehicle_yaw_seed.py --park-s 30 --until 25; the full table: docs/yaw_gsf.md):
    park_drive parked 30 s, ``vehicle: car``, 1-Hz fixes only. Every criterion holds once the yaw 3-sigma is below
    2.5 deg, 9.5-10.4 s after the first motion (the information of 1-m fixes on a 1.5 m/s^2 drive-off: the
    Cramer-Rao bound is 9-10 s), and the flag rises hold_s (5 s) later. Seed 2: before the yaw bank reported the
    innovation of the component it publishes, a discarded heading's NIS of 34 held the flag's NIS window over its
    band until 12.5 s (flag 17.6 s); now 9.6 s (flag 14.7 s). No flag up with abs(yaw error) > 2 deg; coverage 1."""
    row = _bench().run("park_drive", seed, "car", 150.0, until_s=25.0, park_s=30.0)
    assert row["t_criteria_s"] <= 11.0, row
    assert row["t_flag_s"] <= row["t_criteria_s"] + 5.5, row
    assert row["max_err_up_deg"] <= 2.0 and row["max_err_criteria_deg"] <= 2.0, row
    assert row["coverage"] >= 0.95, row


def test_a_car_parked_for_seconds_flags_when_its_heading_is_certain():
    """Issue 25, shortened: the simulated car parks 4.5 s, then drives (``vehicle: car``, 1-Hz fixes, seed 0). core
    auto measures its gyro bias over that rest (gyro_rest_min_s 4 s); the yaw criterion holds 8.7 s after the first
    motion, the level's (1-deg 3-sigma) at 19.7 s: the constraint's vertical row, which made it 8.7 s, is left out
    (it ties the pitch to the vehicle's direction of travel, which a real IMU's mounting does not follow: KITTI 0042,
    docs/yaw_gsf.md); the yaw error inside its 3-sigma."""
    row = _bench().run("car", 0, "car", 120.0, until_s=30.0)
    assert row["t_yaw_s"] <= 9.5 and row["t_level_s"] <= 21.0 and row["t_criteria_s"] <= 21.0, row
    assert row["max_err_criteria_deg"] <= 2.0 and row["coverage"] == 1.0, row


def test_the_non_holonomic_constraint_of_a_car_makes_the_heading_certain_sooner():
    """``vehicle: car``: the session fuses the non-holonomic constraint (10 Hz, lateral 0.5 m/s; no vertical row)
    into the in-motion core. Simulated car (moving from 1.8 s, 1-Hz fixes only), core iekf from the sensors, 45 s,
    seed 0: the yaw 3-sigma at the end is at least 2x smaller than without it (measured 1.15 vs 5.32 deg; the flag
    up at the end) and the error stays inside it; every constraint passes its gate (the simulated car does not slide)."""
    import insalign_ros as ia

    out = {v: ia.align("car", core="iekf", seed=0, duration_s=45.0, vehicle=v) for v in ("unknown", "car")}
    base, nhc = out["unknown"], out["car"]
    assert int(base.diagnostics["nhc_accepted"]) == 0
    c = nhc.diagnostics
    assert int(c["nhc_accepted"]) >= 400 and int(c["nhc_rejected"]) == 0, c
    s_base, s_nhc = base.sigma3_deg[-1, 2], nhc.sigma3_deg[-1, 2]
    assert s_nhc < 0.5 * s_base, (s_nhc, s_base)
    assert abs(nhc.rpy_err_deg[-1, 2]) <= s_nhc, (nhc.rpy_err_deg[-1], s_nhc)
