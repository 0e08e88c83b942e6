"""Motion detector: is the vehicle translating? IMU window statistics and GNSS speed, with hysteresis. ROS-free.

Engine vibration, body sway and a person getting in shake the IMU but do not move the vehicle; a drive-off does.
So the detector separates *shaking* from *translation* (docs/motion_detector.md):

* ``dv_h``: the horizontal velocity change over the last ``dv_window_s``, from the specific force minus the
  specific force of the ``ref_window_s`` before it, rotated by the gyro-integrated rotation since then (a tilt from a
  person sitting down is a rotation, not an acceleration). Projected on the plane normal to the reference specific
  force, i.e. horizontal: heave when someone sits down is vertical and zero-mean. Motion evidence when above
  ``dv_threshold = sqrt(chi2_2(1 - p)) VRW sqrt(T_v + T_v^2 / T_r) (+ g ARW sqrt(T_r + T_v) T_v) + dv_margin_m_s``.
* ``spread_f``, ``spread_omega``: the standard deviation (root of the trace of the window covariance) of the
  specific force and angular rate over ``window_s``. White noise of the IMU's VRW/ARW gives
  ``W s^2 / sigma^2 ~ chi2(3 (W - 1))``; the threshold is that chi-square bound at ``1 - p_false_alarm`` plus the
  allowed vibration RMS in quadrature. Below both thresholds (and ``dv_h`` small) the IMU is *quiet*: rest evidence.
* GNSS speed (norm of the velocity, per-axis sigma): motion evidence above ``sqrt(chi2_3(1 - p)) sigma``, else
  consistent with rest. Used while younger than ``gnss_timeout_s``. Walking-speed veto: ``walk_veto_count``
  consecutive GNSS speeds above ``walk_speed_m_s`` and 3 sigma are motion evidence and veto rest (the 5.5-sigma
  bound alone is 27 m/s for a consumer receiver's 3-5 m per-fix sigma: core auto gives the speed the sigma its fixes
  show, see session/auto.py; one multipath jump spoils two consecutive differences: hence three).
* Learned vibration allowance (``learn_cap_factor`` > 0): the spreads of consecutive ``window_s`` blocks are
  collected (no block with a velocity change over its bound or a GNSS speed over walking speed); while the GNSS
  speed is ~0 (under half the walking speed) the bound is ``LEARN_MARGIN_GNSS`` x their 95th percentile, without
  GNSS ``LEARN_MARGIN_QUIET`` x the 20th percentile of the last ``LEARN_SPAN_S`` (the quietest windows), never below the
  IMU grade's prior (``vib_acc_rms_m_s2``, ``vib_gyro_rms_deg_s``) and never above ``learn_cap_factor`` x it
  (2 x without a GNSS speed). A real parked car shakes at 0.25-0.4 m/s^2 (engine harmonics, a running fan):
  the fixed prior alone never sees it parked.

Hysteresis: motion is declared after ``enter_hold_s`` of uninterrupted motion evidence; rest after ``leave_hold_s``
of uninterrupted rest evidence (quiet IMU, and a fresh GNSS speed if any consistent with zero). Anything else keeps
the state: a person getting in is neither. Before the first decision the state is undecided (``decided`` False).

Two paths with the same decisions (test/test_motion.py): ``detect_motion`` takes whole arrays (offline),
``MotionDetector`` takes samples one by one (``push_imu``) or runs of them (``push_imu_arrays``, the same numbers bit
for bit); all compute the window statistics with one compiled kernel (motion_kernels.py) and decide with
``_Hysteresis``. The rates are treated as nominal (1 / rate_hz); a stamp gap over ``GAP_FACTOR`` sample intervals
restarts the windows (the decision is kept). ``blocking()`` says in words what keeps the state from "parked".
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..core.stats import chi2_ppf
from ..filters import imu_grade
from ..filters.config import ConfigDict
from ..sim import error_model
from .motion_kernels import window_stats_nb

G_M_S2 = error_model.G0_M_S2
#: a stamp step over this many nominal intervals restarts the windows (3: host-stamp jitter and drivers that alternate
#: 20/30-ms intervals, as a real VN-100 at 40 Hz, must not restart them at every sample)
GAP_FACTOR = 3.0
#: learned allowance: these factors over the 95th percentile of the blocks while the GNSS speed is ~0, and over the
#: 20th percentile of all quiet blocks without one (harmonics beating in a 0.5-s window spread by +-20 %)
LEARN_MARGIN_GNSS, LEARN_MARGIN_QUIET = 1.25, 1.5
LEARN_SPAN_S = 60.0  #: blocks older than this are forgotten [s]
LEARN_MIN_BLOCKS = 4  #: blocks needed before anything is learned


@dataclass
class MotionConfig(ConfigDict):
    """Motion-detector parameters. Noise densities are the IMU grade's (``from_imu_grade``; ``from_imu_spec`` for a
    simulated IMU's own numbers)."""

    #: IMU sample rate [Hz] (windows are counted in samples of 1 / rate_hz)
    rate_hz: float = 100.0
    #: gyro angle random walk [deg/sqrt(h)] and accelerometer velocity random walk [m/s/sqrt(h)] of the IMU
    gyro_arw_deg_sqrt_h: float = 0.3
    acc_vrw_m_s_sqrt_h: float = 0.1
    #: window of the spreads [s]; velocity-change window and the reference window before it [s]
    window_s: float = 0.5
    dv_window_s: float = 1.0
    ref_window_s: float = 1.0
    #: false-alarm probability per test of the chi-square bounds (IMU windows, GNSS speed)
    p_false_alarm: float = 1e-6
    #: vibration allowed at rest, RMS of the vector (engine idle 0.05-0.15 m/s^2, ~1 deg/s; road at speed is more)
    vib_acc_rms_m_s2: float = 0.25
    vib_gyro_rms_deg_s: float = 1.5
    #: allowance for the horizontal velocity of a rocking car body at the IMU (lever arm) [m/s]
    dv_margin_m_s: float = 0.1
    #: hysteresis: evidence must hold this long to declare motion / rest [s]
    enter_hold_s: float = 0.2
    leave_hold_s: float = 2.0
    #: a GNSS speed older than this is not used [s]
    gnss_timeout_s: float = 1.5
    #: walking-speed veto: this many consecutive GNSS speeds above walk_speed_m_s are motion, whatever their sigma
    walk_speed_m_s: float = 1.5
    walk_veto_count: int = 3
    #: learned vibration allowance: at most this factor x the prior (0: the fixed prior only)
    learn_cap_factor: float = 4.0

    @classmethod
    def from_imu_spec(cls, spec, **overrides) -> "MotionConfig":
        """Config for an IMU grade (sim.types.ImuSpec or anything with arw_deg_sqrt_h, vrw_m_s_sqrt_h, rate_hz)."""
        base = dict(rate_hz=float(spec.rate_hz), gyro_arw_deg_sqrt_h=float(spec.arw_deg_sqrt_h),
                    acc_vrw_m_s_sqrt_h=float(spec.vrw_m_s_sqrt_h))
        return cls.from_dict({**base, **overrides})

    @classmethod
    def from_imu_grade(cls, grade, rate_hz: float, **overrides) -> "MotionConfig":
        """Config for an IMU grade (a preset name of filters/imu_grade.py or an ImuGrade): its ARW and VRW set the
        white-noise part of every threshold (what ``core: auto`` uses: the session's ``imu_grade``)."""
        g = imu_grade.get_grade(grade)
        base = dict(rate_hz=float(rate_hz), gyro_arw_deg_sqrt_h=float(g.gyro_arw_deg_sqrt_h),
                    acc_vrw_m_s_sqrt_h=float(g.acc_vrw_m_s_sqrt_h))
        return cls.from_dict({**base, **overrides})

    def validate(self) -> None:
        self.check_field_types(non_negative=True)
        if self.rate_hz <= 0 or not 0 < self.p_false_alarm < 1:
            raise ValueError("rate_hz must be > 0 and p_false_alarm in (0, 1)")
        n = self.samples()
        if min(n.values()) < 2:
            raise ValueError(f"windows must hold at least 2 samples at {self.rate_hz} Hz: {n}")
        if n["window"] > n["dv"] + n["ref"]:
            raise ValueError("window_s must not exceed dv_window_s + ref_window_s")
        if self.walk_veto_count < 1:
            raise ValueError("walk_veto_count must be >= 1")

    def samples(self) -> dict:
        """Window lengths in samples."""
        lengths = {"window": self.window_s, "dv": self.dv_window_s, "ref": self.ref_window_s}
        return {k: int(round(v * self.rate_hz)) for k, v in lengths.items()}

    def thresholds(self) -> dict:
        """The bounds, derived from the IMU noise (see the module docstring)."""
        n = self.samples()
        dt = 1.0 / self.rate_hz
        arw = error_model.deg_sqrt_h_to_rad_sqrt_s(self.gyro_arw_deg_sqrt_h)
        vrw = error_model.m_s_sqrt_h_to_m_s_sqrt_s(self.acc_vrw_m_s_sqrt_h)
        W = n["window"]
        q = chi2_ppf(1.0 - self.p_false_alarm, 3 * (W - 1)) / W  # bound on s^2 / sigma_sample^2
        Tv, Tr = n["dv"] * dt, n["ref"] * dt
        dv_noise = math.hypot(vrw * math.sqrt(Tv + Tv**2 / Tr), G_M_S2 * arw * math.sqrt(Tr + Tv) * Tv)
        return {
            "spread_f_m_s2": math.sqrt(vrw**2 / dt * q + self.vib_acc_rms_m_s2**2),
            "spread_omega_rad_s": math.sqrt(arw**2 / dt * q + math.radians(self.vib_gyro_rms_deg_s) ** 2),
            "dv_h_m_s": math.sqrt(chi2_ppf(1.0 - self.p_false_alarm, 2)) * dv_noise + self.dv_margin_m_s,
            "gnss_speed_per_sigma": math.sqrt(chi2_ppf(1.0 - self.p_false_alarm, 3)),
        }


def window_statistics(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, cfg: MotionConfig) -> dict:
    """Per-sample statistics of one gap-free run of samples (NaN until the windows are full).

    omega_ib_b [rad/s], f_ib_b [m/s^2]: (N, 3). Returns arrays (N,): spread_f [m/s^2], spread_omega [rad/s], dv_h [m/s]
    (module docstring; one compiled pass, :func:`motion_kernels.window_stats_nb`).
    """
    n = cfg.samples()
    X = np.concatenate([np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float)], axis=1)
    out = np.empty((X.shape[0], 3))
    window_stats_nb(X, 0, int(n["window"]), int(n["dv"]), int(n["ref"]), 1.0 / cfg.rate_hz, out)
    return {"spread_f": out[:, 0], "spread_omega": out[:, 1], "dv_h": out[:, 2]}


def _gnss_flags(gnss: tuple, thr: dict, cfg: MotionConfig) -> tuple[bool, bool]:
    """(GNSS says moving, GNSS says ~0) from (speed, sigma, consecutive speeds over walking speed) or Nones."""
    speed, sigma, n_fast = gnss
    if speed is None:
        return False, False
    moving = speed > thr["gnss_speed_per_sigma"] * sigma or n_fast >= cfg.walk_veto_count
    return moving, speed < min(0.5 * cfg.walk_speed_m_s, 3.0 * sigma) and not moving


def _evidence(stats: dict, gnss: tuple, thr: dict, cfg: MotionConfig) -> tuple[bool, bool]:
    """(motion evidence, rest evidence) of one sample from its statistics and its fresh GNSS speed (or Nones)."""
    gnss_moving = _gnss_flags(gnss, thr, cfg)[0]
    if not np.isfinite(stats["dv_h"]):  # windows not full: only GNSS can tell
        return gnss_moving, False
    imu_moving = stats["dv_h"] > thr["dv_h_m_s"]
    quiet = (stats["spread_f"] < thr["spread_f_m_s2"] and stats["spread_omega"] < thr["spread_omega_rad_s"]
             and not imu_moving)
    return imu_moving or gnss_moving, quiet and not gnss_moving


def blocking(stats: dict, gnss: tuple, thr: dict, cfg: MotionConfig, learned: str) -> str:
    """What keeps the detector from rest evidence, in words ("" when nothing does)."""
    speed, sigma, n_fast = gnss
    if speed is not None and _gnss_flags(gnss, thr, cfg)[0]:
        return (f"not parked: GNSS speed {speed:.1f} m/s above "
                + (f"walking speed {cfg.walk_speed_m_s:g} m/s" if n_fast >= cfg.walk_veto_count
                   else f"its bound {thr['gnss_speed_per_sigma'] * sigma:.2f} m/s"))
    if not np.isfinite(stats["dv_h"]):
        return "motion undecided: IMU windows filling"
    if stats["dv_h"] > thr["dv_h_m_s"]:
        return f"not parked: horizontal velocity change {stats['dv_h']:.2f} m/s above {thr['dv_h_m_s']:.2f}"
    if stats["spread_f"] >= thr["spread_f_m_s2"]:
        return (f"not parked: specific-force spread {stats['spread_f']:.2f} m/s^2 above the {learned} "
                f"{thr['spread_f_m_s2']:.2f}")
    if stats["spread_omega"] >= thr["spread_omega_rad_s"]:
        return (f"not parked: angular-rate spread {math.degrees(stats['spread_omega']):.2f} deg/s above the "
                f"{learned} {math.degrees(thr['spread_omega_rad_s']):.2f}")
    return ""


def percentile(values: list, q: float) -> float:
    """``np.percentile(values, q)`` bit for bit (numpy's "linear" method and ``_lerp``; NaN if any value is NaN)
    without numpy's ~30 us per call: the learner runs once per block while parked."""
    s = sorted(values)
    if any(x != x for x in s):
        return math.nan
    v = (len(s) - 1) * (q / 100)
    if v >= len(s) - 1:
        return float(s[-1])
    i = math.floor(v)
    g, a, b = v - i, s[i], s[i + 1]
    return float(b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g)


class VibrationLearner:
    """The vibration allowance learned from the recording (module docstring): feed the spreads of consecutive
    ``window_s`` blocks with their GNSS flags; ``thresholds`` are the config's with the spread bounds raised to what
    the quiet blocks show."""

    def __init__(self, cfg: MotionConfig):
        self.cfg = cfg
        self.prior = cfg.thresholds()
        self.thresholds = dict(self.prior)
        self.blocks: deque = deque()  # (t, spread_f, spread_omega, gnss_zero)
        self.source = "prior"

    def add(self, t_s: float, spread_f: float, spread_omega: float, dv_ok: bool, gnss: tuple,
            declared_moving: bool) -> None:
        """One block's spreads [m/s^2, rad/s]; dv_ok: the velocity change under its bound; declared_moving: the
        detector's state (without a GNSS speed ~0 nothing is learned while driving: a smooth road is quiet too)."""
        cfg = self.cfg
        if cfg.learn_cap_factor <= 0 or not dv_ok:
            return
        moving, zero = _gnss_flags(gnss, self.prior, cfg)
        if moving or (declared_moving and not zero):
            return
        self.blocks.append((t_s, spread_f, spread_omega, zero))
        while self.blocks[0][0] < t_s - LEARN_SPAN_S:
            self.blocks.popleft()
        z = [b for b in self.blocks if b[3]]
        if len(z) >= LEARN_MIN_BLOCKS:
            rows, q, m, cap = z, 95.0, LEARN_MARGIN_GNSS, cfg.learn_cap_factor
            self.source = "learned (GNSS speed ~0)"
        elif len(self.blocks) >= LEARN_MIN_BLOCKS:
            rows, q, m, cap = self.blocks, 20.0, LEARN_MARGIN_QUIET, min(2.0, cfg.learn_cap_factor)
            self.source = "learned (quietest windows)"
        else:
            return
        learned = [m * percentile([b[i] for b in rows], q) for i in (1, 2)]
        for i, key, vib in ((0, "spread_f_m_s2", cfg.vib_acc_rms_m_s2),
                            (1, "spread_omega_rad_s", math.radians(cfg.vib_gyro_rms_deg_s))):
            p = self.prior[key]
            self.thresholds[key] = float(min(max(learned[i], p), math.sqrt(p * p + (cap * cap - 1) * vib * vib)))

    def word(self) -> str:
        return "learned" if self.thresholds != self.prior else "prior"


class _Hysteresis:
    """Declares motion after enter_hold_s of motion evidence, rest after leave_hold_s of rest evidence."""

    def __init__(self, enter_hold_s: float, leave_hold_s: float):
        self.enter_hold_s, self.leave_hold_s = enter_hold_s, leave_hold_s
        self.state: bool | None = None  # None: undecided
        self.since_s = self.declared_s = math.nan
        self._motion_from = self._rest_from = None

    def step(self, t_s: float, motion: bool, rest: bool) -> None:
        self._motion_from = (self._motion_from if self._motion_from is not None else t_s) if motion else None
        self._rest_from = (self._rest_from if self._rest_from is not None else t_s) if rest else None
        if self.state is not True and motion and t_s - self._motion_from >= self.enter_hold_s:
            self.state, self.since_s, self.declared_s = True, self._motion_from, t_s
        elif self.state is not False and rest and t_s - self._rest_from >= self.leave_hold_s:
            self.state, self.since_s, self.declared_s = False, self._rest_from, t_s


@dataclass(frozen=True)
class MotionDecision:
    """moving: declared in motion (False also while undecided); since_s: onset of the evidence that decided it;
    declared_s: when it was declared; decided: False until the first decision."""

    moving: bool
    decided: bool
    since_s: float
    declared_s: float


@dataclass
class MotionTrack:
    """Offline result of detect_motion: per IMU sample (arrays (N,)), the decision and the numbers behind it."""

    t_s: np.ndarray
    moving: np.ndarray  # bool
    decided: np.ndarray  # bool
    since_s: np.ndarray
    spread_f: np.ndarray  # [m/s^2]
    spread_omega: np.ndarray  # [rad/s]
    dv_h: np.ndarray  # [m/s]
    gnss_speed: np.ndarray  # [m/s], NaN when no fresh GNSS speed
    thresholds: dict  # at the end (the learned spread bounds)
    rejected: int = 0
    spread_f_threshold: np.ndarray | None = None  # [m/s^2] per sample, as learned so far

    def declarations(self) -> list[tuple[float, bool]]:
        """(stamp [s], moving) of every change of the decision."""
        d = np.flatnonzero(self.decided)
        if d.size == 0:
            return []
        state = self.moving[d]
        change = np.concatenate([[True], state[1:] != state[:-1]])
        return [(float(self.t_s[d[i]]), bool(state[i])) for i in np.flatnonzero(change)]


def _valid_gnss(t, speed, sigma):
    ok = np.isfinite(t) & np.isfinite(speed) & np.isfinite(sigma) & (speed >= 0) & (sigma > 0)
    ok &= t > np.concatenate([[-np.inf], np.fmax.accumulate(np.where(ok, t, -np.inf))[:-1]])
    return t[ok], speed[ok], sigma[ok]


def _fast_counts(speed: np.ndarray, sigma: np.ndarray, walk_m_s: float) -> np.ndarray:
    """Consecutive GNSS speeds over walking speed (and 3 sigma) up to and including each one."""
    n, out = 0, np.zeros(len(speed), int)
    for i, v in enumerate(speed):
        n = n + 1 if v > max(walk_m_s, 3.0 * sigma[i]) else 0
        out[i] = n
    return out


def _block_spreads(x: np.ndarray, W: int) -> np.ndarray:
    """Spread (root of the trace of the covariance) of consecutive W-sample blocks of x (N, 3)."""
    nb = x.shape[0] // W
    b = x[:nb * W].reshape(nb, W, 3)
    return np.sqrt(np.maximum(b.var(axis=1).sum(axis=1), 0.0))


def _segments(t_s: np.ndarray, rate_hz: float):
    """Slices of gap-free runs (a stamp step over GAP_FACTOR nominal intervals starts a new run)."""
    cut = np.flatnonzero(np.diff(t_s) > GAP_FACTOR / rate_hz) + 1
    edges = np.concatenate([[0], cut, [len(t_s)]])
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def detect_motion(t_s, omega_ib_b, f_ib_b, cfg: MotionConfig, gnss_t_s=None, gnss_speed_m_s=None,
                  gnss_sigma_m_s=None) -> MotionTrack:
    """Offline path: the decisions for whole arrays (the same as pushing them one by one into MotionDetector).

    t_s (N,) [s] increasing; omega_ib_b [rad/s], f_ib_b [m/s^2] (N, 3) body FLU; optional GNSS speed: stamps [s],
    speed (norm of the velocity) [m/s] and its per-axis sigma [m/s]. A GNSS speed applies to IMU samples with a
    stamp >= its own (within gnss_timeout_s). Non-finite or non-increasing IMU samples are rejected (counted).
    """
    t_s, omega, f = (np.asarray(a, float) for a in (t_s, omega_ib_b, f_ib_b))
    ok = np.isfinite(t_s) & np.isfinite(omega).all(1) & np.isfinite(f).all(1)
    ok &= t_s > np.concatenate([[-np.inf], np.fmax.accumulate(np.where(ok, t_s, -np.inf))[:-1]])
    rejected = int((~ok).sum())
    t_s, omega, f = t_s[ok], omega[ok], f[ok]
    N = len(t_s)
    stats = {k: np.full(N, np.nan) for k in ("spread_f", "spread_omega", "dv_h")}
    for sl in _segments(t_s, cfg.rate_hz):
        for k, v in window_statistics(omega[sl], f[sl], cfg).items():
            stats[k][sl] = v
    W = cfg.samples()["window"]
    block = {}  # sample index ending a block -> (spread_f, spread_omega)
    for sl in _segments(t_s, cfg.rate_hz):
        sf, so = _block_spreads(f[sl], W), _block_spreads(omega[sl], W)
        for i in range(len(sf)):
            block[sl.start + (i + 1) * W - 1] = (float(sf[i]), float(so[i]))
    g_speed = np.full(N, np.nan)
    g_sigma = np.full(N, np.nan)
    g_fast = np.zeros(N, int)
    if gnss_t_s is not None and len(gnss_t_s):
        gt, gs, gsig = _valid_gnss(*(np.asarray(a, float) for a in (gnss_t_s, gnss_speed_m_s, gnss_sigma_m_s)))
        gn = _fast_counts(gs, gsig, cfg.walk_speed_m_s)
        j = np.searchsorted(gt, t_s, side="right") - 1
        fresh = (j >= 0) & (t_s - gt[np.maximum(j, 0)] <= cfg.gnss_timeout_s)
        g_speed[fresh], g_sigma[fresh], g_fast[fresh] = gs[j[fresh]], gsig[j[fresh]], gn[j[fresh]]
    learner = VibrationLearner(cfg)
    hyst = _Hysteresis(cfg.enter_hold_s, cfg.leave_hold_s)
    moving, decided, since = np.zeros(N, bool), np.zeros(N, bool), np.full(N, np.nan)
    spread_thr = np.full(N, np.nan)
    for k in range(N):
        gnss = (g_speed[k], g_sigma[k], int(g_fast[k])) if np.isfinite(g_speed[k]) else (None, None, 0)
        st = {n: stats[n][k] for n in stats}
        if k in block:
            learner.add(float(t_s[k]), *block[k], not st["dv_h"] > learner.prior["dv_h_m_s"], gnss, hyst.state is True)
        hyst.step(float(t_s[k]), *_evidence(st, gnss, learner.thresholds, cfg))
        moving[k], decided[k], since[k] = hyst.state is True, hyst.state is not None, hyst.since_s
        spread_thr[k] = learner.thresholds["spread_f_m_s2"]
    return MotionTrack(t_s, moving, decided, since, stats["spread_f"], stats["spread_omega"], stats["dv_h"],
                       g_speed, learner.thresholds, rejected, spread_thr)


def rate_hz_from_intervals(dts) -> float:
    """An IMU's rate [Hz] from its stamp intervals [s]: the mean interval without gaps (a driver alternating 20/30-ms
    intervals has a median of 20 ms: a detector at 50 Hz would take every 30-ms interval for a gap)."""
    d = np.asarray(dts, float)
    return 1.0 / float(np.mean(d[d <= 3.0 * np.median(d)]))


class FixNoise:
    """Per-axis noise of the fixes [m] as the data show it: robust sigma of the second differences of the last ``n``
    positions over sqrt(6) (white noise; a vehicle's own acceleration only adds to it), inf until there are enough.
    A consumer receiver's errors are correlated from fix to fix: its 1-s position differences are far better than its
    3-5 m per-fix sigma says (the sigma of the walking-speed veto, session/auto.py)."""

    def __init__(self, n: int = 10) -> None:
        self.h: deque = deque(maxlen=n)  # (t, p_e) of the last fixes

    def push(self, t: float, p_e) -> float:
        """A fix (stamp [s], ECEF position [m]); returns the noise with it [m] (a 2-s gap, or a stamp not after the
        last one, restarts the history: inf until it holds ``n`` fixes again)."""
        h = self.h
        if h and not 0.0 < t - h[-1][0] <= 2.0:
            h.clear()
        h.append((t, np.asarray(p_e, float)))
        if len(h) < h.maxlen:
            return math.inf
        tt = np.array([x[0] for x in h])
        pp = np.array([x[1] for x in h])
        d1 = np.diff(pp, axis=0) / np.diff(tt)[:, None]
        d2 = (d1[1:] - d1[:-1]) * np.diff(tt)[1:, None]  # [m] at the fix interval
        r = d2 - np.median(d2, axis=0)
        return float(1.4826 * np.median(np.abs(r)) / math.sqrt(6.0))


class MotionDetector:
    """Per-sample path: push IMU samples and GNSS speeds in stamp order, read ``decision`` and ``diagnostics()``."""

    def __init__(self, cfg: MotionConfig):
        self.cfg = cfg
        self.thresholds = cfg.thresholds()
        n = cfg.samples()
        self._L = n["dv"] + n["ref"]
        self._t: deque = deque(maxlen=self._L)
        # the last L samples, each row written twice (at i and i + L) so that rows [i + 1, i + 1 + L) are always
        # the window in order, without a copy per sample
        self._ring = np.zeros((2 * self._L, 6))
        self._i = -1
        self._gnss: deque = deque(maxlen=16)  # (stamp, speed, sigma, consecutive over walking), pending or current
        self._n_fast = 0
        self._hyst = _Hysteresis(cfg.enter_hold_s, cfg.leave_hold_s)
        self._stats = {"spread_f": math.nan, "spread_omega": math.nan, "dv_h": math.nan}
        self._gnss_now = (None, None, 0, math.nan)  # speed, sigma, consecutive over walking, age
        self.learner = VibrationLearner(cfg)
        self._W = n["window"]
        self._nb_args = (int(n["window"]), int(n["dv"]), int(n["ref"]), 1.0 / cfg.rate_hz)  # window_stats_nb's
        self._blk: list = []  # the samples (omega, f) of the spread block being filled (slices of the rows taken)
        self._nblk = 0  # ... their number
        self.rejected = {"imu": 0, "gnss": 0}
        self.last_reject_reason = ""

    def _reject(self, kind: str, reason: str) -> None:
        self.rejected[kind] += 1
        self.last_reject_reason = reason

    def push_gnss_speed(self, stamp_s: float, speed_m_s: float, sigma_m_s: float,
                        veto_sigma_m_s: float | None = None) -> bool:
        """A GNSS speed (norm of the velocity [m/s], per-axis sigma [m/s]; veto_sigma_m_s: the sigma of the
        walking-speed veto, e.g. the one the fixes show, default sigma_m_s); False (counted) when rejected."""
        vals = (float(stamp_s), float(speed_m_s), float(sigma_m_s))
        if not (all(map(math.isfinite, vals)) and vals[1] >= 0 and vals[2] > 0):
            self._reject("gnss", f"GNSS speed not finite or sigma <= 0: {vals}")
            return False
        if self._gnss and vals[0] <= self._gnss[-1][0]:
            self._reject("gnss", f"GNSS speed stamp {vals[0]} not after {self._gnss[-1][0]}")
            return False
        vs = vals[2] if veto_sigma_m_s is None or not veto_sigma_m_s > 0 else float(veto_sigma_m_s)
        self._n_fast = self._n_fast + 1 if vals[1] > max(self.cfg.walk_speed_m_s, 3.0 * vs) else 0
        self._gnss.append(vals + (self._n_fast,))
        return True

    def push_imu(self, stamp_s: float, omega_ib_b, f_ib_b) -> MotionDecision:
        """One IMU sample (stamp [s], omega_ib_b [rad/s], f_ib_b [m/s^2]); returns the decision after it."""
        t = float(stamp_s)
        omega, f = np.asarray(omega_ib_b, float).reshape(3), np.asarray(f_ib_b, float).reshape(3)
        if not (math.isfinite(t) and np.isfinite(omega).all() and np.isfinite(f).all()):
            self._reject("imu", "IMU sample not finite")
            return self.decision
        if self._t and t <= self._t[-1]:
            self._reject("imu", f"IMU stamp {t} not after {self._t[-1]}")
            return self.decision
        if self._t and t - self._t[-1] > GAP_FACTOR / self.cfg.rate_hz:
            self._t.clear()  # a gap restarts the windows
            self._blk, self._nblk = [], 0
        self._take([t], np.concatenate([omega, f])[None, :])
        return self.decision

    def push_imu_arrays(self, t_s, omega_ib_b, f_ib_b, until_moving: bool = False) -> int:
        """``push_imu`` for the leading rows of arrays (t_s (N,) [s], omega_ib_b [rad/s], f_ib_b [m/s^2] (N, 3)) that
        continue the time line (finite, increasing, no gap: the first against the last sample taken), their window
        statistics in one compiled call. Stops at the first other row (not taken: ``push_imu`` it) and, with
        ``until_moving``, after the first row whose decision is motion. Returns the number of rows taken; the
        decisions and numbers are ``push_imu``'s row by row, bit for bit."""
        Tl = np.asarray(t_s, float).tolist()
        rows = np.concatenate([np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float)], axis=1)
        prev, hi, m = self._t[-1] if self._t else None, GAP_FACTOR / self.cfg.rate_hz, 0  # None: a finite stamp
        for t, ok in zip(Tl, np.isfinite(rows).all(1).tolist()):  # the run of good rows (a NaN stamp: steps False)
            if not (ok and (0 < t - prev <= hi if prev is not None else math.isfinite(t))):
                break
            prev, m = t, m + 1
        return self._take(Tl[:m], rows[:m], until_moving) if m else 0

    def _take(self, Tl: list, rows: np.ndarray, until_moving: bool = False) -> int:
        """Rows (omega, f) (m, 6) at stamps Tl that continue the windows: statistics (the kernel over the last L - 1
        samples and these), GNSS speed, vibration blocks, evidence and hysteresis row by row; returns the rows taken
        (up to the first that declares motion with ``until_moving``)."""
        L, i, m = self._L, self._i, len(Tl)
        hist = min(len(self._t), L - 1)
        out = np.empty((m, 3))
        window_stats_nb(np.concatenate([self._ring[i + 1 + L - hist:i + 1 + L], rows]), hist, *self._nb_args, out)
        sf, so, dv = out.T.tolist()
        taken = m
        # the row loop in locals (per sample; the statistics, GNSS flags and evidence are _evidence's and
        # _Hysteresis.step's operations, bit for bit, test_motion): the thresholds change only at a block's end
        cfg, hyst, learner, gq, W = self.cfg, self._hyst, self.learner, self._gnss, self._W
        thr = self.thresholds = learner.thresholds
        dv_thr, f_thr, w_thr = thr["dv_h_m_s"], thr["spread_f_m_s2"], thr["spread_omega_rad_s"]
        g_key, g_moving = None, False
        blk, nb = self._blk, self._nblk
        a = 0  # the first row of this call not in blk yet
        for r in range(m):
            t = Tl[r]
            while len(gq) > 1 and gq[1][0] <= t:
                gq.popleft()
            g = gq[0] if gq and gq[0][0] <= t else None
            if g is not None and t - g[0] <= cfg.gnss_timeout_s:
                self._gnss_now = (g[1], g[2], g[3], t - g[0])
                if g is not g_key:
                    g_key, g_moving = g, _gnss_flags(g[1:4], thr, cfg)[0]
                gm = g_moving
            else:
                self._gnss_now = (None, None, 0, math.nan)
                gm = False
            nb += 1
            if nb == W:
                blk.append(rows[a:r + 1])
                b = np.concatenate(blk) if len(blk) > 1 else np.array(blk[0])
                blk.clear()
                nb, a = 0, r + 1
                sp = np.sqrt(np.maximum(b.var(axis=0), 0.0).reshape(2, 3).sum(axis=1))
                learner.add(t, float(sp[1]), float(sp[0]), not dv[r] > learner.prior["dv_h_m_s"],
                            self._gnss_now[:3], hyst.state is True)
                thr = self.thresholds = learner.thresholds
                dv_thr, f_thr, w_thr = thr["dv_h_m_s"], thr["spread_f_m_s2"], thr["spread_omega_rad_s"]
                g_key = None
                if self._gnss_now[0] is not None:
                    g_key, g_moving = g, _gnss_flags(g[1:4], thr, cfg)[0]
            d = dv[r]
            if not math.isfinite(d):  # windows not full: only GNSS can tell (_evidence)
                motion, rest = gm, False
            else:
                imu_moving = d > dv_thr
                motion = imu_moving or gm
                rest = sf[r] < f_thr and so[r] < w_thr and not imu_moving and not gm
            hyst.step(t, motion, rest)
            if until_moving and hyst.state is True:
                taken = r + 1
                break
        if a < taken:
            blk.append(rows[a:taken])
        self._nblk = nb
        self._stats = {"spread_f": sf[taken - 1], "spread_omega": so[taken - 1], "dv_h": dv[taken - 1]}
        self._t.extend(Tl[:taken])
        k = min(taken, L)  # only the last L rows stay in the ring, each at j and j + L
        idx = (i + 1 + np.arange(taken - k, taken)) % L
        self._ring[idx] = self._ring[idx + L] = rows[taken - k:taken]
        self._i = (i + taken) % L
        return taken

    def over_rest_bounds(self) -> bool:
        """The last sample's velocity change, specific-force spread or angular-rate spread above its bound (the
        numbers :meth:`diagnostics` reports, without building them: once per zero-velocity update)."""
        s, thr = self._stats, self.thresholds
        return bool(s["dv_h"] > thr["dv_h_m_s"] or s["spread_f"] > thr["spread_f_m_s2"]
                    or math.degrees(s["spread_omega"]) > math.degrees(thr["spread_omega_rad_s"]))

    def blocking(self) -> str:
        """What keeps the detector from seeing the vehicle parked, in words ("" when nothing does)."""
        return blocking(self._stats, self._gnss_now[:3], self.thresholds, self.cfg, self.learner.word())

    @property
    def decision(self) -> MotionDecision:
        h = self._hyst
        return MotionDecision(h.state is True, h.state is not None, h.since_s, h.declared_s)

    def diagnostics(self) -> dict:
        """The decision and the numbers behind it (for /diagnostics key-values)."""
        d, s, thr = self.decision, self._stats, self.thresholds
        speed, sigma, _, age = self._gnss_now
        return {
            "moving": d.moving, "decided": d.decided, "since_s": d.since_s, "declared_s": d.declared_s,
            "spread_f_m_s2": s["spread_f"], "spread_f_threshold_m_s2": thr["spread_f_m_s2"],
            "spread_omega_deg_s": math.degrees(s["spread_omega"]),
            "spread_omega_threshold_deg_s": math.degrees(thr["spread_omega_rad_s"]),
            "dv_h_m_s": s["dv_h"], "dv_h_threshold_m_s": thr["dv_h_m_s"],
            "gnss_speed_m_s": math.nan if speed is None else speed,
            "gnss_speed_threshold_m_s": math.nan if sigma is None else thr["gnss_speed_per_sigma"] * sigma,
            "gnss_age_s": age, "rejected_imu": self.rejected["imu"], "rejected_gnss": self.rejected["gnss"],
            "last_reject_reason": self.last_reject_reason, "vibration_allowance": self.learner.source,
            "blocking": self.blocking(),
        }
