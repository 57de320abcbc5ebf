"""The fair tuning's comparison (issue 23 item 6; DESIGN §7.3): endpoints, paired verdicts and
the ranking, from the held-out runs of ``analysis.calibration.fair`` (which defines the runs;
this module only summarises them, so it is outside the study store's digest and a change here
re-renders the record from the store).

- **Endpoints**, each its own: *divergence* (the 10 m bound) and *tracking failure*
  (diverged, or the RMSE after the transient above the regime study's ``TRACKING_M``: a run
  that stays within 10 m but misses the path by metres is not a tracking result), per arm
  with Clopper-Pearson intervals, and per held-out plant.  Paired: for each seed (common random
  numbers tie every run of a seed; the seeds are the independent replicates, the cells are
  fixed), the number of cells where a fails and b tracks minus the reverse; an exact sign-flip
  test over the seeds of their sum (:func:`seed_flip_test`: every assignment of signs
  enumerated).  A difference confined to a few cells is detected when it repeats over the
  seeds (a sign test over the cells, used before, could not reach 5 % with five or fewer cells
  differing, whatever the seeds said).  Exact McNemar over the (cell, seed) pairs is kept
  beside it.  *Accuracy*: the after-transient position RMSE on the cells where both arms
  track at every seed (one common set of cells, so every seed's mean is over the same cells),
  per seed the mean over those cells of ``log r_X - log r_Y`` and its 95 % t interval over the
  seeds, with the number of cells beside it.
- **Verdict words** (:func:`word`): "fails more" / "fails less" when the seed test separates
  the two at 5 %.  Else from the accuracy interval: "lower" / "higher" when it excludes 0,
  "equivalent" inside ``±log 1.05``, "tie" when it reaches 0, "undetermined" with fewer than
  two seeds or no common cell; but **"mixed"** when the arm that fails more often (not
  significantly) is the lower, tied or equivalent one: no word claims an arm as good as or
  better than one that tracks where it does not.
- **Restarts**: a comparison is made at the four pairings of the two arms' best and runner-up
  tuning restarts (:data:`PAIRINGS`).  Where all four give the same word, that is the verdict;
  where they differ but all say the same direction, the verdict is **"worse"** (each "higher"
  or "fails more") or **"better"** (each "lower" or "fails less"); otherwise it is
  **restart-dependent**, and no order is claimed (the tuning, not the law, decides it).
- **Best**: the candidate with the fewest tracking failures, then the lowest mean log RMSE
  over its tracking runs; it is *the* best only if every other arm's verdict against it is
  "higher", "fails more" or "worse" (worse at all four pairings).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping

import numpy as np

from analysis.calibration import prior
from analysis.calibration.store import METRICS
from analysis.regimes import stats as rstats
from analysis.regimes.stats import divergence, mcnemar

__all__ = ["EQUIV", "RESTARTS", "PAIRINGS", "WORSE", "BETTER", "summary", "seed_flip_test",
           "paired", "word", "across", "combined", "score", "compare", "at_defaults",
           "fixed_settings", "arm_entry", "assemble", "swap", "RULE"]  # fmt: skip

#: Relative equivalence margin of a paired log ratio: ±5 %.
EQUIV = math.log(1.05)
#: An arm's tuning restarts held out: its best and its runner-up.
RESTARTS = ("tuned", "tuned-other")
#: The four restart pairings of a comparison (a's level, b's level).
PAIRINGS = tuple(itertools.product(RESTARTS, RESTARTS))
_TAIL = METRICS.index("tail_position")
#: The words that say the first arm is worse / better than the second (a direction).
WORSE = ("higher", "fails more")
BETTER = ("lower", "fails less")


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


def seed_flip_test(fa: np.ndarray, fb: np.ndarray) -> dict:
    """Paired failures of arms a and b, ``fa``, ``fb`` (seeds, cells) booleans: per seed the
    cells where a fails and b tracks minus the reverse (``per_seed``), their sum, and the exact
    two-sided sign-flip p-value of the sum over the seeds (every one of the ``2^S`` sign
    assignments of the seeds' differences; valid because, with common random numbers, swapping
    the arms' labels within a seed leaves its runs' joint law unchanged under the null)."""
    d = ((fa & ~fb).sum(axis=1) - (fb & ~fa).sum(axis=1)).astype(int)
    total = int(d.sum())
    p = rstats.sign_flip(d)
    return {"seeds": int(d.size), "per_seed": [int(x) for x in d], "a_more": total,
            "a_only": int((fa & ~fb).sum()), "b_only": int((fb & ~fa).sum()), "p": p}


def paired(arr_a: np.ndarray, arr_b: np.ndarray, columns: np.ndarray | None = None) -> dict:
    """Arm a against arm b on the same held-out runs (see the module), on the cells
    ``columns`` (a boolean mask; None: all): divergence (McNemar), tracking failure (the seed
    sign-flip test, McNemar beside it), the seeds' mean log ratio over the cells where both
    track at every seed with its 95 % t interval, tie, equivalence and the verdict
    :func:`word`."""
    from scipy import stats

    if columns is not None:
        arr_a, arr_b = arr_a[:, columns], arr_b[:, columns]
    ra, da, fa = _runs(arr_a)
    rb, db, fb = _runs(arr_b)
    common = (~fa & ~fb).all(axis=0)  # the cells where both track at every seed
    d = (np.mean(np.log(ra[:, common] / rb[:, common]), axis=1) if common.any()
         else np.empty(0))  # fmt: skip
    out = {"divergence": mcnemar(da.ravel(), db.ravel()),
           "tracking": {**mcnemar(fa.ravel(), fb.ravel()), "by_seed": seed_flip_test(fa, fb)},
           "tracking_pairs": int((~fa & ~fb).sum()), "pairs": int(fa.size),
           "common_cells": int(common.sum()), "cells": int(common.size), "seeds": int(d.size)}
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
    fail = p["tracking"]["by_seed"]
    if fail["p"] < 0.05:
        return "fails more" if fail["a_more"] > 0 else "fails less"
    if p["ci"] is None:
        return "undetermined"
    if p["equivalent"]:
        acc = "equivalent"
    elif p["tie"]:
        acc = "tie"
    else:
        acc = "higher" if p["ci"][0] > 0 else "lower"
    more = np.sign(fail["a_more"])
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
    return {"tuned": by.pop("tuned / tuned"), "by": by, "pairings": words,
            "verdict": combined(list(words.values()))}


def combined(words: list[str]) -> str:
    """The verdict of the four pairings' words: their common word; else "worse" / "better"
    when each says the same direction (:data:`WORSE`, :data:`BETTER`); else
    "restart-dependent"."""
    if len(set(words)) == 1:
        return words[0]
    if all(w in WORSE for w in words):
        return "worse"
    if all(w in BETTER for w in words):
        return "better"
    return "restart-dependent"


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
    beaten = [n for n, v in vs.items() if v["verdict"] in (*WORSE, "worse")]
    return {"ranking": ranking, "best": best, "best_determined": len(beaten) == len(vs),
            "against_best": vs, "order": order,
            "ties_with_best": [n for n, v in vs.items() if v["verdict"] in ("tie", "equivalent")],
            "restart_dependent": [n for n, v in vs.items()
                                  if v["verdict"] == "restart-dependent"]}  # fmt: skip


def fixed_settings(a) -> list[str]:
    """The arm's numeric settings that are not free (left at the controller's defaults by the
    tuning stage): the fields of its ``Settings`` with a number or a tuple of numbers as
    default, less the keys of its free settings (switches and names are choices, not
    listed)."""
    import dataclasses

    from wmr import controllers

    keys = {f.key for f in a.free}

    def numeric(v) -> bool:
        items = v if isinstance(v, tuple) else (v,)
        return all(isinstance(x, int | float) and not isinstance(x, bool) for x in items)

    return [f.name for f in dataclasses.fields(controllers.get(a.controller).Settings)
            if f.name not in keys and numeric(f.default)]  # fmt: skip


def arm_entry(a, rec: Mapping, other_table: Mapping, runs: Mapping[str, np.ndarray],
              main: np.ndarray) -> dict:  # fmt: skip
    """An arm's record (``a``: its ``tuning.Arm``, ``rec`` its tuning record, ``runs`` its
    held-out results by level) on the cells ``main``."""
    return {"controller": a.controller, "pose_source": a.scenario["estimator.pose_source"],
            "free": [f["name"] for f in rec["free"]], "fixed": fixed_settings(a),
            "evaluations": rec["evaluations"],
            "evaluations_per_restart": rec["evaluations_per_restart"],
            "runs_per_evaluation": rec["runs_per_evaluation"],
            "objective": rec["objective"], "objective_at_defaults": rec["objective_at_defaults"],
            "agreement": rec["agreement"], "edges": rec["edges"], "values": rec["values"],
            "other_table": other_table,
            "held_out": summary(runs["tuned"][:, main]),
            "other_held_out": summary(runs["tuned-other"][:, main]),
            "default_held_out": summary(runs["default"][:, main]),
            "tuned_vs_default": paired(runs["tuned"], runs["default"], main)}  # fmt: skip


#: The comparison's rule, as the record states it.
RULE = ("failure first: a run fails to track when it diverges (10 m) or its RMSE after the "
        f"transient exceeds {rstats.TRACKING_M} m (the regime study's threshold); per seed, the "
        "cells where one arm fails and the other tracks minus the reverse, and an exact "
        "sign-flip test over the seeds of their sum at 5 % gives 'fails more' / 'fails less'; "
        "else, per seed, the mean of log r_X - log r_Y over the cells where both arms track at "
        "every seed, with a 95 % t interval over the seeds: 'lower' / 'higher' when it excludes "
        "0, 'equivalent' inside +-log 1.05, 'tie' when it reaches 0, 'undetermined' with fewer "
        "than 2 seeds or no such cell, 'mixed' when the arm failing more often is the lower, "
        "tied or equivalent one; each comparison at the four pairings of the two arms' best "
        "and runner-up restarts: their common word, 'worse' / 'better' when they differ but all "
        "point one way, else 'restart-dependent'; the best candidate (fewest tracking "
        "failures, then lowest mean log RMSE) is the best only if every other arm is 'higher', "
        "'fails more' or 'worse' against it")


def swap(x: str, y: str, own_x: np.ndarray, own_y: np.ndarray, x_with_y: np.ndarray,
         y_with_x: np.ndarray, columns: np.ndarray) -> dict:
    """Two laws ``x``, ``y`` with the same free settings, each held out at its own best table
    (``own_*``) and at the other's (``x_with_y``: law x with y's table): x against y as tuned
    (``as_tuned``), the laws at common settings (``both_at_x``: both with x's table;
    ``both_at_y``), and each law with the other's table against itself with its own
    (``x_swapped``, ``y_swapped``: what the tuning alone changes)."""
    pairs = {"as_tuned": (own_x, own_y), "both_at_x": (own_x, y_with_x),
             "both_at_y": (x_with_y, own_y), "x_swapped": (x_with_y, own_x),
             "y_swapped": (y_with_x, own_y)}
    return {"arms": [x, y], "held_out": {"x_with_y": summary(x_with_y[:, columns]),
                                         "y_with_x": summary(y_with_x[:, columns])},
            "comparisons": {k: paired(a, b, columns) for k, (a, b) in pairs.items()}}


def at_defaults(runs: Mapping, matched: list[str], columns: np.ndarray) -> dict:
    """The matched arms at their defaults on ``columns``: the candidate ranking (as
    :func:`score`), each arm against the candidate best (one pairing: the defaults have no
    restarts) and whether the best is determined (every other arm higher or fails more)."""
    score_of = {n: score(summary(runs[n]["default"][:, columns])) for n in matched}
    ranking = sorted(matched, key=score_of.get)
    best = ranking[0]
    vs = {n: paired(runs[n]["default"], runs[best]["default"], columns) for n in ranking[1:]}
    return {"ranking": ranking, "best": best, "against_best": vs,
            "best_determined": all(v["word"] in WORSE for v in vs.values())}


def assemble(entries: Mapping[str, dict], runs: Mapping[str, Mapping[str, np.ndarray]],
             matched: list[str], paper: str, raw: str, main: np.ndarray,
             apart: np.ndarray, apart_plants: list[str]) -> dict:  # fmt: skip
    """The fair tuning's comparison part of the record: the arms' ``entries``, the matched
    arms' ranking on the cells ``main`` (:func:`compare`), the same on the plants where no
    matched arm's tuned runs fail to track (``where_all_track``: what the ranking says apart
    from the failures; its ``cells`` index the ``main`` cells) and at the defaults
    (:func:`at_defaults`), the paper's arm against the best and against ``raw``, and the
    plants compared apart (cells ``apart``), and the rule on planted truth at the layout and
    noise of the comparisons the record makes (``analysis.calibration.fair_planted``).  The
    columns are the cells scenario by scenario, the plants in the same order within each
    (``fair.cells``), so a column's plant is its index modulo the number of plants."""
    out: dict = {"arms": dict(entries), **compare(runs, matched, main)}
    n_cols = main.size
    plant = np.arange(n_cols) % (n_cols // len(prior.SCENARIOS))
    failing = {int(plant[j]) for n in matched for j in np.flatnonzero(main)
               if _runs(runs[n]["tuned"])[2][:, j].any()}  # fmt: skip
    rest = main & ~np.isin(plant, sorted(failing))
    within = np.flatnonzero(rest[main])  # the kept cells' positions among the main cells
    out["where_all_track"] = ({"cells": within.tolist(), **compare(runs, matched, rest)}
                              if rest.any() else None)  # fmt: skip
    out["at_defaults"] = at_defaults(runs, matched, main)
    best = out["best"]
    out["paper_arm"] = {"arm": paper, "against_best": across(runs[paper], runs[best], main),
                        "against_raw": across(runs[paper], runs[raw], main)}
    if apart.any():
        out["apart"] = {"plants": list(apart_plants), **compare(runs, matched, apart),
                        "held_out": {n: summary(runs[n]["tuned"][:, apart]) for n in runs}}
    out["rule"] = RULE
    from analysis.calibration import fair_planted  # it judges with this module's rule

    comparisons = fair_planted.comparisons(out["ranking"], best, paper, raw)
    out["planted"] = fair_planted.study(runs, comparisons, main, matched)
    return out
