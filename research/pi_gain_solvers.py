"""Research formulations of the PI-LIEKF gains (not installed, not user options).

The PI-LIEKF of the package has one formulation, :class:`insalign_ros.filters.lmi.WindowGainCertifier`. These are
the others that were measured (docs/inmotion_cores.md has the derivations; ``research/lmi_formulations.py`` runs
them through ``ia.align``):

* the per-interval eq. (22) as the paper writes it (:class:`PiGainSolver`: unstructured J, N with the least-squares
  eq. (23); :class:`StructuredPiGainSolver`: the eq. (23) structure built in) is never feasible on the INS (the
  frozen one-interval pair is not detectable);
* :func:`lift_window` + :class:`WindowPiGainSolver` impose eq. (20) on the transition lifted over W intervals
  (k_I synthesised, integral state held): feasible, but the gains it allows buy nothing.

:class:`IntervalGainSolver` adapts the per-interval solvers to the window interface (``history_needed``,
``solve(WindowData, deadline_s)``) that :class:`~insalign_ros.filters.pi_liekf.PiLiekf` calls;
:func:`research_solver_factory` gives the ``gain_solver_factory`` of ``PiLiekf(cfg, gain_solver_factory=...)`` and
:func:`register_research_cores` registers them as cores ``ia.align`` can run.
"""

from __future__ import annotations

import time

import numpy as np

from insalign_ros.filters.lmi import (BUDGET_STATUS, LmiResult, WindowData, _GainSolverBase, _solve,
                                      exact_window_closed_loop)


def _use_safe(res: LmiResult, solver, reason: str) -> None:
    """Replace the gains of ``res`` by the solver's safe gains (k_P = I, k_I = safe) and say why."""
    res.k_P, res.k_I, res.used_fallback = solver.safe_k_P, solver.safe_k_I, True
    res.reason = reason


def _fell_back(res: LmiResult, solver, lmi_max: float, srad: float, gains: np.ndarray, infeasible: str,
               unstable: str) -> bool:
    """Safe gains (and True) when the LMI is on the boundary or the gains do not stabilise the loop."""
    if lmi_max > -0.5 * solver.eps:
        _use_safe(res, solver, infeasible)
        return True
    if srad >= 1.0 or not np.all(np.isfinite(gains)):
        _use_safe(res, solver, unstable)
        return True
    return False


def _solve_or_safe(solver, var, what: str, t0: float, deadline_s: float | None = None):
    """Solve ``solver.prob``; return (status, solver used, seconds since t0, None) or, when it has no solution,
    the same with an LmiResult carrying the safe gains and the reason."""
    status, used = _solve(solver.prob, solver.solver, deadline_s)
    dt = time.perf_counter() - t0
    if status in ("optimal", "optimal_inaccurate") and var.value is not None:
        return status, used, dt, None
    safe = LmiResult(status, solver.safe_k_P, solver.safe_k_I, True, "", solver=used, solve_time_s=dt,
                     budget_miss=status == BUDGET_STATUS)
    safe.reason = f"{what} not solved ({status}): safe gains k_P = I, k_I = safe"
    return status, used, dt, safe


class StructuredPiGainSolver(_GainSolverBase):
    """Eq. (20) with the gain structure K = M K_PI of eq. (23) built in (no non-square inverse needed).

    Dual (equivalent) form of eq. (20): ``A_cl X A_cl^T < (1 - 2 rho) X`` with ``X = J^-1``. With the
    static-output-feedback constraint ``B_bar X = X_m B_bar`` (Crusius & Trofino 1999, linear in X, X_m),
    ``M K_PI B_bar X = M Y B_bar`` with ``Y = K_PI X_m``, so the Schur complement

        [[(1 - 2 rho) X, A_bar X - M Y B_bar], [(.)^T, X]] > 0,   X > 0

    is an LMI in (X, X_m, Y); then ``K_PI = Y X_m^-1`` exactly (eq. (23) residual 0) and J = X^-1 certifies the
    rate of eq. (20). Solved in whitened error coordinates ``e = T e'``, ``P_k = T T^T`` (k_P, k_I act on the
    measurement and are the same in both coordinates).
    """

    def __init__(self, n: int = 9, m: int = 3, rho: float = 0.01, solver: str = "CLARABEL", eps: float = 1e-6,
                 safe_k_I_per_s: float = 0.0):
        cp, q = self._setup(n, m, rho, solver, eps, safe_k_I_per_s)
        self.Abar = cp.Parameter((q, q))
        self.Bbar = cp.Parameter((m, q))
        self.MBL = cp.Parameter((q, 2 * m))  # M (whitened)
        self.X = cp.Variable((q, q), symmetric=True)
        self.Xm = cp.Variable((m, m))
        self.Y = cp.Variable((2 * m, m))
        AX = self.Abar @ self.X - self.MBL @ self.Y @ self.Bbar
        lmi = cp.bmat([[(1.0 - 2.0 * rho) * self.X, AX], [AX.T, self.X]])
        lmi = 0.5 * (lmi + lmi.T)
        cons = [lmi >> eps * np.eye(2 * q), self.X >> eps * np.eye(q), self.X << np.eye(q),
                self.Bbar @ self.X == self.Xm @ self.Bbar]
        self.prob = cp.Problem(cp.Minimize(1e-3 * cp.sum_squares(self.Y)), cons)
        self._lmi_expr = lmi

    def solve(self, A, H, L, Ts, P_prior, deadline_s: float | None = None) -> LmiResult:
        n, m, q = self.n, self.m, self.n + self.m
        T = np.linalg.cholesky(0.5 * (P_prior + P_prior.T))
        Ti = np.linalg.inv(T)
        Aw, Lw = Ti @ A @ T, Ti @ L
        Abar_w = np.zeros((q, q))
        Abar_w[:n, :n] = Aw
        Abar_w[:n, n:] = -Lw
        Abar_w[n:, n:] = np.eye(m)
        Bbar_w = np.zeros((m, q))
        Bbar_w[:, :n] = H @ A @ T
        M = np.zeros((q, 2 * m))
        M[:n, :m] = Lw
        M[n:, m:] = Ts * np.eye(m)
        self.Abar.value, self.Bbar.value, self.MBL.value = Abar_w, Bbar_w, M
        t0 = time.perf_counter()
        status, used, dt, safe = _solve_or_safe(self, self.X, "structured LMI", t0, deadline_s)
        if safe is not None:
            return safe
        K_PI = self.Y.value @ np.linalg.inv(self.Xm.value)
        k_P, k_I = K_PI[:m], -K_PI[m:]
        X = self.X.value
        J = np.linalg.inv(X)
        lmi_val = np.asarray(self._lmi_expr.value)
        lmi_min = float(np.linalg.eigvalsh(0.5 * (lmi_val + lmi_val.T)).min())
        Acl = Abar_w - M @ K_PI @ Bbar_w
        margin = float(np.linalg.eigvalsh(Acl.T @ J @ Acl - (1.0 - 2.0 * self.rho) * J).max())
        srad = float(np.max(np.abs(np.linalg.eigvals(Acl))))
        res = LmiResult(status, k_P, k_I, False, "", 0.0, -lmi_min, margin, srad, used, dt)
        if lmi_min < 0.5 * self.eps or srad >= 1.0 or not np.all(np.isfinite(K_PI)):
            _use_safe(res, self, f"LMI infeasible: solver returned '{status}' on the boundary (min eig "
                                 f"{lmi_min:.2g}, spectral radius {srad:.4f}): safe gains")
        else:
            res.reason = f"LMI solved: eq. (20) rate certified (margin {margin:.2g}, spectral radius {srad:.4f})"
        return res


class PiGainSolver(_GainSolverBase):
    """Builds the DPP-parametrised cvxpy problem once (n, m fixed); each solve only sets A_bar and B_bar."""

    def __init__(self, n: int = 9, m: int = 3, rho: float = 0.01, solver: str = "CLARABEL", eps: float = 1e-6,
                 safe_k_I_per_s: float = 0.0):
        cp, q = self._setup(n, m, rho, solver, eps, safe_k_I_per_s)
        self.Abar = cp.Parameter((q, q))
        self.Bbar = cp.Parameter((m, q))
        self.J = cp.Variable((q, q), symmetric=True)
        self.N = cp.Variable((q, m))
        JA = self.J @ self.Abar - self.N @ self.Bbar
        lmi = cp.bmat([[-(1.0 - 2.0 * rho) * self.J, JA.T], [JA, -self.J]])
        lmi = 0.5 * (lmi + lmi.T)
        cons = [lmi << -eps * np.eye(2 * q), self.J >> eps * np.eye(q), self.J << np.eye(q)]
        # feasibility; the small penalty on N keeps the gains moderate among the feasible ones
        self.prob = cp.Problem(cp.Minimize(1e-3 * cp.sum_squares(self.N)), cons)
        self._lmi_expr = lmi

    def solve(self, A: np.ndarray, H: np.ndarray, L: np.ndarray, Ts: float, P_prior=None,
              deadline_s: float | None = None) -> LmiResult:
        n, m, q = self.n, self.m, self.n + self.m
        Abar = np.zeros((q, q))
        Abar[:n, :n] = A
        Abar[:n, n:] = -L
        Abar[n:, n:] = np.eye(m)
        Bbar = np.zeros((m, q))
        Bbar[:, :n] = H @ A
        self.Abar.value, self.Bbar.value = Abar, Bbar
        t0 = time.perf_counter()
        status, used, dt, safe = _solve_or_safe(self, self.J, "LMI", t0, deadline_s)
        if safe is not None:
            return safe
        J, Nv = self.J.value, self.N.value
        lmi_val = np.asarray(self._lmi_expr.value)
        lmi_max = float(np.linalg.eigvalsh(0.5 * (lmi_val + lmi_val.T)).max())
        K = np.linalg.solve(J, Nv)
        M = np.zeros((q, 2 * m))
        M[:n, :m] = L
        M[n:, m:] = Ts * np.eye(m)
        K_PI, *_ = np.linalg.lstsq(M, K, rcond=None)
        resid = float(np.linalg.norm(M @ K_PI - K) / max(np.linalg.norm(K), 1e-300))
        Acl = Abar - M @ K_PI @ Bbar
        margin = float(np.linalg.eigvalsh(Acl.T @ J @ Acl - (1.0 - 2.0 * self.rho) * J).max())
        srad = float(np.max(np.abs(np.linalg.eigvals(Acl))))
        res = LmiResult(status, K_PI[:m].copy(), -K_PI[m:].copy(), False, "", resid, lmi_max, margin, srad, used, dt)
        if _fell_back(res, self, lmi_max, srad, K_PI,
                      f"LMI infeasible: solver returned '{status}' on the boundary (max eig {lmi_max:.2g} > -eps): "
                      "safe gains",
                      f"structured gains from eq. (23) (residual {resid:.2g}) do not stabilise the augmented system "
                      f"(spectral radius {srad:.4f}): safe gains k_P = I, k_I = safe"):
            return res
        if margin >= 0:
            res.reason = (f"structured gains stable (spectral radius {srad:.4f}) but the eq. (20) rate is not "
                          f"certified with this J (margin {margin:.3g}); eq. (23) residual {resid:.2g}")
        else:
            res.reason = f"LMI solved, eq. (20) rate certified; eq. (23) residual {resid:.2g}"
        return res


def lift_window(w: WindowData):
    """Lifted augmented system of eq. (18) over W intervals with k_P = I and the integral state held.

    Per interval (k_P = I): ``e_j = Phi_j e_{j-1} - L_j Z``, ``Phi_j = (I - L_j H) A_j``, ``z_j = H A_j e_{j-1}``;
    the integral update of eq. (16) summed over the window with Z held: ``Z+ = Z + k_I sum_j Ts_j z_j``. So

        [e_W; Z+] = (A_bar_W + E k_I B_bar_W) [e_0; Z],  A_bar_W = [[Phi_W, -Gamma_W], [0, I]],
        B_bar_W = [O_W, -Lambda_W],  E = [0; I],

    ``Phi_W = Phi_W..Phi_1``, ``Gamma_W = sum_j Phi_W..Phi_{j+1} L_j``, ``O_W = sum_j Ts_j H A_j Phi_{j-1}..Phi_1``,
    ``Lambda_W = sum_j Ts_j H A_j Gamma_{j-1}``. Returns (A_bar_W, B_bar_W) in the whitened error coordinates
    ``e = T e'``, ``T T^T = P0`` (Z in metres, unscaled).
    """
    n, m = w.H.shape[1], w.H.shape[0]
    T = np.linalg.cholesky(0.5 * (w.P0 + w.P0.T))
    Phi_acc, Gam = np.eye(n), np.zeros((n, m))
    O, Lam = np.zeros((m, n)), np.zeros((m, m))
    for A, L, Ts in zip(w.A, w.L, w.Ts):
        HA = w.H @ A
        O += Ts * HA @ Phi_acc
        Lam += Ts * HA @ Gam
        Phi = A - L @ HA
        Phi_acc = Phi @ Phi_acc
        Gam = Phi @ Gam + L
    Ti = np.linalg.inv(T)
    q = n + m
    Abar = np.zeros((q, q))
    Abar[:n, :n] = Ti @ Phi_acc @ T
    Abar[:n, n:] = -Ti @ Gam
    Abar[n:, n:] = np.eye(m)
    Bbar = np.hstack([O @ T, -Lam])
    return Abar, Bbar, T


class WindowPiGainSolver(_GainSolverBase):
    """Eqs. (20)-(23) on the lifted window system of :func:`lift_window` (docs/inmotion_cores.md).

    The frozen one-interval pair of eq. (18) is not detectable on the INS (rotation about the specific force is
    invisible over one interval), so the rate condition is imposed on the transition over a window of W
    intervals in which the motion makes the attitude observable, with the paper's per-update rate compounded:
    ``A_cl^T J A_cl < (1 - 2 rho)^W J``. k_P = I (the Kalman gain, which the filter's covariance assumes);
    the LMI designs k_I.

    ``structure="structured"`` (default): ``J = blkdiag(J_e, J_Z)`` so that ``N = J E k_I = [0; J_Z k_I]`` and
    ``k_I = J_Z^-1 Y`` exactly (eq. (23) with the non-square M replaced by its Z_I rows: residual 0).
    ``structure="paper"``: unstructured (J, N) of eq. (22), ``K = J^-1 N`` (12 x 3), k_I from the least-squares
    solution of ``E k_I = K`` (eq. (23)); its relative residual is reported.
    Objective: the smallest ||N|| that certifies the rate (least noise amplification).
    Every result is checked on the exact per-update product (integral state not held): spectral radius < 1.
    """

    def __init__(self, n: int = 9, m: int = 3, rho: float = 0.01, window: int = 30, solver: str = "CLARABEL",
                 eps: float = 1e-6, safe_k_I_per_s: float = 0.0, structure: str = "structured",
                 objective: str = "min_norm"):
        cp, q = self._setup(n, m, rho, solver, eps, safe_k_I_per_s)
        self.W, self.structure = window, structure
        self.c = (1.0 - 2.0 * rho) ** window
        self.Abar = cp.Parameter((q, q))
        self.Bbar = cp.Parameter((m, q))
        if structure == "structured":
            self.Je = cp.Variable((n, n), symmetric=True)
            # max_integral: J_Z = I fixes the scale of the homogeneous LMI, so k_I = Y exactly
            self.JZ = cp.Variable((m, m), symmetric=True) if objective == "min_norm" else cp.Constant(np.eye(m))
            self.Y = cp.Variable((m, m))
            J = cp.bmat([[self.Je, np.zeros((n, m))], [np.zeros((m, n)), self.JZ]])
            N = cp.vstack([np.zeros((n, m)), -self.Y])  # A_cl = A_bar + E k_I B_bar = A_bar - K B_bar, K = -E k_I
            self.J = J
        else:
            self.J = cp.Variable((q, q), symmetric=True)
            N = cp.Variable((q, m))
            J = self.J
        self.N = N
        JA = J @ self.Abar - N @ self.Bbar
        lmi = cp.bmat([[-self.c * J, JA.T], [JA, -J]])
        lmi = 0.5 * (lmi + lmi.T)
        cons = [lmi << -eps * np.eye(2 * q), J >> eps * np.eye(q), J << np.eye(q)]
        if objective == "max_integral" and structure == "structured":
            # the largest integral gain (min eigenvalue of its symmetric part) that the certificate allows
            s_min = cp.Variable()
            cons.append(0.5 * (self.Y + self.Y.T) >> s_min * np.eye(m))
            self.prob = cp.Problem(cp.Maximize(s_min), cons)
        else:
            self.prob = cp.Problem(cp.Minimize(cp.sum_squares(N)), cons)
        self._lmi_expr = lmi

    @property
    def history_needed(self) -> int:
        return self.W

    def solve(self, w: WindowData, deadline_s: float | None = None) -> LmiResult:
        n, m, q = self.n, self.m, self.n + self.m
        t0 = time.perf_counter()
        Abar, Bbar, _ = lift_window(w)
        self.Abar.value, self.Bbar.value = Abar, Bbar
        status, used, dt, safe = _solve_or_safe(self, self.J, f"lifted LMI (W = {self.W})", t0, deadline_s)
        if safe is not None:
            return safe
        J = np.asarray(self.J.value)
        lmi_val = np.asarray(self._lmi_expr.value)
        lmi_max = float(np.linalg.eigvalsh(0.5 * (lmi_val + lmi_val.T)).max())
        if self.structure == "structured":
            k_I = np.linalg.solve(np.asarray(self.JZ.value), self.Y.value)
            resid = 0.0
        else:
            K = np.linalg.solve(J, self.N.value)  # A_cl = A_bar - K B_bar; E k_I = -K
            k_I = -K[n:]
            resid = float(np.linalg.norm(K[:n]) / max(np.linalg.norm(K), 1e-300))
        E = np.zeros((q, m))
        E[n:] = np.eye(m)
        Acl = Abar + E @ k_I @ Bbar
        margin = float(np.linalg.eigvalsh(Acl.T @ J @ Acl - self.c * J).max())
        Pi = exact_window_closed_loop(w, np.eye(m), k_I)
        srad = float(np.max(np.abs(np.linalg.eigvals(Pi))))
        res = LmiResult(status, np.eye(m), k_I, False, "", resid, lmi_max, margin, srad, used, dt,
                        extra={"window": self.W, "rate_factor": self.c,
                               "spectral_radius_held": float(np.max(np.abs(np.linalg.eigvals(Acl))))})
        if not _fell_back(res, self, lmi_max, srad, k_I,
                          f"lifted LMI (W = {self.W}) infeasible: '{status}' on the boundary (max eig {lmi_max:.2g}):"
                          " safe gains",
                          f"lifted LMI (W = {self.W}) gains do not stabilise the exact window product (spectral radius "
                          f"{srad:.4f}; eq. (23) residual {resid:.2g}): safe gains"):
            res.reason = (f"lifted LMI (W = {self.W}) solved, rate (1-2 rho)^W certified for the held model (margin "
                          f"{margin:.2g}); exact window spectral radius {srad:.4f}; eq. (23) residual {resid:.2g}")
        return res


class IntervalGainSolver:
    """The per-interval eq. (22) solvers (:class:`PiGainSolver`, :class:`StructuredPiGainSolver`) behind the window
    interface: a window of one interval, ``A, L, T_s`` of the latest GNSS interval and its prior covariance."""

    history_needed = 1

    def __init__(self, solver):
        self.solver = solver

    def solve(self, w: WindowData, deadline_s: float | None = None) -> LmiResult:
        return self.solver.solve(w.A[-1], w.H, w.L[-1], float(w.Ts[-1]), w.P0, deadline_s=deadline_s)


def research_solver_factory(formulation: str, structure: str = "structured", objective: str = "max_integral"):
    """``factory(cfg)`` for ``PiLiekf(cfg, gain_solver_factory=...)``: "interval" (eq. (22) on one interval;
    ``structure`` "paper" = :class:`PiGainSolver`, "structured" = :class:`StructuredPiGainSolver`) or "window"
    (:class:`WindowPiGainSolver` over ``cfg.lmi_window_updates`` intervals, ``structure`` and ``objective``).
    rho, solver, eps and the safe gains come from the PI-LIEKF config."""
    if structure not in ("paper", "structured") or objective not in ("min_norm", "max_integral"):
        raise ValueError(f"structure {structure!r} / objective {objective!r}")

    def factory(c):
        if formulation == "window":
            return WindowPiGainSolver(9, 3, c.rho, c.lmi_window_updates, c.lmi_solver, c.lmi_eps, c.safe_k_I_per_s,
                                      structure, objective)
        cls = StructuredPiGainSolver if structure == "structured" else PiGainSolver
        return IntervalGainSolver(cls(9, 3, c.rho, c.lmi_solver, c.lmi_eps, c.safe_k_I_per_s))

    if formulation not in ("interval", "window"):
        raise ValueError(f"formulation {formulation!r}: 'interval' or 'window'")
    return factory


#: research cores ``ia.align`` can run once :func:`register_research_cores` has registered them: name -> (formulation,
#: structure) of :func:`research_solver_factory` (objective "max_integral")
RESEARCH_CORES = {"pi_liekf_window": ("window", "structured"),
                  "pi_liekf_interval_paper": ("interval", "paper"),
                  "pi_liekf_interval_structured": ("interval", "structured")}


def register_research_cores(record: list | None = None) -> tuple[str, ...]:
    """Register :data:`RESEARCH_CORES` (a PI-LIEKF with a research gain solver; the PI-LIEKF's configuration) in the
    core registry, so that ``ia.align(data, core="pi_liekf_window", ...)`` runs them through the session users run.
    ``record``: each core built is appended to it (a benchmark or a test reads ``lmi_history`` after the run)."""
    from insalign_ros.filters.config import PiLiekfConfig
    from insalign_ros.filters.pi_liekf import PiLiekf
    from insalign_ros.filters.registry import register

    for name, (formulation, structure) in RESEARCH_CORES.items():
        factory = research_solver_factory(formulation, structure, "max_integral")

        class Research(PiLiekf):
            def __init__(self, cfg, factory=factory):
                super().__init__(cfg, gain_solver_factory=factory)
                if record is not None:
                    record.append(self)

        register(name, Research, PiLiekfConfig)
    return tuple(RESEARCH_CORES)
