"""rosbag2 writer for the bag contract (docs/bag_contract.md) and a reader of it and of other bags (a rosbag2
directory, a lone .mcap file, a ROS 1 .bag; rosbags' AnyReader), with the ``rosbags`` library (no ROS).

Topics (names configurable in read_bag for bags from other sources):
  /imu/data           sensor_msgs/msg/Imu          frame "imu_link", body FLU, rad/s, m/s^2
  /gps/fix            sensor_msgs/msg/NavSatFix    frame "gps", WGS84 deg, ellipsoidal height, ENU cov [m^2]
  /gps/vel            geometry_msgs/msg/TwistWithCovarianceStamped  frame "gps" (optional): the antenna's velocity
                                                    relative to Earth in ENU [m/s] in twist.linear, its ENU
                                                    covariance [m^2/s^2] in the linear block of the 6x6
  /ground_truth/pose  geometry_msgs/msg/PoseStamped frame "enu" (local ENU about the metadata reference),
                                                    orientation = body FLU -> ENU
  /insalign/metadata  std_msgs/msg/String           JSON, written once before the first sample
  /imu/data_invalid   sensor_msgs/msg/Imu          samples the source flags as not measured (e.g. KITTI fill rows);
                                                    only when there are any: /imu/data then has a gap there
  /gps/fix_invalid    sensor_msgs/msg/NavSatFix    likewise for fixes (status STATUS_NO_FIX)
  /wheel/odom, /gps/heading                         wheel speed and dual-antenna heading (io/bag_vehicle.py)

Stamps: header.stamp = bag timestamp = stamp_offset_ns + round(t_s * 1e9) ns (``stamp_offset_ns`` in the
metadata: 0 for the simulators, the first absolute stamp for converted drives; integer, so no float rounding). The IMU covariances follow REP 145: white-noise variance of one sample = noise density^2 * rate
(ARW [rad/sqrt(s)]^2 * rate_hz on each axis, VRW likewise); biases are not included.
"""

from __future__ import annotations

import json
import logging
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pymap3d
from scipy.spatial.transform import Rotation

from ..core import units
from .bag_vehicle import read_vehicle_topics, vehicle_events  # /wheel/odom, /gps/heading
from ..core.recording import ImuSpec, ScenarioData
from . import bag_fast, cdr_fast, validation
from .topics import INVALID_SUFFIX, VEL_TYPE, listing, resolve_topics

log = logging.getLogger(__name__)

IMU_TOPIC = "/imu/data"
GPS_TOPIC = "/gps/fix"
VEL_TOPIC = "/gps/vel"
CONTRACT_TOPICS = {"imu": IMU_TOPIC, "gps": GPS_TOPIC, "vel": VEL_TOPIC}
TRUTH_TOPIC = "/ground_truth/pose"
META_TOPIC = "/insalign/metadata"
#: flagged samples go to <topic>_invalid (docs/bag_contract.md, "Validity"): INVALID_SUFFIX
IMU_INVALID_TOPIC, GPS_INVALID_TOPIC = IMU_TOPIC + INVALID_SUFFIX, GPS_TOPIC + INVALID_SUFFIX
#: 1-sigma per axis [m] for a fix with position_covariance_type UNKNOWN: the same rule and default as
#: alignment_node's ``gnss_sigma_m`` (R_n = sigma^2 I)
DEFAULT_UNKNOWN_FIX_SIGMA_M = 1.0
IMU_FRAME, GPS_FRAME, TRUTH_FRAME = "imu_link", "gps", "enu"
STORAGES = ("sqlite3", "mcap")
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3
STATUS_FIX = 0
STATUS_NO_FIX = -1


def typestore():
    from rosbags.typesys import Stores, get_typestore

    store = getattr(Stores, "ROS2_JAZZY", None) or Stores.ROS2_HUMBLE
    return get_typestore(store)


def _stamp(ts, t_s: float, off_ns: int = 0):
    ns = off_ns + int(round(t_s * 1e9))
    return ts.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), ns


def _spec_dict(spec: ImuSpec | None):
    return None if spec is None else dict(spec.__dict__)


def metadata_of(data: ScenarioData) -> dict:
    p = data.params or {}
    f = lambda a: None if a is None else [float(x) for x in np.asarray(a)]  # noqa: E731
    return {
        "contract": "insalign_ros bag contract v1",
        "scenario": data.name, "seed": int(data.seed), "t0_s": float(data.t0_s), "stamp_offset_ns": int(p.get("stamp_offset_ns", 0)),
        "bias_gyro_b_rad_s": f(data.bias_gyro_b), "bias_acc_b_m_s2": f(data.bias_acc_b),
        "imu_spec": _spec_dict(data.imu_spec), "gnss_sigma_m": float(data.gnss_sigma_m),
        "ref_lat_deg": float(p.get("ref_lat_deg", math.degrees(data.lat_rad[0]) if data.has_truth else float("nan"))),
        "ref_lon_deg": float(p.get("ref_lon_deg", math.degrees(data.lon_rad[0]) if data.has_truth else float("nan"))),
        "ref_h_m": float(p.get("ref_h_m", data.h_m[0] if data.has_truth else float("nan"))),
        "imu_rate_hz": float(1.0 / np.median(np.diff(data.t_s))) if data.n > 1 else None,
        "gnss_rate_hz": float(1.0 / np.median(np.diff(data.gnss_t_s))) if data.gnss_t_s.shape[0] > 1 else None,
        "params": {k: (v if isinstance(v, (int, float, str, bool)) or v is None else str(v)) for k, v in p.items()},
    }


def imu_covariance_diag(spec: ImuSpec | None):
    """REP 145 per-sample variances (gyro [rad^2/s^2], acc [m^2/s^4]) = density^2 * rate; zeros if unknown."""
    if spec is None:
        return 0.0, 0.0
    arw = units.deg_sqrt_h_to_rad_sqrt_s(spec.arw_deg_sqrt_h)
    vrw = units.m_s_sqrt_h_to_m_s_sqrt_s(spec.vrw_m_s_sqrt_h)
    return arw**2 * spec.rate_hz, vrw**2 * spec.rate_hz


def write_bag(data: ScenarioData, path, storage: str = "sqlite3", write_truth: bool = True,
              progress: bool = False) -> Path:
    """Write ``data`` to a new rosbag2 directory ``path`` (must not exist) per the contract."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {STORAGES}")
    path = Path(path)
    ts = typestore()
    T = ts.types
    meta = metadata_of(data)
    off_ns = meta["stamp_offset_ns"]
    lat0, lon0, h0 = meta["ref_lat_deg"], meta["ref_lon_deg"], meta["ref_h_m"]
    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    var_g, var_a = imu_covariance_diag(data.imu_spec)
    # GNSS: ECEF -> geodetic (deg) and the ECEF covariance -> ENU at the fix
    glat, glon, galt = pymap3d.ecef2geodetic(data.gnss_p_e[:, 0], data.gnss_p_e[:, 1], data.gnss_p_e[:, 2])
    glat, glon, galt = np.atleast_1d(glat), np.atleast_1d(glon), np.atleast_1d(galt)
    from ..core import earth

    imu_ok, gnss_ok = data.imu_valid_mask, data.gnss_valid_mask
    events = []  # (ns, order, topic, msg)
    for k in range(data.n):
        st, ns = _stamp(ts, float(data.t_s[k]), off_ns)
        hdr = T["std_msgs/msg/Header"](stamp=st, frame_id=IMU_FRAME)
        w, f = data.omega_ib_b[k], data.f_ib_b[k]
        msg = T["sensor_msgs/msg/Imu"](
            header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.array([-1.0] + [0.0] * 8),
            angular_velocity=T["geometry_msgs/msg/Vector3"](x=float(w[0]), y=float(w[1]), z=float(w[2])),
            angular_velocity_covariance=np.diag([var_g] * 3).ravel().astype(float),
            linear_acceleration=T["geometry_msgs/msg/Vector3"](x=float(f[0]), y=float(f[1]), z=float(f[2])),
            linear_acceleration_covariance=np.diag([var_a] * 3).ravel().astype(float))
        events.append((ns, 0, IMU_TOPIC if imu_ok[k] else IMU_INVALID_TOPIC, msg))
    for j in range(data.gnss_t_s.shape[0]):
        st, ns = _stamp(ts, float(data.gnss_t_s[j]), off_ns)
        C_en = earth.C_e_n(math.radians(glat[j]), math.radians(glon[j]))
        R_n = C_en @ data.gnss_R_e[j] @ C_en.T
        R_n = 0.5 * (R_n + R_n.T)
        diag = np.allclose(R_n, np.diag(np.diag(R_n)), rtol=0, atol=1e-12 * np.trace(R_n))
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=T["std_msgs/msg/Header"](stamp=st, frame_id=GPS_FRAME),
            status=T["sensor_msgs/msg/NavSatStatus"](status=STATUS_FIX if gnss_ok[j] else STATUS_NO_FIX, service=1),
            latitude=float(glat[j]), longitude=float(glon[j]), altitude=float(galt[j]),
            position_covariance=R_n.ravel().astype(float),
            position_covariance_type=COVARIANCE_TYPE_DIAGONAL_KNOWN if diag else COVARIANCE_TYPE_KNOWN)
        events.append((ns, 1, GPS_TOPIC if gnss_ok[j] else GPS_INVALID_TOPIC, msg))
    if data.has_gnss_velocity:
        events += _velocity_events(ts, data, off_ns)

    aux_events, aux_types = vehicle_events(ts, data, off_ns, _stamp)
    events += aux_events
    if write_truth and data.has_truth:
        e, n_, u = pymap3d.geodetic2enu(data.lat_rad, data.lon_rad, data.h_m, math.radians(lat0),
                                        math.radians(lon0), h0, deg=False)
        q = Rotation.from_matrix(data.C_b_n).as_quat()  # x y z w
        for k in range(data.n):
            st, ns = _stamp(ts, float(data.t_s[k]), off_ns)
            msg = T["geometry_msgs/msg/PoseStamped"](
                header=T["std_msgs/msg/Header"](stamp=st, frame_id=TRUTH_FRAME),
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=float(e[k]), y=float(n_[k]), z=float(u[k])),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=float(q[k, 0]), y=float(q[k, 1]),
                                                                   z=float(q[k, 2]), w=float(q[k, 3]))))
            events.append((ns, 2, TRUTH_TOPIC, msg))
    events.sort(key=lambda ev: (ev[0], ev[1]))
    it = events
    if progress:
        from tqdm import tqdm

        it = tqdm(events, desc=f"writing {path.name}", unit="msg")
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {
            META_TOPIC: w.add_connection(META_TOPIC, "std_msgs/msg/String", typestore=ts),
            IMU_TOPIC: w.add_connection(IMU_TOPIC, "sensor_msgs/msg/Imu", typestore=ts),
            GPS_TOPIC: w.add_connection(GPS_TOPIC, "sensor_msgs/msg/NavSatFix", typestore=ts),
        }
        if not imu_ok.all():
            conns[IMU_INVALID_TOPIC] = w.add_connection(IMU_INVALID_TOPIC, "sensor_msgs/msg/Imu", typestore=ts)
        if not gnss_ok.all():
            conns[GPS_INVALID_TOPIC] = w.add_connection(GPS_INVALID_TOPIC, "sensor_msgs/msg/NavSatFix", typestore=ts)
        if data.has_gnss_velocity:
            conns[VEL_TOPIC] = w.add_connection(VEL_TOPIC, VEL_TYPE, typestore=ts)
        for topic, msgtype in aux_types.items():
            conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
        if write_truth and data.has_truth:
            conns[TRUTH_TOPIC] = w.add_connection(TRUTH_TOPIC, "geometry_msgs/msg/PoseStamped", typestore=ts)
        first_ns = events[0][0] if events else 0
        w.write(conns[META_TOPIC], first_ns,
                ts.serialize_cdr(T["std_msgs/msg/String"](data=json.dumps(meta)), "std_msgs/msg/String"))
        for ns, _, topic, msg in it:
            w.write(conns[topic], ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path


def _velocity_events(ts, data: ScenarioData, off_ns: int) -> list:
    """(ns, 1, VEL_TOPIC, TwistWithCovarianceStamped) per GNSS velocity: ENU linear velocity, ENU covariance in
    the linear block; the angular part is not measured (zero twist, variance -1 on its diagonal)."""
    T = ts.types
    out = []
    for j in range(data.gnss_vel_t_s.shape[0]):
        st, ns = _stamp(ts, float(data.gnss_vel_t_s[j]), off_ns)
        cov = np.zeros((6, 6))
        cov[:3, :3] = data.gnss_vel_R_n[j]
        cov[3:, 3:] = -np.eye(3)
        v = data.gnss_vel_n[j]
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        msg = T[VEL_TYPE](
            header=T["std_msgs/msg/Header"](stamp=st, frame_id=GPS_FRAME),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2])), angular=zero),
                covariance=cov.ravel().astype(float)))
        out.append((ns, 1, VEL_TOPIC, msg))
    return out


def velocity_from_twist(msg) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """(v_n [m/s], R_n [m^2/s^2], "") from a TwistWithCovarianceStamped in ENU, or (None, None, reason)."""
    lin = msg.twist.twist.linear
    v = np.array([lin.x, lin.y, lin.z], float)
    R = np.asarray(msg.twist.covariance, float).reshape(6, 6)[:3, :3]
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(R))):
        return None, None, "non-finite velocity or covariance"
    try:
        np.linalg.cholesky(0.5 * (R + R.T))
    except np.linalg.LinAlgError:
        return None, None, "linear velocity covariance not positive definite (unknown or zero)"
    return v, 0.5 * (R + R.T), ""


#: truth message types read_bag understands -> their Pose (orientation body FLU -> ENU, position ENU [m])
TRUTH_POSE = {"geometry_msgs/msg/PoseStamped": lambda m: m.pose,
              "geometry_msgs/msg/PoseWithCovarianceStamped": lambda m: m.pose.pose,
              "nav_msgs/msg/Odometry": lambda m: m.pose.pose}


#: message types read from their CDR bytes (io/cdr_fast.py, io/bag_fast.py) in a ROS 2 bag: type -> (stream, reader)
FAST_CDR = {"sensor_msgs/msg/Imu": ("imu", cdr_fast.imu),
            "geometry_msgs/msg/PoseStamped": ("truth", cdr_fast.pose_stamped)}


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def interp_held(t_s: np.ndarray, t_key_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of (K, m) ``values`` at ``t_s``, held constant outside [t_key_s[0], t_key_s[-1]]."""
    values = np.asarray(values, float)
    return np.column_stack([np.interp(t_s, t_key_s, values[:, i]) for i in range(values.shape[1])])


def slerp_held(t_s: np.ndarray, t_key_s: np.ndarray, q_key_xyzw: np.ndarray) -> np.ndarray:
    """Attitudes (K, 4) quaternions x y z w -> (N, 3, 3) matrices at ``t_s`` by slerp (scipy), held outside the span."""
    rots = Rotation.from_quat(q_key_xyzw)
    if np.asarray(t_key_s).shape[0] == 1:
        return np.repeat(rots.as_matrix(), np.asarray(t_s).shape[0], axis=0)
    from scipy.spatial.transform import Slerp

    return Slerp(t_key_s, rots)(np.clip(t_s, t_key_s[0], t_key_s[-1])).as_matrix()


def interpolate_poses(t_s: np.ndarray, t_key_s: np.ndarray, p_key: np.ndarray, q_key_xyzw: np.ndarray):
    """Poses at their own stamps -> poses at ``t_s``: position linear, attitude slerp, both held constant outside
    the key span. Returns (C (N, 3, 3), p (N, 3), held: (N,) bool = outside the span)."""
    t_s, t_key_s = np.asarray(t_s, float), np.asarray(t_key_s, float)
    held = (t_s < t_key_s[0]) | (t_s > t_key_s[-1])
    return slerp_held(t_s, t_key_s, q_key_xyzw), interp_held(t_s, t_key_s, p_key), held


def velocity_n_from_positions(t_s: np.ndarray, lat_rad, lon_rad, h_m) -> np.ndarray:
    """ENU velocity relative to the Earth [m/s] at each sample: np.gradient (2nd-order central differences) of the
    ECEF positions over t_s [s], rotated into the local ENU frame of each sample."""
    x, y, z = pymap3d.geodetic2ecef(lat_rad, lon_rad, h_m, deg=False)
    v_e = np.gradient(np.column_stack([x, y, z]), np.asarray(t_s, float), axis=0, edge_order=2)
    sl, cl = np.sin(lat_rad), np.cos(lat_rad)  # the rows of earth.C_e_n, for all samples at once
    so, co = np.sin(lon_rad), np.cos(lon_rad)
    ve, vn, vu = v_e[:, 0], v_e[:, 1], v_e[:, 2]
    return np.column_stack([-so * ve + co * vn, -sl * co * ve - sl * so * vn + cl * vu,
                            cl * co * ve + cl * so * vn + sl * vu])


def _streams(names: dict, invalid: dict, truth_topic: str) -> dict:
    """topic -> (kind, valid) for the resolved sensor topics, their ``_invalid`` siblings and the truth."""
    streams = {}
    for kind in ("imu", "gps"):
        if names[kind] is not None:
            streams[names[kind]] = (kind, True)
            streams[invalid.get(kind) or names[kind] + INVALID_SUFFIX] = (kind, False)
    if names["vel"] is not None:
        streams[names["vel"]] = ("vel", True)
    streams.setdefault(truth_topic, ("truth", True))
    return streams


def _read_messages(path, wanted: dict, invalid: dict, truth_topic: str, meta_topic: str,
                   unknown_fix_sigma_m: float | None, rep: dict):
    """All messages of the sensor topics, validated (validation.py); rejected ones counted per topic and reason.

    ``wanted``: kind -> topic name or None (found: io/topics.py; the result in ``rep["topics"]``, the bag's topics
    in ``rep["bag_topics"]``). Stamps are checked per kind (a topic and its ``_invalid`` sibling form one stream).
    Returns (meta or None, {kind: lists}, rejected, frames, n_unknown_cov, streams: topic -> (kind, valid)).
    """
    from rosbags.highlevel import AnyReader

    ts = typestore()
    got = {"imu": {"t": [], "w": [], "f": [], "ok": []}, "gps": {"t": [], "llh": [], "cov": [], "ok": []},
           "truth": {"t": [], "p": [], "q": []}, "vel": {"t": [], "v": [], "R": []}}
    prev = {"imu": None, "gps": None, "truth": None, "vel": None}
    meta, n_unknown = None, 0
    with AnyReader([Path(path)], default_typestore=ts) as r:
        topics = {c.topic: c.msgtype for c in r.connections}
        rep["bag_topics"] = topics
        names = resolve_topics(topics, wanted, CONTRACT_TOPICS, rep["warnings"])
        rep["topics"] = dict(names, truth=truth_topic if truth_topic in topics else None)
        streams = _streams(names, invalid, truth_topic)
        rejected = {topic: Counter() for topic in streams}
        frames = {topic: set() for topic in streams}
        for topic, (kind, _) in streams.items():
            if kind == "truth" and topic in topics and topics[topic] not in TRUTH_POSE:
                rep["warnings"].append(f"{topic}: type {topics[topic]} is not a pose ({sorted(TRUTH_POSE)}): ignored")
            if kind == "vel" and topic in topics and topics[topic] != VEL_TYPE:
                rep["warnings"].append(f"{topic}: type {topics[topic]} is not {VEL_TYPE}: ignored")
        conns = [c for c in r.connections if c.topic == meta_topic or (
            c.topic in streams and (streams[c.topic][0] != "truth" or c.msgtype in TRUTH_POSE)
            and (streams[c.topic][0] != "vel" or c.msgtype == VEL_TYPE))]
        fast = {c.topic: FAST_CDR[c.msgtype][1] for c in conns if r.is2 and c.topic in streams
                and FAST_CDR.get(c.msgtype, ("",))[0] == streams[c.topic][0]}
        pending = {kind: [] for kind in got}  # (topic, raw) of fast types in bag order, taken a run at once

        def flush(kind):  # io/bag_fast.py; a run it cannot read at once (mixed layouts) is taken one by one below
            items, pending[kind] = pending[kind], []
            done, prev[kind] = bag_fast.take_block(kind, items, prev[kind], got, rejected, frames, streams)
            return [] if done else items

        def messages():
            for conn, _, raw in r.messages(connections=conns):
                if fast.get(conn.topic):
                    pending[streams[conn.topic][0]].append((conn.topic, raw))
                    continue
                yield from (flush(streams[conn.topic][0]) if conn.topic in streams else [])
                yield conn.topic, raw
            for kind in pending:
                yield from flush(kind)

        types = {c.topic: c.msgtype for c in conns}
        for topic, raw in messages():
            dec = fast[topic](raw) if fast.get(topic) else None  # io/cdr_fast.py
            if dec is not None:  # Imu or PoseStamped, read from its bytes
                kind, ok = streams[topic]
                t_ns, frame, a, b = dec
                frames[topic].add(frame)
                reason = validation.check_stamp(t_ns * 1e-9, prev[kind]) or (
                    validation.check_imu(a, b) if kind == "imu" else validation.check_pose(a, b))
                if not reason:
                    g, (ka, kb) = got[kind], (("w", "f") if kind == "imu" else ("p", "q"))
                    g["t"].append(t_ns), g[ka].append(a), g[kb].append(b)
                    if kind == "imu":
                        g["ok"].append(ok)
                if reason:
                    rejected[topic][reason] += 1
                else:
                    prev[kind] = t_ns * 1e-9
                continue
            msg = r.deserialize(raw, types[topic])
            if topic == meta_topic:
                if meta is None:
                    try:
                        meta = json.loads(msg.data)
                    except (ValueError, AttributeError) as exc:
                        rep["warnings"].append(f"metadata not JSON ({exc}); ignored")
                continue
            kind, ok = streams[topic]
            t_ns = _stamp_ns(msg)
            frames[topic].add(msg.header.frame_id)
            reason = validation.check_stamp(t_ns * 1e-9, prev[kind])
            g = got[kind]
            if kind == "imu":
                w = (msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z)
                f = (msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z)
                reason = reason or validation.check_imu(w, f)
                if not reason:
                    g["t"].append(t_ns), g["w"].append(w), g["f"].append(f), g["ok"].append(ok)
            elif kind == "gps":
                cov = np.asarray(msg.position_covariance, float).reshape(3, 3)
                typed_unknown = msg.position_covariance_type == COVARIANCE_TYPE_UNKNOWN
                unknown = typed_unknown or not np.any(cov)  # all zeros under any type (some drivers): unknown
                if unknown and unknown_fix_sigma_m is None:
                    reason = reason or ("position_covariance_type UNKNOWN" if typed_unknown else
                                        "position covariance all zeros")
                elif unknown:
                    cov = np.eye(3) * unknown_fix_sigma_m**2
                # a flagged fix carries STATUS_NO_FIX by contract: judge the rest of it
                reason = reason or validation.check_fix(msg.latitude, msg.longitude, msg.altitude, cov,
                                                        msg.status.status if ok else STATUS_FIX)
                if not reason:
                    g["t"].append(t_ns), g["llh"].append((msg.latitude, msg.longitude, msg.altitude))
                    g["cov"].append(cov), g["ok"].append(ok)
                    n_unknown += int(unknown)
            elif kind == "vel":
                v, R, why = velocity_from_twist(msg)
                reason = reason or why
                if not reason:
                    g["t"].append(t_ns), g["v"].append(v), g["R"].append(R)
            else:
                pose = TRUTH_POSE[types[topic]](msg)
                p, q = pose.position, pose.orientation
                p, q = (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)
                reason = reason or validation.check_pose(p, q)
                if not reason:
                    g["t"].append(t_ns), g["p"].append(p), g["q"].append(q)
            if reason:
                rejected[topic][reason] += 1
            else:
                prev[kind] = t_ns * 1e-9
    return meta, got, rejected, frames, n_unknown, streams


#: words in a driver's own frame ids that pass without a warning (imu, /imu_link, gps, gnss_link, ublox, navsat)
ORDINARY_FRAME_WORDS = {"imu": ("imu",), "gps": ("gps", "gnss", "navsat", "ublox"), "vel": ("gps", "gnss", "ublox")}


def _ordinary_frame(kind: str, frame_id: str) -> bool:
    return any(w in frame_id.lower() for w in ORDINARY_FRAME_WORDS.get(kind, ()))


def _truth_reference(meta: dict, ref_llh_deg, gps: dict, tr_t_ns, tr_p, warnings: list):
    """ENU origin (lat, lon [deg], h [m]) of the truth positions, or None: the metadata's; else ``ref_llh_deg``;
    else placed so that the truth position at the first valid fix inside the truth's span (else the first valid
    fix) equals that fix (antenna lever arm ignored)."""
    ref = tuple(float(meta.get(k, float("nan"))) for k in ("ref_lat_deg", "ref_lon_deg", "ref_h_m"))
    if all(math.isfinite(v) for v in ref):
        return ref
    if ref_llh_deg is not None:
        return tuple(float(v) for v in ref_llh_deg)
    ok = [j for j, good in enumerate(gps["ok"]) if good]
    inside = [j for j in ok if tr_t_ns[0] <= gps["t"][j] <= tr_t_ns[-1]]  # no extrapolated truth if avoidable
    first = (inside or ok or [None])[0]
    if first is None:
        warnings.append("truth present but no ENU reference (no metadata, no valid fix, no ref_llh_deg): truth dropped")
        return None
    t_f = gps["t"][first]
    p_f = interp_held(np.array([(t_f - tr_t_ns[0]) * 1e-9]), (tr_t_ns - tr_t_ns[0]) * 1e-9, tr_p)
    lat_f, lon_f, h_f = gps["llh"][first]
    # the origin O with enu(fix; O) = p_f: start in the fix's tangent plane, then correct the residual (the two
    # tangent planes differ by |p_f| / R rad: mm at 100 m); three steps reach 1e-9 m
    lat0, lon0, h0 = pymap3d.enu2geodetic(-p_f[0, 0], -p_f[0, 1], -p_f[0, 2], lat_f, lon_f, h_f)
    for _ in range(3):
        r = np.array(pymap3d.geodetic2enu(lat_f, lon_f, h_f, lat0, lon0, h0)) - p_f[0]
        lat0, lon0, h0 = pymap3d.enu2geodetic(r[0], r[1], r[2], lat0, lon0, h0)
    warnings.append(f"no ENU reference in metadata: truth origin placed so that the truth at the first fix "
                    f"({lat_f:.7f}, {lon_f:.7f}, {h_f:.2f} m) coincides with it (lever arm ignored)")
    return float(lat0), float(lon0), float(h0)


def read_bag(path, imu_topic: str | None = IMU_TOPIC, gps_topic: str | None = GPS_TOPIC, truth_topic: str = TRUTH_TOPIC,
             meta_topic: str = META_TOPIC, report: dict | None = None,
             unknown_fix_sigma_m: float | None = DEFAULT_UNKNOWN_FIX_SIGMA_M, imu_invalid_topic: str | None = None,
             gps_invalid_topic: str | None = None, ref_llh_deg=None, vel_topic: str | None = VEL_TOPIC) -> ScenarioData:
    """Read a contract bag, or any bag with an Imu topic (and optionally NavSatFix and pose topics), into ScenarioData.

    ``path``: a rosbag2 directory (sqlite3 or mcap), a lone .mcap file or a ROS 1 .bag (rosbags' AnyReader).

    Parameters
    ----------
    imu_topic, gps_topic, vel_topic : sensor topics (default: the contract's). None: the contract's name if the bag
        has it, else the one topic of the type (io/topics.py); a missing IMU topic, or an ambiguous one, is a
        ValueError naming it with the bag's topics; a missing fix or velocity topic is a warning (none read). The
        names read land in ``report["topics"]``, the bag's topics and types in ``report["bag_topics"]``.
    truth_topic, meta_topic : topic names, never guessed (truth: PoseStamped, PoseWithCovarianceStamped or
        Odometry, orientation body FLU -> ENU, position in a local ENU frame [m]).
    unknown_fix_sigma_m : 1-sigma per axis [m] for fixes with position_covariance_type UNKNOWN or an all-zero
        covariance under any type (the node's ``gnss_sigma_m`` rule, R_n = sigma^2 I); None drops such fixes.
    imu_invalid_topic, gps_invalid_topic : topics of flagged samples (default ``<topic>_invalid``): read into
        ``imu_valid`` / ``gnss_valid`` (False), in stamp order with the valid ones.
    ref_llh_deg : (lat [deg], lon [deg], h [m]) ENU origin of the truth positions when the metadata has none.
    vel_topic : GNSS velocity topic (TwistWithCovarianceStamped, ENU, antenna velocity relative to Earth; read when
        present into gnss_vel_*; a velocity with a zero/unknown covariance is rejected and counted).

    Invalid samples (validation.py) are dropped and counted; the counts are logged as warnings and stored in
    ``report`` (if given) as {"rejected": {topic: {reason: count}}, "warnings": [...], "unknown_covariance_fixes": n}.
    Truth at its own rate is interpolated to the IMU stamps (slerp), held outside its span (counted in a warning);
    its ENU origin comes from the metadata, else ``ref_llh_deg``, else the first valid fix (_truth_reference).
    v_n is the truth positions differentiated (velocity_n_from_positions) at the truth stamps, interpolated to the
    IMU stamps. Without metadata, t_s is relative to the first IMU stamp (params["stamp_offset_ns"]).
    """
    if unknown_fix_sigma_m is not None and not (math.isfinite(unknown_fix_sigma_m) and unknown_fix_sigma_m > 0):
        raise ValueError(f"unknown_fix_sigma_m must be > 0 (or None to drop such fixes), got {unknown_fix_sigma_m}")
    rep = report if report is not None else {}
    rep.setdefault("rejected", {})
    rep.setdefault("warnings", [])
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    wanted = {"imu": imu_topic, "gps": gps_topic, "vel": vel_topic}
    invalid = {"imu": imu_invalid_topic, "gps": gps_invalid_topic}
    try:
        meta, got, rejected, frames, n_unknown, streams = _read_messages(path, wanted, invalid, truth_topic,
                                                                         meta_topic, unknown_fix_sigma_m, rep)
    except (AnyReaderError, Ros1Error, Ros2Error) as exc:  # a user error (not a bag, a damaged one): one line
        raise ValueError(f"{path}: not a readable bag (a rosbag2 directory, an .mcap file or a ROS 1 .bag): "
                         f"{exc}") from exc
    gps_topic = rep["topics"]["gps"]
    if gps_topic is None:
        rep["warnings"].append(f"no GNSS fix topic (sensor_msgs/msg/NavSatFix) in the bag; its topics: "
                               f"{listing(rep['bag_topics'])}")
    expect = {"imu": IMU_FRAME, "gps": GPS_FRAME, "truth": TRUTH_FRAME, "vel": GPS_FRAME}
    for topic, fs in frames.items():
        kind = streams[topic][0]
        odd = sorted(f for f in fs if f != expect[kind] and not _ordinary_frame(kind, f))
        if odd:
            rep["warnings"].append(f"{topic}: frame_id {odd} != contract {expect[kind]!r}")
    for topic, c in rejected.items():
        if c:
            rep["rejected"][topic] = dict(c)
            rep["warnings"].append(f"{topic}: rejected {sum(c.values())} sample(s): {dict(c)}")
    rep["unknown_covariance_fixes"] = n_unknown
    if n_unknown:
        rep["warnings"].append(f"{gps_topic}: {n_unknown} fix(es) with UNKNOWN covariance: sigma "
                               f"{unknown_fix_sigma_m:g} m per axis (unknown_fix_sigma_m)")
    bag_fast.stack(got)
    imu, gps, tru, vel = got["imu"], got["gps"], got["truth"], got["vel"]
    if not len(imu["t"]):
        for wmsg in rep["warnings"]:
            log.warning("%s: %s", path, wmsg)
        raise ValueError(f"{path}: no valid IMU sample on {rep['topics']['imu']}")
    if meta is None:
        rep["warnings"].append(f"no metadata on {meta_topic}: scenario/seed/biases/reference unknown; "
                               "times relative to the first IMU stamp")
        meta = {"stamp_offset_ns": int(imu["t"][0])}
    off = int(meta.get("stamp_offset_ns", 0))
    rel = lambda a: (np.array(a, dtype=np.int64) - off) * 1e-9  # noqa: E731
    t_s = rel(imu["t"])
    # GNSS -> ECEF position and ECEF covariance
    if gps["t"]:
        llh = np.array(gps["llh"])
        x, y, z = pymap3d.geodetic2ecef(llh[:, 0], llh[:, 1], llh[:, 2])
        gnss_p_e = np.column_stack([x, y, z])
        from ..core import earth

        R_e = np.array([earth.C_n_e(math.radians(a), math.radians(b)) @ c @ earth.C_e_n(math.radians(a),
                                                                                        math.radians(b))
                        for (a, b, _), c in zip(llh, gps["cov"])])
    else:
        gnss_p_e, R_e = np.zeros((0, 3)), np.zeros((0, 3, 3))
    spec = ImuSpec(**meta["imu_spec"]) if meta.get("imu_spec") else None
    truth = dict(C_b_n=None, lat_rad=None, lon_rad=None, h_m=None, v_n=None)
    ref = None
    if len(tru["t"]):
        tr_t_ns, tr_p, tr_q = np.array(tru["t"], dtype=np.int64), np.array(tru["p"]), np.array(tru["q"])
        ref = _truth_reference(meta, ref_llh_deg, gps, tr_t_ns, tr_p, rep["warnings"])
        if ref is not None:
            truth = _truth_at_imu(t_s, rel(tr_t_ns), tr_p, tr_q, ref, rep["warnings"])
    for wmsg in rep["warnings"]:
        log.warning("%s: %s", path, wmsg)
    arr = lambda v: None if v is None else np.asarray(v, float)  # noqa: E731
    params = dict(meta.get("params", {}))
    params["stamp_offset_ns"] = off
    if ref is not None:
        params.update(zip(("ref_lat_deg", "ref_lon_deg", "ref_h_m"), ref))
    for k in ("ref_lat_deg", "ref_lon_deg", "ref_h_m"):
        if k in meta:
            params[k] = meta[k]
    return ScenarioData(
        name=meta.get("scenario", Path(path).name), seed=int(meta.get("seed", -1)),
        t0_s=float(meta.get("t0_s", t_s[0])), t_s=t_s, omega_ib_b=np.array(imu["w"]), f_ib_b=np.array(imu["f"]),
        gnss_t_s=rel(gps["t"]) if gps["t"] else np.zeros(0), gnss_p_e=gnss_p_e, gnss_R_e=R_e,
        imu_spec=spec, gnss_sigma_m=float(meta.get("gnss_sigma_m", float("nan"))),
        bias_gyro_b=arr(meta.get("bias_gyro_b_rad_s")), bias_acc_b=arr(meta.get("bias_acc_b_m_s2")),
        params=params, imu_valid=np.array(imu["ok"], bool), gnss_valid=np.array(gps["ok"], bool),
        gnss_vel_t_s=rel(vel["t"]) if vel["t"] else None, gnss_vel_n=np.array(vel["v"]) if vel["t"] else None,
        gnss_vel_R_n=np.array(vel["R"]) if vel["t"] else None, **truth,
        **read_vehicle_topics(path, off, rep["warnings"], typestore(), rep["bag_topics"]))  # /wheel/odom, /gps/heading


def _truth_at_imu(t_s, tr_t_s, tr_p_n, tr_q, ref, warnings: list) -> dict:
    """Truth poses (own stamps, ENU about ``ref``) -> C_b_n, lat/lon/h, v_n at the IMU stamps ``t_s``."""
    lat0, lon0, h0 = ref
    lat_k, lon_k, h_k = pymap3d.enu2geodetic(tr_p_n[:, 0], tr_p_n[:, 1], tr_p_n[:, 2], math.radians(lat0),
                                             math.radians(lon0), h0, deg=False)
    v_k = velocity_n_from_positions(tr_t_s, lat_k, lon_k, h_k) if tr_t_s.shape[0] > 1 else None
    if tr_t_s.shape == t_s.shape and np.array_equal(tr_t_s, t_s):  # the contract: truth on the IMU stamps
        C = Rotation.from_quat(tr_q).as_matrix()
        return dict(C_b_n=C, lat_rad=np.asarray(lat_k), lon_rad=np.asarray(lon_k), h_m=np.asarray(h_k), v_n=v_k)
    C, p_n, held = interpolate_poses(t_s, tr_t_s, tr_p_n, tr_q)
    if held.any():
        gap = np.max(np.abs(np.clip(t_s, tr_t_s[0], tr_t_s[-1]) - t_s))
        warnings.append(f"truth ({tr_t_s.shape[0]} poses) held constant for {int(held.sum())} IMU sample(s) outside "
                        f"its span (up to {gap:.3f} s)")
    if tr_t_s.shape[0] > 1 and np.max(np.diff(tr_t_s)) > max(1.0, 5.0 * np.median(np.diff(tr_t_s))):
        warnings.append(f"truth has a gap of {np.max(np.diff(tr_t_s)):.2f} s: interpolated across it")
    lat, lon, h = pymap3d.enu2geodetic(p_n[:, 0], p_n[:, 1], p_n[:, 2], math.radians(lat0), math.radians(lon0), h0,
                                       deg=False)
    v_n = None if v_k is None else interp_held(t_s, tr_t_s, v_k)
    return dict(C_b_n=C, lat_rad=np.asarray(lat), lon_rad=np.asarray(lon), h_m=np.asarray(h), v_n=v_n)
