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


def test_aligned_criteria_as_the_node_takes_them(tmp_path, capsys):
    """``--aligned KEY=VALUE`` sets the aligned flag's criteria as the node's ``aligned.<KEY>`` parameters do: a 5-s
    hold raises the flag 3 s (30 outputs at 10 Hz) after the default 2-s hold; an unknown criterion or a bad value
    is a one-line error, exit 2."""
    first = {}
    for hold in ("2", "5"):
        out = tmp_path / hold
        assert main(["--scenario", "ship", "--duration", "60", "--core", "iekf", "--imu-grade", "paper_ship",
                     "--aligned", f"hold_s={hold}", "--output-period", "0.1", "--out-dir", str(out),
                     "--no-progress", "--no-plot"]) == 0
        m = json.loads((out / "ship_s0_iekf_metrics.json").read_text())
        assert m["aligned_criteria"]["hold_s"] == float(hold) and m["aligned_criteria"]["level_floor_factor"] == 1.5
        first[hold] = m["aligned_first_raised_at_s"]
    assert first["5"] - first["2"] == pytest.approx(3.0, abs=0.11), first
    assert main(["--scenario", "ship", "--aligned", "hold=5", "--out-dir", str(tmp_path)]) == 2
    assert "--aligned: unknown criterion ['hold']; one of roll_pitch_3sigma_deg" in capsys.readouterr().err
    assert main(["--scenario", "ship", "--aligned", "hold_s=-1", "--out-dir", str(tmp_path)]) == 2
    assert "hold_s must be >= 0" in capsys.readouterr().err


def test_a_missing_bag_path_is_not_found_in_the_python_api_too():
    """``ia.align`` on a path that does not exist says so (not "unknown scenario"); a bare unknown name is still an
    unknown scenario with the list of names."""
    import insalign_ros as ia

    for path in ("typo.bag", "bags/no_such_bag", Path("no_such_dir")):
        with pytest.raises(FileNotFoundError, match="not found"):
            ia.align(path, duration_s=1.0)
    with pytest.raises(ValueError, match="unknown scenario"):
        ia.align("no_such_scenario", duration_s=1.0)


def test_csv_says_status_and_unknown_for_a_3_sigma_beyond_180_deg(tmp_path):
    """From the sensors the heading starts unknown (a yaw bank: its 3-sigma is hundreds of degrees, which says
    nothing about an angle): the CSV writes "unknown" there, never a number above 180 deg, and has the status of
    every output; the JSON's final 3-sigma is a number or null."""
    rc = main(["--scenario", "ship", "--duration", "30", "--core", "iekf", "--session-param", "init_mode=sensors",
               "--imu-grade", "paper_ship", "--out-dir", str(tmp_path), "--no-progress", "--no-plot"])
    assert rc == 0
    rows = list(csv.DictReader(open(tmp_path / "ship_s0_iekf.csv")))
    yaw3 = [r["sigma3_yaw_deg"] for r in rows]
    assert "unknown" in yaw3, yaw3[:5]
    assert all(v == "unknown" or float(v) <= 180.0 for v in yaw3)
    assert {r["status"] for r in rows} <= {"aligning", "aligned", "fault", "waiting for data", "waiting for GNSS",
                                            "waiting for motion"}, {r["status"] for r in rows}
    m = json.loads((tmp_path / "ship_s0_iekf_metrics.json").read_text())
    assert all(x is None or 0.0 < x <= 180.0 for x in m["final_3sigma_deg"])


def test_metrics_keep_the_first_flag_and_count_restarts_across_a_restart():
    """A clock step of 100 s at 90 s of a ship run resets the alignment (time jump): the metrics still give the first
    flag of the run (it rose at 18 s), one restart, and the span from the first IMU sample (data time, the step
    included); before, the first flag and the duration restarted with the filter."""
    import dataclasses

    import numpy as np

    import insalign_ros as ia

    d = ia.simulate("ship", seed=2, duration_s=150.0)
    k, j = int(np.searchsorted(d.t_s, 90.0)), int(np.searchsorted(d.gnss_t_s, 90.0))
    t, g = d.t_s.copy(), d.gnss_t_s.copy()
    t[k:] += 100.0
    g[j:] += 100.0
    r = ia.align(dataclasses.replace(d, t_s=t, gnss_t_s=g), core="iekf", init_mode="truth",
                 init_rpy_error_deg=[1.0, 1.0, 5.0], output_period_s=1.0, imu_grade="paper_ship")
    assert r.counters["time_resets"] == 1 and r.metrics["restarts"] == 1
    assert r.metrics["aligned_first_raised_at_s"] is not None and r.metrics["aligned_first_raised_at_s"] < 90.0
    assert r.metrics["duration_s"] == pytest.approx(t[-1] - t[0], abs=1.0)
