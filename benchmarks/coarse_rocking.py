"""Coarse alignment on a rocking parked car (issue 15, "Coarse on a rocking base"): does the reported 3-sigma cover the
error, for every method and window length, and is it not absurdly conservative on a quiet base?

For each seed, one run of the window's maximum length; the estimate at time T is the coarse alignment over the
window [0, T] (the core averages from its start). Per method x window: coverage (|error| <= 3-sigma on yaw and on both
level axes), median |error|, median 3-sigma, the datasheet-only 3-sigma (the covariance before issue 15), how many
runs said "no heading", and the physical floors b_acc/g and eps_east/(omega_ie cos lat) (medians over the seeds' drawn
biases). Aligned flag (session/flag.py criteria: 3-sigma thresholds held hold_s; the coarse core has no innovations,
so NIS is off and every second counts as a fresh update): epochs with the flag up and the error outside its 3-sigma,
and outside the flag's own bounds. Every run goes through ``ia.align``. Not a unit test (test/test_coarse_rocking.py runs a short case).

    nice .venv/bin/python benchmarks/coarse_rocking.py --seeds 25                      # rocking 0.2 deg, navgrade
    nice .venv/bin/python benchmarks/coarse_rocking.py --seeds 25 --rock-deg 0         # quiet navgrade
    nice .venv/bin/python benchmarks/coarse_rocking.py --seeds 25 --rock-deg 0 --scenario static   # quiet MEMS
"""

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from insalign_ros.core import earth  # noqa: E402
from insalign_ros.session.flag import AlignedCriteria, AlignedFlag  # noqa: E402
from insalign_ros.filters.base import AlignmentStatus  # noqa: E402
from insalign_ros.filters.coarse import CoarseConfig, coarse_align  # noqa: E402
from insalign_ros.filters.static_model import DEG_H, MG, config_for_imu, physical_floor  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402

WINDOWS_S = (10.0, 20.0, 30.0, 60.0, 120.0, 300.0)
R2D = 180.0 / math.pi


def record(params: dict, sc, az0_rad=math.radians(90.0), init_sigma_yaw_deg=100.0, offset_s=0.4):
    """Run the coarse core (config ``params``) over a scenario through ``ia.align`` (the truth turned by az0 about Up as
    the initial guess, which the coarse alignment does not use; outputs every 0.2 s of data time); keep every second
    at offset_s past the second (the scenario's 1.3 Hz sway makes whole multiples of 10 s whole periods, whose net
    rotation is zero): t [s], error psi (3,) [rad], 3-sigma (3,) [rad], the core's status."""
    import insalign_ros as ia

    r = ia.align(sc, core="coarse", core_params=params, init_mode="truth",
                 init_rpy_error_deg=[0.0, 0.0, math.degrees(az0_rad)],
                 init_sigma_rpy_deg=[2.0, 2.0, init_sigma_yaw_deg], output_period_s=0.2)
    out = []
    for o in r.outputs[1:]:  # the initial estimate is not a result
        t = o.stamp_s - float(sc.t_s[0])
        if abs(t - math.floor(t) - offset_s) > 1e-6:
            continue
        k = min(int(np.searchsorted(sc.t_s, o.stamp_s - 1e-9)), sc.n - 1)
        e = o.estimate
        out.append((float(o.stamp_s), earth.heading_error_enu_rad(e.C_b_n, sc.C_b_n[k]),
                    3.0 * np.sqrt(np.diag(e.P_att_n)), e.status))
    return out


def datasheet_3sigma(cfg: CoarseConfig, T_s: float, lat_rad: float, g: float = 9.80665) -> tuple[float, float]:
    """(level, azimuth) 3-sigma [rad] of the covariance before issue 15 (datasheet noise and biases only)."""
    sf = cfg.acc_vrw_m_s_sqrt_h / 60.0 / math.sqrt(T_s)
    sw = cfg.gyro_arw_deg_sqrt_h * math.pi / 180.0 / 60.0 / math.sqrt(T_s)
    w_h = earth.OMEGA_IE_RAD_S * math.cos(lat_rad)
    return (3 * math.hypot(sf, cfg.acc_bias_mg * MG) / g, 3 * math.hypot(sw, cfg.gyro_bias_deg_h * DEG_H) / w_h)


def flag_violations(rec, criteria: AlignedCriteria) -> tuple[int, int, int]:
    """(epochs with the flag up, of which error outside 3-sigma, of which error outside the flag's bounds)."""
    flag = AlignedFlag(criteria)
    up = out3 = outb = 0
    for t, err, s3, _ in rec:
        flag.on_update(t, True, 0.0)
        if flag.on_estimate(t, np.diag((s3 / 3.0) ** 2)):
            up += 1
            out3 += int(np.any(np.abs(err) > s3))
            outb += int(max(abs(err[0]), abs(err[1])) * R2D > criteria.roll_pitch_3sigma_deg
                        or abs(err[2]) * R2D > criteria.yaw_3sigma_deg)
    return up, out3, outb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=25)
    ap.add_argument("--scenario", default="static_navgrade")
    ap.add_argument("--rock-deg", type=float, default=0.2, help="rms rocking (rock_amp_deg) [deg]")
    ap.add_argument("--windows", type=float, nargs="*", default=list(WINDOWS_S))
    args = ap.parse_args(argv)
    dur = max(args.windows)
    criteria = AlignedCriteria(nis_window=0)
    rows = {}
    flags = {}
    floors = []
    for seed in range(args.seeds):
        sc = make_scenario(args.scenario, seed=seed, duration_s=dur, rock_amp_deg=args.rock_deg)
        fl = physical_floor(sc.C_b_n[0], sc.bias_gyro_b, sc.bias_acc_b, sc.lat_rad[0])
        floors.append((fl["level_rad"], fl["azimuth_rad"]))
        for method in ("average", "inertial"):
            cfg = config_for_imu(CoarseConfig, sc.imu_spec, method=method)
            rec = record(cfg.to_dict(), sc)
            f = flags.setdefault(method, np.zeros(3, int))
            f += flag_violations(rec, criteria)
            t = np.array([r[0] for r in rec])
            for W in args.windows:  # the record nearest W (W + 0.4 s)
                t_, err, s3, status = rec[int(np.argmin(np.abs(t - W)))]
                lvl_ds, az_ds = datasheet_3sigma(cfg, t_, sc.lat_rad[0])
                k = int(round(t_ / float(sc.t_s[1] - sc.t_s[0])))
                triad = coarse_align(sc.f_ib_b[1:k + 1].mean(0), sc.omega_ib_b[1:k + 1].mean(0))
                triad_yaw = abs(earth.heading_error_enu_rad(triad, sc.C_b_n[k])[2])
                given = status is AlignmentStatus.ALIGNED
                rows.setdefault((method, W), []).append(
                    (bool(np.all(np.abs(err) <= s3)), max(abs(err[0]), abs(err[1])), abs(err[2]), max(s3[0], s3[1]),
                     s3[2], not given,
                     bool(max(abs(err[0]), abs(err[1])) <= lvl_ds and abs(err[2]) <= az_ds), lvl_ds, az_ds,
                     triad_yaw, given and bool(np.all(np.abs(err) <= s3))))
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    fl = np.median(np.array(floors), axis=0)
    print(f"scenario {args.scenario}, rocking {args.rock_deg} deg rms (0.5-2 Hz, lever 0.5 m), {args.seeds} seeds; "
          f"floors (median over seeds): level b_acc/g {fl[0] * R2D * 60:.3f} arcmin, azimuth "
          f"eps_E/(W cos lat) {fl[1] * R2D * 60:.2f} arcmin")
    print("| method | window [s] | coverage (3-sigma, all axes) | median \\|yaw err\\| [deg] | median yaw 3-sigma [deg] | "
          "median \\|level err\\| [deg] | median level 3-sigma [deg] | no heading (covered when given) | "
          "datasheet-only: coverage, yaw 3-sigma, level 3-sigma [deg] | TRIAD yaw err median (max) [deg] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    worst = 1.0
    for (method, W), r in rows.items():
        a = np.array(r, float)
        cov = a[:, 0].mean()
        worst = min(worst, cov)
        print(f"| {method} | {W:g} | {int(a[:, 0].sum())}/{len(a)} ({100 * cov:.0f} %) | {np.median(a[:, 2]) * R2D:.3f} | "
              f"{np.median(a[:, 4]) * R2D:.3f} | {np.median(a[:, 1]) * R2D:.4f} | {np.median(a[:, 3]) * R2D:.4f} | "
              f"{int(a[:, 5].sum())} ({int(a[:, 10].sum())}/{len(a) - int(a[:, 5].sum())}) | "
              f"{int(a[:, 6].sum())}/{len(a)}, {np.median(a[:, 8]) * R2D:.3f}, {np.median(a[:, 7]) * R2D:.4f} | "
              f"{np.median(a[:, 9]) * R2D:.2f} ({np.max(a[:, 9]) * R2D:.2f}) |")
    for method, (up, out3, outb) in flags.items():
        print(f"aligned flag ({method}; 3-sigma <= {criteria.roll_pitch_3sigma_deg:g}/{criteria.yaw_3sigma_deg:g} deg "
              f"held {criteria.hold_s:g} s, NIS off): up in {up} of the 1-s epochs; error outside its 3-sigma while up: "
              f"{out3}; outside the flag's bounds while up: {outb}")
    print(f"worst coverage over method x window: {100 * worst:.0f} % (acceptance: >= 95 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
