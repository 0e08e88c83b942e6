"""The processing loop: buffered IMU samples up to the fusion horizon go to the core in stamp order, runs up to the
next event as arrays (``core.propagate``, split at the samples where an output falls due), the samples that need
attention (a possible gap or spike) one by one (arrays of length 1: the same entry). Period tracking, spike dropping
and gap bridging live here.

docs/session.md ("Time line", "Gaps"), docs/speed.md."""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from . import gaps
from .gaps import median
from .buffers import Ring, row_norms
from .outputs import Output

D2R = math.pi / 180.0


class Loop:
    """Runs the buffered samples through the core (``run``); keeps the IMU period statistics and recent history."""

    #: ``_fast_run``'s lower bound of the smallest interval in ``dts``: (value, valid at ``_dt_count``, exact at that
    #: count, for that deque: a reset makes a new one)
    _dts_min_cache = None

    def __init__(self, session) -> None:
        self.s = session
        self.reset()

    def reset(self) -> None:
        self.dts: deque = deque(maxlen=101)
        self.median_dt: float | None = None
        self._gap_thr: float | None = None  # the longest interval that is not a gap (gaps.gap_threshold)
        self._dt_count = 0
        self._spread = None
        self.hist_t = Ring(1000)  # recent processed samples (gap bridging statistics)
        self.hist_w = Ring(1000, 3)
        self.hist_f = Ring(1000, 3)
        self._batch: tuple[list, int] = ([], 0)  # the batch being processed and the index in it (gap look-ahead)

    def run(self, until: float) -> list[Output]:
        sess = self.s
        out: list[Output] = []
        b = sess.buf
        n = b.imu.count_until(until)
        if n == 0:
            sess.fusion.apply_due_fixes(out)
            return out
        T, W, F = b.imu.take(n)
        Tl = T.tolist()
        arrs = (Tl, W, F)
        after = b.imu.first()
        plan = FastPlan(sess, T, W, F, after, Tl) if sess.fast_path and n >= 8 else None
        i = 0
        while i < n:
            if plan is not None and sess.core is not None and sess.bt is None:
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
                sess._fault(exc)
        sess.fusion.apply_due_fixes(out)
        sess.timing["samples"] += n
        return out

    def _fast_run(self, plan: "FastPlan", i: int, out: list[Output]) -> int:
        """Process samples ``i:j`` of the plan in one batch when none of them needs per-sample attention, the last
        one possibly a sample at which events fall due (fixes, GNSS velocities, wheel speeds, a scheduled update:
        handled after the batch, as ``_step`` does after that sample); outputs that fall due inside the run are
        made at their samples (``_finish_run``). Return ``j`` (``i``: nothing done, the caller takes the per-sample
        path).

        A sample needs attention when its interval could be a gap or make the spike check return early (bounded with
        a lower bound of the running median interval), or when it could be a spike (off both neighbours by more than
        the configured bounds, which the adaptive bound never undercuts). Everything else ``_step`` does per sample
        is done here for the run at once (period tracking, counters, history, ``core.propagate``), with the
        same result (docs/speed.md)."""
        sess = self.s
        core, cfg = sess.core, sess.cfg
        prev = sess.processed_t
        if prev is None or self.median_dt is None or not self.hist_w or i >= plan.n_fast \
                or self._dt_count < self.dts.maxlen:  # the rate model is updated at every interval until then
            return i
        Tl = plan.Tl
        # events: fixes, GNSS velocities, wheel speeds, scheduled updates (stamps increase along the buffer); the run
        # ends at the first sample at which one falls due (outputs fall due inside a run: _finish_run)
        b = sess.buf
        t_end = math.inf
        if b.fix_t and b.fix_t[0] < t_end:
            t_end = b.fix_t[0]
        if b.vel_t and b.vel_t[0] < t_end:
            t_end = b.vel_t[0]
        if b.wheel_t and b.wheel_t[0] < t_end and sess.fusion.wheel_speed_used():
            t_end = b.wheel_t[0]  # a wheel speed is fused at its stamp (a 0.1-s delay at 2 m/s^2 is 0.2 m/s)
        if sess.next_zupt_t < t_end and sess.fusion.zupt_due(math.inf) and not self._zupts_in_run(core):
            t_end = sess.next_zupt_t  # the session schedules zero-velocity updates (at the end of a run, or inside it)
        t_nhc = max(sess.next_nhc_t, sess.nhc_off_until_t)  # ... and the vehicle's non-holonomic constraint
        if t_nhc < t_end and sess.fusion.nhc_due(t_nhc):
            t_end = t_nhc
        j = min(plan.n_fast, bisect.bisect_left(Tl, t_end, i) + 1)
        if plan.cand is not None:  # spike candidates after the first sample; the first against the history
            j = min(j, plan.next_candidate(i + 1))
            # the history ends with the plan's previous sample (the run goes on): its test is the plan's, bit for bit
            if j == i or (plan.next_candidate(i) == i if i > 0 and self.hist_t[-1] == Tl[i - 1]
                          else plan.candidate_at(i, self.hist_w[-1], self.hist_f[-1])):
                return i
        c0 = self._dt_count
        if self._gap_thr > cfg.gap_factor * self.median_dt:
            # jittery stamps (gaps.gap_threshold over gap_factor medians): the run ends before the next update of
            # the rate model, so every interval is checked against the threshold the per-sample path would use (the
            # spike check's cut, max(3 medians, it), is never below it)
            j = min(j, i + (c0 // gaps.MODEL_EVERY + 1) * gaps.MODEL_EVERY - 1 - c0)
            if j <= i:
                return i
            d = [Tl[i] - prev]
            d += plan.dTl[i:j - 1]
            thr = self._gap_thr  # = min(the gap threshold, the spike check's cut max(3 medians, it))
            over = np.flatnonzero(np.array(d) > thr)
            if over.size:
                j = i + int(over[0]) - 1
                d = d[:max(j - i, 0)]
            elif plan.dnextl[j - 1] > thr:
                j -= 1
                d = d[:j - i]
            if j - i < 1:
                return i
            return self._finish_run(plan, i, j, d, min(d), c0, None, t_end, out)
        # intervals: none may be a gap or exceed 3 medians (the spike check's early return), for any median the
        # running window can take during the run (>= the 51st smallest interval of the old window and the run)
        d = [Tl[i] - prev]
        d += plan.dTl[i:j - 1]
        fac = min(3.0, cfg.gap_factor)  # (the stored gap threshold may be older than the median: min with it)
        # cheap bound first (the smallest interval anywhere; the median now may come from a window partly older than
        # the window now), the 51st smallest of the old window and the run when jitter makes the cheap one too tight
        mc = self._dts_min_cache  # (a lower bound of min(dts), at interval count, exact at count, that deque)
        if mc is None or mc[1] != c0 or mc[3] is not self.dts or c0 - mc[2] > self.dts.maxlen:
            mc = (min(self.dts), c0, c0, self.dts)
        d_min = min(d)
        lb = min(mc[0], d_min, self.median_dt)
        if max(d) > min(fac * lb, self._gap_thr) or plan.dnextl[j - 1] > min(fac * lb, self._gap_thr):
            old = list(self.dts)
            alld = np.array(old + d)
            lb = float(alld.min()) if len(old) < self.dts.maxlen else float(np.partition(alld, 50)[50])
            lb = min(lb, self.median_dt)
            thr = min(fac * lb, self._gap_thr)
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
        return self._finish_run(plan, i, j, d, d_min, c0, mc, t_end, out)

    def _finish_run(self, plan: "FastPlan", i: int, j: int, d: list, d_min: float, c0: int, mc, t_end: float,
                    out: list[Output]) -> int:
        """Process the run ``i:j`` of the plan (its intervals ``d``) as ``_step`` would sample by sample."""
        sess = self.s
        core, cfg, b = sess.core, sess.cfg, sess.buf
        Tl = plan.Tl
        if mc is None:
            mc = (min(self.dts), c0, c0, self.dts)
        m = j - i
        # period tracking as _track_period per sample: the median at the last multiple of 20 intervals in the run
        p = (c0 + m) // 20 * 20
        q = (c0 + m) // gaps.MODEL_EVERY * gaps.MODEL_EVERY  # the rate model's update (a multiple of 20 too)
        if p > c0:
            if q > c0:
                self.dts.extend(d[:q - c0])
                self.median_dt = median(self.dts)
                self._gap_thr = gaps.gap_threshold(self.dts, cfg.gap_factor, self.median_dt, self._gap_thr)
                self.dts.extend(d[q - c0:p - c0])
            else:
                self.dts.extend(d[:p - c0])
            self.median_dt = median(self.dts)
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
                self._spread = LazySpread(self.hist_w.view(), self.hist_f.view(), plan.W[i:i + due],
                                           plan.F[i:i + due], self.hist_w.maxlen)
        t = Tl[j - 1]
        sess.processed_t = t
        sess.counters["imu_processed"] += m
        T, W, F = plan.T[i:j], plan.W[i:j], plan.F[i:j]
        self.hist_t.extend(T)
        self.hist_w.extend(W)
        self.hist_f.extend(F)
        sess._est_memo = None
        try:
            sess.yaw_seed.imu_arrays(T, W, F)
            # the outputs due inside the run: the core propagated up to each output's sample, which gets what
            # events_at gives any sample there (no fix, velocity or scheduled update falls due before t_end)
            # (the core's estimates at those samples in one call: core.propagate(..., estimates_at))
            n_in = m - 1 if t >= t_end else m  # the last sample, when an event ends the run: events_at
            ks, k, due = [], 0, sess.next_out_t
            while True:
                k = bisect.bisect_left(Tl, due - 1e-9, i + k, i + n_in) - i
                if k >= n_in:
                    break
                ks.append(k)
                due = Tl[i + k] + cfg.output_period_s  # what events_at sets next_out_t to
                k += 1
            if sess.fusion.zupt_due(math.inf) and self._zupts_in_run(core):
                return self._run_with_updates(core, plan, i, j, ks, n_in, t >= t_end, out)
            k0, q0 = 0, 0
            while q0 < len(ks):
                # a GNSS heading is fused at the first output at or after its stamp (not an end of the run): the
                # estimates are taken up to that output, the rest after its update
                ht = b.heading_t[0] if b.heading_t else math.inf
                q = q0
                while q < len(ks) - 1 and Tl[i + ks[q]] < ht:
                    q += 1
                kc = ks[q]
                if q == q0:  # one output: the core's estimate read by the output itself (no list to build)
                    core.propagate(T[k0:kc + 1], W[k0:kc + 1], F[k0:kc + 1])
                    sess._est_memo = None
                    self.events_at(Tl[i + kc], out)
                    if sess.core is not core:  # a restart at an output: the rest of the run is dropped (as after
                        return j  # a fault)
                    k0, q0 = kc + 1, q + 1
                    continue
                ests = core.propagate(T[k0:kc + 1], W[k0:kc + 1], F[k0:kc + 1],
                                      estimates_at=[k - k0 for k in ks[q0:q + 1]])
                for k, est in zip(ks[q0:q + 1], ests):
                    sess._est_memo = (core, est)
                    self.events_at(Tl[i + k], out)
                    if sess.core is not core:
                        return j
                if not ests:
                    raise RuntimeError(f"{core.name}: propagate(estimates_at) returned no estimate")
                q = q0 + len(ests) - 1  # fewer: the core stopped after its last estimate (auto's hand-over)
                k0, q0 = ks[q] + 1, q + 1
            sess._est_memo = None
            if k0 < m:
                core.propagate(T[k0:], W[k0:], F[k0:])
            if t >= t_end:
                self.events_at(t, out)
        except Exception as exc:  # noqa: BLE001 - a core failure is a fault; the alignment restarts
            sess._fault(exc)
        return j

    def _zupts_in_run(self, core) -> bool:
        """The scheduled zero-velocity updates go into the core with the run's samples (``propagate(...,
        updates)``) instead of ending the run: a core that takes them (``updates_inside_runs``), no GNSS heading
        waiting (fused at an output: the per-output path)."""
        return core.updates_inside_runs and not self.s.buf.heading_t

    def _run_with_updates(self, core, plan: "FastPlan", i: int, j: int, ks: list, n_in: int, ends_at_event: bool,
                          out: list[Output]) -> int:
        """The rest of ``_finish_run`` for a run with its zero-velocity updates inside: the core propagates the run
        with the updates due at its rows and the estimates at its outputs in one call, then the session's side of
        each in row order (the update's schedule, counter and NIS; the output), as one sample at a time would make
        them. A failure in the core ends the run after what it made (a fault); a restart at an output drops the
        rest of the run."""
        sess, Tl = self.s, plan.Tl
        zs = sess.fusion.zupt_rows(Tl, i, i + n_in)
        ups = [(k - i, sess.fusion.zupt_model(Tl[k])) for k in zs]
        res: list = []
        fault = None
        try:
            core.propagate(plan.T[i:j], plan.W[i:j], plan.F[i:j], estimates_at=ks, updates=ups, results=res)
        except Exception as exc:  # noqa: BLE001 - a core failure is a fault; the alignment restarts
            fault = exc
        zset, kset = {k - i for k in zs}, set(ks)
        made = iter(res)
        try:
            for k in sorted(zset | kset):
                if k in zset:
                    r = next(made, None)
                    if r is None:
                        break
                    sess._est_memo = None
                    sess.fusion.zupt_done(Tl[i + k], r)
                if k in kset:
                    est = next(made, None)
                    if est is None:
                        break
                    sess._est_memo = (core, est)
                    self.events_at(Tl[i + k], out)
                    if sess.core is not core:
                        return j
            sess._est_memo = None
            if fault is not None:
                raise fault
            if ends_at_event:
                self.events_at(Tl[j - 1], out)
        except Exception as exc:  # noqa: BLE001
            sess._fault(exc)
        return j

    def _spike(self, t: float, w: np.ndarray, f: np.ndarray, nxt) -> bool:
        """A sample off both of its neighbours by more than the bounds (and 20 x the recent spread): a spike
        (a 30 rad/s glitch is inside the plausibility bound but no vehicle turns like that for 10 ms). Dropped
        and counted; the next sample sees a gap and bridges it."""
        sess = self.s
        cfg = sess.cfg
        if (cfg.imu_spike_rad_s <= 0 and cfg.imu_spike_m_s2 <= 0) or nxt is None or not self.hist_w \
                or self.median_dt is None or sess.processed_t is None:
            return False
        cut = max(3.0 * self.median_dt, self._gap_thr)  # jitter is not a spike's interval either
        if t - sess.processed_t > cut or nxt[0] - t > cut:
            return False
        if self._dt_count % 100 == 1 or self._spread is None:
            self._spread = (float(np.linalg.norm(np.std(np.asarray(self.hist_w), axis=0))),
                            float(np.linalg.norm(np.std(np.asarray(self.hist_f), axis=0))))
        # off BOTH neighbours (the sample before a spike is off only one of them)
        wl, fl = w.tolist(), f.tolist()
        dw = min(dist3(wl, self.hist_w[-1].tolist()), dist3(wl, nxt[1].tolist()))
        df = min(dist3(fl, self.hist_f[-1].tolist()), dist3(fl, nxt[2].tolist()))
        if isinstance(self._spread, LazySpread):  # fell due inside a fast run (_fast_run): computed when it matters
            if not ((cfg.imu_spike_rad_s > 0 and dw > cfg.imu_spike_rad_s)
                    or (cfg.imu_spike_m_s2 > 0 and df > cfg.imu_spike_m_s2)):
                return False  # within the configured bounds: not a spike whatever the spread
            self._spread = self._spread.value()
        bad_w = cfg.imu_spike_rad_s > 0 and dw > max(cfg.imu_spike_rad_s, 20.0 * self._spread[0])
        bad_f = cfg.imu_spike_m_s2 > 0 and df > max(cfg.imu_spike_m_s2, 20.0 * self._spread[1])
        if not (bad_w or bad_f):
            return False
        sess.counters["imu_spikes"] += 1
        sess.last_reject = f"imu: spike at {t + sess.stamp_offset_s:.6f} ({dw:.3g} rad/s, {df:.3g} m/s^2 off its neighbours)"
        sess.log("warn", "imu_spikes", f"IMU spike dropped: {sess.last_reject[5:]} (imu_spikes={sess.counters['imu_spikes']})")
        return True

    def _step(self, t: float, w: np.ndarray, f: np.ndarray, out: list[Output]) -> None:
        sess = self.s
        prev = sess.processed_t
        sess.processed_t = t
        dt = None if prev is None else t - prev
        if dt is not None:
            self._track_period(dt)
        sess.yaw_seed.imu(t, w, f)
        if sess.core is None:
            sess.counters["imu_before_init"] += 1
            sess.initialiser.pre_init.append((t, w, f))
            sess.initialiser.try_initialize(t)
            if sess.core is not None:
                sess.fusion.apply_fixes_until(t, out)  # a fix at the initialisation stamp (not the one used) is fused
                sess.next_out_t = t + sess.cfg.output_period_s
                out.append(sess.outputs.output(t))  # the initial estimate
            return
        gap = dt is not None and self._gap_thr is not None and dt > self._gap_thr
        if gap:
            self._on_gap(prev, t, w, f)
        sess.fusion.propagate(np.array([t]), np.asarray(w, float)[None], np.asarray(f, float)[None])
        sess.counters["imu_processed"] += 1
        self.hist_t.append(t)
        self.hist_w.append(w)
        self.hist_f.append(f)
        self.events_at(t, out)

    def events_at(self, t: float, out: list[Output]) -> None:
        """What falls due at the processed sample ``t``: fixes and GNSS velocities stamped up to it, a zero-velocity
        update, an output."""
        sess = self.s
        sess.fusion.apply_fixes_until(t, out)
        if sess.core is None:  # a divergence restarted the session
            return
        if sess.fusion.zupt_due(t):
            sess.fusion.zupt(t)
        if sess.fusion.nhc_due(t):
            sess.fusion.nhc(t)
        if t >= sess.next_out_t - 1e-9:
            sess.next_out_t = t + sess.cfg.output_period_s
            out.append(sess.outputs.output(t))

    def _track_period(self, dt: float) -> None:
        """Median IMU interval over the last 101 intervals (recomputed every 20): robust to gaps and jitter."""
        self.dts.append(dt)
        self._dt_count += 1
        c = self._dt_count
        if self.median_dt is None or c % 20 == 0 or c <= self.dts.maxlen:
            self.median_dt = median(list(self.dts))
            if c % gaps.MODEL_EVERY == 0 or c <= self.dts.maxlen:
                self._gap_thr = gaps.gap_threshold(self.dts, self.s.cfg.gap_factor, self.median_dt, self._gap_thr)

    def _on_gap(self, t_a: float, t_b: float, w_b: np.ndarray, f_b: np.ndarray) -> None:
        """An IMU gap (t_a, t_b): bridge it and inflate the covariance by what the bridge may have got wrong.

        Bridge (session/gaps.py): samples at the median interval, predicted by the candidate (linear interpolation,
        or a polynomial fitted to the data on both sides of the gap) that makes the smallest error when applied to
        every window of the gap's length in the recent data; the sample after the gap covers its own interval only.
        Inflation: that worst-window error of the attitude increment (integral of the rate) and of the velocity
        increment (integral of the specific force), as a 1-sigma, added to the attitude and velocity variances
        (docs/session.md, "Gaps"). Without enough history: linear, and the rate spread times the missing time."""
        sess = self.s
        sess.counters["imu_gaps"] += 1
        h = self.median_dt
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
            sess.core.inflate_navigation(var_att / len(parts), var_v / len(parts), 0.0)
            sess._est_memo = None
            for k in part[part < n_mid]:
                sess.fusion.propagate(t_mid[k:k + 1], Y_mid[k:k + 1, :3], Y_mid[k:k + 1, 3:])
                sess.fusion.apply_fixes_until(float(t_mid[k]), [])
                if sess.core is None:  # a divergence restarted the session
                    return
        sess.log("warn", "imu_gaps", f"IMU gap of {t_b - t_a:.3f} s before {t_b + sess.stamp_offset_s:.6f} (median "
                                     f"interval {h * 1e3:.2f} ms): bridged with {n_mid} samples, attitude 3-sigma +"
                                     f"{3 * math.sqrt(var_att) / D2R:.3f} deg ({how}; imu_gaps={sess.counters['imu_gaps']})")

    def _lookahead(self, until: float):
        """The IMU samples not processed yet (the rest of the batch being processed, then the buffer), up to the
        stamp ``until`` [s]: data the gap bridge may use after the gap."""
        sess = self.s
        arrs, i = self._batch
        if arrs:
            Tl, W, F = arrs
            for k in range(i + 1, len(Tl)):
                if Tl[k] > until:
                    return
                yield Tl[k], W[k], F[k]
        yield from sess.buf.imu.iter_until(until)


class FastPlan:
    """Arrays of one ``_process`` batch for ``AlignmentSession._fast_run``: stamps, rates, specific forces, the
    intervals, and the samples that could be spikes (off both neighbours by more than the configured bounds)."""

    def __init__(self, session, T: np.ndarray, W: np.ndarray, F: np.ndarray, nxt, Tl: list) -> None:
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
        self.dn_w = np.append(row_norms(np.diff(Wx, axis=0)), math.inf)[:n]
        self.dn_f = np.append(row_norms(np.diff(Fx, axis=0)), math.inf)[:n]
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
        dw = min(dist3(self.W[k].tolist(), np.asarray(w_prev, float).tolist()), float(self.dn_w[k]))
        df = min(dist3(self.F[k].tolist(), np.asarray(f_prev, float).tolist()), float(self.dn_f[k]))
        return bool((self.bound_w > 0 and dw > self.bound_w * (1.0 - 1e-9))
                    or (self.bound_f > 0 and df > self.bound_f * (1.0 - 1e-9)))


class LazySpread:
    """The spike check's spread statistic (rate, specific force) over the history a per-sample run would have
    held when it fell due inside a fast run; computed only if a later spike check needs it."""

    def __init__(self, hist_w: list, hist_f: list, run_w: np.ndarray, run_f: np.ndarray, maxlen: int) -> None:
        self.parts = (hist_w, hist_f, run_w, run_f, maxlen)

    def value(self) -> tuple[float, float]:
        hw, hf, rw, rf, maxlen = self.parts
        W = np.vstack([np.asarray(hw, float).reshape(-1, 3), rw])[-maxlen:]
        F = np.vstack([np.asarray(hf, float).reshape(-1, 3), rf])[-maxlen:]
        return (float(np.linalg.norm(np.std(W, axis=0))), float(np.linalg.norm(np.std(F, axis=0))))


def dist3(a: list, b: list) -> float:
    """|a - b| of two 3-vectors given as lists of floats: ``float(np.linalg.norm(a - b))`` to the last bit or two
    (the same sum; numpy's BLAS dot may fuse or reorder it on some CPUs; test_speed_paths), without numpy's per-call
    overhead."""
    x, y, z = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return math.sqrt(x * x + y * y + z * z)
