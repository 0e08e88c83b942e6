"""PI gains of the PI-LIEKF from the LMI of eqs. (18)-(23), solved with cvxpy (CLARABEL, SCS if it raises).

Augmented error system (eq. (18); A_bar is not written in the paper: derived in docs/inmotion_cores.md).
With the error after the k-th update ``e_k`` (n = 9) and the integral innovation ``Z_I_k`` (m = 3),
``Z_p = H A e_{k-1} + noise`` (eq. (16) with the error reset of eq. (15)),
``e_k = A e_{k-1} - L (k_P Z_p + Z_I_{k-1})`` and ``Z_I_k = Z_I_{k-1} + k_I T_s Z_p``, so

    x_k = (A_bar - K B_bar) x_{k-1} + u_k,  A_bar = [[A, -L], [0, I]],  B_bar = [H A, 0],
    K = M K_PI,  M = [[L, 0], [0, T_s I]]  ((n+m) x 2m),  K_PI = [k_P; -k_I]  (2m x m).

A is the error transition over the interval between two GNSS updates (product of the per-sample
transitions), T_s that interval.

The PI-LIEKF uses one formulation, :class:`WindowGainCertifier`: eq. (20) as an analysis LMI (J the only variable)
on the exact window product of eq. (18) for candidate gains, the first certified candidate wins, else the safe
gains ``k_P = I, k_I = safe`` (the PI-LIEKF then reduces to the LIEKF) with the reason. Every solve takes a
``deadline_s`` (``time.perf_counter()`` clock): each cvxpy call gets the time left as the solver's own time limit
(CLARABEL ``time_limit``, SCS ``time_limit_secs``), and a solve that runs out returns the safe gains with
``budget_miss`` set. Only an "optimal" solve certifies; "optimal_inaccurate", "infeasible" or a solver failure
reject the candidate (no second solver: near infeasibility SCS took seconds and never certified).

Research formulations (not user options; ``benchmarks/lmi_formulations.py`` runs them, docs/inmotion_cores.md
has the derivations and the measurements): the per-interval eq. (22) as the paper writes it (:class:`PiGainSolver`,
unstructured J, N with the least-squares eq. (23); :class:`StructuredPiGainSolver`, the eq. (23) structure built in)
is never feasible on the INS (the frozen pair is not detectable); :func:`lift_window` + :class:`WindowPiGainSolver`
impose eq. (20) on the transition lifted over W intervals (k_I synthesised, integral state held): feasible, but the
gains it allows buy nothing. :class:`IntervalGainSolver` adapts the per-interval solvers to the window interface
(``history_needed``, ``solve(WindowData, deadline_s)``) that :class:`~insalign_ros.filters.pi_liekf.PiLiekf` calls.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

#: status of a solve that ran out of its time budget
BUDGET_STATUS = "budget_exceeded"
#: the cvxpy option that bounds a solver's own run time [s]
_TIME_LIMIT_OPTION = {"CLARABEL": "time_limit", "SCS": "time_limit_secs"}
#: time kept back from the solver's limit for cvxpy's unpacking and the eigenvalue checks [s]
_UNPACK_RESERVE_S = 0.01
# The status says it (and an inaccurate solve certifies nothing). A filter, not warnings.catch_warnings(), which is not
# thread-safe and the solves run in a worker thread.
warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)


@dataclass
class LmiResult:
    status: str  # cvxpy status of the solve ("optimal", "infeasible", ...) or BUDGET_STATUS
    k_P: np.ndarray  # (m, m)
    k_I: np.ndarray  # (m, m)
    used_fallback: bool
    reason: str
    residual_eq23: float = float("nan")  # ||M K_PI - K|| / ||K||
    lmi_max_eig: float = float("nan")  # largest eigenvalue of the eq. (22) matrix at the solution (< 0 wanted)
    rate_margin_structured: float = float("nan")  # max eig of (A_cl^T J A_cl - (1-2 rho) J) with structured K
    spectral_radius_structured: float = float("nan")
    solver: str = ""
    solve_time_s: float = 0.0
    extra: dict = field(default_factory=dict)
    budget_miss: bool = False  # the solve ran out of its time budget (the gains are then the safe ones)


class _GainSolverBase:
    """Common set-up of the PI gain solvers: sizes, rate, solver choice, strictness margin, safe fallback gains."""

    def _setup(self, n: int, m: int, rho: float, solver: str, eps: float, safe_k_I_per_s: float):
        import cvxpy as cp

        self.cp, self.n, self.m, self.rho, self.solver, self.eps = cp, n, m, rho, solver, eps
        self.safe_k_P, self.safe_k_I = np.eye(m), safe_k_I_per_s * np.eye(m)
        return cp, n + m


def _solve(prob, first: str, deadline_s: float | None = None, scs_fallback: bool = True):
    """Solve ``prob`` with ``first`` (then SCS if it raises and ``scs_fallback``) within ``deadline_s``:
    (status, solver used). The status is BUDGET_STATUS when the deadline has passed before or during the solve."""
    status, used = "not solved", ""
    for solver in dict.fromkeys([first, "SCS"] if scs_fallback else [first]):
        opts = {}
        if deadline_s is not None:
            left = deadline_s - time.perf_counter() - _UNPACK_RESERVE_S
            if left <= 0.0:
                return BUDGET_STATUS, used or solver
            opts[_TIME_LIMIT_OPTION[solver]] = left
        try:
            prob.solve(solver=solver, **opts)
            status, used = prob.status, solver
        except Exception as exc:  # solver failure: try the next one
            status, used = f"error: {type(exc).__name__}", solver
            continue
        break  # SCS only when the first solver raised: a status (even "infeasible") is an answer
    if status != "optimal" and deadline_s is not None and time.perf_counter() >= deadline_s - 2 * _UNPACK_RESERVE_S:
        status = BUDGET_STATUS  # stopped by its time limit (user_limit / inaccurate / error at the limit)
    return status, used


@dataclass
class WindowData:
    """The last W GNSS intervals of the LIEKF (k_P = I), oldest first: what the lifted LMI needs.

    Per interval j: ``A_j`` (9x9 error transition between fixes), ``L_j`` (9x3 Kalman gain), ``Ts_j`` [s];
    ``H`` (3x9) is constant; ``P0`` (9x9) is the posterior covariance at the start of the window (whitening).
    """

    A: np.ndarray  # (W, n, n)
    L: np.ndarray  # (W, n, m)
    Ts: np.ndarray  # (W,)
    H: np.ndarray  # (m, n)
    P0: np.ndarray  # (n, n)


def exact_window_closed_loop(w: WindowData, k_P: np.ndarray, k_I: np.ndarray) -> np.ndarray:
    """Product over the window of the per-update closed loops ``A_bar_j - M_j K_PI B_bar_j`` (eq. (18), exact:
    the integral state is not held), in the same whitened coordinates as :func:`lift_window`."""
    n, m = w.H.shape[1], w.H.shape[0]
    T = np.linalg.cholesky(0.5 * (w.P0 + w.P0.T))
    Ti = np.linalg.inv(T)
    q = n + m
    Pi = np.eye(q)
    for A, L, Ts in zip(w.A, w.L, w.Ts):
        HA = w.H @ A
        Acl = np.zeros((q, q))
        Acl[:n, :n] = A - L @ k_P @ HA
        Acl[:n, n:] = -L
        Acl[n:, :n] = Ts * k_I @ HA
        Acl[n:, n:] = np.eye(m)
        Pi = Acl @ Pi
    S = np.eye(q)
    S[:n, :n] = T
    Si = np.eye(q)
    Si[:n, :n] = Ti
    return Si @ Pi @ S


def parse_candidates(text: str) -> list[tuple[float, float]]:
    """``"1.6:0.5,1.0:0.1"`` -> [(k_P, k_I [1/s]), ...] (scalar gains, times the identity). Raises ValueError."""
    out = []
    for item in text.split(","):
        kp, ki = item.split(":")
        kp, ki = float(kp), float(ki)
        if not (np.isfinite(kp) and np.isfinite(ki) and kp > 0 and ki >= 0):
            raise ValueError(f"gain candidate {item!r}: need k_P > 0 and k_I >= 0")
        out.append((kp, ki))
    if not out:
        raise ValueError("no gain candidates")
    return out


class WindowGainCertifier(_GainSolverBase):
    """Eq. (20) as an *analysis* LMI on the exact per-update closed loop (eq. (18), integral state not held).

    For given gains ``K_PI = [k_P; -k_I]`` (eq. (23) structure exact: ``K = M K_PI``) the transition of the
    augmented error over a window of W intervals is the product ``Pi = prod_j (A_bar_j - M_j K_PI B_bar_j)``,
    polynomial in the gains, so the gains cannot be LMI variables; J can. The LMI

        Pi_i^T J Pi_i - (1 - 2 rho)^W J < 0  for the S windows ending 0, s, 2 s, ... updates ago,  J > 0

    (one Lyapunov function for all of them: robust to the motion changing between windows; a single window
    would only test its spectral radius) certifies the paper's rate. The candidates (scalar k_P, k_I, in the
    user's order of preference) are tried in order; the first certified one is returned, else the safe gains.
    """

    def __init__(self, n: int = 9, m: int = 3, rho: float = 0.01, window: int = 30, n_windows: int = 3,
                 shift: int = 10, candidates=((1.0, 0.0),), solver: str = "CLARABEL", eps: float = 1e-6,
                 safe_k_I_per_s: float = 0.0):
        cp, q = self._setup(n, m, rho, solver, eps, safe_k_I_per_s)
        self.W, self.S, self.shift, self.candidates = window, n_windows, shift, list(candidates)
        self.c = (1.0 - 2.0 * rho) ** window
        self.Pi = [cp.Parameter((q, q)) for _ in range(n_windows)]
        self.J = cp.Variable((q, q), symmetric=True)
        self.exprs = []
        cons = [self.J >> eps * np.eye(q), self.J << np.eye(q)]
        for P in self.Pi:
            # Schur form of Pi^T J Pi < c J (eq. (21)-(22) with K fixed): [[-c J, Pi^T J], [J Pi, -J]] < 0
            JP = self.J @ P
            e = cp.bmat([[-self.c * self.J, JP.T], [JP, -self.J]])
            e = 0.5 * (e + e.T)
            self.exprs.append(e)
            cons.append(e << -eps * np.eye(2 * q))
        self.prob = cp.Problem(cp.Minimize(0), cons)

    @staticmethod
    def history_for(window: int, n_windows: int = 3, shift: int = 10) -> int:
        """GNSS intervals of history that S windows of W intervals, shifted by ``shift``, need."""
        return window + (n_windows - 1) * shift

    @property
    def history_needed(self) -> int:
        return self.history_for(self.W, self.S, self.shift)

    def solve(self, w: WindowData, deadline_s: float | None = None) -> LmiResult:
        """``w`` holds the last ``history_needed`` intervals (oldest first); P0 whitens the error coordinates.
        ``deadline_s`` (``time.perf_counter()`` clock, None = no limit): when it passes, the safe gains are
        returned with ``budget_miss`` set and the candidates not tried are named."""
        m = self.m
        t0 = time.perf_counter()
        tried = []
        status, used = "not solved", ""
        errors = 0  # candidates the solver failed on (counted for the benchmarks)
        N = len(w.Ts)
        for kp, ki in self.candidates:
            k_P, k_I = kp * np.eye(m), ki * np.eye(m)
            Pis = []
            for i in range(self.S):
                end = N - i * self.shift
                sub = WindowData(w.A[end - self.W:end], w.L[end - self.W:end], w.Ts[end - self.W:end], w.H, w.P0)
                Pis.append(exact_window_closed_loop(sub, k_P, k_I))
            srad = max(float(np.max(np.abs(np.linalg.eigvals(P)))) for P in Pis)
            if srad >= np.sqrt(self.c):  # necessary condition fails: no J exists, skip the solve
                tried.append(f"{kp:g}/{ki:g}: spectral radius {srad:.3f} >= (1-2 rho)^(W/2)")
                continue
            for par, P in zip(self.Pi, Pis):
                par.value = P
            # no SCS after a CLARABEL failure: that happens near infeasibility, where SCS took 1-40 s per candidate
            # and never certified one on the ship and car sweeps (docs/inmotion_cores.md, 'Bounded solve time')
            status, used = _solve(self.prob, self.solver, deadline_s, scs_fallback=False)
            errors += status.startswith("error")
            if status == BUDGET_STATUS:
                dt = time.perf_counter() - t0
                return LmiResult(status, self.safe_k_P, self.safe_k_I, True,
                                 f"LMI time budget ran out after {dt:.2f} s at candidate {kp:g}/{ki:g}"
                                 + (f" (rejected before: {'; '.join(tried)})" if tried else "") + ": safe gains",
                                 solver=used, solve_time_s=dt, budget_miss=True)
            if status != "optimal" or self.J.value is None:  # optimal_inaccurate is no certificate
                tried.append(f"{kp:g}/{ki:g}: " + (f"{used} failed" if status.startswith("error") else status))
                continue
            lmi_max = max(float(np.linalg.eigvalsh(np.asarray(e.value)).max()) for e in self.exprs)
            if lmi_max > -0.5 * self.eps:
                tried.append(f"{kp:g}/{ki:g}: on the boundary")
                continue
            J = self.J.value
            margin = max(float(np.linalg.eigvalsh(P.T @ J @ P - self.c * J).max()) for P in Pis)
            dt = time.perf_counter() - t0
            return LmiResult(status, k_P, k_I, False,
                             f"gains k_P = {kp:g} I, k_I = {ki:g} I certified: eq. (20) rate (1-2 rho)^W with one J "
                             f"over {self.S} windows (W = {self.W}), worst spectral radius {srad:.3f}"
                             + (f"; rejected before: {'; '.join(tried)}" if tried else ""),
                             0.0, lmi_max, margin, srad, used, dt,
                             extra={"candidate": (kp, ki), "solver_errors": errors})
        dt = time.perf_counter() - t0
        return LmiResult(status, self.safe_k_P, self.safe_k_I, True,
                         f"no gain candidate certified ({'; '.join(tried)}): safe gains", solver=used,
                         solve_time_s=dt, extra={"solver_errors": errors})


# ------------------------------------------------------------------------------ research formulations
# Not user options: benchmarks/lmi_formulations.py and test/test_pi_liekf.py build them and hand them to the
# PI-LIEKF (PiLiekf(config, gain_solver_factory=...)); docs/inmotion_cores.md shows why none of them is the default.


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
