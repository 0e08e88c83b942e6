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


def _run_cores(core_name, max_batch, split, n_hyp=0):
    """Two identical cores over one simulated ship record: one through ``propagate(..., estimates_at)`` (the
    compiled snapshots), one through the base class's segment-by-segment default; GNSS fixes in between."""
    from insalign_ros.filters.base import AlignmentCore
    from insalign_ros.filters.measurements import GnssPosition
    from insalign_ros.filters.registry import make_core

    d = ia.simulate("ship", duration_s=12.0, seed=3)
    params = {"max_batch_samples": max_batch, **({"yaw_hypotheses": n_hyp} if n_hyp else {})}
    cores = [make_core(core_name, params) for _ in range(2)]
    for c in cores:
        c.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]),
                     earth.C_b_n_from_rpy(0.02, -0.01, 0.5) @ d.C_b_n[0], np.zeros(3) + d.v_n[0],
                     np.diag(np.radians([2.0, 2.0, 30.0])) ** 2, 0.1, 2.0)
    ests = ([], [])
    k0 = 1
    for g, tg in enumerate(d.gnss_t_s):
        k1 = int(np.searchsorted(d.t_s, tg, side="right"))
        if k1 <= k0:
            continue
        km = (k0 + k1) // 2 + g % 5  # two calls per fix interval: the second starts with samples still buffered
        for sl in (slice(k0, km), slice(km, k1)):
            n = sl.stop - sl.start
            ends = list(range(split - 1 - g % 3, n - 1, split))
            ests[0].extend(cores[0].propagate(d.t_s[sl], d.omega_ib_b[sl], d.f_ib_b[sl], estimates_at=ends))
            ests[1].extend(AlignmentCore._estimates_along(cores[1], d.t_s[sl], d.omega_ib_b[sl], d.f_ib_b[sl], ends))
        for c in cores:
            c.update(GnssPosition(float(tg), d.gnss_p_e[g], d.gnss_R_e[g]))
        k0 = k1
    return ests, cores


def _assert_same_estimates(a, b):
    assert len(a) == len(b) > 50
    for x, y in zip(a, b):
        assert x.stamp_s == y.stamp_s and x.lat_rad == y.lat_rad and x.h_m == y.h_m and x.reason == y.reason
        for f in ("C_b_n", "v_n", "P_att_n", "P", "bias_gyro_b"):
            np.testing.assert_array_equal(getattr(x, f), getattr(y, f))


def test_compiled_snapshots_are_the_segment_by_segment_estimates():
    """``propagate(..., estimates_at)`` of the ECI cores (one compiled call: mechanization_numba.eci_invariant_snapshots)
    gives bit for bit the estimates of propagating each segment and calling ``estimate()`` after it, across batches
    that end inside a segment (max_batch_samples 7 and 100) and samples left buffered between calls; so does a bank
    of yaw hypotheses over them."""
    for core, mb, split, n_hyp in (("iekf", 7, 10, 0), ("liekf", 100, 10, 0), ("iekf", 100, 3, 0),
                                   ("liekf", 7, 13, 4)):
        (a, b), cores = _run_cores(core, mb, split, n_hyp)
        _assert_same_estimates(a, b)
        np.testing.assert_array_equal(cores[0].estimate().P, cores[1].estimate().P)


def test_align_with_bulk_estimates_is_one_output_at_a_time(monkeypatch):
    """``ia.align`` defaults on a car with ``vehicle: car`` (GNSS headings off the fix stamps, the non-holonomic
    constraint scheduled once the hand-over makes the in-motion core accept it), at 0.1-s and 0.03-s outputs (then
    the hand-over falls inside a run with outputs after it): every output, with the estimates of each run taken at
    once (ECI snapshots, the yaw bank's mixes, auto's cruise blocks; auto one at a time while parked), is the output
    of interleaving one output at a time (propagate to the output's sample, its events, then on: each core returns
    only its first estimate, which the contract allows)."""
    from dataclasses import replace

    from insalign_ros.filters.base import AlignmentCore
    from insalign_ros.filters.hypotheses import YawHypothesisBank
    from insalign_ros.filters.liekf import BatchedEciCore
    from insalign_ros.session.auto import AutoCore

    def first_only(orig):
        def along(self, t_s, omega_ib_b, f_ib_b, ends):
            if not len(ends):
                return orig(self, t_s, omega_ib_b, f_ib_b, ends)
            k = ends[0] + 1
            orig(self, t_s[:k], omega_ib_b[:k], f_ib_b[:k], ())
            return [self.estimate()]
        return along

    d = ia.simulate("car", duration_s=60.0, seed=2, gnss_heading_sigma_deg=0.5)
    d = replace(d, heading_t_s=d.heading_t_s + 0.37)
    runs = []
    for bulk in (True, False):
        with monkeypatch.context() as m:
            if not bulk:
                for cls in (AlignmentCore, BatchedEciCore, YawHypothesisBank, AutoCore):
                    m.setattr(cls, "_estimates_along", first_only(cls.__dict__["_estimates_along"]))
            runs.append([ia.align(d, core=c, vehicle="car", output_period_s=p) for c in ("auto", "iekf")
                         for p in (0.1, 0.03)])
    for a, b in zip(*runs):
        assert a.counters == b.counters and a.counters["nhc_accepted"] > 100 and a.counters["gnss_heading_fused"] > 30
        assert len(a.outputs) == len(b.outputs) > 300
        for x, y in zip(a.outputs, b.outputs):
            assert (x.stamp_s, x.aligned, x.reason) == (y.stamp_s, y.aligned, y.reason)
            np.testing.assert_array_equal(x.estimate.P, y.estimate.P)
            np.testing.assert_array_equal(x.estimate.C_b_n, y.estimate.C_b_n)


def test_zero_velocity_updates_inside_runs_are_the_run_ends(monkeypatch):
    """The static cores take the session's 10-Hz zero-velocity updates with the run's samples (``propagate(...,
    updates)``, ``updates_inside_runs``) instead of the run ending at each: every output, counter and flag change is
    the one of ending the run at each update, also at outputs off the updates' samples (0.07 s) and on a 100-Hz IMU
    whose every 10th stamp is where the schedule falls (its rounding decides the row). When the core fails
    in the middle of a run, the outputs and updates before the failure are the same and the session restarts; the
    rest of that run (up to the next fix) is dropped, as after a failure at an output."""
    from insalign_ros.filters.static_model import StaticZuptCore

    d = ia.simulate("static", duration_s=40.0, seed=4)
    calls = {"n": 0}
    fuse = StaticZuptCore._fuse

    def failing(self, meas):  # the 150th zero-velocity update of the run fails (a core fault)
        calls["n"] += 1
        if calls["n"] == 150:
            raise FloatingPointError("injected")
        return fuse(self, meas)

    d100 = ia.simulate("static", duration_s=40.0, seed=4, rate_hz=100.0)  # the 10-Hz schedule on every 10th stamp
    runs, failed = [], []
    for inside in (True, False):
        with monkeypatch.context() as m:
            m.setattr(StaticZuptCore, "updates_inside_runs", inside)
            runs.append([ia.align(d, core=c, output_period_s=p) for c in ("pkf", "ekf10") for p in (0.1, 0.07)]
                        + [ia.align(d100, core="pkf")])
            calls["n"] = 0
            m.setattr(StaticZuptCore, "_fuse", failing)
            failed.append(ia.align(d, core="pkf"))
    for a, b in zip(*runs):
        assert a.counters == b.counters and a.counters["zupt_accepted"] > 150
        assert a.metrics["events"] == b.metrics["events"]
        _same_outputs(a.outputs, b.outputs)
    a, b = failed
    assert a.counters["core_faults"] == b.counters["core_faults"] == 1
    t_fault = next(e["t_s"] for e in b.metrics["events"] if e["event"] == "restart")
    assert [e for e in a.metrics["events"] if e["t_s"] < t_fault] == [e for e in b.metrics["events"]
                                                                       if e["t_s"] < t_fault]
    t_fault_a = next(e["t_s"] for e in a.metrics["events"] if e["event"] == "restart")
    assert t_fault <= t_fault_a <= t_fault + 1.0  # the end of the run it failed in: the next 1-Hz fix
    _same_outputs([o for o in a.outputs if o.stamp_s <= t_fault], [o for o in b.outputs if o.stamp_s <= t_fault])
    assert a.metrics["final_aligned"] == b.metrics["final_aligned"]  # both re-initialise and go on to the end


def _same_outputs(xs, ys):
    assert len(xs) == len(ys) > 100
    for x, y in zip(xs, ys):
        assert (x.stamp_s, x.aligned, x.reason) == (y.stamp_s, y.aligned, y.reason)
        np.testing.assert_array_equal(x.estimate.P, y.estimate.P)
        np.testing.assert_array_equal(x.estimate.C_b_n, y.estimate.C_b_n)


def test_deferred_truth_is_the_truth_at_each_output(monkeypatch):
    """Offline with a valid truth table the outputs' truth is looked up in the table at the end (``defer_truth``):
    each output's truth is the table's row at its stamp, and its Euler error the one of looking the truth up at
    each output as it is made (the per-sample path, which defers nothing)."""
    from insalign_ros.session.session import AlignmentSession

    d = ia.simulate("car", duration_s=30.0, seed=1)
    runs = []
    for fast in (True, False):
        monkeypatch.setattr(AlignmentSession, "fast_path", fast)
        runs.append(ia.align(d, core="iekf"))
    a, b = runs
    assert len(a.outputs) == len(b.outputs) > 200
    for x, y in zip(a.outputs, b.outputs):
        k = int(np.searchsorted(d.t_s, x.stamp_s))
        assert d.t_s[k] == x.stamp_s
        np.testing.assert_array_equal(x.truth_C_b_n, d.C_b_n[k])
        np.testing.assert_array_equal(x.truth_C_b_n, y.truth_C_b_n)
        _same(x.euler_error_deg, y.euler_error_deg)
