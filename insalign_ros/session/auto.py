"""``core: auto`` (issue 14): from ignition to aligned in one core, parked first, then driving.

A state machine around two cores and the motion detector (session/motion.py), seen by the session as one
:class:`~insalign_ros.filters.base.AlignmentCore` (registered as ``auto``):

* **waiting for data**: the session's own status until it has a position and 1 s of accelerometer data;
* **static, levelling**: a zero-velocity core (``static_core``, default pkf, tuned from the IMU grade) started by
  the session's sensors initialisation (level from the accelerometers, heading unknown: its azimuth bootstrap),
  zero-velocity updates scheduled by the session (``accepts`` has no GNSS position in the static states);
* **static, fine**: the level 1-sigma is within 2x the b_acc/g floor. Heading: gyrocompassing only where the IMU
  grade's azimuth floor eps/(omega_ie cos lat) is below ``heading_floor_max_deg`` at this latitude; otherwise the
  status is WAITING_FOR_MOTION and the reason says "heading needs motion (floor X deg)";
* **starting in motion**: moving from the start (no snapshot at rest; the GNSS speed or the IMU says so), until
  three fixes within 3 s give the in-motion core its velocity and level window;
* **in motion**: when the motion detector declares motion, the in-motion core (``motion_core``, default iekf) is
  initialised from a snapshot of the static solution taken before the onset of the motion (level, heading if
  trusted, their 3x3 covariance, the position, zero velocity, and the gyro bias measured over the rest window:
  :func:`gyro_bias_from_rest`) and the buffered IMU samples since the snapshot are replayed into it; a bank of
  ``unknown_heading_hypotheses`` yaw hypotheses when the heading is not trusted. From then on ``accepts`` is the
  in-motion core's: the session fuses the fixes, gates them and stops its zero-velocity updates;
* **stopped**: the detector declares rest again: the in-motion core keeps running (no reset) and takes a
  zero-velocity constraint at 10 Hz as a position hold (a pseudo-fix at the position where it stopped, 1-sigma
  ``stop_hold_sigma_m``; the in-motion cores have no velocity update) besides the real fixes, and a
  zero-angular-rate update per 1-s gyro mean (the z gyro bias is observable at rest);
* **aligned**: the session's flag (one meaning of "aligned").

docs/session.md ("core: auto") gives the decisions and the measured behaviour.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..core import earth
from ..core.types import GnssFix
from ..filters import imu_grade, registry
from ..filters.base import AlignmentCore, AlignmentEstimate, AlignmentStatus, UpdateResult
from ..filters.hypotheses import YawHypothesisBank
from ..filters.measurements import GnssPosition, GnssVelocity, GyroBiasPrior, ZeroAngularRate, ZeroVelocity
from .auto_config import AutoConfig, D2R
from .config import SessionConfig
from .fix_line import sequence_jump, velocities_agree
from .motion import FixNoise, MotionConfig, MotionDetector, rate_hz_from_intervals
from .rest import (REST_BLOCK_S, _BlockMean, block_variance, gyro_bias_from_rest, rest_rate_mean,
                   static_heading_support, zupt_nis_mean)


#: hand-over without a snapshot at rest (moving from the start): the vehicle acceleration [m/s^2] assumed when the
#: fixes do not give it (the session's init_accel_m_s2)
NO_REST_ACC_M_S2 = 1.0
#: ... the level comes from the IMU window over which the fixes' velocity change is known when they span this [s]
LEVEL_WINDOW_MIN_S = 2.0
#: in motion above this speed [m/s] the motion detector is not run (checked every SPEED_CHECK_PERIOD_S [s])
DETECTOR_SKIP_SPEED_M_S = 3.0
SPEED_CHECK_PERIOD_S = 0.5
#: the GNSS speed for the motion detector is a position difference over at least this long [s]
GNSS_SPEED_BASE_S = 0.9
#: the motion detector is built once this many IMU intervals give the rate (1 s at 10 Hz)
DETECTOR_MIN_INTERVALS = 10
#: a rest window of fewer 1-s gyro blocks than this takes at least the grade's ARW^2 / T as the variance of its mean
SHORT_REST_BLOCKS = 10
FIX_NOISE_FLOOR_M = 0.1  #: the fixes' own noise (motion.FixNoise) is never below this [m] (a parked receiver drifts)
#: state names (``AutoCore.state``), in the order a parked-then-driving run passes through them
STATES = ("static, levelling", "static, fine", "starting in motion", "in motion", "stopped")


class AutoCore(AlignmentCore):
    """The ``auto`` state machine (module docstring). ``state`` is one of :data:`STATES`; ``transitions`` lists
    (stamp [s], state, reason) at every change."""

    name = "auto"
    own_models = frozenset({ZeroVelocity})  # its static core fuses it; after the hand-over: the in-motion core's set

    def __init__(self, cfg: AutoConfig):
        self.cfg = cfg
        self.static: AlignmentCore | None = None
        self.motion: AlignmentCore | None = None
        self.state, self.reason = "waiting for data", ""
        self.transitions: list[tuple[float, str, str]] = []
        self.detector: MotionDetector | None = None
        self._dts: list[float] = []
        self._early_speeds: deque = deque(maxlen=16)  # GNSS speeds before the detector exists (_push_speed)
        self._t: float | None = None
        self._t_start = -math.inf  # the stamp of initialize (the fixes before it were shown, not its own)
        self.hist: deque = deque()  # (t, omega, f): the IMU samples the hand-over may replay
        #: (t, AlignmentEstimate, number of rest blocks done) of the static core at rest
        self.snaps: deque = deque()
        self._blocks: list[np.ndarray] = []  # REST_BLOCK_S means of the gyro rate since the static core started
        self._block = _BlockMean()  # the block being summed (at rest before the hand-over, then at stops)
        self._stop_blocks: list[np.ndarray] = []  # REST_BLOCK_S gyro means of the current stop
        self._stop_applied = 0  # ... of which fused (zero-angular-rate updates)
        self.gyro_bias_prior: tuple[np.ndarray, np.ndarray] | None = None  # (b_g_b, P) given at the hand-over
        self.heading_trusted, self.heading_floor_deg, self.grade_allows_heading = False, math.nan, False
        self.sig_p, self.lat = 1.0, 0.0
        self._hold_p_e: np.ndarray | None = None
        #: driving faster than DETECTOR_SKIP_SPEED_M_S (the in-motion core's speed, checked every
        #: SPEED_CHECK_PERIOD_S): the motion detector is not fed (half of the auto core's time); below, it restarts
        #: its windows (a stop is declared only under stop_speed_max_m_s anyway)
        self.detector_skipped, self._next_speed_check_t = False, -math.inf
        self._fixes: deque = deque()  # (t, p_e, R_e) of the fixes seen while static (GNSS speed for the detector)
        self._level_fixes: deque = deque(maxlen=8)  # ... the last ones (the velocity change over the level window)
        self._vels: deque = deque(maxlen=16)  # (t, v_n, R_n) of the GNSS velocities seen while static
        self._fix_noise = FixNoise()  # the fixes' own noise (the walking-speed veto's sigma)
        self._next_hold_t, self._zupt_support = -math.inf, [0, 0]  # zero-velocity updates asked, accepted while static
        self._zupt_nis: deque = deque(maxlen=200)  # NIS per degree of freedom of the accepted ones
        self._nis_mean: float | None = None  # rest.zupt_nis_mean of them (None: to compute; read per output)
        self.counters = {"handovers": 0, "stops": 0, "stop_holds": 0, "zupt_rejected_moving": 0, "zero_rate_updates": 0,
                         "zero_rate_rejected": 0}
        self.initial_sigmas = cfg.initial_sigmas

    # ------------------------------------------------------------------ life cycle
    def initialize(self, stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m) -> None:
        cfg = self.cfg
        self.static = registry.make_core(cfg.static_core, cfg.static_params())
        self.static.initialize(stamp_s, lat_rad, lon_rad, h_m, C_b_n, v_n, P_att_n, sigma_v_m_s, sigma_p_m)
        self.sig_p, self.lat, self._t = float(sigma_p_m), float(lat_rad), float(stamp_s)
        self._t_start = float(stamp_s)
        floor = cfg.azimuth_floor_rad(lat_rad) / D2R
        self.heading_floor_deg = floor
        self.grade_allows_heading = floor <= cfg.heading_floor_max_deg
        self._set_state(stamp_s, "static, levelling", "level from the accelerometers")

    @property
    def initialized(self) -> bool:
        return self.static is not None

    @property
    def active(self) -> AlignmentCore:
        return self.motion if self.motion is not None else self.static

    @property
    def P(self):
        return None if self.active is None else self.active.P

    @property
    def busy(self) -> bool:
        return self.active is not None and self.active.busy

    def close(self) -> None:
        for c in (self.static, self.motion):
            if c is not None:
                c.close()

    def flush(self) -> None:
        if self.active is not None:
            self.active.flush()

    def inflate_navigation(self, var_att_rad2: float, var_v_m2_s2: float, var_p_m2: float = 0.0,
                           var_bg_rad2_s2: float = 0.0, var_ba_m2_s4: float = 0.0) -> None:
        self.active.inflate_navigation(var_att_rad2, var_v_m2_s2, var_p_m2, var_bg_rad2_s2, var_ba_m2_s4)

    def _set_state(self, t: float, state: str, reason: str) -> None:
        self.reason = reason
        if state != self.state:
            self.state = state
            self.transitions.append((float(t), state, reason))

    # ------------------------------------------------------------------ data
    def _detect(self, t: float, w, f):
        """The motion decision after this sample (the detector is built once the IMU rate is known)."""
        if self.detector is None:
            if self._t is not None and t > self._t:
                self._dts.append(t - self._t)
            if len(self._dts) < DETECTOR_MIN_INTERVALS:
                return None
            self.detector = MotionDetector(MotionConfig.from_dict(dict(
                rate_hz=rate_hz_from_intervals(self._dts), gyro_arw_deg_sqrt_h=max(self.cfg.gyro_arw_deg_sqrt_h, 1e-4),
                acc_vrw_m_s_sqrt_h=max(self.cfg.acc_vrw_m_s_sqrt_h, 1e-4))))
            for args in self._early_speeds:  # the GNSS speeds seen before (a car moving at power-on)
                self.detector.push_gnss_speed(*args)
        return self.detector.push_imu(t, w, f)

    def _push_speed(self, *args) -> None:
        """A GNSS speed (``MotionDetector.push_gnss_speed``'s arguments) to the detector, kept until it exists; until
        then one above walking speed and the detector's GNSS bound is said in the state (not decided: at 10 Hz the
        detector exists 1 s after the start)."""
        if self.detector is None:
            self._early_speeds.append(args)
            mc = MotionConfig()
            if self.state == "static, levelling" and args[1] > max(mc.walk_speed_m_s, mc.thresholds()[
                    "gnss_speed_per_sigma"] * args[2]):
                self._set_state(args[0], "starting in motion", f"GNSS speed {args[1]:.1f} m/s (detector filling)")
        else:
            self.detector.push_gnss_speed(*args)

    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        if backward:
            raise NotImplementedError("auto does not support backward propagation")
        self._estimates_along(t_s, omega_ib_b, f_ib_b, ())

    def _estimates_along(self, t_s, omega_ib_b, f_ib_b, ends) -> list[AlignmentEstimate]:
        """Row by row: the motion decision and the hand-over fall between two samples; the estimate after each row
        in ``ends``, only the first while parked or after a hand-over (the rows after it are left to the caller:
        the session's events at each output follow ``accepts``). Driving with the detector skipped, the rows up to the next speed check go to the in-motion core
        in one block (with the estimates wanted in it: its ``propagate(..., estimates_at)``)."""
        T, W, F = np.asarray(t_s, float), np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float)
        out, k, n, e, ends, m0 = [], 0, T.shape[0], 0, list(ends), self.motion
        while k < n:
            if self.motion is not None and self.state == "in motion" and self.detector_skipped:
                # driving, the detector skipped: nothing is decided before the next speed check; one block
                j = k + int(np.searchsorted(T[k:], self._next_speed_check_t, side="left"))
                if j > k:
                    q = e
                    while q < len(ends) and ends[q] < j:
                        q += 1
                    j = ends[q - 1] + 1 if q > e else j
                    self._remember(T[k:j], W[k:j], F[k:j])
                    ests = self.motion.propagate(T[k:j], W[k:j], F[k:j], estimates_at=[x - k for x in ends[e:q]])
                    out += [self._dressed(est) for est in ests]
                    k, e = j, q
                    continue
            stop = ends[e] + 1 if e < len(ends) else n
            j = k
            if self.motion is None and self.detector is not None:
                # static: the rows the detector takes at once, up to the one that declares motion
                j = k + self.detector.push_imu_arrays(T[k:stop], W[k:stop], F[k:stop], until_moving=True)
                if j > k:
                    self._static_rows(T[k:j], W[k:j], F[k:j], self.detector.decision)
            if j == k:
                self._row(T[k:k + 1], W[k:k + 1], F[k:k + 1])
                j = k + 1
            k = j
            if k == stop and e < len(ends):
                out.append(self.estimate())
                e += 1
                if self.motion is None or self.motion is not m0:  # parked, a hand-over may change what the
                    return out  # session fuses at the next output (accepts): one estimate per call
        return out

    def _static_rows(self, T: np.ndarray, W: np.ndarray, F: np.ndarray, dec) -> None:
        """Rows before the hand-over, their motion decisions made (``dec``: the last one's, None before the detector):
        the history, the rest blocks, the static core (one block); the hand-over when ``dec`` declares motion."""
        self._blocks.extend(self._block.add_rest_rows(self._t, T.tolist(), W))  # samples: mean rates over intervals
        self._remember(T, W, F)
        self.static.propagate(T, W, F)
        if dec is not None and dec.moving:
            self._handover(self._t, dec.since_s)

    def _remember(self, T: np.ndarray, W: np.ndarray, F: np.ndarray) -> None:
        """The rows into the last 6 s of history (the hand-over's replay and level window); the last stamp taken."""
        self.hist.extend(zip(T.tolist(), W, F))
        self._t = t = float(T[-1])
        while self.hist and self.hist[0][0] < t - 6.0:
            self.hist.popleft()

    def _row(self, T: np.ndarray, W: np.ndarray, F: np.ndarray) -> None:
        t, w, f = float(T[0]), W[0], F[0]
        if self.motion is not None and self.state == "in motion" and t >= self._next_speed_check_t:
            self._next_speed_check_t = t + SPEED_CHECK_PERIOD_S
            self.detector_skipped = self._speed() > DETECTOR_SKIP_SPEED_M_S
        skip = self.detector_skipped and self.motion is not None and self.state == "in motion"
        dec = None if skip else self._detect(t, w, f)
        if self.motion is None:
            self._static_rows(T, W, F, dec)
            return
        t_prev = self._t
        self._remember(T, W, F)
        self.motion.propagate(T, W, F)
        if self.state == "stopped" and t_prev is not None and t > t_prev:
            self._stop_block(t - t_prev, w, dec is not None and dec.decided and not dec.moving)
        if dec is None or not dec.decided:
            return
        if dec.moving and self.state == "stopped":
            self._hold_p_e = None
            self._set_state(t, "in motion", f"driving again since {dec.since_s:.2f} s")
        elif not dec.moving and self.state == "in motion" and self._speed() < self.cfg.stop_speed_max_m_s:
            self.counters["stops"] += 1
            self._hold_p_e = self._position_e()
            self._next_hold_t = t
            self._stop_blocks, self._stop_applied = [], 0
            self._block.reset()
            self._set_state(t, "stopped", f"stopped since {dec.since_s:.2f} s: zero-velocity updates (position hold) "
                                          "and zero-angular-rate updates")
        if self.state == "stopped" and t >= self._next_hold_t and self._hold_p_e is not None:
            self._next_hold_t = t + 1.0 / self.cfg.stop_hold_rate_hz - 1e-9
            if not (isinstance(self.motion, YawHypothesisBank) and len(self.motion.hyps) > 1):
                # one pseudo-fix for a bank that has not collapsed would move its weights: the fixes do it
                res = self.motion.update(GnssPosition(t, self._hold_p_e, np.eye(3) * self.cfg.stop_hold_sigma_m ** 2))
                self.counters["stop_holds"] += int(res.accepted)

    def _stop_block(self, dt: float, w: np.ndarray, at_rest: bool) -> None:
        """Stopped: 1-s gyro means; from ``stop_zero_rate_min_blocks`` on, each one is a zero-angular-rate update of
        the in-motion core (the z gyro bias is observable at rest: the yaw 3-sigma stops growing) with the per-block
        variance of :func:`block_variance` over the stop so far. Blocks with the detector not at rest are dropped."""
        mean = self._block.add(dt, w, at_rest)
        if mean is None:
            return
        self._stop_blocks.append(mean)
        n = len(self._stop_blocks)
        if self.cfg.stop_zero_rate_min_blocks == 0 or n < self.cfg.stop_zero_rate_min_blocks \
                or ZeroAngularRate not in self.motion.accepts:
            return
        arw2 = (self.cfg.gyro_arw_deg_sqrt_h * D2R / 60.0) ** 2 / REST_BLOCK_S
        R = np.diag(np.maximum(block_variance(np.array(self._stop_blocks)), 1e-4 * arw2))
        for k in range(self._stop_applied, n):
            res = self.motion.update(ZeroAngularRate(self._stop_blocks[k], R))
            self.counters["zero_rate_updates" if res.accepted else "zero_rate_rejected"] += 1
        self._stop_applied = n

    def _motion_evidence(self) -> bool:
        """No zero-velocity update now: moving, undecided, or the detector's rest evidence fails (horizontal velocity
        change or a spread over its threshold: a drive-off not yet declared, a person getting in rocking the body,
        whose 0.035 m/s at the IMU pulled the navigation-grade gyrocompass by 0.2-0.6 deg)."""
        if self.detector is None or not self.detector.decision.decided or self.detector.decision.moving:
            return True  # undecided counts as motion: a zero-velocity update while driving would corrupt the level
        return self.detector.over_rest_bounds()

    def _speed(self) -> float:
        """Horizontal speed of the in-motion core [m/s] (a stop is declared only when it agrees)."""
        v = self.motion.estimate().v_n
        return float(math.hypot(v[0], v[1]))

    def _fuse_zero_velocity(self, meas: ZeroVelocity) -> UpdateResult:
        stamp_s = meas.stamp_s
        if self.motion is not None:
            return UpdateResult(False, reason="in motion: the in-motion core holds its position at stops")
        self._zupt_support[0] += 1
        if self._motion_evidence():
            self.counters["zupt_rejected_moving"] += 1
            why = self.detector.blocking() if self.detector is not None else ""
            if self.state == "static, levelling" and why:  # say what keeps it from levelling
                self._set_state(stamp_s, self.state, why)
            return UpdateResult(False, reason=f"motion evidence: no zero-velocity update ({why})")
        res = self.static.update(meas)
        if res.accepted:
            self._zupt_support[1] += 1
            if math.isfinite(res.nis) and len(res.innovation):
                self._zupt_nis.append(res.nis / len(res.innovation))
                self._nis_mean = None
        est = self.static.estimate()
        self.snaps.append((float(stamp_s), est, len(self._blocks)))
        while len(self.snaps) > 2 and self.snaps[1][0] < stamp_s - 5.0:
            self.snaps.popleft()
        self._static_state(stamp_s, est)
        return res

    def _static_state(self, t: float, est: AlignmentEstimate) -> None:
        s = [math.sqrt(0.0 if x < 0.0 else x) for x in np.diag(est.P_att_n).tolist()]  # np.sqrt(np.clip(d, 0))
        lvl, yaw = max(s[0], s[1]), s[2]
        floor_l = self.cfg.level_floor_rad()
        level = f"level 1-sigma {lvl / D2R:.3f} deg (floor b_acc/g {floor_l / D2R:.3f} deg)"
        if lvl > 2.0 * floor_l and self.state in ("static, levelling", "starting in motion"):
            self._set_state(t, "static, levelling", level)
            return
        if self.grade_allows_heading:
            head = (f"gyrocompassing: yaw 3-sigma {3 * yaw / D2R:.2f} deg (floor {self.heading_floor_deg:.3f} deg "
                    f"at latitude {self.lat / D2R:.1f} deg)")
        else:
            head = (f"heading needs motion (floor {self.heading_floor_deg:.1f} deg at latitude {self.lat / D2R:.1f} "
                    f"deg > {self.cfg.heading_floor_max_deg:g} deg)")
        self._set_state(t, "static, fine", f"{level}; {head}")

    def _handover(self, t: float, since_s: float) -> None:
        """Motion declared: start the in-motion core from the static solution before ``since_s`` and replay."""
        cfg = self.cfg
        before = [s for s in self.snaps if s[0] <= since_s - cfg.handover_margin_s]
        own = [f for f in self._fixes if f[0] > self._t_start]  # the fixes before the start only told the detector
        if not before and (len(own) < 3 or own[-1][0] - own[-3][0] > 3.0):
            # moving from the start: as the session's sensors initialisation of an in-motion core, wait for three
            # fixes within 3 s (velocity, acceleration, the level window in this core's IMU history); no ZUPT meanwhile
            self._set_state(t, "starting in motion", f"moving since {since_s:.2f} s: waiting for three GNSS fixes "
                                                     "within 3 s (initial velocity and level)")
            return
        if before:
            t0, est, n_blocks = before[-1]
        else:  # no snapshot at rest (moving from the start): the static core now, velocity from the fixes or unknown
            t0, est, n_blocks = self._t, self.static.estimate(), 0
        P = np.array(est.P_att_n, float)
        if not before:  # level from accelerometers that were accelerating: as the session's sensors init, >= 5 deg
            est.C_b_n, sig_lvl = self._moving_level(t0)
            for i in (0, 1):
                P[i, i] = max(P[i, i], sig_lvl ** 2)
        yaw_sigma = math.sqrt(max(P[2, 2], 0.0))
        self.heading_trusted = self.grade_allows_heading and yaw_sigma <= cfg.heading_trust_sigma_deg * D2R
        params = cfg.grade_params(cfg.motion_core)
        if not self.heading_trusted:
            params["yaw_hypotheses"] = cfg.unknown_heading_hypotheses
            P[2, :] = P[:, 2] = 0.0
            P[2, 2] = (1e4 * D2R) ** 2  # unknown: uniform over the bank's hypotheses (as the session's sensors init)
        core = registry.make_core(cfg.motion_core, params)
        sig_v = 0.05  # at rest (moving from the start: from the fixes, below)
        v0_n = np.zeros(3)
        sig_p = self.sig_p
        if not before:  # moving from the start: velocity from the fixes, position the newest fix carried forward
            v0_n, sig_v = self._gnss_velocity_n(est.lat_rad, est.lon_rad)
            t_f, p_f, R_f = self._fixes[-1]
            lat, lon, h = earth.ecef_to_geodetic(p_f + earth.C_n_e(est.lat_rad, est.lon_rad) @ v0_n * (t0 - t_f))
            est.lat_rad, est.lon_rad, est.h_m = lat, lon, h
            sig_p = math.hypot(math.sqrt(max(np.trace(R_f) / 3.0, 0.0)), sig_v * abs(t0 - t_f))
        self.gyro_bias_prior = None
        if n_blocks * REST_BLOCK_S >= cfg.gyro_rest_min_s and GyroBiasPrior in core.accepts:
            sig_lvl = math.sqrt(max(P[0, 0], P[1, 1], 0.0))
            mean_b, var_b = rest_rate_mean(np.array(self._blocks[:n_blocks]))
            if n_blocks < SHORT_REST_BLOCKS:  # a short rest: at least the grade's white noise over the window
                var_b = np.maximum(var_b, (cfg.gyro_arw_deg_sqrt_h * D2R / 60.0) ** 2 / (n_blocks * REST_BLOCK_S))
            self.gyro_bias_prior = gyro_bias_from_rest(
                mean_b, var_b, est.C_b_n, est.lat_rad, self.heading_trusted,
                cfg.gyro_bias_rw_deg_h_sqrt_h * math.sqrt(imu_grade.BIAS_RW_HORIZON_H), sig_lvl,
                math.sqrt(max(P[2, 2], 0.0)) if self.heading_trusted else 0.0)
        try:
            core.initialize(t0, est.lat_rad, est.lon_rad, est.h_m, est.C_b_n, v0_n, P, sig_v, sig_p)
            if self.gyro_bias_prior is not None:
                core.update(GyroBiasPrior(*self.gyro_bias_prior, stamp_s=t0))
            replay = [row for row in self.hist if row[0] > t0]
            if replay:
                core.propagate(np.array([r[0] for r in replay]), np.array([r[1] for r in replay]),
                               np.array([r[2] for r in replay]))
        except Exception:
            core.close()
            raise
        self.motion = core
        self.counters["handovers"] += 1
        self.static.close()
        how = ("heading from gyrocompassing" if self.heading_trusted else
               f"heading unknown: {cfg.unknown_heading_hypotheses} yaw hypotheses")
        self._set_state(t, "in motion", f"motion since {since_s:.2f} s: {cfg.motion_core} from the static solution at "
                                        f"{t0:.2f} s ({how})")

    def replace_motion_core(self, core: AlignmentCore, how: str) -> None:
        """The session's yaw seed (session/yaw_seed.py): ``core`` replaces the in-motion core (yaw bank)."""
        self.motion.close()
        self.motion = core
        self._set_state(self._t, self.state, f"{self.reason}; yaw seeded: {how}")

    def _observe(self, fix) -> UpdateResult:
        """A fix while static (not fused): ``_observe_gnss``; any other model: not used."""
        if isinstance(fix, GnssPosition):
            self._observe_gnss(fix)
        elif isinstance(fix, GnssVelocity):
            self._observe_gnss_velocity(fix)
        return UpdateResult(False, reason=f"{self.state}: {fix.label} not used")

    def _observe_gnss(self, fix: GnssFix) -> None:
        """Static: the GNSS speed over >= ``GNSS_SPEED_BASE_S`` from the fixes (position difference, per-axis sigma
        from both fixes' covariances) goes to the motion detector: a car cruising at constant speed on a smooth road
        looks parked to the IMU (docs/motion_detector.md), and after a re-initialisation while driving the static
        core would otherwise take zero-velocity updates at 15 m/s."""
        t, p, R = float(fix.stamp_s), np.asarray(fix.p_e, float), np.asarray(fix.R_e, float)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            return
        while self._fixes and (t - self._fixes[0][0] > 3.0 * GNSS_SPEED_BASE_S or t <= self._fixes[-1][0]):
            self._fixes.popleft() if t - self._fixes[0][0] > 3.0 * GNSS_SPEED_BASE_S else self._fixes.pop()
        seq = list(self._level_fixes)[-2:]  # every fix seen (a jump: the session's test at its default accel)
        if len(seq) == 2 and t > seq[-1][0] and sequence_jump(seq, t, p, R, SessionConfig.gnss_jump_accel_m_s2):
            self._fixes.clear()  # a jump is no speed: the baseline restarts (a block of bad fixes has one each end)
        old = [f for f in self._fixes if t - f[0] >= GNSS_SPEED_BASE_S]
        self._fixes.append((t, p, R))
        if not self._level_fixes or t > self._level_fixes[-1][0]:
            self._level_fixes.append((t, p, R))
        if not old:
            return
        t0, p0, R0 = old[-1]
        dt = t - t0
        sig_p = math.sqrt(max(np.trace(R + R0) / 6.0, 1e-12))
        noise = max(self._fix_noise.push(t, p), FIX_NOISE_FLOOR_M)  # used when far below the declared (correlated)
        veto = math.sqrt(2.0) * (noise if noise < 0.3 * sig_p else sig_p) / dt
        self._push_speed(t, float(np.linalg.norm(p - p0)) / dt, math.sqrt(2.0) * sig_p / dt, veto)

    def _moving_level(self, t: float) -> tuple[np.ndarray, float]:
        """Moving from the start: C_b_n (yaw 0) levelled at ``t`` and its honest level 1-sigma [rad]. From the IMU
        samples since the first of the fixes' velocities (earth.level_from_window: rotation-compensated) when the
        fixes span LEVEL_WINDOW_MIN_S: the mean acceleration over that window is the change of the fixes' horizontal
        velocity over it, known to their noise; else, as the session's sensors initialisation of an in-motion core,
        the last second: 1 deg (accelerometer bias) + the vehicle acceleration (second difference of the fixes seen +
        0.5 m/s^2, else ``NO_REST_ACC_M_S2``) over g + the spread."""
        win = self._window_level(t)
        if win is not None:
            return win
        a = NO_REST_ACC_M_S2
        fx = list(self._fixes)
        if len(fx) >= 3 and fx[-1][0] - fx[-3][0] <= 3.0:
            (t0, p0, _), (t1, p1, _), (t2, p2, _) = fx[-3:]
            a = float(np.linalg.norm((p2 - p1) / (t2 - t1) - (p1 - p0) / (t1 - t0))) / (0.5 * (t2 - t0)) + 0.5
        roll, pitch, sig = earth.level_from_specific_force([f for (ts, _, f) in self.hist if ts > t - 1.0], a)
        return earth.C_b_n_from_rpy(roll, pitch, 0.0), sig

    def _window_level(self, t: float) -> tuple[np.ndarray, float] | None:
        """(C_b_n with yaw 0, level 1-sigma [rad]) from the samples since the first horizontal velocity held: the
        GNSS velocities' when they span LEVEL_WINDOW_MIN_S, else the middle of the first fix interval's; the
        acceleration bound sqrt(|dv|^2 + var(dv)) / T from the first and the last velocity (dv) plus NO_REST_ACC_M_S2
        over the time after the last one; None when neither spans LEVEL_WINDOW_MIN_S or the IMU history does not
        reach back."""
        lo = self.hist[0][0] if self.hist else t  # within the IMU history
        vs = [v for v in self._vels if lo <= v[0] <= t]
        fx = [f for f in self._level_fixes if lo <= f[0] <= t]
        if len(vs) >= 2 and vs[-1][0] - vs[0][0] >= LEVEL_WINDOW_MIN_S:  # GNSS velocities: the change directly
            (t_first, va, Rva), (t_last, vb, Rvb) = vs[0], vs[-1]
            dv = (vb - va)[:2]
            var = float(np.trace(Rva[:2, :2] + Rvb[:2, :2]))
        elif len(fx) >= 3 and fx[-1][0] - fx[0][0] >= LEVEL_WINDOW_MIN_S:  # the first and the last fix interval
            (ta, va, Ra), (tb, vb, Rb) = (earth.velocity_from_fixes(*zip(*pair)) for pair in (fx[:2], fx[-2:]))
            if not (len(ta) and len(tb)):
                return None
            t_first, t_last, dv = float(ta[0]), float(tb[0]), (vb[0] - va[0])[:2]
            var = float(np.trace(Ra[0, :2, :2] + Rb[0, :2, :2]))
        else:
            return None
        T = t - t_first
        rows = [r for r in self.hist if r[0] >= t_first]
        if T <= 0.0 or len(rows) < 5 or self.hist[0][0] > t_first + 0.1:
            return None
        a_sig = math.sqrt(float(dv @ dv) + max(float(var), 0.0)) / T + NO_REST_ACC_M_S2 * max(t - t_last, 0.0) / T
        roll, pitch, sig = earth.level_from_window([r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows],
                                                   a_sig)
        return earth.C_b_n_from_rpy(roll, pitch, 0.0), sig

    def _gnss_velocity_n(self, lat_rad: float, lon_rad: float) -> tuple[np.ndarray, float] | None:
        """ENU velocity [m/s] from the last two fixes >= GNSS_SPEED_BASE_S apart and its 1-sigma: the fixes' noise
        plus NO_REST_ACC_M_S2 x (the base + the age of the newest fix) for the change since; a GNSS velocity stamped
        within 1 s instead when it is tighter and agrees with it (as the sensors initialisation's); None: neither."""
        best = None
        old = [f for f in self._fixes if self._fixes[-1][0] - f[0] >= GNSS_SPEED_BASE_S]
        if old:
            (t0, p0, R0), (t1, p1, R1) = old[-1], self._fixes[-1]
            dt = t1 - t0
            v_n, sig = earth.C_n_e(lat_rad, lon_rad).T @ ((p1 - p0) / dt), math.sqrt(max(np.trace(R1 + R0) / 3.0, 0.0)) / dt
            best = v_n, math.hypot(sig, NO_REST_ACC_M_S2 * (max(0.0, (self._t or t1) - t1) + dt))
        if self._vels:
            tv, vv, Rv = self._vels[-1]
            age_v = max(0.0, (self._t or tv) - tv)
            sig_v = math.hypot(math.sqrt(max(float(np.max(np.diag(Rv))), 0.0)), NO_REST_ACC_M_S2 * age_v)
            if age_v <= 1.0 and (best is None or sig_v < best[1] and velocities_agree(vv, float(Rv[0, 0] + Rv[1, 1]),
                                                                                  best[0], 2.0 * best[1] ** 2)):
                return vv.copy(), sig_v
        return best

    @property
    def accepts(self) -> frozenset:
        """The session reads it per call: zero velocity while static, the in-motion core's set from the hand-over on."""
        return self.motion.accepts if self.motion is not None else frozenset({ZeroVelocity})

    def _fuse(self, meas) -> UpdateResult:
        if self.motion is None:
            return self._fuse_zero_velocity(meas)  # the only model accepted while static
        res = self.motion.update(meas)
        if self._hold_p_e is not None and isinstance(meas, GnssPosition):
            self._hold_p_e = self._position_e()  # stopped: hold where the fix put the core (holds and fixes agree)
        return res

    def _observe_gnss_velocity(self, vel) -> None:
        """Static: a GNSS velocity (not fused while parked) gives the motion detector its horizontal speed (the
        walking-speed veto; fresher and better than the speed from two fixes)."""
        v, R = np.asarray(vel.v_n, float), np.asarray(vel.R_n, float)
        if self.motion is not None or not (np.all(np.isfinite(v)) and np.all(np.isfinite(R))):
            return
        if not self._vels or vel.stamp_s > self._vels[-1][0]:
            self._vels.append((float(vel.stamp_s), v, R))  # the hand-over's velocity and level window
        self._push_speed(float(vel.stamp_s), float(math.hypot(v[0], v[1])),
                         math.sqrt(max(float(R[0, 0] + R[1, 1]) / 2.0, 1e-12)))

    def predict(self, meas) -> UpdateResult:
        if self.motion is None:
            return super().predict(meas)
        return self.motion.predict(meas)

    def _position_e(self) -> np.ndarray:
        e = self.motion.estimate()
        return np.asarray(earth.geodetic_to_ecef(e.lat_rad, e.lon_rad, e.h_m), float)

    # ------------------------------------------------------------------ outputs
    def estimate(self) -> AlignmentEstimate:
        return self._dressed(self.active.estimate())

    def _dressed(self, est: AlignmentEstimate) -> AlignmentEstimate:
        """The active core's estimate with the state in its reason (and, parked, the heading support)."""
        if self.motion is None and self.state == "static, fine" and not self.grade_allows_heading:
            est.status = AlignmentStatus.WAITING_FOR_MOTION
        est.reason = f"{self.state}: {self.reason}" if self.reason else self.state
        if self.motion is None and est.P_att_n is not None:
            self._nis_mean = zupt_nis_mean(self._zupt_nis) if self._nis_mean is None else self._nis_mean
            est.P_att_n, why = static_heading_support(np.array(est.P_att_n, float), self._zupt_support, self._zupt_nis,
                                                      self.cfg.azimuth_floor_rad(self.lat), self._nis_mean)
            if why:
                est.reason += f"; {why}"
        return est

    def diagnostics(self) -> dict:
        d = {"state": self.state, "state_reason": self.reason,
             "heading_floor_deg": f"{self.heading_floor_deg:.3f}",
             "heading_trusted": str(self.heading_trusted).lower(),
             "motion_detector_skipped": str(self.detector_skipped).lower(),
             **{k: str(v) for k, v in self.counters.items()}}
        if self.gyro_bias_prior is not None:  # the in-motion core's start: the bias measured at rest [deg/h]
            b, P = self.gyro_bias_prior
            k = 180.0 / math.pi * 3600.0
            d["rest_gyro_bias_deg_h"] = " ".join(f"{x * k:.2f}" for x in b)
            d["rest_gyro_bias_sigma_deg_h"] = " ".join(f"{math.sqrt(x) * k:.2f}" for x in np.diag(P))
        if self.detector is not None:
            d.update({f"motion.{k}": v for k, v in self.detector.diagnostics().items()})
        if self.active is not None:
            d.update({f"{self.active.name}.{k}": v for k, v in self.active.diagnostics().items()})
        return d


registry.register("auto", AutoCore, AutoConfig)
imu_grade.CORE_DEFAULT_GRADE["auto"] = "industrial_mems"  # the grade AutoConfig's defaults are (test_imu_grade)
