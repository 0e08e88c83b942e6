"""Is the in-motion noise model honest on a real car? The velocity the filter claims against the RT3003's own
velocity (a reference the pipeline never sees), per KITTI drive, for velocity-random-walk values of the default
grade along the vehicle's vertical (issue 24, "a noise model the data can correct"; docs/imu_grades.md).

    nice .venv/bin/python benchmarks/kitti_velocity_noise.py [--vrw-up 0.2 0.6 1.0 1.5] [--cores auto iekf]

Each run is `core` from the sensors with the default parameters and ``imu_grade: unknown_mems`` with its
``acc_vrw_up_m_s_sqrt_h`` (the velocity random walk along the vehicle's vertical; 0.2 = its horizontal
``acc_vrw_m_s_sqrt_h``: isotropic) replaced by the swept value, on the drives that move (0042, 0018, 0020; fix sigma as reported). Per run, over the outputs from 60 s
on (the filter converged; the RT3003's fill rows left out): the fraction of outputs whose 3-sigma covers the East /
North / Up velocity error against the RT3003's ve, vn, vu, the mean of the squared normalised errors (1 for an
honest filter), and the flag: first rise and the fraction of the time it is up after it. Physical floor: the RT3003's
velocity accuracy (`vel_accuracy`, median printed per drive; a few cm/s).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import real_data as RD  # noqa: E402

DRIVES = ("kitti_0042", "kitti_0018", "kitti_0020")
FROM_S = 60.0


def one(name: str, root: Path, core: str, vrw_up: float) -> dict:
    from insalign_ros.io.kitti import convert_drive

    data, _ = convert_drive(root / "kitti_raw_oxts_sync" / RD.KITTI_DRIVES[name], gnss_rate_hz=1.0)
    ref_v, ref_att = data.v_n.copy(), RD.kitti_reference(data)
    valid = data.imu_valid if data.imu_valid is not None else np.ones(data.n, bool)
    r = RD.run(RD.strip_truth(data), core, core_params={"acc_vrw_up_m_s_sqrt_h": vrw_up})
    outs = r.result.outputs
    cover, z2 = [], []
    for o in outs:
        k = int(np.searchsorted(data.t_s, o.stamp_s))
        if o.stamp_s < data.t_s[0] + FROM_S or k >= data.n or abs(data.t_s[k] - o.stamp_s) > 1e-3 or not valid[k]:
            continue
        e = o.estimate
        iv = [i for i, n in enumerate(e.state_names) if n[:2] in ("nu", "dv") or n.startswith("v_")][:3]
        sig = np.sqrt(np.diag(e.P)[iv])  # the velocity-error sigma of the core's convention (isotropic frames)
        dv = e.v_n - ref_v[k]
        cover.append(np.abs(dv) <= 3.0 * sig)
        z2.append((dv / sig) ** 2)
    ev = RD.evaluate(r, ref_att, float(data.t_s[0]), float(data.t_s[0]))
    return {"drive": name, "core": core, "vrw": vrw_up, "n": len(cover), "cover": np.mean(cover, axis=0),
            "z2": np.mean(z2, axis=0), "t_flag": ev["t_flag_s"], "up": ev["up_fraction"],
            "yaw_cover": ev["coverage"][2]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=None, help="the shared data directory (default: ../shared/data)")
    ap.add_argument("--vrw-up", nargs="+", type=float, default=[0.2, 0.6, 1.0, 1.5],
                    help="acc_vrw_up_m_s_sqrt_h values [m/s/sqrt(h)]")
    ap.add_argument("--cores", nargs="+", default=["auto", "iekf"])
    ap.add_argument("--drives", nargs="+", default=list(DRIVES), choices=DRIVES)
    a = ap.parse_args(argv)
    root = Path(a.data) if a.data else RD.shared_data_dir()
    if root is None or not (root / "kitti_raw_oxts_sync").is_dir():
        print("the shared KITTI drives are absent: nothing to measure")
        return 1
    print(f"velocity 3-sigma coverage and mean squared normalised error vs the RT3003's velocity (outputs from "
          f"{FROM_S:g} s on); flag: first rise [s] and the fraction of the time up after it")
    print("| drive | core | acc_vrw_up [m/s/sqrt(h)] | outputs | coverage E / N / U | mean z^2 E / N / U | first flag [s] | "
          "flag up after first rise | yaw coverage (flag up) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in a.drives:
        for core in a.cores:
            for vrw in a.vrw_up:
                r = one(name, root, core, vrw)
                c, z = r["cover"], r["z2"]
                print(f"| {name} | {core} | {vrw:g} | {r['n']} | {c[0]:.2f} / {c[1]:.2f} / {c[2]:.2f} | "
                      f"{z[0]:.1f} / {z[1]:.1f} / {z[2]:.1f} | {r['t_flag']:.1f} | {r['up']:.2f} | "
                      f"{r['yaw_cover']:.2f} |", flush=True)
    print("Physical floor: the RT3003's velocity accuracy, a few cm/s (dataformat.txt: vel_accuracy), below every "
          "sigma above.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
