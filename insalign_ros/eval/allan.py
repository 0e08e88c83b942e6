"""Allan deviation of a static IMU recording and the noise terms read off it (IEEE Std 952 slopes).

Overlapping Allan deviation (``allantools.oadev``, rate data) of each gyro and accelerometer axis on log-spaced
averaging times tau, then the standard read-off, each term on the *region* of taus where the local log-log slope is
the term's slope (not a single point), the taus used reported with the value:

* white noise, slope -1/2: sigma(tau) = N / sqrt(tau), N read at tau = 1 s: the angle random walk ARW [rad/sqrt(s)
  -> deg/sqrt(h)] of a gyro, the velocity random walk VRW [m/s/sqrt(s) -> m/s/sqrt(h)] of an accelerometer;
* flicker (bias instability), slope 0: sigma = sqrt(2 ln 2 / pi) B = 0.664 B around the minimum of the curve, B the
  bias instability [rad/s -> deg/h, m/s^2 -> mg];
* rate random walk, slope +1/2 (where present): sigma(tau) = K sqrt(tau / 3), K read at tau = 3 s [rad/s/sqrt(s) ->
  deg/h/sqrt(h), m/s^2/sqrt(s) -> mg/sqrt(h)].

The terms add in *variance*: sigma^2 = N^2/tau + (0.664 B)^2 + K^2 tau/3. Near the ends of its region a pure-slope
line would also count its neighbours' share, so each term is fitted (log-mean over its region) after subtracting the
other terms' variance, three passes; ``adev_min`` / 0.664 (the textbook single-point read-off) is reported too. A
term whose region is not in the curve is ``None`` with a note; a curve still falling at its longest usable tau gives
the bias instability as an upper bound (``bias_instability_bound = "upper"``: the recording is too short to reach
the floor). Usable taus: up to ``duration / MIN_CLUSTERS`` (the longer taus are plotted but too noisy to fit).

A static recording must really be static (gravity and the Earth rate are constants, which the Allan deviation
ignores; a tilt or a turn is not): :func:`check_static` refuses, with the time and the size of the worst excursion,
a recording whose 1-s mean specific force leaves its median by more than ``STATIC_MAX_SF_DEV_M_S2`` or whose 1-s mean
angular rate leaves its median by more than ``STATIC_MAX_RATE_DEV_DEG_S``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.units import G0_M_S2
from ..filters.imu_grade import GRADES, ImuGrade, get_grade

#: flat (flicker) Allan floor = FLICKER_FACTOR x bias instability: sqrt(2 ln 2 / pi)
FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: fit only taus with at least this many independent clusters: tau <= duration / MIN_CLUSTERS
MIN_CLUSTERS = 9
#: a point belongs to a term's region when its local log-log slope is within this of the term's slope
SLOPE_TOL = 0.15
#: taus per decade (log-spaced)
TAUS_PER_DECADE = 10
#: static bounds on the 1-s means (a 0.3 m/s^2 change of the specific force is a 1.8 deg tilt, or an acceleration)
STATIC_WINDOW_S = 1.0
STATIC_MAX_SF_DEV_M_S2 = 0.3
STATIC_MAX_RATE_DEV_DEG_S = 1.0
AXES = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")

_RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0
_M_S2_TO_MG = 1.0 / (1e-3 * G0_M_S2)


class NotStaticError(ValueError):
    """The recording is not static (the message says where and by how much, in one line)."""


@dataclass
class AxisFit:
    """Allan deviation of one axis and the terms read off it, SI (rad/s or m/s^2 based); ``*_taus_s`` the taus of
    each term's region, empty when the term is not in the curve."""

    axis: str
    taus_s: np.ndarray
    adev: np.ndarray
    adev_err: np.ndarray
    n_fit: int  # the first n_fit taus are usable for the read-off (tau <= duration / MIN_CLUSTERS)
    white: float | None = None  # N [rad/sqrt(s) or m/s/sqrt(s)]: sigma at tau = 1 s on the -1/2 line
    white_taus_s: list = field(default_factory=list)
    bias_instability: float | None = None  # B [rad/s or m/s^2]
    bias_instability_bound: str = "fit"  # "fit" (a flat region) or "upper" (the curve still falls: B <= value)
    bias_taus_s: list = field(default_factory=list)
    rrw: float | None = None  # K [rad/s/sqrt(s) or m/s^2/sqrt(s)]: on the +1/2 line at tau = 3 s
    rrw_taus_s: list = field(default_factory=list)
    adev_min: float = float("nan")
    tau_min_s: float = float("nan")
    mean: float = float("nan")  # the mean of the recording [rad/s or m/s^2] (bias + Earth rate / gravity)
    notes: list = field(default_factory=list)

    @property
    def is_gyro(self) -> bool:
        return self.axis.startswith("gyro")

    def in_units(self) -> dict:
        """The terms in datasheet units: gyro deg/sqrt(h), deg/h, deg/h/sqrt(h); accelerometer m/s/sqrt(h), mg,
        mg/sqrt(h)."""
        g = self.is_gyro
        w = None if self.white is None else self.white * (math.degrees(60.0) if g else 60.0)
        b = None if self.bias_instability is None else self.bias_instability * (_RAD_S_TO_DEG_H if g else _M_S2_TO_MG)
        k = None if self.rrw is None else self.rrw * 60.0 * (_RAD_S_TO_DEG_H if g else _M_S2_TO_MG)
        return {"axis": self.axis,
                ("arw_deg_sqrt_h" if g else "vrw_m_s_sqrt_h"): w,
                ("white_taus_s"): [round(x, 4) for x in self.white_taus_s],
                ("bias_instability_deg_h" if g else "bias_instability_mg"): b,
                "bias_instability_bound": self.bias_instability_bound,
                "bias_taus_s": [round(x, 4) for x in self.bias_taus_s],
                ("rrw_deg_h_sqrt_h" if g else "rrw_mg_sqrt_h"): k,
                "rrw_taus_s": [round(x, 4) for x in self.rrw_taus_s],
                "adev_min": self.adev_min * (_RAD_S_TO_DEG_H if g else _M_S2_TO_MG),
                "adev_min_unit": "deg/h" if g else "mg",
                "tau_min_s": self.tau_min_s,
                ("mean_deg_h" if g else "mean_m_s2"): self.mean * (_RAD_S_TO_DEG_H if g else 1.0),
                "notes": list(self.notes)}


@dataclass
class AllanResult:
    """The six axes of one static recording (gyro x y z, accelerometer x y z; the body axes of the data)."""

    rate_hz: float
    duration_s: float
    n: int
    axes: list
    static: dict

    @property
    def gyro(self) -> list:
        return [a for a in self.axes if a.is_gyro]

    @property
    def acc(self) -> list:
        return [a for a in self.axes if not a.is_gyro]

    def grade(self, name: str = "measured", base="unknown_mems", source: str = "") -> ImuGrade:
        """An ImuGrade from the measured terms: the largest of the three axes (a grade has one number per sensor;
        the largest keeps it honest on every axis). The turn-on biases (``gyro_bias_deg_h``, ``acc_bias_mg``) are
        run-to-run quantities no single recording measures: they come from ``base`` (a preset or an ImuGrade).
        A term not in the curve also comes from ``base``; a bias instability that is only an upper bound on every
        axis (the recording too short for the floor) is the smaller of that bound and ``base``'s."""
        b = get_grade(base)
        u = [a.in_units() for a in self.axes]

        def worst(key, fallback):
            vals = [d[key] for d in u if d.get(key) is not None]
            return float(max(vals)) if vals else float(fallback)

        def instability(key, base_value):
            # a flat region measured: the worst axis; only upper bounds (the curve still falls): the data say
            # "at most this", the base grade is the prior: the smaller of the two
            fit = [d[key] for d in u if d.get(key) is not None and d["bias_instability_bound"] == "fit"]
            if fit:
                return float(max(fit))
            bounds = [d[key] for d in u if d.get(key) is not None]
            return float(min(max(bounds), base_value)) if bounds else float(base_value)

        return ImuGrade(name, worst("arw_deg_sqrt_h", b.gyro_arw_deg_sqrt_h), b.gyro_bias_deg_h,
                        instability("bias_instability_deg_h", b.gyro_bias_instability_deg_h),
                        worst("vrw_m_s_sqrt_h", b.acc_vrw_m_s_sqrt_h), b.acc_bias_mg,
                        instability("bias_instability_mg", b.acc_bias_instability_mg), source=source)

    def to_dict(self) -> dict:
        return {"rate_hz": self.rate_hz, "duration_s": self.duration_s, "n": self.n, "static": self.static,
                "min_clusters": MIN_CLUSTERS, "slope_tol": SLOPE_TOL, "flicker_factor": FLICKER_FACTOR,
                "axes": [a.in_units() for a in self.axes],
                "adev": {a.axis: {"taus_s": a.taus_s.tolist(), "adev_si": a.adev.tolist()} for a in self.axes}}


def check_static(t_s, omega_ib_b, f_ib_b, max_sf_dev_m_s2: float = STATIC_MAX_SF_DEV_M_S2,
                 max_rate_dev_deg_s: float = STATIC_MAX_RATE_DEV_DEG_S, window_s: float = STATIC_WINDOW_S) -> dict:
    """The 1-s means of the specific force and the angular rate against their medians; NotStaticError when either
    leaves its bound (the worst window's time and deviation in the message). Returns the two deviations."""
    t = np.asarray(t_s, float)
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(window_s / dt)))
    m = len(t) // n
    if m < 2:
        raise ValueError(f"static check: {len(t)} samples: less than two {window_s:g}-s windows")
    fm = np.asarray(f_ib_b, float)[: m * n].reshape(m, n, 3).mean(axis=1)
    wm = np.asarray(omega_ib_b, float)[: m * n].reshape(m, n, 3).mean(axis=1)
    sf_dev = np.linalg.norm(fm - np.median(fm, axis=0), axis=1)
    rate_dev = np.degrees(np.linalg.norm(wm - np.median(wm, axis=0), axis=1))
    i, j = int(np.argmax(sf_dev)), int(np.argmax(rate_dev))
    out = {"window_s": window_s, "max_sf_dev_m_s2": float(sf_dev[i]), "max_rate_dev_deg_s": float(rate_dev[j]),
           "sf_bound_m_s2": max_sf_dev_m_s2, "rate_bound_deg_s": max_rate_dev_deg_s}
    if sf_dev[i] > max_sf_dev_m_s2:
        raise NotStaticError(
            f"not static: the {window_s:g}-s mean specific force is {sf_dev[i]:.3f} m/s^2 from its median at "
            f"t = {t[i * n] - t[0]:.1f} s (bound {max_sf_dev_m_s2:g} m/s^2: a tilt or an acceleration); "
            "choose a static segment (--start-s/--end-s)")
    if rate_dev[j] > max_rate_dev_deg_s:
        raise NotStaticError(
            f"not static: the {window_s:g}-s mean angular rate is {rate_dev[j]:.2f} deg/s from its median at "
            f"t = {t[j * n] - t[0]:.1f} s (bound {max_rate_dev_deg_s:g} deg/s: a turn); choose a static segment "
            "(--start-s/--end-s)")
    return out


def log_taus(rate_hz: float, duration_s: float, per_decade: int = TAUS_PER_DECADE) -> np.ndarray:
    """Log-spaced taus from one sample to a third of the recording, rounded to whole samples (no duplicates)."""
    m_max = max(1, int(duration_s * rate_hz / 3.0))
    m = np.unique(np.round(np.logspace(0.0, math.log10(m_max), max(2, int(per_decade * math.log10(m_max)) + 1))))
    return m.astype(int) / rate_hz


def allan_deviation(x, rate_hz: float, taus_s=None):
    """Overlapping Allan deviation of rate samples ``x`` (allantools.oadev, data_type "freq"): (taus, adev, err)."""
    try:
        import allantools  # optional runtime import: only the characterisation needs it
    except ImportError as exc:
        raise ImportError("the IMU characterisation needs allantools: pip install allantools==2024.6 "
                          "(requirements.txt)") from exc

    x = np.asarray(x, float)
    if taus_s is None:
        taus_s = log_taus(rate_hz, len(x) / rate_hz)
    taus, ad, ade, _ = allantools.oadev(x - x.mean(), rate=rate_hz, data_type="freq", taus=np.asarray(taus_s, float))
    return np.round(np.asarray(taus, float), 9), np.asarray(ad, float), np.asarray(ade, float)


def local_slopes(taus_s: np.ndarray, adev: np.ndarray, half_width: int = 2) -> np.ndarray:
    """Log-log slope at each tau: least squares over the +-half_width neighbouring taus."""
    lt, la = np.log10(taus_s), np.log10(adev)
    s = np.full(len(lt), np.nan)
    for i in range(len(lt)):
        a, b = max(0, i - half_width), min(len(lt), i + half_width + 1)
        if b - a >= 2:
            s[i] = np.polyfit(lt[a:b], la[a:b], 1)[0]
    return s


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True as (first, last + 1)."""
    out, i = [], 0
    while i < len(mask):
        if mask[i]:
            j = i
            while j < len(mask) and mask[j]:
                j += 1
            out.append((i, j))
            i = j
        else:
            i += 1
    return out


def _log_mean(v: np.ndarray) -> float:
    return float(np.exp(np.mean(np.log(v))))


def fit_axis(axis: str, taus_s, adev, adev_err, duration_s: float, mean: float = float("nan"),
             min_region_points: int = 3) -> AxisFit:
    """Read the white-noise, flicker and rate-random-walk terms off one axis's Allan deviation (module docstring)."""
    taus_s, adev = np.asarray(taus_s, float), np.asarray(adev, float)
    ok = np.isfinite(adev) & (adev > 0)
    taus_s, adev, adev_err = taus_s[ok], adev[ok], np.asarray(adev_err, float)[ok]
    n_fit = int(np.sum(taus_s <= duration_s / MIN_CLUSTERS))
    fit = AxisFit(axis, taus_s, adev, adev_err, n_fit, mean=mean)
    if n_fit < min_region_points:
        fit.notes.append(f"too short: {n_fit} usable taus (tau <= {duration_s / MIN_CLUSTERS:.3g} s)")
        return fit
    t, a = taus_s[:n_fit], adev[:n_fit]
    slope = local_slopes(t, a)
    i_min = int(np.argmin(a))
    fit.adev_min, fit.tau_min_s = float(a[i_min]), float(t[i_min])
    near = lambda target: np.abs(slope - target) <= SLOPE_TOL  # noqa: E731
    # the flat region: the run of slope-0 points holding the minimum (or the one ending nearest to it)
    flat_runs = [r for r in _runs(near(0.0)) if r[1] - r[0] >= min_region_points]
    flat = next((r for r in flat_runs if r[0] <= i_min < r[1]), None)
    if flat is None and flat_runs:
        flat = min(flat_runs, key=lambda r: min(abs(r[0] - i_min), abs(r[1] - 1 - i_min)))
    end_white = flat[0] if flat else i_min + 1
    white_runs = [r for r in _runs(near(-0.5)[:end_white]) if r[1] - r[0] >= min_region_points]
    white = max(white_runs, key=lambda r: r[1] - r[0]) if white_runs else None
    start_rrw = flat[1] if flat else i_min
    rrw_runs = [(start_rrw + r[0], start_rrw + r[1]) for r in _runs(near(0.5)[start_rrw:])
                if r[1] - r[0] >= min_region_points]
    rrw = max(rrw_runs, key=lambda r: r[1] - r[0]) if rrw_runs else None
    if rrw is not None and a[rrw[1] - 1] < 1.3 * fit.adev_min:
        rrw = None  # not a rise: noise on the floor
    # fit each term on its region after subtracting the others' variance (three passes)
    N2 = F2 = K2 = 0.0
    for _ in range(3):
        if white:
            s, e = white
            rest = F2 + K2 * t[s:e] / 3.0
            N2 = _log_mean(np.maximum(a[s:e] ** 2 - rest, 0.1 * a[s:e] ** 2) * t[s:e])
        if flat:
            s, e = flat
            rest = N2 / t[s:e] + K2 * t[s:e] / 3.0
            F2 = _log_mean(np.maximum(a[s:e] ** 2 - rest, 0.1 * a[s:e] ** 2))
        if rrw:
            s, e = rrw
            rest = N2 / t[s:e] + F2
            K2 = _log_mean(np.maximum(a[s:e] ** 2 - rest, 0.1 * a[s:e] ** 2) * 3.0 / t[s:e])
    quant = [r for r in _runs(near(-1.0)[:end_white]) if r[1] - r[0] >= min_region_points]
    if quant:
        s, e = max(quant, key=lambda r: r[1] - r[0])
        q = _log_mean(a[s:e] * t[s:e]) / math.sqrt(3.0)
        fit.notes.append(f"slope -1 at tau {t[s]:.3g}-{t[e - 1]:.3g} s: quantization noise Q = {q:.3g} (SI x s; "
                         "sigma = sqrt(3) Q / tau) or a low-pass filtered output (not white: not in the grade)")
    if white:
        fit.white, fit.white_taus_s = math.sqrt(N2), t[white[0]:white[1]].tolist()
    else:
        fit.notes.append("no -1/2 slope region: white noise not resolved (the grade's base value is used)")
    if flat:
        fit.bias_instability, fit.bias_taus_s = math.sqrt(F2) / FLICKER_FACTOR, t[flat[0]:flat[1]].tolist()
    else:
        fit.bias_instability, fit.bias_instability_bound = fit.adev_min / FLICKER_FACTOR, "upper"
        fit.bias_taus_s = [fit.tau_min_s]
        fit.notes.append(f"no flat region up to tau = {t[-1]:.3g} s (the curve still falls): bias instability "
                         "<= min/0.664, an upper bound; a longer recording resolves it")
    if rrw:
        fit.rrw, fit.rrw_taus_s = math.sqrt(K2), t[rrw[0]:rrw[1]].tolist()
    return fit


def characterise(t_s, omega_ib_b, f_ib_b, check: bool = True, **static_bounds) -> AllanResult:
    """Allan deviation of the six axes and their terms. ``check``: refuse a non-static recording (check_static)."""
    t = np.asarray(t_s, float)
    w, f = np.asarray(omega_ib_b, float), np.asarray(f_ib_b, float)
    if t.ndim != 1 or w.shape != (len(t), 3) or f.shape != (len(t), 3):
        raise ValueError("characterise: t (n,), omega (n, 3), f (n, 3) expected")
    if len(t) < 100:
        raise ValueError(f"characterise: {len(t)} IMU samples: at least 100 needed")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f)) and np.all(np.diff(t) > 0)):
        raise ValueError("characterise: non-finite samples or non-increasing stamps")
    dt = np.diff(t)
    rate_hz = 1.0 / float(np.median(dt))
    if np.max(dt) > 3.0 * np.median(dt):
        # the Allan deviation assumes a uniform grid; a gap shifts every later sample in time
        k = int(np.argmax(dt))
        raise ValueError(f"characterise: a gap of {dt[k]:.3f} s at t = {t[k] - t[0]:.1f} s (median interval "
                         f"{np.median(dt):.4f} s): choose a segment without gaps (--start-s/--end-s)")
    static = check_static(t, w, f, **static_bounds) if check else {}
    duration_s = len(t) / rate_hz
    taus = log_taus(rate_hz, duration_s)
    axes = []
    for name, x in zip(AXES, np.column_stack([w, f]).T):
        tt, ad, ade = allan_deviation(x, rate_hz, taus)
        axes.append(fit_axis(name, tt, ad, ade, duration_s, mean=float(np.mean(x))))
    return AllanResult(rate_hz, duration_s, len(t), axes, static)


# ----------------------------------------------------------------------------------------- synthetic static IMU
def flicker_noise(n: int, rate_hz: float, bias_instability: float, rng: np.random.Generator) -> np.ndarray:
    """n samples of flicker (1/f) noise of bias instability B, shaped in the frequency domain: IEEE Std 952's rate
    PSD (B^2 / 2 pi) / f is two-sided (its Allan variance is 4 int S sin^4(pi f tau) / (pi f tau)^2 df = 2 ln 2 B^2 / pi,
    the floor 0.664 B), so the one-sided PSD drawn here is B^2 / (pi f), between 1 / (n dt) and the Nyquist frequency."""
    dt = 1.0 / rate_hz
    f = np.fft.rfftfreq(n, dt)
    S = np.zeros_like(f)
    S[1:] = bias_instability**2 / (math.pi * f[1:])
    X = np.sqrt(n * S / (2.0 * dt)) * (rng.standard_normal(len(f)) + 1j * rng.standard_normal(len(f))) / math.sqrt(2.0)
    X[0] = 0.0
    if n % 2 == 0:
        X[-1] = X[-1].real * math.sqrt(2.0)
    return np.fft.irfft(X, n=n)


def synthetic_static_imu(grade, rate_hz: float = 100.0, duration_s: float = 3600.0, seed: int = 0,
                         rrw_deg_h_sqrt_h: float = 0.0, acc_rrw_mg_sqrt_h: float = 0.0):
    """A static IMU (level, body = ENU, at 45 deg latitude) whose errors are a grade's white noise (ARW, VRW) and
    flicker bias (its bias instabilities), plus an optional rate random walk; its turn-on biases constant, drawn
    from the grade. Returns (t_s, omega_ib_b [rad/s], f_ib_b [m/s^2]); the errors are drawn directly with numpy
    (fast: 1 h at 100 Hz in well under a second)."""
    g = get_grade(grade) if not isinstance(grade, ImuGrade) else grade
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    lat = math.radians(45.0)
    omega_ie = 7.292115e-5
    omega_true = np.array([0.0, omega_ie * math.cos(lat), omega_ie * math.sin(lat)])
    f_true = np.array([0.0, 0.0, 9.806])
    arw = math.radians(g.gyro_arw_deg_sqrt_h) / 60.0
    vrw = g.acc_vrw_m_s_sqrt_h / 60.0
    bg = math.radians(g.gyro_bias_instability_deg_h) / 3600.0
    ba = g.acc_bias_instability_mg * 1e-3 * G0_M_S2
    kg = math.radians(rrw_deg_h_sqrt_h) / 3600.0 / 60.0
    ka = acc_rrw_mg_sqrt_h * 1e-3 * G0_M_S2 / 60.0
    w = np.empty((n, 3))
    f = np.empty((n, 3))
    for i in range(3):
        w[:, i] = (omega_true[i] + rng.normal(0.0, math.radians(g.gyro_bias_deg_h) / 3600.0)
                   + rng.normal(0.0, arw / math.sqrt(dt), n) + flicker_noise(n, rate_hz, bg, rng)
                   + np.cumsum(rng.normal(0.0, kg * math.sqrt(dt), n)))
        f[:, i] = (f_true[i] + rng.normal(0.0, g.acc_bias_mg * 1e-3 * G0_M_S2)
                   + rng.normal(0.0, vrw / math.sqrt(dt), n) + flicker_noise(n, rate_hz, ba, rng)
                   + np.cumsum(rng.normal(0.0, ka * math.sqrt(dt), n)))
    return t, w, f


def load_grade_yaml(path) -> ImuGrade:
    """The grade YAML the characterisation writes (the ImuGrade fields at the top level) -> ImuGrade."""
    import yaml

    with open(path) as fh:
        d = yaml.safe_load(fh)
    if not isinstance(d, dict):
        raise ValueError(f"{path}: not a mapping of ImuGrade fields")
    d = d.get("imu_grade", d) if isinstance(d.get("imu_grade"), dict) else d
    return ImuGrade(**d)


__all__ = ["AllanResult", "AxisFit", "NotStaticError", "characterise", "check_static", "allan_deviation",
           "fit_axis", "flicker_noise", "synthetic_static_imu", "load_grade_yaml", "FLICKER_FACTOR", "GRADES"]
