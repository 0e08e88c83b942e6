"""Compiled kernels of the static zero-velocity cores (PKF paper eqs. (31)-(35), PKF gain, OC-EKF, feedback): the
implementation of filters/static_model.py's steps, one compiled call per zero-velocity update (docs/speed.md).
test/oracles.py keeps the numpy formulas the tests compare them with."""

from __future__ import annotations

import math

import numpy as np

from ..core import earth
from ..core import mechanization_numba as nb


@nb._jit
def _f_model_nb(x, f_np, lat, r_m, m, out):
    """:func:`f_model` compiled (the same expressions, written out); writes out (5,)."""
    dvN, dvE, pN, pE, pD = x[0], x[1], x[2], x[3], x[4]
    c, s = math.cos(pD), math.sin(pD)
    E = ((c, -s, pE * c + pN * s), (s, c, pE * s - pN * c), (-pE, pN, 1.0))
    w0, w2 = _OMEGA_IE * math.cos(lat), -_OMEGA_IE * math.sin(lat)
    Ef0 = E[0][0] * f_np[0] + E[0][1] * f_np[1] + E[0][2] * f_np[2]
    Ef1 = E[1][0] * f_np[0] + E[1][1] * f_np[1] + E[1][2] * f_np[2]
    acc0 = f_np[0] - Ef0 - 2.0 * (-w2 * dvE)
    acc1 = f_np[1] - Ef1 - 2.0 * (w2 * dvN)
    a0 = w0 + dvE / r_m - m[2]
    a1 = 0.0 - dvN / r_m - m[3]
    a2 = w2 - dvE * math.tan(lat) / r_m - m[4]
    z0 = E[0][0] * a0 + E[0][1] * a1 + E[0][2] * a2 - w0
    z1 = E[1][0] * a0 + E[1][1] * a1 + E[1][2] * a2
    z2 = E[2][0] * a0 + E[2][1] * a1 + E[2][2] * a2 - w2
    out[0] = acc0 + m[0]
    out[1] = acc1 + m[1]
    out[2] = c * z0 + s * z1
    out[3] = -s * z0 + c * z1
    out[4] = z2


@nb._jit
def _jacobian_nb(x, f_np, lat, r_m, m, F):
    """Central differences of :func:`_f_model_nb` in x (the steps of :func:`jacobian`); writes F (5, 5)."""
    xp = np.empty(5)
    xm = np.empty(5)
    fp = np.empty(5)
    fm = np.empty(5)
    for j in range(5):
        h = 1e-6 if j < 2 else 1e-7
        for i in range(5):
            xp[i] = x[i]
            xm[i] = x[i]
        xp[j] += h
        xm[j] -= h
        _f_model_nb(xp, f_np, lat, r_m, m, fp)
        _f_model_nb(xm, f_np, lat, r_m, m, fm)
        for i in range(5):
            F[i, j] = (fp[i] - fm[i]) / (2 * h)


_OMEGA_IE = earth.OMEGA_IE_RAD_S
_M0 = np.zeros(5)
_NE_PAIRS = np.array([0, 2, 5, 7])


@nb._jit
def _zupt_predict_nb(x5, f_np, lat, r_m, m, dt, x5_out, F5):
    """The RK2 step of eq. (34) over dt (x5_out) and the Jacobian F5 at x5 (:func:`jacobian`), compiled."""
    k1 = np.empty(5)
    k2 = np.empty(5)
    xe = np.empty(5)
    _f_model_nb(x5, f_np, lat, r_m, m, k1)
    for i in range(5):
        xe[i] = x5[i] + dt * k1[i]
    _f_model_nb(xe, f_np, lat, r_m, m, k2)
    _jacobian_nb(x5, f_np, lat, r_m, _M0, F5)
    for i in range(5):
        x5_out[i] = x5[i] + 0.5 * dt * (k1[i] + k2[i])


@nb._jit
def _corrected_attitude_nb(pN, pE, pD, C_b_n):
    """``mech.correct_attitude(E)`` with eq. (23)'s rotation E: the nearest rotation (SVD) to
    ``T Rz(pD) exp([pN, pE, 0]) T C_b_n`` (:func:`misaligned_attitude_nb`); returns the new C_b_n."""
    u, _, vt = np.linalg.svd(misaligned_attitude_nb(pN, pE, pD, C_b_n))
    return u @ vt


@nb._jit
def misaligned_attitude_nb(pN, pE, pD, C_b_n):
    """Eq. (23)'s orthonormal misalignment rotation in ENU applied to C_b_n, ``T Rz(pD) exp([pN, pE, 0]) T C_b_n``:
    the static cores' attitude with the misalignment still held in the state applied (test/oracles.py has the numpy
    formula, ``misalignment_rotation_enu``)."""
    X = np.empty((3, 3))
    a, b, _, _ = nb._coeffs(pN * pN + pE * pE)  # lie.so3_exp's coefficients
    nb._so3_from(pN, pE, 0.0, a, b, 1.0, X)
    c, s = math.cos(pD), math.sin(pD)
    E = np.empty((3, 3))  # T Rz(pD) X T with T the NED/ENU swap: rows/columns 0, 1 exchanged, row/column 2 negated
    Rx = np.empty((3, 3))
    for j in range(3):
        Rx[0, j] = c * X[0, j] - s * X[1, j]
        Rx[1, j] = s * X[0, j] + c * X[1, j]
        Rx[2, j] = X[2, j]
    sg = np.array([1.0, 1.0, -1.0])
    idx = np.array([1, 0, 2])
    for i in range(3):
        for j in range(3):
            E[i, j] = sg[i] * sg[j] * Rx[idx[i], idx[j]]
    return E @ C_b_n


@nb._jit
def model_error_jacobian_nb(x5, f_np, lat, r_m, G):
    """df/dm' of eq. (34) at x5 by central differences with steps 1e-6 (the 10-state EKF's G), compiled."""
    mp = np.zeros(5)
    mm = np.zeros(5)
    fp = np.empty(5)
    fm = np.empty(5)
    for j in range(5):
        mp[j] = 1e-6
        mm[j] = -1e-6
        _f_model_nb(x5, f_np, lat, r_m, mp, fp)
        _f_model_nb(x5, f_np, lat, r_m, mm, fm)
        for i in range(5):
            G[i, j] = (fp[i] - fm[i]) / 2e-6
        mp[j] = 0.0
        mm[j] = 0.0


@nb._jit
def _expm_taylor_nb(A, order, out):
    """:func:`expm_taylor` compiled (the same sum, term = term A / k, in the same order)."""
    n = A.shape[0]
    term = np.eye(n)
    nxt = np.empty((n, n))
    out[:, :] = np.eye(n)
    for k in range(1, order + 1):
        for i in range(n):
            for j in range(n):
                s = 0.0
                for r in range(n):
                    s += term[i, r] * A[r, j]
                nxt[i, j] = s / k
        for i in range(n):
            for j in range(n):
                term[i, j] = nxt[i, j]
                out[i, j] = out[i, j] + nxt[i, j]


@nb._jit
def _zupt_cov_update_nb(x, P, F, dt, Q, N_k, N_next, use_oc, z, r2, Phi_raw, innov, S):
    """Covariance prediction and the eq. (32) update of the zero-velocity step of :class:`StaticZuptCore`, compiled:
    Phi = exp(F dt) (Taylor, written to Phi_raw), the OC-EKF correction when ``use_oc``, P = Phi P Phi^T + Q, then
    H = [I2 0], R = r2 I2 in Joseph form; updates x, P in place, writes innov (2,), S (2, 2); returns the NIS."""
    n = P.shape[0]
    Fd = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            Fd[i, j] = F[i, j] * dt
    _expm_taylor_nb(Fd, 8, Phi_raw)
    Phi = Phi_raw.copy()
    if use_oc:
        nn = 0.0
        for i in range(n):
            nn += N_k[i] * N_k[i]
        for i in range(n):
            d = -N_next[i]
            for r in range(n):
                d += Phi_raw[i, r] * N_k[r]
            for j in range(n):
                Phi[i, j] = Phi_raw[i, j] - d * N_k[j] / nn
    T = Phi @ P
    Pp = T @ Phi.T + Q
    # update: S = P[0:2, 0:2] + R, K = P[:, 0:2] S^-1
    S[0, 0] = Pp[0, 0] + r2
    S[0, 1] = Pp[0, 1]
    S[1, 0] = Pp[1, 0]
    S[1, 1] = Pp[1, 1] + r2
    Si = np.linalg.inv(S)
    K = np.empty((n, 2))
    for i in range(n):
        K[i, 0] = Pp[i, 0] * Si[0, 0] + Pp[i, 1] * Si[1, 0]
        K[i, 1] = Pp[i, 0] * Si[0, 1] + Pp[i, 1] * Si[1, 1]
    innov[0] = z[0] - x[0]
    innov[1] = z[1] - x[1]
    for i in range(n):
        x[i] = x[i] + K[i, 0] * innov[0] + K[i, 1] * innov[1]
    IKH = np.eye(n)
    for i in range(n):
        IKH[i, 0] -= K[i, 0]
        IKH[i, 1] -= K[i, 1]
    Pn = IKH @ Pp @ IKH.T
    for i in range(n):
        for j in range(n):
            Pn[i, j] += r2 * (K[i, 0] * K[j, 0] + K[i, 1] * K[j, 1])
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.5 * (Pn[i, j] + Pn[j, i])
    sol = np.linalg.solve(S, innov)
    return innov[0] * sol[0] + innov[1] * sol[1]


@nb._jit
def _pkf_gain_rows_nb(F_k, p, re, qm, K5):
    """The first n rows of :func:`pkf.pkf_gain` (the only ones eq. (17) reads), compiled, with ``H = [I2 0]``,
    ``R_e = re I`` and ``Q_m = diag(qm)`` tiled over the horizon (the PKF's own weights); writes K5 (n, n).

    By the push-through identity ``(D^T R D + Q)^-1 D^T R = Q^-1 D^T (R^-1 + D Q^-1 D^T)^-1`` the 5p x 5p solve of
    eq. (16) becomes one of 2p x 2p: ``K = -Q^-1 D^T M^-1 C`` with ``M = I / re + D Q^-1 D^T`` (symmetric positive
    definite: a Cholesky factor). The same gain up to rounding (docs/speed.md, fifth pass); ~35 -> ~3 us."""
    n = F_k.shape[0]
    q = 2
    # HP[k] = H F^k: the first two rows of the powers, k = 0..p
    HP = np.zeros((p + 1, q, n))
    HP[0, 0, 0] = 1.0
    HP[0, 1, 1] = 1.0
    for k in range(1, p + 1):
        for a in range(q):
            for c in range(n):
                s = 0.0
                for r in range(n):
                    s += HP[k - 1, a, r] * F_k[r, c]
                HP[k, a, c] = s
    # M[(i,a),(l,b)] = delta / re + sum_{j <= min(i,l)} G(i-j, l-j)[a,b], G(u,v) = HP[u] Q^-1 HP[v]^T: for i >= l
    # the block (i, l) is G(i, l) plus the block (i-1, l-1)
    HQ = np.empty((p + 1, q, n))
    for k in range(p + 1):
        for b in range(q):
            for c in range(n):
                HQ[k, b, c] = HP[k, b, c] / qm[c]
    m = q * p
    M = np.zeros((m, m))
    for i in range(p):
        for l in range(i + 1):
            for a in range(q):
                for b in range(q):
                    s = 0.0
                    for c in range(n):
                        s += HP[i, a, c] * HQ[l, b, c]
                    if l > 0:
                        s += M[q * (i - 1) + a, q * (l - 1) + b]
                    M[q * i + a, q * l + b] = s
                    M[q * l + b, q * i + a] = s
    for i in range(m):
        M[i, i] += 1.0 / re
    # Y = M^-1 C, C rows (i, a) = HP[i + 1][a]; Cholesky M = L L^T
    L = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            s = M[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:  # not positive definite in floating point: the general solve
                    Y = np.linalg.solve(M, np.ascontiguousarray(HP[1:].reshape(m, n)))
                    _pkf_rows_from(HP, Y, qm, K5)
                    return
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    Y = np.empty((m, n))
    for c in range(n):
        for i in range(m):
            s = HP[i // q + 1, i % q, c]
            for k in range(i):
                s -= L[i, k] * Y[k, c]
            Y[i, c] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = Y[i, c]
            for k in range(i + 1, m):
                s -= L[k, i] * Y[k, c]
            Y[i, c] = s / L[i, i]
    _pkf_rows_from(HP, Y, qm, K5)


@nb._jit
def _pkf_rows_from(HP, Y, qm, K5):
    """K5 = -Q^-1 (D^T)[:n] Y: block column 0 of D is H F^i, i = 0..p-1."""
    p = HP.shape[0] - 1
    q, n = HP.shape[1], HP.shape[2]
    for c in range(n):
        for col in range(n):
            s = 0.0
            for i in range(p):
                for a in range(q):
                    s += HP[i, a, c] * Y[q * i + a, col]
            K5[c, col] = -s / qm[c]


@nb._jit
def _zupt_step_nb(x, P, f_np, lat, r_m, m, dt, with_G, qrate, oc_w_h, N_k, r2, pkf_p, re, qm, m_rate, C, v,
                  acc_corr, gyro_corr, az_thr, innov, S, N_next, Phi_raw):
    """One whole compiled zero-velocity step of the zero-velocity step of :class:`StaticZuptCore` after the interval's
    flush: the eq. (34) prediction (:func:`_zupt_predict_nb`; with ``with_G`` the 10-state EKF's model-error columns
    :func:`model_error_jacobian_nb`), the OC-EKF nullspace at the predicted azimuth when ``oc_w_h > 0`` (the
    10-state EKF's ``_nullspace``: ``[0,0,0,0,1,0,0,w_h sin, w_h cos,0]``, written to N_next), the covariance
    prediction with ``Q = diag(qrate) dt`` and the eq. (32) update (:func:`_zupt_cov_update_nb`, z = the mechanised
    velocity in NED), with ``pkf_p > 0`` the PKF's model-error step (eq. (16)-(17), :func:`_pkf_gain_rows_nb`,
    ``m_rate`` and the sensor corrections), then the feedback of :meth:`StaticZuptCore._feedback` (velocity, the
    attitude, the azimuth reset Jacobian on P and N_next when ``sqrt(P[4,4]) < az_thr``) and the 10-state EKF's
    bias feedback. x, P, m_rate, C, v, acc_corr, gyro_corr are updated in place; returns the NIS."""
    n = x.shape[0]
    x_start = x.copy()
    x5 = x[:5].copy()
    x5n = np.empty(5)
    F5 = np.empty((5, 5))
    _zupt_predict_nb(x5, f_np, lat, r_m, m, dt, x5n, F5)
    F = np.zeros((n, n))
    F[:5, :5] = F5
    if with_G:
        G = np.zeros((5, 5))
        model_error_jacobian_nb(x5, f_np, lat, r_m, G)
        F[:5, 5:10] = G
    x[:5] = x5n
    use_oc = oc_w_h > 0.0
    if use_oc:
        N_next[:] = 0.0
        N_next[4] = 1.0
        N_next[7], N_next[8] = oc_w_h * math.sin(x[4]), oc_w_h * math.cos(x[4])
    Q = np.zeros((n, n))
    for i in range(n):
        Q[i, i] = qrate[i] * dt
    z = np.array([v[1], v[0]])  # ned_from_enu(v)[0:2]
    nis = _zupt_cov_update_nb(x, P, F, dt, Q, N_k, N_next, use_oc, z, r2, Phi_raw, innov, S)
    if pkf_p > 0:  # Pkf._after_update: dm = K[:5] dx, m += dm / dt, applied to the sensor outputs in body axes
        K5 = np.empty((5, 5))
        _pkf_gain_rows_nb(Phi_raw, pkf_p, re, qm, K5)
        for c in range(5):
            s = 0.0
            for r in range(5):
                s += K5[c, r] * (x[r] - x_start[r])
            m_rate[c] = m_rate[c] + s / dt
        _body_from_ned(C, m_rate[1], m_rate[0], -0.0, -1.0, acc_corr, False)
        _body_from_ned(C, m_rate[3], m_rate[2], -m_rate[4], 1.0, gyro_corr, False)
    # StaticZuptCore._feedback
    v[0] = v[0] - x[1]
    v[1] = v[1] - x[0]
    v[2] = 0.0
    if math.sqrt(max(P[4, 4], 0.0)) < az_thr:
        C[:, :] = _corrected_attitude_nb(x[2], x[3], x[4], C)
        c, s = math.cos(x[4]), math.sin(x[4])
        J = np.eye(n)
        for k in range(2 + (n - 5) // 2):  # the (N, E) pairs: velocity, level (and the 10-state EKF's biases)
            i = _NE_PAIRS[k]
            J[i, i], J[i, i + 1], J[i + 1, i], J[i + 1, i + 1] = c, -s, s, c
        Pn = J @ P @ np.ascontiguousarray(J.T)
        P[:, :] = Pn
        if use_oc:
            N_next[:] = J @ N_next
        x[4] = 0.0
    else:
        C[:, :] = _corrected_attitude_nb(x[2], x[3], 0.0, C)
    x[0:4] = 0.0
    if n > 5:  # Ekf10._feedback_bias
        _body_from_ned(C, x[6], x[5], -0.0, 1.0, acc_corr, True)
        _body_from_ned(C, x[8], x[7], -x[9], 1.0, gyro_corr, True)
        x[5:] = 0.0
    return nis


@nb._jit
def _body_from_ned(C, a, b, c, sign, out, add):
    """out (+)= sign C^T [a, b, c] (``body_from_ned`` of a NED vector whose ENU form is [a, b, c])."""
    for i in range(3):
        y = sign * (C[0, i] * a + C[1, i] * b + C[2, i] * c)
        out[i] = out[i] + y if add else y


@nb._jit
def static_run_nb(DT, W, F, ev_row, ev_upd, ev_est, mech, lp, x, P, zargs, m, qrate, N_k, R2, qm, m_rate,
                  INNOV, SS, NIS, SX, SP, SC, SV, SACC, SGYRO):
    """A run of :class:`StaticZuptCore` with its zero-velocity updates and estimates in one call: for each event
    (rows ``ev_row``, increasing; at a row the update ``ev_upd`` before the estimate ``ev_est``) the flush of the rows
    since the last one (``mechanization_numba.local_level_steps``), then the update of ``_fuse`` (the interval's mean
    specific force in NED, its low-pass, :func:`_zupt_step_nb`) and the estimate's state (x, P, C_b_n, v_n, the
    corrections) into the snapshot arrays. ``mech`` = (C, v, gyro_corr, acc_corr, omega_ie_n, g_n, f_sum), ``lp`` =
    (f_lp, [dt_acc, has_lp, tau]), ``zargs`` = [lat, r_m, with_G, oc_w_h, pkf_p, re, az_thr] as ``_zupt_compiled``
    passes them. Updates everything in place; returns the first row not flushed."""
    C, v, gyro_corr, acc_corr, omega_ie_n, g_n, f_sum, geo = mech
    f_lp, st = lp
    n = x.shape[0]
    N_next = np.zeros(n)
    Phi_raw = np.empty((n, n))
    f_np = np.empty(3)
    k0 = iu = ie = 0
    for e in range(ev_row.shape[0]):
        k = ev_row[e]
        if k >= k0:
            st[0] += nb.local_level_steps(C, v, W[k0:k + 1], F[k0:k + 1], DT[k0:k + 1], gyro_corr, acc_corr,
                                          omega_ie_n, g_n, geo[0], geo[1], geo[2], f_sum)
            k0 = k + 1
        if ev_upd[e]:
            dt = st[0]
            f_np[0], f_np[1], f_np[2] = f_sum[1] / dt, f_sum[0] / dt, -(f_sum[2] / dt)  # ned_from_enu(f_sum / dt)
            f_sum[:] = 0.0
            st[0] = 0.0
            if st[1] == 0.0 or st[2] <= 0:
                f_lp[:] = f_np
                st[1] = 1.0
            else:
                a = min(1.0, dt / st[2])
                for i in range(3):
                    f_lp[i] = f_lp[i] + a * (f_np[i] - f_lp[i])
            NIS[iu] = _zupt_step_nb(x, P, f_lp.copy(), zargs[0], zargs[1], m, dt, zargs[2] > 0, qrate, zargs[3], N_k,
                                    R2[iu], int(zargs[4]), zargs[5], qm, m_rate, C, v, acc_corr, gyro_corr, zargs[6],
                                    INNOV[iu], SS[iu], N_next, Phi_raw)
            if zargs[3] > 0:
                N_k[:] = N_next
            iu += 1
        if ev_est[e]:
            SX[ie] = x
            SP[ie] = P
            SC[ie] = C
            SV[ie] = v
            SACC[ie] = acc_corr
            SGYRO[ie] = gyro_corr
            ie += 1
    return k0
