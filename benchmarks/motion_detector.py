"""Motion detector (session/motion.py) over seeds of park_drive (MEMS, navgrade) and drive_stop_drive, no ROS.

Each park_drive run: seed k, true heading U(-180, 180) deg and park length U(60, 120) s drawn from the seed, then
90 s of driving; a person gets in at a time U(10, park - 20) s. Stress rows: a harder rocking or load tilt
of the person getting in, or a 4x engine vibration (outside the thresholds' allowances: these may fail). Each drive_stop_drive run: default timeline (drive-off
at 5 s, stop at 70 s for 60 s, a person gets in 10 s into the stop). Every run twice: IMU only, and IMU + GNSS
speed (1 Hz, per-axis sigma 0.05 m/s, as from a receiver's Doppler velocity).

Reported: false motion declarations while parked (runs, count); drive-off latency (first motion declaration minus
the true drive-off) with its floor (the time the true speed needs to reach the dv_h threshold, plus enter_hold_s);
false rest declarations while the true speed is over 1 m/s; delay from the stop to the rest declaration; the
per-sample cost of MotionDetector.push_imu.

    .venv/bin/python benchmarks/motion_detector.py [--runs 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insalign_ros.session.motion import MotionConfig, MotionDetector, detect_motion  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario, rest_segments  # noqa: E402

GNSS_SIGMA_M_S = 0.05


def gnss_speed(sc, rng):
    g = np.arange(0, sc.n, int(round(sc.imu_spec.rate_hz)))
    speed = np.linalg.norm(sc.v_n[g] + rng.normal(0.0, GNSS_SIGMA_M_S, (len(g), 3)), axis=1)
    return sc.t_s[g], speed, np.full(len(g), GNSS_SIGMA_M_S)


def evaluate(sc, tr):
    """Per run: false motion while parked, drive-off latencies (+ floors), false rests, stop-to-rest delays."""
    dec = tr.declarations()
    speed = np.linalg.norm(sc.v_n[:, :2], axis=1)
    out = {"false_motion": 0, "latency": [], "floor": [], "false_rest": 0, "rest_delay": []}
    segs = rest_segments(sc.params)
    for a, b in segs:
        out["false_motion"] += sum(1 for t, m in dec if m and a <= t < b)
        go = [t for t, m in dec if m and t >= b]
        out["latency"].append(go[0] - b if go else np.inf)
        k = np.flatnonzero((sc.t_s >= b) & (speed >= tr.thresholds["dv_h_m_s"]))
        out["floor"].append(sc.t_s[k[0]] - b + MotionConfig().enter_hold_s if k.size else np.nan)
        if a > 0:
            rest = [t for t, m in dec if not m and t >= a]
            out["rest_delay"].append(rest[0] - a if rest else np.inf)
    for t, m in dec:
        k = np.searchsorted(sc.t_s, t)
        out["false_rest"] += int(not m and speed[min(k, sc.n - 1)] > 1.0)
    return out


def summary(rows, key):
    v = np.array([x for r in rows for x in r[key]], float)
    return f"median {np.median(v):.2f} s, max {np.max(v):.2f} s" if v.size else "-"


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=10)
    a = ap.parse_args(argv)
    t_start = time.time()
    print("| scenario | GNSS speed | runs | runs with false motion while parked (count) | drive-off latency "
          "| floor (true speed reaches dv_h threshold + hold) | false rest while > 1 m/s | stop -> rest |")
    print("|---|---|---|---|---|---|---|---|")
    cases = [("park_drive", {}), ("park_drive_navgrade", {}), ("drive_stop_drive", {})]
    cases += [("park_drive", {"door_rock_deg": 1.0}), ("park_drive", {"door_rock_deg": 2.0}),
              ("park_drive", {"door_tilt_deg": 2.0}), ("park_drive", {"engine_acc_m_s2": 0.2}),
              ("park_drive_vibration", {}), ("park_drive_vibration", {"engine_harmonics_acc_m_s2": 0.4}),
              ("park_drive_vibration", {"engine_harmonics_acc_m_s2": 0.4, "learn_cap_factor": 0.0})]
    for name, stress in cases:
        rows = {False: [], True: []}
        for seed in range(a.runs):
            rng = np.random.default_rng(1000 + seed)
            if name == "drive_stop_drive":
                kw = {}
            else:
                park = float(rng.uniform(60.0, 120.0))
                kw = dict(heading_deg=float(rng.uniform(-180.0, 180.0)), park_s=park, duration_s=park + 90.0,
                          door_at_s=float(rng.uniform(10.0, park - 20.0)))
            det_kw = {k: v for k, v in stress.items() if k == "learn_cap_factor"}  # a detector option, not the sim's
            sc = make_scenario(name, seed=seed, **kw, **{k: v for k, v in stress.items() if k not in det_kw})
            cfg = MotionConfig.from_imu_spec(sc.imu_spec, **det_kw)
            for use_gnss in (False, True):
                g = gnss_speed(sc, rng) if use_gnss else (None, None, None)
                rows[use_gnss].append(evaluate(sc, detect_motion(sc.t_s, sc.omega_ib_b, sc.f_ib_b, cfg, *g)))
        for use_gnss, r in rows.items():
            fm = [x["false_motion"] for x in r]
            label = name + "".join(f", {k}={v:g}" for k, v in stress.items())
            print(f"| {label} | {'1 Hz, 0.05 m/s' if use_gnss else 'no'} | {len(r)} | {sum(f > 0 for f in fm)} "
                  f"({sum(fm)}) | {summary(r, 'latency')} | {summary(r, 'floor')} | "
                  f"{sum(x['false_rest'] for x in r)} | {summary(r, 'rest_delay')} |")
    print(f"thresholds (park_drive MEMS): {MotionConfig.from_imu_spec(sc.imu_spec).thresholds()}")
    sc = make_scenario("park_drive", seed=0, duration_s=20.0, park_s=10.0)
    det = MotionDetector(MotionConfig.from_imu_spec(sc.imu_spec))
    t0 = time.perf_counter()
    for k in range(sc.n):
        det.push_imu(sc.t_s[k], sc.omega_ib_b[k], sc.f_ib_b[k])
    us = (time.perf_counter() - t0) / sc.n * 1e6
    print(f"MotionDetector.push_imu: {us:.0f} us per sample ({sc.n} samples at {sc.imu_spec.rate_hz:g} Hz: "
          f"{us * sc.imu_spec.rate_hz / 1e4:.1f} % of one core); total {time.time() - t_start:.0f} s")


if __name__ == "__main__":
    main()
