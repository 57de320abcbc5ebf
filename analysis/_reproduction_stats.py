"""Statistics of the reproduction study over seeds: per-run tables, paired tests, rankings.

Numbers only; :mod:`analysis.reproduction` assembles them into its record and renders them.
The generic tests (Wilcoxon signed-rank, Holm's adjustment) live in :mod:`wmr.stats`.
"""

from __future__ import annotations

import math

import numpy as np

from wmr.result import Row
from wmr.stats import holm, paired_differences, wilcoxon

__all__ = ["AXES", "TAIL", "ALPHA", "describe", "by_run", "paired", "ranking", "holm",
           "contradictions"]  # fmt: skip

AXES = ("x", "y", "theta")
#: RMSE over t >= wmr.metrics.TRANSIENT (the initial pose error left out), per axis and position.
TAIL = ("tail_x", "tail_y", "tail_theta", "tail_position")
#: Family-wise error rate of the tie-aware ranking check (Holm over the pairs of one axis).
ALPHA = 0.05


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
