"""Coarse alignment on a rocking parked car (issue 15, item 4): the reported covariance includes the disturbance the
window shows, so its 3-sigma covers the error; the averaging method says when its heading is unusable.

Shortened case of benchmarks/coarse_rocking.py (25 seeds, windows 10-300 s; results in docs/static_alignment.md):
static_navgrade with 0.2 deg rms rocking at 0.5-2 Hz, the IMU 0.5 m above the rocking centre, engine vibration on."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth
from insalign_ros.core import mechanization as M
from insalign_ros.filters.base import AlignmentStatus
from insalign_ros.filters.coarse import (DISTURBED, NO_HEADING, CoarseAlignment, CoarseConfig,
                                         gravity_reaction_integral_i0, wahba_covariance_rad2)
from insalign_ros.filters.static_model import config_for_imu
from insalign_ros.sim.scenarios import make_scenario
from oracles import geodetic_from_state_eci, propagate_eci

from reference_loops import run_static

ROCK = dict(rock_amp_deg=0.2)


def test_rocking_scenario_is_the_asked_motion_and_its_imu_is_exact():
    """rms roll/pitch 0.2 deg, spectrum inside 0.5-2 Hz, the IMU moves by lever x angle (mm), and the noise-free IMU
    integrated by our ECI mechanization reproduces the attitude to 1e-6 rad (inverse navigation)."""
    sc = make_scenario("static_navgrade", seed=4, duration_s=60.0, noise=False, engine_acc_m_s2=0.0,
                       engine_ang_deg=0.0, sway_ang_deg=0.0, **ROCK)
    rpy = np.degrees(np.array([earth.rpy_from_C_b_n(C) for C in sc.C_b_n]))
    dev = rpy - rpy.mean(0)
    assert np.sqrt(np.mean(dev[:, :2] ** 2)) == pytest.approx(0.2, rel=0.25)
    spec = np.abs(np.fft.rfft(dev[:, 0]))
    fr = np.fft.rfftfreq(len(dev), float(sc.t_s[1] - sc.t_s[0]))
    assert 0.5 - 0.05 <= fr[np.argmax(spec)] <= 2.0 + 0.05
    lever_m = 0.5 * math.radians(0.2)
    assert 0.3 * lever_m < np.std(sc.v_n[:, 0]) / (2 * np.pi * 0.5) and np.max(np.abs(sc.v_n)) < 0.1
    s = M.state_eci_from_geodetic(0.0, sc.t0_s, sc.lat_rad[0], sc.lon_rad[0], sc.h_m[0], sc.C_b_n[0], sc.v_n[0])
    C, v, p = s.C_b_i, s.v_i, s.p_i
    for k in range(1, sc.n):
        C, v, p = propagate_eci(C, v, p, sc.omega_ib_b[k], sc.f_ib_b[k], sc.t_s[k] - sc.t_s[k - 1])
    C_b_n = geodetic_from_state_eci(M.NavStateEci(sc.t_s[-1], C, v, p), sc.t0_s)[3]
    assert np.linalg.norm(Rotation.from_matrix(C_b_n.T @ sc.C_b_n[-1]).as_rotvec()) < 1e-6


def test_wahba_covariance_matches_monte_carlo():
    """The linearised covariance of the centred Wahba fit (white disturbance + velocity random walk) against 400
    Monte Carlo fits of the same pairs: heading variance within 25 % (400 samples: the estimate's own 1-sigma is 7 %)."""
    lat, g = math.radians(35.0), 9.8
    t = np.arange(0.1, 30.01, 0.1)
    v = gravity_reaction_integral_i0(t, lat, g)
    vc = v - v.mean(0)
    sigma, q = 0.01, 2e-3
    rng = np.random.default_rng(1)
    yaw = []
    for _ in range(400):
        u = rng.normal(0, sigma, v.shape) + np.cumsum(rng.normal(0, q * math.sqrt(0.1), v.shape), axis=0)
        vb = v + u
        R, _ = Rotation.align_vectors(vc, vb - vb.mean(0))
        yaw.append(R.as_rotvec()[2])
    P = wahba_covariance_rad2(vc, t, np.array([sigma**2]), q)
    assert np.var(yaw) == pytest.approx(P[2, 2], rel=0.25), (np.var(yaw), P[2, 2])


@pytest.fixture(scope="module")
def rocking_runs():
    out = {}
    for seed in range(6):
        sc = make_scenario("static_navgrade", seed=seed, duration_s=60.0, **ROCK)
        for method in ("average", "inertial"):
            core = CoarseAlignment(config_for_imu(CoarseConfig, sc.imu_spec, method=method))
            t, err, sig3 = run_static(core, sc, math.radians(90.0), 1e-3)
            out[(seed, method)] = (t, err, sig3, core.estimate(), sc)
    return out


@pytest.mark.parametrize("method", ["average", "inertial"])
def test_three_sigma_covers_rocking(rocking_runs, method):
    """At 20 s and 60 s of window, every seed: |error| <= 3-sigma on yaw and both level axes. The datasheet-only
    covariance (before issue 15: 0.004 deg of level 3-sigma) did not cover the level in most runs (rocking 0.2 deg)."""
    missed_by_datasheet = 0
    for seed in range(6):
        t, err, sig3, _, _ = rocking_runs[(seed, method)]
        for W in (20.0, 60.0):
            k = int(np.argmin(np.abs(t - W)))
            assert np.all(np.abs(err[k]) <= sig3[k]), (seed, W, np.degrees(err[k]), np.degrees(sig3[k]))
            missed_by_datasheet += int(np.max(np.abs(err[k, :2])) > math.radians(0.0043))
    assert missed_by_datasheet >= 10


def test_averaging_says_its_heading_is_unusable(rocking_runs):
    """0.2 deg of rocking moves the window-mean horizontal rate by ~sqrt(2) 0.2 deg / 60 s = 17 deg/h, above the
    12.3 deg/h of horizontal Earth rate at 35 deg: the averaging method must not give a heading at 60 s; the inertial
    one tracks the rocking and gives one (3-sigma below 1 deg)."""
    for seed in range(6):
        e = rocking_runs[(seed, "average")][3]
        assert e.status is AlignmentStatus.WAITING_FOR_DATA and NO_HEADING in e.reason and DISTURBED in e.reason
        assert math.sqrt(e.P_att_n[2, 2]) == pytest.approx(math.radians(100.0))  # the initial guess's own sigma
        ei = rocking_runs[(seed, "inertial")][3]
        assert ei.status is AlignmentStatus.ALIGNED and 3 * math.sqrt(ei.P_att_n[2, 2]) < math.radians(1.0)


def test_quiet_base_is_not_inflated():
    """No rocking (engine vibration and 0.02 deg sway kept), navigation grade, 120 s: the inertial method's yaw
    3-sigma stays within 1.5x the datasheet-only one (ARW + bias: the terms it had before issue 15) plus the exact
    velocity-random-walk term, and still covers the error."""
    sc = make_scenario("static_navgrade", seed=0, duration_s=120.0)
    cfg = config_for_imu(CoarseConfig, sc.imu_spec)
    core = CoarseAlignment(cfg)
    t, err, sig3 = run_static(core, sc, math.radians(90.0), 1e-3)
    assert abs(err[-1, 2]) <= sig3[-1, 2]
    w_h = earth.OMEGA_IE_RAD_S * math.cos(sc.lat_rad[0])
    sheet = math.hypot(cfg.gyro_arw_deg_sqrt_h * math.pi / 180 / 60 / math.sqrt(120.0),
                       cfg.gyro_bias_deg_h * math.pi / 180 / 3600) / w_h
    v = gravity_reaction_integral_i0(np.arange(0.104, 120.0, 0.104), sc.lat_rad[0], 9.8)
    vrw = math.sqrt(wahba_covariance_rad2(v - v.mean(0), np.arange(0.104, 120.0, 0.104), np.zeros(1),
                                          cfg.acc_vrw_m_s_sqrt_h / 60.0)[2, 2])
    assert sig3[-1, 2] / 3 <= 1.5 * math.hypot(sheet, vrw), (math.degrees(sig3[-1, 2] / 3), math.degrees(sheet),
                                                             math.degrees(vrw))
