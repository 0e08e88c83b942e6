#!/usr/bin/env python3
"""Live fuzzing of the node over real DDS (issue 27, item 7). Not a unit test.

Each episode starts ``alignment_node`` (default parameters except the core and the IMU grade), streams a simulated
car or ship from this process and injects faults drawn at random (seeded) from the catalogue below; a referee in
this process publishes the true pose (the node's ``~/euler_error`` compares with it) and records every
``~/euler_error`` with its ``~/euler_error_3sigma`` and the last ``~/aligned`` received before it.

Fault catalogue (each episode draws 3-6): IMU duplicates, a swapped pair, a burst (a second of samples at once),
an IMU gap (2-5 s of stamps missing), a clock step back (10 s) or forward (5 s), NaN/Inf fields, a far (1000 km)
and a near (200 m) outlier fix, a NO_FIX run (10 s), a fix stamped 5 s ahead, a ``~/reset`` call, a restart of the
source (stamps start again from the first sample).

Per episode: did the node survive (process alive, diagnostics still coming), flag-up outputs, flag-up outputs
outside their own 3-sigma by more than the margin (|error| > 1.5 x 3-sigma + 0.05 deg on any axis), IMU messages
sent and counted by the node (``imu_received``). The table goes to docs/nodes.md ("Live fuzzing").

    nice .venv/bin/python benchmarks/fuzz_live.py [--episodes 10] [--seed 1] [--duration 240]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from insalign_ros.cli.bringup import isolated_ros_env, start_node, stop_nodes  # noqa: E402
from insalign_ros.core import earth  # noqa: E402

T0 = 1000.0
FAULTS = ("duplicate", "swap", "burst", "gap", "clock_back", "clock_forward", "nan", "far_fix", "near_fix",
          "no_fix_run", "future_fix", "reset", "source_restart")
SCENARIOS = {"car": "industrial_mems", "ship": "paper_ship"}
MARGIN, FLOOR_DEG = 1.5, 0.05


class Referee:
    """Publisher of the stream and the truth, subscriber of the node's outputs (one rclpy context, spun here)."""

    def __init__(self, data):
        import rclpy
        from geometry_msgs.msg import PoseStamped, Vector3Stamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, NavSatFix
        from std_msgs.msg import Bool
        from std_srvs.srv import Trigger
        from diagnostic_msgs.msg import DiagnosticArray

        self.rclpy, self.Imu, self.NavSatFix, self.PoseStamped = rclpy, Imu, NavSatFix, PoseStamped
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node("fuzz_referee", context=self.ctx)
        qos = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_imu = self.node.create_publisher(Imu, "imu/data", qos)
        self.pub_fix = self.node.create_publisher(NavSatFix, "gps/fix", qos)
        self.pub_truth = self.node.create_publisher(PoseStamped, "ground_truth/pose", qos)
        self.reset_cli = self.node.create_client(Trigger, "alignment_node/reset")
        self.Trigger = Trigger
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.aligned = False
        self.err, self.err3 = {}, {}
        self.records = []  # (stamp, flag at arrival, error deg (3,), 3-sigma deg (3,))
        self.diag = {}
        self.diag_count = 0
        self.node.create_subscription(Bool, "alignment_node/aligned", self._on_flag, latched)
        self.node.create_subscription(Vector3Stamped, "alignment_node/euler_error", self._on_err, 1000)
        self.node.create_subscription(Vector3Stamped, "alignment_node/euler_error_3sigma", self._on_err3, 1000)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.d = data
        self.geo = [earth.ecef_to_geodetic(p) for p in data.gnss_p_e]
        self.quat = Rotation.from_matrix(data.C_b_n).as_quat()
        self.anchor = (data.lat_rad[0], data.lon_rad[0], data.h_m[0])

    @staticmethod
    def _t(msg):
        return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec

    def _on_flag(self, m):
        self.aligned = bool(m.data)

    def _pair(self, t):
        if t in self.err and t in self.err3:
            e, s = self.err.pop(t), self.err3.pop(t)
            self.records.append((t, e[1], e[0], s))

    def _on_err(self, m):
        t = self._t(m)
        self.err[t] = (np.array([m.vector.x, m.vector.y, m.vector.z]), self.aligned)
        self._pair(t)

    def _on_err3(self, m):
        t = self._t(m)
        self.err3[t] = np.array([m.vector.x, m.vector.y, m.vector.z])
        self._pair(t)

    def _on_diag(self, m):
        for st in m.status:
            if "alignment" in st.name.lower():
                self.diag = {kv.key: kv.value for kv in st.values}
                self.diag_count += 1

    def spin(self, s=0.0):
        end = time.monotonic() + s
        while True:
            self.ex.spin_once(timeout_sec=0.0)
            if time.monotonic() >= end:
                break

    @staticmethod
    def stamp(msg, t):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)

    def imu(self, k, off=0.0):
        m = self.Imu()
        self.stamp(m, T0 + off + self.d.t_s[k])
        m.header.frame_id = "imu_link"
        m.orientation_covariance[0] = -1.0
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(x) for x in self.d.omega_ib_b[k])
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (float(x) for x in
                                                                                    self.d.f_ib_b[k])
        return m

    def fix(self, j, off=0.0, shift_m=0.0, status=0):
        lat, lon, h = self.geo[j]
        m = self.NavSatFix()
        self.stamp(m, T0 + off + self.d.gnss_t_s[j])
        m.header.frame_id = "gps_link"
        m.status.status = status
        m.latitude = math.degrees(lat + shift_m / earth.A_M)
        m.longitude, m.altitude = math.degrees(lon), h
        m.position_covariance = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
        m.position_covariance_type = self.NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
        return m

    def truth(self, k):
        m = self.PoseStamped()
        self.stamp(m, T0 + self.d.t_s[k])
        m.header.frame_id = "enu"
        p = earth.ecef_to_enu(earth.geodetic_to_ecef(self.d.lat_rad[k], self.d.lon_rad[k], self.d.h_m[k]),
                              *self.anchor)
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(x) for x in p)
        q = self.quat[k]
        m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = (float(x) for x in q)
        return m

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)


def episode(i: int, rng, duration_s: float, rate_hz: float, log_dir: Path) -> dict:
    from insalign_ros.sim.scenarios import make_scenario

    scen = str(rng.choice(list(SCENARIOS)))
    d = make_scenario(scen, seed=int(rng.integers(1 << 16)), duration_s=duration_s, rate_hz=rate_hz)
    faults = sorted({str(f) for f in rng.choice(FAULTS, size=int(rng.integers(3, 7)), replace=False)})
    at = {f: float(rng.uniform(0.15, 0.85)) * duration_s for f in faults}
    env = isolated_ros_env()
    node = start_node("insalign_ros.nodes.alignment_node", env, log_dir=log_dir, name=f"fuzz{i}", params={
        "core": "auto", "imu_grade": SCENARIOS[scen], "imu_qos": "reliable", "imu_qos_depth": 20000,
        "gnss_qos": "reliable", "gnss_qos_depth": 5000})
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE") if k in env})
    ref = Referee(d)
    sent = 0
    try:
        end = time.monotonic() + 120.0  # the node compiles its kernels before it subscribes
        while ref.pub_imu.get_subscription_count() < 1 or ref.pub_fix.get_subscription_count() < 1:
            if time.monotonic() > end or node.popen.poll() is not None:
                raise RuntimeError("alignment_node did not subscribe")
            ref.spin(0.05)
        off, j, k, done = 0.0, 0, 1, set()
        restarted = False
        while k < d.n:
            t = d.t_s[k]
            due = [f for f in faults if f not in done and t >= at[f]]
            for f in due:
                done.add(f)
                if f == "gap":
                    k += int(rng.uniform(2.0, 5.0) * rate_hz)
                elif f == "clock_back":
                    off -= 10.0
                elif f == "clock_forward":
                    off += 5.0
                elif f == "burst":
                    for kk in range(k, min(d.n, k + int(rate_hz))):
                        ref.pub_imu.publish(ref.imu(kk, off))
                        sent += 1
                    k = min(d.n - 1, k + int(rate_hz))
                elif f == "reset" and ref.reset_cli.service_is_ready():
                    ref.reset_cli.call_async(ref.Trigger.Request())
                elif f == "source_restart" and not restarted:
                    restarted, off = True, off + d.t_s[k] + 1.0  # the same stream again, later stamps
                    k, j = 1, 0
            if k >= d.n:
                break
            t = d.t_s[k]
            if k % 5 == 0 and off == 0.0:
                ref.pub_truth.publish(ref.truth(k))
            ref.pub_imu.publish(ref.imu(k, off))
            sent += 1
            if "duplicate" in done and rng.random() < 0.01:
                ref.pub_imu.publish(ref.imu(k, off))
                sent += 1
            if "swap" in due and k + 1 < d.n:
                ref.pub_imu.publish(ref.imu(k + 1, off))
                ref.pub_imu.publish(ref.imu(k, off))
                sent += 2
            if "nan" in done and rng.random() < 0.005:
                m = ref.imu(k, off + 1e-4)
                m.angular_velocity.y = float("nan") if rng.random() < 0.5 else float("inf")
                ref.pub_imu.publish(m)
                sent += 1
            while j < len(d.gnss_t_s) and d.gnss_t_s[j] <= t:
                if "no_fix_run" in done and at["no_fix_run"] <= d.gnss_t_s[j] < at["no_fix_run"] + 10.0:
                    ref.pub_fix.publish(ref.fix(j, off, status=-1))
                elif "far_fix" in due:
                    ref.pub_fix.publish(ref.fix(j, off, shift_m=1.0e6))
                elif "near_fix" in due:
                    ref.pub_fix.publish(ref.fix(j, off, shift_m=200.0))
                else:
                    if "future_fix" in due and j + 5 < len(d.gnss_t_s):
                        ref.pub_fix.publish(ref.fix(j + 5, off))
                    ref.pub_fix.publish(ref.fix(j, off))
                j += 1
            k += 1
            if sent % 50 == 0:
                ref.spin(0.04)  # ~1,000 messages/s
        ref.spin(3.0)
        alive = node.popen.poll() is None
        n0 = ref.diag_count
        ref.spin(3.0)
        diag_alive = ref.diag_count > n0
    finally:
        ref.close()
        rc = node.popen.poll()
        stop_nodes([node])
    recs = ref.records
    up = [r for r in recs if r[1]]
    bad = [r for r in up if np.any(np.abs(((r[2] + 180.0) % 360.0) - 180.0) > MARGIN * r[3] + FLOOR_DEG)]
    return {"episode": i, "scenario": scen, "faults": faults, "alive": alive and diag_alive, "exit": rc,
            "outputs": len(recs), "flag_up": len(up), "flag_up_outside": len(bad), "imu_sent": sent,
            "imu_received": int(float(ref.diag.get("imu_received", "nan"))) if ref.diag.get("imu_received") else -1}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=240.0)
    ap.add_argument("--rate", type=float, default=50.0)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    rows = []
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.episodes):
            r = episode(i, rng, a.duration, a.rate, Path(tmp))
            rows.append(r)
            print(r, flush=True)
    print(f"\nCommand: `nice .venv/bin/python benchmarks/fuzz_live.py --episodes {a.episodes} --seed {a.seed} "
          f"--duration {a.duration:g}`  \nMachine load {load0:.1f} -> {os.getloadavg()[0]:.1f} on {os.cpu_count()} "
          f"cores. Margin: |error| > {MARGIN} x 3-sigma + {FLOOR_DEG} deg on any axis.\n")
    print("| episode | scenario | faults | node alive | outputs | flag up | flag up outside 3-sigma | IMU sent | "
          "IMU counted |\n|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['episode']} | {r['scenario']} | {', '.join(r['faults'])} | {'yes' if r['alive'] else 'NO'} | "
              f"{r['outputs']} | {r['flag_up']} | {r['flag_up_outside']} | {r['imu_sent']} | {r['imu_received']} |")
    crashes = sum(not r["alive"] for r in rows)
    outside = sum(r["flag_up_outside"] for r in rows)
    print(f"\n{crashes} crashes, {outside} flag-up outputs outside the margin, in {len(rows)} episodes")
    return 1 if crashes or outside else 0


if __name__ == "__main__":
    sys.exit(main())
