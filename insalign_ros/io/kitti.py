"""KITTI raw OXTS (RT3003) drive -> ScenarioData (then io/bag.write_bag): see docs/bag_contract.md, "KITTI".

Layouts: a drive's ``oxts/`` directory, or the directory itself, holding ``timestamps.txt`` and
``data/NNNNNNNNNN.txt`` (one line of 30 space-separated fields per sample). The same layout serves the 10 Hz
*synced* and the ~100 Hz *extract* downloads; the rate is estimated from the stamps.

Field mapping (dataformat.txt; indices 0..29):
  lat lon alt (0-2)  -> truth position and GNSS fixes (WGS84 deg; alt taken as ellipsoidal height, see docs)
  roll pitch yaw (3-5) -> truth C_b_n = Rz(yaw) Ry(pitch) Rx(roll), body FLU -> ENU, yaw 0 = East, CCW
  vn ve vu (6, 7, 10) -> truth v_n = (ve, vn, vu) ENU
  ax ay az (11-13)   -> body specific force f_ib_b (vehicle x fwd, y left, z up) [m/s^2]
  wx wy wz (17-19)   -> body angular rate omega_ib_b [rad/s]
  pos_accuracy (23)  -> GNSS 1-sigma: horizontal = pos_accuracy, vertical = 2 * pos_accuracy, when > 0;
                        else DEFAULT_SIGMA_H_M / DEFAULT_SIGMA_V_M
  vel_accuracy (24)  -> with ``gnss_velocity``: a GNSS velocity (ve, vn, vu) at each fix, 1-sigma horizontal =
                        vel_accuracy, vertical = 2 * vel_accuracy, when > 0; else DEFAULT_SIGMA_VEL_M_S
af/al/au and wf/wl/wu are NOT used: they are resolved in the vehicle's tangent-plane frame (forward and left
parallel to the Earth surface, up along the local vertical), not in the body frame the IMU measures in.

Fill rows: the RT3003 writes rows with posmode/velmode/orimode = -1 where it had no measurement; every field of
such a row is an exact linear interpolation (by index) of the rows around the block. ``fill_rows`` finds them by
the mode flags and, independently, by second differences at rounding level across every float field (a sensor
row never is one: the smallest relative second difference of a real row in the shared drives is 2e-3).
``convert_drive(fill_rows=...)``: "mark" (default) keeps them with ``imu_valid``/``gnss_valid`` False (the bag's
``_invalid`` topics), "drop" removes them (a gap), "keep" passes them as data (the report still counts them).

Robustness: a missing timestamps.txt or data/ is an error (KittiError); a line with != 30 fields, a non-finite
field, an unparsable or missing stamp, a duplicate or non-monotonic stamp, or a missing data file drops that
sample and is counted in the report (never silently). Stamps are KITTI's local time strings, used as-is
(offset from the first stamp; the absolute first stamp goes into the bag as stamp_offset).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np
import pymap3d

from ..core import earth
from ..core.recording import ScenarioData
from . import validation

N_FIELDS = 30
FIELDS = ("lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu pos_accuracy "
          "vel_accuracy navstat numsats posmode velmode orimode").split()
IDX = {n: i for i, n in enumerate(FIELDS)}
DEFAULT_SIGMA_H_M = 5.0  #: no pos_accuracy: stand-alone GPS-class horizontal 1-sigma [m]
DEFAULT_SIGMA_VEL_M_S = 0.1  #: no vel_accuracy: a receiver's Doppler velocity horizontal 1-sigma [m/s]
DEFAULT_SIGMA_V_M = 10.0  #: [m]; vertical GNSS error is typically about twice the horizontal one
MAX_GAP_FACTOR = 1.5  #: a step longer than 1.5 median steps is reported as a gap
MODE_FIELDS = ("posmode", "velmode", "orimode")
FILL_MODE = -1  #: posmode/velmode/orimode of a fill row
FILL_FIELDS = slice(0, IDX["vel_accuracy"] + 1)  #: the float fields (lat .. vel_accuracy) a fill interpolates
FILL_REL_TOL = 1e-11  #: |second difference| <= tol * (|v_k-1| + |v_k| + |v_k+1|) + FILL_ABS_TOL, every field
FILL_ABS_TOL = 1e-13
IMU_FIELDS = [IDX[n] for n in ("ax", "ay", "az", "wx", "wy", "wz")]
FILL_POLICIES = ("mark", "drop", "keep")


class KittiError(ValueError):
    """The drive cannot be converted (message says why)."""


def _oxts_dir(drive_dir: Path) -> Path:
    drive_dir = Path(drive_dir)
    for cand in (drive_dir / "oxts", drive_dir):
        if (cand / "timestamps.txt").exists() or (cand / "data").is_dir():
            return cand
    raise KittiError(f"{drive_dir}: neither {drive_dir}/oxts nor {drive_dir} holds timestamps.txt or data/")


def parse_stamp(s: str) -> int:
    """'YYYY-MM-DD HH:MM:SS.fffffffff' -> integer ns (numpy datetime64, no time-zone shift)."""
    s = s.strip()
    if not s:
        raise ValueError("empty")
    return int(np.datetime64(s.replace(" ", "T"), "ns").astype(np.int64))


def read_drive(drive_dir, progress: bool = False):
    """Parse a drive. Returns (stamps_ns (N,), values (N, 30), report) for the valid samples."""
    d = _oxts_dir(Path(drive_dir))
    ts_file, data_dir = d / "timestamps.txt", d / "data"
    if not ts_file.exists():
        raise KittiError(f"{d}: missing timestamps.txt (needed for the sample times)")
    if not data_dir.is_dir():
        raise KittiError(f"{d}: missing data/ directory")
    lines = ts_file.read_text().splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    files = sorted(data_dir.glob("*.txt"))
    rejected: Counter = Counter()
    notes: list[str] = []
    if len(files) != len(lines):
        notes.append(f"{len(lines)} timestamps but {len(files)} data files")
    it = range(max(len(lines), len(files)))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=f"reading {d}", unit="line")
    stamps, rows = [], []
    prev = None
    for k in it:
        if k >= len(lines):
            rejected["data file without timestamp"] += 1
            continue
        f = data_dir / f"{k:010d}.txt"
        if not f.exists():
            rejected["missing data file"] += 1
            continue
        try:
            ns = parse_stamp(lines[k])
        except ValueError:
            rejected["unparsable or missing timestamp"] += 1
            continue
        parts = f.read_text().split()
        if len(parts) != N_FIELDS:
            rejected[f"line with {len(parts)} fields (!= {N_FIELDS})"] += 1
            continue
        try:
            v = np.array([float(x) for x in parts])
        except ValueError:
            rejected["unparsable field"] += 1
            continue
        if not np.all(np.isfinite(v)):
            rejected["non-finite field"] += 1
            continue
        reason = validation.check_stamp(ns * 1e-9, None if prev is None else prev * 1e-9)
        reason = reason or validation.check_imu(v[[IDX["wx"], IDX["wy"], IDX["wz"]]],
                                                v[[IDX["ax"], IDX["ay"], IDX["az"]]])
        reason = reason or validation.check_fix(v[0], v[1], v[2])
        if reason:
            rejected[reason] += 1
            continue
        stamps.append(ns), rows.append(v)
        prev = ns
    if len(rows) < 2:
        raise KittiError(f"{d}: fewer than 2 valid samples (rejected: {dict(rejected)}; {'; '.join(notes)})")
    stamps_a = np.array(stamps, dtype=np.int64)
    dt = np.diff(stamps_a) * 1e-9
    med = float(np.median(dt))
    gaps = int(np.sum(dt > MAX_GAP_FACTOR * med))
    report = {"dir": str(d), "lines": len(lines), "files": len(files), "valid": len(rows),
              "rejected": dict(rejected), "notes": notes, "rate_hz": 1.0 / med, "gaps": gaps,
              "max_step_s": float(dt.max())}
    if gaps:
        notes.append(f"{gaps} gap(s) longer than {MAX_GAP_FACTOR} x the median step {med:.4f} s "
                     f"(longest {dt.max():.3f} s)")
    return stamps_a, np.array(rows), report


def fill_rows(values: np.ndarray):
    """Rows that are fills, not measurements. Returns (fill, by_mode, by_interpolation), each (N,) bool.

    by_mode: any of posmode/velmode/orimode == -1. by_interpolation: an interior row whose every float field
    (lat .. vel_accuracy) is the mean of its neighbours to rounding (FILL_REL_TOL), while the IMU fields are not
    constant across the three rows (a noise-free simulated straight run would otherwise look like a fill).
    A fill at either end of the file can only be found by its mode.
    """
    v = np.asarray(values, float)
    n = v.shape[0]
    by_mode = np.any(v[:, [IDX[m] for m in MODE_FIELDS]] == FILL_MODE, axis=1)
    by_interp = np.zeros(n, bool)
    if n >= 3:
        a, b, c = v[:-2], v[1:-1], v[2:]
        f = FILL_FIELDS
        d2 = np.abs(c[:, f] - 2.0 * b[:, f] + a[:, f])
        tol = FILL_REL_TOL * (np.abs(a[:, f]) + np.abs(b[:, f]) + np.abs(c[:, f])) + FILL_ABS_TOL
        moving = np.any(np.abs(c[:, IMU_FIELDS] - a[:, IMU_FIELDS]) > 1e-6 * (1.0 + np.abs(b[:, IMU_FIELDS])), axis=1)
        by_interp[1:-1] = np.all(d2 <= tol, axis=1) & moving
    return by_mode | by_interp, by_mode, by_interp


def blocks(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in ``mask`` as inclusive (first, last) index pairs."""
    m = np.r_[False, np.asarray(mask, bool), False].astype(np.int8)
    starts, ends = np.flatnonzero(np.diff(m) == 1), np.flatnonzero(np.diff(m) == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def gnss_indices(t_s: np.ndarray, gnss_rate_hz: float, valid: np.ndarray | None = None) -> np.ndarray:
    """One sample per 1/gnss_rate_hz window from t_s[0]: the first valid one (``valid``, default all), else the
    window's first sample. gnss_rate_hz <= 0 keeps every sample."""
    if gnss_rate_hz <= 0:
        return np.arange(t_s.shape[0])
    win = np.floor((t_s - t_s[0]) * gnss_rate_hz + 1e-6).astype(np.int64)
    ok = np.ones(t_s.shape[0], bool) if valid is None else np.asarray(valid, bool)
    # sort key: window, then invalid after valid, then index -> the first of each window is the pick
    order = np.lexsort((np.arange(t_s.shape[0]), ~ok, win))
    w_sorted = win[order]
    return np.sort(order[np.r_[True, w_sorted[1:] != w_sorted[:-1]]])


def convert_drive(drive_dir, gnss_rate_hz: float = 1.0, progress: bool = False, fill_policy: str = "mark",
                  gnss_velocity: bool = False):
    """KITTI drive -> (ScenarioData with truth, report). The IMU values are the RT3003's instantaneous outputs
    at each stamp (not averages over the preceding interval as the simulators produce; see docs).

    gnss_velocity: also a GNSS velocity at each valid fix (the RT3003's ve, vn, vu with its vel_accuracy), as a
    receiver's velocity topic would give it (the RT3003's is its GNSS/INS velocity: smoother than a receiver's).

    fill_policy: what to do with fill rows (``fill_rows``): "mark" (imu_valid/gnss_valid False), "drop", "keep".
    The report counts them: fill_rows, fill_by_mode, fill_by_interpolation, fill_blocks [(first, last, seconds)]
    (indices among the valid rows read).
    """
    if fill_policy not in FILL_POLICIES:
        raise KittiError(f"fill policy must be one of {FILL_POLICIES}, got {fill_policy!r}")
    stamps, v, report = read_drive(drive_dir, progress=progress)
    fill, by_mode, by_interp = fill_rows(v)
    t_all = (stamps - stamps[0]) * 1e-9
    report.update(fill_rows=int(fill.sum()), fill_by_mode=int(by_mode.sum()), fill_by_interpolation=int(by_interp.sum()),
                  fill_policy=fill_policy,
                  fill_blocks=[(a, b, float(t_all[min(b + 1, len(t_all) - 1)] - t_all[max(a - 1, 0)]))
                               for a, b in blocks(fill)])
    if fill_policy == "drop" and fill.any():
        if fill.all():
            raise KittiError(f"{drive_dir}: every row is a fill row: nothing to convert")
        stamps, v, fill = stamps[~fill], v[~fill], fill[~fill]
    valid = ~fill if fill_policy == "mark" else np.ones(len(stamps), bool)
    t_s = (stamps - stamps[0]) * 1e-9
    lat, lon, alt = np.radians(v[:, 0]), np.radians(v[:, 1]), v[:, 2]
    rpy = v[:, 3:6]
    from scipy.spatial.transform import Rotation

    C_b_n = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix()
    v_n = np.column_stack([v[:, IDX["ve"]], v[:, IDX["vn"]], v[:, IDX["vu"]]])
    omega = v[:, [IDX["wx"], IDX["wy"], IDX["wz"]]]
    f = v[:, [IDX["ax"], IDX["ay"], IDX["az"]]]
    gi = gnss_indices(t_s, gnss_rate_hz, valid)
    x, y, z = pymap3d.geodetic2ecef(lat[gi], lon[gi], alt[gi], deg=False)
    acc = v[gi, IDX["pos_accuracy"]]
    sig_h = np.where(acc > 0, acc, DEFAULT_SIGMA_H_M)
    sig_v = np.where(acc > 0, 2.0 * acc, DEFAULT_SIGMA_V_M)
    R_e = np.array([earth.C_n_e(a, b) @ np.diag([sh**2, sh**2, sv**2]) @ earth.C_e_n(a, b)
                    for a, b, sh, sv in zip(lat[gi], lon[gi], sig_h, sig_v)])
    report["gnss_fixes"] = int(gi.shape[0])
    vel = {}
    if gnss_velocity:
        vi = gi[valid[gi]]
        sv = np.where(v[vi, IDX["vel_accuracy"]] > 0, v[vi, IDX["vel_accuracy"]], DEFAULT_SIGMA_VEL_M_S)
        vel = dict(gnss_vel_t_s=t_s[vi], gnss_vel_n=v_n[vi],
                   gnss_vel_R_n=np.array([np.diag([s * s, s * s, 4.0 * s * s]) for s in sv]).reshape(-1, 3, 3))
        report["gnss_velocities"] = int(vi.shape[0])
    report["gnss_default_sigma"] = int(np.sum(acc <= 0))
    params = {"source": "kitti_oxts", "drive": str(Path(drive_dir)), "ref_lat_deg": float(v[0, 0]),
              "ref_lon_deg": float(v[0, 1]), "ref_h_m": float(v[0, 2]), "stamp_offset_ns": int(stamps[0]),
              "gnss_rate_hz": float(gnss_rate_hz), "imu_rate_hz": report["rate_hz"], "fill_policy": fill_policy,
              "fill_rows": report["fill_rows"]}
    data = ScenarioData(
        name=f"kitti:{Path(drive_dir).resolve().name}", seed=-1, t0_s=0.0, t_s=t_s, omega_ib_b=omega, f_ib_b=f,
        C_b_n=C_b_n, lat_rad=lat, lon_rad=lon, h_m=alt, v_n=v_n, gnss_t_s=t_s[gi],
        gnss_p_e=np.column_stack([x, y, z]), gnss_R_e=R_e, imu_spec=None,
        gnss_sigma_m=float(np.median(sig_h)), params=params, imu_valid=None if valid.all() else valid,
        gnss_valid=None if valid[gi].all() else valid[gi], **vel)
    return data, report


def format_report(rep: dict) -> str:
    s = (f"{rep['dir']}: {rep['valid']} valid of {rep['lines']} timestamps / {rep['files']} files, "
         f"rate {rep['rate_hz']:.2f} Hz, {rep.get('gnss_fixes', 0)} GNSS fixes")
    if rep["rejected"]:
        s += "\n  rejected: " + validation.format_counts(rep["rejected"])
    if rep.get("fill_rows"):
        what = {"mark": "marked invalid (bag: /imu/data_invalid, /gps/fix_invalid)", "drop": "dropped (gaps)",
                "keep": "KEPT AS DATA (--fill-rows keep)"}[rep["fill_policy"]]
        s += (f"\n  warning: {rep['fill_rows']} fill row(s) (mode -1: {rep['fill_by_mode']}, exact interpolation of "
              f"neighbours: {rep['fill_by_interpolation']}) in {len(rep['fill_blocks'])} block(s): "
              + ", ".join(f"rows {a}-{b} ({dt:.1f} s)" for a, b, dt in rep["fill_blocks"]) + f"; {what}")
    elif "fill_rows" in rep:
        s += "\n  fill rows: 0"
    for n in rep["notes"]:
        s += "\n  warning: " + n
    if rep.get("gnss_default_sigma"):
        s += f"\n  warning: {rep['gnss_default_sigma']} fix(es) without pos_accuracy: default sigma used"
    return s


def write_drive(path, t_abs_ns: np.ndarray, values: np.ndarray) -> Path:
    """Write a KITTI-format oxts directory (timestamps.txt, data/*.txt, dataformat.txt): test fixtures."""
    path = Path(path)
    (path / "data").mkdir(parents=True, exist_ok=True)
    (path / "dataformat.txt").write_text("\n".join(FIELDS) + "\n")
    stamps = [str(np.datetime64(int(ns), "ns")).replace("T", " ") for ns in t_abs_ns]
    (path / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    for k, row in enumerate(values):
        (path / "data" / f"{k:010d}.txt").write_text(" ".join(repr(float(x)) if i < 25 else str(int(x))
                                                              for i, x in enumerate(row)) + "\n")
    return path


def oxts_rows_from_scenario(data: ScenarioData, pos_accuracy_m: float = 0.02) -> np.ndarray:
    """The 30 OXTS fields of a simulated run (error-free IMU if present): the test fixture's source."""
    from scipy.spatial.transform import Rotation

    n = data.n
    rpy = Rotation.from_matrix(data.C_b_n).as_euler("ZYX")[:, ::-1]
    w = data.omega_ib_b_true if data.omega_ib_b_true is not None else data.omega_ib_b
    f = data.f_ib_b_true if data.f_ib_b_true is not None else data.f_ib_b
    Rz = Rotation.from_euler("z", -rpy[:, 2:3])  # ENU -> heading frame (forward-left-up, tangent plane)
    C_t_b = (Rz * Rotation.from_matrix(data.C_b_n)).as_matrix()  # body -> tangent plane
    vt = Rz.apply(data.v_n)
    out = np.zeros((n, N_FIELDS))
    out[:, 0], out[:, 1], out[:, 2] = np.degrees(data.lat_rad), np.degrees(data.lon_rad), data.h_m
    out[:, 3:6] = rpy
    out[:, 6], out[:, 7], out[:, 8], out[:, 9], out[:, 10] = data.v_n[:, 1], data.v_n[:, 0], vt[:, 0], vt[:, 1], \
        data.v_n[:, 2]
    out[:, 11:14] = f
    out[:, 14:17] = np.einsum("nij,nj->ni", C_t_b, f)
    out[:, 17:20] = w
    out[:, 20:23] = np.einsum("nij,nj->ni", C_t_b, w)
    out[:, 23], out[:, 24] = pos_accuracy_m, 0.02
    out[:, 25:] = (4, 9, 4, 4, 4)
    return out
