"""Alignment metrics: Euler errors, RMSE, time to |yaw error| < threshold, steady-state error, attitude NEES.

Errors are estimate minus truth (Euler differences wrapped to (-180, 180] deg, as the papers plot them);
NEES uses the ENU small-rotation error psi with ``C_true = exp(psi_x) C_est`` and the core's ``P_att_n``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..core import earth
from ..filters.base import AlignmentEstimate
from ..core.stats import chi2_ppf


@dataclass
class RunResult:
    """Time series of one alignment run against a reference attitude."""

    core: str
    t_s: np.ndarray  # (n,) time since the core's initialisation [s]
    rpy_est_deg: np.ndarray  # (n, 3)
    rpy_err_deg: np.ndarray  # (n, 3) estimate minus truth, wrapped
    sigma3_deg: np.ndarray  # (n, 3) 3-sigma of the ENU attitude error (about E, N, U ~ roll, pitch, yaw near level)
    nees: np.ndarray  # (n,) attitude NEES (3 dof)
    meta: dict = field(default_factory=dict)


def evaluate(core_name: str, estimates: list[AlignmentEstimate], t_ref_s: np.ndarray, C_b_n_ref: np.ndarray,
             t_init_s: float, meta: dict | None = None) -> RunResult:
    """Compare estimates with a reference attitude sampled at t_ref_s (nearest reference sample in time)."""
    t = np.array([e.stamp_s for e in estimates])
    idx = np.clip(np.searchsorted(t_ref_s, t - 1e-6), 0, len(t_ref_s) - 1)
    C_est = np.array([e.C_b_n for e in estimates])
    C_ref = C_b_n_ref[idx]
    ypr_est = Rotation.from_matrix(C_est).as_euler("ZYX")
    ypr_ref = Rotation.from_matrix(C_ref).as_euler("ZYX")
    rpy_est = np.degrees(ypr_est[:, ::-1])
    rpy_err = np.degrees(earth.wrap_angle_rad(ypr_est[:, ::-1] - ypr_ref[:, ::-1]))
    psi = Rotation.from_matrix(C_ref @ np.transpose(C_est, (0, 2, 1))).as_rotvec()  # C_ref = exp(psi) C_est
    P = np.array([e.P_att_n for e in estimates])
    nees = np.einsum("ni,ni->n", psi, np.linalg.solve(P, psi[..., None])[..., 0])
    sig3 = 3.0 * np.degrees(np.sqrt(np.maximum(np.einsum("nii->ni", P), 0.0)))
    return RunResult(core_name, t - t_init_s, rpy_est, rpy_err, sig3, nees, dict(meta or {}))


def rmse_deg(err_deg: np.ndarray, t_s: np.ndarray | None = None, t_from_s: float = -math.inf) -> np.ndarray:
    """Root-mean-square of the errors (per axis) over samples with t >= t_from_s."""
    m = np.ones(len(err_deg), bool) if t_s is None else t_s >= t_from_s
    return np.sqrt(np.mean(err_deg[m] ** 2, axis=0))


def time_below_s(t_s: np.ndarray, abs_err: np.ndarray, threshold: float) -> float:
    """First time after which |error| stays below threshold until the end (NaN if it never does)."""
    above = np.nonzero(np.abs(abs_err) >= threshold)[0]
    if len(above) == 0:
        return float(t_s[0])
    if above[-1] == len(t_s) - 1:
        return float("nan")
    return float(t_s[above[-1] + 1])


def steady_state_deg(t_s: np.ndarray, err_deg: np.ndarray, last_s: float = 60.0) -> np.ndarray:
    """Mean |error| per axis over the last ``last_s`` seconds."""
    m = t_s >= t_s[-1] - last_s
    return np.mean(np.abs(err_deg[m]), axis=0)


def nees_band(n_runs: int, dof: int = 3, conf: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square band of the NEES averaged over n_runs independent runs."""
    a = (1.0 - conf) / 2.0
    return chi2_ppf(a, dof * n_runs) / n_runs, chi2_ppf(1.0 - a, dof * n_runs) / n_runs


def summary(r: RunResult, rmse_from_s: float = -math.inf, nees_from_s: float = 30.0,
            yaw_threshold_deg: float = 1.0, steady_last_s: float = 60.0) -> dict:
    """The metrics JSON of one run."""
    m = r.t_s >= nees_from_s
    return {
        "core": r.core,
        "duration_s": float(r.t_s[-1]),
        "rmse_rpy_deg": rmse_deg(r.rpy_err_deg, r.t_s, rmse_from_s).tolist(),
        "final_err_rpy_deg": r.rpy_err_deg[-1].tolist(),
        "steady_state_abs_err_rpy_deg": steady_state_deg(r.t_s, r.rpy_err_deg, steady_last_s).tolist(),
        "steady_state_window_s": steady_last_s,
        "time_yaw_below_deg_s": time_below_s(r.t_s, r.rpy_err_deg[:, 2], yaw_threshold_deg),
        "yaw_threshold_deg": yaw_threshold_deg,
        "mean_nees_after_s": float(np.mean(r.nees[m])) if np.any(m) else float("nan"),
        "nees_from_s": nees_from_s,
        "nees_band_95_single_run": list(nees_band(1)),
        **r.meta,
    }
