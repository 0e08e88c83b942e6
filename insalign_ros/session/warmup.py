"""Compile the numba kernels before the first real sample arrives (docs/install.md, "First run").

numba compiles a kernel on its first call (a minute or more for the whole package on a cold, busy machine) and caches
the result on disk: next to the source (``__pycache__``), or in ``${XDG_CACHE_HOME:-~/.cache}/insalign_ros/numba``
when the package directory is read-only, or in ``$NUMBA_CACHE_DIR`` when that is set
(core/mechanization_numba.py, ``_jit``). A node that compiles inside its first IMU callback stalls its executor while
the driver keeps publishing, so the node calls :func:`warm_up` before it subscribes and says when it is ready;
``scripts/env.sh`` runs ``python -m insalign_ros.session.warmup`` after installing so that the first run finds a
warm cache.

    python -m insalign_ros.session.warmup [--cores auto,iekf,...] [--quiet] [--jobs 2]

prints the time it took and where the cache is; with a warm cache it takes about a second (the imports).
"""

from __future__ import annotations

import argparse
import sys
import time

#: warm_up(("all",)) and the command line's default: the cores whose kernels the node may run (``auto`` switches
#: between a static model and an in-motion filter; the others are the ``core`` parameter's values)
ALL = "all"


def _core_list(cores: tuple[str, ...]) -> list[str]:
    if ALL not in cores:
        return list(cores)
    from ..filters.registry import core_names

    return ["auto", *core_names()]


def warm_up(cores: tuple[str, ...] = ("auto",), duration_s: float = 30.0, rate_hz: float = 25.0) -> float:
    """Run short simulated alignments through the session for each core in ``cores`` (``"all"``: every core),
    compiling every kernel the core's path calls; return the wall time it took [s].

    Each core runs a static scenario and a moving one (``ship``), ``duration_s`` of data each at ``rate_hz`` (the
    kernels' types do not depend on the rate): ``auto`` runs its static model's kernels only after some 25 s at rest
    and its in-motion filter's prediction only after some 20 s of motion, hence 30 s. With a warm cache this takes
    about 2 s for ``auto``, most of it the first calls of the session's code."""
    from ..sim.scenarios import make_scenario
    from .offline import align

    t0 = time.perf_counter()
    todo = [c for c in _core_list(cores) if c not in _WARM]  # compiled in this process already: nothing to do
    if not todo:
        return time.perf_counter() - t0
    runs = [make_scenario(sc, seed=0, duration_s=duration_s, rate_hz=rate_hz) for sc in ("static", "ship")]
    for core in todo:
        for data in runs:
            align(data, core=core)
        _WARM.add(core)
    return time.perf_counter() - t0


def lock_path() -> str:
    """The machine-wide warm-up lock (beside the user cache of :func:`core.mechanization_numba.user_cache_dir`)."""
    import os

    from ..core.mechanization_numba import user_cache_dir

    return os.path.join(os.path.dirname(user_cache_dir()), "warmup.lock")


def _fingerprint(cores: tuple[str, ...]) -> str:
    """What a warm cache depends on: the package's sources (numba keys its cache on the source file's stamp and
    size), numba, the interpreter, the cache location and the cores warmed."""
    import hashlib
    import os
    from pathlib import Path

    import numba

    from ..core.mechanization_numba import user_cache_dir

    pkg = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(repr((str(pkg), numba.__version__, sys.executable, sys.version, user_cache_dir(),
                             os.environ.get("NUMBA_CACHE_DIR", ""), sorted(_core_list(cores)))).encode())
    for f in sorted(pkg.rglob("*.py")):
        st = f.stat()
        h.update(f"{f.relative_to(pkg)}:{st.st_mtime_ns}:{st.st_size}\n".encode())
    return h.hexdigest()


def _done_path() -> str:
    """The fingerprints of the warm-ups completed on this machine (beside :func:`lock_path`)."""
    import os

    return os.path.join(os.path.dirname(lock_path()), "warmup.done")


def _is_done(fingerprint: str) -> bool:
    try:
        with open(_done_path()) as fh:
            return fingerprint in fh.read().split()
    except OSError:
        return False


def _mark_done(fingerprint: str, keep: int = 32) -> None:
    import os

    try:
        with open(_done_path()) as fh:
            lines = [ln for ln in fh.read().split() if ln != fingerprint]
    except OSError:
        lines = []
    tmp = _done_path() + f".{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write("\n".join([*lines[-(keep - 1):], fingerprint]) + "\n")
    os.replace(tmp, _done_path())


def warm_up_once(cores: tuple[str, ...] = ("auto",), duration_s: float = 30.0) -> tuple[float, float]:
    """:func:`warm_up` under an exclusive file lock shared by every process of this user on this machine: when
    several processes start cold at once (the workers of a fleet), the first compiles the kernels into the on-disk
    cache while the others wait, then load them from it (about a second each), instead of every process compiling
    the same kernels at once. Once a warm-up of the same sources, cores and cache has completed on this machine
    (its fingerprint in ``warmup.done`` beside the lock), the lock is released at once and the processes load the
    cache side by side (two fleet workers: ~0.6 s each, which the lock serialised). Returns (seconds waited for the
    lock, seconds of warm-up)."""
    import fcntl
    import os

    path = lock_path()
    os.makedirs(os.path.dirname(path), exist_ok=True)
    t0 = time.perf_counter()
    fingerprint = _fingerprint(cores)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            waited = time.perf_counter() - t0
            if not _is_done(fingerprint):
                took = warm_up(cores, duration_s)
                _mark_done(fingerprint)
                return waited, took
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
    return waited, warm_up(cores, duration_s)


#: ``--jobs 2``: every core in two processes of similar compile time (the in-motion ECI cores; ``auto`` with the
#: static and Earth-frame ones). Measured cold on 2 cores at load 1-2: 60 s wall (112 CPU-s: a few kernels compiled
#: on both sides) against 92 s (89 CPU-s) in one process; another split (the ECI family, then ``auto`` last, against
#: the rest) compiled more on its longer side (46 against 39 CPU-s).
#: A core missing here goes to the last group.
GROUPS = (("liekf", "pi_liekf", "iekf", "ekf", "liekf_backtrack"), ("auto", "pkf", "ekf10", "coarse", "earth_iekf"))


def core_groups(cores: tuple[str, ...], jobs: int) -> list[list[str]]:
    """``cores`` (``"all"``: every core) in at most ``jobs`` non-empty groups: :data:`GROUPS` for two, else dealt
    round-robin."""
    todo = list(dict.fromkeys(_core_list(cores)))  # ("all": auto is also a registered core name)
    if jobs <= 1 or len(todo) <= 1:
        return [todo]
    if jobs == 2:
        a = [c for c in todo if c in GROUPS[0]]
        groups = [a, [c for c in todo if c not in a]]
    else:
        groups = [todo[i::jobs] for i in range(jobs)]
    return [g for g in groups if g]


def _warm_up_in_processes(groups: list[list[str]], duration_s: float) -> int:
    """One ``python -m insalign_ros.session.warmup --cores ...`` per group, at once; the worst exit code."""
    import subprocess

    procs = [subprocess.Popen([sys.executable, "-m", "insalign_ros.session.warmup", "--cores", ",".join(g), "--quiet",
                               "--duration-s", str(duration_s)]) for g in groups]
    return max(p.wait() for p in procs)


#: the cores :func:`warm_up` ran in this process (a second node in the same process, e.g. in the tests, starts at once)
_WARM: set = set()


def kernel_stats() -> list[dict]:
    """One row per numba kernel of the package that is loaded: name, cache directory, signatures compiled in this
    process, cache hits and misses (numba's dispatcher ``stats``). Empty without numba."""
    try:
        from numba.core.registry import CPUDispatcher
    except ImportError:  # pragma: no cover - numba is a pinned dependency
        return []
    rows, seen = [], set()
    for mod_name, mod in sorted(sys.modules.items()):
        if not mod_name.startswith("insalign_ros.") or mod is None:
            continue
        for name, obj in sorted(vars(mod).items()):
            if isinstance(obj, CPUDispatcher) and id(obj) not in seen:
                seen.add(id(obj))
                st = obj.stats
                rows.append({"kernel": f"{mod_name}.{name}", "cache_path": st.cache_path,
                             "signatures": len(obj.signatures), "cache_hits": sum(st.cache_hits.values()),
                             "cache_misses": sum(st.cache_misses.values())})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m insalign_ros.session.warmup", description=__doc__.splitlines()[0])
    ap.add_argument("--cores", default=ALL, help="comma-separated cores to compile for (default: all)")
    ap.add_argument("--duration-s", type=float, default=30.0, help="data time of each run [s] (default 30)")
    ap.add_argument("--quiet", action="store_true", help="print only the summary line")
    ap.add_argument("--json", action="store_true", help="print the per-kernel cache statistics as JSON")
    ap.add_argument("--jobs", type=int, default=1,
                    help="compile in this many processes at once (default 1; scripts/env.sh uses 2)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    cores = tuple(c.strip() for c in a.cores.split(",") if c.strip())
    if a.jobs > 1 and not a.json:
        try:
            groups = core_groups(cores, a.jobs)
        except ValueError as exc:
            print(f"insalign warm-up: {exc}", file=sys.stderr)
            return 2
        if len(groups) > 1:
            rc = _warm_up_in_processes(groups, a.duration_s)
            print(f"[insalign] numba kernels of {sum(map(len, groups))} cores ready in {time.perf_counter() - t0:.1f} s "
                  f"({len(groups)} processes)", file=sys.stderr)
            return rc
    try:
        dt = warm_up(cores, a.duration_s)
    except ValueError as exc:
        print(f"insalign warm-up: {exc}", file=sys.stderr)
        return 2
    rows = kernel_stats()
    compiled = sum(r["cache_misses"] for r in rows)
    loaded = sum(r["cache_hits"] for r in rows)
    where = sorted({r["cache_path"] for r in rows})
    if a.json:
        import json

        print(json.dumps(rows))
    print(f"[insalign] numba kernels ready in {time.perf_counter() - t0:.1f} s (alignment runs {dt:.1f} s): "
          f"{compiled} compiled, {loaded} loaded from the cache"
          + ("" if a.quiet else f"; cache in {', '.join(where) if where else '-'}"), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
