"""colcon (from PyPI) builds the ament_python package and installs what `ros2 run`/`ros2 launch` need."""

import ast
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COLCON = Path(sys.executable).with_name("colcon")


def test_package_xml_is_format3_ament_python_with_the_runtime_deps():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == "insalign_ros"
    assert root.find("export/build_type").text == "ament_python"
    deps = {e.text for e in root.findall("exec_depend")}
    for dep in ["rclpy", "sensor_msgs", "geometry_msgs", "std_msgs", "diagnostic_msgs", "python3-numpy", "python3-scipy"]:
        assert dep in deps, dep


def test_launch_files_are_valid_python():
    files = list((ROOT / "launch").glob("*.launch.py"))
    assert files
    for f in files:
        tree = ast.parse(f.read_text())
        names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert "generate_launch_description" in names, f


@pytest.mark.timeout(240)
@pytest.mark.skipif(not COLCON.exists(), reason="colcon is not installed in this interpreter's environment")
def test_colcon_build_installs_nodes_config_and_launch(tmp_path):
    src = tmp_path / "ws" / "src" / "insalign_ros"
    src.parent.mkdir(parents=True)
    # copy the package as a user's workspace would hold it (no venv, no caches)
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".venv", ".git", "__pycache__", "*.egg-info", "build",
                                                            "install", "log", ".pytest_cache", "out"))
    ws = tmp_path / "ws"
    r = subprocess.run([str(COLCON), "--log-base", str(ws / "log"), "build", "--base-paths", str(ws / "src"),
                        "--build-base", str(ws / "build"), "--install-base", str(ws / "install")],
                       cwd=ws, capture_output=True, text=True, timeout=200, env=dict(os.environ))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    inst = ws / "install" / "insalign_ros"
    lib = inst / "lib" / "insalign_ros"
    for exe in ["imu_sim_node", "imu_listener_node"]:
        assert (lib / exe).is_file() and os.access(lib / exe, os.X_OK), sorted(p.name for p in lib.iterdir())
    share = inst / "share" / "insalign_ros"
    assert (share / "package.xml").is_file()
    assert list((share / "config").glob("*.yaml"))
    assert list((share / "launch").glob("*.launch.py"))
    assert (inst / "share" / "ament_index" / "resource_index" / "packages" / "insalign_ros").is_file()
    # the Python package itself is installed where the setup hooks put it on PYTHONPATH
    assert list(inst.glob("lib/python3*/site-packages/insalign_ros/core/lie.py"))
