"""Install honesty (issue 13 item 7): package.xml lists every runtime import, the launch file starts the node with
the node's defaults, scripts/env.sh refuses a Python the pins cannot install on, requirements-apt.txt (Ubuntu 24.04's
apt numpy 1.26 / scipy 1.11) covers requirements.txt, and the simulator runs without scipy >= 1.12."""

import ast
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

#: third-party top-level module -> its rosdep key in package.xml
ROSDEP = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "pymap3d": "python3-pymap3d",
    "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm", "numba": "python3-numba", "yaml": "python3-yaml",
    "cvxpy": "python3-cvxpy-pip", "rosbags": "python3-rosbags-pip",
}
#: optional runtime imports (lazy, an ImportError says how to install): no rosdep key; package.xml says so
OPTIONAL = {"distributed", "dask", "allantools"}  # eval/parallel.py imports the first two only when a parallel run
# is asked for; eval/allan.py imports allantools only for insalign-characterise
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "sensor_msgs", "geometry_msgs", "std_msgs", "std_srvs", "diagnostic_msgs",
                "rosgraph_msgs", "tf2_msgs", "nav_msgs"}  # tf2_msgs: not on PyPI; without it publish_tf warns (nodes/publishing.py)


def _runtime_imports() -> set:
    mods = set()
    for f in (ROOT / "insalign_ros").rglob("*.py"):
        for n in ast.walk(ast.parse(f.read_text())):
            if isinstance(n, ast.Import):
                mods |= {a.name.split(".")[0] for a in n.names}
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                mods.add(n.module.split(".")[0])
    return {m for m in mods if m not in sys.stdlib_module_names and m != "insalign_ros"}


def test_package_xml_lists_every_runtime_import():
    deps = {e.text for e in ET.parse(ROOT / "package.xml").getroot().findall("exec_depend")}
    imports = _runtime_imports()
    unknown = imports - set(ROSDEP) - ROS_PACKAGES - OPTIONAL
    xml = (ROOT / "package.xml").read_text()
    assert all(f"optional runtime import: {m}" in xml for m in OPTIONAL & imports)
    assert not unknown, f"new runtime import(s) {sorted(unknown)}: add the rosdep key to package.xml and ROSDEP here"
    missing = sorted(m for m in imports - OPTIONAL if (ROSDEP.get(m) or m) not in deps)
    assert not missing, f"package.xml lacks exec_depend for {missing}"
    assert {"pymap3d", "rcl_interfaces", "std_srvs", "diagnostic_msgs", "cvxpy", "rosbags", "numba"} <= imports


def _launch_defaults() -> dict:
    tree = ast.parse((ROOT / "launch" / "insalign.launch.py").read_text())
    out = {}
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "DeclareLaunchArgument":
            kw = {k.arg: ast.literal_eval(k.value) for k in n.keywords if k.arg == "default_value"}
            out[ast.literal_eval(n.args[0])] = kw["default_value"]
    return out


def test_launch_defaults_are_the_node_defaults():
    pytest.importorskip("rclpy", reason="reading alignment_node's parameter table needs rclpy (ROS 2)")
    from insalign_ros.nodes.alignment_node import NODE_PARAMS
    from insalign_ros.session.config import SessionConfig

    d = _launch_defaults()
    assert d["core"] == NODE_PARAMS["core"][0]
    assert d["init_from_ground_truth"] == str(NODE_PARAMS["init_from_ground_truth"][0]).lower() == "false"
    assert [float(x) for x in d["init_rpy_error_deg"].split(",")] == SessionConfig().init_rpy_error_deg
    assert d["imu_grade"] == NODE_PARAMS["imu_grade"][0] == SessionConfig().imu_grade


def test_env_sh_refuses_python_3_10_with_the_reason(tmp_path):
    fake = tmp_path / "python3.10"  # answers like CPython 3.10 to env.sh's two questions
    fake.write_text('#!/bin/sh\n[ "$1" = "--version" ] && { echo "Python 3.10.13"; exit 0; }\nexit 1\n')
    fake.chmod(0o755)
    venv = tmp_path / "venv"
    r = subprocess.run(["bash", "-c", f'source "{ROOT}/scripts/env.sh"'], capture_output=True, text=True, timeout=30,
                       env=dict(os.environ, PYTHON=str(fake), INSALIGN_VENV=str(venv)))
    assert r.returncode == 2, r.stderr
    assert "3.11" in r.stderr and "numpy==2.4.6" in r.stderr and "Python 3.10.13" in r.stderr, r.stderr
    assert not venv.exists()


def _pins(path: Path) -> dict:
    pins = {}
    for line in path.read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.-]+)==([^\s#;]+)", line)
        if m:
            pins[m.group(1).lower()] = m.group(2)
    return pins


def test_requirements_apt_keeps_apt_numpy_scipy_and_covers_the_rest():
    main, apt = _pins(ROOT / "requirements.txt"), _pins(ROOT / "requirements-apt.txt")
    assert apt["numpy"] == "1.26.4" and apt["scipy"] == "1.11.4"  # Ubuntu 24.04 python3-numpy / python3-scipy
    not_apt = {n for n in main if n.startswith("ros-jazzy-") or n.startswith("colcon") or n == "setuptools"}
    assert set(main) - not_apt == set(apt), sorted((set(main) - not_apt) ^ set(apt))


def test_cumulative_simpson_without_scipy_1_12():
    """The car path integral works on scipy 1.11: exact for a cubic (Simpson), equal to scipy's cumulative_simpson at
    the even nodes when that exists (scipy >= 1.12)."""
    from insalign_ros.sim.scenarios import cumulative_simpson_even_nodes

    x = np.linspace(0.0, 3.0, 61)
    y = np.stack([3 * x**2 - 2 * x + 1, np.cos(x)])
    got = cumulative_simpson_even_nodes(y, x)
    xe = x[::2]
    np.testing.assert_allclose(got[0], xe**3 - xe**2 + xe, rtol=0, atol=1e-12)
    h = x[1] - x[0]
    assert np.max(np.abs(got[1] - np.sin(xe))) < 3.0 * h**4 / 180  # Simpson's error bound, |f''''| <= 1, L = 3
    with pytest.raises(ValueError, match="uniform"):
        cumulative_simpson_even_nodes(x**2, x**2)
    try:
        from scipy.integrate import cumulative_simpson
    except ImportError:
        pytest.skip(f"scipy {__import__('scipy').__version__} has no cumulative_simpson (>= 1.12): closed forms only")
    ref = cumulative_simpson(y, x=x, initial=0.0)[:, ::2]
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)
