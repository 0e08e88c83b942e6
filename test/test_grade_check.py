"""session/grade_check.py: the bias estimates against the declared imu_grade (issue 24, "a noise model the data can
correct").

For a consistent linear filter the estimate's move from its prior, b - b0, has the covariance P0 - P, so
z = |b - b0| / sqrt(P0 - P) is a standard normal per axis. A matched grade keeps z small; an IMU whose biases are 5x
its declared grade is named within 60 s of motion, with the factor it is off by, and the bias priors are widened.
"""

from dataclasses import replace

import numpy as np
import pytest

from insalign_ros.filters.imu_grade import get_grade
from insalign_ros.session.config import SessionConfig
from insalign_ros.session.flag import AlignedCriteria
from insalign_ros.session.offline import run_session
from insalign_ros.session.session import AlignmentSession
from insalign_ros.sim.error_model import CAR_IMU
from insalign_ros.sim.scenarios import make_scenario

GRADE = "industrial_mems"  # 10 deg/h, 1 mg: the simulated car's IMU (CAR_IMU) is of this grade


def _run(seed: int, bias_factor: float, duration_s: float = 120.0, with_outputs: bool = False):
    g = get_grade(GRADE)
    spec = replace(CAR_IMU, gyro_bias_deg_h=bias_factor * g.gyro_bias_deg_h, acc_bias_mg=bias_factor * g.acc_bias_mg)
    data = make_scenario("car", seed=seed, duration_s=duration_s, imu=spec)
    logs = []
    sess = AlignmentSession(SessionConfig.from_dict({"imu_grade": GRADE}), None, AlignedCriteria(),
                            log=lambda level, key, text: logs.append((sess.processed_t, key, text)))
    try:
        outs = run_session(sess, data, 0.0)
        z_max = sess.grade_check.z_max
        factor = sess.grade_check.factor
    finally:
        sess.close()
    notes = [(t, text) for t, key, text in logs if key == "grade_too_optimistic"]
    return (data, notes, z_max, factor, outs) if with_outputs else (data, notes, z_max, factor)


@pytest.mark.parametrize("seed", [0])
def test_a_matched_grade_is_not_named(seed):
    """Biases drawn from the declared grade: the statistic stays a standard normal's maximum over a few hundred tests
    (below 4; the threshold is 5), no note, no widening."""
    _, notes, z_max, factor = _run(seed, 1.0)
    assert notes == [] and factor == 1.0, notes
    assert 0.0 < z_max < 4.0, z_max  # > 0: the statistic ran on learned axes


@pytest.mark.parametrize("seed", [4])
def test_biases_5x_the_grade_are_named_within_60_s_of_motion_and_the_widened_covariance_covers(seed):
    """True biases 5x the grade (this seed's draw: gyro z 8.3 sigma, accelerometer y 8.2 sigma): the note names the
    grade within 60 s of the first motion (at 48 s, 43 s after it) with a factor of the order of the truth (2x-10x),
    and from then on no flag-up output has an attitude error outside its 3-sigma. The widening carries the wider bias
    priors to the attitude through the covariance's regression on the biases (filters/base.widen_biases): before it
    (the bias block alone, plus the tilt b/g), the yaw the 83-deg/h gyro bias had turned stayed 1.7 deg off at a
    3-sigma of 1.1-1.4 deg, 554 of 680 flag-up outputs after the naming outside it. Before the naming the flag is
    up with the level outside its 3-sigma (0.56 deg at 0.25): the first turn (25-31 s) gives the yaw its flag and the
    tilt/bias separation at once, and the fixes show the separation 10-20 s later (docs/session.md)."""
    data, notes, z_max, factor, outs = _run(seed, 5.0, with_outputs=True)
    g = get_grade(GRADE)
    true_k = max(np.max(np.abs(np.degrees(data.bias_gyro_b) * 3600.0)) / g.gyro_bias_deg_h,
                 np.max(np.abs(data.bias_acc_b)) / 9.80665e-3 / g.acc_bias_mg)
    assert true_k > 4.0, true_k  # the seed really is beyond the grade
    assert notes, (z_max, true_k)
    t_note, text = notes[0]
    speed = np.linalg.norm(data.v_n, axis=1)
    t_motion = float(data.t_s[np.argmax(speed > 0.5)])
    assert t_note - t_motion <= 60.0, (t_note, t_motion, text)
    assert f"imu_grade '{GRADE}' is too optimistic" in text and "noisier" in text, text
    assert 2.0 <= factor <= 10.0, (factor, true_k, text)
    after = [o for o in outs if o.stamp_s > t_note and o.aligned]
    assert len(after) > 300, len(after)  # the flag comes back after the widening
    outside = [o.stamp_s for o in after if np.any(np.abs(o.euler_error_deg) > o.euler_3sigma_deg)]
    assert not outside, (len(outside), outside[:3])


def test_widening_a_bias_prior_keeps_the_covariance_conditional_on_the_biases():
    """filters/base.widen_biases on a random covariance of [attitude, velocity, gyro bias, accelerometer bias]: the
    bias block gets exactly the added variance, the Gaussian's conditional covariance of the other states given the
    biases is unchanged (P_xx - P_xb P_bb^-1 P_bx: what the data say about them once the biases are known), the
    result is symmetric positive definite, and a state uncorrelated with the biases is untouched."""
    from insalign_ros.filters.base import widen_biases

    rng = np.random.default_rng(3)
    names = ["att_x", "att_y", "att_z", "v_x", "v_y", "v_z", "bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z", "clk"]
    A = rng.normal(size=(13, 13))
    P = A @ A.T + 0.1 * np.eye(13)
    P[12, :12] = P[:12, 12] = 0.0  # a state the biases do not touch
    var_bg, var_ba = 0.7, 0.2
    P2 = P.copy()
    widen_biases(P2, names, var_bg, var_ba)
    b, x = list(range(6, 12)), list(range(6)) + [12]

    def cond(M):
        return M[np.ix_(x, x)] - M[np.ix_(x, b)] @ np.linalg.solve(M[np.ix_(b, b)], M[np.ix_(b, x)])

    np.testing.assert_allclose(P2[np.ix_(b, b)], P[np.ix_(b, b)] + np.diag([var_bg] * 3 + [var_ba] * 3), atol=1e-12)
    np.testing.assert_allclose(cond(P2), cond(P), atol=1e-10)
    np.testing.assert_allclose(P2, P2.T, atol=0.0)
    assert np.all(np.linalg.eigvalsh(P2) > 0.0)
    assert P2[12, 12] == P[12, 12] and not np.any(P2[12, :12])
    assert np.all(np.diag(P2)[:6] >= np.diag(P)[:6]) and np.any(np.diag(P2)[:3] > np.diag(P)[:3] + 1e-3)
