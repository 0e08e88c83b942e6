"""Flag and status: the aligned flag's moves outside its criteria (lowered at once on evidence), the watchdog, and
what the session reports (status level, message, diagnostics)."""

from __future__ import annotations

import numpy as np

from ..filters.base import AlignmentStatus
from ..filters.measurements import GnssPosition
from ..filters.imu_grade import DEFAULT_IMU_GRADE


class Monitor:
    """The flag's evidence-driven drops, the watchdog, and the status a user reads."""

    def __init__(self, session) -> None:
        self.s = session

    def reset(self) -> None:
        pass

    def attitude_claimed(self, factor: float = 2.0) -> bool:
        """The core claims to know its attitude: 3-sigma within ``factor`` (2) times the flag's bounds at the last
        output."""
        sess = self.s
        s = sess.flag.sigma3_deg
        c = sess.flag.criteria
        return bool(np.all(np.isfinite(s)) and max(s[0], s[1]) < factor * c.roll_pitch_3sigma_deg
                    and s[2] < factor * c.yaw_3sigma_deg)

    def lower_flag(self, reason: str) -> None:
        """Drop the flag at once; it rises again only after the criteria hold for hold_s again."""
        sess = self.s
        sess.flag.holding_since_s = None
        if sess.flag.aligned:
            sess.flag.aligned = False
            sess.flag.reason = reason
            sess.flag_changes.append((sess.processed_t or 0.0, False, reason))
            sess.log("info", "flag", f"aligned flag lowered at t={(sess.processed_t or 0.0) + sess.stamp_offset_s:.3f} s: "
                                     f"{reason}")

    def watchdog(self, wall_s: float) -> None:
        sess = self.s
        to = sess.cfg.imu_timeout_s
        if to <= 0 or sess.last_imu_wall is None:
            return
        silent = wall_s - sess.last_imu_wall
        if silent > to:
            if not sess.watchdog_reason:
                sess.counters["watchdog_trips"] += 1
                sess.log("warn", "watchdog", f"no IMU sample for {silent:.1f} s (imu_timeout_s {to:g} s): "
                                             "aligned flag lowered")
            sess.watchdog_reason = f"no IMU sample for {silent:.1f} s"
            if sess.flag.aligned:
                sess.flag.aligned = False
                sess.flag.holding_since_s = None
                sess.flag_changes.append((sess.processed_t or 0.0, False, sess.watchdog_reason))
        else:
            sess.watchdog_reason = ""

    def level(self) -> int:
        """Diagnostic level: 0 OK (aligned, fresh inputs), 1 WARN, 2 ERROR (fault)."""
        sess = self.s
        if sess.status == AlignmentStatus.FAULT:
            return 2
        if sess.watchdog_reason or not sess.aligned or self.gnss_age_warning():
            return 1
        return 0

    def gnss_age_warning(self) -> str:
        sess = self.s
        if sess.core is None or GnssPosition not in sess.core.accepts or sess.processed_t is None:
            return ""
        ref = sess.last_accepted_fix_t if sess.last_accepted_fix_t is not None else sess.init_t
        age = sess.processed_t - ref
        return f"no GNSS fix for {age:.0f} s" if age > sess.cfg.gnss_timeout_s else ""

    def message(self) -> str:
        sess = self.s
        parts = [f"{sess.status.value}: {sess.reason}"]
        if sess.watchdog_reason:
            parts.append(sess.watchdog_reason)
        g = self.gnss_age_warning()
        if g:
            parts.append(g)
        if sess.grade_check.note:
            parts.append(sess.grade_check.note)
        if sess.nhc_misfit:
            parts.append(sess.nhc_misfit)
        if sess.fusion.heading_check.note:
            parts.append(sess.fusion.heading_check.note)
        if sess.counters["wheel_speed_fused"]:
            w = sess.fusion.wheel_scale
            parts.append(f"wheel speed fused, scale {w.scale:.4f} +- {w.sigma:.4f} (1-sigma, {w.windows} GNSS windows)")
        if not sess.aligned and "3-sigma" in sess.flag.reason and sess.cfg.imu_grade == DEFAULT_IMU_GRADE:
            # the conservative default prior is often why the 3-sigma stays up: say what the user can do
            parts.append(f"imu_grade is the conservative default {DEFAULT_IMU_GRADE!r}: give your IMU's grade "
                         "(docs/imu_grades.md) for a tighter, still honest, covariance")
        return "; ".join(parts)

    def diagnostics(self) -> dict:
        """Key/value pairs for /diagnostics and the metrics JSON (strings, numbers, lists)."""
        sess = self.s
        d: dict = {"core": sess.cfg.core, "state": sess.status.value, "reason": sess.reason,
                   "aligned": str(sess.aligned).lower(), "aligned_reason": sess.flag.reason,
                   "message": self.message()}
        o = sess.last_output
        if o is not None:
            s = sess.flag.sigma3_deg
            d.update(yaw_3sigma_deg=f"{s[2]:.4f}", roll_pitch_3sigma_deg=f"{max(s[0], s[1]):.4f}",
                     yaw_sigma_deg=f"{s[2] / 3:.4f}", filter_time_s=f"{o.stamp_s + sess.stamp_offset_s:.3f}")
        if sess.flag.raised_at_s is not None:
            d["aligned_raised_at_s"] = f"{sess.flag.raised_at_s + sess.stamp_offset_s:.3f}"
            d["aligned_first_raised_at_s"] = f"{sess.flag.first_raised_at_s + sess.stamp_offset_s:.3f}"
        if o is not None:
            d["aligned_at_last_output"] = str(o.aligned).lower()  # the flag at the newest data (before any watchdog)
        if sess.init_t is not None:
            d["initialised_at_s"] = f"{sess.init_t + sess.stamp_offset_s:.3f}"
        lo, hi = sess.flag.band
        d.update(nis_last=f"{sess.last_nis:.3f}", nis_window_sum=f"{sess.flag.nis_sum:.3f}",
                 nis_band=f"[{lo:.2f}, {hi:.2f}]", last_reject=sess.last_reject)
        # divergence guard: the statistics behind a FAULT (docs/session.md)
        d["divergence_cusum_llr"] = f"{sess.guard.cusum_llr:.3f}"
        d["fix_sigma_floor_m"] = f"{sess.guard.last_floor_m:.3f}"
        if sess.grade_check.nis_per_dof:
            d["moving_nis_per_dof_mean"] = f"{float(np.mean(sess.grade_check.nis_per_dof)):.3f}"
        d["grade_bias_z_max"] = f"{sess.grade_check.z_max:.2f}"  # grade_check: bias estimate vs the grade's prior
        if sess.guard.nis_recent:
            d["divergence_nis_window_mean"] = f"{float(np.mean(sess.guard.nis_recent)):.3f}"
        if sess.processed_t is not None and sess.last_accepted_fix_t is not None:
            d["gnss_age_s"] = f"{sess.processed_t - sess.last_accepted_fix_t:.2f}"
        if sess.loop.median_dt is not None:
            d["imu_period_median_ms"] = f"{sess.loop.median_dt * 1e3:.3f}"
        d["wheel_speed"] = ("fused" if sess.fusion.wheel_speed_used() else
                            "unused (vehicle car | wheeled_robot and an in-motion core fuse it)")
        d.update(sess.fusion.wheel_scale.diagnostics())  # the odometry's scale factor (session/wheel_scale.py)
        d.update(sess.yaw_seed.diagnostics())  # vehicle, what it assumes, what seeded the yaw (session/yaw_seed.py)
        d["buffered_imu"] = str(len(sess.buf.imu))
        d["buffered_fixes"] = str(len(sess.buf.fix_t))
        if sess.watchdog_reason:
            d["watchdog"] = sess.watchdog_reason
        if sess.bt is not None:
            d["backtrack_state"] = sess.bt.state
            d.update({f"backtrack_{k}": v for k, v in sess.bt.stats.items()})
        d.update({k: str(v) for k, v in sess.counters.items()})
        if sess.core is not None:
            try:
                d.update({f"core.{k}": v for k, v in sess.core.diagnostics().items()})
                d.update({f"core.counter.{k}": v for k, v in sess.core.counters.items()})
            except Exception as exc:  # noqa: BLE001 - diagnostics never take the pipeline down
                d["core.diagnostics_error"] = f"{type(exc).__name__}: {exc}"
        return d
