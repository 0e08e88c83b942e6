#!/usr/bin/env python3
"""Fixed-seed regression set: every registered core on ship, car, static, park_drive, two_position (single filter and
a 4-hypothesis yaw bank where the core takes one) and the shared KITTI 0042 and 0018 drives, through ``ia.align``.

    .venv/bin/python benchmarks/regression_set.py record OUT.npz      # the estimates of this checkout
    .venv/bin/python benchmarks/regression_set.py compare OLD.npz NEW.npz [--tol-rad 1e-9]

``compare`` prints each case whose attitude differs by more than the tolerance (largest rotation angle between the
two runs over every output), and cases whose outcome (error text, output count) changed. A refactor that keeps the
numbers prints nothing but the summary line.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import insalign_ros as ia  # noqa: E402

SCENARIOS = {"ship": 60.0, "car": 60.0, "static": 40.0, "park_drive": 60.0, "two_position": 60.0}

def _data_root() -> Path:
    """../shared/data beside the checkout (or beside any folder above it: worktrees), or $INSALIGN_DATA."""
    from insalign_ros.io.datasets import shared_data_dir

    return shared_data_dir(__file__) or Path("/nonexistent")


KITTI = _data_root() / "kitti_raw_oxts_sync"
DRIVES = ("2011_10_03_drive_0042_oxts", "2011_09_30_drive_0018_oxts")
STATIC = ("pkf", "ekf10", "coarse")


def cases():
    cores = [c for c in ia.core_names()]
    for scen, dur in SCENARIOS.items():
        for c in cores:
            yield f"{scen}/{c}", scen, dur, c, {}
            if c not in STATIC and c != "auto":
                yield f"{scen}/{c}/bank4", scen, dur, c, {"yaw_hypotheses": 4}
    for d in DRIVES:
        for c in ("auto", "iekf", "liekf", "ekf", "pi_liekf"):
            yield f"kitti_{d[17:21]}/{c}", KITTI / d, 120.0, c, {}


def run_case(src, dur, core, core_params):
    if isinstance(src, Path):
        if not src.exists():
            return None
        from insalign_ros.io.kitti import convert_drive

        src, _ = convert_drive(src, gnss_rate_hz=1.0)
    try:
        r = ia.align(src, core=core, duration_s=dur, seed=3, core_params=core_params or None)
    except Exception as exc:  # noqa: BLE001  (a refused configuration is an outcome too)
        return {"error": f"{type(exc).__name__}: {exc}"}
    C = np.array([o.estimate.C_b_n for o in r.outputs]).reshape(-1, 3, 3)
    return {"t": r.t_s, "C": C, "s3": r.sigma3_deg, "aligned": r.aligned.astype(int), "error": ""}


def record(out: str, only: str = "") -> None:
    store = {}
    for name, src, dur, core, cp in cases():
        if only and not name.startswith(only):
            continue
        t0 = time.perf_counter()
        res = run_case(src, dur, core, cp)
        if res is None:
            print(f"{name}: data absent")
            continue
        for k, v in res.items():
            store[f"{name}::{k}"] = np.asarray(v)
        n = len(res.get("t", []))
        print(f"{name}: {n} outputs {res['error'][:60]} ({time.perf_counter() - t0:.1f} s)", flush=True)
    np.savez_compressed(out, **store)


def _angle(Ca, Cb):
    """Per output, the largest element of |Ca - Cb|: the rotation angle between them to first order [rad] (arccos of
    the trace is ill-conditioned near 0: identical matrices would differ by ~1e-8 rad)."""
    return np.abs(Ca - Cb).max(axis=(1, 2))


def compare(old: str, new: str, tol: float) -> int:
    a, b = np.load(old), np.load(new)
    names = sorted({k.split("::")[0] for k in a.files} | {k.split("::")[0] for k in b.files})
    bad = 0
    for n in names:
        ea, eb = str(a.get(f"{n}::error", "missing")), str(b.get(f"{n}::error", "missing"))
        if "missing" in (ea, eb):
            print(f"{n}: only in {'NEW' if ea == 'missing' else 'OLD'} (not compared)")
            continue
        if ea != eb:
            print(f"{n}: outcome {ea!r} -> {eb!r}")
            bad += 1
            continue
        if ea:
            continue
        Ca, Cb = a[f"{n}::C"], b[f"{n}::C"]
        if Ca.shape != Cb.shape or not np.array_equal(a[f"{n}::t"], b[f"{n}::t"]):
            print(f"{n}: outputs {Ca.shape[0]} -> {Cb.shape[0]}")
            bad += 1
            continue
        d = float(np.max(_angle(Ca, Cb))) if Ca.size else 0.0
        flags = int(np.sum(a[f"{n}::aligned"] != b[f"{n}::aligned"]))
        if d > tol or flags:
            print(f"{n}: max attitude difference {d:.3e} rad, flag differs at {flags} outputs")
            bad += 1
    print(f"{len(names)} cases, {bad} differ (tolerance {tol:g} rad)")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--only", default="", help="record only the cases whose name starts with this")
    c = sub.add_parser("compare")
    c.add_argument("old")
    c.add_argument("new")
    c.add_argument("--tol-rad", type=float, default=1e-9)
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.out, args.only)
        return 0
    return compare(args.old, args.new, args.tol_rad)


if __name__ == "__main__":
    sys.exit(main())
