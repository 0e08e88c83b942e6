"""Wheel speed as a measurement with a scale-factor estimate, through a GNSS outage (issue 25, item 3).

Simulated car (sim/scenarios.py ``car``: default automotive MEMS, 10 deg/h gyro bias, 1-Hz position fixes at 1 m,
no velocity topic), offline through the whole session (``ia.align``, ``core: auto``, ``vehicle: car``, defaults),
fixed seeds; four runs per seed: with/without wheel odometry (10 Hz, 0.05 m/s, reading ``--scale-error`` high)
and with/without a GNSS outage (``--outage-start``, ``--outage-s``: no fix in the window).

Per run: the largest |yaw error| and the smallest yaw 3-sigma through the outage (its window, and 10 s after it when
the filter re-converges), their largest ratio (<= 1: inside), the yaw coverage (|error| <= 3 sigma) over the outputs
from the flag on; the mean |yaw error| while GNSS is present (60 s to the outage start) and over the whole run after
the flag (the "no worse with GNSS present" test); the horizontal position and velocity error at the outage's end
(the drift, before the first fix back); the scale estimate and its 1-sigma against the truth; the first flag [s].

Floors and references printed with them: the yaw 3-sigma at the outage start (the outage cannot end below it);
the yaw drift a 10-deg/h gyro bias would give over the outage if it were not estimated (the worst case); the scale's
floor, sqrt(2) x the 1-m fix sigma over the distance driven with GNSS before the outage (one window spanning the
whole calibrated path: reached on a straight road, test/test_wheel_speed.py; the 20-s windows on a winding one reach
about 2.5 x it); what the filter's own covariance says the drift can be: cross-track, the yaw 1-sigma at the outage
start x the outage's distance, and with odometry along-track, the scale 1-sigma x that distance.

    nice python benchmarks/wheel_speed.py --seeds 0 1 2 3 4
    nice python benchmarks/wheel_speed.py --seeds 0 --outage-start 120 --outage-s 30 --duration 180
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import insalign_ros as ia  # noqa: E402
from insalign_ros.core import earth  # noqa: E402

WHEEL_SIGMA_M_S = 0.05
GNSS_SIGMA_M = 1.0


def _enu_errors(r, d, t):
    """(horizontal position error [m], horizontal velocity error [m/s]) of the output nearest ``t``."""
    i = int(np.argmin(np.abs(r.t_s - t)))
    e = r.outputs[i].estimate
    k = int(np.argmin(np.abs(d.t_s - r.t_s[i])))
    p_est = earth.geodetic_to_ecef(e.lat_rad, e.lon_rad, e.h_m)
    p_true = earth.geodetic_to_ecef(float(d.lat_rad[k]), float(d.lon_rad[k]), float(d.h_m[k]))
    dp = earth.C_n_e(float(d.lat_rad[k]), float(d.lon_rad[k])).T @ (p_est - p_true)
    dv = np.asarray(e.v_n, float) - d.v_n[k]
    return float(np.hypot(dp[0], dp[1])), float(np.hypot(dv[0], dv[1]))


def run(seed: int, odometry: bool, outage: bool, duration_s: float = 180.0, outage_start_s: float = 120.0,
        outage_s: float = 30.0, scale_error: float = 0.02) -> dict:
    kw = {}
    if outage:
        kw.update(gnss_outage_start_s=outage_start_s, gnss_outage_duration_s=outage_s)
    if odometry:
        kw.update(wheel_speed_sigma_m_s=WHEEL_SIGMA_M_S, wheel_scale_error=scale_error)
    d = ia.simulate("car", seed=seed, duration_s=duration_s, **kw)
    r = ia.align(d, vehicle="car")
    t, e, s3 = r.t_s, np.abs(r.rpy_err_deg[:, 2]), r.sigma3_deg[:, 2]
    t0, t1 = outage_start_s, outage_start_s + outage_s
    win = (t >= t0) & (t <= t1 + 10.0)
    gnss = (t >= 60.0) & (t < t0)
    flag_t = r.metrics.get("aligned_first_raised_at_s")
    after = t >= (flag_t if flag_t is not None else math.inf)
    i0 = int(np.argmin(np.abs(t - t0)))
    k0, k1 = (int(np.argmin(np.abs(d.t_s - x))) for x in (t0, t1))
    dist = float(np.sum(np.linalg.norm(d.v_n[k0:k1], axis=1)) / d.imu_spec.rate_hz)
    dist_gnss = float(np.sum(np.linalg.norm(d.v_n[:k0], axis=1)) / d.imu_spec.rate_hz)
    pos, vel = _enu_errors(r, d, t1 - 0.05)
    dg = r.diagnostics
    return dict(
        seed=seed, odometry=odometry, outage=outage,
        yaw_err_max_deg=float(e[win].max()), yaw_3s_min_deg=float(s3[win].min()),
        yaw_ratio_max=float((e[win] / s3[win]).max()), yaw_3s_at_start_deg=float(s3[i0]),
        yaw_err_gnss_mean_deg=float(e[gnss].mean()), yaw_err_after_flag_mean_deg=float(e[after].mean()) if after.any() else math.nan,
        coverage=float(np.mean(e[after] <= s3[after])) if after.any() else math.nan,
        pos_err_end_m=pos, vel_err_end_m_s=vel, outage_dist_m=dist,
        scale=float(dg.get("wheel_scale", "nan")), scale_sigma=float(dg.get("wheel_scale_sigma", "nan")),
        scale_windows=int(dg.get("wheel_scale_windows", 0)), scale_floor=math.sqrt(2.0) * GNSS_SIGMA_M / max(dist_gnss, 1.0),
        wheel_fused=int(r.counters.get("wheel_speed_fused", 0)),
        wheel_rejected=int(r.counters.get("wheel_speed_filter_rejected", 0)),
        t_flag_s=flag_t, gyro_drift_deg=d.imu_spec.gyro_bias_deg_h * outage_s / 3600.0,
    )


def _fmt(x, f="{:.3f}"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f.format(x)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--outage-start", type=float, default=120.0)
    ap.add_argument("--outage-s", type=float, default=30.0)
    ap.add_argument("--scale-error", type=float, default=0.02)
    a = ap.parse_args(argv)
    rows = []
    print("| seed | odometry | outage | yaw err max [deg] | yaw 3-sigma min [deg] | err/3-sigma max | yaw 3-sigma at "
          "outage start (floor) | mean yaw err, GNSS [deg] | mean yaw err after flag [deg] | coverage | pos drift [m] "
          "(yaw 1-sigma x distance; scale 1-sigma x distance) | vel err [m/s] | scale (truth) | scale 1-sigma (floor) | flag [s] |")
    print("|" + "---|" * 15)
    for seed in a.seeds:
        for odo in (False, True):
            for out in (False, True):
                r = run(seed, odo, out, a.duration, a.outage_start, a.outage_s, a.scale_error)
                rows.append(r)
                floor_ct = r["outage_dist_m"] * math.radians(r["yaw_3s_at_start_deg"] / 3.0)
                along = f"; {r['outage_dist_m'] * r['scale_sigma']:.2f}" if odo else ""
                print(f"| {seed} | {'yes' if odo else 'no'} | {'yes' if out else 'no'} | {r['yaw_err_max_deg']:.3f} "
                      f"| {r['yaw_3s_min_deg']:.3f} | {r['yaw_ratio_max']:.3f} | {r['yaw_3s_at_start_deg']:.3f} "
                      f"| {r['yaw_err_gnss_mean_deg']:.3f} | {_fmt(r['yaw_err_after_flag_mean_deg'])} "
                      f"| {_fmt(r['coverage'])} | {r['pos_err_end_m']:.2f} ({floor_ct:.2f}{along}) | {r['vel_err_end_m_s']:.3f} "
                      f"| {_fmt(r['scale'], '{:.4f}') if odo else '-'} ({1 + a.scale_error:.4f}) "
                      f"| {_fmt(r['scale_sigma'], '{:.4f}') if odo else '-'} ({r['scale_floor']:.4f}) "
                      f"| {_fmt(r['t_flag_s'], '{:.1f}')} |", flush=True)
    print(f"\ngyro bias {rows[0]['gyro_drift_deg'] * 3600 / a.outage_s:.0f} deg/h, unestimated over the outage: "
          f"{rows[0]['gyro_drift_deg']:.3f} deg")
    print("\nmedians over the seeds:")
    print("| odometry | outage | yaw err/3-sigma max (worst) | pos drift [m] | vel err [m/s] | mean yaw err, GNSS [deg] "
          "| mean yaw err after flag [deg] | coverage (worst) | |scale - truth| / sigma (worst) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for odo in (False, True):
        for out in (False, True):
            g = [r for r in rows if r["odometry"] == odo and r["outage"] == out]
            med = lambda k: float(np.median([r[k] for r in g]))  # noqa: E731
            z = [abs(r["scale"] - 1 - a.scale_error) / r["scale_sigma"] for r in g] if odo else None
            print(f"| {'yes' if odo else 'no'} | {'yes' if out else 'no'} | {med('yaw_ratio_max'):.3f} "
                  f"({max(r['yaw_ratio_max'] for r in g):.3f}) | {med('pos_err_end_m'):.2f} | {med('vel_err_end_m_s'):.3f} "
                  f"| {med('yaw_err_gnss_mean_deg'):.3f} | {med('yaw_err_after_flag_mean_deg'):.3f} "
                  f"| {med('coverage'):.3f} ({min(r['coverage'] for r in g):.3f}) "
                  f"| {'-' if z is None else f'{np.median(z):.2f} ({max(z):.2f})'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
