"""The fast paths give the numbers of the reference paths (issue 16).

* The compiled kernels and the session's fast path (runs of IMU samples between events as arrays,
  ``AlignmentSession._fast_run``; IMU pushed as arrays by ``ia.align``) against the numpy oracles of test/oracles.py
  with one session step per sample: every core through ``ia.align``, 60 s (ship data for the in-motion cores, the
  static scenario for the static ones).
* The session's fast path alone: 300 s (IEKF and EKF10), and data with every event the
  fast path must hand back to the per-sample path (gaps, spikes, invalid rows, stamp jitter, late fixes, IMU out of
  order, node-style pushes).

The attitude of every output must agree to 1e-9 rad (the issue's bound; measured: 0 for the session path,
~1e-13 for the compiled one, i.e. rounding), the covariance to 1e-9 relative, stamps and counters exactly.
"""

from dataclasses import replace

import math

import numpy as np
import pytest

import insalign_ros as ia
from insalign_ros.filters.measurements import GnssPosition, ZeroVelocity
from insalign_ros.core import earth
from insalign_ros.core import mechanization_numba as nb
from insalign_ros.core.types import GnssFix, ImuSample
from insalign_ros.filters import registry
from insalign_ros.session.offline import events_in_arrival_order
from insalign_ros.session.session import AlignmentSession
from oracles import propagate_eci

import oracles


STATIC = ("pkf", "ekf10", "coarse", "earth_iekf")  # earth_iekf: static (two-position) alignment; on a ship it
# diverges and its numbers are chaotic (rounding differences grow to radians)
KW = dict(init_mode="truth", init_rpy_error_deg=[2.0, -2.0, 30.0], output_period_s=0.5)


@pytest.fixture(scope="module")
def data():
    return {"ship": ia.simulate("ship", seed=3, duration_s=60.0), "static": ia.simulate("static", seed=3,
                                                                                       duration_s=60.0)}


def _run(monkeypatch, d, core, compiled, fast=None, **kw):
    """``compiled`` False: every kernel replaced by its numpy oracle (undone before returning)."""
    with monkeypatch.context() as m:
        if not compiled:
            oracles.use_reference_paths(m)
        m.setattr(AlignmentSession, "fast_path", compiled if fast is None else fast)
        return ia.align(d, core=core, **{**KW, **kw})


def _assert_same(ref, fast, bound_rad=1e-9):
    assert len(ref.outputs) == len(fast.outputs) > 50
    np.testing.assert_array_equal(ref.t_s, fast.t_s)
    d_att = [np.linalg.norm(earth.heading_error_enu_rad(a.estimate.C_b_n, b.estimate.C_b_n))
             for a, b in zip(ref.outputs, fast.outputs)]
    assert max(d_att) < bound_rad, f"attitude differs by {max(d_att):.3e} rad"
    for a, b in zip(ref.outputs, fast.outputs):
        scale = np.abs(a.estimate.P).max()
        assert np.abs(a.estimate.P - b.estimate.P).max() <= 1e-9 * scale
        assert a.aligned == b.aligned and a.reason == b.reason
        # the fast path's Euler errors are computed in one call at the end (Output.euler_error_deg, deferred)
        assert (a.euler_error_deg is None) == (b.euler_error_deg is None)
        if a.euler_error_deg is not None:
            assert np.abs(a.euler_error_deg - b.euler_error_deg).max() <= 10.0 * np.degrees(bound_rad)
    assert ref.counters == fast.counters


@pytest.mark.parametrize("core", registry.core_names())
def test_compiled_path_matches_reference(monkeypatch, data, core):
    d = data["static" if core in STATIC else "ship"]
    ref = _run(monkeypatch, d, core, False)
    fast = _run(monkeypatch, d, core, True)
    # auto's static heading comes from gyrocompassing: the azimuth divides by the horizontal Earth rate
    # (omega_ie cos lat ~ 5e-5 rad/s), so the roundoff of two orders of summation (numba vs numpy) grows by ~1e4 there
    # (measured 5.5e-9 rad); every other core within 1e-9
    _assert_same(ref, fast, **({"bound_rad": 1e-8} if core == "auto" else {}))


@pytest.mark.parametrize("core,scenario", [("iekf", "ship"), ("ekf10", "static")])
def test_session_fast_path_matches_per_sample_over_300_s(monkeypatch, core, scenario):
    """300 s, 1 s outputs, one core of each propagation family (ECI batches; static interval buffer; every core is
    compared at 60 s above): the session's fast path changes no number."""
    d = ia.simulate(scenario, seed=5, duration_s=300.0)
    ref = _run(monkeypatch, d, core, True, fast=False, output_period_s=1.0)
    fast = _run(monkeypatch, d, core, True, fast=True, output_period_s=1.0)
    _assert_same(ref, fast, bound_rad=1e-12)


def _perturbed(d, rng):
    """Every event the fast path must leave to the per-sample path: stamp jitter, a 0.3 s gap (invalid rows), two
    spikes (one inside the plausibility bounds, one beyond: rejected), a NaN row, a specific force beyond the
    bounds."""
    t = d.t_s + rng.uniform(-2e-4, 2e-4, d.n)
    t[0] = d.t_s[0]
    w, f = d.omega_ib_b.copy(), d.f_ib_b.copy()
    valid = np.ones(d.n, bool)
    valid[1500:1530] = False
    w[2100] += [8.0, 0.0, 0.0]
    w[2600] += [0.0, 0.0, 40.0]
    f[3100, 2] = np.nan
    f[3300] += [0.0, 60.0, 0.0]
    # truth without velocity: the session differentiates the truth positions (TruthTable rows built on demand)
    return replace(d, t_s=t, omega_ib_b=w, f_ib_b=f, imu_valid=valid, v_n=None)


@pytest.mark.parametrize("core,scenario", [("iekf", "ship"), ("ekf10", "static")])
def test_session_fast_path_hands_events_back(monkeypatch, core, scenario):
    d = _perturbed(ia.simulate(scenario, seed=7, duration_s=40.0), np.random.default_rng(1))
    ref = _run(monkeypatch, d, core, True, fast=False, fix_delay_s=0.35)
    fast = _run(monkeypatch, d, core, True, fast=True, fix_delay_s=0.35)
    _assert_same(ref, fast, bound_rad=1e-12)
    c = fast.counters
    assert c["imu_gaps"] >= 1 and c["imu_spikes"] >= 1 and c["imu_invalid"] >= 2, c


def _node_style(core, d, fast, swap):
    """One push per message (two messages swapped: reordered in the buffer), ``process`` every 10 messages as a
    node timer would, fixes as they arrive."""
    AlignmentSession.fast_path = fast
    s = AlignmentSession({"core": core, "init_mode": "truth", "init_rpy_error_deg": [2.0, -2.0, 30.0],
                          "output_period_s": 0.5})
    out, n = [], 0
    ev = list(events_in_arrival_order(d, 0.2))
    i = next(k for k, e in enumerate(ev) if e[0] == "imu" and e[1].stamp_s > d.t_s[0] + swap)
    j = next(k for k in range(i + 1, len(ev)) if ev[k][0] == "imu")
    ev[i], ev[j] = ev[j], ev[i]
    for kind, item in ev:
        if kind == "imu":
            s.push_imu(ImuSample(item.stamp_s, item.omega_ib_b, item.f_ib_b))
            n += 1
            if n % 10 == 0:
                out += s.process()
        elif kind == "fix":
            s.push_fix(GnssFix(item.stamp_s, item.p_e, item.R_e))
        else:
            s.push_truth(item)
    out += s.finish()
    counters = dict(s.counters)
    s.close()
    return out, counters


def test_session_fast_path_with_per_message_pushes(monkeypatch):
    """The node's pattern: a message per push, a timer's ``process``; an IMU message out of order."""
    monkeypatch.setattr(AlignmentSession, "fast_path", True)
    d = ia.simulate("ship", seed=2, duration_s=30.0)
    ref, c_ref = _node_style("liekf", d, False, 12.0)
    fast, c_fast = _node_style("liekf", d, True, 12.0)
    assert c_ref == c_fast and c_fast["imu_reordered"] == 1
    assert [o.stamp_s for o in ref] == [o.stamp_s for o in fast] and len(ref) > 50
    for a, b in zip(ref, fast):
        assert np.linalg.norm(earth.heading_error_enu_rad(a.estimate.C_b_n, b.estimate.C_b_n)) < 1e-12
        np.testing.assert_array_equal(a.estimate.P, b.estimate.P)


def test_eci_kernel_is_the_sequential_mechanization():
    """eci_steps = propagate_eci step by step (core/mechanization.py): attitude to rounding, position to 1e-8 m
    (the ECI position's ulp is 1e-9 m: the kernel sums increments relative to the batch start, the reference adds
    each step to 6.4e6 m)."""
    d = ia.simulate("ship", seed=1, duration_s=3.0)
    core = registry.make_core("liekf", {})
    core.initialize(0.0, float(d.lat_rad[0]), float(d.lon_rad[0]), 0.0, d.C_b_n[0], d.v_n[0], np.eye(3) * 1e-4,
                    0.1, 1.0)
    C, v, p = core.C.copy(), core.v.copy(), core.p.copy()
    n = d.n - 1
    dt = np.diff(d.t_s)
    out = [np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3, 3))]
    Ck, vk, pk = C.copy(), v.copy(), p.copy()
    nb.eci_steps(Ck, vk, pk, d.omega_ib_b[1:], d.f_ib_b[1:], dt, nb._ZONAL_N, nb._ZONAL_J, *out)
    for k in range(n):
        C, v, p = propagate_eci(C, v, p, d.omega_ib_b[k + 1], d.f_ib_b[k + 1], dt[k])
    assert np.abs(Ck - C).max() < 1e-13
    assert np.abs(vk - v).max() < 1e-10
    assert np.abs(pk - p).max() < 1e-8


def test_propagate_blocks_equal_one_row_at_a_time(data):
    """``propagate`` of the ECI cores cuts the same batches from blocks as from rows fed one at a time (arrays of
    length 1): identical numbers."""
    d = data["ship"]
    cores = []
    for mode in ("samples", "arrays"):
        c = registry.make_core("iekf", {"max_batch_samples": 64})
        c.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), 0.0, d.C_b_n[0], d.v_n[0],
                     np.eye(3) * 1e-3, 0.1, 1.0)
        if mode == "samples":
            for k in range(1, 700):
                c.propagate([float(d.t_s[k])], [d.omega_ib_b[k]], [d.f_ib_b[k]])
        else:
            c.propagate(d.t_s[1:30], d.omega_ib_b[1:30], d.f_ib_b[1:30])
            c.propagate(d.t_s[30:700], d.omega_ib_b[30:700], d.f_ib_b[30:700])
        c.flush()
        cores.append(c)
    a, b = cores
    np.testing.assert_array_equal(a.C, b.C)
    np.testing.assert_array_equal(a.P, b.P)
    assert a.counters == b.counters
    # a bad row goes through the per-sample path: rejected and counted, the rest propagated
    w = d.omega_ib_b[700:710].copy()
    w[3, 1] = np.nan
    b.propagate(d.t_s[700:710], w, d.f_ib_b[700:710])
    b.flush()
    assert b.counters["imu_rejected"] == 1 and b.counters["imu"] == a.counters["imu"] + 9
    assert np.all(np.isfinite(b.P)) and np.all(np.isfinite(b.C))


def test_static_propagate_blocks_equal_one_row_at_a_time(data):
    """The static cores' ``propagate`` buffers the same interval from blocks as from single rows: identical state after
    the next update."""
    d = data["static"]
    cores = []
    for mode in ("samples", "arrays"):
        c = registry.make_core("ekf10", {})
        c.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]), d.C_b_n[0],
                     np.zeros(3), np.diag(np.radians([1.0, 1.0, 5.0]) ** 2), 0.01, 1.0)
        for k0 in range(1, 1200, 12):
            if mode == "samples":
                for k in range(k0, k0 + 12):
                    c.propagate([float(d.t_s[k])], [d.omega_ib_b[k]], [d.f_ib_b[k]])
            else:
                c.propagate(d.t_s[k0:k0 + 12], d.omega_ib_b[k0:k0 + 12], d.f_ib_b[k0:k0 + 12])
            c.update(ZeroVelocity(float(d.t_s[k0 + 11]), 0.01))
        cores.append(c.estimate())
    a, b = cores
    np.testing.assert_array_equal(a.C_b_n, b.C_b_n)
    np.testing.assert_array_equal(a.P, b.P)


def test_session_fast_path_with_gnss_velocity(monkeypatch):
    """GNSS velocities (push_velocity) arrive like fixes and cut the fast runs the same way: same numbers."""
    from insalign_ros.sim.scenarios import make_scenario

    d = make_scenario("car", seed=3, duration_s=40.0, gnss_vel_sigma_m_s=0.1)
    ref = _run(monkeypatch, d, "iekf", True, fast=False, fix_delay_s=0.35)
    fast = _run(monkeypatch, d, "iekf", True, fast=True, fix_delay_s=0.35)
    _assert_same(ref, fast, bound_rad=1e-12)
    assert fast.counters["gnss_vel_received"] > 30


def test_compiled_update_helpers_match_numpy():
    """The compiled pieces of the updates and outputs against the numpy code they replace (same formulas, so equal
    to rounding); the 3x3 covariance test takes the same decisions as numpy's Cholesky."""
    from insalign_ros.core import lie
    from insalign_ros.core.mechanization_n import LocalLevelMechanization
    from insalign_ros.filters import checks, eci_batch, kalman, static_kernels as sk, static_model as sm

    rng = np.random.default_rng(7)
    cases = [np.eye(3), np.zeros((3, 3)), np.diag([1.0, 1.0, -1e-12]), np.diag([1e-30, 1.0, 1.0]),
             np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), np.array([[4.0, 9.0, 0], [-9.0, 4.0, 0],
                                                                                      [0, 0, 1.0]])]
    cases += [A @ A.T * s for A, s in zip(rng.normal(size=(20, 3, 3)), np.logspace(-8, 8, 20))]
    for R in cases:
        try:
            np.linalg.cholesky(0.5 * (R + R.T))
            ok = True
        except np.linalg.LinAlgError:
            ok = False
        assert kalman.spd3(R) == ok == oracles.spd3(R), R
    A = rng.normal(size=(15, 15))
    P = A @ A.T + np.eye(15)
    H = rng.normal(size=(3, 15))
    N = np.diag([1.0, 2.0, 3.0])
    for a, b in zip(oracles.joseph_update(P, H, N), kalman.joseph_update(P, H, N)):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()
    z = rng.normal(size=3)
    S = H @ P @ H.T + N
    assert abs(kalman.nis(S, z) - z @ np.linalg.solve(S, z)) <= 1e-12 * abs(z @ np.linalg.solve(S, z))
    C = lie.so3_exp(np.array([0.3, -1.2, 2.0]))
    v, p = np.array([1.0, -2.0, 3.0]), np.array([6.4e6, 1e5, -2e4])
    for xi in (rng.normal(size=9) * 0.3, rng.normal(size=9) * 1e-4, np.r_[1.5, 0.2, -0.1, rng.normal(size=6)]):
        X = lie.se23_from(C, v, p) @ lie.se23_exp(xi)
        Cn, vn, pn = eci_batch.retract_se23(C, v, p, xi)
        assert np.abs(Cn - X[:3, :3]).max() < 1e-15 and np.abs(vn - X[:3, 3]).max() < 1e-14
        assert np.abs(pn - X[:3, 4]).max() < 1e-8  # 6.4e6 m: its ulp is 1e-9 m
    for phi in ([1e-3, -2e-3, 0.4], [0.01, 0.02, 0.0], [0.0, 0.0, 3.0]):
        mech = LocalLevelMechanization(0.6, 0.2, 10.0, C, np.zeros(3))
        mech.correct_attitude(oracles.misalignment_rotation_enu(np.array(phi)))
        assert np.abs(sk._corrected_attitude_nb(*phi, C) - mech.C_b_n).max() < 1e-15
        assert np.abs(oracles.corrected_attitude(*phi, C) - mech.C_b_n).max() < 1e-15
    for p_e in rng.normal(scale=6e6, size=(10, 3)):
        np.testing.assert_array_equal(earth._omega_ie_cross(p_e), np.cross(earth.OMEGA_IE_E, p_e))
    # the PKF gain's first rows by the 2p x 2p push-through form against eq. (16)'s 5p x 5p solve
    from insalign_ros.filters import pkf
    for p_h, re, qm in ((10, 1.0, np.array([1e10, 1e10, 1e10, 1e12, 1e10])), (3, 3.0, np.arange(1.0, 6.0)),
                        (1, 1e-3, np.full(5, 1e2))):
        for s in (1e-4, 0.1):
            F5 = np.eye(5) + s * rng.normal(size=(5, 5))
            K_ref = pkf.pkf_gain(F5, sm.H_ZUPT, p_h, np.eye(2 * p_h) * re, np.diag(np.tile(qm, p_h)))[:5]
            K5 = np.empty((5, 5))
            sk._pkf_gain_rows_nb(F5, p_h, re, qm, K5)
            assert np.abs(K5 - K_ref).max() <= 1e-13 * np.abs(K_ref).max()
    buf = checks.ImuBuffer()  # rows (per-sample propagate) and blocks (propagate_arrays) in one buffer, in order
    buf.add(1.0, np.ones(3), 2 * np.ones(3))
    buf.add_block(np.array([2.0, 3.0]), np.arange(6.0).reshape(2, 3), np.arange(6.0, 12.0).reshape(2, 3))
    t, w, f = buf.take()
    np.testing.assert_array_equal(t, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(w, [[1, 1, 1], [0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(f[2], [9, 10, 11])
    assert buf.n == 0 and buf.take()[0].shape == (0,)


def test_session_buffers_and_float_helpers():
    """The session's array buffers against the list/deque models they replace, and the float helpers against numpy:
    ``_dist3`` = ``np.linalg.norm(a - b)`` to the last bit or two; ``_covariance_plainly_fine`` only where numpy's test finds
    nothing (finite, symmetric correlation, smallest eigenvalue >= -1e-9, level within the bound)."""
    from collections import deque

    from insalign_ros.session import buffers, guard, loop, outputs

    rng = np.random.default_rng(3)
    from insalign_ros.session import gaps

    for n in (1, 2, 7, 100, 101):  # the session's median (run bookkeeping, the rate model) is numpy's, bit for bit
        for _ in range(50):
            x = (rng.normal(size=n) * 10.0 ** rng.uniform(-6, 3)).tolist()
            assert gaps.median(x) == float(np.median(x))
    X = rng.normal(size=(4000, 2, 3)) * rng.lognormal(0.0, 3.0, size=(4000, 2, 1))
    # to the last bit or two: numpy's norm is a BLAS dot, whose summation (FMA, SIMD width) depends on the CPU
    assert all(math.isclose(loop.dist3(a.tolist(), b.tolist()), float(np.linalg.norm(a - b)), rel_tol=5e-16)
               for a, b in X)
    fine = 0
    for k in range(3000):
        A = rng.normal(size=(3, 3)) * rng.lognormal(0.0, 2.0, size=3)
        P = A @ A.T + (rng.normal(size=(3, 3)) * 10 ** rng.uniform(-9, -3) * np.abs(A).max() ** 2 if k % 3 else 0)
        if k % 7 == 0:
            P = np.outer(A[0], A[0]) + 10 ** rng.uniform(-12, -5) * np.eye(3) * (A[0] @ A[0])
        lvl = 10 ** rng.uniform(0.0, 4.0)
        if guard.covariance_plainly_fine(P, lvl):
            fine += 1
            C = P / np.sqrt(np.outer(np.diag(P), np.diag(P)))
            assert np.abs(C - C.T).max() <= 1e-6 and np.linalg.eigvalsh(0.5 * (C + C.T))[0] >= -1e-9
            assert 3.0 * np.degrees(np.sqrt(max(P[0, 0], P[1, 1]))) <= lvl
        assert outputs.all_finite(P) and not outputs.all_finite(np.where(np.arange(9).reshape(3, 3) == k % 9, np.nan, P))
    assert 300 < fine < 2900  # both answers occur
    # _ImuBuffer: blocks, single pushes, an out-of-order insert, takes across blocks = one sorted list
    buf, ref = buffers.ImuBuffer(), []
    t = 0.0
    for k in range(40):
        m = int(rng.integers(1, 30))
        T = t + np.cumsum(rng.uniform(0.001, 0.02, m))
        W, F = rng.normal(size=(m, 3)), rng.normal(size=(m, 3))
        if k % 3:
            buf.extend(T, W, F)
        else:
            for r in range(m):
                buf.append(float(T[r]), W[r], F[r])
        ref += [(float(T[r]), W[r], F[r]) for r in range(m)]
        t = float(T[-1])
        if k % 5 == 4 and len(ref) > 3:  # a sample between two buffered ones
            tx = 0.5 * (ref[-3][0] + ref[-2][0])
            buf.insert(tx, np.full(3, float(k)), np.full(3, -float(k)))
            ref.insert(len(ref) - 2, (tx, np.full(3, float(k)), np.full(3, -float(k))))
        if k % 4 == 3:
            until = ref[len(ref) // 2][0]
            n = buf.count_until(until)
            assert n == sum(r[0] <= until for r in ref) and buf.t_at(n - 1) == ref[n - 1][0]
            assert [x[0] for x in buf.iter_until(ref[n + 1][0])] == [r[0] for r in ref[:n + 2]]
            Tt, Wt, Ft = buf.take(n)
            np.testing.assert_array_equal(Tt, [r[0] for r in ref[:n]])
            np.testing.assert_array_equal(Wt, np.array([r[1] for r in ref[:n]]).reshape(-1, 3))
            np.testing.assert_array_equal(Ft, np.array([r[2] for r in ref[:n]]).reshape(-1, 3))
            del ref[:n]
        assert len(buf) == len(ref) and (buf.first() is None if not ref else buf.first()[0] == ref[0][0])
    # Ring = deque(maxlen) of rows; _RecentStamps = the deque + set of the last maxlen stamps
    ring, dq = buffers.Ring(50, 3), deque(maxlen=50)
    rec, rdq = buffers.RecentStamps(64), deque(maxlen=64)
    s0 = 0.0
    for k in range(300):
        m = int(rng.integers(1, 80)) if k % 2 else 1
        R = rng.normal(size=(m, 3))
        ring.extend(R) if k % 2 else ring.append(R[0])
        dq.extend(list(R))
        np.testing.assert_array_equal(np.asarray(ring), np.array(dq))
        np.testing.assert_array_equal(ring[-1], dq[-1])
        if k % 7 == 0:
            snap, snap_ref = ring.view(), np.array(dq)  # a view stays valid while the ring goes on
        np.testing.assert_array_equal(snap, snap_ref)
        T = s0 + np.arange(1, m + 1) * 0.01
        s0 = float(T[-1])
        rec.add_block(T) if k % 2 else rec.add(float(T[0]))
        rdq.extend(T.tolist())
        probe = float(T[0]) - 0.01 * int(rng.integers(0, 150))
        assert (probe in rec) == (probe in rdq)
        assert rec.set == set(rec.rs) == set(rdq)


def test_usable_imu_arrays_compiled_decides_as_numpy():
    """The cores' array fast-path test (filters/checks.usable_imu_arrays): the compiled pass accepts and rejects the
    same blocks as the numpy oracle, with the same intervals."""
    from insalign_ros.filters.checks import usable_imu_arrays

    rng = np.random.default_rng(5)
    t = 10.0 + 0.008 * np.arange(12)
    w, f = rng.normal(0.0, 0.1, (12, 3)), rng.normal(0.0, 9.8, (12, 3))
    cases = [(t, w, f, 9.99), (t, w, f, 10.0), (t, w, f, 8.5)]  # clean; first interval 0; first interval > 1 s
    for what, k, j, v in (("w", 4, 1, np.nan), ("f", 7, 2, np.inf), ("t", 3, None, 10.0), ("t", 11, None, 12.0)):
        tt, ww, ff = t.copy(), w.copy(), f.copy()
        {"w": ww, "f": ff}.get(what, tt)[(k, j) if j is not None else k] = v
        cases.append((tt, ww, ff, 9.99))
    for tt, ww, ff, t_last in cases:
        a = usable_imu_arrays(tt, ww, ff, t_last)
        b = oracles.usable_imu_arrays(tt, ww, ff, t_last)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a[3], b[3])
    assert usable_imu_arrays(t, w, f, 9.99) is not None and usable_imu_arrays(*cases[4][:3], 9.99) is None


@pytest.mark.parametrize("core,params", [("ekf10", {"azimuth_bootstrap_s": 0.0}),
                                         ("pkf", {"azimuth_bootstrap_s": 0.0, "azimuth_feedback_sigma_deg": 5.0})])
def test_fused_zero_velocity_step_matches_reference(monkeypatch, data, core, params):
    """The static cores' whole compiled zero-velocity step (``_zupt_step_nb``: prediction, OC nullspace, update, PKF
    model-error step, feedback) against the generic step (each equation on its own, the path of a core that does not
    declare ``_fused_zupt``) on the numpy oracles, driven directly with a 5 deg azimuth sigma so that both
    feedback branches run (through ``ia.align`` the 10-state EKF never feeds the azimuth back: its sigma stays large):
    attitude < 1e-9 rad, covariance 1e-9 relative, after every update."""
    d = data["static"]
    runs = []
    for compiled in (False, True):
        if not compiled:
            oracles.use_reference_paths(monkeypatch)
        else:
            monkeypatch.undo()
        c = registry.make_core(core, params)
        c.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]),
                     earth.C_b_n_from_rpy(0.01, -0.01, 0.05) @ d.C_b_n[0], np.zeros(3),
                     np.diag(np.radians([1.0, 1.0, 5.0]) ** 2), 0.1, 1.0)
        seen, branches = [], set()
        for k0 in range(1, 1200, 12):
            c.propagate(d.t_s[k0:k0 + 12], d.omega_ib_b[k0:k0 + 12], d.f_ib_b[k0:k0 + 12])
            sig = np.sqrt(c.P[4, 4])
            assert c.update(ZeroVelocity(float(d.t_s[k0 + 11]), 0.01)).accepted
            branches.add(bool(sig < c.cfg.azimuth_feedback_sigma_deg * np.pi / 180.0))
            e = c.estimate()
            seen.append((e.C_b_n, e.P))
        runs.append((seen, branches))
    (ref, b_ref), (fast, _) = runs
    assert b_ref == ({True} if core == "ekf10" else {False, True}), b_ref  # the azimuth fed back (both branches)
    for (C0, P0), (C1, P1) in zip(ref, fast):
        assert np.linalg.norm(earth.heading_error_enu_rad(C0, C1)) < 1e-9
        assert np.abs(P0 - P1).max() <= 1e-9 * np.abs(P0).max()


def test_compiled_gnss_checks_and_terms_match_numpy(monkeypatch):
    """The fix checks in floats take numpy's decisions (same reasons), and the compiled (z, H, N) of a fix equals the
    numpy one to rounding (the invariant cores' GnssPosition terms, lever arm included)."""
    from insalign_ros.filters import checks

    rng = np.random.default_rng(11)
    p = np.array([4.0e6, 1.0e6, 4.8e6])
    bad_R = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    fixes = [(p, np.eye(3)), (np.array([np.nan, 0.0, 6.5e6]), np.eye(3)), (p, np.diag([1.0, np.inf, 1.0])), (p * 1.5, np.eye(3)),
             (p * 0.9, np.eye(3)), (p, bad_R), (p[:2], np.eye(3)), (p, -np.eye(3))]
    fixes += [(p * 7.0e6 / np.linalg.norm(p) * (1 + s), np.eye(3)) for s in (-1e-15, 0.0, 1e-15)]
    for pe, R in fixes:
        fix = GnssFix(1.0, pe, R)
        assert checks.check_fix(fix) == oracles.check_fix(fix)
    d = ia.simulate("ship", seed=2, duration_s=5.0)
    for name, lever in (("liekf", (0.0, 0.0, 0.0)), ("iekf", (1.5, -0.4, 2.0))):
        terms = []
        for compiled in (False, True):
            c = registry.make_core(name, {"gnss_lever_arm_b_m": list(lever)})
            c.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]), d.C_b_n[0],
                         d.v_n[0], np.eye(3) * 1e-2, 0.1, 1.0)
            c.propagate(d.t_s[1:200], d.omega_ib_b[1:200], d.f_ib_b[1:200])
            A = rng.normal(size=(3, 3)) if not terms else A
            fix = GnssFix(float(d.t_s[199]), d.gnss_p_e[1] + 3.0, A @ A.T + np.eye(3))
            terms.append(c._terms(GnssPosition.of(fix)) if compiled else oracles.gnss_terms(c, fix))
        for a, b in zip(*terms):
            assert a.shape == b.shape and np.abs(a - b).max() <= 1e-12 * max(np.abs(a).max(), 1.0)
