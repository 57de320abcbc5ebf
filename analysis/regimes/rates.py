"""The SGD rate as a sensitivity figure, not a verdict (issue 22 item 2).

APID and IAPID-NN-DEKF at the shared defaults except the rate ``mu``, at x1, x10, x100 and x1000
of the default (the retired rate grid's readings; x100 is the per-second reading of the paper's
``mu``, DESIGN §5), on each pose source (both arms on the same one) and the kinematic mechanisms,
every trajectory.  Per rate, pose source and mechanism: each arm's divergence (Clopper-Pearson),
the paired divergence (the seed sign-flip test), and the geometric-mean ratio of both-stable
RMSE after the transient, IAPID / APID, with a Student t interval clustered by seed (the pairs
of one seed on the mechanism's trajectories share its noise; descriptive, no model).  Which
rate each arm should run at is the tuning stage's question; this only shows how the contrast
moves with the rate.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from analysis import common
from analysis.regimes import stats as rstats
from analysis.regimes.pairs import POSES, join, stable
from wmr import controllers

__all__ = ["RATES", "ARMS", "level", "tables", "analyse", "figure", "rows_of_table", "notes"]

#: Multipliers of the controllers' default ``mu``.
RATES = (1, 10, 100, 1000)
#: The two arms that differ only in the Jacobian.
ARMS = ("iapid-nn-dekf", "adaptive-pid")


def level(m: float) -> str:
    """The run level of rate multiplier ``m`` (``"rate-x10"``)."""
    return f"rate-x{m:g}"


def tables(m: float) -> dict:
    """Both arms' ``[controllers.<name>]`` tables at ``m`` times their default ``mu``."""
    out = {}
    for c in ARMS:
        mu = asdict(controllers.get(c).Settings())["mu"]
        out[c] = {"mu": [float(x) * m for x in mu]}
    return out


def _ratio(ok) -> dict:
    """Geometric-mean ratio a / b of the both-stable pairs ``ok`` (``delta``, ``seed``) with its
    95 % interval clustered by seed: the mean's cluster-robust variance ``G / (G - 1) sum_g
    S_g^2 / n^2`` (``S_g`` the seed's sum of residuals, ``G`` seeds, ``n`` pairs) and Student t
    at ``G - 1`` df; None without two seeds."""
    d = np.asarray(ok.delta, float)
    seeds = np.asarray(ok.seed)
    g = np.unique(seeds).size
    if d.size < 2 or g < 2:
        return {"ratio": None, "ratio_ci": None, "n_stable": int(d.size)}
    from scipy.stats import t as student

    m = float(d.mean())
    s = np.array([(d[seeds == k] - m).sum() for k in np.unique(seeds)])
    h = float(student.ppf(1 - rstats.ALPHA / 2, g - 1) * math.sqrt(g / (g - 1) * (s**2).sum())
              / d.size)  # fmt: skip
    return {"ratio": math.exp(m), "ratio_ci": [math.exp(m - h), math.exp(m + h)],
            "n_stable": int(d.size)}  # fmt: skip


def analyse(rows) -> dict | None:
    """The sensitivity record from the study's rows (levels :func:`level`); None without any."""
    levels = {level(m): m for m in RATES}
    r = rows[rows.level.isin(list(levels))]
    if r.empty:
        return None
    key = ["mechanism", "trajectory", "seed"]
    out: dict = {"rates": list(RATES), "arms": list(ARMS), "poses": {}}
    for pose in POSES:
        for m in dict.fromkeys(r.mechanism):
            for lv, mult in levels.items():
                g = r[(r.pose == pose) & (r.mechanism == m) & (r.level == lv)]
                if g.empty:
                    continue
                a, b = (g[g.controller == c].set_index(key) for c in ARMS)
                j = join(a, b)
                out["poses"].setdefault(pose, {}).setdefault(m, {})[f"x{mult:g}"] = {
                    "divergence": {c: rstats.divergence(g[g.controller == c].failed)
                                   for c in ARMS},
                    "paired": rstats.paired_failures(j.failed_a, j.failed_b, j.seed),
                    **_ratio(stable(j))}
    return out


def rows_of_table(rec: dict) -> list[list[str]]:
    """One row per (mechanism, rate): per pose source the ratio with its interval and pairs,
    and both arms' divergence counts."""
    rows = []
    first = next(iter(rec["poses"].values()))
    for m, by in first.items():
        for x in by:
            row = [m, x]
            for pose in rec["poses"]:
                e = rec["poses"][pose][m][x]
                dv = e["divergence"]
                ratio = ("—" if e["ratio"] is None else f"{e['ratio']:.3f} [{e['ratio_ci'][0]:.3f}"
                         f", {e['ratio_ci'][1]:.3f}] ({e['n_stable']})")  # fmt: skip
                row.append(f"{ratio}; diverged {dv[ARMS[0]]['diverged']} / "
                           f"{dv[ARMS[1]]['diverged']} of {dv[ARMS[0]]['n']}")
            rows.append(row)
    return rows


def figure(rec: dict):
    """Per pose source: the ratio IAPID / APID against the rate (top) and each arm's diverged
    share (bottom), a line per mechanism."""
    import matplotlib.pyplot as plt

    poses = list(rec["poses"])
    fig, axes = plt.subplots(2, len(poses), figsize=(5.2 * len(poses), 6.4), sharex=True,
                             squeeze=False)  # fmt: skip
    for j, pose in enumerate(poses):
        top, bot = axes[0, j], axes[1, j]
        for i, (m, by) in enumerate(rec["poses"][pose].items()):
            col = f"C{i}"
            xs = [float(x[1:]) for x in by]
            pts = [(x, e) for x, e in zip(xs, by.values(), strict=True) if e["ratio"] is not None]
            if pts:
                top.errorbar([x for x, _ in pts], [e["ratio"] for _, e in pts],
                             yerr=np.array([[e["ratio"] - e["ratio_ci"][0],
                                             e["ratio_ci"][1] - e["ratio"]] for _, e in pts]).T,
                             color=col, marker="o", ms=3, capsize=2, label=m)  # fmt: skip
            for c, ls in zip(ARMS, ("-", "--"), strict=True):
                bot.plot(xs, [e["divergence"][c]["share"] for e in by.values()], ls, color=col,
                         marker=".", label=f"{m}, {controllers.label(c)}" if j == 0 else None)
        top.axhline(1.0, color="0.5", lw=0.8)
        top.set_xscale("log")
        top.set_yscale("log")
        top.set_title(f"{pose} pose (both arms)")
        top.set_ylabel("RMSE ratio IAPID / APID (both stable)")
        bot.set_xlabel("rate: multiple of the default mu")
        bot.set_ylabel("share of runs diverged")
        bot.set_ylim(-0.03, 1.03)
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=6, ncol=2, title="solid: IAPID, dashed: APID", title_fontsize=7)
    fig.suptitle("The SGD rate: a sensitivity, not a verdict (defaults otherwise)")
    fig.tight_layout()
    return fig


def notes(rec: dict | None) -> str:
    """The report's paragraph and table of the sensitivity record ``rec`` ('' without one)."""
    if not rec:
        return ""
    div = {}
    for by in rec["poses"].values():
        for per in by.values():
            for x, e in per.items():
                for c, v in e["divergence"].items():
                    k, n = div.get((x, c), (0, 0))
                    div[(x, c)] = (k + v["diverged"], n + v["n"])
    said = "; ".join(f"x{m:g}: " + ", ".join(f"{controllers.label(c)} {div[(f'x{m:g}', c)][0]} of "
                                          f"{div[(f'x{m:g}', c)][1]}" for c in rec["arms"])
                     for m in rec["rates"] if (f"x{m:g}", rec["arms"][0]) in div)  # fmt: skip
    poses = list(rec["poses"])
    return "\n".join([
        "**The SGD rate, a sensitivity and not a verdict.** APID and IAPID-NN-DEKF at the "
        "defaults but the rate, both on the same pose, at multiples of the default rate. "
        f"Diverged runs: {said}. The ratio is IAPID / APID on the both-stable pairs, pooled over "
        "trajectories and seeds, its t interval clustered by seed (descriptive).", "",
        *common.md_table(["mechanism", "rate", *[f"{p}: ratio [95 %] (pairs); diverged IAPID / "
                                                 "APID" for p in poses]],
                         rows_of_table(rec))])  # fmt: skip
