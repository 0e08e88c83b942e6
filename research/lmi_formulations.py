#!/usr/bin/env python3
"""PI-LIEKF gain formulations on the ship (docs/inmotion_cores.md, 'PI-LIEKF: A_bar, eq. (23), and what the LMI
says'). Not a unit test.

The user-facing PI-LIEKF has one formulation (``certify``: eq. (20) as an analysis LMI on the exact window product
for candidate gains). The others are research formulations (research/pi_gain_solvers.py), not config options; this
benchmark registers them as cores and runs every one through ``ia.align`` (the session users run; initial error from
the truth, the ship's IMU grade, 1-s outputs):

* ``interval_paper`` / ``interval_structured``: eq. (22) on one frozen interval as the paper writes it
  (unstructured J, N + least-squares eq. (23) / the eq. (23) structure built in): never feasible on the INS;
* ``window``: eq. (20) on the transition lifted over W intervals, k_I synthesised (structured, max integral gain);
* ``fixed:KP/KI``: fixed gains switched in at the first full window of W intervals (a stub in place of the LMI);
* ``liekf``: the LIEKF, for reference (= PI-LIEKF with the safe gains).

Per formulation: RMSE roll / pitch / yaw over the run, steady-state |yaw| mean / max over the seeds (last 60 s),
LMI solves, fallbacks, budget misses and LMI time per run. Core parameters as JSON with ``--params`` (e.g. rho,
lmi_resolve_every_updates, lmi_schedule, lmi_time_budget_s).

    nice .venv/bin/python research/lmi_formulations.py --seeds 10 --formulations certify,window,liekf
    nice .venv/bin/python research/lmi_formulations.py --seeds 10 --formulations window --params '{"rho": 0.003}'
    nice .venv/bin/python research/lmi_formulations.py --seeds 10 --formulations fixed:1.6/0.5,fixed:1/0.3
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "research"), str(ROOT / "benchmarks")]

import insalign_ros as ia  # noqa: E402
import pi_gain_solvers as R  # noqa: E402
from insalign_ros.filters.lmi import LmiResult  # noqa: E402
from insalign_ros.filters.registry import make_config  # noqa: E402
from recorded_core import register_recorded  # noqa: E402


class FixedGains:
    """A stub gain solver: the same k_P, k_I at every solve, switched in at the first full window of
    ``lmi_window_updates`` intervals (as the docs' fixed-gain table was measured)."""

    def __init__(self, k_P: float, k_I: float, history_needed: int):
        self.k_P, self.k_I, self.history_needed = k_P, k_I, history_needed

    def solve(self, w, deadline_s=None):
        return LmiResult("fixed", self.k_P * np.eye(3), self.k_I * np.eye(3), False, "fixed gains")


def core_for(formulation: str, record: list) -> str:
    """The registered core name that runs ``formulation``; its instances go to ``record``."""
    if formulation == "liekf":
        return "liekf"
    if formulation == "certify":
        return register_recorded("pi_liekf_recorded", "pi_liekf", record)
    if formulation.startswith("fixed:"):
        kp, ki = (float(x) for x in formulation[6:].split("/"))
        return register_recorded(f"pi_liekf_{formulation}", "pi_liekf", record,
                                 gain_solver_factory=lambda c: FixedGains(kp, ki, c.lmi_window_updates))
    name = {"window": "pi_liekf_window", "interval_paper": "pi_liekf_interval_paper",
            "interval_structured": "pi_liekf_interval_structured"}.get(formulation)
    if name is None:
        raise SystemExit(f"unknown formulation {formulation!r}")
    R.register_research_cores(record)
    return name


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--formulations", default="certify,window,interval_paper,interval_structured,liekf")
    ap.add_argument("--scenario", default="ship")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seed0", type=int, default=0, help="first seed (10 for the held-out seeds 10-19)")
    ap.add_argument("--yaw", type=float, default=60.0, help="initial yaw error [deg] (roll, pitch 10 deg)")
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--params", default="{}", help="PI-LIEKF parameters as JSON")
    args = ap.parse_args(argv)
    params = json.loads(args.params)
    params.setdefault("lmi_time_budget_s", 600.0)  # the research formulations' SCS solves take seconds
    print(f"command: nice .venv/bin/python research/lmi_formulations.py {' '.join(argv or sys.argv[1:])}")
    print(f"{args.scenario}, {args.duration:g} s, initial error 10 / 10 / {args.yaw:g} deg, seeds {args.seed0}-"
          f"{args.seed0 + args.seeds - 1}, parameters {params}\n")
    print("| formulation | RMSE roll / pitch / yaw [deg] | steady-state yaw mean / max [deg] | solves / run | "
          "fallbacks | budget misses | LMI time / run [s] |")
    print("|---|---|---|---|---|---|---|")
    data = [ia.simulate(args.scenario, seed=s, duration_s=args.duration)
            for s in range(args.seed0, args.seed0 + args.seeds)]
    liekf_fields = make_config("liekf").to_dict()
    for f in args.formulations.split(","):
        rmse, steady, solves, fb, miss, t_lmi = [], [], 0, 0, 0, 0.0
        for d in data:
            record: list = []
            name = core_for(f, record)
            cp = params if f != "liekf" else {k: v for k, v in params.items() if k in liekf_fields}
            r = ia.align(d, core=name, core_params=cp, init_mode="truth", init_rpy_error_deg=[10.0, 10.0, args.yaw],
                         output_period_s=1.0, imu_grade="paper_ship")
            rmse.append(r.metrics["rmse_rpy_deg"])
            steady.append(r.metrics["steady_state_abs_err_rpy_deg"][2])
            hist = [h for c in record for h in getattr(c, "lmi_history", [])]
            solves += len(hist)
            fb += sum(h.used_fallback for _, h in hist)
            miss += sum(h.budget_miss for _, h in hist)
            t_lmi += sum(h.solve_time_s for _, h in hist)
        n = len(data)
        r = np.mean(rmse, 0)
        print(f"| {f} | {r[0]:.2f} / {r[1]:.2f} / {r[2]:.2f} | {np.mean(steady):.3f} / {np.max(steady):.2f} | "
              f"{solves / n:.1f} | {fb} of {solves} | {miss} | {t_lmi / n:.2f} |", flush=True)


if __name__ == "__main__":
    main()
