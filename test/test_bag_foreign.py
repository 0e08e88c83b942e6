"""read_bag on recordings from other sources (issue 13 item 6): any topic names, fixes with UNKNOWN covariance
(given a sigma instead of being dropped), a truth topic at its own rate interpolated to the IMU stamps, and the ENU
origin of the truth from the first fix when there is no metadata."""

import math

import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from insalign_ros.core import earth
from insalign_ros.io.bag import read_bag, typestore
from insalign_ros.sim.scenarios import make_scenario

T_ABS_NS = 1_700_000_000_123_456_789  # a driver's wall-clock stamps
ORIGIN_SHIFT_M = np.array([120.0, -45.0, 3.0])  # the recording's ENU origin, relative to the first position
IN = slice(5, -5)  # IMU samples inside the 10 Hz truth's span (truth on samples 5, 15, ..., 1995)


@pytest.fixture(scope="module")
def car():
    """Noise-free car (exact fixes), 20 s at 100 Hz, fixes at 1 Hz; it turns at up to 0.4 rad/s."""
    return make_scenario("car", seed=4, duration_s=20.0, noise=False)


def write_foreign_bag(d, path, truth_type="geometry_msgs/msg/PoseStamped", truth_step=10, truth_first=5,
                      cov_type=0, zero_cov=False):
    """A driver-style bag: /imu/data_raw (frame 'imu'), /fix (frame 'gps', covariance type ``cov_type``, zeros),
    a truth pose topic every ``truth_step`` IMU samples from sample ``truth_first`` (10 Hz), ENU about an origin
    ORIGIN_SHIFT_M away from the start, absolute stamps, no metadata."""
    from rosbags.rosbag2 import Writer

    ts = typestore()
    T = ts.types
    lat0, lon0, h0 = d.lat_rad[0], d.lon_rad[0], d.h_m[0]
    olat, olon, oh = pymap3d.enu2geodetic(*ORIGIN_SHIFT_M, lat0, lon0, h0, deg=False)
    e, n, u = pymap3d.geodetic2enu(d.lat_rad, d.lon_rad, d.h_m, olat, olon, oh, deg=False)
    q = Rotation.from_matrix(d.C_b_n).as_quat()
    glat, glon, galt = pymap3d.ecef2geodetic(d.gnss_p_e[:, 0], d.gnss_p_e[:, 1], d.gnss_p_e[:, 2])

    def hdr(t, frame):
        ns = T_ABS_NS + int(round(t * 1e9))
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame), ns

    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    events = []
    for k in range(d.n):
        h, ns = hdr(d.t_s[k], "imu")
        w, f = d.omega_ib_b[k], d.f_ib_b[k]
        events.append((ns, "/imu/data_raw", T["sensor_msgs/msg/Imu"](
            header=h, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.r_[-1.0, np.zeros(8)],
            angular_velocity=V3(x=w[0], y=w[1], z=w[2]), angular_velocity_covariance=np.zeros(9),
            linear_acceleration=V3(x=f[0], y=f[1], z=f[2]), linear_acceleration_covariance=np.zeros(9))))
    for j in range(d.gnss_t_s.shape[0]):
        h, ns = hdr(d.gnss_t_s[j], "gps")
        events.append((ns, "/fix", T["sensor_msgs/msg/NavSatFix"](
            header=h, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=float(glat[j]),
            longitude=float(glon[j]), altitude=float(galt[j]),
            position_covariance=np.diag([4.0, 4.0, 9.0]).ravel() if cov_type and not zero_cov else np.zeros(9),
            position_covariance_type=cov_type)))
    for k in range(truth_first, d.n, truth_step):
        h, ns = hdr(d.t_s[k], "map")
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=e[k], y=n[k], z=u[k]),
                                           orientation=Q(x=q[k, 0], y=q[k, 1], z=q[k, 2], w=q[k, 3]))
        if truth_type == "nav_msgs/msg/Odometry":
            msg = T[truth_type](header=h, child_frame_id="base_link",
                                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                                    twist=T["geometry_msgs/msg/Twist"](linear=V3(x=0.0, y=0.0, z=0.0),
                                                                       angular=V3(x=0.0, y=0.0, z=0.0)),
                                    covariance=np.zeros(36)))
        else:
            msg = T[truth_type](header=h, pose=pose)
        events.append((ns, "/truth", msg))
    events.sort(key=lambda ev: ev[0])
    with Writer(path, version=9) as w:
        conns = {}
        for ns, topic, msg in events:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msg.__msgtype__, typestore=ts)
            w.write(conns[topic], ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path


def _interp_bounds(d, dt_s=0.1):
    """Linear interpolation error bounds over dt_s: max|a| dt^2/8 [m] (position), max|alpha| dt^2/8 [rad]."""
    a = np.linalg.norm(np.gradient(d.v_n, d.t_s, axis=0), axis=1).max()
    alpha = np.linalg.norm(np.gradient(d.omega_ib_b, d.t_s, axis=0), axis=1).max()
    return a * dt_s**2 / 8 + 1e-4, alpha * dt_s**2 / 8 + 1e-6


def _pos_err_m(r, d):
    """|position read - position simulated| [m] per sample (ENU at the simulated position)."""
    e, n, u = pymap3d.geodetic2enu(r.lat_rad, r.lon_rad, r.h_m, d.lat_rad, d.lon_rad, d.h_m, deg=False)
    return np.sqrt(e**2 + n**2 + u**2)


def _angle(C_a, C_b):
    dC = np.einsum("nji,njk->nik", C_a, C_b)
    return np.arccos(np.clip((np.trace(dC, axis1=1, axis2=2) - 1) / 2, -1, 1))


@pytest.mark.parametrize("truth_type", ["geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry"])
def test_foreign_bag_truth_at_10hz_is_interpolated_and_anchored_at_the_first_fix(car, truth_type, tmp_path):
    d = car
    rep = {}
    r = read_bag(write_foreign_bag(d, tmp_path / "b", truth_type), imu_topic="/imu/data_raw", gps_topic="/fix",
                 truth_topic="/truth", report=rep, unknown_fix_sigma_m=2.5)
    assert r.n == d.n and r.has_truth and r.gnss_t_s.shape == d.gnss_t_s.shape
    np.testing.assert_allclose(r.t_s, d.t_s, atol=1e-9)  # relative to the first IMU stamp
    assert r.params["stamp_offset_ns"] == T_ABS_NS
    # attitude: slerp of 10 Hz truth, error <= alpha dt^2 / 8 (the car's angular acceleration); the first 5 samples are before the first truth pose (held, said in a warning)
    err = _angle(r.C_b_n, d.C_b_n)
    pos_bound_m, att_bound_rad = _interp_bounds(d)
    assert err[IN].max() < att_bound_rad and err[:5].max() < 0.05 * 0.4
    assert any("held constant for 10 IMU sample(s) outside its span (up to 0.050 s)" in w for w in rep["warnings"])
    # position: the origin is placed by the first fix inside the truth span (exact fixes here, but the truth there
    # is interpolated too): error <= 2 x the linear interpolation bound a dt^2 / 8
    assert _pos_err_m(r, d)[IN].max() < 2 * pos_bound_m
    o = [r.params[k] for k in ("ref_lat_deg", "ref_lon_deg", "ref_h_m")]
    e, n, u = pymap3d.geodetic2enu(*o, math.degrees(d.lat_rad[0]), math.degrees(d.lon_rad[0]), d.h_m[0])
    np.testing.assert_allclose([e, n, u], ORIGIN_SHIFT_M, atol=1e-3)
    assert any("truth at the first fix" in w for w in rep["warnings"])
    # v_n: derivative of 10 Hz positions (car acceleration changes slowly): within 2 cm/s of the simulator's
    assert np.max(np.abs(r.v_n[5:-5] - d.v_n[5:-5])) < 0.02
    # fixes with UNKNOWN covariance: sigma 2.5 m per axis in ENU, counted
    C = earth.C_e_n(d.lat_rad[0], d.lon_rad[0])
    np.testing.assert_allclose(C @ r.gnss_R_e[0] @ C.T, np.eye(3) * 6.25, atol=1e-9)
    assert rep["unknown_covariance_fixes"] == d.gnss_t_s.shape[0] and rep["rejected"] == {}


def test_unknown_covariance_fixes_dropped_only_on_request_and_known_ones_kept(car, tmp_path):
    d = car
    write_foreign_bag(d, tmp_path / "u")
    rep = {}
    r = read_bag(tmp_path / "u", imu_topic="/imu/data_raw", gps_topic="/fix", truth_topic="/truth", report=rep,
                 unknown_fix_sigma_m=None)
    assert r.gnss_t_s.shape == (0,) and rep["rejected"]["/fix"] == {"position_covariance_type UNKNOWN": 21}
    assert not r.has_truth and any("truth dropped" in w for w in rep["warnings"])  # no fix, no metadata
    # the default sigma is the node's gnss_sigma_m default (1 m)
    r = read_bag(tmp_path / "u", imu_topic="/imu/data_raw", gps_topic="/fix", truth_topic="/truth")
    C = earth.C_e_n(d.lat_rad[0], d.lon_rad[0])
    np.testing.assert_allclose(np.diag(C @ r.gnss_R_e[0] @ C.T), [1.0, 1.0, 1.0], atol=1e-9)
    write_foreign_bag(d, tmp_path / "k", cov_type=2)
    r = read_bag(tmp_path / "k", imu_topic="/imu/data_raw", gps_topic="/fix", truth_topic="/truth")
    np.testing.assert_allclose(np.diag(C @ r.gnss_R_e[0] @ C.T), [4.0, 4.0, 9.0], atol=1e-9)
    with pytest.raises(ValueError, match="unknown_fix_sigma_m"):
        read_bag(tmp_path / "k", imu_topic="/imu/data_raw", unknown_fix_sigma_m=-1.0)
    # APPROXIMATED (1) with an all-zero covariance (some drivers): unknown, the same sigma, or dropped on request
    write_foreign_bag(d, tmp_path / "z", cov_type=1, zero_cov=True)
    rep = {}
    r = read_bag(tmp_path / "z", imu_topic="/imu/data_raw", gps_topic="/fix", report=rep, unknown_fix_sigma_m=3.0)
    np.testing.assert_allclose(np.diag(C @ r.gnss_R_e[0] @ C.T), [9.0, 9.0, 9.0], atol=1e-9)
    assert r.gnss_t_s.shape == (21,) and rep["unknown_covariance_fixes"] == 21 and rep["rejected"] == {}
    rep = {}
    r = read_bag(tmp_path / "z", imu_topic="/imu/data_raw", gps_topic="/fix", report=rep, unknown_fix_sigma_m=None)
    assert r.gnss_t_s.shape == (0,) and rep["rejected"]["/fix"] == {"position covariance all zeros": 21}


def test_topics_found_by_type_and_named_when_missing_or_ambiguous(car, tmp_path):
    """None for a topic: the contract's name, else the bag's one topic of the type; the report says which."""
    write_foreign_bag(car, tmp_path / "b", cov_type=2)
    rep = {}
    r = read_bag(tmp_path / "b", imu_topic=None, gps_topic=None, vel_topic=None, report=rep)
    assert rep["topics"] == {"imu": "/imu/data_raw", "gps": "/fix", "vel": None, "truth": None}
    assert r.n == car.n and r.gnss_t_s.shape == (21,) and not r.has_truth  # truth only by name
    assert rep["bag_topics"]["/truth"] == "geometry_msgs/msg/PoseStamped"
    assert not [w for w in rep["warnings"] if "frame_id" in w], rep["warnings"]  # 'imu' and 'gps': a driver's own
    rep = {}
    read_bag(tmp_path / "b", imu_topic=None, gps_topic=None, truth_topic="/truth", report=rep)
    assert [w for w in rep["warnings"] if "frame_id" in w] == ["/truth: frame_id ['map'] != contract 'enu'"]
    with pytest.raises(ValueError, match=r"no IMU topic '/imu/data' \(--imu-topic\) in the bag; its topics: "
                                         r"/fix \(sensor_msgs/msg/NavSatFix\), /imu/data_raw \(sensor_msgs/msg/Imu\)"):
        read_bag(tmp_path / "b")  # the contract's name, which this bag lacks
    with pytest.raises(ValueError, match="not a readable bag"):
        (tmp_path / "x.bag").write_bytes(b"#ROSBAG V2.0\nnot really")
        read_bag(tmp_path / "x.bag", imu_topic=None)


def test_truth_reference_from_the_user_when_there_is_no_fix(car, tmp_path):
    """Truth and IMU only (no fix, no metadata): the ENU origin must come from ref_llh_deg."""
    d = car
    write_foreign_bag(d, tmp_path / "t")
    o = pymap3d.enu2geodetic(*ORIGIN_SHIFT_M, math.degrees(d.lat_rad[0]), math.degrees(d.lon_rad[0]), d.h_m[0])
    r = read_bag(tmp_path / "t", imu_topic="/imu/data_raw", gps_topic="/none", truth_topic="/truth",
                 ref_llh_deg=o)
    assert r.gnss_t_s.shape == (0,) and r.has_truth
    assert _pos_err_m(r, d)[IN].max() < _interp_bounds(d)[0]
