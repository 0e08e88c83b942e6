"""Launch alignment_node alone, on real drivers' topics (no simulator), for users with a ROS 2 Jazzy install:

    ros2 launch insalign_ros alignment.launch.py imu_topic:=/imu/data_raw fix_topic:=/ublox/fix
        [core:=auto] [imu_grade:=industrial_mems] [imu_axes:=flu|frd] [imu_mount_rpy_deg:=0.0,0.0,0.0]
        [params_file:=/path/to/my.yaml] [use_sim_time:=false] [namespace:=]

The node subscribes to ``imu/data`` (sensor_msgs/Imu) and ``gps/fix`` (sensor_msgs/NavSatFix); ``imu_topic`` and
``fix_topic`` remap them to the drivers' topics (``vel_topic`` the GNSS velocity, if any). It compiles its kernels,
logs ``ready``, then subscribes (docs/install.md, "First run"). Parameters: config/alignment_node.yaml, the core's
file (config/<core>.yaml), ``params_file`` if given, then the arguments. robot_localization.launch.py adds
robot_localization's EKF and navsat_transform (docs/robot_localization.md). test/test_launch_files.py checks this
file's syntax and that its defaults name existing configuration files (launch is not on PyPI).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

#: core -> its parameter file in config/ when not <core>.yaml (as insalign.launch.py)
CORE_CONFIG = {"liekf_backtrack": "liekf.yaml"}


def core_config(config_dir: str, core: str) -> list:
    path = os.path.join(config_dir, CORE_CONFIG.get(core, f"{core}.yaml"))
    return [path] if os.path.exists(path) else []


def alignment_node(context, extra_files=()) -> Node:
    config = os.path.join(get_package_share_directory("insalign_ros"), "config")
    arg = lambda name: LaunchConfiguration(name).perform(context)  # noqa: E731
    core = arg("core")
    files = [os.path.join(config, "alignment_node.yaml"), *core_config(config, core), *extra_files]
    if arg("params_file"):
        files.append(arg("params_file"))
    mount = [float(x) for x in arg("imu_mount_rpy_deg").split(",")]
    return Node(
        package="insalign_ros", executable="alignment_node", name="alignment_node", namespace=arg("namespace"),
        output="screen",
        parameters=[*files, {"core": core, "imu_grade": arg("imu_grade"), "imu_axes": arg("imu_axes"),
                             "imu_mount_rpy_deg": mount, "use_sim_time": arg("use_sim_time").lower() == "true"}],
        remappings=[("imu/data", arg("imu_topic")), ("gps/fix", arg("fix_topic")), ("gps/vel", arg("vel_topic"))],
    )


def arguments() -> list:
    return [
        DeclareLaunchArgument("imu_topic", default_value="/imu/data", description="the IMU driver's sensor_msgs/Imu"),
        DeclareLaunchArgument("fix_topic", default_value="/gps/fix", description="the GNSS driver's NavSatFix"),
        DeclareLaunchArgument("vel_topic", default_value="/gps/vel",
                              description="GNSS velocity, TwistWithCovarianceStamped ENU (optional)"),
        DeclareLaunchArgument("core", default_value="auto", description="alignment core (config/<core>.yaml)"),
        DeclareLaunchArgument("imu_grade", default_value="unknown_mems",
                              description="IMU noise model (docs/imu_grades.md)"),
        DeclareLaunchArgument("imu_axes", default_value="flu", description="flu (REP 103) or frd"),
        DeclareLaunchArgument("imu_mount_rpy_deg", default_value="0.0,0.0,0.0",
                              description="IMU mounting roll,pitch,yaw in the vehicle frame [deg]"),
        DeclareLaunchArgument("params_file", default_value="", description="an extra parameter file (loaded last)"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="run on /clock (bag replay)"),
    ]


def generate_launch_description():
    return LaunchDescription([*arguments(), OpaqueFunction(function=lambda context: [alignment_node(context)])])
