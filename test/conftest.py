"""Shared fixtures of the DDS tests; the full core registry for every test module."""

import fcntl
import json
import os
import tempfile

import pytest

import insalign_ros.session  # noqa: F401  registers the session-level core 'auto' (session/auto.py, imported by session/__init__.py), so
#                              tests parametrised over the registry see the same cores whatever is imported first


_WARMUP: dict = {}


def pytest_configure(config):
    """Under pytest-xdist (scripts/test): compile every core's numba kernels once, in the controller, before the
    workers start (``python -m insalign_ros.session.warmup --cores all``): with a cold cache (a fresh clone on an
    installed virtualenv) each worker would otherwise compile the same kernels inside its first tests, both at once
    (60-100 s each); with a warm cache this loads them in a few seconds. ``INSALIGN_TEST_WARMUP=0`` skips it.
    Tests of the cold start itself (test_first_run) use their own cache directories."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None) \
            or os.environ.get("INSALIGN_TEST_WARMUP", "1") == "0":
        return
    import time

    from insalign_ros.session.warmup import warm_up

    t0 = time.perf_counter()
    try:
        warm_up(("all",))
        _WARMUP["s"] = time.perf_counter() - t0
    except Exception as exc:  # noqa: BLE001 - the kernels then compile on first use, as without the warm-up
        _WARMUP["error"] = f"{type(exc).__name__}: {exc}"


def pytest_report_header(config):
    if "s" in _WARMUP:
        return f"numba kernels of every core warmed up before the workers started: {_WARMUP['s']:.1f} s"
    if "error" in _WARMUP:
        return f"numba warm-up failed ({_WARMUP['error']}): kernels compile on first use"
    return None


@pytest.fixture
def ros_env(monkeypatch):
    """A private ROS_DOMAIN_ID and localhost discovery for this test (and its in-process monitor)."""
    from insalign_ros.cli.bringup import isolated_ros_env

    env = isolated_ros_env()
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(k, env[k])
    return env


@pytest.fixture
def node_factory(monkeypatch):
    """``make(args)``: an AlignmentNode in its own rclpy context, started with the ROS arguments ``args`` (after
    ``--ros-args``), on a private ROS_DOMAIN_ID; every node and context made is destroyed after the test."""
    import rclpy

    from insalign_ros.cli.bringup import isolated_ros_env

    for k, v in isolated_ros_env(base={}).items():
        monkeypatch.setenv(k, v)
    made = []

    def make(args):
        from insalign_ros.nodes.alignment_node import AlignmentNode

        ctx = rclpy.Context()
        rclpy.init(args=["--ros-args", *args], context=ctx)
        made.append(ctx)
        node = AlignmentNode(context=ctx)
        made.append(node)
        return node

    make.made = made  # for fixtures built on this one (test_node_restart: a listener node in the same context)
    yield make
    for obj in reversed(made):
        if isinstance(obj, rclpy.Context):
            rclpy.shutdown(context=obj)
        else:
            obj.destroy_node()


def sim_summary(node) -> dict:
    """The SIM_SUMMARY JSON line imu_sim_node prints at exit ({} when absent)."""
    for line in reversed(node.output().splitlines()):
        if line.startswith("SIM_SUMMARY "):
            return json.loads(line[len("SIM_SUMMARY "):])
    return {}


@pytest.fixture(autouse=True)
def _wallclock_tests_run_alone(request):
    """Under pytest-xdist (scripts/test runs the suite on 2 workers) a test marked ``wallclock`` (it compares wall
    time with a budget) runs alone: it holds an exclusive lock that every other test holds shared, so no test of the
    other worker runs beside it. A turnstile lock keeps a waiting wallclock test from being starved by the other
    worker's next tests. Without xdist: nothing to do."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if not run:
        yield
        return
    base = os.path.join(tempfile.gettempdir(), f"insalign-pytest-{run}")
    exclusive = request.node.get_closest_marker("wallclock") is not None
    with open(base + ".turnstile", "a") as turn, open(base + ".lock", "a") as lock:
        fcntl.flock(turn, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        finally:
            fcntl.flock(turn, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
