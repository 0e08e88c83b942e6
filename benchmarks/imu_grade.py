#!/usr/bin/env python3
"""IMU grade benchmark (issue 13 item 4, docs/imu_grades.md). Not a unit test.

The default core (auto; ``--core iekf`` for the in-motion core alone) from the sensors, the driver-style runs of
test/test_node_driver_style.py offline (seed 4, 100 Hz, fixes 150 ms late: car heading -120 deg 150 s, ship 240 s,
park_drive parked 40 s heading 150 deg 105 s) under the default grade (unknown_mems), the scenario's matching grade
(filters/imu_grade.SCENARIO_IMU_GRADE) and a mismatched one. Prints a markdown table:
time the flag first came up, final yaw error and 3-sigma, the fraction of outputs (second half) whose 3-sigma
covers the roll/pitch/yaw error, the mean attitude NEES (3 dof: chi-square mean 3), outputs with the flag up while
|yaw error| > 3 deg.

    nice .venv/bin/python benchmarks/imu_grade.py [--core auto] [--duration-scale 1.0] [--seed 4]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insalign_ros.filters.imu_grade import DEFAULT_IMU_GRADE, SCENARIO_IMU_GRADE  # noqa: E402
from insalign_ros.session.offline import align, flag_up_with_error_above  # noqa: E402
from insalign_ros.sim.scenarios import make_scenario  # noqa: E402

#: (scenario, duration [s], overrides, extra grades): the runs of test/test_node_driver_style.py
RUNS = [("car", 150.0, {"heading_deg": -120.0}, ("industrial_mems",)),
        ("ship", 240.0, {}, ("industrial_mems",)),
        ("park_drive", 105.0, {"heading_deg": 150.0, "park_s": 40.0}, ())]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--core", default=None, help="core (default: the session's, auto)")
    ap.add_argument("--duration-scale", type=float, default=1.0, help="multiply every run's duration")
    ap.add_argument("--seed", type=int, default=4)
    args = ap.parse_args(argv)
    print("| scenario (IMU) | grade | flag first up [s] | final yaw error [deg] | final yaw 3-sigma [deg] "
          "| 3-sigma covers (2nd half) | mean NEES (2nd half) | flag up with \\|yaw err\\| > 3 deg |")
    print("|---|---|---|---|---|---|---|---|")
    for name, duration, overrides, extra in RUNS:
        duration *= args.duration_scale
        d = make_scenario(name, seed=args.seed, duration_s=duration, rate_hz=100.0, **overrides)
        grades = dict.fromkeys((DEFAULT_IMU_GRADE, SCENARIO_IMU_GRADE[name], *extra))
        for grade in grades:
            r = align(d, core=args.core, imu_grade=grade, fix_delay_s=0.15)
            ok = np.isfinite(r.rpy_err_deg[:, 2]) & (r.t_s > r.t_s[0] + duration / 2)
            cover = np.mean(np.all(np.abs(r.rpy_err_deg[ok]) <= r.sigma3_deg[ok], axis=1))
            up = r.metrics["aligned_first_raised_at_s"]
            tag = " (matching)" if grade == SCENARIO_IMU_GRADE[name] else " (default)" if grade == DEFAULT_IMU_GRADE else ""
            print(f"| {name} ({d.imu_spec.name}, {duration:.0f} s) | `{grade}`{tag} | {'never' if up is None else f'{up:.0f}'} | "
                  f"{r.rpy_err_deg[-1, 2]:+.2f} | {r.sigma3_deg[-1, 2]:.2f} | {cover:.3f} | {np.mean(r.nees[ok]):.2f} | "
                  f"{flag_up_with_error_above(r, 3.0)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
