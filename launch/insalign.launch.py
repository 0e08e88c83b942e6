"""Launch imu_sim_node (parameters from config/imu_sim.yaml) and imu_listener_node, for users with a ROS 2 Jazzy
install: `ros2 launch insalign_ros insalign.launch.py [rate_hz:=200.0]`. The test suite does not import this file
(launch is not on PyPI; it only checks that it parses); scripts/demo is the launch-free equivalent.
Argument: rate_hz (IMU rate [Hz], default 100.0)."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    share = get_package_share_directory("insalign_ros")
    config = os.path.join(share, "config")
    return LaunchDescription([
        DeclareLaunchArgument("rate_hz", default_value="100.0", description="IMU rate [Hz]"),
        Node(
            package="insalign_ros",
            executable="imu_sim_node",
            name="imu_sim_node",
            parameters=[
                os.path.join(config, "imu_sim.yaml"),
                {"rate_hz": ParameterValue(LaunchConfiguration("rate_hz"), value_type=float)},
            ],
            output="screen",
        ),
        Node(
            package="insalign_ros",
            executable="imu_listener_node",
            name="imu_listener_node",
            parameters=[{"timeout_s": 0.0, "report_period_s": 5.0}],  # run until Ctrl-C, log a count every 5 s
            output="screen",
        ),
    ])
