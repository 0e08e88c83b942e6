"""IMU dropouts: fill a gap with samples predicted from the data on both sides of it, and measure on the recent
data what that prediction gets wrong (the covariance the session adds for the gap).

A candidate bridge fits a polynomial in time to the rates and specific forces of the last ``span_before_s`` before
the gap and the first ``span_after_s`` after it (least squares, every axis at once) and evaluates it at the missing
stamps; the degree-1 candidate with no span is plain linear interpolation between the two samples next to the gap.
Which candidate is used is decided on the recent history: each candidate is applied to every window of the gap's
length there (with the same spans), and the one whose windows integrate to the smallest attitude error wins; the
windows' rms error, at least a third of the worst (the 3-sigma covers every window seen), in attitude and velocity, is
the 1-sigma the session adds (docs/session.md, "Gaps").
On smooth periodic motion (a ship in waves) a quartic over one second on each side makes a 1.5-s bridge 5-8 times
more accurate than linear interpolation; on a car's piecewise motion the gain is smaller but still 2-4 times.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a gap: an interval longer than the mean interval plus this many stamp-jitter sigmas on each of its two stamps
JITTER_K = 6.0
#: the rate model is updated every this many intervals (and at every one of the first 101)
MODEL_EVERY = 200
#: intervals before the stamp-jitter model is used (before: gap_factor x the median interval only)
JITTER_MIN_INTERVALS = 8


def gap_threshold(dts, gap_factor: float, median_dt: float, prev_threshold: float | None = None) -> float:
    """The longest IMU interval [s] that is not a gap, from a rate model of the stamps (docs/session.md, "Gaps").

    A host-stamped driver stamps each sample when it arrives: stamp = sample time + a latency that varies by a few
    ms. The stamps then scatter about a line t_k = t_0 + k T with a per-stamp sigma sigma_s; an interval is
    T + r_k - r_(k-1), so without a missing sample it stays under ``T + 2 JITTER_K sigma_s``. T is the mean of the
    recent intervals (not the median: a driver that delivers in bursts has many short intervals), sigma_s the
    robust (MAD) sigma of the stamps' residuals to that line; intervals over the previous threshold are taken as
    gaps and left out of both. At 400 Hz the intervals alone hide the jitter (a 5-ms jitter makes them ~
    exponential with the 2.5-ms mean): the residuals of the stamps show it. The threshold is never below
    ``gap_factor`` x the median interval (a stream without jitter keeps the plain rule), nor below 3 x it and 4 x the mean
    interval for the first ``JITTER_MIN_INTERVALS`` intervals."""
    base = gap_factor * median_dt
    d = np.asarray(dts, float)
    if len(d) < JITTER_MIN_INTERVALS:  # too few to tell jitter: a gap is at least 3 medians and 4 mean intervals
        return max(base, 3.0 * median_dt, 4.0 * float(d.mean()) if len(d) else 0.0)
    cut = prev_threshold if prev_threshold is not None else max(base, 3.0 * median_dt)
    ok = d <= cut
    if ok.sum() < JITTER_MIN_INTERVALS // 2:
        return base
    T = float(d[ok].mean())
    r = np.cumsum(np.where(ok, d, T)) - T * np.arange(1, len(d) + 1)
    sigma_s = 1.4826 * median(np.abs(r - median(r.tolist())).tolist())
    return max(base, T + 2.0 * JITTER_K * sigma_s)


def median(x: list) -> float:
    """``float(np.median(x))`` for a list of floats, bit for bit (the middle value, or the mean of the two middle
    ones), without numpy's per-call overhead (per run of samples, and the rate model every 200 intervals)."""
    s = sorted(x)
    h = len(s) // 2
    return float(s[h]) if len(s) % 2 else float((s[h - 1] + s[h]) / 2.0)


@dataclass(frozen=True)
class Bridge:
    """A way to fill a gap: polynomial ``degree`` over ``span_before_s``/``span_after_s`` of data on each side
    (degree 1 with zero spans: linear interpolation between the two samples next to the gap)."""

    degree: int
    span_before_s: float
    span_after_s: float

    @property
    def name(self) -> str:
        if self.span_before_s <= 0.0:
            return "linear interpolation"
        return f"degree-{self.degree} fit over {self.span_before_s:.2f} s before / {self.span_after_s:.2f} s after"


LINEAR = Bridge(1, 0.0, 0.0)


def candidates(after_available_s: float) -> list[Bridge]:
    """The bridges tried: linear interpolation, a quadratic over 0.5 s and a quartic over 1 s on each side (the
    side after the gap limited to the data already received)."""
    out = [LINEAR]
    for degree, span in ((2, 0.5), (4, 1.0)):
        after = min(span, after_available_s)
        if after >= 0.25 * span:
            out.append(Bridge(degree, span, after))
    return out


def fill(bridge: Bridge, t_before, Y_before, t_after, Y_after, t_mid) -> np.ndarray:
    """Samples at the stamps ``t_mid`` [s] (k, ncols) predicted from the rows of ``Y_before`` (stamps ``t_before``,
    the last one next to the gap) and ``Y_after`` (stamps ``t_after``, the first one next to the gap)."""
    t_a, t_b = float(t_before[-1]), float(t_after[0])
    if bridge.span_before_s <= 0.0:
        a = ((np.asarray(t_mid) - t_a) / (t_b - t_a))[:, None]
        return (1.0 - a) * Y_before[-1] + a * Y_after[0]
    keep_b = t_before >= t_a - bridge.span_before_s - 1e-9
    keep_a = t_after <= t_b + bridge.span_after_s + 1e-9
    t = np.concatenate([t_before[keep_b], t_after[keep_a]])
    Y = np.concatenate([Y_before[keep_b], Y_after[keep_a]])
    scale = 0.5 * (t_b - t_a) + 0.5 * (bridge.span_before_s + bridge.span_after_s)
    mid = 0.5 * (t_a + t_b)
    V = np.vander((t - mid) / scale, bridge.degree + 1)
    coef = np.linalg.lstsq(V, Y, rcond=None)[0]
    return np.vander((np.asarray(t_mid) - mid) / scale, bridge.degree + 1) @ coef


def window_errors(bridge: Bridge, t: np.ndarray, W: np.ndarray, F: np.ndarray, m: int,
                  max_windows: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Apply ``bridge`` to windows of ``m - 1`` consecutive samples of the history (stamps ``t`` [s], rates ``W``
    [rad/s], specific forces ``F`` [m/s^2]) as if they were missing; return the errors of their integrals: attitude
    increment [rad] and velocity increment [m/s], one row per window (empty when the history is too short)."""
    if len(t) < 3:  # no interval to measure (a gap right after the initialisation): no window
        return np.empty((0, 3)), np.empty((0, 3))
    h = float(np.median(np.diff(t)))
    kb = int(round(bridge.span_before_s / h)) + 1
    ka = int(round(bridge.span_after_s / h)) + 1
    Y = np.hstack([W, F])
    first, last = kb - 1, len(t) - m - ka  # window start i: samples i+1 .. i+m-1 missing
    if last < first:
        return np.empty((0, 3)), np.empty((0, 3))
    errs = []
    for i in range(first, last + 1, max(1, (last - first) // max_windows)):
        mid = slice(i + 1, i + m)
        pred = fill(bridge, t[i - kb + 1:i + 1], Y[i - kb + 1:i + 1], t[i + m:i + m + ka], Y[i + m:i + m + ka], t[mid])
        errs.append((Y[mid] - pred).sum(axis=0) * h)
    e = np.asarray(errs)
    return e[:, :3], e[:, 3:]


def window_variance(e: np.ndarray) -> float:
    """The bridge error's variance from its errors ``e`` on the history's windows (rows; columns the axes): their mean
    square on the largest axis (the error of a window
    drawn at random from the vehicle's recent motion), at least a ninth of the largest (so the 3-sigma covers every
    window seen). The largest alone, taken as the 1-sigma, made the 3-sigma three times the worst window: on KITTI
    0018 (10 Hz, a 1.6-s gap in city driving) 20.7 deg of added attitude 3-sigma where the windows' errors had an
    rms of 1.8 deg and a maximum of 6.9."""
    e2 = np.asarray(e, float).reshape(len(e), -1) ** 2  # one row per window, one column per axis
    return float(max(np.max(np.mean(e2, axis=0)), np.max(e2) / 9.0))  # the largest axis: the inflation is isotropic


def choose(t: np.ndarray, W: np.ndarray, F: np.ndarray, m: int, after_available_s: float
           ) -> tuple[Bridge, float, float, int]:
    """The candidate bridge with the smallest attitude error variance on the history (:func:`window_variance`), that
    variance [rad^2] and the velocity one [(m/s)^2] (largest axis: the inflation is isotropic), and the windows used.
    ``m``: missing intervals (``m - 1`` missing samples); raises ValueError when no candidate fits the history."""
    best = None
    for bridge in candidates(after_available_s):
        ew, ef = window_errors(bridge, t, W, F, m)
        if len(ew) < 5:
            continue
        var_att, var_v = window_variance(ew), window_variance(ef)
        if best is None or var_att < best[1]:
            best = (bridge, var_att, var_v, len(ew))
    if best is None:
        raise ValueError("history too short for a gap of this length")
    return best
