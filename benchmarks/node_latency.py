"""alignment_node cost and behaviour under load over real Fast DDS (two processes, isolated domain).

1. **cost**: per core, imu_sim_node ship at 125 Hz in real time (rate factor 1) for ``--cost-duration-s``; the node
   process's CPU time (user + system, /proc) over the streaming wall time = its share of one core, outputs at 10 Hz;
   split into the node's Python thread and the other threads (DDS, executor timers; /proc/<pid>/task/*/schedstat),
   with the Python thread's context switches per second (its wake-ups); for one core also with rclpy's
   SingleThreadedExecutor (``INSALIGN_EXECUTOR=single``) to compare. ``--ref DIR``: before each core's run, the same
   run of the node code in DIR (a checkout, e.g. ``git worktree add /tmp/old <commit>``; run with ``python -P`` and
   PYTHONPATH=DIR, so that neither the current directory nor the installed package shadows it), and the ratio: this
   machine's CPU figures move by 1.5x between minutes, a comparison needs both codes in the same minutes.
   ``--floor``: before each cost run, benchmarks/floor_node.py in the node's place (the node's inputs and outputs,
   nothing computed: the floor of rclpy and Fast DDS at this rate).
2. **load**: the same at 1,250 Imu messages/s (rate factor 10, sensor-data QoS as a driver would use), optionally
   with ``--burners`` CPU burners running: sent vs received (drops), gaps counted by the session, the per-Imu
   callback time (median, p99; the callback only converts and pushes), the session's processing rate (samples per
   second of processing time), and the published estimates outside their own published 3-sigma (any axis, after
   ``--settle-s``) next to the same count for ``insalign_ros.align`` on the same data (the load's own effect).

    .venv/bin/python benchmarks/node_latency.py [--cores liekf iekf ekf pi_liekf] [--burners 2] [--ref DIR] [--floor]
        [--truth on|off|both] [--profile DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insalign_ros.cli.bringup import (isolated_ros_env, ros_args, start_node, start_process, stop_nodes,  # noqa: E402
                                     wait_for_exit)

#: the cost run's CPU share is also measured over consecutive intervals this long [s wall] (the median)
INTERVAL_S = 10.0
TICK = os.sysconf("SC_CLK_TCK")
#: the cost run's CPU share is measured from this long after the stream starts [s wall]
WARM_S = 10.0


def _summary(text):
    for line in reversed(text.splitlines()):
        if line.startswith("SIM_SUMMARY "):
            return json.loads(line[len("SIM_SUMMARY "):])
    return {}


def _cpu_s(pid: int) -> float:
    """User + system CPU time [s] of a process and its waited-for children (/proc/<pid>/stat)."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return sum(int(x) for x in f[11:15]) / TICK


def _threads(pid: int) -> dict:
    """tid -> (CPU time [s] from schedstat (ns, exact), context switches) of every thread of a process."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            ns = int((task / "schedstat").read_text().split()[0])
            cs = sum(int(line.split()[1]) for line in (task / "status").read_text().splitlines()
                     if "ctxt_switches:" in line)
        except (OSError, ValueError, IndexError):
            continue
        out[int(task.name)] = (1e-9 * ns, cs)
    return out


def _split(pid: int, before: dict, after: dict, wall_s: float) -> tuple[float, float, float]:
    """(Python thread's CPU share, the other threads' share, the Python thread's context switches per second)."""
    main = other = 0.0
    cs = 0
    for tid, (c, n) in after.items():
        c0, n0 = before.get(tid, (0.0, 0))
        if tid == pid:
            main, cs = c - c0, n - n0
        else:
            other += c - c0
    return main / wall_s, other / wall_s, cs / wall_s


#: static cores run the cost case on the static scenario (the ship moves)
STATIC_CORES = {"pkf", "ekf10", "earth_iekf", "coarse"}


def run_case(core, rate_hz, rate_factor, duration_s, qos, log_dir, executor="events", settle_s=60.0, ref=None,
             truth=True, profile=None, scenario=None, floor=False):
    """One run. ``truth``: the simulator publishes ground_truth/pose (10 Hz) and the node starts from it with an
    error (the benchmark's case); False: what a user runs, no truth topic and the node's default parameters (only
    ``core`` and ``imu_qos`` given; initialised from the sensors). ``profile``: a path for a py-spy flame graph
    (raw/collapsed format) of the node over the measured window (py-spy's sampling costs the node CPU: not for the
    cost figures). ``scenario``: the simulator's scenario (default: static for the static cores, else ship).
    ``floor``: benchmarks/floor_node.py in the node's place (the same inputs and outputs, nothing computed)."""
    env = isolated_ros_env()
    env["INSALIGN_EXECUTOR"] = executor
    for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        os.environ[k] = env[k]
    from insalign_ros.nodes.monitor import AlignmentMonitor

    mon = AlignmentMonitor(keep_poses=10)
    nodes = []
    try:
        params = {"core": core, "imu_qos": qos}
        if truth:
            params.update(init_from_ground_truth=True, imu_timeout_s=0.0, init_rpy_error_deg="[3.0, -3.0, 30.0]")
        if floor:
            align = start_process([sys.executable, "-P", str(Path(__file__).with_name("floor_node.py")),
                                   *ros_args(params)], dict(env, PYTHONPATH=str(Path(__file__).resolve().parents[1])),
                                  f"floor_{core}", log_dir)
        elif ref:
            ref_env = dict(env, PYTHONPATH=str(ref))
            align = start_process([sys.executable, "-P", "-m", "insalign_ros.nodes.alignment_node", *ros_args(params)],
                                  ref_env, f"align_{core}_ref", log_dir)
        else:
            align = start_node("insalign_ros.nodes.alignment_node", env, log_dir=log_dir, name=f"align_{core}",
                               params=params)
        nodes.append(align)
        mon.wait_for(lambda m: m.diag_count > 0, 30.0)
        sim = start_node("insalign_ros.nodes.imu_sim_node", env, log_dir=log_dir, name=f"sim_{core}",
                         params={"source": "scenario",
                                 "scenario": scenario or ("static" if core in STATIC_CORES else "ship"),
                                 "rate_hz": rate_hz, "seed": 3,
                                 "rate_factor": rate_factor, "duration_s": duration_s, "wait_for_subscribers": 1,
                                 "wait_timeout_s": 30.0, "qos_depth": 1000, "publish_ground_truth": truth})
        nodes.append(sim)
        cs, ts = _cpu_s(align.popen.pid), time.monotonic()
        # steady state from WARM_S on: the first samples initialise the core and load its compiled kernels from
        # numba's cache (a one-off of ~1-2 s of CPU that a 30-s run would spread over its share)
        warm = min(WARM_S, 0.3 * duration_s / rate_factor)
        time.sleep(warm)
        pid = align.popen.pid
        c0, t0, th0 = _cpu_s(pid), time.monotonic(), _threads(pid)
        spy = None
        if profile:
            spy = subprocess.Popen([str(Path(sys.executable).with_name("py-spy")), "record", "--pid", str(pid),
                                    "--format", "raw", "--rate", "1000", "--nonblocking", "--output", str(profile),
                                    "--duration", str(max(1, int(duration_s / rate_factor - warm - 2)))],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # the CPU time every INTERVAL_S of wall time while the stream runs (the median of those shares)
        marks, deadline = [(t0, c0)], t0 + duration_s / rate_factor + 60.0
        while sim.popen.poll() is None and time.monotonic() < deadline:
            time.sleep(max(0.0, min(INTERVAL_S - (time.monotonic() - marks[-1][0]), deadline - time.monotonic())))
            if time.monotonic() - marks[-1][0] >= INTERVAL_S - 1e-3 and sim.popen.poll() is None:
                marks.append((time.monotonic(), _cpu_s(pid)))
        rc = wait_for_exit(sim, 60.0)
        shares = [(b[1] - a[1]) / (b[0] - a[0]) for a, b in zip(marks, marks[1:])]
        if spy is not None:
            spy.wait(30)
        c1, t1, th1 = _cpu_s(pid), time.monotonic(), _threads(pid)
        py_share, other_share, wakeups = _split(pid, th0, th1, t1 - t0)
        s = _summary(sim.output())
        sent = s.get("imu_sent", 0)
        mon.wait_for(lambda m: m.counter("imu_received") >= sent, 15.0)
        mon.wait_for(lambda m: int(m.diag.get("buffered_imu", "1")) == 0, 10.0)
        n0 = mon.diag_count
        mon.wait_for(lambda m: m.diag_count >= n0 + 2, 5.0)
        with mon.lock:
            d = dict(mon.diag)
            errs = {round(t, 6): e for t, e in mon.errors}
            sig = {round(t, 6): v for t, v in mon.sigmas3}
        first = s.get("first_stamp_ns", 0) * 1e-9
        late = [t for t in errs if t in sig and t - first >= settle_s]
        outside = sum(bool(np.any(np.abs(errs[t]) > sig[t])) for t in late)
        proc_s = float(d.get("session_process_total_s", "nan"))
        return {"core": core, "executor": executor, "msgs_per_s": rate_hz * rate_factor, "qos": qos, "sim_rc": rc,
                "sent": sent, "received": int(d.get("imu_received", 0)), "gaps": int(d.get("imu_gaps", 0)),
                "cb_median_us": float(d.get("imu_callback_median_us", "nan")),
                "cb_p99_us": float(d.get("imu_callback_p99_us", "nan")),
                "cpu_share": (c1 - c0) / (t1 - t0), "wall_s": t1 - t0, "python_thread_share": py_share,
                "cpu_share_median_interval": float(np.median(shares)) if shares else float("nan"),
                "cpu_share_intervals": len(shares),
                "other_threads_share": other_share, "python_thread_switches_per_s": wakeups,
                "cpu_share_with_start": (c1 - cs) / (t1 - ts),
                "session_samples_per_s": int(d.get("session_samples", 0)) / proc_s if proc_s > 0 else float("nan"),
                "outputs_checked": len(late), "outside_3sigma": outside,
                "aligned_at_end": d.get("aligned_at_last_output")}
    finally:
        stop_nodes(nodes)
        mon.close()


def offline_outside(core, rate_hz, duration_s, settle_s):
    """The same count for insalign_ros.align on the same data (what the filter does without any load)."""
    import insalign_ros as ia
    from insalign_ros.sim.scenarios import make_scenario

    r = ia.align(make_scenario("ship", seed=3, duration_s=duration_s, rate_hz=rate_hz), core=core,
                 init_mode="truth", init_rpy_error_deg=[3.0, -3.0, 30.0], output_period_s=0.1, imu_grade="paper_ship")
    m = r.t_s - r.t_s[0] >= settle_s
    return int(np.sum(np.any(np.abs(r.rpy_err_deg[m]) > r.sigma3_deg[m], axis=1))), int(np.sum(m))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cores", nargs="+", default=["liekf", "iekf", "ekf", "pi_liekf"],
                    help="cores of the cost runs; CORE@SCENARIO picks the simulator's scenario (e.g. auto@static: "
                         "the default core on a parked vehicle)")
    ap.add_argument("--cost-duration-s", type=float, default=30.0, help="real-time run per core [s]")
    ap.add_argument("--load-duration-s", type=float, default=180.0, help="data time of the 1,250 msg/s run [s]")
    ap.add_argument("--settle-s", type=float, default=60.0, help="3-sigma check from this data time on [s]")
    ap.add_argument("--burners", type=int, default=0, help="CPU burners (python busy loops) during the load runs")
    ap.add_argument("--skip-cost", action="store_true")
    ap.add_argument("--ref", type=Path, help="a checkout of older node code: run before each cost run, same minutes")
    ap.add_argument("--floor", action="store_true",
                    help="before each cost run, the same run of benchmarks/floor_node.py in the node's place: what "
                         "rclpy and Fast DDS cost with the node's inputs and outputs and nothing computed")
    ap.add_argument("--skip-load", action="store_true")
    ap.add_argument("--no-single", action="store_true", help="no SingleThreadedExecutor run in the cost table")
    ap.add_argument("--truth", choices=("on", "off", "both"), default="both",
                    help="cost runs with the 10-Hz ground-truth topic and init from it (on), as a user runs the node "
                         "(off: no truth topic, default parameters), or both, interleaved")
    ap.add_argument("--profile", type=Path, help="a directory: py-spy raw profiles of this code's cost runs (the "
                                                 "profiled runs' CPU figures include py-spy's cost)")
    args = ap.parse_args(argv)
    log_dir = Path(tempfile.mkdtemp(prefix="node-latency-"))
    print(f"node logs in {log_dir}", flush=True)
    if not args.skip_cost:
        print(f"\n| core | truth topic | code | executor | Imu msgs/s (real time) | CPU share of one core (from "
              f"{WARM_S:g} s on) | median of {INTERVAL_S:g}-s intervals (n) | Python thread / other threads | Python thread switches/s | with the first seconds | "
              "Imu handling median / p99 [us] |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        truths = {"on": [True], "off": [False], "both": [True, False]}[args.truth]
        cases = [(c, "events", tr) for c in args.cores for tr in truths]
        cases += [] if args.no_single else [(args.cores[0], "single", truths[0])]
        if args.profile:
            if not Path(sys.executable).with_name("py-spy").exists():
                ap.error("--profile needs py-spy in this interpreter's environment (pip install py-spy)")
            args.profile.mkdir(parents=True, exist_ok=True)
        for spec, ex, tr in cases:
            core, _, scenario = spec.partition("@")
            runs = (["floor"] if args.floor and ex == "events" else []) + ([args.ref] if args.ref else []) + [None]
            for ref in runs:
                floor = ref == "floor"
                prof = (args.profile / f"{spec.replace('@', '_')}_{ex}_truth-{'on' if tr else 'off'}.txt"
                        if args.profile and not ref else None)
                r = run_case(core, 125.0, 1.0, args.cost_duration_s, "sensor_data", log_dir, ex,
                             ref=None if floor else ref, truth=tr, profile=prof, scenario=scenario or None,
                             floor=floor)
                if ref and not floor:
                    ref_share = r["cpu_share"]
                ratio = f" ({r['cpu_share'] / ref_share:.2f}x the ref)" if args.ref and not ref else ""
                label = "floor" if floor else "ref" if ref else "this"
                print(f"| {spec} | {'yes' if tr else 'no (defaults)'} | {label} | {ex} | "
                      f"{r['msgs_per_s']:.0f} | "
                      f"{100 * r['cpu_share']:.1f} %{ratio} | {100 * r['cpu_share_median_interval']:.1f} % "
                      f"({r['cpu_share_intervals']}) | {100 * r['python_thread_share']:.1f} / "
                      f"{100 * r['other_threads_share']:.1f} % | {r['python_thread_switches_per_s']:.0f} | "
                      f"{100 * r['cpu_share_with_start']:.1f} % | "
                      f"{r['cb_median_us']:.0f} / {r['cb_p99_us']:.0f} |", flush=True)
    if args.skip_load:
        return 0
    burners = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(args.burners)]
    try:
        print(f"\n1,250 Imu msg/s, sensor-data QoS, {args.burners} CPU burners, {args.load_duration_s:.0f} s of data")
        print("| core | sent | received | dropped | gaps | callback median / p99 [us] | session samples/s | "
              "outputs outside 3-sigma (node / offline) | aligned at end |")
        print("|---|---|---|---|---|---|---|---|---|")
        for core in (c.partition("@")[0] for c in args.cores):  # the load runs: each core's own scenario
            r = run_case(core, 125.0, 10.0, args.load_duration_s, "sensor_data", log_dir, settle_s=args.settle_s)
            off, n_off = offline_outside(core, 125.0, args.load_duration_s, args.settle_s)
            print(f"| {core} | {r['sent']} | {r['received']} | {r['sent'] - r['received']} | {r['gaps']} | "
                  f"{r['cb_median_us']:.0f} / {r['cb_p99_us']:.0f} | {r['session_samples_per_s']:.0f} | "
                  f"{r['outside_3sigma']}/{r['outputs_checked']} / {off}/{n_off} | {r['aligned_at_end']} |",
                  flush=True)
    finally:
        for b in burners:
            b.kill()
    return 0


if __name__ == "__main__":
    sys.exit(main())
