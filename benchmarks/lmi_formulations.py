#!/usr/bin/env python3
"""PI-LIEKF gain formulations on the ship (docs/inmotion_cores.md, 'PI-LIEKF: A_bar, eq. (23), and what the LMI
says'). Not a unit test.

The user-facing PI-LIEKF has one formulation (``certify``: eq. (20) as an analysis LMI on the exact window product
for candidate gains). The others are research formulations of :mod:`insalign_ros.filters.lmi`, not config options;
this benchmark hands them to the core (``PiLiekf(cfg, gain_solver_factory=...)``):

* ``interval_paper`` / ``interval_structured``: eq. (22) on one frozen interval as the paper writes it
  (unstructured J, N + least-squares eq. (23) / the eq. (23) structure built in): never feasible on the INS;
* ``window``: eq. (20) on the transition lifted over W intervals, k_I synthesised (structured, max integral gain);
* ``fixed:KP/KI``: fixed gains switched in at the first full window of W intervals (a stub in place of the LMI);
* ``liekf``: the LIEKF, for reference (= PI-LIEKF with the safe gains).

Per formulation: RMSE roll / pitch / yaw over the run, steady-state |yaw| mean / max over the seeds (last 60 s),
LMI solves, fallbacks, budget misses and LMI time per run. Core parameters as JSON with ``--params`` (e.g. rho,
lmi_resolve_every_updates, lmi_schedule, lmi_time_budget_s).

    nice .venv/bin/python benchmarks/lmi_formulations.py --seeds 10 --formulations certify,window,liekf
    nice .venv/bin/python benchmarks/lmi_formulations.py --seeds 10 --formulations window --params '{"rho": 0.003}'
    nice .venv/bin/python benchmarks/lmi_formulations.py --seeds 10 --formulations fixed:1.6/0.5,fixed:1/0.3
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from insalign_ros.eval import metrics as MT  # noqa: E402
from insalign_ros.filters import lmi  # noqa: E402
from insalign_ros.filters.config import PiLiekfConfig  # noqa: E402
from insalign_ros.filters.pi_liekf import PiLiekf  # noqa: E402
from insalign_ros.filters.registry import make_core  # noqa: E402
from insalign_ros.filters.runner import run_offline  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402


class FixedGains:
    """A stub gain solver: the same k_P, k_I at every solve, switched in at the first full window of
    ``lmi_window_updates`` intervals (as the docs' fixed-gain table was measured)."""

    def __init__(self, k_P: float, k_I: float, history_needed: int):
        self.k_P, self.k_I, self.history_needed = k_P, k_I, history_needed

    def solve(self, w, deadline_s=None):
        return lmi.LmiResult("fixed", self.k_P * np.eye(3), self.k_I * np.eye(3), False, "fixed gains")


def make(formulation: str, params: dict):
    cfg = PiLiekfConfig.from_dict(params)
    if formulation == "certify":
        return PiLiekf(cfg)
    if formulation == "liekf":
        return make_core("liekf", {k: v for k, v in params.items() if k in make_core("liekf").cfg.to_dict()})
    if formulation.startswith("fixed:"):
        kp, ki = (float(x) for x in formulation[6:].split("/"))
        return PiLiekf(cfg, gain_solver_factory=lambda c: FixedGains(kp, ki, c.lmi_window_updates))
    if formulation == "window":
        return PiLiekf(cfg, gain_solver_factory=lmi.research_solver_factory("window"))
    if formulation in ("interval_paper", "interval_structured"):
        return PiLiekf(cfg, gain_solver_factory=lmi.research_solver_factory("interval", formulation[9:]))
    raise SystemExit(f"unknown formulation {formulation!r}")


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
    print(f"command: nice .venv/bin/python benchmarks/lmi_formulations.py {' '.join(argv or sys.argv[1:])}")
    print(f"{args.scenario}, {args.duration:g} s, initial error 10 / 10 / {args.yaw:g} deg, seeds {args.seed0}-"
          f"{args.seed0 + args.seeds - 1}, parameters {params}\n")
    print("| formulation | RMSE roll / pitch / yaw [deg] | steady-state yaw mean / max [deg] | solves / run | "
          "fallbacks | budget misses | LMI time / run [s] |")
    print("|---|---|---|---|---|---|---|")
    data = [make_scenario(args.scenario, seed=s, duration_s=args.duration)
            for s in range(args.seed0, args.seed0 + args.seeds)]
    for f in args.formulations.split(","):
        rmse, steady, solves, fb, miss, t_lmi = [], [], 0, 0, 0, 0.0
        for d in data:
            core = make(f, params)
            ests, _ = run_offline(core, d, [10.0, 10.0, args.yaw], output_period_s=1.0)
            s = MT.summary(MT.evaluate(f, ests, d.t_s, d.C_b_n, float(d.t_s[0])))
            rmse.append(s["rmse_rpy_deg"])
            steady.append(s["steady_state_abs_err_rpy_deg"][2])
            hist = getattr(core, "lmi_history", [])
            solves += len(hist)
            fb += sum(r.used_fallback for _, r in hist)
            miss += sum(r.budget_miss for _, r in hist)
            t_lmi += sum(r.solve_time_s for _, r in hist)
            if isinstance(core, PiLiekf):
                core.close()
        n = len(data)
        r = np.mean(rmse, 0)
        print(f"| {f} | {r[0]:.2f} / {r[1]:.2f} / {r[2]:.2f} | {np.mean(steady):.3f} / {np.max(steady):.2f} | "
              f"{solves / n:.1f} | {fb} of {solves} | {miss} | {t_lmi / n:.2f} |", flush=True)


if __name__ == "__main__":
    main()
