"""The divergence guard's model floor (session/guard.py): the samples' own noise beyond the declared VRW, in closed
form. KITTI's 10-Hz rows (test_real_data.py) are where it matters."""

import math

import numpy as np
import pytest

from insalign_ros.filters.imu_grade import get_grade
from insalign_ros.session.session import AlignmentSession

G = 9.80


def _session_with_samples(F, dt):
    s = AlignmentSession({"imu_grade": "unknown_mems"})
    s.loop.hist_f.extend(np.asarray(F, float))
    return s


@pytest.mark.parametrize("sigma", [0.05, 0.15])
def test_sampling_psd_is_the_white_sample_noise_across_gravity_less_the_declared_vrw(sigma):
    """Samples f = g (tilted 10 deg) + a smooth 0.2-Hz, 2-m/s^2 acceleration + white noise of sigma per axis at 10 Hz:
    the PSD is sigma^2 dt minus the grade's VRW^2 (a 10-s span: 100 second differences, 6 sigma^2 each, correlated;
    the smooth acceleration adds under 1 %), within their sampling error (fixed seed)."""
    dt = 0.1
    rng = np.random.default_rng(7)
    t = np.arange(101) * dt
    up = np.array([math.sin(math.radians(10.0)), 0.0, math.cos(math.radians(10.0))])
    F = G * up + np.outer(2.0 * np.sin(2 * math.pi * 0.2 * t), [1.0, 0.0, 0.0]) + rng.normal(0.0, sigma, (101, 3))
    s = _session_with_samples(F, dt)
    vrw = get_grade("unknown_mems").acc_vrw_m_s_sqrt_h / 60.0
    q = s.guard._sampling_psd(dt)
    assert q == pytest.approx(sigma ** 2 * dt - vrw ** 2, rel=0.25)
    s.close()


def test_sampling_psd_is_zero_for_smooth_samples_and_a_short_history():
    dt = 0.01
    t = np.arange(300) * dt
    F = np.column_stack([1.5 * np.sin(2 * math.pi * 0.5 * t), 0.3 * t, np.full_like(t, G)])
    s = _session_with_samples(F, dt)
    assert s.guard._sampling_psd(dt) == 0.0  # under the declared VRW's share
    s.close()
    s = _session_with_samples(F[:8], dt)
    assert s.guard._sampling_psd(dt) == 0.0
    s.close()
