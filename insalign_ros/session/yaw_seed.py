"""Yaw from GNSS velocity in seconds: the Gaussian-sum yaw estimator (filters/yaw_gsf.py) as a session stage.

It runs beside the core on the IMU samples the session processes and on the GNSS velocity: the velocity topic when
there is one, else the velocity from consecutive fixes' differences (stamped at the middle of the interval, with
the covariance of both fixes). When its yaw is confident (``YawGsf.valid``) and the in-motion core's yaw is not
(the yaw bank of the sensors initialisation or of ``core: auto``'s hand-over, whose yaw 1-sigma is more than
``SEED_RATIO`` times the GSF's), the in-motion core is started again from its own estimate (position, velocity,
level and their covariance) with the GSF's yaw and variance instead of the bank. After that (or once the core's
yaw is as good as the GSF's) the stage stops.

The ``vehicle`` option (SessionConfig) sets what the GSF may assume (:func:`gsf_config`): land vehicles drive
along their x axis up to a side-slip (the course constraint), other platforms do not.

docs/yaw_gsf.md, "In the session".
"""

from __future__ import annotations

import math

import numpy as np

from ..core import earth
from ..core.types import GnssFix, GnssVelocity
from ..filters import registry
from ..filters.base import bias_indices, position_indices, velocity_indices
from ..filters.yaw_gsf import YawGsf, YawGsfConfig
from ..filters.measurements import GnssPosition, GyroBiasPrior
from .auto import AutoCore

D2R = math.pi / 180.0

#: the platforms of ``SessionConfig.vehicle`` and what the GSF assumes for each: (moves along its x axis,
#: side-slip 1-sigma of the course constraint [deg]; 0 = off)
VEHICLES = {
    "car": (True, 3.0),
    "wheeled_robot": (True, 5.0),
    "boat": (False, 0.0),
    "aircraft": (False, 0.0),
    "unknown": (False, 0.0),
}
#: what the status says each vehicle setting assumes
VEHICLE_ASSUMES = {
    "car": "drives along its x axis (side-slip 3 deg)",
    "wheeled_robot": "drives along its x axis (side-slip 5 deg)",
    "boat": "may move sideways (no course constraint)",
    "aircraft": "may move sideways (no course constraint)",
    "unknown": "nothing about the platform's motion (no course constraint)",
}
#: seed the core when its yaw 1-sigma is above this many GSF 1-sigmas
SEED_RATIO = 2.0
#: the GSF seeds once ``valid`` but for its yaw 1-sigma, which may be up to this [deg] (a bank of 8 hypotheses is
#: worth about 13 deg per hypothesis)
SEED_MAX_SIGMA_DEG = 5.0
#: the core's level replaces the GSF's AHRS tilt when its 1-sigma is this many times below the AHRS's, and at most
#: LEVEL_MAX_SIGMA_DEG [deg] (the AHRS's own tilt after a quiet start is 0.5 deg)
LEVEL_RATIO = 1.0
LEVEL_MAX_SIGMA_DEG = 1.0
#: the GSF's variance is inflated by this factor for the seed (the core starts no tighter than the GSF claims)
SEED_VAR_FACTOR = 1.5


def gsf_config(vehicle: str) -> YawGsfConfig:
    """The GSF configuration for a ``vehicle`` setting (unknown: PX4's pure GSF, no platform assumption)."""
    along, slip = VEHICLES[vehicle]
    return YawGsfConfig(vehicle_moves_along_forward_axis=along, side_slip_sigma_deg=slip)


class YawSeed:
    """The GSF stage. ``imu`` / ``imu_arrays`` with every processed IMU sample, ``fix`` / ``velocity`` with every
    GNSS input the fusion takes out of the buffer, ``check`` after them."""

    def __init__(self, session) -> None:
        self.s = session
        self.reset()

    def reset(self) -> None:
        self.gsf = YawGsf(gsf_config(self.s.cfg.vehicle))
        self.done = False
        self.seeded_by = ""  # what gave the in-motion core its yaw (the status)
        self._prev_fix: GnssFix | None = None
        self._have_topic = False
        self._parked = False  # core auto parked: the GSF waits for the hand-over (_takes)
        self.counters = {"gsf_velocities": 0, "gsf_seeds": 0, "gsf_core_levels": 0, "gsf_parked": 0}

    # ------------------------------------------------------------------ data
    def imu(self, t: float, w, f) -> None:
        if not self.done and not self._settled() and self._takes():
            self.gsf.propagate_arrays([t], [w], [f])

    def imu_arrays(self, T, W, F) -> None:
        if not self.done and not self._settled() and self._takes():
            self.gsf.propagate_arrays(T, W, F)

    def _takes(self) -> bool:
        """Whether the GSF takes data now: not while ``core: auto`` is parked (its detector has declared rest and
        there is no in-motion core yet). A parked vehicle's zero velocity holds no heading, there is no in-motion
        core to seed, and the GSF was a fifth of a parked session's time. A fresh GSF starts at the hand-over."""
        core = self.s.core
        parked = (isinstance(core, AutoCore) and core.motion is None and core.detector is not None
                  and core.detector.decision.decided and not core.detector.decision.moving)
        if parked != self._parked:
            self._parked = parked
            if parked:
                self.counters["gsf_parked"] += 1
            else:
                self.gsf = YawGsf(gsf_config(self.s.cfg.vehicle))
        return not parked

    def _settled(self) -> bool:
        """Stop the GSF (it costs a third of a default run) once it can no longer seed anything: the core is static
        for good (pkf, ekf10, coarse: no in-motion core to seed), or the aligned flag is up (the core's yaw 3-sigma
        is within the aligned threshold; a seed needs a GSF 1-sigma SEED_RATIO times below the core's)."""
        sess = self.s
        core = sess.core
        if core is None:
            return False
        if GnssPosition not in core.accepts and not isinstance(core, AutoCore):
            self.done, self.seeded_by = True, "not used (a static core)"
        elif sess.flag.aligned:
            self.done, self.seeded_by = True, self.seeded_by or "the core itself"
            sess.log("info", "yaw_seed", f"t={sess.processed_t:.2f} s: aligned flag up before the GSF seeded; GSF stopped")
        return self.done

    def fix(self, fix: GnssFix) -> None:
        """A fix: with the previous one, a velocity (unless the velocity topic gives them)."""
        if self.done:
            return
        prev, self._prev_fix = self._prev_fix, fix
        if not self._takes() or self._have_topic or prev is None:
            return
        t_mid, v_n, R_n = earth.velocity_from_fixes([prev.stamp_s, fix.stamp_s], [prev.p_e, fix.p_e], [prev.R_e, fix.R_e])
        if len(t_mid):
            self._update(float(t_mid[0]), v_n[0], R_n[0])

    def velocity(self, vel: GnssVelocity) -> None:
        if self.done or not self._takes():
            return
        self._have_topic = True
        self._update(float(vel.stamp_s), vel.v_n, vel.R_n)

    def _update(self, t: float, v_n, R_n) -> None:
        self._level_from_core()
        if self.gsf.update_velocity(t, v_n, R_n):
            self.counters["gsf_velocities"] += 1
        self.check()

    def _level_from_core(self) -> None:
        """Give the GSF the core's level when it is better than the GSF's own AHRS tilt (LEVEL_RATIO): a ship in
        waves never gives the accelerometer-only AHRS a quiet moment, while the core's level (static levelling, the
        in-motion core's fixes) is known to a fraction of a degree. The core is at the GSF's last IMU sample (both
        are fed the same samples before a GNSS input is fused)."""
        sess = self.s
        if sess.core is None or sess.bt is not None:
            return
        try:
            est = sess.outputs.estimate()
        except Exception:  # noqa: BLE001 - a core that cannot give an estimate gives no level either
            return
        P = np.asarray(est.P_att_n, float)
        var = max(float(P[0, 0]), float(P[1, 1]))
        if not (math.isfinite(var) and var <= (LEVEL_MAX_SIGMA_DEG * D2R) ** 2
                and var * LEVEL_RATIO ** 2 < self.gsf.tilt_var_rad2 and np.all(np.isfinite(est.C_b_n))):
            return
        r, p, _ = earth.rpy_from_C_b_n(np.asarray(est.C_b_n, float))
        self.gsf.set_level(float(r), float(p), var)
        self.counters["gsf_core_levels"] += 1

    # ------------------------------------------------------------------ seeding
    def check(self) -> None:
        """Seed the in-motion core when the GSF is valid and the core's yaw is not as good."""
        sess = self.s
        core = sess.core
        if self.done or core is None or not self.gsf.confident(SEED_MAX_SIGMA_DEG) or GnssPosition not in core.accepts \
                or sess.bt is not None:
            return
        est = core.estimate()
        var = self.gsf.yaw_var_rad2
        if not float(est.P_att_n[2, 2]) > SEED_RATIO ** 2 * var:
            sess.log("info", "yaw_seed", f"t={sess.processed_t:.2f} s: GSF confident (yaw 1-sigma {math.degrees(math.sqrt(var)):.2f} deg) after the core "
                                         f"found its yaw (1-sigma {math.degrees(math.sqrt(float(est.P_att_n[2, 2]))):.2f} deg)")
            self.done = True  # the core found its yaw first (gyrocompassing, the bank): nothing to seed
            self.seeded_by = self.seeded_by or "the core itself"
            return
        auto = isinstance(core, AutoCore)  # core: auto: its in-motion core is seeded
        target = core.motion if auto else core
        name, params = (core.cfg.motion_core, core.cfg.grade_params(core.cfg.motion_core)) if auto \
            else (sess.initialiser.core_name(sess.core_params), dict(sess.core_params))
        params["yaw_hypotheses"] = 1
        # core: auto starts its in-motion core from the gyro bias measured at rest (when it had one), as at its hand-over
        new = seeded_core(target, name, params, self.gsf.yaw_rad, SEED_VAR_FACTOR * var,
                          core.gyro_bias_prior if auto else None)
        if auto:
            core.replace_motion_core(new, f"yaw from GNSS velocity (GSF, 1-sigma {math.sqrt(var) / D2R:.2f} deg)")
        else:
            sess.core = new
            core.close()
        sess._est_memo = None
        self.done = True
        self.counters["gsf_seeds"] += 1
        self.seeded_by = (f"GNSS velocity ({'velocity topic' if self._have_topic else 'fix differences'}): GSF yaw "
                          f"{math.degrees(self.gsf.yaw_rad):.2f} deg, 1-sigma {math.degrees(math.sqrt(var)):.2f} deg")
        sess.log("info", "yaw_seed", f"in-motion core seeded at t={sess.processed_t + sess.stamp_offset_s:.3f} s with "
                                     f"the yaw from {self.seeded_by}")

    def diagnostics(self) -> dict:
        g = self.gsf
        d = {"vehicle": self.s.cfg.vehicle, "vehicle_assumes": VEHICLE_ASSUMES[self.s.cfg.vehicle],
             "yaw_seeded_by": self.seeded_by or "not yet (the yaw bank)",
             "gsf_valid": str(g.valid).lower(), **{k: str(v) for k, v in self.counters.items()}}
        if g.started and not self.done:
            d["gsf_yaw_deg"] = f"{math.degrees(g.yaw_rad):.2f}"
            d["gsf_yaw_sigma_deg"] = f"{math.degrees(math.sqrt(g.yaw_var_rad2)):.2f}"
        return d


def seeded_core(old, name: str, params: dict, yaw_rad: float, yaw_var_rad2: float, gyro_bias_prior=None):
    """A new core ``name`` started from ``old``'s estimate now (position, velocity, level and their covariance)
    with the yaw ``yaw_rad`` (ENU, of the body x axis) and its variance instead of ``old``'s; where the new core keeps
    a gyro bias, ``gyro_bias_prior`` (b_g_b [rad/s], 3x3 [rad^2/s^2]) or else the bias ``old`` learned."""
    est = old.estimate()
    rpy = earth.rpy_from_C_b_n(np.asarray(est.C_b_n, float))
    P_att = np.array(est.P_att_n, float)
    P_att[2, :] = P_att[:, 2] = 0.0
    P_att[2, 2] = yaw_var_rad2
    P = np.asarray(est.P, float)

    def sigma(ii: tuple, default: float) -> float:  # the largest 1-sigma of the three states ii
        if not ii or P.shape[0] <= max(ii):
            return default
        return math.sqrt(max(float(np.max(np.diag(P)[list(ii)])), 0.0))

    names = tuple(est.state_names)
    sig_v = max(sigma(velocity_indices(names), 0.5), 0.1)
    sig_p = max(sigma(position_indices(names), 2.0), 0.1)
    gyro = list(bias_indices(est.state_names, "bg"))
    new = registry.make_core(name, params)
    try:
        new.initialize(est.stamp_s, est.lat_rad, est.lon_rad, est.h_m, earth.C_b_n_from_rpy(rpy[0], rpy[1], yaw_rad),
                       np.asarray(est.v_n, float), P_att, sig_v, sig_p)
        if gyro_bias_prior is None and est.bias_gyro_b is not None and len(gyro) == 3 and P.shape[0] > max(gyro):
            # the gyro bias the old core learned, with its covariance
            gyro_bias_prior = (np.asarray(est.bias_gyro_b, float), P[np.ix_(gyro, gyro)].copy())
        if gyro_bias_prior is not None and GyroBiasPrior in new.accepts:
            new.update(GyroBiasPrior(*gyro_bias_prior, stamp_s=est.stamp_s))
    except Exception:
        new.close()
        raise
    return new
