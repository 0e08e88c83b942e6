"""core: auto over real DDS (issue 14): alignment_node with default parameters (core auto, imu_grade unknown_mems)
plus topic remaps, fed a park_drive stream the driver way (test_node_driver_style.Driver: best-effort QoS, driver frame ids, stamp jitter,
fixes 150 ms late, no truth, no guess), passes through the states in order and ends aligned."""

import threading
import time

import pytest

from insalign_ros.cli.bringup import start_node, stop_nodes
from test_node_driver_style import ALIGN, Driver

pytestmark = pytest.mark.ros


@pytest.mark.timeout(270)
def test_auto_core_goes_through_the_states_in_order_over_dds(tmp_path, ros_env):
    from insalign_ros.nodes.monitor import AlignmentMonitor
    from insalign_ros.sim.scenarios import make_scenario

    park = 26.0
    # 40 s of driving: with the default unknown_mems grade (360 deg/h, 5 mg priors on a 5 deg/h, 1 mg IMU) the flag
    # comes up 34 s after the drive-off (offline, the same data: 60.0 s), the gyro bias measured while parked
    # carried across the hand-over (docs/session.md)
    d = make_scenario("park_drive", seed=4, duration_s=park + 40.0, rate_hz=100.0, park_s=park, door_at_s=5.0,
                      heading_deg=150.0)
    node = start_node(ALIGN, ros_env, params={"diagnostics_period_s": 0.05}, log_dir=tmp_path,
                      remaps={"imu/data": "/imu/data_raw", "gps/fix": "/fix"})
    mon = AlignmentMonitor()
    drv = Driver(d)
    seen: list[tuple[str, str]] = []
    stop = threading.Event()

    def watch():  # the sequence of (session status, auto state) the diagnostics show
        while not stop.is_set():
            with mon.lock:
                key = (mon.diag.get("state", ""), mon.diag.get("core.state", "-"))
            if key[0] and (not seen or seen[-1] != key):
                seen.append(key)
            time.sleep(0.01)

    th = threading.Thread(target=watch, daemon=True)
    try:
        up = (lambda m: min(drv.pub_imu.get_subscription_count(), drv.pub_fix.get_subscription_count(),
                            m.node.count_publishers("/alignment_node/pose"), m.diag_count) >= 1)
        assert mon.wait_for(up, 180.0), "alignment_node did not come up"
        th.start()
        drv.stream()  # 1000 msgs/s (10x real time): the auto core keeps up since it skips the detector at speed
        assert mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0
                            and int(m.diag.get("imu_received", "0")) > 0.9 * d.n, 90.0), mon.diag
        time.sleep(0.5)
        stop.set()
        th.join(2.0)
        with mon.lock:
            diag = dict(mon.diag)
        print("states seen:", seen)
        order = []
        for _, s in seen:
            if s != "-" and (not order or order[-1] != s):
                order.append(s)
        assert order[:3] == ["static, levelling", "static, fine", "in motion"], seen
        statuses = [st for st, _ in seen]
        assert statuses.index("waiting for motion") < statuses.index("aligned"), seen
        # the flag at the newest data (the watchdog lowers "aligned" once the stream has ended)
        assert diag["aligned_at_last_output"] == "true" and diag["core.state"] == "in motion", diag
        assert diag["core.handovers"] == "1" and int(diag["core_faults"]) == 0, diag
        assert diag["core"] == "auto", diag  # the default
    finally:
        stop.set()
        drv.close()
        mon.close()
        stop_nodes([node])
