"""Outputs: one record per ``output_period_s`` of data time (estimate, flag, status, 3-sigma, and the Euler error
where a truth pose is at hand)."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from ..core import earth, lie
from ..filters.base import AlignmentEstimate, AlignmentStatus
from .flag import euler_3sigma_deg, euler_3sigma_deg_many
from .truth import TruthDict


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


class Outputs:
    """Builds the output records (and the estimate they share with the divergence guard)."""

    def __init__(self, session) -> None:
        self.s = session
        self._deferred_s3: list[Output] = []  # outputs whose 3-sigma is filled in by ``fill_deferred_errors``
        #: offline with a valid truth table (``defer_truth``): the outputs' truth is looked up in it at the end
        self._truth_table = None
        self._deferred_truth: list[Output] = []

    def reset(self) -> None:
        pass

    def estimate(self) -> AlignmentEstimate:
        """``core.estimate()`` once per core state: the divergence guard's covariance test after a fix and the output
        at the same sample read the same one (the memo is dropped whenever the session hands the core a sample or an
        update)."""
        sess = self.s
        m, core = sess._est_memo, sess.core
        if m is not None and m[0] is core:
            return m[1]
        est = core.estimate()
        sess._est_memo = (core, est)
        return est

    def output(self, t: float) -> Output:
        sess = self.s
        est = self.estimate()
        P = est.P_att_n
        if not (math.isfinite(est.lat_rad) and all_finite(P) and all_finite(est.C_b_n)):
            raise FloatingPointError("non-finite estimate")
        was = sess.flag.aligned
        now = sess.flag.on_estimate(t, P) and not sess.watchdog_reason
        if not now:
            sess.flag.aligned = False
        if now != was:
            sess.flag_changes.append((t, now, sess.flag.reason))
            sess.log("info", "flag", f"aligned flag {'raised' if now else 'lowered'} at t={t + sess.stamp_offset_s:.3f} s: {sess.flag.reason}")
        sess.status = AlignmentStatus.ALIGNED if now else AlignmentStatus.CONVERGING
        if not now and est.status == AlignmentStatus.WAITING_FOR_MOTION:  # issue 14: core auto, heading needs motion
            sess.status = est.status
        sess.reason = sess.flag.reason if not est.reason else f"{sess.flag.reason}; {est.reason}"
        deferred = sess._deferred_errors is not None
        late = deferred and self._truth_table is not None
        tr = self.truth_at(t, prune_only=late)
        o = Output(t, est, now, sess.status, sess.reason, None if deferred else euler_3sigma_deg(est.C_b_n, P), None, tr)
        if deferred:
            self._deferred_s3.append(o)
        if late:
            self._deferred_truth.append(o)
        if tr is not None:
            if deferred:
                sess._deferred_errors.append(o)
            else:
                o.euler_error_deg = np.degrees(earth.euler_error_rad(est.C_b_n, tr))
        sess.last_output = o
        return o

    def defer_truth(self, table) -> None:
        """Offline (``run_session``, with the outputs' errors deferred): ``table`` (a valid TruthTable, the one pushed
        with ``push_truth_table``, rows at every IMU stamp) gives the outputs' truth at the end, looked up at once:
        an output falls on an IMU sample, whose row the table holds, which is what ``truth_at`` finds there."""
        self._truth_table = table

    def fill_deferred_errors(self) -> None:
        """The Euler errors and 3-sigma of the outputs deferred by ``run_session``, in one vectorised call each
        (numpy's elementwise functions: the numbers of one call per output, test_speed_paths); deferring ends."""
        sess = self.s
        outs_t, self._deferred_truth, table, self._truth_table = self._deferred_truth, [], self._truth_table, None
        if outs_t:
            T = np.array([o.stamp_s for o in outs_t])
            k = np.minimum(np.searchsorted(table.t_s, T - 1e-6, side="left"), len(table.t_s) - 1)
            hit = np.abs(table.t_s[k] - T) <= 1e-6
            for o, kk, h in zip(outs_t, k.tolist(), hit.tolist()):
                o.truth_C_b_n = np.asarray(table.C_b_n[kk], float) if h else None
                if h and sess._deferred_errors is not None:
                    sess._deferred_errors.append(o)
        outs3, self._deferred_s3 = self._deferred_s3, []
        if outs3:
            S3 = euler_3sigma_deg_many(np.array([o.estimate.C_b_n for o in outs3], float),
                                       np.array([o.estimate.P_att_n for o in outs3], float))
            for o, s3 in zip(outs3, S3):
                o.euler_3sigma_deg = s3
        outs, sess._deferred_errors = sess._deferred_errors, None
        if outs:
            E = np.degrees(earth.euler_error_rad(np.array([o.estimate.C_b_n for o in outs], float),
                                                 np.array([o.truth_C_b_n for o in outs], float)))
            for o, e in zip(outs, E):
                o.euler_error_deg = e

    def truth_at(self, t: float, prune_only: bool = False) -> np.ndarray | None:
        """Truth attitude at ``t``: the pose stamped there (within 1 us), else the slerp between the two poses that
        bracket ``t`` within 0.25 s (a truth topic at its own rate), else None. ``prune_only``: only forget what is
        behind (the look-up is deferred: ``defer_truth``)."""
        sess = self.s
        b = sess.buf
        tt = b.truth_t
        # truth is only needed near the filter time: forget what is more than 2 s behind
        n_old = bisect.bisect_left(tt, t - 2.0)
        if n_old:
            for k in tt[:n_old]:
                del b.truth[k]
            del tt[:n_old]
        if isinstance(b.truth, TruthDict):
            if not tt:  # the pending rows come after every stamp in the dict
                b.truth.drop_pending_before(t - 2.0)
        if prune_only:
            return None
        if isinstance(b.truth, TruthDict):
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


def all_finite(X: np.ndarray) -> bool:
    """``np.all(np.isfinite(X))`` for a small array, without numpy's per-call overhead (the sum of finite numbers
    overflows only beyond 1e308: then numpy decides)."""
    return math.isfinite(sum(X.ravel().tolist())) or bool(np.all(np.isfinite(X)))
