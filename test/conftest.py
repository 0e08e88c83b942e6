"""Shared fixtures of the DDS tests; the full core registry for every test module."""

import fcntl
import json
import os
import tempfile

import pytest

import insalign_ros.session  # noqa: F401  registers the session-level core 'auto' (session/auto.py, imported by session/__init__.py), so
#                              tests parametrised over the registry see the same cores whatever is imported first


_WARMUP: dict = {}


def _kernel_index_files() -> int:
    """numba cache index files (``*.nbi``) where this tree's kernels are cached: ``$NUMBA_CACHE_DIR`` when set, else
    next to the sources (core/mechanization_numba.py ``_jit``), else the user cache directory."""
    import glob

    import insalign_ros
    from insalign_ros.core.mechanization_numba import user_cache_dir

    roots = [os.environ["NUMBA_CACHE_DIR"]] if os.environ.get("NUMBA_CACHE_DIR") else \
        [os.path.dirname(insalign_ros.__file__), user_cache_dir()]
    return sum(len(glob.glob(os.path.join(r, "**", "*.nbi"), recursive=True)) for r in roots)


def pytest_configure(config):
    """Under pytest-xdist (scripts/test) with a cold kernel cache (a fresh clone on an installed virtualenv: no
    ``*.nbi`` file yet), compile every core's numba kernels in the controller before the workers start, in two
    processes at once (``python -m insalign_ros.session.warmup --jobs 2``, half the cores each): otherwise both
    workers compile the same kernels inside their first tests (60-100 s each, DDS tests waiting on a node that is not
    ready). With a warm cache (scripts/env.sh compiled them after installing) nothing is done.
    ``INSALIGN_TEST_WARMUP=1`` forces it, ``0`` skips it. The cold-start tests (test_first_run, test_node_ready) use
    their own cache directories."""
    want = os.environ.get("INSALIGN_TEST_WARMUP", "")
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None) or want == "0":
        return
    n_index = _kernel_index_files()
    if n_index and want != "1":
        _WARMUP["skipped"] = n_index
        return
    import subprocess
    import sys
    import time

    t0 = time.perf_counter()
    # two processes of similar compile time (session/warmup.py GROUPS)
    rcs = [subprocess.run([sys.executable, "-m", "insalign_ros.session.warmup", "--jobs", "2", "--quiet"],
                          timeout=1200).returncode]
    _WARMUP["s" if not any(rcs) else "error"] = time.perf_counter() - t0 if not any(rcs) else f"exit codes {rcs}"


#: wall time of the longest tests [s] (scripts/test on 2 workers, warm kernel cache, load average 2 on the 2-core
#: machine; the cold-cache test compiles the Earth-frame IEKF's kernels) by node id prefix: only the order of the
#: run depends on it (longest first; the tests marked wallclock balanced between the workers, so that both finish
#: theirs at the same time), never a result; a test not listed counts 10 s when it starts nodes over DDS (marker
#: ``ros``), 0.5 s otherwise
_LONG_TESTS_S = {
    "test_node_ready.py::test_cold_numba_cache": 20.0,
    "test_node_stamp_jitter.py::test_host_stamp_jitter_over_dds": 15.0,
    "test_node_e2e.py::test_every_core_publishes_pose": 19.0,
    "test_node_driver_style.py::test_driver_style_stream_with_default_parameters": 23.0,
    "test_sample_bag.py::test_the_sample_bag_replays": 22.0,
    "test_node_demo.py::test_demo_aligns": 19.0,
    "test_node_outputs.py::test_imu_datum_and_reset_over_dds": 15.0,
    "test_node_bad_input.py::test_bad_input_is_rejected": 19.0,
    "test_node_equivalence.py::test_lagged_fixes_over_dds": 15.0,
    "test_node_bag_replay.py::test_replayed_bag_reaches_aligned": 16.0,
    "test_node_equivalence.py::test_node_over_dds_equals_the_offline_api": 15.0,
    "test_node_driver_style.py::test_vehicle_car_flags_seconds_after_the_first_motion": 14.0,
    "test_imu_axes.py::test_imu_axes_over_dds": 14.0,
    "test_node_demo.py::test_demo_fails_with_the_reason": 12.0,
    "test_node_ready.py::test_imu_only_once_aligned": 12.0,
    "test_node_bag_replay.py::test_paced_bag_replay": 8.0,
    "test_auto_mode_dds.py::test_auto_core_goes_through_the_states": 12.0,
    "test_node_e2e.py::test_unknown_heading_179_deg_off": 9.0,
    "test_node_e2e.py::test_ship_run_reaches_aligned": 9.0,
    "test_align_fleet.py::test_fleet_on_two_workers": 9.0,
    "test_session_fuzz.py::test_session_survives_any_fault": 8.0,
    "test_coarse_rocking.py::test_three_sigma_covers_rocking": 6.0,  # the module's rocking runs (a shared fixture)
    "test_speed_paths.py::test_session_fast_path_matches_per_sample_over_300_s": 4.0,
    "test_mechanization_e.py::test_forward_reproduces_truth_then_inverse": 4.0,
    "test_auto_mode.py::test_park_drive_navgrade_heading": 4.0,
    "test_first_run.py::test_read_only_install": 5.0,
    "test_backtrack.py::test_backward_and_catch_up_300s": 2.0,
    "test_session.py::test_session_equals_the_per_event_runner": 3.0,
    "test_lie.py::test_exp_log_round_trip_10000": 1.5,
    "test_sim_scenarios.py::test_closing_the_loop_noise_free": 3.0,
    # marked wallclock (each runs alone)
    "test_backtrack_node.py::test_node_backtracking_two_position": 7.0,
    "test_pi_liekf.py::test_sync_solve_waits_at_most_the_budget": 3.5,
    "test_pi_liekf.py::test_async_lmi_never_blocks_an_update": 3.2,
    "test_pi_liekf.py::test_a_slow_lmi_on_a_weakly_excited_ship": 1.4,
    "test_backtrack.py::test_driver_live_feed_budgeted": 1.2,
    "test_pi_liekf.py::test_async_solve_that_overruns_the_budget": 1.0,
    "test_pi_liekf.py::test_close_is_idempotent": 0.9,
}


def _expected_s(item) -> float:
    nodeid = item.nodeid.split("/")[-1]
    for prefix, s in _LONG_TESTS_S.items():
        if nodeid.startswith(prefix):
            return s
    return 10.0 if item.get_closest_marker("ros") is not None else 0.5


def _shared_fixture_keys(item) -> list:
    """(module file, fixture name) of each module-, class- or package-scoped fixture ``item`` uses: the tests that
    share one must run one after the other on one worker, or pytest sets the fixture up again (a module's fixture is
    torn down as soon as the next test is of another module)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    path = item.nodeid.split("::")[0]
    keys = []
    for name in info.names_closure:
        defs = info.name2fixturedefs.get(name)
        if defs and str(getattr(defs[-1], "scope", "function")).split(".")[-1].lower() in ("module", "class", "package"):
            keys.append((path, name))
    return keys


def _groups(items) -> list:
    """``items`` in groups that share a module/class-scoped fixture (union over shared fixtures), collection order
    kept inside each group; every other test is a group of its own."""
    parent = list(range(len(items)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    first: dict = {}
    for i, it in enumerate(items):
        for key in _shared_fixture_keys(it):
            j = first.setdefault(key, i)
            parent[find(i)] = find(j)
    out: dict = {}
    for i, it in enumerate(items):
        out.setdefault(find(i), []).append(it)
    return list(out.values())


@pytest.hookimpl(trylast=True)  # after the -m deselection: the slices must be of the items that run
def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, the longest tests first on every worker: pytest-xdist's ``worksteal`` (scripts/test)
    hands each worker one contiguous slice of the collection and lets an idle worker steal the tail of another's
    queue, so the tests are dealt by expected duration into one slice per worker, each slice longest first. A long
    test left for the end (the collection's file order put the DDS tests there) kept one worker busy for a minute
    while the other idled. The tests that share a module-scoped fixture are dealt together and run one after the
    other (dealt one by one, test_coarse_rocking.py computed its 12 rocking runs three times: 16 s instead of 5).
    Without xdist the order is pytest's."""
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0)
    if n < 2 or not items:
        return

    def wallclock(g):
        return any(it.get_closest_marker("wallclock") is not None for it in g)

    # the tests marked wallclock all in the first slice, at its head: each takes the machine alone, so it waits for
    # the other workers' current tests. Split between the slices (each slice's own first), a worker that ran out of
    # them started its longest test, 20-25 s that the other slice's next wallclock test waited for; now the other
    # slices start with their shortest tests, as many seconds of them as the wallclock tests take, so each wallclock
    # test waits for a short test at most. Then the groups by expected duration (stable: file order among equals).
    groups = sorted(_groups(items), key=lambda g: (wallclock(g), sum(map(_expected_s, g))), reverse=True)
    # the shorter slices first: worksteal sends len(pending) // (workers left) to each worker in turn, so the
    # slices must hold exactly its chunks' numbers of tests (one test off, a slice's last, shortest test would start
    # another worker); each group goes to the slice with the least expected time that still has room for it
    N = len(items)
    room = [N // n + (1 if i >= n - N % n else 0) for i in range(n)]
    slices: list = [[] for _ in range(n)]
    load = [0.0] * n
    for g in groups:
        if wallclock(g) and room[0] >= len(g):
            i = 0
        else:
            fits = [i for i in range(n) if room[i] >= len(g)] or [max(range(n), key=lambda i: room[i])]
            i = min(fits, key=lambda i: (load[i], i))
        slices[i].append(g)
        room[i] -= len(g)
        load[i] += sum(map(_expected_s, g))
    alone_s = sum(_expected_s(it) for g in slices[0] if wallclock(g) for it in g)

    def ordered(k, sl):
        """Wallclock first, then the group of the longest test first; the slices without the wallclock tests start
        with their shortest groups, ``alone_s`` seconds of them (shortest first)."""
        sl = sorted(sl, key=lambda g: (wallclock(g), max(map(_expected_s, g))), reverse=True)
        if k == 0 or alone_s <= 0.0:
            return sl
        head, t = [], 0.0
        for g in sorted(sl, key=lambda g: sum(map(_expected_s, g))):
            if t >= alone_s:
                break
            head.append(g)
            t += sum(map(_expected_s, g))
        ids = {id(g) for g in head}
        return head + [g for g in sl if id(g) not in ids]

    items[:] = [it for k, sl in enumerate(slices) for g in ordered(k, sl) for it in g]


def pytest_report_header(config):
    if "s" in _WARMUP:
        return f"numba kernels compiled before the workers started (cold cache): {_WARMUP['s']:.1f} s"
    if "skipped" in _WARMUP:
        return f"numba kernel cache warm ({_WARMUP['skipped']} index files): no warm-up"
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
