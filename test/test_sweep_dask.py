"""Monte-Carlo sweeps as Dask tasks (issue 16, item 2): a 4-run yaw sweep on a 2-worker LocalCluster gives exactly
the numbers of the serial run (every run is seeded; the tasks call ``ia.align``, the session path users take)."""

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="dask.distributed is not installed (requirements.txt pins it)")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import sweep  # noqa: E402
import yaw_sweep  # noqa: E402


@pytest.mark.timeout(120)
def test_four_run_yaw_sweep_on_two_workers_equals_serial():
    tasks = [("ship", seed, 20.0, core, 60.0, False, False) for seed in (0, 1) for core in ("liekf", "iekf")]
    serial = sweep.run_tasks(yaw_sweep.sweep_task, tasks, argparse.Namespace(serial=True), desc="serial")
    dask = sweep.run_tasks(yaw_sweep.sweep_task, tasks,
                           argparse.Namespace(serial=False, scheduler="", workers=2), desc="dask")
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
    # the runs are real alignments: the ship converges from 60 deg of yaw error within 20 s
    assert all(abs(s["final_err_rpy_deg"][2]) < 5.0 for s, *_ in serial)
