"""ECI strapdown over a batch of samples and the SE2(3) transitions shared by the ECI cores.

The mechanization itself is one compiled kernel (mechanization_numba.eci_steps, called through :func:`eci_steps`);
here: the left-invariant transitions of PI-LIEKF eq. (41), prefix products by a log-depth scan and the covariance by
suffix products (filters/liekf.py has the conventions). The compiled kernels are the implementation;
test/oracles.py keeps numpy references for the tests (the sequential mechanization among them).
"""

from __future__ import annotations

import numpy as np

from ..core import lie
from ..core import mechanization_numba as nb

_I3 = np.eye(3)


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


def eci_steps(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s):
    """The ECI mechanization (core/mechanization.py's scheme; compiled: mechanization_numba.eci_steps, the one
    implementation) over a batch of samples from (C_b_i, v_i, p_i), each core's forward and time-reversed steps.
    Returns the body increments of each step (exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2), the attitude at each
    step's start, and (C_b_i, v_i, p_i) at the end."""
    n = dt_s.shape[0]
    c = np.ascontiguousarray
    C, v, p = np.array(C_b_i, float), np.array(v_i, float), np.array(p_i, float)
    dC, C_prev = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    dv_b, dp_b = np.empty((n, 3)), np.empty((n, 3))
    nb.eci_steps(C, v, p, c(omega_ib_b, float), c(f_ib_b, float), c(dt_s, float), nb._ZONAL_N, nb._ZONAL_J, dC, dv_b,
                 dp_b, C_prev)
    return dC, dv_b, dp_b, C_prev, C, v, p


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
