"""Host-stamp jitter is not a gap (session/gaps.py gap_threshold, session/loop.py; issue 24): 5 ms of stamp jitter at
100 and 400 Hz (a driver that stamps on arrival, samples delivered in order: sorted stamps) counts no gap and costs
no more CPU than the clean stream; a real 0.3-s dropout in the same stream is found and bridged."""

import time
from dataclasses import replace

import numpy as np
import pytest

import insalign_ros as ia
from insalign_ros.session import gaps
from insalign_ros.sim.scenarios import make_scenario

KW = dict(core="iekf", init_mode="truth", init_rpy_error_deg=[1, -1, 5])


def _jitter(d, sigma_s, seed=0):
    return replace(d, t_s=np.sort(d.t_s + np.random.default_rng(seed).normal(0.0, sigma_s, d.n)))


def _drop(d, a, b):
    keep = ~((d.t_s > a) & (d.t_s < b))
    return replace(d, **{k: getattr(d, k)[keep] for k in ("t_s", "omega_ib_b", "f_ib_b", "C_b_n", "lat_rad",
                                                          "lon_rad", "h_m", "v_n")})


@pytest.mark.parametrize("rate_hz", [100.0, 400.0])
def test_gap_threshold_of_jittered_stamps(rate_hz):
    """The rate model as the session runs it (every 20 intervals over the last 101): 5-ms stamp jitter (sorted: the
    driver delivers in order) gives thresholds T + 12 sigma_s over every interval of 40,000 (the largest 34 ms at
    100 Hz, 17 ms at 400 Hz, where sorting hides part of the jitter), far under a 0.3-s dropout; clean stamps keep
    gap_factor x the median."""
    rng = np.random.default_rng(1)
    t = np.arange(40000) / rate_hz
    d = np.diff(np.sort(t + rng.normal(0.0, 0.005, t.size)))
    thr, ths, n = None, [], 0
    for k in range(101, len(d)):
        if k % 20 == 0:
            thr = gaps.gap_threshold(d[k - 101:k], 1.5, float(np.median(d[k - 101:k])), thr)
            ths.append(thr)
        n += int(thr is not None and d[k] > thr)
    assert n == 0 and d.max() < 0.75 * min(ths) and max(ths) < 0.15, (n, d.max(), min(ths), max(ths))
    assert gaps.gap_threshold(np.diff(t)[:101], 1.5, 1.0 / rate_hz) == pytest.approx(1.5 / rate_hz)


@pytest.mark.parametrize("rate_hz", [100.0, 400.0])
def test_jitter_is_not_a_gap_and_a_real_gap_is(rate_hz):
    d = make_scenario("car", seed=1, duration_s=60.0, rate_hz=rate_hz)
    cpu = {}
    res = {}
    for name, dd in (("clean", d), ("jitter", _jitter(d, 0.005)), ("gap", _drop(_jitter(d, 0.005), 30.0, 30.3))):
        t0 = time.process_time()
        res[name] = ia.align(dd, **KW)
        cpu[name] = time.process_time() - t0
    print(rate_hz, {k: (r.counters["imu_gaps"], round(cpu[k], 2), round(float(r.rpy_err_deg[-1, 2]), 3),
                         round(float(r.sigma3_deg[-1, 2]), 3)) for k, r in res.items()})
    assert res["clean"].counters["imu_gaps"] == 0 and res["jitter"].counters["imu_gaps"] == 0
    assert res["gap"].counters["imu_gaps"] == 1
    for r in res.values():
        assert np.all(np.abs(r.rpy_err_deg[-1]) < r.sigma3_deg[-1])
    assert cpu["jitter"] < 1.5 * cpu["clean"] + 0.5  # a loose bound on a shared machine (measured: see the report)
