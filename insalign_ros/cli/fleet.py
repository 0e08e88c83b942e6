"""``insalign-align DIR``: every bag under a directory, each aligned as ``insalign-align BAG`` would (same options),
as independent Dask tasks (a LocalCluster of ``--workers`` processes, or ``--scheduler tcp://host:8786``, or
``--serial``), with a progress bar; per-bag outputs in ``<out-dir>/<bag>/`` and one summary table of the fleet,
``<out-dir>/fleet_summary.csv`` (and .md), in bag order, with the final attitude and its 3-sigma of every bag
(truth or not). A bag that fails is a row with its one-line error, not a crash of the fleet.

Scaling (docs/speed.md, "Fleets"): every worker compiles the kernels before its first bag under a machine-wide lock
(``session.warmup.warm_up_once``: the first worker of a machine compiles into the on-disk cache, the others load
it); with ``ship_bags`` (the default on a remote scheduler, whose workers need not see this file system) each bag is
read here just before it is submitted and sent to the worker as bytes, at most ``2 x workers`` at a time, and its
output files come back the same way.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import tempfile
import time
from pathlib import Path


#: what aligning a bag imports (the runner, the cores, numba's kernels, the LMI solver, the bag reader): loaded once
#: in the fork server the LocalCluster's workers start from, not once per worker (``eval.parallel.make_client``)
PRELOAD = ("insalign_ros", "insalign_ros.cli.fleet", "insalign_ros.cli.align", "insalign_ros.session.offline",
           "insalign_ros.filters.registry", "insalign_ros.core.mechanization_numba", "insalign_ros.filters.lmi",
           "insalign_ros.io.bag", "cvxpy")


def find_bags(root: Path) -> list[Path]:
    """The bags under ``root``, sorted by path: rosbag2 directories (with a metadata.yaml), ROS 1 ``.bag`` files and
    ``.mcap`` files that are not inside a rosbag2 directory."""
    dirs = {p.parent for p in Path(root).rglob("metadata.yaml")}
    files = {p for ext in ("*.bag", "*.mcap") for p in Path(root).rglob(ext)
             if p.is_file() and not any(d in p.parents for d in dirs)}
    return sorted(dirs | files)


def align_bag(main, bag: str, argv: list[str], out_dir: str) -> dict:
    """One bag through ``main`` (``insalign-align``'s entry point, passed in by cli/align.py so that this module
    does not import it back) with ``argv`` (the user's options); its summary row."""
    t0 = time.perf_counter()
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main([bag, *argv, "--out-dir", out_dir, "--no-progress"])
        except Exception as exc:  # noqa: BLE001 - one bad bag is a row of the table, not the end of the fleet
            print(f"internal error: {type(exc).__name__}: {exc}", file=err)
            rc = 1
    row: dict = {"bag": bag, "rc": rc, "wall_s": round(time.perf_counter() - t0, 2)}
    if rc != 0:
        row["error"] = err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else f"exit {rc}"
        return row
    metrics = sorted(Path(out_dir).glob("*_metrics.json"))
    m = json.loads(metrics[-1].read_text()) if metrics else {}
    c = m.get("counters", {})
    row.update({k: m.get(k) for k in ("core", "init_mode", "duration_s", "aligned_first_raised_at_s", "restarts",
                                      "final_aligned", "final_rpy_deg", "final_3sigma_deg", "final_err_rpy_deg",
                                      "rmse_rpy_deg")})
    row["warnings"] = "; ".join(m.get("warnings", []))
    row.update({k: c.get(k, 0) for k in ("imu_processed", "imu_gaps", "imu_rejected", "gnss_accepted", "gnss_gated",
                                         "divergences")})
    return row


def pack_bag(bag: Path) -> dict[str, bytes]:
    """A bag's files as ``{path relative to the bag's parent: bytes}`` (a rosbag2 directory: every file in it; a ROS 1
    ``.bag`` or an ``.mcap`` file: itself)."""
    bag = Path(bag)
    if bag.is_dir():
        return {str(p.relative_to(bag.parent)): p.read_bytes() for p in sorted(bag.rglob("*")) if p.is_file()}
    return {bag.name: bag.read_bytes()}


def ship_task(task: tuple) -> tuple:
    """``(main, bag, argv, out_dir)`` -> the same with the bag's bytes appended (run in the client, just before the
    task is submitted)."""
    main, bag, argv, out_dir = task
    return main, bag, argv, out_dir, pack_bag(Path(bag))


def align_shipped_bag(main, bag: str, argv: list[str], out_dir: str, files: dict[str, bytes]) -> dict:
    """:func:`align_bag` on a worker that may not see the client's file system: the bag's ``files`` are written to a
    temporary directory, aligned there, and the output files come back in the row (``_outputs``: name -> bytes)."""
    with tempfile.TemporaryDirectory(prefix="insalign-fleet-") as tmp:
        root = Path(tmp) / "in"
        for rel, data in files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(data)
        local = root / Path(bag).name
        out = Path(tmp) / "out"
        row = align_bag(main, str(local), argv, str(out))
        row["bag"] = bag
        if "error" in row:
            row["error"] = row["error"].replace(str(local), bag)
        row["_outputs"] = {p.name: p.read_bytes() for p in sorted(out.glob("*")) if p.is_file()} if out.is_dir() else {}
    return row


def _write_outputs(out_dirs: list[str]):
    """``on_result`` of a shipped fleet: write a row's returned files into its output directory, keep the row."""

    def write(i: int, row: dict) -> dict:
        files = row.pop("_outputs", {})
        if files:
            d = Path(out_dirs[i])
            d.mkdir(parents=True, exist_ok=True)
            for name, data in files.items():
                (d / name).write_bytes(data)
        return row

    return write


def warm_up_worker(cores: tuple[str, ...]) -> str:
    """Worker set-up: compile (or load) the kernels of ``cores`` once per machine before the first bag."""
    from ..session.warmup import warm_up_once

    waited, took = warm_up_once(cores)
    return f"kernels of {','.join(cores)} ready: waited {waited:.1f} s for the machine's lock, warm-up {took:.1f} s"


def _core_of(argv: list[str]) -> str:
    for k, a in enumerate(argv):
        if a == "--core" and k + 1 < len(argv):
            return argv[k + 1]
        if a.startswith("--core="):
            return a.split("=", 1)[1]
    return "auto"


#: final_rpy_deg / final_3sigma_deg: the last estimate (roll, pitch, yaw; yaw from East, CCW) and its 3-sigma [deg],
#: there with or without truth; final_err_rpy_deg / rmse_rpy_deg only with truth; warnings: the input's (IMU axes)
COLUMNS = ["bag", "rc", "core", "init_mode", "duration_s", "aligned_first_raised_at_s", "restarts", "final_aligned",
           "final_rpy_deg", "final_3sigma_deg", "final_err_rpy_deg", "rmse_rpy_deg", "imu_processed", "imu_gaps",
           "imu_rejected", "gnss_accepted", "gnss_gated", "divergences", "wall_s", "warnings", "error"]


def run_fleet(main, root: str, argv: list[str], out_dir: str, workers: int, scheduler: str, serial: bool,
              progress: bool = True, ship_bags: bool | None = None, stats: dict | None = None) -> list[dict]:
    """Align every bag under ``root`` with ``main`` (``insalign-align``'s entry point); write and return the summary
    rows (bag order). ``ship_bags``: send each bag to its worker as bytes (None: only with a remote ``scheduler``);
    ``stats``: filled with the timing records of :func:`eval.parallel.run_tasks`."""
    from ..eval.parallel import run_tasks

    bags = find_bags(Path(root))
    if not bags:
        raise ValueError(f"{root}: no bag (a directory with metadata.yaml, a .bag or an .mcap file) under it")
    out = Path(out_dir)
    names = [str(b.relative_to(root)).replace("/", "__") or b.name for b in bags]
    tasks = [(main, str(b), argv, str(out / n)) for b, n in zip(bags, names)]
    ship = bool(scheduler) if ship_bags is None else ship_bags
    # bigger bags first (the short ones fill the end); the bag's size on disk is the cost estimate
    cost = [sum(p.stat().st_size for p in (b.rglob("*") if b.is_dir() else [b]) if p.is_file()) for b in bags]
    n_workers = workers or (os.cpu_count() or 1)
    rows = run_tasks(align_shipped_bag if ship else align_bag, tasks, workers=workers, scheduler=scheduler,
                     serial=serial, desc="bags", progress=progress, preload=PRELOAD, cost=cost, stats=stats,
                     worker_setup=None if serial else (warm_up_worker, ((_core_of(argv),),)),
                     prepare=ship_task if ship else None, window=2 * n_workers if ship else 0,
                     on_result=_write_outputs([t[3] for t in tasks]) if ship else None)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "fleet_summary.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(_cell(r.get(k)) for k in COLUMNS) + " |" for r in rows]
    (out / "fleet_summary.md").write_text("\n".join(lines) + "\n")
    return rows


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.3f}"
    if isinstance(v, list):
        return " / ".join(f"{x:.3f}" if isinstance(x, float) else str(x) for x in v)
    return str(v)
