"""The gyro bias prior as a measurement model (filters/measurements.py, GyroBiasPrior): accepted by the cores that keep
the gyro bias block, fused through ``update()`` as a direct observation of that block carrying the information the
prior adds to the core's own (the block becomes the prior, the grade's prior is not counted twice), refused with a
reason when its covariance is not one."""

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


def test_right_after_initialize_the_block_becomes_the_prior_and_the_rest_does_not_move():
    """Bias block of P0 = sigma_g^2 I (gyro_bias_deg_h), prior (b, R) tighter: the posterior bias is b and its
    covariance R (the rest measurement or the learned bias supersedes the grade's prior, as the hand-over always
    did); the navigation states (uncorrelated with the bias at the start) do not move. Fused again: nothing changes
    (no double counting)."""
    core = _started("iekf")
    P0 = core.P.copy()
    C0, v0, p0 = core.C.copy(), core.v.copy(), core.p.copy()
    b = np.array([3.0, -2.0, 5.0]) * DEG_H
    R = np.array([[0.5, 0.1, 0.0], [0.1, 0.8, -0.2], [0.0, -0.2, 1.2]]) ** 2 * DEG_H**2
    res = core.update(GyroBiasPrior(b, R, stamp_s=0.0))
    assert res.accepted and core.counters["gyro_bias_prior"] == 1
    np.testing.assert_allclose(core.b_g, b, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(core.P[9:12, 9:12], R, rtol=1e-9, atol=1e-9 * np.abs(R).max())
    np.testing.assert_array_equal(core.P[0:9, 0:9], P0[0:9, 0:9])
    np.testing.assert_array_equal(core.P[12:15, 12:15], P0[12:15, 12:15])
    np.testing.assert_allclose(core.C, C0, atol=1e-15)
    np.testing.assert_array_equal(core.v, v0)
    np.testing.assert_array_equal(core.p, p0)
    P1, b1 = core.P.copy(), core.b_g.copy()
    assert core.update(GyroBiasPrior(b, R)).accepted
    np.testing.assert_allclose(core.b_g, b1, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(core.P, P1, rtol=1e-6, atol=1e-9 * np.abs(R).max())


def test_a_prior_weaker_than_the_core_along_an_axis_leaves_that_axis():
    """x and y tighter than the grade's prior, z wider: x and y become the prior, z keeps the core's own estimate
    (an update cannot widen the covariance; the prior adds no information there)."""
    core = _started("iekf")
    sg2 = (core.cfg.gyro_bias_deg_h * DEG_H) ** 2
    R = np.diag([0.1 * sg2, 0.2 * sg2, 4.0 * sg2])
    b = np.array([1.0, 2.0, 30.0]) * DEG_H
    assert core.update(GyroBiasPrior(b, R)).accepted
    np.testing.assert_allclose(core.b_g[:2], b[:2], rtol=1e-9)
    assert abs(core.b_g[2]) < 1e-9 * DEG_H
    np.testing.assert_allclose(np.diag(core.P[9:12, 9:12]), [0.1 * sg2, 0.2 * sg2, sg2], rtol=1e-6)


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
