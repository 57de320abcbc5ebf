"""Fair tuning (issue 23 item 6; DESIGN §7.2): who wins when every arm is tuned alike, through
the one tuning stage the regime study uses (``analysis.tuning``).

- **Arms**: the paper's four controllers and the two a practitioner would pick instead (NMPC,
  the parametric adaptive backstepping), all acting on the measured pose (``raw``), so that
  they differ only in the law (DESIGN §7.1); the paper's own asymmetry, IAPID-NN-DEKF on its
  filtered pose, is a separate, labelled arm (:data:`PAPER_ARM`).
- **Tuning**: ``analysis.tuning.tune_arm``, each arm's free settings of ``tuning.FREE`` (the
  adaptation's own rates, time scales and covariances included) with ``per_setting``
  evaluations per free setting per restart, two CMA-ES restarts; on the regime study's
  training pairs (``analysis.regimes.design.TRAINING``: other trajectories on other plants).
  At the medium and full levels the budget and the training are the regime study's full
  level's, so the two studies share one tuning (the cache of ``tune_arm``, keyed by
  everything a tuning depends on).
- **Held out**: the paper's three scenarios (trajectories the tuning never saw) on the
  true-robot plants of :data:`PLANTS` (``design.MECHANISMS``: the lateral skid with the
  outward sign of DESIGN §3.3), at seeds the tuning never used; each arm tuned and at its
  defaults.
- **Endpoints** (DESIGN §7.3): divergence per arm (Clopper-Pearson) and paired (exact McNemar
  over the (cell, seed) pairs); the after-transient position RMSE compared on the pairs where
  both arms stayed within the bound: per seed, the mean over its both-stable cells of
  ``log r_X - log r_best``, and its 95 % t interval over the seeds (the seed is the unit:
  common random numbers tie every run of a seed).  A difference whose interval reaches 0 is
  a **tie**; one inside ``±log 1.05`` is **equivalent** at 5 %.  "Best" is the lowest mean
  over the held-out cells of the seeds' mean log RMSE, counting only arms that never
  diverged held out (a diverging arm is ranked by its divergence, never by a placeholder).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis import tuning
from analysis.calibration import prior
from analysis.calibration.store import METRICS, Task, task_key
from analysis.regimes import design
from analysis.regimes.stats import divergence, mcnemar

__all__ = ["Budget", "ARMS", "POSE", "PAPER_ARM", "PLANTS", "EQUIV", "arms", "held_out_task",
           "paired", "fair_tuning"]  # fmt: skip

#: The compared controllers (all on :data:`POSE`).
ARMS = ("iapid-nn-dekf", "adaptive-pid", "backstepping", "adaptive-nn", "adaptive-bsc", "nmpc")
POSE = "raw"
#: The paper's arm as it ran it: its own filtered pose (labelled; not in the matched ranking).
PAPER_ARM = ("iapid-nn-dekf", "filtered")
#: The held-out plants (``analysis.regimes.design.MECHANISMS``).
PLANTS = ("ideal", "wheel-radius", "unequal-wheels", "lag-delay", "slip",
          "lagged-velocity-change")  # fmt: skip
#: Relative equivalence margin of a paired log ratio: ±5 %.
EQUIV = math.log(1.05)
_TAIL = METRICS.index("tail_position")


@dataclass(frozen=True)
class Budget:
    """The fair tuning's budget and held-out set: ``per_setting`` evaluations per free setting
    per restart (``restarts`` CMA-ES runs) on the first ``training`` pairs of
    ``design.TRAINING`` (None: all) of ``train_duration`` s at ``train_seeds``; held out: the
    paper's scenarios on ``plants`` at ``test_seeds`` (``duration``: None = the scenarios')."""

    per_setting: int
    train_seeds: tuple[int, ...]
    test_seeds: tuple[int, ...]
    train_duration: float = 20.0
    training: int | None = None
    duration: float | None = None
    plants: tuple[str, ...] = PLANTS
    restarts: int = 2

    def tuning(self) -> tuning.Budget:
        return tuning.Budget(per_setting=self.per_setting, seeds=tuple(self.train_seeds),
                             restarts=self.restarts)  # fmt: skip


def arms() -> list[tuning.Arm]:
    """The matched arms, then the paper's labelled one."""
    return [tuning.arm(c, POSE) for c in ARMS] + [tuning.arm(*PAPER_ARM)]


def cells(budget: Budget) -> list[tuple[str, str]]:
    """The held-out (scenario, plant) cells."""
    return [(s, p) for s in prior.SCENARIOS for p in budget.plants]


def held_out_task(a: tuning.Arm, table: Mapping | None, budget: Budget) -> Task:
    """The arm with ``table`` (its ``[controllers.<name>]`` settings; None: the defaults) on
    every held-out cell at the test seeds."""
    cs = cells(budget)
    key = task_key({"fair": "held-out", "arm": a.name, "scenario": dict(a.scenario),
                    "table": table, "cells": cs, "duration": budget.duration,
                    "seeds": list(budget.test_seeds)})  # fmt: skip
    cases = tuple((tuning.scenario(design.document(s, p, budget.duration), a, table,
                                   name=f"{s}@{p}", source=f"<fair {a.name} {s}@{p}>"),
                   a.controller, None) for s, p in cs)  # fmt: skip
    return Task(key, cases, tuple(budget.test_seeds))


def _runs(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(tail position RMSE, failed) of a held-out result, shape (seeds, cells) each."""
    r = arr[..., _TAIL]
    failed = (arr[..., -1] != 0) | ~np.isfinite(r)
    return r, failed


def _summary(arr: np.ndarray) -> dict:
    r, failed = _runs(arr)
    ok = ~failed
    per_seed = [float(np.mean(np.log(r[s, ok[s]]))) if ok[s].any() else None
                for s in range(r.shape[0])]  # fmt: skip
    return {"divergence": divergence(failed.ravel()),
            "mean_log_rmse": float(np.mean(np.log(r[ok]))) if ok.any() else None,
            "median_rmse": float(np.median(r[ok])) if ok.any() else None,
            "per_seed_mean_log_rmse": per_seed,
            "per_cell_median_rmse": [float(np.median(r[ok[:, j], j])) if ok[:, j].any()
                                     else None for j in range(r.shape[1])]}  # fmt: skip


def paired(arr_a: np.ndarray, arr_b: np.ndarray) -> dict:
    """Arm a against arm b on the same held-out runs (see the module): McNemar on divergence,
    the seeds' mean log ratio over both-stable cells with its 95 % t interval, tie and
    equivalence."""
    from scipy import stats

    ra, fa = _runs(arr_a)
    rb, fb = _runs(arr_b)
    both = ~fa & ~fb
    d = np.array([np.mean(np.log(ra[s, both[s]] / rb[s, both[s]]))
                  for s in range(ra.shape[0]) if both[s].any()])  # fmt: skip
    out = {"divergence": mcnemar(fa.ravel(), fb.ravel()), "stable_pairs": int(both.sum()),
           "pairs": int(both.size), "seeds": int(d.size)}  # fmt: skip
    if d.size < 2:  # no interval: no difference can be told from a tie
        return {**out, "mean_log_ratio": float(d.mean()) if d.size else None, "ci": None,
                "ratio": None, "tie": True, "equivalent": False}  # fmt: skip
    half = float(stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size))
    m = float(d.mean())
    ci = [m - half, m + half]
    return {**out, "mean_log_ratio": m, "ci": ci, "ratio": math.exp(m),
            "ratio_ci": [math.exp(ci[0]), math.exp(ci[1])], "tie": bool(ci[0] <= 0.0 <= ci[1]),
            "equivalent": bool(-EQUIV < ci[0] and ci[1] < EQUIV)}  # fmt: skip


def fair_tuning(ev, budget: Budget, cache: Path | None) -> dict:
    """Tune every arm of :func:`arms` (``tuning.tune_arm`` on ``ev``'s engine, records kept in
    ``cache``), run them held out tuned and at their defaults, compare; the record's
    ``fair_tuning``."""
    training = design.training_documents(budget.train_duration, budget.training)
    tb = budget.tuning()
    out: dict = {"arms": {}}
    tuned, default = {}, {}
    for a in arms():
        rec = tuning.tune_arm(a, training, tb, ev.engine(), cache=cache)
        arr_t, arr_d = ev.evaluate([held_out_task(a, rec["table"], budget),
                                    held_out_task(a, None, budget)], f"held out {a.name}")
        tuned[a.name], default[a.name] = arr_t, arr_d
        out["arms"][a.name] = {
            "controller": a.controller, "pose_source": a.scenario["estimator.pose_source"],
            "free": [f["name"] for f in rec["free"]], "evaluations": rec["evaluations"],
            "evaluations_per_restart": rec["evaluations_per_restart"],
            "objective": rec["objective"], "objective_at_defaults": rec["objective_at_defaults"],
            "agreement": rec["agreement"], "edges": rec["edges"], "values": rec["values"],
            "held_out": _summary(arr_t), "default_held_out": _summary(arr_d),
            "tuned_vs_default": paired(arr_t, arr_d)}  # fmt: skip
    matched = [f"{c}@{POSE}" for c in ARMS]
    stable = [n for n in matched if out["arms"][n]["held_out"]["divergence"]["diverged"] == 0]
    score = {n: out["arms"][n]["held_out"]["mean_log_rmse"] for n in stable}
    ranking = sorted(stable, key=score.get)
    ranking += sorted((n for n in matched if n not in stable),
                      key=lambda n: out["arms"][n]["held_out"]["divergence"]["share"])
    best = ranking[0]
    out["ranking"] = ranking
    out["best"] = best
    out["paired_with_best"] = {n: paired(tuned[n], tuned[best]) for n in matched if n != best}
    out["ties_with_best"] = [n for n, p in out["paired_with_best"].items() if p["tie"]]
    paper = f"{PAPER_ARM[0]}@{PAPER_ARM[1]}"
    out["paper_arm"] = {"arm": paper, "against_best": paired(tuned[paper], tuned[best]),
                        "against_raw": paired(tuned[paper], tuned[f"{PAPER_ARM[0]}@{POSE}"])}
    out["budget"] = {"per_setting": budget.per_setting, "restarts": budget.restarts,
                     "train_seeds": list(budget.train_seeds),
                     "test_seeds": list(budget.test_seeds),
                     "train_duration": budget.train_duration,
                     "training": list(training), "duration": budget.duration,
                     "optimiser": "CMA-ES (cma) through analysis.tuning.tune_arm, default "
                                  "population, restart 0 from the defaults"}  # fmt: skip
    out["held_out"] = {"scenarios": list(prior.SCENARIOS), "plants": list(budget.plants),
                       "cells": [f"{s}@{p}" for s, p in cells(budget)],
                       "metric": "position RMSE after the transient [m]"}  # fmt: skip
    out["rule"] = ("paired over the test seeds: per seed, the mean over its both-stable cells "
                   "of log r_X - log r_best; 95 % t interval over the seeds; a tie when it "
                   "reaches 0, equivalent when inside +-log 1.05; divergence by exact McNemar "
                   "over the (cell, seed) pairs; best = the lowest mean log RMSE among the "
                   "arms that never diverged held out")  # fmt: skip
    return out
