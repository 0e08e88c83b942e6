"""One figure per scenario (trajectory + attitude) into docs/figures/scenario_<name>.png, and the parameter
table of docs/scenarios.md (--table).

    nice .venv/bin/python benchmarks/plot_scenarios.py            # figures (default durations, seed 0, noisy)
    .venv/bin/python benchmarks/plot_scenarios.py --table          # markdown parameter table on stdout
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pymap3d  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from insalign_ros.sim.scenarios import SCENARIOS, make_scenario  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "docs" / "figures"


def table() -> str:
    lines = []
    for name, p in SCENARIOS.items():
        s = p.imu
        lines += [f"### `{name}`: {p.description}", "",
                  f"IMU `{s.name}`: gyro bias {s.gyro_bias_deg_h} deg/h, ARW {s.arw_deg_sqrt_h} deg/sqrt(h), "
                  f"acc bias {s.acc_bias_mg} mg, VRW {s.vrw_m_s_sqrt_h:.4g} m/s/sqrt(h), {s.rate_hz:g} Hz", "",
                  "| parameter | default | unit | source |", "|---|---|---|---|"]
        lines += [f"| {k} | {v[0]:g} | {v[1]} | {v[2]} |" for k, v in p.params.items()]
        lines.append("")
    return "\n".join(lines)


def plot(name: str, seed: int = 0):
    d = make_scenario(name, seed=seed)
    P = d.params
    e, n, u = pymap3d.geodetic2enu(d.lat_rad, d.lon_rad, d.h_m, np.radians(P["ref_lat_deg"]),
                                   np.radians(P["ref_lon_deg"]), P["ref_h_m"], deg=False)
    rpy = np.degrees(Rotation.from_matrix(d.C_b_n).as_euler("ZYX")[:, ::-1])
    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    ax[0].plot(e, n)
    ax[0].plot(e[0], n[0], "go", label="start")
    ax[0].set(xlabel="East [m]", ylabel="North [m]", title=f"{name}: horizontal track")
    ax[0].axis("equal")
    ax[0].legend()
    ax[1].plot(d.t_s, u, label="up")
    ax[1].plot(d.t_s, np.linalg.norm(d.v_n, axis=1), label="|v| [m/s]")
    ax[1].set(xlabel="t [s]", ylabel="[m], [m/s]", title="height and speed")
    ax[1].legend()
    for i, lab in enumerate(("roll", "pitch", "yaw (from East, CCW)")):
        ax[2].plot(d.t_s, rpy[:, i], label=lab)
    ax[2].set(xlabel="t [s]", ylabel="[deg]", title="attitude (body FLU -> ENU)")
    ax[2].legend()
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT / f"scenario_{name}.png", dpi=80)
    plt.close(fig)
    return OUT / f"scenario_{name}.png"


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", action="store_true")
    ap.add_argument("names", nargs="*", default=list(SCENARIOS))
    a = ap.parse_args()
    if a.table:
        print(table())
    else:
        for nm in a.names:
            print(plot(nm))
