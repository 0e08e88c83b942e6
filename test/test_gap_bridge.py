"""The IMU gap bridge (session/gaps.py): closed forms of the candidates and the choice on the data."""
import numpy as np
import pytest

from insalign_ros.session import gaps


def _series(fn, h=0.02, T=30.0):
    t = np.arange(0.0, T, h)
    Y = np.stack([fn(t + k) for k in range(6)], axis=1)
    return t, Y


def test_linear_candidate_is_interpolation_between_the_two_neighbours():
    t_before, t_after = np.array([0.0, 1.0]), np.array([3.0, 4.0])
    Yb, Ya = np.array([[9.0, 1.0], [1.0, 2.0]]), np.array([[5.0, 0.0], [7.0, 7.0]])
    got = gaps.fill(gaps.LINEAR, t_before, Yb, t_after, Ya, np.array([1.5, 2.0, 2.5]))
    np.testing.assert_allclose(got, [[2.0, 1.5], [3.0, 1.0], [4.0, 0.5]])


def test_polynomial_candidate_reproduces_a_quartic_exactly():
    """A degree-4 signal is in the span of the degree-4 fit: the bridge is exact (to rounding), whatever the gap."""
    fn = lambda t: 0.3 - 0.2 * t + 0.05 * t**2 - 0.01 * t**3 + 0.002 * t**4  # noqa: E731
    t, Y = _series(fn, T=6.0)
    gap = (t > 2.0) & (t < 3.5)
    before, after = (t <= 2.0), (t >= 3.5)
    got = gaps.fill(gaps.Bridge(4, 1.0, 1.0), t[before], Y[before], t[after], Y[after], t[gap])
    np.testing.assert_allclose(got, Y[gap], atol=1e-9)


def test_window_errors_of_linear_match_the_closed_form_on_a_sinusoid():
    """Linear interpolation of a*sin(w t) over a gap of length g misses, in the integral, a*(sin part) whose
    magnitude is bounded by a*w^2*g^3/12 (trapezoid error); the measured worst window is within 10 % of it."""
    a, w, h, g = 0.15, 2 * np.pi / 5.0, 0.02, 1.5
    t = np.arange(0.0, 40.0, h)
    Y = a * np.sin(w * t)[:, None] * np.ones((1, 3))
    m = int(round(g / h))
    ew, _ = gaps.window_errors(gaps.LINEAR, t, Y, Y, m, max_windows=400)
    bound = a * w**2 * g**3 / 12.0
    assert np.max(np.abs(ew)) == pytest.approx(bound, rel=0.1)


def test_choose_prefers_a_fit_on_smooth_waves_and_its_error_is_an_order_below_linear():
    """Ship-like motion (periods 5-7 s) with white noise: the degree-4 fit wins, and its worst window is at least
    5x smaller than linear interpolation's (the gain that keeps a 1.5-s gap inside the 3-sigma)."""
    rng = np.random.default_rng(1)
    h = 0.02
    t = np.arange(0.0, 20.0, h)
    W = np.stack([0.15 * np.sin(2 * np.pi * t / p) for p in (6.0, 5.0, 7.0)], 1) + 1e-3 * rng.standard_normal((len(t), 3))
    F = np.stack([2.0 * np.cos(2 * np.pi * t / p) for p in (7.0, 6.0, 8.0)], 1) + 1e-2 * rng.standard_normal((len(t), 3))
    m = int(round(1.5 / h))
    bridge, var_att, _, nwin = gaps.choose(t, W, F, m, after_available_s=1.0)
    ew_lin, _ = gaps.window_errors(gaps.LINEAR, t, W, F, m)
    assert bridge.degree == 4 and nwin >= 5
    assert np.sqrt(var_att) < np.max(np.abs(ew_lin)) / 5.0
