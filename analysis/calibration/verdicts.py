"""The fair tuning's comparison (issue 23 item 6; DESIGN §7.3): endpoints, paired verdicts and
the ranking, from the held-out runs of ``analysis.calibration.fair`` (which defines the runs;
this module only summarises them, so it is outside the study store's digest and a change here
re-renders the record from the store).

- **Endpoints**, each its own: *divergence* (the 10 m bound) and *tracking failure*
  (diverged, or the RMSE after the transient above the regime study's ``TRACKING_M``: a run
  that stays within 10 m but misses the path by metres is not a tracking result), per arm
  with Clopper-Pearson intervals; paired, exact McNemar over the (cell, seed) pairs beside an
  exact sign test over the cells of the two arms' failure counts (a cell's failures cluster:
  the cell is the unit there).  *Accuracy*: the after-transient position RMSE on the pairs
  where both arms track, per seed the mean over its both-tracking cells of
  ``log r_X - log r_Y`` and its 95 % t interval over the seeds (common random numbers tie
  every run of a seed).
- **Verdict words** (:func:`word`): "fails more" / "fails less" when the cell sign test
  separates the two at 5 %.  Else from the accuracy interval: "lower" / "higher" when it
  excludes 0, "equivalent" inside ``±log 1.05``, "tie" when it reaches 0, "undetermined" with
  fewer than two seeds that have a both-tracking cell; but **"mixed"** when the arm that
  fails on more cells (not significantly) is the lower, tied or equivalent one: no word claims
  an arm as good as or better than one that tracks where it does not.
- **Restarts**: a comparison is made at the four pairings of the two arms' best and runner-up
  tuning restarts (:data:`PAIRINGS`); where they do not all give the same word it is
  **restart-dependent**, and no order is claimed (the tuning, not the law, decides it).
- **Best**: the candidate with the fewest tracking failures, then the lowest mean log RMSE
  over its tracking runs; it is *the* best only if every other arm's verdict against it is
  "higher" or "fails more" at all four pairings.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping

import numpy as np

from analysis.calibration.store import METRICS
from analysis.regimes import stats as rstats
from analysis.regimes.stats import divergence, mcnemar

__all__ = ["EQUIV", "RESTARTS", "PAIRINGS", "summary", "paired", "word", "across", "score",
           "compare", "RULE"]  # fmt: skip

#: Relative equivalence margin of a paired log ratio: ±5 %.
EQUIV = math.log(1.05)
#: An arm's tuning restarts held out: its best and its runner-up.
RESTARTS = ("tuned", "tuned-other")
#: The four restart pairings of a comparison (a's level, b's level).
PAIRINGS = tuple(itertools.product(RESTARTS, RESTARTS))
_TAIL = METRICS.index("tail_position")


def _runs(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tail position RMSE, diverged, failed to track) of a held-out result, (seeds, cells)."""
    r = arr[..., _TAIL]
    diverged = (arr[..., -1] != 0) | ~np.isfinite(r)
    failed = rstats.failed_to_track(diverged.ravel(), r.ravel()).reshape(r.shape)
    return r, diverged, failed


def summary(arr: np.ndarray) -> dict:
    r, diverged, failed = _runs(arr)
    ok = ~failed
    per_seed = [float(np.mean(np.log(r[s, ok[s]]))) if ok[s].any() else None
                for s in range(r.shape[0])]  # fmt: skip
    return {"divergence": divergence(diverged.ravel()), "tracking_failure": divergence(
                failed.ravel()),
            "mean_log_rmse": float(np.mean(np.log(r[ok]))) if ok.any() else None,
            "median_rmse": float(np.median(r[ok])) if ok.any() else None,
            "per_seed_mean_log_rmse": per_seed,
            "per_cell_median_rmse": [float(np.median(r[ok[:, j], j])) if ok[:, j].any()
                                     else None for j in range(r.shape[1])],
            "per_cell_failures": [int(x) for x in failed.sum(axis=0)]}  # fmt: skip


def _cell_sign_test(fa: np.ndarray, fb: np.ndarray) -> dict:
    """Exact sign test over the cells (columns) of their failure counts: ``a_more`` cells
    where a fails on more seeds than b, ``b_more`` the reverse, two-sided p (1 with none)."""
    from scipy.stats import binomtest

    d = fa.sum(axis=0).astype(int) - fb.sum(axis=0).astype(int)
    k, n = int(np.sum(d > 0)), int(np.sum(d != 0))
    p = 1.0 if n == 0 else float(binomtest(k, n).pvalue)
    return {"cells": int(d.size), "a_more": k, "b_more": n - k, "p": p}


def paired(arr_a: np.ndarray, arr_b: np.ndarray, columns: np.ndarray | None = None) -> dict:
    """Arm a against arm b on the same held-out runs (see the module), on the cells
    ``columns`` (a boolean mask; None: all): divergence and tracking failure (McNemar over
    the pairs, the sign test over the cells), the seeds' mean log ratio over both-tracking
    cells with its 95 % t interval, tie, equivalence and the verdict :func:`word`."""
    from scipy import stats

    if columns is not None:
        arr_a, arr_b = arr_a[:, columns], arr_b[:, columns]
    ra, da, fa = _runs(arr_a)
    rb, db, fb = _runs(arr_b)
    both = ~fa & ~fb
    d = np.array([np.mean(np.log(ra[s, both[s]] / rb[s, both[s]]))
                  for s in range(ra.shape[0]) if both[s].any()])  # fmt: skip
    out = {"divergence": mcnemar(da.ravel(), db.ravel()),
           "tracking": {**mcnemar(fa.ravel(), fb.ravel()), "by_cell": _cell_sign_test(fa, fb)},
           "tracking_pairs": int(both.sum()), "pairs": int(both.size), "seeds": int(d.size)}
    if d.size < 2:  # no interval: the accuracy is undetermined (neither a tie nor a win)
        out.update({"mean_log_ratio": float(d.mean()) if d.size else None, "ci": None,
                    "ratio": None, "ratio_ci": None, "tie": False, "equivalent": False})
    else:
        half = float(stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size))
        m = float(d.mean())
        ci = [m - half, m + half]
        out.update({"mean_log_ratio": m, "ci": ci, "ratio": math.exp(m),
                    "ratio_ci": [math.exp(ci[0]), math.exp(ci[1])],
                    "tie": bool(ci[0] <= 0.0 <= ci[1]),
                    "equivalent": bool(-EQUIV < ci[0] and ci[1] < EQUIV)})  # fmt: skip
    out["word"] = word(out)
    return out


def word(p: Mapping) -> str:
    """The verdict of a paired comparison (see the module): failure first, then accuracy,
    "mixed" where the two point opposite ways."""
    cell = p["tracking"]["by_cell"]
    if cell["p"] < 0.05:
        return "fails more" if cell["a_more"] > cell["b_more"] else "fails less"
    if p["ci"] is None:
        return "undetermined"
    if p["equivalent"]:
        acc = "equivalent"
    elif p["tie"]:
        acc = "tie"
    else:
        acc = "higher" if p["ci"][0] > 0 else "lower"
    more = np.sign(cell["a_more"] - cell["b_more"])
    if (more > 0 and acc != "higher") or (more < 0 and acc != "lower"):
        return "mixed"
    return acc


def across(runs_a: Mapping[str, np.ndarray], runs_b: Mapping[str, np.ndarray],
           columns: np.ndarray | None = None) -> dict:
    """Arm a against arm b at the four pairings of their restarts (``runs_*``: level ->
    held-out result): best / best's :func:`paired` (``tuned``), the other three's (``by``),
    the four words and the verdict, their common word or "restart-dependent"."""
    by = {f"{la} / {lb}": paired(runs_a[la], runs_b[lb], columns) for la, lb in PAIRINGS}
    words = {k: v["word"] for k, v in by.items()}
    common = set(words.values())
    return {"tuned": by.pop("tuned / tuned"), "by": by, "pairings": words,
            "verdict": common.pop() if len(common) == 1 else "restart-dependent"}


def score(s: Mapping) -> tuple[float, float]:
    """An arm's held-out candidate order: tracking failures, then mean log RMSE."""
    m = s["mean_log_rmse"]
    return (s["tracking_failure"]["share"], math.inf if m is None else m)


def compare(runs: dict, matched: list[str], columns: np.ndarray) -> dict:
    """The matched arms on ``columns``: the candidate ranking, each arm against the candidate
    best at the four pairings, and whether the best and each consecutive order is determined."""
    score_of = {n: score(summary(runs[n]["tuned"][:, columns])) for n in matched}
    ranking = sorted(matched, key=score_of.get)
    best = ranking[0]
    vs = {n: across(runs[n], runs[best], columns) for n in ranking[1:]}
    order = [{"pair": [a, b], **{k: v for k, v in across(runs[b], runs[a], columns).items()
                                 if k in ("pairings", "verdict")}}
             for a, b in itertools.pairwise(ranking)]  # fmt: skip
    beaten = [n for n, v in vs.items() if v["verdict"] in ("higher", "fails more")]
    return {"ranking": ranking, "best": best, "best_determined": len(beaten) == len(vs),
            "against_best": vs, "order": order,
            "ties_with_best": [n for n, v in vs.items() if v["verdict"] in ("tie", "equivalent")],
            "restart_dependent": [n for n, v in vs.items()
                                  if v["verdict"] == "restart-dependent"]}  # fmt: skip


def arm_entry(a, rec: Mapping, other_table: Mapping, runs: Mapping[str, np.ndarray],
              main: np.ndarray) -> dict:  # fmt: skip
    """An arm's record (``a``: its ``tuning.Arm``, ``rec`` its tuning record, ``runs`` its
    held-out results by level) on the cells ``main``."""
    return {"controller": a.controller, "pose_source": a.scenario["estimator.pose_source"],
            "free": [f["name"] for f in rec["free"]], "evaluations": rec["evaluations"],
            "evaluations_per_restart": rec["evaluations_per_restart"],
            "objective": rec["objective"], "objective_at_defaults": rec["objective_at_defaults"],
            "agreement": rec["agreement"], "edges": rec["edges"], "values": rec["values"],
            "other_table": other_table,
            "held_out": summary(runs["tuned"][:, main]),
            "other_held_out": summary(runs["tuned-other"][:, main]),
            "default_held_out": summary(runs["default"][:, main]),
            "tuned_vs_default": paired(runs["tuned"], runs["default"], main)}  # fmt: skip


#: The comparison's rule, as the record states it.
RULE = ("failure first: a run fails to track when it diverges (10 m) or its RMSE after the "
        f"transient exceeds {rstats.TRACKING_M} m (the regime study's threshold); an exact sign "
        "test over the cells of the two arms' failure counts at 5 % gives 'fails more' / 'fails "
        "less'; else, per seed, the mean over its both-tracking cells of log r_X - log r_Y with "
        "a 95 % t interval over the seeds: 'lower' / 'higher' when it excludes 0, 'equivalent' "
        "inside +-log 1.05, 'tie' when it reaches 0, 'undetermined' with fewer than 2 seeds, "
        "'mixed' when the arm failing on more cells is the lower, tied or equivalent one; each "
        "comparison at the four pairings of the two arms' best and runner-up restarts, "
        "'restart-dependent' unless all four agree; the best candidate (fewest tracking "
        "failures, then lowest mean log RMSE) is the best only if every other arm is 'higher' "
        "or 'fails more' against it at all four")


def assemble(entries: Mapping[str, dict], runs: Mapping[str, Mapping[str, np.ndarray]],
             matched: list[str], paper: str, raw: str, main: np.ndarray,
             apart: np.ndarray, apart_plants: list[str]) -> dict:  # fmt: skip
    """The fair tuning's comparison part of the record: the arms' ``entries``, the matched
    arms' ranking on the cells ``main`` (:func:`compare`), the paper's arm against the best
    and against ``raw``, and the plants compared apart (cells ``apart``)."""
    out: dict = {"arms": dict(entries), **compare(runs, matched, main)}
    best = out["best"]
    out["paper_arm"] = {"arm": paper, "against_best": across(runs[paper], runs[best], main),
                        "against_raw": across(runs[paper], runs[raw], main)}
    if apart.any():
        out["apart"] = {"plants": list(apart_plants), **compare(runs, matched, apart),
                        "held_out": {n: summary(runs[n]["tuned"][:, apart]) for n in runs}}
    out["rule"] = RULE
    return out
