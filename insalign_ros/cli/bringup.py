"""Start ROS 2 node processes without `ros2 launch`: isolated DDS domain, inherited environment, timeouts.

Used by ``insalign-demo`` and by the tests. The ROS 2 PyPI wheels re-execute Python with an
``LD_LIBRARY_PATH``, so a child must inherit the environment whole: we only *add* variables.
Every child runs in its own process group so that it and anything it spawned can be stopped together.
"""

from __future__ import annotations

import fcntl
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path


def isolated_ros_env(domain_id: int | None = None, base: dict | None = None) -> dict:
    """The current environment plus a private ROS_DOMAIN_ID and localhost-only discovery.

    Domain ids 1..100 are used (Fast DDS derives UDP ports from the id; ids above ~101 collide with the
    ephemeral range on Linux). The id is drawn at random from this process's range (``domain_id_range``: under
    pytest-xdist the worker's own share of 1..100) among the ids no other process on this machine holds: each draw
    takes an exclusive lock on ``<tmp>/insalign_ros_domains/<id>.lock`` (:func:`hold_domain`) and keeps it until
    this process draws again or exits, so that test suites, benchmarks and demos running at the same time never
    share a domain (two runs of one suite drawing the same id made one test's monitor read another's node).
    """
    env = dict(os.environ if base is None else base)
    if domain_id is None:
        lo, hi = domain_id_range()
        ids = list(range(lo, hi + 1))
        random.Random(os.getpid() * 7919 + time.monotonic_ns()).shuffle(ids)
        domain_id = next((i for i in ids if hold_domain(i)), ids[0])  # all held: share one, as before the locks
    env["ROS_DOMAIN_ID"] = str(int(domain_id))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


_HELD_DOMAIN: list = []  # [(domain id, open lock file)]: the one domain this process holds


def hold_domain(domain_id: int) -> bool:
    """Take the machine-wide lock of ``domain_id`` for this process (releasing the one it held before); False when
    another process holds it. The lock is an ``flock`` on a file in the temporary directory: the kernel drops it
    when the process exits, however it exits."""
    if _HELD_DOMAIN and _HELD_DOMAIN[0][0] == domain_id:
        return True
    try:
        d = os.path.join(tempfile.gettempdir(), "insalign_ros_domains")
        os.makedirs(d, exist_ok=True)
        fh = open(os.path.join(d, f"{int(domain_id)}.lock"), "a")
    except OSError:  # no writable temporary directory: no lock, the random draw alone (as before the locks)
        return True
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        return False
    for _, old in _HELD_DOMAIN:
        old.close()  # closing the file releases its lock
    _HELD_DOMAIN[:] = [(int(domain_id), fh)]
    return True


def domain_id_range(env: dict | None = None) -> tuple[int, int]:
    """Inclusive range of ROS_DOMAIN_IDs this process may draw from: 1..100, or under pytest-xdist
    (PYTEST_XDIST_WORKER=gw<k>, PYTEST_XDIST_WORKER_COUNT=n) the k-th of n disjoint slices of 1..100."""
    env = os.environ if env is None else env
    worker, count = env.get("PYTEST_XDIST_WORKER", ""), env.get("PYTEST_XDIST_WORKER_COUNT", "")
    if not (worker.startswith("gw") and worker[2:].isdigit() and count.isdigit()):
        return 1, 100
    k, n = int(worker[2:]), int(count)
    if not 0 <= k < n <= 100:
        return 1, 100
    return 1 + k * 100 // n, (k + 1) * 100 // n


def ros_args(params: dict | None = None, remaps: dict | None = None, param_files: list | None = None) -> list[str]:
    """``--ros-args`` list for parameters (-p name:=value), remappings (-r from:=to) and YAML files."""
    out = ["--ros-args"]
    for path in param_files or []:
        out += ["--params-file", str(path)]
    for k, v in (params or {}).items():
        if isinstance(v, bool):
            v = "true" if v else "false"
        out += ["-p", f"{k}:={v}"]
    for k, v in (remaps or {}).items():
        out += ["-r", f"{k}:={v}"]
    return out


@dataclass
class NodeProcess:
    """A node running as a child process (module run with the current interpreter)."""

    name: str
    popen: subprocess.Popen
    log_path: Path | None = None
    started_s: float = field(default_factory=time.monotonic)

    def alive(self) -> bool:
        return self.popen.poll() is None

    def output(self) -> str:
        if self.log_path and self.log_path.exists():
            return self.log_path.read_text(errors="replace")
        return ""


def start_process(cmd: list[str], env: dict, name: str, log_dir: Path | None = None) -> NodeProcess:
    """Run ``cmd`` in its own process group (session) with ``env``; stdout+stderr go to ``log_dir/name.log``."""
    log_path = None
    if log_dir is not None:
        log_dir = Path(log_dir)
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{name}.log"
        out = open(log_path, "w")
    else:
        out = subprocess.DEVNULL
    try:
        popen = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    finally:
        if out is not subprocess.DEVNULL:
            out.close()  # the child holds its own descriptor
    return NodeProcess(name, popen, log_path)


def start_node(
    module: str,
    env: dict,
    params: dict | None = None,
    remaps: dict | None = None,
    param_files: list | None = None,
    log_dir: Path | None = None,
    name: str | None = None,
) -> NodeProcess:
    """Run ``python -m module --ros-args ...`` (this interpreter) in its own process group, logging to log_dir."""
    name = name or module.rsplit(".", 1)[-1]
    cmd = [sys.executable, "-m", module, *ros_args(params, remaps, param_files)]
    return start_process(cmd, env, name, log_dir)


def stop_nodes(nodes: list[NodeProcess], timeout_s: float = 5.0) -> None:
    """SIGINT each process group, wait up to timeout, then SIGKILL what is left. Never raises."""
    for node in nodes:
        if node.alive():
            try:
                os.killpg(node.popen.pid, signal.SIGINT)
            except (ProcessLookupError, PermissionError):
                pass
    deadline = time.monotonic() + timeout_s
    for node in nodes:
        remaining = max(0.1, deadline - time.monotonic())
        try:
            node.popen.wait(timeout=remaining)
        except subprocess.TimeoutExpired:
            pass
    for node in nodes:
        try:
            os.killpg(node.popen.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            node.popen.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            pass


def wait_for_exit(node: NodeProcess, timeout_s: float) -> int | None:
    """Return code of the node, or None if it is still running after timeout_s."""
    try:
        return node.popen.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None
