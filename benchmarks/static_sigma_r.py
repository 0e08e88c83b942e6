"""Static alignment benchmark (issue 6): PKF vs 10-state EKF for sigma_R in {1e-3, 1e-2, 1e-1} m/s, initial azimuth
errors {30, 90, 170} deg, scenarios 'static' (ADIS16488A, engine vibration) and 'static_navgrade', N seeds, with the
physical floor of every case computed from the biases actually drawn. Prints the PKF paper's Tables 2-3 in their
layout (RMS, STD, convergence time) and writes the section "Stationary alignment" of docs/results.md.

Definitions (docs/static_alignment.md): RMS and STD of the error over the second half of the run (steady state);
floors per run: bias floor eps_east/(omega_ie cos lat) from the drawn biases, ARW limit ARW/(omega_ie cos lat sqrt(T))
at T = 300 s and at the end of the run, combined = sqrt(bias^2 + ARW^2); convergence time = first time after which
|error| stays within max(2 x combined floor at the end of the run, 3 x STD of the steady state).

Filter noise per scenario: VRW/ARW/bias priors from the scenario's IMU spec (``config_for_imu``) plus the vibration
term ``VIBRATION_VRW_M_S_SQRT_S[scenario]`` (docs/static_alignment.md, "Process noise per IMU grade").

Long runs can be split (each command < 10 min on 2 cores) and merged:

    B="nice .venv/bin/python benchmarks/static_sigma_r.py --no-write"
    $B --scenarios static_navgrade --seeds 5 --json-out /tmp/nav.json
    $B --scenarios static --seeds 1 --seed0 0 --json-out /tmp/mems0.json   # one seed per command: ~4 min
    nice .venv/bin/python benchmarks/static_sigma_r.py --from-json /tmp/nav.json /tmp/mems.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from insalign_ros.filters.ekf10 import Ekf10, Ekf10Config  # noqa: E402
from insalign_ros.filters.pkf import Pkf, PkfConfig  # noqa: E402
from insalign_ros.filters.static_model import (  # noqa: E402
    arw_azimuth_limit_rad, config_for_imu, physical_floor)

AS = 180 / math.pi * 3600  # rad -> arcsec
AM = 180 / math.pi * 60  # rad -> arcmin
CORES = {"pkf": (Pkf, PkfConfig), "ekf10": (Ekf10, Ekf10Config)}
#: vibration process noise on the velocity states per scenario [m/s/sqrt(s)] (docs/static_alignment.md: measured,
#: the simulated engine vibration and sway add nothing to the mechanised velocity beyond the VRW; the vibration's own
#: velocity at the update instants, 2.3e-4 m/s rms, is a measurement error that sigma_R covers)
VIBRATION_VRW_M_S_SQRT_S = {"static": 0.0, "static_navgrade": 0.0}
CONFIG_FILES = {"static": "config/{core}.yaml", "static_navgrade": "config/{core}_navgrade.yaml"}


def convergence_time(t, err, tol_floor):
    """First time after which |err| stays within max(2 tol_floor, 3 std(steady state)); nan if never."""
    half = len(t) // 2
    tol = max(2.0 * tol_floor, 3.0 * float(np.std(err[half:])))
    bad = np.nonzero(np.abs(err) > tol)[0]
    if len(bad) == 0:
        return float(t[0])
    if bad[-1] == len(t) - 1:
        return float("nan")
    return float(t[bad[-1] + 1])


def static_run(core, sc, az0_rad, sigma_R_m_s, params, zupt_hz=10.0, init_sigma_yaw_deg=100.0,
               init_sigma_level_deg=2.0):
    """``run_static`` (filters/static_model.py) through the session path users take, ``ia.align``: truth attitude
    turned by az0 about Up, a zero-velocity update every round(rate/zupt_hz) IMU samples (the session's ZUPT rate is
    set to rate/that, so the cadence is the same; the session's first update falls on the first sample after the
    initialisation instead of the 12th), outputs at 1 Hz. Returns (t_s, err_rad (K, 3) [E, N, U], sigma3_rad (K, 3))."""
    import insalign_ros as ia
    from insalign_ros.core import earth

    rate = 1.0 / float(sc.t_s[1] - sc.t_s[0])
    every = max(1, int(round(rate / zupt_hz)))
    r = ia.align(sc, core=core, core_params=params, init_mode="truth", init_rpy_error_deg=[0.0, 0.0, math.degrees(az0_rad)],
                 init_sigma_rpy_deg=[init_sigma_level_deg, init_sigma_level_deg, init_sigma_yaw_deg],
                 zupt_rate_hz=rate / every, zupt_sigma_m_s=sigma_R_m_s, output_period_s=1.0)
    outs = r.outputs[1:]  # the initial estimate is not a result
    k = np.searchsorted(sc.t_s, [o.stamp_s for o in outs])
    err = np.array([earth.heading_error_enu_rad(o.estimate.C_b_n, sc.C_b_n[i]) for o, i in zip(outs, k)])
    sig3 = np.array([3.0 * np.sqrt(np.maximum(np.diag(o.estimate.P_att_n), 0.0)) for o in outs])
    return np.array([o.stamp_s for o in outs]), err, sig3


def run_case(sc, scen, seed, dur, az0, sig_r, core, pkf_params):
    """One (scenario, seed, az0, sigma_R, core) run as a Dask task on the simulated ``sc`` (``sweep.shared_scenario``:
    simulated once per sweep)."""
    lat = float(sc.lat_rad[0])
    fl = physical_floor(sc.C_b_n[0], sc.bias_gyro_b, sc.bias_acc_b, lat)
    arw300 = arw_azimuth_limit_rad(sc.imu_spec.arw_deg_sqrt_h, lat, min(300.0, dur))
    arw_end = arw_azimuth_limit_rad(sc.imu_spec.arw_deg_sqrt_h, lat, dur)
    comb_end = math.hypot(fl["azimuth_rad"], arw_end)
    cls, cc = CORES[core]
    t0 = time.time()
    extra = dict(pkf_params) if core == "pkf" else {}
    extra.setdefault("vibration_vrw_m_s_sqrt_s", VIBRATION_VRW_M_S_SQRT_S[scen])
    params = config_for_imu(cc, sc.imu_spec, **extra).to_dict()
    t, err, sig3 = static_run(core, sc, math.radians(az0), sig_r, params)
    wall = time.time() - t0
    half = len(t) // 2
    out = {"scen": scen, "seed": seed, "dur": dur, "az0": az0, "sig_r": sig_r, "core": core, "wall_s": wall,
           "floor_level": fl["level_rad"], "floor_az": fl["azimuth_rad"], "floor_az_lin": fl["azimuth_linear_rad"],
           "arw300": arw300, "arw_end": arw_end,
           "comb300": math.hypot(fl["azimuth_rad"], arw300), "comb_end": comb_end}
    for i, nm, f in ((0, "roll", fl["level_rad"]), (1, "pitch", fl["level_rad"]), (2, "az", comb_end)):
        e = err[:, i]
        out[f"{nm}_rms"] = float(np.sqrt(np.mean(e[half:] ** 2)))
        out[f"{nm}_std"] = float(np.std(e[half:]))
        out[f"{nm}_tconv"] = convergence_time(t, e, f)
    k300 = min(len(t) - 1, int(np.searchsorted(t, 300.0)))
    out["az_300"] = float(abs(err[k300, 2]))
    out["sig3_300"] = float(sig3[k300, 2])
    out["az_end"] = float(abs(err[-1, 2]))
    out["sig3_end"] = float(sig3[-1, 2])
    out["covered"] = bool(np.all(np.abs(err[10:, 2]) <= sig3[10:, 2]))
    out["t"] = t.tolist()
    out["az_err"] = err[:, 2].tolist()
    return out


def fmt(v, scale, nd=2):
    return "nan" if not math.isfinite(v) else f"{v * scale:.{nd}f}"


def tconv_str(v):
    """median over seeds, with the number of runs that never converged"""
    v = np.asarray(v, dtype=float)
    ok = v[np.isfinite(v)]
    nn = int(np.sum(~np.isfinite(v)))
    med = f"{np.median(ok):.0f}" if len(ok) else "nan"
    return med + (f" ({nn} nan)" if nn else "")


def tables(res, cmd):
    lines = ["## Stationary alignment", "",
             "PKF (5 states + predicted model error) vs 10-state EKF, zero-velocity updates at 10 Hz, sigma_R is the",
             "ZUPT standard deviation given to the filters. Error = attitude error as an ENU rotation vector",
             "(level: E and N components, azimuth: U) against the simulator's truth; RMS/STD over the second half of",
             "the run, mean over seeds; convergence time (docs/static_alignment.md) as the median over seeds, with",
             "the number of runs that never converged. Floors per run (docs/static_alignment.md,",
             "\"The physical floor\"): **bias floor** atan2(|eps_E|, omega_ie cos lat + eps_N) (= eps_east/(omega_ie",
             "cos lat) to first order) from the biases actually drawn (level: b_acc/g); **ARW limit**",
             "ARW/(omega_ie cos lat sqrt(T))",
             "(1 sigma, gyro white noise over T); **combined** = sqrt(bias^2 + ARW^2).",
             "", 
             "Command: `" + cmd + "`", ""]
    for scen in sorted({r["scen"] for r in res}):
        rs = [r for r in res if r["scen"] == scen]
        dur = rs[0]["dur"]
        keys = sorted({(r["az0"], r["sig_r"]) for r in rs})

        def sel(az0, sr, core):
            return [r for r in rs if r["az0"] == az0 and r["sig_r"] == sr and r["core"] == core]

        def agg(az0, sr, core, key, fn=np.mean):
            v = [r[key] for r in sel(az0, sr, core)]
            return float(fn(v)) if v else float("nan")

        ss = sorted({r["seed"] for r in rs})
        lines += [f"### {scen} ({dur:.0f} s, seeds {ss[0]}..{ss[-1]}, config "
                  f"`{CONFIG_FILES[scen].format(core='<core>')}`)", "",
                  "Table 2 layout (level, arcsec):", "",
                  "| az0 deg | sigma_R m/s | PKF E RMS | PKF E STD | PKF N RMS | PKF N STD | EKF E RMS | EKF E STD "
                  "| EKF N RMS | EKF N STD | bias floor level |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for az0, sr in keys:
            row = [f"{az0:g}", f"{sr:g}"]
            for core in ("pkf", "ekf10"):
                for nm in ("roll", "pitch"):
                    row += [fmt(agg(az0, sr, core, f"{nm}_rms"), AS), fmt(agg(az0, sr, core, f"{nm}_std"), AS)]
            row.append(fmt(agg(az0, sr, "pkf", "floor_level"), AS))
            lines.append("| " + " | ".join(row) + " |")
        lines += ["", f"Table 3 layout (azimuth, arcmin; t_conv s; |error| at 300 s mean / max over seeds; floors mean "
                  f"over seeds, ARW and combined at 300 s and (in the last column) at {dur:.0f} s):", "",
                  "| az0 deg | sigma_R m/s | PKF RMS | PKF STD | PKF t_conv | PKF @300s | EKF RMS | EKF STD "
                  "| EKF t_conv | EKF @300s | bias floor | ARW 300 s | combined 300 s | 2x combined 300 s "
                  "| combined end |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for az0, sr in keys:
            row = [f"{az0:g}", f"{sr:g}"]
            for core in ("pkf", "ekf10"):
                row += [fmt(agg(az0, sr, core, "az_rms"), AM), fmt(agg(az0, sr, core, "az_std"), AM),
                        tconv_str([r["az_tconv"] for r in sel(az0, sr, core)]),
                        fmt(agg(az0, sr, core, "az_300"), AM) + " / " + fmt(agg(az0, sr, core, "az_300", np.max), AM)]
            row += [fmt(agg(az0, sr, "pkf", "floor_az"), AM), fmt(agg(az0, sr, "pkf", "arw300"), AM),
                    fmt(agg(az0, sr, "pkf", "comb300"), AM), fmt(2 * agg(az0, sr, "pkf", "comb300"), AM),
                    fmt(agg(az0, sr, "pkf", "comb_end"), AM)]
            lines.append("| " + " | ".join(row) + " |")
        # per-seed checks
        n_runs = len(rs)
        within = sum(r["az_300"] <= 2 * r["comb300"] for r in rs)
        within_bias = sum(r["az_300"] <= 2 * r["floor_az"] for r in rs)
        below_bias = sum(r["az_end"] < r["floor_az"] for r in rs)
        covered = sum(r["covered"] for r in rs)
        lines += ["", f"Per run ({n_runs} runs = seeds x az0 x sigma_R x 2 cores): |error at 300 s| <= 2x combined "
                  f"floor in **{within}/{n_runs}**; <= 2x bias floor alone in {within_bias}/{n_runs}; final error "
                  f"below the bias floor in {below_bias}/{n_runs} (expected when the noise happens to cancel part of "
                  f"the bias: the error is bias + noise, not max(bias, noise)); reported 3-sigma azimuth covers the "
                  f"error at every second after 10 s in {covered}/{n_runs}.", ""]
        for core in ("pkf", "ekf10"):
            for az0 in sorted({k[0] for k in keys}):
                worst = max((r for r in rs if r["core"] == core and r["az0"] == az0),
                            key=lambda r: r["az_300"] / r["comb300"])
                lines.append(f"* {core}, az0 {az0:g} deg: worst |error at 300 s| / combined floor = "
                             f"{worst['az_300'] / worst['comb300']:.2f} (seed {worst['seed']}, sigma_R "
                             f"{worst['sig_r']:g})")
        lines.append("")
    # convergence time vs sigma_R (paper Table 3 claim)
    lines += ["### Convergence time vs sigma_R (paper Table 3: PKF 8/20/50 s, EKF 150/400/524 s)", "",
              "Median over seeds and initial azimuth errors [s] (runs that never converged in brackets):", "",
              "| scenario | sigma_R m/s | PKF t_conv | EKF t_conv | PKF faster in (paired runs) |",
              "|---|---|---|---|---|"]
    for scen in sorted({r["scen"] for r in res}):
        for sr in sorted({r["sig_r"] for r in res}):
            p = {(r["seed"], r["az0"]): r["az_tconv"] for r in res if r["scen"] == scen and r["sig_r"] == sr
                 and r["core"] == "pkf"}
            e = {(r["seed"], r["az0"]): r["az_tconv"] for r in res if r["scen"] == scen and r["sig_r"] == sr
                 and r["core"] == "ekf10"}
            pairs = [(p[k], e[k]) for k in p if k in e]
            faster = sum((math.isfinite(a) and (not math.isfinite(b) or a < b)) for a, b in pairs)
            same = sum((math.isfinite(a) and math.isfinite(b) and a == b) for a, b in pairs)
            lines.append(f"| {scen} | {sr:g} | {tconv_str(list(p.values()))} | {tconv_str(list(e.values()))} | "
                         f"{faster}/{len(pairs)} faster, {same} equal |")
    lines.append("")
    return "\n".join(lines)


def write_section(text, path):
    old = path.read_text() if path.exists() else "# Results\n"
    head = "## Stationary alignment"
    if head in old:
        a = old.index(head)
        b = old.find("\n## ", a + len(head))
        new = old[:a] + text.rstrip() + "\n" + (old[b:] if b >= 0 else "")
    else:
        new = old.rstrip() + "\n\n" + text.rstrip() + "\n"
    path.write_text(new)


def plot(res):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    for scen in sorted({r["scen"] for r in res}):
        fig, axs = plt.subplots(1, 3, figsize=(13, 4.2), sharey=True)
        seed0 = min(r["seed"] for r in res if r["scen"] == scen)
        fl = [r for r in res if r["scen"] == scen and r["seed"] == seed0][0]
        for ax, az0 in zip(axs, (30.0, 90.0, 170.0)):
            for r in res:
                if r["scen"] == scen and r["seed"] == seed0 and r["az0"] == az0:
                    ax.plot(r["t"], np.degrees(r["az_err"]), "-" if r["core"] == "pkf" else "--",
                            label=f"{r['core']} sigma_R={r['sig_r']:g}")
            for v, st, lab in ((fl["floor_az"], "k-", "+-bias floor"), (fl["comb_end"], "k:", "+-combined (end)")):
                ax.plot([0, fl["dur"]], [math.degrees(v)] * 2, st, lw=0.8, label=lab)
                ax.plot([0, fl["dur"]], [-math.degrees(v)] * 2, st, lw=0.8)
            ax.set_xlabel("t [s]")
            ax.set_title(f"initial {az0:g} deg")
            ax.grid(True)
        lim = max(2.0, 4 * math.degrees(fl["comb_end"]))
        axs[0].set_ylim(-lim, lim)
        axs[0].set_ylabel("azimuth error [deg]")
        axs[0].legend(fontsize=6)
        fig.suptitle(f"{scen}: azimuth error (seed {seed0}); the first 20 s are the azimuth bootstrap")
        fig.tight_layout()
        fig.savefig(ROOT / "docs" / "figures" / f"static_{scen}_azimuth.png", dpi=80)
        plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--duration-static", type=float, default=1200.0)
    ap.add_argument("--duration-navgrade", type=float, default=300.0)
    ap.add_argument("--az0", type=float, nargs="+", default=[30.0, 90.0, 170.0])
    ap.add_argument("--sigma-r", type=float, nargs="+", default=[1e-3, 1e-2, 1e-1])
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--pkf-params", default="{}", help="JSON dict of PkfConfig overrides (e.g. the Q_m weights)")
    ap.add_argument("--scenarios", nargs="+", default=["static", "static_navgrade"])
    ap.add_argument("--json-out", help="save every run (with its azimuth error history) to this JSON file")
    ap.add_argument("--from-json", nargs="+", help="no runs: merge these --json-out files and write the tables")
    import sweep

    sweep.add_arguments(ap)
    a = ap.parse_args(argv)
    cmd_args = " ".join(argv if argv is not None else sys.argv[1:])
    if a.from_json:
        res, cmds, wall = [], [], 0.0
        for p in a.from_json:
            d = json.loads(Path(p).read_text())
            res += d["runs"]
            cmds.append(d["cmd"])
            wall += d["wall_s"]
        cmd = "` then `".join(cmds) + "` then `nice .venv/bin/python benchmarks/static_sigma_r.py " + cmd_args
        n_cases = len(res)
    else:
        pkf_params = json.loads(a.pkf_params)
        durs = {"static": a.duration_static, "static_navgrade": a.duration_navgrade}
        cases = [(sweep.shared_scenario(scen, seed, durs[scen]), scen, seed, durs[scen], az0, sr, core, pkf_params)
                 for scen in a.scenarios for seed in range(a.seed0, a.seed0 + a.seeds)
                 for az0 in a.az0 for sr in a.sigma_r for core in CORES]
        # a run's cost grows with its duration (the 1200 s MEMS runs first on Dask)
        res = sweep.run_tasks(run_case, cases, a, desc="static sigma_R sweep", cost=[c[3] for c in cases])
        cmd = "nice .venv/bin/python benchmarks/static_sigma_r.py " + cmd_args
        wall = a.sweep_wall_s  # the Dask run's with --speedup
        n_cases = len(cases)
        if a.json_out:
            Path(a.json_out).write_text(json.dumps({"cmd": cmd, "wall_s": wall, "runs": res}))
    text = tables(res, cmd)
    mode = "serial" if a.serial and not a.speedup else a.scheduler or f"LocalCluster, {a.workers} workers"
    text += (f"\nWall time {wall:.0f} s for {n_cases} runs ({mode}, shared 2-core machine); mean run "
             f"{np.mean([r['wall_s'] for r in res]):.1f} s.\n")
    print(text)
    if not a.from_json:
        print(f"sweep: {a.sweep_summary}")
    if not a.no_write:
        write_section(text, ROOT / "docs" / "results.md")
        try:
            plot(res)
        except Exception as exc:  # a plot failure must not lose the table
            print("plot failed:", exc)


if __name__ == "__main__":
    main()
