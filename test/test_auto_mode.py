"""core: auto (issue 14): parked -> static levelling -> static fine -> in motion -> aligned, on shortened park_drive
(MEMS and navigation grade) and drive_stop_drive runs; hand-over continuity; the flag follows the criteria."""

import math
import re

import numpy as np
import pytest
from scipy.stats import chi2

import insalign_ros as ia
from insalign_ros.core import earth
from insalign_ros.filters.base import AlignmentStatus
from insalign_ros.filters.imu_grade import GRADES, SCENARIO_IMU_GRADE
from insalign_ros.session.auto import AutoConfig
from insalign_ros.sim.scenarios import make_scenario

D2R = math.pi / 180.0
PARK_S = 26.0  # the static core's azimuth bootstrap takes the first 20 s


def _state(o) -> str:
    return o.estimate.reason.split(":")[0]


def _run(name, seed, **kw):
    """core auto on a scenario, with the IMU grade that matches the scenario's IMU (filters/imu_grade.py)."""
    d = make_scenario(name, seed=seed, **kw)
    return d, ia.align(d, core="auto", imu_grade=SCENARIO_IMU_GRADE[name])


def _auto_config(name) -> AutoConfig:
    g = GRADES[SCENARIO_IMU_GRADE[name]]
    return AutoConfig(gyro_bias_deg_h=g.gyro_bias_deg_h, acc_bias_mg=g.acc_bias_mg,
                      gyro_arw_deg_sqrt_h=g.gyro_arw_deg_sqrt_h)


@pytest.fixture(scope="module")
def mems():
    return _run("park_drive", 1, duration_s=PARK_S + 30.0, park_s=PARK_S, door_at_s=5.0, heading_deg=-120.0)


def test_park_drive_mems_levels_says_heading_needs_motion_then_aligns(mems):
    d, r = mems
    t = r.t_s
    lat = float(d.lat_rad[0])
    floor_lvl_deg = 1e-3 / D2R  # b_acc/g of the simulated IMU, 1 mg (the grade's 1 mg too)
    cfg = _auto_config("park_drive")
    floor_az_deg = cfg.azimuth_floor_rad(lat) / D2R
    # physics: the grade's gyro bias (10 deg/h) over the horizontal Earth rate 15.04 deg/h cos(lat)
    assert floor_az_deg == pytest.approx(math.degrees(cfg.gyro_bias_deg_h / (15.0411 * math.cos(lat))), rel=1e-3)
    states = [_state(o) for o in r.outputs]
    order = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert order == ["static, levelling", "static, fine", "in motion"], order
    # end of the park: level within 2x the b_acc/g floor; the status says the heading needs motion, with the floor
    k = int(np.flatnonzero(t < PARK_S - 0.3)[-1])
    o = r.outputs[k]
    lvl = np.abs(r.rpy_err_deg[k, :2])
    print(f"end of park: level error {lvl} deg (floor {floor_lvl_deg:.3f}), {o.status.value}: {o.reason}")
    assert lvl.max() < 2 * floor_lvl_deg
    assert o.status == AlignmentStatus.WAITING_FOR_MOTION and not o.aligned
    m = re.search(r"heading needs motion \(floor ([0-9.]+) deg", o.reason)
    assert m and float(m.group(1)) == pytest.approx(floor_az_deg, abs=0.05)
    # driving: flag up and |yaw| < 1 deg within 30 s of the first motion
    up = np.flatnonzero(r.aligned & (t > PARK_S))
    assert up.size, "flag never up after the drive-off"
    t_up = t[up[0]] - PARK_S
    yaw_last = abs(r.rpy_err_deg[-1, 2])
    print(f"flag up {t_up:.1f} s after the drive-off; |yaw error| at the end {yaw_last:.3f} deg")
    assert t_up < 30.0 and yaw_last < 1.0
    assert np.all(np.abs(r.rpy_err_deg[up, 2]) < 1.0)


def _jumps(r):
    """(stamp, |change of the attitude error| [deg], 3-sigma before [deg]) at every state change."""
    out = []
    for i in range(1, len(r.outputs)):
        a, b = r.outputs[i - 1], r.outputs[i]
        if _state(a) != _state(b) or a.status != b.status:
            out.append((b.stamp_s, _state(a), _state(b), np.abs(r.rpy_err_deg[i] - r.rpy_err_deg[i - 1]),
                        r.sigma3_deg[i - 1]))
    return out


def _flag_follows_criteria(r):
    up = r.aligned
    assert np.all(r.sigma3_deg[up, :2] < 1.0) and np.all(r.sigma3_deg[up, 2] < 2.5)


def test_default_grade_static_level_is_honest():
    """The default grade (unknown_mems: 360 deg/h, 5 mg priors) on a parked MEMS car: the heading is unobservable and
    the static core's level 3-sigma must not fall below 3 b_acc/g (the accelerometer bias and the tilt cannot be
    told apart at rest). With ekf10 as the static core seed 3 went 1.0 deg off at a 0.12-deg 3-sigma (the azimuth
    error state wandering through 360 deg made the body-frame accelerometer bias look observable); pkf keeps the
    biases as consider parameters: 0.08 deg, inside its 0.87-deg 3-sigma."""
    d = make_scenario("park_drive", seed=3, duration_s=40.0)
    r = ia.align(d, core="auto")  # every default: core auto, imu_grade unknown_mems, init from the sensors
    m = r.t_s > 5.0
    err, s3 = np.abs(r.rpy_err_deg[m, :2]), r.sigma3_deg[m, :2]
    floor3 = 3.0 * GRADES["unknown_mems"].acc_bias_mg * 1e-3 / D2R  # 3 b_acc/g [deg]
    assert np.all(err <= s3), (err.max(), s3.min())
    assert s3.min() >= 0.95 * floor3, (s3.min(), floor3)
    assert err.max() < 0.2  # the drawn bias is ~1 mg (0.057 deg): the estimate itself is good


def test_handover_continuity_and_flag(mems):
    _, r = mems
    jumps = _jumps(r)
    assert len(jumps) >= 2
    for t, a, b, dj, s3 in jumps:
        print(f"{t:.2f} s {a} -> {b}: jump {np.round(dj, 4)} deg, 3-sigma before {np.round(s3, 3)} deg")
        assert np.all(dj <= s3), (t, a, b, dj, s3)
    _flag_follows_criteria(r)


def test_park_drive_navgrade_heading_while_parked_and_flag_before_motion():
    park = 74.0
    d, r = _run("park_drive_navgrade", 2, duration_s=park + 3.0, park_s=park, door_at_s=5.0, heading_deg=75.0)
    t = r.t_s
    cfg = _auto_config("park_drive_navgrade")
    floor_az_deg = cfg.azimuth_floor_rad(float(d.lat_rad[0])) / D2R
    k = int(np.flatnonzero(t < park - 0.3)[-1])
    yaw = abs(r.rpy_err_deg[k, 2])
    # a shortened park is still ARW-limited: ARW / (omega_ie cos lat sqrt(T)) after T s of gyrocompassing (0.08 deg
    # at 74 s, 0.07 at 90 s); the bound is 2x the floor and that limit combined
    arw_deg = math.degrees(cfg.gyro_arw_deg_sqrt_h * D2R / 60.0 / (earth.OMEGA_IE_RAD_S * math.cos(d.lat_rad[0])
                                                                     * math.sqrt(park)))
    bound = 2.0 * math.hypot(floor_az_deg, arw_deg)
    first_up = t[np.flatnonzero(r.aligned)[0]] if r.aligned.any() else math.inf
    print(f"navgrade: |yaw error| at the end of the park {yaw:.4f} deg (azimuth floor {floor_az_deg:.4f}, ARW limit "
          f"{arw_deg:.4f}, bound {bound:.4f}); flag up at {first_up:.1f} s (drive-off {park} s)")
    assert yaw < bound
    assert first_up < park and r.aligned[k]
    assert "gyrocompassing" in r.outputs[k].reason
    after = [o for o in r.outputs if o.stamp_s > park + 1.0]
    assert after and all(_state(o) == "in motion" for o in after)
    assert r.diagnostics["core.heading_trusted"] == "true"
    for _, a, b, dj, s3 in _jumps(r):
        assert np.all(dj <= s3), (a, b, dj, s3)
    _flag_follows_criteria(r)


def test_drive_stop_drive_no_reset_yaw_inside_3sigma():
    stop_at, stop_s = 60.0, 10.0
    d, r = _run("drive_stop_drive", 4, duration_s=stop_at + stop_s + 12.0, park_s=2.0, stop_at_s=stop_at,
                stop_s=stop_s, door_at_s=stop_at + 4.0)
    c = r.counters
    assert c["time_resets"] == c["core_faults"] == c["divergences"] == 0
    assert r.diagnostics["core.handovers"] == "1"
    states = [_state(o) for o in r.outputs]
    order = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert order[-3:] == ["in motion", "stopped", "in motion"], order
    w = (r.t_s > stop_at - 5.0)
    ratio = np.abs(r.rpy_err_deg[w, 2]) / r.sigma3_deg[w, 2]
    print(f"yaw error / 3-sigma from 5 s before the stop to the end: max {ratio.max():.2f}; flag up "
          f"{r.aligned[w].mean():.0%} of the time")
    assert ratio.max() < 1.0
    assert r.aligned[w].all()  # the stop does not lose the alignment
    _flag_follows_criteria(r)


def test_config_refusals_and_cli_choice():
    for bad, what in [(dict(static_core="auto"), "static_core"), (dict(motion_core="nope"), "motion_core"),
                      (dict(stop_hold_sigma_m=0.0), "stop_hold_sigma_m"),
                      (dict(unknown_heading_hypotheses=1), "unknown_heading_hypotheses")]:
        with pytest.raises(ValueError, match=what):
            AutoConfig.from_dict(bad)
    from insalign_ros.session.config import SessionConfig

    assert SessionConfig.from_dict({"core": "auto"}).core == "auto"


def test_insalign_align_core_auto(tmp_path):
    from insalign_ros.cli.align import main

    assert main(["--scenario", "park_drive", "--core", "auto", "--duration", "6", "--out-dir", str(tmp_path),
                 "--no-progress"]) == 0
    assert (tmp_path / "park_drive_s0_auto.csv").exists()


def test_gyro_bias_from_rest_closed_form():
    """Synthetic rest data: bias + Earth rate + white noise (ARW) + a person getting in (0.5 deg roll step in 1 s).
    The bias from the rest window is the median of 1-s block means minus the known Earth rate (all of it with a
    trusted heading, the Up part only without), its sigma the closed form (ARW / sqrt(T) x sqrt(pi/2) up to the
    chi-square bound; bias instability; (Omega cos L)^2 / 2 per horizontal axis when the heading is unknown), and
    normalised error over 200 seeds covered at 2 sigma >= 0.95 per axis, RMS 0.6-1 (conservative by the bound)."""
    from insalign_ros.session.rest import REST_BLOCK_S, gyro_bias_from_rest, rest_rate_mean

    lat, T, rate = math.radians(48.0), 40.0, 100.0
    C_b_n = earth.C_b_n_from_rpy(math.radians(1.0), math.radians(-0.5), math.radians(150.0))
    w_ie_b = C_b_n.T @ earth.omega_ie_n(lat)
    b_true = np.radians(np.array([1.6, 2.6, -7.5]) / 3600.0)
    arw = math.radians(0.26) / 60.0  # [rad/sqrt(s)]
    n = int(T * rate)
    nb = int(T / REST_BLOCK_S)
    Om = earth.OMEGA_IE_RAD_S
    zs = []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        w = b_true + w_ie_b + arw * math.sqrt(rate) * rng.standard_normal((n, 3))
        w[2000:2100, 0] += math.radians(0.5)  # the load step: 0.5 deg of roll over 1 s
        blocks = w.reshape(nb, -1, 3).mean(axis=1)
        mean, var = rest_rate_mean(blocks)
        for trusted in (True, False):
            b, P = gyro_bias_from_rest(mean, var, C_b_n, lat, trusted, gyro_bias_instability_deg_h=0.0)
            z = (b - b_true) / np.sqrt(np.diag(P))
            if trusted:
                zs.append(z)
            else:  # the horizontal Earth rate left in, inside its uniform-on-circle sigma
                h = np.array([0.0, math.cos(lat) * Om, 0.0])
                assert np.allclose(b - b_true - (w_ie_b - C_b_n.T @ np.array([0, 0, Om * math.sin(lat)])),
                                   mean - b_true - w_ie_b, atol=1e-15)
                assert np.allclose(C_b_n @ (P - np.diag(var)) @ C_b_n.T,
                                   np.diag([0.5, 0.5, 0.0]) * (h[1] ** 2), atol=1e-18)
    zs = np.abs(np.array(zs))
    rms = float(np.sqrt(np.mean(zs ** 2)))
    print(f"normalised bias error: max {zs.max():.2f}, 2-sigma coverage {np.mean(zs < 2.0):.3f}, RMS {rms:.2f}")
    assert zs.max() < 4.0 and np.mean(zs < 2.0) >= 0.95 and 0.6 < rms < 1.0, (zs.max(), np.mean(zs < 2.0), rms)
    # the white-noise part of the sigma: ARW / sqrt(T) with the median's pi/2 and the 95 % chi-square bound
    expect = arw * arw / T * (math.pi / 2) * (nb - 1) / chi2.ppf(0.05, nb - 1)
    assert 0.5 * expect < float(np.mean(var)) < 1.6 * expect, (var, expect)
    # bias instability: the Allan floor is added on the diagonal
    b0, P0 = gyro_bias_from_rest(mean, var, C_b_n, lat, True, 0.0)
    b1, P1 = gyro_bias_from_rest(mean, var, C_b_n, lat, True, 10.0)
    assert np.allclose(np.diag(P1 - P0), math.radians(10.0 / 3600.0) ** 2) and np.allclose(b0, b1)


def test_handover_starts_the_inmotion_core_from_the_rest_bias(mems):
    """park_drive (MEMS 5 deg/h IMU, default unknown_mems grade prior 360 deg/h): the in-motion core starts from the
    rest bias, its sigma from the rest window and the grade's 10 deg/h instability (not the 360 deg/h prior), the
    truth inside 3 sigma; 45 s after the drive-off the flag is up and |yaw| < 1 deg."""
    d = make_scenario("park_drive", seed=4, duration_s=85.0, rate_hz=100.0, heading_deg=150.0, park_s=40.0)
    r = ia.align(d, core="auto")
    dg = r.diagnostics
    b = np.array([float(x) for x in dg["core.rest_gyro_bias_deg_h"].split()])
    s = np.array([float(x) for x in dg["core.rest_gyro_bias_sigma_deg_h"].split()])
    b_true = np.degrees(d.bias_gyro_b) * 3600.0
    print("rest bias", b, "sigma", s, "truth", b_true, "final yaw err", r.rpy_err_deg[-1, 2])
    assert np.all(np.abs(b - b_true) < 3.0 * s), (b, s, b_true)
    assert 10.0 <= s[2] < 25.0, s  # the Allan floor of unknown_mems <= sigma << the 360 deg/h prior
    assert r.aligned[-1] and abs(r.rpy_err_deg[-1, 2]) < 1.0, (r.metrics, r.rpy_err_deg[-1])


def test_stop_zero_rate_updates_hold_the_yaw_3sigma_through_a_stop():
    """drive_stop_drive with the default grade (unknown_mems: z gyro bias 360 deg/h prior, unobservable while driving
    straight): through a 25-s stop with a person getting in, the zero-angular-rate updates (1-s gyro means) estimate
    the z bias, so the yaw 3-sigma does not grow (it falls: yaw and z bias are correlated after driving) and the
    error stays inside it. The person's load step is rejected by the NIS gate. Without the updates
    (stop_zero_rate_min_blocks 0) the same stop ends at a 3.95 deg yaw 3-sigma (docs/session.md)."""
    stop_at, stop_s = 60.0, 25.0
    d = make_scenario("drive_stop_drive", seed=4, duration_s=stop_at + stop_s + 2.0, rate_hz=100.0, park_s=2.0,
                      stop_at_s=stop_at, stop_s=stop_s, door_at_s=stop_at + 10.0)
    r = ia.align(d, core="auto")
    stop = (r.t_s > stop_at + 3.0) & (r.t_s < stop_at + stop_s)
    s3, err = r.sigma3_deg[stop, 2], r.rpy_err_deg[stop, 2]
    dg = r.diagnostics
    print(f"yaw 3-sigma {s3[0]:.2f} -> {s3[-1]:.2f} deg through the stop, max |err|/3-sigma "
          f"{np.max(np.abs(err) / s3):.2f}; updates {dg['core.zero_rate_updates']}, rejected {dg['core.zero_rate_rejected']}")
    assert int(dg["core.zero_rate_updates"]) >= 15 and int(dg["core.zero_rate_rejected"]) >= 1, dg
    assert np.all(np.diff(s3) < 0.01) and s3[-1] < 2.0, (s3[0], s3[-1])
    assert np.all(np.abs(err) < s3)


def test_config_yaml_is_the_dataclass_and_gnss_velocity_reaches_the_inmotion_core():
    """config/auto.yaml = AutoConfig's defaults (grade fields excluded, as every core's file); a car already moving
    with GNSS velocities and a lever arm: the in-motion core fuses the velocities and gets the lever arm."""
    import yaml

    from insalign_ros.filters.imu_grade import GRADE_FIELDS

    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    p = dict(yaml.safe_load((root / "config" / "auto.yaml").read_text())["/**"]["ros__parameters"])
    assert p.pop("core") == "auto"
    assert p == {k: v for k, v in AutoConfig().to_dict().items() if k not in GRADE_FIELDS}
    d = make_scenario("car", seed=6, duration_s=15.0, gnss_vel_sigma_m_s=0.1)
    r = ia.align(d, core="auto", core_params={"gnss_lever_arm_b_m": [0.0, 0.0, 0.0]})
    assert r.counters["gnss_vel_accepted"] >= 10 and r.diagnostics["core.handovers"] == "1", r.counters
    assert AutoConfig(gnss_lever_arm_b_m=[0.5, 0.0, 1.5]).grade_params("iekf")["gnss_lever_arm_b_m"] == [0.5, 0.0, 1.5]


@pytest.mark.parametrize("over", [{}, {"speed_m_s": 4.0}, {"gnss_vel_sigma_m_s": 0.1}],
                         ids=["ship", "ship_4m_s", "ship_gnss_velocity"])
def test_moving_from_the_start_the_handover_level_is_honest(over):
    """The ship moves from its first sample (no snapshot at rest): the in-motion core's level comes from the IMU window
    the fixes' (or the GNSS velocities') change bounds, each sample turned into the hand-over's body frame
    (earth.level_from_window); before it, the last second's mean (the hull rolls 10 deg at 6 s) put 59 of 1200
    outputs' level outside its 3-sigma over these runs (with the velocity topic: 45 from the fixes' window)."""
    outside = n = 0
    for seed in range(3):
        r = ia.align(make_scenario("ship", seed=seed, duration_s=40.0, **over), imu_grade="paper_ship")
        out = np.any(np.abs(r.rpy_err_deg[:, :2]) > r.sigma3_deg[:, :2], axis=1)
        outside, n = outside + int(out.sum()), n + len(out)
    assert n == 1200 and outside <= 12, f"{outside} of {n} outputs with the level outside its 3-sigma"


def test_a_10hz_imu_gets_its_motion_detector_within_a_second():
    """The detector is built once 10 IMU intervals give the rate (1 s at 10 Hz, KITTI's rate; it was 25: 2.5 s) and
    takes the GNSS speeds of the fixes seen before it: a 10-Hz car that drives off 1.5 s after power-on is declared
    moving 1.0 s after its true speed passes 1 m/s (it was 2.5 s)."""
    for seed in range(2):
        d = make_scenario("car", seed=seed, duration_s=12.0, rate_hz=10.0)
        speed = np.linalg.norm(np.asarray(d.v_n)[:, :2], axis=1)
        t_1m_s = float(d.t_s[np.argmax(speed > 1.0)])
        r = ia.align(d)
        t_motion = next(o.stamp_s for o in r.outputs if "in motion" in o.reason)
        assert 0.0 < t_motion - t_1m_s <= 1.2, (seed, t_1m_s, t_motion)


def test_moving_at_power_on_is_not_called_static_while_auto_waits_for_its_fixes():
    """The fixes before auto's start (the one that gave its position, older ones within 3 s) are shown to it, as the
    fixes it observes while static (never fused: Initialiser.show_earlier_gnss), so its motion detector takes their
    speed at once; while the in-motion core waits for three fixes of its own, the state is "starting in motion". The
    ship moves from its first sample: the status said "static, levelling" until 2.94 s (motion declared at 2.34 s);
    now until the detector's first decision, 1.14 s. The hand-over and every number are unchanged (3.01 s)."""
    for seed in range(2):
        r = ia.align(make_scenario("ship", seed=seed, duration_s=6.0))
        last_static = max(o.stamp_s for o in r.outputs if o.reason.startswith("static") or "; static" in o.reason)
        starting = [o.stamp_s for o in r.outputs if "starting in motion: moving since" in o.reason]
        moving = next(o.stamp_s for o in r.outputs if "in motion: motion since" in o.reason)
        assert last_static <= 1.5 and starting and starting[0] <= 1.5, (seed, last_static, starting[:1])
        assert 2.9 <= moving <= 3.2, moving  # the hand-over waits for three fixes of the in-motion core's own


@pytest.mark.parametrize("n_bad", [1, 2, 3, 5])
def test_a_block_of_fixes_off_while_parked_is_not_motion(n_bad):
    """Parked, a block of fixes 124 m east for 1-5 s (multipath), then back: its start and end are jumps in the fix
    sequence (session/guard.py ``sequence_jump``), which restart the GNSS speed's baseline instead of making a speed
    of 124 m/s. Before, that speed declared motion: a hand-over to the in-motion core on a parked vehicle, fed the bad
    fixes, 23-62 times off its 3-sigma until a divergence restart (benchmarks/fuzz_session.py). Now the state stays
    static. From 3 bad fixes on, the session's fix screen follows them as a new line; it used to drop the buffered
    fixes of the old line while a filter ran too, which left a hole the jump test could not bridge (motion again)."""
    from dataclasses import replace

    d = make_scenario("static", seed=0, duration_s=30.0)
    p = d.gnss_p_e.copy()
    for k in np.flatnonzero((d.gnss_t_s >= 12.0) & (d.gnss_t_s < 12.0 + n_bad)):
        lat, lon, _ = earth.ecef_to_geodetic(p[k])
        p[k] = p[k] + earth.C_n_e(lat, lon) @ np.array([124.0, 0.0, 0.0])
    r = ia.align(replace(d, gnss_p_e=p), core="auto", imu_grade=SCENARIO_IMU_GRADE["static"])
    states = {_state(o) for o in r.outputs}
    assert "in motion" not in states and "static, levelling" in states, states
    assert r.counters["divergences"] == 0 and r.counters["time_resets"] == 0
