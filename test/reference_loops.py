"""Bare filter loops: the reference oracles of the tests (not the way to run an alignment: that is
``insalign_ros.align`` / the session, session/).

* :class:`EventRunner` / :func:`run_offline`: feeds ``ImuSample`` / ``GnssFix`` events to an initialised core, one at a
  time (IMU samples at or before the initialisation stamp skipped, fixes older than it skipped; counted);
  :func:`initial_guess` builds the initial state from a truth sample plus an Euler error.
* :func:`run_static`: a static core with a zero-velocity update every ``round(rate / zupt_hz)`` samples.
* :func:`run_offline_backtrack`: the backtracking driver (filters/backtrack.py) over a whole data set, the passes run
  to completion at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from insalign_ros.core import earth
from insalign_ros.core.types import GnssFix, ImuSample
from insalign_ros.filters.backtrack import BacktrackingAligner
from insalign_ros.filters.base import AlignmentCore, AlignmentEstimate, UpdateResult
from insalign_ros.filters.measurements import GnssPosition, ZeroVelocity

D2R = math.pi / 180.0


@dataclass
class InitialGuess:
    """Arguments of AlignmentCore.initialize."""

    stamp_s: float
    lat_rad: float
    lon_rad: float
    h_m: float
    C_b_n: np.ndarray
    v_n: np.ndarray
    P_att_n: np.ndarray
    sigma_v_m_s: float
    sigma_p_m: float

    def apply(self, core: AlignmentCore) -> None:
        core.initialize(self.stamp_s, self.lat_rad, self.lon_rad, self.h_m, self.C_b_n, self.v_n, self.P_att_n,
                        self.sigma_v_m_s, self.sigma_p_m)


def initial_P_att_n(sigma_rpy_deg) -> np.ndarray:
    """Diagonal ENU attitude covariance [rad^2] from roll/pitch/yaw 1-sigma [deg] (small-angle mapping)."""
    s = np.asarray(sigma_rpy_deg, float) * D2R
    return np.diag(s * s)


def initial_guess(stamp_s, lat_rad, lon_rad, h_m, C_b_n_true, v_n, rpy_error_deg, cfg) -> InitialGuess:
    """Truth (or a user's guess) plus an Euler-angle error [deg] (roll, pitch, yaw added to the truth's Euler).

    P_att_n: diag of the config's init_sigma_{roll,pitch,yaw}_deg (see docs/inmotion_cores.md).
    """
    rpy = earth.rpy_from_C_b_n(np.asarray(C_b_n_true, float)) + np.asarray(rpy_error_deg, float) * D2R
    C_b_n = earth.C_b_n_from_rpy(*rpy)
    P_att = initial_P_att_n([cfg.init_sigma_roll_deg, cfg.init_sigma_pitch_deg, cfg.init_sigma_yaw_deg])
    return InitialGuess(float(stamp_s), float(lat_rad), float(lon_rad), float(h_m), C_b_n,
                        np.asarray(v_n, float).copy(), P_att, cfg.init_sigma_v_m_s, cfg.init_sigma_p_m)


@dataclass
class EventRunner:
    """Feeds events to an initialised core. Use ``feed(event)`` per message (node) or ``run(events)`` (offline)."""

    core: AlignmentCore
    init_stamp_s: float
    counters: dict = field(default_factory=lambda: {"imu": 0, "imu_skipped_before_init": 0, "gnss": 0,
                                                    "gnss_accepted": 0, "gnss_skipped_stale": 0})
    last_update: UpdateResult | None = None

    def feed(self, event) -> UpdateResult | None:
        if isinstance(event, ImuSample):
            if event.stamp_s <= self.init_stamp_s:
                self.counters["imu_skipped_before_init"] += 1
                return None
            self.counters["imu"] += 1
            self.core.propagate(np.array([event.stamp_s], float), np.asarray(event.omega_ib_b, float)[None],
                                np.asarray(event.f_ib_b, float)[None])
            return None
        if isinstance(event, GnssFix):
            self.counters["gnss"] += 1
            if event.stamp_s < self.init_stamp_s:
                self.counters["gnss_skipped_stale"] += 1
                return None
            res = self.core.update(GnssPosition.of(event))
            self.last_update = res
            if res.accepted:
                self.counters["gnss_accepted"] += 1
            return res
        raise TypeError(f"unknown event type {type(event).__name__}")

    def run(self, events, output_period_s: float = 0.5, progress=None) -> list[AlignmentEstimate]:
        """Feed all events; collect an estimate every output_period_s of data time and after each GNSS fix."""
        out: list[AlignmentEstimate] = []
        next_out = self.init_stamp_s
        for ev in events:
            res = self.feed(ev)
            if progress is not None and isinstance(ev, ImuSample):
                progress.update(1)
            if isinstance(ev, GnssFix) and res is not None:
                out.append(self.core.estimate())
                next_out = out[-1].stamp_s + output_period_s
            elif isinstance(ev, ImuSample) and ev.stamp_s >= next_out and ev.stamp_s > self.init_stamp_s:
                out.append(self.core.estimate())
                next_out = ev.stamp_s + output_period_s
        return out


def run_offline(core, data, rpy_error_deg, output_period_s: float = 0.5, init_index: int = 0, progress=None,
                initial_C_b_n=None):
    """Initialise ``core`` from the truth of ``data`` (a ScenarioData) at ``init_index`` plus an Euler error
    (or from ``initial_C_b_n`` when the data have no truth), feed all later events, return the estimates."""
    k = init_index
    if data.has_truth:
        C0 = data.C_b_n[k]
        lat, lon, h = data.lat_rad[k], data.lon_rad[k], data.h_m[k]
        if data.v_n is not None:
            v0 = data.v_n[k]
        else:  # truth without velocity (e.g. a bag's truth topic): central difference of the truth positions
            a, b = max(k - 1, 0), min(k + 1, data.n - 1)
            pa = earth.geodetic_to_ecef(data.lat_rad[a], data.lon_rad[a], data.h_m[a])
            pb = earth.geodetic_to_ecef(data.lat_rad[b], data.lon_rad[b], data.h_m[b])
            v0 = earth.C_e_n(lat, lon) @ (pb - pa) / (data.t_s[b] - data.t_s[a])
    else:
        if initial_C_b_n is None:
            raise ValueError("the data have no truth: give an initial attitude guess")
        C0 = np.asarray(initial_C_b_n, float)
        j = int(np.searchsorted(data.gnss_t_s, data.t_s[k]))
        lat, lon, h = earth.ecef_to_geodetic(data.gnss_p_e[min(j, len(data.gnss_t_s) - 1)])
        v0 = np.zeros(3)
    guess = initial_guess(data.t_s[k], lat, lon, h, C0, v0, rpy_error_deg, core.cfg)
    guess.apply(core)
    runner = EventRunner(core, float(data.t_s[k]))
    ests = runner.run(data.events(start=k), output_period_s=output_period_s, progress=progress)
    return ests, runner


def run_static(core: AlignmentCore, sc, az0_rad: float, sigma_R_m_s: float, zupt_hz: float = 10.0,
               init_sigma_yaw_deg: float = 100.0, init_sigma_level_deg: float = 2.0, record_hz: float = 1.0):
    """Run a static core on a ScenarioData from the true attitude turned by az0 about Up.

    Returns (t_s, err_rad (K, 3): psi = heading_error_enu_rad(est, true) [E, N, U], sigma3_rad (K, 3)).
    The zero-velocity update runs every round(rate/zupt_hz) IMU samples.
    """
    C0 = earth.C_b_n_from_rpy(0.0, 0.0, az0_rad) @ sc.C_b_n[0]
    P0 = np.diag(np.radians([init_sigma_level_deg, init_sigma_level_deg, init_sigma_yaw_deg]) ** 2)
    core.initialize(float(sc.t_s[0]), float(sc.lat_rad[0]), float(sc.lon_rad[0]), float(sc.h_m[0]), C0,
                    np.zeros(3), P0, 0.01, 1.0)
    rate = 1.0 / float(sc.t_s[1] - sc.t_s[0])
    every = max(1, int(round(rate / zupt_hz)))
    rec = max(1, int(round(rate / record_hz)))
    ts, errs, sig = [], [], []
    for k in range(1, sc.n):
        core.propagate(sc.t_s[k:k + 1], sc.omega_ib_b[k:k + 1], sc.f_ib_b[k:k + 1])
        if k % every == 0 and ZeroVelocity in core.accepts:
            core.update(ZeroVelocity(float(sc.t_s[k]), sigma_R_m_s))
        if k % rec == 0:
            e = core.estimate()
            ts.append(float(sc.t_s[k]))
            errs.append(earth.heading_error_enu_rad(e.C_b_n, sc.C_b_n[k]))
            sig.append(3.0 * np.sqrt(np.maximum(np.diag(e.P_att_n), 0.0)))
    return np.array(ts), np.array(errs), np.array(sig)


def run_offline_backtrack(core, data, rpy_error_deg, window_s: float, passes: int = 1, output_period_s: float = 1.0,
                          init_index: int = 0, covariance: str = "reset"):
    """Offline: initialise from the truth of ``data`` plus an Euler error, feed all events; at the end of the
    window run the passes to completion at once (zero catch-up). Returns (estimates, aligner)."""
    k = init_index
    guess = initial_guess(data.t_s[k], data.lat_rad[k], data.lon_rad[k], data.h_m[k], data.C_b_n[k], data.v_n[k],
                          rpy_error_deg, core.cfg)
    guess.apply(core)
    bt = BacktrackingAligner(core, float(data.t_s[k]), window_s, passes, covariance=covariance)
    out = []
    next_out = float(data.t_s[k])
    for ev in data.events(start=k):
        if isinstance(ev, ImuSample):
            bt.propagate([ev.stamp_s], np.asarray(ev.omega_ib_b, float)[None], np.asarray(ev.f_ib_b, float)[None])
        else:
            bt.update(GnssPosition.of(ev))
        if bt.busy:
            bt.run_until_done()
        if isinstance(ev, ImuSample) and ev.stamp_s >= next_out - 1e-9 and ev.stamp_s > data.t_s[k]:
            out.append(bt.estimate())
            next_out = ev.stamp_s + output_period_s
    return out, bt


def run_on_arrays(gsf, t_s, omega_ib_b, f_ib_b, vel_t_s, vel_n, vel_R_n, vel_arrival_s=None,
                  C_b_n_level=None) -> dict:
    """Drive a ``YawGsf`` (filters/yaw_gsf.py) through recorded arrays in time order and record it after every velocity.

    vel_arrival_s (k,): when each velocity becomes available (default: its stamp); a velocity from the difference of
    two fixes is stamped at the middle of the interval and arrives with the second fix. The IMU is propagated up to
    the arrival, then the velocity is fused at its stamp. Returns arrays over the velocities: t_s (arrival), yaw_rad,
    sigma_rad, valid, accepted.
    """
    t_s = np.asarray(t_s, float)
    vel_t_s = np.asarray(vel_t_s, float)
    arr = vel_t_s if vel_arrival_s is None else np.asarray(vel_arrival_s, float)
    out = {k: np.full(len(vel_t_s), np.nan) for k in ("t_s", "yaw_rad", "sigma_rad")}
    out["valid"] = np.zeros(len(vel_t_s), bool)
    out["accepted"] = np.zeros(len(vel_t_s), bool)
    i = 0
    for k in np.argsort(arr, kind="stable"):
        j = int(np.searchsorted(t_s, arr[k], side="right"))
        if j > i:
            gsf.propagate_arrays(t_s[i:j], omega_ib_b[i:j], f_ib_b[i:j],
                                 None if C_b_n_level is None else C_b_n_level[i:j])
            i = j
        out["accepted"][k] = gsf.update_velocity(float(vel_t_s[k]), vel_n[k], vel_R_n[k])
        out["t_s"][k] = arr[k]
        out["yaw_rad"][k] = gsf.yaw_rad
        out["sigma_rad"][k] = math.sqrt(gsf.yaw_var_rad2)
        out["valid"][k] = gsf.valid
    return out
