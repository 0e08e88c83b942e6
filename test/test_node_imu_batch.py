"""alignment_node's Imu path without a Python message per message (docs/nodes.md, "CPU share"): the serialized
sensor_msgs/Imu read as numpy records (conversions.imu_records_from_cdr) equals rclpy's deserialisation field by
field, and a stream through the node's batch path (_on_imu_batch) gives the session exactly what one _on_imu call per
message gives: the same samples, counters, rejections with their reasons and measured samples for ~/imu.

In-process real rclpy nodes (no spinning, no DDS traffic).
"""

import math

import numpy as np
import pytest

from insalign_ros.cli.bringup import isolated_ros_env

pytestmark = pytest.mark.ros


def _msg(Imu, t_s: float, w, f, frame: str = "imu_link"):
    m = Imu()
    ns = int(round(t_s * 1e9))
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    m.header.frame_id = frame
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in w)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in f)
    m.orientation_covariance[0] = -1.0
    m.angular_velocity_covariance = [1e-6 if i in (0, 4, 8) else 0.0 for i in range(9)]
    return m


def test_imu_records_equal_rclpy_deserialisation():
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu

    from insalign_ros.nodes import conversions as cv

    rng = np.random.default_rng(4)
    msgs = []
    for k in range(60):  # frame_id lengths 0..11: every CDR padding before the float64 fields
        m = Imu()
        m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000 + k, int(rng.integers(0, 10**9))
        m.header.frame_id = "abcdefghijk"[: k % 12]
        for name in ("orientation", "angular_velocity", "linear_acceleration"):
            v = getattr(m, name)
            v.x, v.y, v.z = (float(x) for x in rng.normal(size=3))
        m.orientation.w = float(rng.normal())
        for name in ("orientation_covariance", "angular_velocity_covariance", "linear_acceleration_covariance"):
            setattr(m, name, rng.normal(size=9))
        msgs.append(m)
    raws = [serialize_message(m) for m in msgs]
    raws.append(b"\x00\x03" + raws[0][2:])  # another encapsulation (XCDR2): left to rclpy
    raws.append(raws[1][:-8])  # truncated: left to rclpy
    seen = []
    for rows, rec in cv.imu_records_from_cdr(raws):
        for i, k in enumerate(rows):
            m, r = msgs[k], rec[i]
            seen.append(k)
            assert (r["sec"], r["nanosec"]) == (m.header.stamp.sec, m.header.stamp.nanosec)
            assert r["frame"].decode() == m.header.frame_id
            q = m.orientation
            assert r["q"].tolist() == [q.x, q.y, q.z, q.w]
            assert r["w"].tolist() == [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
            assert r["f"].tolist() == [m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
            for field, name in (("cov_q", "orientation"), ("cov_w", "angular_velocity"),
                                ("cov_f", "linear_acceleration")):
                assert r[field].tolist() == list(getattr(m, f"{name}_covariance"))
    assert sorted(seen) == list(range(len(msgs)))  # every message once, the two odd ones in no group
    assert cv.imu_cdr_key(raws[0]) != cv.imu_cdr_key(raws[12])  # same frame_id, other covariances


@pytest.mark.parametrize("axes", ["flu", "frd"])
def test_batch_path_gives_the_session_what_one_callback_per_message_gives(monkeypatch, axes):
    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu

    from insalign_ros.nodes.alignment_node import AlignmentNode

    for k, v in isolated_ros_env(base={}).items():
        monkeypatch.setenv(k, v)
    rng = np.random.default_rng(7)
    g = [0.0, 0.0, 9.8]
    msgs = []
    for k in range(300):  # 100 Hz, a static IMU, and every kind of bad message in between
        t = 1000.0 + 0.01 * k
        msgs.append(_msg(Imu, t, 1e-4 * rng.normal(size=3), np.add(g, 1e-3 * rng.normal(size=3))))
    msgs[40].orientation.x = math.nan  # message level: orientation
    msgs[41].angular_velocity_covariance[1] = 5.0  # message level: covariance not symmetric
    msgs[42].header.stamp.sec, msgs[42].header.stamp.nanosec = 0, 0  # message level: no stamp
    msgs[43].angular_velocity.y = math.nan  # session: non-finite rate
    msgs[60] = _msg(Imu, 1000.59, [0.0, 0.0, 0.0], g)  # session: duplicate stamp of msgs[59]
    msgs[61], msgs[62] = msgs[62], msgs[61]  # out of order by one sample (the session reorders)
    msgs[100].header.frame_id = "other_imu"  # a second frame: logged, accepted (imu_frame_id '')
    msgs[150].linear_acceleration_covariance = [2e-4 if i in (0, 4, 8) else 0.0 for i in range(9)]  # a new kind
    sessions = []
    for batched in (False, True):
        ctx = rclpy.Context()
        rclpy.init(args=["--ros-args", "-p", "core:=iekf", "-p", "imu_timeout_s:=0.0", "-p", f"imu_axes:={axes}",
                         "-p", "imu_mount_rpy_deg:=[0.0, 0.0, 90.0]"], context=ctx)
        node = AlignmentNode(context=ctx)
        try:
            if batched:
                import insalign_ros.nodes.alignment_node as an

                slow = []
                deserialize = an.deserialize_message
                monkeypatch.setattr(an, "deserialize_message", lambda raw, t: slow.append(1) or deserialize(raw, t))
                raws = [serialize_message(m) for m in msgs]
                for s in range(0, len(raws), 7):
                    node._on_imu_batch(raws[s:s + 7], [0] * len(raws[s:s + 7]), 0.0)
            else:
                for m in msgs:
                    node._on_imu(m)
            ses = node.session
            T, W, F = ses.buf.imu.peek()
            sessions.append((dict(ses.counters), T.tolist(), W, F, dict(node._recent_imu),
                             sorted(node.frames_seen), len(node.timing_s)))
        finally:
            node.destroy_node()
            rclpy.shutdown(context=ctx)
    (c0, t0, w0, f0, r0, fr0, n0), (c1, t1, w1, f1, r1, fr1, n1) = sessions
    assert c1 == c0
    assert c0["imu_invalid"] == 4 and c0["imu_duplicate"] == 1 and c0["imu_reordered"] == 1
    assert t1 == t0 and len(t0) == 300 - 5
    # the batch rotates (N, 3) arrays into the vehicle frame at once, the callback one (3,) vector: rounding only
    assert np.abs(w1 - w0).max() <= 1e-18 and np.abs(f1 - f0).max() <= 1e-15
    assert list(r1) == list(r0)
    for t in r0:
        for a, b in zip(r0[t], r1[t]):
            assert np.abs(np.asarray(a) - np.asarray(b)).max() <= 1e-15
    assert fr1 == fr0 == ["imu_link", "other_imu"]
    assert n1 == n0 == 300
    # through rclpy: the first batch (7, before any kind is known), the 3 message-level rejections, the new frame_id,
    # the new covariance; the other 288 from the records
    assert len(slow) == 12
