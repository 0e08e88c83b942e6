"""Forward-backward ("inverse", backtracking) alignment driver (inverse-alignment paper, Figs. 1-2, sec. 3.4).

The IMU data (and GNSS fixes) of the alignment window are recorded while a core runs forward live. At the end
of the window a *copy* of the core runs backward over the stored window to its start (inverse mechanization and
filter), forward again to the window end, ``passes`` times, then forward through the data that arrived in the
mean time (catch-up); when it reaches the newest sample it replaces the live core (handover). The live core keeps
running and producing output during the passes, so a node never stops publishing.

Works with any core that propagates backward (``supports_backtracking``: ``propagate(t_s, omega, f,
backward=True)``): the Earth-frame IEKF (filters/earth_iekf.py) and the ECI LIEKF through :class:`BacktrackLiekf`
(core name ``liekf_backtrack``).

API (no threads needed), the core's own: ``propagate(t_s, omega, f)`` with arrays of IMU samples and ``update(fix)``
with GNSS fixes (the session, session/fusion.py); ``step_background(budget_s)`` does at most about ``budget_s`` of
pass work and returns (a node timer calls it); ``run_until_done()`` for offline use. ``estimate()`` is always the
live core's.
"""

from __future__ import annotations

import copy
import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.types import GnssFix
from .base import AlignmentCore, UpdateResult
from .eci_batch import covariance_batch, eci_steps
from .liekf import Liekf
from .measurements import GnssPosition


class BacktrackLiekf(Liekf):
    """The ECI LIEKF with backward propagation by time reversal (state ``(C, -v, p)``, rate ``-omega``, error
    ``nu -> -nu``); ECI needs no frame rotation. See docs/backtracking.md."""

    name = "liekf_backtrack"
    supports_backtracking = True

    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        if not backward:
            super()._propagate_arrays(t_s, omega_ib_b, f_ib_b)
            return
        self.flush()
        D = np.ones(self._n_states)
        D[3:6] = -1.0
        DD = np.outer(D, D)
        mb = self.cfg.max_batch_samples
        for i in range(0, len(t_s), mb):
            t = np.asarray(t_s[i:i + mb], float)
            w = np.asarray(omega_ib_b[i:i + mb], float) - self.b_g
            f = np.asarray(f_ib_b[i:i + mb], float) - self.b_a
            dt = -np.diff(t, prepend=self.t_s)
            dC, dv_b, dp_b, C_prev, C, v, p = eci_steps(self.C, -self.v, self.p, -w, f, dt)
            Phi, Qd = self._transitions(dC, dv_b, dp_b, dt, C_prev, f)
            Pr, _ = covariance_batch(self.P * DD, Phi, Qd)
            self.P = Pr * DD
            self.C, self.v, self.p = Rotation.from_matrix(C).as_matrix(), -v, p
            self.t_s = float(t[-1])
        self._Phi_since_update = np.eye(self._n_states)


def make_backtrackable(core: AlignmentCore) -> AlignmentCore:
    """Return ``core`` itself when it supports backtracking (ValueError otherwise: build ``liekf_backtrack`` for a
    LIEKF, as the session does through session/catalog.py)."""
    if core.supports_backtracking:
        return core
    raise ValueError(f"core {core.name!r} does not support backtracking "
                     "(needs backward propagation); use earth_iekf or liekf_backtrack")


def _propagate(core, t, w, f, backward: bool) -> None:
    """One chunk of a pass, flushed: its batches start and end with the chunk."""
    if len(t) == 0:
        return
    core.propagate(t, w, f, backward=backward)
    core.flush()


class BacktrackingAligner:
    """Records the live stream, runs backtracking passes on a copy of the core, hands over when caught up.

    ``window_s``: length of the stored alignment window [s] after the initialisation stamp; ``passes``: number of
    backward+forward passes (0 = forward only). ``chunk_samples`` bounds the work between budget checks.
    """

    def __init__(self, core: AlignmentCore, init_stamp_s: float, window_s: float, passes: int = 1,
                 chunk_samples: int = 200, covariance: str = "reset"):
        if passes < 0 or not window_s > 0:
            raise ValueError(f"passes must be >= 0 and window_s > 0 (got {passes}, {window_s})")
        if covariance not in ("reset", "reuse"):
            raise ValueError(f"covariance must be 'reset' or 'reuse', got {covariance!r}")
        #: "reset": the last forward pass over the window starts from the initial covariance (state kept), so every
        #: measurement is counted once and the handed-over covariance is the forward-only one (docs/backtracking.md);
        #: "reuse": the covariance after the backward pass (the paper's scheme; counts the data twice: optimistic)
        self.covariance = covariance
        self._P0 = np.array(core.P, float, copy=True) if core.P is not None else None
        if passes > 0:
            make_backtrackable(core)
        self.live = core
        #: samples at or before the initialisation stamp (they cover intervals before the initial state) and fixes
        #: before it are skipped, counted
        self.counters = {"imu_skipped_before_init": 0, "gnss_skipped_stale": 0}
        self.init_stamp_s = float(init_stamp_s)
        self.window_s = float(window_s)
        self.passes = int(passes)
        self.chunk = int(chunk_samples)
        self._t: list[float] = []
        self._w: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._fixes: list[GnssFix] = []
        self.state = "recording" if passes > 0 else "done"
        self._gen = None
        self.worker = None
        self.stats = {"pass_wall_s": 0.0, "handover_stamp_s": float("nan"), "window_samples": 0,
                      "caught_up_samples": 0, "steps": 0}

    # ------------------------------------------------------------------ live side
    def propagate(self, t_s, omega_ib_b, f_ib_b) -> None:
        """IMU samples (arrays, as ``AlignmentCore.propagate``) to the live core, recorded for the passes; the
        passes start after the sample that ends the window."""
        t = np.asarray(t_s, float)
        w = np.asarray(omega_ib_b, float)
        f = np.asarray(f_ib_b, float)
        after = t > self.init_stamp_s
        if not after.all():
            self.counters["imu_skipped_before_init"] += int(np.count_nonzero(~after))
            t, w, f = t[after], w[after], f[after]
        if self.state == "recording":  # the live core up to the sample that ends the window, then the passes start
            ends = np.nonzero(t - self.init_stamp_s >= self.window_s - 1e-9)[0]
            if ends.size:
                k = int(ends[0])
                self._live(t[:k + 1], w[:k + 1], f[:k + 1])
                self._start()
                t, w, f = t[k + 1:], w[k + 1:], f[k + 1:]
        self._live(t, w, f)

    def _live(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> None:
        if t.shape[0] == 0:
            return
        self.live.propagate(t, w, f)
        if self.state == "done":
            return
        keep = t > (self._t[-1] if self._t else -np.inf)  # stamps after the last recorded one
        self._t.extend(t[keep].tolist())
        self._w.extend(w[keep])
        self._f.extend(f[keep])

    def update(self, fix) -> UpdateResult | None:
        """A GNSS fix (a measurement model) to the live core, recorded for the passes; None for a fix before the
        initialisation stamp (skipped, counted)."""
        if fix.stamp_s < self.init_stamp_s:
            self.counters["gnss_skipped_stale"] += 1
            return None
        res = self.live.update(fix)
        if self.state != "done" and isinstance(fix, GnssFix):
            self._fixes.append(fix)
        return res

    def estimate(self):
        return self.live.estimate()

    @property
    def busy(self) -> bool:
        return self.state == "passes"

    def _start(self) -> None:
        self.live_flush()
        self.worker = copy.deepcopy(self.live)
        self.n_window = len(self._t)
        self.stats["window_samples"] = self.n_window
        self._gen = self._passes()
        self.state = "passes"

    def live_flush(self) -> None:
        self.live.flush()

    # ------------------------------------------------------------------ background work
    def _fix_times(self):
        return np.array([fx.stamp_s for fx in self._fixes]) if self._fixes else np.zeros(0)

    def _passes(self):
        core = self.worker
        n = self.n_window
        t_all = np.asarray(self._t[:n])
        w_all = np.asarray(self._w[:n])
        f_all = np.asarray(self._f[:n])
        t_prev = np.concatenate([[self.init_stamp_s], t_all[:-1]])
        t_end = t_all[-1]
        for _ in range(self.passes):
            # backward: sample k (covering (t_prev[k], t_all[k]]) takes the core from t_all[k] to t_prev[k]
            fix_t = self._fix_times()
            k = n
            while k > 0:
                k0 = max(0, k - self.chunk)
                # stop at the latest GNSS fix stamp inside (t_prev[k0], t_all[k-1]) (not at the window end)
                sel = np.nonzero((fix_t < t_all[k - 1] - 1e-9) & (fix_t >= t_prev[k0] - 1e-9))[0]
                if sel.size:
                    j = int(np.searchsorted(t_prev, fix_t[sel[-1]] - 1e-9, side="left"))
                    k0 = max(k0, j)
                idx = slice(k - 1, k0 - 1 if k0 > 0 else None, -1)
                _propagate(core, t_prev[idx], w_all[idx], f_all[idx], backward=True)
                t_now = t_prev[k0]
                for fx in self._fixes:
                    if abs(fx.stamp_s - t_now) < 1e-6 and fx.stamp_s < t_end - 1e-9:
                        core.update(GnssPosition.of(fx))
                k = k0
                yield
            # forward over the window
            if self.covariance == "reset" and self._P0 is not None and _ == self.passes - 1:
                core.P = self._P0.copy()
            yield from self._forward(core, 0, n)
        # catch-up with everything recorded since (the list grows while we run)
        i = n
        while True:
            m = len(self._t)
            if i >= m:
                return
            yield from self._forward(core, i, m)
            self.stats["caught_up_samples"] += m - i
            i = m

    def _forward(self, core, i0, i1):
        fix_t = self._fix_times()
        t_all = np.asarray(self._t[i0:i1])
        w_all = np.asarray(self._w[i0:i1])
        f_all = np.asarray(self._f[i0:i1])
        i = 0
        n = len(t_all)
        while i < n:
            j = min(n, i + self.chunk)
            sel = np.nonzero((fix_t >= t_all[i] - 1e-9) & (fix_t <= t_all[j - 1] + 1e-9))[0]
            if sel.size:
                j = int(np.searchsorted(t_all, fix_t[sel[0]] - 1e-9, side="left")) + 1
            _propagate(core, t_all[i:j], w_all[i:j], f_all[i:j], backward=False)
            for fx in self._fixes:
                if abs(fx.stamp_s - t_all[j - 1]) < 1e-6:
                    core.update(GnssPosition.of(fx))
            i = j
            yield

    def step_background(self, budget_s: float = 0.02) -> bool:
        """Do pass work for about ``budget_s`` of wall time (one chunk at least); hand over when caught up.

        Returns True while more work remains. Call from the same thread as :meth:`propagate` (e.g. a node timer):
        the handover then happens between two events, with no lock.
        """
        if self.state != "passes":
            return False
        t0 = time.perf_counter()
        while True:
            try:
                next(self._gen)
                self.stats["steps"] += 1
            except StopIteration:
                self._handover()
                self.stats["pass_wall_s"] += time.perf_counter() - t0
                return False
            if time.perf_counter() - t0 >= budget_s:
                self.stats["pass_wall_s"] += time.perf_counter() - t0
                return True

    def _handover(self) -> None:
        self.live = self.worker
        self.worker = None
        self._gen = None
        self.state = "done"
        self.stats["handover_stamp_s"] = self._t[-1] if self._t else float("nan")
        self._t, self._w, self._f, self._fixes = [], [], [], []

    def run_until_done(self) -> None:
        while self.step_background(math.inf):
            pass
