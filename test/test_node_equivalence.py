"""The node and the offline API run the same session: a contract bag through imu_sim_node -> alignment_node over
DDS (reliable, deep histories: nothing lost) gives the estimates of ``insalign_ros.align`` on the same bag at the
same stamps, to 1e-9 rad; with every fix published 0.3 s of data time late the result is the on-time one; when
the IMU goes silent the watchdog drops the flag and /diagnostics says why."""

import math

import numpy as np
import pytest
from conftest import sim_summary
from scipy.spatial.transform import Rotation

import insalign_ros as ia
from insalign_ros.cli.bringup import start_node, stop_nodes, wait_for_exit
from insalign_ros.core import earth
from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE

pytestmark = pytest.mark.ros

SIM = "insalign_ros.nodes.imu_sim_node"
ALIGN = "insalign_ros.nodes.alignment_node"




def _run(tmp_path, ros_env, bag, node_params, fix_delay_s=0.0, name="alignment_node", sim_params=None):
    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor(keep_poses=100000)
    nodes = []
    try:
        nodes.append(start_node(ALIGN, ros_env, log_dir=tmp_path, name=name, params={
            "imu_qos": "reliable", "imu_qos_depth": 20000, "gnss_qos": "reliable", "gnss_qos_depth": 2000,
            **node_params}))
        # the monitor must be matched with the node's publishers before data flows (volatile topics)
        assert mon.wait_for(lambda m: m.diag_count > 0 and m.node.count_publishers("/alignment_node/pose") > 0,
                            30.0), "alignment_node never published diagnostics"
        sim = start_node(SIM, ros_env, log_dir=tmp_path, name=f"sim_{name}", params={
            "source": "bag", "bag_path": str(bag), "rate_factor": 10.0, "wait_for_subscribers": 1,
            "wait_timeout_s": 180.0, "qos": "reliable", "qos_depth": 20000, "fix_delay_s": fix_delay_s,
            **(sim_params or {})})
        nodes.append(sim)
        assert wait_for_exit(sim, 90.0) == 0, sim.output()[-2000:]
        summary = sim_summary(sim)
        assert mon.wait_for(lambda m: m.counter("imu_received") == summary["imu_sent"], 20.0), mon.diag
        # the tail behind the fusion delay is processed once the input has been idle for idle_drain_s
        assert mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0, 10.0), mon.diag
        return mon, nodes, summary
    except BaseException:
        stop_nodes(nodes)
        mon.close()
        raise


def _received_and_published(mon, diffs, n_off) -> None:
    """The poses the monitor received are at least a quarter of the offline outputs (and 50), and the node's own count
    says it published (nearly) all of them: a monitor starved on a loaded 2-core machine misses some of a 10x replay's
    poses (the topic keeps the last 50; 339 of 401 with two CPU burners, 173 of 385 once beside the suite's other
    worker), the node does not skip any; the equality is asserted on the poses received. State, not time."""
    assert len(diffs) >= max(0.25 * n_off, 50), (len(diffs), n_off)
    assert mon.wait_for(lambda m: int(m.diag.get("outputs_published", "0")) >= 0.95 * n_off, 10.0), (
        mon.diag.get("outputs_published"), n_off)


def _compare(mon, summary, result, t0_s):
    """Max attitude difference [rad] between published poses and offline outputs at the same data times."""
    off = {round(float(t) - t0_s, 6): o.estimate.C_b_n for t, o in zip(result.t_s, result.outputs)}
    with mon.lock:
        poses = list(mon.poses)
    diffs = []
    for p in poses:
        st = p.header.stamp
        t = round((st.sec * 1_000_000_000 + st.nanosec - summary["first_stamp_ns"]) * 1e-9, 6)
        if t in off:
            q = p.pose.pose.orientation
            C = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
            diffs.append(np.linalg.norm(Rotation.from_matrix(C @ off[t].T).as_rotvec()))
    return np.asarray(diffs), len(poses), len(off)


@pytest.mark.timeout(400)
@pytest.mark.parametrize("core,scenario", [
    # -m slow (11-15 s): test_imu_axes.py::test_imu_axes_over_dds_frd_mounted_equals_the_flu_offline_run runs the same
    # core on a ship bag (seed 1, 30 s, the same initial guess) through imu_sim_node -> alignment_node and asserts the
    # same equality with the offline API to 1e-9 rad, with the FRD mounting on top (measured 1.4e-10 rad; here
    # 9.1e-11); the pose-paced replay stays in the pkf case below
    pytest.param("iekf", "ship", marks=pytest.mark.slow),
    ("pkf", "static"),
])
def test_node_over_dds_equals_the_offline_api(tmp_path, ros_env, core, scenario):
    from insalign_ros.io.bag import write_bag
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario(scenario, seed=1, duration_s=40.0)
    bag = write_bag(d, tmp_path / "bag")
    rpy0 = (np.degrees(earth.rpy_from_C_b_n(d.C_b_n[0])) + [2.0, -2.0, 10.0]).tolist()
    v0 = d.v_n[0].tolist()
    session = {"init_mode": "guess", "initial_rpy_deg": rpy0, "initial_velocity_enu_m_s": v0, "output_period_s": 0.1,
               "imu_grade": SCENARIO_IMU_GRADE[scenario]}
    ref = ia.align(str(bag), core=core, **session)
    assert ref.counters["imu_processed"] >= d.n - 2
    mon, nodes, summary = _run(tmp_path, ros_env, bag, {
        "core": core, "init_mode": "guess", "initial_rpy_deg": str(rpy0), "initial_velocity_enu_m_s": str(v0), "pose_rate_hz": 10.0,
        "imu_timeout_s": 0.0, "imu_grade": SCENARIO_IMU_GRADE[scenario]},
        # no watchdog here: replay as fast as the node, paced by its pose (at most 2 s of data ahead)
        sim_params={"rate_factor": 40.0, "pace_topic": "/alignment_node/pose", "max_lead_s": 2.0})
    try:
        diffs, n_pub, n_off = _compare(mon, summary, ref, float(d.t_s[0]))
        print(f"{core}: {len(diffs)} common stamps of {n_pub} published / {n_off} offline; max difference "
              f"{diffs.max():.3g} rad")
        _received_and_published(mon, diffs, n_off)
        assert diffs.max() < 1e-9
    finally:
        stop_nodes(nodes)
        mon.close()


@pytest.mark.timeout(400)
def test_lagged_fixes_over_dds_give_the_on_time_result_and_the_watchdog_drops_the_flag(tmp_path, ros_env):
    from insalign_ros.io.bag import write_bag
    from insalign_ros.sim.scenarios import make_scenario

    # 40 s of ship (60 before: 2 s more of the replay at rate factor 10): the flag is up from 16 s on
    d = make_scenario("ship", seed=2, duration_s=40.0)
    bag = write_bag(d, tmp_path / "bag")
    rpy0 = (np.degrees(earth.rpy_from_C_b_n(d.C_b_n[0])) + [1.0, -1.0, 3.0]).tolist()
    session = {"init_mode": "guess", "initial_rpy_deg": rpy0, "initial_velocity_enu_m_s": d.v_n[0].tolist(),
               "output_period_s": 0.1, "imu_grade": "paper_ship"}
    on_time = ia.align(str(bag), core="iekf", **session)
    # every fix published 0.3 s of data time after its stamp (the node's default fusion delay is 0.5 s)
    mon, nodes, summary = _run(tmp_path, ros_env, bag, {
        "core": "iekf", "init_mode": "guess", "initial_rpy_deg": str(rpy0), "initial_velocity_enu_m_s": str(d.v_n[0].tolist()),
        "imu_timeout_s": 1.0, "imu_grade": "paper_ship"}, fix_delay_s=0.3)
    try:
        diffs, _, n_off = _compare(mon, summary, on_time, float(d.t_s[0]))
        # every pose the monitor received equals the on-time run (_received_and_published: the counts)
        _received_and_published(mon, diffs, n_off)
        assert diffs.max() < 1e-6, diffs.max()
        assert int(mon.diag["gnss_stale"]) == 0 and int(mon.diag["gnss_accepted"]) == len(d.gnss_t_s) - 1
        assert mon.diag.get("aligned_at_last_output") == "true", mon.diag
        # the stream has ended: no IMU for > imu_timeout_s -> the flag is down, WARN, the reason in the message
        assert mon.wait_for(lambda m: m.aligned is False and "no IMU sample for" in m.diag.get("message", ""),
                            10.0), (mon.aligned_history, mon.diag)
        assert mon.diag["level"] == 1 and int(mon.diag["watchdog_trips"]) == 1, mon.diag
        assert math.isfinite(float(mon.diag["filter_time_s"]))
    finally:
        stop_nodes(nodes)
        mon.close()
