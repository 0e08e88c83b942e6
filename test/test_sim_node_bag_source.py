"""imu_sim_node's bag source (issue 13 item 6, issue 15 item 1): foreign topic names and the UNKNOWN-covariance sigma
reach read_bag; samples the bag flags invalid are a gap on imu/data and flagged fixes go out with STATUS_NO_FIX."""

import time

import numpy as np
import pytest

from insalign_ros.cli.bringup import isolated_ros_env
from insalign_ros.core import earth
from insalign_ros.io.bag import write_bag
from insalign_ros.sim.scenarios import make_scenario

pytestmark = pytest.mark.ros


@pytest.fixture()
def ros_ctx(monkeypatch):
    import rclpy

    for k, v in isolated_ros_env(base={}).items():
        monkeypatch.setenv(k, v)
    ctxs = []

    def make(params: dict):
        ctx = rclpy.Context()
        args = ["--ros-args"] + [a for k, v in params.items() for a in ("-p", f"{k}:={v}")]
        rclpy.init(args=args, context=ctx)
        ctxs.append(ctx)
        return ctx

    yield make
    for ctx in ctxs:
        rclpy.shutdown(context=ctx)


@pytest.mark.timeout(60)
def test_foreign_bag_topics_and_unknown_fix_sigma(ros_ctx, tmp_path):
    from test_bag_foreign import write_foreign_bag

    from insalign_ros.nodes.imu_sim_node import ImuSimNode

    d = make_scenario("car", seed=4, duration_s=5.0, noise=False)
    write_foreign_bag(d, tmp_path / "f")
    ctx = ros_ctx({"source": "bag", "bag_path": str(tmp_path / "f"), "bag_imu_topic": "/imu/data_raw",
                   "bag_gps_topic": "/fix", "bag_truth_topic": "/truth", "unknown_fix_sigma_m": 3})  # an int
    node = ImuSimNode(context=ctx)
    try:
        data = node.data
        assert data.n == d.n and data.gnss_t_s.shape == d.gnss_t_s.shape and data.has_truth
        C = earth.C_e_n(d.lat_rad[0], d.lon_rad[0])
        np.testing.assert_allclose(np.diag(C @ data.gnss_R_e[0] @ C.T), [9.0, 9.0, 9.0], atol=1e-9)
    finally:
        node.destroy_node()


@pytest.mark.timeout(60)
def test_flagged_samples_are_a_gap_and_flagged_fixes_say_no_fix(ros_ctx, tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, NavSatFix

    from insalign_ros.nodes.imu_sim_node import ImuSimNode
    from insalign_ros.nodes.qos import imu_qos

    s = make_scenario("ship", seed=2, duration_s=3.0)
    s.imu_valid = np.ones(s.n, bool)
    s.imu_valid[100:150] = False  # 0.5 s flagged
    s.gnss_valid = np.array([True, False, True, True])
    write_bag(s, tmp_path / "b")
    ctx = ros_ctx({"source": "bag", "bag_path": str(tmp_path / "b"), "rate_factor": 20.0,
                   "wait_for_subscribers": 1, "wait_timeout_s": 10.0})
    node = ImuSimNode(context=ctx)
    sub = Node("flag_listener", context=ctx)
    got = {"imu": [], "fix": []}
    sub.create_subscription(Imu, "imu/data", lambda m: got["imu"].append(m.header.stamp), imu_qos("reliable", 1000))
    sub.create_subscription(NavSatFix, "gps/fix", lambda m: got["fix"].append(m.status.status),
                            imu_qos("reliable", 100))
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node), ex.add_node(sub)
    try:
        end = time.monotonic() + 30.0
        while not node._ready() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        time.sleep(0.5)
        nxt = node.publish_due(time.monotonic())
        while nxt is not None and time.monotonic() < end:
            ex.spin_once(timeout_sec=max(0.0, min(nxt - time.monotonic(), 0.01)))
            nxt = node.publish_due(time.monotonic())
        while (len(got["imu"]) < s.n - 50 or len(got["fix"]) < 4) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        summary = node.summary()
        assert summary["imu_sent"] == s.n - 50 and summary["imu_flagged_skipped"] == 50
        assert len(got["imu"]) == s.n - 50
        t = np.array([st.sec + st.nanosec * 1e-9 for st in got["imu"]])
        assert np.max(np.diff(t)) == pytest.approx(0.51, abs=1e-6)  # the flagged half second is a gap
        assert got["fix"] == [0, -1, 0, 0]  # STATUS_FIX, STATUS_NO_FIX, ...
    finally:
        ex.shutdown()
        sub.destroy_node()
        node.destroy_node()
