#!/usr/bin/env python3
"""PI-LIEKF LMI solve time over yaw sweeps (issue 16, item 3). Not a unit test.

For each scenario, seed and initial yaw error, one PI-LIEKF run through ``ia.align`` (the session users run; initial
error from the truth, synchronous LMI, the default config with the noise matched to the scenario IMU, as
benchmarks/yaw_sweep.py runs it). Per scenario: solves, certified,
fallbacks, budget misses, and the distribution of the single-solve times (LmiResult.solve_time_s; a miss counts
the time the update waited) against the target (0.5 s) and the budget (``lmi_time_budget_s``). ``--slow`` adds the
reproduction of a slow solve (a ship at 4 m/s in low waves: no candidate certifies; CLARABEL fails fast, SCS iterates
for tens of seconds per candidate, as the SCS fallback did before it was removed), with the budget and with
``--unbudgeted-s`` (before the budget existed the solve had no limit).

    nice .venv/bin/python benchmarks/lmi_solve_time.py --scenarios ship,car,paper_ship --seeds 20
    nice .venv/bin/python benchmarks/lmi_solve_time.py --scenarios ship,car --seeds 2 --yaws -179,-60,0,60,179 --slow
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

import insalign_ros as ia  # noqa: E402
from insalign_ros.filters.imu_grade import SCENARIO_IMU_GRADE  # noqa: E402
from insalign_ros.filters.registry import make_config  # noqa: E402
from insalign_ros.sim.scenarios import SCENARIOS, make_scenario  # noqa: E402
from recorded_core import register_recorded, with_history  # noqa: E402
from yaw_sweep import imu_matched_params  # noqa: E402

TARGET_S = 0.5
SLOW_SHIP = {"speed_m_s": 4.0, "amp_e_m": 0.5, "amp_n_m": 0.5, "amp_u_m": 0.3}


def run(data, yaw_deg: float, params: dict) -> tuple[list, dict, float]:
    """One run through ``ia.align``: (lmi_history, the core's diagnostics, wall time [s])."""
    record: list = []
    name = register_recorded("pi_liekf_recorded", "pi_liekf", record)
    t0 = time.perf_counter()
    ia.align(data, core=name, core_params={"lmi_async": "false", **params}, init_mode="truth",
             init_rpy_error_deg=[10.0, 10.0, yaw_deg], output_period_s=1.0,
             imu_grade=SCENARIO_IMU_GRADE.get(data.name, "paper_ship"))
    wall = time.perf_counter() - t0
    ran = with_history(record)
    hist = [h for c in ran for h in c.lmi_history]
    diag = {"lmi_solves": len(hist), "lmi_budget_misses": sum(r.budget_miss for _, r in hist),
            "lmi_fallbacks": sum(r.used_fallback for _, r in hist),
            "lmi_solve_time_max_s": max((r.solve_time_s for _, r in hist), default=0.0)}
    return hist, diag, wall


def sweep(scenario: str, seeds: int, yaws: list[float], duration_s: float, budget_s: float | None) -> dict:
    from tqdm import tqdm

    times, statuses, misses, fallbacks, walls, worst = [], Counter(), 0, 0, [], (0.0, "")
    by_scs = 0  # certificates found by SCS (the removed fallback after a CLARABEL failure, or lmi_solver SCS)
    solver_errors = 0  # candidates the solver failed on (rejected: no SCS fallback)
    for seed in tqdm(range(seeds), desc=scenario, file=sys.stderr):
        data = make_scenario(scenario, seed=seed, duration_s=duration_s)
        params = {k: v for k, v in imu_matched_params(data.imu_spec).items() if not k.startswith("init_sigma_")}
        if budget_s is not None:
            params["lmi_time_budget_s"] = budget_s
        for yaw in yaws:
            hist, diag, wall = run(data, yaw, params)
            walls.append(wall)
            misses += diag["lmi_budget_misses"]
            fallbacks += diag["lmi_fallbacks"]
            for t_s, r in hist:
                times.append(r.solve_time_s)
                statuses[r.status] += 1
                by_scs += int(not r.used_fallback and r.solver == "SCS")
                solver_errors += r.extra.get("solver_errors", 0)
                if r.solve_time_s > worst[0]:
                    worst = (r.solve_time_s, f"seed {seed}, yaw {yaw:+g}, t = {t_s:.0f} s: {r.reason[:90]}")
    t = np.array(times) if times else np.zeros(1)
    return {"scenario": scenario, "runs": len(walls), "solves": len(times), "fallbacks": fallbacks,
            "misses": misses, "max": float(t.max()), "p99": float(np.percentile(t, 99)),
            "median": float(np.median(t)), "statuses": dict(statuses), "worst": worst[1], "by_scs": by_scs,
            "solver_errors": solver_errors,
            "run_wall_median": float(np.median(walls)), "run_wall_max": float(np.max(walls))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default="ship,car,paper_ship")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--yaws", default="-179,-90,-60,-30,0,30,60,90,179")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--budget-s", type=float, default=None, help="lmi_time_budget_s (default: the config's)")
    ap.add_argument("--slow", action="store_true", help="add the slow-solve reproduction (weakly excited ship)")
    ap.add_argument("--unbudgeted-s", type=float, default=600.0,
                    help="budget of the 'before' run of --slow (600 s = in effect none; 0 skips that run)")
    args = ap.parse_args(argv)
    yaws = [float(y) for y in args.yaws.split(",")]
    budget = args.budget_s if args.budget_s is not None else make_config("pi_liekf").lmi_time_budget_s
    print(f"command: nice .venv/bin/python benchmarks/lmi_solve_time.py {' '.join(argv or sys.argv[1:])}")
    print(f"{args.seeds} seeds x {len(yaws)} yaw errors ({args.yaws}) per scenario, {args.duration:g} s runs, "
          f"synchronous LMI, budget {budget:g} s, target for the longest solve {TARGET_S} s\n")
    rows = []
    for sc in args.scenarios.split(","):
        if sc not in SCENARIOS:
            print(f"scenario {sc!r}: not in this tree (known: {', '.join(sorted(SCENARIOS))}): skipped")
            continue
        rows.append(sweep(sc, args.seeds, yaws, args.duration, args.budget_s))
    print("\n| scenario | runs | solves | fallbacks | budget misses | longest solve [s] (target 0.5, budget "
          f"{budget:g}) | p99 / median [s] | run wall median / max [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scenario']} | {r['runs']} | {r['solves']} | {r['fallbacks']} | {r['misses']} | "
              f"**{r['max']:.3f}** | {r['p99']:.3f} / {r['median']:.3f} | {r['run_wall_median']:.1f} / "
              f"{r['run_wall_max']:.1f} |")
    for r in rows:
        print(f"- {r['scenario']}: statuses {r['statuses']}; certified by SCS: {r['by_scs']}; candidates the "
              f"solver failed on (rejected): {r['solver_errors']}; "
              f"longest: {r['worst']}")
    if rows:
        print(f"\nAll: longest single solve {max(r['max'] for r in rows):.3f} s, "
              f"{sum(r['misses'] for r in rows)} budget misses in {sum(r['solves'] for r in rows)} solves.")
    if args.slow:
        data = make_scenario("ship", seed=0, duration_s=200.0, **SLOW_SHIP)
        print(f"\nslow-solve reproduction: ship {SLOW_SHIP}, seed 0, 200 s, yaw error 60 deg")
        print("| lmi_solver | budget [s] | run wall [s] | solves | budget misses | fallbacks | longest solve [s] | "
              "first solve |")
        print("|---|---|---|---|---|---|---|---|")
        cases = [("CLARABEL", budget), ("SCS", budget)] + ([("SCS", args.unbudgeted_s)] if args.unbudgeted_s else [])
        for solver, b in cases:
            hist, diag, wall = run(data, 60.0, {"lmi_solver": solver, "lmi_time_budget_s": b})
            print(f"| {solver} | {b:g} | {wall:.1f} | {diag['lmi_solves']} | {diag['lmi_budget_misses']} | "
                  f"{diag['lmi_fallbacks']} | {diag['lmi_solve_time_max_s']:.2f} | "
                  f"{hist[0][1].status + ': ' + hist[0][1].reason[:110] if hist else 'none'} |", flush=True)


if __name__ == "__main__":
    main()
