"""alignment_node latency and throughput over real Fast DDS (two processes, isolated domain).

Per core:
1. throughput: imu_sim_node ship at 125 Hz, rate factor 10 (1,250 Imu messages/s, plus 10 Hz truth and 1 Hz
   NavSatFix), ``--duration-s`` of data; counts sent vs received (drops), the node's per-Imu callback time
   (median, p99, max: conversion + validation + EventRunner.feed + publishing when due) and its CPU share
   (sum of callback times / publishing wall time);
2. DDS end-to-end latency: the same node, an IMU at 1,250 Hz in real time (rate factor 1, stamps = wall clock at
   publication), receive time minus header stamp (median, p99): publisher scheduling + DDS + the subscriber's queue.

    .venv/bin/python benchmarks/node_latency.py [--cores liekf iekf] [--duration-s 120] [--qos sensor_data]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insalign_ros.cli.bringup import isolated_ros_env, start_node, stop_nodes, wait_for_exit  # noqa: E402


def _summary(text):
    for line in reversed(text.splitlines()):
        if line.startswith("SIM_SUMMARY "):
            return json.loads(line[len("SIM_SUMMARY "):])
    return {}


def run_case(core: str, rate_hz: float, rate_factor: float, duration_s: float, qos: str, log_dir: Path) -> dict:
    env = isolated_ros_env()
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        os.environ[k] = env[k]
    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor()
    nodes = []
    try:
        align = start_node("insalign_ros.nodes.alignment_node", env, log_dir=log_dir, name=f"align_{core}",
                           params={"core": core, "init_from_ground_truth": True,
                                   "init_rpy_error_deg": "[3.0, -3.0, 30.0]", "imu_qos": qos})
        nodes.append(align)
        sim = start_node("insalign_ros.nodes.imu_sim_node", env, log_dir=log_dir, name=f"sim_{core}",
                         params={"source": "scenario", "scenario": "ship", "rate_hz": rate_hz,
                                 "rate_factor": rate_factor, "duration_s": duration_s, "wait_for_subscribers": 1,
                                 "wait_timeout_s": 30.0, "qos_depth": 1000})
        nodes.append(sim)
        t0 = time.monotonic()
        rc = wait_for_exit(sim, duration_s / rate_factor + 60.0)
        wall = time.monotonic() - t0
        s = _summary(sim.output())
        sent = s.get("imu_sent", 0)
        mon.wait_for(lambda m: m.counter("imu_received") >= sent, 15.0)
        n0 = mon.diag_count
        mon.wait_for(lambda m: m.diag_count >= n0 + 2, 5.0)
        with mon.lock:
            d = dict(mon.diag)
        pub_wall = duration_s / rate_factor
        return {"core": core, "rate_hz": rate_hz, "rate_factor": rate_factor, "msgs_per_s": rate_hz * rate_factor,
                "qos": qos, "sim_rc": rc, "sent": sent, "received": int(d.get("imu_received", 0)),
                "rejected": int(d.get("imu_rejected", 0)), "gaps": int(d.get("imu_gaps", 0)),
                "cb_median_us": float(d.get("imu_callback_median_us", "nan")),
                "cb_p99_us": float(d.get("imu_callback_p99_us", "nan")),
                "cb_max_us": float(d.get("imu_callback_max_us", "nan")),
                "cpu_share": float(d.get("imu_callback_total_s", "nan")) / pub_wall,
                "age_median_ms": float(d.get("imu_stamp_age_median_ms", "nan")),
                "age_p99_ms": float(d.get("imu_stamp_age_p99_ms", "nan")),
                "aligned": d.get("aligned"), "wall_s": wall}
    finally:
        stop_nodes(nodes)
        mon.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cores", nargs="+", default=["liekf", "iekf"])
    ap.add_argument("--duration-s", type=float, default=120.0, help="data time of the throughput run [s]")
    ap.add_argument("--latency-duration-s", type=float, default=10.0, help="data (= wall) time of the latency run")
    ap.add_argument("--qos", default="sensor_data", choices=["sensor_data", "reliable"])
    args = ap.parse_args(argv)
    log_dir = Path(tempfile.mkdtemp(prefix="node-latency-"))
    rows = []
    for core in args.cores:
        thr = run_case(core, 125.0, 10.0, args.duration_s, args.qos, log_dir)
        lat = run_case(core, 1250.0, 1.0, args.latency_duration_s, args.qos, log_dir)
        rows.append((thr, lat))
        print(json.dumps({"throughput": thr, "latency": lat}), flush=True)
    print(f"\nalignment_node, imu_qos={args.qos}, ship, 2-core machine (node logs in {log_dir})\n")
    print("| core | Imu msgs/s | sent | received | dropped | callback median / p99 / max [us] | CPU share | "
          "DDS end-to-end latency median / p99 [ms] (1,250 Hz real time) | keeps up |")
    print("|---|---|---|---|---|---|---|---|---|")
    for thr, lat in rows:
        dropped = thr["sent"] - thr["received"]
        ok = dropped == 0 and thr["cpu_share"] < 1.0
        print(f"| {thr['core']} | {thr['msgs_per_s']:.0f} | {thr['sent']} | {thr['received']} | {dropped} | "
              f"{thr['cb_median_us']:.0f} / {thr['cb_p99_us']:.0f} / {thr['cb_max_us']:.0f} | "
              f"{thr['cpu_share']:.2f} | {lat['age_median_ms']:.2f} / {lat['age_p99_ms']:.2f} "
              f"(received {lat['received']}/{lat['sent']}) | {'yes' if ok else 'NO'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
