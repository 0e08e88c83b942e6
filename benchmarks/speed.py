#!/usr/bin/env python3
"""Throughput of the paths users take, next to a plain numpy loop measured in the same run (issue 28, item 2).
Not a unit test.

Interleaved in one run (the machine is shared: every rate is also given as a ratio to the plain numpy per-sample
loop measured in the same minute, before and after each repetition):

* ``numpy loop``: the loop a filter written in numpy runs per sample: Rodrigues, attitude update, the 15x15
  transition of the imperfect IEKF built per sample, ``P = A P A^T + Q`` (:func:`numpy_loop`);
* ``ia.align(bag)``: the default configuration (initialisation from the sensors, the default output period) on a
  contract bag: reading the bag plus the session;
* ``ia.align(data)``: the same on the data in memory (the session alone);
* ``insalign-align BAG``: the command line end to end (``insalign_ros.cli.align.main``: read the bag, align from the
  sensors at its default 2-Hz outputs, write CSV, JSON and PNG);
* lab configuration (extra column, how the research benchmarks run): ``ia.align(data, init_mode="truth",
  output_period_s=1.0)``;
* ``--floors`` (two more columns, what the default path would reach if its outputs cost nothing): the default with
  one output per hour of data (``output_period_s=3600``, no outputs inside the run), and the same from the truth
  (``init_mode="truth"``: no search for the heading either); what is left is the filtering and the per-fix stages.

Data: ``ship`` (100 Hz, GNSS at 1 Hz) for the in-motion cores and ``auto``, ``static`` (125 Hz, engine vibration,
GNSS fixes give the site) for the static ones and ``auto``; both written once to bags in a temporary directory.
The machine's load average is printed with the table.

    nice .venv/bin/python benchmarks/speed.py [--rows iekf:ship,liekf:ship,pkf:static,ekf10:static,auto:ship,auto:static]
        [--duration 300] [--reps 3] [--floors]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, as the session runs
    os.environ.setdefault(_v, "1")
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import insalign_ros as ia  # noqa: E402

DEFAULT_ROWS = "iekf:ship,liekf:ship,pkf:static,ekf10:static,auto:ship,auto:static"
#: the lab configuration of the research benchmarks (truth initialisation, 1-s outputs)
LAB = dict(init_mode="truth", init_rpy_error_deg=[1.0, 1.0, 10.0], output_period_s=1.0)
COLUMNS = ("bag", "data", "cli", "lab")
#: ``--floors``: the default without outputs inside the run, and without them from the truth
NO_OUTPUTS = dict(output_period_s=3600.0)
FLOORS = {"no_out": NO_OUTPUTS, "no_out_truth": dict(NO_OUTPUTS, init_mode="truth", init_rpy_error_deg=[1.0, 1.0, 10.0])}


def numpy_loop(omega_ib_b: np.ndarray, dt_s: float = 0.01) -> float:
    """The plain numpy per-sample loop (Rodrigues + 15x15 ``P = A P A^T + Q``); returns samples/s.

    A is the imperfect IEKF's transition (filters/iekf.py) built per sample: R = exp(phi)^T on the three navigation
    blocks, dt R coupling position to velocity, -dt I bias columns; Q diagonal."""
    P = np.eye(15) * 1e-4
    Q = np.diag(np.r_[np.full(3, 1e-11), np.full(3, 1e-8), np.zeros(3), np.full(6, 1e-14)]) * dt_s
    C = np.eye(3)
    t0 = time.perf_counter()
    for w in omega_ib_b:
        phi = w * dt_s
        th = np.linalg.norm(phi)
        K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
        dC = np.eye(3) + (np.sin(th) / th) * K + ((1.0 - np.cos(th)) / th**2) * (K @ K)
        C = C @ dC
        R = dC.T
        A = np.eye(15)
        A[0:3, 0:3] = R
        A[3:6, 3:6] = R
        A[6:9, 6:9] = R
        A[6:9, 3:6] = dt_s * R
        A[0:3, 9:12] = -dt_s * np.eye(3)
        A[3:6, 12:15] = -dt_s * np.eye(3)
        P = A @ P @ A.T + Q
    return len(omega_ib_b) / (time.perf_counter() - t0)


def cli_args(bag: Path, core: str, out_dir: Path) -> list[str]:
    """``insalign-align BAG`` as a user runs it on a bag (initialisation from the sensors: a recorded bag has no
    reference; the simulated one has, so the session parameter says it), progress bar off."""
    return [str(bag), "--core", core, "--session-param", "init_mode=sensors", "--out-dir", str(out_dir),
            "--no-progress"]


def timed(fn) -> float:
    """Wall time of ``fn()`` [s] (its standard output swallowed)."""
    with contextlib.redirect_stdout(io.StringIO()):
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0


def run_row(core: str, data, bag: Path, out_dir: Path, floors: bool = False) -> dict:
    """Seconds of each column for one (core, data) row."""
    from insalign_ros.cli.align import main as cli_main

    def cli():
        if cli_main(cli_args(bag, core, out_dir)) != 0:
            raise RuntimeError(f"insalign-align {bag.name} --core {core} failed")

    out = {"bag": timed(lambda: ia.align(str(bag), core=core)),
           "data": timed(lambda: ia.align(data, core=core)),
           "cli": timed(cli),
           "lab": timed(lambda: ia.align(data, core=core, **LAB))}
    for name, kw in FLOORS.items() if floors else ():
        out[name] = timed(lambda: ia.align(data, core=core, **kw))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", default=DEFAULT_ROWS, help="core:scenario pairs")
    ap.add_argument("--duration", type=float, default=300.0, help="seconds of each scenario")
    ap.add_argument("--reps", type=int, default=3, help="repetitions (interleaved); the best of them is reported")
    ap.add_argument("--floors", action="store_true",
                    help="also the default without outputs inside the run, and that from the truth")
    ap.add_argument("--json-out", default="")
    args = ap.parse_args(argv)
    rows = [tuple(r.split(":")) for r in args.rows.split(",")]
    cmd = "nice .venv/bin/python benchmarks/speed.py " + " ".join(argv if argv is not None else sys.argv[1:])
    from insalign_ros.io.bag import write_bag

    with tempfile.TemporaryDirectory(prefix="insalign_speed_") as tmp:
        tmp = Path(tmp)
        data, bags = {}, {}
        for sc in sorted({s for _, s in rows}):
            data[sc] = ia.simulate(sc, seed=0, duration_s=args.duration)
            bags[sc] = write_bag(data[sc], tmp / f"{sc}_bag")
        omega = data[rows[0][1]].omega_ib_b[1:10001]
        for core, sc in rows:  # warm-up: numba compilation or cache load, imports, matplotlib
            short = ia.simulate(sc, seed=1, duration_s=20.0)
            ia.align(short, core=core)
            ia.align(short, core=core, **LAB)
            for kw in FLOORS.values() if args.floors else ():
                ia.align(short, core=core, **kw)
        run_row(rows[0][0], data[rows[0][1]], bags[rows[0][1]], tmp / "out")
        load0 = os.getloadavg()
        cols = COLUMNS + (tuple(FLOORS) if args.floors else ())
        res = {r: {c: [] for c in cols} for r in rows}
        loop = []
        for _ in range(args.reps):
            loop.append(numpy_loop(omega))
            for core, sc in rows:
                for c, s in run_row(core, data[sc], bags[sc], tmp / "out", args.floors).items():
                    res[(core, sc)][c].append(data[sc].n / s)
            loop.append(numpy_loop(omega))
        load1 = os.getloadavg()
    md = table(rows, res, loop, data, load0, load1, cmd, args)
    print(md)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"loop": loop, "load": [load0, load1], "results": {
            f"{c}:{s}": v for (c, s), v in res.items()}}))
    return 0


def table(rows, res, loop, data, load0, load1, cmd, args) -> str:
    base = max(loop)
    L = [f"Command: `{cmd}`  ",
         f"Load average (1 / 5 / 15 min) {load0[0]:.2f} / {load0[1]:.2f} / {load0[2]:.2f} before, {load1[0]:.2f} / "
         f"{load1[1]:.2f} / {load1[2]:.2f} after, on {os.cpu_count()} cores (a shared machine: absolute rates move "
         f"with the load; the ratios are measured in the same minute).  ",
         f"Plain numpy per-sample loop (Rodrigues + 15x15 P = A P A' + Q): best {base:,.0f} samples/s "
         f"(all: {', '.join(f'{x:,.0f}' for x in loop)}).  ",
         "Data: " + ", ".join(f"{sc} {args.duration:.0f} s ({d.n:,} IMU samples)" for sc, d in sorted(data.items()))
         + f"; best of {args.reps} interleaved repetitions.", "",
         "Samples/s and the ratio to the numpy loop (x):", "",
         "| core | data | `ia.align(bag)` default | x | `ia.align(data)` default | x | `insalign-align BAG` | x "
         "| CLI time / `ia.align(bag)` | lab: truth init, 1-s outputs | x |"
         + (" no outputs | x | no outputs, truth init | x |" if args.floors else ""),
         "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|---|---|" if args.floors else "")]
    for core, sc in rows:
        r = {k: max(v) for k, v in res[(core, sc)].items()}
        L.append(f"| {core} | {sc} | {r['bag']:,.0f} | {r['bag'] / base:.2f} | {r['data']:,.0f} | "
                 f"{r['data'] / base:.2f} | {r['cli']:,.0f} | {r['cli'] / base:.2f} | {r['bag'] / r['cli']:.2f} | "
                 f"{r['lab']:,.0f} | {r['lab'] / base:.2f} |"
                 + "".join(f" {r[c]:,.0f} | {r[c] / base:.2f} |" for c in FLOORS if c in r))
    return "\n".join(L)


if __name__ == "__main__":
    sys.exit(main())
