"""Shared fixtures of the DDS tests; the full core registry for every test module."""

import json

import pytest

import insalign_ros.session  # noqa: F401  registers the session-level core 'auto' (filters/registry.LAZY_CORES), so
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
