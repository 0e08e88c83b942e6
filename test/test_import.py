"""insalign-import (issue 15 item 5): axes and Euler conventions converted once (closed-form checks), increments to
rates, the shipped example round-trips CSV -> bag -> read back exactly, an increment-type RFU log of a simulated
car aligns like the scenario itself, and every user error is one line with exit 2."""

import math
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from insalign_ros.cli.import_data import main as import_main
from insalign_ros.core import earth
from insalign_ros.io.bag import read_bag
from insalign_ros.io.importer import (C_b_n_from_euler, C_flu_from_axes, ImportDataError, import_table,
                                      imu_axes_to_flu, increments_to_rates, table_from_scenario, write_csv)
from insalign_ros.sim.scenarios import make_scenario

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "data" / "imu_increments_rfu.csv"
EX_ARGS = ["--imu", "increments", "--axes", "RFU", "--euler", "ned"]


def test_imu_axes_to_flu_closed_form():
    # RFU: the IMU's x points right, y forward, z up
    np.testing.assert_array_equal(imu_axes_to_flu([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "RFU"),
                                  [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    # FRD: x forward, y right, z down; a body at rest: FRD accelerometer reads -g on z -> FLU +g
    np.testing.assert_array_equal(imu_axes_to_flu([[0.1, 0.2, -9.8]], "FRD"), [[0.1, -0.2, 9.8]])
    np.testing.assert_array_equal(C_flu_from_axes("flu"), np.eye(3))
    for bad in ("FRU", "FFU", "XYZ", "FL"):  # left-handed, repeated, unknown letters, too short
        with pytest.raises(ImportDataError):
            C_flu_from_axes(bad)


def test_ned_heading_to_enu_closed_form():
    """NED: heading 30 deg from North (clockwise), nose 10 deg up, right wing 5 deg down (roll +5)."""
    h, p, r = np.radians([30.0]), np.radians([10.0]), np.radians([5.0])
    C = C_b_n_from_euler(r, p, h, "ned")[0]
    fwd = C @ [1.0, 0.0, 0.0]  # FLU x in ENU
    np.testing.assert_allclose(fwd, [math.sin(h[0]) * math.cos(p[0]), math.cos(h[0]) * math.cos(p[0]),
                                     math.sin(p[0])], atol=1e-15)
    left = C @ [0.0, 1.0, 0.0]
    assert left[2] == pytest.approx(math.cos(p[0]) * math.sin(r[0]), abs=1e-15)  # right wing down = left wing up
    # the same attitude in ROS/ENU terms: yaw = 90 - heading, pitch = -pitch (REP 103: positive = nose down)
    rpy = earth.rpy_from_C_b_n(C)
    np.testing.assert_allclose(np.degrees(rpy), [5.0, -10.0, 60.0], atol=1e-12)
    np.testing.assert_allclose(C_b_n_from_euler(*np.radians([[5.0], [-10.0], [60.0]]), "enu")[0], C, atol=1e-15)


def test_increments_to_rates_over_irregular_steps():
    t = np.array([0.0, 0.01, 0.021, 0.029, 0.04])
    w, f = np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.5, 9.8])
    dt = np.r_[np.median(np.diff(t)), np.diff(t)][:, None]
    wr, fr = increments_to_rates(t, w * dt, f * dt)
    np.testing.assert_allclose(wr, np.tile(w, (5, 1)), rtol=1e-14)
    np.testing.assert_allclose(fr, np.tile(f, (5, 1)), rtol=1e-14)
    wr, _ = increments_to_rates(np.array([0.0, 0.01, 0.01, 0.02]), np.ones((4, 3)), np.ones((4, 3)))
    assert np.isnan(wr[2]).all() and np.isfinite(wr[[0, 1, 3]]).all()  # a repeated stamp: no rate


def test_shipped_example_is_current_and_round_trips_exactly(tmp_path, capsys):
    ex = runpy.run_path(str(ROOT / "examples" / "make_import_example.py"))
    write_csv(tmp_path / "regen.csv", ex["example_table"]())
    body = lambda p: [ln for ln in Path(p).read_text().splitlines() if not ln.startswith("#")]  # noqa: E731
    # the same header and the same numbers to 1e-10 relative (the last digit of a float's text differs between
    # machines: numpy's SIMD trigonometry depends on the CPU)
    new, old = body(tmp_path / "regen.csv"), body(EXAMPLE)
    assert new[0] == old[0] and len(new) == len(old), "rerun examples/make_import_example.py"
    num = lambda rows: np.array([[float(x) if x else np.nan for x in r.split(",")] for r in rows[1:]])  # noqa: E731
    np.testing.assert_allclose(num(new), num(old), rtol=1e-10, atol=1e-15, equal_nan=True,
                               err_msg="rerun examples/make_import_example.py")
    assert import_main([str(EXAMPLE), str(tmp_path / "bag"), *EX_ARGS]) == 0
    out = capsys.readouterr().out
    assert "101 valid of 101 rows (increments, axes RFU -> FLU), 2 GNSS fixes, 101 reference" in out, out
    d, _ = import_table(EXAMPLE, **dict(zip(("imu", "axes", "euler"), EX_ARGS[1::2])))
    r = read_bag(tmp_path / "bag")
    # IMU values bit-identical; stamps are integer ns; geodetic conversions (pymap3d, iterative) to 1e-6 m
    tolerance = {"omega_ib_b": 0.0, "f_ib_b": 0.0, "t_s": 1e-9, "gnss_p_e": 1e-6, "gnss_R_e": 1e-12, "C_b_n": 1e-12,
                 "lat_rad": 1e-12, "lon_rad": 1e-12, "h_m": 1e-6}
    for name, atol in tolerance.items():
        np.testing.assert_allclose(getattr(r, name), getattr(d, name), rtol=0, atol=atol, err_msg=name)
    # and the conversions undo the example's: the simulated FLU IMU and ENU attitude come back
    s = make_scenario("car", seed=0, duration_s=1.0)
    # (to 1e-12: the simulator's trigonometry differs in the last digits between CPUs)
    np.testing.assert_allclose(r.omega_ib_b, s.omega_ib_b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(r.f_ib_b, s.f_ib_b, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(r.C_b_n, s.C_b_n, atol=1e-12)
    # .npz with the same columns gives the same data
    cols = ex["example_table"]()
    np.savez(tmp_path / "x.npz", **cols)
    dz, _ = import_table(tmp_path / "x.npz", imu="increments", axes="RFU", euler="ned")
    d, _ = import_table(tmp_path / "regen.csv", imu="increments", axes="RFU", euler="ned")  # the same table as CSV
    np.testing.assert_array_equal(dz.omega_ib_b, d.omega_ib_b)


def test_increment_rfu_log_of_a_simulated_car_aligns(tmp_path):
    """60 s of the car (noise, biases) as increments in RFU with an NED reference -> bag -> IEKF from 5/-5/30 deg:
    the same estimate as on the scenario itself (the import loses nothing), final yaw within 0.5 deg and 3 sigma.
    Through ``ia.align`` (initialised at the truth plus the error, the iekf's default IMU: imu_grade paper_ship)."""
    import insalign_ros as ia

    s = make_scenario("car", seed=5, duration_s=60.0)
    write_csv(tmp_path / "car.csv", table_from_scenario(s, imu="increments", axes="RFU", euler="ned"))
    assert import_main([str(tmp_path / "car.csv"), str(tmp_path / "bag"), *EX_ARGS]) == 0
    r = read_bag(tmp_path / "bag")
    res = {name: ia.align(data, core="iekf", init_mode="truth", init_rpy_error_deg=[5.0, -5.0, 30.0],
                          output_period_s=1.0, imu_grade="paper_ship")
           for name, data in (("import", r), ("scenario", s))}
    np.testing.assert_allclose(res["import"].t_s, res["scenario"].t_s, atol=1e-6)
    err, sig3 = res["import"].rpy_err_deg[-1], res["import"].sigma3_deg[-1]
    print(f"final rpy error {err} deg, 3-sigma {sig3} deg")
    assert abs(err[2]) < min(0.5, sig3[2]) and np.all(np.abs(err[:2]) < sig3[:2])
    np.testing.assert_allclose(res["import"].rpy_err_deg, res["scenario"].rpy_err_deg, atol=1e-4)


def _one_line_error(capsys, argv, expect: str):
    assert import_main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and expect in err, err


def test_user_errors_are_one_line_and_exit_2(tmp_path, capsys):
    good = write_csv(tmp_path / "g.csv", {"t_s": np.array([0.0, 0.01]), "wx_rad_s": np.zeros(2)})
    _one_line_error(capsys, [str(tmp_path / "none.csv"), str(tmp_path / "b")], "no such file")
    _one_line_error(capsys, [str(good), str(tmp_path / "b")], "needs column(s) wy_rad_s")
    _one_line_error(capsys, [str(EXAMPLE), str(tmp_path / "b"), "--axes", "FRU"], "right-handed")
    _one_line_error(capsys, [str(EXAMPLE), str(tmp_path / "b"), "--imu", "deltas"], "invalid choice")
    _one_line_error(capsys, [str(EXAMPLE), str(tmp_path / "b")], "needs column(s) wx_rad_s")  # rates expected
    (tmp_path / "bad.csv").write_text("t_s,wx_rad_s\n0.0,abc\n")
    _one_line_error(capsys, [str(tmp_path / "bad.csv"), str(tmp_path / "b")], "line 2: a cell is not a number")
    (tmp_path / "short.csv").write_text("t_s,wx_rad_s\n0.0\n")
    _one_line_error(capsys, [str(tmp_path / "short.csv"), str(tmp_path / "b")], "line 2: 1 cells, header has 2")
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00")
    _one_line_error(capsys, [str(tmp_path / "bin.csv"), str(tmp_path / "b")], "not a UTF-8")
    att = {"t_s": np.array([0.0, 0.01, 0.02]), **{c: np.zeros(3) for c in
                                                 ("wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2")},
           "fz_m_s2": np.full(3, 9.8), "roll_deg": np.zeros(3), "pitch_deg": np.zeros(3), "yaw_deg": np.zeros(3)}
    write_csv(tmp_path / "att.csv", att)
    _one_line_error(capsys, [str(tmp_path / "att.csv"), str(tmp_path / "b")], "needs a position")
    assert import_main([str(tmp_path / "att.csv"), str(tmp_path / "b"), "--position", "45", "7", "100"]) == 0
    _one_line_error(capsys, [str(tmp_path / "att.csv"), str(tmp_path / "b")], "exists")
    assert not (tmp_path / "none_bag").exists()


def test_bad_rows_are_counted_not_fatal(tmp_path, capsys):
    cols = table_from_scenario(make_scenario("car", seed=1, duration_s=1.0), imu="rates", axes="FLU", euler="enu")
    cols["wz_rad_s"][5] = np.nan
    cols["t_s"][9] = cols["t_s"][8]
    cols["lat_deg"][0] = 95.0  # the fix of row 0 is out of range; the IMU row stays
    write_csv(tmp_path / "c.csv", cols)
    assert import_main([str(tmp_path / "c.csv"), str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "99 valid of 101 rows" in out and "duplicate stamp: 1" in out and "non-finite value: 1" in out, out
    assert "lat/lon out of range: 1" in out
    r = read_bag(tmp_path / "b")
    assert r.n == 99 and r.gnss_t_s.shape == (1,)


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
