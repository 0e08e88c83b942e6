"""The vehicle's own sensors in the bag contract (docs/bag_contract.md), as drivers publish them:

  /wheel/odom    nav_msgs/msg/Odometry    frame "odom", child "base_link": the wheel speed along the vehicle's x axis
                                          in twist.twist.linear.x [m/s] (REP 105: the twist is in the child frame),
                                          its variance in twist.covariance[0] [m^2/s^2]; the rest of the twist is
                                          not measured (variance -1); no pose (covariance -1)
  /gps/heading   sensor_msgs/msg/Imu      frame "gps": a dual-antenna heading as ublox_gps publishes it, the
                                          baseline's ENU yaw (from East, counter-clockwise) in the orientation,
                                          its variance in orientation_covariance[8] [rad^2]; roll and pitch not
                                          measured (variance -1 would mean no orientation: 1e6 rad^2 instead), no
                                          rate or acceleration (covariance element 0 = -1, REP 145)

Written by io/bag.write_bag when a ScenarioData carries them; read back by io/bag.read_bag
(:func:`read_vehicle_topics`: these names, these types; a message without a usable value or variance is skipped and
counted in the warnings).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.recording import ScenarioData

WHEEL_TOPIC, WHEEL_TYPE = "/wheel/odom", "nav_msgs/msg/Odometry"
HEADING_TOPIC, HEADING_TYPE = "/gps/heading", "sensor_msgs/msg/Imu"


def vehicle_events(ts, data: ScenarioData, off_ns: int, stamp) -> tuple[list, dict]:
    """((ns, 1, topic, msg) per wheel speed and per heading, {topic: type} of the topics present). ``stamp``: the
    bag's (typestore, t_s, off_ns) -> (header stamp, ns) function."""
    T = ts.types
    out, types = [], {}
    zero3 = lambda: T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)  # noqa: E731
    if data.wheel_t_s is not None and len(data.wheel_t_s):
        types[WHEEL_TOPIC] = WHEEL_TYPE
        for t, s, var in zip(data.wheel_t_s, data.wheel_speed_m_s, data.wheel_var_m2_s2):
            st, ns = stamp(ts, float(t), off_ns)
            cov = -np.eye(6)
            cov[0, 0] = float(var)
            msg = T[WHEEL_TYPE](
                header=T["std_msgs/msg/Header"](stamp=st, frame_id="odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                                                     orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                                                   w=1.0)),
                    covariance=(-np.eye(6)).ravel()),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](x=float(s), y=0.0, z=0.0),
                                                       angular=zero3()),
                    covariance=cov.ravel()))
            out.append((ns, 1, WHEEL_TOPIC, msg))
    if data.heading_t_s is not None and len(data.heading_t_s):
        types[HEADING_TOPIC] = HEADING_TYPE
        for t, yaw, var in zip(data.heading_t_s, data.heading_yaw_rad, data.heading_var_rad2):
            st, ns = stamp(ts, float(t), off_ns)
            none = np.zeros(9)
            none[0] = -1.0
            msg = T[HEADING_TYPE](
                header=T["std_msgs/msg/Header"](stamp=st, frame_id="gps"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(0.5 * float(yaw)),
                                                              w=math.cos(0.5 * float(yaw))),
                orientation_covariance=np.diag([1e6, 1e6, float(var)]).ravel(),
                angular_velocity=zero3(), angular_velocity_covariance=none.copy(),
                linear_acceleration=zero3(), linear_acceleration_covariance=none.copy())
            out.append((ns, 1, HEADING_TOPIC, msg))
    return out, types


def read_vehicle_topics(path, off_ns: int, warnings: list, ts, bag_topics: dict | None = None) -> dict:
    """The ScenarioData fields of ``/wheel/odom`` (nav_msgs/Odometry) and ``/gps/heading`` (sensor_msgs/Imu) when
    the bag has them with these types (stamps relative to ``off_ns``; ``ts`` the bag's typestore); {} otherwise.
    ``bag_topics`` (topic -> type, when the caller has read them): a bag with neither is not opened again."""
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    want = {WHEEL_TOPIC: WHEEL_TYPE, HEADING_TOPIC: HEADING_TYPE}
    if bag_topics is not None and not any(bag_topics.get(t) == m for t, m in want.items()):
        return {}
    got = {WHEEL_TOPIC: ([], [], []), HEADING_TOPIC: ([], [], [])}
    skipped = {WHEEL_TOPIC: 0, HEADING_TOPIC: 0}
    with AnyReader([Path(path)], default_typestore=ts) as r:
        conns = [c for c in r.connections if want.get(c.topic) == c.msgtype]
        if not conns:
            return {}
        for c, _, raw in r.messages(connections=conns):
            m = r.deserialize(raw, c.msgtype)
            t = (int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec) - off_ns) * 1e-9
            if c.topic == WHEEL_TOPIC:
                value, var = float(m.twist.twist.linear.x), float(m.twist.covariance[0])
            else:
                q = m.orientation
                value = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
                var = float(m.orientation_covariance[8]) if float(m.orientation_covariance[0]) != -1.0 else math.nan
            if not (math.isfinite(value) and math.isfinite(var) and var > 0.0):
                skipped[c.topic] += 1
                continue
            for lst, x in zip(got[c.topic], (t, value, var)):
                lst.append(x)
    for topic, n in skipped.items():
        if n:
            warnings.append(f"{topic}: {n} message(s) without a finite value and a variance > 0: skipped")
    out: dict = {}
    (wt, ws, wv), (ht, hy, hv) = got[WHEEL_TOPIC], got[HEADING_TOPIC]
    if wt:
        out.update(wheel_t_s=np.array(wt), wheel_speed_m_s=np.array(ws), wheel_var_m2_s2=np.array(wv))
    if ht:
        out.update(heading_t_s=np.array(ht), heading_yaw_rad=np.array(hy), heading_var_rad2=np.array(hv))
    return out
