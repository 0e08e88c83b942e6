"""The gyro bias prior as a measurement model (filters/measurements.py, GyroBiasPrior): accepted by the cores that keep
the gyro bias block, fused through ``update()`` as a direct observation of that block (the Kalman combination with the
grade's prior), refused with a reason when its covariance is not one."""

import math

import numpy as np

from insalign_ros.filters.measurements import GyroBiasPrior
from insalign_ros.filters.registry import make_core

LAT, LON, H = 0.6, 0.2, 30.0
DEG_H = math.radians(1.0) / 3600.0  # [rad/s]


def _started(name, params=None):
    core = make_core(name, params or {})
    core.initialize(0.0, LAT, LON, H, np.eye(3), np.zeros(3), np.diag([1e-4, 1e-4, 1e-2]), 0.1, 1.0)
    return core


def test_accepted_only_where_the_gyro_bias_block_is_kept():
    """iekf (and a bank of it) keeps the block with the eci_left terms; the cores without the block never see the
    model (ekf keeps a gyro bias but the model has no eci_ekf terms: as before the model, only iekf took a prior)."""
    assert GyroBiasPrior in make_core("iekf").accepts
    assert GyroBiasPrior in make_core("iekf", {"yaw_hypotheses": 4}).accepts
    for name in ("liekf", "pi_liekf", "pkf", "ekf10", "coarse", "earth_iekf", "ekf"):
        core = make_core(name)
        assert GyroBiasPrior not in core.accepts, name
        res = core.update(GyroBiasPrior(np.zeros(3), np.eye(3) * DEG_H**2))
        assert not res.accepted and "does not use" in res.reason, (name, res.reason)


def test_right_after_initialize_it_is_the_kalman_combination_with_the_grade_prior():
    """Bias block of P0 = sigma_g^2 I (gyro_bias_deg_h), prior b with covariance R: the posterior bias is
    sigma_g^2 (sigma_g^2 I + R)^-1 b, its covariance (sigma_g^-2 I + R^-1)^-1; the navigation states (uncorrelated with
    the bias at the start) do not move."""
    core = _started("iekf")
    sg2 = (core.cfg.gyro_bias_deg_h * DEG_H) ** 2
    P0 = core.P.copy()
    C0, v0, p0 = core.C.copy(), core.v.copy(), core.p.copy()
    b = np.array([3.0, -2.0, 5.0]) * DEG_H
    R = np.diag([0.5, 0.8, 1.2]) ** 2 * DEG_H**2
    res = core.update(GyroBiasPrior(b, R, stamp_s=0.0))
    assert res.accepted and core.counters["gyro_bias_prior"] == 1
    np.testing.assert_allclose(core.b_g, sg2 * np.linalg.solve(sg2 * np.eye(3) + R, b), rtol=1e-9)
    np.testing.assert_allclose(core.P[9:12, 9:12], np.linalg.inv(np.eye(3) / sg2 + np.linalg.inv(R)), rtol=1e-6)
    np.testing.assert_array_equal(core.P[0:9, 0:9], P0[0:9, 0:9])
    np.testing.assert_allclose(core.C, C0, atol=1e-15)
    np.testing.assert_array_equal(core.v, v0)
    np.testing.assert_array_equal(core.p, p0)


def test_every_hypothesis_of_a_bank_gets_it_and_the_weights_do_not_move():
    bank = _started("iekf", {"yaw_hypotheses": 4})
    w0 = bank.weights.copy()
    res = bank.update(GyroBiasPrior(np.array([1.0, 2.0, 3.0]) * DEG_H, np.eye(3) * DEG_H**2))
    assert res.accepted
    assert all(h.counters["gyro_bias_prior"] == 1 for h in bank.hyps)
    np.testing.assert_array_equal(bank.weights, w0)


def test_a_bad_prior_is_refused_with_its_reason():
    core = _started("iekf")
    b_g0, P0 = core.b_g.copy(), core.P.copy()
    for b, R, why in ((np.zeros(3), -np.eye(3), "positive definite"), (np.full(3, np.nan), np.eye(3), "non-finite"),
                      (np.zeros(2), np.eye(3), "bad shapes")):
        res = core.update(GyroBiasPrior(b, R))
        assert not res.accepted and why in res.reason, res.reason
    assert core.counters["gyro_bias_prior_rejected"] == 3
    np.testing.assert_array_equal(core.b_g, b_g0)
    np.testing.assert_array_equal(core.P, P0)
