"""The calibration study's figures, drawn from its record only (``analysis.calibration``)."""

from __future__ import annotations

import numpy as np

from analysis import common
from wmr import controllers

__all__ = ["residual_profile", "projections", "sensitivity_bars", "pareto_fronts", "all_figures"]

STEM = "calibration"


def residual_profile(record: dict):
    """Log ratio ours/paper of the 36 numbers at the best fit, with each number's tolerance
    band and the range its mean spans over the design (grey)."""
    import matplotlib.pyplot as plt

    res = record["best_fit"]["residuals"]
    cov = record["feasible"]["numbers"]
    names = list(res)
    x = np.arange(len(names))
    lr = np.array([res[n]["log_ratio"] for n in names])
    p = np.array([res[n]["paper"] for n in names])
    tol = np.array([res[n]["tolerance"] for n in names])
    lo = np.log(np.array([cov[n]["min"] for n in names]) / p)
    hi = np.log(np.array([cov[n]["max"] for n in names]) / p)
    fig, ax = plt.subplots(figsize=(12, 4.2), layout="constrained")
    ax.bar(x, hi - lo, bottom=lo, color="0.85", width=0.8, label="range over the design")
    ax.fill_between(np.repeat(x, 2) + np.tile([-0.4, 0.4], len(x)),
                    np.repeat(np.log(np.maximum(p - tol, 1e-9) / p), 2),
                    np.repeat(np.log((p + tol) / p), 2), color="tab:green", alpha=0.35,
                    step=None, label="tolerance")  # fmt: skip
    colours = [controllers.colour(n.split("/")[1]) for n in names]
    ax.scatter(x, lr, c=colours, zorder=3, s=22, label="best fit")
    ax.axhline(0.0, color="k", lw=0.8)
    for b in (12, 24):
        ax.axvline(b - 0.5, color="0.5", lw=0.8, ls=":")
    ax.set_xticks(x, [n.split("/", 1)[1].replace("iapid-nn-dekf", "IAPID")
                      .replace("backstepping", "BSC").replace("adaptive-nn", "DA-NN")
                      .replace("adaptive-pid", "APID") for n in names],
                  rotation=90, fontsize=7)  # fmt: skip
    ax.set_ylabel("log(ours / paper)")
    ax.set_title(f"best fit: rms log ratio {record['best_fit']['rms_log_ratio']:.3f}; "
                 "Tables 1 | 2 | 3 (lemniscate | sinusoid | perturbed)", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    return fig


def _top_settings(record: dict, k: int = 6) -> list[str]:
    sobol = record["sensitivity"]["sobol"]
    ix = sobol["N"]["indices"].get("rms_log_ratio")
    varied = record["points"]["varied"]
    if ix:
        return sorted(varied, key=lambda n: -ix[n]["total"])[:k]
    imp = record["screening"]["importance"]
    return sorted(varied, key=lambda n: -imp[n])[:k]


def projections(record: dict, points: dict):
    """The design's rms log ratio against each of the most influential settings, coloured by
    how many of the 36 numbers are within tolerance; feasible points ringed, the fit starred.
    ``points``: the points file as columns (``calibration.read_points``)."""
    import matplotlib.pyplot as plt

    pts = record["points"]
    top = _top_settings(record)
    rms = np.array(points["rms_log_ratio"])
    nw = np.array(points["n_within"])
    fit = record["best_fit"]["settings"]
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained", squeeze=False)
    sc = None
    for ax, name in zip(axes.flat, top, strict=False):
        vals = points[name]
        numeric = all(isinstance(v, float) for v in vals)
        if numeric:
            xv, fx = np.array(vals, dtype=float), float(fit[name])
        else:
            levels = sorted({str(v) for v in vals})
            xv = np.array([levels.index(str(v)) for v in vals], dtype=float)
            xv += np.random.default_rng(0).uniform(-0.2, 0.2, len(xv))
            shown = str(fit[name]).lower() if isinstance(fit[name], bool) else str(fit[name])
            fx = levels.index(shown) if shown in levels else np.nan
            ax.set_xticks(range(len(levels)), levels)
        sc = ax.scatter(xv, rms, c=nw, s=4, cmap="viridis", vmin=0, vmax=36, alpha=0.6)
        feas = nw == 36
        if feas.any():
            ax.scatter(xv[feas], rms[feas], s=40, facecolors="none", edgecolors="r")
        ax.scatter([fx], [record["best_fit"]["rms_log_ratio_at_design_seeds"]], marker="*",
                   s=160, color="tab:red", edgecolors="k", zorder=4)  # fmt: skip
        prior = record["prior"][name]
        if numeric and prior.get("scale") == "log-uniform":
            ax.set_xscale("log")
        ax.set(xlabel=f"{name} [{prior['unit']}]", ylabel="rms log ratio")
    for ax in list(axes.flat)[len(top):]:
        ax.set_axis_off()
    if sc is not None:
        fig.colorbar(sc, ax=axes, label="numbers within tolerance (of 36)", shrink=0.8)
    fig.suptitle(f"design of {pts['n']} points: discrepancy against the most influential "
                 f"settings; feasible points: {record['feasible']['count']} (ringed); star: "
                 "the best fit", fontsize=10)  # fmt: skip
    return fig


def sensitivity_bars(record: dict):
    """Total and first-order Sobol indices (95 % bootstrap intervals) of each output."""
    import matplotlib.pyplot as plt

    sob = record["sensitivity"]["sobol"]
    outs = [o for o in sob["outputs"] if sob["N"]["indices"].get(o)]
    factors = sob["factors"]
    n = len(outs)
    cols = 3
    rows = max(1, (n + cols - 1) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(13, 0.22 * len(factors) * rows + 1.5),
                             layout="constrained", squeeze=False)  # fmt: skip
    y = np.arange(len(factors))
    for ax, o in zip(axes.flat, outs, strict=False):
        ix = sob["N"]["indices"][o]
        for off, kind, colour in ((-0.2, "total", "tab:blue"), (0.2, "first", "tab:orange")):
            v = np.array([ix[f][kind] for f in factors])
            lo = np.array([ix[f][f"{kind}_low"] for f in factors])
            hi = np.array([ix[f][f"{kind}_high"] for f in factors])
            ax.barh(y + off, v, height=0.4, color=colour, label=kind)
            ax.errorbar(np.clip(v, lo, hi), y + off, xerr=[np.clip(v - lo, 0, None),
                        np.clip(hi - v, 0, None)], fmt="none", ecolor="k", lw=0.6)  # fmt: skip
        ax.set_yticks(y, factors, fontsize=6)
        ax.invert_yaxis()
        ax.set_title(o.replace("iapid-nn-dekf", "IAPID").replace("backstepping", "BSC")
                     .replace("adaptive-nn", "DA-NN").replace("adaptive-pid", "APID"),
                     fontsize=9)  # fmt: skip
        ax.axvline(0.0, color="k", lw=0.6)
    for ax in list(axes.flat)[n:]:
        ax.set_axis_off()
    if n:
        axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"Sobol indices (N = {sob['N']['n']}, 95 % bootstrap intervals); margins: log "
                 "RMSE of X minus IAPID's (> 0: IAPID better)", fontsize=10)
    return fig


def pareto_fronts(record: dict):
    """Fair tuning: each controller's evaluations' Pareto front (position RMSE vs control
    effort) on the training trajectories, and the same gains held out."""
    import matplotlib.pyplot as plt

    fair = record["fair_tuning"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
    for c, t in fair["controllers"].items():
        col, lab = controllers.colour(c), controllers.label(c)
        f = sorted(t["front"], key=lambda p: p["effort"])
        axes[0].plot([p["effort"] for p in f], [p["position"] for p in f], "o-", ms=3,
                     color=col, label=lab)  # fmt: skip
        h = sorted(t["front_held_out"], key=lambda p: p["held_out_effort"] or 0)
        axes[1].plot([p["held_out_effort"] for p in h], [p["held_out_position"] for p in h],
                     "o--", ms=3, color=col, alpha=0.6)  # fmt: skip
        ho = t["held_out"]
        axes[1].plot([ho["effort"]], [ho["position"]], "*", ms=14, color=col, mec="k",
                     label=f"{lab} tuned")  # fmt: skip
        d = t["default_held_out"]
        axes[1].plot([d["effort"]], [d["position"]], "s", ms=6, color=col, mfc="none")
    axes[0].set(xlabel="control effort (RMS of (v, w))", ylabel="mean position RMSE [m]",
                title="training trajectories: Pareto fronts", yscale="log")  # fmt: skip
    axes[1].set(xlabel="control effort (RMS of (v, w))", ylabel="mean position RMSE [m]",
                title="held out (the paper's scenarios): star tuned, square default",
                yscale="log")  # fmt: skip
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=7)
    return fig


def all_figures(record: dict, points: dict, out) -> list[str]:
    """Draw and save every figure (``points``: the points file's columns); their file names."""
    return [common.save_figure(out, f"{STEM}_{name}.png", fig) for name, fig in (
        ("residuals", residual_profile(record)), ("projections", projections(record, points)),
        ("sensitivity", sensitivity_bars(record)), ("pareto", pareto_fronts(record)))]  # fmt: skip
