"""Plots of alignment runs (matplotlib, Agg): Euler errors with 3-sigma like the PI-LIEKF paper's Fig. 3."""

from __future__ import annotations

from .metrics import RunResult


def plot_euler_errors(results: list[RunResult], path, title: str = "") -> None:
    """Roll/pitch/yaw error [deg] vs time for one or more runs, with the +-3-sigma envelope of the first run
    (ENU axes E, N, U as roll/pitch/yaw proxies; exact for yaw near level)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for j, r in enumerate(results):
        for i in range(3):
            ax[i].plot(r.t_s, r.rpy_err_deg[:, i], label=r.core)
            if j == 0:
                ax[i].plot(r.t_s, r.sigma3_deg[:, i], "k--", lw=0.7, label="3 sigma" if i == 0 else None)
                ax[i].plot(r.t_s, -r.sigma3_deg[:, i], "k--", lw=0.7)
    for i, nm in enumerate(("roll", "pitch", "yaw")):
        ax[i].set_ylabel(f"{nm} error [deg]")
        ax[i].grid(True)
        lim = 5.0 if i == 2 else 3.0
        ax[i].set_ylim(-lim, lim)
    ax[0].legend(fontsize=8)
    ax[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
