"""Launch imu_sim_node and alignment_node, for users with a ROS 2 Jazzy install:

    ros2 launch insalign_ros insalign.launch.py [core:=auto|iekf|...] [scenario:=ship] [rate_factor:=1.0]
        [source:=scenario|bag] [bag_path:=/path/to/bag] [init_from_ground_truth:=true] [init_rpy_error_deg:=...]
        [imu_grade:=unknown_mems|paper_ship|industrial_mems|...]

The alignment node starts with its own defaults (core auto, no ground-truth initialisation: what works on a real
recording without truth); ``init_from_ground_truth:=true`` (a simulated scenario or a bag with truth) initialises from
the truth plus ``init_rpy_error_deg``. test/test_install_honesty.py checks these defaults against the node's.

Parameters come from config/imu_sim.yaml, config/alignment_node.yaml and the core's file (config/<core>.yaml;
``liekf_backtrack`` shares config/liekf.yaml, a core without a file runs on its defaults; installed under
share/insalign_ros/config), then the launch arguments. The simulator starts publishing once the alignment node has
subscribed, which it does when its kernels are compiled (a minute or more on a cold numba cache).
For real drivers (no simulator, topic remapping) see alignment.launch.py and robot_localization.launch.py. The test suite does not import this file (launch is not on
PyPI; a test only parses it); ``insalign-demo`` is the launch-free equivalent. Set ``use_sim_time:=true`` to run
the alignment node on the simulator's /clock.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


#: core -> its parameter file in config/ when not <core>.yaml (test/test_launch_files.py checks every core)
CORE_CONFIG = {"liekf_backtrack": "liekf.yaml"}


def core_config(config_dir: str, core: str) -> list:
    """[config/<core>.yaml] (or the file the core shares), [] when the core has none: its defaults apply."""
    path = os.path.join(config_dir, CORE_CONFIG.get(core, f"{core}.yaml"))
    return [path] if os.path.exists(path) else []


def _nodes(context):
    share = get_package_share_directory("insalign_ros")
    config = os.path.join(share, "config")
    arg = lambda name: LaunchConfiguration(name).perform(context)  # noqa: E731
    core = arg("core")
    use_sim_time = arg("use_sim_time").lower() == "true"
    err = [float(x) for x in arg("init_rpy_error_deg").split(",")]
    return [
        Node(
            package="insalign_ros", executable="imu_sim_node", name="imu_sim_node", output="screen",
            parameters=[os.path.join(config, "imu_sim.yaml"),
                        {"source": arg("source"), "scenario": arg("scenario"), "bag_path": arg("bag_path"),
                         "rate_factor": float(arg("rate_factor")), "seed": int(arg("seed")),
                         "wait_for_subscribers": 1, "wait_timeout_s": 600.0}],
        ),
        Node(
            package="insalign_ros", executable="alignment_node", name="alignment_node", output="screen",
            parameters=[os.path.join(config, "alignment_node.yaml"), *core_config(config, core),
                        {"core": core, "imu_grade": arg("imu_grade"), "use_sim_time": use_sim_time,
                         "init_from_ground_truth": arg("init_from_ground_truth").lower() == "true",
                         "init_rpy_error_deg": err}],
        ),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("core", default_value="auto", description="alignment core (config/<core>.yaml)"),
        DeclareLaunchArgument("source", default_value="scenario", description="scenario | bag"),
        DeclareLaunchArgument("scenario", default_value="ship", description="ship | car | static | two_position"),
        DeclareLaunchArgument("bag_path", default_value="", description="contract rosbag2 for source:=bag"),
        DeclareLaunchArgument("seed", default_value="0", description="scenario seed"),
        DeclareLaunchArgument("rate_factor", default_value="1.0", description="1.0 = real time"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="alignment_node on /clock"),
        DeclareLaunchArgument("init_from_ground_truth", default_value="false",
                              description="initialise from ground_truth/pose plus init_rpy_error_deg (needs truth)"),
        DeclareLaunchArgument("init_rpy_error_deg", default_value="0.0,0.0,0.0",
                              description="roll,pitch,yaw error added to the truth [deg]"),
        DeclareLaunchArgument("imu_grade", default_value="unknown_mems",
                              description="IMU noise model (docs/imu_grades.md); the simulated ship: paper_ship"),
        OpaqueFunction(function=_nodes),
    ])
