"""insalign-demo: scripted bringup over real DDS, launch-free (the README's main command).

Current stage: starts ``imu_sim_node`` (publisher) and ``imu_listener_node`` (subscriber) as two processes on a
private ROS_DOMAIN_ID with localhost-only discovery, and prints what crossed. Exit 0 on success, non-zero with a
reason otherwise; every wait has a timeout and both processes are stopped on every exit path.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from .bringup import isolated_ros_env, start_node, stop_nodes, wait_for_exit

SUMMARY_PREFIX = "IMU_SUMMARY "  # printed by imu_listener_node


def parse_summary(text: str) -> dict | None:
    for line in reversed(text.splitlines()):
        if line.startswith(SUMMARY_PREFIX):
            return json.loads(line[len(SUMMARY_PREFIX):])
    return None


def run_pub_sub(count: int, rate_hz: float, timeout_s: float, log_dir: Path, domain_id: int | None = None) -> dict:
    """Publisher + subscriber in two processes; returns the listener's summary plus bookkeeping."""
    env = isolated_ros_env(domain_id)
    nodes = []
    t0 = time.monotonic()
    try:
        listener = start_node("insalign_ros.nodes.imu_listener_node", env,
                              params={"expected_count": count, "timeout_s": timeout_s}, log_dir=log_dir)
        nodes.append(listener)
        sim = start_node("insalign_ros.nodes.imu_sim_node", env,
                         params={"rate_hz": rate_hz, "count": count, "wait_for_subscribers": 1,
                                 "wait_timeout_s": timeout_s}, log_dir=log_dir)
        nodes.append(sim)
        rc = wait_for_exit(listener, timeout_s + 10.0)
        summary = parse_summary(listener.output()) or {}
        summary.update(listener_rc=rc, domain_id=int(env["ROS_DOMAIN_ID"]), wall_s=time.monotonic() - t0,
                       pids=[n.popen.pid for n in nodes])
        return summary
    finally:
        stop_nodes(nodes)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="insalign-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=500, help="IMU messages to send (default 500)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="IMU rate [Hz] (default 100)")
    ap.add_argument("--timeout-s", type=float, default=60.0, help="give up after this many seconds")
    ap.add_argument("--log-dir", type=Path, default=None, help="keep node logs here (default: a temp dir)")
    args = ap.parse_args(argv)
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="insalign-demo-"))
    print(f"[insalign-demo] imu_sim_node -> imu_listener_node over Fast DDS, {args.count} Imu at {args.rate_hz:g} Hz")
    s = run_pub_sub(args.count, args.rate_hz, args.timeout_s, log_dir)
    print(f"[insalign-demo] ROS_DOMAIN_ID={s['domain_id']} (localhost discovery), logs in {log_dir}")
    if not s.get("count"):
        print(f"[insalign-demo] FAILED: nothing crossed (listener rc={s.get('listener_rc')}); see {log_dir}")
        return 1
    rows = [
        ("messages received", f"{s['count']} / {args.count}"),
        ("data-time span [s]", f"{s['last_stamp_s'] - s['first_stamp_s']:.3f}"),
        ("data rate [Hz]", f"{s['data_rate_hz']:.2f}" if s["data_rate_hz"] else "-"),
        ("receive rate [Hz]", f"{s['rx_rate_hz']:.2f}" if s["rx_rate_hz"] else "-"),
        ("largest stamp gap [s]", f"{s['max_gap_s']:.4f}" if s["max_gap_s"] is not None else "-"),
        ("mean |f_ib_b| [m/s^2]", f"{s['mean_f_norm_m_s2']:.6f}"),
        ("mean |omega_ib_b| [rad/s]", f"{s['mean_omega_norm_rad_s']:.4e}  (Earth rate 7.2921e-05)"),
        ("wall time [s]", f"{s['wall_s']:.1f}"),
    ]
    for k, v in rows:
        print(f"  {k:<28} {v}")
    ok = s["count"] >= args.count
    print("[insalign-demo] OK" if ok else f"[insalign-demo] FAILED: {args.count - s['count']} messages lost")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
