"""Real rclpy over real Fast DDS: two processes, isolated domain, localhost discovery, timeouts, no leftovers."""

import os
import tempfile
from pathlib import Path

import pytest

from insalign_ros.cli.demo import run_pub_sub

pytestmark = pytest.mark.ros


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie still answers kill(0); look at its state
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split()[2]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.timeout(90)
def test_100_imu_messages_cross_between_two_processes():
    log_dir = Path(tempfile.mkdtemp(prefix="insalign-dds-"))
    s = run_pub_sub(count=100, rate_hz=200.0, timeout_s=40.0, log_dir=log_dir)
    assert s["listener_rc"] == 0, (log_dir / "imu_listener_node.log").read_text()
    assert s["count"] == 100
    assert 1 <= s["domain_id"] <= 100
    # the values that crossed are the physics of a body at rest: |f| = gravity, |omega| = Earth rate
    assert abs(s["mean_f_norm_m_s2"] - 9.81) < 0.01
    assert abs(s["mean_omega_norm_rad_s"] - 7.292115e-5) < 1e-9
    assert abs(s["data_rate_hz"] - 200.0) < 1e-3  # stamps on the data-time grid (float64 of epoch stamps: ~1e-7 s)
    assert s["out_of_order"] == 0
    # both processes are gone (stopped or exited), nothing left behind
    assert not any(_pid_alive(pid) for pid in s["pids"]), s["pids"]
