"""Reference poses for the session: truth samples and tables (simulations, tests, evaluation), and the look-up of
the truth attitude at an output stamp."""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from ..core import earth


@dataclass
class TruthSample:
    """A reference attitude (and optionally position/velocity) at a stamp: simulations, tests, evaluation.

    ``p_n``: position in the truth's own ENU frame [m] (any origin; only differences are used, for the initial
    velocity); ``llh``: (lat_rad, lon_rad, h_m) when known; ``v_n``: ENU velocity [m/s] when known."""

    stamp_s: float
    C_b_n: np.ndarray
    p_n: np.ndarray | None = None
    v_n: np.ndarray | None = None
    llh: tuple[float, float, float] | None = None


@dataclass
class TruthTable:
    """Truth poses as arrays (offline sources): ``t_s`` (N,) [s], ``C_b_n`` (N, 3, 3), ``llh`` (N, 3) (lat_rad,
    lon_rad, h_m) or None, ``v_n`` (N, 3) ENU [m/s] or None. :meth:`sample` builds the :class:`TruthSample` of a row;
    without ``v_n`` it carries ``p_n``, the ENU position relative to row 0 (the session differentiates it)."""

    t_s: np.ndarray
    C_b_n: np.ndarray
    llh: np.ndarray | None = None
    v_n: np.ndarray | None = None

    def t_list(self) -> list:
        """``t_s`` as a list of floats, built once (the output's look-up bisects it: ~0.3 us against ~1.5 us for
        ``np.searchsorted`` on a slice)."""
        tl = self.__dict__.get("_t_list")
        if tl is None:
            tl = self.__dict__["_t_list"] = self.t_s.tolist()
        return tl

    def sample(self, k: int) -> TruthSample:
        llh = None if self.llh is None else tuple(self.llh[k].tolist())
        tr = TruthSample(float(self.t_s[k]), self.C_b_n[k], None, None if self.v_n is None else self.v_n[k], llh)
        if self.v_n is None and llh is not None:
            o = self.llh[0].tolist()
            tr.p_n = earth.ecef_to_enu(earth.geodetic_to_ecef(llh[0], llh[1], llh[2]), o[0], o[1], o[2])
        return tr


def truth_table_valid(table: TruthTable, start: int = 0, stop: int | None = None) -> bool:
    """Rows ``start:stop`` of ``table`` are finite and strictly increasing in time (what ``push_truth_table`` takes in
    bulk)."""
    T = table.t_s[start:stop]
    return bool(np.isfinite(table.C_b_n[start:stop]).all() and np.isfinite(T).all()
                and (T.shape[0] < 2 or np.all(np.diff(T) > 0)))


class TruthDict(dict):
    """stamp -> TruthSample; rows pushed from a :class:`TruthTable` are held as an integer reference and built on
    first read (``[]``, ``get``).

    Row ranges pushed from a table (``add_block``) stay pending, after every stamp of the dict: the output's truth
    look-up (:meth:`around`, :meth:`drop_pending_before`) reads them in the table; any other read (``[]``, ``get``,
    ``in``) first moves them into the dict and the sorted stamps ``tt`` (the session's ``truth_t``)."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list = []
        self.tt: list = []  # the sorted stamps of the dict (linked to Pending.truth_t)
        self.pending: list = []  # [table, lo, hi]: rows lo:hi of a table, in stamp order
        self.n_pending = 0

    def add_block(self, table: "TruthTable", lo: int, hi: int) -> None:
        """Rows ``lo:hi`` of ``table`` (valid, increasing, after every stamp held)."""
        self.pending.append([table, lo, hi])
        self.n_pending += hi - lo

    def last_stamp(self) -> float | None:
        if self.pending:
            tb, _, hi = self.pending[-1]
            return float(tb.t_s[hi - 1])
        return self.tt[-1] if self.tt else None

    def sync(self) -> None:
        """Move the pending rows into the dict and ``tt``."""
        blocks, self.pending, self.n_pending = self.pending, [], 0
        for tb, lo, hi in blocks:
            ts = tb.t_s[lo:hi].tolist()
            self.add_rows(ts, tb, lo)
            self.tt.extend(ts)

    def drop_pending_before(self, t0: float) -> None:
        """Forget the pending rows stamped before ``t0`` (what the look-up forgets in the dict)."""
        while self.pending:
            blk = self.pending[0]
            tb, lo, hi = blk
            k = bisect.bisect_left(tb.t_list(), t0, lo, hi)
            self.n_pending -= k - lo
            if k < hi:
                blk[1] = k
                return
            del self.pending[0]

    def around(self, x: float):
        """``(before, after)``: (stamp, C_b_n) of the last pose stamped before ``x`` and of the first at or after it
        (None where there is none), over the dict and the pending rows, without moving them."""
        tt = self.tt
        i = bisect.bisect_left(tt, x)
        if i < len(tt):
            return ((tt[i - 1], self._sample(tt[i - 1]).C_b_n) if i else None), (tt[i], self._sample(tt[i]).C_b_n)
        before = (tt[-1], self._sample(tt[-1]).C_b_n) if tt else None
        for tb, lo, hi in self.pending:
            T = tb.t_list()
            k = bisect.bisect_left(T, x, lo, hi)
            if k < hi:
                if k > lo:
                    before = (T[k - 1], tb.C_b_n[k - 1])
                return before, (T[k], tb.C_b_n[k])
            before = (T[hi - 1], tb.C_b_n[hi - 1])
        return before, None

    def add_rows(self, stamps: list, table: TruthTable, start: int) -> None:
        if not self.tables or self.tables[-1] is not table:
            self.tables.append(table)
        base = (len(self.tables) - 1) << 32
        self.update(zip(stamps, range(base + start, base + start + len(stamps))))

    def _build(self, t: float, ref: int) -> TruthSample:
        tr = self.tables[ref >> 32].sample(ref & 0xFFFFFFFF)
        dict.__setitem__(self, t, tr)
        return tr

    def _sample(self, t):
        v = dict.__getitem__(self, t)
        return self._build(t, v) if type(v) is int else v

    def __getitem__(self, t):
        if self.pending:
            self.sync()
        return self._sample(t)

    def __contains__(self, t) -> bool:
        if self.pending:
            self.sync()
        return dict.__contains__(self, t)

    def get(self, t, default=None):
        if self.pending:
            self.sync()
        v = dict.get(self, t, default)
        return self._build(t, v) if type(v) is int else v

