"""Batched (vectorised numpy) ECI strapdown helpers and compiled SE2(3) kernels shared by the ECI cores.

Body increments, attitude prefix products by a log-depth scan, velocity/position by cumulative sums with gravity at
the mid-points by a two-pass fixed point, the left-invariant transitions of PI-LIEKF eq. (41) and covariance by
suffix products (filters/liekf.py has the conventions; test/test_liekf.py checks them against the sequential
mechanization). The compiled kernels are the implementation; test/oracles.py keeps numpy references for the tests.
"""

from __future__ import annotations

import numpy as np

from ..core import earth, lie
from ..core import mechanization_numba as nb
from ..core.lie import _A_SERIES, _B_SERIES, _C1_SERIES, _C2_SERIES, _coeff_batch

_I3 = np.eye(3)


def so3_exp_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors -> (N, 3, 3) rotation matrices (same series split as lie.so3_exp)."""
    theta = np.linalg.norm(phi, axis=-1)
    a = _coeff_batch(theta, _A_SERIES, lambda t: np.sin(t) / t)
    b = _coeff_batch(theta, _B_SERIES, lambda t: (1.0 - np.cos(t)) / t**2)
    K = lie.hat3_batch(phi)
    return _I3 + a[:, None, None] * K + b[:, None, None] * (K @ K)


def so3_gamma2_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) Gamma_2 (lie.so3_gamma2) for a batch."""
    theta = np.linalg.norm(phi, axis=-1)
    c1 = _coeff_batch(theta, _C1_SERIES, lambda t: (t - np.sin(t)) / t**3)
    c2 = _coeff_batch(theta, _C2_SERIES, lambda t: (0.5 * t * t + np.cos(t) - 1.0) / t**4)
    K = lie.hat3_batch(phi)
    return 0.5 * _I3 + c1[:, None, None] * K + c2[:, None, None] * (K @ K)


def prefix_products(M: np.ndarray) -> np.ndarray:
    """(N, d, d) -> (N, d, d) with out[k] = M[0] @ M[1] @ ... @ M[k] (Hillis-Steele scan, log2 N batched matmuls)."""
    S = M.copy()
    n = S.shape[0]
    s = 1
    while s < n:
        S_new = S.copy()
        S_new[s:] = S[:-s] @ S[s:]
        S = S_new
        s *= 2
    return S


def step_increments_batch(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: np.ndarray):
    """Batched mechanization.step_increments: (exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2) per sample."""
    phi = omega_ib_b * dt_s[:, None]
    dC = so3_exp_batch(phi)
    dv_b = np.einsum("nij,nj->ni", lie.so3_left_jacobian_batch(phi), f_ib_b) * dt_s[:, None]
    dp_b = np.einsum("nij,nj->ni", so3_gamma2_batch(phi), f_ib_b) * (dt_s * dt_s)[:, None]
    return dC, dv_b, dp_b


def propagate_eci_batch(C_b_i, v_i, p_i, dt_s, dC, dv_b, dp_b, gravity_passes: int = 2):
    """The ECI mechanization of core/mechanization.propagate_eci over a batch of samples, vectorised.

    Returns (C_prev (N,3,3) attitude at the start of each step, C_end, v_end, p_end). The mid-point gravity
    is a fixed point (gravity depends on the positions it produces): start from the gravity at the first
    mid-point, then ``gravity_passes`` batched re-evaluations; the residual is below 1e-10 m over 100 samples
    (the gravity gradient is ~3e-6 s^-2). test_liekf.py checks this against the sequential propagate_eci.
    """
    n = dt_s.shape[0]
    C_rel = prefix_products(dC)
    C_all = C_b_i @ C_rel  # attitude at the end of each step
    C_prev = np.empty_like(C_all)
    C_prev[0] = C_b_i
    C_prev[1:] = C_all[:-1]
    dv_i = np.einsum("nij,nj->ni", C_prev, dv_b)
    dp_i = np.einsum("nij,nj->ni", C_prev, dp_b)
    dt = dt_s[:, None]
    g = np.broadcast_to(earth.gravitation_e(p_i + 0.5 * dt_s[0] * v_i), (n, 3))
    for it in range(gravity_passes + 1):
        v_inc = np.cumsum(dv_i + g * dt, axis=0)
        v_prev = np.empty((n, 3))
        v_prev[0] = 0.0
        v_prev[1:] = v_inc[:-1]
        v_prev += v_i
        p_inc = np.cumsum(v_prev * dt + dp_i + 0.5 * g * dt * dt, axis=0)
        if it == gravity_passes:
            break
        p_prev = np.empty((n, 3))
        p_prev[0] = 0.0
        p_prev[1:] = p_inc[:-1]
        p_prev += p_i
        g = earth.gravitation_e_batch(p_prev + 0.5 * dt * v_prev)
    return C_prev, C_all[-1], v_i + v_inc[-1], p_i + p_inc[-1]



def orthonormalize(C: np.ndarray) -> np.ndarray:
    """The nearest rotation to a nearly orthonormal C (|C^T C - I| ~ 1e-15 after a batch of exact steps): one Newton
    step of the polar decomposition, ``C (3 I - C^T C) / 2`` (quadratic convergence: exact to rounding from 1e-15;
    test/oracles.py has scipy's projection as the reference)."""
    return C @ (1.5 * _I3 - 0.5 * (C.T @ C))


def liekf_transition_batch(dC: np.ndarray, dv_b: np.ndarray, dp_b: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """(N, 9, 9) exact left-invariant error transitions ``Ad(U_k^-1) F_dt`` (eq. (41) to first order).

    ``U_k^-1 = (R, -R dv_b, -R dp_b)`` with ``R = dC^T``; ``Ad = [[R,0,0],[a_x R, R, 0],[b_x R, 0, R]]``,
    ``F_dt = [[I,0,0],[0,I,0],[0,dt I,I]]``.
    """
    n = dC.shape[0]
    R = np.transpose(dC, (0, 2, 1))
    a = -np.einsum("nij,nj->ni", R, dv_b)
    b = -np.einsum("nij,nj->ni", R, dp_b)
    Phi = np.zeros((n, 9, 9))
    Phi[:, 0:3, 0:3] = R
    Phi[:, 3:6, 3:6] = R
    Phi[:, 6:9, 6:9] = R
    Phi[:, 3:6, 0:3] = lie.hat3_batch(a) @ R
    Phi[:, 6:9, 0:3] = lie.hat3_batch(b) @ R
    Phi[:, 6:9, 3:6] = dt_s[:, None, None] * R
    return Phi


def covariance_batch(P: np.ndarray, Phi: np.ndarray, Qd: np.ndarray):
    """P_N = Phi_N ... Phi_1 P (..)^T + sum_k (Phi_N..Phi_{k+1}) Q_k (..)^T for (N, d, d) Phi and Q.

    Returns (P_N, Phi_N ... Phi_1). Suffix products by one scan over the reversed list.
    """
    U = prefix_products(Phi[::-1])  # U[j] = Phi_N Phi_{N-1} ... Phi_{N-j}
    n = Phi.shape[0]
    Q_rev = Qd[::-1]  # Q_rev[j] = Q_{N-j}
    Qsum = Q_rev[0].copy()
    if n > 1:
        T = U[:-1]  # T[j] = Phi_N .. Phi_{N-j} multiplies Q_{N-j-1}
        Qs = Q_rev[1:]
        q = np.diagonal(Qs, axis1=1, axis2=2)
        if np.all(q >= 0.0) and np.count_nonzero(Qs) == np.count_nonzero(q):
            # diagonal Q_k (every core here): sum_j T_j diag(q_j) T_j^T = A A^T with A = [T_j sqrt(q_j)]_j, one GEMM
            A = (T * np.sqrt(q)[:, None, :]).transpose(1, 0, 2).reshape(T.shape[1], -1)
            Qsum += A @ A.T
        else:
            Qsum += np.einsum("nij,njk,nlk->il", T, Qs, T, optimize=True)
    Phi_tot = U[-1]
    P_new = Phi_tot @ P @ Phi_tot.T + Qsum
    return 0.5 * (P_new + P_new.T), Phi_tot


@nb._jit
def retract_se23(C, v, p, xi):
    """``X exp(xi)`` on SE2(3) (eq. (14), lie.se23_exp): returns (C exp(phi), v + C J_l(phi) nu, p + C J_l(phi) rho)
    as new arrays."""
    x, y, z = xi[0], xi[1], xi[2]
    a, b, c1, _ = nb._coeffs(x * x + y * y + z * z)
    E = np.empty((3, 3))
    J = np.empty((3, 3))
    nb._so3_from(x, y, z, a, b, 1.0, E)
    nb._so3_from(x, y, z, b, c1, 1.0, J)
    Cn = np.empty((3, 3))
    nb._mm3(C, E, Cn)
    jn = np.empty(3)
    jr = np.empty(3)
    for i in range(3):
        jn[i] = J[i, 0] * xi[3] + J[i, 1] * xi[4] + J[i, 2] * xi[5]
        jr[i] = J[i, 0] * xi[6] + J[i, 1] * xi[7] + J[i, 2] * xi[8]
    vn = np.empty(3)
    pn = np.empty(3)
    # the whole increment first, then one addition to the 6.4e6 m position (one rounding at its 1e-9 m ulp, as the
    # 5x5 product of the reference path; three additions moved the attitude by 2e-10 rad over 60 s)
    for r in range(3):
        vn[r] = v[r] + (C[r, 0] * jn[0] + C[r, 1] * jn[1] + C[r, 2] * jn[2])
        pn[r] = p[r] + (C[r, 0] * jr[0] + C[r, 1] * jr[1] + C[r, 2] * jr[2])
    return Cn, vn, pn


@nb._jit
def gnss_terms_eci(c, s, p_e, R_e, C, p, lever, z, H, N):
    """``BatchedEciCore._gnss_terms`` without a floor, compiled: with ``C_e_i = [[c,-s,0],[s,c,0],[0,0,1]]``,
    ``p_i = C_e_i p_e``, ``R_i = C_e_i R_e C_e_i^T``, then ``_gnss_model``: ``z = C^T (p_i - p) - l``,
    ``H = [-l_x, 0, I]`` (H zero on entry), ``N = C^T R_i C``."""
    Cei = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    Ct = np.ascontiguousarray(C.T)
    z[:] = Ct @ (Cei @ p_e - p) - lever
    N[:, :] = Ct @ (Cei @ R_e @ np.ascontiguousarray(Cei.T)) @ C
    H[0, 1], H[0, 2] = lever[2], -lever[1]
    H[1, 0], H[1, 2] = -lever[2], lever[0]
    H[2, 0], H[2, 1] = lever[1], -lever[0]
    for i in range(3):
        H[i, 6 + i] = 1.0
