"""Bag replay over real DDS: a contract rosbag2 (docs/bag_contract.md topics) -> imu_sim_node source:=bag ->
alignment_node, which must raise ``aligned`` with |yaw error| < 1 deg.

The bag is written from a ship scenario with ``insalign_ros.io.bag.write_bag`` (the contract writer) and read by
``insalign_ros.io.bag.read_bag`` inside imu_sim_node; the replayed stamps are data time from the replay start.
"""

import importlib.util
import time

import numpy as np
import pytest

from insalign_ros.cli.bringup import isolated_ros_env, start_node, stop_nodes, wait_for_exit

pytestmark = [pytest.mark.ros,
              pytest.mark.skipif(importlib.util.find_spec("insalign_ros.io.bag") is None,
                                 reason="insalign_ros/io/bag.py (the simulator issue's bag reader) has not landed")]

def _ship_bag_and_monitor(tmp_path, monkeypatch, seed, duration_s):
    """A ship scenario written as a contract bag, an isolated DDS domain, and a monitor joined to it."""
    from insalign_ros.io.bag import write_bag
    from insalign_ros.nodes.monitor import AlignmentMonitor
    from insalign_ros.sim.scenarios import make_scenario

    data = make_scenario("ship", seed=seed, duration_s=duration_s)
    bag = tmp_path / "ship_bag"
    write_bag(data, bag)
    env = isolated_ros_env()
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(k, env[k])
    return data, bag, env, AlignmentMonitor()


def _start_align(env, tmp_path, **params):
    return start_node("insalign_ros.nodes.alignment_node", env, log_dir=tmp_path, params={"imu_timeout_s": 0.0, 
        "core": "iekf", "init_from_ground_truth": True, "init_rpy_error_deg": "[3.0, -3.0, 30.0]",
        "imu_grade": "paper_ship", **params})


@pytest.mark.timeout(300)
def test_replayed_bag_reaches_aligned_with_yaw_error_below_1_deg(tmp_path, monkeypatch):
    data, bag, env, mon = _ship_bag_and_monitor(tmp_path, monkeypatch, seed=4, duration_s=120.0)
    nodes = []
    try:
        nodes.append(_start_align(env, tmp_path, imu_qos="reliable"))
        # paced by the node's pose (at most 2 s of data ahead): as fast as the node, whatever the machine's load
        sim = start_node("insalign_ros.nodes.imu_sim_node", env, log_dir=tmp_path, params={
            "source": "bag", "bag_path": str(bag), "rate_factor": 20.0, "wait_for_subscribers": 1,
            "wait_timeout_s": 180.0, "start_stamp_s": 1.7e9, "qos_depth": 1000,
            "pace_topic": "/alignment_node/pose", "max_lead_s": 2.0,
            # the node's first pose can take > 5 s on a loaded machine (kernels loading, the first fix): the
            # safety timeout (default 5 s) must not turn pacing off in this test, which is about pacing
            "pace_timeout_s": 60.0})
        nodes.append(sim)
        assert wait_for_exit(sim, 150.0) == 0, sim.output()[-2000:]
        assert "truth yes" in sim.output(), sim.output()[-2000:]
        end_stamp = 1.7e9 + 120.0
        assert mon.wait_for(lambda m: float(m.diag.get("filter_time_s", 0)) >= end_stamp - 0.5, 15.0), mon.diag
        time.sleep(0.3)
        assert mon.wait_for(lambda m: m.aligned is True, 5.0), mon.diag
        with mon.lock:
            err, s3 = mon.euler_error[1].copy(), mon.euler_3sigma[1].copy()
        assert abs(err[2]) < 1.0 and np.all(np.abs(err) < s3), (err, s3)
        assert int(mon.diag["imu_rejected"]) == 0, mon.diag
    finally:
        stop_nodes(nodes)
        mon.close()


@pytest.mark.timeout(300)
def test_paced_bag_replay_as_fast_as_the_consumer_loses_nothing(tmp_path, monkeypatch):
    """Backpressure: replay at rate factor 1000 (100,000 Imu/s asked for) into a reliable subscription; with
    ``pace_topic`` = the node's pose, imu_sim_node pauses whenever it is more than ``max_lead_s`` of data ahead of the
    node's filter time, so every message arrives (the writer's and the reader's 1,000-deep histories hold the 2 s lead
    of 200 samples; unpaced, the writer's history is overwritten). Reliable, so that the result does not depend on the
    CPU the node gets: into a best-effort subscription the same replay delivered 6,001 of 6,001 on an idle machine and
    5,930 with two CPU burners (the transport drops what a starved reader does not take in time)."""
    import json

    data, bag, env, mon = _ship_bag_and_monitor(tmp_path, monkeypatch, seed=1, duration_s=60.0)
    nodes = []
    try:
        nodes.append(_start_align(env, tmp_path, imu_qos="reliable", imu_qos_depth=1000))
        sim = start_node("insalign_ros.nodes.imu_sim_node", env, log_dir=tmp_path, params={
            "source": "bag", "bag_path": str(bag), "rate_factor": 1000.0, "wait_for_subscribers": 1,
            "wait_timeout_s": 180.0, "start_stamp_s": 1.7e9, "qos_depth": 1000,
            "pace_topic": "/alignment_node/pose", "max_lead_s": 2.0,
            # the node's first pose can take > 5 s on a loaded machine (kernels loading, the first fix): the
            # safety timeout (default 5 s) must not turn pacing off in this test, which is about pacing
            "pace_timeout_s": 60.0})
        nodes.append(sim)
        assert wait_for_exit(sim, 150.0) == 0, sim.output()[-2000:]
        summary = json.loads([ln for ln in sim.output().splitlines() if ln.startswith("SIM_SUMMARY ")][-1][12:])
        assert summary["imu_sent"] == data.n and summary["paused_s"] > 0.1, (summary, sim.output()[-3000:])
        assert "backpressure off" not in sim.output()
        assert mon.wait_for(lambda m: m.counter("imu_received") == data.n, 60.0), (  # state, not time: the
            # diagnostics come from the processing timer, late on a loaded machine
            {k: v for k, v in mon.diag.items() if "imu" in k or "time" in k}, summary)
        assert int(mon.diag["imu_rejected"]) == 0 and int(mon.diag.get("imu_gaps", 0)) == 0, mon.diag
    finally:
        stop_nodes(nodes)
        mon.close()
