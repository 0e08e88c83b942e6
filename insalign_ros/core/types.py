"""Sample types that flow from every source (simulator, bag, DDS topic) into every alignment core."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImuSample:
    """One IMU sample: stamp [s], angular rate omega_ib_b [rad/s], specific force f_ib_b [m/s^2] (body FLU)."""

    stamp_s: float
    omega_ib_b: np.ndarray
    f_ib_b: np.ndarray


@dataclass(frozen=True)
class GnssFix:
    """A GNSS position fix: stamp [s], ECEF position p_e [m] and its 3x3 covariance R_e [m^2] in ECEF."""

    stamp_s: float
    p_e: np.ndarray
    R_e: np.ndarray


@dataclass(frozen=True)
class WheelSpeed:
    """Wheel odometry: stamp [s], the vehicle's speed along its x axis speed_m_s [m/s] (negative when reversing, as
    nav_msgs/Odometry's twist.linear.x in the child frame) and its variance var_m2_s2 [m^2/s^2]."""

    stamp_s: float
    speed_m_s: float
    var_m2_s2: float


@dataclass(frozen=True)
class GnssHeading:
    """Dual-antenna (moving-base) GNSS heading: stamp [s], the yaw of the antenna baseline yaw_rad [rad] (ENU, from
    East counter-clockwise, REP 103; nodes/conversions.py converts a receiver's NED heading) and its variance
    var_rad2 [rad^2]."""

    stamp_s: float
    yaw_rad: float
    var_rad2: float


@dataclass(frozen=True)
class GnssVelocity:
    """A GNSS velocity: stamp [s], the antenna's velocity relative to Earth in local ENU v_n [m/s] (ENU at the
    antenna: REP 103, what u-blox, NovAtel and MicroStrain drivers publish as TwistWithCovarianceStamped) and its
    3x3 covariance R_n [m^2/s^2] in ENU."""

    stamp_s: float
    v_n: np.ndarray
    R_n: np.ndarray
