"""The aligned-flag criteria (insalign_ros/session/flag.py): pure, no ROS."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth
from insalign_ros.session.flag import (AlignedCriteria, AlignedFlag, attitude_3sigma_deg, euler_3sigma_deg,
                                      level_floor_3sigma_deg, nis_band)
from insalign_ros.session.session import AlignmentSession

D2R = math.pi / 180.0


def _P(s_roll_deg, s_pitch_deg, s_yaw_deg):
    return np.diag(np.square(np.array([s_roll_deg, s_pitch_deg, s_yaw_deg]) * D2R))


def test_nis_band_is_the_chi_square_quantile_of_the_window_sum():
    # chi-square with 30 dof: 0.5 % and 99.5 % quantiles (tables: 13.787, 53.672)
    lo, hi = nis_band(10, 3, 0.01)
    assert lo == pytest.approx(13.787, abs=1e-3) and hi == pytest.approx(53.672, abs=1e-3)


def test_flag_rises_after_the_hold_time_and_falls_at_once():
    c = AlignedCriteria(roll_pitch_3sigma_deg=1.0, yaw_3sigma_deg=2.0, nis_window=5, hold_s=3.0, max_update_age_s=2.0)
    f = AlignedFlag(c)
    good = _P(0.1, 0.1, 0.5)  # 3-sigma 0.3, 0.3, 1.5 deg
    rng = np.random.default_rng(0)
    t = 0.0
    raised = None
    for k in range(100):  # 10 s at 10 Hz, an update (NIS ~ chi2(3)) every second
        t = 0.1 * k
        if k % 10 == 0:
            f.on_update(t, True, float(rng.chisquare(3)))
        if f.on_estimate(t, good) and raised is None:
            raised = t
    # the NIS window fills at the 5th update (t = 4 s), then the 3 s hold: raised at t = 7 s
    assert raised == pytest.approx(7.0, abs=1e-9)
    # yaw 3-sigma above 2 deg: lowered at once, with the reason
    assert f.on_estimate(t + 0.1, _P(0.1, 0.1, 0.7)) is False
    assert "3-sigma yaw 2.10 deg" in f.reason
    # back below: the hold restarts
    assert f.on_estimate(t + 0.2, good) is False and "criteria hold for 0.0 of 3 s" in f.reason


def test_the_hold_counts_float_stamps_as_the_intervals_they_sum():
    """Output stamps are sums of float intervals: 14.04 plus twenty 0.1-s periods, minus 14.04, is 1.999999999999993;
    a 2-s hold passes there (the status said "criteria hold for 2.0 of 2 s" with the flag down, for one more output)."""
    c = AlignedCriteria(roll_pitch_3sigma_deg=1.0, yaw_3sigma_deg=2.0, nis_window=0, hold_s=2.0, max_update_age_s=5.0)
    f = AlignedFlag(c)
    good = _P(0.1, 0.1, 0.5)
    t0 = 14.04
    f.on_update(t0, True, 3.0)
    t, raised, stamps = t0, None, []
    for _ in range(30):
        stamps.append(t)
        if f.on_estimate(t, good) and raised is None:
            raised = t
        t += 0.1
    assert stamps[20] - t0 < 2.0  # the float arithmetic the test is about
    assert raised == stamps[20]


def test_flag_needs_fresh_updates_and_a_consistent_nis():
    c = AlignedCriteria(nis_window=4, hold_s=0.0, max_update_age_s=2.0)
    f = AlignedFlag(c)
    good = _P(0.1, 0.1, 0.3)
    assert not f.on_estimate(0.0, good) and "no accepted measurement update" in f.reason
    for k in range(4):
        f.on_update(float(k), True, 3.0)
    assert f.on_estimate(3.0, good)
    assert not f.on_estimate(5.5, good) and "2.5 s ago" in f.reason  # coasting on the IMU alone
    # an over-confident filter: NIS 20 per update, sum 80 > 99.5 % of chi2(12) = 28.3
    for k in range(4):
        f.on_update(6.0 + k, True, 20.0)
    assert not f.on_estimate(9.5, good) and "over-confident" in f.reason
    # rejected updates do not count, non-finite NIS neither
    f.on_update(10.0, False, 1.0)
    f.on_update(10.0, True, float("nan"))
    assert len(f.nis) == 4 and f.last_update_s == 9.0


def test_nis_test_starts_on_a_partial_window_with_the_band_of_the_updates_it_holds():
    """nis_min_updates (5): the window of 10 is tested from its 5th update on, against the chi-square band of the
    updates it holds (5 fixes x 3 dof: 99 % band [4.60, 32.80]); a sum outside that band fails as the full window's
    would, and below 5 updates the flag waits."""
    c = AlignedCriteria(nis_window=10, nis_min_updates=5, hold_s=0.0, max_update_age_s=5.0)
    good = _P(0.1, 0.1, 0.3)
    f = AlignedFlag(c)
    for k in range(4):
        f.on_update(float(k), True, 3.0)
    assert not f.on_estimate(3.5, good) and "NIS window filling (4/5 updates)" in f.reason
    f.on_update(4.0, True, 3.0)
    assert f.on_estimate(4.5, good) and f.band == pytest.approx(nis_band(5, 3, 0.01))
    assert f.band == pytest.approx((4.601, 32.801), abs=1e-3)
    over = AlignedFlag(c)
    for k in range(5):  # sum 40 > 32.8 (but inside the full window's 53.7): over-confident on what it holds
        over.on_update(float(k), True, 8.0)
    assert not over.on_estimate(4.5, good) and "NIS sum 40.0 above the chi-square band [4.6, 32.8]" in over.reason
    full = AlignedFlag(AlignedCriteria(nis_window=10, nis_min_updates=10, hold_s=0.0))
    for k in range(5):
        full.on_update(float(k), True, 3.0)
    assert not full.on_estimate(4.5, good) and "NIS window filling (5/10 updates)" in full.reason


def test_the_nis_window_restarts_when_its_stream_changes():
    """The window tests one stream of innovations: core auto's parked static core answers the session's
    zero-velocity updates ("zupt"), its in-motion core the fixes ("gnss") after the hand-over. A park's
    over-confident zero-velocity innovations (a real car's vibration: NIS 80) do not count against the first fixes
    of the filter that drives (KITTI 0057: the sum 168 against [14, 54] held the flag down, test_real_data.py)."""
    c = AlignedCriteria(nis_window=10, nis_min_updates=5, hold_s=0.0, max_update_age_s=5.0)
    good = _P(0.1, 0.1, 0.3)
    f = AlignedFlag(c)
    for k in range(10):
        f.on_update(float(k), True, 80.0, source="zupt")
    assert not f.on_estimate(9.5, good) and "above the chi-square band" in f.reason
    for k in range(5):
        f.on_update(10.0 + k, True, 3.0)
    assert list(f.nis) == [3.0] * 5 and f.on_estimate(14.5, good), f.reason
    f.on_update(15.0, True, 80.0, source="zupt")  # and back: the fixes' window is not the zero-velocity one's
    assert list(f.nis) == [80.0]


def test_nis_hysteresis_keeps_the_flag_between_the_two_bands():
    """Once up, the NIS test lowers the flag only outside the 1 - nis_alpha_drop band (99.9 %: 62.2 for 10 fixes),
    not when the sum leaves the 99 % band (53.7); a flag that is down rises only inside the 99 % band."""
    c = AlignedCriteria(nis_window=10, hold_s=0.0, max_update_age_s=5.0)
    lo99, hi99 = nis_band(10, 3, 0.01)
    lo999, hi999 = nis_band(10, 3, 0.001)
    assert hi99 == pytest.approx(53.672, abs=1e-3) and hi999 == pytest.approx(62.162, abs=1e-3)
    good = _P(0.1, 0.1, 0.3)
    up = AlignedFlag(c)
    for k in range(10):
        up.on_update(float(k), True, 3.0)
    assert up.on_estimate(9.0, good)
    for k in range(10):  # sum 58: outside the 99 % band, inside the 99.9 % one
        up.on_update(10.0 + k, True, 5.8)
    assert up.on_estimate(19.0, good) and up.band[1] == pytest.approx(hi999)
    down = AlignedFlag(c)  # the same sum never raises a flag that is down
    for k in range(10):
        down.on_update(10.0 + k, True, 5.8)
    assert not down.on_estimate(19.0, good) and "above the chi-square band [13.8, 53.7]" in down.reason
    for k in range(10):  # sum 65 > 62.2: down, and the band to rise again is the 99 % one
        up.on_update(20.0 + k, True, 6.5)
    assert not up.on_estimate(29.0, good) and "NIS sum 65.0 above the chi-square band [10.8, 62.2]" in up.reason
    assert not up.on_estimate(29.1, good) and "[13.8, 53.7]" in up.reason


def test_roll_pitch_threshold_and_lower_nis_check():
    f = AlignedFlag(AlignedCriteria(nis_window=3, hold_s=0.0, nis_lower_check=True))
    for k in range(3):
        f.on_update(float(k), True, 0.01)
    assert not f.on_estimate(2.0, _P(0.5, 0.1, 0.1)) and "roll/pitch 1.50 deg" in f.reason
    assert not f.on_estimate(2.0, _P(0.1, 0.1, 0.1)) and "pessimistic" in f.reason


def test_level_bound_is_at_least_a_margin_over_the_grade_floor():
    """An accelerometer bias b tilts the level by atan(b / g), inseparable from the tilt until the vehicle turns: the
    default grade's 5 mg puts the level's 3-sigma floor at 0.859 deg, so a 1-deg bound made the flag wait for the
    covariance's last hundredths (a simulated car's pitch 3-sigma hovered at 0.93-1.03 deg for 12 s)."""
    floor = level_floor_3sigma_deg(5.0)
    assert floor == pytest.approx(3.0 * math.degrees(math.atan(5e-3)), rel=1e-12)
    assert floor == pytest.approx(0.8594, abs=1e-4)
    level_11 = _P(1.1 / 3.0, 1.1 / 3.0, 0.1)  # 3-sigma 1.1 / 1.1 / 0.3 deg
    f = AlignedFlag(AlignedCriteria(nis_window=0, hold_s=0.0), level_floor_deg=floor)
    f.on_update(0.0, True, 1.0)
    assert f.level_bound_deg == pytest.approx(1.5 * floor) and f.on_estimate(0.0, level_11)
    assert not f.on_estimate(0.1, _P(0.45, 0.1, 0.1))  # 1.35 deg > 1.289
    assert "1.29 deg (1.5 x the level floor 0.86 deg of the declared accelerometer bias)" in f.reason
    off = AlignedFlag(AlignedCriteria(nis_window=0, hold_s=0.0, level_floor_factor=0.0), level_floor_deg=floor)
    off.on_update(0.0, True, 1.0)
    assert not off.on_estimate(0.0, level_11) and off.reason == "3-sigma roll/pitch 1.10 deg >= 1 deg"
    # a good IMU's floor is far below the bound: the bound is the user's
    assert AlignedFlag(level_floor_deg=level_floor_3sigma_deg(0.025)).level_bound_deg == 1.0
    # the session takes the floor from the declared grade, and from an explicit accelerometer bias over it
    assert AlignmentSession({}).flag.level_bound_deg == pytest.approx(1.5 * floor)
    assert AlignmentSession({"imu_grade": "navigation"}).flag.level_bound_deg == 1.0
    assert AlignmentSession({"core": "iekf"}, {"acc_bias_mg": 10.0}).flag.level_floor_deg == pytest.approx(
        level_floor_3sigma_deg(10.0))


@pytest.mark.parametrize("bad", [dict(yaw_3sigma_deg=0.0), dict(level_floor_factor=-1.0), dict(nis_alpha=1.0), dict(nis_alpha_drop=0.02),
                                 dict(nis_window=-1), dict(nis_min_updates=0), dict(hold_s=-1.0), dict(roll_pitch_3sigma_deg=float("nan"))])
def test_bad_criteria_are_refused(bad):
    with pytest.raises(ValueError):
        AlignedCriteria(**bad).validate()


def test_euler_3sigma_maps_enu_covariance_to_body_roll_pitch():
    P = _P(0.1, 0.4, 1.0)  # East, North, Up
    C0 = earth.C_b_n_from_rpy(0.0, 0.0, 0.0)  # body x = East: roll about East, pitch about North
    np.testing.assert_allclose(euler_3sigma_deg(C0, P), attitude_3sigma_deg(P), rtol=1e-5)
    C90 = earth.C_b_n_from_rpy(0.0, 0.0, 90 * D2R)  # body x = North: roll about North, pitch about -East
    np.testing.assert_allclose(euler_3sigma_deg(C90, P), [1.2, 0.3, 3.0], rtol=1e-5)
    # Monte Carlo check of the mapping at a generic attitude
    C = earth.C_b_n_from_rpy(8 * D2R, -5 * D2R, 130 * D2R)
    rng = np.random.default_rng(1)
    psi = rng.multivariate_normal(np.zeros(3), P, 20000)
    rpy = np.array([earth.euler_error_rad(Rotation.from_rotvec(p).as_matrix() @ C, C) for p in psi])
    np.testing.assert_allclose(3 * np.degrees(rpy.std(axis=0)), euler_3sigma_deg(C, P), rtol=0.03)
