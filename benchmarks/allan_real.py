"""IMU characterisation (insalign-characterise, eval/allan.py) on the real static recordings, and the acceptance case.

1. The acceptance case: a 1-h static IMU at 100 Hz with known ARW, VRW and flicker bias instability (test/test_allan.py's
   grade, drawn directly with numpy), seeds 0..N-1: the grade read off it (worst axis) / the truth.
2. The real recordings of ../shared/data that are static: KITTI 2011_09_28_drive_0016 (parked, 18.6 s) and the first
   29 s of 2011_09_26_drive_0057 (parked before it drives off at 29.3 s), an OXTS RT3003 at 10 Hz: per axis the white
   noise, the bias-instability bound and the tau ranges. rover_canada and car_circles_vn100 are tried over their
   first seconds and refused (they never stand still: the static check's message is printed).

    nice .venv/bin/python benchmarks/allan_real.py [--seeds 5] [--out DIR]   (DIR: the plots, JSON and YAML)

docs/characterise.md quotes this output.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from insalign_ros.cli.characterise import load_imu, segment, write_outputs  # noqa: E402
from insalign_ros.eval import allan as A  # noqa: E402
from insalign_ros.filters.imu_grade import ImuGrade  # noqa: E402

TRUE = ImuGrade("allan_test", 0.3, 100.0, 10.0, 0.05, 1.0, 0.05)
FIELDS = ("gyro_arw_deg_sqrt_h", "gyro_bias_instability_deg_h", "acc_vrw_m_s_sqrt_h", "acc_bias_instability_mg")


def shared_data_dir() -> Path | None:
    from insalign_ros.io.datasets import shared_data_dir as find

    return find(__file__)


def acceptance(seeds: int) -> None:
    print(f"## 1 h static at 100 Hz, true ARW {TRUE.gyro_arw_deg_sqrt_h} deg/sqrt(h), gyro BI "
          f"{TRUE.gyro_bias_instability_deg_h} deg/h, VRW {TRUE.acc_vrw_m_s_sqrt_h} m/s/sqrt(h), accel BI "
          f"{TRUE.acc_bias_instability_mg} mg: measured (worst axis) / true\n")
    print("| seed | " + " | ".join(FIELDS) + " | worst per-axis error: white | bias instability |")
    print("|---" * (len(FIELDS) + 3) + "|")
    allw, allb = [], []
    for s in range(seeds):
        t, w, f = A.synthetic_static_imu(TRUE, 100.0, 3600.0, seed=s)
        r = A.characterise(t, w, f)
        g = r.grade()
        ew, eb = [], []
        for a in r.axes:
            u = a.in_units()
            k = ("arw_deg_sqrt_h", "bias_instability_deg_h") if a.is_gyro else ("vrw_m_s_sqrt_h", "bias_instability_mg")
            ref = (FIELDS[0], FIELDS[1]) if a.is_gyro else (FIELDS[2], FIELDS[3])
            ew.append(u[k[0]] / getattr(TRUE, ref[0]) - 1.0)
            eb.append(u[k[1]] / getattr(TRUE, ref[1]) - 1.0)
        allw += ew
        allb += eb
        print(f"| {s} | " + " | ".join(f"{getattr(g, x) / getattr(TRUE, x):.3f}" for x in FIELDS)
              + f" | {100 * max(map(abs, ew)):.1f} % | {100 * max(map(abs, eb)):.1f} % |")
    for what, e in (("white noise", allw), ("bias instability", allb)):
        e = np.array(e)
        print(f"\n{what}, {len(e)} axis values: mean error {100 * e.mean():+.1f} %, rms {100 * np.sqrt(np.mean(e**2)):.1f} %,"
              f" worst {100 * np.abs(e).max():.1f} %, beyond 20 %: {int(np.sum(np.abs(e) > 0.2))}")


def real(data_dir: Path, out: Path | None) -> None:
    k = data_dir / "kitti_raw_oxts_sync"
    cases = [("KITTI 2011_09_28_drive_0016 (all)", k / "2011_09_28_drive_0016_oxts", None, None),
             ("KITTI 2011_09_26_drive_0057 (0-29 s)", k / "2011_09_26_drive_0057_oxts", None, 29.0),
             ("rover_canada (0-8 s)", data_dir / "rover_canada", None, 8.0),
             ("car_circles_vn100 (0-10 s)", data_dir / "car_circles_vn100", None, 10.0)]
    print("\n## Real recordings\n")
    for label, path, s0, s1 in cases:
        if not path.exists():
            print(f"{label}: absent ({path})")
            continue
        args = SimpleNamespace(imu_topic=None, imu="rates", axes="FLU", seed=0, duration=None)
        name, t, w, f = load_imu(str(path), args)
        t, w, f = segment(t, w, f, s0, s1)
        try:
            r = A.characterise(t, w, f)
        except A.NotStaticError as exc:
            print(f"### {label}: refused: {exc}\n")
            continue
        print(f"### {label}: {r.n} samples at {r.rate_hz:.1f} Hz, {r.duration_s:.1f} s; taus "
              f"{r.axes[0].taus_s[0]:.3g}-{r.axes[0].taus_s[-1]:.3g} s, fitted up to "
              f"{r.duration_s / A.MIN_CLUSTERS:.3g} s; static: 1-s means within {r.static['max_sf_dev_m_s2']:.3f} "
              f"m/s^2 and {r.static['max_rate_dev_deg_s']:.3f} deg/s\n")
        print("| axis | white noise (tau = 1 s) | white taus [s] | bias instability | at tau [s] | notes |")
        print("|---|---|---|---|---|---|")
        for a in r.axes:
            u = a.in_units()
            g = a.is_gyro
            wn = u["arw_deg_sqrt_h" if g else "vrw_m_s_sqrt_h"]
            bi = u["bias_instability_deg_h" if g else "bias_instability_mg"]
            wt = f"{a.white_taus_s[0]:.3g}-{a.white_taus_s[-1]:.3g}" if a.white_taus_s else "-"
            bt = f"{a.bias_taus_s[0]:.3g}-{a.bias_taus_s[-1]:.3g}" if a.bias_taus_s else "-"
            print(f"| {a.axis} | {'-' if wn is None else f'{wn:.3g}'} {'deg/sqrt(h)' if g else 'm/s/sqrt(h)'} | {wt} | "
                  f"{'<= ' if a.bias_instability_bound == 'upper' else ''}{bi:.3g} {'deg/h' if g else 'mg'} | {bt} | "
                  f"{'; '.join(n.split(':')[0] for n in a.notes)} |")
        gr = r.grade(name=f"measured_{name}")
        print(f"\ngrade (worst axis; turn-on biases and unresolved terms from unknown_mems): ARW "
              f"{gr.gyro_arw_deg_sqrt_h:.3g} deg/sqrt(h), gyro BI {gr.gyro_bias_instability_deg_h:.3g} deg/h, VRW "
              f"{gr.acc_vrw_m_s_sqrt_h:.3g} m/s/sqrt(h), accel BI {gr.acc_bias_instability_mg:.3g} mg\n")
        if out is not None:
            write_outputs(out, name, r, gr, "unknown_mems", "auto", str(path))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    acceptance(a.seeds)
    d = shared_data_dir()
    if d is None:
        print("\n../shared/data absent: no real recordings")
    else:
        real(d, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
