"""Do the dual-antenna GNSS heading and the IMU agree? A mounting of the antenna baseline that is not the declared
``gnss_heading_baseline_yaw_deg`` biases every heading by the same angle; a consistent filter's heading innovations
are white with the variance S the update reports, so their mean over the last ``WINDOW`` fused headings, in units of
its own sigma sqrt(mean S / n), is a standard normal; beyond ``Z_MAX`` the status and a WARN line say that the
heading and the IMU disagree, by how much, and what to check. The filter follows a heading far more precise than its
own yaw, so the offset shows in the innovations only while the estimate still holds yaw information of its own (the
yaw from the motion before the headings, or a navigation-grade gyro's gyrocompassing): docs/session.md."""

from __future__ import annotations

import math
from collections import deque

import numpy as np


class HeadingCheck:
    """Kept across re-initialisations: the mounting is the installation's, not the filter's."""

    WINDOW = 30
    Z_MAX = 5.0

    def __init__(self, session) -> None:
        self.s = session
        self.note = ""
        self.z = 0.0  # the last window's statistic (diagnostics)
        self._z: deque = deque(maxlen=self.WINDOW)  # innovations [rad]
        self._S: deque = deque(maxlen=self.WINDOW)  # their variances [rad^2]

    def on_result(self, res, var_rad2: float) -> None:
        """One heading update's outcome (accepted or gated: a gated heading is evidence too), counted while the
        estimate claims its attitude (a converging filter's innovations are large by design)."""
        if not self.s.monitor.attitude_claimed():
            self._z.clear()
            self._S.clear()
            return
        if res.innovation is None or len(res.innovation) != 1 or res.S is None or np.size(res.S) != 1:
            return
        z, S = float(res.innovation[0]), float(np.asarray(res.S).reshape(-1)[0])
        if not (math.isfinite(z) and math.isfinite(S) and S > 0):
            return
        self._z.append(z)
        self._S.append(S)
        n = len(self._z)
        if n < self.WINDOW:
            return
        mean = float(np.mean(self._z))
        self.z = mean / math.sqrt(float(np.mean(self._S)) / n)
        if abs(self.z) > self.Z_MAX and not self.note:
            sess = self.s
            off = math.degrees(mean)
            self.note = (f"the GNSS heading and the IMU disagree: the last {n} headings are {off:+.2f} deg from the "
                         f"estimate on average ({abs(self.z):.1f} sigma); check the antenna baseline's mounting "
                         f"(gnss_heading_baseline_yaw_deg = {sess.cfg.gnss_heading_baseline_yaw_deg:g} deg declared)")
            sess.counters["gnss_heading_disagrees"] += 1
            sess.log("warn", "gnss_heading_disagrees", self.note)
