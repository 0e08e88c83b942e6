"""Parameters a ROS user can trust (issue 26 item 5, issue 27 item 6; docs/nodes.md "Parameters"): every numeric
parameter of every core has a range in its descriptor, every out-of-range or ill-typed value is refused by the node's
validation function with one line naming the parameter, its value and its range (generated over every numeric
parameter, in-process), a real start with such a value prints that one line and exits 2 (subprocesses), unknown
parameters and another core's parameters are warned at start, an int for a double stays a double.
"""

import math

import pytest

from insalign_ros.cli.bringup import isolated_ros_env

pytestmark = pytest.mark.ros


def _numeric_parameters() -> dict:
    """name -> every default the node may declare it with (node, session, aligned flag, each core under each grade)."""
    from insalign_ros.nodes.params import NODE_PARAMS, SESSION_DOC, is_numeric
    from insalign_ros.session import catalog
    from insalign_ros.session.config import SessionConfig
    from insalign_ros.session.flag import AlignedCriteria

    out: dict = {}

    def add(name, value):
        if is_numeric(value):
            out.setdefault(name, set()).add(value)

    for name, (default, _, _) in NODE_PARAMS.items():
        add(name, default)
    for name, value in SessionConfig().to_dict().items():
        if name in SESSION_DOC:
            add(name, value)
    for name, value in AlignedCriteria().to_dict().items():
        add(f"aligned.{name}", value)
    for core in catalog.core_names():
        for name, value in catalog.core_defaults(core).items():
            add(name, value)
        for grade in catalog.GRADES:
            for name, value in catalog.grade_defaults(grade, core).items():
                add(name, value)
    return out


NUMERIC = _numeric_parameters()


def test_the_table_covers_every_numeric_parameter():
    from insalign_ros.nodes.params import RANGES

    assert len(NUMERIC) >= 80, len(NUMERIC)
    typed = {n: {type(v) for v in vs} for n, vs in NUMERIC.items()}
    assert all(len(t) == 1 for t in typed.values()), {n: t for n, t in typed.items() if len(t) > 1}
    ints = sorted(n for n, t in typed.items() if int in t)
    assert set(ints) <= set(RANGES), set(ints) - set(RANGES)  # every integer has its own range


@pytest.mark.parametrize("name", sorted(NUMERIC))
def test_every_numeric_parameter_has_a_range_and_bad_values_are_one_line(name):
    from insalign_ros.nodes.params import check_value, descriptor, range_of

    defaults = NUMERIC[name]
    default = next(iter(defaults))
    lo, hi = range_of(name, default)
    d = descriptor(name, default, "text", False)
    if isinstance(default, float):
        r = d.floating_point_range[0]
        assert (r.from_value, r.to_value) == (lo, hi) and not d.integer_range
    else:
        r = d.integer_range[0]
        assert (r.from_value, r.to_value) == (lo, hi) and not d.floating_point_range
    for v in defaults:  # every default of every core and grade is inside the range
        assert check_value(name, default, v) == v and type(check_value(name, default, v)) is type(default)
    bad = [hi * 2 + 1 if math.isfinite(hi) else None, lo - 1 - abs(lo), "abc", True, [1.0]]
    if isinstance(default, float):
        bad += [math.nan, -math.inf]
    for v in bad:
        if v is None:
            continue
        with pytest.raises(ValueError) as exc:
            check_value(name, default, v)
        text = str(exc.value)
        assert "\n" not in text and text.startswith(f"{name}: "), text
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            assert repr(type(default)(v) if math.isfinite(v) else v) in text and f"range [{lo:g}, {hi:g}]" in text, text
        else:
            assert "wrong type" in text and repr(v) in text, text
    ints = [k for k in (1, int(math.ceil(lo))) if lo <= k <= hi]
    if isinstance(default, float) and ints:  # an int for a double stays a double
        assert type(check_value(name, default, ints[0])) is float


def test_arrays_int_for_double_and_other_types():
    from insalign_ros.nodes.params import check_value

    assert check_value("imu_mount_rpy_deg", [0.0, 0.0, 0.0], [0, 0, 90]) == [0.0, 0.0, 90.0]
    assert all(type(x) is float for x in check_value("imu_mount_rpy_deg", [0.0, 0.0, 0.0], [0, 0, 90]))
    with pytest.raises(ValueError, match="imu_mount_rpy_deg: wrong type"):
        check_value("imu_mount_rpy_deg", [0.0, 0.0, 0.0], ["a", "b", "c"])
    with pytest.raises(ValueError, match="world_frame: wrong type"):
        check_value("world_frame", "map", 3)


def test_unknown_and_other_core_parameters_are_named():
    from insalign_ros.nodes.params import unknown_parameters

    lines = unknown_parameters(["yaw_hypotheses", "gnss_sigmaa_m", "use_sim_time", "core"], ["core", "use_sim_time"],
                               "auto")
    assert len(lines) == 2, lines
    assert "unknown parameter 'gnss_sigmaa_m'" in lines[0]
    assert "'yaw_hypotheses' is not a parameter of core 'auto'" in lines[1] and "iekf" in lines[1]


@pytest.mark.timeout(120)
def test_a_started_node_warns_unknown_parameters_and_keeps_doubles(node_factory, capfd):
    from rclpy.parameter import Parameter

    node = node_factory(["-p", "yaw_hypotheses:=3", "-p", "gnss_sigmaa_m:=2.0", "-p", "imu_mount_rpy_deg:=[0,0,90]",
                         "-p", "gnss_sigma_m:=2", "-p", "aligned.hold_s:=3"])
    err = capfd.readouterr().err
    assert "'yaw_hypotheses' is not a parameter of core 'auto'" in err and "unknown parameter 'gnss_sigmaa_m'" in err
    for name, want in (("gnss_sigma_m", 2.0), ("aligned.hold_s", 3.0)):
        prm = node.get_parameter(name)
        assert prm.type_ == Parameter.Type.DOUBLE and prm.value == want, (name, prm.type_)
    prm = node.get_parameter("imu_mount_rpy_deg")
    assert prm.type_ == Parameter.Type.DOUBLE_ARRAY and list(prm.value) == [0.0, 0.0, 90.0]
    # at run time: an int for a double is taken and the parameter stays a double
    assert node.set_parameters([Parameter("gnss_sigma_m", value=3)])[0].successful
    prm = node.get_parameter("gnss_sigma_m")
    assert prm.type_ == Parameter.Type.DOUBLE and prm.value == 3.0 and node.params["gnss_sigma_m"] == 3.0
    res = node.set_parameters([Parameter("gnss_sigma_m", value=-1.0)])[0]
    assert not res.successful and "gnss_sigma_m" in res.reason and node.params["gnss_sigma_m"] == 3.0


@pytest.mark.timeout(120)
@pytest.mark.parametrize("name, value, shown", [("max_gap_s", "1e-6", "1e-06"), ("imu_timeout_s", ".nan", "nan"),
                                                ("gnss_sigma_m", "-1.0", "-1.0"), ("yaw_hypotheses", "0", "0")])
def test_a_bad_start_up_value_is_one_line_and_exit_2(tmp_path, name, value, shown):
    from insalign_ros.cli.bringup import start_node, wait_for_exit

    params = {name: value}
    if name == "yaw_hypotheses":
        params["core"] = "iekf"
    node = start_node("insalign_ros.nodes.alignment_node", isolated_ros_env(), log_dir=tmp_path, params=params)
    assert wait_for_exit(node, 60.0) == 2
    lines = [ln for ln in node.output().splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"alignment_node: bad parameter: {name}: value {shown}") and "range [" in lines[0], lines
