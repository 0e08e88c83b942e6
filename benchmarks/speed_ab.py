#!/usr/bin/env python3
"""Throughput of two checkouts of the package, interleaved in one run (a refactor must not cost speed). Not a unit
test.

Each repetition runs, for checkout A then checkout B (each in its own Python process with its tree first on
``sys.path``; its numba cache warmed by a first untimed pass), ``ia.align(data, core=...)`` (after one untimed run of the same) with the default
configuration (initialisation from the sensors, default outputs) on the same simulated data, and reports IMU samples
per second; the table gives the best of the repetitions per checkout and the ratio B/A. The machine's load average
goes with the table (the machine is shared: only the ratio means something).

    nice .venv/bin/python benchmarks/speed_ab.py OLD_TREE NEW_TREE [--rows iekf:ship,liekf:ship,pkf:static,ekf10:static]
        [--duration 120] [--reps 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

DEFAULT_ROWS = "iekf:ship,liekf:ship,pi_liekf:ship,ekf:ship,pkf:static,ekf10:static,auto:ship,auto:static"

CHILD = r"""
import json, sys, time
import insalign_ros as ia
rows, duration = json.loads(sys.argv[1]), float(sys.argv[2])
data = {s: ia.simulate(s, seed=1, duration_s=duration) for s in {s for _, s in rows}}
out = {}
for core, scen in rows:
    d = data[scen]
    ia.align(d, core=core)  # untimed: every kernel the run uses compiled or loaded (a 5-s run missed some)
    t0 = time.perf_counter()
    ia.align(d, core=core)
    out[f"{core}:{scen}"] = d.n / (time.perf_counter() - t0)
print("RESULT " + json.dumps({"file": ia.__file__, "rates": out}))
"""


def run_tree(tree: str, rows, duration: float) -> dict:
    env = {**os.environ, "PYTHONPATH": os.path.abspath(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps(rows), str(duration)], env=env, cwd=tree,
                       capture_output=True, text=True, timeout=3600)  # cwd: "-c" puts it first on sys.path
    line = next((x for x in r.stdout.splitlines() if x.startswith("RESULT ")), None)
    if line is None:
        raise SystemExit(f"{tree}: no result\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    res = json.loads(line[7:])
    if not res["file"].startswith(os.path.abspath(tree)):
        raise SystemExit(f"{tree}: imported {res['file']} instead of the tree's package")
    return res["rates"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("tree_a")
    ap.add_argument("tree_b")
    ap.add_argument("--rows", default=DEFAULT_ROWS)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args(argv)
    rows = [r.split(":") for r in a.rows.split(",")]
    load0 = os.getloadavg()[0]
    best = {"A": {}, "B": {}}
    for _ in range(a.reps):
        for label, tree in (("A", a.tree_a), ("B", a.tree_b)):
            for k, v in run_tree(tree, rows, a.duration).items():
                best[label][k] = max(best[label].get(k, 0.0), v)
    load1 = os.getloadavg()[0]
    print(f"A = {a.tree_a}\nB = {a.tree_b}\n{a.duration:.0f} s of data per scenario, best of {a.reps} interleaved "
          f"repetitions; load average {load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores\n")
    print("| core:scenario | A [samples/s] | B [samples/s] | B/A |\n|---|---|---|---|")
    for k in best["A"]:
        print(f"| {k} | {best['A'][k]:,.0f} | {best['B'][k]:,.0f} | {best['B'][k] / best['A'][k]:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
