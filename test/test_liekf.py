"""LIEKF / batched ECI core: transition matrix vs finite differences, batched vs sequential mechanization,
zero-noise truth tracking, SPD covariance over 1e5 steps, convergence from 179 deg yaw error, ENU attitude
covariance mapping (Monte-Carlo), bad-input rejection."""

import math

import numpy as np
import pytest

from insalign_ros.filters.measurements import GnssPosition
from insalign_ros.core import earth as E
from insalign_ros.core import lie
from insalign_ros.core import mechanization as M
from insalign_ros.filters import eci_batch as LK
from insalign_ros.filters.registry import make_core
import oracles
from oracles import propagate_eci

from reference_loops import EventRunner, initial_guess
import lie_ref  # noqa: E402  (test/lie_ref.py: the SE2(3) functions only the tests use)

CORES = ("liekf", "pi_liekf", "iekf", "ekf")


def _state(seed=0):
    rng = np.random.default_rng(seed)
    s = M.state_eci_from_geodetic(0.0, 0.0, 0.5, 0.9, 10.0, E.C_b_n_from_rpy(*rng.uniform(-1, 1, 3)),
                                  rng.normal(0, 5, 3))
    w = rng.normal(0, 0.5, 3)  # rad/s: a strongly rotating body, so rotation terms matter
    f = np.array([0.0, 0.0, 9.8]) + rng.normal(0, 3, 3)
    return s, w, f


def _fd_transition(s, w, f, dt):
    """Finite-difference Jacobian of the true left-invariant error after one mechanization step.

    The error map is exactly linear in the Lie algebra (Ad and F_dt are automorphisms) except for the gravity
    gradient, so large steps are fine: 1e-2 rad, 0.1 m/s and m (ECI positions are ~6.4e6 m, so small
    steps would drown in rounding)."""
    C1, v1, p1 = propagate_eci(s.C_b_i, s.v_i, s.p_i, w, f, dt)
    X1_hat = lie.se23_from(C1, v1, p1)
    X0_hat = lie.se23_from(s.C_b_i, s.v_i, s.p_i)
    J = np.zeros((9, 9))
    for j in range(9):
        for sgn in (1.0, -1.0):
            xi = np.zeros(9)
            eps = 1e-2 if j < 3 else 1e-1
            xi[j] = sgn * eps
            X0 = X0_hat @ lie.se23_exp(xi)
            C, v, p = lie.se23_parts(X0)
            C2, v2, p2 = propagate_eci(C, v, p, w, f, dt)
            J[:, j] += sgn * lie_ref.se23_box_minus(lie.se23_from(C2, v2, p2), X1_hat) / (2 * eps)
    return J


def liekf_A_eq41(omega_ib_b: np.ndarray, f_ib_b: np.ndarray, dt_s: float) -> np.ndarray:
    """The paper's first-order A of eq. (41): ``I + [[-w_x,0,0],[-f_x,-w_x,0],[0,I,-w_x]] T_s``."""
    W, Fx = lie.hat3(omega_ib_b), lie.hat3(f_ib_b)
    Ac = np.zeros((9, 9))
    Ac[0:3, 0:3] = -W
    Ac[3:6, 0:3] = -Fx
    Ac[3:6, 3:6] = -W
    Ac[6:9, 3:6] = np.eye(3)
    Ac[6:9, 6:9] = -W
    return np.eye(9) + Ac * dt_s



@pytest.mark.parametrize("dt", [0.01, 0.1])
def test_transition_matches_finite_difference_of_true_error_dynamics(dt):
    s, w, f = _state()
    J_fd = _fd_transition(s, w, f, dt)
    dC, dv_b, dp_b = LK.eci_steps(s.C_b_i, s.v_i, s.p_i, w[None], f[None], np.array([dt]))[:3]
    Phi = LK.liekf_transition_batch(dC, dv_b, dp_b, np.array([dt]))[0]
    # exact discrete transition: only the neglected gravity gradient (~3e-6 s^-2 * dt^2) and FD rounding remain
    assert np.max(np.abs(Phi - J_fd)) < 1e-6
    # eq. (41) is its first-order expansion: error O(dt^2 (|w|^2 + |f||w|)), not O(dt)
    A41 = liekf_A_eq41(w, f, dt)
    err41 = np.max(np.abs(A41 - J_fd))
    scale = dt * dt * (np.linalg.norm(w) ** 2 + np.linalg.norm(f) * np.linalg.norm(w) + 1.0)
    assert err41 < scale
    assert err41 > 1e-3 * scale  # and it is not exact: the test can tell the two apart
    # state independence: a different state, same IMU sample -> same finite-difference matrix
    s2, _, _ = _state(seed=5)
    assert np.max(np.abs(_fd_transition(s2, w, f, dt) - J_fd)) < 1e-6


@pytest.mark.parametrize("steps", [LK.eci_steps, oracles.eci_steps], ids=["compiled", "numpy_batch"])
def test_batched_mechanization_equals_sequential_propagate_eci(steps):
    """The cores' mechanization over a batch (compiled) and the tests' vectorised numpy reference of it, against
    the sequential numpy steps of core/mechanization.py's scheme."""
    s, _, _ = _state()
    rng = np.random.default_rng(3)
    n = 400
    w = rng.normal(0, 0.3, (n, 3))
    f = np.array([0.0, 0.0, 9.8]) + rng.normal(0, 2, (n, 3))
    dt = np.full(n, 0.01)
    dt[7] = 0.013  # uneven steps are allowed
    C, v, p = s.C_b_i, s.v_i, s.p_i
    for k in range(n):
        C, v, p = propagate_eci(C, v, p, w[k], f[k], dt[k])
    _, _, _, _, Cb, vb, pb = steps(s.C_b_i, s.v_i, s.p_i, w, f, dt)
    assert np.linalg.norm(pb - p) < 1e-7
    assert np.linalg.norm(vb - v) < 1e-9
    assert np.linalg.norm(lie.so3_log(Cb.T @ C)) < 1e-12


FAST = {"pi_liekf": {"lmi_resolve_every_updates": 1000}}  # at most one LMI solve per run (none in runs shorter
# than the 30-update certification window) keeps the suite short


def _run(core_name, data, rpy_err_deg, params=None, period=1.0):
    core = make_core(core_name, params if params is not None else FAST.get(core_name))
    initial_guess(data.t_s[0], data.lat_rad[0], data.lon_rad[0], data.h_m[0], data.C_b_n[0], data.v_n[0],
                  rpy_err_deg, core.cfg).apply(core)
    return core, EventRunner(core, float(data.t_s[0])).run(data.events(), output_period_s=period)


def _errors_deg(data, ests):
    k = np.searchsorted(data.t_s, np.array([e.stamp_s for e in ests]) - 1e-9)
    return np.array([np.degrees(E.euler_error_rad(e.C_b_n, data.C_b_n[i])) for e, i in zip(ests, k)])


@pytest.mark.parametrize("name", CORES)
def test_zero_noise_zero_error_stays_at_truth(name):
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("ship", seed=0, duration_s=60.0, noise=False)
    core, ests = _run(name, d, [0.0, 0.0, 0.0])
    err = _errors_deg(d, ests)
    # measured 3e-4 deg: the simulator's truth positions and the mechanization differ by ~2e-4 m (velocity by
    # 3e-8 m/s), and the GNSS updates turn that into a few microradians of attitude
    assert np.max(np.abs(err)) < 1e-3
    e = ests[-1]
    k = d.n - 1
    p_e = E.geodetic_to_ecef(e.lat_rad, e.lon_rad, e.h_m)
    p_true = E.geodetic_to_ecef(d.lat_rad[k], d.lon_rad[k], d.h_m[k])
    assert np.linalg.norm(p_e - p_true) < 1e-3
    assert np.linalg.norm(e.v_n - d.v_n[k]) < 1e-5


@pytest.mark.parametrize("name", CORES)
def test_covariance_spd_through_1e5_steps(name):
    """1e5 IMU samples (ship, 1000 s at 100 Hz, noisy), GNSS at 1 Hz: P stays symmetric positive definite."""
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("ship", seed=4, duration_s=1000.0)
    assert d.n - 1 >= 100_000
    core = make_core(name, FAST.get(name))
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [10.0, 10.0, 120.0],
                  core.cfg).apply(core)
    runner = EventRunner(core, float(d.t_s[0]))
    worst = np.inf
    for ev in d.events():
        res = runner.feed(ev)
        if res is not None:
            assert res.accepted
            P = core.P
            assert np.array_equal(P, P.T)
            worst = min(worst, float(np.linalg.eigvalsh(P).min()))
            assert worst > 0.0, f"P lost positive definiteness at t = {ev.stamp_s}"
    assert runner.counters["imu"] == d.n - 1 and runner.counters["gnss_accepted"] == 1001
    assert np.all(np.isfinite(core.estimate().P))


#: seeds on which a single invariant filter started 179 deg off ends 20-140 deg off on ship (docs/results.md)
_HARD_SEEDS = (4, 6, 9)


@pytest.mark.parametrize("name", ("liekf", "pi_liekf", "iekf"))
@pytest.mark.parametrize("yaw0", (179.0, -179.0))
def test_invariant_cores_converge_from_179_deg_yaw_error_on_ship(name, yaw0):
    """Shortened ship case (90 s), the seeds on which a *single* invariant filter fails from +-179 deg: with the
    bank of 8 yaw hypotheses (filters/hypotheses.py) every one ends within a few degrees. Thresholds: the IEKF
    estimates the 25 deg/h gyro bias (< 1.5 deg after 60 s); the LIEKF/PI-LIEKF do not, and their bias-induced
    yaw error on these seeds is 1-2 deg (docs/results.md), so 3 deg -- against an initial 179 deg."""
    from insalign_ros.sim.scenarios import make_scenario

    tol = 1.5 if name == "iekf" else 3.0
    for seed in _HARD_SEEDS:
        d = make_scenario("ship", seed=seed, duration_s=90.0)
        core, ests = _run(name, d, [10.0, 10.0, yaw0], params={**(FAST.get(name) or {}), "yaw_hypotheses": 8})
        err = _errors_deg(d, ests)
        t = np.array([e.stamp_s for e in ests])
        late = t >= 60.0
        assert np.max(np.abs(err[late, 2])) < tol, (seed, np.max(np.abs(err[late, 2])))
        assert np.max(np.abs(err[late, :2])) < 1.0, seed
        dg = core.diagnostics()
        assert dg["yaw_hypotheses_alive"] == 1 and dg["yaw_hypotheses_collapsed_at_s"] < 30.0, dg


def test_attitude_covariance_mapping_to_enu_by_monte_carlo():
    """Draw xi ~ N(0, P) around an estimate, form the truth X_hat exp(xi), measure psi_n with
    C_true = exp(psi_x) C_est; its sample covariance must match P_att_n (NEES ~ 3)."""
    rng = np.random.default_rng(2)
    for name in ("liekf", "ekf"):
        core = make_core(name)
        C_b_n = E.C_b_n_from_rpy(0.3, -0.2, 2.0)
        A = rng.normal(0, 1, (3, 3))
        P_att_n = np.radians(2.0) ** 2 * (A @ A.T / 3 + 0.2 * np.eye(3))
        core.initialize(100.0, 0.7, 0.3, 0.0, C_b_n, np.zeros(3), P_att_n, 0.1, 1.0)
        est = core.estimate()
        assert np.allclose(est.P_att_n, P_att_n, rtol=1e-9, atol=1e-15)
        L = np.linalg.cholesky(core.P[0:3, 0:3])
        nees = []
        for _ in range(4000):
            d = L @ rng.normal(size=3)
            C_true = core.C @ lie.so3_exp(d) if name == "liekf" else lie.so3_exp(d) @ core.C
            # truth attitude body -> ENU at the same position/time
            C_b_n_true = est.C_b_n @ core.C.T @ C_true
            psi = E.heading_error_enu_rad(C_b_n_true, est.C_b_n)  # C_true = exp(psi_x) C_est
            nees.append(psi @ np.linalg.solve(est.P_att_n, psi))
        assert abs(np.mean(nees) - 3.0) < 0.15  # 4000 draws: std of the mean ~0.04


def test_bad_inputs_are_rejected_and_do_not_corrupt():
    core = make_core("liekf")
    core.initialize(0.0, 0.6, 0.2, 20.0, np.eye(3), np.zeros(3), np.eye(3) * 0.01, 0.1, 1.0)
    before = core.estimate()
    core.propagate([0.01], [np.array([np.nan, 0, 0])], [np.zeros(3)])
    core.propagate([0.0], [np.zeros(3)], [np.zeros(3)])  # not after the current time
    res = core.update(GnssPosition(0.0, np.array([1.0, 2.0, 3.0]), np.eye(3)))
    assert not res.accepted and "surface" in res.reason
    res = core.update(GnssPosition(0.0, E.geodetic_to_ecef(0.6, 0.2, 20.0), -np.eye(3)))
    assert not res.accepted and "positive definite" in res.reason
    after = core.estimate()
    assert core.counters["imu_rejected"] == 2 and core.counters["gnss_rejected"] == 2
    assert np.array_equal(before.C_b_n, after.C_b_n) and np.array_equal(before.P, after.P)
