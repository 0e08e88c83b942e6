"""``insalign-align DIR``: every bag under a directory, each aligned as ``insalign-align BAG`` would (same options),
as independent Dask tasks (a LocalCluster of ``--workers`` processes, or ``--scheduler tcp://host:8786``, or
``--serial``), with a progress bar; per-bag outputs in ``<out-dir>/<bag>/`` and one summary table of the fleet,
``<out-dir>/fleet_summary.csv`` (and .md), in bag order, with the final attitude and its 3-sigma of every bag
(truth or not). A bag that fails is a row with its one-line error, not a crash of the fleet.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
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


#: final_rpy_deg / final_3sigma_deg: the last estimate (roll, pitch, yaw; yaw from East, CCW) and its 3-sigma [deg],
#: there with or without truth; final_err_rpy_deg / rmse_rpy_deg only with truth; warnings: the input's (IMU axes)
COLUMNS = ["bag", "rc", "core", "init_mode", "duration_s", "aligned_first_raised_at_s", "restarts", "final_aligned",
           "final_rpy_deg", "final_3sigma_deg", "final_err_rpy_deg", "rmse_rpy_deg", "imu_processed", "imu_gaps",
           "imu_rejected", "gnss_accepted", "gnss_gated", "divergences", "wall_s", "warnings", "error"]


def run_fleet(main, root: str, argv: list[str], out_dir: str, workers: int, scheduler: str, serial: bool,
              progress: bool = True) -> list[dict]:
    """Align every bag under ``root`` with ``main`` (``insalign-align``'s entry point); write and return the summary
    rows (bag order)."""
    from ..eval.parallel import run_tasks

    bags = find_bags(Path(root))
    if not bags:
        raise ValueError(f"{root}: no bag (a directory with metadata.yaml, a .bag or an .mcap file) under it")
    out = Path(out_dir)
    names = [str(b.relative_to(root)).replace("/", "__") or b.name for b in bags]
    tasks = [(main, str(b), argv, str(out / n)) for b, n in zip(bags, names)]
    rows = run_tasks(align_bag, tasks, workers=workers, scheduler=scheduler, serial=serial, desc="bags",
                     progress=progress, preload=PRELOAD)
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
