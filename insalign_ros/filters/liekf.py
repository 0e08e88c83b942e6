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


from ..core import mechanization_numba as nb
from ..core.mechanization import NavStateEci, navigation_from_state_eci, state_eci_from_geodetic
from ..core.units import deg_sqrt_h_to_rad_sqrt_s, m_s_sqrt_h_to_m_s_sqrt_s
from .base import AlignmentCore, AlignmentEstimate, AlignmentStatus, ImuSample, UpdateResult, accel_noise_b
from .checks import ImuBuffer, check_imu, usable_imu_arrays
from .config import LiekfConfig
from .eci_batch import covariance_batch, eci_steps, liekf_transition_batch, orthonormalize, retract_se23
from . import measurements  # noqa: F401  (registers the models of the cores' conventions)

_I3 = np.eye(3)
_NO_TOT = np.eye(1)  # the fused kernel's transition product when no correction reads it (not written)


# ----------------------------------------------------------------------------------- the shared core
class BatchedEciCore(AlignmentCore):
    """ECI strapdown + error-state covariance with batched propagation; subclasses define the error model.

    Subclass hooks: ``_n_states``, ``state_names``, ``_bias_correct(omega, f)``, ``_transitions(...)``,
    ``_P0(P_att_n, sigma_v, sigma_p)``, ``_inject(dx)``, ``_att_error_inertial``; the measurement Jacobians are the models'
    (filters/measurements.py, ``convention``), the update the one pipeline (filters/update.py).
    """

    needs_motion = True
    convention = "eci_left"  # the models' Jacobians (filters/measurements.py): GNSS position and velocity, ...
    att_index = (0, 1, 2)
    vel_index = (3, 4, 5)
    pos_index = (6, 7, 8)
    _n_states = 9
    state_names: tuple[str, ...] = ()

    def __init__(self, config=None):
        self.cfg = config if config is not None else self.config_class()
        self.cfg.validate()
        self._init = False
        self.initial_sigmas = self.cfg.initial_sigmas
        self._buf = ImuBuffer()
        self.counters = {"imu": 0, "imu_rejected": 0, "gnss": 0, "gnss_rejected": 0, "gnss_vel": 0,
                         "gnss_vel_rejected": 0}
        self.lever_b = np.asarray(getattr(self.cfg, "gnss_lever_arm_b_m", (0.0, 0.0, 0.0)), float)
        self.last_reject_reason = ""
        arw = deg_sqrt_h_to_rad_sqrt_s(self.cfg.gyro_arw_deg_sqrt_h)
        vrw = m_s_sqrt_h_to_m_s_sqrt_s(self.cfg.acc_vrw_m_s_sqrt_h)
        self._q_gyro = arw * arw  # PSD [rad^2/s]
        self._q_acc = vrw * vrw  # PSD [m^2/s^3]
        self._q_acc_up = m_s_sqrt_h_to_m_s_sqrt_s(self.cfg.acc_vrw_up_m_s_sqrt_h) ** 2  # along the vertical; 0: same
        self._q_acc_b = np.full(3, self._q_acc)  # per body axis (set at the initialisation: base.accel_noise_b)

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
        self._q_acc_b = accel_noise_b(C_b_n, self._q_acc, self._q_acc_up)
        self.__dict__.pop("_fused_cache", None)  # the fused kernel's noise PSDs follow it
        self.P = self._P0(C_b_n, np.asarray(P_att_n, float), float(sigma_v_m_s), float(sigma_p_m))
        self._P0_att = self.P[0:3, 0:3].copy()
        self._buf = ImuBuffer()
        self._Phi_since_update = np.eye(self._n_states)
        self._t_last_update = self.t0_s
        self._init = True

    def _propagate_sample(self, imu: ImuSample) -> None:
        """Buffer one IMU sample (propagated in a batch on the next flush). Bad samples are rejected."""
        if not self._init:
            self._reject_imu("not initialised")
            return
        t_last = self._buf.last_t if self._buf.n else self.t_s
        reason = check_imu(imu)
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

    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        """Forward: whole arrays without a Python step per sample, in the same batches as one sample at a time (so
        the same numbers); any unusable row (non-finite, stamps not increasing, a gap > 1 s) sends the call through
        the per-sample step, which rejects and counts it."""
        arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, self._buf.last_t if self._buf.n else self.t_s) \
            if self._init and not backward else None
        if arr is None:
            super()._propagate_arrays(t_s, omega_ib_b, f_ib_b, backward)
            return
        t, w, f, _ = arr
        n = t.shape[0]
        self.counters["imu"] += n
        mb = self.cfg.max_batch_samples
        i = min(n, mb - self._buf.n)  # complete the pending batch first, as the per-sample step would
        self._buf.add_block(t[:i], w[:i], f[:i])
        if self._buf.n >= mb:
            self.flush()
        while n - i >= mb:
            self._propagate_block(t[i:i + mb], w[i:i + mb], f[i:i + mb])
            i += mb
        if i < n:
            self._buf.add_block(t[i:], w[i:], f[i:])

    def _estimates_along(self, t_s, omega_ib_b, f_ib_b, ends) -> list[AlignmentEstimate]:
        """:meth:`propagate` with the estimates after the rows ``ends`` in one compiled call on the fused path
        (``mechanization_numba.eci_invariant_snapshots``): the same batches as ``propagate`` of each segment and
        ``estimate()`` after it, so the same numbers; elsewhere the base class's segment by segment."""
        fs = self._fused_setup() if self._init else (False,)
        arr = usable_imu_arrays(t_s, omega_ib_b, f_ib_b, self._buf.last_t if self._buf.n else self.t_s) \
            if fs[0] and not fs[1] and len(ends) else None
        if arr is None:
            return super()._estimates_along(t_s, omega_ib_b, f_ib_b, ends)
        t, w, f, _ = arr
        n0 = self._buf.n
        last = int(ends[-1]) + 1
        if n0:
            tb, wb, fb = self._buf.take()
            T = np.concatenate((tb, t[:last]))
            W = np.concatenate((wb, w[:last]))
            F = np.concatenate((fb, f[:last]))
        else:
            T, W, F = t[:last], w[:last], f[:last]
        bounds, snap = _flush_plan(n0, [n0 + int(k) + 1 for k in ends], self.cfg.max_batch_samples)
        m = len(ends)
        d = self._n_states
        SP, SC, SV = np.empty((m, d, d)), np.empty((m, 3, 3)), np.empty((m, 3))
        SLLH, SPA = np.empty((m, 3)), np.empty((m, 3, 3))
        C, v, p = self.C.copy(), self.v.copy(), self.p.copy()
        P = np.array(self.P, dtype=float)
        self.omega_b = nb.eci_invariant_snapshots(
            C, v, p, np.ascontiguousarray(T, float), np.ascontiguousarray(W, float), np.ascontiguousarray(F, float),
            self.t_s, np.asarray(self.b_g, float), np.asarray(self.b_a, float), nb._ZONAL_N, nb._ZONAL_J, P,
            fs[2], np.array(bounds, np.int64), np.array(snap, np.int64), self.t0_s, self._att_error_inertial,
            SP, SC, SV, SLLH, SPA)
        self.P, self.C, self.v, self.p = P, C, v, p
        self.t_s = float(T[-1])
        self.counters["imu"] += last
        out = []
        for s, e in enumerate(bounds_of_snapshots(bounds, snap)):
            est = self._estimate_from(float(T[e - 1]), SC[s], SV[s], *SLLH[s].tolist(), SPA[s], SP[s])
            est.bias_gyro_b, est.bias_acc_b = self._bias_out()  # the biases do not move between updates
            out.append(est)
        if last < t.shape[0]:
            self._propagate_arrays(t[last:], w[last:], f[last:])
        return out

    def _propagate_block(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> None:
        """Propagate state and covariance over samples (t (N,) [s], raw omega_ib_b, f_ib_b (N, 3))."""
        fs = self._fused_setup()
        if fs[0]:  # state, transitions, covariance and re-orthonormalisation in one compiled call
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
        dC, dv_b, dp_b, C_prev, C, v, p = eci_steps(self.C, self.v, self.p, w, f, dt)  # compiled (docs/speed.md)
        Phi, Qd = self._transitions(dC, dv_b, dp_b, dt, C_prev, f)
        q = np.diagonal(Qd, axis1=1, axis2=2)
        if np.count_nonzero(Qd) == np.count_nonzero(q):  # diagonal Q_k (every core here)
            P, Phi_tot = nb.covariance_steps(self.P, Phi, q.copy())
            self.P = 0.5 * (P + P.T)
        else:
            self.P, Phi_tot = covariance_batch(self.P, Phi, Qd)
        self._Phi_since_update = Phi_tot @ self._Phi_since_update
        self.omega_b = w[-1].copy()
        self.C = orthonormalize(C)  # once per batch
        self.v, self.p = v, p
        self.t_s = float(t[-1])

    #: whether this class's ``_transitions`` and ``_noise_diag`` are the left-invariant ones that
    #: ``mechanization_numba.eci_invariant_steps`` builds itself (LIEKF 9 states; imperfect IEKF 15 states): a class
    #: that defines either declares it in its own body (checked when the class is created)
    _fused_kernel_transitions = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        own = vars(cls)
        if ("_transitions" in own or "_noise_diag" in own) and "_fused_kernel_transitions" not in own:
            raise TypeError(f"{cls.__name__} defines its own transitions or noise: declare _fused_kernel_transitions")

    @classmethod
    def _fused_transition(cls) -> bool:
        """Whether the fused compiled kernel reproduces this class's transitions and noise (declared)."""
        return cls._fused_kernel_transitions and cls._n_states in (9, 15)

    def _fused_setup(self):
        """(fused kernel usable, transition product wanted, noise PSDs per state: ``_noise_diag(dt) = qrate dt``),
        evaluated once per initialisation (the configuration is fixed; the noise follows the vertical found then)."""
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
        d[:, 3:6] = self._q_acc_b * dt[:, None]  # the velocity error is in the body frame (left-invariant)
        return d

    def _transitions(self, dC, dv_b, dp_b, dt, C_prev, f):
        Phi = liekf_transition_batch(dC, dv_b, dp_b, dt)
        Qd = np.zeros((dt.shape[0], 9, 9))
        idx = np.arange(9)
        Qd[:, idx, idx] = self._noise_diag(dt)
        return Phi, Qd

    def _inject(self, dx: np.ndarray) -> None:
        """Retraction X_hat exp(dxi) (eq. (14)); error reset (eq. (15)) is implicit."""
        self.C, self.v, self.p = retract_se23(self.C, self.v, self.p, np.ascontiguousarray(dx[0:9], dtype=float))

    #: the attitude error states are a rotation vector in ECI (True; P_att_n = C_i_n P C_i_n^T) or in the body frame
    #: (False: the invariant errors, P_att_n = C_b_n P C_b_n^T), core/mechanization.py navigation_from_state_eci
    _att_error_inertial = False

    # ---------------------------------------------------------------- update hooks (filters/update.py)
    def _gate(self, meas) -> float:
        return self.cfg.gnss_nis_gate

    def _fading_factor(self, meas, nis_v: float) -> float:
        """Adaptive fading memory: NIS / threshold, never above ``fading_max_factor`` nor above the initial attitude
        uncertainty (beyond it the linear update only adds damage); 1 = none (docs/inmotion_cores.md)."""
        fading = self.cfg.fading_nis_threshold
        if not (fading > 0 and nis_v > fading):
            return 1.0
        room = float(np.min(np.diag(self._P0_att) / np.maximum(np.diag(self.P)[0:3], 1e-30)))
        return max(1.0, min(nis_v / fading, self.cfg.fading_max_factor, room))

    def _inflate(self, lam: float) -> None:
        """The navigation block by congruence D P D (stays SPD, keeps correlations)."""
        D = np.ones(self._n_states)
        D[0:9] = math.sqrt(lam)
        self.P = self.P * np.outer(D, D)

    def _after_update(self, meas, res: UpdateResult) -> UpdateResult:
        if meas.is_position:  # the update clock of PI-LIEKF's eq. (30)
            self._Phi_since_update = np.eye(self._n_states)
            self._t_last_update = self.t_s
        return res

    # ---------------------------------------------------------------- output
    def estimate(self) -> AlignmentEstimate:
        if not self._init:
            raise RuntimeError("estimate() before initialize()")
        self.flush()
        lat, lon, h, C_b_n, v_n, P_att = navigation_from_state_eci(
            NavStateEci(self.t_s, self.C, self.v, self.p), self.t0_s, self.P[0:3, 0:3], self._att_error_inertial)
        est = self._estimate_from(self.t_s, C_b_n, np.asarray(v_n), lat, lon, h, P_att, self.P.copy())
        est.bias_gyro_b, est.bias_acc_b = self._bias_out()
        return est

    def _estimate_from(self, t_s, C_b_n, v_n, lat, lon, h, P_att, P) -> AlignmentEstimate:
        sig_yaw3 = 3.0 * math.degrees(math.sqrt(max(P_att[2, 2], 0.0)))
        status = AlignmentStatus.ALIGNED if sig_yaw3 < self.cfg.status_yaw_3sigma_deg else AlignmentStatus.CONVERGING
        return AlignmentEstimate(stamp_s=t_s, C_b_n=C_b_n, v_n=v_n, lat_rad=lat, lon_rad=lon, h_m=h, P_att_n=P_att,
                                 P=P, state_names=self.state_names, status=status,
                                 reason=f"3-sigma yaw {sig_yaw3:.2f} deg")

    def _bias_out(self):
        return None, None


def _flush_plan(n0: int, ends: list[int], mb: int) -> tuple[list[int], list[int]]:
    """The batches ``BatchedEciCore.propagate`` of each segment ``[ends[s-1], ends[s])`` then ``estimate()`` make,
    with ``n0`` rows already buffered (rows ``0 .. n0-1``) and batches of at most ``mb`` rows: the end row of each
    batch, and per batch the segment whose estimate follows it (-1: none)."""
    bounds: list[int] = []
    snap: list[int] = []
    buf, pos = n0, n0
    for s, end in enumerate(ends):
        i = min(end - pos, mb - buf)  # the pending batch completed first
        buf += i
        pos += i
        if buf >= mb:
            bounds.append(pos)
            snap.append(-1)
            buf = 0
        while end - pos >= mb:
            pos += mb
            bounds.append(pos)
            snap.append(-1)
        if pos < end:
            buf += end - pos
            pos = end
        if buf:  # estimate(): flush
            bounds.append(pos)
            snap.append(s)
            buf = 0
        else:
            snap[-1] = s
    return bounds, snap


def bounds_of_snapshots(bounds: list[int], snap: list[int]) -> list[int]:
    """The end row of the batch after which each snapshot is taken, in snapshot order."""
    return [b for b, s in zip(bounds, snap) if s >= 0]


class Liekf(BatchedEciCore):
    """Left-invariant EKF on SE2(3) in ECI, PI-LIEKF Alg. 1 (9 states, IMU biases ignored)."""

    name = "liekf"
    config_class = LiekfConfig
    _n_states = 9
    state_names = ("phi_x", "phi_y", "phi_z", "nu_x", "nu_y", "nu_z", "rho_x", "rho_y", "rho_z")
