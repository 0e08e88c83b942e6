"""Backtracking driver (inverse-alignment paper Figs. 1-2, sec. 3.4) with the Earth-frame IEKF and the ECI LIEKF."""

import time

import numpy as np
import pytest

from insalign_ros.core import earth, lie
from insalign_ros.core.types import ImuSample
from insalign_ros.filters.backtrack import BacktrackingAligner, BacktrackLiekf, make_backtrackable
from insalign_ros.filters.earth_iekf import EarthIekf, EarthIekfConfig
from insalign_ros.filters.registry import make_core
from insalign_ros.filters.measurements import GnssPosition
from insalign_ros.sim.scenarios import make_scenario

from reference_loops import initial_guess, run_offline_backtrack


def test_liekf_backward_returns_to_start_noise_free_ship():
    d = make_scenario("ship", seed=0, noise=False, duration_s=20.0)
    c = make_core("liekf_backtrack")
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [0, 0, 0], c.cfg).apply(c)
    C0, v0, p0 = c.C.copy(), c.v.copy(), c.p.copy()
    for k in range(1, d.n):  # one sample at a time (arrays of length 1)
        c.propagate(d.t_s[k:k + 1], d.omega_ib_b[k:k + 1], d.f_ib_b[k:k + 1])
    c.flush()
    c.propagate(d.t_s[:-1][::-1], d.omega_ib_b[1:][::-1], d.f_ib_b[1:][::-1], backward=True)
    assert c.t_s == d.t_s[0]
    assert np.linalg.norm(lie.so3_log(C0.T @ c.C)) < 1e-9
    assert np.linalg.norm(c.v - v0) < 1e-6
    assert np.linalg.norm(c.p - p0) < 1e-5


def test_make_backtrackable():
    c = make_core("liekf_backtrack")
    assert isinstance(c, BacktrackLiekf) and make_backtrackable(c) is c
    for name in ("liekf", "ekf"):  # no class swapping: the session builds liekf_backtrack (session/catalog.py)
        with pytest.raises(ValueError, match="does not support backtracking"):
            make_backtrackable(make_core(name))


def test_the_offline_session_refuses_backtracking_where_the_node_does():
    """ia.align and the node share one check (session/catalog.py): backtracking asked of a core without backward
    propagation is a ValueError naming the cores that have it, not a run of core faults."""
    import insalign_ros as ia

    with pytest.raises(ValueError, match="backward propagation"):
        ia.align("ship", core="iekf", duration_s=5, init_mode="truth", backtrack_passes=2)
    r = ia.align("ship", core="liekf", duration_s=5, init_mode="truth", backtrack_passes=1)
    assert len(r.t_s) > 0 and r.counters["core_faults"] == 0


def test_backtracking_from_the_sensors_runs_one_filter_with_a_flat_heading_prior():
    """The default initialisation (from the sensors, heading unknown) with backtracking: one LIEKF with a flat
    heading prior whose passes converge the heading (a yaw bank cannot run backwards: every start was a core fault,
    no output and no error). Car, 120 s, seed 1: no fault, the flag up before the end, the final attitude inside its
    3-sigma."""
    import insalign_ros as ia

    r = ia.align("car", core="liekf", duration_s=120.0, seed=1, backtrack_passes=2)
    assert r.counters["core_faults"] == 0 and len(r.t_s) > 500
    assert bool(np.asarray(r.aligned)[-1])
    assert np.all(np.abs(r.rpy_err_deg[-1]) < r.sigma3_deg[-1]), (r.rpy_err_deg[-1], r.sigma3_deg[-1])


@pytest.mark.wallclock  # max_step_s is wall time: runs alone under pytest-xdist
def test_driver_live_feed_budgeted_passes_handover_and_catch_up():
    """Live feed with small background budgets: output keeps coming, the worker catches up and takes over at the
    newest sample; the handed-over estimate is at least as good as the live one (two_position, 60-s window)."""
    d = make_scenario("two_position", seed=2, duration_s=90.0)
    core = EarthIekf(EarthIekfConfig())
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [0.5, -0.5, 10.0],
                  core.cfg).apply(core)
    ref = EarthIekf(EarthIekfConfig())
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [0.5, -0.5, 10.0],
                  ref.cfg).apply(ref)
    bt = BacktrackingAligner(core, d.t_s[0], window_s=60.0, passes=1, chunk_samples=200)
    max_step_s = 0.0
    handover_k = None
    for k, ev in enumerate(d.events()):
        if isinstance(ev, ImuSample):
            row = ([ev.stamp_s], [ev.omega_ib_b], [ev.f_ib_b])
            bt.propagate(*row)
            if ev.stamp_s > d.t_s[0]:
                ref.propagate(*row)
        else:
            bt.update(GnssPosition.of(ev))
        if bt.busy and k % 5 == 0:
            t0 = time.perf_counter()
            bt.step_background(0.005)
            max_step_s = max(max_step_s, time.perf_counter() - t0)
            if not bt.busy:
                handover_k = k
    assert bt.state == "done" and handover_k is not None
    assert bt.stats["caught_up_samples"] > 0
    assert bt.stats["handover_stamp_s"] > 60.0
    assert max_step_s < 0.1  # one chunk of 200 samples + budget: no long stall of the feeding thread
    e, r = bt.estimate(), ref.estimate()
    assert e.stamp_s == pytest.approx(d.t_s[-1])
    assert r.stamp_s == pytest.approx(d.t_s[-1])
    err_bt = abs(earth.euler_error_rad(e.C_b_n, d.C_b_n[-1])[2])
    assert np.degrees(err_bt) < 0.3
    assert e.P_att_n[2, 2] < r.P_att_n[2, 2]  # data reused: smaller reported variance


def test_backward_and_catch_up_300s_wall_time():
    """Issue 8: backward + catch-up over 300 s of 100 Hz data < 3 s on one core (the benchmark prints it). Measured
    as a ratio to the forward pass over the same data in the same process, so that the machine's load cancels
    (CPU time alone grew 1.7x under two CPU burners): backward + catch-up are two passes, 1.8-2.2x the forward one on
    a quiet machine and under two burners, one run of five at 2.7x; the test allows 3.5x."""
    d = make_scenario("two_position", seed=0, duration_s=300.0)
    warm = EarthIekf(EarthIekfConfig())  # the kernels loaded (or compiled) outside the timed passes
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [0, 0, 5.0], warm.cfg).apply(warm)
    warm.propagate(d.t_s[1:500], d.omega_ib_b[1:500], d.f_ib_b[1:500])
    warm.propagate(d.t_s[:499][::-1], d.omega_ib_b[1:500][::-1], d.f_ib_b[1:500][::-1], backward=True)
    warm.flush()
    c = EarthIekf(EarthIekfConfig())
    initial_guess(d.t_s[0], d.lat_rad[0], d.lon_rad[0], d.h_m[0], d.C_b_n[0], d.v_n[0], [0, 0, 5.0], c.cfg).apply(c)
    c0 = time.process_time()
    c.propagate(d.t_s[1:], d.omega_ib_b[1:], d.f_ib_b[1:])
    c.flush()
    forward = time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    c.propagate(d.t_s[:-1][::-1], d.omega_ib_b[1:][::-1], d.f_ib_b[1:][::-1], backward=True)
    c.propagate(d.t_s[1:], d.omega_ib_b[1:], d.f_ib_b[1:])
    c.flush()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"backward + catch-up over 300 s at 100 Hz: {wall:.2f} s wall, {cpu:.2f} s CPU; forward pass {forward:.2f} s "
          f"CPU; ratio {cpu / forward:.2f}")
    assert cpu < 3.5 * forward, (cpu, forward)


def test_offline_runner_backtrack_option(tmp_path, capsys):
    """insalign-align --backtrack N: runs the passes at the window end and writes the usual outputs."""
    import json

    from insalign_ros.cli.align import main

    rc = main(["--scenario", "two_position", "--duration", "30", "--core", "earth_iekf", "--rpy-error", "0.5", "-0.5",
               "5", "--backtrack", "1", "--backtrack-window", "20", "--imu-grade", "paper_two_position",
               "--out-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "backtracking: 2000 samples x 1 passes" in err
    summ = json.loads((tmp_path / "two_position_s0_earth_iekf_metrics.json").read_text())
    assert abs(summ["final_err_rpy_deg"][2]) < 1.0
    assert main(["--scenario", "two_position", "--duration", "5", "--core", "ekf", "--backtrack", "1",
                 "--out-dir", str(tmp_path), "--no-progress"]) == 2


def test_reset_covariance_counts_each_measurement_once():
    """covariance='reset' (default): the handed-over yaw sigma equals the forward-only one (the invariant filter's
    covariance does not depend on the state) while the estimate is the backtracked one; 'reuse' (the paper's) is
    optimistic because the window's data are fused twice. Two-position, 60 s, seed 0."""
    import math

    from insalign_ros.filters.earth_iekf import EarthIekf, EarthIekfConfig
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("two_position", seed=0, duration_s=60.0)
    sig = {}
    for mode, passes in (("forward", 0), ("reset", 1), ("reuse", 1)):
        _, bt = run_offline_backtrack(EarthIekf(EarthIekfConfig()), d, [1.0, 1.0, 5.0], window_s=60.0 - 1e-6,
                                      passes=passes, covariance="reuse" if mode == "reuse" else "reset")
        assert bt.state == "done"
        P = bt.estimate().P_att_n
        assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > 0
        sig[mode] = math.sqrt(P[2, 2])
    assert abs(sig["reset"] / sig["forward"] - 1.0) < 0.02, sig
    assert sig["reuse"] < 0.85 * sig["forward"], sig
    with pytest.raises(ValueError):
        run_offline_backtrack(EarthIekf(EarthIekfConfig()), d, [1.0, 1.0, 5.0], 10.0, 1, covariance="twice")
