"""Strapdown mechanization in ECI (PI-LIEKF eq. (35)), forward and inverse, fixed step.

Integration scheme (documented here once; the simulators generate IMU data consistent with it):

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

from . import earth, lie
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


def step_increments(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: float):
    """Body-frame increments of one step: (exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2)."""
    phi = omega_ib_b * dt_s
    return (
        lie.so3_exp(phi),
        lie.so3_left_jacobian(phi) @ f_ib_b * dt_s,
        lie.so3_gamma2(phi) @ f_ib_b * (dt_s * dt_s),
    )


def gravity_mid_i(p_i: np.ndarray, v_i: np.ndarray, dt_s: float) -> np.ndarray:
    """ECI gravitation [m/s^2] at the predicted midpoint of a step (see module docstring)."""
    return earth.gravitation_e(p_i + 0.5 * dt_s * v_i)


def propagate_eci(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s):
    """One forward step of the ECI mechanization; returns (C_b_i, v_i, p_i) at the end of the step."""
    dC, dv_b, dp_b = step_increments(omega_ib_b, f_ib_b, dt_s)
    g = gravity_mid_i(p_i, v_i, dt_s)
    v_new = v_i + C_b_i @ dv_b + g * dt_s
    p_new = p_i + v_i * dt_s + C_b_i @ dp_b + 0.5 * dt_s * dt_s * g
    return C_b_i @ dC, v_new, p_new


def propagate_eci_inverse(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s, iterations: int = 3):
    """Inverse step: from the state at the end of a step and its sample, the state at its start."""
    dC, dv_b, dp_b = step_increments(omega_ib_b, f_ib_b, dt_s)
    C_prev = C_b_i @ dC.T
    dv_i = C_prev @ dv_b
    dp_i = C_prev @ dp_b
    v_prev, p_prev = v_i - dv_i, p_i - v_i * dt_s  # gravity-free first guess
    for _ in range(iterations):
        g = gravity_mid_i(p_prev, v_prev, dt_s)
        v_prev = v_i - dv_i - g * dt_s
        p_prev = p_i - v_prev * dt_s - dp_i - 0.5 * dt_s * dt_s * g
    return C_prev, v_prev, p_prev


def state_eci_from_geodetic(
    t_s: float, t0_s: float, lat_rad: float, lon_rad: float, h_m: float, C_b_n: np.ndarray, v_n: np.ndarray
) -> NavStateEci:
    """ECI state of a body at geodetic position, ENU velocity [m/s] and attitude C_b_n, at time t_s."""
    C_ne = earth.C_n_e(lat_rad, lon_rad)
    p_e = earth.geodetic_to_ecef(lat_rad, lon_rad, h_m)
    p_i, v_i = earth.ecef_to_eci(t_s, p_e, C_ne @ v_n, t0_s)
    C_ei = earth.C_e_i(t_s, t0_s)
    return NavStateEci(t_s, C_ei @ C_ne @ C_b_n, v_i, p_i)


def geodetic_from_state_eci(state: NavStateEci, t0_s: float):
    """(lat_rad, lon_rad, h_m, C_b_n, v_n) of an ECI state."""
    return navigation_from_state_eci(state, t0_s, _ZERO3, False)[:5]


_ZERO3 = np.zeros((3, 3))


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
