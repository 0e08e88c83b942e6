"""imu_sim_node: publishes sensor_msgs/Imu (and, as the simulators land, NavSatFix and ground truth).

Current source: ``rest`` — a body at rest on the rotating Earth at (lat_deg, lon_deg, h_m) with attitude
(roll_deg, pitch_deg, yaw_deg): the gyros read the Earth rate, the accelerometers minus gravity (core/earth.py).

Topics: ``imu/data`` (sensor_msgs/Imu, frame_id ``imu_link``). QoS (nodes/qos.py, REP 2003): parameter ``qos``,
``reliable`` by default (serves reliable and best-effort sensor-data subscribers alike) or ``sensor_data`` (best
effort); volatile, keep-last ``qos_depth`` (200).

Parameters: rate_hz [Hz] (100), count (0: unlimited), duration_s [s] of data time (0: unlimited),
wait_for_subscribers / wait_timeout_s (start only once that many subscribers matched), frame_id, lat_deg, lon_deg,
h_m, roll_deg, pitch_deg, yaw_deg, qos, qos_depth. The stamps lie on an exact grid of 1/rate_hz from the first
message (data time), so the data rate is exact whatever the scheduling jitter.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu

from ..core import earth
from .qos import imu_qos


def rest_imu(lat_deg: float, lon_deg: float, h_m: float, rpy_deg) -> tuple[np.ndarray, np.ndarray]:
    """(omega_ib_b [rad/s], f_ib_b [m/s^2]) of a body at rest relative to the Earth."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    C_b_n = earth.C_b_n_from_rpy(*np.radians(rpy_deg))
    C_e_b = C_b_n.T @ earth.C_e_n(lat, lon)
    p_e = earth.geodetic_to_ecef(lat, lon, h_m)
    return C_e_b @ earth.OMEGA_IE_E, -C_e_b @ earth.gravity_e(p_e)


class ImuSimNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("imu_sim_node", **node_kwargs)
        p = self.declare_parameter
        self.rate_hz = float(p("rate_hz", 100.0).value)
        self.count = int(p("count", 0).value)  # 0: unlimited
        self.duration_s = float(p("duration_s", 0.0).value)  # 0: unlimited
        self.wait_for_subscribers = int(p("wait_for_subscribers", 0).value)
        self.wait_timeout_s = float(p("wait_timeout_s", 20.0).value)
        self.frame_id = str(p("frame_id", "imu_link").value)
        lat, lon, h = (float(p(n, d).value) for n, d in (("lat_deg", 49.0), ("lon_deg", 8.4), ("h_m", 120.0)))
        rpy = [float(p(n, 0.0).value) for n in ("roll_deg", "pitch_deg", "yaw_deg")]
        if not (0.0 < self.rate_hz <= 2000.0):
            raise ValueError(f"rate_hz must be in (0, 2000], got {self.rate_hz}")
        self.omega_ib_b, self.f_ib_b = rest_imu(lat, lon, h, rpy)
        qos = imu_qos(str(p("qos", "reliable").value), int(p("qos_depth", 200).value))
        self.pub = self.create_publisher(Imu, "imu/data", qos)
        self.sent = 0
        self.t_start_ns: int | None = None
        self._wait_start = time.monotonic()
        self.timer = self.create_timer(1.0 / self.rate_hz, self._tick)
        self.done = False
        self.gave_up = False  # no subscriber matched within wait_timeout_s

    def _ready(self) -> bool:
        if self.pub.get_subscription_count() >= self.wait_for_subscribers:
            return True
        if time.monotonic() - self._wait_start > self.wait_timeout_s:
            self.get_logger().error(f"no subscriber matched after {self.wait_timeout_s:g} s (none running, or QoS "
                                    "incompatible: a best-effort publisher cannot serve a reliable subscriber); giving up")
            self.done = self.gave_up = True
        return False

    def _tick(self) -> None:
        if self.done or (self.t_start_ns is None and not self._ready()):
            return
        now_ns = self.get_clock().now().nanoseconds
        if self.t_start_ns is None:
            self.t_start_ns = now_ns
        msg = Imu()
        msg.header.frame_id = self.frame_id
        stamp_ns = self.t_start_ns + round(self.sent * 1e9 / self.rate_hz)  # data time on an exact grid
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.orientation_covariance[0] = -1.0  # no orientation estimate (REP 145)
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, self.omega_ib_b)
        a = msg.linear_acceleration
        a.x, a.y, a.z = map(float, self.f_ib_b)
        self.pub.publish(msg)
        self.sent += 1
        elapsed = self.sent / self.rate_hz
        if (self.count and self.sent >= self.count) or (self.duration_s and elapsed >= self.duration_s):
            self.get_logger().info(f"published {self.sent} Imu messages; done")
            self.done = True


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = ImuSimNode()
        while rclpy.ok() and not node.done:
            rclpy.spin_once(node, timeout_sec=0.1)
        # let the reliable writer deliver what is queued before the process goes away
        end = time.monotonic() + 2.0
        while rclpy.ok() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        return 3 if node.gave_up else 0
    except KeyboardInterrupt:
        return 0
    except ValueError as exc:
        print(f"imu_sim_node: bad parameter: {exc}", file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main())
