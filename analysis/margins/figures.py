"""Figures of the margins study (``analysis.margins``): drawn from the computed arrays.

Each function returns a matplotlib figure; the study saves it as ``figures/margins_*.png``.
"""

from __future__ import annotations

import numpy as np

from wmr import controllers
from wmr.controllers.pid import GAIN_NAMES
from wmr.linear.loops import PID_GAINS, jury_v_loop_stable, routh_w_loop_stable

__all__ = ["stability_region_figure", "along_runs_figure", "printed_rotation_figure"]


def stability_region_figure(regions: list):
    """Figure of :func:`wmr.linear.loops.stability_region` results (one panel each)."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap, LogNorm

    fig, axes = plt.subplots(1, len(regions), figsize=(6.2 * len(regions), 5), layout="constrained")
    for ax, reg in zip(np.atleast_1d(axes), regions, strict=True):
        kp, ki, rho = reg["kp"], reg["ki"], reg["rho"]
        op = reg["operating_point"]
        stable = rho < 1.0
        with np.errstate(divide="ignore"):
            tau = np.where(stable, -op.dt / np.log(np.where(stable, rho, 0.5)), np.nan)
        im = ax.pcolormesh(kp, ki, tau, shading="nearest", cmap="viridis",
                           norm=LogNorm(op.dt, 1e3))  # fmt: skip
        ax.pcolormesh(kp, ki, np.where(stable, np.nan, 1.0), shading="nearest",
                      cmap=ListedColormap(["lightcoral"]))  # fmt: skip
        ax.contour(kp, ki, rho, levels=[1.0], colors="k", linewidths=1.5)
        P, I = np.meshgrid(kp, ki)
        if reg["pair"] == "v":
            closed_form, (ip, ii) = jury_v_loop_stable(P, I, op.dt), (0, 1)
            title = "v loop; orange dashed: closed-form Jury boundary"
        else:
            closed_form, (ip, ii) = routh_w_loop_stable(P, I, op.v_r), (3, 4)
            title = "w loop; orange dashed: continuous-time Routh boundary"
        ax.contour(kp, ki, closed_form.astype(float), levels=[0.5], colors="orange",
                   linestyles="--", linewidths=1.5)  # fmt: skip
        ax.plot(PID_GAINS[ip], PID_GAINS[ii], "w*", mec="k", ms=14, label="default gains")
        ax.set(xlabel=GAIN_NAMES[ip], ylabel=GAIN_NAMES[ii])
        ax.set(xscale="log", yscale="log",
               title=f"{title}\nred: unstable (max|z| > 1); v_r={op.v_r:.3f}, w_r={op.w_r:.3f}")
        ax.legend(loc="lower left", fontsize=8)
        fig.colorbar(im, ax=ax, label="slowest closed-loop time constant -dt/ln max|z| [s]")
    fig.suptitle("Stability region of the fixed PID (eq. 7), other gains at their defaults "
                 "(colour: slowest mode of the whole loop)")  # fmt: skip
    return fig


def along_runs_figure(along: dict):
    """Figure of ``{scenario: {controller: margins_along_run(...)}}``."""
    import matplotlib.pyplot as plt

    scen = list(along)
    fig, axes = plt.subplots(4, len(scen), figsize=(5.2 * len(scen), 10), sharex=True,
                             layout="constrained", squeeze=False)  # fmt: skip
    rows = (("gm_db", "upper GM [dB]"), ("pm_deg", "PM [deg]"), ("dm", "disk margin alpha"))
    for j, sc in enumerate(scen):
        for name, rec in along[sc].items():
            color, label = controllers.colour(name), controllers.label(name)
            for i, (key, lab) in enumerate(rows):
                for ch, ls in (("v", "-"), ("w", "--")):
                    y = np.asarray(rec[f"{ch}_{key}"], dtype=float)
                    axes[i, j].plot(rec["t"], y, ls, color=color, lw=1.1, label=f"{label} {ch}")
                axes[i, j].set_ylabel(lab)
            axes[3, j].plot(rec["t"], rec["rho"], color=color, lw=1.1, label=label)
        axes[3, j].set_ylabel("max|z| closed loop")
        axes[3, j].set_xlabel("t [s]")
        axes[0, j].set_title(sc)
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=2)
    fig.suptitle("Frozen-time margins along runs (seed 0) as the gains adapt; v solid, w dashed")
    return fig


def printed_rotation_figure(sweep: dict):
    """Figure of :func:`analysis.margins.printed_rotation_sweep` (plus the corrected radii)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6), layout="constrained")
    h = sweep["headings_deg"]
    ax.plot(h, sweep["pid_rho"], label="PID (eq. 7), printed T_e")
    ax.plot(h, sweep["bsc_rho"], label="BSC, printed T_e")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(sweep["pid_rho_corrected"], color="C0", ls=":", label="PID, corrected (any heading)")
    ax.axhline(sweep["bsc_rho_corrected"], color="C1", ls=":", label="BSC, corrected (any heading)")
    ax.set(xlabel="reference heading [deg] (straight line)", ylabel="max|z| of the closed loop",
           ylim=(0.95, 1.05), xticks=np.arange(-180, 181, 45))  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig
