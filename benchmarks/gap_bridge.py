"""IMU gaps: the error after a dropout against the published 3-sigma, over random gap positions.

For each scenario (ship 50 Hz, car 100 Hz), core and gap length, a gap starts at random stamps; the run is aligned
through ``ia.align`` (init from the truth with a 3/-3/30 deg error) and the largest |Euler error| / published 3-sigma
over the 30 s after the gap is compared with the same window of the run without the gap (the filter's own
consistency there). ``--linear`` restricts the bridge to linear interpolation (the previous bridge), for comparison.
``--chunk 1`` processes after every sample (as a node keeping up: only ``max_fix_lag_s`` of data after the gap is
available to the bridge). Results: docs/session.md, "Gaps".

    .venv/bin/python benchmarks/gap_bridge.py --runs 8
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from insalign_ros.session import gaps
from insalign_ros.session.config import SessionConfig
from insalign_ros.session.offline import result_from_outputs, run_session
from insalign_ros.session.session import AlignmentSession
from insalign_ros.sim.scenarios import make_scenario


def drop(d, t0: float, T: float):
    """``d`` without its IMU samples (and truth rows) in (t0, t0 + T)."""
    keep = ~((d.t_s > t0) & (d.t_s < t0 + T))
    return replace(d, t_s=d.t_s[keep], omega_ib_b=d.omega_ib_b[keep], f_ib_b=d.f_ib_b[keep], C_b_n=d.C_b_n[keep],
                   lat_rad=d.lat_rad[keep], lon_rad=d.lon_rad[keep], h_m=d.h_m[keep], v_n=d.v_n[keep])


def worst_ratio(d, core: str, t0: float, chunk: int) -> float:
    cfg = SessionConfig.from_dict({"core": core, "init_mode": "truth", "init_rpy_error_deg": [3, -3, 30]})
    s = AlignmentSession(cfg)
    try:
        r = result_from_outputs(core, run_session(s, d, chunk=chunk), s, d)
    finally:
        s.close()
    m = (r.t_s > t0) & (r.t_s < t0 + 30.0)
    return float(np.max(np.abs(r.rpy_err_deg[m]) / r.sigma3_deg[m]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=8, help="random gap positions per case")
    ap.add_argument("--gap", type=float, nargs="+", default=[0.3, 1.5])
    ap.add_argument("--cores", nargs="+", default=["iekf", "liekf"])
    ap.add_argument("--chunk", type=int, default=1000)
    ap.add_argument("--linear", action="store_true", help="linear interpolation only (the previous bridge)")
    a = ap.parse_args()
    if a.linear:
        gaps.candidates = lambda after_available_s: [gaps.LINEAR]
    rng = np.random.default_rng(0)
    print(f"bound: 1.0 (the published 3-sigma); chunk {a.chunk}; bridge {'linear' if a.linear else 'chosen'}")
    for scen, seed, kw in (("ship", 5, {"rate_hz": 50.0}), ("car", 2, {})):
        d = make_scenario(scen, seed=seed, duration_s=140.0, **kw)
        starts = rng.uniform(30.0, 100.0, a.runs)
        for core in a.cores:
            ref = [worst_ratio(d, core, t0, a.chunk) for t0 in starts]
            for T in a.gap:
                r = [worst_ratio(drop(d, t0, T), core, t0, a.chunk) for t0 in starts]
                print(f"{scen:4s} {core:5s} gap {T:.1f} s: max |err|/3-sigma over 30 s after the gap: median "
                      f"{np.median(r):.2f}, max {np.max(r):.2f}, runs > 1: {sum(x > 1 for x in r)}/{len(r)} | same "
                      f"windows without a gap: median {np.median(ref):.2f}, max {np.max(ref):.2f}, > 1: "
                      f"{sum(x > 1 for x in ref)}/{len(ref)}", flush=True)


if __name__ == "__main__":
    main()
