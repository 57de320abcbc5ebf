"""The calibration study's figures, drawn from its record only (``analysis.calibration``)."""

from __future__ import annotations

import numpy as np

from analysis import common
from wmr import controllers

__all__ = ["power_curve", "residual_profile", "projections", "sensitivity_bars", "pareto_fronts",
           "all_figures"]

STEM = "calibration"


def power_curve(record: dict):
    """The rule on planted truths: acceptance at the truth (coverage) and rejection at unit-cube
    distances from it (power), with exact intervals; right: max implausibility at the truth
    against the threshold."""
    import matplotlib.pyplot as plt

    pl = record["planted"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.0), layout="constrained")
    d = [0.0] + [float(k) for k in pl["power"]]
    ps = [pl["coverage"]] + list(pl["power"].values())
    y = [1 - pl["coverage"]["p"]] + [p["p"] for p in ps[1:]]
    lo = [1 - pl["coverage"]["ci_high"]] + [p["ci_low"] for p in ps[1:]]
    hi = [1 - pl["coverage"]["ci_low"]] + [p["ci_high"] for p in ps[1:]]
    ax = axes[0]
    ax.errorbar(d, y, yerr=[np.array(y) - lo, np.array(hi) - y], fmt="o-", capsize=4)
    ax.axhline(0.05, color="tab:green", ls=":", label="nominal 5 % false rejection")
    ax.axhline(0.10, color="tab:red", ls=":", label="10 % (coverage >= 90 %)")
    ax.axhline(0.90, color="0.4", ls="--", label="90 % power")
    ax.set(xlabel="unit-cube distance from the planted truth", ylabel="share ruled out",
           ylim=(-0.02, 1.02), title=f"{pl['n_truths']} planted truths, K = "
           f"{len(pl['rule_seeds'])} seeds (Clopper-Pearson 95 %)")  # fmt: skip
    ax.legend(fontsize=7)
    ax = axes[1]
    it = np.array(pl["max_implausibility_truth"])
    ia = np.array(pl["max_implausibility_away"])
    both = np.concatenate([it, ia.ravel()])
    lo = max(float(both[both > 0].min()) if np.any(both > 0) else 1e-3, 1e-3)
    bins = np.geomspace(lo, max(float(both.max()), 10 * lo), 40)  # log axis: log-spaced bins
    ax.hist([np.maximum(it, lo), *np.maximum(ia, lo).T], bins=bins, histtype="step",
            label=["truth"] + [f"d = {k}" for k in pl["power"]])  # fmt: skip
    ax.axvline(pl["threshold"], color="k", ls="--", label=f"threshold {pl['threshold']:.2f}")
    ax.set(xlabel="max implausibility over the 36 numbers (a diverged run: 1e6)",
           ylabel="planted truths", xscale="log", title="max implausibility")
    ax.legend(fontsize=7)
    return fig


def residual_profile(record: dict):
    """Log ratio ours/paper of the 36 numbers at the closest fit, with the rule's band (the
    threshold times each number's predictive sd) and the range its seed mean spans over the
    design (grey)."""
    import matplotlib.pyplot as plt

    res = record["best_fit"]["residuals"]
    cov = record["points"]["numbers"]
    names = list(res)
    x = np.arange(len(names))
    lr = np.array([res[n]["log_ratio"] for n in names])
    p = np.array([res[n]["paper"] for n in names])
    lo = np.log(np.array([cov[n]["min"] for n in names]) / p)
    hi = np.log(np.array([cov[n]["max"] for n in names]) / p)
    fig, ax = plt.subplots(figsize=(12, 4.2), layout="constrained")
    ax.bar(x, hi - lo, bottom=lo, color="0.85", width=0.8, label="range over the design")
    colours = ["tab:green" if res[n]["within"] else "tab:red" for n in names]
    ax.scatter(x, lr, c=colours, zorder=3, s=22, label="closest fit (green: within the rule)")
    ax.axhline(0.0, color="k", lw=0.8)
    for b in (12, 24):
        ax.axvline(b - 0.5, color="0.5", lw=0.8, ls=":")
    ax.set_xticks(x, [n.split("/", 1)[1].replace("iapid-nn-dekf", "IAPID")
                      .replace("backstepping", "BSC").replace("adaptive-nn", "DA-NN")
                      .replace("adaptive-pid", "APID") for n in names],
                  rotation=90, fontsize=7)  # fmt: skip
    ax.set_ylabel("log(ours / paper)")
    ax.set_title(f"closest fit: rms log ratio {record['best_fit']['rms_log_ratio']:.3f}; "
                 "Tables 1 | 2 | 3 (lemniscate | sinusoid | perturbed)", fontsize=10)
    ax.legend(fontsize=8, loc="lower left")
    return fig


def _top_settings(record: dict, k: int = 6) -> list[str]:
    ix = record["sensitivity"]["pawn"]["indices"].get("rms_log_ratio")
    varied = record["points"]["varied"]
    if ix:
        return sorted(varied, key=lambda n: -ix["indices"][n]["index"])[:k]
    imp = record["screening"]["importance"]
    return sorted(varied, key=lambda n: -imp[n])[:k]


def projections(record: dict, points: dict):
    """The design's rms log ratio against each of the most influential settings, coloured by
    the diverged runs; the CMA-ES restarts' ends starred.  ``points``: the points file as
    columns (``calibration.read_points``)."""
    import matplotlib.pyplot as plt

    pts = record["points"]
    top = _top_settings(record)
    rms = np.array(points["rms_log_ratio"])
    nd = np.array(points["n_diverged"])
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained", squeeze=False)
    sc = None
    for ax, name in zip(axes.flat, top, strict=False):
        vals = points[name]
        numeric = all(isinstance(v, float) for v in vals)
        ends = [r["settings"][name] for r in record["best_fit"]["restarts"]]
        if numeric:
            xv, fx = np.array(vals, dtype=float), np.array(ends, dtype=float)
        else:
            levels = sorted({str(v) for v in vals})
            xv = np.array([levels.index(str(v)) for v in vals], dtype=float)
            xv += np.random.default_rng(0).uniform(-0.2, 0.2, len(xv))
            shown = [str(e).lower() if isinstance(e, bool) else str(e) for e in ends]
            fx = np.array([levels.index(e) if e in levels else np.nan for e in shown])
            ax.set_xticks(range(len(levels)), levels)
        sc = ax.scatter(xv, rms, c=nd, s=4, cmap="viridis", alpha=0.6)
        ax.scatter(fx, [r["rms_log_ratio"] for r in record["best_fit"]["restarts"]],
                   marker="*", s=120, color="tab:red", edgecolors="k", zorder=4)  # fmt: skip
        prior = record["prior"][name]
        if numeric and prior.get("scale") == "log-uniform":
            ax.set_xscale("log")
        ax.set(xlabel=f"{name} [{prior['unit']}]", ylabel="rms log ratio")
    for ax in list(axes.flat)[len(top):]:
        ax.set_axis_off()
    if sc is not None:
        fig.colorbar(sc, ax=axes, label="diverged runs at the point", shrink=0.8)
    fig.suptitle(f"design of {pts['n']} points: discrepancy against the most influential "
                 "settings (PAWN); stars: the CMA-ES restarts' ends", fontsize=10)
    return fig


def sensitivity_bars(record: dict):
    """PAWN indices (95 % bootstrap intervals) of each output, the dummy's band shaded."""
    import matplotlib.pyplot as plt

    sen = record["sensitivity"]["pawn"]
    outs = [o for o in sen["outputs"] if sen["indices"].get(o)]
    factors = sen["factors"]
    n = len(outs)
    cols = 3
    rows = max(1, (n + cols - 1) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(13, 0.22 * len(factors) * rows + 1.5),
                             layout="constrained", squeeze=False)  # fmt: skip
    y = np.arange(len(factors))
    for ax, o in zip(axes.flat, outs, strict=False):
        ix = sen["indices"][o]["indices"]
        v = np.array([ix[f]["index"] for f in factors])
        lo = np.array([ix[f]["low"] for f in factors])
        hi = np.array([ix[f]["high"] for f in factors])
        ax.barh(y, v, height=0.6, color="tab:blue")
        ax.errorbar(v, y, xerr=[np.clip(v - lo, 0, None), np.clip(hi - v, 0, None)],
                    fmt="none", ecolor="k", lw=0.6)  # fmt: skip
        ax.axvspan(0, sen["indices"][o]["dummy_high"], color="0.85", zorder=0)
        ax.set_yticks(y, factors, fontsize=6)
        ax.invert_yaxis()
        ax.set_title(o.replace("iapid-nn-dekf", "IAPID").replace("backstepping", "BSC")
                     .replace("adaptive-nn", "DA-NN").replace("adaptive-pid", "APID"),
                     fontsize=9)  # fmt: skip
    for ax in list(axes.flat)[n:]:
        ax.set_axis_off()
    fig.suptitle(f"PAWN indices (median KS, N = {sen['n']} design points, 95 % bootstrap); "
                 "grey: up to the dummy setting's upper bound", fontsize=10)
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
        ("power", power_curve(record)), ("residuals", residual_profile(record)),
        ("projections", projections(record, points)),
        ("sensitivity", sensitivity_bars(record)), ("pareto", pareto_fronts(record)))]  # fmt: skip
