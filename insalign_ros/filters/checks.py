"""Input checks of the cores (one GNSS fix, one GNSS velocity, one IMU sample, a block of IMU rows) and the IMU
buffer the batched cores flush; shared with the session (session/inputs.py)."""

from __future__ import annotations

import math

import numpy as np

from ..core import mechanization_numba as nb
from .base import GnssFix, ImuSample
from .kalman import spd3


def check_fix(fix: GnssFix) -> str:
    """Why a GNSS fix (p_e (3,) ECEF [m], R_e (3, 3) [m^2]) is unusable, or ""."""
    p = np.asarray(fix.p_e, float)
    R = np.asarray(fix.R_e, float)
    if p.shape != (3,) or R.shape != (3, 3):
        return f"bad shapes p_e {p.shape}, R_e {R.shape}"
    pl = p.tolist()  # tests in floats: numpy's per-call overhead was most of the ~13 us (twice per fix)
    if not all(map(math.isfinite, pl + R.ravel().tolist())):
        return "non-finite position or covariance"
    norm = math.sqrt(pl[0] * pl[0] + pl[1] * pl[1] + pl[2] * pl[2])
    if not 6.0e6 < norm < 7.0e6:
        return f"ECEF position norm {norm:.0f} m is not near the Earth's surface"
    return "" if spd3(R) else "covariance R_e is not positive definite"


def check_velocity(v_n, R_n) -> str:
    """Why a GNSS velocity (v_n (3,) [m/s], R_n (3, 3) [m^2/s^2]) is unusable, or "" (shared with the session)."""
    v = np.asarray(v_n, float)
    R = np.asarray(R_n, float)
    if v.shape != (3,) or R.shape != (3, 3):
        return f"bad shapes v_n {v.shape}, R_n {R.shape}"
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(R))):
        return "non-finite velocity or covariance"
    if not spd3(R):
        return "covariance not positive definite (unknown or zero covariance)"
    return ""


def check_imu(imu: ImuSample) -> str:
    w = np.asarray(imu.omega_ib_b, float)
    f = np.asarray(imu.f_ib_b, float)
    if w.shape != (3,) or f.shape != (3,):
        return f"bad shapes omega {w.shape}, f {f.shape}"
    # one scalar test (hot path: every sample): a sum is non-finite iff a term is (or it overflows: garbage too)
    if not (math.isfinite(float(w[0] + w[1] + w[2] + f[0] + f[1] + f[2])) and math.isfinite(imu.stamp_s)):
        return "non-finite IMU sample"
    return ""


@nb._jit
def _usable_nb(t, w, f, t_last, dt):
    """``usable_imu_arrays``' test in one pass: every row finite (one running sum, as the numpy test: non-finite iff a
    term is, or the sum overflows), the intervals from ``t_last`` in (0, 1] s; fills ``dt`` with them."""
    n = t.shape[0]
    s = 0.0
    for k in range(n):
        s += t[k] + w[k, 0] + w[k, 1] + w[k, 2] + f[k, 0] + f[k, 1] + f[k, 2]
    if not math.isfinite(s):
        return False
    prev = t_last
    for k in range(n):
        d = t[k] - prev
        dt[k] = d
        if not (d > 0.0 and d <= 1.0):
            return False
        prev = t[k]
    return True



def usable_imu_arrays(t_s, omega_ib_b, f_ib_b, t_last_s: float):
    """(t (N,), omega (N, 3), f (N, 3), dt (N,)) as float arrays when every row is usable: finite, stamps after
    ``t_last_s`` and increasing by at most 1 s; else None (the caller takes the per-sample path, which rejects and
    counts the bad rows). The array fast paths of the cores share this check."""
    t = np.asarray(t_s, float)
    w = np.asarray(omega_ib_b, float)
    f = np.asarray(f_ib_b, float)
    n = t.shape[0] if t.ndim == 1 else 0
    if n == 0 or w.shape != (n, 3) or f.shape != (n, 3):
        return None
    dt = np.empty(n)  # one compiled pass: ~1 us instead of ~6 us of numpy calls (runs of ~12 samples at 10 Hz)
    return (t, w, f, dt) if _usable_nb(t, w, f, float(t_last_s), dt) else None


class ImuBuffer:
    """IMU samples waiting for a core's next flush, added one by one (``add``: a stamp or step [s] and two (3,)
    rows) or as blocks (``add_block``: (k,) and (k, 3) arrays, kept as they are); ``take`` returns them as
    (n,), (n, 3), (n, 3) float arrays (the same values in the same order) and empties the buffer."""

    __slots__ = ("t", "w", "f", "n", "blocks", "last_t")

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self.t: list = []
        self.w: list = []
        self.f: list = []
        self.n = 0
        self.blocks = False
        self.last_t = 0.0

    def add(self, t: float, w, f) -> None:
        self.t.append(t)
        self.w.append(w)
        self.f.append(f)
        self.n += 1
        self.last_t = t

    def add_block(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> None:
        if t.shape[0]:
            self.t.append(t)
            self.w.append(w)
            self.f.append(f)
            self.n += t.shape[0]
            self.blocks = True
            self.last_t = float(t[-1])

    def take(self):
        if self.blocks and len(self.t) == 1:
            out = self.t[0], self.w[0], self.f[0]
        elif self.blocks:
            out = (np.hstack(self.t).astype(float, copy=False), np.vstack(self.w).astype(float, copy=False),
                   np.vstack(self.f).astype(float, copy=False))
        else:
            out = np.asarray(self.t, float), np.asarray(self.w, float), np.asarray(self.f, float)
        self.clear()
        return out
