"""PI-LIEKF (PI-LIEKF paper Alg. 2, eqs. (16)-(33)): the LIEKF with a proportional-integral innovation.

Per GNSS update k (our sign convention: :mod:`.liekf`):

* ``Z_p = X_hat^-1 Y - d`` restricted to the position block, ``= C^T (p_gps_i - p_hat)`` (eqs. (16), (29); the
  error-state prediction is zero after the reset of eq. (33));
* ``Z_PI = k_P Z_p + Z_I_{k-1}``, ``Z_I_k = Z_I_{k-1} + k_I T_s Z_p`` (eq. (29)); ``xi_hat = L_k Z_PI``
  (eq. (30)); covariance by eq. (31) (Joseph, unchanged: the covariance does not know about the PI loop);
* gains ``k_P, k_I`` from the LMI (:mod:`.lmi`; the one-interval LMI of eq. (22) is never feasible on the INS,
  docs/inmotion_cores.md). Default formulation "certify": eq. (20) as an analysis LMI (J variable) on the exact
  closed loop of eq. (18) over windows of ``lmi_window_updates`` intervals; the first certified candidate of
  ``lmi_candidates`` is used. "window": synthesis of k_I on the lifted window with the integral state held.
  Safe gains (k_P = I, k_I = ``safe_k_I_per_s``) until the first solve and whenever it fails, with the reason.
  Re-solved every ``lmi_resolve_every_updates`` updates (or once, after convergence) and cached in between; with ``lmi_async`` the solve runs in a worker thread on a snapshot of the window and
  the gains are swapped in at the first update after it finished, so an update never waits for cvxpy.
* ``Z_I`` is clamped per axis at ``integral_clamp_m`` (anti-windup while a large initial attitude error makes the
  innovations meaningless as a bias signal).

``diagnostics()`` returns the latest LMI status, residual, solver time and whether the safe gains are in use.
"""

from __future__ import annotations

import math
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np

from .config import PiLiekfConfig
from .liekf import Liekf


class PiLiekf(Liekf):
    """Proportional-integral LIEKF (9 states) with LMI gains."""

    name = "pi_liekf"
    config_class = PiLiekfConfig

    def __init__(self, config=None):
        super().__init__(config)
        self._solver = None
        self._executor = None
        self.lmi = None
        self.lmi_history: list = []  # (t_s when the gains were applied, LmiResult)

    def _ensure_executor(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pi_liekf_lmi")
        return self._executor

    def __getstate__(self):
        # copy.deepcopy (the backtracking aligner copies the live core): threads, futures and the cvxpy problem are
        # not copied; the copy builds its own. A solve still running for the original is not inherited.
        st = self.__dict__.copy()
        st.update(_executor=None, _pending=None, _solver=None)
        return st

    @property
    def lmi_async(self) -> bool:
        return self.cfg.lmi_async == "true"

    def initialize(self, *args, **kwargs) -> None:
        super().initialize(*args, **kwargs)
        self.Z_I = np.zeros(3)
        self.k_P = np.eye(3)
        self.k_I = self.cfg.safe_k_I_per_s * np.eye(3)
        self._n_updates = 0
        self._window: deque = deque(maxlen=self._history_needed())
        self._pending = None  # Future of an asynchronous solve
        self._frozen = False  # schedule "once": gains fixed after the first successful solve
        self._once_first = None
        if self.lmi_async:  # created here, not in the update path; the cvxpy import and problem build (~1 s)
            self._ensure_executor().submit(self._gain_solver)  # run in the worker now, not at the first solve
        self.lmi_submitted = 0

    # ------------------------------------------------------------------ LMI
    def _gain_solver(self):
        if self._solver is None:
            from . import lmi

            c = self.cfg
            if c.lmi_formulation == "certify":
                self._solver = lmi.WindowGainCertifier(9, 3, c.rho, c.lmi_window_updates, 3,
                                                       max(1, c.lmi_window_updates // 3),
                                                       lmi.parse_candidates(c.lmi_candidates), c.lmi_solver,
                                                       c.lmi_eps, c.safe_k_I_per_s)
            elif c.lmi_formulation == "window":
                self._solver = lmi.WindowPiGainSolver(9, 3, c.rho, c.lmi_window_updates, c.lmi_solver, c.lmi_eps,
                                                      c.safe_k_I_per_s, c.lmi_structure, c.lmi_objective)
            else:
                cls = lmi.StructuredPiGainSolver if c.lmi_structure == "structured" else lmi.PiGainSolver
                self._solver = cls(9, 3, c.rho, c.lmi_solver, c.lmi_eps, c.safe_k_I_per_s)
        return self._solver

    def _history_needed(self) -> int:
        W = self.cfg.lmi_window_updates
        return W + 2 * max(1, W // 3) if self.cfg.lmi_formulation == "certify" else W

    def _solve_due(self) -> bool:
        if self._frozen or self._pending is not None:
            return False
        c = self.cfg
        if c.lmi_formulation != "interval" and len(self._window) < self._history_needed():
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
        from ..core.mechanization import NavStateEci, geodetic_from_state_eci

        *_, C_b_n, _ = geodetic_from_state_eci(NavStateEci(self.t_s, self.C, self.v, self.p), self.t0_s)
        return float((C_b_n @ self.P[0:3, 0:3] @ C_b_n.T)[2, 2])

    def _solve_job(self, A, H, L, Ts):
        """A callable that solves on a snapshot (copies): safe to run in a worker thread."""
        # the solver (cvxpy import and problem build, ~1 s the first time) is built inside the job: in the worker
        if self.cfg.lmi_formulation != "interval":
            from .lmi import WindowData

            w = WindowData(np.array([x[0] for x in self._window]), np.array([x[1] for x in self._window]),
                           np.array([x[2] for x in self._window]), H.copy(), self._window[0][3].copy())
            return lambda: self._gain_solver().solve(w)
        P = self._P_prior.copy()
        A, L = A.copy(), L.copy()
        return lambda: self._gain_solver().solve(A, H, L, Ts, P)

    def _apply(self, res) -> None:
        self.lmi = res
        self.k_P, self.k_I = res.k_P, res.k_I
        self.lmi_history.append((self.t_s, res))
        if self.cfg.lmi_schedule == "once" and not res.used_fallback:
            self._frozen = True

    def _run_guarded(self, job):
        """A solve that raises (bad window data, solver crash) must not take the filter down: safe gains + reason."""
        try:
            return job()
        except Exception as exc:  # noqa: BLE001 - any failure of the gain design falls back
            from .lmi import LmiResult

            c = self.cfg
            return LmiResult(f"error: {type(exc).__name__}", np.eye(3), c.safe_k_I_per_s * np.eye(3), True,
                             f"LMI solve raised {type(exc).__name__}: {exc}: safe gains")

    def _poll(self) -> None:
        if self._pending is not None and self._pending.done():
            fut, self._pending = self._pending, None
            self._apply(fut.result())

    def _correction(self, z, L, H, N):
        Ts = self.t_s - self._t_last_update
        if Ts <= 0.0:  # a fix at the initialisation time: no interval, plain Kalman correction
            return L @ z
        self._window.append((self._Phi_since_update.copy(), L.copy(), Ts, self._P_prior.copy()))
        self._poll()
        if self._solve_due():
            job = self._solve_job(self._Phi_since_update, H, L, Ts)
            self.lmi_submitted += 1
            if self.lmi_async:
                self._pending = self._ensure_executor().submit(self._run_guarded, job)
            else:
                self._apply(self._run_guarded(job))
        self._n_updates += 1
        Z_PI = self.k_P @ z + self.Z_I
        self.Z_I = self.Z_I + self.k_I @ z * Ts
        c = self.cfg.integral_clamp_m
        if c > 0:
            self.Z_I = np.clip(self.Z_I, -c, c)
        return L @ Z_PI

    def wait_for_pending_solve(self, timeout_s: float | None = None) -> bool:
        """Block until an asynchronous solve has finished and apply it (tests, shutdown). True if none is left."""
        if self._pending is None:
            return True
        try:
            self._pending.result(timeout=timeout_s)
        except FutureTimeout:
            return False
        self._poll()
        return True

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def diagnostics(self) -> dict:
        d = {"Z_I_m": self.Z_I.tolist() if self._init else None,
             "lmi_formulation": self.cfg.lmi_formulation, "lmi_async": self.lmi_async,
             "lmi_solve_pending": self._init and self._pending is not None}
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
