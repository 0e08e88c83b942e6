"""Named, seedable scenarios: ship, car, static, static_navgrade, two_position, park_drive, park_drive_navgrade,
park_drive_vibration (a real car's idle vibration), drive_stop_drive.

``make_scenario(name, seed=0, duration_s=None, noise=True, **overrides) -> ScenarioData``

Every parameter of every preset, its unit and its source is in ``SCENARIOS`` (and in docs/scenarios.md, generated
from it). Data time starts at 0 s; the ECI epoch is t = 0. The truth is generated on the IMU grid, the IMU by
inverse navigation (sim/trajectory.py), the errors by sim/error_model.py, GNSS fixes on the grid at gnss_rate_hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..core import earth
from . import error_model
from .trajectory import from_local_enu, imu_from_trajectory
from .types import ImuSpec, ScenarioData

D2R = math.pi / 180.0


@dataclass(frozen=True)
class Preset:
    """A scenario preset: its trajectory model, IMU, default parameters (name -> (value, unit, source))."""

    name: str
    description: str
    model: str
    imu: ImuSpec
    params: dict


_COMMON = {
    "gnss_rate_hz": (1.0, "Hz", "PI-LIEKF sec. 6: GPS 1 Hz"),
    "gnss_sigma_h_m": (1.0, "m", "PI-LIEKF Table 1: GPS position 1.0 m"),
    "gnss_sigma_v_m": (1.0, "m", "PI-LIEKF Table 1 (same sigma vertically)"),
    "h_m": (0.0, "m", "sea level"),
    "gnss_vel_sigma_m_s": (0.0, "m/s", "GNSS velocity output (ENU, at the antenna) 1-sigma; 0: none. PI-LIEKF Table 1 "
                                        "gives 0.1 m/s"),
    # the GNSS antenna in the body frame FLU [m]: fixes and velocities are generated at the antenna
    "gnss_lever_x_m": (0.0, "m", "antenna forward of the IMU (0: at the IMU, as in the paper)"),
    "gnss_lever_y_m": (0.0, "m", "antenna left of the IMU"),
    "gnss_lever_z_m": (0.0, "m", "antenna above the IMU"),
    # a GNSS outage (tunnel, underpass): no fix, GNSS velocity or GNSS heading stamped in [start, start + duration)
    "gnss_outage_start_s": (0.0, "s", "start of a GNSS outage (with gnss_outage_duration_s)"),
    "gnss_outage_duration_s": (0.0, "s", "GNSS outage length; 0: none (the draws of a seed do not change)"),
    # the vehicle's own sensors (drawn after everything else, only when on: a seed's other signals do not change)
    "wheel_speed_sigma_m_s": (0.0, "m/s", "wheel speed (along the body x axis) 1-sigma; 0: none"),
    "wheel_rate_hz": (10.0, "Hz", "wheel odometry rate (must divide the IMU rate)"),
    "wheel_scale_error": (0.0, "-", "wheel speed scale-factor error (0.02: reads 2 % high)"),
    "gnss_heading_sigma_deg": (0.0, "deg", "dual-antenna heading 1-sigma, at the fix stamps; 0: none (0.2: survey)"),
    "gnss_heading_baseline_yaw_deg": (0.0, "deg", "yaw of the antenna baseline in the body frame (0: along x)"),
}

SCENARIOS: dict[str, Preset] = {
    "ship": Preset(
        "ship", "Ship in waves, PI-LIEKF sec. 6 eqs. (44)-(45), Table 1 IMU/GPS", "ship", error_model.SHIP_IMU,
        {
            **_COMMON,
            "duration_s": (300.0, "s", "PI-LIEKF Figs. 3-6 (300 s)"),
            "lat_deg": (30.0, "deg", "not given in the paper; a Persian-Gulf latitude"),
            "lon_deg": (50.0, "deg", "not given in the paper"),
            "heading_deg": (45.0, "deg", "mean yaw (from East, CCW); not given in the paper"),
            "speed_m_s": (0.0, "m/s", "mean speed; the paper's eq. (45) has only the wave velocities"),
            "course_deg": (45.0, "deg", "direction of the mean speed (from East, CCW)"),
            "roll_amp_deg": (10.0, "deg", "eq. (44)"), "roll_period_s": (6.0, "s", "eq. (44)"),
            "pitch_amp_deg": (7.0, "deg", "eq. (44)"), "pitch_period_s": (5.0, "s", "eq. (44)"),
            "yaw_amp_deg": (5.0, "deg", "eq. (44)"), "yaw_period_s": (7.0, "s", "eq. (44)"),
            "amp_e_m": (10.0, "m", "eq. (45) A_x (displacement amplitude, papers README)"),
            "amp_n_m": (10.0, "m", "eq. (45) A_y"), "amp_u_m": (1.0, "m", "eq. (45) A_z"),
            "period_e_s": (7.0, "s", "eq. (45) T_x"), "period_n_s": (6.0, "s", "eq. (45) T_y"),
            "period_u_s": (8.0, "s", "eq. (45) T_z"),
        },
    ),
    "car": Preset(
        "car", "Land vehicle: start, accelerations, braking, 90-deg turns, S-curves, a gentle hill", "car",
        error_model.CAR_IMU,
        {
            **_COMMON,
            "duration_s": (300.0, "s", "same length as the ship runs"),
            "lat_deg": (49.0, "deg", "Karlsruhe (KITTI)"), "lon_deg": (8.4, "deg", "Karlsruhe (KITTI)"),
            "h_m": (115.0, "m", "Karlsruhe (KITTI)"),
            "heading_deg": (20.0, "deg", "initial yaw (from East, CCW)"),
            "cruise_speed_m_s": (15.0, "m/s", "urban/suburban cruise"),
            "hill_amp_m": (3.0, "m", "road height variation amplitude"),
            "hill_length_m": (1800.0, "m", "road height variation wavelength along the path (h is a function of "
                              "distance, so the car does not move vertically when stopped)"),
            "gnss_sigma_v_m": (2.0, "m", "typical single-frequency vertical accuracy"),
        },
    ),
    "static": Preset(
        "static", "Stationary vehicle, engine running (PKF paper sec. 5, ADIS16488A Table 1, 125 Hz, 1200 s)",
        "static", error_model.ADIS16488A,
        {
            **_COMMON,
            "duration_s": (1200.0, "s", "PKF paper sec. 5.2"),
            "lat_deg": (35.0, "deg", "papers README example (5 deg/h at 35 deg -> ~24 deg floor)"),
            "lon_deg": (51.4, "deg", "not given in the paper"), "h_m": (1200.0, "m", "not given in the paper"),
            "roll_deg": (1.0, "deg", "level angles of a parked car"), "pitch_deg": (-0.5, "deg", "parked car"),
            "heading_deg": (30.0, "deg", "yaw (from East, CCW)"),
            "engine_hz": (25.0, "Hz", "idle 1500 rpm, 2nd order of a 4-cylinder (assumption: the paper gives none)"),
            "engine_acc_m_s2": (0.05, "m/s^2", "amplitude of the engine's linear vibration (assumption)"),
            "engine_ang_deg": (0.005, "deg", "amplitude of the engine's angular vibration (assumption)"),
            "sway_hz": (1.3, "Hz", "body sway on the suspension (assumption)"),
            "sway_ang_deg": (0.02, "deg", "body sway amplitude (assumption)"),
            "rock_amp_deg": (0.0, "deg", "rms roll and pitch rocking of the parked car (wind, people, suspension); 0: "
                             "off. Issue 15: a real parked car rocked ~0.2 deg"),
            "rock_min_hz": (0.5, "Hz", "lowest rocking frequency (issue 15: 0.5-2 Hz)"),
            "rock_max_hz": (2.0, "Hz", "highest rocking frequency (issue 15: 0.5-2 Hz)"),
            "rock_components": (3.0, "-", "sinusoids per axis, frequencies uniform in [min, max] and phases drawn "
                                "per seed (assumption)"),
            "rock_yaw_ratio": (0.25, "-", "yaw rocking rms as a fraction of rock_amp_deg (assumption)"),
            "rock_lever_m": (0.5, "m", "IMU height above the rocking centre (suspension roll centre; assumption): "
                             "turns the rocking into linear motion of the IMU"),
        },
    ),
    "two_position": Preset(
        "two_position", "Static base, IMU turned 180 deg about the vertical half way (inverse-alignment paper)",
        "two_position", error_model.RINS_IMU,
        {
            **_COMMON,
            "duration_s": (300.0, "s", "inverse-alignment paper: 300 s alignment"),
            "lat_deg": (28.2, "deg", "Changsha (the authors' site; the paper gives no latitude)"),
            "lon_deg": (112.9, "deg", "Changsha"), "h_m": (50.0, "m", "assumption"),
            "roll_deg": (0.2, "deg", "turntable level (assumption)"), "pitch_deg": (-0.1, "deg", "assumption"),
            "heading_deg": (-0.626, "deg", "paper Table 2 position 1 (converted to our yaw convention: assumption)"),
            "rotate_at_s": (-1.0, "s", "start of the 180-deg turn; < 0 means duration/2"),
            "rotate_duration_s": (4.0, "s", "a smooth turn of a few seconds"),
        },
    ),
}
SCENARIOS["static_navgrade"] = replace(
    SCENARIOS["static"], name="static_navgrade", imu=error_model.NAVGRADE,
    description="static with a navigation-grade IMU (0.01 deg/h, 25 ug) so the floor is small",
)

#: A MEMS IMU for the parked-then-driving scenarios (issue 14: "5 deg/h, 1 mg"): the ADIS16488A noise densities
#: (ARW 0.26 deg/sqrt(h), VRW 0.029 m/s/sqrt(h), 125 Hz) with a 1 mg turn-on accelerometer bias.
PARK_MEMS = replace(error_model.ADIS16488A, name="mems_5degh_1mg", gyro_bias_deg_h=5.0, acc_bias_mg=1.0)

_PARK = {
    "engine_hz": (25.0, "Hz", "idle 750 rpm, 2nd order of a 4-cylinder (assumption, as in static)"),
    "engine_acc_m_s2": (0.05, "m/s^2", "amplitude of the engine's linear vibration (assumption, as in static)"),
    "engine_ang_deg": (0.005, "deg", "amplitude of the engine's angular vibration (assumption, as in static)"),
    "sway_hz": (1.3, "Hz", "body sway on the suspension (assumption, as in static)"),
    "sway_ang_deg": (0.02, "deg", "body sway amplitude (assumption, as in static)"),
    "engine_harmonics_acc_m_s2": (0.0, "m/s^2", "real-like idle vibration: RMS of the specific-force vector of engine "
                                  "harmonics (orders 0.5, 1, 1.5 of engine_hz, slowly modulated); 0: off. A real "
                                  "parked car: 0.25-0.4 (issue 24); park_drive_vibration sets 0.32"),
    "door_at_s": (30.0, "s", "a person gets in at this time (< 0: no one gets in); must be in the park/stop"),
    "door_tilt_deg": (0.5, "deg", "permanent roll from the added load (80 kg on one side, assumption)"),
    "door_rock_deg": (0.5, "deg", "peak of the damped rocking when the person sits down (assumption)"),
    "door_rock_hz": (1.5, "Hz", "body roll frequency on the suspension (assumption)"),
    "door_rock_decay_s": (0.4, "s", "time to the rocking's peak envelope, then e-fold decay (assumption)"),
    "rock_lever_m": (0.4, "m", "height of the IMU above the roll axis: the rocking moves the IMU sideways"),
    "drive_off_acc_m_s2": (1.5, "m/s^2", "normal drive-off/acceleration (assumption)"),
    "brake_acc_m_s2": (2.0, "m/s^2", "normal braking (assumption)"),
    "jerk_ramp_s": (0.5, "s", "time for the acceleration to build up (jerk about 3-4 m/s^3, comfort limit)"),
    "cruise_speed_m_s": (12.0, "m/s", "urban cruise"),
    "road_acc_m_s2": (0.5, "m/s^2", "vertical road vibration amplitude at 10 m/s, grows with speed (ISO 2631 ride "
                      "0.3-0.8 m/s^2; assumption)"),
    "road_ang_deg": (0.3, "deg", "road-induced pitch/roll amplitude at 10 m/s, grows with speed (assumption)"),
    **{k: SCENARIOS["car"].params[k] for k in ("hill_amp_m", "hill_length_m", "lat_deg", "lon_deg", "h_m")},
    "roll_deg": (1.0, "deg", "level angles of the parked car (as in static)"),
    "pitch_deg": (-0.5, "deg", "parked car (as in static)"),
    "heading_deg": (30.0, "deg", "yaw while parked (from East, CCW); random in the Monte Carlo benchmarks"),
}


SCENARIOS["park_drive"] = Preset(
    "park_drive", "Engine-on parked car (a person gets in), then drive-off, turns, braking (issue 14), MEMS IMU",
    "park_drive", PARK_MEMS,
    {
        **_COMMON, **_PARK,
        "duration_s": (180.0, "s", "issue 14: park, then about 90 s of driving"),
        "park_s": (90.0, "s", "length of the park; the drive-off starts here (params motion_start_s)"),
    },
)
SCENARIOS["park_drive_navgrade"] = replace(
    SCENARIOS["park_drive"], name="park_drive_navgrade", imu=error_model.NAVGRADE,
    description="park_drive with a navigation-grade IMU (0.01 deg/h, 25 ug)",
)
SCENARIOS["park_drive_vibration"] = replace(
    SCENARIOS["park_drive"], name="park_drive_vibration",
    description="park_drive with a real car's idle vibration (engine harmonics, 0.5-s specific-force spread ~0.33 "
    "m/s^2: over the motion detector's 0.25 prior)",
    params={**SCENARIOS["park_drive"].params, "engine_harmonics_acc_m_s2": (
        0.32, "m/s^2", "real-like idle vibration (issue 24: a real parked car showed a 0.255-0.266 m/s^2 spread)")},
)
SCENARIOS["drive_stop_drive"] = Preset(
    "drive_stop_drive", "Drive-off, driving, a long engine-on stop (a person gets in), driving again (issue 14), "
    "MEMS IMU", "drive_stop_drive", PARK_MEMS,
    {
        **_COMMON, **_PARK,
        "duration_s": (200.0, "s", "60 s of driving, a 60 s stop, driving to the end"),
        "park_s": (5.0, "s", "rest before the first drive-off (params motion_start_s)"),
        "stop_at_s": (70.0, "s", "the car comes to rest here (params stop_start_s)"),
        "stop_s": (60.0, "s", "length of the stop (issue 14: a long stop); drive-off at stop_at_s + stop_s"),
        "door_at_s": (90.0, "s", "a person gets in during the stop (< 0: no one)"),
    },
)


def _smoothstep(tau: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero first derivative at both ends: tau - sin(2 pi tau) / (2 pi) on [0, 1]."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau - np.sin(2.0 * np.pi * tau) / (2.0 * np.pi)


def _ship(t, p):
    w = {k: 2.0 * np.pi / p[f"period_{k}_s"] for k in ("e", "n", "u")}
    A = {"e": p["amp_e_m"], "n": p["amp_n_m"], "u": p["amp_u_m"]}
    cse = p["course_deg"] * D2R
    vmean = p["speed_m_s"] * np.array([math.cos(cse), math.sin(cse), 0.0])
    p_n = np.stack([A[k] * np.sin(w[k] * t) for k in ("e", "n", "u")], -1) + t[:, None] * vmean
    v_n = np.stack([A[k] * w[k] * np.cos(w[k] * t) for k in ("e", "n", "u")], -1) + vmean
    rpy = np.stack([
        p["roll_amp_deg"] * D2R * np.cos(2 * np.pi * t / p["roll_period_s"]),
        p["pitch_amp_deg"] * D2R * np.cos(2 * np.pi * t / p["pitch_period_s"]),
        p["heading_deg"] * D2R + p["yaw_amp_deg"] * D2R * np.cos(2 * np.pi * t / p["yaw_period_s"]),
    ], -1)
    return p_n, v_n, rpy


def _car_profiles(t, p):
    """Speed [m/s] and heading [rad] as smooth (C1 speed, continuous acceleration) functions of time."""
    T = p["duration_s"]
    V = p["cruise_speed_m_s"]
    # (start as fraction of duration, length [s], change): speed events then heading events
    speed_events = [(0.03, 10.0, V), (0.30, 5.0, -0.6 * V), (0.36, 6.0, 0.6 * V), (0.62, 4.0, -0.7 * V),
                    (0.70, 6.0, 0.7 * V), (0.93, 8.0, -V)]
    heading_events = [(0.20, 8.0, math.pi / 2), (0.45, 5.0, 0.5), (0.50, 5.0, -1.0), (0.55, 5.0, 0.5),
                      (0.75, 9.0, -math.pi / 2), (0.85, 6.0, 0.35)]
    speed = sum(dv * _smoothstep((t - f * T) / d) for f, d, dv in speed_events)
    heading = p["heading_deg"] * D2R + sum(dpsi * _smoothstep((t - f * T) / d) for f, d, dpsi in heading_events)
    return np.maximum(speed, 0.0), heading


def cumulative_simpson_even_nodes(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Integral of ``y(x)`` from ``x[0]`` to each even-index node ``x[0], x[2], ...`` by composite Simpson on a
    uniform grid of odd length: what ``scipy.integrate.cumulative_simpson(y, x=x, initial=0)[::2]`` gives (the
    same sums), written here because that function needs scipy >= 1.12 and Ubuntu 24.04's apt scipy is 1.11."""
    y, x = np.asarray(y, float), np.asarray(x, float)
    if x.ndim != 1 or x.shape[0] % 2 != 1 or y.shape[-1] != x.shape[0]:
        raise ValueError("cumulative_simpson_even_nodes: need matching 1-D grids of odd length")
    h = np.diff(x)
    if x.shape[0] > 1 and not np.allclose(h, h[0], rtol=1e-9, atol=0.0):
        raise ValueError("cumulative_simpson_even_nodes: the grid must be uniform")
    pairs = (h[0] if x.shape[0] > 1 else 0.0) / 3.0 * (y[..., 0:-2:2] + 4.0 * y[..., 1::2] + y[..., 2::2])
    return np.concatenate([np.zeros(y.shape[:-1] + (1,)), np.cumsum(pairs, axis=-1)], axis=-1)


def _car(t, p, profiles=None):
    """Car on a hilly road from speed/heading profiles (default: _car_profiles) -> (p_n, v_n, rpy)."""
    profiles = profiles or _car_profiles
    # fine grid for the horizontal position integral (cumulative Simpson, error << 1e-6 m)
    tf = np.linspace(t[0], t[-1], 4 * (len(t) - 1) + 1)
    speed_f, head_f = profiles(tf, p)
    ve_f, vn_f = speed_f * np.cos(head_f), speed_f * np.sin(head_f)
    pe, pn, s = cumulative_simpson_even_nodes(np.stack([ve_f, vn_f, speed_f]), tf)[:, ::2]  # s: along the path [m]
    speed, heading = profiles(t, p)
    k = 2 * np.pi / p["hill_length_m"]
    pu = p["hill_amp_m"] * np.sin(k * s)
    slope = p["hill_amp_m"] * k * np.cos(k * s)  # dh/ds
    vu = slope * speed
    p_n = np.stack([pe, pn, pu], -1)
    v_n = np.stack([speed * np.cos(heading), speed * np.sin(heading), vu], -1)
    # attitude: pitch follows the grade (nose up uphill -> negative pitch in REP 103) plus squat under
    # acceleration; roll leans out of turns. Derivatives by finite differences of smooth profiles are fine here:
    # they only shape the attitude, which the generator differentiates exactly.
    dt = t[1] - t[0]
    a_long = np.gradient(speed, dt)
    a_lat = speed * np.gradient(np.unwrap(heading), dt)
    grade = np.arctan(slope)
    pitch = -grade - 0.004 * a_long
    roll = -0.008 * a_lat
    return p_n, v_n, np.stack([roll, pitch, heading], -1)


def _static(t, p, rng):
    """Parked car, engine running: small attitude and position oscillations with zero mean."""
    ph = rng.uniform(0, 2 * np.pi, 8)
    fe, fs = p["engine_hz"], p["sway_hz"]
    we, ws = 2 * np.pi * fe, 2 * np.pi * fs
    a = p["engine_acc_m_s2"]
    # displacement amplitude a / w^2 per axis so the vibration acceleration amplitude is a; mean position fixed
    amp = a / we**2 * np.array([0.6, 0.8, 1.0])
    p_n = np.stack([amp[i] * np.sin(we * t + ph[i]) for i in range(3)], -1)
    v_n = np.stack([amp[i] * we * np.cos(we * t + ph[i]) for i in range(3)], -1)
    ang_e, ang_s = p["engine_ang_deg"] * D2R, p["sway_ang_deg"] * D2R
    rpy = np.stack([
        p["roll_deg"] * D2R + ang_e * np.sin(we * t + ph[3]) + ang_s * np.sin(ws * t + ph[4]),
        p["pitch_deg"] * D2R + ang_e * np.sin(1.7 * we * t + ph[5]) + 0.5 * ang_s * np.sin(ws * t + ph[6]),
        p["heading_deg"] * D2R + 0.5 * ang_e * np.sin(we * t + ph[7]),
    ], -1)
    if p["rock_amp_deg"] > 0:  # drawn only when on, so the quiet presets keep their random streams
        rock = _rocking(p, rng)
        rpy = rpy + rock(t)
        dp, dv = _rocking_lever(rock, t, p)
        p_n, v_n = p_n + dp, v_n + dv
    return p_n, v_n, rpy


def _ramp_integral(s, r):
    """Integral of _smoothstep(u / r) from -inf to s [s]: 0 before 0, s - r/2 after r (a C1 velocity ramp)."""
    tau = np.clip(s / r, 0.0, 1.0)
    return np.where(s >= r, s - 0.5 * r, r * (0.5 * tau**2 + (np.cos(2.0 * np.pi * tau) - 1.0) / (4.0 * np.pi**2)))


def _drive_plan(p, model):
    """Driving manoeuvres of park_drive / drive_stop_drive and the times of their rest segments.

    Returns (speed_events, heading_events, segments): speed events (t0_s, dv_m_s, acc_m_s2) change the speed by dv
    with an acceleration pulse of magnitude acc that builds up and decays over jerk_ramp_s (the speed changes from
    t0 to t0 + |dv|/acc + jerk_ramp_s); heading events (t0_s, duration_s, dpsi_rad) turn smoothly.
    """
    V, a_go, a_brk, r = p["cruise_speed_m_s"], p["drive_off_acc_m_s2"], p["brake_acc_m_s2"], p["jerk_ramp_s"]
    if min(V, a_go, a_brk, r) <= 0 or p["park_s"] < 0:
        raise ValueError("cruise_speed_m_s, drive_off_acc_m_s2, brake_acc_m_s2, jerk_ramp_s must be > 0, park_s >= 0")
    t0 = p["park_s"]
    speed = [(t0, V, a_go), (t0 + 25, -0.5 * V, a_brk), (t0 + 33, 0.5 * V, a_go), (t0 + 60, -0.4 * V, a_brk),
             (t0 + 66, 0.4 * V, a_go)]
    heading = [(t0 + 14, 8.0, math.pi / 2), (t0 + 40, 5.0, 0.5), (t0 + 45, 5.0, -1.0), (t0 + 50, 5.0, 0.5),
               (t0 + 72, 9.0, -math.pi / 2)]
    segments = {"motion_start_s": t0}
    if model == "drive_stop_drive":
        t_stop, t_go = p["stop_at_s"], p["stop_at_s"] + p["stop_s"]
        t_brake = t_stop - V / a_brk - r  # the braking pulse ends exactly at t_stop
        if t_brake < t0 + 50.0 or p["stop_s"] <= 0:
            raise ValueError("drive_stop_drive needs stop_at_s >= park_s + 56 s and stop_s > 0")
        speed = speed[:3] + [(t_brake, -V, a_brk), (t_go, V, a_go)]
        heading = heading[:4] + [(t_go + 15, 9.0, -math.pi / 2), (t_go + 35, 6.0, 0.35)]
        segments.update(stop_start_s=t_stop, stop_end_s=t_go)
    return speed, heading, segments


def _plan_profiles(t, p, plan):
    """Speed [m/s], heading [rad] and longitudinal acceleration [m/s^2] of a _drive_plan."""
    speed_events, heading_events, _ = plan
    r = p["jerk_ramp_s"]
    speed, accel = np.zeros_like(t), np.zeros_like(t)
    for t0, dv, acc in speed_events:
        a = math.copysign(acc, dv)
        t1 = t0 + abs(dv) / acc
        speed += a * (_ramp_integral(t - t0, r) - _ramp_integral(t - t1, r))
        accel += a * (_smoothstep((t - t0) / r) - _smoothstep((t - t1) / r))
    heading = p["heading_deg"] * D2R + sum(dpsi * _smoothstep((t - t0) / d) for t0, d, dpsi in heading_events)
    return np.maximum(speed, 0.0), heading, accel


def _vibration(t, p, rng, speed, accel):
    """Engine (always on), body sway, a person getting in, and road vibration growing with speed.

    Returns ENU position [m] and velocity [m/s] offsets (analytic derivatives of each other) and roll/pitch/yaw
    offsets [rad]. Every term is zero-mean or a step (the load tilt), so the vehicle does not travel while parked.
    """
    ph = rng.uniform(0.0, 2.0 * np.pi, 12)
    dp, dv, drpy = np.zeros((len(t), 3)), np.zeros((len(t), 3)), np.zeros((len(t), 3))
    we, ws = 2 * np.pi * p["engine_hz"], 2 * np.pi * p["sway_hz"]
    amp = p["engine_acc_m_s2"] / we**2 * np.array([0.6, 0.8, 1.0])  # acceleration amplitude engine_acc on Up
    dp += amp * np.sin(we * t[:, None] + ph[:3])
    dv += amp * we * np.cos(we * t[:, None] + ph[:3])
    ang_e, ang_s = p["engine_ang_deg"] * D2R, p["sway_ang_deg"] * D2R
    drpy += ang_e * np.sin(we * t[:, None] * np.array([1.0, 1.7, 1.0]) + ph[3:6]) * np.array([1.0, 1.0, 0.5])
    drpy[:, :2] += ang_s * np.sin(ws * t[:, None] + ph[6:8]) * np.array([1.0, 0.5])
    if p["door_at_s"] >= 0:  # load step over 1 s plus a damped rocking, both in roll about an axis below the IMU
        s = t - p["door_at_s"]
        on = s > 0
        tau, wr = p["door_rock_decay_s"], 2 * np.pi * p["door_rock_hz"]
        env = np.where(on, s / tau * np.exp(1.0 - np.where(on, s, 0.0) / tau), 0.0)
        denv = np.where(on, (1.0 - s / tau) / tau * np.exp(1.0 - np.where(on, s, 0.0) / tau), 0.0)
        A, tilt = p["door_rock_deg"] * D2R, p["door_tilt_deg"] * D2R
        phi = tilt * _smoothstep(s) + A * env * np.sin(wr * s)
        dphi = tilt * np.where((s > 0) & (s < 1), 1.0 - np.cos(2 * np.pi * s), 0.0) \
            + A * (denv * np.sin(wr * s) + env * wr * np.cos(wr * s))
        drpy[:, 0] += phi
        L, psi = p["rock_lever_m"], p["heading_deg"] * D2R
        left = np.array([-math.sin(psi), math.cos(psi), 0.0])  # body y in ENU while parked
        up = np.array([0.0, 0.0, 1.0])
        dp += np.outer(-L * np.sin(phi), left) + np.outer(L * (np.cos(phi) - 1.0), up)
        dv += np.outer(-L * np.cos(phi) * dphi, left) + np.outer(-L * np.sin(phi) * dphi, up)
    if p.get("engine_harmonics_acc_m_s2", 0.0) > 0:  # real-like idle: harmonics, amplitude modulated at ~0.3 Hz
        ph2 = rng.uniform(0.0, 2.0 * np.pi, 12)
        orders, rel = np.array([0.5, 1.0, 1.5]), np.array([0.5, 1.0, 0.6])
        axes = np.array([0.6, 0.8, 1.0])
        a0 = p["engine_harmonics_acc_m_s2"] * math.sqrt(2.0) / (np.linalg.norm(rel) * np.linalg.norm(axes))
        wm = 2 * np.pi * 0.3
        A = 1.0 + 0.2 * np.sin(wm * t + ph2[9])
        dA = 0.2 * wm * np.cos(wm * t + ph2[9])
        for i, (o, r) in enumerate(zip(orders, rel)):
            w = o * we
            c = a0 * r / w**2 * axes
            arg = w * t[:, None] + ph2[3 * i:3 * i + 3]
            dp += c * A[:, None] * np.sin(arg)
            dv += c * (dA[:, None] * np.sin(arg) + A[:, None] * w * np.cos(arg))
    # road: vertical body bounce (1.4 Hz) and wheel hop (11 Hz), pitch/roll, amplitudes proportional to speed
    k = speed / 10.0
    for f_hz, rel, phase in ((1.4, 1.0, ph[8]), (11.0, 0.6, ph[9])):
        w = 2 * np.pi * f_hz
        c = rel * p["road_acc_m_s2"] / w**2
        dp[:, 2] += c * k * np.sin(w * t + phase)
        dv[:, 2] += c * (accel / 10.0 * np.sin(w * t + phase) + k * w * np.cos(w * t + phase))
    drpy[:, 0] += p["road_ang_deg"] * D2R * k * np.sin(2 * np.pi * 1.1 * t + ph[10])
    drpy[:, 1] += p["road_ang_deg"] * D2R * k * np.sin(2 * np.pi * 1.7 * t + ph[11])
    return dp, dv, drpy


def _park_drive(t, p, rng, model):
    """park_drive / drive_stop_drive: the car model on a _drive_plan, parked level, plus _vibration."""
    plan = _drive_plan(p, model)
    p_n, v_n, rpy = _car(t, p, profiles=lambda tt, pp: _plan_profiles(tt, pp, plan)[:2])
    speed, _, accel = _plan_profiles(t, p, plan)
    dp, dv, drpy = _vibration(t, p, rng, speed, accel)
    rpy = rpy + drpy + np.array([p["roll_deg"], p["pitch_deg"], 0.0]) * D2R
    return p_n + dp, v_n + dv, rpy, plan[2]


def rest_segments(params: dict) -> list[tuple[float, float]]:
    """Intervals [t_start, t_end) [s] in which a park_drive / drive_stop_drive vehicle is parked (engine on)."""
    rest = [(0.0, float(params["motion_start_s"]))]
    if "stop_start_s" in params:
        rest.append((float(params["stop_start_s"]), float(params["stop_end_s"])))
    return rest

def _rocking(p, rng):
    """Rocking of a parked car: per axis (roll, pitch, yaw) a sum of K sinusoids with frequencies uniform in
    [rock_min_hz, rock_max_hz] and random phases; rms rock_amp_deg in roll and pitch, rock_yaw_ratio times it in yaw.
    Returns t [s] -> (n, 3) angle offsets [rad]."""
    K = max(1, int(round(p["rock_components"])))
    f = rng.uniform(p["rock_min_hz"], p["rock_max_hz"], (3, K))
    ph = rng.uniform(0.0, 2 * np.pi, (3, K))
    amp = p["rock_amp_deg"] * D2R * math.sqrt(2.0 / K) * np.array([1.0, 1.0, p["rock_yaw_ratio"]])

    def angles(t):
        t = np.asarray(t, float)[:, None, None]
        return np.sum(amp[:, None] * np.sin(2 * np.pi * f * t + ph), axis=-1)

    return angles


def _rocking_lever(rock, t, p):
    """ENU displacement [m] and velocity [m/s] of an IMU rock_lever_m above the rocking centre: (C(t) - C_0) r_b with
    C(t) the attitude of the level angles plus the rocking, r_b = [0, 0, lever]; velocity by a central difference of
    this analytic function (h = 1e-4 s: truncation ~1e-8 m/s at 2 Hz)."""
    from scipy.spatial.transform import Rotation

    base = np.array([p["roll_deg"], p["pitch_deg"], p["heading_deg"]]) * D2R
    r_b = np.array([0.0, 0.0, p["rock_lever_m"]])

    def pos(tt):
        rpy = base + rock(tt)
        return Rotation.from_euler("ZYX", rpy[:, ::-1]).apply(r_b) - Rotation.from_euler("ZYX", base[::-1]).apply(r_b)

    h = 1e-4
    return pos(t), (pos(t + h) - pos(t - h)) / (2 * h)


def _two_position(t, p):
    t_rot = p["rotate_at_s"] if p["rotate_at_s"] >= 0 else 0.5 * p["duration_s"]
    yaw = p["heading_deg"] * D2R + np.pi * _smoothstep((t - t_rot) / p["rotate_duration_s"])
    n = len(t)
    rpy = np.stack([np.full(n, p["roll_deg"] * D2R), np.full(n, p["pitch_deg"] * D2R), yaw], -1)
    return np.zeros((n, 3)), np.zeros((n, 3)), rpy


def antenna_position_velocity(traj, lever_b: np.ndarray):
    """ECEF position [m] and ENU velocity relative to Earth [m/s] of a GNSS antenna at ``lever_b`` (body FLU [m]):
    ``p_ant_e = p_e + C_n_e C_b_n l``; the velocity is the time derivative of p_ant_e (second-order differences on
    the grid: ``v_e + C_b_e (omega_eb_b x l)`` without approximating the rates), in ENU at the antenna."""
    from .trajectory import C_e_n_batch

    C_ne = np.transpose(C_e_n_batch(traj.lat_rad, traj.lon_rad), (0, 2, 1))
    arm_e = np.einsum("nij,njk,k->ni", C_ne, traj.C_b_n, np.asarray(lever_b, float))
    p_ant_e = traj.p_e + arm_e
    v_ant_e = traj.v_e + np.gradient(arm_e, traj.t_s, axis=0, edge_order=2)
    return p_ant_e, np.einsum("nji,nj->ni", C_ne, v_ant_e)


def scenario_parameters(name: str) -> dict:
    """Default parameter values of a preset (name -> value)."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {sorted(SCENARIOS)}")
    return {k: v[0] for k, v in SCENARIOS[name].params.items()}


def make_scenario(name: str, seed: int = 0, duration_s: float | None = None, noise: bool = True,
                  imu: ImuSpec | None = None, **overrides) -> ScenarioData:
    """Generate a scenario. overrides: any parameter of the preset (see SCENARIOS) or rate_hz."""
    params = scenario_parameters(name)
    preset = SCENARIOS[name]
    spec = imu or preset.imu
    if "rate_hz" in overrides:
        spec = replace(spec, rate_hz=float(overrides.pop("rate_hz")))
    unknown = set(overrides) - set(params)
    if unknown:
        raise ValueError(f"unknown parameter(s) {sorted(unknown)} for scenario {name!r}; known: {sorted(params)}")
    params.update({k: float(v) for k, v in overrides.items()})
    if duration_s is not None:
        params["duration_s"] = float(duration_s)
    if not params["duration_s"] > 0:
        raise ValueError("duration_s must be > 0")
    rng = np.random.default_rng(seed)
    dt = 1.0 / spec.rate_hz
    n = int(round(params["duration_s"] * spec.rate_hz)) + 1
    t_grid = (np.arange(n + 1) - 1) * dt  # one extra epoch before t = 0 for IMU sample 0
    segments = {}  # times of the motion segments (park_drive, drive_stop_drive)
    lat0, lon0, h0 = params["lat_deg"] * D2R, params["lon_deg"] * D2R, params["h_m"]
    if preset.model == "ship":
        p_n, v_n, rpy = _ship(t_grid, params)
    elif preset.model == "car":
        p_n, v_n, rpy = _car(t_grid, params)
    elif preset.model == "static":
        p_n, v_n, rpy = _static(t_grid, params, rng)
    elif preset.model in ("park_drive", "drive_stop_drive"):
        p_n, v_n, rpy, segments = _park_drive(t_grid, params, rng, preset.model)
    else:
        p_n, v_n, rpy = _two_position(t_grid, params)
    from scipy.spatial.transform import Rotation

    C_b_n = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix()
    traj = from_local_enu(t_grid, p_n, v_n, C_b_n, lat0, lon0, h0)
    omega_true, f_true = imu_from_trajectory(traj, t0_s=0.0)
    if noise:
        omega, f, b_g, b_a = error_model.corrupt(omega_true, f_true, spec, rng)
    else:
        omega, f, b_g, b_a = omega_true.copy(), f_true.copy(), np.zeros(3), np.zeros(3)
    # truth on t_grid[1:] (t = 0 .. duration)
    sl = slice(1, None)
    t_s = t_grid[sl]
    step = int(round(spec.rate_hz / params["gnss_rate_hz"]))
    if step < 1 or abs(spec.rate_hz / params["gnss_rate_hz"] - step) > 1e-9:
        raise ValueError("gnss_rate_hz must divide the IMU rate")
    idx = np.arange(0, n, step)
    lat, lon = traj.lat_rad[sl][idx], traj.lon_rad[sl][idx]
    sig = np.array([params["gnss_sigma_h_m"], params["gnss_sigma_h_m"], params["gnss_sigma_v_m"]])
    C_ne = np.array([earth.C_n_e(a, b) for a, b in zip(lat, lon)])
    R_e = C_ne @ np.diag(sig**2) @ np.transpose(C_ne, (0, 2, 1))
    err_n = rng.normal(0.0, 1.0, (len(idx), 3)) * sig if noise else np.zeros((len(idx), 3))
    lever_b = np.array([params["gnss_lever_x_m"], params["gnss_lever_y_m"], params["gnss_lever_z_m"]])
    p_ant_e, v_ant_n = antenna_position_velocity(traj, lever_b)
    gnss_p_e = p_ant_e[sl][idx] + np.einsum("nij,nj->ni", C_ne, err_n)
    # GNSS velocity at the fix stamps (drawn after the fixes: the fixes of a seed do not change)
    sig_v = params["gnss_vel_sigma_m_s"]
    if sig_v < 0:
        raise ValueError(f"gnss_vel_sigma_m_s must be >= 0 (0: no GNSS velocity), got {sig_v}")
    vel_idx = idx if sig_v > 0 else idx[:0]
    vel_n = v_ant_n[sl][vel_idx] + (rng.normal(0.0, sig_v, (len(vel_idx), 3)) if noise else 0.0)
    aux = _vehicle_signals(params, traj, sl, t_s, idx, spec.rate_hz, rng, noise)
    if params["gnss_outage_duration_s"] < 0:
        raise ValueError(f"gnss_outage_duration_s must be >= 0, got {params['gnss_outage_duration_s']}")
    # the outage removes what was drawn (every other signal of the seed stays as without it)
    t0_out, t1_out = params["gnss_outage_start_s"], params["gnss_outage_start_s"] + params["gnss_outage_duration_s"]
    up = ~((t_s[idx] >= t0_out) & (t_s[idx] < t1_out))
    idx, gnss_p_e, R_e = idx[up], gnss_p_e[up], R_e[up]
    if sig_v > 0:
        vel_idx, vel_n = vel_idx[up], vel_n[up]
    if "heading_t_s" in aux:  # at the fix stamps
        aux.update({k: aux[k][up] for k in ("heading_t_s", "heading_yaw_rad", "heading_var_rad2")})
    return ScenarioData(
        name=name, seed=int(seed), t0_s=0.0, t_s=t_s, omega_ib_b=omega, f_ib_b=f,
        C_b_n=traj.C_b_n[sl], lat_rad=traj.lat_rad[sl], lon_rad=traj.lon_rad[sl], h_m=traj.h_m[sl],
        v_n=traj.v_n[sl], gnss_t_s=t_s[idx], gnss_p_e=gnss_p_e, gnss_R_e=R_e, imu_spec=spec,
        gnss_sigma_m=float(params["gnss_sigma_h_m"]), bias_gyro_b=b_g, bias_acc_b=b_a,
        omega_ib_b_true=omega_true, f_ib_b_true=f_true,
        gnss_vel_t_s=t_s[vel_idx].copy() if sig_v > 0 else None, gnss_vel_n=vel_n if sig_v > 0 else None,
        gnss_vel_R_n=np.broadcast_to(sig_v**2 * np.eye(3), (len(vel_idx), 3, 3)).copy() if sig_v > 0 else None,
        params={**params, **segments, "noise": bool(noise), "ref_lat_deg": params["lat_deg"], "ref_lon_deg": params["lon_deg"],
                "ref_h_m": params["h_m"]}, **aux,
    )


def _vehicle_signals(params, traj, sl, t_s, idx, rate_hz, rng, noise) -> dict:
    """Wheel speed (the body x component of the true velocity, times 1 + wheel_scale_error, plus noise) at
    wheel_rate_hz and the dual-antenna heading (the ENU yaw of the body baseline, plus noise) at the fix stamps, when
    their sigmas are > 0 -> the ScenarioData fields."""
    out: dict = {}
    C, v = traj.C_b_n[sl], traj.v_n[sl]
    s_w = params.get("wheel_speed_sigma_m_s", 0.0)
    if s_w > 0:
        step = int(round(rate_hz / params["wheel_rate_hz"]))
        if step < 1 or abs(rate_hz / params["wheel_rate_hz"] - step) > 1e-9:
            raise ValueError("wheel_rate_hz must divide the IMU rate")
        k = np.arange(0, len(t_s), step)
        v_x = np.einsum("nj,nj->n", C[k][:, :, 0], v[k]) * (1.0 + params["wheel_scale_error"])
        out.update(wheel_t_s=t_s[k].copy(), wheel_speed_m_s=v_x + (rng.normal(0.0, s_w, len(k)) if noise else 0.0),
                   wheel_var_m2_s2=np.full(len(k), s_w**2))
    s_h = params.get("gnss_heading_sigma_deg", 0.0) * D2R
    if s_h > 0:
        b = params["gnss_heading_baseline_yaw_deg"] * D2R
        base_n = C[idx] @ np.array([math.cos(b), math.sin(b), 0.0])
        yaw = np.arctan2(base_n[:, 1], base_n[:, 0]) + (rng.normal(0.0, s_h, len(idx)) if noise else 0.0)
        out.update(heading_t_s=t_s[idx].copy(), heading_yaw_rad=np.remainder(yaw + np.pi, 2 * np.pi) - np.pi,
                   heading_var_rad2=np.full(len(idx), s_h**2))
    return out
