"""insalign-demo: scripted bringup over real DDS, launch-free (the README's main command).

Current stage: starts ``imu_sim_node`` (publisher) and ``imu_listener_node`` (subscriber) as two processes on a
private ROS_DOMAIN_ID with localhost-only discovery, and prints what crossed. Exit 0 on success, non-zero with a
reason otherwise; every wait has a timeout and both processes are stopped on every exit path.
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
                         params={"rate_hz": rate_hz, "count": count, "wait_for_subscribers": 1,
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="insalign-demo", description=__doc__.splitlines()[0])
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


if __name__ == "__main__":
    sys.exit(main())
