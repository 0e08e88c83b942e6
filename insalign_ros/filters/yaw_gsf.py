"""Yaw from horizontal GNSS velocity in seconds: a Gaussian sum of small EKFs over yaw (EKF-GSF).

PX4's EKF-GSF yaw estimator (PX4-Autopilot src/modules/ekf2/EKF/yaw_estimator/EKFGSF_yaw.cpp/.h and
derivation/derivation_yaw_estimator.py) in ENU (yaw from East, counter-clockwise): N EKFs ``[v_E, v_N, yaw]`` started
at yaws spread over the circle, propagated with the specific force rotated into the level frame by an AHRS, fused
with the horizontal GNSS velocity (innovation clipped at 5 sigma), weighted by each EKF's Gaussian density (weights
floored at 1e-5), combined by the weighted circular mean with the variance of the components plus their spread.
docs/yaw_gsf.md says what is PX4's, what differs and why (one shared AHRS, closed-form propagation between
velocities, noise densities, the AHRS's motion corrections and acceleration gate, late velocities, ``valid``), and
what it achieves on simulated and real drives. Imports only numpy and core/ (no ROS).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..core import earth
from ..core.quat import from_C as _quat_from_C, from_rotvec as _quat_from_rotvec, mul as _quat_mul
from ..core.quat import normalize as _quat_normalize, to_C as _quat_to_C
from ..core.types import ImuSample
from ..core.units import G0_M_S2  # the one standard gravity

_J = np.array([[0.0, -1.0], [1.0, 0.0]])  # d/dyaw of Rz2(yaw) = J Rz2(yaw)


@dataclass(frozen=True)
class YawGsfConfig:
    """Parameters of :class:`YawGsf` (units in the names)."""

    n_models: int = 8  #: PX4: 5. With 5 (72 deg apart) an EKF started 36 deg off collapsed its covariance before its yaw (ship: valid with 8 deg errors); 8 did not
    #: white noise on each level-frame velocity axis [m/s/sqrt(s)]: the specific force errors after the tilt
    #: (PX4: 0.2 at 100 Hz in the air, 0.4 on the ground)
    accel_noise_m_s_sqrt_s: float = 0.2
    #: yaw random walk of each model [rad/sqrt(s)] (PX4: 0.01 at 100 Hz)
    yaw_noise_rad_sqrt_s: float = 0.003
    tilt_gain_1_s: float = 0.2  #: AHRS tilt-correction gain (PX4)
    #: AHRS gyro-bias integral gain (PX4: 0.04); learned only in quiet intervals with a small tilt residual, so that
    #: the correction of a large initial tilt error does not wind the integrator up
    gyro_bias_gain_1_s: float = 0.04
    gyro_bias_limit_rad_s: float = 0.05  #: AHRS gyro-bias limit (PX4)
    #: acceleration rejection of the AHRS (not in PX4): the tilt gain is multiplied by exp(-|f_h|^2 / (2 gate^2)),
    #: f_h the specific force (after the vehicle-motion corrections) across the estimated up direction [m/s^2];
    #: 0: off. A tilt error of 1 deg leaves 0.85 of the gain, an unmodelled 1 m/s^2 acceleration 0.004
    tilt_gate_m_s2: float = 0.3
    #: after two consecutive GNSS velocity intervals with no horizontal acceleration (|dv/dt| below tilt_gate_m_s2
    #: + its sigma, and that sigma below tilt_gate_m_s2), the gate widens to this [m/s^2] so that a tilt error the gate would hide is corrected
    tilt_gate_quiet_m_s2: float = 1.5
    #: the first tilt is taken only from a quiet sample: rate below this [rad/s] and |f| within 3 % of g
    tilt_init_max_rate_rad_s: float = 0.05
    #: no quiet sample after this long [s]: the tilt is taken as PX4 does (|f| within 10 % of g)
    tilt_init_timeout_s: float = 10.0
    #: the AHRS tilt's variance: 0.5 deg at a quiet start, 1 deg from a car's compensated specific force, 3 deg when
    #: the velocities cannot tell, 10 deg after the timeout; it grows by this random walk [deg/sqrt(s)] and shrinks
    #: with the tilt gain only in quiet intervals (or with a car's compensation). g * its sigma is added to the
    #: velocity noise: a ship whose tilt the accelerometer cannot find is never confident
    tilt_drift_deg_sqrt_s: float = 0.02
    #: the vehicle moves along forward_axis_b (cars, wheeled robots): the AHRS removes the centripetal and the
    #: longitudinal acceleration from the GNSS speed; False for ships and multicopters
    vehicle_moves_along_forward_axis: bool = True
    forward_axis_b: tuple = (1.0, 0.0, 0.0)
    #: > 0: a wheeled vehicle drives forward along forward_axis_b up to this side-slip [deg]: above
    #: valid_speed_m_s each model also fuses its course (the direction of its velocity) as the forward axis' yaw
    #: (sigma: the slip and 0.2 m/s across). Not in PX4; wrong while reversing faster than valid_speed_m_s;
    #: 0 (off) keeps PX4's pure GSF, safe for every platform
    side_slip_sigma_deg: float = 0.0
    min_vel_sigma_m_s: float = 0.01  #: floor of the velocity sigma (PX4)
    innovation_clip_sigma: float = 5.0  #: PX4 clips the innovation at 5 sigma
    min_weight: float = 1e-5  #: PX4's weight floor
    history_s: float = 3.0  #: how far back a late velocity can be fused [s]
    #: an IMU interval longer than this is a gap (dropped samples): the sample is applied over it and every model's
    #: yaw variance grows by (gap_yaw_rate_rad_s * dt)^2, its velocity variance by (gap_accel_m_s2 * dt)^2
    imu_gap_s: float = 0.25
    #: the AHRS and the models step on the IMU samples averaged over intervals of at least this [s] (rate and
    #: specific force averaged over the interval, as one sample; the GNSS velocities are 1-10 Hz and the vehicle's
    #: dynamics slow next to it): a quarter of the Python cost at 100 Hz and a tenth at 400 Hz. 0: every sample
    step_s: float = 0.04
    gap_yaw_rate_rad_s: float = 0.2
    gap_accel_m_s2: float = 2.0
    valid_speed_m_s: float = 3.0
    valid_motion_s: float = 3.0
    valid_yaw_sigma_deg: float = 2.0
    valid_tilt_sigma_deg: float = 1.0

    def __post_init__(self):
        if self.n_models < 2:
            raise ValueError("n_models must be >= 2")
        for k in ("accel_noise_m_s_sqrt_s", "yaw_noise_rad_sqrt_s", "min_vel_sigma_m_s", "min_weight",
                  "valid_yaw_sigma_deg"):
            if not getattr(self, k) > 0:
                raise ValueError(f"{k} must be > 0")


def _rz2(a):
    """(..., 2, 2) rotation by a [rad] counter-clockwise."""
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


class _Accumulator:
    """Running sums of the shared level-frame delta velocities d_j (2,) since the last sync, for the closed-form
    covariance propagation of every model: with yaw noises w_i (variance q_i) entering after step i,
    ``S = sum d_j``, ``A = sum q_i T_i``, ``M = sum q_i T_i T_i'``, ``W = sum q_i``, ``T_i = sum_{j > i} d_j``;
    ``Qv`` the velocity noise variance per axis. Plain floats: this runs once per IMU sample."""

    __slots__ = ("sx", "sy", "ax", "ay", "mxx", "mxy", "myy", "W", "Qv")

    def __init__(self):
        self.sx = self.sy = self.ax = self.ay = self.mxx = self.mxy = self.myy = self.W = self.Qv = 0.0

    def add(self, dx, dy, q_yaw, q_vel):
        ax, ay, W = self.ax, self.ay, self.W
        self.mxx += 2 * dx * ax + W * dx * dx
        self.mxy += dx * ay + ax * dy + W * dx * dy
        self.myy += 2 * dy * ay + W * dy * dy
        self.ax = ax + W * dx
        self.ay = ay + W * dy
        self.sx += dx
        self.sy += dy
        self.W = W + q_yaw
        self.Qv += q_vel

    def arrays(self):
        """(S (2,), A (2,), M (2, 2))."""
        return (np.array([self.sx, self.sy]), np.array([self.ax, self.ay]),
                np.array([[self.mxx, self.mxy], [self.mxy, self.myy]]))


class YawGsf:
    """Gaussian-sum yaw estimator on horizontal GNSS velocity (see the module docstring).

    Feed IMU samples in time order with :meth:`propagate` (an :class:`ImuSample`) or :meth:`propagate_arrays`, and
    GNSS velocities with :meth:`update_velocity` (ENU [m/s] and its covariance). Read :attr:`yaw_rad` (of the body
    x axis, from East counter-clockwise), :attr:`yaw_var_rad2` and :attr:`valid`.
    """

    def __init__(self, config: YawGsfConfig | None = None):
        self.cfg = config or YawGsfConfig()
        fwd = np.asarray(self.cfg.forward_axis_b, float)
        self._fwd_b = tuple(float(x) for x in fwd / np.linalg.norm(fwd))
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self):
        """Back to the state before any data (the AHRS keeps nothing either)."""
        N = self.cfg.n_models
        self._t_s = None
        self._pend = None  # IMU samples not yet stepped: [last stamp, dt, sum w dt (3), sum f dt (3)]
        self._q = None  # shared AHRS attitude body -> ENU (w, x, y, z); None until the tilt is aligned
        self._b_g = [0.0, 0.0, 0.0]
        self._f_lpf = None
        self._speed_m_s, self._acc_long_m_s2 = 0.0, 0.0
        self._last_vel = None  # (stamp, speed, var, v2, R2) of the last velocity
        self._quiet = 0  # consecutive velocity intervals without horizontal acceleration
        self._init_wait_s, self._dt_last, self._tilt_var = 0.0, 0.0, 0.0
        self._level_given = False  # the tilt comes from set_level (the AHRS integrates the gyro between them)
        self._along_used = False  # the longitudinal acceleration comes from a precise velocity interval
        self._kin_sigma_m_s2 = 0.0  # sigma of the last interval's horizontal acceleration from the velocities
        self._started = False
        self._x = np.zeros((N, 2))
        self._delta = np.zeros(N)  # yaw offset of each model from the shared AHRS [rad]
        self._P = np.zeros((N, 3, 3))
        self._w = np.full(N, 1.0 / N)
        self._acc = _Accumulator()
        self._hist = deque()  # (t_s, cumulative shared level-frame delta velocity (2-tuple))
        self._cum = (0.0, 0.0)
        self._yaw, self._var, self._motion_s = float("nan"), float("inf"), 0.0
        self.n_updates = self.n_restarts = 0
        self.last_nis = np.full(N, np.nan)

    @property
    def started(self) -> bool:
        """True once velocities are being fused."""
        return self._started

    @property
    def yaw_rad(self) -> float:
        """Yaw of the body x axis [rad], ENU, from East counter-clockwise, in (-pi, pi]; nan before the fusion."""
        if not self._started:
            return float("nan")
        return float(_wrap(self._yaw + self._shared_yaw()))

    @property
    def yaw_var_rad2(self) -> float:
        """Variance of :attr:`yaw_rad` [rad^2] (inf before the fusion)."""
        return float(self._var) if self._started else float("inf")

    @property
    def valid(self) -> bool:
        """Fusion started, moved >= valid_motion_s at >= valid_speed_m_s, yaw sigma <= valid_yaw_sigma_deg, and the
        AHRS tilt sigma <= valid_tilt_sigma_deg (a tilt error biases the yaw by g dtilt / a; the course constraint
        measures the yaw without the tilt)."""
        return self.confident(self.cfg.valid_yaw_sigma_deg)

    def confident(self, max_sigma_deg: float) -> bool:
        """``valid`` with the yaw 1-sigma bound ``max_sigma_deg`` (session/yaw_seed.py seeds with a looser one)."""
        c = self.cfg
        return bool(self._started and self._motion_s >= c.valid_motion_s and self._var <= math.radians(max_sigma_deg) ** 2
                    and (self._tilt_var <= math.radians(c.valid_tilt_sigma_deg) ** 2 or c.side_slip_sigma_deg > 0))

    @property
    def weights(self) -> np.ndarray:  # the models' weights, for logs
        return self._w.copy()

    def _shared_yaw(self) -> float:
        if self._q is None:
            return 0.0
        C = _quat_to_C(self._q)
        return math.atan2(C[1, 0], C[0, 0])

    def set_level(self, roll_rad: float, pitch_rad: float, tilt_var_rad2: float) -> None:
        """The tilt (roll, pitch of body -> ENU) and its variance [rad^2] from elsewhere (the session's core): they
        replace the AHRS tilt, and from now on the AHRS only integrates the gyro between calls (no accelerometer
        correction: on a ship in waves it never finds a quiet moment). The AHRS yaw is kept."""
        yaw = self._shared_yaw()
        self._q = _quat_from_C(earth.C_b_n_from_rpy(roll_rad, pitch_rad, yaw))
        self._tilt_var = float(tilt_var_rad2)
        self._level_given = True

    @property
    def tilt_var_rad2(self) -> float:
        """Variance of the AHRS tilt [rad^2] (inf before it is aligned)."""
        return float(self._tilt_var) if self._q is not None else float("inf")

    # ------------------------------------------------------------------ IMU
    def propagate(self, sample: ImuSample, C_b_n_level: np.ndarray | None = None):
        """One IMU sample (average rate and specific force over the interval ending at its stamp).

        C_b_n_level: optional body -> ENU attitude whose roll and pitch replace the AHRS tilt (its yaw is ignored).
        """
        om, f = np.asarray(sample.omega_ib_b, float), np.asarray(sample.f_ib_b, float)
        t = float(sample.stamp_s)
        if om.shape == (3,) and f.shape == (3,) and math.isfinite(t) and np.all(np.isfinite(om)) \
                and np.all(np.isfinite(f)):
            if C_b_n_level is None:
                self._feed(t, *om.tolist(), *f.tolist())
            else:
                self._flush()
                self._step(t, *om.tolist(), *f.tolist(), C_b_n_level)

    def propagate_arrays(self, t_s, omega_ib_b, f_ib_b, C_b_n_level=None):
        """Many IMU samples: t_s (n,), omega_ib_b (n, 3) [rad/s], f_ib_b (n, 3) [m/s^2], C_b_n_level (n, 3, 3)."""
        t_s, om, f = np.asarray(t_s, float), np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float)
        ok = (np.isfinite(t_s) & np.all(np.isfinite(om), 1) & np.all(np.isfinite(f), 1)).tolist()
        rows = np.column_stack([t_s, om, f]).tolist()
        if C_b_n_level is not None:
            self._flush()
            for k, r in enumerate(rows):
                if ok[k]:
                    self._step(*r, C_b_n_level[k])
            return
        feed = self._feed
        for k, r in enumerate(rows):
            if ok[k]:
                feed(*r)

    def _feed(self, t, wx, wy, wz, fx, fy, fz):
        """One IMU sample into the average of the current step (config ``step_s``); the step is taken when it spans
        step_s. A sample after a gap (imu_gap_s) is stepped alone, as before the averaging."""
        pend = self._pend
        last = self._t_s if pend is None else pend[0]
        if last is None or t <= last:
            if last is None:
                self._step(t, wx, wy, wz, fx, fy, fz, None)
            return
        dt = t - last
        if dt > self.cfg.imu_gap_s:
            self._flush()
            self._step(t, wx, wy, wz, fx, fy, fz, None)
            return
        if pend is None:
            self._pend = pend = [t, dt, wx * dt, wy * dt, wz * dt, fx * dt, fy * dt, fz * dt]
        else:
            pend[0] = t
            pend[1] += dt
            pend[2] += wx * dt
            pend[3] += wy * dt
            pend[4] += wz * dt
            pend[5] += fx * dt
            pend[6] += fy * dt
            pend[7] += fz * dt
        if t - self._t_s >= self.cfg.step_s - 1e-9:
            self._flush()

    def _flush(self):
        """Step the averaged pending samples (if any) as one sample at the last one's stamp."""
        pend, self._pend = self._pend, None
        if pend is not None:
            k = 1.0 / pend[1]
            self._step(pend[0], pend[2] * k, pend[3] * k, pend[4] * k, pend[5] * k, pend[6] * k, pend[7] * k, None)

    def _step(self, t, wx, wy, wz, fx, fy, fz, C_level):
        if self._t_s is None or t <= self._t_s:
            if self._t_s is None:
                self._t_s = t
                self._f_lpf = [fx, fy, fz]
            return
        dt = t - self._t_s
        self._t_s = t
        self._dt_last = dt
        c = self.cfg
        gap = dt > c.imu_gap_s  # the sample is applied over the whole gap; the models' variances grow to cover it
        coef = min(10.0 * dt * c.tilt_gain_1_s, 1.0)
        fl = self._f_lpf
        fl[0] += coef * (fx - fl[0])
        fl[1] += coef * (fy - fl[1])
        fl[2] += coef * (fz - fl[2])
        if C_level is not None:
            self._level_from_given(np.asarray(C_level, float), wy, wz, dt)
        else:
            if self._q is None:
                if not self._tilt_init(wx, wy, wz, fx, fy, fz):
                    return
                return
            self._ahrs(wx, wy, wz, dt)
        qw, qx, qy, qz = self._q
        # the first two rows of C_b_n applied to f dt: the shared level-frame delta velocity
        dx = ((1 - 2 * (qy * qy + qz * qz)) * fx + 2 * (qx * qy - qw * qz) * fy + 2 * (qx * qz + qw * qy) * fz) * dt
        dy = (2 * (qx * qy + qw * qz) * fx + (1 - 2 * (qx * qx + qz * qz)) * fy + 2 * (qy * qz - qw * qx) * fz) * dt
        cum = self._cum
        cum = (cum[0] + dx, cum[1] + dy)
        self._cum = cum
        hist = self._hist
        hist.append((t, cum))
        while hist[0][0] < t - c.history_s:
            hist.popleft()
        if self._started:
            # a tilt error is a horizontal specific-force bias g dtilt: as velocity noise over the 1-s GNSS interval
            q_yaw = c.yaw_noise_rad_sqrt_s ** 2 * dt
            q_vel = (c.accel_noise_m_s_sqrt_s ** 2 + G0_M_S2 ** 2 * self._tilt_var * 1.0) * dt
            if gap:
                q_yaw += (c.gap_yaw_rate_rad_s * dt) ** 2
                q_vel += (c.gap_accel_m_s2 * dt) ** 2
            self._acc.add(dx, dy, q_yaw, q_vel)

    def _level_from_given(self, C_level, wy, wz, dt):
        r, p, _ = earth.rpy_from_C_b_n(C_level)
        if self._q is None:
            yaw = 0.0
        else:  # integrate the Euler yaw rate of the given tilt
            yaw = self._shared_yaw() + (math.sin(r) * wy + math.cos(r) * wz) / max(math.cos(p), 1e-3) * dt
        self._q = _quat_from_C(earth.C_b_n_from_rpy(r, p, yaw))

    def _motion_corrected(self, wx, wy, wz, ax, ay, az):
        """The specific force minus omega x v_b and the longitudinal acceleration (vehicles along forward_axis_b)."""
        if self.cfg.vehicle_moves_along_forward_axis:
            e0, e1, e2 = self._fwd_b
            V, al = self._speed_m_s, self._acc_long_m_s2
            ax -= V * (wy * e2 - wz * e1) + al * e0
            ay -= V * (wz * e0 - wx * e2) + al * e1
            az -= V * (wx * e1 - wy * e0) + al * e2
        return ax, ay, az

    def _tilt_init(self, wx, wy, wz, fx, fy, fz):
        """The first tilt, from a quiet sample: after a GNSS velocity interval without horizontal acceleration (or
        one too noisy to tell), the rate below tilt_init_max_rate_rad_s and |f| (sample and low-passed, corrected
        for the vehicle's motion) within 3 % of g."""
        c = self.cfg
        compensated = c.vehicle_moves_along_forward_axis and self._along_used  # the car's whole acceleration
        self._init_wait_s += self._dt_last
        late = self._init_wait_s > c.tilt_init_timeout_s  # then PX4's test: |f| within 10 % of g
        if not late and (self._last_vel is None or not (self._quiet >= 1 or compensated
                                                        or self._kin_sigma_m_s2 > c.tilt_gate_m_s2)):
            return False
        ax, ay, az = self._motion_corrected(wx, wy, wz, *self._f_lpf)
        sx, sy, sz = self._motion_corrected(wx, wy, wz, fx, fy, fz)
        fn, ln = math.sqrt(sx * sx + sy * sy + sz * sz), math.sqrt(ax * ax + ay * ay + az * az)
        tol = 0.1 if late else 0.03
        if not (abs(fn / G0_M_S2 - 1.0) < tol and abs(ln / G0_M_S2 - 1.0) < tol
                and (late or wx * wx + wy * wy + wz * wz < c.tilt_init_max_rate_rad_s ** 2)):
            return False
        r, p, _ = earth.level_from_specific_force(np.array([[ax, ay, az]]), float(ln))
        self._q = _quat_from_C(earth.C_b_n_from_rpy(r, p, 0.0))
        self._tilt_var = math.radians(10.0 if late else 0.5 if self._quiet >= 1 else 1.0 if compensated else 3.0) ** 2
        return True

    def _ahrs(self, wx, wy, wz, dt):
        c = self.cfg
        if self._level_given:  # the tilt comes from set_level: the gyro between calls, the variance grows
            self._tilt_var += math.radians(c.tilt_drift_deg_sqrt_s) ** 2 * dt
            self._q = _quat_normalize(_quat_mul(self._q, _quat_from_rotvec(wx * dt, wy * dt, wz * dt)))
            return
        b = self._b_g
        wx, wy, wz = wx - b[0], wy - b[1], wz - b[2]
        qw, qx, qy, qz = self._q
        ux, uy, uz = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)  # ENU up in body
        ax, ay, az = self._motion_corrected(wx, wy, wz, *self._f_lpf)
        an = math.sqrt(ax * ax + ay * ay + az * az)
        gain = c.tilt_gain_1_s * (1.0 - min(2.0 * abs(an - G0_M_S2) / G0_M_S2, 1.0)) ** 2
        if c.tilt_gate_m_s2 > 0:  # acceleration rejection: the part of f across the estimated up direction
            au = ax * ux + ay * uy + az * uz
            hx, hy, hz = ax - au * ux, ay - au * uy, az - au * uz
            h2 = hx * hx + hy * hy + hz * hz
            gate = c.tilt_gate_quiet_m_s2 if self._quiet >= 2 else c.tilt_gate_m_s2
            gain *= math.exp(-0.5 * h2 / gate ** 2)
            learn = h2 < (2.0 * c.tilt_gate_m_s2) ** 2 and self._quiet >= 1
        else:
            learn = True
        if an > 1e-6 and gain > 0:
            k = gain / an
            cx, cy, cz = (ay * uz - az * uy) * k, (az * ux - ax * uz) * k, (ax * uy - ay * ux) * k
        else:
            cx = cy = cz = 0.0
        # the tilt's variance: grows with the gyro, shrinks only where gravity is known to be the reference
        self._tilt_var += math.radians(c.tilt_drift_deg_sqrt_s) ** 2 * dt
        if self._quiet >= 1 or (c.vehicle_moves_along_forward_axis and self._along_used):
            self._tilt_var = max(self._tilt_var * (1.0 - 2.0 * gain * dt), math.radians(0.2) ** 2)
        if learn and wx * wx + wy * wy + wz * wz < math.radians(10.0) ** 2:
            lim, kb = c.gyro_bias_limit_rad_s, c.gyro_bias_gain_1_s * dt
            self._b_g = [min(max(b[0] - cx * kb, -lim), lim), min(max(b[1] - cy * kb, -lim), lim),
                         min(max(b[2] - cz * kb, -lim), lim)]
        self._q = _quat_normalize(_quat_mul(self._q, _quat_from_rotvec((wx + cx) * dt, (wy + cy) * dt,
                                                                       (wz + cz) * dt)))

    # ------------------------------------------------------------------ GNSS velocity
    def _sync(self):
        """Apply the accumulated propagation to every model (closed form of PX4's per-step F P F' + Q)."""
        acc = self._acc
        S, A, M = acc.arrays()
        R = _rz2(self._delta)  # (N, 2, 2)
        JR = _J @ R
        self._x += R @ S
        F = np.tile(np.eye(3), (self.cfg.n_models, 1, 1))
        F[:, :2, 2] = JR @ S
        P = F @ self._P @ np.transpose(F, (0, 2, 1))
        P[:, :2, :2] += acc.Qv * np.eye(2) + JR @ M @ np.transpose(JR, (0, 2, 1))
        cross = JR @ A
        P[:, :2, 2] += cross
        P[:, 2, :2] += cross
        P[:, 2, 2] += acc.W
        self._P = 0.5 * (P + np.transpose(P, (0, 2, 1)))
        self._acc = _Accumulator()

    def _cum_at(self, stamp):
        """Cumulative shared level-frame delta velocity at stamp (linear between samples), or None if too old."""
        h = self._hist
        if not h or stamp >= h[-1][0]:
            return np.array(self._cum)
        if stamp < h[0][0]:
            return None
        ts = [e[0] for e in h]
        i = int(np.searchsorted(ts, stamp))
        t0, c0 = h[i - 1]
        t1, c1 = h[i]
        return np.array(c0) + (np.array(c1) - np.array(c0)) * (stamp - t0) / (t1 - t0)

    def _initialise(self, v2, R2):
        c = self.cfg
        N = c.n_models
        inc = 2.0 * math.pi / N
        yaw0 = -math.pi + inc * (0.5 + np.arange(N))
        self._delta = _wrap(yaw0 - self._shared_yaw())
        self._x = np.tile(v2, (N, 1))
        self._P = np.zeros((N, 3, 3))
        self._P[:, :2, :2] = R2
        self._P[:, 2, 2] = (0.5 * inc) ** 2
        self._w = np.full(N, 1.0 / N)
        self._acc = _Accumulator()
        self._yaw, self._var = 0.0, (math.pi / 2) ** 2
        self._started = True

    def update_velocity(self, stamp_s: float, v_n, R_n) -> bool:
        """Fuse a GNSS velocity: v_n (3,) ENU [m/s] (the vertical is ignored), R_n (3, 3) its covariance [m^2/s^2].
        A stamp older than the last IMU sample (up to history_s) is fused against the models moved back to it.
        Returns False when the sample is rejected (non-finite, too old, no tilt yet)."""
        v_n, R_n = np.asarray(v_n, float), np.asarray(R_n, float)
        if v_n.shape != (3,) or R_n.shape != (3, 3) or not (np.all(np.isfinite(v_n)) and np.all(np.isfinite(R_n))
                                                             and math.isfinite(stamp_s)):
            return False
        c = self.cfg
        v2 = v_n[:2]
        R2 = 0.5 * (R_n[:2, :2] + R_n[:2, :2].T)
        if np.linalg.eigvalsh(R2)[0] < 0:  # not a covariance
            return False
        R2 = R2 + np.diag(np.maximum(c.min_vel_sigma_m_s ** 2 - np.diag(R2), 0.0))
        self._flush()  # the samples up to now, stepped
        self._track_speed(float(stamp_s), v2, R2)
        if self._q is None or self._t_s is None:
            return False
        cum = self._cum_at(float(stamp_s))
        if cum is None:
            return False
        if not self._started:
            self._initialise(v2, R2)
            return True
        self._sync()
        D = np.array(self._cum) - cum  # shared level-frame delta velocity from the stamp to now
        N = c.n_models
        RD = _rz2(self._delta) @ D  # (N, 2): the delta velocity in each model's frame
        H = np.zeros((N, 2, 3))
        H[:, 0, 0] = H[:, 1, 1] = 1.0
        H[:, :, 2] = -(RD @ _J.T)
        dens = self._kalman(np.ones(N, bool), v2 - (self._x - RD), H, np.broadcast_to(R2, (N, 2, 2)))
        if c.side_slip_sigma_deg > 0:  # a wheeled vehicle's course is its forward axis' yaw, now
            psi_s, fwd = self._shared_yaw(), math.atan2(self._fwd_b[1], self._fwd_b[0])
            vx, vy = self._x[:, 0], self._x[:, 1]
            v_sq = vx * vx + vy * vy
            on = v_sq >= max(c.valid_speed_m_s ** 2, 9.0 * float(np.max(np.diag(R2))))
            if on.any():
                vs = np.where(on, v_sq, 1.0)
                Hc = np.stack([-vy / vs, vx / vs, -np.ones(N)], -1)[:, None, :]
                r_c = math.radians(c.side_slip_sigma_deg) ** 2 + 0.04 / vs  # slip, 0.2 m/s across
                y = _wrap(self._delta + psi_s + fwd - np.arctan2(vy, vx))  # 0 - h(x)
                dens = dens * self._kalman(on, y[:, None], Hc, r_c[:, None, None])
        w = self._w * dens
        if np.all(np.isfinite(w)) and w.sum() > 0:  # PX4 floors before normalizing; the floor is relative here
            w = np.maximum(w / w.sum(), c.min_weight)
            self._w = w / w.sum()
        self._combine()
        self.n_updates += 1
        if not (self._var > 0 and math.isfinite(self._var)):
            self.n_restarts += 1
            self._initialise(v2, R2)
        return True

    def _kalman(self, on, y, H, Rm):
        """Update the models ``on`` (N,) bool, all at once, with the innovations y = z - h(x) (N, m), H (N, m, 3), Rm
        (N, m, m) (innovation clipped at innovation_clip_sigma, Joseph form); returns each model's Gaussian density
        of its (clipped) innovation (nan if S is not positive; 1 for the models not ``on``)."""
        c = self.cfg
        P = self._P
        Ht = np.transpose(H, (0, 2, 1))
        S = H @ P @ Ht + Rm
        det = np.linalg.det(S)
        ok = on & (det > 0)
        dens = np.where(on, np.nan, 1.0)
        if not ok.any():
            return dens
        S = np.where(ok[:, None, None], S, np.eye(S.shape[1]))
        Si = np.linalg.inv(S)
        nis = np.einsum("ni,nij,nj->n", y, Si, y)
        clip2 = c.innovation_clip_sigma ** 2
        big = nis > clip2
        y = np.where(big[:, None], y * np.sqrt(clip2 / np.where(big, nis, 1.0))[:, None], y)
        nis = np.minimum(nis, clip2)
        K = P @ Ht @ Si
        dx = (K @ y[:, :, None])[:, :, 0]
        IKH = np.eye(3) - K @ H
        Pn = IKH @ P @ np.transpose(IKH, (0, 2, 1)) + K @ Rm @ np.transpose(K, (0, 2, 1))
        m = ok[:, None, None]
        self._P = np.where(m, 0.5 * (Pn + np.transpose(Pn, (0, 2, 1))), P)
        self._x = np.where(ok[:, None], self._x + dx[:, :2], self._x)
        self._delta = np.where(ok, _wrap(self._delta + dx[:, 2]), self._delta)
        self.last_nis = np.where(ok, nis, self.last_nis)
        m_dim = y.shape[1]
        dens[ok] = (np.exp(-0.5 * nis) / ((2.0 * math.pi) ** (0.5 * m_dim) * np.sqrt(np.where(ok, det, 1.0))))[ok]
        return dens

    def _track_speed(self, stamp, v2, R2):
        """Speed and longitudinal acceleration for the AHRS's motion corrections, the quiet-interval count of the
        tilt gate, and the motion time of ``valid``. A speed below 3 sigma counts as zero; the acceleration (the
        rate of the speed) is used only when its sigma is below tilt_gate_m_s2 (velocities from fix differences are
        too noisy: the gate then does the work)."""
        c = self.cfg
        speed = float(math.hypot(v2[0], v2[1]))
        var = float(np.linalg.eigvalsh(R2)[-1])
        significant = speed >= 3.0 * math.sqrt(var)
        lv = self._last_vel
        if lv is not None:
            dt = stamp - lv[0]
            if 0 < dt < 2.5:
                sig_a = math.sqrt(var + lv[2]) / dt
                use = sig_a < max(c.tilt_gate_m_s2, 1e-9) and significant
                self._acc_long_m_s2 = (speed - lv[1]) / dt if use else 0.0
                self._along_used = use
                a_kin = float(np.linalg.norm(v2 - lv[3])) / dt
                sig_k = math.sqrt(float(np.trace(R2 + lv[4]))) / dt
                quiet = sig_k <= c.tilt_gate_m_s2 and a_kin < c.tilt_gate_m_s2 + sig_k
                self._quiet = self._quiet + 1 if quiet else 0
                self._kin_sigma_m_s2 = sig_k
                if significant and speed >= c.valid_speed_m_s and self._started:
                    self._motion_s += dt
            else:
                self._acc_long_m_s2, self._quiet, self._along_used = 0.0, 0, False
        self._last_vel = (stamp, speed, var, v2.copy(), R2.copy())
        self._speed_m_s = speed if significant else 0.0

    def _combine(self):
        yaws = self._delta  # offsets; the common shared yaw is added on output
        s = float(np.sum(self._w * np.sin(yaws)))
        co = float(np.sum(self._w * np.cos(yaws)))
        self._yaw = math.atan2(s, co)
        dy = _wrap(yaws - self._yaw)
        self._var = float(np.sum(self._w * (self._P[:, 2, 2] + dy ** 2)))

