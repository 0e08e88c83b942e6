#!/usr/bin/env python3
"""Offline throughput of the alignment cores (issue 16, items 1 and 4). Not a unit test.

In one run, interleaved (the machine is shared: every figure is also given as a ratio to the plain numpy loop
measured in the same minute):

* ``numpy loop``: the plain per-sample loop a filter written in numpy runs: Rodrigues, attitude update, the 15x15
  transition of the imperfect IEKF built per sample, ``P = A P A^T + Q`` (:func:`numpy_loop`);
* ``ia.align``: the session path users take (``insalign_ros.align``, truth init, 1 s outputs): the default (the
  session's fast path, compiled propagation), the session one sample at a time (``AlignmentSession.fast_path =
  False``, the path before it), and that with the numpy reference propagation (``mechanization_numba.ENABLED =
  False``);
* ``core``: the core alone with the session's call pattern (propagate per sample, the GNSS fixes or 10 Hz zero-velocity
  updates, one estimate per second), and with ``propagate_arrays`` between the updates where the core has it;
* the per-stage split of one ``ia.align`` run (benchmarks/sweep.py StageTimer).

Data: 300 s of the ``ship`` scenario (100 Hz) for the in-motion cores, of the ``static`` scenario (125 Hz, engine
vibration) for the static ones (the session runs their zero-velocity updates; on a moving ship they make no sense).

    nice .venv/bin/python benchmarks/speed.py [--cores iekf,liekf,pkf,ekf10] [--duration 300] [--reps 3]
        [--clock wall|cpu]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
import types
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # one core (and CPU time = one thread's)
    os.environ.setdefault(_v, "1")
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import insalign_ros as ia  # noqa: E402
from insalign_ros.core import mechanization_numba as nb  # noqa: E402
from insalign_ros.core.types import GnssFix, ImuSample  # noqa: E402
from insalign_ros.filters import registry  # noqa: E402
from insalign_ros.session.session import AlignmentSession  # noqa: E402
import sweep  # noqa: E402
from sweep import StageTimer, format_stages  # noqa: E402

STATIC_CORES = ("pkf", "ekf10", "coarse")
KW = dict(init_mode="truth", init_rpy_error_deg=[1.0, 1.0, 10.0], output_period_s=1.0)
#: the clock of every rate: wall time (``time.perf_counter``, default) or, with ``--clock cpu``, this process's CPU
#: time (``time.process_time``: on a machine shared with other jobs the time the process waited for a core is not
#: counted; every run here is single-threaded, so it is the time the run would take alone on a quiet core)
CLOCK = [time.perf_counter]


def numpy_loop(omega_ib_b: np.ndarray, dt_s: float = 0.01) -> float:
    """The plain numpy per-sample loop (Rodrigues + 15x15 ``P = A P A^T + Q``); returns samples/s.

    A is the imperfect IEKF's transition (filters/iekf.py) built per sample: R = exp(phi)^T on the three navigation
    blocks, dt R coupling position to velocity, -dt I bias columns; Q diagonal."""
    P = np.eye(15) * 1e-4
    Q = np.diag(np.r_[np.full(3, 1e-11), np.full(3, 1e-8), np.zeros(3), np.full(6, 1e-14)]) * dt_s
    C = np.eye(3)
    t0 = CLOCK[0]()
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
    return len(omega_ib_b) / (CLOCK[0]() - t0)


def align_rate(d, core: str, compiled: bool, fast_session: bool = True) -> float:
    """``ia.align`` samples/s: compiled propagation or the numpy reference; the session's fast path (IMU pushed as
    arrays, runs between events as arrays) or one push and one ``_step`` per sample."""
    nb.ENABLED = compiled and nb.HAVE_NUMBA
    AlignmentSession.fast_path = fast_session
    try:
        t0 = CLOCK[0]()
        ia.align(d, core=core, **KW)
        return d.n / (CLOCK[0]() - t0)
    finally:
        nb.ENABLED = nb.HAVE_NUMBA
        AlignmentSession.fast_path = True


def core_rate(d, core_name: str, arrays: bool) -> float:
    """The core alone, driven like the session drives it (no session): samples/s."""
    core = registry.make_core(core_name)
    v0 = d.v_n[0] if d.v_n is not None else np.zeros(3)
    core.initialize(float(d.t_s[0]), float(d.lat_rad[0]), float(d.lon_rad[0]), float(d.h_m[0]), d.C_b_n[0], v0,
                    np.diag(np.radians([1.0, 1.0, 10.0]) ** 2), 0.1, 1.0)
    t, w, f = d.t_s, d.omega_ib_b, d.f_ib_b
    if core.supports_gnss:  # the IMU index at which each fix is applied (first sample at or after its stamp)
        ev = [(int(k), GnssFix(float(d.gnss_t_s[j]), d.gnss_p_e[j], d.gnss_R_e[j]))
              for j, k in enumerate(np.searchsorted(t, d.gnss_t_s)) if 0 < k < d.n]
    else:
        every = max(1, int(round(0.1 / float(t[1] - t[0]))))
        ev = [(k, None) for k in range(every, d.n, every)]
    out_every = max(1, int(round(1.0 / float(t[1] - t[0]))))
    t0 = CLOCK[0]()
    k0 = 1
    for k, fix in ev + [(d.n, None)]:
        if arrays:
            core.propagate_arrays(t[k0:k + 1], w[k0:k + 1], f[k0:k + 1])
        else:
            for i in range(k0, min(k + 1, d.n)):
                core.propagate(ImuSample(float(t[i]), w[i], f[i]))
        k0 = k + 1
        if k >= d.n:
            break
        if fix is not None:
            core.update_gnss(fix)
        elif not core.supports_gnss:
            core.update_zero_velocity(float(t[k]), 0.01)
        if (k // out_every) != ((k - 1) // out_every):
            core.estimate()
    core.estimate()
    rate = (d.n - 1) / (CLOCK[0]() - t0)
    core.close()
    return rate


@contextlib.contextmanager
def _stage_clock(clock):
    """Run benchmarks/sweep.py's StageTimer on ``clock`` (it reads ``time.perf_counter`` from its module)."""
    saved = sweep.time
    sweep.time = types.SimpleNamespace(perf_counter=clock)
    try:
        yield
    finally:
        sweep.time = saved


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cores", default="iekf,liekf,pkf,ekf10")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--reps", type=int, default=3, help="repetitions (interleaved); the best of them is reported")
    ap.add_argument("--json-out", default="")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="rates and the per-stage split from wall time or from this process's CPU time (a shared, "
                         "loaded machine)")
    args = ap.parse_args(argv)
    CLOCK[0] = time.process_time if args.clock == "cpu" else time.perf_counter
    cores = args.cores.split(",")
    cmd = "nice .venv/bin/python benchmarks/speed.py " + " ".join(argv if argv is not None else sys.argv[1:])
    t_read = time.perf_counter()
    data = {"ship": ia.simulate("ship", seed=0, duration_s=args.duration),
            "static": ia.simulate("static", seed=0, duration_s=args.duration)}
    t_read = time.perf_counter() - t_read
    omega = data["ship"].omega_ib_b[1:20001]
    for c in cores:  # warm-up: numba compilation / cache load, imports, LMI set-up
        d = data["static" if c in STATIC_CORES else "ship"]
        ia.align(ia.simulate("static" if c in STATIC_CORES else "ship", seed=1, duration_s=5.0), core=c, **KW)
        core_rate(d, c, False)
    load0 = os.getloadavg()
    res = {c: {"align_compiled": [], "align_per_sample": [], "align_reference": [], "core_samples": [],
               "core_arrays": []} for c in cores}
    loop = []
    for _ in range(args.reps):
        loop.append(numpy_loop(omega))
        for c in cores:
            d = data["static" if c in STATIC_CORES else "ship"]
            r = res[c]
            r["align_compiled"].append(align_rate(d, c, True))
            r["align_per_sample"].append(align_rate(d, c, True, fast_session=False))
            r["align_reference"].append(align_rate(d, c, False, fast_session=False))
            r["core_samples"].append(core_rate(d, c, False))
            r["core_arrays"].append(core_rate(d, c, True))
        loop.append(numpy_loop(omega))
    stage_lines = []
    for c in cores:
        d = data["static" if c in STATIC_CORES else "ship"]
        with StageTimer() as st, _stage_clock(CLOCK[0]):
            # the offline path checks the IMU once and pushes checked slices; the Euler errors come at the end
            st._wrap(AlignmentSession, "_imu_array_checks", "input")
            st._wrap(AlignmentSession, "_push_imu_checked", "input")
            st._wrap(AlignmentSession, "_fill_deferred_errors", "outputs")
            st.align(d, core=c, **KW)
        stage_lines.append(f"| {c} | " + " | ".join(
            f"{1e6 * st.stages()[k] / d.n:.1f}" for k in ("read", "input", "propagate", "update", "outputs",
                                                          "session", "total")) + " |")
        print(f"stages {c}: {format_stages(st.stages(), d.n)}", file=sys.stderr)
    load1 = os.getloadavg()
    base = max(loop)
    L = [f"Command: `{cmd}`  ",
         f"Load average (1 min) {load0[0]:.2f} before, {load1[0]:.2f} after, on {os.cpu_count()} cores (shared "
         f"machine: the absolute rates move by 2-3x between minutes; the ratios are measured in the same minute).  ",
         f"Clock: {'CPU time of the process' if args.clock == 'cpu' else 'wall time'}.  ",
         f"Plain numpy per-sample loop (Rodrigues + 15x15 P = A P A' + Q): best {base:,.0f} samples/s, all "
         f"{', '.join(f'{x:,.0f}' for x in loop)}.  ",
         f"Data: {args.duration:.0f} s ship ({data['ship'].n} samples, 100 Hz) for the in-motion cores, static "
         f"({data['static'].n} samples, 125 Hz) for the static ones; simulating both took {t_read:.1f} s.\n",
         "Samples/s (best of the repetitions) and the ratio to the numpy loop:\n",
         "| core | ia.align (fast session, compiled) | ratio | ia.align, session per sample, compiled | ratio "
         "| ia.align, session per sample, numpy reference | ratio | core alone, per sample | ratio "
         "| core alone, arrays | ratio |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cores:
        r = {k: max(v) for k, v in res[c].items()}
        L.append(f"| {c} | {r['align_compiled']:,.0f} | {r['align_compiled'] / base:.2f} | "
                 f"{r['align_per_sample']:,.0f} | {r['align_per_sample'] / base:.2f} | "
                 f"{r['align_reference']:,.0f} | {r['align_reference'] / base:.2f} | {r['core_samples']:,.0f} | "
                 f"{r['core_samples'] / base:.2f} | {r['core_arrays']:,.0f} | {r['core_arrays'] / base:.2f} |")
    L += ["", f"Per-stage {args.clock} time of one `ia.align` run (compiled path, instrumented: each wrapped call "
              "adds ~0.5 us) [us per IMU sample]:\n",
          "| core | read/convert | input (validate, buffer) | propagate | update | outputs | session (rest) | total |",
          "|---|---|---|---|---|---|---|---|"] + stage_lines
    md = "\n".join(L)
    print(md)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"loop": loop, "results": res, "load": [load0, load1]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
