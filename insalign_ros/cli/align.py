"""insalign-align: offline alignment of a contract bag or a simulated scenario with any registered core.

    insalign-align BAG [--core auto|iekf|...] [--rpy-error 10 10 60 | --initial-rpy R P Y] [--duration 300] [--out-dir out]
    insalign-align drive.bag --imu-axes frd [--imu-mount-rpy-deg 0 0 90]   (a ROS 1 bag of an FRD driver)
    insalign-align --scenario ship --seed 0 --core pi_liekf --rpy-error 10 10 60 --imu-grade paper_ship
    insalign-align --scenario static --core pkf --param zupt_rate_hz=10
    insalign-align --scenario park_drive --core auto --session-param init_mode=sensors   (parked, then driving)
    insalign-align BAGS_DIR --core iekf [--workers 4 | --scheduler tcp://host:8786 | --serial] --out-dir out

A thin CLI over ``insalign_ros.align`` (the same AlignmentSession as alignment_node). BAG: a rosbag2 directory, an
.mcap file or a ROS 1 .bag; its sensor topics are found by type when it has one of each (io/topics.py), else named
with --imu-topic/--gps-topic/--vel-topic. The IMU's axes and mounting (--imu-axes, --imu-mount-rpy-deg: the node's
imu_axes and imu_mount_rpy_deg, the same conversion) turn its rates and specific forces into the vehicle FLU frame
once, as the bag is read; a mean specific force far from the vehicle's up axis is warned. Initialisation: with
``--initial-rpy`` from that guess; when the data have truth, from the truth plus ``--rpy-error``; otherwise (or with
``--session-param init_mode=sensors``) from the sensors alone (no guess: fixes, accelerometers, a yaw bank).
Static cores get zero-velocity updates from the session (``--session-param zupt_rate_hz=10``). Writes
<out>/<name>_<core>.csv (time, Euler estimate, error, 3-sigma, NEES, flag), a metrics JSON and a PNG: the errors
like the PI-LIEKF paper's Fig. 3 with truth, the estimate with its 3-sigma band and the flag without. Every user
error is one line on stderr and exit status 2 (a missing path: "not found: PATH"). Given a directory of bags, every
bag is aligned with the same options as an independent Dask task (cli/fleet.py): per-bag outputs in
<out>/<bag>/ and a summary table <out>/fleet_summary.csv (.md).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np

from ..core.stats import SIGMA3_UNKNOWN_DEG


def _sigma3_cell(x: float) -> str:
    return f"{x:.6f}" if x <= SIGMA3_UNKNOWN_DEG else "unknown"


def _kv(items: list[str], what: str) -> dict:
    out = {}
    for kv in items:
        k, sep, v = kv.partition("=")
        if not sep or not k:
            raise ValueError(f"{what}: expected KEY=VALUE, got {kv!r}")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv=None) -> int:
    from ..eval.parallel import pin_solver_threads

    pin_solver_threads()  # PI-LIEKF's LMI solver: one rayon thread
    ap = argparse.ArgumentParser(prog="insalign-align", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", nargs="?", help="contract bag (insalign_ros.io.bag), or a directory of bags (a fleet)")
    ap.add_argument("--scenario", help="simulate instead: ship, car, static, ...")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--core", default="auto", help="any registered core (insalign_ros.core_names()); default auto "
                                                   "(static while parked, in-motion iekf once it moves)")
    ap.add_argument("--rpy-error", nargs=3, type=float, default=None, metavar=("R", "P", "Y"),
                    help="initial Euler error added to the truth [deg] (data with truth; default 10 10 60)")
    ap.add_argument("--initial-rpy", nargs=3, type=float, metavar=("R", "P", "Y"),
                    help="initial attitude guess [deg] (yaw from East, CCW); used whether or not the data have truth")
    ap.add_argument("--duration", type=float, default=None, help="seconds of data to use")
    ap.add_argument("--imu-grade", default=None, metavar="GRADE",
                    help="IMU noise model (docs/imu_grades.md): consumer_mems, industrial_mems, tactical, navigation, "
                         "paper_ship, ...; default unknown_mems (conservative MEMS); --param overrides its fields")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="core parameter")
    ap.add_argument("--session-param", action="append", default=[], metavar="KEY=VALUE",
                    help="session parameter (insalign_ros.session.config.SessionConfig)")
    ap.add_argument("--aligned", action="append", default=[], metavar="KEY=VALUE",
                    help="an aligned-flag criterion, as the node's aligned.<KEY> (session/flag.py), e.g. hold_s=5")
    ap.add_argument("--fix-delay", type=float, default=0.0, metavar="S",
                    help="deliver each fix S seconds of data time after its stamp (receiver latency)")
    ap.add_argument("--imu-topic", default=None, help="sensor_msgs/Imu topic of the bag (default: /imu/data if "
                                                      "present, else the bag's one Imu topic)")
    ap.add_argument("--gps-topic", default=None, help="NavSatFix topic (default: /gps/fix if present, else the one)")
    ap.add_argument("--vel-topic", default=None,
                    help="GNSS velocity topic, TwistWithCovarianceStamped in ENU (default: /gps/vel if present, else "
                         "the one of that type, read when present; 'none': not read)")
    ap.add_argument("--imu-axes", choices=("flu", "frd"), default=None,
                    help="axes of the bag's Imu rates and accelerations: flu (x forward, y left, z up; REP 103; "
                         "default) or frd (x forward, y right, z down: SBG, VectorNav, ...); the node's imu_axes")
    ap.add_argument("--imu-mount-rpy-deg", nargs=3, type=float, default=None, metavar=("R", "P", "Y"),
                    help="roll, pitch, yaw [deg] of the IMU's FLU axes (after --imu-axes) in the vehicle FLU frame, "
                         "as a URDF joint base_link -> imu_link (default 0 0 0); the node's imu_mount_rpy_deg")
    ap.add_argument("--truth-topic", default=None, help="reference pose topic, any rate (default /ground_truth/pose)")
    ap.add_argument("--unknown-fix-sigma", type=float, default=None, metavar="M",
                    help="1-sigma per axis [m] for fixes with UNKNOWN covariance (default 1 m, as the node's gnss_sigma_m)")
    ap.add_argument("--out-dir", default=".")
    ap.add_argument("--output-period", type=float, default=0.5)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--backtrack", type=int, default=0, metavar="N",
                    help="forward-backward alignment: N backward+forward passes over the stored window "
                         "(filters/backtrack.py; earth_iekf, liekf)")
    ap.add_argument("--backtrack-window", type=float, default=60.0, metavar="S",
                    help="stored alignment window after initialisation [s] (with --backtrack)")
    g = ap.add_argument_group("a directory of bags (Dask tasks; insalign_ros.eval.parallel)")
    g.add_argument("--workers", type=int, default=0, help="LocalCluster worker processes (default: the CPU count)")
    g.add_argument("--scheduler", default="", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    g.add_argument("--serial", action="store_true", help="no Dask: the bags one after the other, in this process")
    g.add_argument("--ship-bags", action=argparse.BooleanOptionalAction, default=None,
                   help="send each bag to its worker as bytes and its outputs back (default: with --scheduler only; "
                        "for workers that do not share this file system)")
    argv = list(sys.argv[1:] if argv is None else argv)
    args = ap.parse_args(argv)
    if bool(args.bag) == bool(args.scenario):
        ap.error("give exactly one of BAG or --scenario")
    fleet = bool(args.bag) and Path(args.bag).is_dir() and not (Path(args.bag) / "metadata.yaml").exists()
    if not fleet and (args.workers or args.scheduler or args.serial or args.ship_bags is not None):
        ap.error("--workers/--scheduler/--serial/--ship-bags apply to a directory of bags")
    try:
        if args.bag and not Path(args.bag).exists():
            raise ValueError(f"not found: {args.bag}")
        if fleet:
            return _run_fleet(args, argv)
        return _run(args)
    except (ValueError, FileNotFoundError, KeyError) as exc:
        print(f"insalign-align: {exc}", file=sys.stderr)
        return 2


def _run_fleet(args, argv: list[str]) -> int:
    """Every bag under the directory ``args.bag`` with the other options of ``argv``; the summary table."""
    from .fleet import run_fleet

    drop_value = {"--out-dir", "--workers", "--scheduler"}
    rest, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in drop_value:
            skip = True
        elif a in ("--serial", "--ship-bags", "--no-ship-bags") or a == args.bag or a.split("=", 1)[0] in drop_value:
            continue
        else:
            rest.append(a)
    rows = run_fleet(main, args.bag, rest, args.out_dir, args.workers, args.scheduler, args.serial,
                     progress=not args.no_progress, ship_bags=args.ship_bags)
    bad = [r for r in rows if r["rc"] != 0]
    for r in bad:
        print(f"insalign-align: {r['bag']}: {r.get('error', '')}", file=sys.stderr)
    print(f"{len(rows) - len(bad)} of {len(rows)} bags aligned; wrote {Path(args.out_dir) / 'fleet_summary.csv'}")
    return 0 if not bad else 1


def _run(args) -> int:
    from tqdm import tqdm

    from ..session.offline import AlignResult, align, load_source

    from ..filters.registry import make_config
    from ..session.config import SessionConfig
    from ..session.flag import AlignedCriteria

    core_params = _kv(args.param, "--param")
    sp = _kv(args.session_param, "--session-param")
    if args.imu_grade is not None:
        sp["imu_grade"] = args.imu_grade
    SessionConfig.from_dict({"core": args.core, **sp})  # user errors before any work
    make_config(args.core, core_params)
    criteria = _kv(args.aligned, "--aligned")
    try:
        crit = AlignedCriteria(**criteria)
        crit.validate()
    except TypeError:
        names = [f.name for f in fields(AlignedCriteria)]
        raise ValueError(f"--aligned: unknown criterion {sorted(set(criteria) - set(names))}; one of "
                         f"{', '.join(names)}") from None
    reader = {k: v for k, v in (("imu_topic", args.imu_topic), ("gps_topic", args.gps_topic), ("vel_topic", args.vel_topic),
                                ("truth_topic", args.truth_topic), ("unknown_fix_sigma_m", args.unknown_fix_sigma))
              if v is not None}
    if not args.bag and (reader or args.imu_axes is not None or args.imu_mount_rpy_deg is not None):
        raise ValueError("--imu-topic/--gps-topic/--vel-topic/--truth-topic/--unknown-fix-sigma/--imu-axes/"
                         "--imu-mount-rpy-deg apply to a bag")
    rep: dict = {"warnings": []}
    if args.bag:  # a topic not named: found by type (io/topics.py)
        reader = {"imu_topic": None, "gps_topic": None, "vel_topic": None, **reader, "report": rep}
    data = load_source(args.bag or args.scenario, args.duration, args.seed, **reader)
    warnings: list[str] = []
    if args.bag:
        data = _bag_checks(data, args, rep, sp, warnings)
    name = Path(args.bag).stem if args.bag else f"{args.scenario}_s{args.seed}"
    if args.initial_rpy is not None:
        sp.update(init_mode="guess", initial_rpy_deg=list(args.initial_rpy))
        rpy_error = None
    elif data.has_truth and (args.rpy_error is not None or "init_mode" not in sp):
        rpy_error = list(args.rpy_error) if args.rpy_error is not None else [10.0, 10.0, 60.0]
        sp.update(init_mode="truth", init_rpy_error_deg=rpy_error)
    else:  # no truth (or --session-param init_mode=sensors): no guess needed, the session initialises from the sensors
        rpy_error = None
        sp.setdefault("init_mode", "sensors")
    if args.backtrack > 0:
        sp.update(backtrack_passes=args.backtrack, backtrack_window_s=args.backtrack_window,
                  backtrack_budget_s=math.inf)
    sp.setdefault("output_period_s", args.output_period)
    with tqdm(total=data.n, desc=args.core, disable=args.no_progress, file=sys.stderr, mininterval=1) as bar:
        r: AlignResult = align(data, core=args.core, core_params=core_params, fix_delay_s=args.fix_delay,
                               progress=bar, criteria=criteria, **sp)
    if args.backtrack > 0:
        d = r.diagnostics
        print(f"backtracking: {d.get('backtrack_window_samples')} samples x {args.backtrack} passes in "
              f"{float(d.get('backtrack_pass_wall_s', float('nan'))):.2f} s", file=sys.stderr)
    if not len(r.t_s):
        used = rep.get("topics", {})
        raise ValueError(f"no estimate: the session never initialised ({r.diagnostics.get('message')})"
                         + (f"; topics read: {used}" if used else ""))
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"{name}_{args.core}"
    with open(f"{stem}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "roll_deg", "pitch_deg", "yaw_deg", "roll_err_deg", "pitch_err_deg", "yaw_err_deg",
                    "sigma3_roll_deg", "sigma3_pitch_deg", "sigma3_yaw_deg", "nees", "aligned", "status", "event"])
        from ..session.offline import event_column

        ev = event_column(r.t_s, r.metrics.get("events", []))
        for i in range(len(r.t_s)):
            w.writerow([f"{r.t_s[i]:.3f}", *(f"{x:.6f}" for x in r.rpy_deg[i]), *(f"{x:.6f}" for x in r.rpy_err_deg[i]),
                        *(_sigma3_cell(x) for x in r.sigma3_deg[i]), f"{r.nees[i]:.4f}", int(r.aligned[i]),
                        r.status[i], ev[i]])
    summ = dict(r.metrics)
    summ.update(data=name, init_mode=sp["init_mode"], imu_grade=sp.get("imu_grade", SessionConfig().imu_grade),
                final_rpy_deg=r.rpy_deg[-1].tolist(),
                final_3sigma_deg=[None if not x <= SIGMA3_UNKNOWN_DEG else float(x) for x in r.sigma3_deg[-1]],
                final_aligned=bool(r.aligned[-1]), aligned_criteria=crit.to_dict(),
                warnings=warnings, counters=r.counters,
                diagnostics={k: v for k, v in r.diagnostics.items() if k.startswith("core.")})
    if rpy_error is not None:
        summ["rpy_error_deg"] = rpy_error
    elif args.initial_rpy is not None:
        summ["initial_rpy_deg"] = list(args.initial_rpy)
    if args.bag:
        summ.update(topics=rep.get("topics", {}), imu_axes=args.imu_axes or "flu",
                    imu_mount_rpy_deg=list(args.imu_mount_rpy_deg or (0.0, 0.0, 0.0)))
    Path(f"{stem}_metrics.json").write_text(json.dumps(summ, indent=2, default=_json_default))
    start = (f"initial error {rpy_error} deg" if rpy_error is not None else
             f"initial guess {list(args.initial_rpy)} deg" if args.initial_rpy is not None else "from sensors")
    if not args.no_plot and not data.has_truth:
        from ..eval.plots import plot_estimate

        plot_estimate(r.t_s, r.rpy_deg, r.sigma3_deg, r.aligned, f"{stem}.png",
                      title=f"{name}: {args.core}, {start}, no truth")
    elif not args.no_plot:
        from ..eval import metrics as MT
        from ..eval.plots import plot_euler_errors

        res = MT.evaluate(args.core, r.estimates, data.t_s, data.C_b_n, r.init_t_s)
        title = f"{name}: {args.core}, {start}"
        plot_euler_errors([res], f"{stem}.png", title=title)
    keys = ("rmse_rpy_deg", "final_err_rpy_deg", "time_yaw_below_deg_s", "mean_nees_after_s",
            "aligned_first_raised_at_s")
    line = {k: summ[k] for k in keys if k in summ}
    line.update(final_rpy_deg=summ["final_rpy_deg"], final_3sigma_deg=summ["final_3sigma_deg"],
                final_aligned=summ["final_aligned"])
    print(json.dumps(line, default=_json_default))
    print(f"wrote {stem}.csv, {stem}_metrics.json" + ("" if args.no_plot else f", {stem}.png"))
    return 0


def _bag_checks(data, args, rep: dict, sp: dict, warnings: list):
    """The input boundary of a bag: the topics read (said on stderr), a fix to start from, the IMU turned into
    the vehicle FLU frame once (the node's conversion: nodes/conversions.imu_to_vehicle_matrix), gravity where
    the axes put it (a warning naming the option otherwise). Returns the converted data."""
    from ..io.topics import listing
    from ..io.validation import check_gravity_axis

    used, bag_topics = rep.get("topics", {}), rep.get("bag_topics", {})
    if args.gps_topic is not None and used.get("gps") is None:
        raise ValueError(f"no topic {args.gps_topic!r} (--gps-topic) in {args.bag}; its topics: {listing(bag_topics)}")
    if args.vel_topic is not None and args.vel_topic.lower() not in ("", "none") and used.get("vel") is None:
        print(f"insalign-align: warning: no topic {args.vel_topic!r} (--vel-topic) in {args.bag}: fixes only",
              file=sys.stderr)  # the velocity is optional
    print("insalign-align: topics: " + ", ".join(f"{k} {v or '-'}" for k, v in used.items()), file=sys.stderr)
    if not data.gnss_valid_mask.any() and "static_position_deg_m" not in sp:
        why = (f"no valid fix on {used['gps']}" if used.get("gps") else
               "no GNSS fix topic: the bag has no sensor_msgs/msg/NavSatFix (name one with --gps-topic)")
        raise ValueError(f"{args.bag}: {why}: nothing to initialise the position from; its topics: "
                         f"{listing(bag_topics)}")
    axes = args.imu_axes or "flu"
    if args.imu_axes is not None or args.imu_mount_rpy_deg is not None:
        data = _to_vehicle(data, axes, args.imu_mount_rpy_deg or (0.0, 0.0, 0.0))
    why = check_gravity_axis(data.f_ib_b[data.imu_valid_mask], axes)
    if why:
        warnings.append(why)
        print(f"insalign-align: warning: {why}", file=sys.stderr)
    return data


def _to_vehicle(data, imu_axes: str, imu_mount_rpy_deg):
    """Rates, specific forces (and the metadata's biases) from the driver's axes to the vehicle FLU frame."""
    from dataclasses import replace

    from ..nodes.conversions import imu_to_vehicle, imu_to_vehicle_matrix

    C_s_v = imu_to_vehicle_matrix(imu_axes, imu_mount_rpy_deg)
    omega_ib_v, f_ib_v = imu_to_vehicle(data.omega_ib_b, data.f_ib_b, C_s_v)
    rot = lambda v: None if v is None else np.asarray(v, float) @ C_s_v.T  # noqa: E731
    return replace(data, omega_ib_b=omega_ib_v, f_ib_b=f_ib_v, bias_gyro_b=rot(data.bias_gyro_b),
                   bias_acc_b=rot(data.bias_acc_b), omega_ib_b_true=rot(data.omega_ib_b_true),
                   f_ib_b_true=rot(data.f_ib_b_true))


def _json_default(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


if __name__ == "__main__":
    sys.exit(main())
