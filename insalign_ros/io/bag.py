"""rosbag2 writer and reader for the bag contract (docs/bag_contract.md), with the ``rosbags`` library (no ROS).

Topics (names configurable in read_bag for bags from other sources):
  /imu/data           sensor_msgs/msg/Imu          frame "imu_link", body FLU, rad/s, m/s^2
  /gps/fix            sensor_msgs/msg/NavSatFix    frame "gps", WGS84 deg, ellipsoidal height, ENU cov [m^2]
  /ground_truth/pose  geometry_msgs/msg/PoseStamped frame "enu" (local ENU about the metadata reference),
                                                    orientation = body FLU -> ENU
  /insalign/metadata  std_msgs/msg/String           JSON, written once before the first sample

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

from ..sim import error_model
from ..sim.types import ImuSpec, ScenarioData
from . import validation

log = logging.getLogger(__name__)

IMU_TOPIC = "/imu/data"
GPS_TOPIC = "/gps/fix"
TRUTH_TOPIC = "/ground_truth/pose"
META_TOPIC = "/insalign/metadata"
IMU_FRAME, GPS_FRAME, TRUTH_FRAME = "imu_link", "gps", "enu"
STORAGES = ("sqlite3", "mcap")
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3
STATUS_FIX = 0


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
    arw = error_model.deg_sqrt_h_to_rad_sqrt_s(spec.arw_deg_sqrt_h)
    vrw = error_model.m_s_sqrt_h_to_m_s_sqrt_s(spec.vrw_m_s_sqrt_h)
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
        events.append((ns, 0, IMU_TOPIC, msg))
    for j in range(data.gnss_t_s.shape[0]):
        st, ns = _stamp(ts, float(data.gnss_t_s[j]), off_ns)
        C_en = earth.C_e_n(math.radians(glat[j]), math.radians(glon[j]))
        R_n = C_en @ data.gnss_R_e[j] @ C_en.T
        R_n = 0.5 * (R_n + R_n.T)
        diag = np.allclose(R_n, np.diag(np.diag(R_n)), rtol=0, atol=1e-12 * np.trace(R_n))
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=T["std_msgs/msg/Header"](stamp=st, frame_id=GPS_FRAME),
            status=T["sensor_msgs/msg/NavSatStatus"](status=STATUS_FIX, service=1),
            latitude=float(glat[j]), longitude=float(glon[j]), altitude=float(galt[j]),
            position_covariance=R_n.ravel().astype(float),
            position_covariance_type=COVARIANCE_TYPE_DIAGONAL_KNOWN if diag else COVARIANCE_TYPE_KNOWN)
        events.append((ns, 1, GPS_TOPIC, msg))
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
        if write_truth and data.has_truth:
            conns[TRUTH_TOPIC] = w.add_connection(TRUTH_TOPIC, "geometry_msgs/msg/PoseStamped", typestore=ts)
        first_ns = events[0][0] if events else 0
        w.write(conns[META_TOPIC], first_ns,
                ts.serialize_cdr(T["std_msgs/msg/String"](data=json.dumps(meta)), "std_msgs/msg/String"))
        for ns, _, topic, msg in it:
            w.write(conns[topic], ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path


def read_bag(path, imu_topic: str = IMU_TOPIC, gps_topic: str = GPS_TOPIC, truth_topic: str = TRUTH_TOPIC,
             meta_topic: str = META_TOPIC, report: dict | None = None) -> ScenarioData:
    """Read a contract bag (or a foreign bag with an Imu and optionally a NavSatFix topic) into ScenarioData.

    Invalid samples (validation.py) are dropped and counted; the counts are logged as warnings and stored in
    ``report`` (if given) as {"rejected": {topic: {reason: count}}, "warnings": [...]}.
    Truth is None when the bag has no truth topic. v_n is not carried by the contract (None).
    """
    from rosbags.rosbag2 import Reader

    ts = typestore()
    rep = report if report is not None else {}
    rep.setdefault("rejected", {})
    rep.setdefault("warnings", [])
    rejected: dict[str, Counter] = {imu_topic: Counter(), gps_topic: Counter(), truth_topic: Counter()}
    frames: dict[str, set] = {imu_topic: set(), gps_topic: set(), truth_topic: set()}
    meta = None
    imu_t, imu_w, imu_f = [], [], []
    g_t, g_llh, g_cov = [], [], []
    tr_t, tr_p, tr_q = [], [], []
    prev = {imu_topic: None, gps_topic: None, truth_topic: None}
    with Reader(Path(path)) as r:
        topics = {c.topic for c in r.connections}
        if imu_topic not in topics:
            raise ValueError(f"{path}: no IMU topic {imu_topic!r}; topics: {sorted(topics)}")
        conns = [c for c in r.connections if c.topic in (imu_topic, gps_topic, truth_topic, meta_topic)]
        for conn, bag_ns, raw in r.messages(connections=conns):
            msg = ts.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == meta_topic:
                if meta is None:
                    try:
                        meta = json.loads(msg.data)
                    except (ValueError, AttributeError) as exc:
                        rep["warnings"].append(f"metadata not JSON ({exc}); ignored")
                continue
            t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            t = t_ns * 1e-9
            frames[conn.topic].add(msg.header.frame_id)
            reason = validation.check_stamp(t, prev[conn.topic])
            if conn.topic == imu_topic:
                w = np.array([msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z])
                f = np.array([msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z])
                reason = reason or validation.check_imu(w, f)
                if not reason:
                    imu_t.append(t_ns), imu_w.append(w), imu_f.append(f)
            elif conn.topic == gps_topic:
                cov = np.asarray(msg.position_covariance, float).reshape(3, 3)
                if msg.position_covariance_type == 0:
                    reason = reason or "position_covariance_type UNKNOWN"
                reason = reason or validation.check_fix(msg.latitude, msg.longitude, msg.altitude, cov,
                                                        msg.status.status)
                if not reason:
                    g_t.append(t_ns), g_llh.append((msg.latitude, msg.longitude, msg.altitude)), g_cov.append(cov)
            else:
                p = msg.pose.position
                q = msg.pose.orientation
                qa = np.array([q.x, q.y, q.z, q.w])
                if not np.all(np.isfinite(qa)) or abs(np.linalg.norm(qa) - 1.0) > 1e-6:
                    reason = reason or "orientation not a unit quaternion"
                if not reason:
                    tr_t.append(t_ns), tr_p.append((p.x, p.y, p.z)), tr_q.append(qa)
            if reason:
                rejected[conn.topic][reason] += 1
            else:
                prev[conn.topic] = t
    expect = {imu_topic: IMU_FRAME, gps_topic: GPS_FRAME, truth_topic: TRUTH_FRAME}
    for topic, fs in frames.items():
        if fs and fs != {expect[topic]}:
            rep["warnings"].append(f"{topic}: frame_id {sorted(fs)} != contract {expect[topic]!r}")
    for topic, c in rejected.items():
        if c:
            rep["rejected"][topic] = dict(c)
            rep["warnings"].append(f"{topic}: rejected {sum(c.values())} sample(s): {dict(c)}")
    if meta is None:
        rep["warnings"].append(f"no metadata on {meta_topic}: scenario/seed/biases/reference unknown")
        meta = {}
    for wmsg in rep["warnings"]:
        log.warning("%s: %s", path, wmsg)
    if not imu_t:
        raise ValueError(f"{path}: no valid IMU sample on {imu_topic}")
    off = int(meta.get("stamp_offset_ns", 0))
    rel = lambda a: (np.array(a, dtype=np.int64) - off) * 1e-9  # noqa: E731
    t_s = rel(imu_t)
    # GNSS -> ECEF position and ECEF covariance
    if g_t:
        llh = np.array(g_llh)
        x, y, z = pymap3d.geodetic2ecef(llh[:, 0], llh[:, 1], llh[:, 2])
        gnss_p_e = np.column_stack([x, y, z])
        from ..core import earth

        R_e = np.array([earth.C_n_e(math.radians(a), math.radians(b)) @ c @ earth.C_e_n(math.radians(a),
                                                                                        math.radians(b))
                        for (a, b, _), c in zip(llh, g_cov)])
    else:
        gnss_p_e, R_e = np.zeros((0, 3)), np.zeros((0, 3, 3))
    spec = ImuSpec(**meta["imu_spec"]) if meta.get("imu_spec") else None
    truth = dict(C_b_n=None, lat_rad=None, lon_rad=None, h_m=None)
    if tr_t:
        lat0, lon0, h0 = (meta.get(k, float("nan")) for k in ("ref_lat_deg", "ref_lon_deg", "ref_h_m"))
        tr_t_a = rel(tr_t)
        if not all(math.isfinite(v) for v in (lat0, lon0, h0)):
            rep["warnings"].append("truth present but no reference lat/lon/h in metadata: truth dropped")
        elif tr_t_a.shape != t_s.shape or np.max(np.abs(tr_t_a - t_s)) > 1e-9:
            rep["warnings"].append("truth stamps differ from the IMU stamps: truth dropped (contract: aligned)")
        else:
            p = np.array(tr_p)
            lat, lon, h = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], math.radians(lat0), math.radians(lon0),
                                               h0, deg=False)
            truth = dict(C_b_n=Rotation.from_quat(np.array(tr_q)).as_matrix(), lat_rad=np.asarray(lat),
                         lon_rad=np.asarray(lon), h_m=np.asarray(h))
        for wmsg in rep["warnings"][-1:]:
            log.warning("%s: %s", path, wmsg)
    arr = lambda v: None if v is None else np.asarray(v, float)  # noqa: E731
    params = dict(meta.get("params", {}))
    for k in ("ref_lat_deg", "ref_lon_deg", "ref_h_m"):
        if k in meta:
            params[k] = meta[k]
    return ScenarioData(
        name=meta.get("scenario", Path(path).name), seed=int(meta.get("seed", -1)),
        t0_s=float(meta.get("t0_s", t_s[0])), t_s=t_s, omega_ib_b=np.array(imu_w), f_ib_b=np.array(imu_f),
        v_n=None, gnss_t_s=rel(g_t) if g_t else np.zeros(0), gnss_p_e=gnss_p_e, gnss_R_e=R_e,
        imu_spec=spec, gnss_sigma_m=float(meta.get("gnss_sigma_m", float("nan"))),
        bias_gyro_b=arr(meta.get("bias_gyro_b_rad_s")), bias_acc_b=arr(meta.get("bias_acc_b_m_s2")),
        params=params, **truth)
