"""Configuration dataclasses of the in-motion cores (LIEKF, PI-LIEKF, imperfect IEKF, conventional EKF).

Units are in the field names. Defaults are the PI-LIEKF paper's Table 1 / Table 2 values (ship simulation):
gyro ARW 2.0 deg/sqrt(h), VRW 0.2 m/s/sqrt(h), gyro bias 25.2 deg/h, accelerometer bias 0.2 mg, GPS 1 m,
rho = 0.01: the noise and bias fields are the IMU grade ``paper_ship`` (filters/imu_grade.py). Sessions, the node and
insalign-align set those fields from their ``imu_grade`` (default ``unknown_mems``, a conservative MEMS prior); an
explicit field overrides the grade. ``config/<core>.yaml`` holds the other defaults in ROS 2 parameter-file layout
(``/**: ros__parameters: ...``, any node name or namespace); ``test/test_liekf_config.py`` checks that they agree.

``from_dict`` validates: unknown keys, wrong types and out-of-range values raise ``ValueError`` with the field
name and the reason.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields

from .imu_grade import ImuGrade, apply_aliases


def param(default=dataclasses.MISSING, doc: str = "", *, range=None, read_only: bool = False, node: bool = True,
          factory=dataclasses.MISSING):
    """A configuration field with its metadata, the one source of what the node's parameter descriptors, the shipped
    YAML comments and docs/nodes.md's table say (session/catalog.py generates them): ``doc`` one line for a user,
    ``range`` (lo, hi) inclusive for a number (checked by :func:`check_ranges`, shown by ``ros2 param describe``),
    ``read_only`` after the node started, ``node`` False: not a node parameter (the node has its own way to set it)."""
    md = {"doc": doc, "range": range, "read_only": read_only, "node": node}
    if isinstance(default, list):  # a list default: each instance its own copy
        factory, default = (lambda v=tuple(default): list(v)), dataclasses.MISSING
    if factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=factory, metadata=md)
    return dataclasses.field(default=default, metadata=md)


def check_ranges(cfg) -> None:
    """ValueError (the field, its value and its range) for a number outside the range in its field's metadata."""
    for f in fields(cfg):
        rng = f.metadata.get("range")
        v = getattr(cfg, f.name)
        if rng is None or isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        lo, hi = rng
        if not (lo <= v <= hi):  # NaN fails too
            raise ValueError(f"{f.name}: value {v!r} outside its range [{lo:g}, {hi:g}]")


class ConfigDict:
    """from_dict / to_dict / field type checks shared by every core config dataclass (in-motion and static)."""

    @classmethod
    def from_dict(cls, params: dict | None = None):
        """Build from a (possibly partial) dict; ints are accepted for floats. Raises ValueError."""
        params = apply_aliases(dict(params or {}))  # deprecated names (filters/imu_grade.py, one table)
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown} for {cls.__name__}; known: {sorted(known)}")
        kwargs = {}
        for k, v in params.items():
            ftype = known[k].type
            if ftype in ("float", float) and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            if ftype in ("str", str) and not isinstance(v, str):
                raise ValueError(f"{k}: expected a string, got {v!r}")
            if ftype in ("float", float) and not isinstance(v, float):
                raise ValueError(f"{k}: expected a number, got {v!r}")
            if ftype in ("list", list) and isinstance(v, (list, tuple)):
                v = [float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else x for x in v]
            kwargs[k] = v
        cfg = cls(**kwargs)
        cfg.validate()
        check_ranges(cfg)  # the ranges in the fields' metadata (the node's descriptors show the same)
        return cfg

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def imu_grade(self) -> ImuGrade:
        """The typed IMU grade this configuration's noise and bias fields hold (one name per datasheet number,
        filters/imu_grade.py; a number the core does not use is 0)."""
        return ImuGrade.from_fields(type(self).__name__, self.to_dict())

    def check_field_types(self, non_negative: bool = False) -> None:
        """Strings are strings, ints ints, every other field a finite number (and >= 0 when asked)."""
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("str", str):  # choices are checked by the class that adds the field
                if not isinstance(v, str):
                    raise ValueError(f"{f.name}: expected a string, got {v!r}")
                continue
            if f.type in ("list", list):  # a 3-vector (gnss_lever_arm_b_m)
                if not (isinstance(v, (list, tuple)) and len(v) == 3 and all(
                        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
                    raise ValueError(f"{f.name}: expected 3 finite numbers, got {v!r}")
                continue
            if f.type in ("int", int):
                if not (isinstance(v, int) and not isinstance(v, bool)):
                    raise ValueError(f"{f.name}: expected an integer, got {v!r}")
            elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{f.name}: expected a finite number, got {v!r}")
            if non_negative and v < 0:
                raise ValueError(f"{f.name}: must be >= 0, got {v}")


@dataclass
class InMotionConfig(ConfigDict):
    """Shared parameters of the GNSS-aided in-motion cores."""

    #: gyro angle random walk [deg/sqrt(h)] -> process noise of the attitude error (PI-LIEKF Table 2, Q)
    gyro_arw_deg_sqrt_h: float = param(2.0, 'gyro angle random walk [deg/sqrt(h)] (IMU grade)')
    #: accelerometer velocity random walk [m/s/sqrt(h)] -> process noise of the velocity error
    acc_vrw_m_s_sqrt_h: float = param(0.2, 'accelerometer velocity random walk [m/s/sqrt(h)] (IMU grade)')
    #: ... along the vehicle's vertical (the body axis within 25 deg of Up at initialisation; every axis when none is)
    acc_vrw_up_m_s_sqrt_h: float = param(
        0.0, "accelerometer velocity random walk along the vehicle's vertical [m/s/sqrt(h)]: vibration in motion "
             "(IMU grade; 0: acc_vrw_m_s_sqrt_h)")
    #: initial 1-sigma attitude errors about the ENU axes [deg] used by the runners to build P_att_n.
    #: A 179 deg yaw error is not Gaussian in any parametrisation; see docs/inmotion_cores.md for the choice.
    init_sigma_roll_deg: float = param(10.0, range=(0.0, 180.0))
    init_sigma_pitch_deg: float = param(10.0, range=(0.0, 180.0))
    init_sigma_yaw_deg: float = param(60.0, range=(0.0, 1e5))  # above 180: unknown (a flat prior)
    #: initial velocity / position 1-sigma (PI-LIEKF Table 1: GPS velocity 0.1 m/s, position 1.0 m)
    init_sigma_v_m_s: float = 0.1
    init_sigma_p_m: float = 1.0
    #: reject a GNSS fix whose normalised innovation squared exceeds this (0 disables the gate)
    gnss_nis_gate: float = param(
        0.0,
        "the core's own NIS gate on a fix (0: off, the default); the session's outlier gate is "
        'gnss_gate_nis')
    #: adaptive fading memory: when a GNSS innovation's NIS exceeds this, the prior covariance is multiplied by
    #: NIS/threshold before the gain is computed (0 disables; 16.27 = chi-square 3 dof, 99.9 %).
    #: Keeps P honest while the linearisation of a large initial attitude error is poor; see docs.
    fading_nis_threshold: float = 16.27
    #: upper bound of one update's attitude-variance inflation factor
    fading_max_factor: float = param(4.0, range=(1.0, 1e6))
    #: status ALIGNED once the 3-sigma yaw uncertainty is below this [deg]
    status_yaw_3sigma_deg: float = param(
        1.0,
        "the core's own status ALIGNED below this 3-sigma yaw [deg] (not the aligned flag: "
        'aligned.yaw_3sigma_deg)',
        range=(0.0, 360.0))
    #: IMU samples buffered before the batched (vectorised) propagation runs; the buffer is also flushed by
    #: every update and every estimate() call, so this only bounds latency and memory
    max_batch_samples: int = param(100, range=(1, 100000))

    @property
    def initial_sigmas(self) -> tuple:
        """The ``init_sigma_*`` fields as ``AlignmentCore.initial_sigmas``: ((roll, pitch, yaw) [deg], velocity
        [m/s], position [m])."""
        return ((self.init_sigma_roll_deg, self.init_sigma_pitch_deg, self.init_sigma_yaw_deg), self.init_sigma_v_m_s,
                self.init_sigma_p_m)

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        self.check_field_types()
        for name in ("gyro_arw_deg_sqrt_h", "acc_vrw_m_s_sqrt_h"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")
        for name in ("init_sigma_roll_deg", "init_sigma_pitch_deg", "init_sigma_yaw_deg", "init_sigma_v_m_s",
                     "init_sigma_p_m", "status_yaw_3sigma_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")
        if self.fading_nis_threshold < 0:
            raise ValueError(f"fading_nis_threshold: must be >= 0 (0 = off), got {self.fading_nis_threshold}")
        if not self.fading_max_factor >= 1.0:
            raise ValueError(f"fading_max_factor: must be >= 1, got {self.fading_max_factor}")
        if self.gnss_nis_gate < 0:
            raise ValueError(f"gnss_nis_gate: must be >= 0 (0 = off), got {self.gnss_nis_gate}")
        if not 1 <= self.max_batch_samples <= 100_000:
            raise ValueError(f"max_batch_samples: must be in [1, 100000], got {self.max_batch_samples}")


@dataclass
class InMotionGnssConfig(InMotionConfig):
    """InMotionConfig plus options of the batched ECI cores (kept out of the base class that other cores share)."""

    #: lower bound of the GNSS position sigma [m] (0 = trust the fix covariance; KITTI's 2 cm RT3003 accuracy is
    #: far below the model error of 10 Hz instantaneous IMU samples)
    gnss_sigma_floor_m: float = 0.0
    #: GNSS antenna position in the body frame FLU [m] (lever arm from the IMU): the position and velocity
    #: measurement models predict the antenna, p_ant = p + C_b_n l, v_ant = v + C_b_n (omega_ib_b x l)
    #: (docs/inmotion_cores.md, "GNSS velocity and lever arm")
    gnss_lever_arm_b_m: list = param(
        [0.0, 0.0, 0.0],
        'GNSS antenna position in the body frame FLU relative to the IMU [m] (x forward, y left, z up): '
        'the fix and gps/vel models predict the antenna')
    #: yaw hypotheses (filters/hypotheses.py): 1 = a single filter; K >= 2 runs K copies of the core at yaw offsets
    #: 360/K deg apart, weighted by their GNSS likelihoods, for a heading that is unknown (docs/inmotion_cores.md)
    yaw_hypotheses: int = param(
        1,
        'yaw hypotheses: 1 one filter; K >= 2 a bank at yaw offsets 360/K deg (filters/hypotheses.py)',
        range=(1, 36))
    #: drop a hypothesis whose normalised weight falls below this (after hypothesis_min_updates fixes)
    hypothesis_prune_weight: float = param(1e-3, range=(0.0, 1.0))
    hypothesis_min_updates: int = param(3, range=(0, 10000))
    #: merge two hypotheses whose attitudes are closer than this [deg] (the less probable one is dropped)
    hypothesis_merge_deg: float = param(2.0, range=(0.0, 180.0))

    def validate(self) -> None:
        super().validate()
        if self.gnss_sigma_floor_m < 0:
            raise ValueError(f"gnss_sigma_floor_m: must be >= 0, got {self.gnss_sigma_floor_m}")
        if not 1 <= self.yaw_hypotheses <= 36:
            raise ValueError(f"yaw_hypotheses: must be in [1, 36], got {self.yaw_hypotheses}")
        if not 0.0 <= self.hypothesis_prune_weight < 1.0:
            raise ValueError(f"hypothesis_prune_weight: must be in [0, 1), got {self.hypothesis_prune_weight}")
        if self.hypothesis_min_updates < 0:
            raise ValueError(f"hypothesis_min_updates: must be >= 0, got {self.hypothesis_min_updates}")
        if not 0.0 <= self.hypothesis_merge_deg < 90.0:
            raise ValueError(f"hypothesis_merge_deg: must be in [0, 90), got {self.hypothesis_merge_deg}")


@dataclass
class LiekfConfig(InMotionGnssConfig):
    """LIEKF (PI-LIEKF Alg. 1): no bias states."""


@dataclass
class PiLiekfConfig(InMotionGnssConfig):
    """PI-LIEKF (Alg. 2) with PI gains from the LMI of eqs. (18)-(23) (docs/inmotion_cores.md, PI-LIEKF).

    One formulation: eq. (20) as an analysis LMI (J variable) on the exact closed loop of eq. (18) over 3 windows of
    ``lmi_window_updates`` GNSS intervals shifted by W/3, rate (1 - 2 rho)^W; the first certified candidate of
    ``lmi_candidates`` is used, else the safe gains. The formulations that never work on the INS (per-interval
    eq. (22), window synthesis) are not options: benchmarks/lmi_formulations.py runs them."""

    #: decay-rate parameter of eq. (20) per GNSS update (PI-LIEKF Table 2: 0.01), compounded to (1 - 2 rho)^W over a
    #: window
    rho: float = param(0.01, range=(0.0, 1e6))
    #: cvxpy solver for the LMI ("CLARABEL" or "SCS"); a candidate it fails on is rejected (no second solver)
    lmi_solver: str = "CLARABEL"
    #: candidate gains "k_P:k_I,..." (scalars times I; k_I in 1/s) in order of preference; the first one that the
    #: eq. (20) LMI certifies on the exact window product is used
    lmi_candidates: str = param(
        "1.6:0.5,1.6:0.3,1.3:0.3,1.0:0.1",
        'the one formulation: eq. (20) certifies the first of these k_P:k_I candidates on 3 windows of '
        'lmi_window_updates fixes')
    #: GNSS intervals W of each certification window (history needed: W + 2 W/3 intervals)
    lmi_window_updates: int = param(30, range=(2, 600))
    #: re-solve the LMI every this many GNSS updates (1 = every update, as Alg. 2 reads); the gains are cached
    #: in between (A and H are state-independent: the LMI data change only with the IMU input and L_k)
    lmi_resolve_every_updates: int = param(30, range=(1, 100000))
    #: "every": re-solve every ``lmi_resolve_every_updates``; "once": solve once, at the first update with a full
    #: window after the 3-sigma yaw fell below ``lmi_once_yaw_3sigma_deg``, and keep those gains (retried at the
    #: same schedule while the solve falls back)
    lmi_schedule: str = "every"
    #: convergence threshold of the "once" schedule [deg] (the ship's 3-sigma yaw settles near 1.4 deg)
    lmi_once_yaw_3sigma_deg: float = param(3.0, range=(0.0, 360.0))
    #: "auto": synchronous in the offline runner (deterministic), in a worker thread in the ROS node (the node
    #: turns "auto" into "true"); "true": the solve runs in a worker thread and the gains are swapped in at the
    #: first update after it finished (the cached gains are used meanwhile); "false": synchronous
    lmi_async: str = "auto"
    #: wall-time budget of one LMI solve [s] (a solve takes ~0.1 s on the ship). The solver gets the time left as
    #: its own limit; a solve that has not returned within the budget gives the safe gains with the reason and is
    #: counted (diagnostics lmi_budget_misses); its late result is discarded. A synchronous update waits at most
    #: this long
    lmi_time_budget_s: float = param(
        2.0,
        'wall-time budget of one LMI solve [s]: a miss gives the safe gains with the reason (diagnostics)')
    #: safe fallback gains when the LMI is infeasible: k_P = I, k_I = safe_k_I_per_s I [1/s] (0 = the LIEKF)
    safe_k_I_per_s: float = 0.0
    #: margin of the strict inequalities (LMI <= -eps I, J >= eps I)
    lmi_eps: float = 1e-6
    #: integral-innovation clamp [m] per axis: anti-windup while the yaw error is large (0 disables)
    integral_clamp_m: float = 5.0

    @classmethod
    def from_dict(cls, params: dict | None = None):
        params = dict(params or {})
        if isinstance(params.get("lmi_async"), bool):  # YAML/ROS true/false
            params["lmi_async"] = "true" if params["lmi_async"] else "false"
        return super().from_dict(params)

    def validate(self) -> None:
        super().validate()
        if not 0.0 <= self.rho < 0.5:
            raise ValueError(f"rho: must be in [0, 0.5) so that 1 - 2 rho > 0, got {self.rho}")
        choices = {"lmi_solver": ("CLARABEL", "SCS"), "lmi_schedule": ("every", "once"),
                   "lmi_async": ("auto", "true", "false")}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name}: must be one of {list(allowed)}, got {getattr(self, name)!r}")
        try:
            from .lmi import parse_candidates

            parse_candidates(self.lmi_candidates)
        except ValueError as exc:
            raise ValueError(f"lmi_candidates: {exc}") from None
        if self.safe_k_I_per_s < 0:
            raise ValueError(f"safe_k_I_per_s: must be >= 0, got {self.safe_k_I_per_s}")
        if self.lmi_resolve_every_updates < 1:
            raise ValueError(f"lmi_resolve_every_updates: must be >= 1, got {self.lmi_resolve_every_updates}")
        if not 2 <= self.lmi_window_updates <= 600:
            raise ValueError(f"lmi_window_updates: must be in [2, 600], got {self.lmi_window_updates}")
        if not 0.0 < self.lmi_time_budget_s <= 600.0:
            raise ValueError(f"lmi_time_budget_s: must be in (0, 600], got {self.lmi_time_budget_s}")
        if not self.lmi_eps > 0:
            raise ValueError(f"lmi_eps: must be > 0, got {self.lmi_eps}")
        if self.integral_clamp_m < 0:
            raise ValueError(f"integral_clamp_m: must be >= 0, got {self.integral_clamp_m}")
        if not self.lmi_once_yaw_3sigma_deg > 0:
            raise ValueError(f"lmi_once_yaw_3sigma_deg: must be > 0, got {self.lmi_once_yaw_3sigma_deg}")


@dataclass
class BiasStatesConfig(InMotionGnssConfig):
    """Cores with gyro and accelerometer bias states (imperfect IEKF, conventional EKF)."""

    #: initial 1-sigma gyro bias [deg/h] (PI-LIEKF Table 1/2: b_Gyro = 25.2 deg/h)
    gyro_bias_deg_h: float = param(
        25.2,
        '1-sigma gyro bias [deg/h] (IMU grade): initial bias sigma, or the consider floor of a core '
        'without bias states')
    #: initial 1-sigma accelerometer bias [mg] (Table 1/2: b_Acc = 0.2 mg)
    acc_bias_mg: float = param(
        0.2,
        '1-sigma accelerometer bias [mg] (IMU grade): initial bias sigma, or the consider floor of a '
        'core without bias states')
    #: bias random walks (the paper's Q has 0 on the bias block; a small value keeps the filter from locking)
    gyro_bias_rw_deg_h_sqrt_h: float = param(
        0.5,
        'gyro bias random walk [deg/h/sqrt(h)] (IMU grade: bias instability over 1 h)')
    acc_bias_rw_mg_sqrt_h: float = param(
        0.005,
        'accelerometer bias random walk [mg/sqrt(h)] (IMU grade: bias instability over 1 h)')

    def validate(self) -> None:
        super().validate()
        for name in ("gyro_bias_deg_h", "acc_bias_mg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")
        for name in ("gyro_bias_rw_deg_h_sqrt_h", "acc_bias_rw_mg_sqrt_h"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")


@dataclass
class IekfConfig(BiasStatesConfig):
    """Imperfect IEKF (15 states): invariant attitude/velocity/position + EKF bias states."""


@dataclass
class EkfConfig(BiasStatesConfig):
    """Conventional 15-state error-state EKF (multiplicative attitude, additive velocity/position, ECI)."""
