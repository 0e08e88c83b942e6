#!/usr/bin/env python3
"""Real-data regression benchmark: every real recording in ../shared/data through the default pipeline, one table.

    nice .venv/bin/python benchmarks/real_data.py [--recordings NAME ...] [--cores CORE ...] [--full-rate]

Each recording goes through the pipeline of ``insalign_ros.align`` with DEFAULT parameters and NO truth (the reference
is stripped from the input and used only here, for evaluation); ``core`` auto (the default) and the in-motion cores.
Per recording and core it prints: the time of the first flag (from the first motion; from the first IMU sample when
the vehicle moves from the start or never moves), the final roll/pitch/yaw error against the reference with its
3-sigma, the coverage of the 3-sigma while the flag is up (fraction of flag-up outputs with |err| <= 3-sigma, per
axis; again with the reference's own 1-sigma added in quadrature: the error measured is the estimate's plus the
reference's), the re-initialisations and whether each was needed (the yaw error just before it outside its 3-sigma: "N";
inside: "n"; no reference: "?"), the flag-up outputs with |yaw err| > 3 deg, and the fraction of the time the flag
is up after its first rise. Every table prints its physical floor (the reference's own accuracy).

Recordings (docs/real_data.md): KITTI 0042, 0016, 0057, 0018, 0020 (io/kitti.py convert_drive, 1-Hz fixes, the
fix sigma the RT3003's pos_accuracy as is, and again floored at 0.5 m), rover_canada and car_circles_vn100
(io/datasets.py). The rover runs with its IMU averaged to 100 Hz and its fixes thinned to 5 Hz unless --full-rate
(the full rates cost ~3x the CPU: see docs/real_data.md).

The run mirrors ``offline.align`` (same SessionConfig, session, ``run_session`` and ``result_from_outputs``) with one
addition: a log callback that records when the session re-initialises (test/test_real_data.py checks that the
outputs equal ``ia.align``'s).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from insalign_ros.core import earth
from insalign_ros.session.flag import AlignedCriteria
from insalign_ros.io import datasets as DS
from insalign_ros.session.config import SessionConfig
from insalign_ros.session.offline import result_from_outputs, run_session
from insalign_ros.session.session import AlignmentSession

KITTI_DRIVES = {"kitti_0042": "2011_10_03_drive_0042_oxts", "kitti_0016": "2011_09_28_drive_0016_oxts",
                "kitti_0057": "2011_09_26_drive_0057_oxts", "kitti_0018": "2011_09_30_drive_0018_oxts",
                "kitti_0020": "2011_09_30_drive_0020_oxts"}
RECORDINGS = (*KITTI_DRIVES, "rover_canada", "car_circles_vn100")
CORES = ("auto", "iekf", "liekf", "ekf", "pi_liekf")
KITTI_SIGMA_FLOOR_M = 0.5
MOTION_SPEED_M_S = 0.3  #: first motion: the fixes move faster than this over MOTION_BASELINE_S
MOTION_BASELINE_S = 2.0
MOTION_RADIUS_M = 0.5
RESTART_KEYS = ("divergence", "fault", "reinit_restarts")  #: session log keys of a re-initialisation
YAW_WRONG_DEG = 3.0


def shared_data_dir() -> Path | None:
    """$INSALIGN_DATA, else ../shared/data next to the clone (io/datasets.shared_data_dir); None when absent."""
    return DS.shared_data_dir(__file__)


@dataclass
class Recording:
    """One input for the pipeline (no truth) and the references to judge it by."""

    label: str
    data: object  # ScenarioData without truth
    refs: list
    first_motion_s: float | None  # None: never moves; == data.t_s[0]: moving from the start
    note: str = ""


def strip_truth(data):
    return replace(data, C_b_n=None, lat_rad=None, lon_rad=None, h_m=None, v_n=None)


def floor_fix_sigma(data, floor_m: float):
    """The fixes' ENU covariances with every standard deviation at least ``floor_m`` (the data's, not a filter's)."""
    R = []
    for p_e, R_e in zip(data.gnss_p_e, data.gnss_R_e):
        lat, lon, _ = earth.ecef_to_geodetic(p_e)
        R_n = earth.C_e_n(lat, lon) @ R_e @ earth.C_n_e(lat, lon)
        s = np.sqrt(np.maximum(np.diag(R_n), floor_m ** 2))
        R.append(earth.C_n_e(lat, lon) @ np.diag(s ** 2) @ earth.C_e_n(lat, lon))
    return replace(data, gnss_R_e=np.array(R), gnss_sigma_m=max(data.gnss_sigma_m, floor_m))


def first_motion_s(data) -> float | None:
    """When the vehicle starts moving, from the fixes alone: the first IMU stamp when the fixes move faster than
    MOTION_SPEED_M_S over the first MOTION_BASELINE_S (moving from the start); else the first fix farther than
    MOTION_RADIUS_M from the mean of the first MOTION_BASELINE_S of fixes with a window of MOTION_BASELINE_S from
    it or before it faster than MOTION_SPEED_M_S (never before the true start: the radius must be left first);
    None when the fixes never move."""
    t, p = data.gnss_t_s, data.gnss_p_e
    if t.shape[0] < 2:
        return None
    j2 = np.searchsorted(t, t + MOTION_BASELINE_S)
    j = np.flatnonzero(j2 < t.shape[0])
    fast = np.zeros(t.shape[0], bool)
    fast[j] = np.linalg.norm(p[j2[j]] - p[j], axis=1) / (t[j2[j]] - t[j]) > MOTION_SPEED_M_S
    if fast[0]:
        return float(data.t_s[0])
    p0 = p[t <= t[0] + MOTION_BASELINE_S].mean(axis=0)
    far = np.linalg.norm(p - p0, axis=1) > MOTION_RADIUS_M
    for k in np.flatnonzero(far):
        if fast[(t >= t[k] - MOTION_BASELINE_S) & (t <= t[k])].any():
            return max(float(t[k]), float(data.t_s[0]))
    return None


def kitti_reference(data) -> DS.AttitudeReference:
    rpy = np.degrees(earth.rpy_from_C_b_n(data.C_b_n))
    return DS.AttitudeReference("RT3003", data.t_s.copy(), rpy, np.array(DS.KITTI_REF_SIGMA_DEG),
                                "OXTS RT3003 GNSS/INS attitude (datasheet 1-sigma)", max_gap_s=2.0)


def decimate_imu(data, k: int):
    """Average ``k`` consecutive IMU samples (each an average over its interval, sim/types.py: the mean of k is the
    average over the k intervals, exactly)."""
    if k <= 1:
        return data
    n = (data.n - 1) // k * k
    w = data.omega_ib_b[1:n + 1].reshape(-1, k, 3).mean(axis=1)
    f = data.f_ib_b[1:n + 1].reshape(-1, k, 3).mean(axis=1)
    t = data.t_s[k:n + 1:k]
    return replace(data, t_s=np.r_[data.t_s[0], t], omega_ib_b=np.vstack([data.omega_ib_b[:1], w]),
                   f_ib_b=np.vstack([data.f_ib_b[:1], f]), imu_valid=None,
                   params={**data.params, "imu_decimation": k})


def thin_fixes(data, step: int):
    if step <= 1:
        return data
    i = np.arange(0, data.gnss_t_s.shape[0], step)
    return replace(data, gnss_t_s=data.gnss_t_s[i], gnss_p_e=data.gnss_p_e[i], gnss_R_e=data.gnss_R_e[i],
                   gnss_valid=None if data.gnss_valid is None else data.gnss_valid[i],
                   params={**data.params, "gnss_thinning": step})


def load(name: str, root: Path, full_rate: bool = False, gnss_velocity: bool = False) -> list[Recording]:
    """The recording(s) of ``name``: KITTI gives two (fix sigma as is, floored at 0.5 m), with the RT3003's
    velocities as a 1-Hz GNSS velocity topic when ``gnss_velocity``."""
    if name in KITTI_DRIVES:
        from insalign_ros.io.kitti import convert_drive

        data, _ = convert_drive(root / "kitti_raw_oxts_sync" / KITTI_DRIVES[name], gnss_rate_hz=1.0,
                                gnss_velocity=gnss_velocity)
        ref, bare = kitti_reference(data), strip_truth(data)
        fm = first_motion_s(bare)
        short = name.split("_")[1]
        sig = np.sqrt(np.array([np.trace(R) for R in bare.gnss_R_e]) / 6.0)  # ~ horizontal sigma (v = 2 h)
        note = f"fix sigma = pos_accuracy, median {np.median(sig):.3f} m (min {sig.min():.3f})"
        if bare.has_gnss_velocity:
            sv = np.sqrt(bare.gnss_vel_R_n[:, 0, 0])
            note += f"; GNSS velocity at every fix, sigma = vel_accuracy, median {np.median(sv):.3f} m/s"
        return [Recording(f"KITTI {short}", bare, [ref], fm, note),
                Recording(f"KITTI {short}, fix sigma >= {KITTI_SIGMA_FLOOR_M} m",
                          floor_fix_sigma(bare, KITTI_SIGMA_FLOOR_M), [ref], fm, "fix sigma floored")]
    if name == "rover_canada":
        data, ref = DS.read_rover_canada(root / "rover_canada")
        note = "IMU 200 Hz, fixes 20 Hz"
        if not full_rate:
            data = thin_fixes(decimate_imu(data, 2), 4)
            note = "IMU averaged to 100 Hz, fixes thinned to 5 Hz"
        return [Recording("rover_canada", data, [ref], first_motion_s(data), note)]
    if name == "car_circles_vn100":
        data, cog, ahrs = DS.read_car_circles(root / "car_circles_vn100")
        return [Recording("car_circles_vn100", data, [cog, ahrs], first_motion_s(data), "IMU ~40 Hz, fixes 1 Hz")]
    raise ValueError(f"unknown recording {name!r}; one of {RECORDINGS}")


@dataclass
class Run:
    core: str
    result: object
    restarts: list = field(default_factory=list)  # (t [s], log key, text)
    wall_s: float = 0.0
    cpu_s: float = 0.0


def run(data, core: str, vehicle: str = "unknown", criteria: dict | None = None,
        core_params: dict | None = None) -> Run:
    """``offline.align(data, core=core)`` with the defaults (and ``vehicle``, ``core_params``), plus the
    re-initialisations the session logs."""
    cfg = SessionConfig.from_dict({"core": core, "vehicle": vehicle})
    events: list = []
    session = None

    def log(level, key, text):
        if key in RESTART_KEYS:
            events.append((session.processed_t if session.processed_t is not None else float("nan"), key, text))

    t0, c0 = time.time(), time.process_time()
    session = AlignmentSession(cfg, core_params, AlignedCriteria(**(criteria or {})), log=log)
    try:
        outs = run_session(session, data)
        res = result_from_outputs(cfg.core, outs, session, data)
    finally:
        session.close()
    return Run(core, res, events, time.time() - t0, time.process_time() - c0)


def evaluate(r: Run, ref: DS.AttitudeReference, t_motion_s: float | None, t_start_s: float) -> dict:
    """The table's numbers for one run against one reference (see the module docstring)."""
    res = r.result
    t, up, s3 = res.t_s, np.asarray(res.aligned, bool), np.minimum(res.sigma3_deg, 180.0)
    err = np.degrees(earth.wrap_angle_rad(np.radians(res.rpy_deg - ref.at(t))))
    has = np.isfinite(err)
    t_from = t_motion_s if t_motion_s is not None else t_start_s
    out: dict = {"t_flag_s": float("nan"), "final_err": np.full(3, np.nan), "final_s3": np.full(3, np.nan),
                 "coverage": np.full(3, np.nan), "coverage_ref": np.full(3, np.nan), "n_up": int(up.sum()),
                 "up_wrong": 0, "up_fraction": float("nan")}
    # against an imperfect reference the error is the estimate's plus the reference's: the 3-sigma of their sum
    fl = np.where(np.isfinite(ref.floor_deg), ref.floor_deg, 0.0)
    s3_ref = 3.0 * np.sqrt((s3 / 3.0) ** 2 + fl ** 2)
    iu = np.flatnonzero(up)
    if iu.size:
        out["t_flag_s"] = float(t[iu[0]] - t_from)
        tt = np.r_[t[iu[0]:], t[-1]]
        out["up_fraction"] = float(np.sum(np.diff(tt) * up[iu[0]:]) / max(t[-1] - t[iu[0]], 1e-9)) \
            if t[-1] > t[iu[0]] else 1.0
    for i in range(3):
        k = np.flatnonzero(has[:, i])
        if k.size:
            out["final_err"][i], out["final_s3"][i] = err[k[-1], i], s3[k[-1], i]
        m = up & has[:, i]
        if m.any():
            out["coverage"][i] = float(np.mean(np.abs(err[m, i]) <= s3[m, i]))
            out["coverage_ref"][i] = float(np.mean(np.abs(err[m, i]) <= s3_ref[m, i]))
    out["up_wrong"] = int(np.sum(up & has[:, 2] & (np.abs(err[:, 2]) > YAW_WRONG_DEG)))
    out["up_with_ref"] = int(np.sum(up & has[:, 2]))
    out["max_yaw_up"] = float(np.max(np.abs(err[up & has[:, 2], 2]))) if np.any(up & has[:, 2]) else 0.0
    needed = []
    for tr, _, _ in r.restarts:
        k = np.flatnonzero((t < tr) & has[:, 2])
        needed.append("?" if k.size == 0 else ("N" if abs(err[k[-1], 2]) > s3[k[-1], 2] else "n"))
    out["restarts"] = needed
    return out


def _f(x, fmt="{:+.2f}"):
    return "-" if not np.isfinite(x) else fmt.format(x)


def table(rec: Recording, runs: list[Run], ref: DS.AttitudeReference) -> str:
    t0 = float(rec.data.t_s[0])
    fm = rec.first_motion_s
    when = ("never moves: times from the first IMU sample" if fm is None else
            "moving from the start: times from the first IMU sample" if fm <= t0 + 0.5 else
            f"first motion at {fm - t0:.1f} s after the first IMU sample: times from it")
    fl = ref.floor_deg
    head = (f"{rec.data.t_s[-1] - t0:.0f} s, {rec.data.n} IMU samples, {rec.data.gnss_t_s.shape[0]} fixes; "
            f"{rec.note}; {when}. Reference: {ref.note}. Physical floor (reference 1-sigma) roll/pitch/yaw: "
            f"{' / '.join('unknown' if not np.isfinite(x) else f'{x:.2f}' for x in fl)} deg.")
    lines = [f"### {rec.label} vs {ref.name}", "", head, "",
             ("| core | first flag [s] | final err r/p/y [deg] | its 3-sigma [deg] | 3-sigma coverage r/p/y (flag up) "
              "| with the reference's floor | restarts (needed) | flag up, abs(yaw err) > 3 deg | flag up after first rise "
              "| CPU [s] |"),
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        e = evaluate(r, ref, fm, t0)
        fe = " / ".join(_f(x) for x in e["final_err"])
        s3 = " / ".join(_f(x, "{:.2f}") for x in e["final_s3"])
        cov = " / ".join(_f(x, "{:.2f}") for x in e["coverage"]) if e["n_up"] else "-"
        cov_ref = " / ".join(_f(x, "{:.2f}") for x in e["coverage_ref"]) if e["n_up"] else "-"
        rs = f"{len(e['restarts'])} ({''.join(e['restarts'])})" if e["restarts"] else "0"
        lines.append(f"| {r.core} | {_f(e['t_flag_s'], '{:.1f}') if e['n_up'] else 'never'} | {fe} | {s3} | {cov} "
                     f"| {cov_ref} | {rs} | {e['up_wrong']} of {e['up_with_ref']} | {_f(e['up_fraction'], '{:.2f}')} "
                     f"| {r.cpu_s:.1f} |")
    for r in runs:
        if r.core == "auto" and r.result.outputs:
            lines += ["", f"auto's last status: {r.result.outputs[-1].reason}"]
            c = r.result.counters
            if c.get("nhc_accepted", 0) + c.get("nhc_rejected", 0):
                lines.append(f"non-holonomic constraint: {c['nhc_accepted']} accepted, {c['nhc_rejected']} rejected, "
                             f"switched off {c.get('nhc_switched_off', 0)} times"
                             + (" (vehicle found not to fit: off for the rest of the run)"
                                if c.get("nhc_misfit", 0) else ""))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None, help="the shared data directory (default: ../shared/data)")
    ap.add_argument("--recordings", nargs="+", default=list(RECORDINGS), choices=RECORDINGS)
    ap.add_argument("--cores", nargs="+", default=list(CORES))
    ap.add_argument("--full-rate", action="store_true", help="rover_canada at 200 Hz IMU and 20 Hz fixes")
    ap.add_argument("--no-sigma-floor", action="store_true", help="KITTI: skip the 0.5-m fix-sigma variant")
    ap.add_argument("--gnss-velocity", action="store_true",
                    help="KITTI: the RT3003's velocities as a GNSS velocity topic at the fixes (1 Hz)")
    ap.add_argument("--vehicle", default="unknown", help="SessionConfig.vehicle (default: unknown)")
    ap.add_argument("--criterion", action="append", default=[], metavar="NAME=VALUE",
                    help="an aligned-flag criterion other than its default (session/flag.py), e.g. hold_s=2")
    args = ap.parse_args(argv)
    criteria = {k: float(v) for k, v in (c.split("=", 1) for c in args.criterion)}
    root = Path(args.data) if args.data else shared_data_dir()
    if root is None or not root.is_dir():
        print(f"SKIP: the shared data directory is absent ({root or '../shared/data'})")
        return 0
    t_all, c_all = time.time(), time.process_time()
    for name in args.recordings:
        try:
            recs = load(name, root, args.full_rate, args.gnss_velocity)
        except (OSError, ValueError) as exc:
            print(f"SKIP {name}: {exc}")
            continue
        if args.no_sigma_floor:
            recs = recs[:1]
        for rec in recs:
            runs = [run(rec.data, c, args.vehicle, criteria) for c in args.cores]
            for ref in rec.refs:
                print(table(rec, runs, ref), "\n", flush=True)
    print(f"total: {time.time() - t_all:.0f} s wall, {time.process_time() - c_all:.0f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
