"""Fair tuning (issue 23 item 6; DESIGN §7.2): who wins when every arm is tuned alike, through
the one tuning stage the regime study uses (``analysis.tuning``).  This module defines the
runs (it is in the study store's digest); their comparison is ``analysis.calibration.verdicts``.

- **Arms**: the paper's four controllers and the two a practitioner would pick instead (NMPC,
  the parametric adaptive backstepping), all acting on the measured pose (``raw``), so that
  they differ only in the law (DESIGN §7.1); the paper's own asymmetry, IAPID-NN-DEKF on its
  filtered pose, is a separate, labelled arm (:data:`PAPER_ARM`).
- **Tuning**: ``analysis.tuning.tune_arm``, each arm's free settings of ``tuning.FREE`` (the
  adaptation's own rates, time scales and covariances included: the SGD's rates, both network
  laws' weight filter, Adaptive BSC's gains, weights, memory and forgetting) with ``per_setting``
  evaluations per free setting per restart, two CMA-ES restarts; on the regime study's
  training pairs (``analysis.regimes.design.TRAINING``: other trajectories on other plants).
  At the medium and full levels the budget and the training are the regime study's full
  level's, so the two studies share one tuning (the cache of ``tune_arm``, keyed by
  everything a tuning depends on).
- **Held out**: the paper's three scenarios on the true-robot plants of :data:`PLANTS`
  (``design.MECHANISMS``: the lateral skid with the outward sign of DESIGN §3.3), at seeds the
  tuning never used; each arm at its best tuning restart, at its runner-up restart
  (``tuning.other_restart``) and at its defaults (:data:`LEVELS`).  How disjoint that is,
  said plainly: the training trajectories (``design.TRAINING``) are other members of the same
  families (a smaller, faster lemniscate; a sinusoid of other speed, amplitude and frequency;
  an S-curve), and two held-out plants are training mechanisms at twice the magnitude
  (lag-delay: 0.1 s and 2 steps against 0.05 s and 1; slip 0.1 against 0.05); the others are
  mechanisms the training did not have (wheel radius, unequal wheels, a lagged velocity loop
  whose mass changes mid-run).  The ideal plant, a training plant, is not held out.  The
  MuJoCo robot (:data:`APART`, where a level holds it) is held out too but compared apart: the
  regime study found its 2 ms physics not converged, so its cells never enter the simulated
  plants' verdicts.
- **Settings swap** (:data:`SWAP`): the two laws that share free settings (IAPID-NN-DEKF
  and APID: the PID's gains and the SGD's rates) are also run with each other's best values
  of them (:func:`swap_table`; IAPID-NN-DEKF keeps its own weight filter, which APID has not),
  so that the law is compared at common settings apart from what each one's tuning found.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis import tuning
from analysis.calibration import prior, verdicts
from analysis.calibration.store import Task, task_key
from analysis.regimes import design
from analysis.regimes import stats as rstats

__all__ = ["Budget", "ARMS", "POSE", "PAPER_ARM", "PLANTS", "APART", "LEVELS", "SWAP",
           "swap_table", "arms", "cells", "held_out_task", "fair_tuning"]  # fmt: skip

#: The compared controllers (all on :data:`POSE`).
ARMS = ("iapid-nn-dekf", "adaptive-pid", "backstepping", "adaptive-nn", "adaptive-bsc", "nmpc")
POSE = "raw"
#: The paper's arm as it ran it: its own filtered pose (labelled; not in the matched ranking).
PAPER_ARM = ("iapid-nn-dekf", "filtered")
#: The held-out plants (``analysis.regimes.design.MECHANISMS``; "mujoco": ``design.MUJOCO``).
PLANTS = ("wheel-radius", "unequal-wheels", "lag-delay", "slip", "lagged-velocity-change",
          "mujoco")  # fmt: skip
#: Held-out plants compared apart from the others (not in the ranking): the MuJoCo robot.
APART = ("mujoco",)
#: An arm's held-out settings: its best tuning restart, its runner-up, its defaults.
LEVELS = (*verdicts.RESTARTS, "default")
#: The two arms with the same free settings, each also run with the other's best table.
SWAP = ("iapid-nn-dekf", "adaptive-pid")


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


def _columns(budget: Budget, apart: bool) -> np.ndarray:
    """The held-out cells' columns on the plants compared apart (``apart``) or the others."""
    return np.array([(p in APART) == apart for _, p in cells(budget)])


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


def swap_table(own: Mapping, other: Mapping) -> dict:
    """A law's best table with the settings it shares with another law's best table taken from
    that one (the swap: the PID's gains and the SGD's rates); the settings only it has (IAPID-
    NN-DEKF's weight filter) stay its own."""
    return {**own, **{k: v for k, v in other.items() if k in own}}


def fair_tuning(ev, budget: Budget, cache: Path | None) -> dict:
    """Tune every arm of :func:`arms` (``tuning.tune_arm`` on ``ev``'s engine, records kept in
    ``cache``), run them held out at both restarts and at their defaults, compare; the
    record's ``fair_tuning``."""
    training = design.training_documents(budget.train_duration, budget.training)
    tb = budget.tuning()
    runs: dict[str, dict[str, np.ndarray]] = {}
    entries: dict[str, dict] = {}
    main = _columns(budget, apart=False)
    best_tables, by_name = {}, {}
    for a in arms():
        rec = tuning.tune_arm(a, training, tb, ev.engine(), cache=cache)
        tables = (rec["table"], tuning.other_restart(a, rec), None)
        arrs = ev.evaluate([held_out_task(a, t, budget) for t in tables], f"held out {a.name}")
        runs[a.name] = dict(zip(LEVELS, arrs, strict=True))
        entries[a.name] = verdicts.arm_entry(a, rec, tables[1], runs[a.name], main)
        best_tables[a.name], by_name[a.name] = rec["table"], a
    x, y = (f"{c}@{POSE}" for c in SWAP)
    swapped = ev.evaluate([held_out_task(by_name[x], swap_table(best_tables[x], best_tables[y]),
                                         budget),
                           held_out_task(by_name[y], swap_table(best_tables[y], best_tables[x]),
                                         budget)], "settings swap")  # fmt: skip
    out = verdicts.assemble(entries, runs, [f"{c}@{POSE}" for c in ARMS],
                            f"{PAPER_ARM[0]}@{PAPER_ARM[1]}", f"{PAPER_ARM[0]}@{POSE}", main,
                            _columns(budget, apart=True),
                            [p for p in budget.plants if p in APART])  # fmt: skip
    out["swap"] = verdicts.swap(x, y, runs[x]["tuned"], runs[y]["tuned"], *swapped, main)
    out["budget"] = {"per_setting": budget.per_setting, "restarts": budget.restarts,
                     "train_seeds": list(budget.train_seeds),
                     "test_seeds": list(budget.test_seeds),
                     "train_duration": budget.train_duration,
                     "training": list(training), "duration": budget.duration,
                     "optimiser": "CMA-ES (cma) through analysis.tuning.tune_arm, default "
                                  "population, restart 0 from the defaults"}  # fmt: skip
    out["held_out"] = {"scenarios": list(prior.SCENARIOS),
                       "plants": [p for p in budget.plants if p not in APART],
                       "cells": [f"{s}@{p}" for s, p in cells(budget) if p not in APART],
                       "levels": list(LEVELS),
                       "pairings": [f"{a} / {b}" for a, b in verdicts.PAIRINGS],
                       "metric": "position RMSE after the transient [m]",
                       "tracking_m": rstats.TRACKING_M,
                       "tracking_reason": rstats.TRACKING_REASON}  # fmt: skip
    return out
