"""The node and ``ia.align`` accept and refuse the same configurations (issue 23, item 1): one table of
configurations, each run through the node's start-up (in-process, real rclpy) and through ``ia.align`` on a short
simulated run; both must refuse, or both must accept. The node's decisions live in the session's configuration
(session/catalog.py, SessionConfig), so a configuration cannot mean one thing to the node and another offline.

Not in the table, by design: a parameter the chosen core does not have is an error offline (a Python keyword) and a
warning at the node's start (a ROS parameter file keyed ``/**`` is shared by every node; docs/nodes.md).
"""

import pytest

import insalign_ros as ia
from insalign_ros.cli.bringup import isolated_ros_env

pytestmark = pytest.mark.ros

#: (what, core, node parameters beyond core, ia.align keywords beyond core, word both refusals name, or None: accepted)
TABLE = [
    ("backtracking on a core that cannot run backwards", "iekf", {"backtrack_passes": 2}, {"backtrack_passes": 2},
     "backtrack_passes"),
    ("backtracking on the LIEKF (built as liekf_backtrack)", "liekf", {"backtrack_passes": 2},
     {"backtrack_passes": 2}, None),
    ("an unknown core", "no_such_core", {}, {}, "no_such_core"),
    ("an unknown IMU grade", "iekf", {"imu_grade": "no_such_grade"}, {"imu_grade": "no_such_grade"}, "imu_grade"),
    ("a negative GNSS sigma", "liekf", {"gnss_sigma_m": -1.0}, {"gnss_sigma_m": -1.0}, "gnss_sigma_m"),
    ("a NaN IMU timeout", "liekf", {"imu_timeout_s": float("nan")}, {"imu_timeout_s": float("nan")}, "imu_timeout_s"),
    ("the defaults of auto", "auto", {}, {}, None),
    ("a grade under pkf", "pkf", {"imu_grade": "navigation"}, {"imu_grade": "navigation"}, None),
    # deprecated names (filters/imu_grade.DEPRECATED_ALIASES, one table): accepted with a warning by both doors
    ("a deprecated gyro-bias name", "iekf", {"init_sigma_gyro_bias_deg_h": 3.0},
     {"core_params": {"init_sigma_gyro_bias_deg_h": 3.0}}, None),
    ("a deprecated consider-bias name", "pkf", {"consider_acc_bias_mg": 0.5},
     {"core_params": {"consider_acc_bias_mg": 0.5}}, None),
    ("a deprecated unit (ug for mg)", "earth_iekf", {"init_sigma_acc_bias_ug": 30.0},
     {"core_params": {"init_sigma_acc_bias_ug": 30.0}}, None),
    ("the core's old status-threshold name", "liekf", {"aligned_yaw_3sigma_deg": 2.0},
     {"core_params": {"aligned_yaw_3sigma_deg": 2.0}}, None),
    ("an old and a new name that disagree", "iekf", {"init_sigma_gyro_bias_deg_h": 3.0, "gyro_bias_deg_h": 7.0},
     {"core_params": {"init_sigma_gyro_bias_deg_h": 3.0, "gyro_bias_deg_h": 7.0}}, "init_sigma_gyro_bias_deg_h"),
    # one range per field (its metadata): the node's descriptor and the offline validation refuse alike
    ("a hypothesis count outside its range", "liekf", {"unknown_heading_hypotheses": 40},
     {"unknown_heading_hypotheses": 40}, "unknown_heading_hypotheses"),
    ("a core parameter outside its range", "liekf", {"init_sigma_roll_deg": 200.0},
     {"core_params": {"init_sigma_roll_deg": 200.0}}, "init_sigma_roll_deg"),
]


def _node_refuses(monkeypatch, core, params) -> str:
    import rclpy
    from rclpy.parameter import Parameter

    from insalign_ros.nodes.alignment_node import AlignmentNode

    for k, v in isolated_ros_env(base={}).items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = None
    try:
        over = [Parameter("core", value=core)] + [Parameter(k, value=v) for k, v in params.items()]
        node = AlignmentNode(context=ctx, parameter_overrides=over, warm_up=False)
        return ""
    except (ValueError, TypeError, rclpy.exceptions.InvalidParameterValueException) as exc:
        return str(exc) or type(exc).__name__
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=ctx)


def _align_refuses(core, kwargs) -> str:
    try:
        ia.align("car", core=core, duration_s=3.0, **kwargs)
        return ""
    except (ValueError, TypeError) as exc:
        return str(exc) or type(exc).__name__


@pytest.mark.timeout(120)
@pytest.mark.parametrize("what,core,node_params,align_kwargs,word", TABLE, ids=[t[0] for t in TABLE])
def test_node_and_offline_refuse_the_same_configurations(monkeypatch, what, core, node_params, align_kwargs, word):
    node_reason = _node_refuses(monkeypatch, core, node_params)
    align_reason = _align_refuses(core, align_kwargs)
    if word is None:
        assert node_reason == align_reason == "", (node_reason, align_reason)
    else:  # both refuse, for the same reason: the same check (session/catalog.py, SessionConfig) said it
        assert word in node_reason and word in align_reason, (node_reason, align_reason)
