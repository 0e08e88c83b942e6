"""insalign-characterise SOURCE [--imu-topic T] [--out DIR] [--start-s S] [--end-s S]

Characterise an IMU from a static recording: the overlapping Allan deviation of its six axes (allantools), the angle
and velocity random walks (ARW, VRW), the bias instabilities and, where the curve shows it, the rate random walk read
off the standard slopes (insalign_ros/eval/allan.py, docs/characterise.md), and a ready IMU grade to pass back.

SOURCE: a contract bag (--imu-topic), a CSV/.npz the package imports (insalign-import's columns; --imu, --axes), a
KITTI raw oxts drive directory, the rover_canada or car_circles_vn100 directory of the shared data, a simulated
scenario name (make_scenario; --seed, --duration), or ``synthetic:GRADE[:SECONDS]`` (a static IMU with the preset's
ARW, VRW and flicker bias instabilities, drawn directly: a self-check).

Writes <out>/<name>_allan.png (log-log Allan deviation of the six axes with the fitted lines), <name>_allan.json (the
numbers, the taus each term was fitted on), <name>_imu_grade.yaml (the ImuGrade fields: load with
eval.allan.load_grade_yaml) and <name>_params.yaml (the alignment node's parameters file: imu_grade plus the core
parameters the measured grade sets), and prints a one-screen summary. Exit 2 with one line on bad input (a missing
file, no IMU topic, a recording that is not static).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from ..core.units import G0_M_S2

PROG = "insalign-characterise"


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message):
        self.exit(2, f"{PROG}: {message} (see {PROG} --help)\n")


def load_imu(source: str, args) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """(name, t_s, omega_ib_b, f_ib_b) of SOURCE (module docstring), the IMU rows marked valid only."""
    p = Path(source)
    if source.startswith("synthetic:"):
        from ..eval.allan import synthetic_static_imu

        parts = source.split(":")
        dur = float(parts[2]) if len(parts) > 2 else 3600.0
        t, w, f = synthetic_static_imu(parts[1], rate_hz=100.0, duration_s=dur, seed=args.seed)
        return f"synthetic_{parts[1]}_s{args.seed}", t, w, f
    if p.exists():
        if p.is_file() and p.suffix.lower() in (".csv", ".npz"):
            from ..io.importer import import_table

            data, _ = import_table(p, imu=args.imu, axes=args.axes)
        elif p.is_dir() and (p / "imu_planetary.mat").exists():
            from ..io.datasets import read_rover_canada

            data = read_rover_canada(p)[0]
        elif p.is_dir() and (p / "circle_data_0_imu.csv").exists():
            from ..io.datasets import read_car_circles

            data = read_car_circles(p)[0]
        elif p.is_dir() and ((p / "oxts").is_dir() or (p / "timestamps.txt").exists()):
            from ..io.kitti import convert_drive

            data = convert_drive(p, fill_policy="drop")[0]
        else:
            from ..io.bag import read_bag

            data = read_bag(p, **({"imu_topic": args.imu_topic} if args.imu_topic else {}))
        name = (p.resolve().stem if p.is_file() else p.resolve().name) or "imu"
    elif "/" in source or source.endswith((".csv", ".npz", ".db3", ".mcap")):
        raise FileNotFoundError(f"{source}: no such file or directory")
    else:
        from ..sim.scenarios import make_scenario

        data = make_scenario(source, seed=args.seed, duration_s=args.duration)
        name = f"{source}_s{args.seed}"
    ok = data.imu_valid_mask
    return name, np.asarray(data.t_s)[ok], np.asarray(data.omega_ib_b)[ok], np.asarray(data.f_ib_b)[ok]


def segment(t, w, f, start_s, end_s):
    """The samples between start_s and end_s [s after the first sample]."""
    rel = t - t[0]
    keep = np.ones(len(t), bool)
    if start_s is not None:
        keep &= rel >= start_s
    if end_s is not None:
        keep &= rel <= end_s
    if keep.sum() < 100:
        raise ValueError(f"--start-s/--end-s leave {int(keep.sum())} IMU samples (of {len(t)} over "
                         f"{rel[-1]:.1f} s): at least 100 needed")
    return t[keep], w[keep], f[keep]


def _fmt(x, unit, nd=3):
    return "   -   " if x is None else f"{x:.{nd}g} {unit}"


def summary(name: str, res, grade, base: str) -> str:
    """The one-screen summary: per axis, then the grade, with what each number means."""
    s = res.static
    lines = [f"{name}: {res.n} samples at {res.rate_hz:.1f} Hz, {res.duration_s:.1f} s; taus "
             f"{1.0 / res.rate_hz:.3g}-{res.axes[0].taus_s[-1]:.3g} s, fitted up to "
             f"{res.duration_s / 9:.3g} s (>= 9 clusters)"]
    if s:
        lines.append(f"static: 1-s mean specific force within {s['max_sf_dev_m_s2']:.3f} m/s^2 of its median (bound "
                     f"{s['sf_bound_m_s2']:g}), rate within {s['max_rate_dev_deg_s']:.3f} deg/s (bound "
                     f"{s['rate_bound_deg_s']:g})")
    lines.append(f"{'axis':7s} {'white noise (tau=1 s)':>24s} {'bias instability':>22s} {'rate random walk':>22s}"
                 "  taus used (white | flat)")
    for a in res.axes:
        u = a.in_units()
        g = a.is_gyro
        wn = _fmt(u["arw_deg_sqrt_h" if g else "vrw_m_s_sqrt_h"], "deg/sqrt(h)" if g else "m/s/sqrt(h)")
        bi = _fmt(u["bias_instability_deg_h" if g else "bias_instability_mg"], "deg/h" if g else "mg")
        if a.bias_instability_bound == "upper":
            bi = "<= " + bi
        rw = _fmt(u["rrw_deg_h_sqrt_h" if g else "rrw_mg_sqrt_h"], "deg/h/sqrt(h)" if g else "mg/sqrt(h)")
        rng = lambda v: f"{v[0]:.3g}-{v[-1]:.3g}" if v else "-"  # noqa: E731
        lines.append(f"{a.axis:7s} {wn:>24s} {bi:>22s} {rw:>22s}  {rng(a.white_taus_s)} | {rng(a.bias_taus_s)}")
    lines += [
        "meaning: ARW = the attitude error the gyro noise alone builds up, growing as sqrt(t) (deg after 1 h);",
        "  VRW = the same for velocity (m/s after 1 h); bias instability = how far the bias wanders at the best",
        "  averaging time (the Allan floor / 0.664): the best a calibration of the bias can do; rate random walk =",
        "  the slow random drift of the bias beyond that. '<=' the recording is too short to reach the floor.",
        f"grade {grade.name!r} (worst axis; turn-on biases from {base!r}: one recording cannot measure them): "
        f"ARW {grade.gyro_arw_deg_sqrt_h:.3g} deg/sqrt(h), gyro bias instability "
        f"{grade.gyro_bias_instability_deg_h:.3g} deg/h, VRW {grade.acc_vrw_m_s_sqrt_h:.3g} m/s/sqrt(h), accel bias "
        f"instability {grade.acc_bias_instability_mg:.3g} mg"]
    return "\n".join(lines)


def write_outputs(out: Path, name: str, res, grade, base: str, core: str, source: str, no_plot: bool = False) -> dict:
    """The JSON, the grade YAML, the node's parameters file and the plot; returns their paths."""
    import yaml

    from ..session import catalog

    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / f"{name}_allan.json", "grade": out / f"{name}_imu_grade.yaml",
             "params": out / f"{name}_params.yaml", "png": out / f"{name}_allan.png"}
    d = res.to_dict()
    d.update(source=source, imu_grade=grade.to_dict(), base_grade=base)
    paths["json"].write_text(json.dumps(d, indent=2, default=float))
    head = (f"# {PROG} {source}: {res.duration_s:.0f} s at {res.rate_hz:.1f} Hz (docs/characterise.md).\n"
            f"# The ImuGrade fields (filters/imu_grade.py, docs/imu_grades.md; units in the names). The noise terms\n"
            f"# are measured (worst axis); gyro_bias_deg_h and acc_bias_mg (turn-on biases) are {base!r}'s.\n"
            f"# Load: insalign_ros.eval.allan.load_grade_yaml(path) -> ImuGrade; pass back: {paths['params'].name}.\n")
    paths["grade"].write_text(head + yaml.safe_dump(grade.to_dict(), sort_keys=False, width=1000))
    from_grade = catalog.grade_defaults(grade, core)
    params = {"/**": {"ros__parameters": {"core": core, "imu_grade": base, **from_grade}}}
    phead = (f"# alignment_node parameters from {PROG} {source}: imu_grade {base!r} under the measured grade's\n"
             f"# {core} core parameters (explicit core parameters win over imu_grade; docs/imu_grades.md).\n"
             f"#   ros2 run insalign_ros alignment_node --ros-args --params-file {paths['params'].name}\n"
             f"#   insalign-align BAG --core {core} --imu-grade {base} "
             + " ".join(f"--param {k}={v:.6g}" for k, v in from_grade.items()) + "\n")
    paths["params"].write_text(phead + yaml.safe_dump(params, sort_keys=False, width=1000))
    if not no_plot:
        plot(res, paths["png"], f"{name}: Allan deviation ({res.duration_s:.0f} s at {res.rate_hz:.0f} Hz)")
    else:
        del paths["png"]
    return paths


def plot(res, path, title: str = "") -> None:
    """Log-log Allan deviation of the six axes (gyro deg/h, accelerometer mg) with the fitted terms' lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..eval.allan import FLICKER_FACTOR

    fig, axs = plt.subplots(1, 2, figsize=(12, 5))
    for ax, group, unit in ((axs[0], res.gyro, "deg/h"), (axs[1], res.acc, "mg")):
        k = math.degrees(1.0) * 3600.0 if unit == "deg/h" else 1.0 / (G0_M_S2 * 1e-3)
        for a, c in zip(group, ("C0", "C1", "C2")):
            ax.loglog(a.taus_s, a.adev * k, "-", color=c, lw=1.2, label=a.axis)
            if a.n_fit < len(a.taus_s):
                ax.loglog(a.taus_s[a.n_fit - 1:], a.adev[a.n_fit - 1:] * k, ":", color=c, lw=1.0)
            if a.white is not None:
                tt = np.array([a.taus_s[0], max(a.white_taus_s[-1] * 4, 1.0)])
                ax.loglog(tt, a.white / np.sqrt(tt) * k, "--", color=c, lw=0.8)
                ax.plot(1.0, a.white * k, "o", color=c, ms=4)
            if a.bias_instability is not None:
                y = FLICKER_FACTOR * a.bias_instability * k
                ls = "-." if a.bias_instability_bound == "fit" else (0, (1, 3))
                ax.loglog([a.bias_taus_s[0] / 2, a.bias_taus_s[-1] * 2], [y, y], linestyle=ls, color=c, lw=0.8)
            if a.rrw is not None:
                tt = np.array(a.rrw_taus_s)
                ax.loglog(tt, a.rrw * np.sqrt(tt / 3.0) * k, "--", color=c, lw=0.8)
        ax.set_xlabel("averaging time tau [s]")
        ax.set_ylabel(f"Allan deviation [{unit}]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axs[0].set_title("gyro: --- white (ARW at o, tau = 1 s), -.- 0.664 x bias instability", fontsize=9)
    axs[1].set_title("accelerometer: --- white (VRW at o), -.- 0.664 x bias instability; ... unfitted", fontsize=9)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    _, what, rest = __doc__.split("\n\n", 2)
    ap = _OneLineParser(prog=PROG, description=what, formatter_class=argparse.RawDescriptionHelpFormatter, epilog=rest)
    ap.add_argument("source", help="bag, CSV/.npz, KITTI drive dir, rover_canada/car_circles dir, scenario name, "
                                   "or synthetic:GRADE[:SECONDS]")
    ap.add_argument("--imu-topic", default=None, help="Imu topic of a bag (default: the contract's /imu/data)")
    ap.add_argument("--out", default=".", help="output directory (default: the current one)")
    ap.add_argument("--start-s", type=float, default=None, help="first second to use (after the first sample)")
    ap.add_argument("--end-s", type=float, default=None, help="last second to use (after the first sample)")
    ap.add_argument("--name", default=None, help="output stem and grade name (default: from SOURCE)")
    ap.add_argument("--base-grade", default="unknown_mems",
                    help="preset for what one recording cannot measure: the turn-on biases, and any term not in "
                         "the curve (default unknown_mems)")
    ap.add_argument("--core", default="auto", help="core whose parameters the params file sets (default auto)")
    ap.add_argument("--imu", choices=("rates", "increments"), default="rates", help="CSV/.npz: insalign-import's --imu")
    ap.add_argument("--axes", default="FLU", help="CSV/.npz: the IMU's axes (insalign-import's --axes)")
    ap.add_argument("--seed", type=int, default=0, help="scenario / synthetic seed")
    ap.add_argument("--duration", type=float, default=None, help="scenario duration [s]")
    ap.add_argument("--no-static-check", action="store_true", help="skip the static check (you vouch for it)")
    ap.add_argument("--no-plot", action="store_true")
    try:
        a = ap.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        from ..eval.allan import characterise
        from ..filters.imu_grade import get_grade
        from ..session import catalog

        base = get_grade(a.base_grade).name
        catalog.core_defaults(a.core)  # unknown core: ValueError before any work
        name, t, w, f = load_imu(a.source, a)
        t, w, f = segment(t, w, f, a.start_s, a.end_s)
        res = characterise(t, w, f, check=not a.no_static_check)
        stem = a.name or name
        grade = res.grade(name=f"measured_{stem}" if not a.name else a.name, base=base,
                          source=f"{PROG} {a.source} ({res.duration_s:.0f} s at {res.rate_hz:.1f} Hz)")
        paths = write_outputs(Path(a.out), stem, res, grade, base, a.core, a.source, a.no_plot)
    except (ValueError, FileNotFoundError, KeyError, OSError, ImportError) as exc:
        print(f"{PROG}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", file=sys.stderr)
        return 2
    print(summary(stem, res, grade, base))
    print("wrote " + ", ".join(str(p) for p in paths.values()))
    print(f"pass back: ros2 run insalign_ros alignment_node --ros-args --params-file {paths['params']}  (or "
          f"insalign-align ... --imu-grade {base} --param KEY=VALUE as in that file's header)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
