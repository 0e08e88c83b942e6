"""The two message types a recording holds by the thousand, decoded straight from their ROS 2 CDR bytes.

``sensor_msgs/msg/Imu`` and ``geometry_msgs/msg/PoseStamped`` have a fixed layout after their header's frame id:
one ``struct`` call reads what the reader needs (the stamp, the frame id, the rate and specific force or the pose)
without building rosbags' message objects (about 35 us per message against 3 us here; io/bag.py reads with it,
docs/speed.md). Anything that is not exactly that layout in little-endian CDR (a ROS 1 bag, big-endian CDR, a
truncated or longer message) returns None and the caller deserialises it with rosbags as before. test_bag_fast_cdr
checks both paths against each other. ``imu_block`` and ``pose_block`` read a whole run of such messages of one byte
length at once (numpy views of the joined bytes: well under a microsecond a message). Imports struct and numpy (no
ROS)."""

from __future__ import annotations

import struct

import numpy as np

#: the CDR encapsulation of a little-endian plain message (0x0001), options 0
_CDR_LE = b"\x00\x01"
#: at byte 4 (after the encapsulation): header.stamp.sec (int32), .nanosec (uint32), header.frame_id's length (uint32,
#: with its terminating NUL)
_HEADER = struct.Struct("<iII")
#: Imu after the header: orientation (4), orientation_covariance (9), angular_velocity (3), its covariance (9),
#: linear_acceleration (3), its covariance (9)
_IMU = struct.Struct("<37d")
#: PoseStamped after the header: position (3), orientation (x, y, z, w)
_POSE = struct.Struct("<7d")


def _header(raw: bytes):
    """(stamp [ns], frame_id, byte offset of the first field after the header) or None. CDR aligns an 8-byte field
    to 8 bytes from the start of the payload, which begins after the 4 bytes of encapsulation."""
    if len(raw) < 16 or raw[0:2] != _CDR_LE:
        return None
    sec, nsec, n = _HEADER.unpack_from(raw, 4)
    if n < 1 or len(raw) < 16 + n:
        return None
    frame = raw[16:16 + n - 1].decode("utf-8", "replace")
    return sec * 1_000_000_000 + nsec, frame, 4 + ((12 + n + 7) & ~7)


def _fields(raw: bytes, layout: struct.Struct):
    """(stamp [ns], frame_id, the doubles of ``layout`` after the header) of a message that is exactly the header and
    ``layout``, or None."""
    h = _header(raw)
    if h is None or len(raw) != h[2] + layout.size:
        return None
    return h[0], h[1], layout.unpack_from(raw, h[2])


def imu(raw: bytes):
    """(stamp [ns], frame_id, angular_velocity (x, y, z), linear_acceleration (x, y, z)) of an Imu, or None."""
    m = _fields(raw, _IMU)
    return None if m is None else (m[0], m[1], m[2][13:16], m[2][25:28])


def pose_stamped(raw: bytes):
    """(stamp [ns], frame_id, position (x, y, z), orientation (x, y, z, w)) of a PoseStamped, or None."""
    m = _fields(raw, _POSE)
    return None if m is None else (m[0], m[1], m[2][0:3], m[2][3:7])


def _block(raws: list, layout: struct.Struct):
    """(stamps [ns] (N,) int64, frame ids (N,) list, the doubles of ``layout`` (N, k)) of messages that are each
    exactly the header and ``layout`` in little-endian CDR and all of one byte length (what ``_fields`` reads one by
    one), or None."""
    L = len(raws[0])
    if len(set(map(len, raws))) != 1 or L < 16 + layout.size:
        return None
    buf = np.frombuffer(b"".join(raws), np.uint8).reshape(len(raws), L)
    if not (np.all(buf[:, 0] == 0) and np.all(buf[:, 1] == 1)):
        return None
    hdr = buf[:, 4:16].copy().view("<u4")  # stamp sec (int32 bits), nanosec, frame_id length with its NUL
    n = hdr[:, 2].astype(np.int64)
    o = L - layout.size  # where the fields start, the same in every message of this length
    if not np.all((n >= 1) & (4 + ((12 + n + 7) & ~7) == o) & (16 + n <= L)):
        return None
    t_ns = hdr[:, 0].view("<i4").astype(np.int64) * 1_000_000_000 + hdr[:, 1].astype(np.int64)
    uniq, inv = np.unique(np.ascontiguousarray(buf[:, 12:o]).view(np.dtype((np.void, o - 12))).ravel(),
                          return_inverse=True)
    names = []
    for u in uniq:
        b = u.tobytes()
        k = int.from_bytes(b[:4], "little")
        names.append(b[4:4 + k - 1].decode("utf-8", "replace"))
    return t_ns, [names[i] for i in inv.ravel()], buf[:, o:].copy().view("<f8")


def imu_block(raws: list):
    """:func:`imu` of a run of messages at once: (stamps [ns] (N,), frame ids, angular_velocity (N, 3),
    linear_acceleration (N, 3)) or None (see ``_block``)."""
    m = _block(raws, _IMU)
    return None if m is None else (m[0], m[1], m[2][:, 13:16], m[2][:, 25:28])


def pose_block(raws: list):
    """:func:`pose_stamped` of a run of messages at once: (stamps [ns] (N,), frame ids, position (N, 3),
    orientation (x, y, z, w) (N, 4)) or None (see ``_block``)."""
    m = _block(raws, _POSE)
    return None if m is None else (m[0], m[1], m[2][:, 0:3], m[2][:, 3:7])
