"""Shared machinery of the Monte-Carlo benchmarks (yaw_sweep, static_sigma_r, aligned_flag_mc): independent runs as
Dask tasks, a progress bar, results in task order; and per-stage timing of one ``ia.align`` run.

Schedulers (``add_arguments``): by default a ``dask.distributed.LocalCluster`` with ``--workers`` single-threaded
worker processes on this machine; ``--scheduler tcp://host:8786`` for a running cluster (its workers need
insalign_ros installed; this module is uploaded to them); ``--serial`` runs the tasks in this process, in order, for
debugging (same results: every run is seeded). docs/speed.md has the measurements.
"""

from __future__ import annotations

import functools
import os
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _pin_solver_threads() -> None:
    """The runner's process (the serial path, the client) takes one rayon thread like the workers
    (eval.parallel.pin_solver_threads)."""
    from insalign_ros.eval.parallel import pin_solver_threads

    pin_solver_threads()


_pin_solver_threads()


def add_arguments(ap) -> None:
    g = ap.add_argument_group("execution (Dask)")
    g.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="LocalCluster worker processes (one thread each); default: the CPU count")
    g.add_argument("--scheduler", default="", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    g.add_argument("--serial", action="store_true", help="no Dask: run the tasks here, in order (debugging)")
    g.add_argument("--speedup", action="store_true",
                   help="run the tasks twice, serially then on Dask, back to back: print both wall times, the "
                        "speed-up, the load average around each, and whether the results are identical")
    g.add_argument("--spawn-workers", action="store_true",
                   help="start each LocalCluster worker as a fresh interpreter (Dask's default) instead of forking "
                        "it from one process that imported the packages the runs use (PRELOAD)")
    g.add_argument("--stage-timing", action="store_true",
                   help="time the stages of every run (read/convert, input, propagate, update, outputs, session) "
                        "and print their sums (adds ~1 us per sample)")


#: what an ``ia.align`` run imports (the cores, the session, numba's kernels, the LMI solver): imported once before
#: a LocalCluster's workers are forked (insalign_ros.eval.parallel.make_client), not by each worker's first runs
PRELOAD = ("insalign_ros", "insalign_ros.session.offline", "insalign_ros.filters.registry",
           "insalign_ros.core.mechanization_numba", "insalign_ros.filters.lmi", "cvxpy", "sweep")


@functools.lru_cache(maxsize=4)
def scenario(name: str, seed: int, duration_s: float):
    """The simulated run ``(name, seed)`` truncated to ``duration_s``, cached per process. The benchmarks pass it to
    their tasks as ``shared_scenario(...)``: simulated once per sweep, as a task of its own, and shipped to the
    workers that run the seed (serially: once, freed after the seed's last run)."""
    import insalign_ros as ia

    return ia.simulate(name, seed=seed, duration_s=duration_s)


def shared_scenario(name: str, seed: int, duration_s: float):
    """A task argument: the scenario ``(name, seed)`` simulated once per sweep (insalign_ros.eval.parallel.Shared;
    ``ia.simulate`` itself, pickled by reference: the scheduler of a LocalCluster re-imports this uploaded module in
    this process, so a function of this module would no longer be the one pickle finds)."""
    import insalign_ros as ia
    from insalign_ros.eval.parallel import Shared

    return Shared(ia.simulate, (name, seed, float(duration_s)))


#: summary fields that measure the machine, not the run (left out when the serial and Dask results are compared)
VOLATILE_KEYS = frozenset({"wall_s", "lmi_solve_time_s"})


def first_difference(a, b, path: str = "", volatile=VOLATILE_KEYS) -> str:
    """'' when ``a`` and ``b`` are equal (numbers exactly, nan equal to nan; dict keys in ``volatile`` skipped),
    otherwise the path of the first difference."""
    import numpy as np

    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) - volatile != set(b) - volatile:
            return path + " (keys)"
        for k in a:
            if k not in volatile:
                d = first_difference(a[k], b[k], f"{path}.{k}", volatile)
                if d:
                    return d
        return ""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return path + " (length)"
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{path}[{i}]", volatile)
            if d:
                return d
        return ""
    if isinstance(a, (np.ndarray, float, np.floating)) or isinstance(b, (np.ndarray, float, np.floating)):
        x, y = np.asarray(a), np.asarray(b)
        same = x.shape == y.shape and (np.array_equal(x, y, equal_nan=True) if x.dtype.kind in "fc"
                                       else np.array_equal(x, y))
        return "" if same else path
    return "" if a == b else path


def _at(obj, path: str):
    """The element of ``obj`` at a :func:`first_difference` path (e.g. '[73][0].rmse_rpy_deg[0]')."""
    import re

    for key, idx in re.findall(r"\.(\w+)|\[(\d+)\]", path.split(" ")[0]):
        obj = obj[key] if key else obj[int(idx)]
    return obj


def run_tasks(fn, tasks: list[tuple], args, desc: str = "runs", cost=None) -> list:
    """``[fn(*t) for t in tasks]`` with the execution options of :func:`add_arguments` (insalign_ros.eval.parallel;
    this module is uploaded to the workers: they import it by name for the scenarios and the stage timer).
    ``cost``: estimated run time of each task (Dask submits the longest first). Prints the load average around the
    run and where its time went (eval.parallel.efficiency); with ``--speedup``, runs serially first and prints the
    comparison. Sets ``args.sweep_wall_s`` (the parallel run's wall time with ``--speedup``) and ``args.sweep_summary``
    (one line: wall times, load averages, speed-up)."""
    import sys

    from insalign_ros.eval.parallel import efficiency, format_efficiency, loadavg
    from insalign_ros.eval.parallel import run_tasks as run

    def once(serial: bool):
        mode = "serial" if serial else (getattr(args, "scheduler", "") or
                                        f"LocalCluster, {getattr(args, 'workers', 0) or os.cpu_count()} workers")
        load0, st = loadavg(), {}
        out = run(fn, tasks, workers=getattr(args, "workers", 0), scheduler=getattr(args, "scheduler", ""),
                  serial=serial, desc=f"{desc} ({mode})", upload=(__file__,), cost=cost, stats=st,
                  preload=() if getattr(args, "spawn_workers", False) else PRELOAD)
        e = efficiency(st)
        e["line"] = f"{e['wall_s']:.1f} s wall ({mode}; load average {load0} -> {loadavg()})"
        print(f"[{desc}] {e['line']}: " + format_efficiency(e), file=sys.stderr, flush=True)
        return out, e

    if getattr(args, "speedup", False):
        ser, es = once(True)
        par, ep = once(False)
        diff = first_difference(ser, par)
        args.sweep_summary = (f"{len(tasks)} runs: {es['line']}, then {ep['line']}: speed-up "
                              f"{es['wall_s'] / ep['wall_s']:.2f}x (target >= 1.8x on 2 workers); task CPU "
                              f"{es['task_cpu_s']:.1f} s serial, {ep['task_cpu_s']:.1f} s on Dask (CPU-bound ceiling "
                              f"{ep['workers'] * es['task_cpu_s'] / max(ep['task_cpu_s'], 1e-9):.2f}x); results "
                              + ("identical" if not diff else f"DIFFER at {diff}: {_at(ser, diff)!r} serial, "
                                                              f"{_at(par, diff)!r} on Dask"))
        print(f"[{desc}] " + args.sweep_summary, file=sys.stderr, flush=True)
        args.sweep_wall_s = ep["wall_s"]
        return par
    out, e = once(bool(getattr(args, "serial", False)))
    args.sweep_wall_s = e["wall_s"]
    args.sweep_summary = f"{len(tasks)} runs: {e['line']}"
    return out


# ------------------------------------------------------------------------------------- per-stage timing
class StageTimer:
    """Exclusive wall time per pipeline stage of ``ia.align`` runs, by wrapping the methods that make each stage.

    Stages: ``read`` (source -> arrays, truth records), ``input`` (the session's validation and buffering of each
    sample), ``propagate`` (the core's propagate/flush, including flushes inside updates and estimates), ``update``
    (GNSS and zero-velocity updates without their flush), ``outputs`` (estimates, output records, result arrays and
    metrics); ``session`` is the rest of ``ia.align`` (ordering, scheduling, flag, per-sample bookkeeping). Nested
    wrapped calls are subtracted from their caller. Use as a context manager around the runs."""

    def __init__(self):
        self.t = defaultdict(float)
        self.total_s = 0.0
        self._stack: list[float] = []
        self._undo: list = []

    def _wrap(self, owner, name: str, stage: str) -> None:
        orig = owner.__dict__[name]
        timer = self

        @functools.wraps(orig)
        def timed(*a, **k):
            t0 = time.perf_counter()
            timer._stack.append(0.0)
            try:
                return orig(*a, **k)
            finally:
                el = time.perf_counter() - t0
                child = timer._stack.pop()
                timer.t[stage] += el - child
                if timer._stack:
                    timer._stack[-1] += el

        setattr(owner, name, timed)
        self._undo.append((owner, name, orig))

    def __enter__(self):
        from insalign_ros.filters import registry
        from insalign_ros.filters.base import AlignmentCore
        from insalign_ros.session import offline
        from insalign_ros.session.inputs import InputStage
        from insalign_ros.session.outputs import Outputs
        from insalign_ros.session.session import AlignmentSession

        for f in ("load_source", "truth_samples", "truth_table"):
            if hasattr(offline, f):
                self._wrap(offline, f, "read")
        for m in ("push_imu", "push_imu_arrays", "push_fix", "push_truth", "push_truth_table"):
            self._wrap(AlignmentSession, m, "input")
        self._wrap(InputStage, "push_imu_checked", "input")  # the offline path's checked slices
        self._wrap(Outputs, "output", "outputs")
        self._wrap(offline, "result_from_outputs", "outputs")
        seen = set()
        classes = {AlignmentCore}
        for name in registry.core_names():
            core = registry.make_core(name)
            classes.update(type(core).__mro__)
            core.close()
        for klass in classes:
            for m, stage in (("_propagate_arrays", "propagate"), ("_estimates_along", "propagate"),
                             ("flush", "propagate"), ("update", "update"), ("estimate", "outputs")):
                if m in getattr(klass, "__dict__", {}) and (klass, m) not in seen:
                    seen.add((klass, m))
                    self._wrap(klass, m, stage)
        return self

    def __exit__(self, *exc):
        for owner, name, orig in reversed(self._undo):
            setattr(owner, name, orig)
        self._undo.clear()

    def align(self, *a, **k):
        """``ia.align(*a, **k)`` timed as a whole (the ``session`` stage is the part no other stage claims)."""
        import insalign_ros as ia

        t0 = time.perf_counter()
        r = ia.align(*a, **k)
        self.total_s += time.perf_counter() - t0
        return r

    def stages(self) -> dict:
        d = {s: self.t.get(s, 0.0) for s in ("read", "input", "propagate", "update", "outputs")}
        d["session"] = max(self.total_s - sum(d.values()), 0.0)
        d["total"] = self.total_s
        return d


def merge_stages(parts) -> dict:
    out: dict = defaultdict(float)
    for p in parts:
        for k, v in (p or {}).items():
            out[k] += v
    return dict(out)


def format_stages(st: dict, samples: int | None = None) -> str:
    """One line: each stage's seconds, share of the total and (with ``samples``) microseconds per sample."""
    tot = st.get("total", 0.0) or float("nan")
    parts = []
    for k in ("read", "input", "propagate", "update", "outputs", "session"):
        v = st.get(k, 0.0)
        s = f"{k} {v:.2f} s ({100 * v / tot:.0f} %"
        s += f", {1e6 * v / samples:.1f} us/sample)" if samples else ")"
        parts.append(s)
    return "; ".join(parts) + f"; total {tot:.2f} s"
