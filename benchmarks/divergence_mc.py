"""Divergence guard Monte Carlo (issue 15): a 60-deg yaw kick of an aligned filter and a 10-s block of wrong GNSS
(block: 300 m East, 180 m North; walk: a bias walking at 3 m/s East, 1.8 m/s North, then back at once).

    .venv/bin/python benchmarks/divergence_mc.py [--seeds 10] [--cores iekf liekf ekf pi_liekf] [--scenario ship]
                                                 [--cases kick block walk]

Per core and case, over the seeds: the detection latency (kick: the divergence, FAULT; block: the first gated fix,
which starts the hold), the outputs with the flag up while |yaw error| > the flag's yaw bound (2.5 deg) outside the
blind time between the event and its detection (must be 0) and inside it, the outputs with the flag up inside the
block, and the time from the event's end (kick: the detection; block: the block's end) to re-aligned (flag up and |yaw error| < 2 deg; target < 60 s), and to the estimate back (|yaw error| < 2 deg
for the next 10 s, whatever the flag); after the estimate is back: the fraction of outputs with |yaw error| <= its
3-sigma and the mean attitude NEES (95 % band of one output [0.22, 9.35]). Initialised from the truth plus 2/-2/10 deg; the
event at 60 s. The physical floor: a fix gated at the first epoch after the event (1 Hz fixes: latency >= the
time to the next fix) and a re-alignment no faster than the flag's hold_s (5 s) after the first good fix.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from insalign_ros.core import earth  # noqa: E402
from insalign_ros.eval.metrics import evaluate  # noqa: E402
from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE  # noqa: E402
from insalign_ros.session.config import SessionConfig  # noqa: E402
from insalign_ros.session.offline import events_in_arrival_order  # noqa: E402
from insalign_ros.session.session import AlignmentSession  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402

YAW_BOUND_DEG = 2.5  # the aligned flag's yaw 3-sigma bound (eval/aligned.py default)
TRUTH = {"init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]}
SHIP = {"imu_grade": SCENARIO_IMU_GRADE["ship"], **TRUTH}  # the scenario's own IMU noise (docs/imu_grades.md)


def offset_fixes(d, t0_s: float, t1_s: float, east_north_m, walk: bool = False):
    """``d`` with the fixes stamped in [t0_s, t1_s) moved by ``east_north_m`` (ENU [m]; ``walk``: by that many
    metres per second since t0_s - 1 s, a bias walking at that rate); reported R unchanged."""
    p = d.gnss_p_e.copy()
    for j in np.flatnonzero((d.gnss_t_s >= t0_s) & (d.gnss_t_s < t1_s)):
        lat, lon, _ = earth.ecef_to_geodetic(p[j])
        k = d.gnss_t_s[j] - (t0_s - 1.0) if walk else 1.0
        p[j] = p[j] + earth.C_n_e(lat, lon) @ np.array([k * east_north_m[0], k * east_north_m[1], 0.0])
    return replace(d, gnss_p_e=p)


def yaw_kick(deg: float):
    """An action for :func:`run`: rotate the core's attitude by ``deg`` about the local vertical (P untouched: a
    lost filter that still believes its covariance)."""
    from scipy.spatial.transform import Rotation

    def kick(s):
        c = s.core
        c.flush()
        up_i = c.p / np.linalg.norm(c.p)
        c.C = Rotation.from_rotvec(math.radians(deg) * up_i).as_matrix() @ c.C
    return kick


def run(d, cfg: dict, params: dict | None = None, at_s: float | None = None, action=None):
    """Push ``d`` through a session in arrival order (processing every 0.1 s of data); ``action(session)`` once the
    filter time reaches ``at_s``. Returns (session, t, aligned, yaw error [deg], log lines (key, text, filter time))."""
    logs = []
    s = AlignmentSession(SessionConfig.from_dict(cfg), params,
                         log=lambda level, key, text: logs.append((key, text, s.processed_t)))
    outs, done = [], action is None
    for kind, item in events_in_arrival_order(d):
        {"imu": s.push_imu, "fix": s.push_fix, "truth": s.push_truth, "vel": s.push_velocity}[kind](item)
        if kind == "imu" and int(round(item.stamp_s * 100)) % 10 == 0:
            outs += s.process()
            if not done and s.processed_t is not None and s.processed_t >= at_s:
                action(s)
                done = True
    outs += s.finish()
    s.close()
    s.bench_outputs = outs  # the full outputs, for the consistency columns of :func:`one`
    t = np.array([o.stamp_s for o in outs])
    aligned = np.array([o.aligned for o in outs])
    yaw_err = np.array([o.euler_error_deg[2] if o.euler_error_deg is not None else np.nan for o in outs])
    return s, t, aligned, yaw_err, logs


def one(scenario: str, seed: int, core: str, case: str, t_ev: float = 60.0, block_s: float = 10.0,
        gnss_vel_sigma_m_s: float = 0.0) -> dict:
    d = make_scenario(scenario, seed=seed, duration_s=t_ev + 90.0, gnss_vel_sigma_m_s=gnss_vel_sigma_m_s)
    if case == "kick":
        s, t, al, ye, logs = run(d, {"core": core, "imu_grade": SCENARIO_IMU_GRADE[scenario], **TRUTH}, at_s=t_ev, action=yaw_kick(60.0))
        t_end = t_ev
        det = [tf for k, _, tf in logs if k == "divergence"]
    else:
        bad = offset_fixes(d, t_ev, t_ev + block_s, (300.0, 180.0)) if case == "block" else \
            offset_fixes(d, t_ev, t_ev + block_s, (3.0, 1.8), walk=True)
        s, t, al, ye, logs = run(bad, {"core": core, "imu_grade": SCENARIO_IMU_GRADE[scenario], **TRUTH})
        t_end = t_ev + block_s
        det = [tf for k, _, tf in logs if k == "gnss_gated" and tf >= t_ev]
    t_det = det[0] if det else t_ev
    again = t[(t > max(t_end, t_det)) & al & (np.abs(ye) < 2.0)]
    wrong = al & (np.abs(ye) > YAW_BOUND_DEG)
    back = _estimate_back(t, ye, max(t_end, t_det))
    after = t >= back if math.isfinite(back) else np.zeros(t.size, bool)
    s3 = np.array([o.euler_3sigma_deg[2] for o in s.bench_outputs])
    nees = _nees(s.bench_outputs)
    return {"aligned_at_event": bool(np.any(al[(t > t_ev - 1.0) & (t < t_ev)])),
            "latency_s": det[0] - t_ev if det else math.nan,
            "flag_up_wrong_blind": int(np.sum(wrong & (t >= t_ev) & (t < t_det))),
            "flag_up_wrong": int(np.sum(wrong & ((t < t_ev) | (t >= t_det)))),
            "flag_up_in_block": int(np.sum(al & (t >= t_ev) & (t < t_end))) if case != "kick" else 0,
            "realigned_s": float(again[0] - t_end) if again.size else math.inf,
            "estimate_back_s": back - t_end, "inside_after": float(np.mean(np.abs(ye[after]) <= s3[after])) if after.any() else math.nan,
            "nees_after": float(np.nanmean(nees[after])) if after.any() else math.nan,
            "divergences": s.counters["divergences"], "holds": s.counters["gnss_holds"]}


def _estimate_back(t, yaw_err, t0: float, hold_s: float = 10.0) -> float:
    """First output time after ``t0`` from which |yaw error| < 2 deg for ``hold_s`` (inf if never)."""
    ok = (np.abs(yaw_err) < 2.0) & (t > t0)
    for i in np.flatnonzero(ok):
        w = (t >= t[i]) & (t < t[i] + hold_s)
        if t[-1] >= t[i] + hold_s and ok[w].all():
            return float(t[i])
    return math.inf


def _nees(outs) -> np.ndarray:
    """Attitude NEES of each output (3 dof; eval.metrics.evaluate), NaN without truth."""
    has = np.array([o.truth_C_b_n is not None for o in outs])
    nees = np.full(len(outs), np.nan)
    if has.any():
        sel = [o for o in outs if o.truth_C_b_n is not None]
        t = np.array([o.stamp_s for o in sel])
        nees[has] = evaluate("", [o.estimate for o in sel], t, np.array([o.truth_C_b_n for o in sel]), 0.0).nees
    return nees


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--cores", nargs="+", default=["iekf", "liekf", "ekf", "pi_liekf"])
    ap.add_argument("--scenario", default="ship")
    ap.add_argument("--cases", nargs="+", default=["kick", "block", "walk"])
    ap.add_argument("--gnss-vel-sigma", type=float, default=0.0, help="GNSS velocity 1-sigma [m/s] (0: none)")
    args = ap.parse_args(argv)
    print(f"{args.scenario}, seeds 0..{args.seeds - 1}, GNSS velocity sigma {args.gnss_vel_sigma:g} m/s, event at 60 s; latency floor: the next fix (<= 1 s); "
          "re-aligned floor: hold_s 5 s after the first good fix")
    print("| case | core | aligned at the event | detection latency [s] median (max) | flag up with \\|yaw err\\| > "
          "2.5 deg (outputs, all seeds; in brackets: between event and detection) | flag up in the block | divergences / holds | re-aligned after [s] median "
          "(max) | runs re-aligned within 60 s | estimate back after [s] median (max) | after it: \\|yaw\\| <= 3-sigma; "
          "mean NEES | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for case in args.cases:
        for core in args.cores:
            t0 = time.perf_counter()
            rs = [one(args.scenario, seed, core, case, gnss_vel_sigma_m_s=args.gnss_vel_sigma) for seed in range(args.seeds)]
            lat = np.array([r["latency_s"] for r in rs])
            re = np.array([r["realigned_s"] for r in rs])
            eb = np.array([r["estimate_back_s"] for r in rs])
            print(f"| {case} | {core} | {sum(r['aligned_at_event'] for r in rs)}/{len(rs)} | "
                  f"{np.nanmedian(lat):.1f} ({np.nanmax(lat):.1f}) | {sum(r['flag_up_wrong'] for r in rs)} "
                  f"({sum(r['flag_up_wrong_blind'] for r in rs)}) | "
                  f"{sum(r['flag_up_in_block'] for r in rs)} | {sum(r['divergences'] for r in rs)} / "
                  f"{sum(r['holds'] for r in rs)} | {np.median(re):.1f} ({np.max(re):.1f}) | "
                  f"{int(np.sum(re < 60.0))}/{len(rs)} | {np.median(eb):.1f} ({np.max(eb):.1f}) | "
                  f"{np.nanmean([r['inside_after'] for r in rs]):.3f}; {np.nanmean([r['nees_after'] for r in rs]):.2f} | "
                  f"{time.perf_counter() - t0:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
