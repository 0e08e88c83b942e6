"""PI-LIEKF (PI-LIEKF paper Alg. 2, eqs. (16)-(33)): the LIEKF with a proportional-integral innovation.

Per GNSS update k (our sign convention: :mod:`.liekf`):

* ``Z_p = X_hat^-1 Y - d`` restricted to the position block, ``= C^T (p_gps_i - p_hat)`` (eqs. (16), (29); the
  error-state prediction is zero after the reset of eq. (33));
* ``Z_PI = k_P Z_p + Z_I_{k-1}``, ``Z_I_k = Z_I_{k-1} + k_I T_s Z_p`` (eq. (29)); ``xi_hat = L_k Z_PI``
  (eq. (30)); covariance by eq. (31) in Joseph form with the gain the correction applies, L k_P (valid for
  any gain; the paper's L under-states P when k_P > I; the integral term is not in P);
* gains ``k_P, k_I`` from the LMI (:mod:`.lmi`; the one-interval LMI of eq. (22) is never feasible on the INS,
  docs/inmotion_cores.md): eq. (20) as an analysis LMI (J variable) on the exact closed loop of eq. (18) over
  windows of ``lmi_window_updates`` intervals; the first certified candidate of ``lmi_candidates`` is used.
  Safe gains (k_P = I, k_I = ``safe_k_I_per_s``) until the first solve and whenever it fails, with the reason.
  Re-solved every ``lmi_resolve_every_updates`` updates (or once, after convergence) and cached in between.
* Every solve runs in one worker thread per core (a daemon thread, at most one job waiting) under a wall-time
  budget ``lmi_time_budget_s``: synchronously (offline default) the update waits at most the budget; with
  ``lmi_async`` it never waits and the gains are swapped in at the first update after the solve finished. A solve
  that has not returned within the budget gives the safe gains with the reason and is counted; its late result is
  discarded, so it can never overwrite newer gains.
* ``Z_I`` is clamped per axis at ``integral_clamp_m`` (anti-windup while a large initial attitude error makes the
  innovations meaningless as a bias signal).
* **The NIS it reports is the plain LIEKF's** (issue 15): the PI loop pulls the position onto the fixes beyond the
  Kalman correction (k_P > I, the integral), so its own innovation stays small while the attitude is lost (a 60-deg
  yaw kick on the car: NIS 6-11 while the open-loop error grows to 49 m). The core carries the first-order offset
  ``d`` (left-invariant, X_plain = X_hat exp(d)) to the LIEKF that would have made the plain correction L z from the
  same data and covariance: between updates ``d <- Phi d``; at an update the plain innovation is ``z - H d`` and
  ``d <- d + L (z - H d) - L Z_PI``. ``predict`` and ``update`` of a position report the NIS of ``z - H d`` (with the
  same S): what the session's gate, CUSUM and flag test (docs/session.md "PI-LIEKF"). The estimate is unchanged.

``diagnostics()`` returns the latest LMI status, reason, solver time, whether the safe gains are in use, and the
counters ``lmi_budget_misses`` and ``lmi_fallbacks``.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from collections import deque

import numpy as np

from .base import UpdateResult
from .config import PiLiekfConfig
from ..core.lie import hat3
from .kalman import nis
from .liekf import Liekf

_I3 = np.eye(3)


class _Job:
    """One LMI solve handed to the worker: ``fn(job)``'s result or exception, and when it was submitted, started
    and finished (``time.perf_counter()`` [s]; None until then). ``cancelled``: replaced or dropped before it ran."""

    def __init__(self, fn):
        self.fn = fn
        self.submitted_s = time.perf_counter()
        self.started_s = self.finished_s = None
        self.result = self.error = None
        self.cancelled = False
        self._done = threading.Event()

    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout_s: float | None) -> bool:
        return self._done.wait(timeout_s)

    def _finish(self) -> None:
        self.finished_s = time.perf_counter()
        self._done.set()


class _SolveWorker:
    """One daemon thread that runs jobs one at a time and holds at most one waiting job: a newer submit replaces
    the waiting one, which then never runs. The thread starts with the first job and ends after ``IDLE_EXIT_S``
    without work (the next submit starts another), so a core that is dropped without close() keeps no thread.
    Daemon, so a solve that overruns never blocks the interpreter's exit."""

    IDLE_EXIT_S = 2.0

    def __init__(self):
        self._cv = threading.Condition()
        self._waiting: _Job | None = None
        self._running: _Job | None = None
        self._closed = False
        self._thread: threading.Thread | None = None

    def submit(self, fn) -> _Job:
        job = _Job(fn)
        with self._cv:
            self._drop_waiting()
            self._waiting = job
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="pi_liekf_lmi", daemon=True)
                self._thread.start()
            self._cv.notify()
        return job

    def cancel(self, job: _Job) -> None:
        """Drop ``job`` if it has not started (a running solve cannot be interrupted: its result is ignored)."""
        with self._cv:
            if self._waiting is job:
                self._drop_waiting()

    def _drop_waiting(self) -> None:
        if self._waiting is not None:
            self._waiting.cancelled = True
            self._waiting._finish()
            self._waiting = None

    def _loop(self) -> None:
        while True:
            with self._cv:
                if self._waiting is None and not self._closed:
                    self._cv.wait(self.IDLE_EXIT_S)
                if self._closed or self._waiting is None:  # closed, or idle: end (a submit starts a new thread)
                    if self._thread is threading.current_thread():
                        self._thread = None
                    return
                job, self._waiting = self._waiting, None
                self._running = job
            job.started_s = time.perf_counter()
            try:
                job.result = job.fn(job)
            except Exception as exc:  # noqa: BLE001 - reported to the core, which falls back with the reason
                job.error = exc
            with self._cv:
                self._running = None
            job._finish()

    def close(self) -> None:
        """Idempotent, never blocks on a running solve: the thread ends when that solve returns."""
        with self._cv:
            self._closed = True
            self._drop_waiting()
            thread, idle = self._thread, self._running is None
            self._cv.notify()
        if idle and thread is not None and thread is not threading.current_thread():
            thread.join(1.0)  # it only has to see the flag


class PiLiekf(Liekf):
    """Proportional-integral LIEKF (9 states) with LMI gains.

    ``gain_solver_factory`` (benchmarks and tests only; None = the certifier of the config): ``factory(cfg)`` returns
    an object with ``history_needed`` [GNSS intervals] and ``solve(WindowData, deadline_s) -> LmiResult``, e.g. the
    research formulations of :mod:`.lmi` (``benchmarks/lmi_formulations.py``).
    """

    name = "pi_liekf"
    config_class = PiLiekfConfig

    def __init__(self, config=None, gain_solver_factory=None):
        super().__init__(config)
        self._factory = gain_solver_factory
        self._solver = None
        self._executor: _SolveWorker | None = None  # the LMI worker, created at the first need
        self._finalizer = None
        self._pending: _Job | None = None  # an asynchronous solve not applied yet
        self.lmi = None
        self.lmi_history: list = []  # (t_s when the gains were applied, LmiResult)
        self._reset_counters()

    def _reset_counters(self) -> None:
        self.lmi_submitted = 0
        self.lmi_budget_misses = 0  # solves that had not returned within lmi_time_budget_s
        self.lmi_fallbacks = 0  # solves that ended with the safe gains (any reason, misses included)
        self.lmi_solve_time_max_s = 0.0  # longest single solve (wall time; a miss counts the time waited)

    def _ensure_executor(self) -> _SolveWorker:
        if self._executor is None:
            self._executor = _SolveWorker()
            # a core dropped without close() (e.g. a deep copy of the backtracking aligner) frees its thread
            self._finalizer = weakref.finalize(self, self._executor.close)
        return self._executor

    def __getstate__(self):
        # copy.deepcopy (the backtracking aligner copies the live core): threads, jobs and the cvxpy problem are
        # not copied; the copy builds its own. A solve still running for the original is not inherited.
        st = self.__dict__.copy()
        st.update(_executor=None, _pending=None, _solver=None, _finalizer=None)
        return st

    @property
    def lmi_async(self) -> bool:
        return self.cfg.lmi_async == "true"

    def initialize(self, *args, **kwargs) -> None:
        super().initialize(*args, **kwargs)
        self.Z_I = np.zeros(3)
        self._d = np.zeros(9)  # offset to the plain LIEKF (module docstring), left-invariant [phi, nu, rho]
        self._pi_gain = None  # (z_plain, N, L (k_P - I)) of the update in progress
        self._H_pos = None  # predict: a fix's H (built at the first prediction)
        self.k_P = np.eye(3)
        self._k_P_excess = None
        self.k_I = self.cfg.safe_k_I_per_s * np.eye(3)
        self._n_updates = 0
        self._window: deque = deque(maxlen=self._history_needed())
        self._pending = None  # a solve of the previous run is not applied to this one
        self._frozen = False  # schedule "once": gains fixed after the first successful solve
        self._once_first = None
        self.lmi = None
        self.lmi_history = []
        self._reset_counters()
        if self.lmi_async and self._solver is None:  # the cvxpy import and problem build (~1 s) run in the worker
            self._ensure_executor().submit(lambda job: self._gain_solver())  # now, not at the first solve

    # ------------------------------------------------------------------ LMI
    def _gain_solver(self):
        if self._solver is None:
            from . import lmi

            c = self.cfg
            if self._factory is not None:
                self._solver = self._factory(c)
            else:
                W = c.lmi_window_updates
                self._solver = lmi.WindowGainCertifier(9, 3, c.rho, W, 3, max(1, W // 3),
                                                       lmi.parse_candidates(c.lmi_candidates), c.lmi_solver,
                                                       c.lmi_eps, c.safe_k_I_per_s)
        return self._solver

    def _history_needed(self) -> int:
        if self._factory is not None:
            return self._gain_solver().history_needed
        from .lmi import WindowGainCertifier

        W = self.cfg.lmi_window_updates
        return WindowGainCertifier.history_for(W, 3, max(1, W // 3))

    def _solve_due(self) -> bool:
        if self._frozen or self._pending is not None:
            return False
        c = self.cfg
        if len(self._window) < self._history_needed():
            return False
        if c.lmi_schedule == "once":
            sig_yaw3 = 3.0 * math.degrees(math.sqrt(max(self._yaw_var_n(), 0.0)))
            if sig_yaw3 >= c.lmi_once_yaw_3sigma_deg:
                return False
            # the first converged update, then (while the solve falls back) every lmi_resolve_every_updates
            if self._once_first is None:
                self._once_first = self._n_updates
            return (self._n_updates - self._once_first) % c.lmi_resolve_every_updates == 0
        return self._n_updates % c.lmi_resolve_every_updates == 0

    def _yaw_var_n(self) -> float:
        # vertical component of the body-frame attitude covariance: psi_n = C_b_n phi (docs/inmotion_cores.md)
        from ..core.mechanization import NavStateEci, navigation_from_state_eci

        P_att_n = navigation_from_state_eci(NavStateEci(self.t_s, self.C, self.v, self.p), self.t0_s,
                                            self.P[0:3, 0:3], self._att_error_inertial)[5]
        return float(P_att_n[2, 2])

    def _solve_job(self, H):
        """``fn(job)`` that solves on a snapshot (copies) of the window: safe to run in the worker thread. The
        deadline counts from the submission when the update waits for it, from the start in the worker when not."""
        from .lmi import WindowData

        w = WindowData(np.array([x[0] for x in self._window]), np.array([x[1] for x in self._window]),
                       np.array([x[2] for x in self._window]), H.copy(), self._window[0][3].copy())
        budget, from_submit = self.cfg.lmi_time_budget_s, not self.lmi_async
        # the solver (cvxpy import and problem build, ~1 s the first time) is built inside the job: in the worker
        return lambda job: self._gain_solver().solve(
            w, deadline_s=(job.submitted_s if from_submit else job.started_s) + budget)

    def _safe_result(self, status: str, reason: str, **kw):
        from .lmi import LmiResult

        return LmiResult(status, np.eye(3), self.cfg.safe_k_I_per_s * np.eye(3), True, reason + ": safe gains", **kw)

    def _result_of(self, job: _Job):
        """The job's LmiResult; a solve that raised (bad window data, solver crash) gives the safe gains + reason."""
        if job.cancelled:  # close() from another thread while the update waited
            return self._safe_result("cancelled", "LMI solve dropped before it ran (the core was closed)")
        if job.error is not None:
            exc = job.error
            return self._safe_result(f"error: {type(exc).__name__}", f"LMI solve raised {type(exc).__name__}: {exc}",
                                     solve_time_s=job.finished_s - job.started_s)
        return job.result

    def _miss(self, waited_s: float):
        from .lmi import BUDGET_STATUS

        return self._safe_result(BUDGET_STATUS, f"LMI solve had not returned after {waited_s:.2f} s > "
                                 f"lmi_time_budget_s = {self.cfg.lmi_time_budget_s:g} s (its late result is discarded)",
                                 solve_time_s=waited_s, budget_miss=True)

    def _apply(self, res) -> None:
        self.lmi = res
        self.k_P, self.k_I = res.k_P, res.k_I
        dk = np.asarray(res.k_P, float) - _I3
        self._k_P_excess = dk if dk.any() else None  # k_P - I: the correction's gain beyond Kalman's
        self.lmi_history.append((self.t_s, res))
        self.lmi_budget_misses += int(res.budget_miss)
        self.lmi_fallbacks += int(res.used_fallback)
        self.lmi_solve_time_max_s = max(self.lmi_solve_time_max_s, res.solve_time_s)
        if self.cfg.lmi_schedule == "once" and not res.used_fallback:
            self._frozen = True

    def _submit(self, H) -> None:
        job_fn = self._solve_job(H)
        self.lmi_submitted += 1
        if self.lmi_async:
            self._pending = self._ensure_executor().submit(job_fn)
            return
        if self._solver is None:  # a one-off build (cvxpy import) is not part of the solve's budget
            try:
                self._gain_solver()
            except Exception:  # noqa: BLE001 - the job raises it again and falls back with the reason
                pass
        worker = self._ensure_executor()
        job = worker.submit(job_fn)
        if job.wait(self.cfg.lmi_time_budget_s):
            self._apply(self._result_of(job))
        else:
            worker.cancel(job)  # still waiting behind an overrun solve: never runs
            self._apply(self._miss(time.perf_counter() - job.submitted_s))

    def _poll(self) -> None:
        """Apply a finished asynchronous solve, or the safe gains once it has run longer than the budget."""
        job = self._pending
        if job is None:
            return
        budget = self.cfg.lmi_time_budget_s
        if job.done():
            self._pending = None
            if job.cancelled:
                return
            wall = job.finished_s - job.started_s
            self._apply(self._miss(wall) if wall > budget else self._result_of(job))
        elif job.started_s is not None and time.perf_counter() - job.started_s > budget:
            self._pending = None
            self._apply(self._miss(time.perf_counter() - job.started_s))

    def _correction(self, meas, z, L, H, N):
        self._pi_gain = None
        if not meas.is_position:  # GNSS velocity, ...: a plain Kalman correction (the PI loop is on positions)
            return L @ z
        Ts = self.t_s - self._t_last_update
        if Ts <= 0.0:  # a fix at the initialisation time: no interval, plain Kalman correction
            return L @ z
        self._window.append((self._Phi_since_update.copy(), L.copy(), Ts, self._P_prior.copy()))
        self._poll()
        if self._solve_due():
            self._submit(H)
        self._n_updates += 1
        d = self._Phi_since_update @ self._d
        z_plain = z - H @ d
        Z_PI = self.k_P @ z + self.Z_I
        self._d = d + L @ (z_plain - Z_PI)
        dk = self._k_P_excess
        # (z_plain, N, L (k_P - I) or None): _after_update finishes the NIS and the covariance with the S it returns
        self._pi_gain = (z_plain, N, None if dk is None else L @ dk)
        self.Z_I = self.Z_I + self.k_I @ z * Ts
        c = self.cfg.integral_clamp_m
        if c > 0:
            self.Z_I = np.clip(self.Z_I, -c, c)
        return L @ Z_PI

    def _after_prediction(self, meas, res: UpdateResult) -> UpdateResult:
        """A position's prediction reports the NIS of the plain LIEKF's innovation ``z - H Phi d``."""
        if meas.is_position:
            if self._H_pos is None:  # the lever arm is fixed: built once
                self._H_pos = np.zeros((3, self._n_states))
                self._H_pos[:, 0:3] = -hat3(self.lever_b)
                self._H_pos[:, 6:9] = np.eye(3)
            res.nis = nis(res.S, res.innovation - self._H_pos @ (self._Phi_since_update @ self._d))  # a fresh result
        return res

    def _after_update(self, meas, res: UpdateResult) -> UpdateResult:
        """The update of :class:`Liekf` with the PI correction, reporting the plain LIEKF's NIS (module docstring)."""
        res = super()._after_update(meas, res)
        pi, self._pi_gain = self._pi_gain, None
        if pi is None:
            return res
        z_plain, N, G = pi
        if G is not None:
            # Joseph form with the gain the correction applied, K = L k_P: for any gain P(K) = P(L) + (K - L) S
            # (K - L)^T, L the Kalman gain (P(L): the core's update), K - L = L (k_P - I)
            M = G @ res.S @ G.T
            self.P = self.P + 0.5 * (M + M.T)
        # the NIS with S before the fading step (which scales the 9-state prior by last_fading_factor), as the LIEKF's
        lam = self.last_fading_factor
        res.nis = nis(res.S if lam == 1.0 else (res.S - N) / lam + N, z_plain)  # the core's own result object
        return res

    @property
    def busy(self) -> bool:
        """True while an asynchronous solve is pending (not applied yet, nor declared a budget miss)."""
        return self._pending is not None

    def wait_for_pending_solve(self, timeout_s: float | None = None) -> bool:
        """Wait up to ``timeout_s`` for an asynchronous solve and apply it, or its budget miss (tests, shutdown).
        True if none is left."""
        if self._pending is not None:
            self._pending.wait(timeout_s)
            self._poll()
        return self._pending is None

    def close(self) -> None:
        """Stop the LMI worker thread. Idempotent and safe at any time (before initialize, during a solve, twice):
        a running solve is abandoned (its result discarded). The core stays usable: a later solve starts a new
        worker."""
        worker, self._executor, self._pending = self._executor, None, None
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        if worker is not None:
            worker.close()

    def diagnostics(self) -> dict:
        d = {"Z_I_m": self.Z_I.tolist() if self._init else None, "lmi_async": self.lmi_async,
             "lmi_solve_pending": self._init and self._pending is not None,
             "lmi_time_budget_s": self.cfg.lmi_time_budget_s, "lmi_solves": len(self.lmi_history),
             "lmi_budget_misses": self.lmi_budget_misses, "lmi_fallbacks": self.lmi_fallbacks,
             "lmi_solve_time_max_s": self.lmi_solve_time_max_s}
        if self.lmi is None:
            d["lmi_reason"] = ("no LMI solved yet (waiting for a full window of GNSS updates): safe gains"
                               if self._init else "not initialised")
        else:
            r = self.lmi
            d.update(lmi_status=r.status, lmi_used_fallback=r.used_fallback, lmi_reason=r.reason,
                     lmi_residual_eq23=r.residual_eq23, lmi_max_eig=r.lmi_max_eig,
                     lmi_rate_margin_structured=r.rate_margin_structured,
                     lmi_spectral_radius_structured=r.spectral_radius_structured, lmi_solver=r.solver,
                     lmi_solve_time_s=r.solve_time_s, k_P=r.k_P.tolist(), k_I=r.k_I.tolist())
        return d
