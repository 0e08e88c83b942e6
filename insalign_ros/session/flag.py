"""The "aligned" flag: criteria a user can trust and tune. Pure Python, no ROS (the node and the benchmarks share it).

The flag is raised when, continuously for at least ``hold_s`` of data time:

1. **attitude 3-sigma below thresholds**: ``3 sqrt(P_att_n[0,0])`` and ``3 sqrt(P_att_n[1,1])`` below the level
   bound and ``3 sqrt(P_att_n[2,2])`` (the azimuth error about Up) below ``yaw_3sigma_deg``. The level bound is
   ``roll_pitch_3sigma_deg``, or ``level_floor_factor`` times the level floor of the declared IMU when that is
   larger: an accelerometer bias b tilts the level by atan(b / g), which no aiding separates from the tilt until
   the vehicle turns, so the floor is ``3 atan(acc_bias / g)`` (0.86 deg for the default ``unknown_mems``'s 5 mg);
   a bound at the floor would make the flag wait for the covariance's last hundredths;
2. **innovations consistent with the covariance**: the normalized innovation squared (NIS) of the last
   ``nis_window`` accepted GNSS updates, summed, lies inside the two-sided chi-square band of probability
   ``1 - nis_alpha`` with ``n * dof`` degrees of freedom for the n updates the window holds, at least
   ``nis_min_updates`` (a sum of independent chi-square(dof) variables is chi-square(n*dof)); once the flag is up, inside the wider band of ``1 - nis_alpha_drop``
   (hysteresis: the window slides one update at a time, so the sum of a consistent filter leaves the narrower band
   every few minutes). Too large a sum means the filter is over-confident (the covariance
   in 1. cannot be trusted); too small means it is pessimistic (harmless for safety, but the model is off, so
   ``nis_lower_check`` can switch that side off). Cores without innovations (static cores fed with zero-velocity
   updates only) can use the same test on their ZUPT innovations; with ``nis_window = 0`` the test is off.
3. **fresh aiding**: an accepted measurement update within ``max_update_age_s`` of data time (a filter coasting
   on the IMU alone is not declared aligned, whatever its covariance says).

The flag is lowered at once when any criterion stops holding (no hold time on the way down), and the hold
timer restarts. ``AlignedFlag.reason`` says which criterion is failing, in words a user can act on.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from ..core.stats import chi2_ppf
from ..filters.imu_grade import level_floor_rad

#: the hold's comparison tolerance [s] (float stamps; far below any output period)
HOLD_TOL_S = 1e-6


@dataclass
class AlignedCriteria:
    """Tunable thresholds of the aligned flag (node parameters ``aligned.<field>``)."""

    #: 3-sigma roll and pitch bound [deg]
    roll_pitch_3sigma_deg: float = 1.0
    #: the roll/pitch bound is at least this many times the declared IMU's level floor, 3 atan(acc_bias / g)
    #: (0: the bound is roll_pitch_3sigma_deg whatever the grade)
    level_floor_factor: float = 1.5
    #: 3-sigma azimuth (yaw about Up) bound [deg]
    yaw_3sigma_deg: float = 2.5
    #: number of recent accepted updates whose NIS sum is tested (0: no NIS test)
    nis_window: int = 10
    #: the test runs once the window holds this many updates, with the band of the updates it holds (a filter that
    #: meets the bounds a few fixes after its start is tested on those; the full window waits 10 s at 1 Hz)
    nis_min_updates: int = 5
    #: two-sided probability outside the band (0.01: the 0.5 % and 99.5 % quantiles)
    nis_alpha: float = 0.01
    #: once the flag is up, the NIS test lowers it only outside the band of this smaller probability (hysteresis:
    #: the window slides by one update, so a consistent filter's sum leaves the 99 % band every few minutes; the
    #: session's CUSUM of the NIS watches sustained over-confidence); equal to ``nis_alpha``: no hysteresis
    nis_alpha_drop: float = 0.001
    #: also reject a too-small NIS sum (a pessimistic filter)
    nis_lower_check: bool = False
    #: the criteria must hold this long [s of data time] before the flag rises
    hold_s: float = 2.0
    #: an accepted update must be at most this old [s of data time]
    max_update_age_s: float = 5.0

    def validate(self) -> None:
        values = asdict(self)
        for name in ("roll_pitch_3sigma_deg", "level_floor_factor", "yaw_3sigma_deg", "nis_alpha", "nis_alpha_drop",
                     "hold_s", "max_update_age_s"):
            v = values[name]
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"{name}: expected a finite number, got {v!r}")
        if not self.roll_pitch_3sigma_deg > 0 or not self.yaw_3sigma_deg > 0:
            raise ValueError("roll_pitch_3sigma_deg and yaw_3sigma_deg must be > 0")
        if not 0 < self.nis_alpha < 1:
            raise ValueError(f"nis_alpha: must be in (0, 1), got {self.nis_alpha}")
        if not 0 < self.nis_alpha_drop <= self.nis_alpha:
            raise ValueError(f"nis_alpha_drop: must be in (0, nis_alpha], got {self.nis_alpha_drop}")
        if not (isinstance(self.nis_window, int) and 0 <= self.nis_window <= 10000):
            raise ValueError(f"nis_window: must be an integer in [0, 10000], got {self.nis_window!r}")
        if not (isinstance(self.nis_min_updates, int) and 1 <= self.nis_min_updates <= 10000):
            raise ValueError(f"nis_min_updates: must be an integer in [1, 10000], got {self.nis_min_updates!r}")
        if self.level_floor_factor < 0:
            raise ValueError(f"level_floor_factor: must be >= 0, got {self.level_floor_factor}")
        if self.hold_s < 0 or not self.max_update_age_s > 0:
            raise ValueError("hold_s must be >= 0 and max_update_age_s > 0")

    def to_dict(self) -> dict:
        return asdict(self)


@functools.lru_cache(maxsize=64)  # per output with the same arguments: scipy's ppf costs ~0.2 ms a call
def nis_band(window: int, dof: int, alpha: float) -> tuple[float, float]:
    """(lower, upper) bounds of a sum of ``window`` NIS values of ``dof`` dof, two-sided probability ``alpha``."""
    k = window * dof
    return chi2_ppf(alpha / 2.0, k), chi2_ppf(1.0 - alpha / 2.0, k)


def level_floor_3sigma_deg(acc_bias_mg: float) -> float:
    """3-sigma level error [deg] that an accelerometer bias of 1-sigma ``acc_bias_mg`` [mg] leaves while no
    manoeuvre separates it from the tilt: 3 atan(b / g)."""
    return 3.0 * math.degrees(level_floor_rad(acc_bias_mg))


def attitude_3sigma_deg(P_att_n: np.ndarray) -> np.ndarray:
    """3-sigma [deg] of the ENU attitude error about East, North, Up (roll, pitch, yaw near level)."""
    return np.array(attitude_3sigma_list(P_att_n))


def attitude_3sigma_list(P_att_n: np.ndarray) -> list[float]:
    """:func:`attitude_3sigma_deg` as a list of floats, the same numbers (``np.clip``, ``np.sqrt`` and
    ``np.degrees`` are the IEEE operations of ``max``, ``math.sqrt`` and ``math.degrees``), without numpy's per-call
    overhead (once per output)."""
    P = np.asarray(P_att_n, float)
    d = (float(P[0, 0]), float(P[1, 1]), float(P[2, 2]))
    return [3.0 * math.degrees(math.sqrt(0.0 if x < 0.0 else x)) if x == x else math.nan for x in d]


class AlignedFlag:
    """State machine of the aligned flag. Feed ``on_update`` per measurement update and ``on_estimate`` per output."""

    def __init__(self, criteria: AlignedCriteria | None = None, level_floor_deg: float = 0.0) -> None:
        self.criteria = criteria or AlignedCriteria()
        self.criteria.validate()
        #: the declared IMU's level floor (:func:`level_floor_3sigma_deg`) [deg]
        self.level_floor_deg = float(level_floor_deg)
        self.reset()

    @property
    def level_bound_deg(self) -> float:
        """The roll/pitch 3-sigma bound [deg]: ``roll_pitch_3sigma_deg`` or ``level_floor_factor`` x the floor."""
        c = self.criteria
        return max(c.roll_pitch_3sigma_deg, c.level_floor_factor * self.level_floor_deg)

    def reset(self) -> None:
        self.aligned = False
        self.nis: deque = deque(maxlen=max(self.criteria.nis_window, 1))
        self._nis_total: float | None = None  # sum(self.nis), None: to compute (the window changed)
        self.nis_dof = 3
        self.nis_source: str | None = None  # the stream whose innovations the window holds (on_update)
        self.last_update_s: float | None = None
        self.holding_since_s: float | None = None
        self.reason = "no estimate yet"
        self.sigma3_deg = np.full(3, np.inf)
        self.nis_sum = float("nan")
        self.band = (float("nan"), float("nan"))
        self.raised_at_s: float | None = None  # the last time the flag rose [s data time]
        self.first_raised_at_s: float | None = None

    def set_criteria(self, criteria: AlignedCriteria) -> None:
        criteria.validate()
        keep = list(self.nis)
        self.criteria = criteria
        self.nis = deque(keep, maxlen=max(criteria.nis_window, 1))
        self._nis_total = None
        self.holding_since_s = None

    def on_update(self, stamp_s: float, accepted: bool, nis: float, dof: int = 3, source: str = "gnss") -> None:
        """An accepted measurement update with its NIS (rejected updates do not count). ``source`` names its stream
        ("gnss": fixes and GNSS velocities; "zupt": the session's zero-velocity updates of a static core): the window
        tests one stream and restarts when the stream changes (core auto's hand-over from its parked static core to
        the in-motion core, whose fixes are a new filter's: on KITTI 0057 the park's zero-velocity innovations, a
        real car's vibration, stayed in the window of the first fixes after the drive-off, a sum of 168 against a
        band of [14, 54], and held the flag down)."""
        if not accepted or not math.isfinite(nis):
            return
        if source != self.nis_source:
            self.nis.clear()
            self.nis_source = source
        self.nis.append(float(nis))
        self._nis_total = None
        self.nis_dof = int(dof)
        self.last_update_s = float(stamp_s)

    def _failing(self, stamp_s: float, P_att_n: np.ndarray) -> str:
        c = self.criteria
        sl = attitude_3sigma_list(P_att_n)
        self.sigma3_deg = np.array(sl)
        if not (math.isfinite(sl[0]) and math.isfinite(sl[1]) and math.isfinite(sl[2])):
            return "attitude covariance is not finite"
        bound = self.level_bound_deg
        if max(sl[0], sl[1]) >= bound:
            why = ("" if bound == c.roll_pitch_3sigma_deg else
                   f" ({c.level_floor_factor:g} x the level floor {self.level_floor_deg:.2f} deg of the declared "
                   f"accelerometer bias)")
            return f"3-sigma roll/pitch {max(sl[0], sl[1]):.2f} deg >= {bound:.3g} deg{why}"
        if sl[2] >= c.yaw_3sigma_deg:
            return f"3-sigma yaw {sl[2]:.2f} deg >= {c.yaw_3sigma_deg:g} deg"
        if self.last_update_s is None:
            return "no accepted measurement update yet"
        age = stamp_s - self.last_update_s
        if age > c.max_update_age_s:
            return f"last accepted update {age:.1f} s ago (> {c.max_update_age_s:g} s)"
        if c.nis_window > 0:
            need = min(c.nis_window, c.nis_min_updates)
            if len(self.nis) < need:
                return f"NIS window filling ({len(self.nis)}/{need} updates)"
            alpha = c.nis_alpha_drop if self.aligned else c.nis_alpha  # hysteresis: a wider band to stay up
            self.band = lo, hi = nis_band(len(self.nis), self.nis_dof, alpha)
            # the window's sum, recomputed only when an update changed it (outputs outnumber updates): the same
            # float as summing at every output (a running sum would round differently)
            if self._nis_total is None:
                self._nis_total = float(sum(self.nis))
            self.nis_sum = total = self._nis_total
            if total > hi:
                return f"NIS sum {total:.1f} above the chi-square band [{lo:.1f}, {hi:.1f}] (over-confident)"
            if c.nis_lower_check and total < lo:
                return f"NIS sum {total:.1f} below the chi-square band [{lo:.1f}, {hi:.1f}] (pessimistic)"
        return ""

    def on_estimate(self, stamp_s: float, P_att_n: np.ndarray) -> bool:
        """Evaluate the criteria at ``stamp_s`` [s data time]; returns the flag."""
        failing = self._failing(float(stamp_s), P_att_n)
        if failing:
            self.aligned = False
            self.holding_since_s = None
            self.reason = failing
            return False
        if self.holding_since_s is None:
            self.holding_since_s = float(stamp_s)
        held = stamp_s - self.holding_since_s
        # (stamps are sums of float intervals: 14.04 s plus twenty 0.1-s periods, minus 14.04 s, is 1.999999999999993 s,
        # which a 2-s hold must pass, not wait another output for)
        if not self.aligned and held >= self.criteria.hold_s - HOLD_TOL_S:
            self.aligned = True
            self.raised_at_s = float(stamp_s)
            if self.first_raised_at_s is None:
                self.first_raised_at_s = float(stamp_s)
        self.reason = ("criteria hold" if self.aligned
                       else f"criteria hold for {held:.1f} of {self.criteria.hold_s:g} s")
        return self.aligned


def euler_3sigma_deg(C_b_n: np.ndarray, P_att_n: np.ndarray) -> np.ndarray:
    """3-sigma [deg] of roll, pitch, yaw for an attitude C_b_n with ENU error covariance P_att_n.

    Maps the covariance of ``psi`` (C_true = exp(psi_x) C_est) through the Jacobian of the Euler angles,
    ``d(rpy)/d(psi) = E^-1`` (E: ``psi = E d(roll, pitch, yaw)``, columns Rz(yaw) Ry(pitch) e1, Rz(yaw) e2, e3),
    so roll and pitch are about the body axes, not East and North. Closed form (test_session.py checks it against
    central differences); singular at pitch +-90 deg, where the roll/yaw split is undefined and the result is
    infinite."""
    C = np.asarray(C_b_n, float)
    sp = max(-1.0, min(1.0, float(C[2, 0])))  # sin(pitch) = -C[2, 0]: only its magnitude and tan matter below
    cp = math.sqrt(1.0 - sp * sp)  # det(E) = cos(pitch)
    if abs(sp) > 1.0 - 1e-12 or cp < 1e-12:
        return np.full(3, np.inf)
    yaw = math.atan2(C[1, 0], C[0, 0])
    cy, sy, tp = math.cos(yaw), math.sin(yaw), -sp / cp
    # E^-1 in closed form (per output this runs at the output rate; np.linalg.inv's errstate costs ~30 us):
    # rows (cy/cp, sy/cp, 0), (-sy, cy, 0), (cy tp, sy tp, 1)
    (a, b, c), (_, d, e), (_, _, f) = np.asarray(P_att_n, float).tolist()
    # u P u' of a row u = (ux, uy, uz): the covariance of one Euler angle
    def quad(ux, uy, uz):
        return ux * ux * a + uy * uy * d + uz * uz * f + 2.0 * (ux * uy * b + ux * uz * c + uy * uz * e)
    var = (quad(cy / cp, sy / cp, 0.0), quad(-sy, cy, 0.0), quad(cy * tp, sy * tp, 1.0))
    return np.array([3.0 * math.degrees(math.sqrt(v)) if v > 0.0 else 0.0 for v in var])


def euler_3sigma_deg_many(C_b_n: np.ndarray, P_att_n: np.ndarray) -> np.ndarray:
    """:func:`euler_3sigma_deg` of n attitudes (n, 3, 3) and covariances (n, 3, 3) at once: the same operations in
    the same order, elementwise (test_speed_paths checks the numbers against one call per output)."""
    C = np.asarray(C_b_n, float).reshape(-1, 3, 3)
    P = np.asarray(P_att_n, float).reshape(-1, 3, 3)
    sp = np.minimum(1.0, np.maximum(-1.0, C[:, 2, 0]))
    cp = np.sqrt(1.0 - sp * sp)
    singular = (np.abs(sp) > 1.0 - 1e-12) | (cp < 1e-12)
    cp = np.where(singular, 1.0, cp)
    yaw = np.arctan2(C[:, 1, 0], C[:, 0, 0])
    cy, sy, tp = np.cos(yaw), np.sin(yaw), -sp / cp
    a, b, c, d, e, f = P[:, 0, 0], P[:, 0, 1], P[:, 0, 2], P[:, 1, 1], P[:, 1, 2], P[:, 2, 2]

    def quad(ux, uy, uz):
        return ux * ux * a + uy * uy * d + uz * uz * f + 2.0 * (ux * uy * b + ux * uz * c + uy * uz * e)

    zero = np.zeros_like(sp)
    var = np.stack((quad(cy / cp, sy / cp, zero), quad(-sy, cy, zero), quad(cy * tp, sy * tp, zero + 1.0)), axis=1)
    with np.errstate(invalid="ignore"):
        out = np.where(var > 0.0, 3.0 * np.degrees(np.sqrt(np.where(var > 0.0, var, 0.0))), 0.0)
    out[singular] = np.inf
    return out
