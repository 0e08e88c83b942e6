"""Strapdown mechanization in ECI (PI-LIEKF eq. (35)), forward and inverse, fixed step.

Integration scheme (documented here once; the simulators generate IMU data consistent with it). The steps are one
compiled kernel (core/mechanization_numba.eci_steps, through filters/eci_batch.eci_steps); test/oracles.py keeps
their numpy form (``propagate_eci``, ``propagate_eci_inverse``) as the tests' reference:

* An IMU sample stamped ``t_k`` holds the *average* angular rate ``omega_ib_b`` [rad/s] and specific force
  ``f_ib_b`` [m/s^2] over the interval ``(t_{k-1}, t_k]`` (what an integrating IMU outputs as
  delta-angle/dt and delta-velocity/dt). Within the interval both are taken constant in the body frame.
* With ``phi = omega dt``:
  ``C_{k} = C_{k-1} exp(phi)``
  ``v_{k} = v_{k-1} + C_{k-1} J_l(phi) f dt + g_mid dt``
  ``p_{k} = p_{k-1} + v_{k-1} dt + C_{k-1} Gamma_2(phi) f dt^2 + g_mid dt^2 / 2``
  where J_l and Gamma_2 are the exact single and double integrals of exp over the step (lie.py), and
  ``g_mid`` is the ECI gravitation evaluated at the predicted midpoint ``p_{k-1} + v_{k-1} dt/2``
  (third-order accurate in dt; the Earth's field is axially symmetric so no epoch is needed).
* The inverse step recovers (C, v, p)_{k-1} from (C, v, p)_k and the same sample; the implicit gravity term
  is solved by a short fixed-point iteration (contraction ~ gravity gradient * dt^2 ~ 1e-10), so forward then
  inverse returns to the start to rounding error.

In ECI the attitude is ``C_b_i``, velocity ``v_i`` is the inertial velocity and position ``p_i`` the ECI
position; gravity is pure gravitation (no centrifugal term, no Coriolis term).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import earth
from . import mechanization_numba as nb


@dataclass
class NavStateEci:
    """Navigation state in ECI: attitude C_b_i, inertial velocity v_i [m/s], ECI position p_i [m], time t_s [s]."""

    t_s: float
    C_b_i: np.ndarray
    v_i: np.ndarray
    p_i: np.ndarray

    def copy(self) -> "NavStateEci":
        return NavStateEci(self.t_s, self.C_b_i.copy(), self.v_i.copy(), self.p_i.copy())


def state_eci_from_geodetic(
    t_s: float, t0_s: float, lat_rad: float, lon_rad: float, h_m: float, C_b_n: np.ndarray, v_n: np.ndarray
) -> NavStateEci:
    """ECI state of a body at geodetic position, ENU velocity [m/s] and attitude C_b_n, at time t_s."""
    C_ne = earth.C_n_e(lat_rad, lon_rad)
    p_e = earth.geodetic_to_ecef(lat_rad, lon_rad, h_m)
    p_i, v_i = earth.ecef_to_eci(t_s, p_e, C_ne @ v_n, t0_s)
    C_ei = earth.C_e_i(t_s, t0_s)
    return NavStateEci(t_s, C_ei @ C_ne @ C_b_n, v_i, p_i)


def navigation_from_state_eci(state: NavStateEci, t0_s: float, P_att: np.ndarray, inertial: bool):
    """(lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n) of an ECI state whose attitude error covariance ``P_att`` is
    kept in the body frame (``inertial`` False) or in ECI (True): one compiled call
    (mechanization_numba.eci_navigation, once per output). Within 1 km of the Earth's centre (a lost filter) the
    geodetic position is NaN and so is everything else."""
    C_b_n, v_n, P_att_n = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    c = np.ascontiguousarray
    lat, lon, h = nb.eci_navigation(float(state.t_s), float(t0_s), c(state.C_b_i, float), c(state.v_i, float),
                                    c(state.p_i, float), c(P_att, float), bool(inertial), C_b_n, v_n, P_att_n)
    return lat, lon, h, C_b_n, v_n, P_att_n
