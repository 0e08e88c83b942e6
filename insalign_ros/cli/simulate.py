"""insalign-simulate SCENARIO OUT [--seed N] [--duration S] [--storage sqlite3|mcap] [--no-noise] [--set k=v ...]

Generate a scenario (sim/scenarios.py) and write it to a rosbag2 directory per docs/bag_contract.md.
Exit codes: 0 ok, 2 bad arguments (message on stderr, no traceback).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    from ..sim.scenarios import SCENARIOS, make_scenario
    from ..io.bag import STORAGES, write_bag

    ap = argparse.ArgumentParser(prog="insalign-simulate", description=__doc__.splitlines()[2])
    ap.add_argument("scenario", choices=sorted(SCENARIOS))
    ap.add_argument("out", type=Path, help="output bag directory (must not exist)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=None, help="duration [s] (default: the preset's)")
    ap.add_argument("--storage", choices=STORAGES, default="sqlite3")
    ap.add_argument("--no-noise", action="store_true", help="error-free IMU and GNSS")
    ap.add_argument("--no-truth", action="store_true", help="omit /ground_truth/pose")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a preset parameter")
    a = ap.parse_args(argv)
    if a.out.exists():
        print(f"insalign-simulate: {a.out} exists; refusing to overwrite", file=sys.stderr)
        return 2
    overrides = {}
    for kv in a.set:
        k, sep, v = kv.partition("=")
        try:
            if not sep:
                raise ValueError
            overrides[k.strip()] = float(v)
        except ValueError:
            print(f"insalign-simulate: --set expects KEY=NUMBER, got {kv!r}", file=sys.stderr)
            return 2
    try:
        data = make_scenario(a.scenario, seed=a.seed, duration_s=a.duration, noise=not a.no_noise, **overrides)
    except ValueError as exc:
        print(f"insalign-simulate: {exc}", file=sys.stderr)
        return 2
    write_bag(data, a.out, storage=a.storage, write_truth=not a.no_truth, progress=sys.stderr.isatty())
    print(f"wrote {a.out}: {a.scenario} seed {a.seed}, {data.n} IMU samples, {data.gnss_t_s.shape[0]} fixes, "
          f"{data.t_s[-1] - data.t_s[0]:.1f} s, {a.storage}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
