"""insalign-align: offline alignment of a contract bag or a simulated scenario with one in-motion core.

    insalign-align BAG --core iekf --rpy-error 10 10 60 [--duration 300] [--out-dir out]
    insalign-align --scenario ship --seed 0 --core pi_liekf --rpy-error 10 10 60

Starts from the truth plus the Euler error (or, when the bag has no truth, from --initial-rpy plus nothing), feeds
the events through filters.runner (the same code path as the ROS node), writes <out>/<name>_<core>.csv (time,
Euler estimate, Euler error, 3-sigma), a metrics JSON (RMSE, final error, time after which |yaw error| stays < 1
deg, NEES) and a PNG like the PI-LIEKF paper's Fig. 3.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="insalign-align", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", nargs="?", help="contract bag (insalign_ros.io.bag)")
    ap.add_argument("--scenario", help="simulate instead: ship, car, static, ...")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--core", default="iekf", help="liekf, pi_liekf, iekf, ekf (or any registered core)")
    ap.add_argument("--rpy-error", nargs=3, type=float, default=[10.0, 10.0, 60.0], metavar=("R", "P", "Y"))
    ap.add_argument("--initial-rpy", nargs=3, type=float, metavar=("R", "P", "Y"),
                    help="initial attitude guess [deg] when the data have no truth")
    ap.add_argument("--duration", type=float, default=None, help="seconds of data to use")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="core parameter override")
    ap.add_argument("--out-dir", default=".")
    ap.add_argument("--output-period", type=float, default=0.5)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--backtrack", type=int, default=0, metavar="N",
                    help="forward-backward alignment: N backward+forward passes over the stored window "
                         "(filters/backtrack.py; earth_iekf, liekf)")
    ap.add_argument("--backtrack-window", type=float, default=60.0, metavar="S",
                    help="stored alignment window after initialisation [s] (with --backtrack)")
    args = ap.parse_args(argv)
    if bool(args.bag) == bool(args.scenario):
        ap.error("give exactly one of BAG or --scenario")

    from ..core import earth
    from ..eval import metrics as MT
    from ..eval.plots import plot_euler_errors
    from ..filters.registry import make_core
    from ..filters.runner import run_offline

    params = {}
    for kv in args.param:
        k, _, v = kv.partition("=")
        try:
            params[k] = json.loads(v)
        except json.JSONDecodeError:
            params[k] = v
    try:
        core = make_core(args.core, params)
    except ValueError as exc:
        print(f"insalign-align: {exc}", file=sys.stderr)
        return 2
    if args.scenario:
        from ..sim.scenarios import make_scenario

        data = make_scenario(args.scenario, seed=args.seed, duration_s=args.duration)
        name = f"{args.scenario}_s{args.seed}"
    else:
        from ..io.bag import read_bag

        data = read_bag(args.bag)
        name = Path(args.bag).stem
        if args.duration is not None:
            from dataclasses import replace

            n = int(np.searchsorted(data.t_s, data.t_s[0] + args.duration, side="right"))
            m = int(np.searchsorted(data.gnss_t_s, data.t_s[n - 1], side="right"))
            data = replace(data, t_s=data.t_s[:n], omega_ib_b=data.omega_ib_b[:n], f_ib_b=data.f_ib_b[:n],
                           gnss_t_s=data.gnss_t_s[:m], gnss_p_e=data.gnss_p_e[:m], gnss_R_e=data.gnss_R_e[:m],
                           **({} if not data.has_truth else dict(
                               C_b_n=data.C_b_n[:n], lat_rad=data.lat_rad[:n], lon_rad=data.lon_rad[:n],
                               h_m=data.h_m[:n], v_n=data.v_n[:n])))
    init_C = None
    if not data.has_truth:
        if args.initial_rpy is None:
            ap.error("the data have no truth: give --initial-rpy R P Y [deg]")
        init_C = earth.C_b_n_from_rpy(*np.radians(args.initial_rpy))
    from tqdm import tqdm

    if args.backtrack > 0:
        from ..filters.backtrack import make_backtrackable, run_offline_backtrack

        if not data.has_truth:
            ap.error("--backtrack needs data with truth for the initial guess (not implemented for truth-free bags)")
        try:
            make_backtrackable(core)
        except ValueError as exc:
            print(f"insalign-align: {exc}", file=sys.stderr)
            return 2
        ests, bt = run_offline_backtrack(core, data, args.rpy_error, args.backtrack_window, args.backtrack,
                                         output_period_s=args.output_period)
        runner, core = bt.runner, bt.live
        print(f"backtracking: {bt.stats['window_samples']} samples x {args.backtrack} passes in "
              f"{bt.stats['pass_wall_s']:.2f} s", file=sys.stderr)
    else:
        with tqdm(total=data.n, desc=f"{args.core}", disable=args.no_progress, file=sys.stderr,
                  mininterval=1) as bar:
            ests, runner = run_offline(core, data, args.rpy_error if data.has_truth else [0, 0, 0],
                                       output_period_s=args.output_period, progress=bar, initial_C_b_n=init_C)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"{name}_{args.core}"
    t_init = float(data.t_s[0])
    if data.has_truth:
        r = MT.evaluate(args.core, ests, data.t_s, data.C_b_n, t_init)
    else:
        r = MT.evaluate(args.core, ests, np.array([e.stamp_s for e in ests]), np.array([e.C_b_n for e in ests]),
                        t_init)
        r.rpy_err_deg[:] = math.nan
        r.nees[:] = math.nan
    with open(f"{stem}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "roll_deg", "pitch_deg", "yaw_deg", "roll_err_deg", "pitch_err_deg", "yaw_err_deg",
                    "sigma3_e_deg", "sigma3_n_deg", "sigma3_u_deg", "nees"])
        for i in range(len(r.t_s)):
            w.writerow([f"{r.t_s[i]:.3f}", *(f"{x:.6f}" for x in r.rpy_est_deg[i]),
                        *(f"{x:.6f}" for x in r.rpy_err_deg[i]), *(f"{x:.6f}" for x in r.sigma3_deg[i]),
                        f"{r.nees[i]:.4f}"])
    summ = MT.summary(r) if data.has_truth else {"core": args.core, "duration_s": float(r.t_s[-1])}
    summ.update(data=name, rpy_error_deg=args.rpy_error, counters={**runner.counters, **getattr(core, "counters", {})})
    if hasattr(core, "diagnostics"):
        summ["diagnostics"] = core.diagnostics()
    Path(f"{stem}_metrics.json").write_text(json.dumps(summ, indent=2, default=float))
    plot_euler_errors([r], f"{stem}.png", title=f"{name}: {args.core}, initial error {args.rpy_error} deg")
    print(json.dumps({k: summ[k] for k in ("rmse_rpy_deg", "final_err_rpy_deg", "time_yaw_below_deg_s",
                                           "mean_nees_after_s") if k in summ}, default=float))
    print(f"wrote {stem}.csv, {stem}_metrics.json, {stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
