#!/usr/bin/env python3
"""Gaussian-sum yaw estimator (insalign_ros/filters/yaw_gsf.py) on simulated and real drives. Not a unit test.

Simulated (sim/scenarios.py, default IMUs, fixes at 1 Hz): car (moving off at 1.8 s), park_drive (drive-off at
90 s), ship (waves, no mean speed), each over seeds x 8 true headings (0, 45, ..., 315 deg), with a GNSS velocity
(0.1 m/s 1-sigma, 1 Hz) and with velocities from the differences of the 1-m fixes only (velocity_from_fixes, fused at
the middle of each interval when the second fix arrives). Time zero of the timings: the first time the true
horizontal speed reaches 5 m/s (ship: t = 0). Printed per case: time to ``valid`` (median, max, never), the |yaw
error| when valid turns on and at the end (median, max over runs), the coverage (|error| <= 3 sigma over the
epochs from 10 s after time zero) and the physical floor sigma_v / V (the course error of one velocity at the cruise
speed: car 15 m/s, park_drive 12 m/s; the ship: over its wave orbital speed).

Real (``/work/shared/data``, skipped when absent): KITTI drives (OXTS RT3003 10-Hz IMU; velocity = the OXTS ENU
velocity at 1 Hz with its vel_accuracy, or the difference of the 1-Hz fixes) against the RT3003's own yaw; and
car_circles_vn100 (VN-100 at 40 Hz, BU-353 1-Hz fixes only, the sensor's x axis to the rear) against the course over
ground + 180 deg.

    nice python benchmarks/yaw_gsf.py --seeds 5            # the table in docs/yaw_gsf.md
    nice python benchmarks/yaw_gsf.py --real-only
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "test"))  # reference_loops.run_on_arrays: the GSF on recorded arrays

from insalign_ros.core import earth  # noqa: E402
from insalign_ros.core.earth import velocity_from_fixes  # noqa: E402
from insalign_ros.filters.yaw_gsf import YawGsf, YawGsfConfig  # noqa: E402
from insalign_ros.io.datasets import shared_data_dir  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402
from reference_loops import run_on_arrays  # noqa: E402

DATA = shared_data_dir(__file__) or Path("../shared/data")
VEL_SIGMA_M_S = 0.1
EXTRA_CFG: dict = {}  # --cfg key=value: YawGsfConfig overrides for every run
SIDE_SLIP_DEG = 3.0  # the optional lateral-velocity constraint of wheeled vehicles (YawGsfConfig.side_slip_sigma_deg)
HEADINGS = np.arange(0.0, 360.0, 45.0)
CASES = {  # name: (duration [s], cruise speed [m/s] for the floor, config overrides)
    "car": (60.0, 15.0, {}),
    "park_drive": (130.0, 12.0, {}),
    "ship": (120.0, None, {"vehicle_moves_along_forward_axis": False}),
}


def fuse_inputs(data, source: str):
    """(vel_t, vel_n, vel_R, arrival) from a ScenarioData: 'vel' its GNSS velocities, 'fix' fix differences."""
    if source == "vel":
        return data.gnss_vel_t_s, data.gnss_vel_n, data.gnss_vel_R_n, None
    ok = np.ones(len(data.gnss_t_s), bool) if data.gnss_valid is None else data.gnss_valid
    t, p, R = data.gnss_t_s[ok], data.gnss_p_e[ok], data.gnss_R_e[ok]
    tm, v, Rv = velocity_from_fixes(t, p, R)
    arrival = tm + 0.5 * np.interp(tm, 0.5 * (t[1:] + t[:-1]), np.diff(t))
    return tm, v, Rv, arrival


def evaluate(out, t_ref, yaw_ref_rad, t_zero):
    """Errors [deg] of a run_on_arrays output against a reference yaw at the arrival stamps."""
    yref = np.interp(out["t_s"], t_ref, np.unwrap(yaw_ref_rad))
    err = np.degrees(earth.wrap_angle_rad(out["yaw_rad"] - yref))
    sig = np.degrees(out["sigma_rad"])
    v = out["valid"] & (out["t_s"] >= t_zero)
    iv = int(np.argmax(v)) if v.any() else None
    after = (out["t_s"] >= t_zero + 10.0) & np.isfinite(err)
    fin = np.flatnonzero(np.isfinite(err))
    return {
        "t_valid_s": out["t_s"][iv] - t_zero if iv is not None else math.nan,
        "err_at_valid_deg": abs(err[iv]) if iv is not None else math.nan,
        "err_final_deg": abs(err[fin[-1]]) if fin.size else math.nan,
        "sigma_final_deg": sig[fin[-1]] if fin.size else math.nan,
        "coverage": float(np.mean(np.abs(err[after]) <= 3 * sig[after])) if after.any() else math.nan,
        "max_err_valid_deg": float(np.max(np.abs(err[out["valid"]]))) if out["valid"].any() else math.nan,
        "err": err, "sig": sig,
    }


def sim_run(name, seed, heading_deg, source, level_truth=False, **cfg):
    dur, _, over = CASES[name]
    kw = {"gnss_vel_sigma_m_s": VEL_SIGMA_M_S} if source == "vel" else {}
    d = make_scenario(name, seed=seed, duration_s=dur, heading_deg=heading_deg, **kw)
    gsf = YawGsf(YawGsfConfig(**{**over, **cfg, **EXTRA_CFG}))
    vt, vn, vR, arr = fuse_inputs(d, source)
    out = run_on_arrays(gsf, d.t_s, d.omega_ib_b, d.f_ib_b, vt, vn, vR, vel_arrival_s=arr,
                        C_b_n_level=d.C_b_n if level_truth else None)
    speed = np.linalg.norm(d.v_n[:, :2], axis=1)
    t_zero = 0.0 if name == "ship" else float(d.t_s[np.argmax(speed >= 5.0)])
    return evaluate(out, d.t_s, earth.rpy_from_C_b_n(d.C_b_n)[:, 2], t_zero)


def summarize(rows):
    tv = np.array([r["t_valid_s"] for r in rows])
    f = lambda k: np.array([r[k] for r in rows])  # noqa: E731
    return {
        "runs": len(rows), "never": int(np.sum(~np.isfinite(tv))),
        "tv_med": float(np.nanmedian(tv)) if np.isfinite(tv).any() else math.nan,
        "tv_max": float(np.nanmax(tv)) if np.isfinite(tv).any() else math.nan,
        "ev_med": float(np.nanmedian(f("err_at_valid_deg"))) if np.isfinite(tv).any() else math.nan,
        "ev_max": float(np.nanmax(f("err_at_valid_deg"))) if np.isfinite(tv).any() else math.nan,
        "ef_med": float(np.median(f("err_final_deg"))), "ef_max": float(np.max(f("err_final_deg"))),
        "sf_med": float(np.median(f("sigma_final_deg"))),
        "cov_min": float(np.nanmin(f("coverage"))), "cov_mean": float(np.nanmean(f("coverage"))),
        "maxv": float(np.nanmax(f("max_err_valid_deg"))) if np.isfinite(f("max_err_valid_deg")).any() else math.nan,
    }


def floor_deg(name, source, d=None):
    sig_v = VEL_SIGMA_M_S if source == "vel" else math.sqrt(2.0) * 1.0  # 1-m fixes 1 s apart
    V = CASES[name][1]
    if V is None:  # ship: the wave orbital speed amplitude (amp 10 m, periods 7 and 6 s)
        V = math.hypot(10.0 * 2 * math.pi / 7.0, 10.0 * 2 * math.pi / 6.0) / math.sqrt(2.0)
    return math.degrees(sig_v / V), V


def sim_table(seeds, names, sources):
    lines = ["| scenario | velocity | side-slip constraint | runs | floor sigma_v/V [deg] | valid after [s] median / "
             "max | never valid | abs(err) at valid [deg] median / max | final abs(err) [deg] median / max | "
             "final sigma [deg] | coverage 3-sigma min / mean | max abs(err) while valid [deg] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        for source in sources:
            for slip in ((0.0, SIDE_SLIP_DEG) if name != "ship" else (0.0,)):
                t0 = time.time()
                rows = [sim_run(name, s, h, source, side_slip_sigma_deg=slip) for s in range(seeds) for h in HEADINGS]
                S = summarize(rows)
                fl, V = floor_deg(name, source)
                src = "GNSS 0.1 m/s" if source == "vel" else "fix differences (1 m)"
                lines.append(f"| {name} | {src} | {_slip(slip)} | {S['runs']} | {fl:.2f} (V {V:.0f} m/s) | "
                             f"{S['tv_med']:.1f} / {S['tv_max']:.1f} | {S['never']} | {S['ev_med']:.2f} / "
                             f"{S['ev_max']:.2f} | {S['ef_med']:.2f} / {S['ef_max']:.2f} | {S['sf_med']:.2f} | "
                             f"{S['cov_min']:.2f} / {S['cov_mean']:.3f} | {S['maxv']:.2f} |")
                print(lines[-1], f"({time.time() - t0:.0f} s)", flush=True)
        if name == "ship":
            for source in sources:
                rows = [sim_run(name, s, h, source, level_truth=True) for s in range(seeds) for h in HEADINGS]
                S = summarize(rows)
                fl, V = floor_deg(name, source)
                src = ("GNSS 0.1 m/s" if source == "vel" else "fix differences (1 m)") + ", level given"
                lines.append(f"| ship | {src} | off (PX4) | {S['runs']} | {fl:.2f} (V {V:.0f} m/s) | "
                             f"{S['tv_med']:.1f} / {S['tv_max']:.1f} | {S['never']} | {S['ev_med']:.2f} / "
                             f"{S['ev_max']:.2f} | {S['ef_med']:.2f} / {S['ef_max']:.2f} | {S['sf_med']:.2f} | "
                             f"{S['cov_min']:.2f} / {S['cov_mean']:.3f} | {S['maxv']:.2f} |")
                print(lines[-1], flush=True)
    return lines


# ----------------------------------------------------------------------------------------------- real data
def kitti_runs(drive, source, **cfg):
    from insalign_ros.io import kitti

    path = DATA / "kitti_raw_oxts_sync" / f"{drive}_oxts"
    if not path.exists():
        return None
    d, _ = kitti.convert_drive(path, gnss_rate_hz=1.0, fill_policy="mark")
    ok = d.imu_valid_mask
    if source == "vel":
        _, v, _ = kitti.read_drive(path)
        gi = kitti.gnss_indices(d.t_s, 1.0, ok)
        acc = v[gi, kitti.IDX["vel_accuracy"]]
        sig = np.where(acc > 0, acc, VEL_SIGMA_M_S)
        vt, vn = d.t_s[gi], d.v_n[gi]
        vR = np.array([np.diag([s**2, s**2, (2 * s) ** 2]) for s in sig])
        arr = None
    else:
        vt, vn, vR, arr = fuse_inputs(d, "fix")
    gsf = YawGsf(YawGsfConfig(**{**cfg, **EXTRA_CFG}))
    out = run_on_arrays(gsf, d.t_s[ok], d.omega_ib_b[ok], d.f_ib_b[ok], vt, vn, vR, vel_arrival_s=arr)
    speed = np.linalg.norm(d.v_n[:, :2], axis=1)
    moving = speed >= 5.0
    t_zero = float(d.t_s[np.argmax(moving)]) if moving.any() else math.nan
    t_move = float(d.t_s[np.argmax(speed >= 0.5)]) if (speed >= 0.5).any() else math.nan
    ev = evaluate(out, d.t_s, earth.rpy_from_C_b_n(d.C_b_n)[:, 2], t_zero)
    ev["t_zero"], ev["t_move"] = t_zero, t_move
    return ev


def car_circles_runs(reference="cog", **cfg):
    from insalign_ros.io import datasets

    path = DATA / "car_circles_vn100"
    if not path.exists():
        return None
    d, cog, ahrs = datasets.read_car_circles(path)
    vt, vn, vR, arr = fuse_inputs(d, "fix")
    # the VN-100's x axis points to the rear (io/datasets.py CAR_MOUNT_YAW_DEG): the car moves along -x
    gsf = YawGsf(YawGsfConfig(**{"forward_axis_b": (-1.0, 0.0, 0.0), **cfg, **EXTRA_CFG}))
    out = run_on_arrays(gsf, d.t_s, d.omega_ib_b, d.f_ib_b, vt, vn, vR, vel_arrival_s=arr)
    ref = (cog if reference == "cog" else ahrs).at(out["t_s"])[:, 2]
    ok = np.isfinite(ref)
    sp = np.linalg.norm(vn[:, :2], axis=1)
    t_zero = float(vt[np.argmax(sp >= 3.0)]) if (sp >= 3.0).any() else 0.0
    ev = evaluate({k: (v[ok] if isinstance(v, np.ndarray) else v) for k, v in out.items()},
                  out["t_s"][ok], np.radians(ref[ok]), t_zero)
    ev["t_zero"] = t_zero
    ev["max_speed"] = float(sp.max())
    return ev


def real_lines(slips=(0.0, SIDE_SLIP_DEG)):
    lines = ["| recording | velocity | side-slip constraint | t first >= 5 m/s [s] | valid after [s] | "
             "abs(err) at valid [deg] | final abs(err) / sigma [deg] | coverage 3-sigma | max abs(err) while valid "
             "[deg] |", "|---|---|---|---|---|---|---|---|---|"]
    for drive in ("2011_10_03_drive_0042", "2011_09_30_drive_0018", "2011_09_30_drive_0020",
                  "2011_09_26_drive_0057"):
        for source in ("vel", "fix"):
            for slip in slips:
                ev = kitti_runs(drive, source, side_slip_sigma_deg=slip)
                if ev is None:
                    print(f"skip {drive}: absent")
                    continue
                src = "OXTS velocity 1 Hz" if source == "vel" else "fix differences 1 Hz"
                lines.append(f"| KITTI {drive[-10:]} | {src} | {_slip(slip)} | {ev['t_zero']:.1f} | "
                             f"{ev['t_valid_s']:.1f} | {ev['err_at_valid_deg']:.2f} | {ev['err_final_deg']:.2f} / "
                             f"{ev['sigma_final_deg']:.2f} | {ev['coverage']:.3f} | {ev['max_err_valid_deg']:.2f} |")
                print(lines[-1], flush=True)
    for slip, ref in ((0.0, "cog"), (0.0, "ahrs"), (SIDE_SLIP_DEG, "cog")):
        ev = car_circles_runs(ref, side_slip_sigma_deg=slip)
        if ev is None:
            break
        rname = "course over ground + 180 deg" if ref == "cog" else "the VN-100's magnetic AHRS"
        lines.append(f"| car_circles_vn100 (ref: {rname}; time zero: 3 m/s) | fix differences "
                     f"1 Hz | {_slip(slip)} | {ev['t_zero']:.1f} | {ev['t_valid_s']:.1f} | "
                     f"{ev['err_at_valid_deg']:.2f} | {ev['err_final_deg']:.2f} / {ev['sigma_final_deg']:.2f} | "
                     f"{ev['coverage']:.3f} | {ev['max_err_valid_deg']:.2f} |")
        print(lines[-1], flush=True)
    return lines


def _slip(slip):
    return f"{slip:.0f} deg" if slip > 0 else "off (PX4)"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--scenarios", default="car,park_drive,ship")
    ap.add_argument("--sources", default="vel,fix")
    ap.add_argument("--real-only", action="store_true")
    ap.add_argument("--sim-only", action="store_true")
    ap.add_argument("--cfg", action="append", default=[], help="YawGsfConfig override key=value (repeatable)")
    a = ap.parse_args(argv)
    for kv in a.cfg:
        k, v = kv.split("=", 1)
        EXTRA_CFG[k] = type(getattr(YawGsfConfig(), k))(v)
    if not a.real_only:
        sim_table(a.seeds, a.scenarios.split(","), a.sources.split(","))
    if not a.sim_only:
        real_lines()


if __name__ == "__main__":
    main()
