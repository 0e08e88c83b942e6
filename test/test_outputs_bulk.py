"""Outputs built in bulk (issue 28, item 1): the offline path's 3-sigma and Euler errors computed for every output
at once at the end of a run, the flag's criteria without numpy per output, give exactly the numbers of one call per
output."""

import math

import numpy as np

import insalign_ros as ia
from insalign_ros.core import earth, lie
from insalign_ros.session.flag import (AlignedFlag, attitude_3sigma_deg, attitude_3sigma_list, euler_3sigma_deg,
                                       euler_3sigma_deg_many)


def _reference_attitude_3sigma(P):
    d = np.clip(np.diag(np.asarray(P, float)), 0.0, None)
    return 3.0 * np.degrees(np.sqrt(d))


def _same(a, b):
    """Equal to the last bits (1e-13 relative; infinities and NaN at the same places): the vectorised and per-output
    numpy calls sum in orders that depend on the CPU's SIMD width (bit for bit on some CPUs, 1-2 ulp apart on others)."""
    np.testing.assert_allclose(a, b, rtol=1e-13, atol=0.0, equal_nan=True)


def test_bulk_euler_3sigma_is_the_per_output_one():
    rng = np.random.default_rng(7)
    n = 4000
    C = np.array([lie.so3_exp(rng.normal(0, 1.5, 3)) for _ in range(n)])
    A = rng.normal(0, 0.02, (n, 3, 3))
    P = A @ A.transpose(0, 2, 1)
    P[::97, 2, 2] = -1e-9  # a slightly negative variance: 0
    P[::89, 1, 1] = np.nan
    P[::83, 0, 0] = np.inf
    C[5] = earth.C_b_n_from_rpy(0.1, math.pi / 2 - 1e-7, 0.3)  # near the singularity
    C[6, 2, 0] = -1.0  # pitch at +90 deg: singular
    bulk = euler_3sigma_deg_many(C, P)
    one = np.array([euler_3sigma_deg(c, p) for c, p in zip(C, P)])
    _same(bulk, one)  # infinities and NaN where the per-output call has them
    assert np.isinf(bulk[6]).all()


def test_flag_3sigma_without_numpy_is_numpys():
    rng = np.random.default_rng(8)
    for k in range(2000):
        P = rng.normal(0, 1e-3, (3, 3))
        if k % 7 == 0:
            P[k % 3, k % 3] = [np.nan, np.inf, -0.5][k % 3]
        ref = _reference_attitude_3sigma(P)
        np.testing.assert_array_equal(attitude_3sigma_deg(P), ref)
        np.testing.assert_array_equal(np.array(attitude_3sigma_list(P)), ref)


def test_flag_nis_sum_cached_between_updates():
    """The window's sum is recomputed when an update arrives, not per output: the same float as summing each time."""
    f = AlignedFlag()
    P = np.diag([1e-6, 1e-6, 1e-6])
    rng = np.random.default_rng(9)
    for k in range(60):
        f.on_update(float(k), True, float(rng.chisquare(3)))
        for j in range(10):
            f.on_estimate(k + 0.1 * j, P)
            if len(f.nis) == f.criteria.nis_window:
                assert f.nis_sum == float(sum(f.nis))
    assert f.aligned


def test_default_align_outputs_are_the_per_output_ones():
    """ia.align with its defaults (initialisation from the sensors, 0.1-s outputs): every output's 3-sigma and Euler
    error, filled in at the end, equal the per-output computation from the same estimate."""
    r = ia.align("ship", core="iekf", duration_s=40.0)
    assert len(r.outputs) > 300
    for o in r.outputs:
        _same(o.euler_3sigma_deg, euler_3sigma_deg(o.estimate.C_b_n, o.estimate.P_att_n))
        if o.truth_C_b_n is not None:
            _same(o.euler_error_deg, np.degrees(earth.euler_error_rad(o.estimate.C_b_n, o.truth_C_b_n)))
    np.testing.assert_array_equal(r.sigma3_deg,
                                  np.array([o.euler_3sigma_deg for o in r.outputs]))
