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
