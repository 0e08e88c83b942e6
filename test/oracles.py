"""Reference oracles: the numpy formulas of the package's compiled kernels, kept here (not in the package) so that
the tests can compare the kernels with them (docs/architecture.md, "One source per equation").

Each function is the plain numpy form of one kernel; :func:`use_reference_paths` patches the package so that a
whole alignment runs on these formulas (the per-sample mechanizations, numpy batches, numpy updates), which is how
test/test_speed_paths.py checks every core end to end against the compiled path.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth, lie
from insalign_ros.core.lie import _A_SERIES, _B_SERIES, _C1_SERIES, _C2_SERIES, _coeff_batch
from insalign_ros.core.mechanization import NavStateEci, navigation_from_state_eci
from insalign_ros.filters import (
    backtrack, checks, earth_iekf, ekf10, liekf, measurements, pi_liekf, pkf, static_model, update,
)
from insalign_ros.filters.eci_batch import covariance_batch, prefix_products


# ------------------------------------------------------------------- ECI mechanization (core/mechanization.py)
def step_increments(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: float):
    """Body-frame increments of one step: (exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2)."""
    phi = omega_ib_b * dt_s
    return (
        lie.so3_exp(phi),
        lie.so3_left_jacobian(phi) @ f_ib_b * dt_s,
        lie.so3_gamma2(phi) @ f_ib_b * (dt_s * dt_s),
    )


def gravity_mid_i(p_i: np.ndarray, v_i: np.ndarray, dt_s: float) -> np.ndarray:
    """ECI gravitation [m/s^2] at the predicted midpoint of a step (core/mechanization.py's docstring)."""
    return earth.gravitation_e(p_i + 0.5 * dt_s * v_i)


def propagate_eci(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s):
    """One forward step of the ECI mechanization; returns (C_b_i, v_i, p_i) at the end of the step."""
    dC, dv_b, dp_b = step_increments(omega_ib_b, f_ib_b, dt_s)
    g = gravity_mid_i(p_i, v_i, dt_s)
    v_new = v_i + C_b_i @ dv_b + g * dt_s
    p_new = p_i + v_i * dt_s + C_b_i @ dp_b + 0.5 * dt_s * dt_s * g
    return C_b_i @ dC, v_new, p_new


def propagate_eci_inverse(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s, iterations: int = 3):
    """Inverse step: from the state at the end of a step and its sample, the state at its start (the implicit
    gravity term by a short fixed-point iteration)."""
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


def geodetic_from_state_eci(state: NavStateEci, t0_s: float):
    """(lat_rad, lon_rad, h_m, C_b_n, v_n) of an ECI state."""
    return navigation_from_state_eci(state, t0_s, np.zeros((3, 3)), False)[:5]


# ------------------------------------------------------------------- the same over a batch, vectorised numpy
def so3_exp_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors -> (N, 3, 3) rotation matrices (same series split as lie.so3_exp)."""
    theta = np.linalg.norm(phi, axis=-1)
    a = _coeff_batch(theta, _A_SERIES, lambda t: np.sin(t) / t)
    b = _coeff_batch(theta, _B_SERIES, lambda t: (1.0 - np.cos(t)) / t**2)
    K = lie.hat3_batch(phi)
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def so3_left_jacobian_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) SO(3) left Jacobians (same series/closed-form split as lie.so3_left_jacobian)."""
    theta = np.linalg.norm(phi, axis=-1)
    b = _coeff_batch(theta, _B_SERIES, lambda t: (1.0 - np.cos(t)) / t**2)
    c = _coeff_batch(theta, _C1_SERIES, lambda t: (t - np.sin(t)) / t**3)
    K = lie.hat3_batch(phi)
    return np.eye(3) + b[:, None, None] * K + c[:, None, None] * (K @ K)


def so3_gamma2_batch(phi: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) Gamma_2 (lie.so3_gamma2) for a batch."""
    theta = np.linalg.norm(phi, axis=-1)
    c1 = _coeff_batch(theta, _C1_SERIES, lambda t: (t - np.sin(t)) / t**3)
    c2 = _coeff_batch(theta, _C2_SERIES, lambda t: (0.5 * t * t + np.cos(t) - 1.0) / t**4)
    K = lie.hat3_batch(phi)
    return 0.5 * np.eye(3) + c1[:, None, None] * K + c2[:, None, None] * (K @ K)


def step_increments_batch(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: np.ndarray):
    """:func:`step_increments` per sample: (exp(phi), J_l(phi) f dt, Gamma_2(phi) f dt^2)."""
    phi = omega_ib_b * dt_s[:, None]
    dC = so3_exp_batch(phi)
    dv_b = np.einsum("nij,nj->ni", so3_left_jacobian_batch(phi), f_ib_b) * dt_s[:, None]
    dp_b = np.einsum("nij,nj->ni", so3_gamma2_batch(phi), f_ib_b) * (dt_s * dt_s)[:, None]
    return dC, dv_b, dp_b


def propagate_eci_batch(C_b_i, v_i, p_i, dt_s, dC, dv_b, dp_b, gravity_passes: int = 2):
    """:func:`propagate_eci` over a batch, vectorised: attitude by prefix products, velocity and position by
    cumulative sums, the mid-point gravity by a fixed point (``gravity_passes`` batched re-evaluations; residual
    below 1e-10 m over 100 samples). Returns (C_prev (N,3,3) attitude at each step's start, C_end, v_end, p_end)."""
    n = dt_s.shape[0]
    C_all = C_b_i @ prefix_products(dC)  # attitude at the end of each step
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


def eci_steps(C_b_i, v_i, p_i, omega_ib_b, f_ib_b, dt_s):
    """filters/eci_batch.eci_steps in numpy batches."""
    dC, dv_b, dp_b = step_increments_batch(np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float), dt_s)
    C_prev, C, v, p = propagate_eci_batch(np.asarray(C_b_i, float), np.asarray(v_i, float), np.asarray(p_i, float),
                                          dt_s, dC, dv_b, dp_b)
    return dC, dv_b, dp_b, C_prev, C, v, p


# ------------------------------------------------------------------- Earth-frame mechanization (mechanization_e)
OMEGA_IE_E = earth.OMEGA_IE_E


def C_i_e_step(dt_s: float) -> np.ndarray:
    """Rotation of the ECEF frame over dt [s] seen from the ECI frame frozen at the step start: exp(-omega dt)."""
    return lie.so3_exp(-OMEGA_IE_E * dt_s)


def propagate_e(C_b_e, vbar_e, p_e, omega_ib_b, f_ib_b, dt_s):
    """One forward step of eqs. (21), (22), (26): returns (C_b_e, vbar_e, p_e) at the end of the step."""
    C, v, p = propagate_eci(C_b_e, vbar_e, p_e, omega_ib_b, f_ib_b, dt_s)
    R = C_i_e_step(dt_s)
    return R @ C, R @ v, R @ p


def propagate_e_inverse(C_b_e, vbar_e, p_e, omega_ib_b, f_ib_b, dt_s):
    """Inverse step (backward in time, paper eqs. (6)-(10) in the Earth frame): the state at the step start
    from the state at its end and the same sample."""
    Rt = C_i_e_step(dt_s).T
    return propagate_eci_inverse(Rt @ C_b_e, Rt @ vbar_e, Rt @ p_e, omega_ib_b, f_ib_b, dt_s)


def vector_field_e(X: np.ndarray, omega_ib_b: np.ndarray, f_ib_b: np.ndarray, gbar_e: np.ndarray) -> np.ndarray:
    """dX/dt of eq. (33) as a 5x5 matrix (top three rows; bottom rows zero) with a frozen gravitation gbar_e."""
    C, v, p = X[0:3, 0:3], X[0:3, 3], X[0:3, 4]
    W = lie.hat3(OMEGA_IE_E)
    out = np.zeros((5, 5))
    out[0:3, 0:3] = C @ lie.hat3(omega_ib_b) - W @ C
    out[0:3, 3] = C @ f_ib_b - W @ v + gbar_e
    out[0:3, 4] = v - W @ p
    return out


# ------------------------------------------------------------------------------------------- Kalman update
def joseph_update(P, H, N):
    """Gain and Joseph-form covariance (PI-LIEKF eqs. (11), (13)): (L, P_new, S)."""
    S = H @ P @ H.T + N
    S = 0.5 * (S + S.T)
    L = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S symmetric)
    IKH = np.eye(P.shape[0]) - L @ H
    P_new = IKH @ P @ IKH.T + L @ N @ L.T
    return L, 0.5 * (P_new + P_new.T), S


def nis(S, z) -> float:
    return float(z @ np.linalg.solve(S, z))


def prediction(P, H, N, z):
    S = H @ P @ H.T + N
    S = 0.5 * (S + S.T)
    return S, nis(S, z)


def spd3(R) -> bool:
    try:
        np.linalg.cholesky(0.5 * (R + R.T))
    except np.linalg.LinAlgError:
        return False
    return True


# ------------------------------------------------------------------------------------------- input checks
def check_fix(fix) -> str:
    p = np.asarray(fix.p_e, float)
    R = np.asarray(fix.R_e, float)
    if p.shape != (3,) or R.shape != (3, 3):
        return f"bad shapes p_e {p.shape}, R_e {R.shape}"
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
        return "non-finite position or covariance"
    if not 6.0e6 < np.linalg.norm(p) < 7.0e6:
        return f"ECEF position norm {np.linalg.norm(p):.0f} m is not near the Earth's surface"
    if not spd3(R):
        return "covariance R_e is not positive definite"
    return ""


def usable_imu_arrays(t_s, omega_ib_b, f_ib_b, t_last_s: float):
    t = np.asarray(t_s, float)
    w = np.asarray(omega_ib_b, float)
    f = np.asarray(f_ib_b, float)
    n = t.shape[0] if t.ndim == 1 else 0
    if n == 0 or w.shape != (n, 3) or f.shape != (n, 3):
        return None
    # one finiteness test: a sum is non-finite iff a term is (or it overflows)
    if not math.isfinite(float(t.sum()) + float(w.sum()) + float(f.sum())):
        return None
    dt = np.empty(n)
    dt[0] = t[0] - t_last_s
    np.subtract(t[1:], t[:-1], out=dt[1:])
    return (t, w, f, dt) if dt.min() > 0.0 and dt.max() <= 1.0 else None


# ------------------------------------------------------------------------------------------- ECI cores
def retract_se23(C, v, p, xi):
    """X exp(xi) on SE2(3) by the 5x5 matrices (eq. (14))."""
    X = lie.se23_from(C, v, p) @ lie.se23_exp(xi[0:9])
    Cn, vn, pn = lie.se23_parts(X)
    return Cn.copy(), vn.copy(), pn.copy()


def orthonormalize(C):
    return Rotation.from_matrix(C).as_matrix()


def _propagate_block(self, t, w, f):
    """``BatchedEciCore._propagate_block`` in numpy batches (no compiled kernel)."""
    w = w - self.b_g
    f = f - self.b_a
    dt = np.empty(t.shape[0])
    dt[0] = t[0] - self.t_s
    np.subtract(t[1:], t[:-1], out=dt[1:])
    dC, dv_b, dp_b = step_increments_batch(w, f, dt)
    C_prev, C, v, p = propagate_eci_batch(self.C, self.v, self.p, dt, dC, dv_b, dp_b)
    Phi, Qd = self._transitions(dC, dv_b, dp_b, dt, C_prev, f)
    self.P, Phi_tot = covariance_batch(self.P, Phi, Qd)
    self._Phi_since_update = Phi_tot @ self._Phi_since_update
    self.omega_b = w[-1].copy()
    self.C = orthonormalize(C)
    self.v, self.p = v, p
    self.t_s = float(t[-1])


def gnss_terms(core, fix):
    """(z, H, N) of a fix for a left-invariant ECI core in numpy (ECEF -> ECI, then PI-LIEKF eqs. (42), (43) with the
    lever arm l: z = C^T (p_gps - p) - l, H = [-l_x, 0, I], N = C^T R_i C)."""
    core.flush()
    Cei = earth.C_e_i(core.t_s, core.t0_s)
    R_i = Cei @ np.asarray(fix.R_e, float) @ Cei.T
    l = core.lever_b
    H = np.zeros((3, core._n_states))
    H[:, 0:3] = -np.array([[0.0, -l[2], l[1]], [l[2], 0.0, -l[0]], [-l[1], l[0], 0.0]])
    H[:, 6:9] = np.eye(3)
    return core.C.T @ (Cei @ np.asarray(fix.p_e, float) - core.p) - l, H, core.C.T @ R_i @ core.C


# ------------------------------------------------------------------------------------------- static cores
def f_model(x, u, m_prime=None):
    """PKF paper eq. (34) (static_model's module docstring) in numpy."""
    m = np.zeros(5) if m_prime is None else m_prime
    dvN, dvE, pN, pE, pD = x
    E = static_model.misalignment_matrix(x[2:5])
    w = u.omega_ie_ned
    coriolis = 2.0 * np.array([-w[2] * dvE, w[2] * dvN, w[0] * dvE])
    acc = u.f_np_ned - E @ u.f_np_ned - coriolis
    d_w_in = np.array([dvE / u.r_m, -dvN / u.r_m, -dvE * math.tan(u.lat_rad) / u.r_m])  # eq. (25)
    zeta = E @ (w + d_w_in - m[2:5]) - w
    rot = static_model.Rz(pD).T @ zeta
    return np.array([acc[0] + m[0], acc[1] + m[1], rot[0], rot[1], zeta[2]])


def jacobian(x, u):
    """eq. (35) by central differences of :func:`f_model`."""
    F = np.zeros((5, 5))
    for j in range(5):
        h = 1e-6 if j < 2 else 1e-7
        e = np.zeros(5)
        e[j] = h
        F[:, j] = (f_model(x + e, u) - f_model(x - e, u)) / (2 * h)
    return F


def model_error_jacobian(x5, f_np, lat, r_m, G):
    """d f / d m' by central differences (the 10-state EKF's G), written into G."""
    u = static_model.StaticModelInputs(np.asarray(f_np, float), float(lat), float(r_m))
    for j in range(5):
        e = np.zeros(5)
        e[j] = 1e-6
        G[:, j] = (f_model(x5, u, e) - f_model(x5, u, -e)) / 2e-6


def misalignment_rotation_enu(phi_ned: np.ndarray) -> np.ndarray:
    """Orthonormal version of eq. (23) in ENU: ``T Rz(phiD) exp([phiN, phiE, 0]) T`` (the static cores' feedback and
    attitude estimate; compiled as static_kernels.misaligned_attitude_nb)."""
    T = static_model.T_NED_ENU
    return T @ static_model.Rz(phi_ned[2]) @ lie.so3_exp(np.array([phi_ned[0], phi_ned[1], 0.0])) @ T


def corrected_attitude(pN, pE, pD, C_b_n):
    """``C_b_n <- E C_b_n`` with the eq. (23) misalignment rotation in ENU, re-orthonormalised by an SVD."""
    E = misalignment_rotation_enu(np.array([pN, pE, pD]))
    u, _, vt = np.linalg.svd(E @ C_b_n)
    return u @ vt


def _static_propagate(self, imu):
    """``StaticZuptCore._propagate_sample``: sample by sample through the numpy local-level mechanization."""
    dt = static_model.usable_step(self, imu)
    if dt is None:
        return
    self.t_s = float(imu.stamp_s)
    f_n = self.mech.step(imu.omega_ib_b, imu.f_ib_b, dt)
    self._f_sum_n += f_n * dt
    self._dt_acc += dt


def _position_terms_floored(m, core):
    """:func:`gnss_terms` with the core's covariance floor (the compiled model's reference)."""
    R_e = measurements._floored(np.asarray(m.R_e, float), getattr(core.cfg, "gnss_sigma_floor_m", 0.0))
    return gnss_terms(core, measurements.GnssPosition(m.stamp_s, m.p_e, R_e))


def use_reference_paths(monkeypatch) -> None:
    """Run every core on the numpy formulas above instead of the compiled kernels (pytest's ``monkeypatch``)."""
    for mod in (update, earth_iekf):
        monkeypatch.setattr(mod, "joseph_update", joseph_update)
    for mod in (update, pi_liekf):
        monkeypatch.setattr(mod, "nis", nis)
    monkeypatch.setattr(update, "prediction", prediction)
    monkeypatch.setattr(measurements, "check_fix", check_fix)
    monkeypatch.setattr(liekf, "retract_se23", retract_se23)
    monkeypatch.setattr(liekf, "orthonormalize", orthonormalize)
    monkeypatch.setattr(liekf.BatchedEciCore, "_propagate_block", _propagate_block)
    for mod in (earth_iekf, backtrack):
        monkeypatch.setattr(mod, "eci_steps", eci_steps)
    monkeypatch.setitem(measurements._TERMS, (measurements.GnssPosition, "eci_left"), _position_terms_floored)
    monkeypatch.setattr(checks, "spd3", spd3)
    monkeypatch.setattr(checks, "usable_imu_arrays", usable_imu_arrays)
    monkeypatch.setattr(liekf, "usable_imu_arrays", usable_imu_arrays)
    monkeypatch.setattr(static_model, "f_model", f_model)
    monkeypatch.setattr(static_model, "jacobian", jacobian)
    monkeypatch.setattr(static_model, "_corrected_attitude_nb", corrected_attitude)
    monkeypatch.setattr(static_model, "usable_imu_arrays", lambda *a: None)  # per-sample propagation below
    monkeypatch.setattr(static_model.StaticZuptCore, "_propagate_sample", _static_propagate)
    monkeypatch.setattr(ekf10, "model_error_jacobian_nb", model_error_jacobian)
    for cls in (static_model.StaticZuptCore, pkf.Pkf, ekf10.Ekf10):
        monkeypatch.setattr(cls, "_fused_zupt", False)
