"""ROS message <-> core type conversions, with the checks that make a message acceptable.

Each ``*_from_msg`` returns ``(value, "")`` or ``(None, reason)``; it never raises on bad content. The reason is
what the node logs (throttled) and counts in /diagnostics. Frames: sensor_msgs/Imu in the body FLU frame
(REP 103/145), NavSatFix position covariance in ENU [m^2] (REP: "ENU"), poses in the local ENU frame ``enu``
anchored at the first accepted fix.
"""

from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, NavSatFix

from ..core import earth
from ..core.types import GnssFix, ImuSample
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


def imu_from_msg(msg: Imu, max_rate_rad_s: float, max_acc_m_s2: float,
                 frame_id: str = "") -> tuple[ImuSample | None, str]:
    """sensor_msgs/Imu -> ImuSample (omega_ib_b [rad/s], f_ib_b [m/s^2]) or (None, reason)."""
    if frame_id and msg.header.frame_id != frame_id:
        return None, f"frame_id {msg.header.frame_id!r} is not {frame_id!r}"
    w, a, q = msg.angular_velocity, msg.linear_acceleration, msg.orientation
    t = stamp_s(msg)
    omega = np.array([w.x, w.y, w.z])
    f = np.array([a.x, a.y, a.z])
    reason = (validation.check_vector(omega, "angular_velocity", max_rate_rad_s)
              or validation.check_vector(f, "linear_acceleration", max_acc_m_s2))
    if reason:
        return None, reason
    if not _finite(q.x, q.y, q.z, q.w):
        return None, "orientation: non-finite value"
    if not t > 0.0:
        return None, f"stamp {t:.6f} s is not positive"
    for cov, name in ((msg.angular_velocity_covariance, "angular_velocity"),
                      (msg.linear_acceleration_covariance, "linear_acceleration"),
                      (msg.orientation_covariance, "orientation")):
        if name == "orientation" and cov[0] == -1.0:  # REP 145: no orientation estimate
            if not np.all(np.isfinite(np.asarray(cov, float))):
                return None, "orientation covariance: non-finite value"
            continue
        reason = check_covariance(cov, 3, name)
        if reason:
            return None, reason
    return ImuSample(t, omega, f), ""


def imu_sample_fast(msg: Imu, cov_ok: dict, epoch_s: int = 0) -> tuple[ImuSample | None, str]:
    """sensor_msgs/Imu -> ImuSample for the node's callback: the message-level checks only (orientation finite,
    covariances usable, stamp > 0); the session checks the values. A covariance seen before is not checked again
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
    return ImuSample(t, np.array((w.x, w.y, w.z)), np.array((a.x, a.y, a.z))), ""


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

    Covariance: ``position_covariance`` (ENU, m^2) when its type is not UNKNOWN, else ``default_sigma_m`` per axis.
    """
    if frame_id and msg.header.frame_id != frame_id:
        return None, f"frame_id {msg.header.frame_id!r} is not {frame_id!r}"
    lat, lon, h = msg.latitude, msg.longitude, msg.altitude
    t = stamp_s(msg, epoch_s)
    known = msg.position_covariance_type != NavSatFix.COVARIANCE_TYPE_UNKNOWN
    cov = np.asarray(msg.position_covariance, float).reshape(3, 3)
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


def truth_from_msg(msg: PoseStamped, epoch_s: int = 0) -> tuple[tuple[float, np.ndarray, np.ndarray] | None, str]:
    """Ground-truth PoseStamped (frame ``enu``: orientation body FLU -> ENU) -> (stamp_s, C_b_n, p_n) or reason."""
    q, p = msg.pose.orientation, msg.pose.position
    if not _finite(q.x, q.y, q.z, q.w, p.x, p.y, p.z):
        return None, "NaN/Inf in ground-truth pose"
    nq = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    if abs(nq - 1.0) > 1e-3:
        return None, f"ground-truth quaternion norm {nq:.4f} is not 1"
    return (stamp_s(msg, epoch_s), Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), np.array([p.x, p.y, p.z])), ""


def quat_xyzw(C: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(C).as_quat()


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


def pose_msg(est, anchor, frame_id: str, child_frame_id: str, epoch_s: int = 0) -> PoseWithCovarianceStamped:
    """A core estimate -> PoseWithCovarianceStamped in the local ENU frame anchored at ``anchor`` (lat, lon, h)."""
    msg = PoseWithCovarianceStamped()
    set_stamp(msg, est.stamp_s, epoch_s)
    msg.header.frame_id = frame_id
    p_e = earth.geodetic_to_ecef(est.lat_rad, est.lon_rad, est.h_m)
    p_n = earth.ecef_to_enu(p_e, *anchor)
    pp = msg.pose.pose.position
    pp.x, pp.y, pp.z = (float(x) for x in p_n)
    q = quat_xyzw(est.C_b_n)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(x) for x in q)
    msg.pose.covariance = pose_cov_ros(position_cov_n(est, est.C_b_n), est.P_att_n)
    return msg
