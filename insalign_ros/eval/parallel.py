"""Independent runs as Dask tasks (``dask.distributed``): a LocalCluster on this machine or a running scheduler,
a progress bar, results in task order; ``serial`` runs them here, in order (debugging; same results when every run
is seeded). Used by ``insalign-align DIR`` (a fleet of bags) and the Monte-Carlo benchmarks (benchmarks/sweep.py).

Scheduling (docs/speed.md, "Monte-Carlo sweeps on Dask"): tasks are submitted longest first when the caller gives a
``cost`` estimate per task (the short tasks fill the end, so no worker idles while another finishes a long one);
:class:`Shared` arguments (e.g. a simulated scenario used by many runs) are computed once, as a task of their own, and
their result is shipped to the tasks that need it. Every run is timed on its worker (wall, CPU, process), and
:func:`efficiency` summarises where a parallel run loses against the serial one.

Dask is optional at run time: without it, ``serial`` works and the parallel path says how to install it.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class Shared:
    """An argument computed once as ``fn(*args)`` and passed to every task that holds an equal ``Shared`` (``fn``
    module-level, ``args`` hashable). Serially: computed on first use, kept while later tasks still need it."""

    fn: object
    args: tuple = ()


def _timed(fn, *args):
    """``fn(*args)`` and its timing record: (pid, start and end [s, time.time()], CPU time of this process and of
    this thread [s]; the difference is what other threads, e.g. a Dask worker's event loop, used meanwhile)."""
    t0, c0, h0 = time.time(), time.process_time(), time.thread_time()
    out = fn(*args)
    return out, (os.getpid(), t0, time.time(), time.process_time() - c0, time.thread_time() - h0)


def _timed_with_shared(fn, shared_at: tuple, *args):
    """:func:`_timed` where ``args[k]`` for k in ``shared_at`` is a Shared's ``(value, record)``: pass the value;
    return the Shared's records too (the client never fetches a Shared's value)."""
    out, rec = _timed(fn, *(a[0] if k in shared_at else a for k, a in enumerate(args)))
    return out, rec, tuple(args[k][1] for k in shared_at)


#: LocalCluster worker settings for CPU-bound pure-Python tasks: no statistical profiler (it samples the running
#: task's stack every 10 ms and takes the GIL to do it), and the event-loop health check, memory monitor and system
#: monitor at 1-5 s instead of 20-500 ms. Measured (docs/speed.md): the worker's own threads used ~20 ms of CPU per
#: 0.3 s run with the defaults, ~2 ms with these.
QUIET_WORKER_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "1s",
                       "distributed.worker.memory.monitor-interval": "1s",
                       "distributed.admin.system-monitor.interval": "5s"}

#: Environment of each LocalCluster worker process (set by its nanny; a variable already set in this process's
#: environment wins): one thread in clarabel's rayon pool. Clarabel (PI-LIEKF's LMI solver) otherwise starts a pool of
#: one thread per CPU in every process; with one worker process per CPU the pools oversubscribe the machine and their
#: idle threads spin. Measured (docs/speed.md): 9 PI-LIEKF runs took 9 % less CPU on 2 workers with one rayon thread
#: (7 pairs; 5-15 % serially), same numbers.
WORKER_ENVIRON = {"RAYON_NUM_THREADS": "1"}


def pin_solver_threads() -> None:
    """``WORKER_ENVIRON`` for this process too (a value already set wins), before any LMI solve: the package's entry
    points (alignment_node, insalign-align, the benchmarks' runner) call it; a library user decides for their own
    process. Measured on the 20-seed ship sweep run serially on a quiet machine (docs/results.md, "Yaw sweep on
    Dask"): 262 s of wall and 260 s of CPU with one rayon thread, 292 s and 308 s with the default pool; the same
    numbers."""
    for k, v in WORKER_ENVIRON.items():
        os.environ.setdefault(k, v)


def _forkserver_preload(modules: tuple[str, ...]) -> dict:
    """Dask config that starts the LocalCluster's worker processes from a multiprocessing fork server which has
    imported ``modules`` (and distributed, numpy) once, instead of spawning fresh interpreters that each import them;
    {} where there is no fork server (not POSIX). The preload list only acts before the server starts (the first
    cluster of this process); a module that fails to import is skipped by the server. Measured (docs/speed.md): each
    worker process used ~0.9 s less CPU at start-up, its first runs no longer import cvxpy, and a worker exits in
    ~0.05 s instead of ~0.9 s (a forked child leaves with os._exit, without the interpreter's teardown); the cluster is
    up ~1 s later (the server imports everything before the first fork, on one core)."""
    import multiprocessing

    if not modules or "forkserver" not in multiprocessing.get_all_start_methods():
        return {}
    import dask
    from distributed.utils import get_mp_context

    cfg = {"distributed.worker.multiprocessing-method": "forkserver"}
    with dask.config.set(cfg):
        ctx = get_mp_context()  # distributed sets its own preload list once; ours replaces it before the start
    ctx.set_forkserver_preload(["distributed", "numpy", *modules])
    import multiprocessing.forkserver

    multiprocessing.forkserver.ensure_running()  # start importing now, while this process starts the scheduler
    return cfg


def _setup_plugin(fn, args: tuple = ()):
    """A Dask worker plugin that calls ``fn(*args)`` once in every worker, before it runs a task (also in workers that
    join a remote cluster later). Its result goes to the worker's log; an exception does not stop the worker. (The
    class derives from distributed's WorkerPlugin, imported here: importing this module does not import Dask.)"""
    from distributed.diagnostics.plugin import WorkerPlugin

    class SetupPlugin(WorkerPlugin):
        name = "insalign-setup"

        def __init__(self, fn, args):
            self.fn, self.args = fn, args

        def setup(self, worker):
            import logging

            log = logging.getLogger("distributed.worker")
            try:
                log.info("insalign setup: %s", self.fn(*self.args))
            except Exception as exc:  # noqa: BLE001 - a failed warm-up costs the first task its compile time only
                log.warning("insalign setup failed: %s", exc)

    return SetupPlugin(fn, args)


def make_client(workers: int, scheduler: str = "", upload: tuple[str, ...] = (), preload: tuple[str, ...] = ()):
    """A distributed Client on ``scheduler`` (e.g. tcp://host:8786) or on a new LocalCluster of ``workers``
    single-threaded processes; ``upload``: module files the workers import by name; ``preload``: modules the runs
    import, loaded once before the LocalCluster's workers are forked (:func:`_forkserver_preload`; () spawns each
    worker, Dask's default). Returns (client, cluster)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise ValueError("parallel runs need dask.distributed (pip install dask distributed); or run serially") from exc
    # one BLAS thread per worker process: the runs are the parallelism (2 workers x N threads would oversubscribe)
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(k, "1")
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        import dask

        env = {f"distributed.nanny.environ.{k}": v for k, v in WORKER_ENVIRON.items()}
        # the nannies hand this config to their workers
        with dask.config.set({**QUIET_WORKER_CONFIG, **env, **_forkserver_preload(tuple(preload))}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=40)
        client = Client(cluster)
    for path in upload:
        client.upload_file(path)
    return client, cluster


def _resolve(task: tuple, values: dict) -> tuple:
    return tuple(values[a] if isinstance(a, Shared) else a for a in task)


def _run_windowed(client, fn, tasks, order, prepare, window: int, bar, records, on_result=None) -> list:
    """Submit ``tasks`` in ``order`` with at most ``window`` in flight, each prepared just before it is submitted."""
    from distributed import as_completed

    out = [None] * len(tasks)
    pending = iter(order)
    index: dict = {}
    ac = as_completed()

    def submit_next() -> bool:
        i = next(pending, None)
        if i is None:
            return False
        t = prepare(tasks[i]) if prepare is not None else tasks[i]
        fut = client.submit(_timed_with_shared, fn, (), *t, pure=False)
        index[fut.key] = i
        ac.add(fut)
        return True

    for _ in range(window):
        if not submit_next():
            break
    for fut in ac:
        i = index.pop(fut.key)
        out[i], rec, _ = fut.result()
        if on_result is not None:
            out[i] = on_result(i, out[i])
        records.append(("task", i) + rec)
        fut.release()  # the result is ours now: the worker may drop it
        bar.update(1)
        submit_next()
    return out


def _run_serial(fn, tasks, bar, records, prepare=None, on_result=None):
    remaining: dict = {}
    for t in tasks:
        for a in t:
            if isinstance(a, Shared):
                remaining[a] = remaining.get(a, 0) + 1
    values: dict = {}
    out = []
    for i, t in enumerate(tasks):
        for a in t:
            if isinstance(a, Shared) and a not in values:
                values[a], rec = _timed(a.fn, *a.args)
                records.append(("shared", -1) + rec)
        res, rec = _timed(fn, *_resolve(prepare(t) if prepare is not None else t, values))
        if on_result is not None:
            res = on_result(i, res)
        records.append(("task", i) + rec)
        out.append(res)
        for a in t:
            if isinstance(a, Shared):
                remaining[a] -= 1
                if not remaining[a]:
                    del values[a]  # free it: the caller's order decides how many are alive at once
        bar.update(1)
    return out


def run_tasks(fn, tasks: list[tuple], workers: int = 0, scheduler: str = "", serial: bool = False,
              desc: str = "runs", upload: tuple[str, ...] = (), progress: bool = True, cost=None,
              stats: dict | None = None, preload: tuple[str, ...] = (), worker_setup: tuple | None = None,
              prepare=None, window: int = 0, on_result=None) -> list:
    """``[fn(*t) for t in tasks]``, as Dask tasks unless ``serial``; a tqdm bar on stderr; results in task order.

    ``fn`` must be a module-level function (pickled by reference or, from ``__main__``, by value); ``workers``:
    LocalCluster processes (0: the CPU count). ``cost``: an estimate of each task's run time (any unit; a list
    parallel to ``tasks``): the parallel path submits the longest first. A :class:`Shared` in a task is replaced by its
    value, computed once. ``stats``: a dict to fill with the timing records (see :func:`efficiency`). ``preload``:
    modules ``fn`` imports, loaded once before a LocalCluster's workers start (:func:`make_client`).
    ``worker_setup``: ``(setup_fn, args)`` called once in each worker before its first task (e.g. compiling the
    kernels under a machine-wide lock). ``prepare``: ``task -> task`` applied just before a task is submitted (or run
    serially), e.g. reading a bag into bytes; with ``window`` > 0 at most that many tasks are in flight at once, so
    the client holds at most ``window`` prepared tasks (no Shared arguments then). ``on_result``: ``(i, result) ->
    result`` called in the client as each result arrives (e.g. writing a run's files and dropping their bytes)."""
    from tqdm import tqdm

    bar = tqdm(total=len(tasks), desc=desc, file=sys.stderr, mininterval=2, disable=not progress)
    t0, c0 = time.time(), time.process_time()
    records: list = []
    workers = 1 if serial else (workers or os.cpu_count() or 1)
    try:
        if serial:
            return _run_serial(fn, [prepare(t) for t in tasks] if prepare and not window else tasks, bar, records,
                               prepare if window else None, on_result)
        client, cluster = make_client(workers, scheduler, upload, preload)
        try:
            from distributed import as_completed

            if worker_setup is not None:
                client.register_plugin(_setup_plugin(*worker_setup))
            t_ready = time.time()
            if scheduler:  # the efficiency figures count the cluster's worker threads, not --workers
                workers = sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()) \
                    or workers
            order = list(range(len(tasks)))
            if cost is not None:
                order.sort(key=lambda i: -cost[i])  # stable: equal costs keep the caller's order
            if window > 0:
                out = _run_windowed(client, fn, tasks, order, prepare, window, bar, records, on_result)
                if stats is not None:
                    stats["cluster_start_s"] = t_ready - t0
                    stats["client_cpu_s"] = time.process_time() - c0
                return out
            if prepare is not None:
                tasks = [prepare(t) for t in tasks]
            shared: dict = {}
            futures = []
            for rank, i in enumerate(order):
                for a in tasks[i]:
                    if isinstance(a, Shared) and a not in shared:
                        # before its first user; the scheduler runs a dependency before lower-priority work
                        shared[a] = client.submit(_timed, a.fn, *a.args, pure=False, priority=len(tasks) - rank + 1)
                at = tuple(k for k, a in enumerate(tasks[i]) if isinstance(a, Shared))
                args = tuple(shared[a] if isinstance(a, Shared) else a for a in tasks[i])
                futures.append(client.submit(_timed_with_shared, fn, at, *args, pure=False,
                                             priority=len(tasks) - rank))
            del shared  # the scheduler keeps each value while a task still needs it, then frees it
            index = {f.key: i for f, i in zip(futures, order)}
            out = [None] * len(tasks)
            shared_recs = set()
            for fut in as_completed(futures):
                i = index[fut.key]
                out[i], rec, srecs = fut.result()
                if on_result is not None:
                    out[i] = on_result(i, out[i])
                records.append(("task", i) + rec)
                shared_recs.update(srecs)
                bar.update(1)
            records.extend(("shared", -1) + r for r in shared_recs)
            if stats is not None:
                stats["cluster_start_s"] = t_ready - t0
                # CPU outside the runs: the client, and with a LocalCluster its scheduler and nannies (this
                # process); each worker process's whole CPU (imports, Dask's own threads, the runs)
                stats["client_cpu_s"] = time.process_time() - c0
                try:
                    stats["worker_process_cpu_s"] = sum(client.run(time.process_time).values())
                except Exception:  # a remote cluster may refuse run(): the figure is optional
                    pass
            return out
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    finally:
        bar.close()
        wall = time.time() - t0
        if stats is not None:
            stats.update(records=records, wall_s=wall, workers=workers, t0=t0)
        if progress and not serial:
            print(f"[parallel] {len(tasks)} tasks on {scheduler or f'{workers} local workers'}: "
                  f"{wall:.1f} s wall", file=sys.stderr)


def loadavg() -> str:
    """The 1/5/15-min load averages of /proc/loadavg ("n/a" elsewhere): printed beside every wall time."""
    try:
        with open("/proc/loadavg") as fh:
            return " ".join(fh.read().split()[:3])
    except OSError:
        return "n/a"


def efficiency(stats: dict) -> dict:
    """Where a run of :func:`run_tasks` spent its wall time, from its ``stats``: task CPU and wall sums, the Shared
    computations' share, the CPU share of the task wall time (< 1: the tasks waited for a CPU), the busy share of
    the workers, start-up (cluster start to the first task), the idle tail (workers done while others still ran) and
    shut-down."""
    rec = stats.get("records", [])  # (kind, task index, pid, start, end, process CPU, thread CPU)
    tasks = [r for r in rec if r[0] == "task"]
    shared = [r for r in rec if r[0] == "shared"]
    wall, w, t0 = stats["wall_s"], stats["workers"], stats["t0"]
    busy = sum(r[4] - r[3] for r in rec)
    first = min((r[3] for r in rec), default=t0)
    last = max((r[4] for r in rec), default=t0)
    ends: dict = {}
    for r in rec:
        ends[r[2]] = max(ends.get(r[2], 0.0), r[4])
    return {"tasks": len(tasks), "wall_s": wall, "workers": w,
            "task_wall_s": sum(r[4] - r[3] for r in tasks), "task_cpu_s": sum(r[5] for r in tasks),
            "task_thread_cpu_s": sum(r[6] for r in tasks),
            "shared": len(shared), "shared_wall_s": sum(r[4] - r[3] for r in shared),
            "shared_cpu_s": sum(r[5] for r in shared),
            "busy_share": busy / (w * wall) if wall > 0 else float("nan"),
            "cluster_start_s": stats.get("cluster_start_s", 0.0), "startup_s": first - t0,
            "tail_idle_s": sum(last - e for e in ends.values()),
            # worker time between runs (per-task overhead: dispatch, (de)serialisation, results) and idle tail
            "gaps_s": len(ends) * (last - first) - busy,
            "shutdown_s": t0 + wall - last, "processes": len(ends),
            "client_cpu_s": stats.get("client_cpu_s"), "worker_process_cpu_s": stats.get("worker_process_cpu_s")}


def format_efficiency(e: dict) -> str:
    """One line for :func:`efficiency`."""
    n = max(e["tasks"], 1)
    cpu = e["task_cpu_s"] + e["shared_cpu_s"]
    return (f"{e['tasks']} tasks, {e['workers']} worker(s), {e['wall_s']:.1f} s wall: task CPU {e['task_cpu_s']:.1f} s "
            f"({1000 * e['task_cpu_s'] / n:.0f} ms/task; task thread {e['task_thread_cpu_s']:.1f} s), task wall {e['task_wall_s']:.1f} s "
            f"(CPU/wall {e['task_cpu_s'] / max(e['task_wall_s'], 1e-9):.2f}); {e['shared']} shared inputs "
            f"{e['shared_cpu_s']:.1f} s CPU ({100 * e['shared_cpu_s'] / max(cpu, 1e-9):.1f} % of all CPU); "
            f"workers busy {100 * e['busy_share']:.0f} % of {e['workers']} x wall; start-up {e['startup_s']:.1f} s "
            f"(cluster {e['cluster_start_s']:.1f} s), "
            f"gaps between runs {e['gaps_s'] - e['tail_idle_s']:.1f} worker-s "
            f"({1000 * (e['gaps_s'] - e['tail_idle_s']) / n:.0f} ms/task), idle tail {e['tail_idle_s']:.1f} worker-s, shut-down {e['shutdown_s']:.1f} s; "
            f"{e['processes']} process(es) ran tasks"
            + (f"; this process (client, scheduler, nannies) {e['client_cpu_s']:.1f} s CPU" if e["client_cpu_s"] is not None
               else "")
            + (f"; worker processes {e['worker_process_cpu_s']:.1f} s CPU in all (start-up and Dask's threads included)"
               if e["worker_process_cpu_s"] is not None else ""))
