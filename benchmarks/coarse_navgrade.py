"""Coarse alignment on `static_navgrade` at 300 s: |azimuth error| against the bias floor and the combined floor
(bias + ARW limit, docs/static_alignment.md) and the reported 3-sigma, both methods, seeds 0..N-1 (not a unit test). Each run goes through ``ia.align`` (core ``coarse``, the truth turned by
90 deg about Up as the initial guess, which the coarse alignment does not use; 1-s outputs).

    nice .venv/bin/python benchmarks/coarse_navgrade.py --seeds 8
"""

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
from insalign_ros.filters.coarse import CoarseConfig  # noqa: E402
from insalign_ros.filters.static_model import (  # noqa: E402
    arw_azimuth_limit_rad, config_for_imu, physical_floor)
from insalign_ros.sim.error_model import NAVGRADE  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402
from static_sigma_r import static_run  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--duration-s", type=float, default=300.0)
    args = ap.parse_args(argv)
    print("| method | seed | \\|az err\\| [arcmin] | bias floor | combined floor | err / combined | 3-sigma [arcmin] |")
    print("|---|---|---|---|---|---|---|")
    summary = {}
    for method in ("inertial", "average"):
        rows = []
        for seed in range(args.seeds):
            sc = make_scenario("static_navgrade", seed=seed, duration_s=args.duration_s)
            fl = physical_floor(sc.C_b_n[0], sc.bias_gyro_b, sc.bias_acc_b, sc.lat_rad[0])["azimuth_rad"]
            comb = math.hypot(fl, arw_azimuth_limit_rad(NAVGRADE.arw_deg_sqrt_h, sc.lat_rad[0], args.duration_s))
            params = config_for_imu(CoarseConfig, NAVGRADE, method=method).to_dict()
            _, err, sig3 = static_run("coarse", sc, math.radians(90.0), 1e-3, params)  # the guess does not enter
            e = abs(err[-1, 2])
            rows.append((e, fl, comb, e <= sig3[-1, 2]))
            print(f"| {method} | {seed} | {math.degrees(e) * 60:.2f} | {math.degrees(fl) * 60:.2f} | "
                  f"{math.degrees(comb) * 60:.2f} | {e / comb:.2f} | {math.degrees(sig3[-1, 2]) * 60:.2f} |")
        r = np.array(rows)
        summary[method] = (int(np.sum(r[:, 0] <= 2 * r[:, 2])), int(np.sum(r[:, 0] <= 2 * r[:, 1])),
                           math.degrees(r[:, 0].mean()) * 60, math.degrees(r[:, 2].mean()) * 60, int(r[:, 3].sum()))
    for m, (n2c, n2b, me, mc, n3) in summary.items():
        print(f"{m}: within 2x combined floor {n2c}/{args.seeds}, within 2x bias floor {n2b}/{args.seeds}; "
              f"mean |err| {me:.2f} arcmin vs mean combined floor {mc:.2f}; inside the reported 3-sigma "
              f"{n3}/{args.seeds}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
