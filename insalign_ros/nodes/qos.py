"""QoS profiles of the IMU topics, following REP 2003 (sensor data QoS).

REP 2003: sensor drivers publish reliable (the system-default profile), consumers subscribe with the
sensor-data profile (best effort, volatile, keep-last). A reliable writer matches both reliable and best-effort
readers; a best-effort writer matches only best-effort readers. Both ends take a ``qos`` parameter:

- ``sensor_data``: best effort, volatile, keep-last ``depth`` (rclpy's qos_profile_sensor_data with our depth);
- ``reliable``: reliable, volatile, keep-last ``depth`` (the system default with our depth).
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

QOS_CHOICES = ("sensor_data", "reliable")


def imu_qos(kind: str, depth: int = 200) -> QoSProfile:
    """QoS profile ``kind`` (one of QOS_CHOICES) with keep-last ``depth``; ValueError on anything else."""
    if kind not in QOS_CHOICES:
        raise ValueError(f"qos must be one of {QOS_CHOICES}, got {kind!r}")
    if not 1 <= int(depth) <= 100000:
        raise ValueError(f"qos_depth must be in [1, 100000], got {depth}")
    reliability = ReliabilityPolicy.BEST_EFFORT if kind == "sensor_data" else ReliabilityPolicy.RELIABLE
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth), reliability=reliability,
                      durability=DurabilityPolicy.VOLATILE)
