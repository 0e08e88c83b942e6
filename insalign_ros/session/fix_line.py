"""The GNSS inputs against each other, filter-free: where a fix may lie after the fixes before it (the straight-line
extrapolation of the two before it, or one fix and a speed: the jump test's and the fix screen's common measure), and
whether a GNSS velocity agrees with the fixes' velocity.

docs/session.md, "Outliers and divergence"."""

from __future__ import annotations

import math

import numpy as np

from ..core.types import GnssFix


class FixScreen:
    """Plausibility of a fix against the vehicle's own recent fixes, filter-free (from the first fix on): off the
    straight-line extrapolation of the two fixes before it (:func:`extrapolation_excess`), or with one fix within
    ``SPAN_S`` only, farther than its speed (``MAX_SPEED_M_S`` when unknown) and ``gnss_jump_accel_m_s2`` allow.
    Enforced at the door while no filter runs (before the first initialisation, while a restart waits); a running
    filter's fixes only keep the line current (the guard's jump test and NIS gate decide there, fusion.py). ``CONFIRM`` implausible fixes consistent with each other are a new
    line (a re-acquisition shift, or a first fix that was the bad one): the line moves to them and buffered fixes
    of the old line are dropped (``inputs_dropped``). docs/session.md, "Outliers and divergence"."""

    SPAN_S = 10.0
    MAX_SPEED_M_S = 600.0
    CONFIRM = 3

    def __init__(self, session) -> None:
        self.s = session
        self.reset()

    def reset(self) -> None:
        self.line: list = []  # plausible fixes (stamp, p_e, sigma), stamp order, the last SPAN_S
        self.cand: list = []  # implausible fixes consistent with each other (a possible new line)

    def excess(self, pts: list, point) -> float:
        """How far [m] ``point`` lies beyond what the fixes ``pts`` (stamp order) allow; -inf: nothing to tell."""
        t = point[0]
        near = [q for q in pts if abs(q[0] - t) <= self.SPAN_S]
        if not near:
            return -math.inf
        before = [q for q in near if q[0] < t]
        accel = self.s.cfg.gnss_jump_accel_m_s2
        if len(before) >= 2:
            e = extrapolation_excess((before[-2], before[-1]), point, accel)
            if e != -math.inf:
                return e
        q = min(near, key=lambda q: abs(q[0] - t))
        dt = abs(q[0] - t)
        i = near.index(q)
        pair = (near[i - 1], q) if i > 0 else (q, near[i + 1]) if i + 1 < len(near) else None
        speed = self.MAX_SPEED_M_S
        if pair is not None and 0.0 < pair[1][0] - pair[0][0] <= 3.0:
            speed = float(np.linalg.norm(pair[1][1] - pair[0][1])) / (pair[1][0] - pair[0][0])
        noise = 5.0 * math.hypot(q[2], point[2])
        return float(np.linalg.norm(point[1] - q[1])) - ((speed + accel * dt) * dt + 0.5 * accel * dt * dt + noise)

    def check(self, fix: GnssFix) -> str:
        """"" when ``fix`` is plausible (it joins the line), else the reason (enforced only while no filter claims
        its attitude: the caller decides)."""
        sess = self.s
        point = fix_point(fix)
        t = point[0]
        e = self.excess(self.line, point)
        if not e > 0:
            self._join(point)
            return ""
        c = self.cand
        if c and (self.excess(c, point) > 0 or not 0.0 < t - c[-1][0] <= 3.0):
            c.clear()
        c.append(point)
        if len(c) < self.CONFIRM:
            return (f"{e:.3g} m beyond what the vehicle's recent fixes allow (extrapolation, speed and "
                    f"{sess.cfg.gnss_jump_accel_m_s2:g} m/s^2)")
        new = list(c)
        self.reset()
        b = sess.buf
        if sess.core is None:  # (a running filter's buffered fixes go to its jump test and NIS gate instead)
            keep = [k for k in range(len(b.fix_t)) if b.fix_t[k] > t]
            sess.counters["inputs_dropped"] += len(b.fix_t) - len(keep)
            b.fix_t[:] = [b.fix_t[k] for k in keep]
            b.fix[:] = [b.fix[k] for k in keep]
        sess.log("warn", "gnss_implausible", f"{len(new)} consistent GNSS fixes off the previous ones by {e:.3g} m: "
                 "following them (a new line" + ("; buffered fixes of the old one dropped)" if sess.core is None
                                                 else ")"))
        for q in new:
            self._join(q)
        return ""

    def _join(self, point) -> None:
        line = self.line
        k = len(line)
        while k > 0 and line[k - 1][0] > point[0]:
            k -= 1
        line.insert(k, point)
        while line and line[-1][0] - line[0][0] > self.SPAN_S:
            line.pop(0)


def fix_point(fix: GnssFix) -> tuple[float, np.ndarray, float]:
    """(stamp [s], p_e [m], 1-sigma [m] per axis: the RMS of R_e's diagonal) of a fix: the jump detection's input."""
    return point_of(fix.stamp_s, fix.p_e, fix.R_e)


def point_of(t: float, p_e, R_e) -> tuple[float, np.ndarray, float]:
    """:func:`fix_point` of a fix given as its stamp [s], ECEF position [m] and covariance [m^2]."""
    return float(t), np.asarray(p_e, float), math.sqrt(max(float(np.trace(R_e)) / 3.0, 0.0))


def sequence_jump(prev, t: float, p_e, R_e, accel_m_s2: float) -> bool:
    """Whether a fix (stamp ``t``, ECEF ``p_e``, covariance ``R_e``) is a jump after the two fixes ``prev`` ((t, p_e,
    R_e) each): :func:`extrapolation_excess` > 0 (for a fix sequence kept as arrays: core auto's GNSS speed)."""
    return extrapolation_excess([point_of(*f) for f in prev], point_of(t, p_e, R_e), accel_m_s2) > 0


def extrapolation_excess(prev, point, accel_m_s2: float) -> float:
    """How far [m] a fix ``point`` lies beyond what the straight-line extrapolation of ``prev`` (two earlier
    points, each within 3 s of the next; points from :func:`fix_point`) allows: acceleration up to ``accel_m_s2``
    plus 5 sigma of the three fixes' noise. -inf when the fixes are too far apart in time to tell."""
    (t0, p0, s0), (t1, p1, s1) = prev
    t, p, sigma_m = point
    d1, d2 = t1 - t0, t - t1
    if not (0 < d1 <= 3.0 and 0 < d2 <= 3.0):
        return -math.inf
    r = d2 / d1
    pred = p1 + (p1 - p0) * r
    noise = math.sqrt(s0 * s0 * r * r + s1 * s1 * (1 + r) ** 2 + sigma_m * sigma_m)
    return float(np.linalg.norm(p - pred)) - (0.5 * accel_m_s2 * d2 * (d1 + d2) + 5.0 * noise)


def velocities_agree(v_a, var_a: float, v_b, var_b: float) -> bool:
    """Two ENU velocities [m/s] agree horizontally within 5 sigma of both (var: the sum of the two horizontal
    variances [m^2/s^2]): a GNSS velocity replaces the fixes' velocity of an initialisation only then."""
    d = np.asarray(v_a, float)[:2] - np.asarray(v_b, float)[:2]
    return bool(math.hypot(d[0], d[1]) <= 5.0 * math.sqrt(max(var_a + var_b, 0.0)))
