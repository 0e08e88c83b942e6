"""Shared fixtures of the DDS tests; the full core registry for every test module."""

import fcntl
import json
import os
import tempfile

import pytest

import insalign_ros.session  # noqa: F401  registers the session-level core 'auto' (session/auto.py, imported by session/__init__.py), so
#                              tests parametrised over the registry see the same cores whatever is imported first


@pytest.fixture
def ros_env(monkeypatch):
    """A private ROS_DOMAIN_ID and localhost discovery for this test (and its in-process monitor)."""
    from insalign_ros.cli.bringup import isolated_ros_env

    env = isolated_ros_env()
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(k, env[k])
    return env


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
