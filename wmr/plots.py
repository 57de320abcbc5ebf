"""Figures: tracking (path, pose coordinates) and tracking errors, as in the paper's Figs. 4-10."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np

from wmr import controllers
from wmr.closedloop.metrics import wrap

__all__ = ["robot_frame_errors", "tracking_figure", "MAX_POINTS"]

#: Most points a figure draws per curve: longer runs are decimated (every k-th sample).
MAX_POINTS = 20_000


def robot_frame_errors(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Tracking errors ``(x_e, y_e, theta_e)`` of eq. (6), corrected rotation, shape (n, 3)."""
    c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
    dx, dy = ref[:, 0] - q[:, 0], ref[:, 1] - q[:, 1]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy, wrap(ref[:, 2] - q[:, 2])))


def tracking_figure(runs: Sequence, title: str = ""):
    """Path (reference vs robots) and the robot-frame errors vs time, for runs of one scenario."""
    fig = plt.figure(figsize=(11, 6.5), layout="constrained")
    grid = fig.add_gridspec(3, 2, width_ratios=(1.1, 1))
    ax_path = fig.add_subplot(grid[:, 0])
    ax_err = [fig.add_subplot(grid[i, 1]) for i in range(3)]
    every = max(1, -(-len(runs[0].t) // MAX_POINTS))
    ref = runs[0].ref[::every]
    ax_path.plot(ref[:, 0], ref[:, 1], "k--", lw=1.5, label="reference")
    for r in runs:
        color = controllers.colour(r.controller)
        label = controllers.label(r.controller)
        if r.diverged:
            label += f" (diverged at {r.diverged_at:.2f} s)"
        q = r.q[::every]
        ax_path.plot(q[:, 0], q[:, 1], color=color, lw=1.2, label=label)
        e = robot_frame_errors(q, r.ref[::every])
        for i in range(3):
            ax_err[i].plot(r.t[::every], e[:, i], color=color, lw=1.0)
    ax_path.plot(*runs[0].q[0, :2], "ko", ms=5, label="start")
    ax_path.set(xlabel="x [m]", ylabel="y [m]", title=title or runs[0].scenario)
    span = max(np.ptp(r.q[:, :2]) if np.all(np.isfinite(r.q)) else np.inf for r in runs)
    if span < 1e6:  # an equal aspect is singular for a run that diverged astronomically far
        ax_path.set_aspect("equal")
    ax_path.legend(loc="best", fontsize=8)
    for ax, name in zip(ax_err, ("$x_e$ [m]", "$y_e$ [m]", r"$\theta_e$ [rad]"), strict=True):
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.5)
    ax_err[-1].set_xlabel("t [s]")
    ax_err[0].set_title("tracking errors (robot frame, eq. 6)")
    return fig
