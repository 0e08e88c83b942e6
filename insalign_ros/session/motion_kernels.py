"""The motion detector's compiled kernel (session/motion.py): the window statistics of each IMU sample, one source
for the per-sample, run and whole-array paths."""

from __future__ import annotations

import math

import numpy as np

from ..core import mechanization_numba as nb


@nb._jit
def window_stats_nb(X, start, W, Nv, Nr, dt, out):
    """The statistics of each row k >= ``start`` of X (n, 6) (omega_ib_b [rad/s], f_ib_b [m/s^2]) over the L = Nv + Nr
    rows ending at k (a gap-free run), written to out (n - start, 3): spread_f [m/s^2], spread_omega [rad/s], dv_h [m/s]
    (module docstring); NaN while k < L - 1. Per window: the spreads over its last W rows, centred on its first row (the
    sums of squares keep their precision); theta the small-angle body rotation since its first row; the reference
    specific force the mean of its first Nr rows; dv the sum over the last Nv of f_j - R(theta_j - theta_ref)^T f_ref,
    R^T v = v - theta x v."""
    L = Nv + Nr
    for k in range(start, X.shape[0]):
        o = k - start
        if k < L - 1:
            out[o, 0] = out[o, 1] = out[o, 2] = np.nan
            continue
        j0 = k - L + 1
        for c in range(2):  # 0: spread_f (columns 3:6), 1: spread_omega (columns 0:3)
            col = 3 if c == 0 else 0
            tr = 0.0
            for a in range(3):
                x0 = X[j0, col + a]
                s1 = 0.0
                s2 = 0.0
                for j in range(k - W + 1, k + 1):
                    d = X[j, col + a] - x0
                    s1 += d
                    s2 += d * d
                tr += s2 - s1 * s1 / W
            out[o, c] = math.sqrt(max(tr / W, 0.0))
        th = np.zeros(3)  # running sum of omega (theta = sum * dt)
        S = np.zeros((2, 6))  # over the reference rows (0) and the velocity-change rows (1): sum f - f_j0, sum theta
        for i in range(L):
            j, w = j0 + i, 0 if i < Nr else 1
            for a in range(3):
                th[a] += X[j, a]
                S[w, a] += X[j, 3 + a] - X[j0, 3 + a]
                S[w, 3 + a] += th[a] * dt
        fr0, fr1, fr2, tr0, tr1, tr2 = S[0, 0], S[0, 1], S[0, 2], S[0, 3], S[0, 4], S[0, 5]
        sf0, sf1, sf2, st0, st1, st2 = S[1, 0], S[1, 1], S[1, 2], S[1, 3], S[1, 4], S[1, 5]
        fc0, fc1, fc2 = fr0 / Nr, fr1 / Nr, fr2 / Nr  # reference specific force, centred
        g0, g1, g2 = fc0 + X[j0, 3], fc1 + X[j0, 4], fc2 + X[j0, 5]
        a0, a1, a2 = st0 - Nv * (tr0 / Nr), st1 - Nv * (tr1 / Nr), st2 - Nv * (tr2 / Nr)
        d0 = dt * (sf0 - Nv * fc0 + (a1 * g2 - a2 * g1))
        d1 = dt * (sf1 - Nv * fc1 + (a2 * g0 - a0 * g2))
        d2 = dt * (sf2 - Nv * fc2 + (a0 * g1 - a1 * g0))
        gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        u0, u1, u2 = g0 / gn, g1 / gn, g2 / gn
        p = d0 * u0 + d1 * u1 + d2 * u2
        h0, h1, h2 = d0 - p * u0, d1 - p * u1, d2 - p * u2
        out[o, 2] = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
