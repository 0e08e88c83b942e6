"""Monte-Carlo check of the aligned flag (session/flag.py) on the ship scenario, no ROS.

Each run: ship scenario (seed k), core initialised from the truth plus a random Euler error (roll, pitch
U(-5, 5) deg, yaw U(-60, 60) deg), the session the node runs (``ia.align``), the session's flag at the node's
default output rate (10 Hz data time) with the node's default criteria. Runs are Dask tasks (benchmarks/sweep.py:
``--workers N``, ``--scheduler tcp://host:8786``, ``--serial``).

Reported: runs in which the flag was ever up while the true |yaw error| exceeded the yaw threshold (false aligned),
the number of such 10 Hz epochs, and the delay from the time the true |yaw error| falls below the threshold for
good to the first rise of the flag (median, max).

    .venv/bin/python benchmarks/aligned_flag_mc.py [--runs 20] [--core liekf] [--duration-s 300] [--workers 2]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from insalign_ros.session.flag import AlignedCriteria  # noqa: E402


def one_run(data, seed: int, core_name: str, duration_s: float, criteria: AlignedCriteria, rate_s: float = 0.1,
            yaw_range_deg: float = 60.0, yaw_hypotheses: int = 1) -> dict:
    """One seeded run through the session path users take (``ia.align``): truth init plus the random error, the
    session's aligned flag at ``rate_s`` of data time (a Dask task on the seed's simulated ship ``data``,
    ``sweep.shared_scenario``)."""
    import insalign_ros as ia
    from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE

    rng = np.random.default_rng(10_000 + seed)
    err0 = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-yaw_range_deg, yaw_range_deg)])
    r = ia.align(data, core=core_name, core_params={"yaw_hypotheses": yaw_hypotheses} if yaw_hypotheses > 1 else {},
                 init_mode="truth", init_rpy_error_deg=err0.tolist(), output_period_s=rate_s,
                 criteria=criteria.to_dict(), imu_grade=SCENARIO_IMU_GRADE["ship"])
    keep = r.t_s > data.t_s[0]  # the initial estimate is not judged
    ts, yaw_err, up, s3 = r.t_s[keep], r.rpy_err_deg[keep, 2], r.aligned[keep], r.sigma3_deg[keep, 2]
    ts, yaw_err, up = np.array(ts), np.abs(np.array(yaw_err)), np.array(up)
    thr = criteria.yaw_3sigma_deg
    false_epochs = int(np.sum(up & (yaw_err > thr)))
    above = np.nonzero(yaw_err > thr)[0]
    t_below = ts[above[-1] + 1] if len(above) and above[-1] + 1 < len(ts) else (ts[0] if not len(above) else None)
    t_raise = ts[np.argmax(up)] if up.any() else None
    delay = (t_raise - t_below) if (t_raise is not None and t_below is not None) else None
    return {"seed": seed, "err0": err0, "false_epochs": false_epochs, "t_below": t_below, "t_raise": t_raise,
            "delay": delay, "final_yaw_err": yaw_err[-1], "final_up": bool(up[-1]), "final_s3": s3[-1],
            "max_err_while_up": float(yaw_err[up].max()) if up.any() else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--core", default="liekf")
    ap.add_argument("--duration-s", type=float, default=300.0)
    ap.add_argument("--yaw-3sigma-deg", type=float, default=AlignedCriteria.yaw_3sigma_deg)
    ap.add_argument("--yaw-range-deg", type=float, default=60.0, help="initial yaw error ~ U(-R, R) [deg]")
    ap.add_argument("--yaw-hypotheses", type=int, default=1, help="bank of K yaw hypotheses (1 = one filter)")
    ap.add_argument("--hold-s", type=float, default=AlignedCriteria.hold_s, help="the criteria's hold_s")
    import sweep

    sweep.add_arguments(ap)
    args = ap.parse_args(argv)
    crit = AlignedCriteria(yaw_3sigma_deg=args.yaw_3sigma_deg, hold_s=args.hold_s)
    t0 = time.monotonic()
    tasks = [(sweep.shared_scenario("ship", s, args.duration_s), s, args.core, args.duration_s, crit, 0.1, args.yaw_range_deg, args.yaw_hypotheses)
             for s in range(args.runs)]
    rows = sweep.run_tasks(one_run, tasks, args, desc="aligned-flag MC")
    print(f"aligned flag, {args.runs} ship runs x {args.duration_s:g} s, core {args.core}, yaw error "
          f"U(-{args.yaw_range_deg:g}, {args.yaw_range_deg:g}) deg, {args.yaw_hypotheses} yaw hypotheses, "
          f"criteria {crit.to_dict()}")
    print("| seed | initial error r/p/y [deg] | true |yaw err| < thr from [s] | flag first up [s] | delay [s] | "
          "false-aligned epochs | max |yaw err| while up [deg] | final |yaw err| / 3-sigma [deg] |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        f = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        print(f"| {r['seed']} | {r['err0'][0]:+.1f} / {r['err0'][1]:+.1f} / {r['err0'][2]:+.1f} | {f(r['t_below'])} | "
              f"{f(r['t_raise'])} | {f(r['delay'])} | {r['false_epochs']} | {r['max_err_while_up']:.2f} | "
              f"{r['final_yaw_err']:.2f} / {r['final_s3']:.2f} |")
    n_false = sum(r["false_epochs"] > 0 for r in rows)
    delays = [r["delay"] for r in rows if r["delay"] is not None]
    never = sum(r["t_raise"] is None for r in rows)
    print(f"\nthreshold |yaw err| {crit.yaw_3sigma_deg:g} deg: false-aligned runs {n_false}/{len(rows)} "
          f"({sum(r['false_epochs'] for r in rows)} epochs at 10 Hz); flag never up in {never} runs; "
          f"delay median {np.median(delays) if delays else float('nan'):.1f} s, "
          f"max {max(delays) if delays else float('nan'):.1f} s; {time.monotonic() - t0:.0f} s wall")
    print(f"sweep: {args.sweep_summary}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
