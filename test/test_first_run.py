"""The first run: numba's kernel cache where an installed, read-only package can write it (docs/install.md).

A copy of the package is made read-only (as a colcon ``install/`` or a system site-packages) and warmed up in a
subprocess whose ``XDG_CACHE_HOME`` is a temporary directory: the kernels must be cached there, and a second process
must load every kernel from that cache (numba's dispatcher statistics: hits, no misses) and write no new cache file.
As root, file permissions do not bind: the subprocess runs without CAP_DAC_OVERRIDE (``setpriv``) so that they do.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: the subprocess: import (or warm up) the package, print its kernels' cache statistics as JSON
_PROBE = """
import json, sys
import insalign_ros
from insalign_ros.session import warmup
if sys.argv[1] == "warm":  # a static core's kernels (6): where the cache goes does not depend on which kernels, and
    # compiling them all in a cold copy costs minutes on a loaded machine (test_node_ready compiles auto's cold)
    from insalign_ros.session.offline import align
    from insalign_ros.sim.scenarios import make_scenario
    align(make_scenario("static", seed=0, duration_s=10.0, rate_hz=25.0), core="pkf")
else:  # import every core (and so every module that decorates kernels), compile nothing
    import insalign_ros.filters.registry
print(json.dumps({"package": insalign_ros.__file__, "kernels": warmup.kernel_stats()}))
"""


def _read_only_copy(dst: Path) -> Path:
    """Copy insalign_ros/ (no caches) under ``dst`` and make every directory and file read-only."""
    pkg = dst / "insalign_ros"
    shutil.copytree(REPO / "insalign_ros", pkg, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for root, dirs, files in os.walk(dst, topdown=False):
        for f in files:
            os.chmod(os.path.join(root, f), stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
        os.chmod(root, stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
    return pkg


def _make_writable(path: Path) -> None:
    for root, dirs, files in os.walk(path):
        os.chmod(root, 0o755)


def _unprivileged() -> list[str]:
    """Command prefix under which the permission bits bind (root: drop CAP_DAC_OVERRIDE), or skip."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root without setpriv (util-linux): a read-only directory cannot be simulated")
    return [setpriv, "--bounding-set=-dac_override,-dac_read_search", "--"]


def _probe(mode: str, src: Path, cache_home: Path, extra_env: dict | None = None, timeout_s: float = 900.0) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "INSALIGN_NO_NUMBA", "NUMBA_DISABLE_JIT")}
    env.update(PYTHONPATH=str(src), HOME=str(cache_home / "home"), XDG_CACHE_HOME=str(cache_home / "xdg"),
               PYTHONDONTWRITEBYTECODE="1", **(extra_env or {}))
    r = subprocess.run([*_unprivileged(), sys.executable, "-c", _PROBE, mode], env=env, cwd=str(cache_home),
                       capture_output=True, text=True, timeout=timeout_s)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert Path(out["package"]).resolve().is_relative_to(src.resolve()), out["package"]
    return out


def _cache_files(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file()}


@pytest.fixture
def read_only_install(tmp_path):
    src = tmp_path / "site"
    src.mkdir()
    _read_only_copy(src)
    probe = src / "insalign_ros" / "core" / "probe"
    if os.geteuid() != 0:
        with pytest.raises(PermissionError):  # the premise: nothing can be written into the package
            probe.mkdir()
    yield src
    _make_writable(src)


def test_kernels_of_a_writable_tree_are_cached_next_to_their_source(tmp_path):
    out = _probe("import", REPO, tmp_path)
    assert len(out["kernels"]) >= 30  # core/mechanization_numba and the filters' kernel modules
    for k in out["kernels"]:
        assert Path(k["cache_path"]).parent.parent == REPO / "insalign_ros", k
        assert Path(k["cache_path"]).name == "__pycache__", k


def test_numba_cache_dir_set_by_the_user_wins(tmp_path):
    mine = tmp_path / "mine"
    out = _probe("import", REPO, tmp_path, {"NUMBA_CACHE_DIR": str(mine)})
    assert out["kernels"] and all(Path(k["cache_path"]).parent == mine for k in out["kernels"])


def test_read_only_install_caches_in_the_user_cache_dir_and_a_second_process_hits(read_only_install, tmp_path):
    cache_home = tmp_path / "user"
    cache_home.mkdir()
    user_dir = cache_home / "xdg" / "insalign_ros" / "numba"

    first = _probe("warm", read_only_install, cache_home)
    paths = {Path(k["cache_path"]) for k in first["kernels"]}
    assert paths and all(p.parent == user_dir for p in paths), paths
    compiled = {k["kernel"]: k["cache_misses"] for k in first["kernels"] if k["cache_misses"]}
    assert len(compiled) >= 5, compiled  # the static core's kernels
    files = _cache_files(user_dir)
    assert sum(f.endswith(".nbi") for f in files) >= len(compiled)
    assert not list(read_only_install.rglob("*.nbi")) and not list(read_only_install.rglob("__pycache__"))

    second = _probe("warm", read_only_install, cache_home)
    rows = {k["kernel"]: k for k in second["kernels"]}
    assert sum(k["cache_misses"] for k in rows.values()) == 0, {n: k for n, k in rows.items() if k["cache_misses"]}
    assert sum(k["cache_hits"] for k in rows.values()) >= 2, rows  # the two the core calls (a kernel inlined in a
    # loaded one shows none)
    assert _cache_files(user_dir) == files  # nothing compiled, nothing rewritten


class _FakeGraph:
    """count_subscribers answers 0 until ``ready_after`` calls, then 1 (the node subscribed after its warm-up)."""

    def __init__(self, ready_after: int | None):
        self.calls, self.ready_after = 0, ready_after

    def count_subscribers(self, topic: str) -> int:
        assert topic == "/imu/data"
        self.calls += 1
        return int(self.ready_after is not None and self.calls > self.ready_after)


class _FakeProc:
    def __init__(self, alive_calls: int | None = None):
        self.n, self.alive_calls = 0, alive_calls

    def alive(self) -> bool:
        self.n += 1
        return self.alive_calls is None or self.n <= self.alive_calls


def _fake_mon(graph):
    return type("Mon", (), {"node": graph})()


def test_the_demo_waits_for_the_node_subscription_not_for_a_time():
    """insalign-demo's readiness wait: returns once alignment_node subscribed to imu/data; None when the node dies or
    never subscribes within the timeout (no fixed sleep decides)."""
    import io
    import time

    from insalign_ros.cli.demo import _wait_ready

    out = io.StringIO()
    graph = _FakeGraph(ready_after=3)
    t0 = time.monotonic()
    ready = _wait_ready(_fake_mon(graph), _FakeProc(), None, t0, 30.0, out)
    assert ready is not None and graph.calls == 4 and "ready after" in out.getvalue()
    assert _wait_ready(_fake_mon(_FakeGraph(None)), _FakeProc(alive_calls=2), None, time.monotonic(), 30.0, out) is None
    t0 = time.monotonic()
    assert _wait_ready(_fake_mon(_FakeGraph(None)), _FakeProc(), None, t0, 0.3, out) is None
    assert time.monotonic() - t0 < 5.0


def test_warm_up_jobs_split_every_core_once_into_the_measured_groups():
    """``python -m insalign_ros.session.warmup --jobs 2`` (scripts/env.sh, the test suite's cold start): every core
    exactly once, in the two groups of similar compile time; one group for one job or one core."""
    from insalign_ros.filters.registry import core_names
    from insalign_ros.session.warmup import GROUPS, core_groups

    groups = core_groups(("all",), 2)
    flat = [c for g in groups for c in g]
    assert len(groups) == 2 and sorted(flat) == sorted(set(core_names()) | {"auto"}), groups
    assert groups[0] == [c for c in GROUPS[0] if c in flat] and set(GROUPS[1]) <= set(groups[1]), groups
    assert core_groups(("all",), 1) == [flat] or sorted(core_groups(("all",), 1)[0]) == sorted(flat)
    assert core_groups(("auto",), 2) == [["auto"]]
    assert core_groups(("liekf", "pkf", "iekf"), 3) == [["liekf"], ["pkf"], ["iekf"]]
