"""The schedule: what is fused when. Fixes and GNSS velocities at their own stamps (through the outlier gate of the
divergence guard), zero-velocity updates for static cores, backtracking passes in the background.

docs/session.md, "Schedule"."""

from __future__ import annotations

import bisect
import math

import numpy as np

from ..core.types import GnssFix, GnssVelocity
from ..filters.measurements import GnssPosition, ZeroVelocity
from ..filters.measurements import GnssVelocity as GnssVelocityModel
from ..filters.vehicle_models import GnssHeading as GnssHeadingModel
from ..filters.vehicle_models import NonHolonomic  # (importing it registers the vehicle models' Jacobians)
from ..filters.vehicle_models import WheelSpeed as WheelSpeedModel
from .fix_line import fix_point
from .heading_check import HeadingCheck
from .outputs import Output
from .wheel_scale import WheelScale


#: the non-holonomic constraint of a land vehicle (``vehicle``): rate [Hz data time], lateral and vertical 1-sigma
#: [m/s] (side-slip of a few degrees, the IMU's lever arm to the rear axle in a turn: 1.5 m at 20 deg/s is 0.5 m/s;
#: the suspension), chi-square gate (2 dof, p = 1e-3); that many rejections in a row switch it off for NHC_OFF_S
NHC_RATE_HZ = 10.0
#: (lateral, vertical) 1-sigma [m/s] of the constraint per vehicle; the vertical row is left out (inf): it ties the
#: IMU's pitch to the vehicle's direction of travel, so an IMU mounted a few tenths of a degree pitched on the vehicle
#: gets a pitch 3-sigma that does not cover it (KITTI 0042 with the vertical row at 0.3 m/s: pitch 0.42 deg off at a
#: 3-sigma of 0.30, inside it for 37 % of the flag-up time; without: 94 %; docs/yaw_gsf.md)
NHC_SIGMA_M_S = {"car": (0.5, math.inf), "wheeled_robot": (0.3, math.inf)}
NHC_NIS_GATE = {1: 10.83, 2: 13.82}  # chi-square 0.999 quantile by the rows used
NHC_OFF_AFTER = 10
NHC_OFF_S = 10.0
#: the vehicle does not drive like the declared ``vehicle``: more than this fraction of at least NHC_MISFIT_MIN tests
#: (the simulated ship with vehicle car: 40-70 %; simulated and KITTI cars: under 0.1 %)
#: failed the gate (a boat declared a car; an IMU mounted off the vehicle's axes): the constraint stays off
NHC_MISFIT_FRACTION = 0.3
NHC_MISFIT_MIN = 100
#: wheel speed: the scale factor's error is one bias shared by every wheel speed, not white noise; fused at 10 Hz
#: as white noise it would average down and make the core's forward velocity over-confident (simulated car, seed
#: 2, scale prior 5 %: the divergence guard's CUSUM tripped 90 s in). Its variance is counted once per this span of
#: data [s] (the filter's memory of the forward velocity between fixes): (sigma_s * speed)^2 x span / interval
WHEEL_SCALE_MEMORY_S = 10.0


class Fusion:
    """Feeds the core: IMU samples, fixes, velocities and zero-velocity updates, in stamp order."""

    def __init__(self, session) -> None:
        self.s = session
        self.heading_check = HeadingCheck(session)  # the dual-antenna heading against the IMU (kept across resets)
        self.wheel_scale = WheelScale(session)  # the wheel odometry's scale factor (the vehicle's: kept across resets)

    def reset(self) -> None:
        self.wheel_scale.restart()

    def propagate(self, t_s, omega_ib_b, f_ib_b) -> None:
        """IMU samples as arrays (one sample: length 1) to the core, or to the backtracking driver that records
        them for its passes."""
        sess = self.s
        sess._est_memo = None
        (sess.bt if sess.bt is not None else sess.core).propagate(t_s, omega_ib_b, f_ib_b)

    def apply_due_fixes(self, out: list[Output]) -> None:
        sess = self.s
        if sess.core is not None and sess.processed_t is not None:
            self.apply_fixes_until(sess.processed_t, out)

    def apply_fixes_until(self, t: float, out: list[Output]) -> None:
        sess = self.s
        b = sess.buf
        while b.fix_t and b.fix_t[0] <= t and sess.core is not None:
            b.fix_t.pop(0)
            fix = b.fix.pop(0)
            sess.yaw_seed.fix(fix)
            if fix.stamp_s == sess._used_fix_stamp:
                sess.guard.fix_seq.append(fix_point(fix))  # divergence guard: the jump test goes on from the init's fixes
                continue  # gave the initial position: not fused twice
            if fix.stamp_s < sess.init_t:
                sess.counters["gnss_before_init"] += 1
                sess.guard.fix_seq.append(fix_point(fix))  # divergence guard (as above)
                continue
            sess._est_memo = None
            self._fuse_fix(fix)
        self._apply_velocities_until(t)
        self._apply_aux_until(t)

    def _apply_aux_until(self, t: float) -> None:
        """Wheel speeds and GNSS headings at their stamps (after the fixes and velocities up to ``t``)."""
        sess = self.s
        b = sess.buf
        while b.wheel_t and b.wheel_t[0] <= t and sess.core is not None:
            b.wheel_t.pop(0)
            self.fuse_wheel_speed(b.wheel.pop(0))
        while b.heading_t and b.heading_t[0] <= t and sess.core is not None:
            b.heading_t.pop(0)
            self.fuse_heading(b.heading.pop(0))

    # -- the fusion of the vehicle's own sensors through their measurement models (filters/vehicle_models.py)
    def wheel_speed_used(self) -> bool:
        """Wheel speeds are fused: ``vehicle`` car or wheeled_robot and a core that accepts the WheelSpeed model."""
        sess = self.s
        return (sess.cfg.vehicle in NHC_SIGMA_M_S and sess.core is not None and sess.bt is None
                and WheelSpeedModel in sess.core.accepts)

    def fuse_wheel_speed(self, ws) -> None:
        """One wheel speed (core.types.WheelSpeed: along the vehicle's x axis [m/s]) at its stamp, for ``vehicle`` car
        or wheeled_robot: the scale stage integrates it (session/wheel_scale.py), then the core fuses it as the
        WheelSpeed model with the scale's estimate and 1-sigma (its own NIS gate, 1 dof); else counted as unused. At a
        stop it reads 0: the forward velocity is held at 0 (the constraint keeps the lateral one), which is the
        only stop evidence taken from it (no zero-velocity update: the in-motion cores get none from the session)."""
        sess = self.s
        c = sess.counters
        if not self.wheel_speed_used():
            c["wheel_speed_unused"] += 1
            return
        sc = self.wheel_scale
        dt = sc.interval_s(ws.stamp_s)
        sc.on_wheel(ws, sess.outputs.estimate())
        sess._est_memo = None
        sigma_s = sc.sigma * math.sqrt(max(1.0, WHEEL_SCALE_MEMORY_S / dt))
        res = sess.core.update(WheelSpeedModel(ws.stamp_s, ws.speed_m_s, ws.var_m2_s2, sc.scale, sigma_s))
        if res.accepted:
            c["wheel_speed_fused"] += 1
            return
        c["wheel_speed_filter_rejected"] += 1
        sess.last_reject = f"wheel_speed: {res.reason}"

    def fuse_heading(self, heading) -> None:
        """One dual-antenna GNSS heading (core.types.GnssHeading: the baseline's ENU yaw along the body x axis) at its
        stamp, fused in the cores that accept the GnssHeading model; else counted as unused."""
        sess = self.s
        core = sess.core
        if GnssHeadingModel not in core.accepts or sess.bt is not None:
            sess.counters["gnss_heading_unused"] += 1
            return
        sess._est_memo = None
        b = math.radians(sess.cfg.gnss_heading_baseline_yaw_deg)  # the declared mounting of the antenna baseline
        res = core.update(GnssHeadingModel(heading.stamp_s, heading.yaw_rad, math.sqrt(heading.var_rad2),
                                           baseline_b=(math.cos(b), math.sin(b), 0.0)))
        sess.counters["gnss_heading_fused" if res.accepted else "gnss_heading_filter_rejected"] += 1
        if not res.accepted:
            sess.last_reject = f"gnss_heading: {res.reason}"
        self.heading_check.on_result(res, heading.var_rad2)

    def nhc_due(self, t: float) -> bool:
        """A non-holonomic constraint is due at ``t`` (``vehicle`` car or wheeled_robot, a core that accepts it)."""
        sess = self.s
        return (t >= sess.next_nhc_t and sess.cfg.vehicle in NHC_SIGMA_M_S and sess.bt is None
                and NonHolonomic in sess.core.accepts and sess.nhc_off_until_t <= t)

    def nhc(self, t: float) -> None:
        """The non-holonomic constraint at ``t`` (NHC_RATE_HZ): lateral and vertical velocity of the vehicle ~ 0 with
        the vehicle's sigmas and a chi-square gate; NHC_OFF_AFTER rejections in a row (skidding, the IMU not on the
        vehicle's axes) switch it off for NHC_OFF_S, said in the status."""
        sess = self.s
        sess._est_memo = None
        lat, vert = NHC_SIGMA_M_S[sess.cfg.vehicle]
        m = NonHolonomic(t, lat, vert)
        m.nis_gate = NHC_NIS_GATE[len(m.rows)]
        res = sess.core.update(m)
        sess.next_nhc_t = t + 1.0 / NHC_RATE_HZ - 1e-9
        c = sess.counters
        if res.accepted:
            c["nhc_accepted"] += 1
            sess.nhc_rejected_run = 0
            return
        c["nhc_rejected"] += 1
        sess.nhc_rejected_run += 1
        tests = c["nhc_accepted"] + c["nhc_rejected"]
        if tests >= NHC_MISFIT_MIN and c["nhc_rejected"] > NHC_MISFIT_FRACTION * tests and not sess.nhc_misfit:
            sess.nhc_misfit = (f"vehicle {sess.cfg.vehicle!r} does not fit the motion: the non-holonomic constraint "
                               f"failed its gate in {c['nhc_rejected']} of {tests} tests; it is off for the rest of the "
                               f"run (is the vehicle a {sess.cfg.vehicle.replace('_', ' ')}, and the IMU on its axes: "
                               f"imu_mount_rpy_deg?)")
            sess.nhc_off_until_t = math.inf
            c["nhc_misfit"] += 1
            sess.log("warn", "nhc_misfit", sess.nhc_misfit)
            return
        if sess.nhc_rejected_run >= NHC_OFF_AFTER:
            sess.nhc_off_until_t = t + NHC_OFF_S
            sess.nhc_rejected_run = 0
            c["nhc_switched_off"] += 1
            sess.log("warn", "nhc_off", f"t={t:.2f} s: {NHC_OFF_AFTER} non-holonomic constraints in a row failed "
                                        f"their gate ({res.reason}): the vehicle slides or the IMU is not on its axes "
                                        f"(imu_mount_rpy_deg); constraint off for {NHC_OFF_S:g} s")
    # -- end of the vehicle sensors' fusion

    def _fuse_fix(self, fix: GnssFix) -> None:
        sess = self.s
        core = sess.core
        fix = GnssPosition.of(fix)
        if GnssPosition not in core.accepts:
            sess.counters["gnss_unused"] += 1
            core.update(fix)  # not fused (core: auto's motion detector takes the GNSS speed)
            return
        gate = sess.cfg.gnss_gate_nis
        excess = sess.guard.fix_jump(fix)  # -inf: no two fixes before it to tell
        jump = excess > 0
        fix = GnssPosition.of(sess.guard.floored(fix))  # divergence guard: the model's error budget under the receiver's sigma
        if jump and sess.guard.restart_young_reinit():  # divergence guard
            return
        if jump and gate > 0 and sess.guard.hold_since is None and not sess.monitor.attitude_claimed():
            # a jump before the claim: a young filter's covariance lets it through any NIS gate (a fix stamped 5 s
            # ahead with the position of now: 60 m on a car, NIS < 100); not fused (the fix screen's rule), and the
            # jump test goes on from the fixes before it (a lone outlier does not make the next fix a jump; a real
            # shift is fused once the fixes before it are more than 3 s old)
            sess.guard.fix_seq.pop()
            sess.counters["gnss_gated"] += 1
            sess.counters["gnss_rejected"] += 1
            sess.last_reject = "gnss: a jump in the fix sequence before the filter claims its attitude"
            sess.log("warn", "gnss_gated", f"fix at {fix.stamp_s + sess.stamp_offset_s:.3f} s not fused: "
                                           f"{sess.last_reject[6:]} (gnss_gated={sess.counters['gnss_gated']})")
            return
        if excess == -math.inf and gate > 0 and sess.guard.hold_since is None \
                and not sess.monitor.attitude_claimed() and self._fix_off(fix):
            return
        # a jump in the fix sequence is suspect by itself: gated even while the core does not claim its attitude
        if gate > 0 and (sess.monitor.attitude_claimed() or jump or sess.guard.hold_since is not None):
            pr = core.predict(fix)
            if pr.S.size and pr.nis > gate:
                sess.counters["gnss_gated"] += 1
                sess.counters["gnss_rejected"] += 1
                sess.guard.gated_run += 1
                sess.last_reject = f"gnss: NIS {pr.nis:.3g} above the gate {gate:g} (|innovation| {np.linalg.norm(pr.innovation):.3g} m)"
                sess.log("warn", "gnss_gated", f"fix gated: {sess.last_reject[6:]} ({sess.guard.gated_run} in a row, "
                                               f"gnss_gated={sess.counters['gnss_gated']})")
                # an implausible fix while the core claims its attitude: the claim cannot be trusted now
                sess.monitor.lower_flag(f"a fix failed the NIS gate ({sess.guard.gated_run} in a row)")
                if sess.guard.hold(fix, jump, pr.nis, float(np.linalg.norm(pr.innovation))):
                    return
                if sess.guard.gated_run_evidence(pr.nis, len(pr.innovation) or 3):  # divergence guard
                    return
                if sess.guard.gated_run >= sess.cfg.gnss_gate_max_consecutive:
                    sess._diverged(f"{sess.guard.gated_run} consecutive fixes beyond the NIS gate (last NIS {pr.nis:.3g}), "
                                   "continuous with the fixes before them: the filter is lost")
                return
        sess.guard.gated_run = 0
        if sess.guard.hold_since is not None:
            sess.log("info", "gnss_hold", f"GNSS agrees with the held filter again after "
                                          f"{fix.stamp_s - sess.guard.hold_since:.1f} s: fusing fixes")
            sess.guard.hold_since = None
        res = (sess.bt if sess.bt is not None else core).update(fix)
        sess._est_memo = None
        if res is None:
            return
        sess.last_nis = res.nis
        if res.accepted and sess.guard.nis_diverged(res.nis, len(res.innovation) or 3):
            return
        if res.accepted:
            sess.counters["gnss_accepted"] += 1
            sess.last_accepted_fix_t = fix.stamp_s
            if sess.cfg.vehicle in NHC_SIGMA_M_S and sess.bt is None:
                self.wheel_scale.on_fix(fix, sess.outputs.estimate())  # a window boundary of the wheel scale
            sess.grade_check.on_fix(res.nis, len(res.innovation) or 3)  # does the imu_grade fit the innovations?
        else:
            sess.counters["gnss_filter_rejected"] += 1
            sess.counters["gnss_rejected"] += 1
            sess.last_reject = f"gnss: core: {res.reason}"
            sess.log("warn", "gnss_filter_rejected", f"fix rejected by the core: {res.reason}")
        sess.flag.on_update(sess.processed_t, res.accepted, res.nis, len(res.innovation) or 3)

    def _apply_velocities_until(self, t: float) -> None:
        sess = self.s
        b = sess.buf
        while b.vel_t and b.vel_t[0] <= t and sess.core is not None:
            b.vel_t.pop(0)
            vel = b.vel.pop(0)
            sess.yaw_seed.velocity(vel)
            if vel.stamp_s == sess._used_vel_stamp:
                continue  # gave the initial velocity (session/initialiser.py): not fused twice
            if vel.stamp_s < sess.init_t:
                sess.counters["gnss_vel_before_init"] += 1
                continue
            sess._est_memo = None
            self._fuse_velocity(vel)

    def _fuse_velocity(self, vel: GnssVelocity) -> None:
        """One GNSS velocity into the core: the NIS gate of the fixes (while the attitude is claimed, or at a jump in
        the velocity sequence: guard.velocity_jump), then the core's update; the flag's NIS window sees its NIS like
        a fix's."""
        sess = self.s
        core, c = sess.core, sess.counters
        vel = GnssVelocityModel.of(vel)
        if GnssVelocityModel not in core.accepts or sess.bt is not None:
            c["gnss_vel_unused"] += 1
            if sess.bt is None:
                core.update(vel)  # not fused (core: auto's motion detector takes the speed while parked)
            return
        gate = sess.cfg.gnss_gate_nis
        jump = sess.guard.velocity_jump(vel)  # a jump in the velocity sequence opens the gate before the claim
        claimed = sess.monitor.attitude_claimed()
        if gate > 0 and (claimed or jump > 0):
            pr = core.predict(vel)
            if pr.S.size and pr.nis > gate:
                sess.inputs.reject("gnss_vel", "velocity", "gnss_vel_gated", f"NIS {pr.nis:.3g} above the gate {gate:g} "
                             f"(|innovation| {np.linalg.norm(pr.innovation):.3g} m/s" +
                             (f"; {jump:.3g} m/s beyond its sequence)" if jump > 0 else ")"))
                sess.monitor.lower_flag("a GNSS velocity failed the NIS gate")
                return
        if gate > 0 and not claimed and self._speed_off(vel):  # (a yaw bank has no NIS to gate before the claim)
            return
        sess.guard.velocity_let_in(vel)
        res = core.update(sess.guard.floored_velocity(vel))
        sess._est_memo = None  # the floor read the estimate before the update
        if res.accepted:
            c["gnss_vel_accepted"] += 1
        else:
            c["gnss_vel_filter_rejected"] += 1
            c["gnss_vel_rejected"] += 1
            sess.last_reject = f"gnss_vel: core: {res.reason}"
            sess.log("warn", "gnss_vel_filter_rejected", f"GNSS velocity rejected by the core: {res.reason}")
        sess.flag.on_update(sess.processed_t, res.accepted, res.nis, len(res.innovation) or 3)

    def _speed_off(self, vel: GnssVelocityModel) -> bool:
        """Before the claim: a velocity whose speed is off the filter's (guard.speed_off) is rejected (gnss_vel_gated),
        unless it is the guard's SPEED_OFF_BELIEVED-th in a row (then the filter's speed is what is wrong)."""
        sess = self.s
        g = sess.guard
        w = sess.loop.hist_w[-1] if sess.loop.hist_w else np.zeros(3)
        off = g.speed_off(vel, sess.outputs.estimate(), float(np.linalg.norm(w)) * self._lever_m())
        if not off > 0:
            return False
        g.speed_off_run += 1
        if g.speed_off_run >= g.SPEED_OFF_BELIEVED:
            sess.log("warn", "gnss_vel_speed", f"{g.speed_off_run} GNSS velocities in a row off the filter's speed: "
                                                "believed (the filter's speed is what is wrong)")
            return False
        sess.inputs.reject("gnss_vel", "velocity", "gnss_vel_gated", f"speed {off:.3g} m/s off the filter's beyond 5 "
                           "sigma of both (before the heading is known only the speed is tested)")
        return True

    def _fix_off(self, fix: GnssPosition) -> bool:
        """Before the claim, where the jump test cannot tell (no two fixes within 3 s before it: the first fixes after
        an initialisation or a driver's restart): a fix off the filter's position beyond what any attitude error allows
        (guard.fix_off) is not fused (gnss_gated) and leaves the jump test's sequence (a lone outlier is no reference);
        the guard's FIX_OFF_BELIEVED-th in a row is believed: the filter's position is what is wrong (a divergence,
        re-initialisation from the sensors)."""
        sess = self.s
        g = sess.guard
        fixed = [t for t in (sess.init_t, sess.last_accepted_fix_t) if t is not None and t <= fix.stamp_s]
        off = g.fix_off(fix, sess.outputs.estimate(), self._lever_m(), fix.stamp_s - max(fixed, default=fix.stamp_s))
        if not off > 0:
            g.fix_off_run = 0
            return False
        g.fix_off_run += 1
        if g.fix_off_run >= g.FIX_OFF_BELIEVED:
            sess._diverged(f"{g.fix_off_run} fixes in a row off the filter's position ({off:.3g} m beyond what any "
                           "attitude error allows): its position is what is wrong")
            return True
        g.fix_seq.pop()
        sess.counters["gnss_gated"] += 1
        sess.counters["gnss_rejected"] += 1
        sess.last_reject = f"gnss: {off:.3g} m off the filter's position beyond what any attitude error allows"
        sess.log("warn", "gnss_gated", f"fix at {fix.stamp_s + sess.stamp_offset_s:.3f} s not fused before the filter "
                                       f"claims its attitude: {sess.last_reject[6:]} (gnss_gated={sess.counters['gnss_gated']})")
        return True

    def _lever_m(self) -> float:
        """|l| [m], the configured GNSS antenna lever arm's length (0 when none)."""
        return float(np.linalg.norm(self.s.core_params.get("gnss_lever_arm_b_m") or (0.0, 0.0, 0.0)))

    def zupt_due(self, t: float) -> bool:
        sess = self.s
        c = sess.core
        return (sess.cfg.zupt_rate_hz > 0 and t >= sess.next_zupt_t and not c.schedules_own_zero_velocity
                and ZeroVelocity in c.accepts and GnssPosition not in c.accepts)

    def zupt(self, t: float) -> None:
        self.s._est_memo = None
        self.zupt_done(t, self.s.core.update(self.zupt_model(t)))

    def zupt_model(self, t: float) -> ZeroVelocity:
        return ZeroVelocity(t, self.s.cfg.zupt_sigma_m_s)

    def zupt_rows(self, Tl: list, lo: int, hi: int) -> list:
        """The rows ``lo:hi`` of the stamps ``Tl`` at which scheduled zero-velocity updates fall due, if each is made
        (``zupt_done``) before the next row (the session's schedule: the first sample at or after ``next_zupt_t``,
        the next one period later)."""
        rows, nxt, period = [], self.s.next_zupt_t, 1.0 / self.s.cfg.zupt_rate_hz
        k = bisect.bisect_left(Tl, nxt, lo, hi)
        while k < hi:
            rows.append(k)
            nxt = Tl[k] + period - 1e-9
            k = bisect.bisect_left(Tl, nxt, k + 1, hi)
        return rows

    def zupt_done(self, t: float, res) -> None:
        """The session's side of a zero-velocity update at ``t`` that the core made (result ``res``): the schedule,
        the counter, the flag's NIS window."""
        sess = self.s
        sess.next_zupt_t = t + 1.0 / sess.cfg.zupt_rate_hz - 1e-9
        if res.accepted:
            sess.counters["zupt_accepted"] += 1
        sess.flag.on_update(t, res.accepted, res.nis, len(res.innovation) or 3, source="zupt")

    def background(self, budget_s: float) -> None:
        sess = self.s
        if sess.bt is None or not sess.bt.busy:
            return
        try:
            if budget_s == math.inf:
                sess.bt.run_until_done()
            else:
                sess.bt.step_background(budget_s)
            self.after_handover()
        except Exception as exc:  # noqa: BLE001
            sess._fault(exc)

    def after_handover(self) -> None:
        sess = self.s
        if sess.bt is not None and sess.bt.live is not sess.core:
            old = sess.core
            sess.core = sess.bt.live
            if old is not None:
                old.close()
            sess.log("info", "backtrack", "backtracking: handed over to the re-aligned core")
