"""Fair tuning (issue 15, step 6): every controller's free gains tuned with the same optimiser
and the same budget on training trajectories, then evaluated on held-out ones.

- **Training**: three trajectories that are not the paper's (a smaller, faster lemniscate, a
  circle, a perturbed sinusoid of other geometry and another disturbance), each with an initial
  pose error, the suite's defaults otherwise (dt 0.01 s, 40 s, pose noise 0.01).
- **Held out**: the paper's three scenarios as shipped, on seeds the tuning never saw.
- **Free gains**: the PID's six initial gains for APID and IAPID-NN-DEKF (each tuned on its
  own), the three backstepping gains for BSC and for DA-NN's base law.  Nothing else moves:
  mu, the filters, the network sizes stay at the suite's defaults.
- **Optimiser**: ``scipy.optimize.differential_evolution`` in unit coordinates (log-uniform
  ranges), population :attr:`Budget.population` for every controller (``popsize`` = population /
  dimension), ``tol = atol = 0`` so every controller gets exactly the same number of
  evaluations; seeded; the population evaluated through the engine.
- **Objective**: the mean over trajectories and axes of ``log RMSE`` (the tables' per-axis
  numbers, scale-free), each the mean over the training seeds; a diverged run counts as 10.
- **Pareto fronts**: the tuning's evaluations as (mean position RMSE, mean control effort);
  the non-dominated ones, and up to :attr:`Budget.front_points` of them re-evaluated held out.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from analysis.calibration import prior
from analysis.calibration.store import METRICS, Task, task_key
from wmr import controllers
from wmr import scenario as scn

__all__ = ["Budget", "TRAINING", "FREE_GAINS", "gains_at", "training_scenarios",
           "pareto_front", "tune", "fair_tuning"]  # fmt: skip

#: The training trajectories (TOML text of each; the suite's defaults otherwise).
TRAINING = {
    "train-lemniscate": ('kind = "lemniscate"\nsize = 1.5\nperiod = 30.0\n', [0.0, -0.5, 1.2],
                         None),
    "train-circle": ('kind = "circle"\nradius = 1.5\nperiod = 30.0\n', [1.5, -0.3, 1.2], None),
    "train-sinusoid-perturbed": ('kind = "sinusoid"\nspeed = 0.4\namplitude = 0.7\n'
                                 'omega = 0.7\n', [0.0, 0.2, 0.0], (0.15, -0.2)),
}  # fmt: skip
#: Free gains per controller: (name, low, high, log) in the order of the settings' ``gains``.
_PID = (("Kpv", 0.5, 50.0, True), ("Kiv", 0.05, 50.0, True), ("Kdv", 0.0, 0.45, False),
        ("Kpw", 0.5, 50.0, True), ("Kiw", 0.05, 50.0, True), ("Kdw", 0.0, 0.45, False))
_BSC = (("k1", 0.25, 25.0, True), ("k2", 1.0, 100.0, True), ("k3", 0.5, 30.0, True))
FREE_GAINS = {"iapid-nn-dekf": _PID, "backstepping": _BSC, "adaptive-nn": _BSC,
              "adaptive-pid": _PID}  # fmt: skip


@dataclass(frozen=True)
class Budget:
    """The tuning budget, the same for every controller: ``population x (generations + 1)``
    evaluations, each over ``seeds`` on the training trajectories."""

    population: int
    generations: int
    seeds: tuple[int, ...]
    test_seeds: tuple[int, ...]
    front_points: int
    duration: float = 40.0

    @property
    def evaluations(self) -> int:
        return self.population * (self.generations + 1)


def gains_at(controller: str, u) -> tuple[float, ...]:
    """The gains at unit coordinates ``u`` (one per free gain)."""
    out = []
    for (_, lo, hi, log), x in zip(FREE_GAINS[controller], u, strict=True):
        x = min(max(float(x), 0.0), 1.0)
        out.append(lo * (hi / lo) ** x if log else lo + x * (hi - lo))
    return tuple(out)


def _settings(controller: str, gains):
    """The suite's default settings of ``controller`` with ``gains``."""
    return controllers.get(controller).Settings(gains=tuple(gains))


def training_scenarios(duration: float = 40.0) -> list[scn.Scenario]:
    """The training trajectories as validated scenarios."""
    out = []
    for name, (ref, pose, dist) in TRAINING.items():
        text = (f'name = "{name}"\nduration = {duration}\ndt = 0.01\ninitial_pose = {pose}\n'
                f"[reference]\n{ref}[noise]\npose_std = [0.01, 0.01, 0.01]\n")
        if dist:
            text += (f"[[disturbance]]\nstart = 15.0\nstop = 20.0\nvelocity = [{dist[0]}, "
                     f"{dist[1]}]\n")
        out.append(scn.loads(text, f"<{name}>"))
    return out


def held_out_scenarios(duration: float = 40.0) -> list[scn.Scenario]:
    """The paper's three scenarios as shipped (``duration`` other than their 40 s: cut, for the
    quick level)."""
    out = [scn.load(scn.builtin(n)) for n in prior.SCENARIOS]
    return [sc if sc.duration == duration else dataclasses.replace(sc, duration=duration)
            for sc in out]


def _task(controller, gains, scenarios, seeds, tag) -> Task:
    key = task_key({"fair": tag, "controller": controller, "gains": list(gains),
                    "scenarios": [s.name for s in scenarios],
                    "duration": scenarios[0].duration, "seeds": list(seeds)})  # fmt: skip
    st = _settings(controller, gains)
    return Task(key, tuple((sc, controller, st) for sc in scenarios), tuple(seeds))


def _score(arr: np.ndarray) -> dict:
    """Objective and its parts from a task result ``(n_seeds, n_scenarios, metrics + 1)``."""
    x = np.where(np.isfinite(arr[..., :3]), arr[..., :3], prior.DIVERGED_RMSE)
    pos = np.where(np.isfinite(arr[..., 3]), arr[..., 3], prior.DIVERGED_RMSE)
    eff = arr[..., METRICS.index("effort")]
    return {"objective": float(np.mean(np.log(x.mean(axis=0)))),
            "position": float(pos.mean()),
            "position_per_scenario": [float(p) for p in pos.mean(axis=0)],
            "axes_per_scenario": x.mean(axis=0).tolist(),
            "effort": float(np.nanmean(eff)) if np.any(np.isfinite(eff)) else None,
            "diverged": int(np.sum(arr[..., -1] != 0))}  # fmt: skip


def pareto_front(cost: np.ndarray, effort: np.ndarray) -> np.ndarray:
    """Indices of the points not dominated in (cost, effort), both minimised, by cost."""
    idx = np.argsort(cost, kind="stable")
    front, best = [], math.inf
    for i in idx:
        if np.isfinite(effort[i]) and effort[i] < best:
            front.append(int(i))
            best = effort[i]
    return np.array(front, dtype=int)


def tune(ev, controller: str, budget: Budget, seed: int = 0) -> dict:
    """Tune ``controller``'s free gains on the training trajectories (see the module)."""
    from scipy.optimize import differential_evolution

    train = training_scenarios(budget.duration)
    dim = len(FREE_GAINS[controller])
    seen: dict[tuple, dict] = {}

    def mapper(func, xs):
        xs = [tuple(float(v) for v in x) for x in xs]
        tasks = [_task(controller, gains_at(controller, x), train, budget.seeds, "train")
                 for x in xs]  # fmt: skip
        for x, arr in zip(xs, ev.evaluate(tasks, f"fair tuning {controller}"), strict=True):
            seen.setdefault(x, _score(arr))
        return [func(np.array(x)) for x in xs]

    res = differential_evolution(lambda x: seen[tuple(float(v) for v in x)]["objective"],
                                 [(0.0, 1.0)] * dim, popsize=budget.population // dim,
                                 maxiter=budget.generations, tol=0.0, atol=0.0, seed=seed,
                                 polish=False, init="latinhypercube", updating="deferred",
                                 workers=mapper)  # fmt: skip
    xs = list(seen)
    cost = np.array([seen[x]["position"] for x in xs])
    effort = np.array([np.nan if seen[x]["effort"] is None else seen[x]["effort"] for x in xs])
    front = pareto_front(cost, effort)
    return {"x": [float(v) for v in res.x], "objective": float(res.fun), "nfev": int(res.nfev),
            "evaluations": len(xs), "gains": list(gains_at(controller, res.x)),
            "gain_names": [g[0] for g in FREE_GAINS[controller]],
            "front": [{"gains": list(gains_at(controller, xs[i])), "u": list(xs[i]),
                       "position": float(cost[i]), "effort": float(effort[i])}
                      for i in front]}  # fmt: skip


def _held_out(ev, controller, gains_list, budget: Budget) -> list[dict]:
    test = held_out_scenarios(budget.duration)
    tasks = [_task(controller, g, test, budget.test_seeds, "test") for g in gains_list]
    out = []
    for arr in ev.evaluate(tasks, f"held out {controller}"):
        rec = _score(arr)
        pos = np.where(np.isfinite(arr[..., 3]), arr[..., 3], prior.DIVERGED_RMSE)
        rec["position_per_seed"] = pos.mean(axis=1).tolist()  # mean over scenarios, per seed
        out.append(rec)
    return out


def fair_tuning(ev, budget: Budget) -> dict:
    """Tune every paper controller with ``budget``, evaluate held out; the record's
    ``fair_tuning``."""
    out = {"budget": {"population": budget.population, "generations": budget.generations,
                      "evaluations": budget.evaluations, "seeds": list(budget.seeds),
                      "test_seeds": list(budget.test_seeds), "optimiser":
                      "scipy.optimize.differential_evolution (tol = atol = 0, seed 0, "
                      "latin-hypercube init, no polish)"},
           "training": list(TRAINING), "held_out": list(prior.SCENARIOS),
           "free_gains": {c: [{"name": n, "low": lo, "high": hi, "scale": "log" if lg else
                               "linear"} for n, lo, hi, lg in g]
                          for c, g in FREE_GAINS.items()},
           "objective": "mean over trajectories and axes of log RMSE (seed mean first)",
           "controllers": {}}  # fmt: skip
    for c in prior.CONTROLLERS:
        t = tune(ev, c, budget)
        picks = t["front"]
        if len(picks) > budget.front_points:
            sel = np.unique(np.linspace(0, len(picks) - 1, budget.front_points).round().astype(int))
            picks = [picks[i] for i in sel]
        held = _held_out(ev, c, [t["gains"]] + [p["gains"] for p in picks], budget)
        t["held_out"] = held[0]
        t["front_held_out"] = [{**p, "held_out_position": h["position"],
                                "held_out_effort": h["effort"]}
                               for p, h in zip(picks, held[1:], strict=True)]  # fmt: skip
        default = _held_out(ev, c, [tuple(controllers.get(c).Settings().gains)], budget)[0]
        t["default_held_out"] = default
        out["controllers"][c] = t
    scores = {c: out["controllers"][c]["held_out"]["objective"] for c in prior.CONTROLLERS}
    out["ranking_held_out"] = sorted(scores, key=scores.get)
    pos = {c: out["controllers"][c]["held_out"]["position"] for c in prior.CONTROLLERS}
    out["ranking_held_out_position"] = sorted(pos, key=pos.get)
    best = out["ranking_held_out"][0]
    per_seed = {c: np.array(out["controllers"][c]["held_out"]["position_per_seed"])
                for c in prior.CONTROLLERS}  # fmt: skip
    out["wins_of_best"] = {c: int(np.sum(per_seed[best] < per_seed[c]))
                           for c in prior.CONTROLLERS if c != best}  # fmt: skip
    return out
