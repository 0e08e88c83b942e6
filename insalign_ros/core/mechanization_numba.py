"""Compiled (numba) per-sample loops of the strapdown mechanizations and the error-state covariance.

The same formulas as the numpy code they replace, sample by sample, in one compiled call per batch of buffered IMU
samples (docs/speed.md has the measurements and the decision):

* :func:`local_level_steps` = ``LocalLevelMechanization.step`` (core/mechanization_n.py) over a batch, with the
  interval sums of the static cores (specific force in ENU times dt, dt);
* :func:`eci_steps` = core/mechanization.py's ECI step (numpy form: test/oracles.py ``propagate_eci``) over a
  batch: body increments, attitude, velocity and position with the gravitation at each step's predicted mid-point
  (the tests' vectorised numpy reference solves the same mid-point gravity by a fixed point, residual < 1e-10 m);
* :func:`covariance_steps` = ``P <- Phi_k P Phi_k^T + diag(q_k)`` sample by sample, and the product of the Phi_k.

The kernels are the implementation (one source per equation); test/oracles.py keeps the numpy formulas they replace
and test/test_speed_paths.py compares every core through the session on both (attitude < 1e-9 rad). Without numba,
or with ``INSALIGN_NO_NUMBA=1`` in the environment, the same functions run as plain Python (slow, same numbers).
Kernels are compiled on first use and cached on disk (``cache=True``): next to the source, or in
:func:`user_cache_dir` when the package directory is read-only (:func:`_jit`).
"""

from __future__ import annotations

import math
import os

import numpy as np

from . import earth, mechanization_n
from .lie import _A_SERIES, _B_SERIES, _C1_SERIES, _C2_SERIES, _SERIES_BELOW_RAD

try:  # numba is a pinned dependency; without it the numpy reference paths run
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    HAVE_NUMBA = False

#: compile the kernels (False: run them as plain Python)
COMPILE: bool = HAVE_NUMBA and os.environ.get("INSALIGN_NO_NUMBA", "") not in ("1", "true", "yes")

_GM = earth.GM_M3_S2
_A = earth.A_M
_ZONAL_N = np.array([float(n) for n, _ in earth._ZONAL])
_ZONAL_J = np.array([float(j) for _, j in earth._ZONAL])
#: Taylor coefficients of the four SO(3) functions (core/lie.py), one row each (read as constants by numba)
_SERIES = np.array([_A_SERIES, _B_SERIES, _C1_SERIES, _C2_SERIES])


def user_cache_dir() -> str:
    """Where the kernels are cached when their source directory is not writable (docs/install.md, "First run"):
    ``${XDG_CACHE_HOME:-~/.cache}/insalign_ros/numba`` (``$NUMBA_CACHE_DIR``, when set, wins over both)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "insalign_ros", "numba")


_WRITABLE: dict[str, bool] = {}  # source directory -> its __pycache__ is writable (numba's in-tree cache)


def _in_tree_writable(src_dir: str) -> bool:
    """numba's own test of its in-tree cache: create ``__pycache__`` and a file in it."""
    if src_dir not in _WRITABLE:
        import tempfile

        try:
            path = os.path.join(src_dir, "__pycache__")
            os.makedirs(path, exist_ok=True)
            with tempfile.TemporaryFile(dir=path):
                pass
            _WRITABLE[src_dir] = True
        except OSError:
            _WRITABLE[src_dir] = False
    return _WRITABLE[src_dir]


def _jit(fn):
    """``njit(cache=True)``, the cache next to the source (``__pycache__``) when that is writable, else in
    :func:`user_cache_dir` (a read-only install: colcon ``install/``, a system site-packages); ``$NUMBA_CACHE_DIR``
    wins when set. numba picks the location when it decorates, so only these kernels see the setting."""
    if not COMPILE:
        return fn
    from numba.core import config

    src = os.path.dirname(os.path.abspath(fn.__code__.co_filename))
    user_set = bool(config.CACHE_DIR)
    if not (user_set or _in_tree_writable(src)):
        config.CACHE_DIR = user_cache_dir()
    try:
        return njit(cache=True, fastmath=False, nogil=True)(fn)
    except RuntimeError:  # no writable cache location at all ("cannot cache function"): compile at every start
        return njit(cache=False, fastmath=False, nogil=True)(fn)
    finally:
        if not user_set:
            config.CACHE_DIR = ""


@_jit
def _coeffs(t2):
    """(sin t/t, (1-cos t)/t^2, (t-sin t)/t^3, (t^2/2+cos t-1)/t^4): Taylor below 0.1 rad as core/lie.py."""
    t = math.sqrt(t2)
    if t < _SERIES_BELOW_RAD:
        a = 0.0
        b = 0.0
        c1 = 0.0
        c2 = 0.0
        for k in range(_SERIES.shape[1] - 1, -1, -1):  # Horner, as lie._taylor
            a = a * t2 + _SERIES[0, k]
            b = b * t2 + _SERIES[1, k]
            c1 = c1 * t2 + _SERIES[2, k]
            c2 = c2 * t2 + _SERIES[3, k]
        return a, b, c1, c2
    s, c = math.sin(t), math.cos(t)
    return s / t, (1.0 - c) / t2, (t - s) / (t2 * t), (0.5 * t2 + c - 1.0) / (t2 * t2)


_rodrigues_ab = _jit(mechanization_n.rodrigues_ab)


@_jit
def _rodrigues(x, y, z, out):
    """out = exp([x, y, z]_x) (the coefficients of mechanization_n._rodrigues)."""
    a, b = _rodrigues_ab(x * x + y * y + z * z)
    _so3_from(x, y, z, a, b, 1.0, out)


@_jit
def _so3_from(x, y, z, a, b, d, out):
    """out = d I + a K + b K^2 with K = [x, y, z]_x (K^2 = v v^T - |v|^2 I)."""
    t2 = x * x + y * y + z * z
    out[0, 0] = d + b * (x * x - t2)
    out[1, 1] = d + b * (y * y - t2)
    out[2, 2] = d + b * (z * z - t2)
    out[0, 1] = -a * z + b * x * y
    out[1, 0] = a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[2, 0] = -a * y + b * x * z
    out[1, 2] = -a * x + b * y * z
    out[2, 1] = a * x + b * y * z


@_jit
def _mm3(A, B, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@_jit
def local_level_steps(C, v, W, F, DT, gyro_corr, acc_corr, omega_ie_n, g_n, R_N, R_E, tan_lat, f_sum):
    """``LocalLevelMechanization.step`` for each row of W, F (N, 3) [rad/s, m/s^2] and DT (N,) [s].

    Updates C (C_b_n) and v (v_n) in place, adds sum(C_mid f dt) to f_sum (3,) in place; returns sum(dt)."""
    dC = np.empty((3, 3))
    Ra = np.empty((3, 3))
    Rb = np.empty((3, 3))
    T = np.empty((3, 3))
    Cmid = np.empty((3, 3))
    dt_acc = 0.0
    for k in range(W.shape[0]):
        dt = DT[k]
        wx, wy, wz = W[k, 0] - gyro_corr[0], W[k, 1] - gyro_corr[1], W[k, 2] - gyro_corr[2]
        fx, fy, fz = F[k, 0] - acc_corr[0], F[k, 1] - acc_corr[1], F[k, 2] - acc_corr[2]
        wen0, wen1, wen2 = -v[1] / R_N, v[0] / R_E, v[0] * tan_lat / R_E
        win0, win1, win2 = omega_ie_n[0] + wen0, omega_ie_n[1] + wen1, omega_ie_n[2] + wen2
        _rodrigues(wx * dt, wy * dt, wz * dt, dC)
        # C_mid = exp(-dt/2 w_in) C exp(dt/2 w)
        _rodrigues(-0.5 * dt * win0, -0.5 * dt * win1, -0.5 * dt * win2, Ra)
        _rodrigues(0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz, Rb)
        _mm3(Ra, C, T)
        _mm3(T, Rb, Cmid)
        # C = exp(-dt w_in) C dC
        _rodrigues(-dt * win0, -dt * win1, -dt * win2, Ra)
        _mm3(Ra, C, T)
        _mm3(T, dC, C)
        fn0 = Cmid[0, 0] * fx + Cmid[0, 1] * fy + Cmid[0, 2] * fz
        fn1 = Cmid[1, 0] * fx + Cmid[1, 1] * fy + Cmid[1, 2] * fz
        fn2 = Cmid[2, 0] * fx + Cmid[2, 1] * fy + Cmid[2, 2] * fz
        a0, a1, a2 = 2.0 * omega_ie_n[0] + wen0, 2.0 * omega_ie_n[1] + wen1, 2.0 * omega_ie_n[2] + wen2
        c0 = a1 * v[2] - a2 * v[1]
        c1 = a2 * v[0] - a0 * v[2]
        c2 = a0 * v[1] - a1 * v[0]
        v[0] = v[0] + (fn0 + g_n[0] - c0) * dt
        v[1] = v[1] + (fn1 + g_n[1] - c1) * dt
        v[2] = v[2] + (fn2 + g_n[2] - c2) * dt
        f_sum[0] += fn0 * dt
        f_sum[1] += fn1 * dt
        f_sum[2] += fn2 * dt
        dt_acc += dt
    return dt_acc


@_jit
def _gravitation(x, y, z, zn, zj, out):
    """earth.gravitation_e (WGS84 J2, J4, J6) at (x, y, z) [m] -> out (3,) [m/s^2]."""
    r2 = x * x + y * y + z * z
    r = math.sqrt(r2)
    u = z / r
    # Legendre P_k(u) and P_k'(u) by the recursion, k = 2 .. 6, in scalars (no allocation per call); each zonal
    # term is added when its degree is reached (the zonal list is in increasing degree: the same order of sums)
    p0, p1, d1 = 1.0, u, 1.0
    gx = 0.0
    gy = 0.0
    gz = 0.0
    for k in range(2, 7):
        pk = ((2 * k - 1) * u * p1 - (k - 1) * p0) / k
        dk = k * p1 + u * d1
        p0, p1, d1 = p1, pk, dk
        for i in range(zn.shape[0]):
            if int(zn[i]) == k:
                c = -_GM * zj[i] * (_A / r) ** k / r
                radial = -(k + 1) * pk / r2 - dk * z / (r2 * r)
                gx += c * radial * x
                gy += c * radial * y
                gz += c * (radial * z + dk / r)
    k0 = -_GM / (r2 * r)
    out[0] = k0 * x + gx
    out[1] = k0 * y + gy
    out[2] = k0 * z + gz


@_jit
def _eci_step(k, C, v, p, W, F, DT, zn, zj, dpa, dva, dC, dv_b, dp_b, J, G2, T, g, vk):
    """Step k of :func:`eci_steps`: writes the body increments dC, dv_b, dp_b, advances dpa, dva (position and
    velocity relative to the batch start) and C (C_b_i) in place."""
    dt = DT[k]
    x, y, z = W[k, 0] * dt, W[k, 1] * dt, W[k, 2] * dt
    a, b, c1, c2 = _coeffs(x * x + y * y + z * z)
    _so3_from(x, y, z, a, b, 1.0, dC)
    _so3_from(x, y, z, b, c1, 1.0, J)
    _so3_from(x, y, z, c1, c2, 0.5, G2)
    fx, fy, fz = F[k, 0], F[k, 1], F[k, 2]
    for i in range(3):
        dv_b[i] = (J[i, 0] * fx + J[i, 1] * fy + J[i, 2] * fz) * dt
        dp_b[i] = (G2[i, 0] * fx + G2[i, 1] * fy + G2[i, 2] * fz) * (dt * dt)
    for i in range(3):
        vk[i] = v[i] + dva[i]
    _gravitation((p[0] + dpa[0]) + 0.5 * dt * vk[0], (p[1] + dpa[1]) + 0.5 * dt * vk[1],
                 (p[2] + dpa[2]) + 0.5 * dt * vk[2], zn, zj, g)
    for i in range(3):
        dvi = C[i, 0] * dv_b[0] + C[i, 1] * dv_b[1] + C[i, 2] * dv_b[2]
        dpi = C[i, 0] * dp_b[0] + C[i, 1] * dp_b[1] + C[i, 2] * dp_b[2]
        dpa[i] += vk[i] * dt + dpi + 0.5 * g[i] * dt * dt
        dva[i] += dvi + g[i] * dt
    _mm3(C, dC, T)
    C[:, :] = T


@_jit
def _eci_scratch():
    """Work arrays of :func:`_eci_step`: J, Gamma_2, a 3x3 product, gravity, and the position and velocity increments
    accumulated relative to the batch start (zeros; as the batched numpy path does: adding each step to a 6.4e6 m ECI
    position rounds at its 1e-9 m ulp every step), the step's start velocity."""
    return (np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.zeros(3), np.zeros(3),
            np.empty(3))


@_jit
def eci_steps(C, v, p, W, F, DT, zn, zj, dC_out, dv_out, dp_out, Cprev_out):
    """The ECI step (test/oracles.py ``propagate_eci``) for each row of W, F (N, 3) and DT (N,): updates C (C_b_i),
    v (v_i), p (p_i) in place and writes the body increments exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2 and the
    attitude at each step's start."""
    J, G2, T, g, dpa, dva, vk = _eci_scratch()
    for k in range(W.shape[0]):
        Cprev_out[k] = C
        _eci_step(k, C, v, p, W, F, DT, zn, zj, dpa, dva, dC_out[k], dv_out[k], dp_out[k], J, G2, T, g, vk)
    for i in range(3):
        p[i] = p[i] + dpa[i]
        v[i] = v[i] + dva[i]


@_jit
def _sparse_rows_mm(A, B, hi, d, dt, out):
    """out = A B for the structure of :func:`eci_invariant_steps`: rows i < 9 of A over columns 0 .. hi[i]-1 (and
    -dt in column 9 + i for i < 6 when d = 15), identity rows i >= 9. Each out[i, j] sums its terms in column order
    (as the pattern loop of :func:`covariance_steps`)."""
    for i in range(9):
        for j in range(d):
            out[i, j] = 0.0
        for m in range(hi[i]):
            a = A[i, m]
            for j in range(d):
                out[i, j] += a * B[m, j]
        if d == 15 and i < 6:
            for j in range(d):
                out[i, j] += -dt * B[9 + i, j]
    for i in range(9, d):
        for j in range(d):
            out[i, j] = B[i, j]


@_jit
def _sparse_rows_mm_lower(A, T, hi, d, dt, out):
    """The lower triangle (j <= i) of ``out = A T^T`` for the structure of :func:`_sparse_rows_mm`, reading T^T in
    place: each out[i, j] is the sum of :func:`_sparse_rows_mm` on the transposed copy, in the same order (the same
    numbers, without the copy and the upper triangle that the caller overwrites by symmetry)."""
    for i in range(9):
        for j in range(i + 1):
            out[i, j] = 0.0
        for m in range(hi[i]):
            a = A[i, m]
            for j in range(i + 1):
                out[i, j] += a * T[j, m]
        if d == 15 and i < 6:
            for j in range(i + 1):
                out[i, j] += -dt * T[j, 9 + i]
    for i in range(9, d):
        for j in range(i + 1):
            out[i, j] = T[j, i]


@_jit
def eci_invariant_steps(C, v, p, W, F, DT, zn, zj, P, qrate, want_tot, tot):
    """:func:`eci_steps` fused with the left-invariant error transition and the covariance, sample by sample,
    without forming the (N, d, d) transitions: per step ``Phi = [[R, 0, 0], [a_x R, R, 0], [b_x R, dt R, R]]`` with
    ``R = dC^T``, ``a = -R dv_b``, ``b = -R dp_b`` (filters/liekf.py ``liekf_transition_batch``), for d = 15 the
    imperfect IEKF's bias columns ``-dt I`` (phi <- db_g, nu <- db_a) and identity bias rows
    (filters/iekf.py ``_transitions``), then ``P <- Phi P Phi^T + diag(qrate dt)`` over the structural non-zero
    pattern. Updates C, v, p and P in place; when ``want_tot``, tot <- Phi_N ... Phi_1 tot."""
    d = P.shape[0]
    J, G2, T3, g, dpa, dva, vk = _eci_scratch()
    dC = np.empty((3, 3))
    dv_b = np.empty(3)
    dp_b = np.empty(3)
    A = np.zeros((d, d))
    # structural pattern: row i of A is non-zero in columns 0 .. hi[i]-1, plus -dt in column 9 + i for i < 6 (d = 15)
    hi = np.zeros(9, np.int64)
    for i in range(9):
        hi[i] = 3 * (i // 3 + 1)
    for i in range(9, d):
        A[i, i] = 1.0
    T = np.empty((d, d))
    tot2 = np.empty((d, d))
    for k in range(W.shape[0]):
        dt = DT[k]
        _eci_step(k, C, v, p, W, F, DT, zn, zj, dpa, dva, dC, dv_b, dp_b, J, G2, T3, g, vk)
        a0 = -(dC[0, 0] * dv_b[0] + dC[1, 0] * dv_b[1] + dC[2, 0] * dv_b[2])
        a1 = -(dC[0, 1] * dv_b[0] + dC[1, 1] * dv_b[1] + dC[2, 1] * dv_b[2])
        a2 = -(dC[0, 2] * dv_b[0] + dC[1, 2] * dv_b[1] + dC[2, 2] * dv_b[2])
        b0 = -(dC[0, 0] * dp_b[0] + dC[1, 0] * dp_b[1] + dC[2, 0] * dp_b[2])
        b1 = -(dC[0, 1] * dp_b[0] + dC[1, 1] * dp_b[1] + dC[2, 1] * dp_b[2])
        b2 = -(dC[0, 2] * dp_b[0] + dC[1, 2] * dp_b[1] + dC[2, 2] * dp_b[2])
        for j in range(3):
            r0, r1, r2 = dC[j, 0], dC[j, 1], dC[j, 2]  # column j of R = dC^T
            for blk in range(3):
                A[3 * blk + 0, 3 * blk + j] = r0
                A[3 * blk + 1, 3 * blk + j] = r1
                A[3 * blk + 2, 3 * blk + j] = r2
            A[3, j] = -a2 * r1 + a1 * r2
            A[4, j] = a2 * r0 - a0 * r2
            A[5, j] = -a1 * r0 + a0 * r1
            A[6, j] = -b2 * r1 + b1 * r2
            A[7, j] = b2 * r0 - b0 * r2
            A[8, j] = -b1 * r0 + b0 * r1
            A[6, 3 + j] = dt * r0
            A[7, 3 + j] = dt * r1
            A[8, 3 + j] = dt * r2
        _sparse_rows_mm(A, P, hi, d, dt, T)  # T = A P
        if want_tot:
            _sparse_rows_mm(A, tot, hi, d, dt, tot2)
            tot[:, :] = tot2
        _sparse_rows_mm_lower(A, T, hi, d, dt, P)  # P = A (A P)^T = A P A^T; its lower triangle, mirrored below
        for i in range(d):
            for j in range(i + 1, d):
                P[i, j] = P[j, i]
            P[i, i] += qrate[i] * dt
    for i in range(3):
        p[i] = p[i] + dpa[i]
        v[i] = v[i] + dva[i]


@_jit
def eci_invariant_block(C, v, p, T, W, F, t_prev, b_g, b_a, zn, zj, P, qrate, want_tot, tot):
    """One batch of ``BatchedEciCore._propagate_block`` on the fused path in one call: the intervals from
    ``t_prev`` and the stamps T, the bias-corrected increments ``W - b_g``, ``F - b_a``,
    :func:`eci_invariant_steps`, then the re-orthonormalisation of ``liekf.orthonormalize`` (one polar Newton step
    ``C (3 I - C^T C) / 2``). Updates C, v, p, P (and tot) in place; returns the last corrected rate [rad/s]."""
    n = T.shape[0]
    DT = np.empty(n)
    DT[0] = T[0] - t_prev
    for k in range(1, n):
        DT[k] = T[k] - T[k - 1]
    Wc = np.empty((n, 3))
    Fc = np.empty((n, 3))
    for k in range(n):
        for i in range(3):
            Wc[k, i] = W[k, i] - b_g[i]
            Fc[k, i] = F[k, i] - b_a[i]
    eci_invariant_steps(C, v, p, Wc, Fc, DT, zn, zj, P, qrate, want_tot, tot)
    M = 1.5 * np.eye(3) - 0.5 * (np.ascontiguousarray(C.T) @ C)
    C[:, :] = C @ M
    return Wc[n - 1].copy()


if COMPILE:  # earth.py's frame chain, callable as it is from the kernels below (and plain Python elsewhere)
    from numba.extending import register_jitable

    for _fn in (earth.C_e_i, earth.C_e_n, earth._omega_ie_cross, earth.eci_to_ecef_pv, earth.geodetic_closed_form):
        register_jitable(_fn)


@_jit
def eci_navigation(t_s, t0_s, C_b_i, v_i, p_i, P_att, inertial, C_b_n, v_n, P_att_n):
    """An ECI state as navigation outputs (core/mechanization.py ``navigation_from_state_eci``: one compiled call
    per estimate; earth.py's eci_to_ecef_pv, geodetic_closed_form and C_e_n composed): returns (lat, lon, h)
    [rad, rad, m] (NaN within 1 km of the Earth's centre: a lost filter, which the outputs refuse) and fills C_b_n,
    v_n (ENU) and ``P_att_n = R P_att R^T`` (symmetrised), the attitude error covariance in ENU of an error kept
    in the body frame (``inertial`` False: R = C_b_n) or in ECI (True: R = C_i_n)."""
    C_ie = np.ascontiguousarray(earth.C_e_i(t_s, t0_s).T)
    p_e, v_e = earth.eci_to_ecef_pv(C_ie, p_i, v_i)
    lat, lon, h = earth.geodetic_closed_form(p_e[0], p_e[1], p_e[2])
    C_en = earth.C_e_n(lat, lon)
    C_in = C_en @ C_ie
    C_b_n[:, :] = C_in @ C_b_i
    v_n[:] = C_en @ v_e
    R = C_in if inertial else np.ascontiguousarray(C_b_n)
    X = R @ (P_att @ np.ascontiguousarray(R.T))
    P_att_n[:, :] = 0.5 * (X + X.T)
    return lat, lon, h


@_jit
def eci_invariant_snapshots(C, v, p, T, W, F, t_prev, b_g, b_a, zn, zj, P, qrate, ends, snap, t0_s, inertial,
                            SP, SC, SV, SLLH, SPA):
    """:func:`eci_invariant_block` over consecutive blocks of the rows (block ``b`` ends before row ``ends[b]``),
    as a run of ``BatchedEciCore`` flushes would call it (no transition product), and after each block ``b`` with
    ``snap[b] = s >= 0`` the estimate of that state in slot ``s``: the covariance (``SP[s]``) and
    :func:`eci_navigation` (C_b_n ``SC[s]``, v_n ``SV[s]``, lat/lon/h ``SLLH[s]``, P_att_n ``SPA[s]``). Updates C, v,
    p, P in place; returns the last block's corrected rate [rad/s]."""
    nop = np.eye(1)
    w_last = np.zeros(3)
    i0 = 0
    for b in range(ends.shape[0]):
        i1 = ends[b]
        w_last = eci_invariant_block(C, v, p, T[i0:i1], W[i0:i1], F[i0:i1], t_prev, b_g, b_a, zn, zj, P, qrate,
                                     False, nop)
        t_prev = T[i1 - 1]
        s = snap[b]
        if s >= 0:
            SP[s, :, :] = P
            SLLH[s, 0], SLLH[s, 1], SLLH[s, 2] = eci_navigation(
                t_prev, t0_s, C, v, p, np.ascontiguousarray(P[0:3, 0:3]), inertial, SC[s], SV[s], SPA[s])
        i0 = i1
    return w_last


@_jit
def covariance_steps(P, Phi, q):
    """P <- Phi_k P Phi_k^T + diag(q_k) for k = 0..N-1 (Phi (N, d, d), q (N, d)); returns (P, Phi_N ... Phi_1).

    The transitions here are block-sparse with one pattern per core: the products run over the union of the
    non-zero entries of the batch only (exact: the skipped terms are zeros)."""
    n, d = Phi.shape[0], Phi.shape[1]
    nzc = np.zeros((d, d), np.int64)  # nzc[i, :cnt[i]] = columns m with some Phi_k[i, m] != 0
    cnt = np.zeros(d, np.int64)
    for i in range(d):
        for m in range(d):
            for k in range(n):
                if Phi[k, i, m] != 0.0:
                    nzc[i, cnt[i]] = m
                    cnt[i] += 1
                    break
    T = np.empty((d, d))
    Pn = P.copy()
    tot = np.eye(d)
    tot2 = np.empty((d, d))
    for k in range(n):
        A = Phi[k]
        for i in range(d):  # T = A P, tot2 = A tot
            for j in range(d):
                s = 0.0
                s2 = 0.0
                for r in range(cnt[i]):
                    m = nzc[i, r]
                    s += A[i, m] * Pn[m, j]
                    s2 += A[i, m] * tot[m, j]
                T[i, j] = s
                tot2[i, j] = s2
        for i in range(d):  # P = T A^T + Q (symmetric: the upper triangle, mirrored)
            for j in range(i, d):
                s = 0.0
                for r in range(cnt[j]):
                    m = nzc[j, r]
                    s += T[i, m] * A[j, m]
                Pn[i, j] = s
                Pn[j, i] = s
            Pn[i, i] += q[k, i]
        tot[:, :] = tot2
    return Pn, tot
