"""AlignmentMonitor: an in-process rclpy node that watches alignment_node's outputs (demo, tests, benchmarks).

Runs in its own rclpy Context and executor thread so that the caller (a CLI or a test) stays free. Records the
aligned flag history, the last Euler error and 3-sigma, pose covariances and the last /diagnostics values.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool


def _t(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


class AlignmentMonitor:
    """Subscribe to ``<ns>/alignment_node/{aligned,euler_error,euler_error_3sigma,pose}`` and ``/diagnostics``."""

    def __init__(self, node_name: str = "alignment_node", keep_poses: int = 100) -> None:
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = Node("insalign_monitor", context=self.ctx)
        self.lock = threading.RLock()
        self.aligned = None  # last flag
        self.aligned_history: list[tuple[float, bool, float]] = []  # (wall, value, last euler stamp)
        self.euler_error = None  # (stamp, [r, p, y] deg)
        self.euler_3sigma = None
        self.errors: list[tuple[float, np.ndarray]] = []
        self.sigmas3: list[tuple[float, np.ndarray]] = []  # (stamp, published 3-sigma [deg])
        self.poses: list[PoseWithCovarianceStamped] = []
        self.pose_count = 0
        self.keep_poses = keep_poses
        self.diag: dict = {}
        self.diag_count = 0
        latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        n = self.node
        n.create_subscription(Bool, f"{node_name}/aligned", self._on_aligned, latched)
        n.create_subscription(Vector3Stamped, f"{node_name}/euler_error", self._on_err, 100)
        n.create_subscription(Vector3Stamped, f"{node_name}/euler_error_3sigma", self._on_err3, 100)
        n.create_subscription(PoseWithCovarianceStamped, f"{node_name}/pose", self._on_pose, 100)
        self.node_name = node_name
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(n)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop and self.ctx.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - shutdown race
                if self._stop:
                    return

    def _on_aligned(self, msg: Bool) -> None:
        with self.lock:
            self.aligned = bool(msg.data)
            st = self.euler_3sigma[0] if self.euler_3sigma else float("nan")
            self.aligned_history.append((time.monotonic(), bool(msg.data), st))

    def _on_err(self, msg: Vector3Stamped) -> None:
        v = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
        with self.lock:
            self.euler_error = (_t(msg), v)
            self.errors.append((_t(msg), v))

    def _on_err3(self, msg: Vector3Stamped) -> None:
        with self.lock:
            self.euler_3sigma = (_t(msg), np.array([msg.vector.x, msg.vector.y, msg.vector.z]))
            self.sigmas3.append(self.euler_3sigma)

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        with self.lock:
            self.pose_count += 1
            self.poses.append(msg)
            if len(self.poses) > self.keep_poses:
                del self.poses[0]

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name == f"{self.node_name}: alignment":
                with self.lock:
                    self.diag = {kv.key: kv.value for kv in st.values}
                    self.diag["level"] = int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level)
                    self.diag["message"] = st.message
                    self.diag_count += 1

    def counter(self, name: str) -> int:
        with self.lock:
            return int(self.diag.get(name, 0))

    def wait_for(self, pred, timeout_s: float, period_s: float = 0.05) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                ok = pred(self)
            if ok:
                return True
            time.sleep(period_s)
        return False

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=2.0)
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            if self.ctx.ok():
                rclpy.shutdown(context=self.ctx)
