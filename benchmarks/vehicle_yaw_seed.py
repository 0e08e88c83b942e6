"""Time to the aligned flag from the first motion, with and without the yaw seed from GNSS velocity (issue 25).

Simulated cars (sim/scenarios.py, default grade, position fixes at 1 Hz only, no velocity topic), offline through the
whole session (``ia.align``): ``car`` (moving from 1.8 s) and ``park_drive`` (parked, then driving), fixed seeds,
``vehicle: unknown`` (the default: the GSF assumes nothing, the pure GSF cannot reach ``valid`` on fix differences,
so no seed: as before the stage existed) against ``vehicle: car`` (the course constraint; the GSF seeds the
in-motion core when it is confident before the yaw bank).

Per run: the first flag after the first motion [s], the largest |yaw error| while the flag is up [deg], the yaw
coverage (|error| <= 3 sigma over the outputs from 10 s after the first motion), what seeded the yaw and when.

    nice python benchmarks/vehicle_yaw_seed.py --seeds 5
    nice python benchmarks/vehicle_yaw_seed.py --scenarios car --vehicles car --seeds 1 --duration 60
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from insalign_ros.session.offline import align, load_source  # noqa: E402

DURATION_S = {"car": 120.0, "park_drive": 150.0}


def first_motion_s(name: str, data) -> float:
    """The first stamp at which the true horizontal speed exceeds 0.5 m/s."""
    speed = np.linalg.norm(np.asarray(data.v_n)[:, :2], axis=1)
    return float(data.t_s[int(np.argmax(speed > 0.5))])


def run(name: str, seed: int, vehicle: str, duration_s: float) -> dict:
    data = load_source(name, duration_s, seed)
    r = align(data, vehicle=vehicle)
    t0 = first_motion_s(name, data)
    up = r.aligned & (r.t_s >= t0)
    t_flag = float(r.t_s[np.argmax(up)] - t0) if up.any() else math.nan
    err = r.rpy_err_deg[:, 2]
    max_up = float(np.max(np.abs(err[r.aligned]))) if r.aligned.any() else 0.0
    late = (r.t_s >= t0 + 10.0) & np.isfinite(err)
    cover = float(np.mean(np.abs(err[late]) <= r.sigma3_deg[late, 2])) if late.any() else math.nan
    d = r.diagnostics
    return {"scenario": name, "seed": seed, "vehicle": vehicle, "t_flag_s": t_flag, "max_err_up_deg": max_up,
            "coverage": cover, "seeded_by": d.get("yaw_seeded_by", ""), "final_err_deg": float(err[-1])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default="car,park_drive")
    ap.add_argument("--vehicles", default="unknown,car")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=None, help="seconds per run (default: per scenario)")
    a = ap.parse_args(argv)
    print("| scenario | vehicle | runs | flag after first motion [s] median / max | never flagged | max abs(yaw err) "
          "while flagged [deg] | coverage min | seeded by GSF |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.scenarios.split(","):
        for veh in a.vehicles.split(","):
            rows = [run(name, s, veh, a.duration or DURATION_S[name]) for s in range(a.seeds)]
            for row in rows:
                print("  ", row, file=sys.stderr, flush=True)
            t = np.array([row["t_flag_s"] for row in rows])
            ok = np.isfinite(t)
            med = float(np.median(t[ok])) if ok.any() else math.nan
            mx = float(np.max(t)) if ok.all() else math.inf
            print(f"| {name} | {veh} | {len(rows)} | {med:.1f} / {mx:.1f} | {int((~ok).sum())} | "
                  f"{max(row['max_err_up_deg'] for row in rows):.2f} | "
                  f"{np.nanmin([row['coverage'] for row in rows]):.3f} | "
                  f"{sum(row['seeded_by'].startswith('GNSS') for row in rows)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
