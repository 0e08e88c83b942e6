"""imu_listener_node: counts sensor_msgs/Imu on ``imu/data`` and prints one JSON summary line at exit.

Exits when ``expected_count`` messages arrived or after ``timeout_s``. The summary (count, data-time span,
rate, largest stamp gap, mean specific-force norm) is what the scripted bringup and the tests read.
"""

from __future__ import annotations

import json
import math
import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

SUMMARY_PREFIX = "IMU_SUMMARY "


class ImuListenerNode(Node):
    def __init__(self) -> None:
        super().__init__("imu_listener_node")
        self.expected = int(self.declare_parameter("expected_count", 0).value)
        self.timeout_s = float(self.declare_parameter("timeout_s", 30.0).value)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE)
        self.sub = self.create_subscription(Imu, "imu/data", self._on_imu, qos)
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
        self.f_norm_sum += math.sqrt(a.x * a.x + a.y * a.y + a.z * a.z)
        self.omega_norm_sum += math.sqrt(w.x * w.x + w.y * w.y + w.z * w.z)

    @property
    def finished(self) -> bool:
        return (self.expected and len(self.stamps) >= self.expected) or time.monotonic() - self.t0 > self.timeout_s

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
        }


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    code = 1
    try:
        node = ImuListenerNode()
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
