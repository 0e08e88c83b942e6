"""alignment_node parameters: config files match the declared parameters, run-time changes are validated."""

import math
from pathlib import Path

import pytest
import yaml


pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(60)
def test_config_files_set_declared_parameters(node_factory):
    common = ROOT / "config" / "alignment_node.yaml"
    core = ROOT / "config" / "liekf.yaml"
    node = node_factory(["--params-file", str(common), "--params-file", str(core), "-p", "aligned.hold_s:=7.5"])
    want = yaml.safe_load(common.read_text())["/**"]["ros__parameters"]
    flat = {}
    for k, v in want.items():
        if isinstance(v, dict):
            flat.update({f"{k}.{kk}": vv for kk, vv in v.items()})
        else:
            flat[k] = v
    assert set(flat) <= set(node._parameters), sorted(set(flat) - set(node._parameters))
    for k, v in flat.items():
        got = node.get_parameter(k).value
        if k == "aligned.hold_s":
            assert got == 7.5  # the command line overrides the file
        elif isinstance(v, list):
            assert len(got) == len(v) and all((math.isnan(a) and math.isnan(b)) or a == b for a, b in zip(got, v)), k
        else:
            assert got == v, k
    assert node.criteria.hold_s == 7.5
    core_want = yaml.safe_load(core.read_text())["/**"]["ros__parameters"]
    for k, v in core_want.items():
        assert node.get_parameter(k).value == v, k


@pytest.mark.timeout(60)
def test_run_time_changes_are_validated_and_bad_values_refused(node_factory):
    from rclpy.parameter import Parameter

    node = node_factory(["-p", "core:=iekf"])
    cases = [
        (Parameter("aligned.yaw_3sigma_deg", value=-1.0), "yaw_3sigma_deg"),
        (Parameter("aligned.nis_alpha", value=2.0), "nis_alpha"),
        (Parameter("gyro_arw_deg_sqrt_h", value=-2.0), "gyro_arw_deg_sqrt_h"),
        (Parameter("core", value="liekf"), "read-only"),  # a core comes with its own parameter set: restart
        (Parameter("max_rate_rad_s", value=float("nan")), "max_rate_rad_s"),
        (Parameter("initial_rpy_deg", value=[1.0, 2.0]), "initial_rpy_deg"),
        (Parameter("pose_rate_hz", value="fast"), "type"),  # rclpy refuses a type change itself
        (Parameter("imu_qos", value="reliable"), "read-only"),
        (Parameter("backtrack_passes", value=1), "backward propagation"),  # iekf cannot run backward
        (Parameter("yaw_hypotheses", value=0), "yaw_hypotheses"),
    ]
    for prm, word in cases:
        old = node.get_parameter(prm.name).value
        res = node.set_parameters([prm])[0]
        assert not res.successful and word in res.reason.lower() + res.reason, (prm.name, res.reason)
        new = node.get_parameter(prm.name).value
        assert new == old or (isinstance(old, list) and list(new) == list(old)), prm.name  # the old value is kept
    # good values are taken, the criteria apply at once
    res = node.set_parameters([Parameter("aligned.yaw_3sigma_deg", value=1.5), Parameter("pose_rate_hz", value=20.0)])
    assert all(r.successful for r in res)
    assert node.criteria.yaw_3sigma_deg == 1.5 and node.flag.criteria.yaw_3sigma_deg == 1.5
    assert node.pose_period_s == pytest.approx(0.05)
    # a core parameter change restarts the alignment with the new value (and the core keeps its own defaults: the
    # dataclass's, the noise and bias fields from the default imu_grade)
    from insalign_ros.filters.config import IekfConfig
    from insalign_ros.filters.imu_grade import DEFAULT_IMU_GRADE, grade_params

    assert node.set_parameters([Parameter("gnss_sigma_floor_m", value=2)])[0].successful  # int for a double
    assert node.session.core_params["gnss_sigma_floor_m"] == 2.0 and node.state == "waiting for data"
    cfg = node.session.core_params
    want = {**IekfConfig().to_dict(), **grade_params(DEFAULT_IMU_GRADE, IekfConfig)}
    assert not node.set_parameters([Parameter("imu_grade", value="tactical")])[0].successful  # read-only
    assert {k: v for k, v in cfg.items() if k != "gnss_sigma_floor_m"} == \
        {k: v for k, v in want.items() if k != "gnss_sigma_floor_m"}


@pytest.mark.timeout(60)
def test_bad_start_up_parameter_is_an_error_with_the_reason(node_factory):
    with pytest.raises(ValueError, match="unknown 'nope'|unknown core 'nope'"):
        node_factory(["-p", "core:=nope"])
    with pytest.raises(ValueError, match="hold_s"):
        node_factory(["-p", "aligned.hold_s:=-3.0"])
    with pytest.raises(ValueError, match="backward propagation"):  # a bank cannot be backtracked
        node_factory(["-p", "core:=liekf", "-p", "backtrack_passes:=1", "-p", "yaw_hypotheses:=8"])


@pytest.mark.timeout(60)
def test_descriptors_via_the_parameter_service_and_int_for_double(node_factory):
    """What `ros2 param describe` shows: a description and a range through the real parameter service; an integer
    given for a double parameter (-p gnss_sigma_m:=2) is accepted as 2.0."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter_client import AsyncParameterClient

    node = node_factory(["-p", "gnss_sigma_m:=2", "-p", "core:=iekf"])
    assert node.params["gnss_sigma_m"] == 2.0 and isinstance(node.params["gnss_sigma_m"], float)
    ctx = node.context
    client_node = Node("param_client", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(client_node)
    try:
        cli = AsyncParameterClient(client_node, "alignment_node")
        assert cli.wait_for_services(timeout_sec=10.0)
        fut = cli.describe_parameters(["max_fix_lag_s", "core", "imu_qos_depth"])
        ex.spin_until_future_complete(fut, timeout_sec=10.0)
        lag, core, depth = fut.result().descriptors
        assert "fused at their stamp" in lag.description and lag.floating_point_range[0].to_value == 10.0
        assert core.read_only and "read-only" in core.description
        assert depth.integer_range[0].from_value == 1
    finally:
        client_node.destroy_node()


@pytest.mark.timeout(60)
def test_wrong_type_at_start_up_is_one_line_and_exit_2(tmp_path):
    from insalign_ros.cli.bringup import isolated_ros_env, start_node, wait_for_exit

    env = isolated_ros_env()
    node = start_node("insalign_ros.nodes.alignment_node", env, log_dir=tmp_path,
                      params={"gnss_sigma_m": "abc"})
    assert wait_for_exit(node, 30.0) == 2
    out = node.output()
    assert "bad parameter" in out and "gnss_sigma_m" in out and "Traceback" not in out, out
