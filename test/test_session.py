"""AlignmentSession (ROS-free): the same numbers as the per-event runner, lagged fixes fused at their stamps,
reordering, gaps inside the published 3-sigma, time jumps, refusals, the watchdog, static cores through the CLI."""

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import insalign_ros as ia
from insalign_ros.core.types import GnssFix, ImuSample
from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE
from insalign_ros.session.config import SessionConfig
from insalign_ros.session.offline import events_in_arrival_order
from insalign_ros.session.session import AlignmentSession
from insalign_ros.sim.scenarios import make_scenario

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ship60():
    return make_scenario("ship", seed=0, duration_s=60.0)


def _angle(Ca, Cb) -> float:
    from scipy.spatial.transform import Rotation

    return float(np.linalg.norm(Rotation.from_matrix(Ca @ Cb.T).as_rotvec()))


@pytest.mark.parametrize("core", ["liekf", "iekf", "ekf"])
def test_session_equals_the_per_event_runner(ship60, core):
    """The session (fusion delay, buffer, batches of 1000) gives the runner's estimates at the same stamps, exactly."""
    from insalign_ros.filters.registry import make_core
    from reference_loops import run_offline

    # the runner's core has the dataclass defaults: the paper's ship IMU (imu_grade paper_ship)
    r = ia.align(ship60, core=core, init_mode="truth", init_rpy_error_deg=[10, 10, 60], output_period_s=0.0,
                 imu_grade="paper_ship")
    ests, _ = run_offline(make_core(core), ship60, [10, 10, 60], output_period_s=0.0)
    ref = {round(e.stamp_s, 6): e for e in ests}
    common = [(o, ref[round(o.stamp_s, 6)]) for o in r.outputs if round(o.stamp_s, 6) in ref]
    assert len(common) >= 5900
    assert max(_angle(o.estimate.C_b_n, e.C_b_n) for o, e in common) < 1e-9


def test_lagged_fixes_are_fused_at_their_stamps(ship60):
    """Every fix delivered 0.3 s of data time after its stamp: the same run as on time (fusion delay 0.5 s)."""
    kw = dict(core="iekf", init_mode="truth", init_rpy_error_deg=[5, -5, 30])
    on_time = ia.align(ship60, **kw)
    late = ia.align(ship60, fix_delay_s=0.3, **kw)
    assert late.counters["gnss_stale"] == 0 and late.counters["gnss_accepted"] == on_time.counters["gnss_accepted"]
    assert _angle(late.outputs[-1].estimate.C_b_n, on_time.outputs[-1].estimate.C_b_n) < 1e-6
    # beyond the fusion delay a fix is stale: rejected with a count, never applied at the wrong time
    from insalign_ros.session.offline import run_session

    s = AlignmentSession(SessionConfig.from_dict({**kw, "max_fix_lag_s": 0.5}))
    run_session(s, ship60, fix_delay_s=0.8, chunk=1)  # processed after every sample, as a node keeping up
    # every fix that arrived while the IMU ran was stale; the last one arrives after the stream and is fused
    assert s.counters["gnss_stale"] == len(ship60.gnss_t_s) - 1 and s.counters["gnss_accepted"] == 1


def test_out_of_order_imu_inside_the_window_is_put_back_in_order(ship60):
    """Samples swapped in pairs on arrival: reordered (counted), same estimate as in order."""
    cfg = dict(core="liekf", init_mode="truth", init_rpy_error_deg=[5, -5, 30])
    ref = ia.align(ship60, **cfg)
    s = AlignmentSession(SessionConfig.from_dict(cfg))
    evs = list(events_in_arrival_order(ship60))
    imu_idx = [i for i, (k, _) in enumerate(evs) if k == "imu"]
    for a, b in zip(imu_idx[200:4000:2], imu_idx[201:4000:2]):
        evs[a], evs[b] = evs[b], evs[a]
    outs = []
    for kind, item in evs:
        {"imu": s.push_imu, "fix": s.push_fix, "truth": s.push_truth}[kind](item)
        outs += s.process()
    outs += s.finish()
    assert s.counters["imu_reordered"] >= 1800 and s.counters["imu_out_of_order"] == 0
    assert _angle(outs[-1].estimate.C_b_n, ref.outputs[-1].estimate.C_b_n) < 1e-9


def _drop(d, t0, T):
    keep = ~((d.t_s > t0) & (d.t_s < t0 + T))
    return replace(d, t_s=d.t_s[keep], omega_ib_b=d.omega_ib_b[keep], f_ib_b=d.f_ib_b[keep], C_b_n=d.C_b_n[keep],
                   lat_rad=d.lat_rad[keep], lon_rad=d.lon_rad[keep], h_m=d.h_m[keep], v_n=d.v_n[keep])


@pytest.mark.parametrize("scenario,core,T,t0", [("ship", "iekf", 0.3, 40.0), ("car", "liekf", 0.3, 40.0),
                                                ("ship", "iekf", 1.5, 85.7), ("car", "iekf", 1.5, 30.0)])
def test_gap_is_bridged_and_counted_and_the_error_stays_inside_3_sigma(scenario, core, T, t0):
    """An IMU dropout: bridged by the candidate (linear, or a polynomial fitted on both sides) that does best on the
    recent data, the covariance inflated by that candidate's worst error there; the Euler errors stay inside the
    published 3-sigma afterwards (docs/session.md, "Gaps"; the ship at 85.7 s was 1.46 x with linear bridging and
    the whole inflation added at the end of the gap)."""
    d = make_scenario(scenario, seed=5 if scenario == "ship" else 2, duration_s=t0 + 30.0,
                      **({"rate_hz": 50.0} if scenario == "ship" else {}))
    # the scenario's grade; the LIEKF (no bias states) keeps the paper's ship noise (ARW 2 deg/sqrt(h), 6x the car
    # IMU's): with the car's own grade it is over-confident on the 10 deg/h, 1 mg car IMU, gap or not (1.98 x the
    # 3-sigma; docs/imu_grades.md)
    grade = "paper_ship" if core == "liekf" else SCENARIO_IMU_GRADE[scenario]
    r = ia.align(_drop(d, t0, T), core=core, init_mode="truth", init_rpy_error_deg=[3, -3, 30], imu_grade=grade)
    assert r.counters["imu_gaps"] == 1
    m = r.t_s > t0
    ratio = np.abs(r.rpy_err_deg[m]) / r.sigma3_deg[m]
    assert ratio.max() < 1.0, ratio.max(axis=0)


def test_session_refuses_values_that_would_disable_it():
    for bad, word in (({"max_gap_s": 1e-6}, "max_gap_s"), ({"gap_factor": 1.0}, "gap_factor"),
                      ({"core": "nope"}, "unknown core"), ({"output_period_s": -1.0}, "output_period_s"),
                      ({"init_sigma_rpy_deg": [1.0, 1.0]}, "init_sigma_rpy_deg")):
        with pytest.raises(ValueError, match=word):
            SessionConfig.from_dict(bad)


def test_time_jump_resets_and_a_fix_ahead_waits(ship60):
    """A run of samples 1 h ahead resets the session; a fix 5 s ahead of the IMU waits and does not poison later
    fixes (they are fused in stamp order)."""
    d = ship60
    # the liekf from the zero guess loses this ship (it tumbles without the guard; the windowed NIS test restarts it
    # at 21 s, the level 3-sigma passes 90 deg near 56 s, by a degree: a different CPU's rounding decides): the guard
    # is off here, this test counts fixes
    s = AlignmentSession(SessionConfig.from_dict({"core": "liekf", "init_mode": "guess", "divergence_nis_window": 0,
                                                  "divergence_level_3sigma_deg": 360.0}))
    fix_ahead = GnssFix(float(d.gnss_t_s[10]), d.gnss_p_e[10], d.gnss_R_e[10])
    s.push_fix(fix_ahead)  # stamped 10 s, arrives first
    for kind, item in events_in_arrival_order(d):
        if kind == "imu":
            s.push_imu(item)
        elif kind == "fix" and item.stamp_s != fix_ahead.stamp_s:
            s.push_fix(item)
        s.process()
    s.finish()
    assert s.counters["gnss_accepted"] == len(d.gnss_t_s) - 1  # every fix but the one used for the position
    assert s.counters["gnss_stale"] == 0 and s.counters["gnss_duplicate"] == 0
    for k in range(6):
        s.push_imu(ImuSample(3600.0 + 0.01 * k, d.omega_ib_b[k], d.f_ib_b[k]))
    assert s.counters["time_resets"] == 1 and s.counters["imu_future"] == 4
    assert s.core is None and s.newest_imu_t == pytest.approx(3600.05)


@pytest.mark.parametrize("arrays", [False, True])
def test_a_fix_far_ahead_before_the_first_imu_sample_is_rejected_when_it_comes(ship60, arrays):
    """A GNSS reader that delivers before the IMU reader (DDS matches topics one by one): a fix and a velocity
    stamped an hour ahead, pushed before any IMU sample, cannot be checked on arrival; the first IMU sample (one by
    one or as arrays) rejects them as gnss_future / gnss_vel_future, and a fix within max_fix_ahead_s stays."""
    from insalign_ros.core.types import GnssVelocity

    d = ship60
    s = AlignmentSession(SessionConfig.from_dict({"core": "liekf", "init_mode": "guess"}))
    far = GnssFix(float(d.gnss_t_s[3]) + 3600.0, d.gnss_p_e[3], d.gnss_R_e[3])
    near = GnssFix(float(d.gnss_t_s[3]), d.gnss_p_e[3], d.gnss_R_e[3])
    for fix in (far, near):
        assert s.push_fix(fix)  # no IMU time line yet: buffered
    assert s.push_velocity(GnssVelocity(3603.0, np.zeros(3), 0.01 * np.eye(3)))
    if arrays:
        assert s.push_imu_arrays(d.t_s[:10], d.omega_ib_b[:10], d.f_ib_b[:10]) == 10
    else:
        assert s.push_imu(ImuSample(float(d.t_s[0]), d.omega_ib_b[0], d.f_ib_b[0]))
    c = s.counters
    assert (c["gnss_future"], c["gnss_vel_future"], c["gnss_rejected"], c["gnss_vel_rejected"]) == (1, 1, 1, 1)
    assert s.buf.fix_t == [near.stamp_s] and s.buf.vel_t == []
    assert "ahead of the first IMU sample" in s.last_reject


def test_watchdog_drops_the_flag_when_the_imu_goes_silent(ship60):
    s = AlignmentSession(SessionConfig.from_dict({"core": "iekf", "init_mode": "truth", "imu_timeout_s": 1.0,
                                                  "init_rpy_error_deg": [1.0, 1.0, 2.0], "imu_grade": "paper_ship"}))
    wall = 0.0
    for kind, item in events_in_arrival_order(ship60):
        if kind == "imu":
            wall += 0.001
            s.push_imu(item, wall)
            if int(round(item.stamp_s * 100)) % 10 == 0:
                s.process(wall)
        else:
            (s.push_fix if kind == "fix" else s.push_truth)(item)
    s.process(wall)
    assert s.aligned, s.flag.reason
    s.process(wall + 0.5)
    assert s.aligned and s.level() == 0
    s.process(wall + 1.5)
    assert not s.aligned and s.counters["watchdog_trips"] == 1
    assert "no IMU sample for 1.5 s" in s.message() and s.level() == 1


@pytest.mark.parametrize("core", ["coarse", "pkf", "ekf10", "earth_iekf"])
def test_static_cores_run_through_insalign_align(tmp_path, core):
    """Every registered static core through the CLI (zero-velocity updates scheduled by the session)."""
    import json

    from insalign_ros.cli.align import main

    rc = main(["--scenario", "static", "--core", core, "--duration", "60", "--rpy-error", "1", "1", "5",
               "--out-dir", str(tmp_path), "--no-progress", "--no-plot"])
    assert rc == 0
    m = json.loads((tmp_path / f"static_s0_{core}_metrics.json").read_text())
    assert m["init_mode"] == "truth" and m["rpy_error_deg"] == [1.0, 1.0, 5.0]
    assert np.all(np.isfinite(m["final_err_rpy_deg"]))
    assert max(abs(m["final_err_rpy_deg"][0]), abs(m["final_err_rpy_deg"][1])) < 1.0  # level from 1 deg
    if core != "coarse":
        assert m["counters"]["zupt_accepted"] >= 100 or core == "earth_iekf"


def test_duration_on_a_bag_with_truth_and_initial_rpy_is_honoured(tmp_path):
    import json

    from insalign_ros.cli.align import main
    from insalign_ros.io.bag import write_bag

    bag = tmp_path / "ship_bag"
    write_bag(make_scenario("ship", seed=5, duration_s=30.0), bag)
    assert main([str(bag), "--duration", "12", "--core", "iekf", "--initial-rpy", "0", "0", "0",
                 "--out-dir", str(tmp_path / "o"), "--no-progress", "--no-plot"]) == 0
    m = json.loads((tmp_path / "o" / "ship_bag_iekf_metrics.json").read_text())
    assert m["init_mode"] == "guess" and m["initial_rpy_deg"] == [0.0, 0.0, 0.0] and "rpy_error_deg" not in m
    assert 11.0 < m["duration_s"] <= 12.0


def test_no_capability_probing_in_nodes_and_session():
    """Capabilities are declared by the core interface (filters/base.py), never probed with hasattr/getattr."""
    hits = []
    for p in list((ROOT / "insalign_ros" / "nodes").glob("*.py")) + list((ROOT / "insalign_ros" / "session").glob("*.py")):
        for i, line in enumerate(p.read_text().splitlines(), 1):
            if re.search(r"\b(hasattr|getattr)\(", line):
                hits.append(f"{p.name}:{i}: {line.strip()}")
    assert not hits, hits


def test_euler_3sigma_closed_form_matches_central_differences():
    from scipy.spatial.transform import Rotation

    from insalign_ros.session.flag import euler_3sigma_deg

    rng = np.random.default_rng(0)
    for _ in range(20):
        C = Rotation.from_euler("ZYX", [rng.uniform(-3, 3), rng.uniform(-1.3, 1.3), rng.uniform(-3, 3)]).as_matrix()
        A = rng.normal(size=(3, 3)) * 0.01
        P = A @ A.T
        J = np.zeros((3, 3))
        eps = 1e-6
        for i in range(3):
            e = np.zeros(3)
            e[i] = eps
            ya, pa, ra = Rotation.from_matrix(Rotation.from_rotvec(e).as_matrix() @ C).as_euler("ZYX")
            yb, pb, rb = Rotation.from_matrix(Rotation.from_rotvec(-e).as_matrix() @ C).as_euler("ZYX")
            dd = np.array([ra - rb, pa - pb, ya - yb])
            J[:, i] = (np.mod(dd + math.pi, 2 * math.pi) - math.pi) / (2 * eps)
        fd = 3 * np.degrees(np.sqrt(np.diag(J @ P @ J.T)))
        np.testing.assert_allclose(euler_3sigma_deg(C, P), fd, rtol=1e-6)


@pytest.mark.parametrize("scenario,overrides,core,bound_deg", [
    ("car", {"heading_deg": -120.0}, "iekf", 1.0),   # already moving at 15 m/s when the data start
    ("ship", {}, "iekf", 2.0),
    ("park_drive", {"heading_deg": 150.0, "park_s": 40.0}, "iekf", 1.0),
])
def test_initialisation_from_sensors_no_guess_any_heading(scenario, overrides, core, bound_deg):
    """init_mode 'sensors' (the default): no truth, no guess. Position/velocity from the fixes, level from the
    accelerometers, the unknown heading by a bank of 8 hypotheses. The flag rises, is never up with |yaw error| >
    3 deg, and the final yaw error is within the bound (issue 13 acceptance (a)-(c), offline)."""
    d = make_scenario(scenario, seed=4, duration_s=150.0, **overrides)
    r = ia.align(d, core=core, imu_grade=SCENARIO_IMU_GRADE[scenario])  # default init_mode: sensors
    assert r.diagnostics["core.yaw_hypotheses_alive"] >= 1
    assert r.aligned.any(), r.diagnostics["aligned_reason"]
    assert not np.any(r.aligned & (np.abs(r.rpy_err_deg[:, 2]) > 3.0))
    assert abs(r.rpy_err_deg[-1, 2]) < bound_deg and np.all(np.abs(r.rpy_err_deg[-1]) < r.sigma3_deg[-1])
    assert r.init_t_s - d.t_s[0] < 5.0  # two fixes and a second of accelerometer data


def test_host_stamp_jitter_is_not_a_gap(ship60):
    """+-0.5 ms uniform jitter on 100 Hz stamps (a host-stamped driver): no gap counted, the estimate as without
    jitter to well inside its 3-sigma; a real 50-ms dropout in the same stream is counted."""
    rng = np.random.default_rng(7)
    t = ship60.t_s + rng.uniform(-0.5e-3, 0.5e-3, ship60.n)
    t[0] = ship60.t_s[0]
    jit = replace(ship60, t_s=t)
    kw = dict(core="iekf", init_mode="truth", init_rpy_error_deg=[2, -2, 10], imu_grade="paper_ship")
    r = ia.align(jit, **kw)
    ref = ia.align(ship60, **kw)
    assert r.counters["imu_gaps"] == 0
    err = np.abs(r.rpy_err_deg[-1])
    assert np.all(err < r.sigma3_deg[-1]) and abs(r.rpy_err_deg[-1, 2] - ref.rpy_err_deg[-1, 2]) < 0.2
    keep = np.ones(ship60.n, bool)
    keep[3000:3005] = False  # 5 samples: 60 ms instead of 10 ms
    r2 = ia.align(replace(jit, t_s=t[keep], omega_ib_b=jit.omega_ib_b[keep], f_ib_b=jit.f_ib_b[keep],
                          C_b_n=jit.C_b_n[keep], lat_rad=jit.lat_rad[keep], lon_rad=jit.lon_rad[keep],
                          h_m=jit.h_m[keep], v_n=jit.v_n[keep]), **kw)
    assert r2.counters["imu_gaps"] == 1


def test_insalign_align_on_a_bag_without_truth_needs_no_guess(tmp_path):
    """A recording without truth and without a guess: initialised from the sensors; topic names and the sigma of
    UNKNOWN-covariance fixes are options; a wrong topic is one line and exit 2."""
    import json

    from insalign_ros.cli.align import main
    from insalign_ros.io.bag import write_bag

    bag = tmp_path / "car_bag"
    write_bag(make_scenario("car", seed=3, duration_s=60.0, heading_deg=-120.0), bag, write_truth=False)
    assert main([str(bag), "--core", "iekf", "--out-dir", str(tmp_path / "o"), "--no-progress", "--no-plot",
                 "--imu-topic", "/imu/data", "--unknown-fix-sigma", "2"]) == 0
    m = json.loads((tmp_path / "o" / "car_bag_iekf_metrics.json").read_text())
    assert m["init_mode"] == "sensors" and m["counters"]["gnss_accepted"] >= 55
    assert m["diagnostics"]["core.yaw_hypotheses_alive"] >= 1
    assert main([str(bag), "--imu-topic", "/nope", "--out-dir", str(tmp_path / "o"), "--no-progress"]) == 2


def _fixes_offset(d, idx, east_m):
    from insalign_ros.core import earth

    p = d.gnss_p_e.copy()
    for j in idx:
        lat, lon, _ = earth.ecef_to_geodetic(p[j])
        p[j] = p[j] + earth.C_n_e(lat, lon) @ np.array([east_m, 0, 0])
    return replace(d, gnss_p_e=p)


@pytest.fixture(scope="module")
def ship120():
    return make_scenario("ship", seed=3, duration_s=100.0)


BANK = {"yaw_hypotheses": 8}


@pytest.mark.parametrize("core,params,case", [
    ("iekf", {}, "fix_1000km"), ("liekf", {}, "fix_1000km"), ("ekf", {}, "fix_1000km"), ("iekf", BANK, "fix_1000km"),
    ("iekf", {}, "fix_200m"), ("ekf", BANK, "fix_200m"),
    ("iekf", {}, "spike_30rad_s"), ("liekf", {}, "spike_30rad_s"), ("liekf", BANK, "spike_30rad_s")])
def test_outliers_change_nothing_and_are_counted(ship120, core, params, case):
    """One fix 1000 km or 200 m off (once the filter claims its attitude) is gated before it touches the core; a
    30 rad/s single-sample spike is dropped (a gap, bridged). The estimate equals (fixes) or stays near (spike)
    the clean run, inside its 3-sigma."""
    kw = dict(core=core, core_params=params, init_mode="truth", init_rpy_error_deg=[2, -2, 10], imu_grade="paper_ship")
    valid = np.ones(len(ship120.gnss_t_s), bool)
    valid[80] = False  # the reference: the same run without fix 80 at all
    clean = ia.align(replace(ship120, gnss_valid=valid), **kw)
    if case.startswith("fix"):
        d = _fixes_offset(ship120, [80], 1e6 if case == "fix_1000km" else 200.0)
    else:
        w = ship120.omega_ib_b.copy()
        w[8000] += [30.0, 0.0, 0.0]
        d = replace(ship120, omega_ib_b=w)
    r = ia.align(d, **kw)
    c = r.counters
    if case.startswith("fix"):
        assert c["gnss_gated"] == 1 and c["divergences"] == 0
        # the gated fix changed nothing (state and P): the run equals the one that never had that fix
        assert _angle(r.outputs[-1].estimate.C_b_n, clean.outputs[-1].estimate.C_b_n) < 1e-9
    else:
        assert c["imu_spikes"] == 1 and c["imu_gaps"] == 1
    m = r.t_s > 75.0
    assert np.all(np.abs(r.rpy_err_deg[m]) < 1.05 * r.sigma3_deg[m])  # liekf sits at ~1.0 x on this ship anyway


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf", "pi_liekf"])
def test_a_lost_filter_is_a_divergence_then_realigned(core):
    """A 60-deg yaw kick of the aligned filter at 60 s (it keeps its small covariance: a lost filter): the fixes
    fail the NIS gate from the second on, the first gated fix drops the flag, 3 in a row = divergence (the CUSUM
    takes gated fixes from the second of a run on, capped at the gate; docs/session.md): FAULT,
    re-initialised from the sensors (yaw bank) and aligned again within 60 s."""
    from scipy.spatial.transform import Rotation

    d = make_scenario("ship", seed=3, duration_s=180.0)
    # (PI-LIEKF: a wall-time budget no LMI solve reaches, so that its gains do not depend on the machine's load)
    s = AlignmentSession(SessionConfig.from_dict({"core": core, "init_mode": "truth", "imu_grade": "paper_ship",
                                                  "init_rpy_error_deg": [2.0, -2.0, 10.0]}),
                         core_params={"lmi_time_budget_s": 600.0} if core == "pi_liekf" else None)
    outs, kicked = [], False
    for kind, item in events_in_arrival_order(d):
        {"imu": s.push_imu, "fix": s.push_fix, "truth": s.push_truth}[kind](item)
        if kind == "imu" and int(round(item.stamp_s * 100)) % 10 == 0:
            outs += s.process()
            if not kicked and s.processed_t is not None and s.processed_t >= 60.0:
                assert s.aligned
                c = s.core
                c.flush()
                up_i = c.p / np.linalg.norm(c.p)
                c.C = Rotation.from_rotvec(math.radians(60.0) * up_i).as_matrix() @ c.C
                kicked = True
    outs += s.finish()
    t = np.array([o.stamp_s for o in outs])
    aligned = np.array([o.aligned for o in outs])
    yaw_err = np.array([o.euler_error_deg[2] if o.euler_error_deg is not None else np.nan for o in outs])
    assert s.counters["divergences"] == 1 and s.counters["divergences_cusum"] == 1 and s.counters["gnss_gated"] == 3, s.counters
    # the fix at 61 s still fits (the position error grows with time: NIS ~12 < 100); from the next one on the flag
    # is down until re-aligned (measured: gated at 62-64 s, divergence at 64 s; 66 s with 5 gated fixes in a row)
    assert not np.any(aligned[(t >= 62.0) & (t < 67.0)])
    again = t[(t > 67.0) & aligned]
    assert again.size and again[0] < 127.0, again[:1]
    assert not np.any(aligned & (np.abs(yaw_err) > 3.0) & ((t < 60.0) | (t >= 62.0)))


def test_outputs_of_a_full_buffer_are_not_lost(ship60):
    """A caller that pushes without calling process(): the buffer bound forces processing inside push_imu, and the
    outputs made there come out of the next finish()/process() (before: dropped), the same as a regular caller's."""
    cfg = dict(core="iekf", init_mode="truth", init_rpy_error_deg=[5, -5, 30])
    ref = ia.align(ship60, **cfg)
    s = AlignmentSession(SessionConfig.from_dict(cfg))
    s.MAX_BUFFER = 500  # 5 s at 100 Hz: the 60-s run overflows it about 110 times
    for kind, item in events_in_arrival_order(ship60):
        {"imu": s.push_imu, "fix": s.push_fix, "truth": s.push_truth}[kind](item)
    outs = s.finish()
    assert [round(o.stamp_s, 6) for o in outs] == [round(o.stamp_s, 6) for o in ref.outputs]
    assert _angle(outs[-1].estimate.C_b_n, ref.outputs[-1].estimate.C_b_n) < 1e-9
    # the same with the IMU pushed as arrays (blocks of up to 50 samples between the other inputs): the bound holds
    s = AlignmentSession(SessionConfig.from_dict(cfg))
    s.MAX_BUFFER = 500
    block, longest = [], 0

    def flush():
        nonlocal longest
        if block:
            s.push_imu_arrays([x.stamp_s for x in block], [x.omega_ib_b for x in block], [x.f_ib_b for x in block])
            block.clear()
            longest = max(longest, len(s.buf.imu))

    for kind, item in events_in_arrival_order(ship60):
        if kind == "imu":
            block.append(item)
            if len(block) == 50:
                flush()
            continue
        flush()
        {"fix": s.push_fix, "truth": s.push_truth}[kind](item)
    flush()
    assert longest <= s.MAX_BUFFER
    outs = s.finish()
    assert [round(o.stamp_s, 6) for o in outs] == [round(o.stamp_s, 6) for o in ref.outputs]
    assert _angle(outs[-1].estimate.C_b_n, ref.outputs[-1].estimate.C_b_n) < 1e-9


def test_reject_lines_print_the_users_stamps():
    """The node subtracts an epoch from header stamps (stamp_offset_s); what it logs must be the header stamp."""
    s = AlignmentSession(SessionConfig.from_dict({"core": "iekf"}))
    s.stamp_offset_s = 1_700_000_000.0
    w, f = np.zeros(3), np.array([0.0, 0.0, 9.8])
    assert s.push_imu(ImuSample(1.0, w, f)) and not s.push_imu(ImuSample(1.0, w, f))
    assert s.last_reject == "imu: duplicate stamp 1700000001.000000"
