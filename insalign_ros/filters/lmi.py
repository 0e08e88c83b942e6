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

The research formulations that were measured and not kept (the per-interval eq. (22) as the paper writes it, never
feasible on the INS; eq. (20) on the transition lifted over a window, feasible but buying nothing) live outside the
package, in ``research/pi_gain_solvers.py`` (docs/inmotion_cores.md has the derivations and the measurements).
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
