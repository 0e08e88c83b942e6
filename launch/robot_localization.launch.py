"""Launch alignment_node with robot_localization (docs/robot_localization.md), on real drivers' topics:

    ros2 launch insalign_ros robot_localization.launch.py imu_topic:=/imu/data_raw fix_topic:=/ublox/fix
        [core:=auto] [imu_grade:=industrial_mems] [imu_axes:=flu|frd] [rl_params_file:=/path/to/my_rl.yaml]

Starts alignment_node (as alignment.launch.py: same arguments), robot_localization's ``ekf_node`` (name
``ekf_filter_node``) and ``navsat_transform_node`` (name ``navsat_transform``) with config/robot_localization.yaml
(or ``rl_params_file``). navsat_transform takes the heading from ``alignment_node/imu``, which the node publishes only
once aligned, and the fixes from ``fix_topic``; the EKF fuses ``alignment_node/imu`` (attitude, rates) and
navsat_transform's ``odometry/gps``. Needs ``ros-jazzy-robot-localization``. test/test_launch_files.py checks this
file's syntax and defaults (launch is not on PyPI).
"""

import importlib.util
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _alignment_launch():
    """alignment.launch.py, next to this file: its arguments and its alignment_node."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "alignment.launch.py")
    spec = importlib.util.spec_from_file_location("insalign_alignment_launch", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _nodes(context):
    share = get_package_share_directory("insalign_ros")
    rl_params = LaunchConfiguration("rl_params_file").perform(context) or os.path.join(
        share, "config", "robot_localization.yaml")
    fix_topic = LaunchConfiguration("fix_topic").perform(context)
    ns = LaunchConfiguration("namespace").perform(context)
    imu_out = f"/{ns.strip('/')}/alignment_node/imu" if ns.strip("/") else "/alignment_node/imu"
    use_sim_time = LaunchConfiguration("use_sim_time").perform(context).lower() == "true"
    return [
        # the alignment block of the same file (publish_imu_before_aligned false, publish_tf false, frames)
        _alignment_launch().alignment_node(context, extra_files=[rl_params]),
        Node(package="robot_localization", executable="ekf_node", name="ekf_filter_node", output="screen",
             parameters=[rl_params, {"use_sim_time": use_sim_time}],
             remappings=[("alignment_node/imu", imu_out)]),
        Node(package="robot_localization", executable="navsat_transform_node", name="navsat_transform",
             output="screen", parameters=[rl_params, {"use_sim_time": use_sim_time}],
             remappings=[("imu", imu_out), ("gps/fix", fix_topic), ("odometry/filtered", "odometry/filtered")]),
    ]


def generate_launch_description():
    return LaunchDescription([
        *_alignment_launch().arguments(),
        DeclareLaunchArgument("rl_params_file", default_value="",
                              description="robot_localization parameters (default: config/robot_localization.yaml)"),
        OpaqueFunction(function=_nodes),
    ])
