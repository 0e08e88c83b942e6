"""Launch files and the robot_localization example, checked by syntax (the ``launch`` package is not on PyPI):
every launch file parses, declares literal defaults and names configuration files that exist (for every core);
config/robot_localization.yaml is a ROS 2 parameter file whose node names are the launch file's."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = sorted((ROOT / "launch").glob("*.launch.py"))
RL_YAML = ROOT / "config" / "robot_localization.yaml"


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def _declared(tree: ast.Module) -> dict[str, str]:
    """DeclareLaunchArgument(name, default_value=...) -> {name: default} (literals only, as launch needs strings)."""
    out = {}
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "DeclareLaunchArgument":
            name = ast.literal_eval(n.args[0])
            kw = {k.arg: k.value for k in n.keywords}
            assert name not in out, f"argument {name} declared twice"
            out[name] = ast.literal_eval(kw["default_value"])
            assert isinstance(out[name], str), (name, out[name])
            assert "description" in kw, f"argument {name} has no description"
    return out


def _literal(tree: ast.Module, name: str):
    for n in tree.body:
        if isinstance(n, ast.Assign) and any(getattr(t, "id", None) == name for t in n.targets):
            return ast.literal_eval(n.value)
    raise KeyError(name)


def _node_names(tree: ast.Module) -> dict[str, str]:
    """Node(package=..., executable=..., name=...) -> {name: executable}."""
    out = {}
    for n in ast.walk(tree):
        if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Node":
            kw = {k.arg: k.value for k in n.keywords}
            out[ast.literal_eval(kw["name"])] = ast.literal_eval(kw["executable"])
    return out


def test_the_launch_files_are_there_and_installed():
    names = {p.name for p in LAUNCH}
    assert {"insalign.launch.py", "alignment.launch.py", "robot_localization.launch.py"} <= names
    setup = (ROOT / "setup.py").read_text()
    assert 'glob("launch/*.py")' in setup and 'glob("config/*.yaml")' in setup


@pytest.mark.parametrize("path", LAUNCH, ids=lambda p: p.name)
def test_launch_file_parses_and_declares_literal_defaults(path):
    tree = _tree(path)
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    d = _declared(tree)
    if path.name == "robot_localization.launch.py":  # the alignment arguments come from alignment.launch.py
        d |= _declared(_tree(path.parent / "alignment.launch.py"))
    assert d["core"] == "auto" and d["imu_grade"] == "unknown_mems"
    for n in ast.walk(tree):  # every file name a launch file spells out exists
        if (isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value.endswith((".yaml", ".launch.py"))
                and not n.value.startswith(".")):  # (".yaml" alone: the tail of f"{core}.yaml")
            where = ROOT / ("launch" if n.value.endswith(".py") else "config") / n.value
            assert where.exists(), f"{path.name} names {n.value}, which does not exist"


@pytest.mark.parametrize("name", ["insalign.launch.py", "alignment.launch.py"])
def test_every_core_has_its_config_file_in_the_launch(name):
    """core:=<any core> loads config/<core>.yaml or the file CORE_CONFIG names (issue 26: liekf_backtrack had none)."""
    from insalign_ros.filters.registry import CORES

    mapping = _literal(_tree(ROOT / "launch" / name), "CORE_CONFIG")
    for core in {"auto", *CORES}:
        f = ROOT / "config" / mapping.get(core, f"{core}.yaml")
        assert f.exists(), f"{name}: core:={core} -> {f.name} missing"
        block = yaml.safe_load(f.read_text())["/**"]["ros__parameters"]
        assert block.get("core") in (core, "liekf" if core == "liekf_backtrack" else core)


def test_alignment_launch_remaps_the_driver_topics():
    tree = _tree(ROOT / "launch" / "alignment.launch.py")
    src = ast.unparse(tree)
    for topic, arg in (("imu/data", "imu_topic"), ("gps/fix", "fix_topic"), ("gps/vel", "vel_topic")):
        assert f"('{topic}', arg('{arg}'))" in src, topic
    assert "imu_sim_node" not in src  # real drivers: no simulator
    d = _declared(tree)
    assert d["imu_topic"] == "/imu/data" and d["fix_topic"] == "/gps/fix"


def _ros_value_ok(v) -> bool:
    """A ROS 2 parameter value: bool, int, float, str, or a homogeneous list of one of them."""
    if isinstance(v, (bool, int, float, str)):
        return True
    if isinstance(v, list) and v:
        kinds = {bool if isinstance(x, bool) else float if isinstance(x, (int, float)) else type(x) for x in v}
        return len(kinds) == 1 and kinds <= {bool, float, str} and (
            kinds != {float} or len({type(x) for x in v}) == 1)  # ints and doubles do not mix in one array
    return False


def test_robot_localization_yaml_is_a_ros_parameter_file():
    doc = yaml.safe_load(RL_YAML.read_text())
    assert isinstance(doc, dict) and doc
    for node, block in doc.items():
        assert node == "/**" or node.replace("_", "").isalnum(), node
        assert list(block) == ["ros__parameters"], (node, list(block))
        for k, v in block["ros__parameters"].items():
            assert _ros_value_ok(v), (node, k, v)
    ekf = doc["ekf_filter_node"]["ros__parameters"]
    assert ekf["imu0"] == "alignment_node/imu" and ekf["odom0"] == "odometry/gps"
    for key in ("imu0_config", "odom0_config"):
        assert len(ekf[key]) == 15 and all(isinstance(x, bool) for x in ekf[key])
    assert ekf["imu0_config"][3:6] == [True, True, True]  # the aligned attitude
    assert ekf["odom0_config"][:2] == [True, True] and ekf["odom0_differential"] is False
    assert isinstance(ekf["two_d_mode"], bool)
    nav = doc["navsat_transform"]["ros__parameters"]
    assert nav["yaw_offset"] == 0.0 and nav["magnetic_declination_radians"] == 0.0  # ENU yaw from true East
    assert nav["use_odometry_yaw"] is False
    al = doc["alignment_node"]["ros__parameters"]
    assert al["publish_imu_before_aligned"] is False and al["publish_tf"] is False


def test_robot_localization_launch_starts_the_nodes_of_the_yaml():
    tree = _tree(ROOT / "launch" / "robot_localization.launch.py")
    nodes = _node_names(tree)
    assert nodes == {"ekf_filter_node": "ekf_node", "navsat_transform": "navsat_transform_node"}
    doc = yaml.safe_load(RL_YAML.read_text())
    assert set(nodes) | {"alignment_node"} == set(doc)
    assert "robot_localization.yaml" in ast.unparse(tree)


def test_robot_localization_yaml_sets_only_parameters_the_node_has():
    pytest.importorskip("rclpy", reason="the node's parameter table imports rclpy (ROS 2)")
    try:
        from insalign_ros.nodes.params import NODE_PARAMS
    except ImportError:
        from insalign_ros.nodes.alignment_node import NODE_PARAMS
    if "publish_imu_before_aligned" not in NODE_PARAMS:
        pytest.skip("this alignment_node has no ~/imu gating parameters yet (issue 26)")
    al = yaml.safe_load(RL_YAML.read_text())["alignment_node"]["ros__parameters"]
    assert set(al) <= set(NODE_PARAMS), set(al) - set(NODE_PARAMS)
