"""core: auto (issue 14): Monte Carlo on park_drive (MEMS) and park_drive_navgrade, and KITTI drives without truth.

Monte Carlo: ``--runs`` runs per IMU grade, random heading U(-180, 180) deg and park length U(``--park-min``,
``--park-max``) s, ``--drive`` s of driving after it; every run seeded (seed = run index). Per run: outputs with the
flag up while |yaw error| > the flag's bound (``AlignedCriteria.yaw_3sigma_deg``, 2.5 deg), the time from the
drive-off to the flag (navgrade: the flag may rise while parked), level and yaw error at the end of the park against
2x the b_acc/g and the azimuth floors, and the status at the end of the park.

The simulated runs use the IMU grade matching the simulated IMU (``SCENARIO_IMU_GRADE``: industrial_mems,
navigation). KITTI (``--kitti``): ``core auto`` from the sensors (no truth init, no guess) with the default grade
(unknown_mems), the states over time and the yaw error against the RT3003.

    python benchmarks/auto_mode_mc.py --runs 25 --workers 2
    python benchmarks/auto_mode_mc.py --runs 0 --kitti 2011_09_26_drive_0057_oxts 2011_09_30_drive_0018_oxts
    python benchmarks/auto_mode_mc.py --runs 0 --dsd-seeds 0 1 2
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sweep  # noqa: E402

D2R = math.pi / 180.0
FLAG_YAW_DEG = 2.5  # AlignedCriteria().yaw_3sigma_deg (the flag's bound)


def one_run(name: str, seed: int, heading_deg: float, park_s: float, drive_s: float) -> dict:
    import insalign_ros as ia
    from insalign_ros.core import earth
    from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE
    from insalign_ros.filters.registry import resolve_core_params
    from insalign_ros.session.auto import AutoConfig
    from insalign_ros.sim.scenarios import make_scenario

    grade = SCENARIO_IMU_GRADE[name]  # the preset matching the simulated IMU
    d = make_scenario(name, seed=seed, duration_s=park_s + drive_s, park_s=park_s, heading_deg=heading_deg)
    r = ia.align(d, core="auto", imu_grade=grade)
    acfg = AutoConfig.from_dict(resolve_core_params(grade, "auto"))
    t = r.t_s
    k = int(np.flatnonzero(t < park_s - 0.3)[-1])
    up = np.flatnonzero(r.aligned)
    first_up = float(t[up[0]]) if up.size else math.nan
    after = np.flatnonzero(r.aligned & (t >= park_s))
    states = [o.estimate.reason.split(":")[0] for o in r.outputs]
    return dict(
        name=name, seed=seed, heading_deg=heading_deg, park_s=park_s,
        flag_bad=int(np.sum(r.aligned & (np.abs(r.rpy_err_deg[:, 2]) > FLAG_YAW_DEG))),
        first_up_s=first_up, up_after_motion_s=float(t[after[0]] - park_s) if after.size else math.nan,
        up_at_end_of_park=bool(r.aligned[k]),
        level_err_deg=float(np.max(np.abs(r.rpy_err_deg[k, :2]))), level_floor_deg=acfg.level_floor_rad() / D2R,
        # this run's own floor: its drawn horizontal accelerometer bias over g (body x, y ~ level axes when parked)
        level_floor_run_deg=float(np.max(np.abs(d.bias_acc_b[:2]))) / 9.80665 / D2R,
        yaw_err_park_deg=float(abs(r.rpy_err_deg[k, 2])),
        az_floor_deg=acfg.azimuth_floor_rad(float(d.lat_rad[0])) / D2R,
        # this run's own azimuth floor (its drawn gyro bias, East component at the end of the park) and the ARW limit
        # of gyrocompassing over the whole park, ARW / (omega_ie cos lat sqrt(T))
        az_floor_run_deg=float(abs((d.C_b_n[int(np.searchsorted(d.t_s, park_s - 1.0))] @ d.bias_gyro_b)[0]))
        / (earth.OMEGA_IE_RAD_S * math.cos(float(d.lat_rad[0]))) / D2R,
        arw_limit_deg=acfg.gyro_arw_deg_sqrt_h / 60.0 / (earth.OMEGA_IE_RAD_S * math.cos(float(d.lat_rad[0]))
                                                          * math.sqrt(park_s)),
        **_gyrocompass_limits(d, park_s, acfg.acc_vrw_m_s_sqrt_h),
        status_park=r.outputs[k].status.value, state_park=states[k],
        yaw_err_end_deg=float(abs(r.rpy_err_deg[-1, 2])), final_state=states[-1],
        resets=r.counters["time_resets"] + r.counters["core_faults"] + r.counters["divergences"])


def _gyrocompass_limits(d, park_s: float, vrw_m_s_sqrt_h: float) -> dict:
    """Two more references for the heading at the end of the park (navgrade, where the gyrocompass claims it).

    ``ideal_yaw_park_deg``: the heading error of an ideal gyrocompass on this run's own sensor errors: the East
    component (true attitude) of the gyro error (bias and noise) averaged over the park, over omega_ie cos lat; a
    perfect level and a perfect compensation of the car's rocking are assumed, so no estimator on these samples
    can be expected to do better on average.
    ``vrw_limit_deg``: what the accelerometers add on a car that may rotate while parked (a person gets in, the
    body sways): a Kalman filter with zero-velocity updates sees the azimuth only as the rate of the tilt it
    causes (omega_N psi), measured by the accelerometers; the slope of a line fitted to T seconds of white tilt
    noise (VRW / g per sqrt(Hz)) has a 1-sigma of sqrt(12) (VRW / g) / T^1.5."""
    from insalign_ros.core import earth

    k = d.t_s <= park_s - 0.3
    err_n = np.einsum("kij,kj->ki", d.C_b_n[k], d.omega_ib_b[k] - d.omega_ib_b_true[k])
    om = earth.OMEGA_IE_RAD_S * math.cos(float(d.lat_rad[0]))
    tilt_noise = vrw_m_s_sqrt_h / 60.0 / 9.80665  # [rad sqrt(s)]
    return dict(ideal_yaw_park_deg=float(np.mean(err_n[:, 0])) / om / D2R,
                vrw_limit_deg=math.sqrt(12.0) * tilt_noise / park_s ** 1.5 / om / D2R)


def summary(rows: list[dict]) -> None:
    for name in sorted({r["name"] for r in rows}):
        rs = [r for r in rows if r["name"] == name]
        t_up = np.array([r["up_after_motion_s"] for r in rs])
        before = sum(r["up_at_end_of_park"] for r in rs)
        lvl = np.array([r["level_err_deg"] / r["level_floor_deg"] for r in rs])
        yp = np.array([r["yaw_err_park_deg"] / r["az_floor_deg"] for r in rs])
        fin = np.array([r["yaw_err_end_deg"] for r in rs])
        print(f"\n{name}: {len(rs)} runs, park {min(r['park_s'] for r in rs):.0f}-{max(r['park_s'] for r in rs):.0f} s")
        print(f"  runs with the flag up while |yaw err| > {FLAG_YAW_DEG} deg: {sum(r['flag_bad'] > 0 for r in rs)} "
              f"(outputs: {sum(r['flag_bad'] for r in rs)})")
        print(f"  flag up at the end of the park: {before}/{len(rs)}; time from drive-off to flag up (runs where it "
              f"was down at the drive-off or dropped): median {np.nanmedian(t_up):.1f} s, max {np.nanmax(t_up):.1f} s, "
              f"never {int(np.sum(np.isnan(t_up)))}")
        print(f"  end of park: level error / (b_acc/g floor {rs[0]['level_floor_deg']:.4f} deg): median "
              f"{np.median(lvl):.2f}, max {lvl.max():.2f}; |yaw err| / (azimuth floor {rs[0]['az_floor_deg']:.3f} "
              f"deg): median {np.median(yp):.2f}, max {yp.max():.2f}")
        lvr = np.array([r["level_err_deg"] / max(r["level_floor_run_deg"], 1e-9) for r in rs])
        print(f"  level error / this run's own floor (max |b_acc x, y| / g): median {np.median(lvr):.2f}, max "
              f"{lvr.max():.2f}")
        long = [r for r in rs if r["park_s"] >= 70.0]
        if long:
            yl = np.array([r["yaw_err_park_deg"] / r["az_floor_deg"] for r in long])
            print(f"  parks >= 70 s ({len(long)} runs): flag up before the drive-off {sum(r['up_at_end_of_park'] for r in long)}"
                  f"/{len(long)}; |yaw err| at the end of the park / azimuth floor: median {np.median(yl):.2f}, max "
                  f"{yl.max():.2f}, within 2x: {int(np.sum(yl < 2))}/{len(long)}")
            yo = np.array([r["yaw_err_park_deg"] / math.hypot(r["az_floor_run_deg"], r["arw_limit_deg"]) for r in long])
            print(f"    |yaw err| / hypot(the run's own azimuth floor, ARW limit over the park): median "
                  f"{np.median(yo):.2f}, max {yo.max():.2f}, within 2x: {int(np.sum(yo < 2))}/{len(long)}")
            yv = np.array([r["yaw_err_park_deg"] / math.hypot(r["az_floor_run_deg"], r["arw_limit_deg"],
                                                              r["vrw_limit_deg"]) for r in long])
            print(f"    ... / hypot(own floor, ARW limit, VRW tilt-rate limit {np.median([r['vrw_limit_deg'] for r in long]):.3f} "
                  f"deg median): median {np.median(yv):.2f}, max {yv.max():.2f}, within 2x: {int(np.sum(yv < 2))}/{len(long)}")
            yi = np.array([abs(r["ideal_yaw_park_deg"]) for r in long])
            yr = np.array([r["yaw_err_park_deg"] for r in long])
            print(f"    an ideal gyrocompass on the same sensor errors: |yaw err| median {np.median(yi):.3f} deg, max "
                  f"{yi.max():.3f}; ours median {np.median(yr):.3f}, max {yr.max():.3f}; ideal within 2x hypot(own floor, "
                  f"ARW limit): {int(np.sum(yi / np.hypot([r['az_floor_run_deg'] for r in long], [r['arw_limit_deg'] for r in long]) < 2))}/{len(long)}")
        print(f"  status at the end of the park: {sorted({r['status_park'] + ' / ' + r['state_park'] for r in rs})}")
        print(f"  |yaw err| at the end: median {np.median(fin):.3f} deg, max {fin.max():.3f} deg; resets/faults "
              f"{sum(r['resets'] for r in rs)}")


def kitti(drives: list[str], data_dir: Path, grade: str) -> None:
    import insalign_ros as ia
    from insalign_ros.io.kitti import convert_drive

    for name in drives:
        drive = data_dir / name
        if not drive.exists():
            print(f"SKIP: {drive} not found")
            continue
        data, _ = convert_drive(drive, gnss_rate_hz=1.0)
        res = ia.align(data, core="auto", output_period_s=0.5, imu_grade=grade, core_params={"gnss_sigma_floor_m": 1.0})
        t0 = float(data.t_s[0])
        speed = np.linalg.norm(data.v_n, axis=1) if data.v_n is not None else None
        print(f"\n{data.name} (imu_grade {grade}): {data.n} IMU samples over {data.t_s[-1] - t0:.1f} s, {len(data.gnss_t_s)} fixes; "
              f"initialised at {res.init_t_s - t0:.1f} s")
        states = [o.estimate.reason.split(":")[0] for o in res.outputs]
        prev = None
        print("| t [s] | state | status | RT3003 speed [m/s] | yaw err [deg] | yaw 3-sigma [deg] | flag |")
        print("|---|---|---|---|---|---|---|")
        for i, o in enumerate(res.outputs):
            key = (states[i], o.status.value, bool(res.aligned[i]))
            last = i == len(res.outputs) - 1
            if key != prev or last or (o.stamp_s - t0) % 10.0 < 0.25:
                v = float(np.interp(o.stamp_s, data.t_s, speed)) if speed is not None else math.nan
                print(f"| {o.stamp_s - t0:.1f} | {states[i]} | {o.status.value} | {v:.2f} | "
                      f"{res.rpy_err_deg[i, 2]:+.2f} | {res.sigma3_deg[i, 2]:.2f} | {int(res.aligned[i])} |")
            prev = key
        up = res.aligned
        bad = int(np.sum(up & (np.abs(res.rpy_err_deg[:, 2]) > FLAG_YAW_DEG)))
        print(f"outputs with the flag up: {int(up.sum())}/{len(up)}, of them |yaw err| > {FLAG_YAW_DEG} deg: {bad}; "
              f"counters: gaps {res.counters['imu_gaps']}, gated {res.counters['gnss_gated']}, divergences "
              f"{res.counters['divergences']}, faults {res.counters['core_faults']}")


def drive_stop_drive(seeds: list[int]) -> None:
    """The full drive_stop_drive (a 60-s stop at 70-130 s, a person getting in at 90 s): no reset, the yaw error
    against its 3-sigma and the flag from 5 s before the stop to 20 s after it."""
    import insalign_ros as ia
    from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE
    from insalign_ros.sim.scenarios import make_scenario

    for seed in seeds:
        d = make_scenario("drive_stop_drive", seed=seed)
        r = ia.align(d, core="auto", imu_grade=SCENARIO_IMU_GRADE["drive_stop_drive"])
        a, b = float(d.params["stop_start_s"]), float(d.params["stop_end_s"])
        w = (r.t_s > a - 5) & (r.t_s < b + 20)
        ratio = np.abs(r.rpy_err_deg[w, 2]) / r.sigma3_deg[w, 2]
        c = r.counters
        print(f"drive_stop_drive seed {seed}: stop {a:.0f}-{b:.0f} s; max |yaw err| / 3-sigma {ratio.max():.2f} from 5 s "
              f"before the stop to 20 s after; flag up {r.aligned[w].mean():.0%} of that window; yaw 3-sigma at the end "
              f"of the stop {r.sigma3_deg[np.searchsorted(r.t_s, b) - 1, 2]:.2f} deg (flag bound {FLAG_YAW_DEG}); "
              f"|yaw err| at the end {abs(r.rpy_err_deg[-1, 2]):.3f} deg; resets/faults/divergences "
              f"{c['time_resets'] + c['core_faults'] + c['divergences']}; hand-overs {r.diagnostics['core.handovers']}, "
              f"stops {r.diagnostics['core.stops']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=25, help="runs per IMU grade (0: none)")
    ap.add_argument("--park-min", type=float, default=30.0)
    ap.add_argument("--park-max", type=float, default=120.0)
    ap.add_argument("--drive", type=float, default=45.0, help="driving after the park [s]")
    ap.add_argument("--grades", nargs="+", default=["park_drive", "park_drive_navgrade"])
    ap.add_argument("--kitti", nargs="*", default=[])
    ap.add_argument("--kitti-grade", default="unknown_mems", help="imu_grade of the KITTI runs (default: the session's)")
    ap.add_argument("--dsd-seeds", nargs="*", type=int, default=[], help="full drive_stop_drive runs (seeds)")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "kitti_raw_oxts_sync"))
    sweep.add_arguments(ap)
    args = ap.parse_args(argv)
    tasks = []
    for name in args.grades:
        rng = np.random.default_rng(1000 + len(name))
        for i in range(args.runs):
            tasks.append((name, i, float(rng.uniform(-180, 180)), float(rng.uniform(args.park_min, args.park_max)),
                          args.drive))
    if tasks:
        rows = sweep.run_tasks(one_run, tasks, args, desc="auto")
        for r in rows:
            print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()})
        summary(rows)
    if args.kitti:
        kitti(args.kitti, Path(args.data), args.kitti_grade)
    if args.dsd_seeds:
        drive_stop_drive(args.dsd_seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
