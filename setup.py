"""ament_python package definition: works with colcon (ROS 2 Jazzy) and with pip (PyPI wheels of ROS)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "insalign_ros"

# Executables that `ros2 run insalign_ros <name>` finds (installed under lib/insalign_ros by setup.cfg)
# and command-line tools. One list, so colcon and pip install the same things.
CONSOLE_SCRIPTS = [
    "imu_sim_node = insalign_ros.nodes.imu_sim_node:main",
    "imu_listener_node = insalign_ros.nodes.imu_listener_node:main",
    "insalign-demo = insalign_ros.cli.demo:main",
    "alignment_node = insalign_ros.nodes.alignment_node:main",
    "insalign-simulate = insalign_ros.cli.simulate:main",
    "insalign-kitti2bag = insalign_ros.cli.kitti2bag:main",
    "insalign-import = insalign_ros.cli.import_data:main",
    "insalign-align = insalign_ros.cli.align:main",
    "insalign-characterise = insalign_ros.cli.characterise:main",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, PACKAGE + ".*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml")),
        ("share/" + PACKAGE + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="insalign_ros developers",
    maintainer_email="insalign@example.invalid",
    description="Strapdown INS initial alignment (LIEKF, PI-LIEKF, IEKF, EKF, PKF, backtracking) for ROS 2 Jazzy",
    license="Apache-2.0",
    extras_require={"test": ["pytest"]},
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
