"""Input stage: every pushed input is validated at the door (counted per reason, never raised) and put into the time
buffer in stamp order; a run of self-consistent samples off the time line is a time jump (the session resets).

docs/session.md, "Inputs"."""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from ..core.types import GnssFix, GnssHeading, GnssVelocity, ImuSample, WheelSpeed
from ..filters.checks import check_velocity
from ..io.validation import check_covariance
from .buffers import RecentStamps, row_norms
from .fix_line import FixScreen
from .truth import TruthDict, TruthSample, TruthTable, truth_table_valid

#: a GNSS velocity faster than this is not a vehicle's [m/s]
MAX_GNSS_SPEED_M_S = 600.0


class InputStage:
    """``push_*`` of :class:`AlignmentSession`: validation, duplicate and time-jump checks, buffering."""

    def __init__(self, session) -> None:
        self.s = session
        self.reset()

    def reset(self) -> None:
        self.recent_stamps = RecentStamps(4096)
        self.fix_stamps: deque = deque(maxlen=256)
        self.jump_candidates: list = []
        self.screen = FixScreen(self.s)  # the fixes' line (a restart keeps it: AlignmentSession._restart)

    def push_imu(self, sample: ImuSample, wall_s: float | None = None) -> bool:
        """Validate and buffer one IMU sample (omega_ib_b [rad/s], f_ib_b [m/s^2], body FLU). False if rejected."""
        sess = self.s
        c = sess.counters
        c["imu_received"] += 1
        self.touch(wall_s)
        t = float(sample.stamp_s)
        w, f = sample.omega_ib_b, sample.f_ib_b
        reason = check_imu(t, w, f, sess.cfg.max_rate_rad_s, sess.cfg.max_acc_m_s2)
        if reason:
            return self.reject_imu("imu_invalid", reason)
        w, f = np.asarray(w, float), np.asarray(f, float)
        if w.shape != (3,) or f.shape != (3,):  # (the array buffer holds (3,) rows)
            return self.reject_imu("imu_invalid", f"angular_velocity/linear_acceleration: shapes {w.shape}, {f.shape} "
                                                   "instead of (3,)")
        if wall_s is not None:
            sess.last_imu_wall = wall_s  # the watchdog counts valid samples only
        if t in self.recent_stamps:
            return self.reject_imu("imu_duplicate", f"duplicate stamp {t + sess.stamp_offset_s:.6f}")
        newest = sess.newest_imu_t
        if newest is not None and (t - newest > sess.cfg.max_gap_s or newest - t > sess.cfg.max_gap_s):
            return self._jump_candidate(sample, t - newest)
        self.jump_candidates.clear()
        if sess.processed_t is not None and t <= sess.processed_t:
            return self.reject_imu("imu_out_of_order", f"stamp {t + sess.stamp_offset_s:.6f} is {sess.processed_t - t:.3f} s before "
                                                        "the filter time (beyond the fusion delay)")
        self._remember(t)
        if newest is None or t > newest:
            sess.buf.imu.append(t, w, f)
            sess.newest_imu_t = t
            if newest is None:
                self._check_early_fixes()
        else:
            c["imu_reordered"] += 1
            sess.buf.imu.insert(t, w, f)
        self.check_overflow()
        return True

    def check_overflow(self) -> None:
        """More than MAX_BUFFER samples held: the oldest are processed at once (outputs handed out later)."""
        sess = self.s
        b = sess.buf.imu
        if len(b) > sess.MAX_BUFFER:
            sess._overflow_out += sess.loop.run(until=b.t_at(len(b) - sess.MAX_BUFFER))

    def push_imu_arrays(self, t_s, omega_ib_b, f_ib_b, wall_s: float | None = None) -> int:
        """``push_imu`` for arrays of samples (t_s (N,) [s], omega_ib_b (N, 3) [rad/s], f_ib_b (N, 3) [m/s^2], body
        FLU, in arrival order); returns how many were accepted. The same checks, counters and buffer as one
        ``push_imu`` per sample: rows that are valid and continue the time line (increasing, no jump) are taken in
        bulk, any other row goes through ``push_imu`` (rejected or reordered there, with its reason)."""
        t = np.asarray(t_s, float)
        w = np.asarray(omega_ib_b, float)
        f = np.asarray(f_ib_b, float)
        n = t.shape[0] if t.ndim == 1 else -1
        if n < 0 or w.shape != (n, 3) or f.shape != (n, 3):
            return sum(self.push_imu(ImuSample(float(t[k]), w[k], f[k]), wall_s) for k in range(len(t)))
        ok, cont = self.imu_array_checks(t, w, f)
        return self.push_imu_checked(t, w, f, ok, cont, wall_s)

    def imu_array_checks(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``push_imu``'s checks of arrays of samples, at once: ``ok`` (N,) rows valid; ``cont`` (N - 1,) row k + 1 is
        valid and after row k by at most ``max_gap_s`` (it continues a bulk run). Row-wise: the checks of a slice are
        the slice of the checks (``run_session`` checks a whole recording once)."""
        sess = self.s
        cfg = sess.cfg
        with np.errstate(invalid="ignore", over="ignore"):
            nw = row_norms(w)
            nf = row_norms(f)
            ok = (np.isfinite(t) & (t >= 0.0) & np.isfinite(w[:, 0] + w[:, 1] + w[:, 2])
                  & np.isfinite(f[:, 0] + f[:, 1] + f[:, 2]) & ~(nw > cfg.max_rate_rad_s)
                  & ~(nf > cfg.max_acc_m_s2))
            dt = np.diff(t)
            # a row continues the bulk run when valid and after its predecessor by at most max_gap_s
            cont = ok[1:] & (dt > 0.0) & ~(dt > cfg.max_gap_s)
        return ok, cont

    def push_imu_checked(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, ok: np.ndarray, cont: np.ndarray,
                          wall_s: float | None = None) -> int:
        """``push_imu_arrays`` with the checks of :meth:`_imu_array_checks` done (for these rows, this config)."""
        sess = self.s
        cfg = sess.cfg
        n = t.shape[0]
        brk = np.flatnonzero(~cont) + 1  # rows that cannot continue the run of their predecessor
        accepted = 0
        s = 0
        while s < n:
            newest = sess.newest_imu_t
            if not ok[s] or (newest is not None and not (0.0 < t[s] - newest <= cfg.max_gap_s)) \
                    or self.jump_candidates:
                accepted += self.push_imu(ImuSample(float(t[s]), w[s], f[s]), wall_s)
                s += 1
                continue
            i = int(np.searchsorted(brk, s, side="right"))
            e = int(brk[i]) if i < brk.shape[0] else n
            self._push_imu_run(t[s:e], w[s:e], f[s:e], wall_s)
            accepted += e - s
            s = e
        return accepted

    def _push_imu_run(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, wall_s: float | None) -> None:
        """Buffer valid samples that continue the time line (what ``push_imu`` does for each of them)."""
        sess = self.s
        m = t.shape[0]
        sess.counters["imu_received"] += m
        self.touch(wall_s)
        if wall_s is not None:
            sess.last_imu_wall = wall_s
        t, w, f = t.copy(), w.copy(), f.copy()  # the caller may reuse its arrays
        self.recent_stamps.add_block(t)
        sess.buf.imu.extend(t, w, f)
        first = sess.newest_imu_t is None
        sess.newest_imu_t = float(t[m - 1])
        if first:
            self._check_early_fixes()
        self.check_overflow()

    def _check_early_fixes(self) -> None:
        """The first IMU sample of a time line: fixes and velocities buffered before it (a GNSS reader that matched or
        delivered first) get the ``max_fix_ahead_s`` check they could not get on arrival, with the same counters."""
        sess = self.s
        limit = sess.newest_imu_t + sess.cfg.max_fix_ahead_s
        b = sess.buf
        for times, items, topic, what in ((b.fix_t, b.fix, "gnss", "fix"), (b.vel_t, b.vel, "gnss_vel", "velocity")):
            while times and times[-1] > limit:
                t = times.pop()
                items.pop()
                self.reject(topic, what, f"{topic}_future", f"stamp {t + sess.stamp_offset_s:.6f} is "
                             f"{t - sess.newest_imu_t:.3f} s ahead of the first IMU sample (buffered before it)")

    def push_fix(self, fix: GnssFix, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS position fix (ECEF p_e [m], R_e [m^2]). False if rejected."""
        sess = self.s
        c = sess.counters
        c["gnss_received"] += 1
        self.touch(wall_s)
        t = float(fix.stamp_s)
        reason = check_fix_input(t, fix.p_e, fix.R_e)
        if reason:
            return self.reject_fix("gnss_invalid", reason)
        if sess.processed_t is not None and t < sess.processed_t:
            return self.reject_fix("gnss_stale", f"stamp {t + sess.stamp_offset_s:.6f} is {sess.processed_t - t:.3f} s behind the filter "
                                                  f"time (max_fix_lag_s {sess.cfg.max_fix_lag_s:g} s)")
        key = (t, tuple(np.asarray(fix.p_e, float).ravel().tolist()))
        if key in self.fix_stamps:  # the same stamp and position: a duplicate (another fix at a stamp is not one)
            return self.reject_fix("gnss_duplicate", f"duplicate stamp {t + sess.stamp_offset_s:.6f}")
        if sess.newest_imu_t is not None and t > sess.newest_imu_t + sess.cfg.max_fix_ahead_s:
            return self.reject_fix("gnss_future", f"stamp {t + sess.stamp_offset_s:.6f} is {t - sess.newest_imu_t:.3f} s ahead of the IMU")
        reason = self.screen.check(fix)
        if reason and sess.core is None:  # a filter's fixes: the guard's jump test and NIS gate (fusion.py)
            return self.reject_fix("gnss_implausible", reason)
        self.fix_stamps.append(key)
        i = bisect.bisect(sess.buf.fix_t, t)
        sess.buf.fix_t.insert(i, t)
        sess.buf.fix.insert(i, fix)
        if len(sess.buf.fix_t) > 1000:  # fixes with no IMU to reach them: keep the newest
            del sess.buf.fix_t[0], sess.buf.fix[0]
            c["inputs_dropped"] += 1
        return True

    def push_truth(self, truth: TruthSample) -> None:
        """A reference pose (initialisation in init_mode 'truth', and the Euler errors of the outputs)."""
        sess = self.s
        sess.counters["truth_received"] += 1
        C = np.asarray(truth.C_b_n, float)
        if C.shape != (3, 3) or not np.all(np.isfinite(C)) or not math.isfinite(truth.stamp_s):
            sess.counters["truth_invalid"] += 1
            return
        t = float(truth.stamp_s)
        if t not in sess.buf.truth:
            bisect.insort(sess.buf.truth_t, t)
        sess.buf.truth[t] = truth
        while len(sess.buf.truth_t) > 5000:
            del sess.buf.truth[sess.buf.truth_t.pop(0)]

    def push_truth_table(self, table: "TruthTable", start: int = 0, stop: int | None = None,
                         checked: bool = False) -> None:
        """``push_truth`` for rows ``start:stop`` of a :class:`TruthTable` (the offline path): one vectorised check,
        and a :class:`TruthSample` is built only for the stamps the session reads (initialisation, outputs). Rows that
        are not all valid, new and after the buffered poses go through ``push_truth`` one by one. ``checked``: the
        caller found the whole table valid (:func:`truth_table_valid`) and does not change it."""
        sess = self.s
        b = sess.buf
        stop = len(table.t_s) if stop is None else stop
        m = stop - start
        if m <= 0:
            return
        T = table.t_s[start:stop]
        last = b.truth.last_stamp() if isinstance(b.truth, TruthDict) else None
        if not isinstance(b.truth, TruthDict) or not (checked or truth_table_valid(table, start, stop)) \
                or (last is not None and not T[0] > last):
            for k in range(start, stop):
                self.push_truth(table.sample(k))
            return
        sess.counters["truth_received"] += m
        b.truth.add_block(table, start, stop)  # read in the table until a reader needs them in the dict
        if len(b.truth_t) + b.truth.n_pending <= 5000:
            return
        b.truth.sync()
        k = len(b.truth_t) - 5000
        if k > 0:
            for x in b.truth_t[:k]:
                del b.truth[x]
            del b.truth_t[:k]

    def reject_input(self, topic: str, counter: str, reason: str, wall_s: float | None = None) -> None:
        """Count an input the caller rejected before it became a sample (a message's frame, covariance, status)."""
        sess = self.s
        sess.counters[f"{topic}_received"] += 1
        self.touch(wall_s)
        if topic in ("imu", "gnss"):
            (self.reject_imu if topic == "imu" else self.reject_fix)(counter, reason)
        else:  # wheel_speed, gnss_heading
            self.reject(topic, "sample", counter, reason)

    def touch(self, wall_s: float | None) -> None:
        sess = self.s
        if wall_s is not None:
            sess.last_input_wall = wall_s

    def _remember(self, t: float) -> None:
        self.recent_stamps.add(t)

    def reject(self, topic: str, what: str, counter: str, reason: str) -> bool:
        """Count a rejected input under its own counter and the topic's total; a throttled log line; False."""
        sess = self.s
        sess.counters[counter] += 1
        sess.counters[f"{topic}_rejected"] += 1
        sess.last_reject = f"{topic}: {reason}"
        sess.log("warn", counter, f"rejected {topic} {what}: {reason} ({counter}={sess.counters[counter]})")
        return False

    def reject_imu(self, counter: str, reason: str) -> bool:
        return self.reject("imu", "sample", counter, reason)

    def reject_fix(self, counter: str, reason: str) -> bool:
        return self.reject("gnss", "fix", counter, reason)

    def _jump_candidate(self, sample: ImuSample, dt: float) -> bool:
        """Samples off the time line: a run of self-consistent ones is a real time jump -> reset."""
        sess = self.s
        c = self.jump_candidates
        t = float(sample.stamp_s)
        if c and not (0.0 < t - c[-1].stamp_s <= sess.cfg.max_gap_s):
            c.clear()
        c.append(sample)
        if len(c) < sess.cfg.time_jump_confirm:
            return self.reject_imu("imu_out_of_order" if dt < 0 else "imu_future",
                                    f"stamp {t + sess.stamp_offset_s:.6f} is {dt:+.3f} s from the newest "
                                    f"{sess.newest_imu_t + sess.stamp_offset_s:.6f}")
        kind = "backward" if dt < 0 else "forward"
        run = list(c)
        resets = sess.counters["time_resets"] + 1
        sess.log("warn", "time_reset", f"time jumped {kind} by {dt:+.3f} s (from {sess.newest_imu_t + sess.stamp_offset_s:.6f} to "
                                       f"{t + sess.stamp_offset_s:.6f}, {len(run)} consistent samples): resetting the alignment")
        sess._reset_state(f"time jumped {kind} by {dt:+.3f} s")
        sess.counters["time_resets"] = resets
        # the earlier candidates were counted as rejected; the run starts the new time line
        for s in run:
            self._remember(s.stamp_s)
            sess.buf.imu.append(float(s.stamp_s), np.asarray(s.omega_ib_b, float), np.asarray(s.f_ib_b, float))
        sess.newest_imu_t = float(run[-1].stamp_s)
        return True

    def push_velocity(self, vel: GnssVelocity, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS velocity (ENU antenna velocity relative to Earth v_n [m/s], covariance R_n
        [m^2/s^2]); fused at its own stamp like a fix (same buffer rule, same fusion delay). False if rejected."""
        sess = self.s
        c = sess.counters
        c["gnss_vel_received"] += 1
        self.touch(wall_s)
        t = float(vel.stamp_s)
        reason = check_velocity_input(t, vel.v_n, vel.R_n)
        if reason:
            return self.reject("gnss_vel", "velocity", "gnss_vel_invalid", reason)
        if sess.processed_t is not None and t < sess.processed_t:
            return self.reject("gnss_vel", "velocity", "gnss_vel_stale",
                                f"stamp {t + sess.stamp_offset_s:.6f} is {sess.processed_t - t:.3f} s behind the filter time "
                                f"(max_fix_lag_s {sess.cfg.max_fix_lag_s:g} s)")
        if t in sess.buf.vel_t:
            return self.reject("gnss_vel", "velocity", "gnss_vel_duplicate", f"duplicate stamp {t + sess.stamp_offset_s:.6f}")
        if sess.newest_imu_t is not None and t > sess.newest_imu_t + sess.cfg.max_fix_ahead_s:
            return self.reject("gnss_vel", "velocity", "gnss_vel_future",
                                f"stamp {t + sess.stamp_offset_s:.6f} is {t - sess.newest_imu_t:.3f} s ahead of the IMU")
        i = bisect.bisect(sess.buf.vel_t, t)
        sess.buf.vel_t.insert(i, t)
        sess.buf.vel.insert(i, GnssVelocity(t, np.asarray(vel.v_n, float), np.asarray(vel.R_n, float)))
        if len(sess.buf.vel_t) > 1000:  # velocities with no IMU to reach them: keep the newest
            del sess.buf.vel_t[0], sess.buf.vel[0]
            c["inputs_dropped"] += 1
        return True

    def push_wheel_speed(self, ws: WheelSpeed, wall_s: float | None = None) -> bool:
        """Validate and buffer one wheel speed (along the vehicle's x axis [m/s], its variance [m^2/s^2])."""
        t, speed, var = float(ws.stamp_s), float(ws.speed_m_s), float(ws.var_m2_s2)
        reason = check_scalar_input(t, speed, var, MAX_WHEEL_SPEED_M_S, "speed_m_s", "m/s")
        b = self.s.buf
        return self._push_scalar("wheel_speed", reason, t, WheelSpeed(t, speed, var), b.wheel_t, b.wheel, wall_s)

    def push_gnss_heading(self, hd: GnssHeading, wall_s: float | None = None) -> bool:
        """Validate and buffer one dual-antenna GNSS heading (baseline yaw, ENU [rad], its variance [rad^2])."""
        t, yaw, var = float(hd.stamp_s), float(hd.yaw_rad), float(hd.var_rad2)
        reason = check_scalar_input(t, yaw, var, 4.0 * math.pi, "yaw_rad", "rad")
        if not reason and not var < math.pi ** 2:
            reason = f"var_rad2: {var:.3g} rad^2 (1-sigma above 180 deg: no heading)"
        b = self.s.buf
        return self._push_scalar("gnss_heading", reason, t, GnssHeading(t, math.remainder(yaw, 2.0 * math.pi), var),
                                 b.heading_t, b.heading, wall_s)

    def _push_scalar(self, topic: str, reason: str, t: float, item, ts: list, items: list, wall_s) -> bool:
        """The stamp rules of the velocities for a wheel speed or a GNSS heading, then the stamp-ordered buffer."""
        sess = self.s
        c = sess.counters
        c[f"{topic}_received"] += 1
        self.touch(wall_s)
        if reason:
            return self.reject(topic, "sample", f"{topic}_invalid", reason)
        if sess.processed_t is not None and t < sess.processed_t:
            return self.reject(topic, "sample", f"{topic}_stale", f"stamp {t + sess.stamp_offset_s:.6f} is "
                               f"{sess.processed_t - t:.3f} s behind the filter time")
        if t in ts:
            return self.reject(topic, "sample", f"{topic}_duplicate", f"duplicate stamp {t + sess.stamp_offset_s:.6f}")
        if sess.newest_imu_t is not None and t > sess.newest_imu_t + sess.cfg.max_fix_ahead_s:
            return self.reject(topic, "sample", f"{topic}_future", f"stamp {t + sess.stamp_offset_s:.6f} is "
                               f"{t - sess.newest_imu_t:.3f} s ahead of the IMU")
        i = bisect.bisect(ts, t)
        ts.insert(i, t)
        items.insert(i, item)
        if len(ts) > 1000:  # no IMU to reach them: keep the newest
            del ts[0], items[0]
            c["inputs_dropped"] += 1
        return True


#: a wheel speed above this [m/s] is not a vehicle's (500 km/h)
MAX_WHEEL_SPEED_M_S = 140.0


def check_scalar_input(t: float, value: float, var: float, max_abs: float, name: str, unit: str) -> str:
    """Checks of one scalar measurement: finite stamp >= 0, a finite value within +-max_abs, a finite variance > 0."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    if not math.isfinite(value):
        return f"{name}: not a finite number ({value!r})"
    if abs(value) > max_abs:
        return f"{name}: {value:.4g} {unit} beyond +-{max_abs:.4g} {unit}"
    if not (math.isfinite(var) and var > 0.0):
        return f"variance {var!r}: not a finite number > 0"
    return ""


def check_fix_input(t: float, p_e, R_e) -> str:
    """Checks of one GNSS position fix: finite stamp >= 0, a finite ECEF position (3,) within 100 km of the Earth's
    surface, a symmetric positive semi-definite covariance (3, 3) with positive variances."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    p = np.asarray(p_e, float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return f"p_e: not 3 finite numbers ({np.array2string(p.ravel()[:6], precision=3)})"
    r = float(np.linalg.norm(p))
    if not 6.25e6 < r < 6.5e6:
        return f"p_e: {r:.4g} m from the Earth's centre (not within 100 km of its surface)"
    R = np.asarray(R_e, float)
    if R.shape != (3, 3):
        return f"R_e: shape {R.shape} instead of (3, 3)"
    return check_covariance(R, "R_e", require_positive_diag=True) or ""


def check_velocity_input(t: float, v_n, R_n) -> str:
    """Checks of one GNSS velocity: finite stamp, the core's checks (filters/liekf.check_velocity), plausible speed."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    reason = check_velocity(v_n, R_n)
    if not reason and float(np.linalg.norm(v_n)) > MAX_GNSS_SPEED_M_S:
        reason = f"speed {np.linalg.norm(v_n):.3g} m/s > {MAX_GNSS_SPEED_M_S:g} m/s"
    return reason


def check_imu(t: float, w, f, max_rate: float, max_acc: float) -> str:
    """Scalar checks of one IMU sample (hot path: plain floats, no numpy reductions)."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
    fx, fy, fz = float(f[0]), float(f[1]), float(f[2])
    if not math.isfinite(wx + wy + wz):
        return "angular_velocity: non-finite value"
    if not math.isfinite(fx + fy + fz):
        return "linear_acceleration: non-finite value"
    nw = math.sqrt(wx * wx + wy * wy + wz * wz)
    if nw > max_rate:
        return f"angular_velocity: magnitude {nw:.3g} > {max_rate:.3g}"
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    if nf > max_acc:
        return f"linear_acceleration: magnitude {nf:.3g} > {max_acc:.3g}"
    return ""
