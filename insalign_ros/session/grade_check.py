"""Does the declared ``imu_grade`` fit what the IMU does? The filter's own gyro-bias estimate against the grade's
1-sigma (the prior it started from); the innovation statistics while moving are collected (mean NIS/dof of the last
``WINDOW`` fixes, in the diagnostics) but do not decide: their excess may be the fixes'. When they contradict it: a WARN line and a status note that name the
grade as too optimistic and by how much (once per finding); the estimate is not touched: a young filter's bias
estimate (a large yaw error just after a hand-over) can pass the bound on a matched grade, and acting on it then
threw away a good alignment (test_auto_mode's parked-then-driving MEMS car). docs/session.md "A grade the data
contradict"."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..filters.imu_grade import get_grade


class GradeCheck:
    """The session stage behind the "imu_grade ... too optimistic" note (kept across re-initialisations: it is the
    IMU's, not the filter's)."""

    #: fused fixes while moving in the innovation window; the test's false-alarm probability per full window
    WINDOW = 20
    P_FALSE = 1e-3
    #: a bias estimate beyond this many of the grade's 1-sigma (the prior the filter started from) contradicts it
    BIAS_SIGMAS = 4.0
    #: moving: the fixes' chord speed above this [m/s]
    MOVING_M_S = 2.0

    def __init__(self, session) -> None:
        self.s = session
        self.note = ""  # the finding (status message), "" while the grade fits
        self.factor = 1.0  # how many times too optimistic (the widest finding so far)
        self.reset()

    def reset(self) -> None:
        self._nis: deque = deque(maxlen=self.WINDOW)

    def _moving(self) -> bool:
        seq = self.s.guard._fix_seq
        if len(seq) < 2:
            return False
        (t1, p1, _), (t2, p2, _) = seq[-2], seq[-1]
        return 0.0 < t2 - t1 <= 3.0 and float(np.linalg.norm(p2 - p1)) / (t2 - t1) > self.MOVING_M_S

    def on_fix(self, nis: float, dof: int) -> None:
        """One accepted fused fix: its NIS while moving, then the bias estimates."""
        sess = self.s
        if math.isfinite(nis) and dof > 0 and self._moving():
            self._nis.append(nis / dof)
        findings = []
        # the NIS window (self._nis) is kept for the diagnostics only: on KITTI 0018 its excess (1.5x) comes from the
        # fixes' centimetre sigmas, not from the IMU, so it cannot name the grade; the filter's own bias estimate can
        try:
            grade = get_grade(sess.cfg.imu_grade)
            b = sess.core.estimate().bias_gyro_b
        except Exception:  # noqa: BLE001 - a check never takes the pipeline down
            b, grade = None, None
        if b is not None and grade is not None and grade.gyro_bias_deg_h > 0:
            b_deg_h = float(np.max(np.abs(np.degrees(np.asarray(b, float)) * 3600.0)))
            k = b_deg_h / grade.gyro_bias_deg_h
            if k > self.BIAS_SIGMAS:
                findings.append((k / 1.0, f"the estimated gyro bias {b_deg_h:.0f} deg/h is {k:.1f}x its 1-sigma "
                                          f"{grade.gyro_bias_deg_h:g} deg/h"))
        if not findings:
            return
        k, why = max(findings)
        if k <= 1.5 * self.factor:  # said already (a new note only when it is clearly worse)
            return
        self.factor = k
        self.note = (f"imu_grade {sess.cfg.imu_grade!r} is too optimistic for this IMU: {why}; "
                     f"pass a grade about {k:.0f}x noisier (or characterise it: insalign-characterise)")
        sess.counters["grade_too_optimistic"] += 1
        sess.log("warn", "grade_too_optimistic", self.note)
