"""IMU error model of PI-LIEKF eq. (34) and the datasheet unit conversions (the one place they live).

    omega_meas = omega_ib_b + b_g + w_g,   f_meas = f_ib_b + b_a + w_a,   b_g, b_a constant in a run

* b_g ~ N(0, sigma_bg^2 I), b_a ~ N(0, sigma_ba^2 I), drawn once per run from the seed.
* w_g, w_a: white noise of the *average* over one sample interval dt, so sigma = (random-walk coefficient)/sqrt(dt).

Conversions: core/units.py (re-exported here).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.units import (  # noqa: F401  (re-exported: the simulator's users import them from here)
    G0_M_S2, deg_h_to_rad_s, deg_s_sqrt_hz_to_rad_sqrt_s, deg_sqrt_h_to_rad_sqrt_s, m_s_sqrt_h_to_m_s_sqrt_s, mg_to_m_s2,
    ug_sqrt_hz_to_m_s_sqrt_h, ug_sqrt_hz_to_m_s_sqrt_s, ug_to_m_s2,
)
from .types import ImuSpec



class ImuErrorSI:
    """An ImuSpec in SI: bias sigmas [rad/s], [m/s^2]; random-walk coefficients [rad/sqrt(s)], [m/s/sqrt(s)]."""

    def __init__(self, spec: ImuSpec):
        self.spec = spec
        self.sigma_bg_rad_s = deg_h_to_rad_s(spec.gyro_bias_deg_h)
        self.sigma_ba_m_s2 = mg_to_m_s2(spec.acc_bias_mg)
        self.arw_rad_sqrt_s = deg_sqrt_h_to_rad_sqrt_s(spec.arw_deg_sqrt_h)
        self.vrw_m_s_sqrt_s = m_s_sqrt_h_to_m_s_sqrt_s(spec.vrw_m_s_sqrt_h)
        self.dt_s = 1.0 / spec.rate_hz

    @property
    def gyro_sample_sigma_rad_s(self) -> float:
        """Std of one gyro sample's white noise [rad/s]."""
        return self.arw_rad_sqrt_s / math.sqrt(self.dt_s)

    @property
    def acc_sample_sigma_m_s2(self) -> float:
        """Std of one accelerometer sample's white noise [m/s^2]."""
        return self.vrw_m_s_sqrt_s / math.sqrt(self.dt_s)


def corrupt(
    omega_ib_b: np.ndarray, f_ib_b: np.ndarray, spec: ImuSpec, rng: np.random.Generator,
    bias_gyro_b: np.ndarray | None = None, bias_acc_b: np.ndarray | None = None,
):
    """Apply PI-LIEKF eq. (34): returns (omega_meas, f_meas, b_g, b_a); biases drawn unless given."""
    e = ImuErrorSI(spec)
    b_g = rng.normal(0.0, e.sigma_bg_rad_s, 3) if bias_gyro_b is None else np.asarray(bias_gyro_b, float)
    b_a = rng.normal(0.0, e.sigma_ba_m_s2, 3) if bias_acc_b is None else np.asarray(bias_acc_b, float)
    n = omega_ib_b.shape[0]
    w_g = rng.normal(0.0, e.gyro_sample_sigma_rad_s, (n, 3))
    w_a = rng.normal(0.0, e.acc_sample_sigma_m_s2, (n, 3))
    return omega_ib_b + b_g + w_g, f_ib_b + b_a + w_a, b_g, b_a


# ----------------------------------------------------------------------------- the papers' IMUs
#: PI-LIEKF Table 1 (ship simulation).
SHIP_IMU = ImuSpec("pi_liekf_table1", gyro_bias_deg_h=25.2, arw_deg_sqrt_h=2.0, acc_bias_mg=0.2,
                   vrw_m_s_sqrt_h=0.2, rate_hz=100.0)
#: PKF paper Table 1, ADIS16488A: bias stability 5.1 deg/h and 0.07 mg used as the constant-in-run bias sigma,
#: ARW 0.26 deg/sqrt(h), VRW 0.029 m/s/sqrt(h); 125 Hz.
ADIS16488A = ImuSpec("adis16488a", gyro_bias_deg_h=5.1, arw_deg_sqrt_h=0.26, acc_bias_mg=0.07,
                     vrw_m_s_sqrt_h=0.029, rate_hz=125.0)
#: A navigation-grade IMU (issue 6): 0.01 deg/h, 25 ug; noise 0.002 deg/sqrt(h), 10 ug/sqrt(Hz).
NAVGRADE = ImuSpec("navigation_grade", gyro_bias_deg_h=0.01, arw_deg_sqrt_h=0.002, acc_bias_mg=0.025,
                   vrw_m_s_sqrt_h=ug_sqrt_hz_to_m_s_sqrt_h(10.0), rate_hz=125.0)
#: Inverse-alignment paper Table 1: 0.002 deg/h and 20 ug bias; 0.0003 deg/sqrt(h) and 20 ug/sqrt(Hz) noise; 100 Hz.
RINS_IMU = ImuSpec("inverse_alignment_table1", gyro_bias_deg_h=0.002, arw_deg_sqrt_h=0.0003, acc_bias_mg=0.020,
                   vrw_m_s_sqrt_h=ug_sqrt_hz_to_m_s_sqrt_h(20.0), rate_hz=100.0)
#: A consumer-automotive MEMS IMU for the car scenario: 10 deg/h, 0.3 deg/sqrt(h), 1 mg, 0.1 m/s/sqrt(h); 100 Hz.
CAR_IMU = ImuSpec("automotive_mems", gyro_bias_deg_h=10.0, arw_deg_sqrt_h=0.3, acc_bias_mg=1.0,
                  vrw_m_s_sqrt_h=0.1, rate_hz=100.0)
