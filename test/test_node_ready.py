"""alignment_node over real DDS (two processes): readiness and what a fusion node sees (issue 26 items 1, 3, 6;
docs/nodes.md "Start-up and readiness", "~/imu and robot_localization", "Frames").

- With an EMPTY numba cache the node compiles its kernels before it subscribes ("ready (kernels compiled in X s)"),
  so a driver that starts streaming as soon as it sees a subscriber loses nothing: every message sent at 200 Hz is
  counted by the node (its /diagnostics). The default run compiles the static core's kernels (pkf); the default
  core's (auto, 1.5 times the compile time) is marked slow.
- With the defaults no ~/imu message goes out before the first ~/aligned True, and every ~/imu message carries an
  attitude covariance inside the flag's bounds; ~/pose is in frame ``map``, ~/imu in ``base_link``; ordinary driver
  frame ids (``imu``, ``/gps``) pass without a warning; /diagnostics ``hardware_id`` names the IMU.
"""

import re
import threading
import time

import numpy as np
import pytest

from insalign_ros.cli.bringup import start_node, stop_nodes, wait_for_exit

pytestmark = pytest.mark.ros
ALIGN = "insalign_ros.nodes.alignment_node"
SIM = "insalign_ros.nodes.imu_sim_node"


def _wait(pred, timeout_s: float, period_s: float = 0.05) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(period_s)
    return bool(pred())


@pytest.mark.timeout(600)
@pytest.mark.parametrize("core", [
    # the Earth-frame IEKF compiles 2 kernels of its own (~9 s cold on an idle machine; pkf 21 kernels, 22 s; the
    # default core 35 s): the same warm-up-before-subscribe path as any core's
    # (AlignmentNode.__init__ -> session.warmup.warm_up((core,))), and a compile of seconds in the first tick
    # would still overflow the 1-s reader queue
    "earth_iekf",
    # the default core, what a first run compiles (75 s, the longest test of a 10-min CI run): -m slow
    pytest.param("auto", marks=pytest.mark.slow),
])
def test_cold_numba_cache_the_node_subscribes_when_ready_and_loses_nothing(tmp_path, ros_env, core):
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from insalign_ros.nodes.monitor import AlignmentMonitor

    env = dict(ros_env, NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))  # nothing compiled: the first run's case
    mon = AlignmentMonitor()
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    drv = Node("driver", context=ctx)
    pub = drv.create_publisher(Imu, "imu/data", QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                                                            reliability=ReliabilityPolicy.RELIABLE))
    nodes = []
    try:
        t_start = time.monotonic()
        # a reader queue of 1 s at 200 Hz: a first tick that compiled for seconds would overflow it
        nodes.append(start_node(ALIGN, env, log_dir=tmp_path, params={"imu_timeout_s": 0.0, "imu_qos_depth": 200,
                                                                          "core": core}))
        # the driver: streams as soon as it sees a subscriber (as a real driver does not wait at all: then the
        # first messages are lost to DDS whatever the node does; that part is the driver's)
        assert _wait(lambda: pub.get_subscription_count() > 0 or not nodes[0].alive(), 500.0, 0.01)
        t_sub = time.monotonic() - t_start
        assert nodes[0].alive(), nodes[0].output()[-3000:]
        # 5 s at 200 Hz, five reader queues (2,000 before: 5 s of the test; the same run with the kernels compiled
        # in the first processing tick instead, the warm-up switched off, fails here: messages lost)
        n, rate_hz, t0 = 1000, 200.0, time.monotonic()
        base = 1_700_000_000
        for k in range(n):
            m = Imu()
            m.header.stamp.sec, m.header.stamp.nanosec = base + k // 200, (k % 200) * 5_000_000
            m.header.frame_id = "imu_link"
            m.linear_acceleration.z = 9.81
            m.angular_velocity.x = 1e-5
            m.orientation_covariance[0] = -1.0
            pub.publish(m)
            time.sleep(max(0.0, t0 + (k + 1) / rate_hz - time.monotonic()))
        wall = time.monotonic() - t0
        assert mon.wait_for(lambda m: m.diag.get("imu_messages_taken") == str(n), 60.0), mon.diag
        log = nodes[0].output()
        ready = re.search(r"ready \(kernels compiled in ([0-9.]+) s\)", log)
        assert ready, log[-3000:]
        assert log.index("ready (kernels compiled") < log.index("waiting for imu/data")
        print(f"cold numba cache: ready after {float(ready.group(1)):.1f} s of compilation, subscription seen "
              f"{t_sub:.1f} s after the start; {n} Imu sent at {n / wall:.0f} Hz, node took "
              f"{mon.diag['imu_messages_taken']}, session received {mon.counter('imu_received')}")
        assert mon.counter("imu_received") == n and mon.counter("imu_rejected") == 0, mon.diag
        assert mon.diag.get("node_errors") == "0", mon.diag
    finally:
        stop_nodes(nodes)
        drv.destroy_node()
        rclpy.shutdown(context=ctx)
        mon.close()


@pytest.mark.timeout(300)
def test_imu_only_once_aligned_frames_and_hardware_id(tmp_path, ros_env):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Imu

    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor(keep_poses=100000)
    imus, hw = [], []
    # created after the monitor's ~/aligned subscription: in one wait of its executor the flag is handled first
    mon.node.create_subscription(Imu, "alignment_node/imu", lambda m: imus.append((time.monotonic(), m)), 10000)
    mon.node.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda a: hw.extend(s.hardware_id for s in a.status), 10)
    nodes = []
    try:
        nodes.append(start_node(ALIGN, ros_env, log_dir=tmp_path, params={"imu_timeout_s": 0.0,
                                                                          "imu_grade": "paper_ship"}))
        sim = start_node(SIM, ros_env, log_dir=tmp_path, params={
            "source": "scenario", "scenario": "ship", "seed": 3, "duration_s": 100.0, "rate_factor": 20.0,
            "wait_for_subscribers": 1, "wait_timeout_s": 120.0, "qos": "reliable", "qos_depth": 2000,
            "frame_id": "imu", "gps_frame_id": "/gps", "pace_topic": "/alignment_node/pose", "max_lead_s": 2.0})
        nodes.append(sim)
        assert wait_for_exit(sim, 200.0) == 0, sim.output()[-2000:]
        assert mon.wait_for(lambda m: m.aligned is True and len(imus) > 0, 20.0), (mon.aligned_history, mon.diag)
        with mon.lock:
            first_true = min(w for w, v, _ in mon.aligned_history if v)
            poses = list(mon.poses)
        first_imu = imus[0][0]
        # the monitor's clock: the flag True was handled before the first ~/imu arrived
        assert first_true <= first_imu, (first_true, first_imu)
        yaw3 = [3.0 * np.degrees(np.sqrt(m.orientation_covariance[8])) for _, m in imus]
        lim = 2.5  # aligned.yaw_3sigma_deg (default)
        n_before = sum(1 for p in poses if (p.header.stamp.sec, p.header.stamp.nanosec)
                       < (imus[0][1].header.stamp.sec, imus[0][1].header.stamp.nanosec))
        print(f"~/imu: {len(imus)} messages, the first {first_imu - first_true:.3f} s after the first ~/aligned True; "
              f"{n_before} ~/pose before it; yaw 3-sigma of ~/imu max {max(yaw3):.2f} deg; hardware_id {set(hw)}")
        assert max(yaw3) < lim and n_before > 50
        assert {p.header.frame_id for p in poses} == {"map"}
        assert {m.header.frame_id for _, m in imus} == {"base_link"}
        assert set(hw) == {"imu"}, set(hw)
        log = nodes[0].output()
        assert not [ln for ln in log.splitlines() if "WARN" in ln and "frame" in ln], log[-3000:]
    finally:
        stop_nodes(nodes)
        mon.close()
