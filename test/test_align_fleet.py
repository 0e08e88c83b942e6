"""insalign-align over a directory of bags (issue 16, item 2): every bag as a Dask task on a 2-worker LocalCluster,
the same numbers as one after the other, one summary table; a broken bag is a row with its error."""

import csv

from insalign_ros.cli.align import main
from insalign_ros.io.bag import write_bag
from insalign_ros.sim.scenarios import make_scenario


def _rows(path):
    return {r["bag"].rsplit("/", 1)[-1]: r for r in csv.DictReader(open(path))}


def test_fleet_on_two_workers_equals_serial_and_reports_a_broken_bag(tmp_path):
    fleet = tmp_path / "fleet"
    write_bag(make_scenario("car", seed=1, duration_s=25.0), fleet / "car_1")
    write_bag(make_scenario("ship", seed=2, duration_s=25.0), fleet / "day2" / "ship_2")
    (fleet / "broken").mkdir()
    (fleet / "broken" / "metadata.yaml").write_text("not: a bag\n")
    opts = ["--core", "iekf", "--rpy-error", "3", "-3", "20", "--no-plot", "--no-progress"]
    assert main([str(fleet), *opts, "--serial", "--out-dir", str(tmp_path / "serial")]) == 1  # one bag failed
    assert main([str(fleet), *opts, "--workers", "2", "--out-dir", str(tmp_path / "dask")]) == 1
    # bags sent to the workers as bytes (a remote cluster without a shared file system), outputs sent back
    assert main([str(fleet), *opts, "--workers", "2", "--ship-bags", "--out-dir", str(tmp_path / "ship")]) == 1
    serial, dask = _rows(tmp_path / "serial" / "fleet_summary.csv"), _rows(tmp_path / "dask" / "fleet_summary.csv")
    ship = _rows(tmp_path / "ship" / "fleet_summary.csv")
    assert sorted(ship) == sorted(serial)
    for name in ("car_1", "ship_2"):
        assert ship[name]["final_err_rpy_deg"] == serial[name]["final_err_rpy_deg"]
        assert ship[name]["bag"] == serial[name]["bag"]  # the client's path, not the worker's temporary copy
    assert ship["broken"]["rc"] == "2" and str(fleet / "broken") in ship["broken"]["error"]
    assert (tmp_path / "ship" / "car_1" / "car_1_iekf_metrics.json").read_text() \
        == (tmp_path / "dask" / "car_1" / "car_1_iekf_metrics.json").read_text()
    assert sorted(serial) == ["broken", "car_1", "ship_2"]
    for name in ("car_1", "ship_2"):
        assert serial[name]["rc"] == "0" and serial[name]["final_err_rpy_deg"] == dask[name]["final_err_rpy_deg"]
        final = [float(x) for x in serial[name]["final_err_rpy_deg"].strip("[]").split(",")]
        assert abs(final[2]) < 3.0, final  # from 20 deg in 25 s (the single-bag path's accuracy)
        assert int(serial[name]["gnss_accepted"]) >= 20
    assert serial["broken"]["rc"] == "2" and "not a readable bag" in serial["broken"]["error"]
    assert (tmp_path / "dask" / "car_1" / "car_1_iekf_metrics.json").exists()
    assert (tmp_path / "serial" / "day2__ship_2" / "ship_2_iekf.csv").exists()


def test_kernels_are_compiled_once_per_machine(tmp_path, monkeypatch):
    """warm_up_once holds a machine-wide file lock: a second process (here a thread with its own open file) waits
    until the first has filled the cache, then loads it."""
    import fcntl
    import threading
    import time

    from insalign_ros.session import warmup

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    path = warmup.lock_path()
    assert path.startswith(str(tmp_path))
    (tmp_path / "insalign_ros").mkdir()
    got = {}
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # a first worker compiling
        t = threading.Thread(target=lambda: got.setdefault("r", warmup.warm_up_once((), duration_s=1.0)))
        t.start()
        held_from = time.perf_counter()
        t.join(timeout=1.0)
        assert t.is_alive(), "the second warm-up did not wait for the lock"
        held = time.perf_counter() - held_from
        fcntl.flock(fh, fcntl.LOCK_UN)
    t.join(timeout=120)
    assert not t.is_alive()
    waited, _ = got["r"]
    assert waited >= held * 0.9, (waited, held)


def test_a_completed_warm_up_lets_the_next_processes_load_side_by_side(tmp_path, monkeypatch):
    """The first warm-up of a fingerprint runs under the machine's lock (it may compile); once it has completed, the
    next ones only check the fingerprint under the lock and load the cache outside it (two fleet workers load at
    once instead of one after the other). Another set of cores is another fingerprint: under the lock again."""
    import fcntl

    from insalign_ros.session import warmup

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    (tmp_path / "insalign_ros").mkdir()
    under_lock = []

    def fake_warm_up(cores, duration_s=30.0):
        with open(warmup.lock_path(), "a") as fh:  # another open file: blocked while anyone holds the lock
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(fh, fcntl.LOCK_UN)
                under_lock.append(False)
            except BlockingIOError:
                under_lock.append(True)
        return 0.0

    monkeypatch.setattr(warmup, "warm_up", fake_warm_up)
    for cores in (("iekf",), ("iekf",), ("iekf",), ("pkf",), ("iekf",)):
        warmup.warm_up_once(cores, duration_s=1.0)
    assert under_lock == [True, False, False, True, False]
    assert warmup._fingerprint(("iekf",)) != warmup._fingerprint(("pkf",))
    assert len((tmp_path / "insalign_ros" / "warmup.done").read_text().split()) == 2
