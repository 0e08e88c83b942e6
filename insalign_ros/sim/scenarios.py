"""Named, seedable scenarios: ship, car, static, static_navgrade, two_position.

``make_scenario(name, seed=0, duration_s=None, noise=True, **overrides) -> ScenarioData``

Every parameter of every preset, its unit and its source is in ``SCENARIOS`` (and in docs/scenarios.md, generated
from it). Data time starts at 0 s; the ECI epoch is t = 0. The truth is generated on the IMU grid, the IMU by
inverse navigation (sim/trajectory.py), the errors by sim/error_model.py, GNSS fixes on the grid at gnss_rate_hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.integrate import cumulative_simpson

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


def _car(t, p):
    # fine grid for the horizontal position integral (cumulative Simpson, error << 1e-6 m)
    tf = np.linspace(t[0], t[-1], 4 * (len(t) - 1) + 1)
    speed_f, head_f = _car_profiles(tf, p)
    ve_f, vn_f = speed_f * np.cos(head_f), speed_f * np.sin(head_f)
    pe_f = cumulative_simpson(ve_f, x=tf, initial=0.0)
    pn_f = cumulative_simpson(vn_f, x=tf, initial=0.0)
    s_f = cumulative_simpson(speed_f, x=tf, initial=0.0)  # distance along the path [m]
    pe, pn, s = pe_f[::4], pn_f[::4], s_f[::4]
    speed, heading = _car_profiles(t, p)
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
    lat0, lon0, h0 = params["lat_deg"] * D2R, params["lon_deg"] * D2R, params["h_m"]
    if preset.model == "ship":
        p_n, v_n, rpy = _ship(t_grid, params)
    elif preset.model == "car":
        p_n, v_n, rpy = _car(t_grid, params)
    elif preset.model == "static":
        p_n, v_n, rpy = _static(t_grid, params, rng)
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
    gnss_p_e = traj.p_e[sl][idx] + np.einsum("nij,nj->ni", C_ne, err_n)
    return ScenarioData(
        name=name, seed=int(seed), t0_s=0.0, t_s=t_s, omega_ib_b=omega, f_ib_b=f,
        C_b_n=traj.C_b_n[sl], lat_rad=traj.lat_rad[sl], lon_rad=traj.lon_rad[sl], h_m=traj.h_m[sl],
        v_n=traj.v_n[sl], gnss_t_s=t_s[idx], gnss_p_e=gnss_p_e, gnss_R_e=R_e, imu_spec=spec,
        gnss_sigma_m=float(params["gnss_sigma_h_m"]), bias_gyro_b=b_g, bias_acc_b=b_a,
        omega_ib_b_true=omega_true, f_ib_b_true=f_true,
        params={**params, "noise": bool(noise), "ref_lat_deg": params["lat_deg"], "ref_lon_deg": params["lon_deg"],
                "ref_h_m": params["h_m"]},
    )
