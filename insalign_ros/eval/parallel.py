"""Independent runs as Dask tasks (``dask.distributed``): a LocalCluster on this machine or a running scheduler,
a progress bar, results in task order; ``serial`` runs them here, in order (debugging; same results when every run
is seeded). Used by ``insalign-align DIR`` (a fleet of bags) and the Monte-Carlo benchmarks (benchmarks/sweep.py).

Dask is optional at run time: without it, ``serial`` works and the parallel path says how to install it.
"""

from __future__ import annotations

import os
import sys
import time


def make_client(workers: int, scheduler: str = "", upload: tuple[str, ...] = ()):
    """A distributed Client on ``scheduler`` (e.g. tcp://host:8786) or on a new LocalCluster of ``workers``
    single-threaded processes; ``upload``: module files the workers import by name. Returns (client, cluster)."""
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
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=40)
        client = Client(cluster)
    for path in upload:
        client.upload_file(path)
    return client, cluster


def run_tasks(fn, tasks: list[tuple], workers: int = 0, scheduler: str = "", serial: bool = False,
              desc: str = "runs", upload: tuple[str, ...] = (), progress: bool = True) -> list:
    """``[fn(*t) for t in tasks]``, as Dask tasks unless ``serial``; a tqdm bar on stderr; results in task order.

    ``fn`` must be a module-level function (pickled by reference or, from ``__main__``, by value); ``workers``:
    LocalCluster processes (0: the CPU count)."""
    from tqdm import tqdm

    bar = tqdm(total=len(tasks), desc=desc, file=sys.stderr, mininterval=2, disable=not progress)
    t0 = time.perf_counter()
    if serial:
        out = []
        for t in tasks:
            out.append(fn(*t))
            bar.update(1)
        bar.close()
        return out
    workers = workers or os.cpu_count() or 1
    client, cluster = make_client(workers, scheduler, upload)
    try:
        from distributed import as_completed

        futures = client.map(fn, *zip(*tasks), pure=False) if tasks else []
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(tasks)
        for fut in as_completed(futures):
            out[index[fut.key]] = fut.result()
            bar.update(1)
        bar.close()
        return out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
        if progress:
            print(f"[parallel] {len(tasks)} tasks on {scheduler or f'{workers} local workers'}: "
                  f"{time.perf_counter() - t0:.1f} s wall", file=sys.stderr)
