#!/usr/bin/env python3
"""Yaw-sweep benchmark of the in-motion cores (issue 5, item 7). Not a unit test.

Scenario (default ship), initial roll/pitch error 10 deg, yaw error in --yaws, N Monte-Carlo seeds, every core.
Prints and writes a markdown section: the paper's Table 3 layout at 60 deg (RMSE over the run) next to the
paper's numbers, time to |yaw error| < 1 deg (and stays), steady-state error (mean |error| over the last 60 s),
averaged attitude NEES after 30 s with its 95 % chi-square band, throughput side by side, physical floors;
and figures like the paper's Figs. 3-6.

    nice .venv/bin/python benchmarks/yaw_sweep.py --scenario ship --seeds 20 --md-out /tmp/ship.md

Every run goes through ``ia.align`` (the session users run) as a Dask task (benchmarks/sweep.py): a LocalCluster of
``--workers`` processes by default, ``--scheduler tcp://host:8786`` for a cluster, ``--serial`` to debug;
``--stage-timing`` adds the per-stage time summed over all runs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from insalign_ros.core import earth  # noqa: E402
from insalign_ros.eval import metrics as MT  # noqa: E402
from insalign_ros.sim.error_model import ImuErrorSI  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402

PAPER_TABLE3 = {"iekf": (1.59, 1.20, 4.8), "pi_liekf": (1.61, 1.24, 4.4)}


def parse_core(label):
    """'iekf' -> ('iekf', None); 'iekf:mh8' -> ('iekf', {'yaw_hypotheses': 8}) (a bank of 8 yaw hypotheses)."""
    name, _, k = label.partition(":mh")
    return name, ({"yaw_hypotheses": int(k)} if k else None)


def imu_matched_params(spec) -> dict:
    """Core noise parameters from the scenario's IMU spec (what a user sets from the data sheet). For `ship` they
    equal the defaults (PI-LIEKF Tables 1-2); for `car` the defaults would be 7x too noisy in ARW."""
    return {"gyro_arw_deg_sqrt_h": spec.arw_deg_sqrt_h, "acc_vrw_m_s_sqrt_h": spec.vrw_m_s_sqrt_h,
            "gyro_bias_deg_h": spec.gyro_bias_deg_h, "acc_bias_mg": spec.acc_bias_mg}


def run_one(core_label, data, yaw, params=None, period=1.0):
    """One run through the session path users take (``ia.align``): truth init plus (10, 10, yaw) deg; returns the
    AlignResult and its summary (eval/metrics.summary, wall time, samples, LMI and bank diagnostics)."""
    import insalign_ros as ia
    from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE
    from insalign_ros.filters.registry import make_config

    core_name, bank = parse_core(core_label)
    p = {**(bank or {}), **(params or {})}
    fields = make_config(core_name).to_dict()
    t0 = time.perf_counter()
    r = ia.align(data, core=core_name, core_params={k: v for k, v in p.items() if k in fields}, init_mode="truth",
                 init_rpy_error_deg=[10.0, 10.0, yaw], output_period_s=period,
                 imu_grade=SCENARIO_IMU_GRADE.get(data.name, "paper_ship"))
    s = dict(r.metrics)
    s["wall_s"] = time.perf_counter() - t0
    s["samples"] = int(r.counters.get("imu_processed", data.n))
    dg = r.diagnostics
    if bank:
        s["hypotheses_collapsed_at_s"] = dg.get("core.yaw_hypotheses_collapsed_at_s")
    if "core.lmi_solves" in dg:  # PI-LIEKF: the run's solves and the last one's outcome (the session closes the core)
        s["lmi_solves"] = int(dg["core.lmi_solves"])
        s["lmi_solve_time_s"] = float(dg.get("core.lmi_solve_time_max_s") or 0.0)  # the run's longest solve
        s["lmi_used_fallback"] = bool(dg.get("core.lmi_used_fallback", False))
        s["lmi_last_reason"] = str(dg.get("core.lmi_reason", ""))
        # a solve that misses its wall-time budget falls back to the safe gains: such a run depends on the load
        s["lmi_budget_misses"] = int(dg.get("core.lmi_budget_misses") or 0)
    return r, s


def sweep_task(data, core_label, yaw, default_noise, stage_timing=False, core_params=None):
    """One (seed, core, yaw) run as a Dask task on the seed's simulated ``data`` (``sweep.shared_scenario``: simulated
    once per sweep): summary, (t, yaw error) and (t, NEES) series, stage times."""
    import sweep

    params = {**({} if default_noise else imu_matched_params(data.imu_spec)), **(core_params or {})}
    if stage_timing:
        with sweep.StageTimer() as st:
            t0 = time.perf_counter()
            r, s = run_one(core_label, data, yaw, params)
            st.total_s = time.perf_counter() - t0
        stages = st.stages()
    else:
        r, s = run_one(core_label, data, yaw, params)
        stages = None
    return s, (r.t_s - r.init_t_s, r.rpy_err_deg), (r.t_s - r.init_t_s, r.nees), stages


def task_cost(core_label: str) -> float:
    """Relative run time of one run, for the Dask submission order (longest first). Measured on 300 s of ship data
    (docs/speed.md): liekf / iekf / ekf ~0.3 s of CPU, pi_liekf ~1.1 s (its LMI solves); a bank of K hypotheses
    runs K filters."""
    name, bank = parse_core(core_label)
    return (4.0 if name.startswith("pi_liekf") else 1.0) * (bank or {}).get("yaw_hypotheses", 1)


def throughput(scenario, cores=("liekf", "iekf"), duration=120.0, reps=3):
    """Samples/s per core through ``ia.align``, interleaved on the same data (the machine is shared and noisy)."""
    import insalign_ros as ia
    from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE

    d = make_scenario(scenario, seed=0, duration_s=duration)
    rates = {c: [] for c in cores}
    for _ in range(reps):
        for c in cores:
            t0 = time.perf_counter()
            ia.align(d, core=c, init_mode="truth", init_rpy_error_deg=[10.0, 10.0, 60.0], output_period_s=1.0,
                     imu_grade=SCENARIO_IMU_GRADE[scenario])
            rates[c].append(d.n / (time.perf_counter() - t0))
    return {c: (float(np.median(v)), float(np.max(v))) for c, v in rates.items()}


def fmt(x, nd=2):
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="ship")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--yaws", default="-179,-90,-60,-30,0,30,60,90,179")
    ap.add_argument("--cores", default="liekf,pi_liekf,iekf,ekf",
                    help="comma-separated; 'name:mhK' runs the core in a bank of K yaw hypotheses (filters/hypotheses.py)")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--md-out", default="")
    ap.add_argument("--json-out", default="")
    ap.add_argument("--fig-prefix", default="")
    ap.add_argument("--throughput-only", action="store_true")
    ap.add_argument("--default-noise", action="store_true",
                    help="use the cores' default noise (PI-LIEKF Table 2) instead of the scenario IMU's spec")
    ap.add_argument("--no-throughput", action="store_true", help="skip the single-core throughput measurement")
    ap.add_argument("--lmi-time-budget-s", type=float, default=0.0,
                    help="PI-LIEKF wall-time budget per LMI solve (0: the core's default, 2 s). A solve that misses "
                         "it gives the safe gains, so on a busy machine runs can differ between two sweeps; a large "
                         "budget (e.g. 60) makes serial and Dask runs comparable there")
    import sweep

    sweep.add_arguments(ap)
    args = ap.parse_args(argv)
    cores = args.cores.split(",")
    yaws = [float(y) for y in args.yaws.split(",")]
    cmd = "nice .venv/bin/python benchmarks/yaw_sweep.py " + " ".join(argv if argv is not None else sys.argv[1:])

    tp = {} if args.no_throughput else throughput(args.scenario)
    tp_lines = [f"| {c} | {m:,.0f} | {mx:,.0f} |" for c, (m, mx) in tp.items()]
    print("throughput (samples/s, median / best of 3, interleaved):", tp, flush=True)
    if args.throughput_only:
        return

    import sweep

    results = {}  # (core, yaw) -> list of summaries
    series = {}  # (core, yaw) -> list of (t, err) for figures
    nees_series = {}
    extra = {"lmi_time_budget_s": args.lmi_time_budget_s} if args.lmi_time_budget_s > 0 else {}
    tasks = [(sweep.shared_scenario(args.scenario, seed, args.duration), c, yaw, args.default_noise, args.stage_timing,
              extra) for seed in range(args.seeds) for yaw in yaws for c in cores]
    outs = sweep.run_tasks(sweep_task, tasks, args, desc=f"{args.scenario} sweep", cost=[task_cost(t[1]) for t in tasks])
    for (_, c, yaw, *_), (s, ser, nees, _) in zip(tasks, outs):
        results.setdefault((c, yaw), []).append(s)
        series.setdefault((c, yaw), []).append(ser)
        nees_series.setdefault((c, yaw), []).append(nees)
    print(f"sweep wall time: {args.sweep_summary}", flush=True)
    if args.stage_timing:
        st = sweep.merge_stages(o[3] for o in outs)
        print("stages (sum over runs): " + sweep.format_stages(st, sum(s["samples"] for s, *_ in outs)), flush=True)
    data = make_scenario(args.scenario, seed=args.seeds - 1, duration_s=args.duration)
    spec = data.imu_spec
    e = ImuErrorSI(spec)
    g = 9.8
    a_h = None
    if data.omega_ib_b_true is not None:
        # horizontal specific-force RMS (excitation) from the truth
        f_n = np.einsum("nij,nj->ni", data.C_b_n, data.f_ib_b_true)
        a_h = float(np.sqrt(np.mean(np.sum(f_n[:, :2] ** 2, axis=1))))
    floor_level = math.degrees(e.sigma_ba_m_s2 / g)
    floor_yaw = math.degrees(e.sigma_ba_m_s2 / a_h) if a_h else float("nan")

    L = []
    L.append(f"Command: `{cmd}`  ")
    L.append(f"Scenario `{args.scenario}`, {args.duration:.0f} s, IMU `{spec.name}` (gyro bias {spec.gyro_bias_deg_h} deg/h, "
             f"ARW {spec.arw_deg_sqrt_h} deg/sqrt(h), acc bias {spec.acc_bias_mg} mg, VRW {spec.vrw_m_s_sqrt_h} m/s/sqrt(h), "
             f"{spec.rate_hz:.0f} Hz), GNSS {data.gnss_sigma_m} m at 1 Hz; {args.seeds} seeds; initial roll/pitch error "
             f"10 deg.  ")
    L.append(f"Physical floors (1 sigma): level b_acc/g = {floor_level:.4f} deg; yaw b_acc/a_h = {floor_yaw:.4f} deg "
             f"(a_h = RMS horizontal specific force {fmt(a_h)} m/s^2). These are the floors of a filter that cannot "
             f"separate the accelerometer bias from tilt/yaw (acceleration of one fixed direction); turns and wave "
             f"oscillations in both horizontal axes make the bias observable, so a bias-estimating core (IEKF, EKF) "
             f"may end below the yaw number here, not a hidden bias.  ")
    L.append("Core noise: " + ("the cores' defaults (PI-LIEKF Table 2)" if args.default_noise else
                               f"from the IMU spec ({imu_matched_params(spec)})") + ".\n")
    if 60.0 in yaws:
        L.append("**Table 3 layout**: RMSE [deg] over the whole run at 60 deg initial yaw error, mean over seeds "
                 "(paper: one run).\n")
        L.append("| core | roll | pitch | yaw | paper roll | paper pitch | paper yaw |")
        L.append("|---|---|---|---|---|---|---|")
        for c in cores:
            rm = np.mean([s["rmse_rpy_deg"] for s in results[(c, 60.0)]], axis=0)
            p = PAPER_TABLE3.get(c, (None, None, None))
            L.append(f"| {c} | {rm[0]:.2f} | {rm[1]:.2f} | {rm[2]:.2f} | {fmt(p[0])} | {fmt(p[1])} | {fmt(p[2], 1)} |")
        L.append("")
    def table(title, cell):
        """A core x initial-yaw table; cell(runs) -> text from the summaries of one (core, yaw) pair."""
        L.append(title + "\n")
        L.append("| core | " + " | ".join(f"{y:+.0f}" for y in yaws) + " |")
        L.append("|---|" + "---|" * len(yaws))
        for c in cores:
            L.append(f"| {c} | " + " | ".join(cell(c, y, results[(c, y)]) for y in yaws) + " |")
        L.append("")

    def time_cell(c, y, runs):
        tt = np.array([s["time_yaw_below_deg_s"] for s in runs])
        never = int(np.isnan(tt).sum())
        ok = tt[~np.isnan(tt)]
        cell = f"{np.median(ok):.0f} / {np.max(ok):.0f}" if len(ok) else "-"
        return cell + (f" ({never} never)" if never else "")

    table("**Time to |yaw error| < 1 deg and stays** [s]: median / max over seeds (never = runs that end above 1 deg).",
          time_cell)
    table("**Gross failures**: runs whose final |yaw error| exceeds 5 deg (count over seeds).",
          lambda c, y, runs: str(sum(abs(s["final_err_rpy_deg"][2]) > 5.0 for s in runs)))
    banks = [c for c in cores if parse_core(c)[1]]
    if banks:
        L.append("**Yaw-hypothesis banks**: data time at which one hypothesis was left [s], median / max over seeds "
                 "and yaws.\n")
        for c in banks:
            tc = [s.get("hypotheses_collapsed_at_s") for y in yaws for s in results[(c, y)]]
            tcv = np.array([x for x in tc if x is not None], float)
            never = sum(x is None for x in tc)
            L.append(f"- {c}: {np.median(tcv):.0f} / {np.max(tcv):.0f} s" + (f" ({never} runs ended with several)"
                                                                              if never else ""))
        L.append("")
    def ss_cell(c, y, runs):
        ss = np.array([s["steady_state_abs_err_rpy_deg"][2] for s in runs])
        return f"{ss.mean():.2f} / {ss.max():.2f}"

    table("**Steady-state |yaw error|** [deg], mean over the last 60 s: mean / max over seeds.", ss_cell)
    lo, hi = MT.nees_band(args.seeds)
    def nees_cell(c, y, runs):
        arr = nees_series[(c, y)]
        n = min(len(a[0]) for a in arr)
        t = arr[0][0][:n]
        avg = np.mean([a[1][:n] for a in arr], axis=0)
        m = t >= 30.0
        inside = float(np.mean((avg[m] >= lo) & (avg[m] <= hi)))
        return f"{np.mean(avg[m]):.2f} ({100 * inside:.0f} % in)"

    table(f"**Averaged attitude NEES** (3 dof) over t >= 30 s: NEES averaged over the {args.seeds} seeds at each "
          f"output time, then the mean over time and the fraction of output times inside the 95 % band "
          f"[{lo:.2f}, {hi:.2f}].", nees_cell)
    if "pi_liekf" in cores:
        allpi = [s for y in yaws for s in results[("pi_liekf", y)]]
        withlmi = [s for s in allpi if s.get("lmi_solves")]
        nfb = sum(s.get("lmi_used_fallback", False) for s in withlmi)
        tsol = [s["lmi_solve_time_s"] for s in withlmi]
        misses = sum(s.get("lmi_budget_misses", 0) for s in allpi)
        L.append(f"PI-LIEKF LMI: {len(withlmi)} of {len(allpi)} runs solved ({sum(s.get('lmi_solves', 0) for s in allpi)} "
                 f"solves), {nfb} ended on the safe gains; {misses} solves missed their wall-time budget (a miss gives "
                 f"the safe gains and depends on the machine's load); longest solve per run: mean "
                 f"{1000 * np.mean(tsol) if tsol else float('nan'):.0f} ms, max "
                 f"{1000 * max(tsol) if tsol else float('nan'):.0f} ms. Last reason (seed {args.seeds - 1}, "
                 f"yaw {yaws[-1]:+.0f}): {allpi[-1].get('lmi_last_reason', '')}\n")
    if tp_lines:
        L.append("**Throughput** (samples/s, single-threaded, `ia.align`, the cores interleaved on the same 120 s of "
                 "data, median and best of 3, an output every 1 s; benchmarks/speed.py has the full comparison):\n")
        L.append("| core | median | best |")
        L.append("|---|---|---|")
        L.extend(tp_lines)
        L.append("")
    L.append(f"Sweep: {args.sweep_summary}.\n")
    md = "\n".join(L)
    print(md)
    if args.md_out:
        Path(args.md_out).write_text(md + "\n")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({f"{c}|{y}": v for (c, y), v in results.items()}, default=float))
    if args.fig_prefix:
        figures(series, cores, yaws, args.fig_prefix, args.scenario)


def figures(series, cores, yaws, prefix, scenario):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Fig. 3 analogue: Euler errors at 60 deg initial yaw error, seed 0, every core
    if 60.0 in yaws:
        fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        for c in cores:
            t, e = series[(c, 60.0)][0]
            for i in range(3):
                ax[i].plot(t, e[:, i], label=c)
        for i, nm in enumerate(("roll", "pitch", "yaw")):
            ax[i].set_ylabel(f"{nm} error [deg]")
            ax[i].grid(True)
            ax[i].set_ylim(-5, 5) if i == 2 else ax[i].set_ylim(-3, 3)
        ax[0].legend()
        ax[-1].set_xlabel("time [s]")
        fig.suptitle(f"{scenario}: Euler errors, initial error 10/10/60 deg (seed 0)")
        fig.tight_layout()
        fig.savefig(f"{prefix}_fig3.png", dpi=90)
        plt.close(fig)
    # Figs. 4-6 analogue: per axis, per core, error vs time for every initial yaw error (seed 0)
    for i, nm in enumerate(("roll", "pitch", "yaw")):
        fig, axs = plt.subplots(len(cores), 1, figsize=(8, 2.2 * len(cores)), sharex=True)
        for ax, c in zip(np.atleast_1d(axs), cores):
            for y in yaws:
                t, e = series[(c, y)][0]
                ax.plot(t, e[:, i], lw=0.8, label=f"{y:+.0f}")
            ax.set_ylabel(f"{c}\n{nm} err [deg]")
            ax.set_ylim(-10, 10)
            ax.grid(True)
        np.atleast_1d(axs)[0].legend(ncol=5, fontsize=7)
        np.atleast_1d(axs)[-1].set_xlabel("time [s]")
        fig.suptitle(f"{scenario}: {nm} error for initial yaw errors (seed 0)")
        fig.tight_layout()
        fig.savefig(f"{prefix}_{nm}.png", dpi=80)
        plt.close(fig)


if __name__ == "__main__":
    main()
