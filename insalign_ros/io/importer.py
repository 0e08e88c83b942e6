"""Generic IMU log (CSV or .npz) -> ScenarioData (then io/bag.write_bag): the input of ``insalign-import``.

A table with one row per IMU sample; the column names carry the units (docs/bag_contract.md, "insalign-import"):

  t_s                                          time [s] (any origin: a UNIX time is kept as the bag's stamp offset)
  wx_rad_s wy_rad_s wz_rad_s fx_m_s2 fy_m_s2 fz_m_s2
                                               ``imu="rates"``: angular rate [rad/s], specific force [m/s^2]
  dthx_rad dthy_rad dthz_rad dvx_m_s dvy_m_s dvz_m_s
                                               ``imu="increments"``: angle [rad] and velocity [m/s] increments over
                                               (t_{k-1}, t_k] (converted to average rates; see increments_to_rates)
  lat_deg lon_deg h_m sigma_h_m [sigma_v_m]    optional GNSS fix (WGS84, ellipsoidal height; 1-sigma horizontal
                                               and vertical, default vertical = 2 x horizontal); empty = no fix
  roll_deg pitch_deg yaw_deg                   optional reference attitude in ``euler`` convention; empty = none
  ref_lat_deg ref_lon_deg ref_h_m              optional reference position (e.g. a GNSS/INS solution); empty = none
  vel_e_m_s vel_n_m_s vel_u_m_s sigma_vel_m_s  optional GNSS velocity, ENU components (or vel_north_m_s
                                               vel_east_m_s vel_down_m_s: NED, or speed_m_s course_deg: the
                                               horizontal speed and its course from North clockwise), per-axis
                                               1-sigma [m/s]; empty = none
  wheel_speed_m_s [sigma_wheel_m_s]            optional wheel speed along the vehicle's x axis (default 1-sigma 0.1)
  gnss_heading_deg sigma_heading_deg           optional dual-antenna heading of the baseline, from North clockwise
                                               (as receivers report it; converted to the ENU yaw 90 deg - heading)

Conventions are converted once, here: the IMU axes (``axes``, e.g. "RFU", "FRD") to body FLU by
``imu_axes_to_flu``; the reference Euler angles ("enu": ROS/REP 103, body FLU -> ENU, yaw from East CCW; "ned":
aerospace, body FRD -> NED, heading from North clockwise, nose-up pitch positive) to C_b_n by ``C_b_n_from_euler``.
The reference attitude describes the vehicle whose forward/left/up are the IMU axes after the axes conversion.
Its position (the truth topic needs one) is, in this order: the ref_* columns, the GNSS fixes (both interpolated
linearly to the IMU stamps), ``position_llh``. Truth velocity (v_n) is the reference positions differentiated, as
read_bag does; with positions from 1-Hz fixes it is only as good as the fixes (a metre of noise over a second).

Bad rows never crash: a non-finite or out-of-range IMU value or a stamp that does not increase drops the row
(counted per reason in the report); a bad fix or attitude in a row drops that fix or attitude only.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import pymap3d
from scipy.spatial.transform import Rotation

from ..core import earth
from ..core.recording import ScenarioData
from . import validation

IMU_COLUMNS = {"rates": ("wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2"),
               "increments": ("dthx_rad", "dthy_rad", "dthz_rad", "dvx_m_s", "dvy_m_s", "dvz_m_s")}
GNSS_COLUMNS = ("lat_deg", "lon_deg", "h_m", "sigma_h_m")
EULER_COLUMNS = ("roll_deg", "pitch_deg", "yaw_deg")
REF_POSITION_COLUMNS = ("ref_lat_deg", "ref_lon_deg", "ref_h_m")
EULER_CONVENTIONS = ("enu", "ned")
_AXIS = {"F": (1, 0, 0), "B": (-1, 0, 0), "L": (0, 1, 0), "R": (0, -1, 0), "U": (0, 0, 1), "D": (0, 0, -1)}
#: FRD -> FLU and NED -> ENU (both symmetric, own inverses)
C_FRD_FLU = np.diag([1.0, -1.0, -1.0])
C_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


class ImportDataError(ValueError):
    """The input cannot be imported (the message says why, in one line)."""


def C_flu_from_axes(axes: str) -> np.ndarray:
    """(3, 3) matrix mapping a vector in the IMU's ``axes`` (three letters of F/B, L/R, U/D naming where the IMU's
    x, y, z point, e.g. "FLU", "RFU", "FRD") to body FLU: v_flu = C @ v_axes. Must be right-handed."""
    a = str(axes).upper()
    if len(a) != 3 or any(c not in _AXIS for c in a):
        raise ImportDataError(f"axes {axes!r}: three letters of F/B/L/R/U/D expected (e.g. FLU, RFU, FRD)")
    C = np.array([_AXIS[c] for c in a], float).T
    if abs(np.linalg.det(C) - 1.0) > 1e-12:
        raise ImportDataError(f"axes {axes!r}: not a right-handed frame (x cross y must be z)")
    return C


def imu_axes_to_flu(v: np.ndarray, axes: str) -> np.ndarray:
    """(N, 3) vectors (rates, specific forces, increments) in the IMU's ``axes`` -> body FLU."""
    return np.asarray(v, float) @ C_flu_from_axes(axes).T


def C_b_n_from_euler(roll_rad, pitch_rad, yaw_rad, convention: str) -> np.ndarray:
    """Euler angles (N,) [rad] -> (N, 3, 3) C_b_n, body FLU -> ENU (REP 103).

    "enu": roll, pitch, yaw of body FLU relative to ENU, C = Rz(yaw) Ry(pitch) Rx(roll), yaw from East CCW.
    "ned": roll, pitch, heading of body FRD relative to NED, C_frd_ned = Rz(heading) Ry(pitch) Rx(roll), heading
    from North clockwise; C_b_n = C_NED_ENU C_frd_ned C_FRD_FLU (yaw_enu = 90 deg - heading, pitch changes sign).
    """
    if convention not in EULER_CONVENTIONS:
        raise ImportDataError(f"Euler convention {convention!r}: one of {EULER_CONVENTIONS}")
    ypr = np.column_stack([yaw_rad, pitch_rad, roll_rad])
    C = Rotation.from_euler("ZYX", ypr).as_matrix()
    return C if convention == "enu" else C_NED_ENU @ C @ C_FRD_FLU


def increments_to_rates(t_s: np.ndarray, dtheta: np.ndarray, dv: np.ndarray):
    """Angle [rad] and velocity [m/s] increments over (t_{k-1}, t_k] -> average rate [rad/s] and specific force
    [m/s^2] (the ScenarioData convention, core/recording.py). Row 0's interval is unknown: the median step is used.
    Rows whose step is not positive get NaN (rejected later as a bad stamp)."""
    t = np.asarray(t_s, float)
    dt = np.diff(t)
    pos = dt[dt > 0]
    dt0 = float(np.median(pos)) if pos.size else float("nan")
    dt = np.r_[dt0, dt]
    dt = np.where(dt > 0, dt, np.nan)
    return np.asarray(dtheta, float) / dt[:, None], np.asarray(dv, float) / dt[:, None]


def read_table(path) -> dict[str, np.ndarray]:
    """CSV (header row of column names, comma-separated, lines starting with '#' ignored, empty cell = missing)
    or .npz (one 1-D array per column) -> {name: float array}."""
    path = Path(path)
    if not path.is_file():
        raise ImportDataError(f"{path}: no such file")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            cols = {k: np.asarray(z[k], float).ravel() for k in z.files}
    else:
        cols = _read_csv(path)
    lengths = {v.shape[0] for v in cols.values()}
    if len(lengths) != 1:
        raise ImportDataError(f"{path}: columns of different lengths {sorted(lengths)}")
    return cols


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    import csv

    names, rows = None, []
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            for lineno, cells in enumerate(csv.reader(fh), start=1):
                if not cells or not "".join(cells).strip() or cells[0].lstrip().startswith("#"):
                    continue
                cells = [c.strip() for c in cells]
                if names is None:
                    names = cells
                    if len(set(names)) != len(names) or "" in names:
                        raise ImportDataError(f"{path}: line {lineno}: empty or repeated column names")
                    continue
                if len(cells) != len(names):
                    raise ImportDataError(f"{path}: line {lineno}: {len(cells)} cells, header has {len(names)}")
                try:
                    rows.append([float(c) if c else math.nan for c in cells])
                except ValueError:
                    raise ImportDataError(f"{path}: line {lineno}: a cell is not a number") from None
    except UnicodeDecodeError:
        raise ImportDataError(f"{path}: not a UTF-8 text file") from None
    if names is None:
        raise ImportDataError(f"{path}: no header row of column names")
    a = np.array(rows, float).reshape(-1, len(names))
    return {n: a[:, i] for i, n in enumerate(names)}


def _need(cols: dict, names, what: str, path) -> list[np.ndarray]:
    missing = [n for n in names if n not in cols]
    if missing:
        raise ImportDataError(f"{path}: {what} needs column(s) {', '.join(missing)}; found {', '.join(cols)}")
    return [cols[n] for n in names]


def import_table(path, imu: str = "rates", axes: str = "FLU", euler: str = "enu", position_llh=None):
    """Read ``path`` (CSV or .npz, columns above) -> (ScenarioData, report). ``imu``: "rates" or "increments";
    ``axes``: the IMU's axes (C_flu_from_axes); ``euler``: the reference attitude's convention (C_b_n_from_euler);
    ``position_llh``: (lat [deg], lon [deg], h [m]) of a vehicle that does not move, when there is no GNSS."""
    if imu not in IMU_COLUMNS:
        raise ImportDataError(f"imu kind {imu!r}: one of {tuple(IMU_COLUMNS)}")
    C_axes = C_flu_from_axes(axes)
    if euler not in EULER_CONVENTIONS:
        raise ImportDataError(f"Euler convention {euler!r}: one of {EULER_CONVENTIONS}")
    cols = read_table(path)
    (t_all,) = _need(cols, ("t_s",), "the time", path)
    a = np.column_stack(_need(cols, IMU_COLUMNS[imu], f"--imu {imu}", path))
    if imu == "increments":
        w_raw, f_raw = increments_to_rates(t_all, a[:, :3], a[:, 3:])
    else:
        w_raw, f_raw = a[:, :3], a[:, 3:]
    w_all, f_all = w_raw @ C_axes.T, f_raw @ C_axes.T
    rejected: Counter = Counter()
    keep, prev = np.zeros(t_all.shape[0], bool), None
    for k in range(t_all.shape[0]):
        reason = validation.check_stamp(float(t_all[k]), prev) or validation.check_imu(w_all[k], f_all[k])
        if reason:
            rejected[reason] += 1
            continue
        keep[k], prev = True, float(t_all[k])
    if keep.sum() < 2:
        raise ImportDataError(f"{path}: fewer than 2 valid IMU rows (rejected: {dict(rejected)})")
    off_ns = int(round(float(t_all[keep][0]) * 1e9))
    t_s = t_all[keep] - t_all[keep][0]
    report = {"file": str(path), "rows": int(t_all.shape[0]), "valid": int(keep.sum()), "rejected": dict(rejected),
              "imu": imu, "axes": str(axes).upper(), "euler": euler}
    gnss = _gnss(cols, keep, t_s, path, report)
    truth = _reference(cols, keep, t_s, euler, gnss, position_llh, path, report)
    params = {"source": "insalign-import", "file": str(path), "imu": imu, "axes": str(axes).upper(),
              "euler": euler, "stamp_offset_ns": off_ns}
    if truth["C_b_n"] is not None:
        params.update(ref_lat_deg=math.degrees(truth["lat_rad"][0]), ref_lon_deg=math.degrees(truth["lon_rad"][0]),
                      ref_h_m=float(truth["h_m"][0]))
    g_t, g_p, g_R = gnss["t"], gnss["p_e"], gnss["R_e"]
    aux = _vehicle_inputs(cols, keep, t_s, report)
    data = ScenarioData(
        name=Path(path).stem, seed=-1, t0_s=0.0, t_s=t_s, omega_ib_b=w_all[keep], f_ib_b=f_all[keep],
        gnss_t_s=g_t, gnss_p_e=g_p, gnss_R_e=g_R, imu_spec=None,
        gnss_sigma_m=float(np.median(gnss["sigma_h"])) if g_t.size else float("nan"), params=params, **truth, **aux)
    return data, report


VEL_COLUMNS = {"enu": ("vel_e_m_s", "vel_n_m_s", "vel_u_m_s"), "ned": ("vel_north_m_s", "vel_east_m_s", "vel_down_m_s"),
               "course": ("speed_m_s", "course_deg")}
#: wheel speed 1-sigma [m/s] when the table has no sigma_wheel_m_s
WHEEL_DEFAULT_SIGMA_M_S = 0.1


def _vehicle_inputs(cols: dict, keep: np.ndarray, t_s: np.ndarray, report: dict) -> dict:
    """GNSS velocity (ENU, NED or speed + course), wheel speed and dual-antenna heading columns -> the ScenarioData
    fields; a row whose value or sigma is empty or not finite (or a sigma <= 0) has none; counted in the report."""
    out: dict = {}
    kinds = [k for k, names in VEL_COLUMNS.items() if all(n in cols for n in names)]
    if len(kinds) > 1:
        raise ImportDataError(f"GNSS velocity given twice ({' and '.join(kinds)} columns): keep one")
    if kinds:
        a = np.column_stack([cols[n][keep] for n in VEL_COLUMNS[kinds[0]]])
        if kinds[0] == "ned":
            v = a @ C_NED_ENU.T
        elif kinds[0] == "course":  # course from North clockwise -> ENU; no vertical (0 with the horizontal sigma)
            c = np.radians(a[:, 1])
            v = np.column_stack([a[:, 0] * np.sin(c), a[:, 0] * np.cos(c), np.zeros(len(c))])
        else:
            v = a
        s = cols.get("sigma_vel_m_s", np.full(len(keep), np.nan))[keep]
        ok = np.all(np.isfinite(v), 1) & np.isfinite(s) & (s > 0) & (np.linalg.norm(v, axis=1) < 600.0)
        out.update(gnss_vel_t_s=t_s[ok], gnss_vel_n=v[ok], gnss_vel_R_n=s[ok, None, None] ** 2 * np.eye(3))
        report["gnss_velocities"], report["gnss_velocity_columns"] = int(ok.sum()), kinds[0]
    if "wheel_speed_m_s" in cols:
        w = cols["wheel_speed_m_s"][keep]
        s = cols.get("sigma_wheel_m_s", np.full(len(keep), WHEEL_DEFAULT_SIGMA_M_S))[keep]
        ok = np.isfinite(w) & np.isfinite(s) & (s > 0) & (np.abs(w) < 140.0)
        out.update(wheel_t_s=t_s[ok], wheel_speed_m_s=w[ok], wheel_var_m2_s2=s[ok] ** 2)
        report["wheel_speeds"] = int(ok.sum())
    if "gnss_heading_deg" in cols:
        h = cols["gnss_heading_deg"][keep]
        s = cols.get("sigma_heading_deg", np.full(len(keep), np.nan))[keep]
        ok = np.isfinite(h) & np.isfinite(s) & (s > 0) & (s < 180.0)
        yaw = np.remainder(np.radians(90.0 - h[ok]) + np.pi, 2.0 * np.pi) - np.pi
        out.update(heading_t_s=t_s[ok], heading_yaw_rad=yaw, heading_var_rad2=np.radians(s[ok]) ** 2)
        report["gnss_headings"] = int(ok.sum())
    return out


def _gnss(cols: dict, keep: np.ndarray, t_s: np.ndarray, path, report: dict) -> dict:
    out = {"t": np.zeros(0), "p_e": np.zeros((0, 3)), "R_e": np.zeros((0, 3, 3)), "sigma_h": np.zeros(0),
           "llh": np.zeros((0, 3))}
    if not any(n in cols for n in GNSS_COLUMNS):
        report["gnss_fixes"] = 0
        return out
    lat, lon, h, sh = (c[keep] for c in _need(cols, GNSS_COLUMNS, "a GNSS fix", path))
    sv = cols["sigma_v_m"][keep] if "sigma_v_m" in cols else 2.0 * sh
    present = ~(np.isnan(lat) & np.isnan(lon) & np.isnan(h))
    bad: Counter = Counter()
    ok = np.zeros(lat.shape[0], bool)
    for j in np.flatnonzero(present):
        cov = np.diag([sh[j] ** 2, sh[j] ** 2, sv[j] ** 2])
        reason = validation.check_fix(lat[j], lon[j], h[j], cov if np.all(np.isfinite([sh[j], sv[j]])) else
                                      np.full((3, 3), np.nan))
        if reason:
            bad[reason] += 1
        else:
            ok[j] = True
    report["gnss_fixes"], report["gnss_rejected"] = int(ok.sum()), dict(bad)
    la, lo = np.radians(lat[ok]), np.radians(lon[ok])
    x, y, z = pymap3d.geodetic2ecef(la, lo, h[ok], deg=False)
    R_e = np.array([earth.C_n_e(a, b) @ np.diag([s**2, s**2, v**2]) @ earth.C_e_n(a, b)
                    for a, b, s, v in zip(la, lo, sh[ok], sv[ok])]).reshape(-1, 3, 3)
    out.update(t=t_s[ok], p_e=np.column_stack([x, y, z]).reshape(-1, 3), R_e=R_e, sigma_h=sh[ok],
               llh=np.column_stack([la, lo, h[ok]]))
    return out


def _reference(cols, keep, t_s, euler, gnss, position_llh, path, report) -> dict:
    """Reference attitude rows -> truth at the IMU stamps (slerp); position from the fixes or ``position_llh``."""
    from .bag import interp_held, slerp_held, velocity_n_from_positions

    none = dict(C_b_n=None, lat_rad=None, lon_rad=None, h_m=None, v_n=None)
    if not any(n in cols for n in EULER_COLUMNS):
        report["reference_rows"] = 0
        return none
    r, p, y = (np.radians(c[keep]) for c in _need(cols, EULER_COLUMNS, "a reference attitude", path))
    ok = np.isfinite(r) & np.isfinite(p) & np.isfinite(y)
    report["reference_rows"] = int(ok.sum())
    if not ok.any():
        return none
    q = Rotation.from_matrix(C_b_n_from_euler(r[ok], p[ok], y[ok], euler)).as_quat()
    if any(n in cols for n in REF_POSITION_COLUMNS):
        la, lo, hh = (c[keep] for c in _need(cols, REF_POSITION_COLUMNS, "a reference position", path))
        okp = np.isfinite(la) & np.isfinite(lo) & np.isfinite(hh)
        if not okp.any():
            raise ImportDataError(f"{path}: the ref_lat_deg/ref_lon_deg/ref_h_m columns are empty")
        t_p, llh_p = t_s[okp], np.column_stack([np.radians(la[okp]), np.radians(lo[okp]), hh[okp]])
    elif gnss["t"].size:
        t_p, llh_p = gnss["t"], gnss["llh"]
    elif position_llh is not None:
        t_p = t_s[:1]
        llh_p = np.array([[math.radians(position_llh[0]), math.radians(position_llh[1]), float(position_llh[2])]])
    else:
        raise ImportDataError(f"{path}: a reference attitude needs a position: ref_lat_deg.. or GNSS columns, "
                              "or --position LAT LON H")
    lat0, lon0, h0 = llh_p[0]
    e, n, u = pymap3d.geodetic2enu(llh_p[:, 0], llh_p[:, 1], llh_p[:, 2], lat0, lon0, h0, deg=False)
    p_n = interp_held(t_s, t_p, np.column_stack([e, n, u]))
    lat, lon, h = pymap3d.enu2geodetic(p_n[:, 0], p_n[:, 1], p_n[:, 2], lat0, lon0, h0, deg=False)
    C = slerp_held(t_s, t_s[ok], q)
    lat, lon, h = np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float)
    return dict(C_b_n=C, lat_rad=lat, lon_rad=lon, h_m=h, v_n=velocity_n_from_positions(t_s, lat, lon, h))


def table_from_scenario(data: ScenarioData, imu: str = "increments", axes: str = "RFU", euler: str = "ned",
                        gnss: bool = True, reference: bool = True) -> dict[str, np.ndarray]:
    """The columns ``import_table`` reads, from a simulated run (the inverse conversions): examples and tests.
    GNSS columns are filled on the rows of the run's fix stamps (NaN elsewhere)."""
    C_axes = C_flu_from_axes(axes)
    w, f = data.omega_ib_b @ C_axes, data.f_ib_b @ C_axes  # FLU -> the IMU's axes (C is orthonormal)
    cols = {"t_s": np.asarray(data.t_s, float)}
    if imu == "increments":
        dt = np.diff(data.t_s)
        dt = np.r_[np.median(dt), dt][:, None]
        w, f = w * dt, f * dt
    cols.update(zip(IMU_COLUMNS[imu], np.column_stack([w, f]).T))
    if gnss:
        k = np.clip(np.searchsorted(data.t_s, data.gnss_t_s - 1e-9), 0, data.n - 1)
        llh = np.array([earth.ecef_to_geodetic(p) for p in data.gnss_p_e])
        C_en = [earth.C_e_n(a, b) for a, b, _ in llh]
        sig = np.array([np.sqrt(np.diag(C @ R @ C.T)) for C, R in zip(C_en, data.gnss_R_e)])
        for name, vals in zip(("lat_deg", "lon_deg", "h_m", "sigma_h_m", "sigma_v_m"),
                              (np.degrees(llh[:, 0]), np.degrees(llh[:, 1]), llh[:, 2], sig[:, 0], sig[:, 2])):
            col = np.full(data.n, np.nan)
            col[k] = vals
            cols[name] = col
    if reference and data.has_truth:
        C = data.C_b_n if euler == "enu" else C_NED_ENU @ data.C_b_n @ C_FRD_FLU
        ypr = np.degrees(Rotation.from_matrix(C).as_euler("ZYX"))
        cols.update(roll_deg=ypr[:, 2], pitch_deg=ypr[:, 1], yaw_deg=ypr[:, 0], ref_lat_deg=np.degrees(data.lat_rad),
                    ref_lon_deg=np.degrees(data.lon_rad), ref_h_m=np.asarray(data.h_m, float))
    return cols


def write_csv(path, cols: dict[str, np.ndarray], comment: str = "") -> Path:
    """Columns -> CSV (header row, repr() floats: exact; NaN -> empty cell)."""
    path = Path(path)
    names = list(cols)
    lines = [f"# {c}" for c in comment.splitlines()] + [",".join(names)]
    rows = np.column_stack([cols[n] for n in names])
    lines += [",".join("" if math.isnan(x) else repr(float(x)) for x in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path
