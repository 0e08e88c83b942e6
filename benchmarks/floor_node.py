"""The physical floor of node_latency's cost run: what rclpy and Fast DDS cost a node with the alignment node's
inputs and outputs and nothing computed.

Named ``alignment_node``, it subscribes to the same topics with the same QoS (``imu_qos``, default sensor_data), takes
every waiting message at the same processing tick (10 Hz; the Imu messages serialized, the others as messages, from
readers polled outside the executor, the node's default with the EventsExecutor), and publishes what the node
publishes to node_latency's monitor: per 0.1 s of Imu data a ``~/pose`` and a ``~/euler_error_3sigma`` (constant
contents), ``~/aligned`` once, and ``/diagnostics`` every second with as many key-values as the node's (~150, with the
``imu_received`` and ``buffered_imu`` counts the benchmark waits on). No message is converted, no sample is
processed. Run by ``benchmarks/node_latency.py --floor``.
"""

from __future__ import annotations

import sys

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistWithCovarianceStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Bool

from insalign_ros.nodes.alignment_node import _take_all, make_executor, spin
from insalign_ros.nodes.publishing import latched_qos
from insalign_ros.nodes.qos import imu_qos

#: about as many key-values as the alignment node's /diagnostics status
N_DIAG_VALUES = 150


class FloorNode(Node):
    def __init__(self) -> None:
        super().__init__("alignment_node")
        self.declare_parameter("imu_qos", "sensor_data")
        self.declare_parameter("core", "")  # accepted (node_latency passes it), unused
        qi = imu_qos(self.get_parameter("imu_qos").value, 1000)
        qg = imu_qos("sensor_data", 100)  # gnss_qos, gnss_qos_depth defaults
        subs = [self.create_subscription(Imu, "imu/data", lambda m: None, qi)]
        for typ, topic, qos in ((NavSatFix, "gps/fix", qg), (TwistWithCovarianceStamped, "gps/vel", qg),
                                (Odometry, "wheel/odom", qg), (Imu, "gps/heading", qg),
                                (PoseStamped, "ground_truth/pose", qi)):
            subs.append(self.create_subscription(typ, topic, lambda m: None, qos))
        for s in subs:  # polled by the tick, as the alignment node's poll_inputs
            self._subscriptions.remove(s)
        self.imu_sub, self.others = subs[0], subs[1:]
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "~/pose", 50)
        self.pub_err3 = self.create_publisher(Vector3Stamped, "~/euler_error_3sigma", 50)
        self.pub_aligned = self.create_publisher(Bool, "~/aligned", latched_qos())
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.received = 0
        self.next_out = None  # the next output's Imu stamp [s]
        self.create_timer(0.1, self._tick)
        self.create_timer(1.0, self._diagnostics)
        self.pub_aligned.publish(Bool(data=False))

    def _tick(self) -> None:
        got = _take_all(self.imu_sub, raw=True)
        self.received += len(got)
        for sub in self.others:
            _take_all(sub)
        if not got:
            return
        # the outputs due in the batch: one per 0.1 s of data, stamped as the wall clock (nothing is read from
        # the messages)
        now = self.get_clock().now()
        t = now.nanoseconds * 1e-9
        if self.next_out is None:
            self.next_out = t
        while self.next_out <= t:
            self.next_out += 0.1
            pose = PoseWithCovarianceStamped()
            pose.header.stamp = now.to_msg()
            pose.header.frame_id = "map"
            pose.pose.pose.orientation.w = 1.0
            self.pub_pose.publish(pose)
            m3 = Vector3Stamped()
            m3.header = pose.header
            m3.vector.x, m3.vector.y, m3.vector.z = 0.1, 0.1, 1.0
            self.pub_err3.publish(m3)

    def _diagnostics(self) -> None:
        self._tick()
        st = DiagnosticStatus(name="alignment_node: alignment", hardware_id="imu", message="floor")
        vals = {"imu_received": str(self.received), "buffered_imu": "0"}
        vals.update({f"key_{k}": f"{k * 1.5:.3f}" for k in range(N_DIAG_VALUES - len(vals))})
        st.values = [KeyValue(key=k, value=v) for k, v in vals.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def main(args=None) -> int:
    rclpy.init(args=args)
    node = FloorNode()
    ex = make_executor("events")
    ex.add_node(node)
    try:
        spin(ex)
    except KeyboardInterrupt:
        pass
    finally:
        node._subscriptions.extend([node.imu_sub, *node.others])
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
