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
    serial, dask = _rows(tmp_path / "serial" / "fleet_summary.csv"), _rows(tmp_path / "dask" / "fleet_summary.csv")
    assert sorted(serial) == ["broken", "car_1", "ship_2"]
    for name in ("car_1", "ship_2"):
        assert serial[name]["rc"] == "0" and serial[name]["final_err_rpy_deg"] == dask[name]["final_err_rpy_deg"]
        final = [float(x) for x in serial[name]["final_err_rpy_deg"].strip("[]").split(",")]
        assert abs(final[2]) < 3.0, final  # from 20 deg in 25 s (the single-bag path's accuracy)
        assert int(serial[name]["gnss_accepted"]) >= 20
    assert serial["broken"]["rc"] == "2" and "not a readable bag" in serial["broken"]["error"]
    assert (tmp_path / "dask" / "car_1" / "car_1_iekf_metrics.json").exists()
    assert (tmp_path / "serial" / "day2__ship_2" / "ship_2_iekf.csv").exists()
