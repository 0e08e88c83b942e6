"""The session's time buffer: IMU samples as array blocks, fixes and velocities in stamp order, the recent stamps (the
duplicate check) and the rings of recent processed samples."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .truth import TruthDict


@dataclass
class Pending:
    """Time-ordered input buffer (IMU and fixes in stamp order; truth by stamp)."""

    imu: "ImuBuffer" = field(default_factory=lambda: ImuBuffer())  # t, omega (3,), f (3,) as array blocks
    fix_t: list = field(default_factory=list)
    fix: list = field(default_factory=list)
    truth: dict = field(default_factory=lambda: TruthDict())  # stamp -> TruthSample
    truth_t: list = field(default_factory=list)  # sorted stamps of ``truth``
    vel_t: list = field(default_factory=list)  # GNSS velocities in stamp order (push_velocity)
    vel: list = field(default_factory=list)
    #: wheel speeds and GNSS headings in stamp order (push_wheel_speed, push_gnss_heading; session/fusion.py)
    wheel_t: list = field(default_factory=list)
    wheel: list = field(default_factory=list)
    heading_t: list = field(default_factory=list)
    heading: list = field(default_factory=list)

    def __post_init__(self) -> None:
        if isinstance(self.truth, TruthDict):
            self.truth.tt = self.truth_t


class ImuBuffer:
    """IMU samples waiting to be processed, in stamp order, held as array blocks: ``(T (m,) [s], W (m, 3) [rad/s],
    F (m, 3) [m/s^2])`` with a read offset into the first block, then a growing block of single pushes (``push_imu``
    from the node). A block pushed as arrays reaches the core as views, without a Python object per sample."""

    __slots__ = ("blocks", "off", "n", "_t", "_w", "_f")

    def __init__(self) -> None:
        self.blocks: list = []
        self.off = 0
        self.n = 0
        self._t: list = []
        self._w: list = []
        self._f: list = []

    def __len__(self) -> int:
        return self.n

    def _seal(self) -> None:
        if self._t:
            m = len(self._t)
            self.blocks.append((np.array(self._t, float), np.array(self._w, float).reshape(m, 3),
                                np.array(self._f, float).reshape(m, 3)))
            self._t, self._w, self._f = [], [], []

    def append(self, t: float, w: np.ndarray, f: np.ndarray) -> None:
        """One sample stamped after every buffered one (``w``, ``f`` of shape (3,))."""
        self._t.append(t)
        self._w.append(w)
        self._f.append(f)
        self.n += 1

    def extend(self, T: np.ndarray, W: np.ndarray, F: np.ndarray) -> None:
        """A block of increasing stamps after every buffered one (held as it is: the caller passes its own copy)."""
        self._seal()
        self.blocks.append((T, W, F))
        self.n += T.shape[0]

    def insert(self, t: float, w: np.ndarray, f: np.ndarray) -> None:
        """One sample among the buffered ones (out of order): after those stamped at or before it."""
        T, W, F = self.take(self.n)
        k = int(np.searchsorted(T, t, side="right"))
        self.blocks = [(np.insert(T, k, t), np.insert(W, k, w, axis=0), np.insert(F, k, f, axis=0))]
        self.n = T.shape[0] + 1

    def count_until(self, until: float) -> int:
        """How many buffered samples are stamped at or before ``until``."""
        self._seal()
        c, off = 0, self.off
        for T, _, _ in self.blocks:
            k = int(np.searchsorted(T, until, side="right"))
            if k < T.shape[0]:
                return c + max(k - off, 0)
            c += T.shape[0] - off
            off = 0
        return c

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first ``n`` samples as arrays (views when they lie in one block), removed from the buffer."""
        self._seal()
        parts = []
        need = n
        while need > 0:
            T, W, F = self.blocks[0]
            a = self.off
            k = min(T.shape[0] - a, need)
            parts.append((T[a:a + k], W[a:a + k], F[a:a + k]))
            need -= k
            self.off = a + k
            if self.off == T.shape[0]:
                del self.blocks[0]
                self.off = 0
        self.n -= n
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        return tuple(np.concatenate(x) for x in zip(*parts))

    def peek(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every buffered sample as (T, W, F) copies, the buffer unchanged (inspection, tests)."""
        self._seal()
        parts = [(T[self.off if i == 0 else 0:], W[self.off if i == 0 else 0:], F[self.off if i == 0 else 0:])
                 for i, (T, W, F) in enumerate(self.blocks)]
        if not parts:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        return tuple(np.concatenate(x) for x in zip(*parts))

    def first(self):
        """(t, w, f) of the first buffered sample, or None."""
        if self.n == 0:
            return None
        if self.blocks:
            T, W, F = self.blocks[0]
            return float(T[self.off]), W[self.off], F[self.off]
        return self._t[0], self._w[0], self._f[0]

    def t_at(self, k: int) -> float:
        """Stamp of the ``k``-th buffered sample (0-based)."""
        self._seal()
        k += self.off
        for T, _, _ in self.blocks:
            if k < T.shape[0]:
                return float(T[k])
            k -= T.shape[0]
        raise IndexError(k)

    def iter_until(self, until: float):
        """(t, w, f) of the buffered samples stamped at or before ``until``, in order (not removed)."""
        self._seal()
        off = self.off
        for T, W, F in self.blocks:
            for k in range(off, T.shape[0]):
                if T[k] > until:
                    return
                yield float(T[k]), W[k], F[k]
            off = 0


class Ring:
    """The last ``maxlen`` values or rows appended (a deque held in one array of twice that length): rows or blocks
    in, one view out. A row once written is never overwritten (a full array is replaced by a new one), so a view is
    a snapshot that stays valid (``LazySpread`` keeps one)."""

    __slots__ = ("maxlen", "a", "e")

    def __init__(self, maxlen: int, width: int = 0) -> None:
        self.maxlen = maxlen
        self.a = np.empty((2 * maxlen, width) if width else 2 * maxlen)
        self.e = 0  # rows a[max(e - maxlen, 0):e] are held

    def __len__(self) -> int:
        return min(self.e, self.maxlen)

    def _shift(self) -> None:
        k = min(self.e, self.maxlen)
        a = np.empty_like(self.a)
        a[:k] = self.a[self.e - k:self.e]
        self.a, self.e = a, k

    def append(self, x) -> None:
        if self.e == self.a.shape[0]:
            self._shift()
        self.a[self.e] = x
        self.e += 1

    def extend(self, X: np.ndarray) -> None:
        m = X.shape[0]
        if m >= self.maxlen:
            self.a = np.empty_like(self.a)
            self.a[:self.maxlen] = X[m - self.maxlen:]
            self.e = self.maxlen
            return
        if self.e + m > self.a.shape[0]:
            self._shift()
        self.a[self.e:self.e + m] = X
        self.e += m

    def view(self) -> np.ndarray:
        return self.a[max(self.e - self.maxlen, 0):self.e]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return np.array(self.view(), dtype=dtype)

    def __getitem__(self, k: int):
        if k != -1 or self.e == 0:
            raise IndexError(k)
        return self.a[self.e - 1]


class RecentStamps:
    """The last ``maxlen`` IMU stamps taken into the buffer (``push_imu``'s duplicate check): single stamps in a
    deque and the set ``set``; runs pushed as arrays (increasing, after every stamp held) kept as arrays and moved
    into the set only when a single stamp is checked or added (never on the offline path)."""

    __slots__ = ("rs", "set", "pending", "n_pending")

    def __init__(self, maxlen: int) -> None:
        self.rs: deque = deque(maxlen=maxlen)
        self.set: set = set()
        self.pending: list = []
        self.n_pending = 0

    def add(self, t: float) -> None:
        if self.pending:
            self._flush()
        rs = self.rs
        if len(rs) == rs.maxlen:
            self.set.discard(rs[0])
        rs.append(t)
        self.set.add(t)

    def add_block(self, T: np.ndarray) -> None:
        self.pending.append(T)
        self.n_pending += T.shape[0]
        if self.n_pending > 8 * self.rs.maxlen:  # only the newest maxlen can matter
            keep = np.concatenate(self.pending)[-self.rs.maxlen:]
            self.pending, self.n_pending = [keep], keep.shape[0]

    def __contains__(self, t: float) -> bool:
        if self.pending:
            self._flush()
        return t in self.set

    def _flush(self) -> None:
        rs, rset = self.rs, self.set
        tl = np.concatenate(self.pending)[-rs.maxlen:].tolist()
        self.pending, self.n_pending = [], 0
        drop = len(rs) + len(tl) - rs.maxlen
        if drop >= len(rs):
            rset.clear()
        elif drop > 0:
            for k in range(drop):
                rset.discard(rs[k])
        rs.extend(tl)
        rset.update(tl)


def row_norms(X: np.ndarray) -> np.ndarray:
    return np.sqrt(X[:, 0] * X[:, 0] + X[:, 1] * X[:, 1] + X[:, 2] * X[:, 2])

