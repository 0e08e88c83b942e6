"""Nonlinear large-azimuth static alignment error model (PKF paper eqs. (18)-(35)) and the shared
zero-velocity error-state machinery of the static cores (PKF, 10-state EKF).

The paper works in NED; the package works in ENU/FLU. The conversion happens here once, in
:func:`ned_from_enu` / :func:`enu_psi_from_ned_phi` (tested in test/test_static_model.py).

State (paper order, NED, n' = computed frame): ``x = [dvN, dvE, phiN, phiE, phiD]`` [m/s, m/s, rad, rad, rad].
Misalignment (eq. (23)): ``C_n'^n = Rz(phiD) (I + [rho x])``, rho = [phiN, phiE, 0], so that the true attitude is
``C_b^n = C_n'^n C_b^n'`` (eq. (22)). The eq. (23) matrix is exactly Rz(phiD)(I + [rho x]) (checked in the test),
which lets the cores feed back the level angles at every update and keep the large azimuth in the state.

Dynamics (derived from eqs. (22)-(25), (27)-(30); see docs/static_alignment.md for why we do not copy the
scalar eqs. (26)/(34) literally): with ``E = C_n'^n``, ``f' = C_b^n' f_meas`` (NED), ``omega_ie = [wN, 0, wD]``,
  ``d(dv)/dt   = [(I - E) f']_NE - [2 omega_ie x dv]_NE + Df``         (eq. (31); identical to the paper)
  ``zeta       = E (omega_ie + d_omega_in(dv) - Domega) - omega_ie``    (E' E^T = [zeta x], eq. (24))
  ``[phiN', phiE'] = [Rz^T zeta]_NE``,  ``phiD' = zeta_D``              (eq. (26), exact for the eq. (23) form)
To first order in the level angles this equals the paper's eq. (26) except the phiD row, which the paper
writes with the level angles rotated by phiD (second order at small phiD, see docs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core import earth
from ..core import mechanization_numba as nb
from ..core.mechanization_n import LocalLevelMechanization
from ..core.units import G0_M_S2
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, ImuSample, UpdateResult
from .config import ConfigDict, param
from .static_kernels import _corrected_attitude_nb, _f_model_nb, _jacobian_nb, _M0, _zupt_step_nb, misaligned_attitude_nb
from . import static_run
from .static_bootstrap import bootstrap_fit
from .checks import ImuBuffer, usable_imu_arrays
from .measurements import ZeroVelocity

#: NED <-> ENU axis swap (a proper rotation, its own inverse): v_ned = T v_enu
T_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
H_ZUPT = np.hstack([np.eye(2), np.zeros((2, 3))])  #: eq. (32)
D2R = math.pi / 180.0
DEG_H = D2R / 3600.0
MG = G0_M_S2 * 1e-3  # [m/s^2] per mg (== 9.80665e-3 to the bit)


def ned_from_enu(v_enu: np.ndarray) -> np.ndarray:
    """A vector in ENU -> the same vector in NED (and back: T is its own inverse)."""
    return T_NED_ENU @ np.asarray(v_enu, dtype=float)


def enu_psi_from_ned_phi(phi_ned: np.ndarray) -> np.ndarray:
    """Paper misalignment [phiN, phiE, phiD] (small level, any azimuth) -> interface rotation vector psi in ENU,
    ``C_true = exp(psi_x) C_est`` (first order in the level angles; psi_U = -phiD)."""
    return T_NED_ENU @ np.asarray(phi_ned, dtype=float)


def Rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def misalignment_matrix(phi_ned: np.ndarray) -> np.ndarray:
    """``C_n'^n`` of eq. (23) (NED): [[c,-s,phiE c+phiN s],[s,c,phiE s-phiN c],[-phiE,phiN,1]]."""
    pN, pE, pD = phi_ned
    c, s = math.cos(pD), math.sin(pD)
    return np.array([[c, -s, pE * c + pN * s], [s, c, pE * s - pN * c], [-pE, pN, 1.0]])


@dataclass
class StaticModelInputs:
    """Inputs of eq. (34) over one filter step: f' (NED, [m/s^2]), latitude [rad], Earth radius r [m]."""

    f_np_ned: np.ndarray
    lat_rad: float
    r_m: float

    @property
    def omega_ie_ned(self) -> np.ndarray:
        return np.array([earth.OMEGA_IE_RAD_S * math.cos(self.lat_rad), 0.0,
                         -earth.OMEGA_IE_RAD_S * math.sin(self.lat_rad)])



def f_model(x: np.ndarray, u: StaticModelInputs, m_prime: np.ndarray | None = None) -> np.ndarray:
    """Continuous nonlinear model f(x, m') of eq. (34) (derivation in the module docstring; compiled).

    m' = [DfN, DfE, DwN, DwE, DwD]: residual accelerometer [m/s^2] and gyro [rad/s] errors in n' (NED).
    """
    out = np.empty(5)
    _f_model_nb(np.asarray(x, float), np.asarray(u.f_np_ned, float), float(u.lat_rad), float(u.r_m),
                _M0 if m_prime is None else np.asarray(m_prime, float), out)
    return out


def jacobian(x: np.ndarray, u: StaticModelInputs) -> np.ndarray:
    """F_t = df/dx (eq. (35)) of :func:`f_model`, by central differences (exact to ~1e-9 relative; compiled)."""
    F = np.zeros((5, 5))
    _jacobian_nb(np.asarray(x, float), np.asarray(u.f_np_ned, float), float(u.lat_rad), float(u.r_m), _M0, F)
    return F


def expm_taylor(A: np.ndarray, order: int = 8) -> np.ndarray:
    """exp(A) by its Taylor series (the filter steps have ||F dt|| ~ g dt |dphi| << 1; error < 1e-12 there).

    scipy.linalg.expm costs ~20 ms per 5x5 call here (Pade with scaling); this is ~30 us."""
    n = A.shape[0]
    out = np.eye(n)
    term = np.eye(n)
    for k in range(1, order + 1):
        term = term @ A / k
        out = out + term
    return out


# ---------------------------------------------------------------------------------------------- config
@dataclass
class StaticConfig(ConfigDict):
    """Shared parameters of the static (zero-velocity) cores. Units in the names.

    Defaults: PKF paper Table 1 (ADIS16488A): ARW 0.26 deg/sqrt(h), VRW 0.029 m/s/sqrt(h); bias stability 5.1 deg/h,
    0.07 mg used as the initial bias sigma of the 10-state EKF: the IMU grade ``paper_static``
    (filters/imu_grade.py). Sessions, the node and insalign-align set the noise and bias fields from their
    ``imu_grade`` (default ``unknown_mems``); an explicit field overrides the grade.
    """

    gyro_arw_deg_sqrt_h: float = 0.26
    acc_vrw_m_s_sqrt_h: float = 0.029
    #: extra velocity process noise for vibration effects the model does not describe (sculling, aliasing of a real
    #: IMU) [m/s/sqrt(s)], added to the VRW. 0 by default: measured on the simulated engine vibration and sway, the
    #: mechanised velocity gains nothing beyond the VRW (docs/static_alignment.md, "Process noise per IMU grade")
    vibration_vrw_m_s_sqrt_s: float = 0.0
    init_sigma_v_m_s: float = 0.01
    #: feed the azimuth estimate back into the mechanization once its 1-sigma is below this [deg]; before that
    #: the large azimuth stays in the state and the nonlinear model (eq. (34)) carries it. Default 180: always
    #: (after the azimuth bootstrap the mechanization itself is the exact nonlinear model; with the azimuth kept
    #: in the state the honest 10-state EKF, whose sigma never drops below the ~24 deg MEMS bias floor, would
    #: carry a large phiD for ever and its velocity rows then depend to first order on the horizontal specific
    #: force; see docs/static_alignment.md, "Feedback and rates")
    azimuth_feedback_sigma_deg: float = param(180.0, range=(0.0, 360.0))
    #: status ALIGNED once the 3-sigma azimuth uncertainty is below this [deg]
    status_yaw_3sigma_deg: float = param(
        1.0,
        "the core's own status ALIGNED below this 3-sigma yaw [deg] (not the aligned flag: "
        'aligned.yaw_3sigma_deg)',
        range=(0.0, 360.0))
    #: 1-sigma sensor biases (the IMU grade's): the 5-state cores do not estimate them and add them to the reported
    #: attitude covariance as the physical floor ((b_acc/g)^2 level, (eps/(omega_ie cos lat))^2 azimuth) so P_att_n
    #: stays honest; the 10-state EKF starts its bias states with them; coarse alignment puts them in its covariance
    gyro_bias_deg_h: float = 5.1
    acc_bias_mg: float = 0.07
    #: azimuth bootstrap (docs/static_alignment.md, "Large initial azimuth"): when the initial yaw 1-sigma exceeds
    #: ``azimuth_bootstrap_above_sigma_deg``, the first ``azimuth_bootstrap_s`` seconds run the mechanization open
    #: loop, fit the drift of its velocity (quadratic in time: the level error grows at the residual horizontal
    #: rate), and start the filter at the azimuth of the horizontal Earth rate seen in the computed frame. 0 = off.
    azimuth_bootstrap_s: float = 20.0
    azimuth_bootstrap_above_sigma_deg: float = param(10.0, range=(0.0, 360.0))
    #: time constant of the low-pass on the interval-mean specific force that enters the error model [s]: the
    #: engine vibration (25 Hz) leaves ~5e-3 m/s^2 in a 0.1 s mean; its velocity is not a motion the zero-velocity
    #: update can see, and with the raw value the phiD column of the velocity rows turns it into false azimuth
    #: information (measured: docs). 0 = no filter.
    specific_force_lowpass_s: float = 1.0

    @property
    def initial_sigmas(self) -> tuple:
        """``AlignmentCore.initial_sigmas``: the level to a few degrees from the accelerometers, the heading unknown
        (the bootstrap handles any azimuth), ``init_sigma_v_m_s``, position 1 m."""
        return ((5.0, 5.0, 100.0), self.init_sigma_v_m_s, 1.0)

    def validate(self) -> None:
        self.check_field_types(non_negative=True)
        for name in ("init_sigma_v_m_s", "status_yaw_3sigma_deg", "azimuth_feedback_sigma_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")


def usable_step(core, imu: ImuSample) -> float | None:
    """The step dt [s] of an IMU sample a static core can use: initialised, 0 < dt <= 1 s, finite values. Otherwise
    None, and a later finite stamp (a gap) still moves the core's time so the next step is measured from it."""
    if not core._init:
        return None
    t = float(imu.stamp_s)
    dt = t - core.t_s
    w, f = imu.omega_ib_b, imu.f_ib_b
    # one scalar test (hot path): a sum is non-finite iff a term is (or it overflows: garbage too)
    if not (0.0 < dt <= 1.0) or len(w) != 3 or len(f) != 3 or not math.isfinite(
            float(w[0]) + float(w[1]) + float(w[2]) + float(f[0]) + float(f[1]) + float(f[2])):
        core.t_s = max(core.t_s, t) if math.isfinite(t) else core.t_s
        return None
    return dt


# ---------------------------------------------------------------------------------------------- core
class StaticZuptCore(AlignmentCore):
    """Error-state filter on the eq. (34) model with zero-velocity updates (eq. (32)) and feedback (Fig. 2).

    State: the 5 paper states, plus (``n_bias = 5``) residual accelerometer N/E [m/s^2] and gyro N/E/D [rad/s]
    errors in n' (the 10-state EKF). ``propagate`` runs the mechanization at the IMU rate (cheap) and accumulates
    the interval; ``update(ZeroVelocity(...))`` predicts the error state over the accumulated interval with the
    nonlinear model and the Jacobian, fuses eq. (32), and feeds back: velocity and level angles (and biases) every
    update, the azimuth once ``sigma(phiD) < azimuth_feedback_sigma_deg``. Recommended ZUPT rate: 10 Hz.
    """

    name = "static"
    convention = "static"
    own_models = frozenset({ZeroVelocity})  # its own fused zero-velocity step (_fuse)
    _fused_zupt = True  #: this class's hooks are the ones :func:`_zupt_step_nb` implements (declared per class)
    updates_inside_runs = True  # the session's 10-Hz zero-velocity updates go in with the run's samples
    vel_index = (0, 1)  # dvN dvE
    att_index = (2, 3, 4)  # phiN phiE phiD

    n_bias = 0

    def __init__(self, cfg: StaticConfig):
        self.cfg = cfg
        self.initial_sigmas = cfg.initial_sigmas
        self._init = False

    # ------------------------------------------------------------------ interface
    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m):
        self.mech = LocalLevelMechanization(lat_rad, lon_rad, h_m, C_b_n, v_n)
        self.t_s = float(stamp_s)
        self.t_last_update_s = float(stamp_s)
        n = 5 + self.n_bias
        self.x = np.zeros(n)
        self.P = np.zeros((n, n))
        self.P[0:2, 0:2] = np.eye(2) * max(sigma_v_m_s, 1e-6) ** 2
        P_ned = T_NED_ENU @ np.asarray(P_att_n, dtype=float) @ T_NED_ENU
        self.P[2:5, 2:5] = P_ned
        self._init_bias_cov()
        self._f_sum_n = np.zeros(3)
        self._dt_acc = 0.0
        self._buf = ImuBuffer()  # (dt, omega, f) of the samples since the last flush
        self._f_lp_ned = None
        self._N_prev = None
        self.t0_s = float(stamp_s)
        self._boot = (self.cfg.azimuth_bootstrap_s > 0
                      and self.P[4, 4] > (self.cfg.azimuth_bootstrap_above_sigma_deg * D2R) ** 2)
        self._boot_t: list[float] = []
        self._boot_v: list[np.ndarray] = []
        self._boot_breaks: list[int] = []  # bootstrap points after which a gap or a widening broke the fit
        self.status = AlignmentStatus.CONVERGING
        self.reason = "zero-velocity alignment running"
        self.r_m = math.sqrt(self.mech.R_N_m * self.mech.R_E_m)
        self._floor = None  # _consider_floor's
        self._init = True

    def _init_bias_cov(self) -> None:
        pass

    @property
    def initialized(self) -> bool:
        return self._init

    def _propagate_sample(self, imu: ImuSample) -> None:
        dt = usable_step(self, imu)
        if dt is None:
            return
        self.t_s = float(imu.stamp_s)
        self._buf.add(dt, imu.omega_ib_b, imu.f_ib_b)  # buffered: the compiled loop runs on the next flush

    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        """Forward: whole arrays appended to the interval buffer when every row is usable (finite, 0 < dt <= 1 s);
        otherwise sample by sample (which skips and handles the bad rows)."""
        arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, self.t_s) if self._init and not backward else None
        if arr is None:
            super()._propagate_arrays(t_s, omega_ib_b, f_ib_b, backward)
            return
        t, w, f, dt = arr
        self._buf.add_block(dt, w, f)
        self.t_s = float(t[-1])

    def flush(self) -> None:
        """Run the buffered IMU samples through the mechanization (one compiled call for the whole interval)."""
        if not self._init or not self._buf.n:
            return
        DT, W, F = self._buf.take()
        m = self.mech
        C = np.ascontiguousarray(m.C_b_n)
        v = np.array(m.v_n, dtype=float)
        self._dt_acc += nb.local_level_steps(C, v, W, F, DT, m.gyro_correction_b, m.acc_correction_b, m.omega_ie_n,
                                             m.g_n, m.R_N_m, m.R_E_m, m.tan_lat, self._f_sum_n)
        m.C_b_n, m.v_n = C, v

    def _process_noise(self, dt: float) -> np.ndarray:
        return np.diag(self._q_rate()) * dt

    def _full_jacobian(self, F5: np.ndarray) -> np.ndarray:
        return F5

    def body_from_ned(self, v_ned: np.ndarray) -> np.ndarray:
        """A vector in n' (NED) -> body FLU with the current mechanised attitude (C_n'^b = (C_b^n')^T)."""
        return self.mech.C_b_n.T @ ned_from_enu(v_ned)

    def _fuse(self, meas) -> UpdateResult:
        """The zero-velocity step is the paper's own (eq. (32) after the eq. (34) prediction, the fused compiled
        kernel): the core's one hook instead of the shared pipeline (filters/update.py)."""
        if not self._init:
            return UpdateResult(False, reason="not initialized")
        reason = meas.check()
        if reason:
            return UpdateResult(False, reason=reason)
        stamp_s, sigma_v_m_s = meas.stamp_s, meas.sigma_v_m_s
        self.flush()
        dt = self._dt_acc
        if dt <= 0:
            return UpdateResult(False, reason="no IMU data since the last update")
        f_np_ned = ned_from_enu(self._f_sum_n / dt)
        self._f_sum_n[:] = 0.0
        self._dt_acc = 0.0
        tau = self.cfg.specific_force_lowpass_s
        if self._f_lp_ned is None or tau <= 0:
            self._f_lp_ned = f_np_ned
        else:
            self._f_lp_ned = self._f_lp_ned + min(1.0, dt / tau) * (f_np_ned - self._f_lp_ned)
        f_np_ned = self._f_lp_ned
        if self._boot:
            return self._bootstrap_step(float(stamp_s), sigma_v_m_s)
        u = StaticModelInputs(f_np_ned, self.mech.lat_rad, self.r_m)
        self._u_last = u
        # ---- predict the error state over the interval with eq. (34) (RK2) and its Jacobian eq. (35)
        m_prime = self._model_error_prime()
        x_start = self.x.copy()
        if type(self).__dict__.get("_fused_zupt", False):
            # the steps below in one compiled kernel (docs/speed.md) for the classes that declare it; the code below
            # is the generic path of a subclass whose hooks the kernel does not implement (and the tests' reference)
            return self._zupt_compiled(u, m_prime, dt, float(stamp_s), sigma_v_m_s)
        x5 = self.x[:5].copy()
        k1 = f_model(x5, u, m_prime)
        k2 = f_model(x5 + dt * k1, u, m_prime)
        F = self._full_jacobian(jacobian(x5, u))
        Phi = expm_taylor(F * dt)
        self.x[:5] = x5 + 0.5 * dt * (k1 + k2)
        N_next = self._nullspace(self.x[4])
        if N_next is not None:
            # observability constraint (Huang, Mourikis, Roumeliotis, OC-EKF): the transition must carry the
            # unobservable direction of the previous prediction onto the one of this prediction, Phi N_k = N_k+1;
            # the minimal correction in the least-squares sense (docs/static_alignment.md, "10-state EKF")
            N_k = self._N_prev if self._N_prev is not None else self._nullspace(x5[4])
            Phi = Phi - np.outer(Phi @ N_k - N_next, N_k) / float(N_k @ N_k)
            self._N_prev = N_next
        self.P = Phi @ self.P @ Phi.T + self._process_noise(dt)
        # ---- update with eq. (32): the measured velocity error is the mechanised velocity (truth is zero)
        n = self.x.shape[0]
        H = np.zeros((2, n))
        H[:, 0:2] = np.eye(2)
        z = ned_from_enu(self.mech.v_n)[0:2]
        Rm = np.eye(2) * sigma_v_m_s**2
        S = H @ self.P @ H.T + Rm
        K = self.P @ H.T @ np.linalg.inv(S)
        innov = z - H @ self.x
        self.x = self.x + K @ innov
        I_KH = np.eye(n) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ Rm @ K.T
        self.P = 0.5 * (self.P + self.P.T)
        nis = float(innov @ np.linalg.solve(S, innov))
        self._after_update(x_start, dt)
        self._feedback()
        self.t_last_update_s = float(stamp_s)
        return UpdateResult(True, innovation=innov, S=S, nis=nis)

    def _zupt_compiled(self, u, m_prime, dt, stamp_s, sigma_v_m_s) -> UpdateResult:
        """The prediction, update, model-error step and feedback of :meth:`_fuse` in one compiled
        call (:func:`_zupt_step_nb`, the same formulas) for the classes that declare ``_fused_zupt`` (their hooks are
        the ones the kernel implements)."""
        m = self.mech
        n = self.x.shape[0]
        P = np.array(self.P, dtype=float)  # new arrays, as the reference path assigns them
        C, v = np.array(m.C_b_n, dtype=float), np.array(m.v_n, dtype=float)
        acc, gyro = np.array(m.acc_correction_b, dtype=float), np.array(m.gyro_correction_b, dtype=float)
        oc_w_h = self._oc_w_h()
        N_k = np.zeros(n) if oc_w_h <= 0 else self._N_prev if self._N_prev is not None else self._nullspace(self.x[4])
        N_next = np.zeros(n)
        p, re, qm, m_rate = self._pkf_args()
        innov, S = np.empty(2), np.empty((2, 2))
        nis = _zupt_step_nb(self.x, P, np.asarray(u.f_np_ned, float), float(u.lat_rad), float(u.r_m),
                            _M0 if m_prime is None else np.asarray(m_prime, float), dt, self.n_bias > 0,
                            self._q_rate(), oc_w_h, np.asarray(N_k, float), sigma_v_m_s**2, p, re, qm, m_rate, C, v,
                            acc, gyro, self.cfg.azimuth_feedback_sigma_deg * D2R, innov, S, N_next,
                            np.empty((n, n)))
        self.P = P
        m.C_b_n, m.v_n, m.acc_correction_b, m.gyro_correction_b = C, v, acc, gyro
        if oc_w_h > 0:
            self._N_prev = N_next
        if p > 0:
            self.m_rate = m_rate
        self.t_last_update_s = stamp_s
        return UpdateResult(True, innovation=innov, S=S, nis=nis)

    def _updates_along(self, t_s, omega_ib_b, f_ib_b, ends: list, updates, out: list) -> None:
        """In one compiled call where the run allows it (filters/static_run.py), else segment by segment."""
        if not static_run.run_with_updates(self, t_s, omega_ib_b, f_ib_b, ends, updates, out, StaticModelInputs):
            super()._updates_along(t_s, omega_ib_b, f_ib_b, ends, updates, out)

    def _oc_w_h(self) -> float:
        """The fused kernel's OC-EKF switch: w_h of the nullspace (``_nullspace``), 0 for a core without one."""
        return 0.0

    def _pkf_args(self):
        """The fused kernel's PKF model-error step: (horizon p, R_e weight, Q_m diagonal, m_rate copy); p = 0: none."""
        return 0, 1.0, _M0, np.zeros(5)

    def _q_rate(self) -> np.ndarray:
        """Diagonal of the process noise per second (``_process_noise(dt) = diag(q) dt``)."""
        q = np.zeros(5)
        vrw = (self.cfg.acc_vrw_m_s_sqrt_h / 60.0) ** 2 + self.cfg.vibration_vrw_m_s_sqrt_s**2
        q[0:2] = vrw
        q[2:5] = (self.cfg.gyro_arw_deg_sqrt_h * D2R / 60.0) ** 2
        return q

    def _bootstrap_step(self, stamp_s: float, sigma_v_m_s: float) -> UpdateResult:
        """Open-loop azimuth bootstrap (docs/static_alignment.md, "Large initial azimuth").

        The mechanization runs without feedback. Its level error in n' (NED) grows as rho(t) = rho0 + r t with the
        residual horizontal rate r = [wN (1 - cos a) - epsN, wN sin a - epsE] (eq. (34) rows 3-4 at azimuth error
        a), so the velocity error (eq. (31)) is quadratic: dvN = g (pE0 t + rE t^2/2), dvE = -g (pN0 t + rN t^2/2).
        A least-squares fit over the window gives r, and (wN - rN, rE) = wN (cos a, sin a) + bias is the horizontal
        Earth rate in the computed frame: a = atan2(rE, wN - rN). The sway and the engine vibration are integrated
        by the mechanization (the velocity of the vibration is bounded), so unlike the rate-averaging coarse
        alignment this needs no long window. The filter then starts from (a, rho(T)) with the covariance of the fit
        plus the gyro-bias floor.
        """
        self._boot_t.append(stamp_s - self.t0_s)
        self._boot_v.append(ned_from_enu(self.mech.v_n)[0:2].copy())
        self.t_last_update_s = stamp_s
        T = stamp_s - self.t0_s
        brk = self._boot_breaks
        if T < self.cfg.azimuth_bootstrap_s or len(self._boot_t) - (brk[-1] if brk else 0) < 10:
            return UpdateResult(False, reason="azimuth bootstrap: %.1f of %.1f s" % (T, self.cfg.azimuth_bootstrap_s))
        t = np.array(self._boot_t)
        V = np.array(self._boot_v)
        c2, slope_T, k_rate, k_level, n = bootstrap_fit(t, V, brk, T)  # (after a gap: a segment each side)
        g = float(np.linalg.norm(self.mech.g_n))
        w_h = earth.OMEGA_IE_RAD_S * math.cos(self.mech.lat_rad)
        rE, rN = 2.0 * c2[0] / g, -2.0 * c2[1] / g
        pE_T = slope_T[0] / g
        pN_T = -slope_T[1] / g
        a = math.atan2(rE, w_h - rN)
        # covariance: rate from the fit (velocity noise sigma_v; std of the t^2 coefficient ~ sigma_v sqrt(180/N)/T^2)
        # and from the angle random walk (fitted slope of a random-walk tilt ~ ARW sqrt(12 / (5 T))); level from the
        # fit, the accelerometer-bias floor and the random-walk tilt ARW sqrt(T); the gyro-bias part of the azimuth
        # is added by _bootstrap_azimuth_cov
        s_r_fit = 2.0 * sigma_v_m_s * math.sqrt(180.0 / n) / (g * T * T) * k_rate
        s_r_arw = self.cfg.gyro_arw_deg_sqrt_h * D2R / 60.0 * math.sqrt(12.0 / (5.0 * T))
        s_noise_rad = math.hypot(s_r_fit, s_r_arw) / w_h
        s_lvl = float(np.linalg.norm([sigma_v_m_s * math.sqrt(12.0 / n) / (g * T) * k_level,
                                      self.cfg.acc_bias_mg * MG / g,
                                      self.cfg.gyro_arw_deg_sqrt_h * D2R / 60.0 * math.sqrt(T)]))
        self.x[:] = 0.0
        self.x[0:2] = V[-1]
        self.x[2:5] = [pN_T, pE_T, a]
        self.P[:] = 0.0
        self.P[0:2, 0:2] = np.eye(2) * sigma_v_m_s**2
        self.P[2:4, 2:4] = np.eye(2) * s_lvl**2
        self._init_bias_cov()
        self._bootstrap_azimuth_cov(s_noise_rad, w_h)
        self._boot = False
        self._f_lp_ned = None  # the open-loop mechanization's tilt is about to be corrected: restart the low-pass
        self._feedback()
        return UpdateResult(True, reason="azimuth bootstrap done: %.2f deg" % math.degrees(a))

    def inflate_navigation(self, var_att_rad2, var_v_m2_s2, var_p_m2=0.0, var_bg_rad2_s2=0.0, var_ba_m2_s4=0.0):
        """The base class's; while the open-loop bootstrap runs, also a break of its fit (the gap bridge may have
        stepped the tilt and velocity, which a single quadratic cannot follow: static_bootstrap.py)."""
        super().inflate_navigation(var_att_rad2, var_v_m2_s2, var_p_m2, var_bg_rad2_s2, var_ba_m2_s4)
        if self._init and self._boot and self._boot_t and (not self._boot_breaks
                                                           or self._boot_breaks[-1] != len(self._boot_t)):
            self._boot_breaks.append(len(self._boot_t))

    def _nullspace(self, phiD: float) -> np.ndarray | None:
        """Unobservable direction of the error state at azimuth phiD (None: the state has none)."""
        return None

    def _bootstrap_azimuth_cov(self, s_noise_rad: float, w_h: float) -> None:
        """5-state cores: the fit noise only; the gyro-bias part is the consider floor added in estimate()."""
        self.P[4, 4] = s_noise_rad**2

    def _model_error_prime(self) -> np.ndarray | None:
        return None

    def _after_update(self, x_start: np.ndarray, dt: float) -> None:
        """Hook after the measurement update, before feedback; x_start = state at the start of the step."""

    def _feedback(self) -> None:
        x = self.x
        # velocity (NED error -> ENU) and vertical channel (zero-velocity condition, delta v_D = 0)
        dv_enu = ned_from_enu(np.array([x[0], x[1], 0.0]))
        self.mech.v_n = self.mech.v_n - dv_enu
        self.mech.v_n[2] = 0.0
        sigma_D = math.sqrt(max(self.P[4, 4], 0.0))
        feed_az = sigma_D < self.cfg.azimuth_feedback_sigma_deg * D2R
        if feed_az:
            self.mech.C_b_n = _corrected_attitude_nb(float(x[2]), float(x[3]), float(x[4]),
                                                     np.ascontiguousarray(self.mech.C_b_n, dtype=float))
            # the computed frame n' turns by phiD about Down: every (N, E) pair of the state (velocity, level,
            # accelerometer and gyro errors) is now expressed in the new axes, v'' = Rz(phiD) v' (reset Jacobian)
            J = np.eye(self.x.shape[0])
            R2 = Rz(x[4])[0:2, 0:2]
            for i in (0, 2, 5, 7)[:2 + self.n_bias // 2]:
                J[i:i + 2, i:i + 2] = R2
            self.P = J @ self.P @ J.T
            if self._N_prev is not None:
                self._N_prev = J @ self._N_prev
            self.x[4] = 0.0
        else:
            # level only: C_true = Rz(phiD) exp(rho) C_est -> C_est <- exp(rho) C_est, phiD stays in the state
            self.mech.C_b_n = _corrected_attitude_nb(float(x[2]), float(x[3]), 0.0,
                                                     np.ascontiguousarray(self.mech.C_b_n, dtype=float))
        self.x[0:4] = 0.0
        self._feedback_bias()

    def _feedback_bias(self) -> None:
        pass

    def estimate(self) -> AlignmentEstimate:
        if not self._init:
            return AlignmentEstimate(float("nan"), np.eye(3), np.zeros(3), float("nan"), float("nan"),
                                     float("nan"), np.eye(3) * np.pi**2, np.eye(5 + self.n_bias),
                                     self.state_names, status=AlignmentStatus.WAITING_FOR_DATA,
                                     reason="not initialized")
        self.flush()
        m = self.mech
        return self._estimate_of(self.t_s, self.x, self.P, m.C_b_n, m.v_n, m.gyro_correction_b, m.acc_correction_b)

    def _estimate_of(self, t_s, x, P, C_b_n, v_n, gyro_corr, acc_corr, own: bool = False) -> AlignmentEstimate:
        """The estimate of the state (x, P, the mechanization's C_b_n, v_n and corrections) at ``t_s``; ``own``: the
        arrays are the estimate's own (a run's snapshots), not copied."""
        P_att = T_NED_ENU @ P[2:5, 2:5] @ T_NED_ENU
        if self.n_bias == 0:
            P_att = P_att + self._consider_floor()
        yaw3 = 3.0 * math.sqrt(max(P_att[2, 2], 0.0))
        status = AlignmentStatus.ALIGNED if yaw3 < self.cfg.status_yaw_3sigma_deg * D2R else AlignmentStatus.CONVERGING
        reason = ("3-sigma azimuth %.3g deg" % (yaw3 / D2R))
        if self._boot:
            status, reason = AlignmentStatus.CONVERGING, "azimuth bootstrap (open-loop drift fit) running"
        C = misaligned_attitude_nb(float(x[2]), float(x[3]), float(x[4]), np.ascontiguousarray(C_b_n, float))
        if not own:
            v_n, P, gyro_corr, acc_corr = v_n.copy(), P.copy(), gyro_corr.copy(), acc_corr.copy()
        return AlignmentEstimate(t_s, C, v_n, self.mech.lat_rad, self.mech.lon_rad, self.mech.h_m, P_att, P,
                                 self.state_names, bias_gyro_b=gyro_corr, bias_acc_b=acc_corr, status=status,
                                 reason=reason)

    def _consider_floor(self) -> np.ndarray:
        """The 5-state cores' attitude floor of the declared biases (ENU): the level's accelerometer bias over g, the
        azimuth's gyro bias over the horizontal Earth rate (the site is fixed at ``initialize``: computed once)."""
        if self._floor is None:
            g = float(np.linalg.norm(self.mech.g_n))
            w_h = earth.OMEGA_IE_RAD_S * math.cos(self.mech.lat_rad)
            lvl = (self.cfg.acc_bias_mg * MG / g) ** 2
            self._floor = np.diag([lvl, lvl, (self.cfg.gyro_bias_deg_h * DEG_H / w_h) ** 2])
        return self._floor

    @property
    def state_names(self) -> tuple[str, ...]:
        return ("dvN", "dvE", "phiN", "phiE", "phiD")


# ---------------------------------------------------------------------------------------------- runner helpers
def physical_floor(C_b_n_true: np.ndarray, bias_gyro_b: np.ndarray, bias_acc_b: np.ndarray, lat_rad: float,
                   g_m_s2: float = G0_M_S2) -> dict:
    """The static-alignment floor from the biases actually present (papers README):
    level ~ b_acc_horizontal / g (per ENU axis), azimuth ~ eps_east / (omega_ie cos(lat)); 'azimuth_rad' is the exact
    form atan2(|eps_E|, omega_ie cos(lat) + eps_N), 'azimuth_linear_rad' the first-order one.

    Returns magnitudes [rad]: 'east_acc_tilt_rad', 'north_acc_tilt_rad' (the accelerometer bias resolved in ENU;
    east -> tilt about north, north -> tilt about east), 'level_rad' (the larger), 'azimuth_rad', 'azimuth_linear_rad',
    and the ENU gyro biases 'eps_east_rad_s', 'eps_north_rad_s' [rad/s].
    """
    b_a_n = C_b_n_true @ np.asarray(bias_acc_b)
    b_g_n = C_b_n_true @ np.asarray(bias_gyro_b)
    level = np.abs(b_a_n[0:2]) / g_m_s2
    w_h = earth.OMEGA_IE_RAD_S * math.cos(lat_rad)
    az_lin = abs(b_g_n[0]) / w_h
    # exact: a static estimator that cannot separate the bias takes North along the measured horizontal rate
    # (eps_E, w_h + eps_N) [ENU]; its angle from the true North is the floor. = eps_E / w_h to first order; differs
    # when the horizontal bias is not small against w_h (MEMS: 5 deg/h against 12.3 deg/h at 35 deg)
    az = abs(math.atan2(b_g_n[0], w_h + b_g_n[1]))
    return {"east_acc_tilt_rad": float(level[0]), "north_acc_tilt_rad": float(level[1]),
            "level_rad": float(max(level)), "azimuth_rad": float(az), "azimuth_linear_rad": float(az_lin),
            "eps_east_rad_s": float(b_g_n[0]), "eps_north_rad_s": float(b_g_n[1])}


def arw_azimuth_limit_rad(arw_deg_sqrt_h: float, lat_rad: float, T_s: float) -> float:
    """1-sigma azimuth limit of gyrocompassing over T_s set by the gyro white noise: the east tilt rate
    omega_ie cos(lat) psi is the slope of a random-walk tilt of density ARW, ARW / (omega_ie cos(lat) sqrt(T))."""
    return arw_deg_sqrt_h * D2R / 60.0 / (earth.OMEGA_IE_RAD_S * math.cos(lat_rad) * math.sqrt(T_s))


def config_for_imu(config_class, spec, **overrides):
    """Config of a static core from an ImuSpec (datasheet): process noise from VRW and ARW, the bias priors (EKF10
    initial bias sigmas, the 5-state consider floor, the coarse alignment's bias terms) from the bias stability
    (filters/imu_grade.py maps the fields). config/<core>_navgrade.yaml is this function's output (tested)."""
    from .imu_grade import ImuGrade, grade_params

    return config_class.from_dict({**grade_params(ImuGrade.from_spec(spec), config_class), **overrides})
