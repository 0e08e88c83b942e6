"""The initialiser: the first estimate from the truth (simulations), a guess, or the sensors alone (position and
velocity from the fixes, level from the accelerometers, heading unknown: a yaw bank); after a divergence, from the
sensors with the level the lost filter kept.

docs/session.md, "Initialisation"."""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from ..core import earth, lie
from ..filters import registry
from ..filters.base import AlignmentCore, AlignmentStatus
from ..filters.measurements import GnssPosition, GnssVelocity
from . import catalog
from .fix_line import extrapolation_excess, fix_point, velocities_agree
from .truth import TruthSample

#: a static core's first initialisation with one fix waits for a second one when the gyros turn faster than this
#: about the vertical [rad/s] (0.5 deg/s: 70 times the Earth's rate; a parked vehicle does not turn)
TURN_WAIT_RAD_S = math.radians(0.5)
#: the GNSS fixes and velocities of this span [s] before a core's start, which the session does not fuse, are shown
#: to a core that does not fuse them either (core auto's motion detector: ``Initialiser.show_earlier_gnss``)
EARLIER_GNSS_S = 3.0

D2R = math.pi / 180.0


class Initialiser:
    """Starts the core when the data allow it (``try_initialize`` at every sample before the core exists)."""

    def __init__(self, session) -> None:
        self.s = session
        self.reset()

    def reset(self) -> None:
        self._declared = None
        self.sensors_reinit = False
        self.kept_level = None  # (t, C_b_n, level 1-sigma) of the lost filter, if it claimed its level
        #: a restart (time jump, reset, fault, divergence): the vehicle may be moving; start from what the data say
        self.after_restart = False
        self.pre_init: deque = deque(maxlen=4000)  # IMU samples before the initialisation (level from sensors)

    def capabilities(self):
        """(accepts GNSS positions, initial_sigmas) of the configured core as the registry declares them (read once,
        not per sample while the session waits for its first fix)."""
        sess = self.s
        if self._declared is None:
            accepts, sigmas = registry.declared(sess.cfg.core, sess.core_params)
            self._declared = (GnssPosition in accepts, sigmas)
        return self._declared

    def core_name(self, params: dict) -> str:
        """The configured core, or its backtrackable form when backtracking passes are asked for (session/catalog.py)."""
        cfg = self.s.cfg
        if cfg.backtrack_passes > 0 and int(params.get("yaw_hypotheses", 1)) == 1:
            return catalog.BACKTRACKING_CORES.get(cfg.core, cfg.core)
        return cfg.core

    def try_initialize(self, t: float) -> None:
        sess = self.s
        cfg = sess.cfg
        if cfg.init_mode == "sensors" or self.sensors_reinit:
            self._from_sensors(t)
            return self._still_faulted()  # divergence guard: FAULT stays until a new filter runs
        tr = sess.buf.truth.get(t) if cfg.init_mode == "truth" else None
        gnss_core, (sig_rpy, sig_v, sig_p) = self.capabilities()
        static = not gnss_core
        pos, used_fix = None, None
        if static and all(math.isfinite(x) for x in cfg.static_position_deg_m):
            la, lo, h = cfg.static_position_deg_m
            pos = (la * D2R, lo * D2R, float(h))
        elif tr is not None and tr.llh is not None:
            pos = tuple(float(x) for x in tr.llh)
        else:
            j = bisect.bisect_right(sess.buf.fix_t, t)
            if j > 0:
                used_fix = sess.buf.fix[j - 1]
                pos = earth.ecef_to_geodetic(used_fix.p_e)
        if pos is None:
            sess.status = AlignmentStatus.WAITING_FOR_GNSS
            sess.reason = ("waiting for a GNSS fix (initial position)" if not static else
                           "waiting for a GNSS fix or static_position_deg_m (site position)")
            return
        if cfg.init_mode == "truth":
            if tr is None:
                sess.status = AlignmentStatus.WAITING_FOR_DATA
                sess.reason = "waiting for a ground-truth pose at an IMU stamp (init_mode truth)"
                return
            rpy = earth.rpy_from_C_b_n(np.asarray(tr.C_b_n, float)) + np.asarray(cfg.init_rpy_error_deg) * D2R
            v0 = self._truth_velocity(tr)
        else:
            rpy = np.asarray(cfg.initial_rpy_deg) * D2R
            v0 = np.asarray(cfg.initial_velocity_enu_m_s, float)
        sig_rpy = [u if math.isfinite(u) else d for u, d in zip(cfg.init_sigma_rpy_deg, sig_rpy)]
        P_att = np.diag((np.asarray(sig_rpy, float) * D2R) ** 2)
        core = registry.make_core(self.core_name(sess.core_params), sess.core_params)
        try:
            core.initialize(t, pos[0], pos[1], pos[2], earth.C_b_n_from_rpy(*rpy), v0, P_att, sig_v, sig_p)
        except Exception:
            core.close()
            raise
        self._start(core, t, pos, used_fix, rpy, v0)

    def _start(self, core: AlignmentCore, t: float, pos, used_fix, rpy, v0, how: str = "") -> None:
        sess = self.s
        cfg = sess.cfg
        # fixes up to the initialisation stamp: the one that gave the position is consumed, older ones dropped
        sess._used_fix_stamp = used_fix.stamp_s if used_fix is not None else None
        self.pre_init.clear()
        sess.core = core
        self.show_earlier_gnss(core, t, used_fix)
        if cfg.backtrack_passes > 0:
            from ..filters.backtrack import BacktrackingAligner

            sess.bt = BacktrackingAligner(core, t, cfg.backtrack_window_s, cfg.backtrack_passes,
                                          covariance=cfg.backtrack_covariance)
        sess.init_t = t
        sess.anchor = pos
        sess.status = AlignmentStatus.CONVERGING
        sess.reason = "initialised"
        sess.next_out_t = t
        sess.next_zupt_t = t
        sess.fault_reason = ""
        sess.log("info", "init", f"initialised {cfg.core} at t={t + sess.stamp_offset_s:.3f} s, lat {pos[0] / D2R:.6f} deg, lon "
                                 f"{pos[1] / D2R:.6f} deg, h {pos[2]:.1f} m, rpy "
                                 f"{np.round(rpy / D2R, 2).tolist()} deg, v {np.round(v0, 3).tolist()} m/s{how}")

    def show_earlier_gnss(self, core: AlignmentCore, t: float, used_fix) -> None:
        """The fixes and GNSS velocities of the last ``EARLIER_GNSS_S`` up to the start ``t`` that the session will not
        fuse (older than the start, or the fix that gave the position), shown to a core that does not fuse them
        either: ``update`` of a model a core does not accept only lets it observe it (core auto's motion detector
        takes their speed), so a vehicle driving at power-on is seen moving from its second fix, not after two fixes
        of auto's own. A core that fuses them is shown nothing from before its start."""
        b = self.s.buf
        if GnssPosition not in core.accepts:
            for fx in b.fix[:bisect.bisect_right(b.fix_t, t)]:
                if t - fx.stamp_s <= EARLIER_GNSS_S and (fx.stamp_s < t or fx is used_fix):
                    core.update(GnssPosition.of(fx))
        if GnssVelocity not in core.accepts:
            for vel in b.vel[:bisect.bisect_right(b.vel_t, t)]:
                if t - vel.stamp_s <= EARLIER_GNSS_S and vel.stamp_s < t:
                    core.update(GnssVelocity.of(vel))

    def _from_sensors(self, t: float) -> None:
        """init_mode 'sensors': no guess. Position from the newest fix; velocity from the last two fixes (0 for a
        static core); roll and pitch from the mean specific force over ``init_level_window_s``; heading unknown.

        Sigmas are honest rather than small: velocity sqrt(2) sigma_p / dt plus the unknown acceleration over the
        half interval and the age of the fix; level the accelerometer spread, the vehicle acceleration (the fixes'
        second difference, else ``init_accel_m_s2``) over g, and a 1-deg floor for an unknown accelerometer bias
        (10 mg on a poor MEMS: 0.6 deg). Heading: a bank of ``unknown_heading_hypotheses`` hypotheses for GNSS
        cores (uniform prior); static cores find it themselves (gyrocompassing bootstrap)."""
        sess = self.s
        cfg = sess.cfg
        sess._used_vel_stamp = None  # set by _gnss_velocity when a GNSS velocity gives the initial one
        fixes = sess.buf.fix[:bisect.bisect_right(sess.buf.fix_t, t)]
        gnss_core, (sig_rpy0, sig_v0, sig_p0) = self.capabilities()
        if not gnss_core and all(math.isfinite(x) for x in cfg.static_position_deg_m):
            la, lo, h = cfg.static_position_deg_m
            pos, used, sig_p = (la * D2R, lo * D2R, float(h)), None, sig_p0
        elif fixes:
            used = fixes[-1]
            pos = earth.ecef_to_geodetic(used.p_e)
            sig_p = max(sig_p0, math.sqrt(max(float(np.trace(used.R_e)) / 3.0, 0.0)))
        else:
            sess.status = AlignmentStatus.WAITING_FOR_GNSS
            sess.reason = "waiting for a GNSS fix (initial position)"
            return
        a_est = cfg.init_accel_m_s2
        recent = [fx for fx in fixes if t - fx.stamp_s <= 3.0]
        # two fixes at one stamp (an early wrong one and the genuine one): the later arrival (no zero interval)
        recent = [fx for i, fx in enumerate(recent) if i + 1 == len(recent) or recent[i + 1].stamp_s != fx.stamp_s]
        # a restart of a static (or auto) core: the vehicle may be driving; wait for two fixes to tell (not for a
        # site position given by the user)
        waits = gnss_core or (self.after_restart and used is not None)
        if waits:
            if len(recent) < 2:
                sess.status = AlignmentStatus.WAITING_FOR_GNSS
                sess.reason = f"waiting for a second GNSS fix (initial velocity; {len(recent)} of 2 within 3 s)"
                return
            # -- divergence guard: a re-initialisation waits for three fixes consistent with each other (the
            # fixes that made the filter diverge may be the bad ones); any initialisation refuses three that are not
            if len(recent) < 3 and self.sensors_reinit:
                sess.status = AlignmentStatus.WAITING_FOR_GNSS
                sess.reason = f"re-initialising: waiting for three consistent GNSS fixes ({len(recent)} of 3 within 3 s)"
                return
            if len(recent) >= 3:
                excess = extrapolation_excess([fix_point(fx) for fx in recent[-3:-1]], fix_point(recent[-1]),
                                               cfg.gnss_jump_accel_m_s2)
                if excess > 0:
                    sess.status = AlignmentStatus.WAITING_FOR_GNSS
                    sess.reason = (f"waiting for consistent GNSS fixes (the newest is {excess:.1f} m beyond the "
                                   "extrapolation of the two before it)")
                    return
            # -- end divergence guard
            f1, f2 = recent[-2], recent[-1]
            dt = f2.stamp_s - f1.stamp_s
            C_en = earth.C_e_n(pos[0], pos[1])
            v0 = C_en @ (np.asarray(f2.p_e) - np.asarray(f1.p_e)) / dt
            if len(recent) >= 3:
                f0 = recent[-3]
                dt0 = f1.stamp_s - f0.stamp_s
                v_prev = C_en @ (np.asarray(f1.p_e) - np.asarray(f0.p_e)) / dt0
                a_est = float(np.linalg.norm(v0 - v_prev)) / (0.5 * (dt + dt0)) + 0.5  # + margin for noise/jerk
            s_p = math.sqrt(max(float(np.trace(f2.R_e)) / 3.0, 0.0))
            # the turn rate the gyros measure times the speed (a car initialised in a turn: the fixes' second
            # difference, up to a second old, does not see the centripetal acceleration yet)
            speed = float(np.linalg.norm(v0[:2])) if self.after_restart else self._fix_speed(recent)
            if self.after_restart or speed > 0.0:
                a_est = max(a_est, self._turn_accel(t, speed))
            sig_v = math.sqrt(2.0) * s_p / dt + a_est * (0.5 * dt + (t - f2.stamp_s))
            v0, sig_v = self._gnss_velocity(t, v0, sig_v, a_est)  # a GNSS velocity topic, when tighter
            if not gnss_core and not float(np.linalg.norm(v0[:2])) > max(0.5, 3.0 * sig_v):
                v0, sig_v, a_est = np.zeros(3), sig_v0, 0.0  # a static core at rest: as a first initialisation
        else:
            v0, sig_v, a_est = np.zeros(3), sig_v0, 0.0
            if (used is not None and len(recent) < 2 and t - used.stamp_s < 2.0 and not self.after_restart
                    and self._turn_rate(t) > TURN_WAIT_RAD_S):
                # turning with one fix: wait up to 2 s for a second one, which tells a vehicle turning on the spot
                # from one driving through a turn (its accelerometers' mean is tilted by the centripetal acceleration)
                sess.status = AlignmentStatus.WAITING_FOR_GNSS
                sess.reason = "waiting for a second GNSS fix (is the vehicle moving?)"
                return
            speed = self._fix_speed(recent)
            if speed > 0.0:  # a static core's first initialisation while the fixes say the vehicle drives: its level
                a_est = self._turn_accel(t, speed)  # is the accelerometers' mean with the centripetal acceleration in it
        win = [(w_, f_) for (tt, w_, f_) in self.pre_init if tt > t - cfg.init_level_window_s]
        if len(win) < 5:
            sess.status = AlignmentStatus.WAITING_FOR_DATA
            sess.reason = f"collecting accelerometer data for the level ({len(win)} samples)"
            return
        roll, pitch, sig_level = earth.level_from_specific_force([f_ for _, f_ in win], a_est)
        # -- divergence guard: the lost filter's level (carried by the gyros) when it agrees with the accelerometers
        kept, level_from = self._kept_level_now(t), "accelerometers"
        if kept is not None and max(abs(earth.wrap_angle_rad(kept[0] - roll)), abs(kept[1] - pitch)) \
                < 3.0 * math.hypot(sig_level, kept[2]):
            roll, pitch, sig_level = kept
            level_from = "the lost filter's level, gyro-propagated"
        # -- end divergence guard
        params = dict(sess.core_params)
        # heading unknown: a bank of hypotheses; with backtracking one filter with a flat heading prior (the passes
        # need one filter and converge its heading; a bank here would fault at every start: docs/backtracking.md)
        if gnss_core and params.get("yaw_hypotheses", 1) == 1 and cfg.unknown_heading_hypotheses > 1 \
                and cfg.backtrack_passes == 0:
            params["yaw_hypotheses"] = cfg.unknown_heading_hypotheses
        core = registry.make_core(self.core_name(params), params)
        sig_yaw = 1e4 if gnss_core else sig_rpy0[2]  # unknown: uniform over the bank's hypotheses
        user = cfg.init_sigma_rpy_deg
        sig = [u * D2R if math.isfinite(u) else d for u, d in zip(user, (sig_level, sig_level, sig_yaw * D2R))]
        rpy = np.array([roll, pitch, 0.0])
        try:
            core.initialize(t, pos[0], pos[1], pos[2], earth.C_b_n_from_rpy(*rpy), v0, np.diag(np.square(sig)),
                            sig_v, sig_p)
        except Exception:
            core.close()
            raise
        self._start(core, t, pos, used, rpy, v0, how=(
            f" (from sensors: level 1-sigma {sig_level / D2R:.2f} deg from {level_from} ({len(win)} samples), "
            f"velocity 1-sigma "
            f"{sig_v:.2f} m/s, heading unknown: {params.get('yaw_hypotheses', 1)} hypotheses)"))

    @staticmethod
    def _fix_speed(recent: list) -> float:
        """The horizontal speed [m/s] between the last two of ``recent`` fixes when it is above 0.5 m/s and three
        times its own noise; else 0 (at rest, or the fixes cannot tell)."""
        if len(recent) < 2:
            return 0.0
        f1, f2 = recent[-2], recent[-1]
        _, v_n, R_n = earth.velocity_from_fixes([f1.stamp_s, f2.stamp_s], [f1.p_e, f2.p_e], [f1.R_e, f2.R_e])
        if not len(v_n):
            return 0.0
        speed = float(np.linalg.norm(v_n[0, :2]))
        return speed if speed > max(0.5, 3.0 * math.sqrt(max(float(R_n[0, 0, 0] + R_n[0, 1, 1]), 0.0))) else 0.0

    def _turn_accel(self, t: float, speed_m_s: float) -> float:
        """A bound of the centripetal acceleration [m/s^2] over the level window: the mean turn rate the gyros
        measure times the speed from the fixes, plus 0.5 m/s^2 for its change (a car entering a turn at 15 m/s
        reaches 4.7 m/s^2 in 2 s, which the fixes' second difference, 1 s old, does not see yet)."""
        return self._turn_rate(t) * speed_m_s + 0.5

    def _turn_rate(self, t: float) -> float:
        """|mean angular rate about the vertical| [rad/s] over the level window (the roll and pitch rates of a rolling
        hull or a rough road are not turns); 0 without samples."""
        win = [(w_, f_) for (tt, w_, f_) in self.pre_init if tt > t - self.s.cfg.init_level_window_s]
        if not win:
            return 0.0
        w_mean = np.mean(np.asarray([w_ for w_, _ in win], float), axis=0)
        f_mean = np.mean(np.asarray([f_ for _, f_ in win], float), axis=0)
        return abs(float(w_mean @ f_mean)) / max(float(np.linalg.norm(f_mean)), 1e-6)

    def _gnss_velocity(self, t: float, v0: np.ndarray, sig_v: float, a_est: float) -> tuple[np.ndarray, float]:
        """The newest GNSS velocity stamped within 1 s before ``t`` when it is tighter than the fixes' difference:
        (v_n [m/s], 1-sigma [m/s]: its largest axis plus the acceleration over its age); else ``(v0, sig_v)``."""
        b = self.s.buf
        k = bisect.bisect_right(b.vel_t, t)
        if k == 0 or t - b.vel_t[k - 1] > 1.0:
            return v0, sig_v
        vel = b.vel[k - 1]
        # where the velocity belongs within the IMU period is unknown (the guard's model floor, session/guard.py):
        # a_est dt / sqrt(12), 0.14 m/s in a 25-deg/s turn at 10 m/s with a 10-Hz IMU
        dt = self.s.loop.median_dt or 0.0
        s = math.hypot(math.sqrt(max(float(np.max(np.diag(vel.R_n))), 0.0)), a_est * dt / math.sqrt(12.0)) \
            + a_est * (t - vel.stamp_s)
        if not s < sig_v or not velocities_agree(vel.v_n, float(vel.R_n[0, 0] + vel.R_n[1, 1]), v0, 2.0 * sig_v ** 2):
            return v0, sig_v  # (not tighter, or off the fixes' velocity: a glitch is not the initial velocity)
        self.s._used_vel_stamp = vel.stamp_s  # the velocity that gave the initial one is not fused again
        return np.asarray(vel.v_n, float).copy(), s

    def _truth_velocity(self, tr: TruthSample) -> np.ndarray:
        """Truth velocity: given, or the slope at ``tr`` of a quadratic through up to two truth positions on each
        side (the fusion delay means the later ones have arrived); the initial-velocity guess when none."""
        sess = self.s
        if tr.v_n is not None:
            return np.asarray(tr.v_n, float)
        if tr.p_n is None:
            return np.asarray(sess.cfg.initial_velocity_enu_m_s, float)
        ts = [k for k in sess.buf.truth_t if abs(k - tr.stamp_s) <= 1.0 and sess.buf.truth[k].p_n is not None]
        before = [k for k in ts if k < tr.stamp_s][-2:]
        after = [k for k in ts if k > tr.stamp_s][:2]
        keys = before + [tr.stamp_s] + after
        if len(keys) < 2:
            return np.asarray(sess.cfg.initial_velocity_enu_m_s, float)
        dt = np.array(keys) - tr.stamp_s
        P = np.array([np.asarray(sess.buf.truth[k].p_n if k != tr.stamp_s else tr.p_n, float) for k in keys])
        deg = min(2, len(keys) - 1)
        coef = np.polyfit(dt, P, deg)  # highest power first; the slope at dt = 0 is the linear coefficient
        return coef[-2]

    def claimed_level(self):
        """(t, C_b_n, level 1-sigma [rad]) of the core when it claims its level (roll and pitch 3-sigma within twice
        the flag's bound): what a divergence keeps for the re-initialisation (a lost heading leaves the level, which
        gravity keeps observable); None otherwise."""
        sess = self.s
        if sess.core is None or sess.processed_t is None:
            return None
        est = sess.core.estimate()
        sig = math.sqrt(max(float(est.P_att_n[0, 0]), float(est.P_att_n[1, 1]), 0.0))
        if not (math.isfinite(sig) and 3.0 * math.degrees(sig) < 2.0 * sess.flag.criteria.roll_pitch_3sigma_deg):
            return None
        return sess.processed_t, np.asarray(est.C_b_n, float), sig

    def _kept_level_now(self, t: float):
        """The level kept at the divergence carried to ``t`` with the gyros (the samples since the divergence; the
        heading of C_b_n does not matter: a rotation about the vertical leaves roll and pitch): (roll, pitch,
        1-sigma [rad]) with the kept 1-sigma doubled (0.5-deg floor), or None."""
        if self.kept_level is None:
            return None
        t0, C, sig = self.kept_level
        prev = t0
        for tt, w_, _ in self.pre_init:
            if prev < tt <= t:
                C = C @ lie.so3_exp(np.asarray(w_, float) * (tt - prev))
                prev = tt
        rpy = earth.rpy_from_C_b_n(C)
        return float(rpy[0]), float(rpy[1]), max(2.0 * sig, 0.5 * D2R)

    def _still_faulted(self) -> None:
        """While re-initialising after a fault or a divergence: status FAULT with its reason, and what the
        initialisation waits for (instead of the plain waiting status)."""
        sess = self.s
        if sess.core is None and sess.fault_reason:
            waiting = sess.reason if not sess.reason.startswith("fault (") else ""
            sess.status = AlignmentStatus.FAULT
            sess.reason = f"fault ({sess.fault_reason}); re-initialising" + (f": {waiting}" if waiting else "")
