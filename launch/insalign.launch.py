"""Launch imu_sim_node and alignment_node for users with a ROS 2 Jazzy install (`ros2 launch insalign_ros
insalign.launch.py`). The test suite does not import this file (launch is not on PyPI); scripts/demo is the
launch-free equivalent. Arguments: core (alignment core), rate_factor, use_sim_time."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory("insalign_ros")
    config = os.path.join(share, "config")
    return LaunchDescription([
        DeclareLaunchArgument("rate_hz", default_value="100.0", description="IMU rate [Hz]"),
        Node(
            package="insalign_ros",
            executable="imu_sim_node",
            name="imu_sim_node",
            parameters=[os.path.join(config, "imu_sim.yaml"), {"rate_hz": LaunchConfiguration("rate_hz")}],
            output="screen",
        ),
        Node(
            package="insalign_ros",
            executable="imu_listener_node",
            name="imu_listener_node",
            output="screen",
        ),
    ])
