"""Datasheet unit conversions (the one place they live; SI inside the package).

Conversions (SI inside the package):

| datasheet unit | SI | factor |
|---|---|---|
| deg/h (bias) | rad/s | pi/180 / 3600 |
| deg/sqrt(h) (ARW) | rad/sqrt(s) | pi/180 / 60 |
| deg/s/sqrt(Hz) (rate noise density) | rad/sqrt(s) | pi/180 |
| mg, ug (bias) | m/s^2 | 1e-3 g0, 1e-6 g0 with g0 = 9.80665 |
| m/s/sqrt(h) (VRW) | m/s/sqrt(s) | 1/60 |
| ug/sqrt(Hz) (acceleration noise density) | m/s/sqrt(s) | 1e-6 g0 |

REP 145 covariances of a sensor_msgs/Imu sample are the variances of one sample: (ARW or VRW in SI)^2 / dt.
"""

from __future__ import annotations

import math

G0_M_S2 = 9.80665  #: standard gravity, the "g" of mg and ug


def deg_h_to_rad_s(x: float) -> float:
    return math.radians(x) / 3600.0


def deg_sqrt_h_to_rad_sqrt_s(x: float) -> float:
    return math.radians(x) / 60.0


def deg_s_sqrt_hz_to_rad_sqrt_s(x: float) -> float:
    return math.radians(x)


def mg_to_m_s2(x: float) -> float:
    return x * 1e-3 * G0_M_S2


def ug_to_m_s2(x: float) -> float:
    return x * 1e-6 * G0_M_S2


def m_s_sqrt_h_to_m_s_sqrt_s(x: float) -> float:
    return x / 60.0


def ug_sqrt_hz_to_m_s_sqrt_s(x: float) -> float:
    return x * 1e-6 * G0_M_S2


def ug_sqrt_hz_to_m_s_sqrt_h(x: float) -> float:
    return ug_sqrt_hz_to_m_s_sqrt_s(x) * 60.0
