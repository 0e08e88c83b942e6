"""ROS message <-> core type conversions, with the checks that make a message acceptable.

Each ``*_from_msg`` returns ``(value, "")`` or ``(None, reason)``; it never raises on bad content. The reason is
what the node logs (throttled) and counts in /diagnostics. Frames: sensor_msgs/Imu in the body FLU frame
(REP 103/145), NavSatFix position covariance in ENU [m^2] (REP: "ENU"), poses in the local ENU frame ``enu``
anchored at the first accepted fix.

IMU axes and mounting (docs/nodes.md, "IMU axes and mounting"): the session works in the *vehicle* FLU frame ``v``
(x forward, y left, z up of the vehicle; the ``b`` of ``C_b_n`` everywhere else). A driver reports rates and specific
forces in its own sensor axes ``s``. Two node parameters describe them and :func:`imu_to_vehicle_matrix` turns
them into one constant rotation ``C_s_v``, applied once per message by :func:`imu_to_vehicle`:

- ``imu_axes``: ``flu`` (REP 103: x forward, y left, z up) or ``frd`` (x forward, y right, z down: SBG, VectorNav,
  many aerospace IMUs). FRD -> FLU is a 180 deg rotation about x, :func:`frd_to_flu`.
- ``imu_mount_rpy_deg``: roll, pitch, yaw [deg] of the IMU's FLU axes (after ``imu_axes``) in the vehicle FLU frame,
  in the convention of a URDF joint or ``static_transform_publisher base_link imu_link``: C_s_v = Rz(yaw) Ry(pitch)
  Rx(roll) (fixed axes x, y, z of the vehicle, in that order; REP 103 signs: positive pitch turns the IMU's x axis
  down, positive yaw turns it to the left). A vector measured in IMU axes is ``v_v = C_s_v v_s``. Example: an IMU
  whose x axis points to the vehicle's left and z up has yaw 90: it measures a forward acceleration on its -y axis.
  Only the rotation is applied: the IMU's position in the vehicle (lever arm) is not.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

from ..core import earth
from ..core.types import GnssFix, GnssHeading, ImuSample, WheelSpeed
from ..io import validation


def stamp_s(msg, epoch_s: int = 0) -> float:
    """header.stamp -> seconds (float) after ``epoch_s`` [whole s]. With an epoch near the data, the float keeps
    sub-nanosecond resolution (an absolute 1.8e9-s stamp as a float resolves only ~0.24 us)."""
    st = msg.header.stamp
    return (st.sec - epoch_s) + 1e-9 * st.nanosec


def set_stamp(msg, t_s: float, epoch_s: int = 0) -> None:
    """Inverse of :func:`stamp_s`: ``t_s`` seconds after ``epoch_s``, to the nearest nanosecond."""
    ns = epoch_s * 1_000_000_000 + int(round(t_s * 1e9))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)


#: accepted values of the node parameter ``imu_axes``
IMU_AXES = ("flu", "frd")
#: FRD (x forward, y right, z down) -> FLU (x forward, y left, z up): a 180 deg rotation about x (its own inverse)
C_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def frd_to_flu(v_frd: np.ndarray) -> np.ndarray:
    """Vectors (3,) or (N, 3) in FRD axes (x forward, y right, z down) -> the same vectors in FLU axes."""
    return np.asarray(v_frd, float) @ C_FRD_FLU.T


def mount_rotation(imu_mount_rpy_deg) -> np.ndarray:
    """C_s_v: IMU FLU axes -> vehicle FLU axes from the mounting roll, pitch, yaw [deg] of the IMU in the vehicle
    (Rz(yaw) Ry(pitch) Rx(roll), as a URDF joint or static_transform_publisher base_link -> imu_link)."""
    rpy = [float(x) for x in imu_mount_rpy_deg]
    if len(rpy) != 3 or not all(math.isfinite(x) for x in rpy):
        raise ValueError(f"imu_mount_rpy_deg: need 3 finite numbers [deg], got {list(imu_mount_rpy_deg)}")
    return Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()


def imu_to_vehicle_matrix(imu_axes: str, imu_mount_rpy_deg) -> np.ndarray:
    """The one rotation from the driver's axes to the vehicle FLU frame: C_s_v = mount_rotation @ (FRD -> FLU)."""
    if imu_axes not in IMU_AXES:
        raise ValueError(f"imu_axes: must be one of {IMU_AXES}, got {imu_axes!r}")
    C = mount_rotation(imu_mount_rpy_deg)
    return C @ C_FRD_FLU if imu_axes == "frd" else C


def imu_to_vehicle(omega_s: np.ndarray, f_s: np.ndarray, C_s_v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Angular rate [rad/s] and specific force [m/s^2] (each (3,) or (N, 3)) in the driver's axes -> vehicle FLU
    (``C_s_v`` from :func:`imu_to_vehicle_matrix`; None: already vehicle FLU, returned as they are)."""
    if C_s_v is None:
        return omega_s, f_s
    return np.asarray(omega_s, float) @ C_s_v.T, np.asarray(f_s, float) @ C_s_v.T


def covariance_to_vehicle(cov_s, C_s_v: np.ndarray | None) -> np.ndarray:
    """A row-major 3x3 covariance of a vector in the driver's axes -> vehicle FLU: C_s_v Sigma C_s_v^T, (9,)."""
    c = np.asarray(cov_s, float).reshape(3, 3)
    return (c if C_s_v is None else C_s_v @ c @ C_s_v.T).reshape(-1)


def _finite(*vals) -> bool:
    return all(math.isfinite(v) for v in vals)


def check_covariance(cov, n: int, what: str) -> str:
    """A row-major 3x3 covariance from a message: "" when usable. All zeros = "unknown" (REP 145), accepted.

    Otherwise io/validation.check_covariance with a positive diagonal required (finite, symmetric, PSD).
    """
    c = np.asarray(cov, float)
    if not np.all(np.isfinite(c)):
        return f"{what} covariance: non-finite value"
    if not np.any(c):
        return ""
    return validation.check_covariance(c, f"{what} covariance", require_positive_diag=True) or ""


def imu_sample_fast(msg: Imu, cov_ok: dict, epoch_s: int = 0,
                    C_s_v: np.ndarray | None = None) -> tuple[ImuSample | None, str]:
    """sensor_msgs/Imu -> ImuSample in vehicle FLU axes for the node's callback (``C_s_v``: the driver's axes to the
    vehicle, :func:`imu_to_vehicle_matrix`; None: the message is already vehicle FLU): the message-level checks only
    (orientation finite, covariances usable, stamp > 0); the session checks the values. A covariance seen before is not checked again
    (``cov_ok``: covariance tuple -> reason, bounded): drivers send the same covariance in every message."""
    h = msg.header.stamp
    if not (h.sec > 0 or h.nanosec > 0):
        return None, "stamp is zero (unset)"
    t = (h.sec - epoch_s) + 1e-9 * h.nanosec
    q = msg.orientation
    if not math.isfinite(q.x + q.y + q.z + q.w):
        return None, "orientation: non-finite value"
    for cov, name in ((msg.angular_velocity_covariance, "angular_velocity"),
                      (msg.linear_acceleration_covariance, "linear_acceleration"),
                      (msg.orientation_covariance, "orientation")):
        key = (name, tuple(cov))
        reason = cov_ok.get(key)
        if reason is None:
            if name == "orientation" and cov[0] == -1.0:  # REP 145: no orientation estimate
                reason = "" if np.all(np.isfinite(np.asarray(cov, float))) else "orientation covariance: non-finite value"
            else:
                reason = check_covariance(cov, 3, name)
            if len(cov_ok) > 1000:
                cov_ok.clear()
            cov_ok[key] = reason
        if reason:
            return None, reason
    w, a = msg.angular_velocity, msg.linear_acceleration
    omega, f = imu_to_vehicle(np.array((w.x, w.y, w.z)), np.array((a.x, a.y, a.z)), C_s_v)
    return ImuSample(t, omega, f), ""


#: CDR encapsulation of plain little-endian CDR (XCDR1), what Fast DDS writes for ROS 2 messages on x86 and ARM
CDR_LE = b"\x00\x01"
#: sensor_msgs/Imu after header.frame_id: orientation (4), its covariance (9), angular_velocity (3), its covariance (9),
#: linear_acceleration (3), its covariance (9), all float64
_IMU_TAIL = (("q", 4), ("cov_q", 9), ("w", 3), ("cov_w", 9), ("f", 3), ("cov_f", 9))


@lru_cache(maxsize=64)
def _imu_dtype(frame_len: int) -> np.dtype:
    """The record of one serialized sensor_msgs/Imu whose frame_id takes ``frame_len`` bytes (with its NUL): CDR
    offsets count from after the 4-byte encapsulation header and float64 fields are aligned to 8 there."""
    names, formats, offsets = ["sec", "nanosec", "frame"], ["<i4", "<u4", f"S{frame_len}"], [4, 8, 16]
    off = 4 + ((12 + frame_len + 7) & ~7)
    for name, n in _IMU_TAIL:
        names.append(name)
        formats.append(("<f8", (n,)))
        offsets.append(off)
        off += 8 * n
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": off})


def imu_records_from_cdr(raws: list) -> list:
    """Serialized sensor_msgs/Imu messages (``take_message(Imu, raw=True)``) -> numpy records in one pass per layout,
    without a Python message object per message (rclpy's deserialisation was the largest per-message cost of the
    node: docs/nodes.md, "CPU share").

    Returns ``[(rows, records), ...]``: ``rows`` the indices into ``raws`` of one layout (little-endian CDR, one
    frame_id length), ``records`` a structured array with fields sec, nanosec, frame (bytes, NUL-stripped), q,
    cov_q, w, cov_w, f, cov_f (:func:`_imu_dtype`). A message of any other encapsulation, or whose length does not
    match its frame_id length, is in no group: the caller deserialises it with rclpy."""
    groups: dict = {}
    for k, r in enumerate(raws):
        if len(r) >= 16 and r[:2] == CDR_LE:
            groups.setdefault((len(r), r[12:16]), []).append(k)
    out = []
    for (length, flen_b), rows in groups.items():
        flen = int.from_bytes(flen_b, "little")
        if not 1 <= flen <= length:
            continue
        dt = _imu_dtype(flen)
        if dt.itemsize != length:
            continue
        out.append((rows, np.frombuffer(b"".join([raws[k] for k in rows]), dtype=dt)))
    return out


def imu_cdr_key(raw: bytes) -> bytes:
    """What the message-level checks of a serialized Imu read besides its stamp and orientation: the frame_id (with
    its length) and the three covariances, as bytes (a node caches the keys that passed: drivers repeat them)."""
    flen = int.from_bytes(raw[12:16], "little")
    return raw[12:16 + flen] + raw[-8 * 33:-8 * 24] + raw[-8 * 21:-8 * 12] + raw[-8 * 9:]


def imu_noise_from_msg(msg: Imu, dt_s: float) -> dict:
    """Noise densities implied by the Imu covariances of one sample [rad^2, (m/s^2)^2] over dt_s, as config fields.

    A per-sample variance s^2 of a rate averaged over dt corresponds to a white-noise PSD q = s^2 dt, i.e. an angle
    random walk sqrt(q) [rad/sqrt(s)] = 60 * deg(sqrt(q)) [deg/sqrt(h)]. Returns {} when the covariances are unknown.
    """
    out = {}
    g = np.diag(np.asarray(msg.angular_velocity_covariance, float).reshape(3, 3))
    a = np.diag(np.asarray(msg.linear_acceleration_covariance, float).reshape(3, 3))
    if np.all(g > 0) and np.all(np.isfinite(g)):
        out["gyro_arw_deg_sqrt_h"] = float(math.degrees(math.sqrt(float(np.mean(g)) * dt_s)) * 60.0)
    if np.all(a > 0) and np.all(np.isfinite(a)):
        out["acc_vrw_m_s_sqrt_h"] = float(math.sqrt(float(np.mean(a)) * dt_s) * 60.0)
    return out


def fix_from_msg(msg: NavSatFix, default_sigma_m: float, frame_id: str = "",
                 epoch_s: int = 0) -> tuple[GnssFix | None, str]:
    """sensor_msgs/NavSatFix -> GnssFix (ECEF p_e [m], R_e [m^2]) or (None, reason).

    Covariance: ``position_covariance`` (ENU, m^2) when its type is not UNKNOWN, else ``default_sigma_m`` per axis;
    an all-zero covariance under any type (drivers that fill APPROXIMATED with zeros) is unknown too.
    """
    if frame_id and msg.header.frame_id != frame_id:
        return None, f"frame_id {msg.header.frame_id!r} is not {frame_id!r}"
    lat, lon, h = msg.latitude, msg.longitude, msg.altitude
    t = stamp_s(msg, epoch_s)
    cov = np.asarray(msg.position_covariance, float).reshape(3, 3)
    known = msg.position_covariance_type != NavSatFix.COVARIANCE_TYPE_UNKNOWN and bool(np.any(cov != 0.0))
    reason = validation.check_fix(lat, lon, h, cov if known else None, int(msg.status.status))
    if reason:
        return None, reason
    if not (msg.header.stamp.sec > 0 or msg.header.stamp.nanosec > 0):
        return None, "stamp is zero (unset)"
    if known:
        R_n = cov
        try:
            np.linalg.cholesky(R_n)
        except np.linalg.LinAlgError:
            return None, "position covariance is not positive definite"
    else:
        R_n = np.eye(3) * default_sigma_m**2
    lat_r, lon_r = math.radians(lat), math.radians(lon)
    C = earth.C_n_e(lat_r, lon_r)
    return GnssFix(t, earth.geodetic_to_ecef(lat_r, lon_r, h), C @ R_n @ C.T), ""


#: wheel speed 1-sigma [m/s] when an Odometry's twist covariance leaves the x-speed variance unset (0 or negative)
WHEEL_SPEED_DEFAULT_SIGMA_M_S = 0.1


def yaw_enu_from_heading_ned(heading_ned_rad: float) -> float:
    """A heading in NED (from North, clockwise: what receivers and NMEA report) as the ENU yaw (from East,
    counter-clockwise, REP 103) [rad] in [-pi, pi]: ``pi/2 - heading``."""
    return math.remainder(math.pi / 2.0 - float(heading_ned_rad), 2.0 * math.pi)


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """The yaw [rad] of a quaternion (ZYX Euler angles: the direction of the rotated x axis in the horizontal plane)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def gnss_heading_from_imu_msg(msg: Imu, epoch_s: int = 0) -> tuple[GnssHeading | None, str]:
    """A dual-antenna heading published as sensor_msgs/Imu (ublox_gps ``navheading``: the orientation's yaw is the
    baseline's ENU yaw, ``orientation_covariance[8]`` its variance [rad^2]) -> GnssHeading or (None, reason).
    An orientation covariance of -1 (unknown orientation) or a yaw variance <= 0 is refused."""
    q = msg.orientation
    var = float(msg.orientation_covariance[8])
    if float(msg.orientation_covariance[0]) == -1.0:
        return None, "orientation_covariance[0] is -1 (no orientation)"
    if not _finite(q.x, q.y, q.z, q.w, var):
        return None, "NaN/Inf in the heading orientation or its covariance"
    if not var > 0.0:
        return None, f"heading variance orientation_covariance[8] = {var!r} (unset)"
    if abs(math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1.0) > 1e-3:
        return None, "heading quaternion norm is not 1"
    return GnssHeading(stamp_s(msg, epoch_s), yaw_from_quaternion(q.x, q.y, q.z, q.w), var), ""


def gnss_heading_from_quaternion_msg(msg, sigma_rad: float, epoch_s: int = 0) -> tuple[GnssHeading | None, str]:
    """A dual-antenna heading as geometry_msgs/QuaternionStamped (the baseline's orientation in ENU; the message has
    no covariance: ``sigma_rad`` is the heading 1-sigma) -> GnssHeading or (None, reason)."""
    q = msg.quaternion
    if not _finite(q.x, q.y, q.z, q.w) or abs(math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w) - 1.0) > 1e-3:
        return None, "heading quaternion is not finite or its norm is not 1"
    return GnssHeading(stamp_s(msg, epoch_s), yaw_from_quaternion(q.x, q.y, q.z, q.w), float(sigma_rad) ** 2), ""


def wheel_speed_from_odometry(msg, epoch_s: int = 0,
                              default_sigma_m_s: float = WHEEL_SPEED_DEFAULT_SIGMA_M_S) -> tuple[WheelSpeed | None, str]:
    """nav_msgs/Odometry -> WheelSpeed: ``twist.twist.linear.x``, the speed along the vehicle's x axis in the child
    frame (REP 105: the twist of an Odometry is in ``child_frame_id``, i.e. the vehicle frame; negative reversing),
    its variance ``twist.covariance[0]`` (unset, 0 or negative: ``default_sigma_m_s``). The lateral and vertical
    speeds of wheel odometry are the constraint, not a measurement: not taken."""
    vx = float(msg.twist.twist.linear.x)
    var = float(msg.twist.covariance[0])
    if not _finite(vx, var):
        return None, "NaN/Inf in the twist's linear.x or its covariance"
    if not var > 0.0:
        var = float(default_sigma_m_s) ** 2
    return WheelSpeed(stamp_s(msg, epoch_s), vx, var), ""


def truth_from_msg(msg: PoseStamped, epoch_s: int = 0) -> tuple[tuple[float, np.ndarray, np.ndarray] | None, str]:
    """Ground-truth PoseStamped (frame ``enu``: orientation body FLU -> ENU) -> (stamp_s, C_b_n, p_n) or reason."""
    q, p = msg.pose.orientation, msg.pose.position
    if not _finite(q.x, q.y, q.z, q.w, p.x, p.y, p.z):
        return None, "NaN/Inf in ground-truth pose"
    nq = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(nq - 1.0) > 1e-3:
        return None, f"ground-truth quaternion norm {nq:.4f} is not 1"
    return (stamp_s(msg, epoch_s), quat_matrix(q.x, q.y, q.z, q.w), np.array([p.x, p.y, p.z])), ""


def quat_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w), normalised first: ``Rotation.from_quat(q).as_matrix()`` to
    ~1e-16 (test_node_conversions_fast.py) in scalar floats, ~2 us against ~8 us a call (each ground-truth message;
    docs/nodes.md, "CPU share")."""
    n = 1.0 / math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x * n, y * n, z * n, w * n
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return np.array([[1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
                     [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
                     [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)]])


def quat_xyzw(C: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix ``C``: ``Rotation.from_matrix(C).as_quat()`` for an
    orthonormal C, the same method and sign (Markley: the branch of the largest of the diagonal and the trace), in
    scalar floats: ~3 us against ~30 us a call, once per output (test_node_conversions_fast.py; docs/nodes.md, "CPU
    share"). A matrix that is not orthonormal to 1e-6 goes to scipy, which first takes the nearest rotation."""
    (a, b, c), (d, e, f), (g, h, i) = C.tolist()
    tr = a + e + i
    big = max(a, e, i, tr)
    if big == tr:
        m = 1.0 + tr
        q = (h - f, c - g, d - b, m)
    elif big == a:
        m = 1.0 - tr + 2.0 * a
        q = (m, d + b, g + c, h - f)
    elif big == e:
        m = 1.0 - tr + 2.0 * e
        q = (d + b, m, h + f, c - g)
    else:
        m = 1.0 - tr + 2.0 * i
        q = (g + c, h + f, m, d - b)
    n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    # a rotation has |q|^2 = 4 m (m = 4 x the square of the largest component); otherwise scipy's projection
    if not abs(n2 - 4.0 * m) <= 1e-6 * n2:
        return Rotation.from_matrix(C).as_quat()
    n = 1.0 / math.sqrt(n2)
    return np.array([q[0] * n, q[1] * n, q[2] * n, q[3] * n])


def pose_cov_ros(P_pos_n: np.ndarray, P_att_n: np.ndarray, P_pos_att: np.ndarray | None = None) -> list[float]:
    """6x6 covariance in the ROS order (x, y, z, rot x, rot y, rot z), row-major, symmetrised."""
    M = np.zeros((6, 6))
    M[0:3, 0:3] = P_pos_n
    M[3:6, 3:6] = P_att_n
    if P_pos_att is not None:
        M[0:3, 3:6] = P_pos_att
        M[3:6, 0:3] = P_pos_att.T
    M = 0.5 * (M + M.T)
    return M.reshape(-1).tolist()


def position_cov_n(est, C_b_n: np.ndarray) -> np.ndarray:
    """ENU position covariance [m^2] from a core estimate, by state name (rho_* body frame, dp_* ENU/ECEF-like).

    Left-invariant cores hold the position error in the body frame (``rho``): P_n = C_b_n P_rho C_b_n^T. Cores
    whose position states are named ``dp_*``/``p_*`` are taken as ENU. Falls back to the block after attitude
    and velocity (states 6:9).
    """
    names = list(est.state_names)
    P = est.P
    for prefix, rotate in (("rho_", True), ("dp_", False), ("p_", False)):
        idx = [i for i, n in enumerate(names) if n.startswith(prefix)][:3]
        if len(idx) == 3:
            B = P[np.ix_(idx, idx)]
            return C_b_n @ B @ C_b_n.T if rotate else B
    if P.shape[0] >= 9:
        return P[6:9, 6:9]
    return np.eye(3) * 1e6  # a core without position states: "unknown", large


def pose_msg(est, anchor, frame_id: str, child_frame_id: str, epoch_s: int = 0,
             q_xyzw: np.ndarray | None = None) -> PoseWithCovarianceStamped:
    """A core estimate -> PoseWithCovarianceStamped in the local ENU frame anchored at ``anchor`` (lat, lon, h)
    (``q_xyzw``: :func:`quat_xyzw` of ``est.C_b_n`` when the caller has it already)."""
    msg = PoseWithCovarianceStamped()
    set_stamp(msg, est.stamp_s, epoch_s)
    msg.header.frame_id = frame_id
    p_e = earth.geodetic_to_ecef(est.lat_rad, est.lon_rad, est.h_m)
    p_n = earth.ecef_to_enu(p_e, *anchor)
    pp = msg.pose.pose.position
    pp.x, pp.y, pp.z = (float(x) for x in p_n)
    q = quat_xyzw(est.C_b_n) if q_xyzw is None else q_xyzw
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(x) for x in q)
    msg.pose.covariance = pose_cov_ros(position_cov_n(est, est.C_b_n), est.P_att_n)
    return msg


def imu_msg(est, frame_id: str, epoch_s: int = 0, sample=None, q_xyzw: np.ndarray | None = None) -> Imu:
    """A core estimate -> sensor_msgs/Imu (REP 145) in the vehicle FLU frame ``frame_id``, as robot_localization's
    navsat_transform takes it: orientation body FLU -> ENU (yaw from East, counter-clockwise) and its covariance
    P_att_n [rad^2] (attitude error about the fixed ENU axes x, y, z, as REP 145 asks).

    ``sample``: (omega_ib_v [rad/s], f_ib_v [m/s^2], cov_omega (9,), cov_f (9,)) of the IMU sample at the estimate's
    stamp, in vehicle FLU, as measured (not bias-corrected); the covariances are the driver's rotated into the
    vehicle frame (all zeros: unknown). None (no measured sample at that stamp, e.g. one bridging a gap): zero vectors
    with covariance element 0 set to -1 (REP 145: "no estimate"). ``q_xyzw``: as in :func:`pose_msg`."""
    msg = Imu()
    set_stamp(msg, est.stamp_s, epoch_s)
    msg.header.frame_id = frame_id
    o = msg.orientation
    o.x, o.y, o.z, o.w = (float(x) for x in (quat_xyzw(est.C_b_n) if q_xyzw is None else q_xyzw))
    P = np.asarray(est.P_att_n, float)
    msg.orientation_covariance = (0.5 * (P + P.T)).reshape(-1).tolist()
    if sample is None:
        msg.angular_velocity_covariance[0] = -1.0
        msg.linear_acceleration_covariance[0] = -1.0
        return msg
    w, f, cov_w, cov_f = sample
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(x) for x in w)
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (float(x) for x in f)
    msg.angular_velocity_covariance = [float(x) for x in cov_w]
    msg.linear_acceleration_covariance = [float(x) for x in cov_f]
    return msg


def datum_msg(anchor, stamp_s: float, frame_id: str, epoch_s: int = 0) -> NavSatFix:
    """The ENU origin of ~/pose (lat_rad, lon_rad, h_m: WGS84, ellipsoidal height) -> NavSatFix [deg, m].

    A frame definition, not a measurement: status FIX, covariance UNKNOWN; ``frame_id``: the ENU frame it anchors."""
    msg = NavSatFix()
    set_stamp(msg, stamp_s, epoch_s)
    msg.header.frame_id = frame_id
    msg.status.status = NavSatStatus.STATUS_FIX
    msg.latitude, msg.longitude = math.degrees(anchor[0]), math.degrees(anchor[1])
    msg.altitude = float(anchor[2])
    msg.position_covariance_type = NavSatFix.COVARIANCE_TYPE_UNKNOWN
    return msg
