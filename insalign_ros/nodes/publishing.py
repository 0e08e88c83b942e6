"""alignment_node's outputs: what the session returns -> ~/aligned, ~/pose, ~/imu, the Euler topics, ~/datum, /tf and
/diagnostics (docs/nodes.md, "Topics" and "Frames").

Rules this module keeps:

- the flag goes out **before** the outputs it qualifies: an output is published as aligned only when its own record
  says so and no restart happened in the tick it came from; ~/aligned is published (when it changes) before it;
- a restart (a re-initialisation by the session, ``~/reset``, a core-parameter change) is seen here in one place
  (:meth:`OutputPublisher.restart`): the flag drops before anything else is published, and every derived state (the
  ENU anchor of ~/pose, the ~/datum, the measured samples for ~/imu, the TF) is cleared;
- ``~/imu`` and the TF (what a fusion node such as robot_localization latches on) go out only while aligned, unless
  ``publish_imu_before_aligned``.
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped, Vector3Stamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, NavSatFix
from std_msgs.msg import Bool

from ..core import earth
from ..core.stats import SIGMA3_UNKNOWN_DEG
from . import conversions as cv

try:  # tf2_msgs is a ROS package (not on PyPI): without it the node runs, publish_tf warns once and is ignored
    from tf2_msgs.msg import TFMessage
except ImportError:  # pragma: no cover - depends on the install
    TFMessage = None


def latched_qos() -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def tf_msg(est, anchor, world_frame: str, child_frame: str, epoch_s: int = 0, q_xyzw=None) -> TransformStamped:
    """world_frame (local ENU at ``anchor``) -> child_frame (vehicle FLU): the estimate's ENU position and attitude
    (REP 105: ``map`` or ``odom`` -> ``base_link``)."""
    m = TransformStamped()
    cv.set_stamp(m, est.stamp_s, epoch_s)
    m.header.frame_id = world_frame
    m.child_frame_id = child_frame
    p_n = earth.ecef_to_enu(earth.geodetic_to_ecef(est.lat_rad, est.lon_rad, est.h_m), *anchor)
    tr = m.transform.translation
    tr.x, tr.y, tr.z = (float(x) for x in p_n)
    q = cv.quat_xyzw(est.C_b_n) if q_xyzw is None else q_xyzw
    r = m.transform.rotation
    r.x, r.y, r.z, r.w = (float(x) for x in q)
    return m


def restart_split(outs, init_t: float | None) -> int:
    """Index of the first output of the filter initialised at ``init_t`` in a tick that restarted: the new filter's
    outputs are the tail of stamps >= ``init_t`` in non-decreasing order (a backward time step puts the old filter's
    stamps above the new ones); ``len(outs)`` when no new filter was initialised."""
    if init_t is None:
        return len(outs)
    k = len(outs)
    while k > 0 and outs[k - 1].stamp_s >= init_t and (k == len(outs) or outs[k - 1].stamp_s <= outs[k].stamp_s):
        k -= 1
    return k


class OutputPublisher:
    """The node's publishers and the derived state of what it published (anchor, flag, datum)."""

    def __init__(self, node) -> None:
        self.node = node
        self.pub_pose = node.create_publisher(PoseWithCovarianceStamped, "~/pose", 50)
        self.pub_err = node.create_publisher(Vector3Stamped, "~/euler_error", 50)
        self.pub_err3 = node.create_publisher(Vector3Stamped, "~/euler_error_3sigma", 50)
        self.pub_aligned = node.create_publisher(Bool, "~/aligned", latched_qos())
        self.pub_imu = node.create_publisher(Imu, "~/imu", 50)
        self.pub_datum = node.create_publisher(NavSatFix, "~/datum", latched_qos())
        self.pub_diag = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.pub_tf = node.create_publisher(TFMessage, "/tf", 100) if TFMessage is not None else None
        self._tf_warned = False
        self.counters = {"node_errors": 0, "outputs_published": 0, "restarts_seen": 0, "imu_held_unaligned": 0,
                         "outputs_without_anchor": 0}
        self.last_error = ""
        self._err_logged = -math.inf
        self.process_s: deque = deque(maxlen=10000)
        self.published_aligned = False
        self.pub_aligned.publish(Bool(data=False))
        self.anchor = None  # the ENU origin of the outputs last published (and of ~/datum)
        self._gen = (None, None)  # (session.anchor, session.init_t) when last seen

    # ------------------------------------------------------------------ restarts: one place
    def restart(self, why: str) -> None:
        """A restart: the flag down first, then every derived state cleared (anchor, datum, measured samples)."""
        self.counters["restarts_seen"] += 1
        self.publish_flag(False)
        self.anchor = None
        self._gen = (None, None)
        self.node._recent_imu.clear()
        self.node.get_logger().info(f"outputs restart ({why}): flag down, ENU anchor and ~/datum cleared")

    # ------------------------------------------------------------------ the guard
    def guard_error(self, where: str, exc: BaseException) -> None:
        """Any exception after the callbacks: counted (`node_errors` in /diagnostics), logged (throttled), survived."""
        self.counters["node_errors"] += 1
        self.last_error = f"{where}: {type(exc).__name__}: {exc}"
        now = time.monotonic()
        if now - self._err_logged >= max(self.node.throttle_s, 1.0):
            self._err_logged = now
            import traceback

            self.node.get_logger().error(f"error in {where} (#{self.counters['node_errors']}; carrying on): "
                                         f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=4)}")
        try:
            if self.published_aligned:
                self.publish_flag(False)
        except Exception:  # noqa: BLE001 - the flag is best effort here
            pass

    # ------------------------------------------------------------------ outputs
    def publish(self, outs: list, t0: float) -> None:
        node, s, p = self.node, self.node.session, self.node.params
        gen = (s.anchor, s.init_t)
        restarted = False
        old_anchor = self.anchor
        if gen[0] is not self._gen[0] or gen[1] != self._gen[1]:
            if self._gen[0] is not None:  # a filter whose anchor was seen is gone: a restart
                self.restart("the session re-initialised")
                restarted = True
            self._gen = gen
            if s.anchor is not None:
                self.anchor = s.anchor
                self._publish_datum()
        split = restart_split(outs, s.init_t if s.anchor is not None else None) if restarted else 0
        pose, imu, err, err3 = ((pb.get_subscription_count() > 0 for pb in (self.pub_pose, self.pub_imu, self.pub_err,
                                                                            self.pub_err3)) if outs else (False,) * 4)
        tf = bool(p["publish_tf"]) and outs and self._tf_ok()
        frame, epoch = p["world_frame"], node.epoch_s
        for k, o in enumerate(outs):
            anchor = old_anchor if k < split else self.anchor
            ok = bool(o.aligned) and not restarted
            if ok != self.published_aligned:
                self.publish_flag(ok)  # before the outputs it qualifies
            est = o.estimate
            send_imu = imu and (ok or p["publish_imu_before_aligned"])
            if imu and not send_imu:
                self.counters["imu_held_unaligned"] += 1
            if pose or send_imu or (tf and ok):
                q = cv.quat_xyzw(est.C_b_n)  # once for ~/pose, ~/imu and /tf
            if (pose or (tf and ok)) and anchor is None:
                self.counters["outputs_without_anchor"] += 1
            elif pose:
                self.pub_pose.publish(cv.pose_msg(est, anchor, frame, "", epoch, q))
            if tf and ok and anchor is not None:
                self.pub_tf.publish(TFMessage(transforms=[tf_msg(est, anchor, frame, p["tf_child_frame"], epoch, q)]))
            if send_imu:
                self.pub_imu.publish(cv.imu_msg(est, p["body_frame_id"], epoch, node._measured_sample(o.stamp_s), q))
            self.counters["outputs_published"] += 1
            err_o = err and o.euler_error_deg is not None
            if not (err3 or err_o):
                continue
            m3 = Vector3Stamped()
            cv.set_stamp(m3, o.stamp_s, epoch)
            m3.header.frame_id = frame
            if err_o:
                me = Vector3Stamped()
                me.header = m3.header
                me.vector.x, me.vector.y, me.vector.z = (float(x) for x in o.euler_error_deg)
                self.pub_err.publish(me)
            if err3:  # NaN where the angle is unknown (3-sigma above SIGMA3_UNKNOWN_DEG)
                m3.vector.x, m3.vector.y, m3.vector.z = (float(x) if x <= SIGMA3_UNKNOWN_DEG else math.nan
                                                         for x in o.euler_3sigma_deg)
                self.pub_err3.publish(m3)
        self.publish_flag(bool(s.aligned))
        if outs:
            self.process_s.append(time.perf_counter() - t0)

    def _tf_ok(self) -> bool:
        if self.pub_tf is None and not self._tf_warned:
            self._tf_warned = True
            self.node.get_logger().warning("publish_tf: tf2_msgs is not installed (a ROS package): no TF broadcast")
        return self.pub_tf is not None

    def publish_flag(self, now: bool) -> None:
        if now != self.published_aligned:
            self.published_aligned = now
            self.pub_aligned.publish(Bool(data=now))

    def _publish_datum(self) -> None:
        """~/datum: the ENU origin of ~/pose, once per initialisation (transient local: late joiners get it)."""
        s, a = self.node.session, self.anchor
        self.pub_datum.publish(cv.datum_msg(a, s.init_t, self.node.params["world_frame"], self.node.epoch_s))
        self.node.get_logger().info(f"datum (ENU origin of ~/pose): lat {math.degrees(a[0]):.7f} deg, lon "
                                    f"{math.degrees(a[1]):.7f} deg, h {a[2]:.2f} m")

    # ------------------------------------------------------------------ /diagnostics
    def publish_diagnostics(self) -> None:
        """The /diagnostics status (about 150 key-values: ~1 ms a message), built only while something subscribes
        (an aggregator, a bag recorder, ``ros2 topic echo``: it gets the next period's)."""
        if self.pub_diag.get_subscription_count() == 0:
            return
        node, s = self.node, self.node.session
        st = DiagnosticStatus()
        st.name = f"{node.get_name()}: alignment"
        st.hardware_id = node.params["hardware_id"] or node.imu_frame or "imu"
        st.level = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)[s.level()]
        st.message = s.message()
        if self.counters["node_errors"]:
            st.level = max(st.level, DiagnosticStatus.WARN)
        vals = s.diagnostics()
        vals.pop("message", None)
        if len(node.timing_s):  # over the last _STATS_WINDOW Imu messages
            tt = node.timing_s.view()
            t50, t99, tmax = quantiles(tt, (50.0, 99.0, 100.0))
            a50, a99 = quantiles(node.stamp_age_s.view(), (50.0, 99.0))
            vals.update(imu_callback_median_us=f"{t50 * 1e6:.1f}", imu_callback_p99_us=f"{t99 * 1e6:.1f}",
                        imu_callback_max_us=f"{tmax * 1e6:.1f}", imu_callback_total_s=f"{np.sum(tt):.3f}",
                        imu_stamp_age_median_ms=f"{a50 * 1e3:.3f}", imu_stamp_age_p99_ms=f"{a99 * 1e3:.3f}")
        vals.update(session_process_total_s=f"{s.timing['process_s']:.3f}", session_samples=str(s.timing["samples"]),
                    imu_messages_taken=str(node.imu_messages_taken), ready_s=f"{node.ready_s:.3f}")
        vals.update({k: str(v) for k, v in self.counters.items()})
        if self.last_error:
            vals["node_last_error"] = self.last_error
        st.values = [KeyValue(key=k, value=v if isinstance(v, str) else _json(v)) for k, v in vals.items()]
        arr = DiagnosticArray()
        arr.header.stamp = node.get_clock().now().to_msg()
        arr.status = [st]
        self.pub_diag.publish(arr)


def quantiles(x: np.ndarray, qs) -> list[float]:
    """``np.percentile(x, qs)`` (linear interpolation) from one ``np.partition`` (~2x cheaper than percentile for
    20,000 values)."""
    n = x.shape[0]
    pos = [q / 100.0 * (n - 1) for q in qs]
    lo = [min(int(p), n - 1) for p in pos]
    y = np.partition(x, sorted({k for j in lo for k in (j, min(j + 1, n - 1))}))
    return [float(y[j] + (p - j) * (y[min(j + 1, n - 1)] - y[j])) for p, j in zip(pos, lo)]


def _json(v) -> str:
    import json

    try:
        return json.dumps(v, default=str)
    except (TypeError, ValueError):
        return str(v)
