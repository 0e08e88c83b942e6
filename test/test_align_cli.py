"""insalign-align: scenario and bag inputs write CSV, metrics JSON and PNG with sensible numbers; bad input exits 2."""

import csv
import json
from pathlib import Path

import pytest

from insalign_ros.cli.align import main


def test_align_scenario_writes_csv_metrics_png(tmp_path):
    rc = main(["--scenario", "ship", "--duration", "40", "--core", "iekf", "--rpy-error", "10", "10", "60",
               "--imu-grade", "paper_ship", "--out-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    m = json.loads((tmp_path / "ship_s0_iekf_metrics.json").read_text())
    assert m["imu_grade"] == "paper_ship"
    assert abs(m["final_err_rpy_deg"][2]) < 2.0  # from 60 deg to within 2 deg in 40 s
    assert m["time_yaw_below_deg_s"] < 40.0
    rows = list(csv.DictReader(open(tmp_path / "ship_s0_iekf.csv")))
    assert len(rows) >= 80 and abs(float(rows[0]["yaw_err_deg"]) - 60.0) < 1e-4
    assert (tmp_path / "ship_s0_iekf.png").stat().st_size > 10_000


def test_align_bag_round_trip(tmp_path):
    from insalign_ros.io.bag import write_bag
    from insalign_ros.sim.scenarios import make_scenario

    bag = tmp_path / "ship_bag"
    write_bag(make_scenario("ship", seed=5, duration_s=30.0), bag)
    rc = main([str(bag), "--core", "liekf", "--rpy-error", "5", "5", "30", "--out-dir", str(tmp_path / "o"),
               "--no-progress"])
    assert rc == 0
    m = json.loads((tmp_path / "o" / "ship_bag_liekf_metrics.json").read_text())
    assert abs(m["final_err_rpy_deg"][2]) < 2.0
    assert m["counters"]["gnss_accepted"] >= 29


def test_align_bad_arguments(tmp_path, capsys):
    assert main(["--scenario", "ship", "--core", "nope", "--out-dir", str(tmp_path)]) == 2
    assert "unknown core" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--out-dir", str(tmp_path)])


def test_a_missing_bag_path_is_not_found_in_the_python_api_too():
    """``ia.align`` on a path that does not exist says so (not "unknown scenario"); a bare unknown name is still an
    unknown scenario with the list of names."""
    import insalign_ros as ia

    for path in ("typo.bag", "bags/no_such_bag", Path("no_such_dir")):
        with pytest.raises(FileNotFoundError, match="not found"):
            ia.align(path, duration_s=1.0)
    with pytest.raises(ValueError, match="unknown scenario"):
        ia.align("no_such_scenario", duration_s=1.0)
