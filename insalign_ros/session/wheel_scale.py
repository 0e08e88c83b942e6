"""The wheel odometry's scale factor, estimated beside the core (which keeps no scale state): a scalar Kalman filter
on s (the wheels read s times the forward speed; prior s = 1 with ``wheel_scale_sigma``, a slow random walk).

Its measurement compares distances, not speeds: over a window of at least WINDOW_S between two accepted GNSS fixes
(no fix missing: consecutive fixes at most MAX_FIX_GAP_S apart) the wheel speeds integrated along the estimated body x
axis in ENU, D = int w C_b_n e_x dt, against the fixes' displacement dp (antenna lever arm removed): s_obs = |D| / |dp|.
|D| does not depend on a constant attitude error (a rotation of D), so the scale is measured while the yaw is still
being found; the window is used only if the core's yaw 3-sigma stays under MAX_YAW_3SIGMA_DEG (a correction within
the window bends D) and the vehicle moved at least MIN_DIST_M (a slow robot's window stays open until it has, for
at most MAX_WINDOW_S). Why not the core's forward speed against the wheel's:
the core fuses the wheel speed, so once the scale's sigma is small its velocity follows the wheels and the comparison
pulls the scale towards itself; the fixes are independent of the wheels. The noise of s_obs is that of |dp| along
the track (the fixes' covariances) and of the integrated wheel noise; a window whose innovation fails a chi-square
gate (1 dof, p = 1e-3: a slipping wheel, a multipath fix) is not used. Windows that share a fix have negatively
correlated errors (telescoping): treating them as independent is conservative.

The session passes the estimate and its 1-sigma to the WheelSpeed model (filters/vehicle_models.py), whose noise
carries (sigma_s * speed)^2 (counted once per session/fusion.WHEEL_SCALE_MEMORY_S). docs/inmotion_cores.md,
"Wheel speed".
"""

from __future__ import annotations

import math

import numpy as np

from ..core import earth

#: a window closes at the first accepted fix at least this long after the one that opened it [s]
WINDOW_S = 20.0
#: consecutive accepted fixes further apart than this [s] (an outage, a rejected fix) restart the window
MAX_FIX_GAP_S = 2.5
#: wheel samples further apart than this [s] restart the window (odometry dropped out)
MAX_WHEEL_GAP_S = 1.0
#: the window is used only if the vehicle moved at least this far [m] (a 1-m fix noise is 3 % of 30 m); a slower
#: vehicle's window stays open until it has, for at most MAX_WINDOW_S
MIN_DIST_M = 30.0
MAX_WINDOW_S = 120.0
#: and the core's yaw 3-sigma stayed under this [deg] in the window
MAX_YAW_3SIGMA_DEG = 6.0
#: chi-square gate (1 dof, p = 1e-3) of a window's scale against the estimate
GATE = 10.83
#: fixes held for the wheel integration to reach (it reaches them within MAX_WHEEL_GAP_S while wheel speeds come)
MAX_PENDING_FIXES = 50
#: random walk of the scale [1/sqrt(s)] (tyre pressure and load change it slowly: 0.6 % in an hour)
RANDOM_WALK = 1e-4


class WheelScale:
    """The scale factor s of the wheel odometry and its variance; ``on_fix`` (accepted fixes), ``on_wheel`` (every
    wheel speed the session fuses, with the core's estimate at its stamp)."""

    def __init__(self, session) -> None:
        self.s = session
        self.scale = 1.0
        self.P = float(session.cfg.wheel_scale_sigma) ** 2
        self.windows = 0  # windows fused
        self.windows_rejected = 0
        self.t_updated: float | None = None
        self.restart()

    @property
    def sigma(self) -> float:
        return math.sqrt(self.P)

    def restart(self) -> None:
        """Drop the window in progress (the session's restart); the scale is the vehicle's: it is kept."""
        self._prev = None  # (t, ENU displacement rate [m/s]) of the last wheel sample
        self._win = None  # (t, p_e [m], R_e [m^2]) of the fix opening the window
        self._acc = np.zeros(3)
        self._acc_var = 0.0
        self._yaw3_max = 0.0
        self._fixes: list = []  # accepted fixes the wheel integration has not reached
        self._last_fix_t: float | None = None

    def interval_s(self, t: float) -> float:
        """The interval [s] from the previous wheel sample to ``t`` (0.1 s before the first; clipped to [1 ms, 1 s])."""
        return min(max(t - self._prev[0], 1e-3), 1.0) if self._prev is not None else 0.1

    def on_fix(self, fix, est) -> None:
        """An accepted fix (antenna position) with the core's estimate after it: a window boundary."""
        t = float(fix.stamp_s)
        if self._last_fix_t is not None and t - self._last_fix_t > MAX_FIX_GAP_S:
            self._win = None  # a fix missing: the window restarts at this one
            self._fixes.clear()
        self._last_fix_t = t
        lever = np.asarray(self.s.core_params.get("gnss_lever_arm_b_m", (0.0, 0.0, 0.0)) or (0.0, 0.0, 0.0), float)
        p_e = np.asarray(fix.p_e, float)
        if np.any(lever):
            p_e = p_e - earth.C_n_e(est.lat_rad, est.lon_rad) @ (est.C_b_n @ lever)
        self._fixes.append((t, p_e, np.asarray(fix.R_e, float)))
        if len(self._fixes) > MAX_PENDING_FIXES:  # no wheel speed comes (a car without odometry): bounded memory
            del self._fixes[:-MAX_PENDING_FIXES]

    def on_wheel(self, ws, est) -> None:
        """One wheel speed (core.types.WheelSpeed) with the core's estimate at its stamp: integrate, close windows."""
        t = float(ws.stamp_s)
        d = float(ws.speed_m_s) * est.C_b_n[:, 0]
        self._yaw3_max = max(self._yaw3_max, 3.0 * math.degrees(math.sqrt(max(float(est.P_att_n[2, 2]), 0.0))))
        prev, self._prev = self._prev, (t, d)
        if prev is None or not 0.0 < t - prev[0] <= MAX_WHEEL_GAP_S:
            self._win = None
            self._fixes = [f for f in self._fixes if f[0] >= t]
            return
        t0, d0 = prev
        a = t0
        while self._fixes and self._fixes[0][0] <= t:
            fix = self._fixes.pop(0)
            tf = fix[0]
            if tf < t0:  # before the previous wheel sample: cannot be a boundary
                self._win = None
                continue
            self._integrate(a, tf, t0, d0, t, d, ws.var_m2_s2)
            a = tf
            if self._win is None:
                self._open(fix)
            elif tf - self._win[0] >= WINDOW_S and self._close(fix):
                self._open(fix)
        self._integrate(a, t, t0, d0, t, d, ws.var_m2_s2)

    def _open(self, fix) -> None:
        self._win = fix
        self._acc = np.zeros(3)
        self._acc_var = 0.0
        self._yaw3_max = 0.0

    def _integrate(self, a, b, t0, d0, t1, d1, var) -> None:
        """Trapezoid of the linearly interpolated displacement rate over [a, b] inside [t0, t1]."""
        if self._win is None or b <= a:
            return
        da = d0 + (d1 - d0) * (a - t0) / (t1 - t0)
        db = d0 + (d1 - d0) * (b - t0) / (t1 - t0)
        self._acc += 0.5 * (b - a) * (da + db)
        self._acc_var += var * (b - a) ** 2

    def _close(self, fix) -> bool:
        """The window up to ``fix`` as a scale measurement; False: kept open (a slow vehicle has not moved
        MIN_DIST_M yet, the window is younger than MAX_WINDOW_S)."""
        t_a, p_a, R_a = self._win
        t_b, p_b, R_b = fix
        if self._yaw3_max > MAX_YAW_3SIGMA_DEG:
            return True
        lat, lon, _ = earth.ecef_to_geodetic(p_a)
        Cne = earth.C_n_e(lat, lon)
        dp = Cne.T @ (p_b - p_a)
        L, Dn = float(np.linalg.norm(dp)), float(np.linalg.norm(self._acc))
        if L < MIN_DIST_M or Dn < 0.5 * MIN_DIST_M:
            return t_b - t_a >= MAX_WINDOW_S
        u = dp / L
        var_L = float(u @ (Cne.T @ (R_a + R_b) @ Cne) @ u)
        s_obs = Dn / L
        var_obs = (Dn / L ** 2) ** 2 * var_L + self._acc_var / L ** 2
        if self.t_updated is not None:
            self.P += RANDOM_WALK ** 2 * max(t_b - self.t_updated, 0.0)
        r = s_obs - self.scale
        S = self.P + var_obs
        if r * r / S > GATE:
            self.windows_rejected += 1
            self.s.counters["wheel_scale_rejected"] += 1
            return True
        K = self.P / S
        self.scale += K * r
        self.P *= 1.0 - K
        self.t_updated = t_b
        self.windows += 1
        self.s.counters["wheel_scale_windows"] += 1
        return True

    def diagnostics(self) -> dict:
        return {"wheel_scale": f"{self.scale:.5f}", "wheel_scale_sigma": f"{self.sigma:.5f}",
                "wheel_scale_windows": str(self.windows)}
