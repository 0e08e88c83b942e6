"""Short pieces of benchmarks/real_data.py (docs/real_data.md) as tests.

Data-free: the evaluation's counts on a hand-made run, the first-motion rule, and that the benchmark's run equals
``ia.align``. On the real recordings (skipped with the reason when ../shared/data is absent), the acceptance lines of
issue 24 that the default pipeline meets today, with DEFAULT parameters and no truth:
  * KITTI 0042: no re-initialisation while the yaw is inside its 3-sigma; flag up >= 90 % after its first rise; yaw
    3-sigma coverage >= 0.95 while up; no flag-up output with |yaw err| > 3 deg (RT3003 floor 0.1 deg).
  * car_circles_vn100 and rover_canada: never flag up with |yaw err| > 3 deg against the references; an in-motion
    core's final yaw within the combined 3-sigma of its estimate and the reference's floor.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import real_data as RD

import insalign_ros as ia
from insalign_ros.core import earth
from insalign_ros.io import datasets as DS

SHARED = RD.shared_data_dir()


def _need(name: str) -> Path:
    if SHARED is None or not (SHARED / name).exists():
        pytest.skip(f"real data not available: ../shared/data/{name} is absent (read-only shared data, never copied "
                    "into the repo)")
    return SHARED


# ------------------------------------------------------------------------------------ data-free
def test_evaluate_counts_on_a_hand_made_run():
    """10 outputs 1 s apart; flag up from t=3 except t=6; yaw error 1 deg except 5 deg at t=8 (3-sigma 2 deg);
    a re-initialisation at t=4.5 with the yaw inside its 3-sigma (not needed) and one at t=8.5 after the 5-deg
    output (needed)."""
    t = np.arange(10.0)
    up = np.array([0, 0, 0, 1, 1, 1, 0, 1, 1, 1], bool)
    rpy = np.zeros((10, 3))
    rpy[:, 2] = 1.0
    rpy[8, 2] = 5.0
    res = SimpleNamespace(t_s=t, rpy_deg=rpy, sigma3_deg=np.tile([0.5, 0.5, 2.0], (10, 1)), aligned=up)
    run = RD.Run("x", res, [(4.5, "divergence", ""), (8.5, "divergence", "")])
    ref = DS.AttitudeReference("zero", t, np.zeros((10, 3)), np.zeros(3))
    e = RD.evaluate(run, ref, t_motion_s=1.0, t_start_s=0.0)
    assert e["t_flag_s"] == pytest.approx(2.0)  # first up at 3 s, motion at 1 s
    assert e["up_wrong"] == 1 and e["up_with_ref"] == 6 and e["n_up"] == 6
    assert e["coverage"][2] == pytest.approx(5 / 6) and e["coverage"][0] == pytest.approx(1.0)
    assert e["up_fraction"] == pytest.approx(5 / 6)  # down over [6, 7) of the 6 s after 3 s
    assert e["restarts"] == ["n", "N"]
    assert e["final_err"][2] == pytest.approx(1.0) and e["final_s3"][2] == pytest.approx(2.0)


def _fixes(t, e_m):
    lat0, lon0 = math.radians(45.0), math.radians(8.0)
    p = np.array([earth.enu_to_ecef(np.array([x, 0.0, 0.0]), lat0, lon0, 100.0) for x in e_m])
    return SimpleNamespace(gnss_t_s=t, gnss_p_e=p, t_s=np.arange(0.0, t[-1], 0.01))


def test_first_motion_from_the_fixes():
    t = np.arange(0.0, 30.0, 1.0)
    parked_then_1m_s = np.where(t < 10.0, 0.0, t - 10.0)
    assert 10.0 < RD.first_motion_s(_fixes(t, parked_then_1m_s)) <= 11.0  # never before the true start
    assert RD.first_motion_s(_fixes(t, 3.0 * t)) == 0.0  # moving from the start
    noise = np.random.default_rng(1).normal(0.0, 0.05, t.size)
    assert RD.first_motion_s(_fixes(t, noise)) is None  # parked, 5-cm fixes


def test_benchmark_run_equals_align():
    """The benchmark's run (offline.align plus a log callback) gives ia.align's outputs, on a simulated car."""
    data = ia.simulate("car", seed=3, duration_s=40.0)
    bare = RD.strip_truth(data)
    r = RD.run(bare, "iekf")
    a = ia.align(bare, core="iekf")
    assert np.array_equal(r.result.t_s, a.t_s) and np.array_equal(r.result.rpy_deg, a.rpy_deg)
    assert np.array_equal(r.result.aligned, a.aligned) and np.array_equal(r.result.sigma3_deg, a.sigma3_deg)
    assert len(r.restarts) == a.counters["divergences"] + a.counters["core_faults"] + a.counters["reinit_restarts"]


def test_fix_sigma_floor_keeps_larger_sigmas():
    data = ia.simulate("car", seed=1, duration_s=5.0)
    floored = RD.floor_fix_sigma(data, 3.0)
    for p_e, R0, R1 in zip(data.gnss_p_e, data.gnss_R_e, floored.gnss_R_e):
        lat, lon, _ = earth.ecef_to_geodetic(p_e)
        s0 = np.sqrt(np.diag(earth.C_e_n(lat, lon) @ R0 @ earth.C_n_e(lat, lon)))
        s1 = np.sqrt(np.diag(earth.C_e_n(lat, lon) @ R1 @ earth.C_n_e(lat, lon)))
        assert np.allclose(s1, np.maximum(s0, 3.0))


# ------------------------------------------------------------------------------------ the real recordings
def _one(name: str, core: str, which: int = 0, vehicle: str = "unknown", **load_kw):
    rec = RD.load(name, _need(name if not name.startswith("kitti") else "kitti_raw_oxts_sync"), **load_kw)[which]
    r = RD.run(rec.data, core, vehicle)
    return rec, r, [RD.evaluate(r, ref, rec.first_motion_s, float(rec.data.t_s[0])) for ref in rec.refs]


@pytest.mark.parametrize("core,which", [("auto", 0), ("iekf", 1)])
def test_kitti_0042_defaults_no_truth(core, which):
    """Default pipeline, no truth, 1-Hz fixes: the fix sigma as the RT3003 reports it (auto) and floored at 0.5 m
    (iekf). Issue 24's KITTI acceptance lines."""
    rec, r, (e,) = _one("kitti_0042", core, which)
    # issue 24: a car moving at >= 2 m/s is never called static: 0042 drives at 9.4 m/s from its first sample; auto's
    # state says so from its start (the fixes before it give the GNSS speed; "static, levelling" until 4.15 s before)
    assert core != "auto" or not any("static, " in o.reason for o in r.result.outputs)
    assert e["n_up"] > 0 and e["t_flag_s"] < 110.0  # today: 101 s (auto), 103 s (iekf, floored)
    assert "n" not in e["restarts"]  # no re-initialisation while the yaw is inside its 3-sigma
    assert e["up_fraction"] >= 0.9
    assert e["coverage"][2] >= 0.95
    assert e["up_wrong"] == 0
    assert abs(e["final_err"][2]) <= e["final_s3"][2] + 3 * rec.refs[0].floor_deg[2]


def test_kitti_0020_with_the_oxts_velocities_as_a_gnss_velocity_topic():
    """Issue 25's KITTI line with GNSS velocity: the RT3003's velocities at the 1-Hz fixes (1-3 cm/s
    vel_accuracy), `vehicle: car`, defaults, no truth. The velocity's sigma is raised to what the filter's model can
    use (session/guard.py model_floor_vel_m_s: timing within the 10-Hz IMU period at the car's acceleration, the
    IMU-rate integration in a turn, an unmodelled lever arm); without it the filter took the centimetre sigmas as
    they are, and the flag was up 0.48 of the time after its first rise (the NIS window over-confident), the pitch
    inside its 3-sigma on 0.61 of the flag-up outputs."""
    rec, _, (e,) = _one("kitti_0020", "auto", vehicle="car", gnss_velocity=True)
    # issue 25: within 10 s of the first motion (moving from the first sample): 9.6 s (11.1 s while the flag's NIS
    # test waited for a full window of 10 updates; aligned.nis_min_updates 5)
    assert rec.data.has_gnss_velocity and e["t_flag_s"] <= 10.0, e["t_flag_s"]
    assert e["restarts"] == [] and e["up_wrong"] == 0
    assert e["coverage"][2] >= 0.95 and e["coverage"][1] >= 0.9  # yaw 1.00, pitch 0.95 (was 0.61)
    assert e["up_fraction"] >= 0.9  # 0.94 (was 0.48)


def test_kitti_0042_iekf_started_in_a_turn_with_the_oxts_velocities_keeps_an_honest_level():
    """KITTI 0042 starts in a 25-deg/s turn at 10 m/s; iekf starts from the sensors at the second fix, with the
    RT3003's velocity at that stamp (2.8 cm/s) as its initial velocity. That velocity is consumed by the
    initialisation (not fused again at the same stamp), its sigma carries where it falls within the 10-Hz IMU
    period (a dt / sqrt(12), a the centripetal acceleration), and the first fix and velocity after a start get the
    guard's model floor from the gyros' turn (session/guard.py). Before, it was fused twice with 2.8 cm/s and no
    floor: the level was 0.5-0.7 deg off at a 3-sigma of 0.4 for the whole drive (pitch inside its 3-sigma on 0.48
    of the flag-up outputs, roll 0.63)."""
    rec, _, (e,) = _one("kitti_0042", "iekf", vehicle="car", gnss_velocity=True)
    assert rec.data.has_gnss_velocity and e["t_flag_s"] <= 10.0, e["t_flag_s"]  # 7.2 s (6.1 s over-confident)
    assert e["restarts"] == [] and e["up_wrong"] == 0
    assert e["coverage"][0] >= 0.95 and e["coverage"][1] >= 0.95, e["coverage"]  # 0.98 / 1.00


def test_kitti_0018_with_the_oxts_velocities_the_flag_stays_up():
    """KITTI 0018 with the RT3003's velocities (1-3 cm/s), `vehicle: car`, defaults: the 10-Hz rows sample the car's
    vibration, 2-5 cm/s of velocity error over a 1-s interval that the declared VRW (0.2 m/s/sqrt(h)) does not
    carry; the guard's floor takes it from the samples' second differences (session/guard.py _sampling_psd). Before,
    the velocities' NIS was 1.65x their dof and the NIS window dropped the flag for 15 % of the time after its first
    rise (0.85), the roll inside its 3-sigma on 0.90 of the flag-up outputs."""
    rec, _, (e,) = _one("kitti_0018", "auto", vehicle="car", gnss_velocity=True)
    assert e["restarts"] == [] and e["up_wrong"] == 0
    assert e["up_fraction"] >= 0.95, e["up_fraction"]  # 0.98
    assert min(e["coverage"]) >= 0.92, e["coverage"]  # 0.94 / 0.95 / 0.99


def test_kitti_0057_the_park_s_zero_velocity_innovations_do_not_hold_the_flag_after_the_drive_off():
    """KITTI 0057: parked 28 s, then driving for 9 s; `vehicle: car`, defaults, no truth. After auto's hand-over the
    flag's NIS window holds the in-motion core's fixes only (session/flag.py on_update's stream): the criteria hold
    before the recording ends (yaw 3-sigma under 2.5 deg 6.3 s after the first motion). Before, the park's
    zero-velocity innovations (a real car's vibration) stayed in the window: "NIS sum 168.5 above the chi-square
    band [13.8, 53.7] (over-confident)" to the end."""
    rec, r, _ = _one("kitti_0057", "auto", vehicle="car")
    last = r.result.outputs[-1]
    assert "NIS sum" not in last.reason and "in motion" in last.reason, last.reason
    assert last.reason.startswith("criteria hold") or last.aligned, last.reason


@pytest.mark.parametrize("name", ["kitti_0018", "kitti_0020"])
def test_kitti_centimetre_sigmas_no_needless_restart(name):
    """The RT3003's centimetre sigmas as reported, auto: the fix-sigma floor from the filter's own error budget
    (session/guard.py model_floor_m) leaves no re-initialisation (0018 had 2, none needed, all at sharp turns), the
    yaw 3-sigma covers every flag-up output (was 0.51 on 0018) and no flag is up with the yaw > 3 deg off. Flag up
    after its first rise (issue 24: >= 0.90): 0018 0.903 (the 1.6-s IMU gap at 156 s costs 22 s; with the datasheet's
    vertical velocity random walk instead of the default grade's 1.0 m/s/sqrt(h) along the vertical, 0.843: the NIS
    window also called the filter over-confident for 14 s at 213 s), 0020 1.00 (was 0.32)."""
    rec, _, (e,) = _one(name, "auto")
    assert e["restarts"] == []
    assert e["coverage"][2] >= 0.95 and e["up_wrong"] == 0
    assert e["up_fraction"] >= 0.9, e["up_fraction"]


def test_car_circles_flag_never_up_while_wrong():
    """car_circles_vn100 (VN-100, 1-Hz consumer GPS, no velocity): neither auto nor iekf raises the flag with
    |yaw err| > 3 deg against the course over ground or the AHRS; iekf's final yaw is inside the combined 3-sigma of
    its estimate and the reference's floor (the AHRS: 5 deg)."""
    name = "car_circles_vn100"
    for core in ("auto", "iekf"):
        rec, _, (e_cog, e_ahrs) = _one(name, core)
        assert e_cog["up_wrong"] == 0 and e_ahrs["up_wrong"] == 0
    fl = rec.refs[1].floor_deg[2]
    assert abs(e_ahrs["final_err"][2]) <= math.hypot(e_ahrs["final_s3"][2], 3 * fl)


def test_rover_first_90_s_iekf():
    """rover_canada, first 90 s (100-Hz IMU, 5-Hz fixes as the benchmark): the flag never up with |yaw err| > 3 deg
    against the reference pose; roll and pitch inside their 3-sigma plus the reference's floor at the end."""
    rec = RD.load("rover_canada", _need("rover_canada"))[0]
    data = rec.data.until(float(rec.data.t_s[0]) + 90.0)
    r = RD.run(data, "iekf")
    e = RD.evaluate(r, rec.refs[0], rec.first_motion_s, float(data.t_s[0]))
    assert e["up_wrong"] == 0
    fl = rec.refs[0].floor_deg
    for i in (0, 1):
        assert abs(e["final_err"][i]) <= e["final_s3"][i] + 3 * fl[i]


def test_table_prints_the_floor_and_one_row_per_core():
    data = RD.strip_truth(ia.simulate("car", seed=2, duration_s=5.0))
    t = data.t_s[::10]
    res = SimpleNamespace(t_s=t, rpy_deg=np.zeros((t.size, 3)), sigma3_deg=np.full((t.size, 3), 2.0),
                          aligned=np.zeros(t.size, bool), outputs=[])
    ref = DS.AttitudeReference("zero", t, np.zeros((t.size, 3)), np.array([0.03, 0.03, 0.1]), "a test reference")
    rec = RD.Recording("sim", data, [ref], None, "simulated")
    text = RD.table(rec, [RD.Run("iekf", res), RD.Run("ekf", res)], ref)
    assert "Physical floor (reference 1-sigma) roll/pitch/yaw: 0.03 / 0.03 / 0.10 deg" in text
    rows = [line for line in text.splitlines() if line.startswith(("| iekf", "| ekf"))]
    assert len(rows) == 2 and all(r.count("|") == 11 and "| never |" in r for r in rows)
