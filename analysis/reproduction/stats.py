"""Statistics of the reproduction study over seeds: per-run tables, paired tests, rankings.

Numbers only; :mod:`analysis.reproduction` assembles them into its record and renders them.
The generic tests (Wilcoxon signed-rank, Holm's adjustment) live in :mod:`wmr.stats`.
"""

from __future__ import annotations

import math

import numpy as np

from wmr.closedloop.result import Row
from wmr.stats import holm, paired_differences, tost, wilcoxon

__all__ = ["AXES", "TAIL", "ALPHA", "MARGIN", "EQUIVALENCE_PAIRS", "EQUIVALENCE_METRICS",
           "describe", "by_run", "paired", "ranking", "holm", "contradictions", "lowest_mean",
           "equivalence"]  # fmt: skip

AXES = ("x", "y", "theta")
# RMSE over t >= wmr.closedloop.metrics.TRANSIENT (the initial pose error left out), per axis and
# position.
TAIL = ("tail_x", "tail_y", "tail_theta", "tail_position")
#: Family-wise error rate of the tie-aware ranking check (Holm over the pairs of one axis).
ALPHA = 0.05
#: Equivalence margin [m] of the TOST of "these two controllers are the same" (1 mm).
MARGIN = 1e-3
#: The pairs tested for equivalence, (a, b): the difference is a - b (negative: a is better).
EQUIVALENCE_PAIRS = (("iapid-nn-dekf", "adaptive-pid"), ("adaptive-pid", "pid"))
#: The RMSEs the equivalence is tested on: the full run, and after the transient.
EQUIVALENCE_METRICS = ("position", "tail_position")


def describe(values: np.ndarray) -> dict:
    """Mean, std (ddof 1) and count of the finite ``values`` (a diverged run is NaN)."""
    ok = values[np.isfinite(values)]
    if ok.size == 0:
        return {"mean": None, "std": None, "n": 0}
    std = float(np.std(ok, ddof=1)) if ok.size > 1 else 0.0
    return {"mean": float(np.mean(ok)), "std": std, "n": int(ok.size)}


def by_run(rows: list[Row]) -> dict:
    """rows -> {(scenario, controller, variant): {axis: values array in seed order}}, with the
    ``seed`` and ``diverged`` columns beside the RMSEs."""
    out: dict = {}
    for r in sorted(rows, key=lambda r: r.seed):
        d = out.setdefault((r.scenario, r.controller, r.variant), {"seed": [], "diverged": []})
        d["seed"].append(r.seed)
        d["diverged"].append(r.diverged)
        for axis in (*AXES, "position"):
            d.setdefault(axis, []).append(getattr(r, f"rmse_{axis}"))
        for axis in TAIL:
            d.setdefault(axis, []).append(getattr(r, axis))
    return {k: {a: np.asarray(v) for a, v in d.items()} for k, d in out.items()}


def paired(a: np.ndarray, b: np.ndarray) -> dict:
    """Paired comparison of per-seed RMSEs a vs b (same seeds): difference a - b, the seeds
    where a is better (``wins``) and the two-sided Wilcoxon signed-rank p-value."""
    d = paired_differences(a, b)
    if d.size == 0:
        return {"n": 0}
    return {"n": int(d.size), "mean_diff": float(np.mean(d)),
            "std_diff": float(np.std(d, ddof=1)) if d.size > 1 else 0.0,
            "wins": int(np.sum(d < 0)), "wilcoxon_p": wilcoxon(d)}  # fmt: skip


def ranking(table: dict, scenario: str, names, variant_of: dict | None = None) -> dict:
    """Order of ``names`` by mean RMSE per axis (ascending); a diverging controller ranks last.

    ``variant_of`` maps a controller to the variant whose runs stand for it (default runs
    otherwise)."""
    ranks = {}
    for axis in (*AXES, "position", "tail_position"):
        means = {}
        for n in names:
            v = (variant_of or {}).get(n, "default")
            vals = table[(scenario, n, v)][axis]
            means[n] = float(np.mean(vals)) if np.all(np.isfinite(vals)) else math.inf
        ranks[axis] = sorted(names, key=lambda n: means[n])
    return ranks


def contradictions(paper_order: list[str], pairs: dict, axis: str,
                   alpha: float = ALPHA) -> list[dict]:  # fmt: skip
    """Pairs the paper orders ``a`` before ``b`` where our runs make ``b`` significantly better.

    Tie-aware: a pair whose means merely swap without a significant paired difference does not
    contradict the paper.  Two-sided Wilcoxon signed-rank p-values of every pair of the axis
    (``pairs``: ``"a vs b"`` -> axis -> :func:`paired`), Holm-adjusted together (family-wise
    error ``alpha``); ``b`` is significantly better when its mean is lower and the adjusted p is
    below ``alpha``.
    """
    tested = []
    for i, a in enumerate(paper_order):
        for b in paper_order[i + 1 :]:
            key, sign = (f"{a} vs {b}", 1.0) if f"{a} vs {b}" in pairs else (f"{b} vs {a}", -1.0)
            r = pairs[key][axis]
            if r.get("n"):
                tested.append((a, b, sign * r["mean_diff"], r["wilcoxon_p"]))
    adjusted = holm([p for *_, p in tested])
    return [{"paper_better": a, "paper_worse": b, "mean_diff": d, "p_holm": q}
            for (a, b, d, _), q in zip(tested, adjusted, strict=True)
            if d > 0 and q < alpha]  # fmt: skip


def lowest_mean(table: dict, scenario: str, names, variant: str = "default",
                metric: str = "position") -> dict:  # fmt: skip
    """The controller of ``names`` with the lowest mean ``metric`` on ``scenario``, each on
    ``variant``'s runs where it has them and on its default runs otherwise.

    Returns ``{"best": name, "mean": its mean, "means": {name: mean}, "on_variant": [names whose
    variant runs were used]}``; a controller with a diverged run has mean ``inf`` (it cannot be
    best), stored as None.
    """
    means, used = {}, []
    for n in names:
        key = (scenario, n, variant)
        if key in table:
            used.append(n)
        else:
            key = (scenario, n, "default")
        vals = table[key][metric]
        means[n] = float(np.mean(vals)) if np.all(np.isfinite(vals)) else math.inf
    best = min(names, key=lambda n: means[n])
    return {"best": best, "mean": _finite(means[best]),
            "means": {n: _finite(m) for n, m in means.items()}, "on_variant": used}


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def equivalence(table: dict, scenarios, pairs=EQUIVALENCE_PAIRS, metrics=EQUIVALENCE_METRICS,
                delta: float = MARGIN, alpha: float = ALPHA) -> dict:  # fmt: skip
    """Paired tests of "a and b are the same controller" per scenario, pair and metric.

    For the per-seed RMSEs ``a``, ``b`` (the same seeds, default runs): the paired-t TOST at the
    margin ``delta`` (:func:`wmr.stats.tost`; each one-sided test at ``alpha``, so its interval is
    the ``1 - 2 alpha`` one) and the two-sided Wilcoxon signed-rank p of the difference
    (:func:`wmr.stats.wilcoxon`), Holm-adjusted (:func:`wmr.stats.holm`) over the family of one
    metric: every (scenario, pair) tested.  ``equivalent`` and ``different`` (Holm-adjusted
    p < ``alpha``) can both hold: a difference smaller than the margin can be detectable.

    Returns ``{scenario: {"a vs b": {metric: {TOST fields, "wilcoxon_p", "p_holm",
    "different"}}}}`` for the pairs whose two controllers both ran on the scenario with at least
    two finite pairs of runs.
    """
    out: dict = {}
    for metric in metrics:
        tested = []
        for sc in scenarios:
            for a, b in pairs:
                if (sc, a, "default") in table and (sc, b, "default") in table:
                    x, y = table[(sc, a, "default")][metric], table[(sc, b, "default")][metric]
                    if paired_differences(x, y).size < 2:  # TOST needs two pairs
                        continue
                    rec = tost(x, y, delta, alpha).to_json()
                    rec["wilcoxon_p"] = wilcoxon(paired_differences(x, y))
                    out.setdefault(sc, {}).setdefault(f"{a} vs {b}", {})[metric] = rec
                    tested.append(rec)
        for rec, q in zip(tested, holm([r["wilcoxon_p"] for r in tested]), strict=True):
            rec["p_holm"] = q
            rec["different"] = bool(q < alpha)
    return out
