#!/usr/bin/env python3
"""GNSS velocity and GNSS antenna lever arm benchmark (issue 13 item 3). Not a unit test.

Part A, lever arm: the simulator generates the fixes (and, in the second pair of rows, the GNSS velocities) at an
antenna 1.5 m from the IMU (car: 1.5 m forward; ship: 1.5 m up, a mast, where the waves' roll and pitch swing it
most). Each run is aligned twice, with ``gnss_lever_arm_b_m`` set to the simulated offset and with it left at zero:
the difference is the error the parameter removes.

Part B, GNSS velocity: antenna at the IMU; fixes only vs fixes + GNSS velocities (0.1 m/s, PI-LIEKF Table 1), at
the same rate (1 Hz): time to the aligned flag, time to |yaw error| < 1 deg (and stays), final errors.

Every run: the session (the node's pipeline) on the offline path, ``init_mode`` ``sensors`` (the node's default:
level from the accelerometers, velocity from the fixes, unknown heading -> the bank of yaw hypotheses) or
``truth`` with ``--rpy-error``. Printed per scenario and case: RMS over seeds of the final roll/pitch/yaw errors, the
mean final yaw 3-sigma the filter reports (its own bound: an error above it is inconsistent), the physical floor of
the level (accelerometer bias / g), mean time to the flag and to |yaw| < 1 deg, flag-up-while-|yaw| > 3 deg count.

    nice /work/venv_gnssvel/bin/python benchmarks/gnss_velocity_lever_arm.py --seeds 5 --md-out /tmp/gv.md
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

from insalign_ros.session.offline import align, flag_up_with_error_above  # noqa: E402
from insalign_ros.sim import error_model  # noqa: E402
from insalign_ros.sim.scenarios import SCENARIOS, make_scenario  # noqa: E402

LEVER = {"car": (1.5, 0.0, 0.0), "ship": (0.0, 0.0, 1.5)}
DURATION = {"car": 120.0, "ship": 300.0}
VEL_SIGMA_M_S = 0.1  # PI-LIEKF Table 1: GPS velocity 0.1 m/s


def run(scn: str, seed: int, core: str, lever_sim, lever_param, vel: bool, init: str, rpy_error,
        gnss_sigma_m: float | None = None) -> dict:
    ov = dict(zip(("gnss_lever_x_m", "gnss_lever_y_m", "gnss_lever_z_m"), lever_sim))
    if gnss_sigma_m is not None:  # e.g. RTK: the lever arm is then large against the fix noise
        ov.update(gnss_sigma_h_m=gnss_sigma_m, gnss_sigma_v_m=gnss_sigma_m)
    d = make_scenario(scn, seed=seed, duration_s=DURATION[scn], gnss_vel_sigma_m_s=VEL_SIGMA_M_S if vel else 0.0,
                      **ov)
    sp = {"init_mode": init}
    if init == "truth":
        sp["init_rpy_error_deg"] = list(rpy_error)
    t0 = time.perf_counter()
    r = align(d, core=core, core_params={"gnss_lever_arm_b_m": list(lever_param)}, **sp)
    m = r.metrics
    return {"final": np.asarray(m["final_err_rpy_deg"]), "s3_yaw": float(r.sigma3_deg[-1, 2]),
            "flag_s": m.get("aligned_first_raised_at_s"), "yaw1_s": m.get("time_yaw_below_deg_s"),
            "bad_flag": flag_up_with_error_above(r, 3.0), "vel_fused": r.counters["gnss_vel_accepted"],
            "wall_s": time.perf_counter() - t0}


def table(title: str, rows: list[tuple[str, list[dict]]], floor_deg: float) -> list[str]:
    out = [f"### {title}", "",
           "| case | RMS final roll / pitch / yaw err [deg] | mean final yaw 3-sigma [deg] | level floor b_a/g [deg] | "
           "flag up at [s] (mean, runs) | yaw < 1 deg from [s] (mean, runs) | flag up with yaw > 3 deg | "
           "velocities fused | wall [s] |", "|---|---|---|---|---|---|---|---|---|"]
    for name, rs in rows:
        fin = np.array([x["final"] for x in rs])
        rms = np.sqrt(np.mean(fin**2, axis=0))
        fl = [x["flag_s"] for x in rs if x["flag_s"] is not None]
        y1 = [x["yaw1_s"] for x in rs if x["yaw1_s"] is not None and math.isfinite(x["yaw1_s"])]
        out.append(f"| {name} | {rms[0]:.3f} / {rms[1]:.3f} / {rms[2]:.3f} | {np.mean([x['s3_yaw'] for x in rs]):.3f} "
                   f"| {floor_deg:.3f} | {np.mean(fl) if fl else float('nan'):.1f} ({len(fl)}/{len(rs)}) | "
                   f"{np.mean(y1) if y1 else float('nan'):.1f} ({len(y1)}/{len(rs)}) | "
                   f"{sum(x['bad_flag'] for x in rs)} | {int(np.mean([x['vel_fused'] for x in rs]))} | "
                   f"{sum(x['wall_s'] for x in rs):.1f} |")
    return out + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--core", default="iekf")
    ap.add_argument("--scenarios", nargs="+", default=["car", "ship"])
    ap.add_argument("--init", choices=("sensors", "truth"), default="sensors")
    ap.add_argument("--rpy-error", nargs=3, type=float, default=(10.0, 10.0, 60.0))
    ap.add_argument("--gnss-sigma-m", type=float, default=None,
                    help="fix 1-sigma per axis [m] (default: the scenario's 1 m; 0.02 = RTK)")
    ap.add_argument("--parts", nargs="+", choices=("lever", "velocity"), default=["lever", "velocity"])
    ap.add_argument("--md-out", default=None)
    args = ap.parse_args(argv)
    seeds = range(args.seeds)
    init = f"init {args.init}" + (f" (error {list(args.rpy_error)} deg)" if args.init == "truth" else "")
    fixes = "fixes 1 m (scenario)" if args.gnss_sigma_m is None else f"fixes {args.gnss_sigma_m:g} m per axis"
    lines = [f"core {args.core}, {init}, {fixes}, seeds 0..{args.seeds - 1}", ""]
    for scn in args.scenarios:
        floor = math.degrees(error_model.mg_to_m_s2(SCENARIOS[scn].imu.acc_bias_mg) / 9.81)
        lev = LEVER[scn]
        go = lambda lever_sim, lever_param, vel: [run(scn, s, args.core, lever_sim, lever_param, vel, args.init,  # noqa: E731
                                                      args.rpy_error, args.gnss_sigma_m) for s in seeds]
        n0 = len(lines)
        if "lever" in args.parts:
            rows_a = [(f"antenna at {list(lev)} m, fixes only, parameter set", go(lev, lev, False)),
                      ("antenna offset, fixes only, parameter 0 (ignored)", go(lev, (0, 0, 0), False)),
                      ("antenna offset, fixes + velocity, parameter set", go(lev, lev, True)),
                      ("antenna offset, fixes + velocity, parameter 0 (ignored)", go(lev, (0, 0, 0), True))]
            lines += table(f"{scn} ({DURATION[scn]:.0f} s): lever arm", rows_a, floor)
        if "velocity" in args.parts:
            rows_b = [("antenna at the IMU, fixes only", go((0, 0, 0), (0, 0, 0), False)),
                      (f"antenna at the IMU, fixes + velocity ({VEL_SIGMA_M_S} m/s)", go((0, 0, 0), (0, 0, 0), True))]
            lines += table(f"{scn} ({DURATION[scn]:.0f} s): GNSS velocity", rows_b, floor)
        print("\n".join(lines[n0:]), flush=True)
    if args.md_out:
        Path(args.md_out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
