"""park_drive / park_drive_navgrade / drive_stop_drive (issue 14): exact IMU, rest and motion segments, bags."""

import numpy as np
import pytest

from insalign_ros.sim import error_model
from insalign_ros.sim.scenarios import SCENARIOS, make_scenario, rest_segments
from test_sim_scenarios import _integrate

SHORT = {  # shortened runs: drive-off, the first turn and (drive_stop_drive) a stop and a restart
    "park_drive": dict(duration_s=50.0, park_s=20.0, door_at_s=5.0),
    "park_drive_navgrade": dict(duration_s=50.0, park_s=20.0, door_at_s=5.0),
    "drive_stop_drive": dict(duration_s=95.0, park_s=2.0, stop_at_s=60.0, stop_s=15.0, door_at_s=65.0),
}
QUIET = dict(engine_acc_m_s2=0.0, engine_ang_deg=0.0, sway_ang_deg=0.0, door_at_s=-1.0, road_acc_m_s2=0.0,
             road_ang_deg=0.0)


@pytest.mark.parametrize("name", sorted(SHORT))
def test_exact_imu_integrates_back_to_the_truth(name):
    sc = make_scenario(name, seed=3, noise=False, **SHORT[name])
    att, pos = _integrate(sc)
    assert att < 1e-6, att
    assert pos < 0.05, pos


def test_grades():
    assert SCENARIOS["park_drive"].imu.gyro_bias_deg_h == 5.0 and SCENARIOS["park_drive"].imu.acc_bias_mg == 1.0
    assert SCENARIOS["park_drive_navgrade"].imu is error_model.NAVGRADE
    assert SCENARIOS["drive_stop_drive"].imu is SCENARIOS["park_drive"].imu


@pytest.mark.parametrize("name", ["park_drive", "drive_stop_drive"])
def test_segments_rest_then_motion(name):
    kw = SHORT[name]
    sc = make_scenario(name, seed=1, noise=False, **kw)
    segs = rest_segments(sc.params)
    assert segs[0] == (0.0, kw["park_s"]) and sc.params["motion_start_s"] == kw["park_s"]
    if name == "drive_stop_drive":
        assert segs[1] == (kw["stop_at_s"], kw["stop_at_s"] + kw["stop_s"])
    speed = np.linalg.norm(sc.v_n, axis=1)
    p0 = sc.lat_rad[0], sc.lon_rad[0]
    R = 6.37e6
    for a, b in segs:
        m = (sc.t_s >= a) & (sc.t_s < b)
        # engine vibration and the rocking of a person getting in (lever arm 0.4 m): centimetres per second at most
        assert speed[m].max() < 0.05, (a, speed[m].max())
        # ... and the vehicle does not travel: the position stays within 2 cm of where the segment started
        i = np.flatnonzero(m)
        dn = (sc.lat_rad[i] - sc.lat_rad[i[0]]) * R
        de = (sc.lon_rad[i] - sc.lon_rad[i[0]]) * R * np.cos(p0[0])
        assert np.hypot(dn, de).max() < 0.02
    # moving between the rest segments: faster than 1 m/s from 1 s after each drive-off to 2 s before each stop
    ends = [b for _, b in segs]
    starts = [a for a, _ in segs[1:]] + [sc.t_s[-1] + 2.0]
    for go, stop in zip(ends, starts):
        m = (sc.t_s >= go + 1.0) & (sc.t_s < stop - 2.0)
        assert speed[m].min() > 1.0, (go, speed[m].min())


@pytest.mark.parametrize("name", ["park_drive", "drive_stop_drive"])
def test_segment_times_are_exact_without_vibration(name):
    sc = make_scenario(name, seed=1, noise=False, **{**SHORT[name], **QUIET})
    speed = np.linalg.norm(sc.v_n, axis=1)
    for a, b in rest_segments(sc.params):
        at_rest = (sc.t_s >= a) & (sc.t_s <= b)
        assert speed[at_rest].max() < 1e-9
        just_after = (sc.t_s > b) & (sc.t_s < b + 0.1)
        assert speed[just_after].min() > 0.0
        if a > 0:  # the stop: still moving just before it
            assert speed[(sc.t_s > a - 0.1) & (sc.t_s < a)].min() > 0.0


def test_a_person_getting_in_tilts_the_parked_car():
    p = SHORT["park_drive"]
    sc = make_scenario("park_drive", seed=1, noise=False, **p)
    from insalign_ros.core import earth as E

    roll = np.degrees([E.rpy_from_C_b_n(C)[0] for C in sc.C_b_n[:: 25]])
    t = sc.t_s[::25]
    before, after = roll[t < p["door_at_s"]], roll[(t > p["door_at_s"] + 8) & (t < p["park_s"])]
    assert abs(np.median(after) - np.median(before) - 0.5) < 0.02  # the load's 0.5 deg


def test_park_drive_to_a_bag_and_back(tmp_path):
    from insalign_ros.cli.simulate import main
    from insalign_ros.io.bag import read_bag

    out = tmp_path / "pd"
    assert main(["park_drive", str(out), "--duration", "12", "--set", "park_s=8", "--set", "door_at_s=2"]) == 0
    d = read_bag(out)
    assert float(d.params["motion_start_s"]) == 8.0 and d.n == 12 * 125 + 1
