"""Monte-Carlo sweeps as Dask tasks (issue 16, item 2): a 4-run yaw sweep on a 2-worker LocalCluster gives exactly
the numbers of the serial run (every run is seeded; the tasks call ``ia.align``, the session path users take), each
seed's scenario is simulated once per sweep (a Shared input) and every run is timed."""

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="dask.distributed is not installed (requirements.txt pins it)")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import sweep  # noqa: E402
import yaw_sweep  # noqa: E402

from insalign_ros.eval.parallel import efficiency, run_tasks  # noqa: E402


@pytest.mark.timeout(120)
def test_four_run_yaw_sweep_on_two_workers_equals_serial():
    tasks = [(sweep.shared_scenario("ship", seed, 20.0), core, 60.0, False, False)
             for seed in (0, 1) for core in ("liekf", "iekf")]
    serial = sweep.run_tasks(yaw_sweep.sweep_task, tasks, argparse.Namespace(serial=True), desc="serial")
    st: dict = {}
    # the workers forked from a server that imported the runs' packages, as the benchmarks start them
    dask = run_tasks(yaw_sweep.sweep_task, tasks, workers=2, desc="dask", upload=(sweep.__file__,),
                     cost=[yaw_sweep.task_cost(t[1]) for t in tasks], stats=st, preload=sweep.PRELOAD)
    assert len(serial) == len(dask) == 4
    for (s1, (t1, e1), (_, n1), _), (s2, (t2, e2), (_, n2), _) in zip(serial, dask):
        np.testing.assert_array_equal(t1, t2)
        np.testing.assert_array_equal(e1, e2)
        np.testing.assert_array_equal(n1, n2)
        for k in s1:
            if k == "wall_s":
                continue
            a, b = np.asarray(s1[k]), np.asarray(s2[k])
            if a.dtype.kind == "f":
                assert np.array_equal(a, b, equal_nan=True), k
            else:
                assert s1[k] == s2[k], k
    assert sweep.first_difference(serial, dask) == ""
    # two seeds: two simulations on the cluster, whichever worker runs which task; every run timed there
    e = efficiency(st)
    assert (e["tasks"], e["shared"]) == (4, 2)
    assert 0.0 < e["task_cpu_s"] and 0.0 < e["busy_share"] <= 1.0 + 1e-9
    # the runs are real alignments: the ship converges from 60 deg of yaw error within 20 s
    assert all(abs(s["final_err_rpy_deg"][2]) < 5.0 for s, *_ in serial)


def test_first_difference_finds_a_changed_number_and_skips_wall_times():
    a = [({"rmse": np.array([1.0, np.nan]), "wall_s": 1.0}, (np.arange(3.0),))]
    b = [({"rmse": np.array([1.0, np.nan]), "wall_s": 2.0}, (np.arange(3.0),))]
    assert sweep.first_difference(a, b) == ""
    b[0][0]["rmse"][0] = np.nextafter(1.0, 2.0)
    assert sweep.first_difference(a, b) == "[0][0].rmse"
    assert sweep._at(b, "[0][0].rmse")[0] == np.nextafter(1.0, 2.0)


def _worker_env(name):
    import os

    return os.environ.get(name)  # the worker's environment (os.environ.get itself would pickle this process's)


@pytest.mark.timeout(60)
def test_local_cluster_workers_run_one_solver_thread(monkeypatch):
    """A LocalCluster worker gets WORKER_ENVIRON (clarabel's rayon pool on one thread: one worker per CPU is the
    parallelism), spawned or forked from the preloaded server; a value the user set in the environment wins."""
    from insalign_ros.eval.parallel import WORKER_ENVIRON, make_client

    assert WORKER_ENVIRON["RAYON_NUM_THREADS"] == "1"
    for preset, expected, preload in ((None, "1", ()), ("3", "3", ()), (None, "1", sweep.PRELOAD)):
        if preset is None:
            monkeypatch.delenv("RAYON_NUM_THREADS", raising=False)
        else:
            monkeypatch.setenv("RAYON_NUM_THREADS", preset)
        client, cluster = make_client(1, preload=preload)
        try:
            got = list(client.run(_worker_env, "RAYON_NUM_THREADS").values())
        finally:
            client.close()
            cluster.close()
        assert got == [expected]


def test_stage_timer_splits_a_default_run():
    """``--stage-timing`` (sweep.StageTimer): the session's entry points are wrapped where they are now, each stage of
    a default ``ia.align`` gets time, the stages add up to the total, and everything is unwrapped afterwards."""
    import time

    import insalign_ros as ia
    from insalign_ros.session.outputs import Outputs

    d = ia.simulate("ship", duration_s=10.0, seed=0)
    before = Outputs.output
    with sweep.StageTimer() as st:
        t0 = time.perf_counter()
        ia.align(d, core="iekf")
        st.total_s = time.perf_counter() - t0
    s = st.stages()
    assert all(s[k] > 0.0 for k in ("input", "propagate", "update", "outputs")), s
    assert abs(sum(v for k, v in s.items() if k != "total") - s["total"]) < 1e-9 * s["total"] + 1e-12
    assert Outputs.output is before
