"""The numerical core must not import rclpy (it runs offline, in CI without DDS, and in other frameworks)."""

import subprocess
import sys

CORE_PACKAGES = ["insalign_ros.core", "insalign_ros.filters", "insalign_ros.sim", "insalign_ros.io", "insalign_ros.eval"]


def test_importing_the_core_does_not_import_rclpy():
    code = (
        "import importlib, pkgutil, sys\n"
        f"for name in {CORE_PACKAGES!r}:\n"
        "    pkg = importlib.import_module(name)\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, name + '.'):\n"
        "        importlib.import_module(m.name)\n"
        "bad = sorted(k for k in sys.modules if k.split('.')[0] in ('rclpy', 'rosidl_runtime_py', 'rpyutils'))\n"
        "print('LOADED', len(sys.modules)); print('BAD', bad)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def test_the_check_itself_detects_rclpy():
    """Guard against a vacuous test: importing a node module does pull rclpy in."""
    code = "import sys, insalign_ros.nodes.imu_sim_node; sys.exit(0 if 'rclpy' in sys.modules else 1)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
