"""LIEKF in ECI on SE2(3) (PI-LIEKF Alg. 1, eqs. (4)-(15), (35)-(43)) and the batched ECI core it shares.

Conventions (docs/inmotion_cores.md has the derivations):

* State ``X = [[C_b_i, v_i, p_i], [0, 1, 0], [0, 0, 1]]`` (eq. (36)); ECI == ECEF at the initialisation stamp.
* Error: truth ``X = X_hat exp(xi)``, ``xi = [phi, nu, rho]`` (body-frame, left-invariant). The paper writes
  ``eta = X^-1 X_hat = exp(xi_paper)``, so ``xi_paper = -xi``. The linear error dynamics are homogeneous, so
  A of eq. (41) is the same for both signs; the paper's eq. (14) ``X_hat exp(xi_hat)`` is only consistent with
  our sign (with theirs it would need ``exp(-xi_hat)``), so we use ours throughout.
* Propagation: the exact discrete transition of the left-invariant error for the project's strapdown scheme
  (core/mechanization.py): ``X_k = G_k Phi_dt(X_{k-1}) U_k`` with the body increment ``U_k`` and the
  gravity element ``G_k``; ``Phi_dt`` is a group automorphism, so ``xi_k = Ad(U_k^-1) F_dt xi_{k-1}``
  (``F_dt``: rho += nu dt). Its first-order expansion is eq. (41), ``I + A_c T_s``; test_liekf.py checks both
  against a finite-difference linearisation of the true error dynamics. The gravity gradient is neglected
  (as in eq. (41)).
* GNSS (eqs. (42), (43), (11)): ``z = C^T (p_gps_i - p_hat_i)`` (= X_hat^-1 Y - d), ``H = [0 0 I]``,
  ``N = C^T R_i C``; Joseph form (eq. (13)); retraction ``X_hat exp(dxi)`` (eq. (14)). With the antenna lever
  arm ``l`` (body FLU, ``gnss_lever_arm_b_m``): ``z = C^T (p_gps_i - p_hat_i) - l``, ``H = [-l_x 0 I]``.
* GNSS velocity (ENU, relative to Earth, at the antenna) -> ECI inertial antenna velocity
  ``v_meas_i = C_e_i (C_n_e v_n + omega_ie x p_ant_e)``; model ``v_ant_i = v_i + C_b_i (omega_ib_b x l)`` (exact in
  ECI: the inertial derivative of ``C_b_i l``); ``z = C^T (v_meas_i - v_hat_i) - a`` with ``a = omega_ib_b x l``,
  ``H = [-a_x I 0]`` (docs/inmotion_cores.md, "GNSS velocity and lever arm").
* Attitude output: ``C_b_n_true = C_b_n_hat exp(phi_x) = exp((C_b_n_hat phi)_x) C_b_n_hat`` so
  ``psi_n = C_b_n_hat phi`` and ``P_att_n = C_b_n P_phiphi C_b_n^T`` (a Monte-Carlo NEES test checks it).

Speed: IMU samples are buffered and propagated in vectorised batches (body increments, attitude prefix
products by a log-depth scan, velocity/position by cumulative sums with gravity at the mid-points by a
two-pass fixed point, covariance by suffix products of the state-independent transitions). The buffer is
flushed by every update, every ``estimate()`` and every ``max_batch_samples`` samples.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import earth, lie
from ..core import mechanization_numba as nb
from ..core.lie import _A_SERIES, _B_SERIES, _C1_SERIES, _C2_SERIES, _coeff_batch
from ..core.mechanization import NavStateEci, geodetic_from_state_eci, state_eci_from_geodetic
from ..core.units import deg_sqrt_h_to_rad_sqrt_s, m_s_sqrt_h_to_m_s_sqrt_s
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, GnssFix, GnssVelocity, ImuSample, UpdateResult
from .config import LiekfConfig

_I3 = np.eye(3)
_NO_TOT = np.eye(1)  # the fused kernel's transition product when no correction reads it (not written)


# ------------------------------------------------------------------------------------ batched helpers
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
    """The nearest rotation to a nearly orthonormal C (|C^T C - I| ~ 1e-15 after a batch of exact steps).

    Reference path: scipy's projection; compiled path: one Newton step of the polar decomposition,
    ``C (3 I - C^T C) / 2`` (quadratic convergence: exact to rounding from 1e-15), 30x cheaper."""
    if not nb.ENABLED:
        return Rotation.from_matrix(C).as_matrix()
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


def liekf_A_eq41(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: float) -> np.ndarray:
    """The paper's first-order A of eq. (41): ``I + [[-w_x,0,0],[-f_x,-w_x,0],[0,I,-w_x]] T_s``."""
    W, Fx = lie.hat3(omega_ib_b), lie.hat3(f_ib_b)
    Ac = np.zeros((9, 9))
    Ac[0:3, 0:3] = -W
    Ac[3:6, 0:3] = -Fx
    Ac[3:6, 3:6] = -W
    Ac[6:9, 3:6] = _I3
    Ac[6:9, 6:9] = -W
    return np.eye(9) + Ac * dt_s


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
def _joseph_nb(P, H, N):
    """:func:`joseph_update` compiled (the same products, LAPACK solve); returns (L, P_new, S)."""
    HP = H @ P
    S = HP @ np.ascontiguousarray(H.T) + N
    S = 0.5 * (S + S.T)
    L = np.ascontiguousarray(np.linalg.solve(S, HP).T)
    IKH = np.eye(P.shape[0]) - L @ H
    P_new = IKH @ P @ np.ascontiguousarray(IKH.T) + L @ N @ np.ascontiguousarray(L.T)
    return L, 0.5 * (P_new + P_new.T), S


@nb._jit
def _prediction_nb(P, H, N, z):
    """``BatchedEciCore._prediction`` compiled: ``S = H P H^T + N`` symmetrised (the products of :func:`_joseph_nb`)
    and the NIS; returns (S, nis)."""
    S = (H @ P) @ np.ascontiguousarray(H.T) + N
    S = 0.5 * (S + S.T)
    return S, _nis_nb(S, z)


@nb._jit
def _nis_nb(S, z):
    """z^T S^-1 z (LAPACK solve)."""
    y = np.linalg.solve(S, z)
    s = 0.0
    for i in range(z.shape[0]):
        s += z[i] * y[i]
    return s


@nb._jit
def _spd3_nb(R) -> bool:
    """Whether the symmetric part of a 3x3 matrix has a Cholesky factor (the test of ``np.linalg.cholesky``)."""
    A = 0.5 * (R + R.T)
    L = np.zeros((3, 3))
    for j in range(3):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, 3):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@nb._jit
def _retract_nb(C, v, p, xi):
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


def _spd3(R: np.ndarray) -> bool:
    """3x3 covariance test of the checks below (compiled; numpy's Cholesky on the reference path)."""
    if nb.ENABLED:
        return _spd3_nb(np.ascontiguousarray(R, dtype=float))
    try:
        np.linalg.cholesky(0.5 * (R + R.T))
    except np.linalg.LinAlgError:
        return False
    return True


@nb._jit
def _gnss_terms_nb(c, s, p_e, R_e, C, p, lever, z, H, N):
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


def nis(S: np.ndarray, z: np.ndarray) -> float:
    """Normalised innovation squared z^T S^-1 z."""
    if nb.ENABLED:
        return float(_nis_nb(np.ascontiguousarray(S, dtype=float), np.ascontiguousarray(z, dtype=float)))
    return float(z @ np.linalg.solve(S, z))


def joseph_update(P: np.ndarray, H: np.ndarray, N: np.ndarray, compiled: bool = False):
    """Kalman gain and Joseph-form covariance (PI-LIEKF eqs. (11), (13)); returns (L, P_new, S). ``compiled``: the
    same products in a numba kernel (when ``mechanization_numba.ENABLED``)."""
    if compiled and nb.ENABLED:
        return _joseph_nb(np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(H, dtype=float),
                          np.ascontiguousarray(N, dtype=float))
    S = H @ P @ H.T + N
    S = 0.5 * (S + S.T)
    L = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S symmetric)
    IKH = np.eye(P.shape[0]) - L @ H
    P_new = IKH @ P @ IKH.T + L @ N @ L.T
    return L, 0.5 * (P_new + P_new.T), S


def _check_fix(fix: GnssFix) -> str:
    p = np.asarray(fix.p_e, float)
    R = np.asarray(fix.R_e, float)
    if p.shape != (3,) or R.shape != (3, 3):
        return f"bad shapes p_e {p.shape}, R_e {R.shape}"
    if nb.ENABLED:  # the same tests in floats (numpy's per-call overhead was most of the ~13 us; twice per fix)
        pl = p.tolist()
        if not all(map(math.isfinite, pl + R.ravel().tolist())):
            return "non-finite position or covariance"
        norm = math.sqrt(pl[0] * pl[0] + pl[1] * pl[1] + pl[2] * pl[2])  # np.linalg.norm's sum, same order
        if not 6.0e6 < norm < 7.0e6:
            return f"ECEF position norm {norm:.0f} m is not near the Earth's surface"
        return "" if _spd3(R) else "covariance R_e is not positive definite"
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
        return "non-finite position or covariance"
    if not 6.0e6 < np.linalg.norm(p) < 7.0e6:
        return f"ECEF position norm {np.linalg.norm(p):.0f} m is not near the Earth's surface"
    if not _spd3(R):
        return "covariance R_e is not positive definite"
    return ""


def check_velocity(v_n, R_n) -> str:
    """Why a GNSS velocity (v_n (3,) [m/s], R_n (3, 3) [m^2/s^2]) is unusable, or "" (shared with the session)."""
    v = np.asarray(v_n, float)
    R = np.asarray(R_n, float)
    if v.shape != (3,) or R.shape != (3, 3):
        return f"bad shapes v_n {v.shape}, R_n {R.shape}"
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(R))):
        return "non-finite velocity or covariance"
    if not _spd3(R):
        return "covariance not positive definite (unknown or zero covariance)"
    return ""


def _check_imu(imu: ImuSample) -> str:
    w = np.asarray(imu.omega_ib_b, float)
    f = np.asarray(imu.f_ib_b, float)
    if w.shape != (3,) or f.shape != (3,):
        return f"bad shapes omega {w.shape}, f {f.shape}"
    # one scalar test (hot path: every sample): a sum is non-finite iff a term is (or it overflows: garbage too)
    if not (math.isfinite(float(w[0] + w[1] + w[2] + f[0] + f[1] + f[2])) and math.isfinite(imu.stamp_s)):
        return "non-finite IMU sample"
    return ""


@nb._jit
def _usable_nb(t, w, f, t_last, dt):
    """``usable_imu_arrays``' test in one pass: every row finite (one running sum, as the numpy test: non-finite iff a
    term is, or the sum overflows), the intervals from ``t_last`` in (0, 1] s; fills ``dt`` with them."""
    n = t.shape[0]
    s = 0.0
    for k in range(n):
        s += t[k] + w[k, 0] + w[k, 1] + w[k, 2] + f[k, 0] + f[k, 1] + f[k, 2]
    if not math.isfinite(s):
        return False
    prev = t_last
    for k in range(n):
        d = t[k] - prev
        dt[k] = d
        if not (d > 0.0 and d <= 1.0):
            return False
        prev = t[k]
    return True


def usable_imu_arrays(t_s, omega_ib_b, f_ib_b, t_last_s: float):
    """(t (N,), omega (N, 3), f (N, 3), dt (N,)) as float arrays when every row is usable: finite, stamps after
    ``t_last_s`` and increasing by at most 1 s; else None (the caller takes the per-sample path, which rejects and
    counts the bad rows). The array fast paths of the cores share this check."""
    t = np.asarray(t_s, float)
    w = np.asarray(omega_ib_b, float)
    f = np.asarray(f_ib_b, float)
    n = t.shape[0] if t.ndim == 1 else 0
    if n == 0 or w.shape != (n, 3) or f.shape != (n, 3):
        return None
    if nb.ENABLED:  # one compiled pass: ~1 us instead of ~6 us of numpy calls (runs of ~12 samples at 10-Hz updates)
        dt = np.empty(n)
        return (t, w, f, dt) if _usable_nb(t, w, f, float(t_last_s), dt) else None
    # one finiteness test: a sum is non-finite iff a term is (or it overflows: garbage, the per-sample path decides)
    if not math.isfinite(float(t.sum()) + float(w.sum()) + float(f.sum())):
        return None
    dt = np.empty(n)
    dt[0] = t[0] - t_last_s
    np.subtract(t[1:], t[:-1], out=dt[1:])
    return (t, w, f, dt) if dt.min() > 0.0 and dt.max() <= 1.0 else None


class ImuBuffer:
    """IMU samples waiting for a core's next flush, added one by one (``add``: a stamp or step [s] and two (3,)
    rows) or as blocks (``add_block``: (k,) and (k, 3) arrays, kept as they are); ``take`` returns them as
    (n,), (n, 3), (n, 3) float arrays (the same values in the same order) and empties the buffer."""

    __slots__ = ("t", "w", "f", "n", "blocks", "last_t")

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.t: list = []
        self.w: list = []
        self.f: list = []
        self.n = 0
        self.blocks = False
        self.last_t = 0.0

    def add(self, t: float, w, f) -> None:
        self.t.append(t)
        self.w.append(w)
        self.f.append(f)
        self.n += 1
        self.last_t = t

    def add_block(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> None:
        if t.shape[0]:
            self.t.append(t)
            self.w.append(w)
            self.f.append(f)
            self.n += t.shape[0]
            self.blocks = True
            self.last_t = float(t[-1])

    def take(self):
        if self.blocks and len(self.t) == 1:
            out = self.t[0], self.w[0], self.f[0]
        elif self.blocks:
            out = (np.hstack(self.t).astype(float, copy=False), np.vstack(self.w).astype(float, copy=False),
                   np.vstack(self.f).astype(float, copy=False))
        else:
            out = np.asarray(self.t, float), np.asarray(self.w, float), np.asarray(self.f, float)
        self.clear()
        return out


# ----------------------------------------------------------------------------------- the shared core
class BatchedEciCore(AlignmentCore):
    """ECI strapdown + error-state covariance with batched propagation; subclasses define the error model.

    Subclass hooks: ``_n_states``, ``state_names``, ``_bias_correct(omega, f)``, ``_transitions(...)``,
    ``_P0(P_att_n, sigma_v, sigma_p)``, ``_gnss_model()``, ``_inject(dx)``, ``_P_att_n()``.
    """

    needs_motion = True
    supports_gnss = True
    supports_gnss_velocity = True
    att_index = (0, 1, 2)
    vel_index = (3, 4, 5)
    pos_index = (6, 7, 8)
    _n_states = 9
    state_names: tuple[str, ...] = ()

    def __init__(self, config=None):
        self.cfg = config if config is not None else self.config_class()
        self.cfg.validate()
        self._init = False
        self._buf = ImuBuffer()
        self.counters = {"imu": 0, "imu_rejected": 0, "gnss": 0, "gnss_rejected": 0, "gnss_vel": 0,
                         "gnss_vel_rejected": 0}
        self.lever_b = np.asarray(getattr(self.cfg, "gnss_lever_arm_b_m", (0.0, 0.0, 0.0)), float)
        self.last_reject_reason = ""
        arw = deg_sqrt_h_to_rad_sqrt_s(self.cfg.gyro_arw_deg_sqrt_h)
        vrw = m_s_sqrt_h_to_m_s_sqrt_s(self.cfg.acc_vrw_m_s_sqrt_h)
        self._q_gyro = arw * arw  # PSD [rad^2/s]
        self._q_acc = vrw * vrw  # PSD [m^2/s^3]

    config_class = LiekfConfig

    # ---------------------------------------------------------------- life cycle
    @property
    def initialized(self) -> bool:
        return self._init

    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m) -> None:
        self.t0_s = float(stamp_s)
        s = state_eci_from_geodetic(self.t0_s, self.t0_s, lat_rad, lon_rad, h_m, np.asarray(C_b_n, float),
                                    np.asarray(v_n, float))
        self.t_s = self.t0_s
        self.C, self.v, self.p = s.C_b_i, s.v_i, s.p_i
        self.b_g = np.zeros(3)
        self.b_a = np.zeros(3)
        self.omega_b = np.zeros(3)  # bias-corrected rate of the newest sample [rad/s] (lever-arm velocity)
        C_b_n = np.asarray(C_b_n, float)
        self.P = self._P0(C_b_n, np.asarray(P_att_n, float), float(sigma_v_m_s), float(sigma_p_m))
        self._P0_att = self.P[0:3, 0:3].copy()
        self._buf = ImuBuffer()
        self._Phi_since_update = np.eye(self._n_states)
        self._t_last_update = self.t0_s
        self._init = True

    def propagate(self, imu: ImuSample) -> None:
        """Buffer one IMU sample (propagated in a batch on the next flush). Bad samples are rejected."""
        if not self._init:
            self._reject_imu("not initialised")
            return
        t_last = self._buf.last_t if self._buf.n else self.t_s
        reason = _check_imu(imu)
        if not reason and not imu.stamp_s > t_last:
            reason = f"stamp {imu.stamp_s:.6f} not after {t_last:.6f}"
        if not reason and imu.stamp_s - t_last > 1.0:
            reason = f"gap of {imu.stamp_s - t_last:.3f} s (> 1 s) before this sample"
        if reason:
            self._reject_imu(reason)
            if "gap" not in reason:
                return
            # a gap: propagate anyway (the sample's average covers the gap) but count it
        self.counters["imu"] += 1
        self._buf.add(float(imu.stamp_s), np.asarray(imu.omega_ib_b, float), np.asarray(imu.f_ib_b, float))
        if self._buf.n >= self.cfg.max_batch_samples:
            self.flush()

    def _reject_imu(self, reason: str) -> None:
        self.counters["imu_rejected"] += 1
        self.last_reject_reason = f"IMU: {reason}"

    def flush(self) -> None:
        """Propagate the buffered samples (state and covariance)."""
        if not self._buf.n:
            return
        self._propagate_block(*self._buf.take())

    def propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        """Forward: whole arrays without a Python step per sample, in the same batches as sample-by-sample
        ``propagate`` (so the same numbers); any unusable row (non-finite, stamps not increasing, a gap > 1 s) sends
        the call through the per-sample path, which rejects and counts it."""
        arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, self._buf.last_t if self._buf.n else self.t_s) \
            if self._init and not backward else None
        if arr is None:
            super().propagate_arrays(t_s, omega_ib_b, f_ib_b, backward)
            return
        t, w, f, _ = arr
        n = t.shape[0]
        self.counters["imu"] += n
        mb = self.cfg.max_batch_samples
        i = min(n, mb - self._buf.n)  # complete the pending batch first, as propagate() would
        self._buf.add_block(t[:i], w[:i], f[:i])
        if self._buf.n >= mb:
            self.flush()
        while n - i >= mb:
            self._propagate_block(t[i:i + mb], w[i:i + mb], f[i:i + mb])
            i += mb
        if i < n:
            self._buf.add_block(t[i:], w[i:], f[i:])

    def _propagate_block(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> None:
        """Propagate state and covariance over samples (t (N,) [s], raw omega_ib_b, f_ib_b (N, 3))."""
        fs = self._fused_setup() if nb.ENABLED else None
        if fs is not None and fs[0]:  # state, transitions, covariance and re-orthonormalisation in one compiled call
            _, want_tot, qrate = fs
            C, v, p = self.C.copy(), self.v.copy(), self.p.copy()
            P = np.array(self.P, dtype=float)  # exactly symmetric on return (the kernel mirrors its upper triangle)
            tot = np.eye(self._n_states) if want_tot else _NO_TOT
            self.omega_b = nb.eci_invariant_block(C, v, p, np.asarray(t, float), np.asarray(w, float),
                                                  np.asarray(f, float), self.t_s, np.asarray(self.b_g, float),
                                                  np.asarray(self.b_a, float), nb._ZONAL_N, nb._ZONAL_J, P, qrate,
                                                  want_tot, tot)
            if want_tot:
                self._Phi_since_update = tot @ self._Phi_since_update
            self.P, self.C, self.v, self.p = P, C, v, p
            self.t_s = float(t[-1])
            return
        w = w - self.b_g
        f = f - self.b_a
        dt = np.empty(t.shape[0])
        dt[0] = t[0] - self.t_s
        np.subtract(t[1:], t[:-1], out=dt[1:])
        if nb.ENABLED:  # compiled sequential loops (docs/speed.md); the numpy batch below is the reference path
            n = dt.shape[0]
            C, v, p = self.C.copy(), self.v.copy(), self.p.copy()
            dC, C_prev = np.empty((n, 3, 3)), np.empty((n, 3, 3))
            dv_b, dp_b = np.empty((n, 3)), np.empty((n, 3))
            nb.eci_steps(C, v, p, w, f, dt, nb._ZONAL_N, nb._ZONAL_J, dC, dv_b, dp_b, C_prev)
            Phi, Qd = self._transitions(dC, dv_b, dp_b, dt, C_prev, f)
            q = np.diagonal(Qd, axis1=1, axis2=2)
            if np.count_nonzero(Qd) == np.count_nonzero(q):  # diagonal Q_k (every core here)
                P, Phi_tot = nb.covariance_steps(self.P, Phi, q.copy())
                self.P = 0.5 * (P + P.T)
            else:
                self.P, Phi_tot = covariance_batch(self.P, Phi, Qd)
        else:
            dC, dv_b, dp_b = step_increments_batch(w, f, dt)
            C_prev, C, v, p = propagate_eci_batch(self.C, self.v, self.p, dt, dC, dv_b, dp_b)
            Phi, Qd = self._transitions(dC, dv_b, dp_b, dt, C_prev, f)
            self.P, Phi_tot = covariance_batch(self.P, Phi, Qd)
        self._Phi_since_update = Phi_tot @ self._Phi_since_update
        self.omega_b = w[-1].copy()
        self.C = orthonormalize(C)  # once per batch
        self.v, self.p = v, p
        self.t_s = float(t[-1])

    #: set on a class whose ``_transitions`` and ``_noise_diag`` are the left-invariant ones that
    #: ``mechanization_numba.eci_invariant_steps`` builds itself (LIEKF 9 states; imperfect IEKF 15 states)
    _fused_kernel_transitions = True

    @classmethod
    def _fused_transition(cls) -> bool:
        """Whether the fused compiled kernel reproduces this class's transitions and noise: the class that defines
        ``_transitions`` also defines ``_noise_diag`` and declares ``_fused_kernel_transitions`` itself."""
        owner = next(k for k in cls.__mro__ if "_transitions" in k.__dict__)
        return (owner.__dict__.get("_fused_kernel_transitions", False) and "_noise_diag" in owner.__dict__
                and cls._n_states in (9, 15))

    def _fused_setup(self):
        """(fused kernel usable, transition product wanted, noise PSDs per state: ``_noise_diag(dt) = qrate dt``),
        evaluated once per core (the configuration is fixed after construction)."""
        fs = self.__dict__.get("_fused_cache")
        if fs is None:
            fs = self._fused_cache = (self._fused_transition(), self._tracks_phi_since_update(),
                                      np.ascontiguousarray(self._noise_diag(np.ones(1))[0], dtype=float))
        return fs

    @classmethod
    def _tracks_phi_since_update(cls) -> bool:
        """Whether a correction reads ``_Phi_since_update`` (PI-LIEKF's eq. (30) overrides ``_correction``); the
        fused kernel forms the transition product only then."""
        return cls._correction is not BatchedEciCore._correction

    def default_initial_sigmas(self):
        c = self.cfg
        return (c.init_sigma_roll_deg, c.init_sigma_pitch_deg, c.init_sigma_yaw_deg), c.init_sigma_v_m_s, c.init_sigma_p_m

    # ---------------------------------------------------------------- hooks
    def _P0(self, C_b_n, P_att_n, sigma_v, sigma_p) -> np.ndarray:
        """phi = C_b_n^T psi_n (body frame); nu, rho ~ isotropic, so their rotation to the body frame is free."""
        P = np.zeros((self._n_states, self._n_states))
        P[0:3, 0:3] = C_b_n.T @ P_att_n @ C_b_n
        P[3:6, 3:6] = sigma_v * sigma_v * _I3
        P[6:9, 6:9] = sigma_p * sigma_p * _I3
        return P

    def _noise_diag(self, dt: np.ndarray) -> np.ndarray:
        d = np.zeros((dt.shape[0], self._n_states))
        d[:, 0:3] = self._q_gyro * dt[:, None]
        d[:, 3:6] = self._q_acc * dt[:, None]
        return d

    def _transitions(self, dC, dv_b, dp_b, dt, C_prev, f):
        Phi = liekf_transition_batch(dC, dv_b, dp_b, dt)
        Qd = np.zeros((dt.shape[0], 9, 9))
        idx = np.arange(9)
        Qd[:, idx, idx] = self._noise_diag(dt)
        return Phi, Qd

    def _gnss_model(self, p_gps_i: np.ndarray, R_i: np.ndarray):
        """(z, H, N): left-invariant position innovation, eqs. (10), (11), (42), (43), of the antenna at the lever
        arm l: p_ant = p + C exp(phi) l, so z = C^T (p_gps - p) - l = rho - l_x phi."""
        Ct = self.C.T
        return Ct @ (p_gps_i - self.p) - self.lever_b, self._position_H(), Ct @ R_i @ self.C

    def _position_H(self) -> np.ndarray:
        """H of the position innovation z = rho - l_x phi (:meth:`_gnss_model`): (3, n_states)."""
        H = np.zeros((3, self._n_states))
        H[:, 0:3] = -lie.hat3(self.lever_b)
        H[:, 6:9] = _I3
        return H

    def _velocity_model(self, v_gps_i: np.ndarray, R_i: np.ndarray):
        """(z, H, N): left-invariant velocity innovation of the antenna, v_ant = v + C exp(phi) a with
        a = omega_ib_b x l: z = C^T (v_gps - v) - a = nu - a_x phi."""
        a = np.cross(self.omega_b, self.lever_b)
        H = np.zeros((3, self._n_states))
        H[:, 0:3] = -lie.hat3(a)
        H[:, 3:6] = _I3
        Ct = self.C.T
        return Ct @ (v_gps_i - self.v) - a, H, Ct @ R_i @ self.C

    def _inject(self, dx: np.ndarray) -> None:
        """Retraction X_hat exp(dxi) (eq. (14)); error reset (eq. (15)) is implicit."""
        if nb.ENABLED:
            self.C, self.v, self.p = _retract_nb(self.C, self.v, self.p, np.ascontiguousarray(dx[0:9], dtype=float))
            return
        X = lie.se23_from(self.C, self.v, self.p) @ lie.se23_exp(dx[0:9])
        self.C, self.v, self.p = lie.se23_parts(X)
        self.C, self.v, self.p = self.C.copy(), self.v.copy(), self.p.copy()

    def _P_att_n(self, C_b_n: np.ndarray) -> np.ndarray:
        return C_b_n @ self.P[0:3, 0:3] @ C_b_n.T

    # ---------------------------------------------------------------- update
    def _gnss_terms(self, fix: GnssFix):
        """(z, H, N) of a fix at the core's current time (after flushing the buffered samples)."""
        self.flush()
        if nb.ENABLED and type(self)._gnss_model is BatchedEciCore._gnss_model \
                and not getattr(self.cfg, "gnss_sigma_floor_m", 0.0) > 0:  # the same products, one compiled call
            a = earth.OMEGA_IE_RAD_S * (self.t_s - self.t0_s)
            z, H, N = np.empty(3), np.zeros((3, self._n_states)), np.empty((3, 3))
            _gnss_terms_nb(math.cos(a), math.sin(a), np.asarray(fix.p_e, float), np.asarray(fix.R_e, float),
                           np.ascontiguousarray(self.C), np.asarray(self.p, float), self.lever_b, z, H, N)
            return z, H, N
        Cei = earth.C_e_i(self.t_s, self.t0_s)
        p_i = Cei @ np.asarray(fix.p_e, float)
        R_i = Cei @ np.asarray(fix.R_e, float) @ Cei.T
        floor2 = getattr(self.cfg, "gnss_sigma_floor_m", 0.0) ** 2
        if floor2 > 0:
            lo = float(np.linalg.eigvalsh(0.5 * (R_i + R_i.T)).min())
            if lo < floor2:
                R_i = R_i + (floor2 - lo) * np.eye(3)
        return self._gnss_model(p_i, R_i)

    def _velocity_terms(self, vel: GnssVelocity):
        """(z, H, N) of a GNSS velocity at the core's current time: the ENU antenna velocity relative to Earth
        turned into the ECI inertial velocity at the estimated antenna position (the earth-rate term
        omega_ie x p_ant uses the estimate: its error is omega_ie |dp| ~ 7e-5 m/s per metre, neglected in H)."""
        self.flush()
        Cei = earth.C_e_i(self.t_s, self.t0_s)
        p_ant_e = Cei.T @ (self.p + self.C @ self.lever_b)
        lat, lon, _ = earth.ecef_to_geodetic(p_ant_e)
        Cne = earth.C_n_e(lat, lon)
        v_i = Cei @ (Cne @ np.asarray(vel.v_n, float) + np.cross(earth.OMEGA_IE_E, p_ant_e))
        M = Cei @ Cne
        return self._velocity_model(v_i, M @ np.asarray(vel.R_n, float) @ M.T)

    def _prediction(self, terms) -> UpdateResult:
        z, H, N = terms
        if nb.ENABLED:  # the same S (as in _joseph_nb) and NIS, one compiled call
            S, nis_v = _prediction_nb(np.ascontiguousarray(self.P, dtype=float), np.ascontiguousarray(H, dtype=float),
                                      np.ascontiguousarray(N, dtype=float), np.ascontiguousarray(z, dtype=float))
            return UpdateResult(False, z, S, float(nis_v), "prediction only")
        S = H @ self.P @ H.T + N
        S = 0.5 * (S + S.T)
        return UpdateResult(False, z, S, nis(S, z), "prediction only")

    def predict_gnss(self, fix: GnssFix) -> UpdateResult:
        """The innovation, its covariance and NIS a fix would have now; changes nothing (an outlier gate)."""
        if not self._init:
            return UpdateResult(False, reason="not initialised")
        reason = _check_fix(fix)
        if reason:
            return UpdateResult(False, reason=reason)
        return self._prediction(self._gnss_terms(fix))

    def predict_gnss_velocity(self, vel: GnssVelocity) -> UpdateResult:
        """The innovation, its covariance and NIS a GNSS velocity would have now; changes nothing."""
        if not self._init:
            return UpdateResult(False, reason="not initialised")
        reason = check_velocity(vel.v_n, vel.R_n)
        if reason:
            return UpdateResult(False, reason=reason)
        return self._prediction(self._velocity_terms(vel))

    def update_gnss_velocity(self, vel: GnssVelocity) -> UpdateResult:
        """Fuse a GNSS velocity (Joseph form, the same fading memory and NIS gate as a fix; a plain Kalman
        correction in every core, PI-LIEKF included: its PI loop and LMI are built on position innovations)."""
        if not self._init:
            return UpdateResult(False, reason="not initialised")
        reason = check_velocity(vel.v_n, vel.R_n)
        if reason:
            self.counters["gnss_vel_rejected"] += 1
            self.last_reject_reason = f"GNSS velocity: {reason}"
            return UpdateResult(False, reason=reason)
        return self._kalman_update(*self._velocity_terms(vel), kind="gnss_vel")

    def update_gnss(self, fix: GnssFix) -> UpdateResult:
        if not self._init:
            return UpdateResult(False, reason="not initialised")
        reason = _check_fix(fix)
        if reason:
            self.counters["gnss_rejected"] += 1
            self.last_reject_reason = f"GNSS: {reason}"
            return UpdateResult(False, reason=reason)
        return self._kalman_update(*self._gnss_terms(fix), kind="gnss")

    def _kalman_update(self, z, H, N, kind: str) -> UpdateResult:
        """One update with (z, H, N); ``kind`` "gnss" (position: the PI-LIEKF correction and its update clock) or
        "gnss_vel" (plain correction L z)."""
        self._P_prior = self.P
        L, P_new, S = joseph_update(self.P, H, N, compiled=True)
        nis_v = nis(S, z)
        fading = self.cfg.fading_nis_threshold
        self.last_fading_factor = 1.0
        if fading > 0 and nis_v > fading:
            # adaptive fading memory: the innovation says P is too small (linearisation error of a large
            # initial attitude error); inflate the prior by NIS/threshold and redo the gain (docs/inmotion_cores.md)
            # never above the initial attitude uncertainty: beyond it the linear update only adds damage
            room = float(np.min(np.diag(self._P0_att) / np.maximum(np.diag(self.P)[0:3], 1e-30)))
            lam = max(1.0, min(nis_v / fading, self.cfg.fading_max_factor, room))
            self.last_fading_factor = lam
            D = np.ones(self._n_states)
            D[0:9] = math.sqrt(lam)  # navigation block, by congruence D P D (stays SPD, keeps correlations)
            self.P = self.P * np.outer(D, D)
            self._P_prior = self.P
            self.counters["fading"] = self.counters.get("fading", 0) + 1
            L, P_new, S = joseph_update(self.P, H, N, compiled=True)
        if self.cfg.gnss_nis_gate > 0 and nis_v > self.cfg.gnss_nis_gate:
            self.counters[f"{kind}_rejected"] += 1
            self.last_reject_reason = (f"{'GNSS' if kind == 'gnss' else 'GNSS velocity'}: NIS {nis_v:.1f} above "
                                       f"gate {self.cfg.gnss_nis_gate}")
            return UpdateResult(False, z, S, nis_v, self.last_reject_reason)
        dx = self._correction(z, L, H, N) if kind == "gnss" else L @ z
        self.P = P_new
        self._inject(dx)
        self.counters[kind] += 1
        if kind == "gnss":
            self._Phi_since_update = np.eye(self._n_states)
            self._t_last_update = self.t_s
        return UpdateResult(True, z, S, nis_v, "")

    def _correction(self, z, L, H, N) -> np.ndarray:
        """Error-state correction dx = L z (eq. (12)); PI-LIEKF overrides (eq. (30))."""
        return L @ z

    # ---------------------------------------------------------------- output
    def estimate(self) -> AlignmentEstimate:
        if not self._init:
            raise RuntimeError("estimate() before initialize()")
        self.flush()
        lat, lon, h, C_b_n, v_n = geodetic_from_state_eci(NavStateEci(self.t_s, self.C, self.v, self.p), self.t0_s)
        P_att = self._P_att_n(C_b_n)
        P_att = 0.5 * (P_att + P_att.T)
        sig_yaw3 = 3.0 * math.degrees(math.sqrt(max(P_att[2, 2], 0.0)))
        if sig_yaw3 < self.cfg.aligned_yaw_3sigma_deg:
            status, reason = AlignmentStatus.ALIGNED, f"3-sigma yaw {sig_yaw3:.2f} deg"
        else:
            status, reason = AlignmentStatus.CONVERGING, f"3-sigma yaw {sig_yaw3:.2f} deg"
        return AlignmentEstimate(
            stamp_s=self.t_s, C_b_n=C_b_n, v_n=np.asarray(v_n), lat_rad=lat, lon_rad=lon, h_m=h, P_att_n=P_att,
            P=self.P.copy(), state_names=self.state_names, bias_gyro_b=self._bias_out()[0],
            bias_acc_b=self._bias_out()[1], status=status, reason=reason,
        )

    def _bias_out(self):
        return None, None


class Liekf(BatchedEciCore):
    """Left-invariant EKF on SE2(3) in ECI, PI-LIEKF Alg. 1 (9 states, IMU biases ignored)."""

    name = "liekf"
    config_class = LiekfConfig
    _n_states = 9
    state_names = ("phi_x", "phi_y", "phi_z", "nu_x", "nu_y", "nu_z", "rho_x", "rho_y", "rho_z")
