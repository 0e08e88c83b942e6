"""Plots of alignment runs (matplotlib, Agg): Euler errors with 3-sigma like the PI-LIEKF paper's Fig. 3 (with truth);
the estimate with its 3-sigma band and the aligned flag (without truth)."""

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
    fixed_layout(fig, bool(title))
    fig.savefig(path, dpi=90)
    plt.close(fig)


#: the 3-sigma band drawn at most this wide [deg] (roll, pitch, yaw): before alignment the yaw is unknown (180)
BAND_CLIP_DEG = (30.0, 30.0, 180.0)


def plot_estimate(t_s, rpy_deg, sigma3_deg, aligned, path, title: str = "") -> None:
    """The estimate without truth: roll, pitch, yaw [deg] (yaw from East, CCW; unwrapped for the plot, in
    (-180, 180] at the end) vs time with their +-3-sigma band (clipped to BAND_CLIP_DEG) and the aligned flag
    (shaded where up, and in its own panel)."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(t_s, float)
    rpy = np.array(rpy_deg, float)
    yaw = np.degrees(np.unwrap(np.radians(rpy[:, 2])))  # continuous, shifted by whole turns to end as estimated
    rpy[:, 2] = yaw + 360.0 * np.round((rpy[-1, 2] - yaw[-1]) / 360.0) if len(yaw) else yaw
    s3 = np.minimum(np.asarray(sigma3_deg, float), BAND_CLIP_DEG)
    up = np.asarray(aligned, bool)
    fig, ax = plt.subplots(4, 1, figsize=(8, 9), sharex=True, gridspec_kw={"height_ratios": [3, 3, 3, 1]})
    for i, nm in enumerate(("roll", "pitch", "yaw")):
        ax[i].fill_between(t, rpy[:, i] - s3[:, i], rpy[:, i] + s3[:, i], color="C0", alpha=0.25, lw=0,
                           label="+-3 sigma" if i == 0 else None)
        ax[i].plot(t, rpy[:, i], "C0", lw=1.0, label="estimate" if i == 0 else None)
        lo, hi = _limits(rpy[:, i], s3[:, i], up)
        ax[i].set_ylim(lo, hi)
        ax[i].set_ylabel(f"{nm} [deg]")
        ax[i].grid(True)
    for a in ax[:3]:
        a.fill_between(t, 0, 1, where=up, transform=a.get_xaxis_transform(), color="C2", alpha=0.12, lw=0,
                       step="post", label="aligned" if a is ax[0] else None)
    ax[3].step(t, up.astype(int), "C2", where="post")
    ax[3].set_yticks([0, 1], ["no", "yes"])
    ax[3].set_ylabel("aligned")
    ax[3].set_xlabel("time [s]")
    ax[0].legend(fontsize=8, loc="upper right")
    if title:
        fig.suptitle(title)
    fixed_layout(fig, bool(title))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _limits(x, s3, up):
    """y limits showing the estimate and its band once aligned (or the whole run if it never aligned)."""
    import numpy as np

    sel = up if up.any() else np.ones_like(up)
    lo, hi = float(np.min(x[sel] - s3[sel])), float(np.max(x[sel] + s3[sel]))
    lo, hi = min(lo, float(np.min(x))), max(hi, float(np.max(x)))
    pad = max(0.5, 0.05 * (hi - lo))
    return lo - pad, hi + pad


def fixed_layout(fig, title: bool) -> None:
    """Fixed margins for the stacked panels (room for 7-character tick labels and the axis labels), instead of
    ``tight_layout``, which draws every tick once more to measure them: half the time of a plot."""
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.06, top=0.94 if title else 0.97, hspace=0.12)
