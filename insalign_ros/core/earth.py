"""Earth model: WGS84, Earth rate, ECI/ECEF/ENU frames, gravity, Euler angles (REP 103).

Frames: i = ECI, e = ECEF, n = local-level ENU (REP 103), b = body FLU.
``C_a_b`` maps vectors in frame a to frame b (``v_b = C_a_b @ v_a``), so ``C_b_n`` is body -> ENU.

ECI definition: the ECI frame coincides with ECEF at a chosen epoch ``t0_s`` (data time, seconds) and the
ECEF frame rotates about the common z axis at ``OMEGA_IE_RAD_S``. Precession, nutation and polar motion are
ignored: over an alignment window (minutes) they are far below any sensor error.

Gravity: the gravitation (mass attraction) of the WGS84 *normal* field, with its even zonal harmonics
J2, J4, J6, plus the centrifugal term gives the normal gravity vector, which on the ellipsoid equals
Somigliana's closed form along the ellipsoid normal (the test checks both).
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
from scipy.spatial.transform import Rotation

# --------------------------------------------------------------------------------- WGS84 constants
A_M = 6378137.0  #: semi-major axis [m]
F = 1.0 / 298.257223563  #: flattening
B_M = A_M * (1.0 - F)  #: semi-minor axis [m]
E2 = F * (2.0 - F)  #: first eccentricity squared
GM_M3_S2 = 3.986004418e14  #: Earth's gravitational constant incl. atmosphere [m^3/s^2]
OMEGA_IE_RAD_S = 7.292115e-5  #: Earth rotation rate [rad/s]
GAMMA_EQUATOR_M_S2 = 9.7803253359  #: normal gravity at the equator [m/s^2]
GAMMA_POLE_M_S2 = 9.8321849378  #: normal gravity at the poles [m/s^2]
J2 = 1.082629821313e-3  #: second zonal harmonic of the WGS84 normal field (= -sqrt(5) C20)
_M = OMEGA_IE_RAD_S**2 * A_M**2 * B_M / GM_M3_S2
_K_SOMIGLIANA = B_M * GAMMA_POLE_M_S2 / (A_M * GAMMA_EQUATOR_M_S2) - 1.0


def _normal_field_j2n(n: int) -> float:
    """Even zonal coefficient J_2n of the normal (ellipsoidal) field (Moritz, Geodetic Reference System)."""
    e2n = E2**n
    return (-1.0) ** (n + 1) * 3.0 * e2n / ((2 * n + 1) * (2 * n + 3)) * (1.0 - n + 5.0 * n * J2 / E2)


_ZONAL = ((2, J2), (4, _normal_field_j2n(2)), (6, _normal_field_j2n(3)))
OMEGA_IE_E = np.array([0.0, 0.0, OMEGA_IE_RAD_S])  #: Earth rate in ECEF (and ECI) [rad/s]


# ------------------------------------------------------------------------------------ frames, time
def C_e_i(t_s: float, t0_s: float = 0.0) -> np.ndarray:
    """Rotation ECEF -> ECI at data time t_s [s]; ECI == ECEF at the epoch t0_s."""
    a = OMEGA_IE_RAD_S * (t_s - t0_s)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ecef_to_eci(t_s: float, p_e: np.ndarray, v_e: np.ndarray | None = None, t0_s: float = 0.0):
    """ECEF position [m] (and velocity [m/s] relative to ECEF) -> ECI position and inertial velocity."""
    C = C_e_i(t_s, t0_s)
    p_i = C @ p_e
    if v_e is None:
        return p_i
    return p_i, C @ (np.asarray(v_e) + _omega_ie_cross(p_e))


def eci_to_ecef(t_s: float, p_i: np.ndarray, v_i: np.ndarray | None = None, t0_s: float = 0.0):
    """ECI position [m] (and inertial velocity [m/s]) -> ECEF position and velocity relative to ECEF."""
    C = C_e_i(t_s, t0_s).T
    if v_i is None:
        return C @ p_i
    return eci_to_ecef_pv(C, p_i, np.asarray(v_i))


def eci_to_ecef_pv(C_i_e: np.ndarray, p_i: np.ndarray, v_i: np.ndarray):
    """:func:`eci_to_ecef` of a position and a velocity with the rotation ``C_i_e = C_e_i(t_s, t0_s)^T`` given
    (compiled as is inside core/mechanization_numba.py's ``eci_navigation``)."""
    p_e = C_i_e @ p_i
    return p_e, C_i_e @ v_i - _omega_ie_cross(p_e)


def _omega_ie_cross(p_e: np.ndarray) -> np.ndarray:
    """``OMEGA_IE_E x p_e`` [m/s] written out (the same numbers as np.cross, which costs ~12 us a call; every
    estimate() of the ECI cores converts once, docs/speed.md)."""
    return np.array([-OMEGA_IE_RAD_S * p_e[1], OMEGA_IE_RAD_S * p_e[0], 0.0])


def geodetic_to_ecef(lat_rad: float, lon_rad: float, h_m: float) -> np.ndarray:
    """Geodetic latitude/longitude [rad], ellipsoidal height [m] -> ECEF [m] (pymap3d, WGS84)."""
    return np.array(pymap3d.geodetic2ecef(lat_rad, lon_rad, h_m, deg=False))


def ecef_to_geodetic(p_e: np.ndarray) -> tuple[float, float, float]:
    """ECEF [m] -> (lat_rad, lon_rad, h_m) (WGS84), Heikkinen's closed form (IEEE Trans. AES 30(3), 1994, J. Zhu's
    summary) in scalar floats (:func:`geodetic_closed_form`, which every estimate() of the ECI cores runs compiled,
    8x with a yaw bank): pymap3d's ``ecef2geodetic`` costs ~85 us a call against ~2 us here. Round trip with :func:`geodetic_to_ecef` from -10 km to
    1,000 km of height: < 1e-15 rad and < 1e-8 m (pymap3d: the same near the surface, 1.2e-9 rad above 10 km;
    test/test_earth.py); pymap3d within 1 km of the Earth's centre."""
    x, y, z = float(p_e[0]), float(p_e[1]), float(p_e[2])
    if x * x + y * y + z * z < 1e6:  # the closed form's singular region (the centre): the library
        lat, lon, h = pymap3d.ecef2geodetic(x, y, z, deg=False)
        return float(lat), float(lon), float(h)
    return geodetic_closed_form(x, y, z)


def geodetic_closed_form(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Heikkinen's closed form of :func:`ecef_to_geodetic` (floats; NaN within 1 km of the Earth's centre, where
    :func:`ecef_to_geodetic` takes the library); compiled as is by core/mechanization_numba.py."""
    p2 = x * x + y * y
    p = math.sqrt(p2)
    if p2 + z * z < 1e6:
        return math.nan, math.nan, math.nan
    z2 = z * z
    F_ = 54.0 * B_M * B_M * z2
    G = p2 + (1.0 - E2) * z2 - E2 * (A_M * A_M - B_M * B_M)
    c = E2 * E2 * F_ * p2 / (G * G * G)
    s = (1.0 + c + math.sqrt(c * c + 2.0 * c)) ** (1.0 / 3.0)
    k = s + 1.0 + 1.0 / s
    P = F_ / (3.0 * k * k * G * G)
    Q = math.sqrt(1.0 + 2.0 * E2 * E2 * P)
    r0 = -P * E2 * p / (1.0 + Q) + math.sqrt(max(0.5 * A_M * A_M * (1.0 + 1.0 / Q)
                                                 - P * (1.0 - E2) * z2 / (Q * (1.0 + Q)) - 0.5 * P * p2, 0.0))
    dp = p - E2 * r0
    U = math.sqrt(dp * dp + z2)
    V = math.sqrt(dp * dp + (1.0 - E2) * z2)
    z0 = B_M * B_M * z / (A_M * V)
    h = U * (1.0 - B_M * B_M / (A_M * V))
    lat = math.atan2(z + (E2 / (1.0 - E2)) * z0, p)
    return lat, math.atan2(y, x), h


def C_e_n(lat_rad: float, lon_rad: float) -> np.ndarray:
    """Rotation ECEF -> local ENU at geodetic (lat, lon); rows are the E, N, U axes in ECEF."""
    sl, cl = math.sin(lat_rad), math.cos(lat_rad)
    so, co = math.sin(lon_rad), math.cos(lon_rad)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def C_n_e(lat_rad: float, lon_rad: float) -> np.ndarray:
    """Rotation local ENU -> ECEF (transpose of :func:`C_e_n`)."""
    return C_e_n(lat_rad, lon_rad).T


def ecef_to_enu(p_e: np.ndarray, lat0_rad: float, lon0_rad: float, h0_m: float) -> np.ndarray:
    """ECEF point [m] -> ENU coordinates [m] about the origin (lat0, lon0, h0) (pymap3d)."""
    return np.array(pymap3d.ecef2enu(p_e[0], p_e[1], p_e[2], lat0_rad, lon0_rad, h0_m, deg=False))


def enu_to_ecef(p_n: np.ndarray, lat0_rad: float, lon0_rad: float, h0_m: float) -> np.ndarray:
    """ENU coordinates [m] about the origin (lat0, lon0, h0) -> ECEF [m] (pymap3d)."""
    return np.array(pymap3d.enu2ecef(p_n[0], p_n[1], p_n[2], lat0_rad, lon0_rad, h0_m, deg=False))


def omega_ie_n(lat_rad: float) -> np.ndarray:
    """Earth rate in local ENU [rad/s]: [0, omega cos(lat), omega sin(lat)]."""
    return OMEGA_IE_RAD_S * np.array([0.0, math.cos(lat_rad), math.sin(lat_rad)])


def radii_of_curvature(lat_rad: float) -> tuple[float, float]:
    """Meridian R_N and transverse (prime vertical) R_E radii of curvature [m]."""
    s2 = math.sin(lat_rad) ** 2
    d = 1.0 - E2 * s2
    return A_M * (1.0 - E2) / d**1.5, A_M / math.sqrt(d)


# ----------------------------------------------------------------------------------------- gravity
def normal_gravity(lat_rad: float, h_m: float = 0.0) -> float:
    """Magnitude of WGS84 normal gravity [m/s^2]: Somigliana's formula with the second-order height correction."""
    s2 = math.sin(lat_rad) ** 2
    g0 = GAMMA_EQUATOR_M_S2 * (1.0 + _K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    if h_m == 0.0:
        return g0
    return g0 * (1.0 - 2.0 / A_M * (1.0 + F + _M - 2.0 * F * s2) * h_m + 3.0 * h_m * h_m / (A_M * A_M))


def gravitation_e(p_e: np.ndarray) -> np.ndarray:
    """Gravitational (mass) acceleration in ECEF [m/s^2] of the WGS84 normal field (J2, J4, J6).

    The field is axially symmetric, so the same function gives the gravitation in ECI for an ECI position:
    ``gravitation_e(p_i)`` is the ECI gravitation at ECI position p_i (rotation about z commutes).
    Written with scalar math: it runs once per IMU sample in every mechanization.
    """
    x, y, z = float(p_e[0]), float(p_e[1]), float(p_e[2])
    r2 = x * x + y * y + z * z
    r = math.sqrt(r2)
    u = z / r
    # V = GM/r [1 - sum J_n (a/r)^n P_n(u)];  grad of r^-(n+1) P_n(u) via P_n and P_n'.
    # Legendre by recurrence up to degree 6.
    P = [1.0, u]
    dP = [0.0, 1.0]
    for k in range(2, 7):
        P.append(((2 * k - 1) * u * P[k - 1] - (k - 1) * P[k - 2]) / k)
        dP.append(k * P[k - 1] + u * dP[k - 1])
    # central term: -GM/r^3 * p
    gx = gy = gz = 0.0
    for n, Jn in _ZONAL:
        an = (A_M / r) ** n
        # term T = -GM Jn a^n r^-(n+1) P_n(u)  (potential part); its gradient:
        # dT/dx_i = -GM Jn a^n [ -(n+1) r^-(n+3) x_i P_n + r^-(n+1) P_n' (d_iz/r - z x_i/r^3) ]
        c = -GM_M3_S2 * Jn * an / r  # = -GM Jn a^n r^-(n+1)
        radial = -(n + 1) * P[n] / r2 - dP[n] * z / (r2 * r)
        gx += c * radial * x
        gy += c * radial * y
        gz += c * (radial * z + dP[n] / r)
    k0 = -GM_M3_S2 / (r2 * r)
    return np.array([k0 * x + gx, k0 * y + gy, k0 * z + gz])


def gravitation_e_batch(p_e: np.ndarray) -> np.ndarray:
    """Vectorised :func:`gravitation_e` for an (N, 3) array of positions [m] (same field, same formula)."""
    p_e = np.asarray(p_e, dtype=float)
    x, y, z = p_e[:, 0], p_e[:, 1], p_e[:, 2]
    r2 = x * x + y * y + z * z
    r = np.sqrt(r2)
    u = z / r
    P = [np.ones_like(u), u]
    dP = [np.zeros_like(u), np.ones_like(u)]
    for k in range(2, 7):
        P.append(((2 * k - 1) * u * P[k - 1] - (k - 1) * P[k - 2]) / k)
        dP.append(k * P[k - 1] + u * dP[k - 1])
    k0 = -GM_M3_S2 / (r2 * r)
    g = k0[:, None] * p_e
    for n, Jn in _ZONAL:
        c = -GM_M3_S2 * Jn * (A_M / r) ** n / r
        radial = -(n + 1) * P[n] / r2 - dP[n] * z / (r2 * r)
        g[:, 0] += c * radial * x
        g[:, 1] += c * radial * y
        g[:, 2] += c * (radial * z + dP[n] / r)
    return g


def gravity_e(p_e: np.ndarray) -> np.ndarray:
    """Gravity (gravitation + centrifugal) in ECEF [m/s^2] at ECEF position p_e [m]."""
    g = gravitation_e(p_e)
    w2 = OMEGA_IE_RAD_S * OMEGA_IE_RAD_S
    g[0] += w2 * p_e[0]
    g[1] += w2 * p_e[1]
    return g


def gravity_n(lat_rad: float, h_m: float = 0.0) -> np.ndarray:
    """Normal gravity vector in ENU [m/s^2]: [0, 0, -normal_gravity(lat, h)] (ellipsoid normal)."""
    return np.array([0.0, 0.0, -normal_gravity(lat_rad, h_m)])


# ------------------------------------------------------------------------------------ Euler angles
def C_b_n_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Body FLU -> ENU rotation from roll, pitch, yaw [rad] (REP 103: R = Rz(yaw) Ry(pitch) Rx(roll)).

    Yaw is measured from East, counter-clockwise about Up; positive pitch is nose down (rotation about +y = left),
    as in ROS and the KITTI OXTS data.
    """
    return Rotation.from_euler("ZYX", [yaw_rad, pitch_rad, roll_rad]).as_matrix()


def rpy_from_C_b_n(C_b_n: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) [rad] of a body FLU -> ENU rotation ``C_b_n = Rz(yaw) Ry(pitch) Rx(roll)`` (intrinsic
    ZYX); yaw in (-pi, pi], pitch in [-pi/2, pi/2]. Also for a stack (..., 3, 3) -> (..., 3).

    Closed form from the matrix entries (scipy's ``as_euler("ZYX")`` gives the same to 1e-14 rad and costs ~7x more:
    it ran per output, docs/speed.md); at pitch +-90 deg roll and yaw are not separable and the split is arbitrary."""
    C = np.asarray(C_b_n, float)
    return np.stack([np.arctan2(C[..., 2, 1], C[..., 2, 2]),
                     np.arctan2(-C[..., 2, 0], np.hypot(C[..., 0, 0], C[..., 1, 0])),
                     np.arctan2(C[..., 1, 0], C[..., 0, 0])], axis=-1)


def level_from_specific_force(f_ib_b: np.ndarray, accel_m_s2: float) -> tuple[float, float, float]:
    """(roll, pitch, level 1-sigma) [rad] from specific-force samples f_ib_b (N, 3) [m/s^2] of a vehicle that may be
    accelerating by up to ``accel_m_s2``: the mean's direction is up; the 1-sigma is honest rather than small: 1 deg
    for an unknown accelerometer bias, the acceleration over g, and the samples' spread over g."""
    F = np.asarray(f_ib_b, float)
    return _level_from_mean(F.mean(axis=0), accel_m_s2, float(np.linalg.norm(F.std(axis=0))))


def _level_from_mean(fm: np.ndarray, accel_m_s2: float, spread_m_s2: float) -> tuple[float, float, float]:
    """(roll, pitch, 1-sigma) [rad] from a mean specific force ``fm``: its direction is up; 1 deg for an unknown
    accelerometer bias, the acceleration and the spread [m/s^2] over g."""
    g = max(float(np.linalg.norm(fm)), 1.0)
    sig = math.sqrt(math.radians(1.0) ** 2 + (accel_m_s2 / g) ** 2 + (spread_m_s2 / g) ** 2)
    return math.atan2(fm[1], fm[2]), math.atan2(-fm[0], math.hypot(fm[1], fm[2])), sig


def level_from_window(t_s, omega_ib_b, f_ib_b, accel_sigma_m_s2: float) -> tuple[float, float, float]:
    """(roll, pitch, level 1-sigma) [rad] at the last of a window of IMU samples (t_s (N,) [s], rates [rad/s] and
    specific forces [m/s^2], each the mean over the interval ending at its stamp) of a body that may rotate and
    accelerate: every specific force turned into the body frame of the last sample by the gyros (their rotation over
    the window; a gyro bias of b turns it by b T), so that their mean is up tilted by the mean acceleration over the
    window, whose 1-sigma the caller bounds (``accel_sigma_m_s2``: e.g. the change of the GNSS velocity over the
    window over its length). 1-sigma as :func:`level_from_specific_force`, with the noise of the mean in place of the
    samples' spread (the acceleration they carry is in the bound)."""
    t = np.asarray(t_s, float)
    W = np.asarray(omega_ib_b, float)
    F = np.asarray(f_ib_b, float)
    n = t.shape[0]
    Fr = np.empty_like(F)
    Q = np.eye(3)  # body(k) -> body(last)
    Fr[n - 1] = F[n - 1]
    for k in range(n - 2, -1, -1):
        Q = Q @ Rotation.from_rotvec(W[k + 1] * (t[k + 1] - t[k])).as_matrix().T  # undo the step k -> k + 1
        Fr[k] = Q @ F[k]
    return _level_from_mean(Fr.mean(axis=0), accel_sigma_m_s2,
                            float(np.linalg.norm(Fr.std(axis=0))) / math.sqrt(max(n, 1)))


def wrap_angle_rad(a):
    """Wrap angle(s) to (-pi, pi]."""
    return -((-np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi)


def euler_error_rad(C_b_n_est: np.ndarray, C_b_n_true: np.ndarray) -> np.ndarray:
    """Roll/pitch/yaw error [rad] of an estimate, estimate minus truth, each wrapped to (-pi, pi]."""
    return wrap_angle_rad(rpy_from_C_b_n(C_b_n_est) - rpy_from_C_b_n(C_b_n_true))


def heading_error_enu_rad(C_b_n_est: np.ndarray, C_b_n_true: np.ndarray) -> np.ndarray:
    """Attitude error as a small rotation vector in ENU [rad]: C_b_n_est = exp(psi_x) C_b_n_true, returns psi.

    Its third component is the azimuth error about Up; unlike Euler differences it has no gimbal-lock problem.
    """
    return Rotation.from_matrix(C_b_n_est @ C_b_n_true.T).as_rotvec()


def velocity_from_fixes(t_s, p_e, R_e, max_dt_s: float = 2.5):
    """ENU velocity from successive GNSS fixes, for users without a velocity topic.

    t_s (n,) [s], p_e (n, 3) ECEF [m], R_e (n, 3, 3) ECEF covariances [m^2] -> (t_mid (m,), v_n (m, 3) [m/s],
    R_n (m, 3, 3) [m^2/s^2]): for each pair of consecutive fixes 0 < dt <= max_dt_s, the ECEF difference over dt
    rotated into ENU at the mid-point, stamped at the middle of the interval (the average velocity over an interval
    is the velocity at its middle to second order), with the covariance ``C_e_n (R_1 + R_2) C_e_n' / dt^2``
    (independent fixes; successive differences share a fix, so neighbouring velocities are correlated -1/2, which
    the caller should know when it fuses them as independent).
    """
    t_s, p_e, R_e = np.asarray(t_s, float), np.asarray(p_e, float), np.asarray(R_e, float)
    dt = np.diff(t_s)
    ok = (dt > 0) & (dt <= max_dt_s) & np.all(np.isfinite(p_e[1:]), 1) & np.all(np.isfinite(p_e[:-1]), 1)
    idx = np.flatnonzero(ok)
    t_mid = 0.5 * (t_s[idx] + t_s[idx + 1])
    v_n = np.zeros((len(idx), 3))
    R_n = np.zeros((len(idx), 3, 3))
    for m, i in enumerate(idx):
        lat, lon, _ = ecef_to_geodetic(0.5 * (p_e[i] + p_e[i + 1]))
        C = C_e_n(lat, lon)
        v_n[m] = C @ (p_e[i + 1] - p_e[i]) / dt[i]
        R_n[m] = C @ (R_e[i] + R_e[i + 1]) @ C.T / dt[i] ** 2
    return t_mid, v_n, R_n
