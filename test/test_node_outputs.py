"""alignment_node outputs for the ROS ecosystem over real DDS (issue 13 item 5): ``~/imu`` (the estimated orientation
ENU with the REP 145 covariance P_att_n, the measured sample in vehicle FLU at that stamp), ``~/datum`` (transient
local, the ENU origin, again after a reset) and the ``~/reset`` service (std_srvs/Trigger)."""

import dataclasses
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import insalign_ros as ia
from insalign_ros.cli.bringup import isolated_ros_env, start_node, stop_nodes, wait_for_exit
from insalign_ros.core import earth

SIM = "insalign_ros.nodes.imu_sim_node"
ALIGN = "insalign_ros.nodes.alignment_node"


def _frd_mounted_bag(d, path, mount_deg):
    """A bag of what an FRD IMU mounted at ``mount_deg`` measures for the motion of ``d`` (vehicle FLU)."""
    from test_imu_axes import _sensor_data

    from insalign_ros.io.bag import write_bag

    w_s, f_s = _sensor_data(d, "frd", mount_deg)
    return write_bag(dataclasses.replace(d, omega_ib_b=w_s, f_ib_b=f_s), path)


def _wait(pred, timeout_s):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.05)
    return pred()


def _play(bag, env, tmp_path, name):
    sim = start_node(SIM, env, log_dir=tmp_path, name=name, params={
        "source": "bag", "bag_path": str(bag), "rate_factor": 10.0, "wait_for_subscribers": 1,
        "wait_timeout_s": 180.0, "qos": "reliable", "qos_depth": 5000})
    assert wait_for_exit(sim, 60.0) == 0, sim.output()[-2000:]
    return sim


def test_imu_message_without_a_measured_sample_says_no_estimate():
    """REP 145: an output stamp with no measured sample (one that bridged a gap) gets zero rate and acceleration with
    covariance element 0 = -1; the orientation covariance is P_att_n as given (ENU axes, rad^2)."""
    from types import SimpleNamespace

    pytest.importorskip("sensor_msgs", reason="builds a sensor_msgs/Imu: needs the ROS 2 message packages")
    from insalign_ros.nodes import conversions as cv

    C = earth.C_b_n_from_rpy(0.1, -0.2, 2.5)
    P = np.array([[4e-6, 1e-7, 0.0], [1e-7, 5e-6, 0.0], [0.0, 0.0, 9e-4]])
    est = SimpleNamespace(stamp_s=12.25, C_b_n=C, P_att_n=P)
    m = cv.imu_msg(est, "base_link", epoch_s=1_700_000_000)
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1_700_000_012, 250_000_000)
    q = m.orientation
    np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), C, atol=1e-15)
    assert np.array_equal(np.asarray(m.orientation_covariance).reshape(3, 3), P)
    assert m.angular_velocity_covariance[0] == -1.0 and m.linear_acceleration_covariance[0] == -1.0
    assert (m.angular_velocity.x, m.linear_acceleration.z) == (0.0, 0.0)
    cov = np.eye(3).reshape(-1) * 1e-6
    m = cv.imu_msg(est, "base_link", 0, (np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 9.8]), cov, 4 * cov))
    assert (m.angular_velocity.y, m.linear_acceleration.z) == (0.2, 9.8)
    assert m.angular_velocity_covariance[0] == 1e-6 and m.linear_acceleration_covariance[8] == 4e-6


@pytest.mark.ros
@pytest.mark.timeout(360)
def test_imu_datum_and_reset_over_dds(tmp_path, monkeypatch):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, NavSatFix
    from std_srvs.srv import Trigger

    from insalign_ros.nodes.monitor import AlignmentMonitor

    env = isolated_ros_env()
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(k, env[k])
    mount = [3.0, -5.0, 120.0]
    ship = ia.simulate("ship", seed=2, duration_s=10.0)
    car = ia.simulate("car", seed=2, duration_s=10.0)
    bag_ship = _frd_mounted_bag(ship, tmp_path / "ship", mount)
    bag_car = _frd_mounted_bag(car, tmp_path / "car", mount)
    rpy0 = (np.degrees(earth.rpy_from_C_b_n(ship.C_b_n[0])) + [1.0, -1.0, 5.0]).tolist()

    mon = AlignmentMonitor(keep_poses=100000)
    imus, datums = [], []
    n = mon.node
    n.create_subscription(Imu, "alignment_node/imu", lambda m: imus.append(m), 10000)
    nodes = []
    try:
        nodes.append(start_node(ALIGN, env, log_dir=tmp_path, params={
            "core": "iekf", "init_mode": "guess", "initial_rpy_deg": str(rpy0), "initial_velocity_enu_m_s": str(ship.v_n[0].tolist()),
            "imu_axes": "frd", "imu_mount_rpy_deg": str(mount), "imu_timeout_s": 0.0, "imu_qos": "reliable",
            "imu_qos_depth": 5000, "gnss_qos": "reliable", "imu_grade": "paper_ship",
            "publish_imu_before_aligned": True}))  # ~/imu before the flag too: its content is checked here
        assert mon.wait_for(lambda m: m.diag_count > 0 and n.count_publishers("/alignment_node/imu") > 0, 30.0)
        sim = _play(bag_ship, env, tmp_path, "sim_ship")
        t0_ns = _sim_first_stamp_ns(sim)
        assert mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0
                            and m.counter("imu_received") == ship.n, 20.0), mon.diag
        assert _wait(lambda: len(imus) == mon.pose_count and imus, 5.0), (len(imus), mon.pose_count)

        # ~/imu: the pose's orientation and its rotation covariance block, in the vehicle frame base_link
        with mon.lock:
            poses = {_ns(p): p for p in mon.poses}
        n_checked = 0
        for m in imus:
            p = poses[_ns(m)]
            q, qp = m.orientation, p.pose.pose.orientation
            assert (q.x, q.y, q.z, q.w) == (qp.x, qp.y, qp.z, qp.w)
            P6 = np.asarray(p.pose.covariance).reshape(6, 6)
            assert np.array_equal(np.asarray(m.orientation_covariance).reshape(3, 3), P6[3:, 3:])
            assert m.header.frame_id == "base_link"
            # the measured sample at that stamp, back in vehicle FLU axes (the FRD mounted data converted)
            k = int(round((_ns(m) - t0_ns) * 1e-9 * 100.0))
            av, la = m.angular_velocity, m.linear_acceleration
            np.testing.assert_allclose([av.x, av.y, av.z], ship.omega_ib_b[k], rtol=0, atol=1e-12)
            np.testing.assert_allclose([la.x, la.y, la.z], ship.f_ib_b[k], rtol=0, atol=1e-12)
            assert m.angular_velocity_covariance[0] > 0 and m.linear_acceleration_covariance[0] > 0
            n_checked += 1
        assert n_checked >= 95, n_checked  # 10 s at 10 Hz
        # ENU orientation of the vehicle (not of the IMU, mounted 120 deg off in yaw): near the truth at the end
        last = imus[-1]
        C = Rotation.from_quat([last.orientation.x, last.orientation.y, last.orientation.z,
                                last.orientation.w]).as_matrix()
        k = int(round((_ns(last) - t0_ns) * 1e-9 * 100.0))
        err_deg = np.degrees(np.linalg.norm(Rotation.from_matrix(C @ ship.C_b_n[k].T).as_rotvec()))
        sigma3_deg = 3 * np.degrees(np.sqrt(np.trace(np.asarray(last.orientation_covariance).reshape(3, 3))))
        print(f"~/imu: {n_checked} messages = ~/pose; final attitude error {err_deg:.3f} deg (3-sigma of the "
              f"rotation norm {sigma3_deg:.3f} deg)")
        assert err_deg < sigma3_deg

        # ~/datum: transient local (this subscriber joins after it was published), the ship's first fix
        latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        n.create_subscription(NavSatFix, "alignment_node/datum", lambda m: datums.append(m), latched)
        assert _wait(lambda: len(datums) == 1, 10.0), datums
        lat, lon, h = earth.ecef_to_geodetic(ship.gnss_p_e[0])
        _assert_datum(datums[0], lat, lon, h)

        # ~/reset: the alignment restarts (flag down, waiting for data); the next initialisation sends a new datum
        cli = n.create_client(Trigger, "alignment_node/reset")
        assert cli.wait_for_service(timeout_sec=10.0)
        fut = cli.call_async(Trigger.Request())
        assert _wait(fut.done, 10.0)
        res = fut.result()
        assert res.success and "restarted" in res.message, res.message
        assert mon.wait_for(lambda m: m.diag.get("state") == "waiting for data" and m.aligned is False, 10.0), \
            (mon.diag, mon.aligned)
        _play(bag_car, env, tmp_path, "sim_car")
        # >= 2: the ship's initial guess (velocity 14 m/s) is wrong for the car at rest; the divergence guard may
        # re-initialise it from the sensors, which publishes a third datum (the second is the car's first fix)
        assert _wait(lambda: len(datums) >= 2, 15.0), datums
        lat, lon, h = earth.ecef_to_geodetic(car.gnss_p_e[0])
        _assert_datum(datums[1], lat, lon, h)
        print(f"~/datum: ship {datums[0].latitude:.6f} {datums[0].longitude:.6f}, after ~/reset car "
              f"{datums[1].latitude:.6f} {datums[1].longitude:.6f}; reset answer: {res.message!r}")
    finally:
        stop_nodes(nodes)
        mon.close()


def _ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _sim_first_stamp_ns(sim) -> int:
    from conftest import sim_summary as _sim_summary

    return _sim_summary(sim)["first_stamp_ns"]


def _assert_datum(msg, lat_rad, lon_rad, h_m):
    from sensor_msgs.msg import NavSatFix

    assert abs(msg.latitude - np.degrees(lat_rad)) < 1e-9 and abs(msg.longitude - np.degrees(lon_rad)) < 1e-9
    assert abs(msg.altitude - h_m) < 1e-3 and msg.header.frame_id == "map"  # world_frame (REP 105)
    assert msg.position_covariance_type == NavSatFix.COVARIANCE_TYPE_UNKNOWN


def test_tf_frames_rep105():
    """The TF the node broadcasts with publish_tf: world_frame (map by default) -> tf_child_frame (base_link), the
    ENU position from the datum and the attitude body FLU -> ENU (the same quaternion as ~/pose). Built without
    tf2_msgs (geometry_msgs/TransformStamped); the broadcast itself needs tf2_msgs/TFMessage."""
    from insalign_ros.nodes import conversions as cv
    from insalign_ros.nodes.params import NODE_PARAMS
    from insalign_ros.nodes.publishing import tf_msg

    assert (NODE_PARAMS["world_frame"][0], NODE_PARAMS["tf_child_frame"][0], NODE_PARAMS["publish_tf"][0]) == \
        ("map", "base_link", False)
    lat, lon, h = np.radians(45.0), np.radians(7.0), 100.0
    C = Rotation.from_euler("xyz", [1.0, -2.0, 30.0], degrees=True).as_matrix()

    class E:
        stamp_s, lat_rad, lon_rad, h_m, C_b_n = 2.5, lat + 1e-5, lon, h + 3.0, C

    m = tf_msg(E(), (lat, lon, h), "map", "base_link", 1_700_000_000)
    assert (m.header.frame_id, m.child_frame_id) == ("map", "base_link")
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1_700_000_002, 500_000_000)
    t = m.transform.translation
    want = earth.ecef_to_enu(earth.geodetic_to_ecef(lat + 1e-5, lon, h + 3.0), lat, lon, h)
    np.testing.assert_allclose([t.x, t.y, t.z], want, atol=1e-9)
    assert abs(t.y - 63.7) < 0.5 and abs(t.z - 3.0) < 1e-3  # 1e-5 rad north, 3 m up
    r = m.transform.rotation
    np.testing.assert_allclose([r.x, r.y, r.z, r.w], cv.quat_xyzw(C), atol=1e-15)
