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

from ..core.units import G0_M_S2, deg_h_to_rad_s, mg_to_m_s2
from ..filters.base import bias_indices
from ..filters.imu_grade import get_grade


class GradeCheck:
    """The session stage behind the "imu_grade ... too optimistic" note (kept across re-initialisations: it is the
    IMU's, not the filter's)."""

    #: fused fixes while moving in the innovation window (its mean NIS/dof goes to the diagnostics)
    WINDOW = 20
    #: the bias consistency statistic (see _bias_findings) above this contradicts the grade (6 axes tested at every
    #: fix: 5 sigma keeps the false alarms of a matched grade rare)
    Z_MAX = 5.0
    #: moving: the fixes' chord speed above this [m/s]
    MOVING_M_S = 2.0

    def __init__(self, session) -> None:
        self.s = session
        self.note = ""  # the finding (status message), "" while the grade fits
        self.factor = 1.0  # how many times too optimistic (the widest finding so far)
        self.reset()

    def reset(self) -> None:
        self.nis_per_dof: deque = deque(maxlen=self.WINDOW)
        self._core = None  # the core whose prior (b0, P0) is held
        self._b0 = self._P0 = None
        self.z_max = 0.0  # the largest bias consistency statistic so far (diagnostics)

    def _bias_findings(self) -> list:
        """The bias estimates against the prior the core started from: for a consistent linear filter the estimate's
        move from its prior, b - b0, has the covariance P0 - P (the prior's minus the posterior's: the estimate is
        orthogonal to its error), so z = |b - b0| / sqrt(P0 - P) per axis is a standard normal; an axis counts once
        the data have taken at least half of its prior variance (below that P0 - P is mostly the prior's own noise).
        z above ``Z_MAX`` says the IMU's biases are beyond the declared grade (a shrunk estimate: the bias in grade
        sigmas, |b - b0| / sqrt(P0), is a lower bound of how far)."""
        sess = self.s
        try:
            est = sess.outputs.estimate()  # the session's memo: the guard and the output at this sample read it too
        except Exception:  # noqa: BLE001 - a check never takes the pipeline down
            return []
        names = est.state_names
        blocks = []
        for kind, b, unit, scale in (("gyro", est.bias_gyro_b, "deg/h", math.degrees(1.0) * 3600.0),
                                     ("accelerometer", est.bias_acc_b, "mg", 1e3 / G0_M_S2)):
            idx = bias_indices(names, "bg" if kind == "gyro" else "ba")
            if b is None or len(idx) != 3:
                continue
            Pd = est.P.diagonal()
            blocks.append((kind, np.asarray(b, float).tolist(), [float(Pd[i]) for i in idx], unit, scale))
        if sess.core is not self._core:  # a new core (initialisation, hand-over): its prior is what it holds now
            self._core, self._b0, self._P0 = sess.core, [bl[1] for bl in blocks], [bl[2] for bl in blocks]
            return []
        findings = []
        for (kind, b, P, unit, scale), b0, P0 in zip(blocks, self._b0, self._P0):
            # per axis in plain floats (three of them at every fix): the IEEE operations numpy's would do
            learned = [p < 0.5 * p0 for p, p0 in zip(P, P0)]
            if not any(learned):
                continue
            db = [abs(x - x0) for x, x0 in zip(b, b0)]
            z = [d / math.sqrt(max(p0 - p, 1e-30)) if ok else 0.0 for d, p, p0, ok in zip(db, P, P0, learned)]
            # np.argmax's axis: the first NaN (a lost filter: no finding), else the first of the largest
            i = next((j for j, x in enumerate(z) if x != x), max(range(len(z)), key=z.__getitem__))
            self.z_max = max(self.z_max, z[i])
            if z[i] > self.Z_MAX:
                k = db[i] / math.sqrt(P0[i])
                # the attitude error such a bias leaves uncovered: a tilt of b/g for the accelerometer's (its
                # horizontal part is what levelling cannot tell from tilt); the gyro's is left to the innovations
                findings.append((max(k, 1.0), f"the {kind} bias estimate moved {db[i] * scale:.3g} {unit} from its "
                                              f"prior on axis {'xyz'[i]}, {z[i]:.1f} sigma of what the grade allows "
                                              f"({math.sqrt(P0[i]) * scale:.3g} {unit} 1-sigma prior)"))
        return findings

    def _moving(self) -> bool:
        seq = self.s.guard.fix_seq
        if len(seq) < 2:
            return False
        (t1, p1, _), (t2, p2, _) = seq[-2], seq[-1]
        return 0.0 < t2 - t1 <= 3.0 and float(np.linalg.norm(p2 - p1)) / (t2 - t1) > self.MOVING_M_S

    def on_fix(self, nis: float, dof: int) -> None:
        """One accepted fused fix: its NIS while moving, then the bias estimates."""
        sess = self.s
        if math.isfinite(nis) and dof > 0 and self._moving():
            self.nis_per_dof.append(nis / dof)
        findings = self._bias_findings()
        if not findings:
            return
        k, why = max(findings)  # k: the bias in sigmas of the prior the core holds now (the grade's, or widened)
        if k < 1.5:  # not clearly beyond the current prior (said already)
            return
        grade = get_grade(sess.cfg.imu_grade)
        before, self.factor = self.factor, self.factor * k
        self.note = (f"imu_grade {sess.cfg.imu_grade!r} is too optimistic for this IMU: {why}; "
                     f"pass a grade about {self.factor:.0f}x noisier (or characterise it: insalign-characterise); "
                     f"the bias priors are widened to that")
        sess.counters["grade_too_optimistic"] += 1
        sess.log("warn", "grade_too_optimistic", self.note)
        # the covariance must cover what the grade did not: both bias priors widened to the grade ``factor`` times
        # noisier (what the user is told to pass), carried to the attitude through the covariance's regression on the
        # biases (the yaw a gyro bias has turned since the start: base.widen_biases), and the tilt the wider
        # accelerometer bias leaves uncovered (b/g), so the estimate re-converges with honest sigmas (the flag
        # follows them)
        widen = self.factor ** 2 - before ** 2
        var_bg = widen * deg_h_to_rad_s(grade.gyro_bias_deg_h) ** 2
        var_ba = widen * mg_to_m_s2(grade.acc_bias_mg) ** 2
        sess.core.inflate_navigation(var_ba / G0_M_S2 ** 2, 0.0, 0.0, var_bg_rad2_s2=var_bg, var_ba_m2_s4=var_ba)
        sess._est_memo = None
        self._core = None  # the widened state is the new prior the next findings are measured from
