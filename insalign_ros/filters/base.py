"""The one interface every alignment core implements, and the sample/fix/estimate types it speaks.

Every entry point (``insalign-align``, ``alignment_node``, ``insalign_ros.align``) drives the same
:class:`AlignmentCore` objects through the session (session/): IMU samples as arrays (``propagate``), the sensors as
measurement models (``update``, filters/measurements.py).

Time: every stamp is data time in seconds (float), monotonic within a run. An IMU sample stamped ``t_k`` holds the
average rate and specific force over ``(t_{k-1}, t_k]`` (see core/mechanization.py).

Attitude output: ``C_b_n`` is body FLU -> local ENU at the current position; ``P_att_n`` is the 3x3 covariance
[rad^2] of the attitude error expressed as a small rotation in ENU, ``C_b_n_true = exp(psi_x) C_b_n_est``
with ``psi ~ N(0, P_att_n)`` (psi[2] is the azimuth error about Up).
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Mapping
from types import MappingProxyType
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..core.types import GnssFix, GnssVelocity, ImuSample  # noqa: F401  (re-exported: the interface speaks these)
from . import update as update_pipeline
from .update import UpdateResult  # noqa: F401  (re-exported)


class AlignmentStatus(enum.Enum):
    """What the core is doing, with a reason string a user can act on (see AlignmentEstimate.reason)."""

    WAITING_FOR_DATA = "waiting for data"
    WAITING_FOR_GNSS = "waiting for GNSS"
    WAITING_FOR_MOTION = "waiting for motion"
    CONVERGING = "aligning"
    ALIGNED = "aligned"
    FAULT = "fault"


@dataclass
class AlignmentEstimate:
    """A snapshot of a core's estimate (all arrays are copies)."""

    stamp_s: float
    C_b_n: np.ndarray  # body FLU -> ENU
    v_n: np.ndarray  # velocity relative to Earth, ENU [m/s]
    lat_rad: float
    lon_rad: float
    h_m: float
    P_att_n: np.ndarray  # 3x3 [rad^2], attitude error as rotation vector in ENU (see module docstring)
    P: np.ndarray  # full error-state covariance in the core's own state order (see state_names)
    state_names: tuple[str, ...]
    bias_gyro_b: np.ndarray | None = None  # [rad/s] where estimated
    bias_acc_b: np.ndarray | None = None  # [m/s^2] where estimated
    status: AlignmentStatus = AlignmentStatus.CONVERGING
    reason: str = ""


def bias_indices(state_names, block: str) -> tuple[int, ...]:
    """Indices of the gyro-bias (``block`` "bg") or accelerometer-bias ("ba") error states in a core's state order
    (named ``bg_x``.. or ``dbg_x``..); empty when the core keeps no such block. (Once per state order: the grade
    check reads them at every fix.)"""
    return _bias_indices(tuple(state_names), block)


@functools.lru_cache(maxsize=64)
def _bias_indices(state_names: tuple, block: str) -> tuple[int, ...]:
    return tuple(i for i, n in enumerate(state_names) if n.rstrip("_xyz").lstrip("d") == block)


#: the velocity error states' name prefixes in the cores' conventions (invariant cores ``nu_``, the EKF ``dv_``)
VELOCITY_PREFIXES = ("nu_", "dv_", "v_")


@functools.lru_cache(maxsize=64)
def velocity_indices(state_names: tuple) -> tuple[int, ...]:
    """Indices of the three velocity error states in a core's state order (a tuple); empty when it has fewer."""
    return _three(state_names, VELOCITY_PREFIXES)


#: the position error states' name prefixes (invariant cores ``rho_``, the EKF ``dp_``)
POSITION_PREFIXES = ("rho_", "dp_")


@functools.lru_cache(maxsize=64)
def position_indices(state_names: tuple) -> tuple[int, ...]:
    """Indices of the three position error states [m] in a core's state order (a tuple); empty when it has fewer."""
    return _three(state_names, POSITION_PREFIXES)


def _three(state_names: tuple, prefixes: tuple) -> tuple[int, ...]:
    ii = tuple(i for i, n in enumerate(state_names) if n.startswith(prefixes))[:3]
    return ii if len(ii) == 3 else ()


def accel_noise_b(C_b_n: np.ndarray, q_m2_s3: float, q_up_m2_s3: float) -> np.ndarray:
    """The accelerometer's white-noise PSD per body axis [m^2/s^3]: ``q_m2_s3`` on each axis and ``q_up_m2_s3`` on the
    body axis of the vehicle's vertical, the one within 25 deg of Up in the attitude ``C_b_n`` (body to ENU) of the
    initialisation (a vehicle's vibration in motion is mostly along its own vertical); an IMU mounted so that no axis is
    within 25 deg of Up gets ``q_up_m2_s3`` on every axis (the diagonal of the rotated matrix would under-state it along
    the vertical)."""
    q = np.full(3, float(q_m2_s3))
    if q_up_m2_s3 <= 0.0 or q_up_m2_s3 == q_m2_s3:
        return q
    up_b = np.abs(np.asarray(C_b_n, float)[2, :])  # Up in the body frame
    i = int(np.argmax(up_b))
    if up_b[i] >= math.cos(math.radians(25.0)):
        q[i] = q_up_m2_s3
        return q
    return np.full(3, max(float(q_m2_s3), float(q_up_m2_s3)))


def widen_biases(P: np.ndarray, state_names, var_bg_rad2_s2: float, var_ba_m2_s4: float) -> None:
    """Add ``var_bg_rad2_s2`` / ``var_ba_m2_s4`` to each gyro- / accelerometer-bias variance of the covariance ``P``
    (in place), carried to every state through the Gaussian's regression on the biases: with K = P_xb P_bb^-1,
    P += K diag(var) K^T. So a state the data tie to a bias (the attitude a gyro bias has turned since the start, the
    tilt an accelerometer bias mimics) gets the uncertainty a wider bias prior implies, in the core's own error
    coordinates; the bias block itself gets exactly ``var``. A singular bias block falls back to the diagonal."""
    blocks = [(bias_indices(state_names, b), v) for b, v in (("bg", var_bg_rad2_s2), ("ba", var_ba_m2_s4)) if v > 0.0]
    idx = [i for ix, _ in blocks for i in ix]
    if not idx:
        return
    d = np.concatenate([np.full(len(ix), v) for ix, v in blocks])
    try:
        K = np.linalg.solve(P[np.ix_(idx, idx)], P[idx, :]).T  # P_xb P_bb^-1 (P_bb symmetric)
    except np.linalg.LinAlgError:
        K = np.zeros((len(P), len(idx)))
        K[idx, np.arange(len(idx))] = 1.0
    P += (K * d) @ K.T
    P[:] = 0.5 * (P + P.T)


class AlignmentCore(ABC):
    """Base class of every alignment estimator.

    Life cycle: construct with a config dataclass, ``initialize(...)`` with an initial guess, then any
    interleaving of ``propagate`` (arrays of IMU samples) and ``update(model)`` with the measurement models it
    ``accepts`` (filters/measurements.py: GNSS position and velocity, zero velocity, zero angular rate, a gyro bias
    prior, ...), reading ``estimate()`` whenever needed. Cores that need motion (GNSS-aided in-motion cores) say so
    with ``needs_motion``; static cores accept ``ZeroVelocity``.
    """

    name: str = "base"
    #: capabilities a caller may rely on (declared here, never probed with hasattr)
    needs_motion: bool = False
    #: the error convention the models compute their Jacobians for (filters/measurements.py); "" for none
    convention: str = ""
    #: the state blocks beyond the navigation states that a model may need ("gyro_bias", "acc_bias")
    state_blocks: frozenset = frozenset()
    #: models fused by the core's own hook (``_fuse``) rather than by a Jacobian of its convention
    own_models: frozenset = frozenset()
    #: ``propagate(..., backward=True)`` works (filters/backtrack.py)
    supports_backtracking: bool = False
    #: initial 1-sigmas the core was tuned for: ((roll, pitch, yaw) [deg], velocity [m/s], position [m]); the session
    #: uses them unless the user gives others. Each core takes them from its configuration's ``initial_sigmas`` (the
    #: one source: registry.declared reads them there before any core is built)
    initial_sigmas: tuple
    #: the core runs its own zero-velocity updates (earth_iekf's ``auto_zupt_period_s``: its backward passes need
    #: them inside the passes); the session then schedules none for it
    schedules_own_zero_velocity: bool = False
    #: ``propagate(..., updates=...)``: the session may hand the core the updates it schedules inside a run of samples
    #: (the static cores' 10-Hz zero-velocity updates); its ``accepts`` does not change on the way
    updates_inside_runs: bool = False
    #: state indices of the attitude and velocity error blocks in ``P`` (for :meth:`inflate_navigation`);
    #: ``None``: the core keeps no such covariance
    att_index: tuple[int, ...] | None = None
    vel_index: tuple[int, ...] | None = None
    pos_index: tuple[int, ...] | None = None
    #: per-core counters (imu, rejected, ...) merged into the session's diagnostics; cores that count assign
    #: their own dict in __init__
    counters: Mapping[str, int] = MappingProxyType({})
    last_reject_reason: str = ""
    last_fading_factor: float = 1.0

    #: covariance [state order]; cores without one leave it None
    P: np.ndarray | None = None

    @abstractmethod
    def initialize(
        self,
        stamp_s: float,
        lat_rad: float,
        lon_rad: float,
        h_m: float,
        C_b_n: np.ndarray,
        v_n: np.ndarray,
        P_att_n: np.ndarray,
        sigma_v_m_s: float,
        sigma_p_m: float,
    ) -> None:
        """Start from an initial guess: position, ENU velocity [m/s], attitude C_b_n and its 3x3 covariance
        [rad^2] in ENU, velocity and position standard deviations."""

    def propagate(self, t_s, omega_ib_b, f_ib_b, backward: bool = False, estimates_at=None, updates=None,
                  results: list | None = None) -> list:
        """Propagate with arrays of IMU samples: ``t_s`` (N,) [s], ``omega_ib_b`` (N, 3) [rad/s], ``f_ib_b`` (N, 3)
        [m/s^2] (one sample: arrays of length 1). Sample ``k`` holds the average over ``(t_s[k-1], t_s[k]]``.

        ``backward`` (cores with ``supports_backtracking``, filters/backtrack.py): the inverse steps from the core's
        time back; ``t_s`` are then the times *after* each step (decreasing), sample ``k`` covering
        ``(t_s[k], t_s[k-1]]``.

        ``estimates_at`` (forward): increasing row indices after which the estimate is wanted (the session's outputs
        inside a run of samples); returns them, the numbers of propagating each segment and calling :meth:`estimate`
        after it (a core with a compiled path takes them in one call: ``_estimates_along``). A core whose ``accepts``
        changes on the way (``auto``'s hand-over) may return fewer: it then stopped after the row of its last
        estimate, and the caller propagates the rest. Otherwise returns [].

        ``updates`` (forward, cores with ``updates_inside_runs``): ``(row, model)`` pairs in row order, each model
        fused (:meth:`update`) after its row and before that row's estimate. The update results and the estimates
        are appended to ``results`` (returned; a new list when None) in row order as they are made, so that a
        failure leaves those made before it: the numbers of propagating each segment and calling :meth:`update` and
        :meth:`estimate` after it (``_updates_along``)."""
        if updates:
            if backward or not self.updates_inside_runs:
                raise ValueError(f"{self.name}: updates inside a run: forward, cores with updates_inside_runs")
            out = [] if results is None else results
            self._updates_along(t_s, omega_ib_b, f_ib_b, list(estimates_at or ()), updates, out)
            return out
        if estimates_at:
            if backward:
                raise ValueError("estimates_at: forward propagation only")
            return self._estimates_along(t_s, omega_ib_b, f_ib_b, estimates_at)
        self._propagate_arrays(t_s, omega_ib_b, f_ib_b, backward)
        return []

    def _propagate_arrays(self, t_s, omega_ib_b, f_ib_b, backward: bool = False) -> None:
        """:meth:`propagate` without estimates. Default: one ``_propagate_sample`` per row forward; cores with an array
        path override this and give the same numbers."""
        if backward:
            raise NotImplementedError(f"{self.name} does not support backward propagation")
        for k in range(len(t_s)):
            self._propagate_sample(ImuSample(float(t_s[k]), omega_ib_b[k], f_ib_b[k]))

    def _estimates_along(self, t_s, omega_ib_b, f_ib_b, ends) -> list[AlignmentEstimate]:
        """``propagate(..., estimates_at=ends)``: segment by segment, :meth:`estimate` after each."""
        out, k0 = [], 0
        for k in ends:
            self._propagate_arrays(t_s[k0:k + 1], omega_ib_b[k0:k + 1], f_ib_b[k0:k + 1])
            out.append(self.estimate())
            k0 = k + 1
        if k0 < len(t_s):
            self._propagate_arrays(t_s[k0:], omega_ib_b[k0:], f_ib_b[k0:])
        return out

    def _updates_along(self, t_s, omega_ib_b, f_ib_b, ends: list, updates, out: list) -> None:
        """``propagate(..., estimates_at=ends, updates=updates, results=out)``: segment by segment, the updates at a
        row and then its estimate."""
        k0 = e = u = 0
        while e < len(ends) or u < len(updates):
            k = min(ends[e] if e < len(ends) else math.inf, updates[u][0] if u < len(updates) else math.inf)
            if k >= k0:
                self._propagate_arrays(t_s[k0:k + 1], omega_ib_b[k0:k + 1], f_ib_b[k0:k + 1])
                k0 = k + 1
            while u < len(updates) and updates[u][0] == k:
                out.append(self.update(updates[u][1]))
                u += 1
            if e < len(ends) and ends[e] == k:
                out.append(self.estimate())
                e += 1
        if k0 < len(t_s):
            self._propagate_arrays(t_s[k0:], omega_ib_b[k0:], f_ib_b[k0:])

    def _propagate_sample(self, imu: ImuSample) -> None:
        """One IMU sample forward (the per-row step behind the default :meth:`propagate`; bad rows are rejected and
        counted here)."""
        raise NotImplementedError

    @property
    def accepts(self) -> frozenset:
        """The measurement model types :meth:`update` fuses: the models with terms for ``convention`` whose state
        blocks the core keeps, and ``own_models`` (a composite core, ``auto``, changes its set with its state)."""
        return update_pipeline.models_for(self.convention, self.state_blocks, self.own_models)

    @classmethod
    def declared_accepts(cls) -> frozenset:
        """:attr:`accepts` of a core of this class from its initialisation on, read before any is built
        (registry.declared; the class attributes decide, as they do for a built core)."""
        return update_pipeline.models_for(cls.convention, cls.state_blocks, cls.own_models)

    def update(self, meas) -> UpdateResult:
        """Fuse a measurement model (filters/measurements.py) at the core's current time (the caller propagates
        first). A model the core does not accept (``accepts``) changes nothing: the result says why (a core that
        uses it otherwise, ``core: auto``'s motion detector taking the GNSS speed, observes it: ``_observe``)."""
        if type(meas) not in self.accepts:
            return self._observe(meas)
        return self._fuse(meas)

    def predict(self, meas) -> UpdateResult:
        """The innovation (``innovation``, ``S``, ``nis``) ``meas`` would have now, with nothing changed (the
        session's outlier gate); a result with an empty ``S`` (no gate) where the core has no prediction."""
        if type(meas) not in self.accepts or type(meas) in self.own_models:  # own hooks: no prediction
            return UpdateResult(False, reason=f"{self.name} has no prediction of {meas.label}")
        return update_pipeline.predict(self, meas)

    # ---------------------------------------------------------------- hooks of the update (filters/update.py)
    def _observe(self, meas) -> UpdateResult:
        return UpdateResult(False, reason=f"{self.name} does not use {meas.label}")

    def _fuse(self, meas) -> UpdateResult:
        """The update of an accepted model: the one pipeline; a core whose equation is its paper's own (the static
        cores' fused zero-velocity kernel) overrides this one step."""
        return update_pipeline.update(self, meas)

    def _terms(self, meas):
        self.flush()
        return meas.terms(self)

    def _fading_factor(self, meas, nis_v: float) -> float:
        return 1.0

    def _inflate(self, lam: float) -> None:
        raise NotImplementedError

    def _gate(self, meas) -> float:
        return 0.0

    def _correction(self, meas, z, L, H, N) -> np.ndarray:
        """Error-state correction dx = L z (eq. (12)); PI-LIEKF overrides (eq. (30))."""
        return L @ z

    def _inject(self, dx: np.ndarray) -> None:
        raise NotImplementedError

    def _after_update(self, meas, res: UpdateResult) -> UpdateResult:
        return res

    def _after_prediction(self, meas, res: UpdateResult) -> UpdateResult:
        return res

    def flush(self) -> None:
        """Apply buffered IMU samples now (batched cores buffer; the default keeps none)."""

    def inflate_navigation(self, var_att_rad2: float, var_v_m2_s2: float, var_p_m2: float = 0.0,
                           var_bg_rad2_s2: float = 0.0, var_ba_m2_s4: float = 0.0) -> None:
        """Add ``var_att_rad2`` [rad^2] to each attitude-error variance and ``var_v_m2_s2`` [m^2/s^2] to each
        velocity-error variance and ``var_p_m2`` [m^2] to each position-error variance (isotropic, so the frame of
        the error states does not matter), and ``var_bg_rad2_s2`` [rad^2/s^2] / ``var_ba_m2_s4`` [m^2/s^4] to each
        gyro- / accelerometer-bias variance where the core keeps that block.

        The session calls it across an IMU gap (the motion during the gap is unknown, and what the missing samples
        would have told the filter is lost: docs/session.md, "Gaps") and when the data contradict the declared
        ``imu_grade`` (session/grade_check.py: a prior that was too narrow is widened)."""
        if self.P is None or self.att_index is None:
            return
        self.flush()
        a = list(self.att_index)
        self.P[a, a] += var_att_rad2
        for idx, var in ((self.vel_index, var_v_m2_s2), (self.pos_index, var_p_m2)):
            if idx is not None and var:
                i = list(idx)
                self.P[i, i] += var
        widen_biases(self.P, self.state_names, var_bg_rad2_s2, var_ba_m2_s4)

    def diagnostics(self) -> dict:
        """Core-specific diagnostics (key -> value) for /diagnostics and the metrics JSON."""
        return {}

    @property
    def busy(self) -> bool:
        """True while background work (an asynchronous solve) is pending."""
        return False

    def close(self) -> None:
        """Release threads and other resources. Idempotent; the session calls it on every reset and shutdown."""

    @abstractmethod
    def estimate(self) -> AlignmentEstimate:
        """A copy of the current estimate."""

    @property
    @abstractmethod
    def initialized(self) -> bool:
        """True once initialize() was called."""

