"""imu_listener_node: counts sensor_msgs/Imu on ``imu/data`` and prints one JSON summary line at exit.

Exits when ``expected_count`` messages arrived or after ``timeout_s`` (0: run until Ctrl-C); logs the running count
every ``report_period_s`` (0: never). The summary (count, first/last stamps, data and
receive rates, largest stamp gap, frame ids, the first message's f_ib_b and omega_ib_b and the largest deviation of
any later message from them) is what the scripted bringup and the tests read. QoS: parameter ``qos``,
``sensor_data`` by default (REP 2003 consumer side) or ``reliable``; keep-last ``qos_depth`` (200).
"""

from __future__ import annotations

import json
import math
import sys
import time

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu

from .qos import imu_qos

SUMMARY_PREFIX = "IMU_SUMMARY "


class ImuListenerNode(Node):
    def __init__(self) -> None:
        super().__init__("imu_listener_node")
        self.expected = int(self.declare_parameter("expected_count", 0).value)
        self.timeout_s = float(self.declare_parameter("timeout_s", 30.0).value)
        report_period_s = float(self.declare_parameter("report_period_s", 0.0).value)
        if report_period_s > 0.0:
            self.create_timer(report_period_s, self._report)
        self.qos = str(self.declare_parameter("qos", "sensor_data").value)
        qos = imu_qos(self.qos, int(self.declare_parameter("qos_depth", 200).value))
        self.sub = self.create_subscription(Imu, "imu/data", self._on_imu, qos)
        self.frame_ids: set[str] = set()
        self.first_f_ib_b: list[float] | None = None
        self.first_omega_ib_b: list[float] | None = None
        self.max_dev_f_m_s2 = 0.0
        self.max_dev_omega_rad_s = 0.0
        self.stamps: list[float] = []
        self.f_norm_sum = 0.0
        self.omega_norm_sum = 0.0
        self.t0 = time.monotonic()
        self.first_rx: float | None = None
        self.last_rx: float | None = None

    def _on_imu(self, msg: Imu) -> None:
        now = time.monotonic()
        self.first_rx = self.first_rx or now
        self.last_rx = now
        self.stamps.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
        a, w = msg.linear_acceleration, msg.angular_velocity
        self.frame_ids.add(msg.header.frame_id)
        f, om = [a.x, a.y, a.z], [w.x, w.y, w.z]
        if self.first_f_ib_b is None:
            self.first_f_ib_b, self.first_omega_ib_b = f, om
        self.max_dev_f_m_s2 = max(self.max_dev_f_m_s2, max(abs(x - y) for x, y in zip(f, self.first_f_ib_b)))
        self.max_dev_omega_rad_s = max(self.max_dev_omega_rad_s,
                                       max(abs(x - y) for x, y in zip(om, self.first_omega_ib_b)))
        self.f_norm_sum += math.sqrt(a.x * a.x + a.y * a.y + a.z * a.z)
        self.omega_norm_sum += math.sqrt(w.x * w.x + w.y * w.y + w.z * w.z)

    def _report(self) -> None:
        s = self.summary()
        rate = f"{s['rx_rate_hz']:.1f} Hz" if s["rx_rate_hz"] else "-"
        self.get_logger().info(f"received {s['count']} Imu on {self.sub.topic_name} ({rate})")

    @property
    def finished(self) -> bool:
        if self.expected and len(self.stamps) >= self.expected:
            return True
        return self.timeout_s > 0.0 and time.monotonic() - self.t0 > self.timeout_s

    def summary(self) -> dict:
        n = len(self.stamps)
        gaps = [b - a for a, b in zip(self.stamps, self.stamps[1:])]
        span = self.stamps[-1] - self.stamps[0] if n > 1 else 0.0
        return {
            "count": n,
            "expected": self.expected,
            "first_stamp_s": self.stamps[0] if n else None,
            "last_stamp_s": self.stamps[-1] if n else None,
            "data_rate_hz": (n - 1) / span if span > 0 else None,
            "rx_rate_hz": (n - 1) / (self.last_rx - self.first_rx) if n > 1 and self.last_rx > self.first_rx else None,
            "max_gap_s": max(gaps) if gaps else None,
            "out_of_order": sum(g <= 0 for g in gaps),
            "mean_f_norm_m_s2": self.f_norm_sum / n if n else None,
            "mean_omega_norm_rad_s": self.omega_norm_sum / n if n else None,
            "frame_ids": sorted(self.frame_ids),
            "first_f_ib_b": self.first_f_ib_b,
            "first_omega_ib_b": self.first_omega_ib_b,
            "max_dev_f_m_s2": self.max_dev_f_m_s2,
            "max_dev_omega_rad_s": self.max_dev_omega_rad_s,
            "qos": self.qos,
        }


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    code = 1
    try:
        try:
            node = ImuListenerNode()
        except ValueError as exc:
            print(f"imu_listener_node: bad parameter: {exc}", file=sys.stderr)
            return 2
        while rclpy.ok() and not node.finished:
            rclpy.spin_once(node, timeout_sec=0.1)
        s = node.summary()
        print(SUMMARY_PREFIX + json.dumps(s), flush=True)
        code = 0 if (not node.expected or s["count"] >= node.expected) else 3
    except KeyboardInterrupt:
        if node is not None:
            print(SUMMARY_PREFIX + json.dumps(node.summary()), flush=True)
        code = 130
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
