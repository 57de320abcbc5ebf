"""The regime study's decision rule and intervals measured on planted truth (DESIGN §7).

Synthetic paired data with the record's structure: the both-stable pairs of the record's
model frame (the same units: mechanism, pose source, trajectory, seed; so the same clusters,
trajectories and pair counts) get a planted log contrast ``log(ratio)`` in every cell plus
noise at the record's levels: per mechanism a seed effect (shared by that mechanism's pairs of
one seed on both pose sources and every trajectory) and a pair's own noise, their standard
deviations the method-of-moments estimates from the record's variation over the seeds
(:func:`noise`).  Each replicate is fitted by the study's model
(``analysis.regimes.stats.fit_model`` and ``estimates``) and judged by its verdict rule
(``analysis.regimes.rule``: ``classify`` per pose source, ``_combine`` per mechanism); the
planted truth is "same within 5 %" at 1.0 and 0.97, "pays" at 0.90 and "costs" at 1.10.
Reported, per planted ratio and per interval (normal or t at G - 1 df): the 95 % interval's
coverage of the planted log ratio (cells and mechanisms); each word's share of the (mechanism,
pose source) verdicts; the share of mechanisms whose pose sources contradict ("depends on the
pose source": never true of a planted ratio shared by both); the rule's **acceptance of the
truth** (DESIGN §7.6: no word of the mechanism false of the planted ratio, ``rule.compatible``;
"undecided" rejects nothing, and "pays" is true of 0.97) and its **power** (``correct``: every
pose source's word the planted one).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from analysis.regimes import rule
from analysis.regimes import stats as rstats

__all__ = ["RATIOS", "TRUTH", "noise", "simulate", "coverage"]

#: Planted ratios and the verdict each should get (the rule's 5 % margin: 0.97 is inside it).
RATIOS = (1.0, 0.97, 0.90, 1.10)
TRUTH = {1.0: "same within 5 %", 0.97: "same within 5 %", 0.90: "pays", 1.10: "costs"}
#: A pose source's verdict words (the synthetic pairs have no divergence).
WORDS = ("pays", "costs", "same within 5 %", "undecided")


def noise(frame) -> dict[str, dict[str, float]]:
    """Per mechanism the seed effect's and a pair's own noise standard deviations [log units]
    from ``frame``'s residuals about its (mechanism, pose, trajectory) means (what varies over
    the seeds; a trajectory's systematic difference within a cell is no noise: it is the same
    for every seed and cancels in the cell's estimate): one-way method of moments over the
    seeds (within: the pooled within-seed variance on its degrees of freedom; seed: the
    variance of the seed means less within / pairs per seed, floored at 0)."""
    df = frame.assign(resid=frame.delta - frame.groupby(["mechanism", "pose", "trajectory"])
                      .delta.transform("mean"))  # fmt: skip
    out = {}
    for m, g in df.groupby("mechanism", sort=False):
        by = g.groupby("seed").resid
        n, cells = by.size(), g.groupby(["pose", "trajectory"]).ngroups
        dof = len(g) - cells - len(n) + 1
        within = float(((g.resid - by.transform("mean")) ** 2).sum() / dof) if dof > 0 else 0.0
        seed = float(by.mean().var(ddof=1)) - within / float(n.mean()) if len(n) > 1 else 0.0
        out[m] = {"seed_sd": math.sqrt(max(seed, 0.0)), "pair_sd": math.sqrt(within)}
    return out


def simulate(frame, sd: dict, ratio: float, rng: np.random.Generator):
    """One replicate: ``frame``'s units with ``delta`` = log(ratio) + seed effect + pair noise
    (``sd``: :func:`noise`)."""
    df = frame[["mechanism", "pose", "trajectory", "seed"]].copy()
    delta = np.full(len(df), math.log(ratio))
    for m, idx in df.groupby("mechanism", sort=False).indices.items():
        seeds = df.seed.to_numpy()[idx]
        u = dict(zip(np.unique(seeds), rng.normal(0.0, sd[m]["seed_sd"], len(np.unique(seeds))),
                     strict=True))  # fmt: skip
        delta[idx] += np.array([u[s] for s in seeds]) + rng.normal(0.0, sd[m]["pair_sd"],
                                                                   len(idx))  # fmt: skip
    df["delta"] = delta
    return df


def _verdicts(est: dict, poses) -> dict[str, dict[str, str]]:
    """Each mechanism's pose-source words (``rule._one`` of its cells, as the report has
    them)."""
    return {m: {p: rule._one(est["cells"][m].get(p), 0)["verdict"] for p in poses
                if p in est["cells"][m]} for m in est["mechanisms"]}  # fmt: skip


def coverage(frame, replicates: int, seed: int = 0, use_t: tuple[bool, ...] = (False, True),
             mechanisms: tuple[str, ...] | None = None) -> dict:  # fmt: skip
    """The rule on planted truth (see the module) at ``frame``'s layout (only ``mechanisms``,
    None: all): per interval ("normal", "t(G-1)") and planted ratio, the coverage of the cells'
    and mechanisms' 95 % intervals and each verdict's share over mechanisms x replicates."""
    if mechanisms is not None:
        frame = frame[frame.mechanism.isin(mechanisms)]
    sd = noise(frame)
    mechs = list(dict.fromkeys(frame.mechanism))
    poses = sorted(set(frame.pose))
    out = {"replicates": replicates, "seed": seed, "clusters": int(frame.seed.nunique()),
           "pairs": int(len(frame)), "mechanisms": mechs, "noise": sd, "truth":
           {f"{r:g}": TRUTH[r] for r in RATIOS}, "intervals": {}}  # fmt: skip
    for t in use_t:
        rows = {}
        for k, ratio in enumerate(RATIOS):
            rng = np.random.default_rng([seed, k])
            cells = mech = 0
            n_cells = n_mech = 0
            counts = dict.fromkeys(WORDS, 0)
            judged = accepts = correct = depends = 0
            for _ in range(replicates):
                df = simulate(frame, sd, ratio, rng)
                with warnings.catch_warnings(record=True):
                    warnings.simplefilter("always")
                    fit, df = rstats.fit_model(df, use_t=t)
                    est = rstats.estimates(fit, df, mechs, poses)
                truth = math.log(ratio)
                for by in est["cells"].values():
                    for e in by.values():
                        cells += e["log_ci"][0] <= truth <= e["log_ci"][1]
                        n_cells += 1
                for e in est["mechanisms"].values():
                    mech += e["log_ci"][0] <= truth <= e["log_ci"][1]
                    n_mech += 1
                for by in _verdicts(est, poses).values():
                    for w in by.values():
                        counts[w] += 1
                    split = rule.contradict(by.values())
                    judged += 1
                    depends += split
                    accepts += not split and all(rule.compatible(w, ratio) for w in by.values())
                    correct += all(w == TRUTH[ratio] for w in by.values())
            total = sum(counts.values())
            rows[f"{ratio:g}"] = {"coverage_cells": cells / n_cells,
                                  "coverage_mechanisms": mech / n_mech,
                                  "verdicts": {w: c / total for w, c in counts.items()},
                                  "depends": depends / judged, "accepts": accepts / judged,
                                  "correct": correct / judged}  # fmt: skip
        out["intervals"]["t(G-1)" if t else "normal"] = rows
    return out
