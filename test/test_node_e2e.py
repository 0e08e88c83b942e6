"""End to end over real Fast DDS: imu_sim_node -> alignment_node (two processes, isolated domain, timeouts).

A shortened ship run at a high rate factor must raise ``aligned`` with |yaw error| < 1 deg; every registered core
selected by parameter must publish a pose with a symmetric positive-definite covariance.
"""

import json
import os
import time

import numpy as np
import pytest
from conftest import sim_summary

from insalign_ros.filters.measurements import GnssPosition
from insalign_ros.cli.bringup import start_node, stop_nodes, wait_for_exit
from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE

pytestmark = pytest.mark.ros

SIM = "insalign_ros.nodes.imu_sim_node"
ALIGN = "insalign_ros.nodes.alignment_node"




def _pose_cov_ok(msg) -> tuple[bool, str]:
    C = np.asarray(msg.pose.covariance, float).reshape(6, 6)
    if not np.all(np.isfinite(C)):
        return False, "non-finite"
    if not np.array_equal(C, C.T):
        return False, f"asymmetric by {np.max(np.abs(C - C.T))}"
    ev = np.linalg.eigvalsh(C)
    return bool(ev[0] > 0), f"eigenvalues {ev}"


def _run_lossless_ship(nodes, ros_env, tmp_path, seed, duration_s):
    """Ship scenario at 100 Hz, rate factor 20, reliable with a history deeper than the run; waits for the end.

    The replay is paced by the node's pose (at most 2 s of data ahead of its filter time): the run is as fast as the
    node, not a wall-time schedule that a loaded CPU may not keep (nothing is lost either way: deep histories)."""
    sim = start_node(SIM, ros_env, log_dir=tmp_path, params={
        "source": "scenario", "scenario": "ship", "seed": seed, "duration_s": duration_s, "rate_hz": 100.0,
        "rate_factor": 20.0, "wait_for_subscribers": 1, "wait_timeout_s": 180.0, "qos": "reliable",
        "qos_depth": 9000, "pace_topic": "/alignment_node/pose", "max_lead_s": 2.0})
    nodes.append(sim)
    assert wait_for_exit(sim, 90.0) == 0, sim.output()[-2000:]
    return sim, sim_summary(sim)


@pytest.mark.timeout(300)
def test_ship_run_reaches_aligned_with_yaw_error_below_1_deg(tmp_path, ros_env):
    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor()
    nodes = []
    try:
        nodes.append(start_node(ALIGN, ros_env, log_dir=tmp_path, params={"imu_timeout_s": 0.0, 
            "core": "liekf", "init_from_ground_truth": True, "init_rpy_error_deg": "[3.0, -3.0, 30.0]",
            "imu_qos": "reliable", "imu_qos_depth": 9000, "imu_grade": "paper_ship"}))
        # reliable with deep histories on both ends: nothing is lost on a loaded machine, so the run is the offline
        # one (seed 3: final yaw error 0.78 deg, 3-sigma 1.54 deg); with best effort a few drops moved it to 1.0 deg
        sim, summary = _run_lossless_ship(nodes, ros_env, tmp_path, seed=3, duration_s=80.0)
        assert summary["imu_sent"] == 8001
        # the last diagnostics arrive within ~1 s; wait until the node has processed everything sent
        assert mon.wait_for(lambda m: m.counter("imu_received") == summary["imu_sent"], 15.0), mon.diag
        assert mon.wait_for(lambda m: m.diag.get("filter_time_s") and float(m.diag["filter_time_s"]) * 1e9
                            >= summary["first_stamp_ns"] + 79.0e9, 10.0), mon.diag
        assert mon.wait_for(lambda m: m.aligned is True, 5.0), (mon.aligned_history, mon.diag)
        err = mon.euler_error[1]
        s3 = mon.euler_3sigma[1]
        assert abs(err[2]) < 1.0, (err, s3)
        assert np.all(np.abs(err) < s3), (err, s3)  # the truth inside the published 3-sigma
        assert mon.counter("imu_rejected") == 0 and mon.counter("gnss_rejected") == 0, mon.diag
        assert mon.diag["state"] == "aligned" and mon.diag["core"] == "liekf"
        # started 30 deg off in yaw: the flag rose once, after the 5 s hold, not at the start
        log = nodes[0].output()
        assert log.count("aligned flag raised") >= 1, log[-3000:]
        t_init = float(log.split("initialised liekf at t=")[1].split(" s")[0])
        t_raised = float(log.split("aligned flag raised at t=")[1].split(" s")[0])
        assert 5.0 <= t_raised - t_init <= 70.0, (t_init, t_raised)
    finally:
        stop_nodes(nodes)
        mon.close()


@pytest.mark.timeout(300)
def test_unknown_heading_179_deg_off_aligns_with_the_yaw_hypothesis_bank(tmp_path, ros_env):
    """The node parameter yaw_hypotheses: 8 (filters/hypotheses.py): started 179 deg off in yaw, the IEKF bank keeps
    one hypothesis within seconds, raises the flag and ends within 1 deg; the bank is visible in /diagnostics."""
    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor()
    nodes = []
    try:
        nodes.append(start_node(ALIGN, ros_env, log_dir=tmp_path, params={"imu_timeout_s": 0.0, 
            "core": "iekf", "yaw_hypotheses": 8, "init_from_ground_truth": True,
            "init_rpy_error_deg": "[3.0, -3.0, 179.0]", "imu_qos": "reliable", "imu_qos_depth": 9000,
            "imu_grade": "paper_ship"}))
        # reliable with deep histories on both ends: no sample is lost even on a loaded machine, so the run is the
        # offline one (seed 1: final yaw error -0.16 deg, 3-sigma 1.87 deg)
        sim, summary = _run_lossless_ship(nodes, ros_env, tmp_path, seed=1, duration_s=60.0)
        assert mon.wait_for(lambda m: m.diag.get("filter_time_s") and float(m.diag["filter_time_s"]) * 1e9
                            >= summary["first_stamp_ns"] + 59.0e9, 15.0), mon.diag
        assert mon.wait_for(lambda m: m.aligned is True, 5.0), (mon.aligned_history, mon.diag)
        err, s3 = mon.euler_error[1], mon.euler_3sigma[1]
        assert abs(err[2]) < 1.0 and np.all(np.abs(err) < s3), (err, s3)
        assert mon.counter("imu_received") == summary["imu_sent"], mon.diag
        assert mon.diag["core.yaw_hypotheses_alive"] == "1", mon.diag
        t_init = float(mon.diag["initialised_at_s"])
        assert float(mon.diag["core.yaw_hypotheses_collapsed_at_s"]) - t_init < 30.0, mon.diag
        assert abs(abs(json.loads(mon.diag["core.yaw_hypothesis_offsets_deg"])[0]) - 180.0) < 1e-6, mon.diag
    finally:
        stop_nodes(nodes)
        mon.close()


_TOPICS = ("imu/data", "gps/fix", "gps/vel", "ground_truth/pose")


def _run_groups(groups, tmp_path, ros_env):
    """Each group ``(cores, scenario)``: one simulator and one alignment_node per core (node renamed), the group's
    topics under ``/<scenario>/``; the groups run at the same time in one isolated domain (one after the other
    took ~10 % longer: the nodes' start-up is CPU-bound, the streams are paced by the simulators)."""
    from insalign_ros.nodes.monitor import AlignmentMonitor

    cores_all = [c for cores, _ in groups for c in cores]
    mons = {c: AlignmentMonitor(node_name=f"align_{c}") for c in cores_all}
    nodes, sims = [], []
    try:
        for cores, scenario in groups:
            remaps = {t: f"/{scenario}/{t}" for t in _TOPICS}
            for c in cores:
                nodes.append(start_node(ALIGN, ros_env, log_dir=tmp_path, name=f"align_{c}",
                                        params={"core": c, "init_from_ground_truth": True,
                                                "init_rpy_error_deg": "[2.0, 2.0, 10.0]",
                                                "imu_grade": SCENARIO_IMU_GRADE[scenario]},
                                        remaps={"__node": f"align_{c}", **remaps}))
        for cores, scenario in groups:
            sim = start_node(SIM, ros_env, log_dir=tmp_path, name=f"sim_{scenario}", params={
                "source": "scenario", "scenario": scenario, "duration_s": 10.0, "rate_hz": 100.0, "rate_factor": 2.5,
                "wait_for_subscribers": len(cores), "wait_timeout_s": 180.0},
                remaps={t: f"/{scenario}/{t}" for t in _TOPICS})
            sims.append(sim)
        for sim in sims:
            assert wait_for_exit(sim, 100.0) == 0, sim.output()[-2000:]
        for i, (c, m) in enumerate(mons.items()):
            assert m.wait_for(lambda mm: mm.pose_count >= 40, 10.0), (c, m.pose_count, m.diag,
                                                                        nodes[i].output()[-2000:])
            with m.lock:
                poses = list(m.poses)
            for msg in poses:
                ok, why = _pose_cov_ok(msg)
                assert ok, (c, why)
                assert msg.header.frame_id == "map"  # world_frame (REP 105)
                q = msg.pose.pose.orientation
                assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1.0) < 1e-9
            assert m.wait_for(lambda mm: mm.diag.get("core") == c and mm.diag.get("core_faults") == "0", 5.0), m.diag
    finally:
        stop_nodes(nodes + sims)
        for m in mons.values():
            m.close()


@pytest.mark.timeout(380)
def test_every_core_publishes_pose_with_spd_covariance(tmp_path, ros_env):
    """One simulator and one alignment_node per registered core (node renamed), in the same isolated domain:
    the GNSS-aided cores on the ship, the others (static, zero-velocity or averaging) on the static scenario."""
    from insalign_ros.filters.registry import core_names, make_core

    gnss = [c for c in core_names() if GnssPosition in make_core(c, {}).accepts]
    other = [c for c in core_names() if c not in gnss]
    assert {"liekf", "pi_liekf", "iekf", "ekf"} <= set(gnss)
    _run_groups([(gnss, "ship"), (other, "static")] if other else [(gnss, "ship")], tmp_path, ros_env)
