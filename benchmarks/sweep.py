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


def add_arguments(ap) -> None:
    g = ap.add_argument_group("execution (Dask)")
    g.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="LocalCluster worker processes (one thread each); default: the CPU count")
    g.add_argument("--scheduler", default="", help="address of a running Dask scheduler, e.g. tcp://host:8786")
    g.add_argument("--serial", action="store_true", help="no Dask: run the tasks here, in order (debugging)")
    g.add_argument("--stage-timing", action="store_true",
                   help="time the stages of every run (read/convert, input, propagate, update, outputs, session) "
                        "and print their sums (adds ~1 us per sample)")


@functools.lru_cache(maxsize=4)
def scenario(name: str, seed: int, duration_s: float):
    """The simulated run ``(name, seed)`` truncated to ``duration_s``, cached per worker process (the tasks of one
    seed share it instead of re-simulating it)."""
    import insalign_ros as ia

    return ia.simulate(name, seed=seed, duration_s=duration_s)


def run_tasks(fn, tasks: list[tuple], args, desc: str = "runs") -> list:
    """``[fn(*t) for t in tasks]`` with the execution options of :func:`add_arguments` (insalign_ros.eval.parallel;
    this module is uploaded to the workers: they import it by name for the scenario cache and the stage timer)."""
    from insalign_ros.eval.parallel import run_tasks as run

    return run(fn, tasks, workers=getattr(args, "workers", 0), scheduler=getattr(args, "scheduler", ""),
               serial=args.serial, desc=desc, upload=(__file__,))


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
        from insalign_ros.session.session import AlignmentSession

        self._wrap(offline, "load_source", "read")
        self._wrap(offline, "truth_samples", "read")
        self._wrap(offline, "truth_table", "read")
        for m in ("push_imu", "push_imu_arrays", "push_fix", "push_truth", "push_truth_table"):
            self._wrap(AlignmentSession, m, "input")
        self._wrap(AlignmentSession, "_output", "outputs")
        self._wrap(offline, "result_from_outputs", "outputs")
        seen = set()
        classes = {AlignmentCore}
        for name in registry.core_names():
            core = registry.make_core(name)
            classes.update(type(core).__mro__)
            core.close()
        for klass in classes:
            for m, stage in (("propagate", "propagate"), ("flush", "propagate"), ("propagate_arrays", "propagate"),
                             ("update_gnss", "update"), ("update_zero_velocity", "update"), ("estimate", "outputs")):
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
