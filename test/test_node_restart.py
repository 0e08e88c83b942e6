"""alignment_node survives the session's restarts and keeps the flag honest (issue 27 items 2-3, docs/nodes.md "The
flag and the outputs"): the sequences that killed the node (`TypeError: Value after * must be an iterable, not
NoneType` at `ecef_to_enu(p_e, *anchor)` with the anchor cleared by a restart inside a processing tick) fed into a
real node in-process, and a stub session that restarts in the middle of a tick.

In-process real rclpy nodes: the messages go through the node's own callbacks (`_on_imu`, `_on_fix`) and its
processing tick (`_process`) is called every 10 Imu messages (10 Hz of data time, as the 10 Hz timer at real time);
what it publishes is recorded in order from its publishers.
"""

import math
import time

import numpy as np
import pytest

import insalign_ros as ia
from insalign_ros.core import earth

pytestmark = pytest.mark.ros
BASE_S = 1_700_000_000


@pytest.fixture
def make_node(node_factory):
    """An AlignmentNode (conftest.node_factory) with ``params`` and matched subscribers on ~/pose and ~/imu."""

    def make(params: dict):
        from rclpy.node import Node

        node = node_factory([a for k, v in params.items() for a in ("-p", f"{k}:={v}")])
        # matched subscribers: the node builds ~/pose and ~/imu only for a matched subscription
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from sensor_msgs.msg import Imu

        sub = Node("listener", context=node.context)
        node_factory.made.append(sub)
        sub.create_subscription(PoseWithCovarianceStamped, "alignment_node/pose", lambda m: None, 10)
        sub.create_subscription(Imu, "alignment_node/imu", lambda m: None, 10)
        t_end = time.monotonic() + 10.0
        while (node.pub_pose.get_subscription_count() < 1 or node.pub_imu.get_subscription_count() < 1) \
                and time.monotonic() < t_end:
            time.sleep(0.01)
        assert node.pub_pose.get_subscription_count() >= 1 and node.pub_imu.get_subscription_count() >= 1
        return node

    return make


def record(node) -> list:
    """(topic, data, restarts seen) for every message the node publishes on ~/aligned, ~/pose, ~/imu, ~/datum."""
    log = []
    out = node.out
    for name, pub in (("aligned", out.pub_aligned), ("pose", out.pub_pose), ("imu", out.pub_imu),
                      ("datum", out.pub_datum)):
        def rec(msg, name=name):
            log.append((name, getattr(msg, "data", msg), out.counters["restarts_seen"]))
        pub.publish = rec
    return log


def _imu(t_s: float, w, f):
    from sensor_msgs.msg import Imu

    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(round(t_s * 1e9)), 1_000_000_000)
    m.header.frame_id = "imu"
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in f)
    m.orientation_covariance[0] = -1.0
    return m


def _fix(t_s: float, p_e, sigma_m: float):
    from sensor_msgs.msg import NavSatFix, NavSatStatus

    m = NavSatFix()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(round(t_s * 1e9)), 1_000_000_000)
    m.header.frame_id = "/gps"
    m.status.status = NavSatStatus.STATUS_FIX
    lat, lon, h = earth.ecef_to_geodetic(np.asarray(p_e, float))
    m.latitude, m.longitude, m.altitude = math.degrees(lat), math.degrees(lon), float(h)
    m.position_covariance = [sigma_m ** 2 if i in (0, 4, 8) else 0.0 for i in range(9)]
    m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
    return m


def feed(node, d, fix_offset_m: dict | None = None, step_back_at_s: float | None = None, step_s: float = 10.0):
    """The run ``d`` through the node: Imu and fixes in stamp order, a processing tick every 10 Imu messages.
    ``fix_offset_m``: fix index -> ECEF offset [m] (outliers); ``step_back_at_s``: from this data time on every stamp
    is ``step_s`` earlier (a driver's clock correction)."""
    fix_offset_m = fix_offset_m or {}
    sigma = d.gnss_sigma_m if math.isfinite(d.gnss_sigma_m) else 1.0
    gi, t0 = 0, d.t_s[0]
    for k in range(d.t_s.shape[0]):
        shift = -step_s if step_back_at_s is not None and d.t_s[k] - t0 >= step_back_at_s else 0.0
        node._on_imu(_imu(BASE_S + d.t_s[k] - t0 + shift, d.omega_ib_b[k], d.f_ib_b[k]))
        while gi < d.gnss_t_s.shape[0] and d.gnss_t_s[gi] <= d.t_s[k]:
            p = d.gnss_p_e[gi] + np.asarray(fix_offset_m.get(gi, (0.0, 0.0, 0.0)))
            node._on_fix(_fix(BASE_S + d.gnss_t_s[gi] - t0 + shift, p, sigma))
            gi += 1
        if k % 10 == 9:
            node._process()
    node._process()


def check_flag_before_outputs(log: list, imu_gated: bool = True) -> dict:
    """The invariants: no ~/pose or ~/imu with the flag up unless the flag rose after the last restart; no ~/imu
    while the flag is down (the default gating). Returns counts."""
    flag, rose_after = False, -1
    n = {"pose": 0, "imu": 0, "pose_flag_up": 0, "aligned_true": 0}
    for name, data, restarts in log:
        if name == "aligned":
            flag = bool(data)
            if flag:
                rose_after = restarts
                n["aligned_true"] += 1
        elif name in ("pose", "imu"):
            n[name] += 1
            if flag:
                n["pose_flag_up"] += name == "pose"
                assert rose_after == restarts, f"{name} with the flag up from before restart {restarts}"
            elif imu_gated:
                assert name != "imu", "~/imu published before the flag rose"
    return n


@pytest.mark.timeout(600)
def test_ship_outlier_fixes_before_alignment_do_not_kill_the_node(make_node):
    """Issue 27: ship, imu_grade paper_ship, a 1000-km fix then a 200-m fix 40 s later (the sequence that restarted
    the alignment twice and killed the node)."""
    d = ia.simulate("ship", seed=3, duration_s=140.0)
    node = make_node({"imu_grade": "paper_ship", "imu_timeout_s": 0.0})
    log = record(node)
    g = np.searchsorted(d.gnss_t_s - d.t_s[0], [30.0, 70.0])
    up = earth.geodetic_to_ecef(d.lat_rad[0], d.lon_rad[0], d.h_m[0])
    up = up / np.linalg.norm(up)
    feed(node, d, {int(g[0]): np.array([1e6, 0.0, 0.0]), int(g[1]): 200.0 * up})
    n = check_flag_before_outputs(log)
    print(f"ship + 1000-km and 200-m fixes: node counters {node.out.counters}; session divergences "
          f"{node.session.counters.get('divergences')}, faults {node.session.counters.get('core_faults')}; {n}")
    assert node.out.counters["node_errors"] == 0, node.out.last_error
    assert n["pose"] > 1000  # it kept publishing to the end (140 s at 10 Hz)


@pytest.mark.timeout(600)
def test_clock_step_back_on_an_aligned_car_does_not_kill_the_node(make_node):
    """Issue 27: a car (industrial_mems) aligned, then every stamp 10 s earlier from then on."""
    d = ia.simulate("car", seed=1, duration_s=200.0)
    node = make_node({"imu_grade": "industrial_mems", "imu_timeout_s": 0.0})
    log = record(node)
    feed(node, d, step_back_at_s=150.0)
    n = check_flag_before_outputs(log)
    print(f"car, 10-s clock step back at 150 s: node counters {node.out.counters}; time_resets "
          f"{node.session.counters.get('time_resets')}; {n}")
    assert node.out.counters["node_errors"] == 0, node.out.last_error
    assert n["aligned_true"] >= 1  # it was aligned before the step


def test_restart_inside_a_tick_drops_the_flag_first_and_keeps_the_old_anchor(make_node):
    """A stub session whose processing returns two aligned outputs of the old filter and then restarts (anchor None,
    the flag down): the node publishes ~/aligned False before anything else, the two poses relative to the old
    anchor, no ~/imu (not aligned any more), and then a re-initialisation's outputs relative to the new anchor."""
    from insalign_ros.session.outputs import Output

    node = make_node({"imu_timeout_s": 0.0})
    log = record(node)
    s = node.session
    lat, lon, h = math.radians(45.0), math.radians(7.0), 100.0

    def est(t, dlat=0.0):
        class E:  # the fields conversions.pose_msg / imu_msg read
            stamp_s, lat_rad, lon_rad, h_m = t, lat + dlat, lon, h
            C_b_n, P_att_n, P = np.eye(3), np.eye(3) * 1e-6, np.eye(9) * 1e-4
            state_names = [f"x{i}" for i in range(9)]
        return E()

    def out(t, aligned, dlat=0.0):
        return Output(t, est(t, dlat), aligned, s.status, "", np.zeros(3))

    node.epoch_s = BASE_S
    node.params["publish_tf"] = True  # without tf2_msgs: one warning, nothing else (with it: a TF while aligned)
    old = (lat, lon, h)
    s.anchor, s.init_t = old, 0.0
    s.process = lambda wall=None: [out(1.0, True), out(1.1, True)]
    s.flag.aligned = True  # as an aligned session
    node._process()
    assert [e[0] for e in log] == ["datum", "aligned", "pose", "imu", "pose", "imu"], log
    log.clear()

    def restart_in_tick(wall=None):
        outs = [out(1.2, True, 1e-5), out(1.3, True, 1e-5)]
        s.anchor, s.init_t = None, None  # the session's restart: every state dropped
        s.flag.aligned = False
        return outs
    s.process = restart_in_tick
    node._process()
    names = [e[0] for e in log]
    assert names[0] == "aligned" and log[0][1] is False and names[1:] == ["pose", "pose"], log
    y = [e[1].pose.pose.position.y for e in log[1:]]
    want = earth.ecef_to_enu(earth.geodetic_to_ecef(lat + 1e-5, lon, h), *old)[1]  # 1e-5 rad north of the old anchor
    assert 60.0 < want < 70.0 and y == pytest.approx([want] * 2, abs=1e-9), y
    log.clear()
    new = (lat + 1e-3, lon, h)

    def reinit(wall=None):
        s.anchor, s.init_t = new, 2.0
        return [out(2.0, False, 1e-3)]
    s.process = reinit
    node._process()
    assert [e[0] for e in log] == ["datum", "pose"], log
    assert abs(log[1][1].pose.pose.position.y) < 1e-6  # relative to the new anchor
    assert node.out.counters["node_errors"] == 0 and node.out.counters["restarts_seen"] == 1


def test_an_exception_after_the_callbacks_is_counted_and_survived(make_node):
    node = make_node({"imu_timeout_s": 0.0})
    log = record(node)

    def boom(wall=None):
        raise TypeError("Value after * must be an iterable, not NoneType")
    node.session.process = boom
    for _ in range(3):
        node._process()
    assert node.out.counters["node_errors"] == 3 and "TypeError" in node.out.last_error
    node._publish_diagnostics()
    assert not [e for e in log if e[0] in ("pose", "imu")]
