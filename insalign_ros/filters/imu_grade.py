"""IMU grade: one datasheet noise model from which every core's process noise and bias priors derive.

An :class:`ImuGrade` holds what a datasheet gives (units in the names):

* ``gyro_arw_deg_sqrt_h`` angle random walk [deg/sqrt(h)] (= 60 x the rate noise density in deg/s/sqrt(Hz));
* ``gyro_bias_deg_h`` 1-sigma gyro bias at the start of a run [deg/h] (run-to-run / turn-on bias left after the
  factory calibration): the initial bias prior of the cores with bias states, the consider floor of the others;
* ``gyro_bias_instability_deg_h`` in-run bias instability [deg/h] (the Allan-deviation floor): the bias random walk
  ``gyro_bias_rw_deg_h_sqrt_h`` = instability / sqrt(1 h), a walk that wanders by the instability in one hour;
* ``acc_vrw_m_s_sqrt_h`` velocity random walk [m/s/sqrt(h)] (= 60 g0 x the noise density in g/sqrt(Hz));
* ``acc_bias_mg``, ``acc_bias_instability_mg`` [mg] likewise for the accelerometers.

Every core's config class names these numbers the same way (``gyro_arw_deg_sqrt_h``, ``acc_vrw_m_s_sqrt_h``,
``gyro_bias_deg_h``, ``acc_bias_mg``, ``gyro_bias_rw_deg_h_sqrt_h``, ``acc_bias_rw_mg_sqrt_h``): one name per
datasheet number. The old names are deprecated aliases, mapped in :data:`DEPRECATED_ALIASES` (one table).

:func:`grade_params` maps a grade onto the fields of any core's config dataclass (the fields the class has; the
others are left alone), :func:`filters.registry.resolve_core_params` puts the explicit per-core parameters on top of it. The
presets, their numbers and their sources are in docs/imu_grades.md. The core dataclasses keep the papers'
defaults, which are presets too (``CORE_DEFAULT_GRADE``): ``paper_ship`` for the in-motion cores, ``paper_static``
for the static ones, ``paper_two_position`` for earth_iekf; the user-facing default (session, node,
insalign-align) is ``DEFAULT_IMU_GRADE``, a conservative prior for an unknown MEMS IMU.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from ..core.units import G0_M_S2

#: the bias random walk is the one that wanders by the bias instability in this time [h]
BIAS_RW_HORIZON_H = 1.0


@dataclass(frozen=True)
class ImuGrade:
    """Datasheet noise model of an IMU (1-sigma values; units in the names)."""

    name: str
    gyro_arw_deg_sqrt_h: float
    gyro_bias_deg_h: float
    gyro_bias_instability_deg_h: float
    acc_vrw_m_s_sqrt_h: float
    acc_bias_mg: float
    acc_bias_instability_mg: float
    #: where the numbers come from (docs/imu_grades.md has the table)
    source: str = ""
    #: velocity random walk along the vehicle's vertical [m/s/sqrt(h)], 0: ``acc_vrw_m_s_sqrt_h`` (road, engine and
    #: hull vibration in motion is mostly vertical; the in-motion cores put it on the body axis of the vertical)
    acc_vrw_up_m_s_sqrt_h: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", float) and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"imu grade {self.name!r}: {f.name} must be a finite number >= 0, got {v!r}")

    @classmethod
    def from_spec(cls, spec) -> "ImuGrade":
        """A simulator ImuSpec (sim/types.py: constant-in-run biases) as a grade (no bias instability)."""
        return cls(spec.name, spec.arw_deg_sqrt_h, spec.gyro_bias_deg_h, 0.0, spec.vrw_m_s_sqrt_h, spec.acc_bias_mg,
                   0.0, source=f"simulator ImuSpec {spec.name!r}")

    @classmethod
    def from_fields(cls, name: str, values: dict) -> "ImuGrade":
        """The grade held by a core configuration's fields (:data:`GRADE_FIELDS`; a missing one is 0)."""
        h = math.sqrt(BIAS_RW_HORIZON_H)
        v = {k: float(values.get(k, 0.0)) for k in GRADE_FIELDS}
        return cls(name, v["gyro_arw_deg_sqrt_h"], v["gyro_bias_deg_h"], v["gyro_bias_rw_deg_h_sqrt_h"] * h,
                   v["acc_vrw_m_s_sqrt_h"], v["acc_bias_mg"], v["acc_bias_rw_mg_sqrt_h"] * h,
                   source="core configuration fields", acc_vrw_up_m_s_sqrt_h=v["acc_vrw_up_m_s_sqrt_h"])

    @property
    def gyro_bias_rw_deg_h_sqrt_h(self) -> float:
        return self.gyro_bias_instability_deg_h / math.sqrt(BIAS_RW_HORIZON_H)

    @property
    def acc_bias_rw_mg_sqrt_h(self) -> float:
        return self.acc_bias_instability_mg / math.sqrt(BIAS_RW_HORIZON_H)

    def to_dict(self) -> dict:
        return asdict(self)


def _ug_sqrt_hz(x: float) -> float:
    """Accelerometer noise density [ug/sqrt(Hz)] -> VRW [m/s/sqrt(h)]."""
    return x * 1e-6 * G0_M_S2 * 60.0


def _dps_sqrt_hz(x: float) -> float:
    """Gyro noise density [deg/s/sqrt(Hz)] -> ARW [deg/sqrt(h)]."""
    return x * 60.0


#: named presets (docs/imu_grades.md: the numbers, their datasheets, and which simulated IMU each one covers)
GRADES: dict[str, ImuGrade] = {g.name: g for g in (
    ImuGrade("consumer_mems", _dps_sqrt_hz(0.014), 1800.0, 10.0, _ug_sqrt_hz(175.0), 20.0, 0.2,
             "Bosch BMI088 (gyro 0.014 deg/s/sqrt(Hz), zero-rate offset +-1 deg/s typ., bias stability 2 deg/h; "
             "accel 175 ug/sqrt(Hz), offset +-20 mg typ.), InvenSense ICM-42688-P (0.0028 deg/s/sqrt(Hz), "
             "+-0.5 deg/s; 70 ug/sqrt(Hz), +-20 mg): a raw chip, turn-on offsets not removed"),
    ImuGrade("industrial_mems", 0.4, 10.0, 10.0, 0.1, 1.0, 0.03,
             "Xsens MTi-1/MTi-3 (0.007 deg/s/sqrt(Hz), in-run 10 deg/h; 120 ug/sqrt(Hz), 0.03 mg in-run), "
             "Analog Devices ADIS16470 (ARW 0.34 deg/sqrt(h), in-run 8 deg/h); the in-run bias stability is the "
             "run bias sigma (the PKF paper's convention for its ADIS16488A): turn-on offsets removed (factory "
             "calibration and the driver's still-period offset); covers the simulator's automotive_mems and "
             "mems_5degh_1mg"),
    ImuGrade("tactical", 0.125, 1.0, 0.1, 0.02, 1.0, 0.05,
             "Honeywell HG1700-AG58 (gyro bias 1 deg/h, ARW 0.125 deg/sqrt(h); accel bias 1 mg, VRW 0.065 "
             "ft/s/sqrt(h) = 0.02 m/s/sqrt(h)), KVH 1750 (in-run 0.05 deg/h, 0.05 mg)"),
    ImuGrade("navigation", 0.002, 0.01, 0.0, _ug_sqrt_hz(10.0), 0.025, 0.0,
             "Honeywell HG9900 (0.003 deg/h, ARW 0.002 deg/sqrt(h); 25 ug), iXblue/Exail navigation-grade FOG IMUs "
             "(0.01 deg/h class); equal to the simulator's navigation_grade IMU"),
    ImuGrade("paper_ship", 2.0, 25.2, 0.5, 0.2, 0.2, 0.005,
             "PI-LIEKF paper Table 1/2 ship IMU (25.2 deg/h, 2.0 deg/sqrt(h), 0.2 mg, 0.2 m/s/sqrt(h)); the bias "
             "random walks are not in the paper (its Q has 0 there): the small values the cores always used"),
    ImuGrade("paper_static", 0.26, 5.1, 0.0, 0.029, 0.07, 0.0,
             "PKF paper Table 1, ADIS16488A (bias stability 5.1 deg/h and 0.07 mg used as the constant bias "
             "sigma; 0.26 deg/sqrt(h), 0.029 m/s/sqrt(h))"),
    ImuGrade("paper_two_position", 0.0003, 0.002, 0.0, _ug_sqrt_hz(20.0), 0.020, 0.0,
             "inverse-alignment paper Table 1 (0.002 deg/h, 0.0003 deg/sqrt(h), 20 ug, 20 ug/sqrt(Hz))"),
    ImuGrade("unknown_mems", 2.0, 360.0, 10.0, 0.2, 5.0, 0.1,
             "the default: no datasheet, only 'a MEMS IMU'. Noise at or above every MEMS datasheet above (ARW and "
             "VRW of the paper's ship IMU: 2x the BMI088's), and a vehicle's vibration in motion along its vertical "
             "(VRW 1.0 m/s/sqrt(h): a car's velocity against its reference, benchmarks/kitti_velocity_noise.py); "
             "turn-on biases of a factory-calibrated MEMS part, 0.1 deg/s (360 deg/h) and 5 mg 1-sigma; a raw "
             "consumer chip: consumer_mems", acc_vrw_up_m_s_sqrt_h=1.0),
)}
#: the user-facing default (SessionConfig.imu_grade, the node's imu_grade, insalign-align)
DEFAULT_IMU_GRADE = "unknown_mems"
#: the grade each core's dataclass defaults are (the papers' IMUs; test/test_imu_grade.py checks it)
CORE_DEFAULT_GRADE = {"liekf": "paper_ship", "pi_liekf": "paper_ship", "iekf": "paper_ship", "ekf": "paper_ship",
                      "liekf_backtrack": "paper_ship", "earth_iekf": "paper_two_position", "pkf": "paper_static",
                      "ekf10": "paper_static", "coarse": "paper_static"}
#: the preset matching each simulated scenario's IMU (sim/scenarios.py; docs/imu_grades.md): equal numbers, or
#: (car, park_drive, drive_stop_drive) the MEMS preset whose numbers cover (>=) the simulated IMU's
SCENARIO_IMU_GRADE = {"ship": "paper_ship", "car": "industrial_mems", "static": "paper_static",
                      "static_navgrade": "navigation", "two_position": "paper_two_position",
                      "park_drive": "industrial_mems", "park_drive_vibration": "industrial_mems",
                      "park_drive_navgrade": "navigation",
                      "drive_stop_drive": "industrial_mems"}

#: config field -> its value from a grade. The cores' config classes name each datasheet number as the grade does
#: (each class has a subset of these fields): the noise densities, the 1-sigma biases (the initial bias sigma of a
#: core with bias states, the consider floor of one without, the covariance terms of coarse alignment) and the bias
#: random walks
_FIELD_FROM_GRADE = {
    "gyro_arw_deg_sqrt_h": lambda g: g.gyro_arw_deg_sqrt_h,
    "acc_vrw_m_s_sqrt_h": lambda g: g.acc_vrw_m_s_sqrt_h,
    "acc_vrw_up_m_s_sqrt_h": lambda g: g.acc_vrw_up_m_s_sqrt_h,
    "gyro_bias_deg_h": lambda g: g.gyro_bias_deg_h,
    "acc_bias_mg": lambda g: g.acc_bias_mg,
    "gyro_bias_rw_deg_h_sqrt_h": lambda g: g.gyro_bias_rw_deg_h_sqrt_h,
    "acc_bias_rw_mg_sqrt_h": lambda g: g.acc_bias_rw_mg_sqrt_h,
}
GRADE_FIELDS = tuple(_FIELD_FROM_GRADE)

#: THE table of deprecated parameter names (accepted for one release, with a warning, at every input boundary:
#: node parameters, ``ia.align``/``insalign-align`` keyword arguments and core parameters, YAML files):
#: old name -> (new name, factor: new value = factor x old value). docs/imu_grades.md lists them.
DEPRECATED_ALIASES = {
    "init_sigma_gyro_bias_deg_h": ("gyro_bias_deg_h", 1.0),
    "consider_gyro_bias_deg_h": ("gyro_bias_deg_h", 1.0),
    "init_sigma_acc_bias_mg": ("acc_bias_mg", 1.0),
    "consider_acc_bias_mg": ("acc_bias_mg", 1.0),
    "init_sigma_acc_bias_ug": ("acc_bias_mg", 1e-3),
    # not an IMU number, the same one table: a core's own status ALIGNED (AlignmentEstimate.status), not the aligned
    # flag, whose bounds are the flag criteria aligned.yaw_3sigma_deg / aligned.roll_pitch_3sigma_deg
    "aligned_yaw_3sigma_deg": ("status_yaw_3sigma_deg", 1.0),
}


def deprecation_message(old: str) -> str:
    new, factor = DEPRECATED_ALIASES[old]
    scale = "" if factor == 1.0 else f" (x {factor:g}: the unit changed)"
    return f"parameter {old!r} is deprecated: use {new!r}{scale}; the old name goes in the next release"


def apply_aliases(params: dict, warn=None) -> dict:
    """``params`` with every deprecated name (:data:`DEPRECATED_ALIASES`) replaced by its new name and value; one
    warning per old name (``warn(message)``; default: a FutureWarning, shown to users by default). An old and a new name given together
    with different values: ValueError. A dict without old names is returned as is."""
    if not any(k in DEPRECATED_ALIASES for k in params):
        return params
    out = {k: v for k, v in params.items() if k not in DEPRECATED_ALIASES}
    for old, value in params.items():
        if old not in DEPRECATED_ALIASES:
            continue
        new, factor = DEPRECATED_ALIASES[old]
        msg = deprecation_message(old)
        if warn is None:
            import warnings

            warnings.warn(msg, FutureWarning, stacklevel=3)
        else:
            warn(msg)
        v = value * factor if factor != 1.0 and isinstance(value, (int, float)) and not isinstance(value, bool) else value
        if new in out and out[new] != v:
            raise ValueError(f"{old}: deprecated name of {new!r}, given both with different values ({value!r}, "
                             f"{out[new]!r})")
        out[new] = v
    return out


def level_floor_rad(acc_bias_mg: float) -> float:
    """The level error [rad] an accelerometer bias of ``acc_bias_mg`` [mg] leaves while no manoeuvre separates it from
    the tilt: atan(b / g) (the static cores' floor, the aligned flag's level bound)."""
    return math.atan(max(float(acc_bias_mg), 0.0) * 1e-3)


def get_grade(grade) -> ImuGrade:
    """A preset name (or an ImuGrade, returned as is) -> ImuGrade; ValueError (one line) for an unknown name."""
    if isinstance(grade, ImuGrade):
        return grade
    if grade not in GRADES:
        raise ValueError(f"imu_grade: unknown IMU grade {grade!r}; choose one of {sorted(GRADES)}")
    return GRADES[grade]


def grade_params(grade, config_class) -> dict:
    """The fields of ``config_class`` (a core config dataclass) that the IMU grade sets: process noise (ARW, VRW),
    bias priors, bias random walks, consider biases. Fields the class does not have are left out."""
    g = get_grade(grade)
    names = {f.name for f in fields(config_class)}
    return {k: float(fn(g)) for k, fn in _FIELD_FROM_GRADE.items() if k in names}

