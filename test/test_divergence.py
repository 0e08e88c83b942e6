"""The session's divergence guard (issue 15): bad fixes are held through, not re-initialised from; a filter lost
before it claims its attitude is found by the windowed NIS test or the covariance sanity checks; fill rows are
gaps. docs/session.md "Outliers and divergence"."""

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE
from insalign_ros.sim.scenarios import make_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from divergence_mc import SHIP, YAW_BOUND_DEG, offset_fixes, run, yaw_kick  # noqa: E402


@pytest.fixture(scope="module")
def ship():
    return make_scenario("ship", seed=3, duration_s=85.0)


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf", "pi_liekf"])
def test_a_block_of_wrong_fixes_is_held_through_not_reinitialised_from(ship, core):
    """10 s of fixes 300 m East and 180 m North of the truth (reported sigma unchanged: small) while the filter is
    aligned: the first bad fix is a jump in the fix sequence and fails the NIS gate -> bad fixes, not a lost filter:
    the filter coasts on the IMU (flag down) and fuses again when the fixes come back; no re-initialisation from the
    bad fixes (which used to diverge again at the jump back)."""
    d = offset_fixes(ship, 40.0, 50.0, (300.0, 180.0))
    s, t, aligned, yaw_err, logs = run(d, {"core": core, **SHIP})
    c = s.counters
    assert c["gnss_holds"] == 1 and c["gnss_gated"] == 10 and c["divergences"] == 0, dict(c)
    assert c["gnss_jumps"] >= 2  # at least the first bad fix and the first good one after the block
    assert any(k == "gnss_holds" and "bad fixes, not a lost filter" in text for k, text, _ in logs)
    assert aligned[(t > 30.0) & (t < 40.0)].any()  # aligned before the block
    assert not aligned[(t >= 40.0) & (t < 50.0)].any()  # flag down throughout the block
    assert not np.any(aligned & (np.abs(yaw_err) > YAW_BOUND_DEG))
    again = t[(t >= 50.0) & aligned & (np.abs(yaw_err) < 2.0)]
    assert again.size and again[0] < 50.0 + 60.0


@pytest.mark.parametrize("core", ["iekf", "liekf"])
def test_a_filter_lost_before_it_claims_its_attitude_is_found_by_the_windowed_nis(ship, core):
    """A 170-deg yaw kick at 3 s, before the filter claims its attitude (the NIS gate is not armed yet): unguarded,
    a single iekf/liekf on this ship tumbles for good. The windowed NIS test (mean of 10 fixes > 1000) declares the
    divergence: FAULT with the reason, re-initialised from the sensors, aligned again within 60 s."""
    s, t, aligned, yaw_err, logs = run(ship, {"core": core, **SHIP}, at_s=3.0, action=yaw_kick(170.0))
    c = s.counters
    assert c["divergences"] == 1 and c["divergences_nis"] == 1, dict(c)
    fault = [(text, tf) for k, text, tf in logs if k == "divergence"]
    assert len(fault) == 1 and "mean NIS" in fault[0][0]
    t_fault = fault[0][1]
    assert 3.0 < t_fault < 3.0 + 20.0, t_fault  # measured: FAULT at 16 s (18 s before the imu_grade merge)
    inits = [text for k, text, _ in logs if k == "init"]
    assert len(inits) == 2 and "from sensors" in inits[1]
    assert not aligned[(t >= 3.0) & (t < s.init_t)].any()
    assert not np.any(aligned & (np.abs(yaw_err) > YAW_BOUND_DEG))
    again = t[(t > t_fault) & aligned & (np.abs(yaw_err) < 2.0)]
    assert again.size and again[0] < t_fault + 60.0, (t_fault, again[:1])


def _indefinite_attitude_covariance(s):
    c = s.core
    c.flush()
    c.P[0, 1] = c.P[1, 0] = 2.0 * math.sqrt(c.P[0, 0] * c.P[1, 1])  # correlation 2: not positive definite


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf"])
def test_an_impossible_attitude_covariance_is_a_divergence(core):
    """An attitude covariance that is not positive definite (injected at 3 s, before the claim) is caught at the
    next fix: FAULT with the reason and a re-initialisation; the counters say which check fired."""
    d = make_scenario("ship", seed=3, duration_s=25.0)
    s, t, aligned, _, logs = run(d, {"core": core, **SHIP}, at_s=3.0, action=_indefinite_attitude_covariance)
    c = s.counters
    assert c["divergences"] == 1 and c["divergences_covariance"] == 1 and c["core_faults"] == 0, dict(c)
    fault = [(text, tf) for k, text, tf in logs if k == "divergence"]
    assert len(fault) == 1 and "not positive definite" in fault[0][0] and 3.0 < fault[0][1] <= 4.0 + 0.02
    assert fault[0][1] < s.init_t <= fault[0][1] + 4.0  # re-initialised from three consistent fixes
    assert not aligned[t < s.init_t].any()


@pytest.fixture(scope="module")
def car_with_fill_block():
    """A simulated car (seed 2, 100 Hz) with the 2 s of IMU samples after 45.70 s (in a turn) replaced by the
    straight line between the samples on both sides, as the RT3003 writes its fill rows (KITTI mode -1)."""
    d = make_scenario("car", seed=2, duration_s=90.0).until(80.0)  # the 90-s drive plan: aligned before the turn
    a = int(np.argmin(np.abs(d.t_s - 45.70)))
    b = a + 201  # samples a+1 .. a+200 (2.0 s) interpolated between a and b
    k = (np.arange(1, 201) / 201.0)[:, None]
    w, f = d.omega_ib_b.copy(), d.f_ib_b.copy()
    w[a + 1:b] = w[a] + (w[b] - w[a]) * k
    f[a + 1:b] = f[a] + (f[b] - f[a]) * k
    heading_loss_deg = math.degrees(abs(np.sum(d.omega_ib_b[a + 1:b, 2] - w[a + 1:b, 2])) * 0.01)
    valid = np.ones(d.n, bool)
    valid[a + 1:b] = False
    return replace(d, omega_ib_b=w, f_ib_b=f), valid, float(d.t_s[b]), heading_loss_deg


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf"])
def test_fill_rows_in_a_turn_are_gaps_not_data(car_with_fill_block, core):
    """The same interpolated block, marked invalid (the session leaves it out: a gap, bridged, covariance inflated)
    or fed as data: over the 30 s after it, the mean attitude NEES is inside its 95 % band with the fills handled
    and far above it without (measured, iekf/liekf/ekf: 1.4/2.4/2.4 handled, 174/77/178 as data)."""
    from insalign_ros.eval.metrics import nees_band

    filled, valid, t_end, heading_loss_deg = car_with_fill_block
    assert heading_loss_deg > 5.0  # the interpolation loses that much heading in this turn (KITTI: up to 11.7 deg)
    lo, hi = nees_band(1)
    # max_gap_s above the 2-s block: the default (2 s) would make it a time jump (a reset), not a gap
    # the scenario's IMU grade; the LIEKF (no bias states) keeps the paper's ship noise, as in test_session.py
    grade = "paper_ship" if core == "liekf" else SCENARIO_IMU_GRADE["car"]
    kw = dict(core=core, init_mode="truth", init_rpy_error_deg=[2.0, -2.0, 10.0], max_gap_s=3.0, imu_grade=grade)
    import insalign_ros as ia

    handled = ia.align(replace(filled, imu_valid=valid), **kw)
    as_data = ia.align(filled, **kw)
    m_h = (handled.t_s >= t_end) & (handled.t_s < t_end + 30.0)
    m_d = (as_data.t_s >= t_end) & (as_data.t_s < t_end + 30.0)
    assert handled.counters["imu_gaps"] == 1 and as_data.counters["imu_gaps"] == 0
    assert lo < np.mean(handled.nees[m_h]) < hi
    assert np.mean(as_data.nees[m_d]) > 3.0 * hi
    assert not np.any(handled.aligned & (np.abs(handled.rpy_err_deg[:, 2]) > YAW_BOUND_DEG))


def test_after_a_divergence_the_status_is_fault_with_the_reason_until_three_consistent_fixes():
    """Right after the divergence (an indefinite covariance at 3 s, caught at the 4-s fix): status FAULT, the
    reason in the status message, diagnostic level ERROR, the counters in the diagnostics; no new filter before
    three consistent fixes after the fault (5 s, 6 s: still waiting at 5.5 s)."""
    from insalign_ros.filters.base import AlignmentStatus

    d = make_scenario("ship", seed=3, duration_s=5.5)
    s, t, aligned, _, logs = run(d, {"core": "iekf", **SHIP}, at_s=3.0, action=_indefinite_attitude_covariance)
    assert s.core is None and s.status == AlignmentStatus.FAULT and s.level() == 2
    assert "not positive definite" in s.message() and "re-initialising" in s.message()
    diag = s.diagnostics()
    assert diag["divergences"] == "1" and diag["divergences_covariance"] == "1" and diag["aligned"] == "false"


@pytest.mark.parametrize("core", ["iekf", "ekf"])
def test_a_small_kick_under_the_gate_drops_the_flag_by_the_cusum(ship, core):
    """An 8-deg yaw kick of the aligned filter at 60 s: no fix reaches the NIS gate (100), the sequential test does:
    the CUSUM of the NIS log-likelihood ratio passes ``divergence_cusum_flag_llr`` (8) at the second fix (NIS ~36)
    and drops the flag; the filter recovers by itself (no divergence: the CUSUM stays under 40). Never up with a
    wrong yaw after that fix (the 2 s before it are blind: the fix at 61 s still fits)."""
    s, t, aligned, yaw_err, logs = run(ship, {"core": core, **SHIP}, at_s=60.0, action=yaw_kick(8.0))
    c = s.counters
    assert c["gnss_gated"] == 0 and c["divergences"] == 0, dict(c)
    drops = [tf for k, text, tf in logs if k == "flag" and "inconsistent innovations" in text]
    assert len(drops) == 1 and 60.0 < drops[0] <= 63.0 + 0.02, drops
    assert aligned[(t > 55.0) & (t < 60.0)].all()
    assert not np.any(aligned & (t >= drops[0]) & (np.abs(yaw_err) > YAW_BOUND_DEG))


@pytest.mark.parametrize("core", ["iekf", "ekf"])
def test_a_reinitialisation_keeps_the_lost_filters_level(ship, core):
    """A 60-deg yaw kick at 60 s -> divergence at 66 s. The accelerometers' level on this rolling ship is off by
    tens of degrees (level 1-sigma 40-60 deg); the lost filter still claims its level (gravity keeps it observable):
    the re-initialisation takes it, carried by the gyros to the new start, when it agrees with the accelerometers.
    Roll and pitch within 1 deg of the truth at the re-initialisation (measured 0.07 deg; the accelerometers alone:
    -40.5 / -10.1 deg at a 1-sigma of 60 deg)."""
    s, t, aligned, yaw_err, logs = run(ship, {"core": core, **SHIP}, at_s=60.0, action=yaw_kick(60.0))
    assert s.counters["divergences"] == 1, dict(s.counters)
    inits = [(text, tf) for k, text, tf in logs if k == "init"]
    assert len(inits) == 2 and "the lost filter's level" in inits[1][0], inits
    _, t_init = inits[1]
    tr = ship.C_b_n[int(np.argmin(np.abs(ship.t_s - t_init)))]
    from insalign_ros.core import earth

    rpy0 = [float(x) for x in inits[1][0].split("rpy [")[1].split("]")[0].split(",")]
    truth = np.degrees(earth.rpy_from_C_b_n(tr))
    assert abs(rpy0[0] - truth[0]) < 1.0 and abs(rpy0[1] - truth[1]) < 1.0, (rpy0, truth)


def test_diagnostics_show_the_cusum_that_drops_the_flag(ship):
    """/diagnostics carries the guard's statistics: when the CUSUM drops the flag (8-deg kick, as above), the value
    published is the one above ``divergence_cusum_flag_llr``, and the windowed NIS mean is there."""
    seen = []

    def kick_and_watch(s):
        yaw_kick(8.0)(s)
        lower = s.monitor.lower_flag

        def spy(reason, *a, **k):
            seen.append((reason, s.diagnostics()))
            return lower(reason, *a, **k)
        s.monitor.lower_flag = spy

    run(ship, {"core": "iekf", **SHIP}, at_s=60.0, action=kick_and_watch)
    hits = [d for reason, d in seen if "inconsistent innovations" in reason]
    assert hits, [r for r, _ in seen]
    assert float(hits[0]["divergence_cusum_llr"]) > 8.0 and float(hits[0]["divergence_nis_window_mean"]) > 3.0


def test_the_car_kick_faults_within_a_second_of_its_physical_detection_floor():
    """A 60-deg yaw kick of the aligned iekf at 60 s on the car (seed 4, driving straight: the kick is invisible
    until the first turn). The floor: the first fix whose open-loop innovation from the kick (the double integral
    of (R_z(60) - I) f_n of the true specific force) exceeds the gate in the claimed covariance: 12 s after the
    kick. The FAULT comes at most 1 s after it (measured 13 s: CUSUM, whose gated fixes count from the second of a
    run on; 16 s when only 5 gated fixes in a row faulted) and never before the floor's p = 0.001 level."""
    from divergence_mc import detection_floor

    d = make_scenario("car", seed=4, duration_s=150.0).until(80.0)  # the benchmark's drive plan
    rec = {}
    s, t, aligned, yaw_err, logs = run(d, {"core": "iekf", "imu_grade": SCENARIO_IMU_GRADE["car"],
                                           "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]},
                                       at_s=60.0, action=yaw_kick(60.0, rec))
    floor_gate, floor_any = detection_floor(d, rec["t"], 60.0, rec["M"], 100.0)
    assert 11.0 <= floor_gate <= 13.0 and floor_any < floor_gate, (floor_gate, floor_any)
    fault = [tf for k, _, tf in logs if k == "divergence"]
    assert len(fault) == 1 and s.counters["divergences_cusum"] == 1, dict(s.counters)
    assert floor_any <= fault[0] - rec["t"] <= floor_gate + 1.0 + 0.02, (fault[0] - rec["t"], floor_gate)


def test_a_reinitialisation_during_a_walking_gnss_restarts_at_the_jump_back():
    """Car seed 3, ekf, a GNSS bias walking at 3.5 m/s over 60-70 s then back at once: the CUSUM faults the
    aligned filter inside the walk (63 s) and the session re-initialises from walking fixes (66 s). The jump back
    at 70 s comes before the young filter claims its attitude: re-initialised again from the fixes after the jump
    (73 s) instead of fusing it; re-aligned 45 s after the walk (never within the run before this rule)."""
    d = offset_fixes(make_scenario("car", seed=3, duration_s=150.0).until(125.0), 60.0, 70.0, (3.0, 1.8), walk=True)
    s, t, aligned, yaw_err, logs = run(d, {"core": "ekf", "imu_grade": SCENARIO_IMU_GRADE["car"],
                                           "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]})
    c = s.counters
    # with the fix-sigma floor (guard.model_floor_m) the young filter may instead hold through the jump back (a
    # GNSS hold) rather than restart its re-initialisation: either way it is not fused
    assert c["divergences"] == 1 and (c["reinit_restarts"] == 1 or c["gnss_holds"] >= 1), dict(c)
    inits = [tf for k, _, tf in logs if k == "init"]
    restart = [tf for k, _, tf in logs if k == "reinit_restarts"]
    if restart:
        assert len(inits) == 3 and 70.0 <= restart[0] < 71.02 and restart[0] < inits[2] <= restart[0] + 4.0, (inits, restart)
    assert not np.any(aligned & (np.abs(yaw_err) > YAW_BOUND_DEG))
    again = t[(t > 70.0) & aligned & (np.abs(yaw_err) < 2.0)]
    assert again.size and again[0] < 70.0 + 60.0, again[:1]


#: the PI-LIEKF's LMI solve under a wall-time budget falls back to safe gains on a loaded CPU: a budget no solve
#: reaches makes the gains (and so the run) independent of the machine's load
NO_LMI_BUDGET = {"lmi_time_budget_s": 600.0}


def test_the_pi_liekf_loop_no_longer_hides_a_lost_attitude_on_the_car():
    """Car seed 0, PI-LIEKF, a 60-deg yaw kick at 60 s while driving straight. Its PI loop (k_P 1.6, k_I 0.5 from
    the LMI solved at 60 s) pulled the position onto the fixes: its own NIS stayed 6-11 while the open-loop error
    grew to 49 m, and the CUSUM faulted 20 s after the kick (8 s after the floor). The core now reports the NIS of
    the plain LIEKF's innovation (first-order offset carried through the PI corrections, filters/pi_liekf.py):
    FAULT at most 1 s after the gate floor (measured: 13 s, floor 12 s), never before the p = 0.001 floor."""
    from divergence_mc import detection_floor

    d = make_scenario("car", seed=0, duration_s=150.0).until(80.0)
    rec = {}
    s, t, aligned, yaw_err, logs = run(d, {"core": "pi_liekf", "imu_grade": SCENARIO_IMU_GRADE["car"],
                                           "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]},
                                       NO_LMI_BUDGET, at_s=60.0, action=yaw_kick(60.0, rec))
    floor_gate, floor_any = detection_floor(d, rec["t"], 60.0, rec["M"], 100.0)
    fault = [tf for k, _, tf in logs if k == "divergence"]
    assert len(fault) == 1, dict(s.counters)
    assert floor_any <= fault[0] - rec["t"] <= floor_gate + 1.0 + 0.02, (fault[0] - rec["t"], floor_gate)
    assert not np.any(aligned & (t >= fault[0]) & (np.abs(yaw_err) > YAW_BOUND_DEG))


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf", "pi_liekf"])
def test_a_car_kick_before_a_turn_faults_within_10_s(core):
    """Car seed 1, a 60-deg yaw kick at 66 s, 2 s before the 14-deg turn of 68-72 s (issue 15: FAULT within 10 s when
    the car manoeuvres). The floor (open-loop NIS above the gate) is 9 s; every in-motion core faults 8-10 s after
    the kick (PI-LIEKF: 15 s before it reported the plain LIEKF's NIS) and its flag is down from the FAULT on."""
    d = make_scenario("car", seed=1, duration_s=150.0).until(80.0)
    s, t, aligned, yaw_err, logs = run(d, {"core": core, "imu_grade": SCENARIO_IMU_GRADE["car"],
                                           "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]},
                                       NO_LMI_BUDGET if core == "pi_liekf" else None, at_s=66.0, action=yaw_kick(60.0))
    fault = [tf for k, _, tf in logs if k == "divergence" and tf >= 66.0]
    assert fault and 66.0 < fault[0] <= 66.0 + 10.0 + 0.02, (fault, dict(s.counters))
    assert not np.any(aligned & (t >= fault[0]) & (np.abs(yaw_err) > YAW_BOUND_DEG))


def test_the_jump_test_sees_the_first_fix_after_a_reinitialisation():
    """Car seed 0, ekf, the walking GNSS of 60-70 s: the CUSUM faults the filter inside the walk (66 s), the session
    re-initialises from walking fixes at 69 s and the walk jumps back at 70 s, 1 s later. The fixes the
    initialisation consumed (67-69 s) are in the jump test's sequence now, so the 70-s fix is a jump (7 m beyond the
    allowance) and restarts the re-initialisation; before, the sequence had a 4-s hole there, the young filter fused
    the jump back and re-aligned 65 s after the walk. Now within 60 s (measured 39 s)."""
    d = offset_fixes(make_scenario("car", seed=0, duration_s=150.0).until(120.0), 60.0, 70.0, (3.0, 1.8), walk=True)
    s, t, aligned, yaw_err, logs = run(d, {"core": "ekf", "imu_grade": SCENARIO_IMU_GRADE["car"],
                                           "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 10.0]})
    restart = [tf for k, _, tf in logs if k == "reinit_restarts"]
    assert s.counters["reinit_restarts"] == 1 and 70.0 <= restart[0] < 71.02, (restart, dict(s.counters))
    assert not np.any(aligned & (np.abs(yaw_err) > YAW_BOUND_DEG))
    again = t[(t > 70.0) & aligned & (np.abs(yaw_err) < 2.0)]
    assert again.size and again[0] < 70.0 + 60.0, again[:1]


def _fixes_moved(d, rows, east_m: float):
    """``d`` with the fixes of ``rows`` moved ``east_m`` East (their reported covariance unchanged)."""
    from insalign_ros.core import earth

    p = np.array(d.gnss_p_e, float)
    for k in rows:
        lat, lon, _ = earth.ecef_to_geodetic(p[k])
        p[k] = p[k] + earth.C_n_e(lat, lon) @ np.array([east_m, 0.0, 0.0])
    return replace(d, gnss_p_e=p)


def _streamed(d, cfg: dict):
    """``d`` pushed as a driver delivers it (arrival order, the truth pose with each IMU sample, ``process`` every
    0.25 s): the filter runs when the later fixes arrive, so the fix screen at the door leaves them to the filter's
    tests (offline, every fix is at the door before the filter starts). Returns (session, outputs, |error| / 3-sigma
    per output)."""
    from insalign_ros.core import earth
    from insalign_ros.session.config import SessionConfig
    from insalign_ros.session.offline import events_in_arrival_order, truth_table
    from insalign_ros.session.session import AlignmentSession

    s = AlignmentSession(SessionConfig.from_dict(cfg))
    table, outs, k = truth_table(d), [], 0
    for kind, item in events_in_arrival_order(d):
        if kind == "imu":
            s.push_truth(table.sample(k))
            s.push_imu(item, float(item.stamp_s))
            k += 1
            if k % 25 == 0:
                outs += s.process(float(item.stamp_s))
        elif kind == "fix":
            s.push_fix(item, float(item.stamp_s))
    outs += s.finish()
    rows = np.searchsorted(d.t_s, [o.stamp_s - 1e-9 for o in outs])
    ratio = np.array([np.max(np.abs(np.degrees(earth.euler_error_rad(o.estimate.C_b_n, table.C_b_n[r])))
                             / o.euler_3sigma_deg) for o, r in zip(outs, rows)])
    return s, outs, ratio


@pytest.mark.parametrize("core", ["iekf", "liekf", "ekf"])
@pytest.mark.parametrize("east_m", [1e6, 2e3])
def test_a_far_fix_before_the_claim_with_no_sequence_to_judge_it_is_not_fused(core, east_m):
    """The fix 1 s after an initialisation from the truth (fuzz_session: the first fix after a restart of the
    driver), 1,000 km or 2 km off: one fix before it, so the jump test cannot see it, and no NIS gate before the
    claim. Farther from the filter's position than any attitude error can move it in 1 s (guard.fix_off: 5 sigma,
    the lever arm, g T^2): not fused (gnss_gated), and the errors stay inside their 3-sigma. Fused, the 1,000-km fix
    left the filter 50-110 deg off at a 3-sigma of 2-25 deg (74x)."""
    d = make_scenario("ship", seed=3, duration_s=20.0)
    k = int(np.flatnonzero(d.gnss_t_s >= 1.0)[0])
    cfg = {"core": core, "imu_grade": SCENARIO_IMU_GRADE["ship"], "init_mode": "truth",
           "init_rpy_error_deg": [1.0, -1.0, 5.0]}
    s, outs, ratio = _streamed(_fixes_moved(d, [k], east_m), cfg)
    c = s.counters
    assert c["gnss_gated"] == 1 and c["divergences"] == 0 and c["gnss_implausible"] == 0, dict(c)
    # as the run without the bad fix (iekf, liekf, ekf: 0.74, 0.98, 1.56); fused: 33, 50, 1.6 (1,000 km), 4.1, 4.2,
    # 6.4 (2 km)
    clean = np.max(_streamed(d, cfg)[2])
    assert len(outs) > 150 and np.max(ratio) < max(1.2, 1.1 * clean)


def test_three_fixes_in_a_row_off_the_filters_position_are_believed():
    """Every fix 2 km East of the truth the filter starts from: its position is what is wrong. The first two are
    not fused, the third is believed (guard.FIX_OFF_BELIEVED): a divergence, re-initialisation from the fixes, and
    the errors inside their 3-sigma from then on (not a filter that refuses every fix)."""
    d = make_scenario("ship", seed=3, duration_s=30.0)
    s, outs, ratio = _streamed(_fixes_moved(d, range(len(d.gnss_t_s)), 2e3),
                               {"core": "iekf", "imu_grade": SCENARIO_IMU_GRADE["ship"], "init_mode": "truth",
                                "init_rpy_error_deg": [1.0, -1.0, 5.0]})
    c = s.counters
    assert c["divergences"] == 1 and c["gnss_gated"] == 2, dict(c)
    assert len(outs) > 200 and np.max(ratio) < 1.2  # 0.98; without the test 55 (the fixes fused into the filter)
