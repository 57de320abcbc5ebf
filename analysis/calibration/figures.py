"""The calibration study's figures, drawn from its record only (``analysis.calibration``)."""

from __future__ import annotations

import numpy as np

from analysis import common
from wmr import controllers

__all__ = ["power_curve", "residual_profile", "projections", "sensitivity_bars",
           "fair_comparison", "waves_figure", "all_figures"]

STEM = "calibration"


def power_curve(record: dict):
    """The rule on planted truths: acceptance at the truth (coverage) and rejection at unit-cube
    distances from it (power), with exact intervals, for the truths the rule was revised
    against and the fresh ones; right: max implausibility at the (first) truths against the
    threshold."""
    import matplotlib.pyplot as plt

    pl = record["planted"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.0), layout="constrained")
    ax = axes[0]
    sets = [(pl, "the truths the rule was revised against", 0.0)]
    if record.get("planted_fresh"):
        sets.append((record["planted_fresh"], "fresh truths (out of sample)", 0.006))
    for x, label, shift in sets:
        # at each move's median actual distance (reflection at the cube's edges shortens it)
        d = np.array([0.0] + [p["actual_distance_median"] for p in x["power"].values()]) + shift
        y = np.array([1 - x["coverage"]["p"]] + [p["p"] for p in x["power"].values()])
        lo = [1 - x["coverage"]["ci_high"]] + [p["ci_low"] for p in x["power"].values()]
        hi = [1 - x["coverage"]["ci_low"]] + [p["ci_high"] for p in x["power"].values()]
        ax.errorbar(d, y, yerr=[y - lo, hi - y], fmt="o-", capsize=4, ms=4,
                    label=f"{label}, {x['n_truths']}")  # fmt: skip
    ax.axhline(0.05, color="tab:green", ls=":", label="nominal 5 % false rejection")
    ax.axhline(0.10, color="tab:red", ls=":", label="10 % (coverage >= 90 %)")
    ax.axhline(0.90, color="0.4", ls="--", label="90 % power")
    ax.set(xlabel="unit-cube distance from the planted truth (median actual)",
           ylabel="share ruled out",
           ylim=(-0.02, 1.02), title=f"planted truths, K = {len(pl['rule_seeds'])} seeds "
           "(Clopper-Pearson 95 %)")  # fmt: skip
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
           ylabel="planted truths", xscale="log",
           title=f"max implausibility: the {pl['n_truths']} truths the rule was revised against")
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
    """The design's rms log ratio against each of the most influential settings (a point with
    a diverged run has none: it is drawn as a cross on the top edge); the CMA-ES restarts'
    ends starred.  ``points``: the points file as columns (``calibration.read_points``)."""
    import matplotlib.pyplot as plt

    pts = record["points"]
    top = _top_settings(record)
    rms = np.array(points["rms_log_ratio"], dtype=float)
    div = np.array(points["n_diverged"]) > 0
    top_edge = np.nanmax(rms) * 1.05
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained", squeeze=False)
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
        ax.scatter(xv[~div], rms[~div], s=4, color="tab:blue", alpha=0.6,
                   label="every run tracked")  # fmt: skip
        ax.scatter(xv[div], np.full(div.sum(), top_edge), marker="x", s=14, color="tab:orange",
                   label=f"a run diverged ({div.sum()} points)")  # fmt: skip
        ax.scatter(fx, [r["rms_log_ratio"] for r in record["best_fit"]["restarts"]],
                   marker="*", s=120, color="tab:red", edgecolors="k", zorder=4)  # fmt: skip
        prior = record["prior"][name]
        if numeric and prior.get("scale") == "log-uniform":
            ax.set_xscale("log")
        ax.set(xlabel=f"{name} [{prior['unit']}]", ylabel="rms log ratio")
    for ax in list(axes.flat)[len(top):]:
        ax.set_axis_off()
    if top:
        axes.flat[0].legend(fontsize=7, loc="lower right")
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
                 "grey: up to the inert floor (the null's 95th percentile)", fontsize=10)
    return fig


def fair_comparison(record: dict):
    """Fair tuning, held out on the kinematic plants: each arm's RMSE ratio to the candidate
    best with its 95 % interval at the four pairings of the two arms' restarts (left: filled
    best / best, open the others), and its share of runs that fail to track, with the exact
    interval, at its best restart, its runner-up and its defaults (right)."""
    import matplotlib.pyplot as plt

    f = record["fair_tuning"]
    names = [n for n in f["ranking"] if n != f["best"]]
    vs = [f["against_best"][n] for n in names]
    names.append(f["paper_arm"]["arm"])
    vs.append(f["paper_arm"]["against_best"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 0.5 * len(names) + 2.2), layout="constrained")
    for i, (n, v) in enumerate(zip(names, vs, strict=True)):
        col = controllers.colour(n.split("@")[0])
        for j, p in enumerate([v["tuned"], *v["by"].values()]):
            if p["ci"] is None:
                continue
            lo, hi = p["ratio_ci"]
            axes[0].errorbar([p["ratio"]], [i + 0.15 * j - 0.2], fmt="o", color=col, capsize=2,
                             xerr=[[p["ratio"] - lo], [hi - p["ratio"]]],
                             mfc=None if j == 0 else "none")  # fmt: skip
        axes[0].annotate(v["verdict"], (1.0, i), xytext=(4, 6), textcoords="offset points",
                         fontsize=7, color="0.3")  # fmt: skip
    axes[0].axvline(1.0, color="k", lw=0.8)
    axes[0].axvspan(1 / 1.05, 1.05, color="0.85", zorder=0)
    axes[0].set(yticks=np.arange(len(names)), yticklabels=names, xscale="log",
                xlabel=f"RMSE ratio to {f['best']} on both-tracking runs (grey: +-5 %)",
                title="tuned alike, held out: ratio at the restart pairings")  # fmt: skip
    arms = list(f["ranking"]) + [f["paper_arm"]["arm"]]
    levels = (("held_out", "o", -0.2, "best restart"), ("other_held_out", "D", 0.0,
              "runner-up restart"), ("default_held_out", "s", 0.2, "defaults"))  # fmt: skip
    for j, (key, mk, off, label) in enumerate(levels):
        for i, n in enumerate(arms):
            d = f["arms"][n][key]["tracking_failure"]
            axes[1].errorbar([d["share"]], [i + off], xerr=[[d["share"] - d["ci_low"]],
                             [d["ci_high"] - d["share"]]], fmt=mk, capsize=2,
                             color=controllers.colour(n.split("@")[0]), mfc="none" if j else None,
                             label=label if i == 0 else None)  # fmt: skip
    axes[1].set(yticks=np.arange(len(arms)), yticklabels=arms, xlim=(-0.02, 1.02),
                xlabel=f"share of held-out runs failing to track (diverged or RMSE > "
                       f"{f['held_out']['tracking_m']:g} m; Clopper-Pearson 95 %)",
                title="tracking failure")  # fmt: skip
    axes[1].legend(fontsize=8)
    return fig


def waves_figure(record: dict):
    """The sequential design: the emulator's standardised errors at the planted truths against
    N(0, 1) (left), and the share of the prior's volume retained after each wave for the
    paper's tables (black) and for each planted truth (green: its setting retained, red: ruled
    out), with the 5 % line (right)."""
    import matplotlib.pyplot as plt
    from scipy.stats import norm

    seq = record["sequential"]
    val = seq["emulator"]["validation"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.0), layout="constrained")
    ax = axes[0]
    e = np.clip(np.asarray(val["errors"], dtype=float), -8, 8)
    ax.hist(e, bins=np.linspace(-8, 8, 49), density=True, color="0.6",
            label=f"{val['values']} errors (clipped at +-8)")  # fmt: skip
    g = np.linspace(-8, 8, 321)
    ax.plot(g, norm.pdf(g), "k", label="N(0, 1)")
    ax.set(xlabel="(m - E) / sqrt(V + s^2 / K)", ylabel="density",
           title=f"emulator at {val['points']} planted truths: {100 * val['within_2']:.0f} % "
                 f"within +-2, {100 * val['within_3']:.0f} % within +-3")  # fmt: skip
    ax.legend(fontsize=7)
    ax = axes[1]
    floor = 0.5 / seq["mc_points"]  # an empty region drawn at half a sample point
    for s in seq["recovery"]["waves"]["per_truth"]:
        ok = s["truth_retained"][-1]
        ax.plot(range(len(s["retained"])), np.maximum(s["retained"], floor), "o-", lw=0.8,
                ms=3, alpha=0.6, color="tab:green" if ok else "tab:red")  # fmt: skip
    ax.plot(range(len(seq["paper"]["retained"])), np.maximum(seq["paper"]["retained"], floor),
            "s-", color="k", lw=2, label="the paper's tables")  # fmt: skip
    ax.axhline(0.05, color="0.4", ls="--", label="5 % of the prior")
    ax.plot([], [], "o-", color="tab:green", label="planted truth: retained")
    ax.plot([], [], "o-", color="tab:red", label="planted truth: ruled out")
    ax.set(xlabel="wave (0: the space-filling design)", yscale="log",
           ylabel=f"share of {seq['mc_points']} uniform points retained",
           title="history-matching waves")  # fmt: skip
    ax.set_xticks(range(seq["waves"] + 1))
    ax.legend(fontsize=7)
    return fig


def all_figures(record: dict, points: dict, out) -> list[str]:
    """Draw and save every figure (``points``: the points file's columns); their file names."""
    return [common.save_figure(out, f"{STEM}_{name}.png", fig) for name, fig in (
        ("power", power_curve(record)), ("residuals", residual_profile(record)),
        ("projections", projections(record, points)),
        ("sensitivity", sensitivity_bars(record)), ("fair", fair_comparison(record)),
        ("waves", waves_figure(record)))]  # fmt: skip
