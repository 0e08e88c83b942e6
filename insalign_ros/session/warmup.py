"""Compile the numba kernels before the first real sample arrives (docs/install.md, "First run").

numba compiles a kernel on its first call (25-90 s for the whole package on a cold machine) and caches the result on
disk. A node that compiles inside its first IMU callback stalls its executor while the driver keeps publishing, so
the node calls :func:`warm_up` before it subscribes and says when it is ready; ``scripts/env.sh`` calls it once
after installing so that the first run finds a warm cache.
"""

from __future__ import annotations

import time


def warm_up(cores: tuple[str, ...] = ("auto",), duration_s: float = 3.0) -> float:
    """Run a short simulated alignment through the session for each core in ``cores`` (compiling every kernel the
    core's path calls); return the wall time it took [s]. Warm caches make this well under a second."""
    from .offline import align

    t0 = time.perf_counter()
    for core in cores:
        for scenario in ("static", "car"):
            align(scenario, core=core, duration_s=duration_s, seed=0)
    return time.perf_counter() - t0
