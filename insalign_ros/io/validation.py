"""Input validation shared by the bag reader (io/bag.py), the KITTI converter and the ROS node. No ROS import.

Every check is a pure function returning ``None`` when the sample is acceptable, else a short reason string
(the callers count rejections per reason and report the counts). Bounds are physical, not tuned:

* angular rate: |omega| <= MAX_RATE_RAD_S = 2000 deg/s (the largest common MEMS full-scale range);
* specific force: |f| <= MAX_SPECIFIC_FORCE_M_S2 = 50 g (beyond any vehicle IMU's range here);
* stamps: finite, strictly increasing (a repeated stamp is a duplicate, a smaller one is non-monotonic);
* covariance: finite, symmetric (rel. 1e-9), positive semi-definite (eigenvalues >= -1e-12 * trace),
  and for a GNSS fix a non-zero diagonal (a zero covariance would make a filter trust the fix infinitely).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.units import G0_M_S2

MAX_RATE_RAD_S = math.radians(2000.0)
MAX_SPECIFIC_FORCE_M_S2 = 50.0 * G0_M_S2
MAX_GNSS_SIGMA_M = 1.0e4  #: a fix with a larger 1-sigma is useless for alignment


def check_stamp(t_s: float, prev_t_s: float | None) -> str | None:
    if not math.isfinite(t_s):
        return "non-finite stamp"
    if prev_t_s is not None:
        if t_s == prev_t_s:
            return "duplicate stamp"
        if t_s < prev_t_s:
            return "non-monotonic stamp"
    return None


def check_vector(v, name: str, max_norm: float) -> str | None:
    if type(v) is tuple and len(v) == 3:  # three floats (the bag reader's fast path): no numpy per sample
        x, y, z = v
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return f"{name}: non-finite value"
        n = math.sqrt(x * x + y * y + z * z)
        return f"{name}: magnitude {n:.3g} > {max_norm:.3g}" if n > max_norm else None
    a = np.asarray(v, dtype=float)
    if a.shape != (3,):
        return f"{name}: shape {a.shape} != (3,)"
    if not np.all(np.isfinite(a)):
        return f"{name}: non-finite value"
    if float(np.linalg.norm(a)) > max_norm:
        return f"{name}: magnitude {np.linalg.norm(a):.3g} > {max_norm:.3g}"
    return None


def check_imu(omega_ib_b, f_ib_b) -> str | None:
    return check_vector(omega_ib_b, "angular_velocity", MAX_RATE_RAD_S) or check_vector(
        f_ib_b, "linear_acceleration", MAX_SPECIFIC_FORCE_M_S2)


def check_pose(p: tuple, q: tuple) -> str | None:
    """Why a pose (position (x, y, z), orientation quaternion (x, y, z, w)) is unusable, or None."""
    x, y, z, w = q
    n2 = x * x + y * y + z * z + w * w  # nan or inf when a component is
    if not abs(math.sqrt(n2) - 1.0) <= 1e-6:
        return "orientation not a unit quaternion"
    if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
        return "non-finite position"
    return None


def check_covariance(cov, name: str = "covariance", require_positive_diag: bool = False) -> str | None:
    c = np.asarray(cov, dtype=float)
    if c.shape == (9,):
        c = c.reshape(3, 3)
    if c.shape != (3, 3):
        return f"{name}: shape {c.shape} != (3, 3)"
    if not np.all(np.isfinite(c)):
        return f"{name}: non-finite value"
    scale = max(float(np.max(np.abs(c))), 1e-300)
    if float(np.max(np.abs(c - c.T))) > 1e-9 * scale:
        return f"{name}: not symmetric"
    a, b, d, e, f, k = c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2]
    if a > 0.0 and a * e - b * b > 1e-9 * a * e and \
            a * (e * k - f * f) - b * (b * k - f * d) + d * (b * f - e * d) > 1e-9 * a * e * k:
        pass  # leading minors clearly positive (Sylvester): positive definite, no eigenvalues needed (every fix)
    elif (ev := np.linalg.eigvalsh(0.5 * (c + c.T)))[0] < -1e-12 * max(float(np.trace(c)), 1e-300):
        return f"{name}: not positive semi-definite (min eigenvalue {ev[0]:.3g})"
    if require_positive_diag and not np.all(np.diag(c) > 0):
        return f"{name}: zero or negative variance on the diagonal"
    return None


def check_fix(lat_deg: float, lon_deg: float, alt_m: float, cov_enu=None, status: int = 0) -> str | None:
    """A WGS84 fix (NavSatFix semantics: status < 0 = no fix)."""
    if status < 0:
        return "no fix (status < 0)"
    if not all(math.isfinite(x) for x in (lat_deg, lon_deg, alt_m)):
        return "non-finite lat/lon/alt"
    if abs(lat_deg) > 90.0 or abs(lon_deg) > 180.0:
        return "lat/lon out of range"
    if not -1.0e4 < alt_m < 1.0e5:
        return f"altitude {alt_m:.3g} m out of range"
    if cov_enu is not None:
        r = check_covariance(cov_enu, "position_covariance", require_positive_diag=True)
        if r:
            return r
        if float(np.sqrt(np.max(np.diag(np.asarray(cov_enu, float).reshape(3, 3))))) > MAX_GNSS_SIGMA_M:
            return "position sigma > 10 km"
    return None


def format_counts(counts: dict) -> str:
    """{reason: count} -> 'reason: n, ...' sorted by reason (the converters' and readers' reports)."""
    return ", ".join(f"{k}: {n}" for k, n in sorted(counts.items()))


#: the mean specific force of a recording further than this from the vehicle's up axis (+z of FLU) means the IMU
#: axes or mounting are wrong: no vehicle spends a recording tilted this much on average
MAX_MEAN_TILT_DEG = 60.0


def check_gravity_axis(f_ib_v: np.ndarray, imu_axes: str = "flu") -> str | None:
    """The recording's mean specific force [m/s^2] in the vehicle FLU frame (after the IMU axes and mounting) against
    gravity: held level, an FLU body measures f ~ (0, 0, +9.8) (the reaction to gravity points up). A mean more
    than MAX_MEAN_TILT_DEG from +z is a wrong ``imu_axes`` or mounting; a negative z (upside down) is the sign of an
    FRD IMU read as FLU (or the reverse). Returns None, or the reason with the option to check."""
    f = np.asarray(f_ib_v, float)
    f = f[np.all(np.isfinite(f), axis=1)] if f.ndim == 2 else f[None, :]
    if not f.shape[0]:
        return None
    m = f.mean(axis=0)
    g = float(np.linalg.norm(m))
    if g < 1.0:  # free fall or no data: nothing to judge
        return None
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, m[2] / g))))
    if tilt <= MAX_MEAN_TILT_DEG:
        return None
    where = (f"mean specific force ({m[0]:.2f}, {m[1]:.2f}, {m[2]:.2f}) m/s^2 in the vehicle FLU frame, "
             f"{tilt:.0f} deg from +z (a level FLU IMU reads about (0, 0, +9.8))")
    if m[2] < 0 and tilt > 135.0:
        other = "frd" if imu_axes == "flu" else "flu"
        why = ("z down: an FRD IMU (x forward, y right, z down) read as FLU?" if other == "frd" else
               "the data already FLU?")
        return f"{where}: the IMU looks upside down ({why}); check --imu-axes {other} (node: imu_axes)"
    return f"{where}: check --imu-axes and --imu-mount-rpy-deg (node: imu_axes, imu_mount_rpy_deg)"
