"""insalign-demo: scripted bringup over real DDS, launch-free (the README's main command).

Starts ``imu_sim_node`` and ``alignment_node`` as two processes on a private ROS_DOMAIN_ID with localhost-only
discovery, runs a scenario (``ship`` by default, 300 s of data at rate factor 6: about a minute) or replays a bag with the
node's defaults (``core: auto``, initialised from the sensors: no ground truth, no guess; ``--init-error-deg`` starts
from the simulator's truth plus that error instead, ``--initial-rpy-deg`` from a guess for a bag),
waits until the node is ready (it subscribes once its numba kernels are compiled: docs/install.md; the simulator
publishes once it has a subscriber: no fixed sleep), prints a live one-line status and a final table (time to
aligned, final Euler errors and 3-sigma per axis, messages sent / received / rejected / dropped). Exit 0 on success, 1 with the reason otherwise; every wait has a timeout and
both processes are stopped on every exit path.

``insalign-demo --count N`` runs the IMU transport check instead (imu_sim_node ``source:=rest`` ->
imu_listener_node, values checked against gravity and the Earth rate).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core import earth
from ..core.stats import SIGMA3_UNKNOWN_DEG
from .bringup import isolated_ros_env, start_node, stop_nodes, wait_for_exit

QOS_CHOICES = ("sensor_data", "reliable")  # as insalign_ros/nodes/qos.py (not imported: it needs rclpy)

SUMMARY_PREFIX = "IMU_SUMMARY "  # printed by imu_listener_node


def parse_summary(text: str) -> dict | None:
    for line in reversed(text.splitlines()):
        if line.startswith(SUMMARY_PREFIX):
            return json.loads(line[len(SUMMARY_PREFIX):])
    return None


def run_pub_sub(count: int, rate_hz: float, timeout_s: float, log_dir: Path, domain_id: int | None = None,
                pub_qos: str = "reliable", sub_qos: str = "sensor_data", site: dict | None = None) -> dict:
    """Publisher + subscriber in two processes; returns the listener's summary plus bookkeeping.

    QoS defaults follow REP 2003 (reliable publisher, sensor-data subscriber); see insalign_ros/nodes/qos.py.
    """
    env = isolated_ros_env(domain_id)
    nodes = []
    t0 = time.monotonic()
    try:
        listener = start_node("insalign_ros.nodes.imu_listener_node", env,
                              params={"expected_count": count, "timeout_s": timeout_s, "qos": sub_qos}, log_dir=log_dir)
        nodes.append(listener)
        sim = start_node("insalign_ros.nodes.imu_sim_node", env,
                         params={"source": "rest", "rate_hz": rate_hz, "count": count, "wait_for_subscribers": 1,
                                 "wait_timeout_s": timeout_s, "qos": pub_qos, **(site or {})}, log_dir=log_dir)
        nodes.append(sim)
        rc = wait_for_exit(listener, timeout_s + 10.0)
        sim_rc = wait_for_exit(sim, 5.0)
        summary = parse_summary(listener.output()) or {}
        summary.update(listener_rc=rc, sim_rc=sim_rc, domain_id=int(env["ROS_DOMAIN_ID"]), wall_s=time.monotonic() - t0,
                       pids=[n.popen.pid for n in nodes])
        return summary
    finally:
        stop_nodes(nodes)


def expected_norms(site: dict) -> tuple[float, float]:
    """(|f_ib_b| [m/s^2], |omega_ib_b| [rad/s]) of a body at rest at ``site``: gravity and Earth rate (core/earth.py)."""
    p_e = earth.geodetic_to_ecef(math.radians(site["lat_deg"]), math.radians(site["lon_deg"]), site["h_m"])
    return float(np.linalg.norm(earth.gravity_e(p_e))), earth.OMEGA_IE_RAD_S


def transport_check_main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="insalign-demo --count N", description="IMU transport check")
    ap.add_argument("--count", type=int, default=500, help="IMU messages to send (default 500)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="IMU rate [Hz] (default 100)")
    ap.add_argument("--timeout-s", type=float, default=60.0, help="give up after this many seconds (default 60)")
    ap.add_argument("--pub-qos", choices=QOS_CHOICES, default="reliable", help="imu_sim_node QoS (REP 2003: reliable)")
    ap.add_argument("--sub-qos", choices=QOS_CHOICES, default="sensor_data",
                    help="imu_listener_node QoS (REP 2003: sensor_data)")
    ap.add_argument("--lat-deg", type=float, default=49.0, help="site latitude [deg] (default 49)")
    ap.add_argument("--lon-deg", type=float, default=8.4, help="site longitude [deg] (default 8.4)")
    ap.add_argument("--h-m", type=float, default=120.0, help="site ellipsoidal height [m] (default 120)")
    ap.add_argument("--log-dir", type=Path, default=None, help="keep node logs here (default: a temp dir)")
    args = ap.parse_args(argv)
    if args.count < 1 or not (0.0 < args.rate_hz <= 2000.0) or args.timeout_s <= 0.0:
        ap.error("need --count >= 1, 0 < --rate-hz <= 2000, --timeout-s > 0")
    site = {"lat_deg": args.lat_deg, "lon_deg": args.lon_deg, "h_m": args.h_m}
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="insalign-demo-"))
    print(f"[insalign-demo] imu_sim_node -> imu_listener_node over Fast DDS, {args.count} Imu at {args.rate_hz:g} Hz "
          f"(pub {args.pub_qos}, sub {args.sub_qos})")
    s = run_pub_sub(args.count, args.rate_hz, args.timeout_s, log_dir, pub_qos=args.pub_qos, sub_qos=args.sub_qos,
                    site=site)
    print(f"[insalign-demo] ROS_DOMAIN_ID={s['domain_id']} (localhost discovery), node logs in {log_dir}")
    if not s.get("count"):
        print(f"[insalign-demo] FAILED: nothing crossed (imu_listener_node rc={s.get('listener_rc')}, "
              f"imu_sim_node rc={s.get('sim_rc')}); last lines of the node logs in {log_dir}:")
        for log in sorted(log_dir.glob("*.log")):
            for line in log.read_text(errors="replace").splitlines()[-3:]:
                print(f"  {log.stem}: {line[:200]}")
        return 1
    g_m_s2, w_rad_s = expected_norms(site)
    f_err = abs(s["mean_f_norm_m_s2"] - g_m_s2)
    w_err = abs(s["mean_omega_norm_rad_s"] - w_rad_s)
    rows = [
        ("messages received", f"{s['count']} / {args.count}"),
        ("frame_id", ", ".join(s["frame_ids"])),
        ("first / last stamp [s]", f"{s['first_stamp_s']:.6f} / {s['last_stamp_s']:.6f}"),
        ("data-time span [s]", f"{s['last_stamp_s'] - s['first_stamp_s']:.3f}"),
        ("data rate [Hz]", f"{s['data_rate_hz']:.3f}" if s["data_rate_hz"] else "-"),
        ("receive rate [Hz]", f"{s['rx_rate_hz']:.2f}" if s["rx_rate_hz"] else "-"),
        ("largest stamp gap [s]", f"{s['max_gap_s']:.4f}" if s["max_gap_s"] is not None else "-"),
        ("f_ib_b (first) [m/s^2]", "[" + ", ".join(f"{x:.6f}" for x in s["first_f_ib_b"]) + "]"),
        ("omega_ib_b (first) [rad/s]", "[" + ", ".join(f"{x:.4e}" for x in s["first_omega_ib_b"]) + "]"),
        ("mean |f_ib_b| [m/s^2]", f"{s['mean_f_norm_m_s2']:.6f}  (gravity here {g_m_s2:.6f})"),
        ("mean |omega_ib_b| [rad/s]", f"{s['mean_omega_norm_rad_s']:.6e}  (Earth rate {w_rad_s:.6e})"),
        ("wall time [s]", f"{s['wall_s']:.1f}"),
    ]
    for k, v in rows:
        print(f"  {k:<28} {v}")
    problems = []
    if s["count"] < args.count:
        problems.append(f"{args.count - s['count']} of {args.count} messages lost")
    if s["frame_ids"] != ["imu_link"]:
        problems.append(f"frame_id {s['frame_ids']} is not ['imu_link']")
    if f_err > 1e-9 * g_m_s2 or w_err > 1e-9 * w_rad_s or s["max_dev_f_m_s2"] or s["max_dev_omega_rad_s"]:
        problems.append("IMU values are not those of a body at rest")
    if s["out_of_order"]:
        problems.append(f"{s['out_of_order']} stamps out of order")
    if problems:
        print("[insalign-demo] FAILED: " + "; ".join(problems))
        return 1
    print("[insalign-demo] OK")
    return 0




# ---------------------------------------------------------------------------------------------- alignment demo
SIM_PREFIX = "SIM_SUMMARY "


def _sim_summary(text: str) -> dict:
    for line in reversed(text.splitlines()):
        if line.startswith(SIM_PREFIX):
            return json.loads(line[len(SIM_PREFIX):])
    return {}


def _fmt3(v) -> str:
    """Three angles [deg]; NaN (the node's ~/euler_error_3sigma of an unknown angle) as "unknown"."""
    return "  ".join(" unknown" if math.isnan(x) else f"{x:+8.3f}" for x in v) if v is not None else "   -"


def run_alignment(args, log_dir: Path, out=None) -> tuple[int, dict]:
    """imu_sim_node -> alignment_node over DDS; returns (exit code, result dict). Prints status and table."""
    import os

    out = out or sys.stdout
    env = isolated_ros_env(args.domain_id)
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        os.environ[k] = env[k]  # the in-process monitor joins the same isolated domain
    from ..nodes.monitor import AlignmentMonitor

    # the node's defaults: initialised from the sensors (level from the accelerometers, position and velocity from
    # the fixes, unknown heading); --init-error-deg: the simulator's truth plus that error (a filter demo)
    align_params = {"core": args.core, "init_mode": "sensors", "imu_qos": "reliable"}
    if args.init_error_deg is not None and not args.bag:
        align_params["init_from_ground_truth"] = True
        align_params["init_rpy_error_deg"] = str([float(x) for x in args.init_error_deg.split(",")])
    if args.yaw_hypotheses > 1:  # unknown heading: a bank of yaw hypotheses (filters/hypotheses.py)
        align_params["yaw_hypotheses"] = args.yaw_hypotheses
    if args.imu_grade or not args.bag:  # a simulated scenario: its IMU's grade (docs/imu_grades.md)
        from ..filters.imu_grade import SCENARIO_IMU_GRADE

        align_params["imu_grade"] = args.imu_grade or SCENARIO_IMU_GRADE.get(args.scenario, "unknown_mems")
    if args.bag and args.initial_rpy_deg is not None:
        align_params["init_mode"] = "guess"
        align_params["initial_rpy_deg"] = str([float(x) for x in args.initial_rpy_deg.split(",")])
    if args.bag and args.bag_truth_init:
        align_params["init_from_ground_truth"] = True
        align_params["init_rpy_error_deg"] = str([float(x) for x in (args.init_error_deg or "0,0,0").split(",")])
    # the simulator publishes once the node subscribed, which it does only after compiling its kernels (cold: a
    # minute or more): it waits as long as the demo waits for the node's readiness
    sim_params = {"rate_factor": args.rate_factor, "wait_for_subscribers": 1, "wait_timeout_s": args.ready_timeout_s,
                  "seed": args.seed, "qos_depth": 1000}
    if args.bag:
        sim_params.update(source="bag", bag_path=str(args.bag))
    else:
        sim_params.update(source="scenario", scenario=args.scenario, rate_hz=args.rate_hz)
    if args.duration_s:
        sim_params["duration_s"] = args.duration_s
    nodes = []
    res: dict = {"domain_id": int(env["ROS_DOMAIN_ID"])}
    t0 = time.monotonic()
    mon = AlignmentMonitor()
    try:
        align = start_node("insalign_ros.nodes.alignment_node", env, params=align_params, log_dir=log_dir)
        nodes.append(align)
        sim = start_node("insalign_ros.nodes.imu_sim_node", env, params=sim_params, log_dir=log_dir)
        nodes.append(sim)
        ready_s = _wait_ready(mon, align, sim, t0, args.ready_timeout_s, out)
        if ready_s is None:
            why = "died" if not align.alive() else f"not ready after {args.ready_timeout_s:g} s"
            return _fail(out, f"alignment_node {why} (it subscribes once its kernels are compiled)", log_dir), res
        res["ready_s"] = ready_s
        deadline = time.monotonic() + args.timeout_s
        last_line = 0.0
        while sim.alive() and time.monotonic() < deadline:
            time.sleep(0.1)
            if not align.alive():
                break
            if time.monotonic() - last_line > 0.5:
                last_line = time.monotonic()
                out.write("\r" + _status_line(mon, t0))
                out.flush()
        out.write("\r" + _status_line(mon, t0) + "\n")
        if sim.alive():
            return _fail(out, f"timeout after {args.timeout_s:g} s (imu_sim_node still running)", log_dir), res
        sim_rc = sim.popen.returncode
        summary = _sim_summary(sim.output())
        if sim_rc != 0 or not summary:
            return _fail(out, f"imu_sim_node exited with {sim_rc}", log_dir), res
        if not align.alive():
            return _fail(out, f"alignment_node died (rc {align.popen.returncode})", log_dir), res
        sent = summary["imu_sent"]
        # let the node drain its queue and publish a last diagnostics message
        mon.wait_for(lambda m: m.counter("imu_received") >= sent, 10.0)
        n0 = mon.diag_count
        mon.wait_for(lambda m: m.diag_count >= n0 + 2, 5.0)
        with mon.lock:
            d = dict(mon.diag)
            e = None if mon.euler_error is None else mon.euler_error[1].copy()
            s3 = None if mon.euler_3sigma is None else mon.euler_3sigma[1].copy()
        res.update(sent=sent, summary=summary, diag=d, euler_error_deg=e, euler_3sigma_deg=s3,
                   wall_s=time.monotonic() - t0)
        first_stamp = summary["first_stamp_ns"] * 1e-9 if summary.get("first_stamp_ns") else float("nan")
        t_al = float(d["aligned_first_raised_at_s"]) - first_stamp if "aligned_first_raised_at_s" in d else None
        res["time_to_aligned_s"] = t_al
        received = int(d.get("imu_received", 0))
        rejected = int(d.get("imu_rejected", 0))
        rows = [
            ("core / scenario", f"{args.core} / {args.bag or args.scenario}"),
            ("time to aligned [s data]", f"{t_al:.1f}" if t_al is not None else "never"),
            ("aligned at the end", d.get("aligned_at_last_output", d.get("aligned", "?"))),
            ("final Euler error [deg]  r p y", _fmt3(e) if e is not None else "- (no ground truth)"),
            ("final 3-sigma [deg]      r p y", _fmt3(s3)),
            ("IMU sent / received", f"{sent} / {received}"),
            ("IMU rejected / dropped", f"{rejected} / {max(sent - received, 0)}"),
            ("GNSS sent / accepted", f"{summary['fix_sent']} / {d.get('gnss_accepted', '0')}"),
            ("IMU callback median / p99 [us]", f"{d.get('imu_callback_median_us', '-')} / "
                                               f"{d.get('imu_callback_p99_us', '-')}"),
            ("wall time [s]", f"{res['wall_s']:.1f}"),
        ]
        for k, v in rows:
            print(f"  {k:<32} {v}", file=out)
        problems = []
        if t_al is None:
            problems.append(f"never aligned ({d.get('aligned_reason', '?')})")
        if e is not None and s3 is not None and not np.all(np.abs(e) <= s3):
            problems.append("final Euler error outside the published 3-sigma")
        if sent - received > 0.01 * sent:
            problems.append(f"{sent - received} of {sent} IMU messages lost")
        if problems:
            return _fail(out, "; ".join(problems), log_dir), res
        print(f"[insalign-demo] OK (ROS_DOMAIN_ID={res['domain_id']}, node logs in {log_dir})", file=out)
        return 0, res
    finally:
        stop_nodes(nodes)
        mon.close()


def _wait_ready(mon, align, sim, t0: float, timeout_s: float, out) -> float | None:
    """Wait until alignment_node subscribed to imu/data (it does so after compiling its kernels: session/warmup.py);
    return the seconds it took, None if it died or did not within ``timeout_s``. Prints a status line meanwhile."""
    deadline = t0 + timeout_s
    last_line = 0.0
    while time.monotonic() < deadline and align.alive():
        if mon.node.count_subscribers("/imu/data") >= 1:
            ready_s = time.monotonic() - t0
            out.write(f"\r[insalign-demo] alignment_node ready after {ready_s:.1f} s{' ' * 40}\n")
            out.flush()
            return ready_s
        if time.monotonic() - last_line > 0.5:
            last_line = time.monotonic()
            out.write(f"\r[{time.monotonic() - t0:5.1f} s] alignment_node starting (numba kernels load from the "
                      "cache, or compile on a cold one)   ")
            out.flush()
        time.sleep(0.1)
    out.write("\n")
    return None


def _status_line(mon, t0: float) -> str:
    with mon.lock:
        d = mon.diag
        e = mon.euler_error[1] if mon.euler_error is not None else None
        s3 = mon.euler_3sigma[1] if mon.euler_3sigma is not None else None
        state = d.get("state", "starting")
        yaw = f"yaw err {e[2]:+7.2f} deg" if e is not None else "yaw err    -   "
        sig = "3-sigma   -   " if s3 is None else (  # above 180 deg a 3-sigma says nothing about an angle
            f"3-sigma {s3[2]:6.2f} deg" if s3[2] <= SIGMA3_UNKNOWN_DEG else "3-sigma unknown   ")
        return (f"[{time.monotonic() - t0:5.1f} s] {state:<16} | {yaw} | {sig} | IMU rx {d.get('imu_received', 0):>6} "
                f"rej {d.get('imu_rejected', 0):>3} | GNSS {d.get('gnss_accepted', 0):>4}   ")


def _fail(out, reason: str, log_dir: Path) -> int:
    print(f"[insalign-demo] FAILED: {reason}; last lines of the node logs in {log_dir}:", file=out)
    for log in sorted(Path(log_dir).glob("*.log")):
        for line in log.read_text(errors="replace").splitlines()[-3:]:
            print(f"  {log.stem}: {line[:200]}", file=out)
    return 1


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(a.startswith(("--count", "--pub-qos", "--sub-qos")) for a in argv):
        return transport_check_main(argv)
    from ..filters.registry import core_names

    ap = argparse.ArgumentParser(prog="insalign-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="ship", help="simulated scenario (default ship)")
    ap.add_argument("--core", default="auto", choices=sorted(core_names()),
                    help="alignment core (default auto, the node's default)")
    ap.add_argument("--rate-factor", type=float, default=6.0, help="data time / wall time (default 6)")
    ap.add_argument("--duration-s", type=float, default=0.0, help="data time [s] (default: the scenario's)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="IMU rate [Hz] (default 100)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--init-error-deg", default=None, help="start from the simulator's truth plus this roll,pitch,"
                    "yaw error [deg] (e.g. 5,-5,30); default: from the sensors (no truth, no guess)")
    ap.add_argument("--yaw-hypotheses", type=int, default=1, help="in-motion cores: a bank of K yaw hypotheses for an "
                    "unknown heading (e.g. --yaw-hypotheses 8 --init-error-deg 5,-5,179; default 1 = one filter)")
    ap.add_argument("--imu-grade", default=None, help="alignment_node imu_grade (docs/imu_grades.md; default: the "
                    "scenario's IMU grade, unknown_mems for a bag)")
    ap.add_argument("--bag", type=Path, default=None, help="replay this contract rosbag2 instead of a scenario")
    ap.add_argument("--initial-rpy-deg", default=None, help="bag: start from this roll,pitch,yaw guess [deg] "
                    "(default: from the sensors)")
    ap.add_argument("--bag-truth-init", action="store_true", help="bag with truth: initialise from it + "
                    "--init-error-deg")
    ap.add_argument("--timeout-s", type=float, default=110.0, help="give up when the run takes longer than this once "
                    "the node is ready (default 110 s)")
    ap.add_argument("--ready-timeout-s", type=float, default=600.0, help="give up when alignment_node is not ready "
                    "(kernels compiled, imu/data subscribed) after this long (default 600 s: a cold cache on a busy "
                    "machine)")
    ap.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: a random one in 1..100)")
    ap.add_argument("--log-dir", type=Path, default=None, help="keep node logs here (default: a temp dir)")
    args = ap.parse_args(argv)
    if not 0 < args.rate_factor <= 1000 or args.timeout_s <= 0 or args.duration_s < 0 or args.ready_timeout_s <= 0:
        ap.error("need 0 < --rate-factor <= 1000, --timeout-s > 0, --ready-timeout-s > 0, --duration-s >= 0")
    for opt, val in (("--init-error-deg", args.init_error_deg), ("--initial-rpy-deg", args.initial_rpy_deg)):
        try:
            if val is not None and len([float(x) for x in val.split(",")]) != 3:
                raise ValueError
        except ValueError:
            ap.error(f"{opt} needs three numbers: roll,pitch,yaw")
    if args.bag is not None and not args.bag.exists():
        ap.error(f"--bag {args.bag}: no such file or directory")
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="insalign-demo-"))
    print(f"[insalign-demo] imu_sim_node ({args.bag or args.scenario}, rate factor {args.rate_factor:g}) -> "
          f"alignment_node ({args.core}) over Fast DDS, isolated domain, localhost discovery")
    rc, _ = run_alignment(args, log_dir)
    return rc


if __name__ == "__main__":
    sys.exit(main())
