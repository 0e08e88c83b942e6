"""Readers of the shared real recordings that are not KITTI: ``rover_canada`` and ``car_circles_vn100``.

Each reader returns a :class:`ScenarioData` **without truth** (what the pipeline sees) and an
:class:`AttitudeReference` (what a benchmark compares with; never given to the pipeline). Conventions are converted
once, here, in the named functions below (test/test_datasets.py checks each). docs/real_data.md gives the evidence
behind every decision; the numbers it quotes come from the data, and the tests recompute them.

rover_canada (``imu_planetary.mat``, ``gps-latlong.txt``, ``global-pose-utm.txt``):
  * IMU axes: x right, y backward, z down (RBD). Evidence: the 2-s mean of each accelerometer axis against the
    specific force the reference pose predicts in its own FLU body (correlation -0.97 for x vs left, -0.95 for y vs
    forward, -0.88 for z vs up over the run) and the gyro's -z against the pose's yaw rate (+0.86). ``rbd_to_flu``.
  * Clock: the IMU's relative time plus ROVER_IMU_CLOCK_OFFSET_S is the time since the first GNSS stamp: the lag
    that maximises the correlation of the gyro's yaw rate with the reference pose's (0.38 s; 0.35-0.39 s in three
    2-minute windows, so no drift). ``estimate_clock_offset_s`` recomputes it.
  * The pose is UTM 18T: its yaw is a grid yaw; ``utm_grid_yaw_to_enu_rad`` removes the meridian convergence.
  * Fix sigma: ROVER_FIX_SIGMA_H_M, the rms per-axis difference between the GNSS track and the reference pose track
    (0.6 m; the receiver gives no accuracy); vertical twice that.
car_circles_vn100 (``circle_data_0_imu.csv`` with two-line records, ``circle_data_0_gps.csv``):
  * IMU axes: FRD (x forward, y right, z down) of the sensor; ``frd_to_flu``. The sensor's x axis points to the rear
    of the car (the centripetal acceleration of the left turns appears on the sensor's right; the VN-100's own
    yaw is ~177 deg from the course over ground): the pipeline estimates the sensor's attitude, so this matters only
    for the course-over-ground reference (CAR_MOUNT_YAW_DEG).
  * The $VNYMR yaw/pitch/roll (NED, magnetic) -> ENU: ``ned_rpy_to_enu_rpy_rad`` plus the magnetic declination.
  * Fix sigma: CAR_UERE_M times the GGA's HDOP (BU-353, SiRF Star IV class); vertical twice that. No velocity.
Time base of both: seconds since the first stamp of either stream (``t0_s`` = the first IMU stamp).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pymap3d
from scipy.spatial.transform import Rotation

from ..core import earth
from ..core.recording import ScenarioData

#: IMU relative time + this = seconds since the first GNSS stamp (estimate_clock_offset_s)
ROVER_IMU_CLOCK_OFFSET_S = 0.38
ROVER_FIX_SIGMA_H_M = 0.6  #: horizontal 1-sigma of the rover's fixes [m] (GNSS vs reference pose, rms per axis)
ROVER_UTM_ZONE = 18
CAR_UERE_M = 2.5  #: BU-353 horizontal accuracy at HDOP 1 [m] (datasheet class: 2.5 m with SBAS); sigma = UERE * HDOP
CAR_MOUNT_YAW_DEG = 180.0  #: yaw of the VN-100's x axis relative to the car's direction of travel [deg]
CAR_DECLINATION_DEG = -14.0  #: magnetic declination at 42.34 N, 71.09 W (WMM, 2025; east positive) [deg]
COG_MIN_SPEED_M_S = 1.0  #: the course over ground is a reference only above this chord speed [m/s]

# RT3003 attitude accuracy (OXTS datasheet, 1-sigma): roll/pitch 0.03 deg, heading 0.1 deg
KITTI_REF_SIGMA_DEG = (0.03, 0.03, 0.1)


def shared_data_dir(start: Path | str | None = None) -> Path | None:
    """The shared real recordings (read-only, never copied into a checkout): ``$INSALIGN_DATA`` when set, else the
    first ``shared/data`` beside ``start`` or one of its ancestors (default: this package's location, which finds
    ``../shared/data`` beside a clone and beside a worktree inside it); None when there is none."""
    import os

    env = os.environ.get("INSALIGN_DATA")
    if env:
        return Path(env) if Path(env).is_dir() else None
    for p in Path(start or __file__).resolve().parents:
        if (p / "shared" / "data").is_dir():
            return p / "shared" / "data"
    return None


class DatasetError(ValueError):
    """The recording cannot be read (message says why)."""


@dataclass
class AttitudeReference:
    """An independent attitude reference of a recording, for evaluation only (never given to the pipeline).

    ``t_s`` [s, the recording's time base]; ``rpy_deg`` (n, 3) roll, pitch, yaw of body FLU in ENU [deg], yaw from
    East CCW, NaN where the reference does not give that axis; ``floor_deg`` (3,) the reference's own 1-sigma
    accuracy (the physical floor of any comparison with it), NaN where unknown; ``max_gap_s``: no interpolation
    across a longer gap; ``note``: what the reference is."""

    name: str
    t_s: np.ndarray
    rpy_deg: np.ndarray
    floor_deg: np.ndarray
    note: str = ""
    max_gap_s: float = 2.0
    extra: dict = field(default_factory=dict)

    def at(self, t_s) -> np.ndarray:
        """(len(t_s), 3) reference roll/pitch/yaw [deg] at the stamps ``t_s`` (linear, yaw unwrapped; NaN outside
        the span, across gaps longer than ``max_gap_s`` and where the reference has no value)."""
        t = np.atleast_1d(np.asarray(t_s, float))
        out = np.full((t.shape[0], 3), np.nan)
        for i in range(3):
            ok = np.isfinite(self.rpy_deg[:, i])
            if ok.sum() < 2:
                continue
            tr, a = self.t_s[ok], self.rpy_deg[ok, i]
            a = np.degrees(np.unwrap(np.radians(a)))
            v = np.interp(t, tr, a)
            k = np.clip(np.searchsorted(tr, t), 1, tr.shape[0] - 1)
            bad = (t < tr[0]) | (t > tr[-1]) | (tr[k] - tr[k - 1] > self.max_gap_s)
            v[bad] = np.nan
            out[:, i] = np.degrees(earth.wrap_angle_rad(np.radians(v)))
        return out


# ------------------------------------------------------------------------------------ conventions (one place)
def rbd_to_flu(v_rbd: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) in the rover IMU's axes (x right, y backward, z down) -> body FLU: (-y, -x, -z)."""
    v = np.asarray(v_rbd, float)
    return np.stack([-v[..., 1], -v[..., 0], -v[..., 2]], axis=-1)


def frd_to_flu(v_frd: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) in x forward, y right, z down -> FLU: (x, -y, -z)."""
    v = np.asarray(v_frd, float)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


def ned_rpy_to_enu_rpy_rad(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """Euler angles of an FRD body in NED (yaw from North, clockwise) -> of the same body's FLU axes in ENU
    (REP 103): roll unchanged, pitch negated, yaw = pi/2 - yaw_ned (wrapped). Returns (..., 3) [rad]."""
    r, p, y = (np.asarray(a, float) for a in (roll_rad, pitch_rad, yaw_rad))
    return np.stack([r, -p, earth.wrap_angle_rad(np.pi / 2 - y)], axis=-1)


def utm_convergence_rad(lat_rad: float, lon_rad: float, zone: int) -> float:
    """Meridian convergence of a UTM zone [rad]: the angle from true north to grid north, positive when grid north
    lies east of true north (east of the central meridian in the northern hemisphere): atan(tan(dlon) sin(lat))."""
    lon0 = math.radians(-183.0 + 6.0 * zone)
    return math.atan(math.tan(lon_rad - lon0) * math.sin(lat_rad))


def utm_grid_yaw_to_enu_rad(yaw_grid_rad, lat_rad: float, lon_rad: float, zone: int):
    """A yaw from grid east (CCW, a UTM map's x axis) -> from true East (CCW): minus the convergence."""
    return earth.wrap_angle_rad(np.asarray(yaw_grid_rad, float) - utm_convergence_rad(lat_rad, lon_rad, zone))


def fixes_to_ecef(lat_deg, lon_deg, h_m, sigma_h_m, sigma_v_m):
    """Geodetic fixes [deg, deg, m] with ENU 1-sigmas [m] -> (p_e (M, 3) [m], R_e (M, 3, 3) [m^2])."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    x, y, z = pymap3d.geodetic2ecef(lat, lon, np.asarray(h_m, float), deg=False)
    sh = np.broadcast_to(np.asarray(sigma_h_m, float), lat.shape)
    sv = np.broadcast_to(np.asarray(sigma_v_m, float), lat.shape)
    R_e = np.array([earth.C_n_e(a, b) @ np.diag([h * h, h * h, v * v]) @ earth.C_e_n(a, b)
                    for a, b, h, v in zip(lat, lon, sh, sv)])
    return np.column_stack([x, y, z]), R_e.reshape(-1, 3, 3)


def course_over_ground(t_s: np.ndarray, e_m: np.ndarray, n_m: np.ndarray, min_speed_m_s: float = COG_MIN_SPEED_M_S):
    """Course over ground from consecutive fixes: (t_mid [s], yaw from East CCW [rad], chord speed [m/s]) at the
    midpoints, where the chord speed is above ``min_speed_m_s``. On a circular arc at constant speed the chord's
    direction is exactly the tangent at the arc's midpoint (no turn-rate lag)."""
    de, dn, dt = np.diff(e_m), np.diff(n_m), np.diff(t_s)
    sp = np.hypot(de, dn) / dt
    ok = sp > min_speed_m_s
    return 0.5 * (t_s[1:] + t_s[:-1])[ok], np.arctan2(dn, de)[ok], sp[ok]


def estimate_clock_offset_s(t_imu_s, omega_up_rad_s, t_ref_s, yaw_ref_rad, lags_s=None,
                            step_s: float = 0.1) -> tuple[float, float]:
    """The lag L [s] with IMU time + L = reference time that maximises the correlation of the gyro's rate about
    Up (smoothed to ``step_s``) with the reference's yaw rate: (L, the correlation). ``lags_s``: the lags tried
    (default -2..2 s in 0.01-s steps)."""
    lags_s = np.arange(-2.0, 2.0, 0.01) if lags_s is None else lags_s
    tt = np.arange(t_ref_s[0], t_ref_s[-1], step_s)
    yr = np.gradient(np.interp(tt, t_ref_s, np.unwrap(yaw_ref_rad)), tt)
    k = max(round(float(step_s / np.median(np.diff(t_imu_s)))), 1)
    w = np.convolve(omega_up_rad_s, np.ones(k) / k, mode="same")
    best = (-2.0, float("nan"))
    for lag in lags_s:
        inside = (tt > t_imu_s[0] + lag) & (tt < t_imu_s[-1] + lag)
        c = float(np.corrcoef(np.interp(tt[inside], t_imu_s + lag, w), yr[inside])[0, 1])
        if c > best[0]:
            best = (c, float(lag))
    return best[1], best[0]


# ------------------------------------------------------------------------------------ rover_canada
def _need(path: Path) -> Path:
    if not path.exists():
        raise DatasetError(f"{path}: not found")
    return path


def read_rover_raw(directory) -> dict:
    """The rover's files as arrays, in the sensor's own conventions: IMU t [s relative], fb, wb (sensor axes);
    gps (M, 4) unix s, lat, lon, alt; pose (P, 8) unix s, UTM E, N, z, qx, qy, qz, qw."""
    from scipy.io import loadmat

    d = Path(directory)
    s = loadmat(_need(d / "imu_planetary.mat"), squeeze_me=True, struct_as_record=False)["imu_planetary"]
    gps = np.loadtxt(_need(d / "gps-latlong.txt"), delimiter=",", comments="#", ndmin=2)
    pose = np.loadtxt(_need(d / "global-pose-utm.txt"), delimiter=",", comments="#", ndmin=2)
    return {"t": np.asarray(s.t, float), "fb": np.asarray(s.fb, float), "wb": np.asarray(s.wb, float),
            "gps": gps, "pose": pose}


def rover_reference(raw: dict, t_gnss0_unix: float) -> AttitudeReference:
    """The rover's reference pose as roll/pitch/yaw of its FLU body in ENU (grid yaw corrected for convergence)."""
    pose, gps = raw["pose"], raw["gps"]
    rpy = Rotation.from_quat(pose[:, 4:8]).as_euler("ZYX")[:, ::-1].copy()  # the pose's body is FLU-like, x forward
    lat0, lon0 = math.radians(gps[0, 1]), math.radians(gps[0, 2])
    rpy[:, 2] = utm_grid_yaw_to_enu_rad(rpy[:, 2], lat0, lon0, ROVER_UTM_ZONE)
    # floor: undocumented reference; the grid->ENU rotation the GNSS track implies varies by +-1.2 deg between
    # 2-minute windows (docs/real_data.md), the IMU-to-pose level mounting is ~1 deg
    return AttitudeReference("rover reference pose", pose[:, 0] - t_gnss0_unix, np.degrees(rpy),
                             np.array([1.0, 1.0, 1.2]),
                             "dataset's global pose (UTM 18T), ~2.2 Hz; accuracy undocumented",
                             max_gap_s=1.5)


def read_rover_canada(directory) -> tuple[ScenarioData, AttitudeReference]:
    """rover_canada -> (ScenarioData without truth, the reference pose). See the module docstring."""
    raw = read_rover_raw(directory)
    gps = raw["gps"]
    t0u = float(gps[0, 0])
    t_imu = raw["t"] + ROVER_IMU_CLOCK_OFFSET_S
    ok = np.all(np.isfinite(gps), axis=1)
    gps = gps[ok]
    sh = np.full(gps.shape[0], ROVER_FIX_SIGMA_H_M)
    p_e, R_e = fixes_to_ecef(gps[:, 1], gps[:, 2], gps[:, 3], sh, 2.0 * sh)
    data = ScenarioData(
        name="rover_canada", seed=-1, t0_s=float(t_imu[0]), t_s=t_imu, omega_ib_b=rbd_to_flu(raw["wb"]),
        f_ib_b=rbd_to_flu(raw["fb"]), C_b_n=None, lat_rad=None, lon_rad=None, h_m=None, v_n=None,
        gnss_t_s=gps[:, 0] - t0u, gnss_p_e=p_e, gnss_R_e=R_e, gnss_sigma_m=ROVER_FIX_SIGMA_H_M,
        params={"source": "rover_canada", "imu_axes": "RBD -> FLU", "clock_offset_s": ROVER_IMU_CLOCK_OFFSET_S,
                "stamp_offset_unix_s": t0u, "ref_lat_deg": float(gps[0, 1]), "ref_lon_deg": float(gps[0, 2])})
    return data, rover_reference(raw, t0u)


# ------------------------------------------------------------------------------------ car_circles_vn100
def read_car_raw(directory) -> dict:
    """The car's CSV files (a real CSV parser: an IMU record spans two lines) -> arrays in the files' conventions:
    t [unix s], gyro, acc (sensor FRD), ymr_deg (VN-100 yaw, pitch, roll from $VNYMR); GPS t, lat, lon, alt, hdop."""
    d = Path(directory)
    with open(_need(d / "circle_data_0_imu.csv"), newline="") as fh:
        rows = list(csv.DictReader(fh))
    with open(_need(d / "circle_data_0_gps.csv"), newline="") as fh:
        grows = list(csv.DictReader(fh))
    if not rows or not grows:
        raise DatasetError(f"{d}: an empty CSV")
    col = lambda rs, names: np.array([[float(r[k]) for k in names] for r in rs])
    ymr = np.array([[float(x) for x in r["raw_vnymr"].strip().split("*")[0].split(",")[1:4]] for r in rows])
    return {"t": col(rows, ["t"])[:, 0], "gyro": col(rows, ["gyro_x", "gyro_y", "gyro_z"]),
            "acc": col(rows, ["acc_x", "acc_y", "acc_z"]), "ymr_deg": ymr,
            "gps_t": col(grows, ["t"])[:, 0], "lat": col(grows, ["latitude"])[:, 0],
            "lon": col(grows, ["longitude"])[:, 0], "alt": col(grows, ["altitude"])[:, 0],
            "hdop": col(grows, ["hdop"])[:, 0]}


def car_references(raw: dict, t0_unix: float) -> tuple[AttitudeReference, AttitudeReference]:
    """(course over ground + CAR_MOUNT_YAW_DEG as the sensor's yaw, the VN-100's own AHRS attitude in ENU)."""
    e, n, _ = pymap3d.geodetic2enu(raw["lat"], raw["lon"], raw["alt"], raw["lat"][0], raw["lon"][0], raw["alt"][0])
    tm, cog, sp = course_over_ground(raw["gps_t"] - t0_unix, e, n)
    yaw = earth.wrap_angle_rad(cog + math.radians(CAR_MOUNT_YAW_DEG))
    rpy = np.column_stack([np.full_like(yaw, np.nan), np.full_like(yaw, np.nan), np.degrees(yaw)])
    cog_ref = AttitudeReference(
        "course over ground", tm, rpy, np.array([np.nan, np.nan, 5.0]),
        f"chord course of consecutive 1-Hz fixes (speed > {COG_MIN_SPEED_M_S} m/s) + {CAR_MOUNT_YAW_DEG:.0f} deg mount",
        max_gap_s=1.5, extra={"speed_m_s": sp})
    y, p, r = (np.radians(raw["ymr_deg"][:, i]) for i in range(3))
    rpy_enu = ned_rpy_to_enu_rpy_rad(r, p, y + math.radians(CAR_DECLINATION_DEG))  # magnetic -> true north
    ahrs = AttitudeReference("VN-100 AHRS", raw["t"] - t0_unix, np.degrees(rpy_enu), np.array([1.0, 1.0, 5.0]),
                             "the sensor's own magnetometer/accelerometer AHRS, declination applied (weak)",
                             max_gap_s=0.2)
    return cog_ref, ahrs


def read_car_circles(directory) -> tuple[ScenarioData, AttitudeReference, AttitudeReference]:
    """car_circles_vn100 -> (ScenarioData without truth, the course-over-ground reference, the AHRS reference)."""
    raw = read_car_raw(directory)
    t0u = float(min(raw["t"][0], raw["gps_t"][0]))
    t = raw["t"] - t0u
    sh = CAR_UERE_M * raw["hdop"]
    p_e, R_e = fixes_to_ecef(raw["lat"], raw["lon"], raw["alt"], sh, 2.0 * sh)
    data = ScenarioData(
        name="car_circles_vn100", seed=-1, t0_s=float(t[0]), t_s=t, omega_ib_b=frd_to_flu(raw["gyro"]),
        f_ib_b=frd_to_flu(raw["acc"]), C_b_n=None, lat_rad=None, lon_rad=None, h_m=None, v_n=None,
        gnss_t_s=raw["gps_t"] - t0u, gnss_p_e=p_e, gnss_R_e=R_e, gnss_sigma_m=float(np.median(sh)),
        params={"source": "car_circles_vn100", "imu_axes": "FRD -> FLU", "stamp_offset_unix_s": t0u,
                "ref_lat_deg": float(raw["lat"][0]), "ref_lon_deg": float(raw["lon"][0])})
    cog, ahrs = car_references(raw, t0u)
    return data, cog, ahrs
