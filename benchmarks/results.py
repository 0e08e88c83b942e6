#!/usr/bin/env python3
"""Regenerate docs/results.md: shortened runs of the benchmarks, each table with the command that makes it and the
machine load while it ran. Not a unit test.

    nice .venv/bin/python benchmarks/results.py --write docs/results.md
    nice .venv/bin/python benchmarks/results.py --only speed,static      # some sections, printed

Every benchmark runs in this process (``module.main(argv)``; the same as the printed command) through ``ia.align``,
the session users run. The runs are short (a seed or two, minutes of data) so that the whole page takes about ten
minutes on a 2-core machine; each benchmark's docstring gives the full-length command. Sections whose data are absent
(../shared/data) say so instead of a table.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
from insalign_ros.io.datasets import shared_data_dir  # noqa: E402

#: the shared data ($INSALIGN_DATA, else next to the checkout or above a worktree inside it)
DATA = (shared_data_dir(__file__) or ROOT.parent / "shared" / "data") / "kitti_raw_oxts_sync"


@dataclass
class Section:
    key: str
    title: str
    text: str  # what the table shows and where the method is documented
    module: str
    argv: list
    needs: Path | None = None  # data the section reads
    data_arg: bool = False  # pass ``--data needs`` (not shown in the command: the default finds it in a checkout)

    @property
    def command(self) -> str:
        return f"nice .venv/bin/python benchmarks/{self.module}.py {' '.join(self.argv)}".rstrip()


SECTIONS = [
    Section("inmotion_ship", "In-motion alignment: ship",
            "GNSS-aided cores from a 60-deg initial yaw error (roll and pitch 10 deg), the ship's IMU grade, 1-s outputs "
            "(docs/inmotion_cores.md). RMSE over the run, steady-state error, time for |yaw| to stay below 1 deg, "
            "NEES; the physical floor is printed with the table.",
            "yaw_sweep", ["--scenario", "ship", "--seeds", "1", "--yaws", "60", "--cores", "liekf,pi_liekf,iekf,ekf",
                          "--duration", "120", "--no-throughput", "--serial"]),
    Section("inmotion_car", "In-motion alignment: car",
            "The same on the car scenario (MEMS IMU, industrial grade).",
            "yaw_sweep", ["--scenario", "car", "--seeds", "1", "--yaws", "60", "--cores", "liekf,iekf,ekf",
                          "--duration", "120", "--no-throughput", "--serial"]),
    Section("kitti", "Real data: KITTI 2011_10_03_drive_0042",
            "OXTS IMU and GNSS of a real drive, initial error 10/10/60 deg from the OXTS reference "
            "(benchmarks/kitti_0042.py; docs/bag_contract.md for the importer).",
            "kitti_0042", ["--cores", "liekf", "iekf"], needs=DATA, data_arg=True),
    Section("flag", "Aligned flag, Monte Carlo",
            "The session's aligned flag at 10 Hz with the default criteria (session/flag.py): runs in which the flag was "
            "up while the true yaw error exceeded its bound, and the delay of the first rise.",
            "aligned_flag_mc", ["--runs", "4", "--core", "iekf", "--duration-s", "120", "--serial"]),
    Section("static", "Stationary alignment",
            "PKF and 10-state EKF with zero-velocity updates on a navigation-grade IMU; the floors per run "
            "(docs/static_alignment.md).",
            "static_sigma_r", ["--scenarios", "static_navgrade", "--seeds", "1", "--az0", "90", "--sigma-r", "0.01",
                               "--no-write", "--serial"]),
    Section("coarse", "Coarse alignment",
            "Analytic coarse alignment (both methods) on a navigation-grade IMU at rest, against the bias floor and "
            "the combined floor (bias + ARW).",
            "coarse_navgrade", ["--seeds", "1", "--duration-s", "300"]),
    Section("backtracking", "Forward-backward alignment",
            "Two-position alignment with the inverse-alignment paper's IMU (coarse + KF, forward and forward-backward "
            "invariant filter) and backtracking on the ship (docs/backtracking.md).",
            "backtracking", ["--seeds", "1", "--windows", "60", "--ship-seeds", "1", "--ship-windows", "20",
                             "--timing-duration", "60"]),
    Section("auto", "core auto: parked, then driving",
            "The default core: static alignment while parked, the in-motion core once the vehicle moves "
            "(docs/session.md, docs/motion_detector.md).",
            "auto_mode_mc", ["--runs", "2", "--grades", "park_drive", "--serial"]),
    Section("speed", "Speed",
            "Samples per second of the paths users take (default configuration: initialisation from the sensors, "
            "default output period) next to a plain numpy per-sample loop measured in the same run; the lab "
            "configuration as an extra column (docs/speed.md explains the figures).",
            "speed", ["--duration", "60", "--reps", "1", "--rows", "iekf:ship,liekf:ship,pkf:static,ekf10:static,"
                      "auto:ship"]),
]

_DROP = re.compile(r"^\s*(command:|Command:|sweep: |sweep wall time:|seed \d+ done|throughput \(samples/s.*\{\}$|\{'name': )")


def clean(text: str) -> str:
    """The benchmark's own output without its command line (the section gives it), progress lines or temporary
    paths; its headings one level down (the section is the ## level)."""
    out, seen = [], set()
    for line in text.splitlines():
        if _DROP.match(line):
            continue
        if line.strip() and not line.startswith("|") and line in seen:  # a line a benchmark printed twice
            continue
        seen.add(line)
        line = re.sub(r"(/tmp|/var/tmp)/\S+", "<tmp>", line)
        line = re.sub(r"\s*\(?(branch|commit) [0-9a-f]{7,}\)?", "", line)
        if line.startswith("#"):
            line = "#" + line
        out.append(line.rstrip())
    while out and not out[0]:
        out.pop(0)
    return "\n".join(out).strip() + "\n"


def run_section(s: Section) -> str:
    head = [f"## {s.title}", "", s.text, ""]
    if s.needs is not None and not s.needs.exists():
        return "\n".join(head + [f"Not run: the data ({s.needs.name}) are absent on this machine.", ""])
    mod = importlib.import_module(s.module)
    buf = io.StringIO()
    l0, t0 = os.getloadavg(), time.perf_counter()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        try:
            rc = mod.main(list(s.argv) + (["--data", str(s.needs)] if s.data_arg else []))
        except SystemExit as exc:  # a benchmark that exits (argparse, a missing input)
            rc = exc.code
    wall, l1 = time.perf_counter() - t0, os.getloadavg()
    body = clean(buf.getvalue())
    status = "" if rc in (None, 0) else f" (exit status {rc})"
    head += [f"Command: `{s.command}`  ",
             f"Machine load (1-min load average) {l0[0]:.1f} at the start, {l1[0]:.1f} at the end, on "
             f"{os.cpu_count()} cores; {wall:.0f} s wall{status}.", ""]
    return "\n".join(head) + "\n" + body


PREAMBLE = """# Results

What the package achieves, measured. Every table below is regenerated by one command,

    nice .venv/bin/python benchmarks/results.py --write docs/results.md

from shortened runs of the benchmarks in benchmarks/ (a seed or two, minutes of data: the whole page in about ten
minutes on a 2-core machine). Each table gives the command that makes it and the machine's load while it ran: the
machine is shared, so wall times and rates move with the load; accuracy does not (fixed seeds). Every run goes
through `insalign_ros.align`, the session the node and `insalign-align` run. For the full-length runs use the
command in each benchmark's docstring; the measurements behind the design decisions, with their history, are in
research/notebook/ (not part of the documentation).

"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--write", type=Path, help="write the page here (default: print it)")
    ap.add_argument("--only", default="", help="comma-separated section keys: " + ",".join(s.key for s in SECTIONS))
    args = ap.parse_args(argv)
    keys = set(args.only.split(",")) if args.only else None
    parts, t0 = [PREAMBLE], time.perf_counter()
    for s in SECTIONS:
        if keys is not None and s.key not in keys:
            continue
        print(f"[results] {s.key} ...", file=sys.stderr, flush=True)
        t = time.perf_counter()
        parts.append(run_section(s))
        print(f"[results] {s.key}: {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    page = "\n".join(parts)
    page += f"\nThe page took {time.perf_counter() - t0:.0f} s to regenerate.\n"
    if args.write:
        args.write.write_text(page)
        print(f"wrote {args.write}", file=sys.stderr)
    else:
        print(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
