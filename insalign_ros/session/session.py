"""AlignmentSession: the whole alignment pipeline behind the node, ``insalign-align``, the API and the benchmarks.

Push inputs in arrival order (``push_imu``, ``push_fix``, ``push_truth``), call ``process()`` (a node timer, or
the offline loop), read the returned :class:`Output` records and ``diagnostics()``. No ROS import.

Time line (docs/session.md):

* inputs are validated at the door (counted per reason, never raised) and kept in a time-ordered buffer;
* the filter runs ``max_fix_lag_s`` behind the newest IMU sample (a fixed fusion delay), so a fix that arrives
  up to that late is fused at its own stamp, exactly as if it had been on time; an IMU sample that arrives out of
  order inside that window is put back in order;
* a fix is applied after the first IMU sample stamped at or after it (as ``ScenarioData.events``);
* an IMU interval longer than ``gap_factor`` times the median interval is a gap: counted, and the attitude and
  velocity covariance are inflated by what the unknown motion during the gap may have done;
* a run of ``time_jump_confirm`` self-consistent samples more than ``max_gap_s`` away from the time line is a
  time jump: the session resets;
* watchdog: no IMU pushed for ``imu_timeout_s`` of wall time drops the flag with the reason.

One meaning of "aligned": the session's flag (eval/aligned.py criteria); the core reports status and covariance.
"""

from __future__ import annotations

import bisect
import math
import time
import traceback
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import numpy as np

from ..core import earth, lie
from ..core.types import GnssFix, GnssVelocity, ImuSample
from ..eval.aligned import AlignedCriteria, AlignedFlag, euler_3sigma_deg
from ..filters import registry
from ..filters.base import AlignmentCore, AlignmentEstimate, AlignmentStatus
from ..filters.liekf import check_velocity
from ..filters.imu_grade import DEFAULT_IMU_GRADE, resolve_core_params
from . import gaps
from .config import SessionConfig

D2R = math.pi / 180.0

COUNTERS = (
    "imu_received", "imu_processed", "imu_rejected", "imu_invalid", "imu_frame", "imu_duplicate", "imu_out_of_order",
    "imu_reordered", "imu_future", "imu_gaps", "imu_before_init", "gnss_received", "gnss_accepted", "gnss_rejected",
    "gnss_invalid", "gnss_no_fix", "gnss_frame", "gnss_duplicate", "gnss_stale", "gnss_future", "gnss_before_init", "gnss_filter_rejected",
    "gnss_unused", "truth_received", "truth_invalid", "time_resets", "core_faults", "zupt_accepted",
    "watchdog_trips", "inputs_dropped", "gnss_gated", "imu_spikes", "divergences")
COUNTERS += ("gnss_jumps", "gnss_holds", "divergences_nis", "divergences_covariance", "divergences_cusum")  # divergence guard
COUNTERS += ("reinit_restarts",)  # divergence guard: a re-initialisation restarted after a GNSS jump
#: GNSS velocity (push_velocity): received, fused, rejected (total) and per reason
VEL_COUNTERS = ("gnss_vel_received", "gnss_vel_accepted", "gnss_vel_rejected", "gnss_vel_invalid", "gnss_vel_duplicate",
                "gnss_vel_stale", "gnss_vel_future", "gnss_vel_before_init", "gnss_vel_gated", "gnss_vel_filter_rejected",
                "gnss_vel_unused")
COUNTERS = COUNTERS + VEL_COUNTERS
#: a GNSS velocity faster than this is not a vehicle's [m/s]
MAX_GNSS_SPEED_M_S = 600.0


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


class _TruthDict(dict):
    """stamp -> TruthSample; rows pushed from a :class:`TruthTable` are held as an integer reference and built on
    first read (``[]``, ``get``).

    Row ranges pushed from a table (``add_block``) stay pending, after every stamp of the dict: the output's truth
    look-up (:meth:`around`, :meth:`drop_pending_before`) reads them in the table; any other read (``[]``, ``get``,
    ``in``) first moves them into the dict and the sorted stamps ``tt`` (the session's ``truth_t``)."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list = []
        self.tt: list = []  # the sorted stamps of the dict (linked to _Pending.truth_t)
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
            k = lo + int(np.searchsorted(tb.t_s[lo:hi], t0, side="left"))
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
            T = tb.t_s
            k = lo + int(np.searchsorted(T[lo:hi], x, side="left"))
            if k < hi:
                if k > lo:
                    before = (float(T[k - 1]), tb.C_b_n[k - 1])
                return before, (float(T[k]), tb.C_b_n[k])
            before = (float(T[hi - 1]), tb.C_b_n[hi - 1])
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


@dataclass
class Output:
    """One estimate output (every ``output_period_s`` of data time)."""

    stamp_s: float
    estimate: AlignmentEstimate
    aligned: bool
    status: AlignmentStatus
    reason: str
    euler_3sigma_deg: np.ndarray  # roll, pitch, yaw 3-sigma [deg]
    euler_error_deg: np.ndarray | None = None  # estimate minus truth [deg] (when a truth pose is at this stamp)
    truth_C_b_n: np.ndarray | None = None


@dataclass
class _Pending:
    """Time-ordered input buffer (IMU and fixes in stamp order; truth by stamp)."""

    imu: "_ImuBuffer" = field(default_factory=lambda: _ImuBuffer())  # t, omega (3,), f (3,) as array blocks
    fix_t: list = field(default_factory=list)
    fix: list = field(default_factory=list)
    truth: dict = field(default_factory=lambda: _TruthDict())  # stamp -> TruthSample
    truth_t: list = field(default_factory=list)  # sorted stamps of ``truth``
    vel_t: list = field(default_factory=list)  # GNSS velocities in stamp order (push_velocity)
    vel: list = field(default_factory=list)

    def __post_init__(self) -> None:
        if isinstance(self.truth, _TruthDict):
            self.truth.tt = self.truth_t


class AlignmentSession:
    """The alignment pipeline. ``core_params``: the core's config fields; ``criteria``: the aligned-flag criteria."""

    #: the most IMU samples held for reordering / the fusion delay; beyond it the oldest are processed at once
    MAX_BUFFER = 200_000
    #: process runs of IMU samples between events as arrays (``_fast_run``); False: one ``_step`` per sample
    fast_path: bool = True
    #: (core, its estimate) while the core's state has not changed since (``_estimate``)
    _est_memo: tuple | None = None
    #: outputs whose Euler error is filled in later by ``_fill_deferred_errors`` (offline ``run_session``); None: at once
    _deferred_errors: list | None = None

    def __init__(self, config: SessionConfig | dict | None = None, core_params: dict | None = None,
                 criteria: AlignedCriteria | None = None, log=None) -> None:
        self.cfg = config if isinstance(config, SessionConfig) else SessionConfig.from_dict(config)
        self.cfg.validate()
        # the IMU grade's noise and bias fields under the explicit core parameters (filters/imu_grade.py)
        self.core_params = resolve_core_params(self.cfg.imu_grade, self.cfg.core, core_params)
        registry.make_config(self.cfg.core, self.core_params)  # validate now (ValueError with the reason)
        self.flag = AlignedFlag(criteria or AlignedCriteria())
        self.log = log or (lambda level, key, text: None)
        self.counters: OrderedDict[str, int] = OrderedDict((k, 0) for k in COUNTERS)
        self.core: AlignmentCore | None = None
        self.bt = None  # filters/backtrack.BacktrackingAligner when backtrack_passes > 0
        self.last_reject = ""
        self.timing = {"process_s": 0.0, "process_calls": 0, "samples": 0}
        #: added to stamps in log lines and diagnostics (the node's epoch: users see their header stamps)
        self.stamp_offset_s = 0.0
        #: outputs of processing forced by a full buffer inside push_imu*, handed out by the next process()/finish()
        self._overflow_out: list[Output] = []
        self._reset_state("start")

    # ------------------------------------------------------------------ configuration
    def reconfigure(self, config: SessionConfig, core_params: dict, criteria: AlignedCriteria) -> bool:
        """Apply new parameters. Returns True when the alignment was restarted (core or core parameters changed)."""
        config.validate()
        core_params = resolve_core_params(config.imu_grade, config.core, core_params)
        registry.make_config(config.core, core_params)
        restart = (config.core != self.cfg.core or core_params != self.core_params
                   or config.init_mode != self.cfg.init_mode or config.backtrack_passes != self.cfg.backtrack_passes)
        self.cfg, self.core_params = config, dict(core_params)
        self.flag.set_criteria(criteria)
        if restart:
            self.reset("parameters changed")
        return restart

    def reset(self, why: str) -> None:
        """Drop the core and every buffered input; start over (the flag goes down)."""
        self._reset_state(why)

    def close(self) -> None:
        self._close_core()

    def _close_core(self) -> None:
        if self.core is not None:
            self.core.close()
        if self.bt is not None and self.bt.live is not self.core:
            self.bt.live.close()
        self.core, self.bt = None, None

    def _reset_state(self, why: str) -> None:
        self._close_core()
        self.buf = _Pending()
        self.status = AlignmentStatus.WAITING_FOR_DATA
        self.reason = f"waiting for IMU data ({why})"
        self.fault_reason = ""
        self.newest_imu_t: float | None = None
        self.processed_t: float | None = None  # stamp of the last processed IMU sample (= the core's time)
        self.recent_stamps = _RecentStamps(4096)
        self.fix_stamps: deque = deque(maxlen=256)
        self.jump_candidates: list = []
        self.dts: deque = deque(maxlen=101)
        self._median_dt: float | None = None
        self._dt_count = 0
        self._probe = None
        self._sensors_reinit = False
        self._spread = None
        self.gated_run = 0
        self._hold_since: float | None = None  # divergence guard: holding the filter through a GNSS jump since
        self._hold_innovation_m = 0.0  # divergence guard: |innovation| when the hold began (or the fixes last jumped)
        self._fix_seq: deque = deque(maxlen=3)  # divergence guard: the last fixes seen (stamp, p_e, sigma_m)
        self._nis_win: deque = deque(maxlen=max(self.cfg.divergence_nis_window, 1))  # divergence guard
        self._level_bound_deg: float | None = None  # divergence guard: level 3-sigma bound of this filter
        self._cusum_llr = 0.0  # divergence guard: CUSUM of the NIS log-likelihood ratio while the attitude is claimed
        self._kept_level = None  # divergence guard: (t, C_b_n, level 1-sigma) of the lost filter, if it claimed its level
        self.pre_init: deque = deque(maxlen=4000)  # IMU samples before the initialisation (level from sensors)
        self.hist_t = Ring(1000)  # recent processed samples (gap bridging statistics)
        self.hist_w = Ring(1000, 3)
        self.hist_f = Ring(1000, 3)
        self._batch: tuple[list, int] = ([], 0)  # the batch being processed and the index in it (gap look-ahead)
        self.init_t: float | None = None
        self.anchor: tuple[float, float, float] | None = None
        self.next_out_t = -math.inf
        self.next_zupt_t = -math.inf
        self.last_output: Output | None = None
        self.last_nis = float("nan")
        self.last_accepted_fix_t: float | None = None
        self.last_imu_wall: float | None = None
        self.last_input_wall: float | None = None
        self.watchdog_reason = ""
        self._used_fix_stamp: float | None = None
        self.flag_changes: list[tuple[float, bool, str]] = []
        self.flag.reset()

    # ------------------------------------------------------------------ inputs
    def push_imu(self, sample: ImuSample, wall_s: float | None = None) -> bool:
        """Validate and buffer one IMU sample (omega_ib_b [rad/s], f_ib_b [m/s^2], body FLU). False if rejected."""
        c = self.counters
        c["imu_received"] += 1
        self._touch(wall_s)
        t = float(sample.stamp_s)
        w, f = sample.omega_ib_b, sample.f_ib_b
        reason = _check_imu(t, w, f, self.cfg.max_rate_rad_s, self.cfg.max_acc_m_s2)
        if reason:
            return self._reject_imu("imu_invalid", reason)
        w, f = np.asarray(w, float), np.asarray(f, float)
        if w.shape != (3,) or f.shape != (3,):  # (the array buffer holds (3,) rows)
            return self._reject_imu("imu_invalid", f"angular_velocity/linear_acceleration: shapes {w.shape}, {f.shape} "
                                                   "instead of (3,)")
        if wall_s is not None:
            self.last_imu_wall = wall_s  # the watchdog counts valid samples only
        if t in self.recent_stamps:
            return self._reject_imu("imu_duplicate", f"duplicate stamp {t + self.stamp_offset_s:.6f}")
        newest = self.newest_imu_t
        if newest is not None and (t - newest > self.cfg.max_gap_s or newest - t > self.cfg.max_gap_s):
            return self._jump_candidate(sample, t - newest)
        self.jump_candidates.clear()
        if self.processed_t is not None and t <= self.processed_t:
            return self._reject_imu("imu_out_of_order", f"stamp {t + self.stamp_offset_s:.6f} is {self.processed_t - t:.3f} s before "
                                                        "the filter time (beyond the fusion delay)")
        self._remember(t)
        if newest is None or t > newest:
            self.buf.imu.append(t, w, f)
            self.newest_imu_t = t
            if newest is None:
                self._check_early_fixes()
        else:
            c["imu_reordered"] += 1
            self.buf.imu.insert(t, w, f)
        self._check_overflow()
        return True

    def _check_overflow(self) -> None:
        """More than MAX_BUFFER samples held: the oldest are processed at once (outputs handed out later)."""
        b = self.buf.imu
        if len(b) > self.MAX_BUFFER:
            self._overflow_out += self._process(until=b.t_at(len(b) - self.MAX_BUFFER))

    def push_imu_arrays(self, t_s, omega_ib_b, f_ib_b, wall_s: float | None = None) -> int:
        """``push_imu`` for arrays of samples (t_s (N,) [s], omega_ib_b (N, 3) [rad/s], f_ib_b (N, 3) [m/s^2], body
        FLU, in arrival order); returns how many were accepted. The same checks, counters and buffer as one
        ``push_imu`` per sample: rows that are valid and continue the time line (increasing, no jump) are taken in
        bulk, any other row goes through ``push_imu`` (rejected or reordered there, with its reason)."""
        t = np.asarray(t_s, float)
        w = np.asarray(omega_ib_b, float)
        f = np.asarray(f_ib_b, float)
        n = t.shape[0] if t.ndim == 1 else -1
        if n < 0 or w.shape != (n, 3) or f.shape != (n, 3):
            return sum(self.push_imu(ImuSample(float(t[k]), w[k], f[k]), wall_s) for k in range(len(t)))
        ok, cont = self._imu_array_checks(t, w, f)
        return self._push_imu_checked(t, w, f, ok, cont, wall_s)

    def _imu_array_checks(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``push_imu``'s checks of arrays of samples, at once: ``ok`` (N,) rows valid; ``cont`` (N - 1,) row k + 1 is
        valid and after row k by at most ``max_gap_s`` (it continues a bulk run). Row-wise: the checks of a slice are
        the slice of the checks (``run_session`` checks a whole recording once)."""
        cfg = self.cfg
        with np.errstate(invalid="ignore", over="ignore"):
            nw = _row_norms(w)
            nf = _row_norms(f)
            ok = (np.isfinite(t) & (t >= 0.0) & np.isfinite(w[:, 0] + w[:, 1] + w[:, 2])
                  & np.isfinite(f[:, 0] + f[:, 1] + f[:, 2]) & ~(nw > cfg.max_rate_rad_s)
                  & ~(nf > cfg.max_acc_m_s2))
            dt = np.diff(t)
            # a row continues the bulk run when valid and after its predecessor by at most max_gap_s
            cont = ok[1:] & (dt > 0.0) & ~(dt > cfg.max_gap_s)
        return ok, cont

    def _push_imu_checked(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, ok: np.ndarray, cont: np.ndarray,
                          wall_s: float | None = None) -> int:
        """``push_imu_arrays`` with the checks of :meth:`_imu_array_checks` done (for these rows, this config)."""
        cfg = self.cfg
        n = t.shape[0]
        brk = np.flatnonzero(~cont) + 1  # rows that cannot continue the run of their predecessor
        accepted = 0
        s = 0
        while s < n:
            newest = self.newest_imu_t
            if not ok[s] or (newest is not None and not (0.0 < t[s] - newest <= cfg.max_gap_s)) \
                    or self.jump_candidates:
                accepted += self.push_imu(ImuSample(float(t[s]), w[s], f[s]), wall_s)
                s += 1
                continue
            i = int(np.searchsorted(brk, s, side="right"))
            e = int(brk[i]) if i < brk.shape[0] else n
            self._push_imu_run(t[s:e], w[s:e], f[s:e], wall_s)
            accepted += e - s
            s = e
        return accepted

    def _push_imu_run(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, wall_s: float | None) -> None:
        """Buffer valid samples that continue the time line (what ``push_imu`` does for each of them)."""
        m = t.shape[0]
        self.counters["imu_received"] += m
        self._touch(wall_s)
        if wall_s is not None:
            self.last_imu_wall = wall_s
        t, w, f = t.copy(), w.copy(), f.copy()  # the caller may reuse its arrays
        self.recent_stamps.add_block(t)
        self.buf.imu.extend(t, w, f)
        first = self.newest_imu_t is None
        self.newest_imu_t = float(t[m - 1])
        if first:
            self._check_early_fixes()
        self._check_overflow()

    def _check_early_fixes(self) -> None:
        """The first IMU sample of a time line: fixes and velocities buffered before it (a GNSS reader that matched or
        delivered first) get the ``max_fix_ahead_s`` check they could not get on arrival, with the same counters."""
        limit = self.newest_imu_t + self.cfg.max_fix_ahead_s
        b = self.buf
        for times, items, topic, what in ((b.fix_t, b.fix, "gnss", "fix"), (b.vel_t, b.vel, "gnss_vel", "velocity")):
            while times and times[-1] > limit:
                t = times.pop()
                items.pop()
                self._reject(topic, what, f"{topic}_future", f"stamp {t + self.stamp_offset_s:.6f} is "
                             f"{t - self.newest_imu_t:.3f} s ahead of the first IMU sample (buffered before it)")

    def push_fix(self, fix: GnssFix, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS position fix (ECEF p_e [m], R_e [m^2]). False if rejected."""
        c = self.counters
        c["gnss_received"] += 1
        self._touch(wall_s)
        t = float(fix.stamp_s)
        if self.processed_t is not None and t < self.processed_t:
            return self._reject_fix("gnss_stale", f"stamp {t + self.stamp_offset_s:.6f} is {self.processed_t - t:.3f} s behind the filter "
                                                  f"time (max_fix_lag_s {self.cfg.max_fix_lag_s:g} s)")
        if t in self.fix_stamps or t in self.buf.fix_t:
            return self._reject_fix("gnss_duplicate", f"duplicate stamp {t + self.stamp_offset_s:.6f}")
        if self.newest_imu_t is not None and t > self.newest_imu_t + self.cfg.max_fix_ahead_s:
            return self._reject_fix("gnss_future", f"stamp {t + self.stamp_offset_s:.6f} is {t - self.newest_imu_t:.3f} s ahead of the IMU")
        self.fix_stamps.append(t)
        i = bisect.bisect(self.buf.fix_t, t)
        self.buf.fix_t.insert(i, t)
        self.buf.fix.insert(i, fix)
        if len(self.buf.fix_t) > 1000:  # fixes with no IMU to reach them: keep the newest
            del self.buf.fix_t[0], self.buf.fix[0]
            c["inputs_dropped"] += 1
        return True

    def push_truth(self, truth: TruthSample) -> None:
        """A reference pose (initialisation in init_mode 'truth', and the Euler errors of the outputs)."""
        self.counters["truth_received"] += 1
        C = np.asarray(truth.C_b_n, float)
        if C.shape != (3, 3) or not np.all(np.isfinite(C)) or not math.isfinite(truth.stamp_s):
            self.counters["truth_invalid"] += 1
            return
        t = float(truth.stamp_s)
        if t not in self.buf.truth:
            bisect.insort(self.buf.truth_t, t)
        self.buf.truth[t] = truth
        while len(self.buf.truth_t) > 5000:
            del self.buf.truth[self.buf.truth_t.pop(0)]

    def push_truth_table(self, table: "TruthTable", start: int = 0, stop: int | None = None,
                         checked: bool = False) -> None:
        """``push_truth`` for rows ``start:stop`` of a :class:`TruthTable` (the offline path): one vectorised check,
        and a :class:`TruthSample` is built only for the stamps the session reads (initialisation, outputs). Rows that
        are not all valid, new and after the buffered poses go through ``push_truth`` one by one. ``checked``: the
        caller found the whole table valid (:func:`truth_table_valid`) and does not change it."""
        b = self.buf
        stop = len(table.t_s) if stop is None else stop
        m = stop - start
        if m <= 0:
            return
        T = table.t_s[start:stop]
        last = b.truth.last_stamp() if isinstance(b.truth, _TruthDict) else None
        if not isinstance(b.truth, _TruthDict) or not (checked or truth_table_valid(table, start, stop)) \
                or (last is not None and not T[0] > last):
            for k in range(start, stop):
                self.push_truth(table.sample(k))
            return
        self.counters["truth_received"] += m
        b.truth.add_block(table, start, stop)  # read in the table until a reader needs them in the dict
        if len(b.truth_t) + b.truth.n_pending <= 5000:
            return
        b.truth.sync()
        k = len(b.truth_t) - 5000
        if k > 0:
            for x in b.truth_t[:k]:
                del b.truth[x]
            del b.truth_t[:k]

    def reject_input(self, topic: str, counter: str, reason: str, wall_s: float | None = None) -> None:
        """Count an input the caller rejected before it became a sample (a message's frame, covariance, status)."""
        self.counters[f"{topic}_received"] += 1
        self._touch(wall_s)
        (self._reject_imu if topic == "imu" else self._reject_fix)(counter, reason)

    def _touch(self, wall_s: float | None) -> None:
        if wall_s is not None:
            self.last_input_wall = wall_s

    def _remember(self, t: float) -> None:
        self.recent_stamps.add(t)

    def _reject(self, topic: str, what: str, counter: str, reason: str) -> bool:
        """Count a rejected input under its own counter and the topic's total; a throttled log line; False."""
        self.counters[counter] += 1
        self.counters[f"{topic}_rejected"] += 1
        self.last_reject = f"{topic}: {reason}"
        self.log("warn", counter, f"rejected {topic} {what}: {reason} ({counter}={self.counters[counter]})")
        return False

    def _reject_imu(self, counter: str, reason: str) -> bool:
        return self._reject("imu", "sample", counter, reason)

    def _reject_fix(self, counter: str, reason: str) -> bool:
        return self._reject("gnss", "fix", counter, reason)

    def _jump_candidate(self, sample: ImuSample, dt: float) -> bool:
        """Samples off the time line: a run of self-consistent ones is a real time jump -> reset."""
        c = self.jump_candidates
        t = float(sample.stamp_s)
        if c and not (0.0 < t - c[-1].stamp_s <= self.cfg.max_gap_s):
            c.clear()
        c.append(sample)
        if len(c) < self.cfg.time_jump_confirm:
            return self._reject_imu("imu_out_of_order" if dt < 0 else "imu_future",
                                    f"stamp {t + self.stamp_offset_s:.6f} is {dt:+.3f} s from the newest "
                                    f"{self.newest_imu_t + self.stamp_offset_s:.6f}")
        kind = "backward" if dt < 0 else "forward"
        run = list(c)
        resets = self.counters["time_resets"] + 1
        self.log("warn", "time_reset", f"time jumped {kind} by {dt:+.3f} s (from {self.newest_imu_t + self.stamp_offset_s:.6f} to "
                                       f"{t + self.stamp_offset_s:.6f}, {len(run)} consistent samples): resetting the alignment")
        self._reset_state(f"time jumped {kind} by {dt:+.3f} s")
        self.counters["time_resets"] = resets
        # the earlier candidates were counted as rejected; the run starts the new time line
        for s in run:
            self._remember(s.stamp_s)
            self.buf.imu.append(float(s.stamp_s), np.asarray(s.omega_ib_b, float), np.asarray(s.f_ib_b, float))
        self.newest_imu_t = float(run[-1].stamp_s)
        return True

    # ------------------------------------------------------------------ processing
    def process(self, wall_s: float | None = None, final: bool = False) -> list[Output]:
        """Process buffered inputs up to the fusion horizon (all of them when ``final`` or idle); return outputs.

        ``wall_s``: the caller's wall clock [s] (node: time.monotonic()); drives the watchdog and the idle drain."""
        t0 = time.perf_counter()
        if wall_s is not None and not final and self.last_input_wall is not None \
                and wall_s - self.last_input_wall >= self.cfg.idle_drain_s:
            final = True
        until = math.inf if final else (self.newest_imu_t - self.cfg.max_fix_lag_s
                                        if self.newest_imu_t is not None else -math.inf)
        out = self._take_overflow() + self._process(until)
        self._background(math.inf if final and self.cfg.backtrack_budget_s == math.inf else self.cfg.backtrack_budget_s)
        if wall_s is not None:
            self._watchdog(wall_s)
        self.timing["process_s"] += time.perf_counter() - t0
        self.timing["process_calls"] += 1
        return out

    def finish(self) -> list[Output]:
        """Process everything buffered (end of a recording); run pending backtracking passes to the end."""
        out = self._take_overflow() + self._process(math.inf)
        if self.bt is not None:
            self.bt.run_until_done()
            self._after_handover()
        return out

    def _take_overflow(self) -> list[Output]:
        out, self._overflow_out = self._overflow_out, []
        return out

    def _process(self, until: float) -> list[Output]:
        out: list[Output] = []
        b = self.buf
        n = b.imu.count_until(until)
        if n == 0:
            self._apply_due_fixes(out)
            return out
        T, W, F = b.imu.take(n)
        Tl = T.tolist()
        arrs = (Tl, W, F)
        after = b.imu.first()
        plan = _FastPlan(self, T, W, F, after, Tl) if self.fast_path and n >= 8 else None
        i = 0
        while i < n:
            if plan is not None and self.core is not None and self.bt is None:
                j = self._fast_run(plan, i, out)
                if j > i:
                    i = j
                    continue
            t, w, f = Tl[i], W[i], F[i]
            self._batch = (arrs, i)
            nxt = (Tl[i + 1], W[i + 1], F[i + 1]) if i + 1 < n else after
            i += 1
            if self._spike(t, w, f, nxt):
                continue
            try:
                self._step(t, w, f, out)
            except Exception as exc:  # noqa: BLE001 - a core failure is a fault; the alignment restarts
                self._fault(exc)
        self._apply_due_fixes(out)
        self.timing["samples"] += n
        return out

    #: ``_fast_run``'s lower bound of the smallest interval in ``dts``: (value, valid at ``_dt_count``, exact at that
    #: count, for that deque: a reset makes a new one)
    _dts_min_cache = None

    def _fast_run(self, plan: "_FastPlan", i: int, out: list[Output]) -> int:
        """Process samples ``i:j`` of the plan in one batch when none of them needs per-sample attention, the last
        one possibly a sample at which events fall due (fixes, a zero-velocity update, an output: handled after the
        batch, as ``_step`` does after that sample); return ``j`` (``i``: nothing done, the caller takes the per-sample
        path).

        A sample needs attention when its interval could be a gap or make the spike check return early (bounded with
        a lower bound of the running median interval), or when it could be a spike (off both neighbours by more than
        the configured bounds, which the adaptive bound never undercuts). Everything else ``_step`` does per sample
        is done here for the run at once (period tracking, counters, history, ``core.propagate_arrays``), with the
        same result (docs/speed.md)."""
        core, cfg = self.core, self.cfg
        prev = self.processed_t
        if prev is None or self._median_dt is None or not self.hist_w or i >= plan.n_fast:
            return i
        Tl = plan.Tl
        # events: fixes, outputs, zero-velocity updates (stamps increase along the buffer); the run ends at the first
        # sample at which one falls due
        b = self.buf
        t_end = self.next_out_t - 1e-9
        if b.fix_t and b.fix_t[0] < t_end:
            t_end = b.fix_t[0]
        if b.vel_t and b.vel_t[0] < t_end:
            t_end = b.vel_t[0]
        if self.next_zupt_t < t_end and self._zupt_due(math.inf):  # the session schedules zero-velocity updates
            t_end = self.next_zupt_t
        j = min(plan.n_fast, bisect.bisect_left(Tl, t_end, i) + 1)
        if plan.cand is not None:  # spike candidates after the first sample; the first against the history
            j = min(j, plan.next_candidate(i + 1))
            # the history ends with the plan's previous sample (the run goes on): its test is the plan's, bit for bit
            if j == i or (plan.next_candidate(i) == i if i > 0 and self.hist_t[-1] == Tl[i - 1]
                          else plan.candidate_at(i, self.hist_w[-1], self.hist_f[-1])):
                return i
        # intervals: none may be a gap or exceed 3 medians (the spike check's early return), for any median the
        # running window can take during the run (>= the 51st smallest interval of the old window and the run)
        d = [Tl[i] - prev]
        d += plan.dTl[i:j - 1]
        fac = min(3.0, cfg.gap_factor)
        # cheap bound first (the smallest interval anywhere; the median now may come from a window partly older than
        # the window now), the 51st smallest of the old window and the run when jitter makes the cheap one too tight
        c0 = self._dt_count
        mc = self._dts_min_cache  # (a lower bound of min(dts), at interval count, exact at count, that deque)
        if mc is None or mc[1] != c0 or mc[3] is not self.dts or c0 - mc[2] > self.dts.maxlen:
            mc = (min(self.dts), c0, c0, self.dts)
        d_min = min(d)
        lb = min(mc[0], d_min, self._median_dt)
        if max(d) > fac * lb or plan.dnextl[j - 1] > fac * lb:
            old = list(self.dts)
            alld = np.array(old + d)
            lb = float(alld.min()) if len(old) < self.dts.maxlen else float(np.partition(alld, 50)[50])
            lb = min(lb, self._median_dt)
            thr = fac * lb
            over = np.flatnonzero(np.array(d) > thr)
            if over.size:
                j = i + int(over[0]) - 1  # the sample before the long interval is the last whose next one is short
                d = d[:max(j - i, 0)]
            elif plan.dnextl[j - 1] > thr:
                j -= 1
                d = d[:j - i]
            if j - i < 1:
                return i
            d_min = min(d)
        m = j - i
        # period tracking as _track_period per sample: the median at the last multiple of 20 intervals in the run
        p = (c0 + m) // 20 * 20
        if p > c0:
            self.dts.extend(d[:p - c0])
            self._median_dt = _median(self.dts)
            self.dts.extend(d[p - c0:])
        else:
            self.dts.extend(d)
        self._dt_count = c0 + m
        # intervals only leave the window: the smaller of the old bound and the run's stays a lower bound
        self._dts_min_cache = (min(mc[0], d_min), c0 + m, mc[2], self.dts)
        # the spike check's spread statistic, due at sample k when its interval count % 100 == 1: lazily
        if cfg.imu_spike_rad_s > 0 or cfg.imu_spike_m_s2 > 0:
            due = None if self._spread is not None else 0
            q = (1 - c0) % 100  # the first run offset r with (c0 + r) % 100 == 1
            if q < m:
                due = q + (m - 1 - q) // 100 * 100
            if due is not None:
                self._spread = _LazySpread(self.hist_w.view(), self.hist_f.view(), plan.W[i:i + due],
                                           plan.F[i:i + due], self.hist_w.maxlen)
        t = Tl[j - 1]
        self.processed_t = t
        self.counters["imu_processed"] += m
        T, W, F = plan.T[i:j], plan.W[i:j], plan.F[i:j]
        self.hist_t.extend(T)
        self.hist_w.extend(W)
        self.hist_f.extend(F)
        self._est_memo = None
        try:
            if core.propagate_arrays_matches_propagate:
                core.propagate_arrays(T, W, F)
            else:
                AlignmentCore.propagate_arrays(core, T, W, F)
            if t >= t_end:
                self._events_at(t, out)
        except Exception as exc:  # noqa: BLE001 - a core failure is a fault; the alignment restarts
            self._fault(exc)
        return j

    def _spike(self, t: float, w: np.ndarray, f: np.ndarray, nxt) -> bool:
        """A sample off both of its neighbours by more than the bounds (and 20 x the recent spread): a spike
        (a 30 rad/s glitch is inside the plausibility bound but no vehicle turns like that for 10 ms). Dropped
        and counted; the next sample sees a gap and bridges it."""
        cfg = self.cfg
        if (cfg.imu_spike_rad_s <= 0 and cfg.imu_spike_m_s2 <= 0) or nxt is None or not self.hist_w \
                or self._median_dt is None or self.processed_t is None:
            return False
        if t - self.processed_t > 3.0 * self._median_dt or nxt[0] - t > 3.0 * self._median_dt:
            return False
        if self._dt_count % 100 == 1 or self._spread is None:
            self._spread = (float(np.linalg.norm(np.std(np.asarray(self.hist_w), axis=0))),
                            float(np.linalg.norm(np.std(np.asarray(self.hist_f), axis=0))))
        # off BOTH neighbours (the sample before a spike is off only one of them)
        wl, fl = w.tolist(), f.tolist()
        dw = min(_dist3(wl, self.hist_w[-1].tolist()), _dist3(wl, nxt[1].tolist()))
        df = min(_dist3(fl, self.hist_f[-1].tolist()), _dist3(fl, nxt[2].tolist()))
        if isinstance(self._spread, _LazySpread):  # fell due inside a fast run (_fast_run): computed when it matters
            if not ((cfg.imu_spike_rad_s > 0 and dw > cfg.imu_spike_rad_s)
                    or (cfg.imu_spike_m_s2 > 0 and df > cfg.imu_spike_m_s2)):
                return False  # within the configured bounds: not a spike whatever the spread
            self._spread = self._spread.value()
        bad_w = cfg.imu_spike_rad_s > 0 and dw > max(cfg.imu_spike_rad_s, 20.0 * self._spread[0])
        bad_f = cfg.imu_spike_m_s2 > 0 and df > max(cfg.imu_spike_m_s2, 20.0 * self._spread[1])
        if not (bad_w or bad_f):
            return False
        self.counters["imu_spikes"] += 1
        self.last_reject = f"imu: spike at {t + self.stamp_offset_s:.6f} ({dw:.3g} rad/s, {df:.3g} m/s^2 off its neighbours)"
        self.log("warn", "imu_spikes", f"IMU spike dropped: {self.last_reject[5:]} (imu_spikes={self.counters['imu_spikes']})")
        return True

    def _step(self, t: float, w: np.ndarray, f: np.ndarray, out: list[Output]) -> None:
        prev = self.processed_t
        self.processed_t = t
        dt = None if prev is None else t - prev
        if dt is not None:
            self._track_period(dt)
        if self.core is None:
            self.counters["imu_before_init"] += 1
            self.pre_init.append((t, w, f))
            self._try_initialize(t)
            if self.core is not None:
                self._apply_fixes_until(t, out)  # a fix at the initialisation stamp (not the one used) is fused
                self.next_out_t = t + self.cfg.output_period_s
                out.append(self._output(t))  # the initial estimate
            return
        gap = dt is not None and self._median_dt is not None and dt > self.cfg.gap_factor * self._median_dt
        if gap:
            self._on_gap(prev, t, w, f)
        self._feed(ImuSample(t, w, f))
        self.counters["imu_processed"] += 1
        self.hist_t.append(t)
        self.hist_w.append(w)
        self.hist_f.append(f)
        self._events_at(t, out)

    def _events_at(self, t: float, out: list[Output]) -> None:
        """What falls due at the processed sample ``t``: fixes and GNSS velocities stamped up to it, a zero-velocity
        update, an output."""
        self._apply_fixes_until(t, out)
        if self.core is None:  # a divergence restarted the session
            return
        if self._zupt_due(t):
            self._zupt(t)
        if t >= self.next_out_t - 1e-9:
            self.next_out_t = t + self.cfg.output_period_s
            out.append(self._output(t))

    def _track_period(self, dt: float) -> None:
        """Median IMU interval over the last 101 intervals (recomputed every 20): robust to gaps and jitter."""
        self.dts.append(dt)
        self._dt_count += 1
        if self._median_dt is None or self._dt_count % 20 == 0:
            self._median_dt = _median(list(self.dts))

    def _on_gap(self, t_a: float, t_b: float, w_b: np.ndarray, f_b: np.ndarray) -> None:
        """An IMU gap (t_a, t_b): bridge it and inflate the covariance by what the bridge may have got wrong.

        Bridge (session/gaps.py): samples at the median interval, predicted by the candidate (linear interpolation,
        or a polynomial fitted to the data on both sides of the gap) that makes the smallest error when applied to
        every window of the gap's length in the recent data; the sample after the gap covers its own interval only.
        Inflation: that worst-window error of the attitude increment (integral of the rate) and of the velocity
        increment (integral of the specific force), as a 1-sigma, added to the attitude and velocity variances
        (docs/session.md, "Gaps"). Without enough history: linear, and the rate spread times the missing time."""
        self.counters["imu_gaps"] += 1
        h = self._median_dt
        n_mid = max(int(round((t_b - t_a) / h)) - 1, 0)
        step = (t_b - t_a) / (n_mid + 1)
        t_mid = t_a + step * np.arange(1, n_mid + 1)
        ahead = [(t_b, w_b, f_b)] + [it for it in self._lookahead(t_b + 1.0)]
        t_after = np.array([it[0] for it in ahead])
        Y_after = np.array([np.concatenate([it[1], it[2]]) for it in ahead])
        if self.hist_w:
            t_before = np.asarray(self.hist_t)
            Y_before = np.hstack([np.asarray(self.hist_w), np.asarray(self.hist_f)])
        else:
            t_before, Y_before = np.array([t_a]), Y_after[:1]
        try:
            bridge, var_att, var_v, nwin = gaps.choose(t_before, Y_before[:, :3], Y_before[:, 3:], n_mid + 1,
                                                       float(t_after[-1] - t_b))
            how = f"{bridge.name}, error measured on {nwin} windows of the last {t_before[-1] - t_before[0]:.1f} s"
        except ValueError:
            n = len(t_before)
            s_w = float(np.linalg.norm(np.std(Y_before[:, :3], axis=0))) if n >= 3 else 0.2
            s_f = float(np.linalg.norm(np.std(Y_before[:, 3:], axis=0))) if n >= 3 else 2.0
            bridge, var_att, var_v = gaps.LINEAR, (s_w * (t_b - t_a)) ** 2, (s_f * (t_b - t_a)) ** 2
            how = "linear interpolation, short history: rate spread x gap"
        Y_mid = gaps.fill(bridge, t_before, Y_before, t_after, Y_after, t_mid)
        # the bridge's error builds up over the gap like process noise: added in up to 5 equal parts along it (the
        # propagation turns the velocity part into position error), and a fix stamped inside the gap is fused at
        # its own stamp, after the part of the bridge before it
        parts = np.array_split(np.arange(n_mid + 1), min(5, n_mid + 1))
        for part in parts:
            self.core.inflate_navigation(var_att / len(parts), var_v / len(parts), 0.0)
            for k in part[part < n_mid]:
                self._feed(ImuSample(float(t_mid[k]), Y_mid[k, :3], Y_mid[k, 3:]))
                self._apply_fixes_until(float(t_mid[k]), [])
                if self.core is None:  # a divergence restarted the session
                    return
        self.log("warn", "imu_gaps", f"IMU gap of {t_b - t_a:.3f} s before {t_b + self.stamp_offset_s:.6f} (median "
                                     f"interval {h * 1e3:.2f} ms): bridged with {n_mid} samples, attitude 3-sigma +"
                                     f"{3 * math.sqrt(var_att) / D2R:.3f} deg ({how}; imu_gaps={self.counters['imu_gaps']})")

    def _lookahead(self, until: float):
        """The IMU samples not processed yet (the rest of the batch being processed, then the buffer), up to the
        stamp ``until`` [s]: data the gap bridge may use after the gap."""
        arrs, i = self._batch
        if arrs:
            Tl, W, F = arrs
            for k in range(i + 1, len(Tl)):
                if Tl[k] > until:
                    return
                yield Tl[k], W[k], F[k]
        yield from self.buf.imu.iter_until(until)

    def _feed(self, event) -> None:
        self._est_memo = None
        if self.bt is not None:
            self.bt.feed(event)
        elif isinstance(event, ImuSample):
            self.core.propagate(event)
        else:
            return

    def _apply_due_fixes(self, out: list[Output]) -> None:
        if self.core is not None and self.processed_t is not None:
            self._apply_fixes_until(self.processed_t, out)

    def _apply_fixes_until(self, t: float, out: list[Output]) -> None:
        b = self.buf
        while b.fix_t and b.fix_t[0] <= t and self.core is not None:
            b.fix_t.pop(0)
            fix = b.fix.pop(0)
            if fix.stamp_s == self._used_fix_stamp:
                self._fix_seq.append(_fix_point(fix))  # divergence guard: the jump test goes on from the init's fixes
                continue  # gave the initial position: not fused twice
            if fix.stamp_s < self.init_t:
                self.counters["gnss_before_init"] += 1
                self._fix_seq.append(_fix_point(fix))  # divergence guard (as above)
                continue
            self._est_memo = None
            self._fuse_fix(fix)
        self._apply_velocities_until(t)

    def _fuse_fix(self, fix: GnssFix) -> None:
        core = self.core
        if not core.supports_gnss:
            self.counters["gnss_unused"] += 1
            core.observe_gnss(fix)  # (core: auto's motion detector takes the GNSS speed)
            return
        gate = self.cfg.gnss_gate_nis
        jump = self._fix_jump(fix)
        if jump and self._restart_young_reinit():  # divergence guard
            return
        # a jump in the fix sequence is suspect by itself: gated even while the core does not claim its attitude
        if gate > 0 and (self._attitude_claimed() or jump or self._hold_since is not None):
            pr = core.predict_gnss(fix)
            if pr.S.size and pr.nis > gate:
                self.counters["gnss_gated"] += 1
                self.counters["gnss_rejected"] += 1
                self.gated_run += 1
                self.last_reject = f"gnss: NIS {pr.nis:.3g} above the gate {gate:g} (|innovation| {np.linalg.norm(pr.innovation):.3g} m)"
                self.log("warn", "gnss_gated", f"fix gated: {self.last_reject[6:]} ({self.gated_run} in a row, "
                                               f"gnss_gated={self.counters['gnss_gated']})")
                # an implausible fix while the core claims its attitude: the claim cannot be trusted now
                self._lower_flag(f"a fix failed the NIS gate ({self.gated_run} in a row)")
                if self._hold(fix, jump, pr.nis, float(np.linalg.norm(pr.innovation))):
                    return
                if self._gated_run_evidence(pr.nis, len(pr.innovation) or 3):  # divergence guard
                    return
                if self.gated_run >= self.cfg.gnss_gate_max_consecutive:
                    self._diverged(f"{self.gated_run} consecutive fixes beyond the NIS gate (last NIS {pr.nis:.3g}), "
                                   "continuous with the fixes before them: the filter is lost")
                return
        self.gated_run = 0
        if self._hold_since is not None:
            self.log("info", "gnss_hold", f"GNSS agrees with the held filter again after "
                                          f"{fix.stamp_s - self._hold_since:.1f} s: fusing fixes")
            self._hold_since = None
        res = self.bt.feed(fix) if self.bt is not None else core.update_gnss(fix)
        if res is None:
            return
        self.last_nis = res.nis
        if res.accepted and self._nis_diverged(res.nis, len(res.innovation) or 3):
            return
        if res.accepted:
            self.counters["gnss_accepted"] += 1
            self.last_accepted_fix_t = fix.stamp_s
        else:
            self.counters["gnss_filter_rejected"] += 1
            self.counters["gnss_rejected"] += 1
            self.last_reject = f"gnss: core: {res.reason}"
            self.log("warn", "gnss_filter_rejected", f"fix rejected by the core: {res.reason}")
        self.flag.on_update(self.processed_t, res.accepted, res.nis, len(res.innovation) or 3)

    # -- divergence guard (issue 15): fix-sequence jumps, the hold through bad fixes, the windowed NIS test and the
    # attitude-covariance sanity checks; docs/session.md "Outliers and divergence"
    def _fix_jump(self, fix: GnssFix) -> bool:
        """Whether ``fix`` breaks the fix sequence: off the straight-line extrapolation of the two fixes before it
        (within 3 s each) by more than ``gnss_jump_accel_m_s2`` allows, plus 5 sigma of the fixes' noise (the
        extrapolation error of three independent fixes: sqrt(1 + (1 + r)^2 + r^2) sigma, r = dt2/dt1). Filter-free:
        a fix block hundreds of metres off starts (and ends) with a jump; a lost filter leaves the fixes smooth."""
        seq = self._fix_seq
        point = _fix_point(fix)
        err = _extrapolation_excess((seq[-2], seq[-1]), point, self.cfg.gnss_jump_accel_m_s2) \
            if len(seq) >= 2 else -math.inf
        seq.append(point)
        if err <= 0:
            return False
        self.counters["gnss_jumps"] += 1
        self.log("warn", "gnss_jumps", f"GNSS jump at t={fix.stamp_s + self.stamp_offset_s:.3f} s: the fix is {err:.1f} m "
                                       f"beyond the extrapolation of the two before it (gnss_jumps={self.counters['gnss_jumps']})")
        return True

    def _hold(self, fix: GnssFix, jump: bool, nis: float, innovation_m: float) -> bool:
        """A gated fix: True when the session holds the filter through bad fixes (a gated run that began with a
        GNSS jump: the fixes are bad, not the filter). The filter runs on the IMU, the flag stays down; after
        ``gnss_hold_max_s`` of fixes that still disagree, the fixes are believed (divergence, re-initialisation).
        Sooner when the held filter drifts away from fixes that are consistent with each other: |innovation|
        changed by more than ``gnss_hold_drift_m`` since the hold began, with no jump in between (a constant offset
        keeps it; a filter that absorbed a walking bias before the jump back drifts at the walk's rate)."""
        if self.gated_run == 1 and jump and self._hold_since is None:
            self._hold_since = float(fix.stamp_s)
            self._hold_innovation_m = innovation_m
            self.counters["gnss_holds"] += 1
            self.log("warn", "gnss_holds", f"GNSS jumped and the filter gates the new fixes (NIS {nis:.3g}): bad fixes, not a "
                                           f"lost filter; holding the filter on the IMU for up to {self.cfg.gnss_hold_max_s:g} s")
        if self._hold_since is None:
            return False
        held = float(fix.stamp_s) - self._hold_since
        self.last_reject = f"gnss: holding the filter through bad fixes ({held:.0f} s); {self.last_reject[6:]}"
        if jump:  # the fixes jumped again while held: a new reference for the drift
            self._hold_innovation_m = innovation_m
        drift = abs(innovation_m - self._hold_innovation_m)
        if held <= self.cfg.gnss_hold_max_s and drift <= self.cfg.gnss_hold_drift_m:
            return True
        self._hold_since = None
        why = (f"fixes disagree with the held filter for {held:.0f} s after a GNSS jump" if drift <= self.cfg.gnss_hold_drift_m
               else f"the held filter drifts away from consistent fixes (|innovation| changed by {drift:.0f} m in "
                    f"{held:.0f} s without a jump)")
        self._diverged(f"{why} (last NIS {nis:.3g}): believing the fixes")
        return True

    def _nis_diverged(self, nis: float, dof: int = 3) -> bool:
        """Windowed NIS test of every filter, also before it claims its attitude: the mean NIS of the last
        ``divergence_nis_window`` fused fixes above ``divergence_nis_mean`` -> divergence. Then the CUSUM of a
        claimed filter (:meth:`_cusum`) and the attitude covariance sanity (:func:`_covariance_problem`). True when
        the session restarted."""
        cfg = self.cfg
        reason, key = self._cusum(nis, dof), "divergences_cusum"
        if cfg.divergence_nis_window > 0 and math.isfinite(nis):
            self._nis_win.append(float(nis))
            mean = sum(self._nis_win) / len(self._nis_win)
            if len(self._nis_win) >= cfg.divergence_nis_window and mean > cfg.divergence_nis_mean:
                reason, key = reason or (f"mean NIS {mean:.3g} of the last {len(self._nis_win)} fixes above "
                               f"{cfg.divergence_nis_mean:g} (chi-square(3) mean 3)"), "divergences_nis"
        if not reason:
            P = self._estimate().P_att_n
            if self._level_bound_deg is None:  # an initialisation from sensors may start near the bound (a_est / g)
                d = np.clip(np.diag(P)[:2], 0.0, None)
                self._level_bound_deg = max(cfg.divergence_level_3sigma_deg, 2.0 * 3.0 * math.degrees(math.sqrt(max(d))))
            reason = _covariance_problem(P, self._level_bound_deg)
            key = "divergences_covariance"
        if not reason:
            return False
        self.counters[key] += 1
        self._lower_flag(reason)
        self._diverged(reason)
        return True

    def _cusum(self, nis: float, dof: int) -> str:
        """Page's CUSUM of the log-likelihood ratio of one fix's NIS while the core claims its attitude: H0 NIS ~
        chi-square(dof), H1 NIS ~ r chi-square(dof) (r = ``divergence_cusum_ratio``: a covariance r times too
        small), per fix ``-dof/2 ln r + NIS/2 (1 - 1/r)``, floored at 0; armed while the 3-sigma is within
        ``divergence_cusum_arm_factor`` times the flag's bounds (small angles: where the filter's linearisation and
        so its NIS hold; a converging filter's NIS is large by design: the windowed test watches it), reset
        otherwise. Above ``divergence_cusum_flag_llr`` the flag drops; above ``divergence_cusum_llr`` the reason of a
        divergence. docs/session.md "The quiet inconsistency"."""
        cfg = self.cfg
        armed = self._attitude_claimed(cfg.divergence_cusum_arm_factor)
        if cfg.divergence_cusum_llr <= 0 or not math.isfinite(nis) or not armed:
            self._cusum_llr = 0.0
            return ""
        r = cfg.divergence_cusum_ratio
        self._cusum_llr = max(0.0, self._cusum_llr - 0.5 * dof * math.log(r) + 0.5 * nis * (1.0 - 1.0 / r))
        if self._cusum_llr > cfg.divergence_cusum_llr:
            return (f"CUSUM of the NIS log-likelihood ratio {self._cusum_llr:.3g} above {cfg.divergence_cusum_llr:g} "
                    f"(last NIS {nis:.3g}; the filter claims its attitude with a covariance {r:g}x too small)")
        if cfg.divergence_cusum_flag_llr > 0 and self._cusum_llr > cfg.divergence_cusum_flag_llr:
            self._lower_flag(f"inconsistent innovations (NIS {nis:.3g}, CUSUM {self._cusum_llr:.3g})")
        return ""

    def _gated_run_evidence(self, nis: float, dof: int) -> bool:
        """A gated fix in a run without a jump (smooth fixes the claimed filter disagrees with: the lost-filter
        signature) is evidence for the CUSUM too, from the second fix of the run on and capped at the gate (the
        first may be a lone outlier, and a single gated fix must not decide): a filter whose CUSUM had already risen
        faults at its second gated fix, any other at its third, instead of the fifth (``gnss_gate_max_consecutive``).
        From the first fix of the run when the CUSUM is already above ``divergence_cusum_flag_llr`` (the fixes
        before it were inconsistent already: the gated fix corroborates them, it is not a lone outlier).
        True when the session restarted."""
        flag_llr = self.cfg.divergence_cusum_flag_llr
        if self.gated_run < 2 and not (self.gated_run == 1 and 0 < flag_llr < self._cusum_llr):
            return False
        reason = self._cusum(min(nis, self.cfg.gnss_gate_nis), dof)
        if not reason:
            return False
        self.counters["divergences_cusum"] += 1
        self._diverged(f"{reason}; {self.gated_run} gated fixes in a row")
        return True

    def _restart_young_reinit(self) -> bool:
        """A GNSS jump within ``gnss_hold_max_s`` of a re-initialisation after a divergence, before the new filter
        claims its attitude: the fixes it started from may be the anomalous ones (a walking GNSS that made the old
        filter's CUSUM fire, then jumped back), and a young filter (a yaw bank: no gate yet) would fuse the jump.
        Re-initialise again from the fixes after the jump (three consistent ones). True when the session restarted."""
        if not (self._sensors_reinit and self.init_t is not None and self.processed_t is not None
                and self.processed_t - self.init_t <= self.cfg.gnss_hold_max_s and not self._attitude_claimed()):
            return False
        self.counters["reinit_restarts"] += 1
        reason = (f"GNSS jump {self.processed_t - self.init_t:.0f} s after the re-initialisation, before the new "
                  "filter claims its attitude: the fixes it started from are suspect")
        self.log("warn", "reinit_restarts", f"{reason}; re-initialising from the fixes after the jump")
        self._reinitialise(reason)
        return True

    def _still_faulted(self) -> None:
        """While re-initialising after a fault or a divergence: status FAULT with its reason, and what the
        initialisation waits for (instead of the plain waiting status)."""
        if self.core is None and self.fault_reason:
            waiting = self.reason if not self.reason.startswith("fault (") else ""
            self.status = AlignmentStatus.FAULT
            self.reason = f"fault ({self.fault_reason}); re-initialising" + (f": {waiting}" if waiting else "")

    # ------------------------------------------------------------------ GNSS velocity (push_velocity)
    def push_velocity(self, vel: GnssVelocity, wall_s: float | None = None) -> bool:
        """Validate and buffer one GNSS velocity (ENU antenna velocity relative to Earth v_n [m/s], covariance R_n
        [m^2/s^2]); fused at its own stamp like a fix (same buffer rule, same fusion delay). False if rejected."""
        c = self.counters
        c["gnss_vel_received"] += 1
        self._touch(wall_s)
        t = float(vel.stamp_s)
        reason = _check_velocity(t, vel.v_n, vel.R_n)
        if reason:
            return self._reject("gnss_vel", "velocity", "gnss_vel_invalid", reason)
        if self.processed_t is not None and t < self.processed_t:
            return self._reject("gnss_vel", "velocity", "gnss_vel_stale",
                                f"stamp {t + self.stamp_offset_s:.6f} is {self.processed_t - t:.3f} s behind the filter time "
                                f"(max_fix_lag_s {self.cfg.max_fix_lag_s:g} s)")
        if t in self.buf.vel_t:
            return self._reject("gnss_vel", "velocity", "gnss_vel_duplicate", f"duplicate stamp {t + self.stamp_offset_s:.6f}")
        if self.newest_imu_t is not None and t > self.newest_imu_t + self.cfg.max_fix_ahead_s:
            return self._reject("gnss_vel", "velocity", "gnss_vel_future",
                                f"stamp {t + self.stamp_offset_s:.6f} is {t - self.newest_imu_t:.3f} s ahead of the IMU")
        i = bisect.bisect(self.buf.vel_t, t)
        self.buf.vel_t.insert(i, t)
        self.buf.vel.insert(i, GnssVelocity(t, np.asarray(vel.v_n, float), np.asarray(vel.R_n, float)))
        if len(self.buf.vel_t) > 1000:  # velocities with no IMU to reach them: keep the newest
            del self.buf.vel_t[0], self.buf.vel[0]
            c["inputs_dropped"] += 1
        return True

    def _apply_velocities_until(self, t: float) -> None:
        b = self.buf
        while b.vel_t and b.vel_t[0] <= t and self.core is not None:
            b.vel_t.pop(0)
            vel = b.vel.pop(0)
            if vel.stamp_s < self.init_t:
                self.counters["gnss_vel_before_init"] += 1
                continue
            self._est_memo = None
            self._fuse_velocity(vel)

    def _fuse_velocity(self, vel: GnssVelocity) -> None:
        """One GNSS velocity into the core: the NIS gate of the fixes (while the attitude is claimed), then the
        core's update; the flag's NIS window sees its NIS like a fix's."""
        core, c = self.core, self.counters
        if not core.supports_gnss_velocity or self.bt is not None:
            c["gnss_vel_unused"] += 1
            return
        gate = self.cfg.gnss_gate_nis
        if gate > 0 and self._attitude_claimed():
            pr = core.predict_gnss_velocity(vel)
            if pr.S.size and pr.nis > gate:
                self._reject("gnss_vel", "velocity", "gnss_vel_gated", f"NIS {pr.nis:.3g} above the gate {gate:g} "
                             f"(|innovation| {np.linalg.norm(pr.innovation):.3g} m/s)")
                self._lower_flag("a GNSS velocity failed the NIS gate")
                return
        res = core.update_gnss_velocity(vel)
        if res.accepted:
            c["gnss_vel_accepted"] += 1
        else:
            c["gnss_vel_filter_rejected"] += 1
            c["gnss_vel_rejected"] += 1
            self.last_reject = f"gnss_vel: core: {res.reason}"
            self.log("warn", "gnss_vel_filter_rejected", f"GNSS velocity rejected by the core: {res.reason}")
        self.flag.on_update(self.processed_t, res.accepted, res.nis, len(res.innovation) or 3)

    def _attitude_claimed(self, factor: float = 2.0) -> bool:
        """The core claims to know its attitude: 3-sigma within ``factor`` (2) times the flag's bounds at the last
        output."""
        s = self.flag.sigma3_deg
        c = self.flag.criteria
        return bool(np.all(np.isfinite(s)) and max(s[0], s[1]) < factor * c.roll_pitch_3sigma_deg
                    and s[2] < factor * c.yaw_3sigma_deg)

    def _lower_flag(self, reason: str) -> None:
        """Drop the flag at once; it rises again only after the criteria hold for hold_s again."""
        self.flag.holding_since_s = None
        if self.flag.aligned:
            self.flag.aligned = False
            self.flag.reason = reason
            self.flag_changes.append((self.processed_t or 0.0, False, reason))
            self.log("info", "flag", f"aligned flag lowered at t={(self.processed_t or 0.0) + self.stamp_offset_s:.3f} s: "
                                     f"{reason}")

    def _diverged(self, reason: str) -> None:
        """Divergence: FAULT with the reason, the flag down at once, re-initialisation from the data that follow."""
        self.counters["divergences"] += 1
        self.log("error", "divergence", f"divergence: {reason}; re-initialising from the sensors (yaw bank)")
        self._reinitialise(f"divergence: {reason}")

    def _reinitialise(self, why: str) -> None:
        """FAULT with ``why`` and a re-initialisation from the sensors, keeping the fix sequence (jump detection)
        and the level the lost filter claims (if it does)."""
        seq = self._fix_seq
        kept = self._claimed_level()
        self._restart(why)
        self._fix_seq = seq  # jump detection continues across the re-initialisation
        self._kept_level = kept
        self._sensors_reinit = True  # whatever the first initialisation was: a guess or the truth no longer holds

    def _claimed_level(self):
        """(t, C_b_n, level 1-sigma [rad]) of the core when it claims its level (roll and pitch 3-sigma within twice
        the flag's bound): what a divergence keeps for the re-initialisation (a lost heading leaves the level, which
        gravity keeps observable); None otherwise."""
        if self.core is None or self.processed_t is None:
            return None
        est = self.core.estimate()
        sig = math.sqrt(max(float(est.P_att_n[0, 0]), float(est.P_att_n[1, 1]), 0.0))
        if not (math.isfinite(sig) and 3.0 * math.degrees(sig) < 2.0 * self.flag.criteria.roll_pitch_3sigma_deg):
            return None
        return self.processed_t, np.asarray(est.C_b_n, float), sig

    def _kept_level_now(self, t: float):
        """The level kept at the divergence carried to ``t`` with the gyros (the samples since the divergence; the
        heading of C_b_n does not matter: a rotation about the vertical leaves roll and pitch): (roll, pitch,
        1-sigma [rad]) with the kept 1-sigma doubled (0.5-deg floor), or None."""
        if self._kept_level is None:
            return None
        t0, C, sig = self._kept_level
        prev = t0
        for tt, w_, _ in self.pre_init:
            if prev < tt <= t:
                C = C @ lie.so3_exp(np.asarray(w_, float) * (tt - prev))
                prev = tt
        rpy = earth.rpy_from_C_b_n(C)
        return float(rpy[0]), float(rpy[1]), max(2.0 * sig, 0.5 * D2R)
    # -- end divergence guard

    def _zupt_due(self, t: float) -> bool:
        c = self.core
        return (c.supports_zero_velocity and not c.supports_gnss and not c.schedules_own_zero_velocity
                and self.cfg.zupt_rate_hz > 0 and t >= self.next_zupt_t)

    def _zupt(self, t: float) -> None:
        self._est_memo = None
        res = self.core.update_zero_velocity(t, self.cfg.zupt_sigma_m_s)
        self.next_zupt_t = t + 1.0 / self.cfg.zupt_rate_hz - 1e-9
        if res.accepted:
            self.counters["zupt_accepted"] += 1
        self.flag.on_update(t, res.accepted, res.nis, len(res.innovation) or 3)

    def _background(self, budget_s: float) -> None:
        if self.bt is None or not self.bt.busy:
            return
        try:
            if budget_s == math.inf:
                self.bt.run_until_done()
            else:
                self.bt.step_background(budget_s)
            self._after_handover()
        except Exception as exc:  # noqa: BLE001
            self._fault(exc)

    def _after_handover(self) -> None:
        if self.bt is not None and self.bt.live is not self.core:
            old = self.core
            self.core = self.bt.live
            if old is not None:
                old.close()
            self.log("info", "backtrack", "backtracking: handed over to the re-aligned core")

    # ------------------------------------------------------------------ initialisation
    def _capabilities(self):
        """(supports_gnss, default_initial_sigmas) of the configured core, from one probe built once (not per
        sample while the session waits for its first fix)."""
        if self._probe is None:
            probe = registry.make_core(self.cfg.core, self.core_params)
            self._probe = (probe.supports_gnss, probe.default_initial_sigmas())
            probe.close()
        return self._probe

    def _try_initialize(self, t: float) -> None:
        cfg = self.cfg
        if cfg.init_mode == "sensors" or self._sensors_reinit:
            self._try_initialize_from_sensors(t)
            return self._still_faulted()  # divergence guard: FAULT stays until a new filter runs
        tr = self.buf.truth.get(t) if cfg.init_mode == "truth" else None
        gnss_core, (sig_rpy, sig_v, sig_p) = self._capabilities()
        static = not gnss_core
        pos, used_fix = None, None
        if static and all(math.isfinite(x) for x in cfg.static_position_deg_m):
            la, lo, h = cfg.static_position_deg_m
            pos = (la * D2R, lo * D2R, float(h))
        elif tr is not None and tr.llh is not None:
            pos = tuple(float(x) for x in tr.llh)
        else:
            j = bisect.bisect_right(self.buf.fix_t, t)
            if j > 0:
                used_fix = self.buf.fix[j - 1]
                pos = earth.ecef_to_geodetic(used_fix.p_e)
        if pos is None:
            self.status = AlignmentStatus.WAITING_FOR_GNSS
            self.reason = ("waiting for a GNSS fix (initial position)" if not static else
                           "waiting for a GNSS fix or static_position_deg_m (site position)")
            return
        if cfg.init_mode == "truth":
            if tr is None:
                self.status = AlignmentStatus.WAITING_FOR_DATA
                self.reason = "waiting for a ground-truth pose at an IMU stamp (init_mode truth)"
                return
            rpy = earth.rpy_from_C_b_n(np.asarray(tr.C_b_n, float)) + np.asarray(cfg.init_rpy_error_deg) * D2R
            v0 = self._truth_velocity(tr)
        else:
            rpy = np.asarray(cfg.initial_rpy_deg) * D2R
            v0 = np.asarray(cfg.initial_velocity_enu_m_s, float)
        sig_rpy = [u if math.isfinite(u) else d for u, d in zip(cfg.init_sigma_rpy_deg, sig_rpy)]
        P_att = np.diag((np.asarray(sig_rpy, float) * D2R) ** 2)
        core = registry.make_core(cfg.core, self.core_params)
        try:
            core.initialize(t, pos[0], pos[1], pos[2], earth.C_b_n_from_rpy(*rpy), v0, P_att, sig_v, sig_p)
        except Exception:
            core.close()
            raise
        self._start(core, t, pos, used_fix, rpy, v0)

    def _start(self, core: AlignmentCore, t: float, pos, used_fix, rpy, v0, how: str = "") -> None:
        cfg = self.cfg
        # fixes up to the initialisation stamp: the one that gave the position is consumed, older ones dropped
        self._used_fix_stamp = used_fix.stamp_s if used_fix is not None else None
        self.pre_init.clear()
        self.core = core
        if cfg.backtrack_passes > 0:
            from ..filters.backtrack import BacktrackingAligner

            self.bt = BacktrackingAligner(core, t, cfg.backtrack_window_s, cfg.backtrack_passes,
                                          covariance=cfg.backtrack_covariance)
        self.init_t = t
        self.anchor = pos
        self.status = AlignmentStatus.CONVERGING
        self.reason = "initialised"
        self.next_out_t = t
        self.next_zupt_t = t
        self.fault_reason = ""
        self.log("info", "init", f"initialised {cfg.core} at t={t + self.stamp_offset_s:.3f} s, lat {pos[0] / D2R:.6f} deg, lon "
                                 f"{pos[1] / D2R:.6f} deg, h {pos[2]:.1f} m, rpy "
                                 f"{np.round(rpy / D2R, 2).tolist()} deg, v {np.round(v0, 3).tolist()} m/s{how}")

    def _try_initialize_from_sensors(self, t: float) -> None:
        """init_mode 'sensors': no guess. Position from the newest fix; velocity from the last two fixes (0 for a
        static core); roll and pitch from the mean specific force over ``init_level_window_s``; heading unknown.

        Sigmas are honest rather than small: velocity sqrt(2) sigma_p / dt plus the unknown acceleration over the
        half interval and the age of the fix; level the accelerometer spread, the vehicle acceleration (the fixes'
        second difference, else ``init_accel_m_s2``) over g, and a 1-deg floor for an unknown accelerometer bias
        (10 mg on a poor MEMS: 0.6 deg). Heading: a bank of ``unknown_heading_hypotheses`` hypotheses for GNSS
        cores (uniform prior); static cores find it themselves (gyrocompassing bootstrap)."""
        cfg = self.cfg
        fixes = self.buf.fix[:bisect.bisect_right(self.buf.fix_t, t)]
        gnss_core, (sig_rpy0, sig_v0, sig_p0) = self._capabilities()
        if not gnss_core and all(math.isfinite(x) for x in cfg.static_position_deg_m):
            la, lo, h = cfg.static_position_deg_m
            pos, used, sig_p = (la * D2R, lo * D2R, float(h)), None, sig_p0
        elif fixes:
            used = fixes[-1]
            pos = earth.ecef_to_geodetic(used.p_e)
            sig_p = max(sig_p0, math.sqrt(max(float(np.trace(used.R_e)) / 3.0, 0.0)))
        else:
            self.status = AlignmentStatus.WAITING_FOR_GNSS
            self.reason = "waiting for a GNSS fix (initial position)"
            return
        a_est = cfg.init_accel_m_s2
        if gnss_core:
            recent = [fx for fx in fixes if t - fx.stamp_s <= 3.0]
            if len(recent) < 2:
                self.status = AlignmentStatus.WAITING_FOR_GNSS
                self.reason = f"waiting for a second GNSS fix (initial velocity; {len(recent)} of 2 within 3 s)"
                return
            # -- divergence guard: a re-initialisation waits for three fixes consistent with each other (the
            # fixes that made the filter diverge may be the bad ones); any initialisation refuses three that are not
            if len(recent) < 3 and self._sensors_reinit:
                self.status = AlignmentStatus.WAITING_FOR_GNSS
                self.reason = f"re-initialising: waiting for three consistent GNSS fixes ({len(recent)} of 3 within 3 s)"
                return
            if len(recent) >= 3:
                excess = _extrapolation_excess([_fix_point(fx) for fx in recent[-3:-1]], _fix_point(recent[-1]),
                                               cfg.gnss_jump_accel_m_s2)
                if excess > 0:
                    self.status = AlignmentStatus.WAITING_FOR_GNSS
                    self.reason = (f"waiting for consistent GNSS fixes (the newest is {excess:.1f} m beyond the "
                                   "extrapolation of the two before it)")
                    return
            # -- end divergence guard
            f1, f2 = recent[-2], recent[-1]
            dt = f2.stamp_s - f1.stamp_s
            C_en = earth.C_e_n(pos[0], pos[1])
            v0 = C_en @ (np.asarray(f2.p_e) - np.asarray(f1.p_e)) / dt
            if len(recent) >= 3:
                f0 = recent[-3]
                dt0 = f1.stamp_s - f0.stamp_s
                v_prev = C_en @ (np.asarray(f1.p_e) - np.asarray(f0.p_e)) / dt0
                a_est = float(np.linalg.norm(v0 - v_prev)) / (0.5 * (dt + dt0)) + 0.5  # + margin for noise/jerk
            s_p = math.sqrt(max(float(np.trace(f2.R_e)) / 3.0, 0.0))
            sig_v = math.sqrt(2.0) * s_p / dt + a_est * (0.5 * dt + (t - f2.stamp_s))
        else:
            v0, sig_v, a_est = np.zeros(3), sig_v0, 0.0
        win = [(w_, f_) for (tt, w_, f_) in self.pre_init if tt > t - cfg.init_level_window_s]
        if len(win) < 5:
            self.status = AlignmentStatus.WAITING_FOR_DATA
            self.reason = f"collecting accelerometer data for the level ({len(win)} samples)"
            return
        roll, pitch, sig_level = earth.level_from_specific_force([f_ for _, f_ in win], a_est)
        # -- divergence guard: the lost filter's level (carried by the gyros) when it agrees with the accelerometers
        kept, level_from = self._kept_level_now(t), "accelerometers"
        if kept is not None and max(abs(earth.wrap_angle_rad(kept[0] - roll)), abs(kept[1] - pitch)) \
                < 3.0 * math.hypot(sig_level, kept[2]):
            roll, pitch, sig_level = kept
            level_from = "the lost filter's level, gyro-propagated"
        # -- end divergence guard
        params = dict(self.core_params)
        if gnss_core and params.get("yaw_hypotheses", 1) == 1 and cfg.unknown_heading_hypotheses > 1:
            params["yaw_hypotheses"] = cfg.unknown_heading_hypotheses
        core = registry.make_core(cfg.core, params)
        sig_yaw = 1e4 if gnss_core else sig_rpy0[2]  # unknown: uniform over the bank's hypotheses
        user = cfg.init_sigma_rpy_deg
        sig = [u * D2R if math.isfinite(u) else d for u, d in zip(user, (sig_level, sig_level, sig_yaw * D2R))]
        rpy = np.array([roll, pitch, 0.0])
        try:
            core.initialize(t, pos[0], pos[1], pos[2], earth.C_b_n_from_rpy(*rpy), v0, np.diag(np.square(sig)),
                            sig_v, sig_p)
        except Exception:
            core.close()
            raise
        self._start(core, t, pos, used, rpy, v0, how=(
            f" (from sensors: level 1-sigma {sig_level / D2R:.2f} deg from {level_from} ({len(win)} samples), "
            f"velocity 1-sigma "
            f"{sig_v:.2f} m/s, heading unknown: {params.get('yaw_hypotheses', 1)} hypotheses)"))

    def _truth_velocity(self, tr: TruthSample) -> np.ndarray:
        """Truth velocity: given, or the slope at ``tr`` of a quadratic through up to two truth positions on each
        side (the fusion delay means the later ones have arrived); the initial-velocity guess when none."""
        if tr.v_n is not None:
            return np.asarray(tr.v_n, float)
        if tr.p_n is None:
            return np.asarray(self.cfg.initial_velocity_enu_m_s, float)
        ts = [k for k in self.buf.truth_t if abs(k - tr.stamp_s) <= 1.0 and self.buf.truth[k].p_n is not None]
        before = [k for k in ts if k < tr.stamp_s][-2:]
        after = [k for k in ts if k > tr.stamp_s][:2]
        keys = before + [tr.stamp_s] + after
        if len(keys) < 2:
            return np.asarray(self.cfg.initial_velocity_enu_m_s, float)
        dt = np.array(keys) - tr.stamp_s
        P = np.array([np.asarray(self.buf.truth[k].p_n if k != tr.stamp_s else tr.p_n, float) for k in keys])
        deg = min(2, len(keys) - 1)
        coef = np.polyfit(dt, P, deg)  # highest power first; the slope at dt = 0 is the linear coefficient
        return coef[-2]

    # ------------------------------------------------------------------ outputs, flag, status
    def _estimate(self) -> AlignmentEstimate:
        """``core.estimate()`` once per core state: the divergence guard's covariance test after a fix and the output
        at the same sample read the same one (the memo is dropped whenever the session hands the core a sample or an
        update)."""
        m, core = self._est_memo, self.core
        if m is not None and m[0] is core:
            return m[1]
        est = core.estimate()
        self._est_memo = (core, est)
        return est

    def _output(self, t: float) -> Output:
        est = self._estimate()
        P = est.P_att_n
        if not (math.isfinite(est.lat_rad) and _all_finite(P) and _all_finite(est.C_b_n)):
            raise FloatingPointError("non-finite estimate")
        was = self.flag.aligned
        now = self.flag.on_estimate(t, P) and not self.watchdog_reason
        if not now:
            self.flag.aligned = False
        if now != was:
            self.flag_changes.append((t, now, self.flag.reason))
            self.log("info", "flag", f"aligned flag {'raised' if now else 'lowered'} at t={t + self.stamp_offset_s:.3f} s: {self.flag.reason}")
        self.status = AlignmentStatus.ALIGNED if now else AlignmentStatus.CONVERGING
        if not now and est.status == AlignmentStatus.WAITING_FOR_MOTION:  # issue 14: core auto, heading needs motion
            self.status = est.status
        self.reason = self.flag.reason if not est.reason else f"{self.flag.reason}; {est.reason}"
        tr = self._truth_at(t)
        o = Output(t, est, now, self.status, self.reason, euler_3sigma_deg(est.C_b_n, P), None, tr)
        if tr is not None:
            if self._deferred_errors is not None:
                self._deferred_errors.append(o)
            else:
                o.euler_error_deg = np.degrees(earth.euler_error_rad(est.C_b_n, tr))
        self.last_output = o
        return o

    def _fill_deferred_errors(self) -> None:
        """The Euler errors of the outputs deferred by ``run_session``, in one vectorised call (numpy's elementwise
        functions: the numbers of one call per output, test_speed_paths); deferring ends."""
        outs, self._deferred_errors = self._deferred_errors, None
        if outs:
            E = np.degrees(earth.euler_error_rad(np.array([o.estimate.C_b_n for o in outs], float),
                                                 np.array([o.truth_C_b_n for o in outs], float)))
            for o, e in zip(outs, E):
                o.euler_error_deg = e

    def _truth_at(self, t: float) -> np.ndarray | None:
        """Truth attitude at ``t``: the pose stamped there (within 1 us), else the slerp between the two poses that
        bracket ``t`` within 0.25 s (a truth topic at its own rate), else None."""
        b = self.buf
        tt = b.truth_t
        # truth is only needed near the filter time: forget what is more than 2 s behind
        n_old = bisect.bisect_left(tt, t - 2.0)
        if n_old:
            for k in tt[:n_old]:
                del b.truth[k]
            del tt[:n_old]
        if isinstance(b.truth, _TruthDict):
            if not tt:  # the pending rows come after every stamp in the dict
                b.truth.drop_pending_before(t - 2.0)
            before, after = b.truth.around(t - 1e-6)
        else:
            i = bisect.bisect_left(tt, t - 1e-6)
            before = (tt[i - 1], b.truth[tt[i - 1]].C_b_n) if 0 < i <= len(tt) else None
            after = (tt[i], b.truth[tt[i]].C_b_n) if i < len(tt) else None
        if after is not None and abs(after[0] - t) <= 1e-6:
            return np.asarray(after[1], float)
        if before is not None and after is not None and after[0] - before[0] <= 0.25:
            # slerp C_a exp(s log(C_a^T C_b)), s = (t - t_a) / (t_b - t_a): what scipy's Slerp computes, without
            # building its objects (~40 vs ~155 us; once per output with a truth topic; docs/nodes.md, "CPU share")
            C_a = np.asarray(before[1], float)
            s = (t - before[0]) / (after[0] - before[0])
            return C_a @ lie.so3_exp(s * lie.so3_log(C_a.T @ np.asarray(after[1], float)))
        return None

    def _watchdog(self, wall_s: float) -> None:
        to = self.cfg.imu_timeout_s
        if to <= 0 or self.last_imu_wall is None:
            return
        silent = wall_s - self.last_imu_wall
        if silent > to:
            if not self.watchdog_reason:
                self.counters["watchdog_trips"] += 1
                self.log("warn", "watchdog", f"no IMU sample for {silent:.1f} s (imu_timeout_s {to:g} s): "
                                             "aligned flag lowered")
            self.watchdog_reason = f"no IMU sample for {silent:.1f} s"
            if self.flag.aligned:
                self.flag.aligned = False
                self.flag.holding_since_s = None
                self.flag_changes.append((self.processed_t or 0.0, False, self.watchdog_reason))
        else:
            self.watchdog_reason = ""

    def _fault(self, exc: Exception) -> None:
        self.counters["core_faults"] += 1
        self.last_reject = f"fault: {type(exc).__name__}: {exc}"
        self.log("error", "fault", f"core fault ({type(exc).__name__}: {exc}); resetting the alignment\n"
                                   f"{traceback.format_exc(limit=3)}")
        self._restart(f"{type(exc).__name__}: {exc}")

    def _restart(self, why: str) -> None:
        """Drop the core, keep the time line and the buffered inputs, status FAULT: re-initialise from what follows."""
        keep_t = self.processed_t
        resets = dict(self.counters)
        newest, recent = self.newest_imu_t, self.recent_stamps
        pending = self.buf
        last_reject, offset = self.last_reject, self.stamp_offset_s
        self._reset_state(f"after {why}")
        self.counters.update(resets)
        self.last_reject, self.stamp_offset_s = last_reject, offset
        # keep the time line and the buffered inputs: re-initialise from the data that follow
        self.buf, self.newest_imu_t, self.recent_stamps = pending, newest, recent
        self.processed_t = keep_t
        self.status = AlignmentStatus.FAULT
        self.fault_reason = why
        self.reason = f"fault ({why}); re-initialising"
        self.flag_changes.append((keep_t or 0.0, False, self.reason))

    @property
    def aligned(self) -> bool:
        return self.flag.aligned and not self.watchdog_reason

    @property
    def filter_time_s(self) -> float | None:
        return self.processed_t

    def level(self) -> int:
        """Diagnostic level: 0 OK (aligned, fresh inputs), 1 WARN, 2 ERROR (fault)."""
        if self.status == AlignmentStatus.FAULT:
            return 2
        if self.watchdog_reason or not self.aligned or self._gnss_age_warning():
            return 1
        return 0

    def _gnss_age_warning(self) -> str:
        if self.core is None or not self.core.supports_gnss or self.processed_t is None:
            return ""
        ref = self.last_accepted_fix_t if self.last_accepted_fix_t is not None else self.init_t
        age = self.processed_t - ref
        return f"no GNSS fix for {age:.0f} s" if age > self.cfg.gnss_timeout_s else ""

    def message(self) -> str:
        parts = [f"{self.status.value}: {self.reason}"]
        if self.watchdog_reason:
            parts.append(self.watchdog_reason)
        g = self._gnss_age_warning()
        if g:
            parts.append(g)
        if not self.aligned and "3-sigma" in self.flag.reason and self.cfg.imu_grade == DEFAULT_IMU_GRADE:
            # the conservative default prior is often why the 3-sigma stays up: say what the user can do
            parts.append(f"imu_grade is the conservative default {DEFAULT_IMU_GRADE!r}: give your IMU's grade "
                         "(docs/imu_grades.md) for a tighter, still honest, covariance")
        return "; ".join(parts)

    def diagnostics(self) -> dict:
        """Key/value pairs for /diagnostics and the metrics JSON (strings, numbers, lists)."""
        d: dict = {"core": self.cfg.core, "state": self.status.value, "reason": self.reason,
                   "aligned": str(self.aligned).lower(), "aligned_reason": self.flag.reason,
                   "message": self.message()}
        o = self.last_output
        if o is not None:
            s = self.flag.sigma3_deg
            d.update(yaw_3sigma_deg=f"{s[2]:.4f}", roll_pitch_3sigma_deg=f"{max(s[0], s[1]):.4f}",
                     yaw_sigma_deg=f"{s[2] / 3:.4f}", filter_time_s=f"{o.stamp_s + self.stamp_offset_s:.3f}")
        if self.flag.raised_at_s is not None:
            d["aligned_raised_at_s"] = f"{self.flag.raised_at_s + self.stamp_offset_s:.3f}"
            d["aligned_first_raised_at_s"] = f"{self.flag.first_raised_at_s + self.stamp_offset_s:.3f}"
        if o is not None:
            d["aligned_at_last_output"] = str(o.aligned).lower()  # the flag at the newest data (before any watchdog)
        if self.init_t is not None:
            d["initialised_at_s"] = f"{self.init_t + self.stamp_offset_s:.3f}"
        lo, hi = self.flag.band
        d.update(nis_last=f"{self.last_nis:.3f}", nis_window_sum=f"{self.flag.nis_sum:.3f}",
                 nis_band=f"[{lo:.2f}, {hi:.2f}]", last_reject=self.last_reject)
        # divergence guard: the statistics behind a FAULT (docs/session.md)
        d["divergence_cusum_llr"] = f"{self._cusum_llr:.3f}"
        if self._nis_win:
            d["divergence_nis_window_mean"] = f"{float(np.mean(self._nis_win)):.3f}"
        if self.processed_t is not None and self.last_accepted_fix_t is not None:
            d["gnss_age_s"] = f"{self.processed_t - self.last_accepted_fix_t:.2f}"
        if self._median_dt is not None:
            d["imu_period_median_ms"] = f"{self._median_dt * 1e3:.3f}"
        d["buffered_imu"] = str(len(self.buf.imu))
        d["buffered_fixes"] = str(len(self.buf.fix_t))
        if self.watchdog_reason:
            d["watchdog"] = self.watchdog_reason
        if self.bt is not None:
            d["backtrack_state"] = self.bt.state
            d.update({f"backtrack_{k}": v for k, v in self.bt.stats.items()})
        d.update({k: str(v) for k, v in self.counters.items()})
        if self.core is not None:
            try:
                d.update({f"core.{k}": v for k, v in self.core.diagnostics().items()})
                d.update({f"core.counter.{k}": v for k, v in self.core.counters.items()})
            except Exception as exc:  # noqa: BLE001 - diagnostics never take the pipeline down
                d["core.diagnostics_error"] = f"{type(exc).__name__}: {exc}"
        return d


def _fix_point(fix: GnssFix) -> tuple[float, np.ndarray, float]:
    """(stamp [s], p_e [m], 1-sigma [m] per axis: the RMS of R_e's diagonal) of a fix: the jump detection's input."""
    return float(fix.stamp_s), np.asarray(fix.p_e, float), math.sqrt(max(float(np.trace(fix.R_e)) / 3.0, 0.0))


def _extrapolation_excess(prev, point, accel_m_s2: float) -> float:
    """How far [m] a fix ``point`` lies beyond what the straight-line extrapolation of ``prev`` (two earlier
    points, each within 3 s of the next; points from :func:`_fix_point`) allows: acceleration up to ``accel_m_s2``
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


def _covariance_problem(P_att: np.ndarray, level_3sigma_deg: float) -> str:
    """Why an attitude covariance [rad^2, ENU] cannot be a filter's honest belief ("" when it can): not finite,
    not symmetric, not positive definite, or a roll/pitch (East/North) 3-sigma beyond ``level_3sigma_deg``."""
    if _covariance_plainly_fine(P_att, level_3sigma_deg):
        return ""
    P = np.asarray(P_att, float)
    if not np.all(np.isfinite(P)):
        return "attitude covariance is not finite"
    d = np.diag(P)
    if np.any(d <= 0):
        return f"attitude covariance is not positive definite (diagonal {np.array2string(d, precision=3)} rad^2)"
    # in correlation form: a yaw variance of 1e8 rad^2 (unknown heading) next to 1e-8 rad^2 of level is no problem
    C = P / np.sqrt(np.outer(d, d))
    if float(np.max(np.abs(C - C.T))) > 1e-6:
        return f"attitude covariance is not symmetric (correlation asymmetry {float(np.max(np.abs(C - C.T))):.3g})"
    ev = np.linalg.eigvalsh(0.5 * (C + C.T))
    if ev[0] < -1e-9:
        return f"attitude covariance is not positive definite (correlation eigenvalue {ev[0]:.3g})"
    s_level = 3.0 * math.degrees(math.sqrt(max(P[0, 0], P[1, 1])))
    if s_level > level_3sigma_deg:
        return f"level 3-sigma {s_level:.0f} deg beyond the physical bound {level_3sigma_deg:g} deg"
    return ""


def _covariance_plainly_fine(P_att: np.ndarray, level_3sigma_deg: float) -> bool:
    """A sufficient condition for :func:`_covariance_problem` to find nothing, in Python floats (it runs after every
    fix; numpy's eigvalsh on 3x3 costs ~15 us): finite, positive diagonal, the correlation form symmetric within the
    same 1e-6, the symmetrised correlation minus 1e-6 I has a Cholesky factor (so its smallest eigenvalue is above
    1e-6 minus rounding, far from the -1e-9 limit), and the same level 3-sigma test. False: the full test decides."""
    (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = np.asarray(P_att, float).tolist()
    if not (math.isfinite(p00 + p01 + p02 + p10 + p11 + p12 + p20 + p21 + p22) and p00 > 0 and p11 > 0 and p22 > 0):
        return False
    c01, c10 = p01 / math.sqrt(p00 * p11), p10 / math.sqrt(p11 * p00)
    c02, c20 = p02 / math.sqrt(p00 * p22), p20 / math.sqrt(p22 * p00)
    c12, c21 = p12 / math.sqrt(p11 * p22), p21 / math.sqrt(p22 * p11)
    if max(abs(c01 - c10), abs(c02 - c20), abs(c12 - c21)) > 1e-6:
        return False
    s01, s02, s12 = 0.5 * (c01 + c10), 0.5 * (c02 + c20), 0.5 * (c12 + c21)
    delta = 1e-6
    a = p00 / math.sqrt(p00 * p00) - delta
    if not a > 0:
        return False
    l00 = math.sqrt(a)
    l10, l20 = s01 / l00, s02 / l00
    a = p11 / math.sqrt(p11 * p11) - delta - l10 * l10
    if not a > 0:
        return False
    l11 = math.sqrt(a)
    l21 = (s12 - l20 * l10) / l11
    if not p22 / math.sqrt(p22 * p22) - delta - l20 * l20 - l21 * l21 > 0:
        return False
    return not 3.0 * math.degrees(math.sqrt(max(p00, p11))) > level_3sigma_deg


def _all_finite(X: np.ndarray) -> bool:
    """``np.all(np.isfinite(X))`` for a small array, without numpy's per-call overhead (the sum of finite numbers
    overflows only beyond 1e308: then numpy decides)."""
    return math.isfinite(sum(X.ravel().tolist())) or bool(np.all(np.isfinite(X)))


def _check_velocity(t: float, v_n, R_n) -> str:
    """Checks of one GNSS velocity: finite stamp, the core's checks (filters/liekf.check_velocity), plausible speed."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    reason = check_velocity(v_n, R_n)
    if not reason and float(np.linalg.norm(v_n)) > MAX_GNSS_SPEED_M_S:
        reason = f"speed {np.linalg.norm(v_n):.3g} m/s > {MAX_GNSS_SPEED_M_S:g} m/s"
    return reason


def _check_imu(t: float, w, f, max_rate: float, max_acc: float) -> str:
    """Scalar checks of one IMU sample (hot path: plain floats, no numpy reductions)."""
    if not math.isfinite(t) or t < 0.0:
        return f"stamp {t!r} is not a finite number >= 0"
    wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
    fx, fy, fz = float(f[0]), float(f[1]), float(f[2])
    if not math.isfinite(wx + wy + wz):
        return "angular_velocity: non-finite value"
    if not math.isfinite(fx + fy + fz):
        return "linear_acceleration: non-finite value"
    nw = math.sqrt(wx * wx + wy * wy + wz * wz)
    if nw > max_rate:
        return f"angular_velocity: magnitude {nw:.3g} > {max_rate:.3g}"
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    if nf > max_acc:
        return f"linear_acceleration: magnitude {nf:.3g} > {max_acc:.3g}"
    return ""


class _FastPlan:
    """Arrays of one ``_process`` batch for ``AlignmentSession._fast_run``: stamps, rates, specific forces, the
    intervals, and the samples that could be spikes (off both neighbours by more than the configured bounds)."""

    def __init__(self, session: AlignmentSession, T: np.ndarray, W: np.ndarray, F: np.ndarray, nxt, Tl: list) -> None:
        n = T.shape[0]
        self.n = n
        self.T, self.W, self.F, self.Tl = T, W, F, Tl
        self.n_fast = n if nxt is not None else n - 1  # the last sample of the buffer: per sample (no neighbour)
        self.dT = np.diff(self.T)
        self.dnext = np.append(self.dT, (nxt[0] - self.T[-1]) if nxt is not None else math.inf)
        self.dTl = self.dT.tolist()
        self.dnextl = self.dnext.tolist()
        cfg = session.cfg
        self.bound_w, self.bound_f = cfg.imu_spike_rad_s, cfg.imu_spike_m_s2
        self.cand = None
        if self.bound_w <= 0 and self.bound_f <= 0:
            return
        # |x_{k+1} - x_k| for every sample k (the last against the next buffered sample)
        Wx = np.vstack((self.W, np.asarray(nxt[1], float).reshape(1, 3))) if nxt is not None else self.W
        Fx = np.vstack((self.F, np.asarray(nxt[2], float).reshape(1, 3))) if nxt is not None else self.F
        self.dn_w = np.append(_row_norms(np.diff(Wx, axis=0)), math.inf)[:n]
        self.dn_f = np.append(_row_norms(np.diff(Fx, axis=0)), math.inf)[:n]
        # sample k >= 1 with its predecessor in the run; the margin keeps the test conservative against rounding
        dw = np.minimum(self.dn_w[1:], self.dn_w[:-1])
        df = np.minimum(self.dn_f[1:], self.dn_f[:-1])
        bad = np.zeros(n - 1, bool)
        if self.bound_w > 0:
            bad |= dw > self.bound_w * (1.0 - 1e-9)
        if self.bound_f > 0:
            bad |= df > self.bound_f * (1.0 - 1e-9)
        self.cand = (np.flatnonzero(bad) + 1).tolist()

    def next_candidate(self, k: int) -> int:
        """Index of the first possible spike at or after ``k`` (``n`` when none)."""
        c = self.cand
        i = bisect.bisect_left(c, k)
        return c[i] if i < len(c) else self.n

    def candidate_at(self, k: int, w_prev, f_prev) -> bool:
        """Could sample ``k`` be a spike, with ``w_prev``, ``f_prev`` the last processed sample before it?"""
        dw = min(_dist3(self.W[k].tolist(), np.asarray(w_prev, float).tolist()), float(self.dn_w[k]))
        df = min(_dist3(self.F[k].tolist(), np.asarray(f_prev, float).tolist()), float(self.dn_f[k]))
        return bool((self.bound_w > 0 and dw > self.bound_w * (1.0 - 1e-9))
                    or (self.bound_f > 0 and df > self.bound_f * (1.0 - 1e-9)))


class _ImuBuffer:
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
    a snapshot that stays valid (``_LazySpread`` keeps one)."""

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


class _RecentStamps:
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


class _LazySpread:
    """The spike check's spread statistic (rate, specific force) over the history a per-sample run would have
    held when it fell due inside a fast run; computed only if a later spike check needs it."""

    def __init__(self, hist_w: list, hist_f: list, run_w: np.ndarray, run_f: np.ndarray, maxlen: int) -> None:
        self.parts = (hist_w, hist_f, run_w, run_f, maxlen)

    def value(self) -> tuple[float, float]:
        hw, hf, rw, rf, maxlen = self.parts
        W = np.vstack([np.asarray(hw, float).reshape(-1, 3), rw])[-maxlen:]
        F = np.vstack([np.asarray(hf, float).reshape(-1, 3), rf])[-maxlen:]
        return (float(np.linalg.norm(np.std(W, axis=0))), float(np.linalg.norm(np.std(F, axis=0))))


def _median(x: list) -> float:
    """``float(np.median(x))`` for a list of floats, bit for bit (the middle value, or the mean of the two middle
    ones), without numpy's per-call overhead."""
    s = sorted(x)
    h = len(s) // 2
    return float(s[h]) if len(s) % 2 else float((s[h - 1] + s[h]) / 2.0)


def _dist3(a: list, b: list) -> float:
    """|a - b| of two 3-vectors given as lists of floats: ``float(np.linalg.norm(a - b))`` bit for bit (the same
    sum in the same order; test_speed_paths), without numpy's per-call overhead."""
    x, y, z = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return math.sqrt(x * x + y * y + z * z)


def _row_norms(X: np.ndarray) -> np.ndarray:
    return np.sqrt(X[:, 0] * X[:, 0] + X[:, 1] * X[:, 1] + X[:, 2] * X[:, 2])
