"""Bag contract round trip (docs/bag_contract.md): every field written equals every field read, sqlite3 and mcap."""

import json
import math

import numpy as np
import pytest

from insalign_ros.io import validation
from insalign_ros.io.bag import IMU_TOPIC, read_bag, typestore, write_bag
from insalign_ros.sim.scenarios import make_scenario


@pytest.fixture(scope="module")
def ship():
    return make_scenario("ship", seed=7, duration_s=12.0)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_every_field_round_trips(ship, storage, tmp_path):
    rep = {}
    r = read_bag(write_bag(ship, tmp_path / "b", storage=storage), report=rep)
    assert rep["warnings"] == [] and rep["rejected"] == {}
    assert (r.name, r.seed, r.imu_spec) == (ship.name, ship.seed, ship.imu_spec)
    assert r.gnss_sigma_m == ship.gnss_sigma_m
    np.testing.assert_allclose(r.t_s, ship.t_s, rtol=0, atol=1e-9)  # ns stamps
    np.testing.assert_array_equal(r.omega_ib_b, ship.omega_ib_b)  # float64 in the message: exact
    np.testing.assert_array_equal(r.f_ib_b, ship.f_ib_b)
    np.testing.assert_array_equal(r.bias_gyro_b, ship.bias_gyro_b)
    np.testing.assert_array_equal(r.bias_acc_b, ship.bias_acc_b)
    np.testing.assert_allclose(r.gnss_t_s, ship.gnss_t_s, rtol=0, atol=1e-9)
    # geodetic <-> ECEF / ENU conversions (pymap3d, iterative): 1e-6 m is far below any use
    np.testing.assert_allclose(r.gnss_p_e, ship.gnss_p_e, rtol=0, atol=1e-6)
    np.testing.assert_allclose(r.gnss_R_e, ship.gnss_R_e, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.C_b_n, ship.C_b_n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.lat_rad, ship.lat_rad, rtol=0, atol=1e-12)  # 1e-12 rad = 6 um
    np.testing.assert_allclose(r.lon_rad, ship.lon_rad, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.h_m, ship.h_m, rtol=0, atol=1e-6)
    # v_n is not in the bag: read_bag differentiates the truth positions (2nd order, 100 Hz): < 1 mm/s here
    np.testing.assert_allclose(r.v_n, ship.v_n, rtol=0, atol=1e-3)
    assert r.imu_valid.all() and r.gnss_valid.all() and r.imu_valid.shape == (r.n,)


def test_imu_message_fields_follow_the_contract(ship, tmp_path):
    from rosbags.rosbag2 import Reader

    ts = typestore()
    write_bag(ship, tmp_path / "b")
    with Reader(tmp_path / "b") as rd:
        topics = {c.topic: c.msgtype for c in rd.connections}
        conn = [c for c in rd.connections if c.topic == IMU_TOPIC][0]
        _, _, raw = next(rd.messages(connections=[conn]))
        meta_c = [c for c in rd.connections if c.topic == "/insalign/metadata"][0]
        first = next(rd.messages())
    assert topics == {"/insalign/metadata": "std_msgs/msg/String", "/imu/data": "sensor_msgs/msg/Imu",
                      "/gps/fix": "sensor_msgs/msg/NavSatFix", "/ground_truth/pose": "geometry_msgs/msg/PoseStamped"}
    assert first[0].topic == meta_c.topic  # metadata written first
    m = ts.deserialize_cdr(raw, "sensor_msgs/msg/Imu")
    assert m.header.frame_id == "imu_link" and m.orientation_covariance[0] == -1.0
    arw = math.radians(2.0) / 60.0  # 2 deg/sqrt(h) in rad/sqrt(s)
    np.testing.assert_allclose(m.angular_velocity_covariance, np.diag([arw**2 * 100.0] * 3).ravel(), rtol=1e-12)
    vrw = 0.2 / 60.0
    np.testing.assert_allclose(m.linear_acceleration_covariance, np.diag([vrw**2 * 100.0] * 3).ravel(), rtol=1e-12)
    meta = json.loads(ts.deserialize_cdr(first[2], "std_msgs/msg/String").data)
    assert meta["scenario"] == "ship" and meta["seed"] == 7 and meta["ref_lat_deg"] == ship.params["lat_deg"]


def test_foreign_bag_without_metadata_truth_and_with_bad_samples(ship, tmp_path):
    """A bag from another source: other topic names and frame ids, no metadata, NaN/duplicate samples."""
    from rosbags.rosbag2 import Writer

    ts = typestore()
    T = ts.types
    with Writer(tmp_path / "f", version=9) as w:
        c = w.add_connection("/my_imu", "sensor_msgs/msg/Imu", typestore=ts)
        stamps = [0.0, 0.01, 0.01, 0.02, 0.015, 0.03, 0.04]
        for k, t in enumerate(stamps):
            ns = int(round(t * 1e9))
            x = float("nan") if k == 5 else 0.001
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=ns),
                                                frame_id="base_link"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9), angular_velocity=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=np.zeros(9))
            # bag (receive) time increases; the header stamps repeat and go back (the reader uses the header)
            w.write(c, 1_000_000 * (k + 1), ts.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
    rep = {}
    r = read_bag(tmp_path / "f", imu_topic="/my_imu", report=rep)
    assert r.n == 4 and not r.has_truth and r.gnss_t_s.shape == (0,)
    np.testing.assert_allclose(r.t_s, [0.0, 0.01, 0.02, 0.04], atol=1e-12)
    assert rep["rejected"]["/my_imu"] == {"duplicate stamp": 1, "non-monotonic stamp": 1,
                                          "angular_velocity: non-finite value": 1}
    assert any("frame_id" in w for w in rep["warnings"]) and any("no metadata" in w for w in rep["warnings"])
    with pytest.raises(ValueError, match="no IMU topic"):
        read_bag(tmp_path / "f")


def test_validation_reasons():
    assert validation.check_imu([0, 0, 0.1], [0, 0, 9.8]) is None
    assert "magnitude" in validation.check_imu([0, 0, 100.0], [0, 0, 9.8])
    assert "non-finite" in validation.check_imu([0, 0, 0], [0, np.inf, 9.8])
    assert validation.check_fix(45.0, 7.0, 100.0, np.eye(3)) is None
    assert "diagonal" in validation.check_fix(45.0, 7.0, 100.0, np.zeros((3, 3)))
    assert "semi-definite" in validation.check_fix(45.0, 7.0, 100.0, np.diag([1.0, -1.0, 1.0]))
    assert "symmetric" in validation.check_covariance(np.array([[1, 0.5, 0], [0, 1, 0], [0, 0, 1.0]]))
    assert "range" in validation.check_fix(95.0, 7.0, 100.0)
    assert "no fix" in validation.check_fix(45.0, 7.0, 100.0, status=-1)


def test_covariance_check_decides_as_the_eigenvalues():
    """check_covariance's shortcut (positive definite when the leading minors are clearly positive) gives the verdict
    of the smallest eigenvalue on covariances of every kind: well and badly conditioned, semi-definite, indefinite,
    fix-like (1e-4 to 1e4 m^2)."""
    def reference(c):
        ev = np.linalg.eigvalsh(0.5 * (c + c.T))
        return ev[0] < -1e-12 * max(float(np.trace(c)), 1e-300)

    rng = np.random.default_rng(5)
    n_pd = n_not = 0
    for _ in range(3000):
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        ev = 10.0 ** rng.uniform(-4, 4, 3) * rng.choice([1.0, 1.0, 1.0, 0.0, -1e-13, -1e-6], 3)
        c = Q @ np.diag(ev) @ Q.T
        c = 0.5 * (c + c.T)
        r = validation.check_covariance(c)
        assert (r is not None and "semi-definite" in r) == reference(c), (ev, r)
        n_pd += r is None
        n_not += r is not None
    assert n_pd > 1000 and n_not > 300


def test_simulate_cli(tmp_path, capsys):
    from insalign_ros.cli.simulate import main

    assert main(["static_navgrade", str(tmp_path / "s"), "--seed", "3", "--duration", "5", "--storage", "mcap"]) == 0
    r = read_bag(tmp_path / "s")
    assert r.name == "static_navgrade" and r.seed == 3 and r.n == int(5 * r.imu_spec.rate_hz) + 1
    assert main(["ship", str(tmp_path / "s")]) == 2  # exists
    assert main(["ship", str(tmp_path / "t"), "--set", "nonsense=1"]) == 2
    assert "unknown parameter" in capsys.readouterr().err
