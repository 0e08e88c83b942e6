"""The bag reader's CDR fast path (io/cdr_fast.py) against rosbags' deserialiser: the same fields for every frame-id
length (the CDR alignment after the string), None for what is not exactly the layout (then rosbags reads it), and
read_bag with and without the fast path gives the same recording, bit for bit, rejections included; so does the
block path (io/bag_fast.py: runs of messages read and checked at once) against reading them one by one."""

import math

import numpy as np
import pytest

import insalign_ros as ia
from insalign_ros.io import bag, bag_fast, cdr_fast


def _imu_msg(T, frame: str, w, f, sec=1_700_000_000, nsec=123_456_789):
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)
    V, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    return T["sensor_msgs/msg/Imu"](
        header=hdr, orientation=Q(x=0.1, y=0.2, z=0.3, w=0.9), orientation_covariance=np.arange(9.0),
        angular_velocity=V(x=w[0], y=w[1], z=w[2]), angular_velocity_covariance=np.arange(9.0) + 10,
        linear_acceleration=V(x=f[0], y=f[1], z=f[2]), linear_acceleration_covariance=np.arange(9.0) + 20)


@pytest.mark.parametrize("frame", ["", "i", "im", "imu", "imu_", "imu_l", "imu_li", "imu_lin", "imu_link", "ïmu"])
def test_fast_imu_and_pose_equal_rosbags_for_every_alignment(frame):
    ts = bag.typestore()
    T = ts.types
    w, f = (0.01, -0.02, 1e-300), (0.5, -9.81, float("nan"))
    raw = bytes(ts.serialize_cdr(_imu_msg(T, frame, w, f), "sensor_msgs/msg/Imu"))
    t_ns, fr, a, b = cdr_fast.imu(raw)
    m = ts.deserialize_cdr(raw, "sensor_msgs/msg/Imu")
    assert t_ns == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec and fr == m.header.frame_id == frame
    assert a == (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) == w
    assert b[:2] == f[:2] and math.isnan(b[2])
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=-5, nanosec=7), frame_id=frame)
    pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=1.0, y=-2.0, z=3.5),
                                       orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.6, z=0.0, w=0.8))
    raw = bytes(ts.serialize_cdr(T["geometry_msgs/msg/PoseStamped"](header=hdr, pose=pose),
                                 "geometry_msgs/msg/PoseStamped"))
    assert cdr_fast.pose_stamped(raw) == (-5 * 1_000_000_000 + 7, frame, (1.0, -2.0, 3.5), (0.0, 0.6, 0.0, 0.8))


def test_what_is_not_the_layout_is_left_to_rosbags():
    ts = bag.typestore()
    raw = bytes(ts.serialize_cdr(_imu_msg(ts.types, "imu", (0, 0, 0), (0, 0, 9.8)), "sensor_msgs/msg/Imu"))
    assert cdr_fast.imu(raw) is not None
    assert cdr_fast.imu(b"\x00\x00" + raw[2:]) is None  # big-endian CDR
    assert cdr_fast.imu(raw[:-8]) is None and cdr_fast.imu(raw + b"\x00" * 8) is None  # shorter, longer
    assert cdr_fast.imu(raw[:10]) is None
    assert cdr_fast.pose_stamped(raw) is None  # an Imu is not a PoseStamped


def test_read_bag_with_and_without_the_fast_path_is_the_same_recording(tmp_path, monkeypatch):
    d = ia.simulate("car", seed=2, duration_s=8.0)
    d.omega_ib_b[40] = np.nan  # rejected: non-finite
    d.f_ib_b[41] = (600.0, 0.0, 0.0)  # rejected: beyond 50 g
    d.t_s[60] = d.t_s[59]  # rejected: duplicate stamp
    path = bag.write_bag(d, tmp_path / "b")
    rep_fast, rep_slow = {}, {}
    fast = bag.read_bag(path, report=rep_fast)
    monkeypatch.setattr(bag, "FAST_CDR", {})
    slow = bag.read_bag(path, report=rep_slow)
    for k in ("t_s", "omega_ib_b", "f_ib_b", "gnss_t_s", "gnss_p_e", "gnss_R_e", "C_b_n", "v_n", "lat_rad", "h_m", "imu_valid"):
        a, b = getattr(fast, k), getattr(slow, k)
        assert (a is None) == (b is None), k
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=k)
    assert rep_fast["rejected"] == rep_slow["rejected"]
    assert sum(sum(c.values()) for c in rep_fast["rejected"].values()) == 4  # the duplicate stamp: Imu and truth


def test_block_path_reads_what_one_by_one_reads(tmp_path, monkeypatch):
    # a flagged stretch on /imu/data_invalid interleaved with /imu/data (one stream), a non-finite rate, a 60-g
    # specific force, a repeated and an earlier stamp, a truth quaternion that is not a unit one: the three readers
    # (runs at once, one by one from the bytes, rosbags' deserialiser) give the same recording and rejections
    d = ia.simulate("car", seed=2, duration_s=8.0)
    valid = np.ones(d.n, bool)
    valid[100:130] = False
    d.imu_valid = valid
    d.omega_ib_b[40] = np.nan
    d.f_ib_b[41] = (600.0, 0.0, 0.0)
    d.t_s[60] = d.t_s[59]
    d.t_s[120] = d.t_s[118]
    path = bag.write_bag(d, tmp_path / "b")
    reads = {}
    for mode in ("block", "one by one", "rosbags"):
        if mode == "one by one":
            monkeypatch.setattr(bag_fast, "take_block", lambda kind, items, prev, *a: (False, prev))
        if mode == "rosbags":
            monkeypatch.setattr(bag, "FAST_CDR", {})
        rep = {}
        reads[mode] = (bag.read_bag(path, report=rep), rep)
    (ref, rep_ref) = reads["block"]
    assert not ref.imu_valid_mask[95:135].all() and ref.imu_valid_mask.sum() > d.n - 40
    assert sum(sum(c.values()) for c in rep_ref["rejected"].values()) >= 5
    for mode in ("one by one", "rosbags"):
        other, rep = reads[mode]
        for k in ("t_s", "omega_ib_b", "f_ib_b", "gnss_t_s", "gnss_p_e", "C_b_n", "v_n", "lat_rad", "h_m", "imu_valid"):
            np.testing.assert_array_equal(getattr(ref, k), getattr(other, k), err_msg=f"{mode}: {k}")
        assert rep["rejected"] == rep_ref["rejected"], mode


def test_a_block_of_frame_ids_that_pad_alike_is_read_per_message():
    # "im" and "imu" (3 and 4 bytes with the NUL) pad the header alike: one byte length, one block; their frame ids
    # and fields are each message's own; a block of two lengths is left to the one-by-one reader
    ts = bag.typestore()
    raws = [bytes(ts.serialize_cdr(_imu_msg(ts.types, fr, (k, 0.5, -k), (1.0, k, 9.8), nsec=k), "sensor_msgs/msg/Imu"))
            for k, fr in enumerate(["im", "imu", "imu", "im"])]
    t_ns, frames, w, f = cdr_fast.imu_block(raws)
    for k, raw in enumerate(raws):
        one = cdr_fast.imu(raw)
        assert (int(t_ns[k]), frames[k], tuple(w[k]), tuple(f[k])) == one
    other = bytes(ts.serialize_cdr(_imu_msg(ts.types, "imu_link", (0, 0, 0), (0, 0, 9.8)), "sensor_msgs/msg/Imu"))
    assert cdr_fast.imu_block(raws + [other]) is None and cdr_fast.pose_block(raws) is None
