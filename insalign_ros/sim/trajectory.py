"""Trajectory -> exact IMU by inverse navigation ("reverse navigation", PI-LIEKF sec. 6).

A trajectory gives, on a time grid, the ECEF position ``p_e`` [m], the ECEF velocity ``v_e`` [m/s] and the
attitude ``C_b_n`` (body FLU -> local ENU at the current position). The generator maps it to ECI
(core/earth.py: ECI == ECEF at ``t0_s``) and solves the project's own ECI mechanization
(core/mechanization.py) for the IMU sample of every step, so that the noise-free samples integrated by that
mechanization reproduce the trajectory:

* ``omega_k = log(C_b_i[k-1]^T C_b_i[k]) / dt`` — exact attitude increment of the step;
* ``f_k = J_l(omega_k dt)^-1 C_b_i[k-1]^T (v_i[k] - v_i[k-1] - g_mid dt) / dt`` — exact velocity increment, with
  the same midpoint gravitation ``g_mid`` as the mechanization.

The position then follows from the velocity to third order in dt (the mechanization assumes constant body rate
and specific force over a step): ~1e-3 m over 300 s of the ship's wave motion (tests/test_sim_*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import earth, lie


@dataclass
class TrajectorySamples:
    """Truth on a time grid (arrays aligned on t_s)."""

    t_s: np.ndarray  # (N,)
    p_e: np.ndarray  # (N, 3) ECEF [m]
    v_e: np.ndarray  # (N, 3) ECEF velocity relative to Earth [m/s]
    C_b_n: np.ndarray  # (N, 3, 3) body FLU -> local ENU
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray

    @property
    def v_n(self) -> np.ndarray:
        """ENU velocity at the current position [m/s]."""
        return np.einsum("nij,nj->ni", C_e_n_batch(self.lat_rad, self.lon_rad), self.v_e)


def C_e_n_batch(lat_rad: np.ndarray, lon_rad: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations ECEF -> local ENU (rows E, N, U), vectorised core.earth.C_e_n."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    z = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


def C_e_i_batch(t_s: np.ndarray, t0_s: float) -> np.ndarray:
    """(N, 3, 3) rotations ECEF -> ECI, vectorised core.earth.C_e_i."""
    a = earth.OMEGA_IE_RAD_S * (t_s - t0_s)
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def from_local_enu(t_s, p_n, v_n, C_b_n, lat0_rad, lon0_rad, h0_m) -> TrajectorySamples:
    """Trajectory given in the tangent-plane ENU frame at (lat0, lon0, h0): ECEF is an exact Cartesian map of it.

    p_n, v_n: (N, 3) position [m] and velocity [m/s] in the *reference* tangent frame; C_b_n: body -> ENU at the
    *current* position (the truth attitude that users and the papers mean).
    """
    C_ne0 = earth.C_n_e(lat0_rad, lon0_rad)
    p_e = earth.geodetic_to_ecef(lat0_rad, lon0_rad, h0_m) + p_n @ C_ne0.T
    v_e = v_n @ C_ne0.T
    import pymap3d

    lat, lon, h = pymap3d.ecef2geodetic(p_e[:, 0], p_e[:, 1], p_e[:, 2], deg=False)
    return TrajectorySamples(np.asarray(t_s, float), p_e, v_e, np.asarray(C_b_n, float),
                             np.asarray(lat), np.asarray(lon), np.asarray(h))


def to_eci(traj: TrajectorySamples, t0_s: float):
    """(C_b_i, v_i, p_i) arrays of a trajectory, ECI == ECEF at t0_s."""
    C_ei = C_e_i_batch(traj.t_s, t0_s)
    C_ne = np.transpose(C_e_n_batch(traj.lat_rad, traj.lon_rad), (0, 2, 1))
    C_b_i = C_ei @ C_ne @ traj.C_b_n
    p_i = np.einsum("nij,nj->ni", C_ei, traj.p_e)
    v_i = np.einsum("nij,nj->ni", C_ei, traj.v_e + np.cross(earth.OMEGA_IE_E, traj.p_e))
    return C_b_i, v_i, p_i


def imu_from_trajectory(traj: TrajectorySamples, t0_s: float):
    """Exact IMU samples for steps k = 1..N-1 of the trajectory: (omega_ib_b, f_ib_b), each (N-1, 3).

    Sample k is the average over (t_{k-1}, t_k]; see the module docstring for why it is exact for the
    project's mechanization.
    """
    C_b_i, v_i, p_i = to_eci(traj, t0_s)
    dt = np.diff(traj.t_s)
    dC = np.einsum("nji,njk->nik", C_b_i[:-1], C_b_i[1:])  # C_{k-1}^T C_k
    phi = Rotation.from_matrix(dC).as_rotvec()
    omega = phi / dt[:, None]
    g_mid = earth.gravitation_e_batch(p_i[:-1] + 0.5 * dt[:, None] * v_i[:-1])
    dv_i = v_i[1:] - v_i[:-1] - g_mid * dt[:, None]
    dv_b = np.einsum("nji,nj->ni", C_b_i[:-1], dv_i)  # C_{k-1}^T dv
    f = np.einsum("nij,nj->ni", lie.so3_left_jacobian_inv_batch(phi), dv_b) / dt[:, None]
    return omega, f
