"""The static cores' open-loop azimuth bootstrap fit (filters/static_model.py ``_bootstrap_step``;
docs/static_alignment.md, "Large initial azimuth").

The open-loop mechanization's horizontal velocity error is quadratic in time, ``v(t) = c0 + c1 t + c2 t^2`` per
axis: c2 holds the residual horizontal rate (the azimuth), the slope at the end the level. An IMU gap (or any
widening of the covariance) while the window runs is a *break*: the bridge over the gap may step the tilt and the
velocity, which moves the line but not the residual rate. After a break the fit gives each segment its own offset
and slope and keeps c2 common; its uncertainty grows by what the segments cost, from the design (the ratio of the
exact variance to the single quadratic's on the same stamps, which the unbroken fit's closed forms assume).
"""

from __future__ import annotations

import math

import numpy as np

#: a segment needs this many points to give its offset and slope and something to the common curvature
MIN_SEGMENT_POINTS = 3


def bootstrap_fit(t: np.ndarray, V: np.ndarray, breaks: list[int], T: float) -> tuple:
    """(c2 (2,), the slope at ``T`` (2,), k_rate, k_level, the number of points fitted) of the velocities ``V``
    (n, 2) [m/s] at ``t`` (n,) [s since the start of the window]: without ``breaks`` one quadratic (k = 1); with them
    (indices of the first point of each new segment) one offset and slope per segment of at least
    MIN_SEGMENT_POINTS points and a common c2. k_rate and k_level scale the single quadratic's standard deviations of
    c2 and of the slope at T."""
    if not breaks:
        A = np.stack([np.ones_like(t), t, t * t], -1)
        coef, *_ = np.linalg.lstsq(A, V, rcond=None)  # (3, 2): rows c0, c1, c2; columns vN, vE
        return coef[2], coef[1] + 2.0 * coef[2] * T, 1.0, 1.0, t.shape[0]
    edges = [0, *breaks, len(t)]
    segs = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= MIN_SEGMENT_POINTS]
    rows = np.concatenate([np.arange(a, b) for a, b in segs])
    ts, S = t[rows], len(segs)
    A = np.zeros((rows.shape[0], 2 * S + 1))
    k = 0
    for s, (a, b) in enumerate(segs):
        A[k:k + b - a, 2 * s] = 1.0
        A[k:k + b - a, 2 * s + 1] = t[a:b]
        k += b - a
    A[:, -1] = ts * ts
    coef, *_ = np.linalg.lstsq(A, V[rows], rcond=None)
    M = np.linalg.inv(A.T @ A)
    M1 = np.linalg.inv((A1 := np.stack([np.ones_like(ts), ts, ts * ts], -1)).T @ A1)
    u = np.zeros(2 * S + 1)
    u[2 * S - 1], u[-1] = 1.0, 2.0 * T  # the last segment's slope at T
    u1 = np.array([0.0, 1.0, 2.0 * T])
    k_rate = math.sqrt(M[-1, -1] / M1[2, 2])
    k_level = math.sqrt(float(u @ M @ u) / float(u1 @ M1 @ u1))
    return coef[-1], coef[2 * S - 1] + 2.0 * coef[-1] * T, k_rate, k_level, rows.shape[0]
