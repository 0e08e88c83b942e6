"""Time to the aligned flag from the first motion, with and without the yaw seed from GNSS velocity (issue 25).

Simulated cars (sim/scenarios.py, default grade, position fixes at 1 Hz, no velocity topic unless
``--gnss-vel-sigma``), offline through the whole session (``ia.align``): ``car`` (parked ~4 s, then driving) and
``park_drive`` (parked 90 s, then driving), fixed seeds, ``vehicle: unknown`` (the default: the GSF assumes
nothing, the pure GSF cannot reach ``valid`` on fix differences, so no seed: as before the stage existed) against
``vehicle: car`` (the course constraint and the non-holonomic constraint).

Per run: the first flag after the first motion [s], the largest |yaw error| while the flag is up [deg], the yaw
coverage (|error| <= 3 sigma over the outputs from 10 s after the first motion), what seeded the yaw; and where the
delay goes (``--decompose``): the first time after the motion at which the roll/pitch 3-sigma, then the yaw 3-sigma
stay below the flag's bounds (the information), at which every criterion holds (the NIS window too: the flag with
``hold_s`` 0), and the flag with the default 5-s hold. ``--hold-s`` runs the session with another hold.

    nice python benchmarks/vehicle_yaw_seed.py --seeds 5
    nice python benchmarks/vehicle_yaw_seed.py --scenarios park_drive --vehicles car --seeds 10 --decompose
    nice python benchmarks/vehicle_yaw_seed.py --scenarios car --vehicles car --seeds 10 --gnss-vel-sigma 0.1
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from insalign_ros.filters.imu_grade import DEFAULT_IMU_GRADE, get_grade  # noqa: E402
from insalign_ros.session.flag import AlignedCriteria, AlignedFlag, level_floor_3sigma_deg  # noqa: E402
from insalign_ros.session.offline import align, truncate  # noqa: E402
from insalign_ros.sim.scenarios import SCENARIOS, make_scenario  # noqa: E402

DURATION_S = {"car": 120.0, "park_drive": 150.0, "ship": 180.0}
DEFAULT_PARK_S = 90.0


def first_motion_s(name: str, data) -> float:
    """The first stamp at which the true horizontal speed exceeds 0.5 m/s."""
    speed = np.linalg.norm(np.asarray(data.v_n)[:, :2], axis=1)
    return float(data.t_s[int(np.argmax(speed > 0.5))])


def _first_stays(t: np.ndarray, ok: np.ndarray, t0: float) -> float:
    """The first stamp >= t0 from which ``ok`` holds to the end of the run, minus t0 (NaN: never)."""
    sel = t >= t0
    tt, oo = t[sel], ok[sel]
    if not oo.size or not oo[-1]:
        return math.nan
    bad = np.flatnonzero(~oo)
    k = bad[-1] + 1 if bad.size else 0
    return float(tt[k] - t0)


def run(name: str, seed: int, vehicle: str, duration_s: float, vel_sigma: float = 0.0,
        hold_s: float | None = None, until_s: float | None = None, park_s: float | None = None,
        scenario_over: dict | None = None, gyro_bias_deg_h: float | None = None, **session_params) -> dict:
    over = {"gnss_vel_sigma_m_s": vel_sigma} if vel_sigma > 0 else {}
    over.update(scenario_over or {})
    imu = None
    if gyro_bias_deg_h is not None:
        imu = replace(SCENARIOS[name].imu, gyro_bias_deg_h=gyro_bias_deg_h)
    if park_s is not None and name == "park_drive":  # a shorter park (the person gets in half way)
        over.update(park_s=park_s, door_at_s=0.5 * park_s)
        duration_s = duration_s - DEFAULT_PARK_S + park_s
    data = make_scenario(name, seed=seed, duration_s=duration_s, imu=imu, **over)
    if until_s is not None:  # the same drive (the car's manoeuvres scale with duration_s), cut short
        data = truncate(data, first_motion_s(name, data) + until_s)
    crit = {} if hold_s is None else {"hold_s": hold_s}
    r = align(data, vehicle=vehicle, criteria=crit, **session_params)
    t0 = first_motion_s(name, data)
    up = r.aligned & (r.t_s >= t0)
    t_flag = float(r.t_s[np.argmax(up)] - t0) if up.any() else math.nan
    err = r.rpy_err_deg[:, 2]
    max_up = float(np.max(np.abs(err[r.aligned]))) if r.aligned.any() else 0.0
    late = (r.t_s >= t0 + 10.0) & np.isfinite(err)
    cover = float(np.mean(np.abs(err[late]) <= r.sigma3_deg[late, 2])) if late.any() else math.nan
    c = AlignedCriteria(**crit)
    grade = get_grade(session_params.get("imu_grade") or DEFAULT_IMU_GRADE)
    level_bound = AlignedFlag(c, level_floor_3sigma_deg(grade.acc_bias_mg)).level_bound_deg
    # where the delay goes: the flag's own 3-sigma (P_att_n about East, North, Up) and its reason per output
    s3 = np.array([o.estimate.P_att_n.diagonal() for o in r.outputs])
    s3 = 3.0 * np.degrees(np.sqrt(np.clip(s3, 0.0, None)))
    holds = np.array([o.reason.startswith("criteria hold") for o in r.outputs], bool)
    crit_t = r.t_s[holds & (r.t_s >= t0)]
    d = r.diagnostics
    return {"scenario": name, "seed": seed, "vehicle": vehicle, "vel_sigma": vel_sigma, "t_flag_s": t_flag,
            "t_level_s": _first_stays(r.t_s, np.max(s3[:, :2], axis=1) < level_bound, t0),
            "t_yaw_s": _first_stays(r.t_s, s3[:, 2] < c.yaw_3sigma_deg, t0),
            "t_criteria_s": float(crit_t[0] - t0) if crit_t.size else math.nan,
            "max_err_up_deg": max_up,
            "max_err_criteria_deg": float(np.max(np.abs(err[holds]))) if holds.any() else 0.0,
            "coverage": cover, "seeded_by": d.get("yaw_seeded_by", ""), "final_err_deg": float(err[-1])}


def _med_max(rows, key) -> str:
    t = np.array([row[key] for row in rows])
    ok = np.isfinite(t)
    med = float(np.median(t[ok])) if ok.any() else math.nan
    mx = float(np.max(t)) if ok.all() else math.inf
    return f"{med:.1f} / {mx:.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default="car,park_drive")
    ap.add_argument("--vehicles", default="unknown,car")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=None, help="seconds per run (default: per scenario)")
    ap.add_argument("--gnss-vel-sigma", type=float, default=0.0,
                    help="a GNSS velocity topic at the fixes with this 1-sigma [m/s] (0: fixes only)")
    ap.add_argument("--until", type=float, default=None,
                    help="cut every run this many seconds after the first motion (the same drive, shorter)")
    ap.add_argument("--park-s", type=float, default=None,
                    help=f"park_drive: park this long instead of {DEFAULT_PARK_S:g} s (same drive after it)")
    ap.add_argument("--hold-s", type=float, default=None, help="the flag's hold_s (default: the criteria's 5 s)")
    ap.add_argument("--decompose", action="store_true", help="also print where the delay goes")
    ap.add_argument("--json", default=None, help="write every run's row to this file")
    ap.add_argument("--set", action="append", default=[], metavar="PARAM=VALUE",
                    help="a scenario parameter (e.g. speed_m_s=4 for the ship); repeatable")
    ap.add_argument("--gyro-bias-deg-h", type=float, default=None,
                    help="the simulated gyro bias 1-sigma [deg/h] (default: the scenario's IMU)")
    ap.add_argument("--imu-grade", default=None, help="the session's imu_grade (default: SessionConfig's)")
    a = ap.parse_args(argv)
    vel = f", GNSS velocity {a.gnss_vel_sigma:g} m/s" if a.gnss_vel_sigma > 0 else ", fixes only"
    print(f"| scenario{vel} | vehicle | runs | flag after first motion [s] median / max | never flagged | "
          "max abs(yaw err) while flagged [deg] | coverage min | seeded by GSF |"
          + (" level 3-sigma < bound [s] | yaw 3-sigma < bound [s] | all criteria (hold 0) [s] | max abs(yaw err) "
             "while the criteria hold [deg] |" if a.decompose else ""))
    print("|---|---|---|---|---|---|---|---|" + ("---|---|---|---|" if a.decompose else ""))
    over = {k: float(v) for k, v in (kv.split("=", 1) for kv in a.set)}
    sess = {"imu_grade": a.imu_grade} if a.imu_grade else {}
    every = []
    for name in a.scenarios.split(","):
        for veh in a.vehicles.split(","):
            rows = [run(name, s, veh, a.duration or DURATION_S[name], a.gnss_vel_sigma, a.hold_s,
                        a.until, a.park_s, over, a.gyro_bias_deg_h, **sess)
                    for s in range(a.first_seed, a.first_seed + a.seeds)]
            for row in rows:
                print("  ", row, file=sys.stderr, flush=True)
            every += rows
            t = np.array([row["t_flag_s"] for row in rows])
            line = (f"| {name} | {veh} | {len(rows)} | {_med_max(rows, 't_flag_s')} | {int((~np.isfinite(t)).sum())} | "
                    f"{max(row['max_err_up_deg'] for row in rows):.2f} | "
                    f"{np.nanmin([row['coverage'] for row in rows]):.3f} | "
                    f"{sum(row['seeded_by'].startswith('GNSS') for row in rows)} |")
            if a.decompose:
                line += (f" {_med_max(rows, 't_level_s')} | {_med_max(rows, 't_yaw_s')} | "
                         f"{_med_max(rows, 't_criteria_s')} | {max(row['max_err_criteria_deg'] for row in rows):.2f} |")
            print(line, flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(every, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
