"""colcon (from PyPI) builds the ament_python package and installs what `ros2 run`/`ros2 launch` need."""

import ast
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from insalign_ros.cli.bringup import isolated_ros_env

ROOT = Path(__file__).resolve().parents[1]
COLCON = Path(sys.executable).with_name("colcon")


def console_scripts() -> list[str]:
    """Executable names of setup.py's CONSOLE_SCRIPTS list (read with ast: setup.py must not run here)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "CONSOLE_SCRIPTS" for t in node.targets):
            return [ast.literal_eval(e).split("=")[0].strip() for e in node.value.elts]
    raise AssertionError("setup.py has no CONSOLE_SCRIPTS list")


def test_pip_editable_install_puts_every_executable_on_the_venv_path():
    """scripts/env.sh runs `pip install -e .`: the nodes and tools are then plain commands in the venv's bin/."""
    names = console_scripts()
    assert {"imu_sim_node", "imu_listener_node", "insalign-demo"} <= set(names)
    bindir = Path(sys.executable).parent
    missing = [n for n in names if not os.access(bindir / n, os.X_OK)]
    assert not missing, f"not in {bindir}: {missing} (re-run scripts/env.sh after editing setup.py)"


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


LEFTOVERS = ("build", "install", "log")


@pytest.mark.timeout(240)
@pytest.mark.skipif(not COLCON.exists(), reason="colcon is not installed in this interpreter's environment")
def test_colcon_build_installs_nodes_config_and_launch(tmp_path):
    """colcon build straight from the repository, every colcon directory in tmp; the repo is left untouched."""
    before = {d for d in LEFTOVERS if (ROOT / d).exists()} | set(p.name for p in ROOT.glob("*.egg-info"))
    r = subprocess.run([str(COLCON), "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(ROOT),
                        "--packages-select", "insalign_ros",
                        "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=200, env=dict(os.environ))
    after = {d for d in LEFTOVERS if (ROOT / d).exists()} | set(p.name for p in ROOT.glob("*.egg-info"))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert after <= before, f"colcon left {sorted(after - before)} in the repository"
    assert "1 package finished" in r.stdout, r.stdout[-2000:]

    inst = tmp_path / "install" / "insalign_ros"
    lib = inst / "lib" / "insalign_ros"  # where `ros2 run insalign_ros <exe>` looks (setup.cfg)
    for exe in console_scripts():
        assert (lib / exe).is_file() and os.access(lib / exe, os.X_OK), sorted(p.name for p in lib.iterdir())
    share = inst / "share" / "insalign_ros"
    assert (share / "package.xml").read_bytes() == (ROOT / "package.xml").read_bytes()
    assert sorted(p.name for p in (share / "config").iterdir()) == sorted(p.name for p in (ROOT / "config").glob("*.yaml"))
    assert sorted(p.name for p in (share / "launch").iterdir()) == sorted(p.name for p in (ROOT / "launch").glob("*.py"))
    assert (inst / "share" / "ament_index" / "resource_index" / "packages" / "insalign_ros").is_file()
    # the Python package itself is installed where the colcon environment hooks put it on PYTHONPATH
    site = list(inst.glob("lib/python3*/site-packages"))
    assert site and (site[0] / "insalign_ros" / "core" / "lie.py").is_file()

    # the installed executable runs from the installed tree (not from the repo): a bad parameter is rejected
    env = isolated_ros_env(base=dict(os.environ, PYTHONPATH=str(site[0])))
    run = subprocess.run([str(lib / "imu_sim_node"), "--ros-args", "-p", "rate_hz:=-1.0"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "rate_hz must be in (0, 2000]" in run.stderr, run.stdout + run.stderr
