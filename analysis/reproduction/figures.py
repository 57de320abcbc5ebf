"""Figures of the reproduction study: the equivalents of the paper's Figs. 4-10, the ablations.

Every figure is named ``reproduction_<what>.png`` and written through
:func:`analysis.common.save_figure`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis import common
from wmr import controllers

__all__ = ["tracking_figures", "ablation_figure"]

STEM = "reproduction"


def _three_panels(runs, values, ylabels, title, reference=None, zero_line=False):
    """Three stacked panels of ``values`` (one (n, 3) array per run) against time, one line per
    controller; returns the figure."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True, layout="constrained")
    for i, (ax, lab) in enumerate(zip(axes, ylabels, strict=True)):
        if reference is not None:
            ax.plot(runs[0].t, reference[:, i], "k--", lw=1.4, label="reference")
        for r, v in zip(runs, values, strict=True):
            ax.plot(r.t, v[:, i], color=controllers.colour(r.controller), lw=1.0,
                    label=controllers.label(r.controller))  # fmt: skip
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
        if zero_line:
            ax.axhline(0, color="k", lw=0.5)
    axes[0].legend(fontsize=8, ncol=len(runs) + (reference is not None))
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    return fig


def _paths(runs: dict, seed: int):
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(14, 6.5), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(1, 1.4))
    axes = [fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])]
    for ax, (sc, rs) in zip(axes, runs.items(), strict=True):
        ax.plot(rs[0].ref[:, 0], rs[0].ref[:, 1], "k--", lw=1.5, label="reference")
        for r in rs:
            ax.plot(r.q[:, 0], r.q[:, 1], color=controllers.colour(r.controller), lw=1.1,
                    label=controllers.label(r.controller))  # fmt: skip
        ax.set(title=sc, xlabel="x [m]", ylabel="y [m]")
        ax.grid(alpha=0.3)
    axes[0].set_aspect("equal")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Figure 4 equivalent: tracking of the three scenarios (seed {seed})")
    return fig


def tracking_figures(scenarios: dict, out: str | Path, seed: int = 0) -> list[str]:
    """Figures 4-10 for one seed (paths, pose coordinates, robot-frame errors of eq. 6) of the
    paper's controllers; returns the file names written."""
    from wmr.closedloop.sim import simulate
    from wmr.plots import robot_frame_errors

    names = [n for n in controllers.PAPER_NAMES if n in controllers.REGISTRY]
    runs = {sc: [simulate(s, n, seed) for n in names] for sc, s in scenarios.items()}
    written = [common.save_figure(out, f"{STEM}_paths.png", _paths(runs, seed))]
    for num, (sc, rs) in zip((5, 6, 7), runs.items(), strict=True):
        fig = _three_panels(rs, [r.q for r in rs], ("x [m]", "y [m]", r"$\theta$ [rad]"),
                            f"Figure {num} equivalent: pose coordinates, {sc} (seed {seed})",
                            reference=rs[0].ref[:, :3])  # fmt: skip
        written.append(common.save_figure(out, f"{STEM}_coordinates_{sc}.png", fig))
    for num, (sc, rs) in zip((8, 9, 10), runs.items(), strict=True):
        fig = _three_panels(rs, [robot_frame_errors(r.q, r.ref) for r in rs],
                            ("$x_e$ [m]", "$y_e$ [m]", r"$\theta_e$ [rad]"),
                            f"Figure {num} equivalent: tracking errors (eq. 6), {sc} (seed {seed})",
                            zero_line=True)  # fmt: skip
        written.append(common.save_figure(out, f"{STEM}_errors_{sc}.png", fig))
    return written


def ablation_figure(record: dict, out: str | Path) -> str:
    """Position RMSE (mean ± std) of each controller under each variant, per scenario."""
    import matplotlib.pyplot as plt

    scen = list(record["scenarios"])
    fig, axes = plt.subplots(len(scen), 1, figsize=(12, 3.2 * len(scen)), layout="constrained")
    variants = ["default", *record["variants"]]
    for ax, sc in zip(np.atleast_1d(axes), scen, strict=True):
        runs = record["scenarios"][sc]["runs"]
        names = [n for n in controllers.NAMES if n in runs]
        width = 0.8 / len(names)
        for j, n in enumerate(names):
            xs, ms, ss = [], [], []
            for i, v in enumerate(variants):
                rec = runs[n].get(v)
                if rec and rec["position"]["mean"] is not None:
                    xs.append(i + (j - len(names) / 2 + 0.5) * width)
                    ms.append(rec["position"]["mean"])
                    ss.append(rec["position"]["std"])
            ax.bar(xs, ms, width, yerr=ss, color=controllers.colour(n),
                   label=controllers.label(n))  # fmt: skip
        ax.set_xticks(range(len(variants)), variants, rotation=20, fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("position RMSE [m]")
        ax.set_title(sc)
        ax.grid(alpha=0.3, axis="y")
    np.atleast_1d(axes)[0].legend(fontsize=8, ncol=5)
    return common.save_figure(out, f"{STEM}_ablations.png", fig)
