"""The calibration study's stages, each run through the engine (``_calibration_store``).

1. :func:`screening`: Morris elementary effects of every setting of the prior on the
   discrepancy, each controller's (log) position RMSE per scenario and the ranking margins;
   settings whose ``mu*`` stays below ``screen_fraction`` of the largest for every output are
   fixed at the suite's default.
2. :func:`design`: a scrambled Sobol design over the settings kept (``A`` and ``B`` of
   ``methods.sobol_design``, stacked), each point over the level's seeds (common random
   numbers): the 36 numbers per point, the tolerance, the feasible set, the range each number
   spans.
3. :func:`sensitivity`: Sobol indices (first and total, bootstrap intervals) of the outputs of
   :data:`OUTPUTS` from ``A``, ``B`` and ``A_B^(i)`` on the first ``2**saltelli_m`` rows, at
   ``N`` and ``N/2`` (convergence); P(the paper's order) over the design at its halves.
4. :func:`fit`: ``scipy.optimize.differential_evolution`` of the rms log ratio from several
   starts (the first from the best design points), seeds as common random numbers; the best
   re-evaluated over more seeds for the residual profile.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis import _calibration_methods as methods
from analysis import _calibration_prior as prior
from analysis._calibration_fair import Budget
from analysis._calibration_store import Task, task_key
from wmr.sweep import Factor

__all__ = ["Level", "FULL", "QUICK", "Space", "OUTPUTS", "numbers", "run_outputs", "screening",
           "design", "sensitivity", "fit", "MORRIS_SEED", "DESIGN_SEED"]  # fmt: skip

MORRIS_SEED = 0
DESIGN_SEED = 0
#: Outputs of the sensitivity analysis, per run: each controller's log position RMSE (mean over
#: the three scenarios), the ranking margins (log RMSE of X minus IAPID's: > 0 = IAPID better),
#: the rms log ratio to the paper and the mean Kendall tau against the paper's 9 orders.
OUTPUTS = tuple([f"log_rmse:{c}" for c in prior.CONTROLLERS]
                + [f"margin:{c}" for c in prior.CONTROLLERS[1:]]
                + ["rms_log_ratio", "kendall_tau"])  # fmt: skip
#: Screening outputs: OUTPUTS and the log position RMSE of each (scenario, controller).
SCREEN_OUTPUTS = OUTPUTS + tuple(f"log_rmse:{s}/{c}" for s in prior.SCENARIOS
                                 for c in prior.CONTROLLERS)  # fmt: skip


@dataclass(frozen=True)
class Level:
    """How much of the study to run (``FULL``, or ``QUICK`` for tests)."""

    name: str
    seeds: tuple[int, ...]
    morris_r: int
    design_m: int  # A and B: 2**design_m rows each (the design: twice that)
    saltelli_m: int  # A_B^(i) on the first 2**saltelli_m rows
    fit_popsize: int  # DE population = fit_popsize x settings kept
    fit_maxiter: int
    fit_starts: int
    fit_seeds: tuple[int, ...]
    fair: Budget
    factors: Mapping[str, Factor] = field(default_factory=dict)  # prior overrides
    base: Mapping[str, object] = field(default_factory=dict)  # default overrides
    screen_fraction: float = 0.1


FULL = Level("full", (0, 1), morris_r=20, design_m=11, saltelli_m=7, fit_popsize=2,
             fit_maxiter=8, fit_starts=3, fit_seeds=tuple(range(10)),
             fair=Budget(population=24, generations=15, seeds=(0, 1),
                         test_seeds=tuple(range(100, 110)), front_points=6))  # fmt: skip
QUICK = Level("quick", (0,), morris_r=2, design_m=3, saltelli_m=2, fit_popsize=1, fit_maxiter=1,
              fit_starts=2, fit_seeds=(0, 1),
              fair=Budget(population=6, generations=1, seeds=(0,), test_seeds=(100,),
                          front_points=2, duration=21.0),
              factors={"duration": Factor("duration", levels=(21.0,)),
                       "dt": Factor("dt", levels=(0.05,))},
              base={"duration": 21.0, "dt": 0.05}, screen_fraction=0.3)  # fmt: skip


@dataclass(frozen=True)
class Space:
    """The settings varied (``names``, unit coordinates in that order) and the values of the
    others (``base``)."""

    names: tuple[str, ...]
    base: Mapping[str, object]
    factors: Mapping[str, Factor]

    @classmethod
    def of(cls, level: Level, names: Sequence[str], fixed: Mapping | None = None) -> Space:
        base = {**prior.defaults(), **level.base, **(fixed or {})}
        factors = {s.name: level.factors.get(s.name, s.factor) for s in prior.PRIOR}
        return cls(tuple(names), base, factors)

    def values(self, u) -> dict:
        out = dict(self.base)
        for name, x in zip(self.names, u, strict=True):
            out[name] = self.factors[name].value(min(max(float(x), 0.0), 1.0 - 1e-12))
        return out

    def task(self, u, seeds: Sequence[int]) -> Task:
        v = self.values(u)
        return Task(task_key({"tables": v, "seeds": list(seeds)}), tuple(prior.cases(v)),
                    tuple(seeds))  # fmt: skip


def numbers(arr: np.ndarray) -> np.ndarray:
    """The 36 numbers of each seed's runs, shape (n_seeds, 36); diverged = ``DIVERGED_RMSE``."""
    x = arr[:, :, :3]
    return np.where(np.isfinite(x), x, prior.DIVERGED_RMSE).reshape(arr.shape[0], 36)


def diverged(arr: np.ndarray) -> np.ndarray:
    """Whether each of the 36 numbers of each seed's runs diverged, shape (n_seeds, 36)."""
    return ~np.isfinite(arr[:, :, :3]).reshape(arr.shape[0], 36)


def _within(mean, sd_eff, div, n_seeds: int, z: float) -> np.ndarray:
    """A number is matched when the paper's value lies within its tolerance of our mean and
    none of its seeds diverged (a diverged seed would widen the band to anything)."""
    return (np.abs(mean - prior.PAPER) <= prior.tolerance(sd_eff, n_seeds, z)) & ~div


def _log_position(arr: np.ndarray) -> np.ndarray:
    p = arr[:, :, 3]
    return np.log(np.where(np.isfinite(p), p, prior.DIVERGED_RMSE)).reshape(-1, 3, 4)


def run_outputs(arr: np.ndarray, screen: bool = False) -> np.ndarray:
    """Per seed, the values of :data:`OUTPUTS` (or :data:`SCREEN_OUTPUTS`), shape (n_seeds, s)."""
    lp = _log_position(arr)
    per = lp.mean(axis=1)
    nums = numbers(arr)
    tau = _tau(nums)
    cols = [per, per[:, 1:] - per[:, :1], prior.discrepancy(nums)["rms_log_ratio"][:, None],
            tau[:, None]]  # fmt: skip
    if screen:
        cols.append(lp.reshape(-1, 12))
    return np.column_stack(cols)


def _tau(nums: np.ndarray) -> np.ndarray:
    """Mean Kendall tau over the 9 (scenario, axis) orders against the paper's, per seed."""
    x = nums.reshape(-1, 3, 4, 3)
    pp = prior.PAPER.reshape(3, 4, 3)
    taus = [methods.kendall_tau(x[:, s, :, a], pp[s, :, a])
            for s, a in itertools.product(range(3), range(3))]  # fmt: skip
    return np.mean(taus, axis=0)


# ---------------------------------------------------------------------------------------------
# 1. Screening


def screening(ev, level: Level) -> dict:
    """Morris screening of the whole prior (one seed, the level's first); the settings kept."""
    names = prior.NAMES
    k = len(names)
    u, order, up, delta = methods.morris_design(k, level.morris_r, 4, seed=MORRIS_SEED)
    space = Space.of(level, names)
    res = ev.evaluate([space.task(x, level.seeds[:1]) for x in u.reshape(-1, k)], "screening")
    y = np.stack([run_outputs(a, screen=True)[0] for a in res]).reshape(level.morris_r, k + 1, -1)
    eff = methods.morris_effects(y, order, up, delta)
    top = eff["mu_star"].max(axis=0)
    rel = np.where(top > 0, eff["mu_star"] / np.where(top > 0, top, 1.0), 0.0)
    importance = rel.max(axis=1)
    active = [n for n, imp in zip(names, importance, strict=True) if imp >= level.screen_fraction]
    fixed = {n: space.base[n] for n in names if n not in active}
    return {"method": "Morris elementary effects (Campolongo et al. 2007 mu*)",
            "trajectories": level.morris_r, "grid_levels": 4, "delta": delta,
            "seed": int(level.seeds[0]), "points": int(u.shape[0] * u.shape[1]),
            "outputs": list(SCREEN_OUTPUTS), "threshold": level.screen_fraction,
            "rule": "kept when mu* >= threshold x the largest mu* of some output",
            "importance": {n: float(x) for n, x in zip(names, importance, strict=True)},
            "mu_star": {o: {n: float(eff["mu_star"][i, j]) for i, n in enumerate(names)}
                        for j, o in enumerate(SCREEN_OUTPUTS)},
            "sigma": {o: {n: float(eff["sigma"][i, j]) for i, n in enumerate(names)}
                      for j, o in enumerate(SCREEN_OUTPUTS)},
            "active": active, "fixed_at": fixed}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# 2. The design: feasibility and coverage


def _feasibility(nums: np.ndarray, div: np.ndarray) -> dict:
    """Per point: mean, tolerance, within (joint 95 %: :data:`prior.Z_JOINT`; and per number
    at :data:`prior.Z_SEED`); the pooled seed spread (see the record).  ``div``: (p, s, 36)."""
    n_p, n_s, _ = nums.shape
    mean = nums.mean(axis=1)
    sd = nums.std(axis=1, ddof=1) if n_s > 1 else np.zeros_like(mean)
    any_div = div.any(axis=1)
    ok = ~any_div  # the pooled spread from points where the number never diverged
    if n_s > 1 and ok.any():
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a number diverged everywhere
            cv = np.nan_to_num(np.nanmedian(np.where(ok, sd / mean, np.nan), axis=0))
    else:
        cv = np.zeros(36)
    sd_eff = np.maximum(sd, cv * mean)
    return {"mean": mean, "sd": sd_eff, "tol": prior.tolerance(sd_eff, n_s),
            "within": _within(mean, sd_eff, any_div, n_s, prior.Z_JOINT),
            "within_per_number": _within(mean, sd_eff, any_div, n_s, prior.Z_SEED),
            "any_diverged": any_div, "cv": cv}


def design(ev, level: Level, space: Space) -> dict:
    """Run the Sobol design over ``space``; return its arrays (``u``, ``nums``, ``status``,
    ``A``, ``B``, the feasibility arrays) for the later stages and the record."""
    d = len(space.names)
    A, B = methods.sobol_design(d, level.design_m, seed=DESIGN_SEED)
    U = np.vstack([A, B])
    res = ev.evaluate([space.task(x, level.seeds) for x in U], "design")
    nums = np.stack([numbers(a) for a in res])
    status = np.stack([a[..., -1] for a in res])
    feas = _feasibility(nums, np.stack([diverged(a) for a in res]))
    disc = prior.discrepancy(feas["mean"])
    return {"u": U, "A": A, "B": B, "results": res, "nums": nums, "status": status, **feas,
            **disc}  # fmt: skip


def coverage(des: dict) -> dict:
    """Per number: the range its mean spans over the design (points where none of its seeds
    diverged) against the paper's value, and at how many points it is matched."""
    mean, within = des["mean"], des["within"]
    out = {}
    for i, name in enumerate(prior.NUMBER_NAMES):
        m = mean[~des["any_diverged"][:, i], i]
        m = m if m.size else np.array([np.nan])
        q = np.quantile(m, [0.05, 0.5, 0.95])
        out[name] = {"paper": float(prior.PAPER[i]), "min": float(m.min()),
                     "max": float(m.max()), "q05": float(q[0]), "median": float(q[1]),
                     "q95": float(q[2]), "spanned": bool(m.min() <= prior.PAPER[i] <= m.max()),
                     "n_reached": int(within[:, i].sum()),
                     "n_reached_per_number": int(des["within_per_number"][:, i].sum()),
                     "n_diverged": int(des["any_diverged"][:, i].sum())}  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# 3. Sensitivity and the ranking's robustness


def _indices_json(ix: dict, names, outputs, keep) -> dict:
    out = {}
    for j, o in enumerate(outputs):
        if not keep[j]:
            out[o] = None
            continue
        out[o] = {n: {k: float(ix[k][j, i]) for k in ix} for i, n in enumerate(names)}
    return out


def _agree(a: dict, b: dict) -> tuple[int, int]:
    """How many intervals of ``a`` overlap those of ``b`` (first and total), of how many."""
    hit = tot = 0
    for o, fa in a.items():
        if fa is None or b.get(o) is None:
            continue
        for n, x in fa.items():
            y = b[o][n]
            for k in ("first", "total"):
                tot += 1
                hit += x[f"{k}_low"] <= y[f"{k}_high"] and y[f"{k}_low"] <= x[f"{k}_high"]
    return hit, tot


def sensitivity(ev, level: Level, space: Space, des: dict) -> dict:
    """Sobol indices of :data:`OUTPUTS` at ``N = 2**saltelli_m`` and ``N/2`` (seed: the level's
    first), and their agreement."""
    d = len(space.names)
    n = 2**level.saltelli_m
    AB = methods.ab_matrices(des["A"][:n], des["B"][:n])
    res = ev.evaluate([space.task(x, level.seeds[:1]) for x in AB.reshape(-1, d)], "sobol")
    f_ab = np.stack([run_outputs(a)[0] for a in res]).reshape(d, n, -1).transpose(0, 2, 1)
    res_all = des["results"]
    half = len(des["A"])
    f_a = np.stack([run_outputs(res_all[i])[0] for i in range(n)]).T
    f_b = np.stack([run_outputs(res_all[half + i])[0] for i in range(n)]).T
    keep = np.var(np.concatenate([f_a, f_b], axis=1), axis=1) > 0
    out = {"method": "Sobol indices: first order Saltelli et al. (2010), total Jansen (1999), "
                     "the estimators of scipy.stats.sobol_indices; 95 % percentile bootstrap "
                     f"({methods.BOOTSTRAP} resamples of the rows, seeded)",
           "outputs": list(OUTPUTS), "factors": list(space.names), "seed": int(level.seeds[0]),
           "runs": int((d + 2) * n * 12)}  # fmt: skip
    h = n // 2
    parts = {"N": slice(0, n), "N/2": slice(0, h), "first half": slice(0, h),
             "second half": slice(h, n)}  # fmt: skip
    for label, sl in parts.items():
        ix = methods.sobol_indices(f_a[:, sl], f_b[:, sl], f_ab[..., sl])
        varies = keep & (np.var(np.concatenate([f_a[:, sl], f_b[:, sl]], axis=1), axis=1) > 0)
        out[label] = {"n": sl.stop - sl.start,
                      "indices": _indices_json(ix, space.names, OUTPUTS, varies)}  # fmt: skip
    hit, tot = _agree(out["N"]["indices"], out["N/2"]["indices"])
    out["convergence"] = {"intervals_overlapping": hit, "intervals": tot,
                          "fraction": hit / tot if tot else None,
                          "note": "N/2 is nested in N: overlap is expected; the independent "
                                  "halves below are the test"}  # fmt: skip
    hit, tot = _agree(out["first half"]["indices"], out["second half"]["indices"])
    widths = [x[f"{k}_high"] - x[f"{k}_low"] for fa in out["N"]["indices"].values() if fa
              for x in fa.values() for k in ("first", "total")]  # fmt: skip
    out["independent_halves"] = {"intervals_overlapping": hit, "intervals": tot,
                                 "fraction": hit / tot if tot else None,
                                 "median_interval_width_at_N": float(np.median(widths))
                                 if widths else None}  # fmt: skip
    del out["first half"]["indices"], out["second half"]["indices"]  # the agreement is kept
    return out


def ranking(des: dict, level: Level) -> dict:
    """P(the paper's order) and friends over the design (points x seeds), at the whole design
    and at its first half (``A``), with their agreement."""
    full = methods.order_stats(des["nums"], prior.PAPER, prior.CONTROLLERS, prior.SCENARIOS,
                               prior.AXES)  # fmt: skip
    half = methods.order_stats(des["nums"][: len(des["A"])], prior.PAPER, prior.CONTROLLERS,
                               prior.SCENARIOS, prior.AXES)  # fmt: skip

    def probs(rec):
        yield "all_nine", rec["all_nine"]
        yield "iapid_first_all", rec["iapid_first_all"]
        yield "iapid_first_any", rec["iapid_first_any"]
        yield from rec["per_table"].items()
        yield from rec["pairwise"].items()

    other = methods.order_stats(des["nums"][len(des["A"]):], prior.PAPER, prior.CONTROLLERS,
                                prior.SCENARIOS, prior.AXES)  # fmt: skip

    def agree(x, y):
        a, b = dict(probs(x)), dict(probs(y))
        ok = [a[k]["ci_low"] <= b[k]["ci_high"] and b[k]["ci_low"] <= a[k]["ci_high"] for k in a]
        return {"agreeing": int(sum(ok)), "compared": len(ok)}

    return {**full, "half": half, "convergence": {**agree(full, half),
                                                  "note": "A is nested in the design"},
            "independent_halves": agree(half, other)}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# 4. The closest fit


def _objective_cache(ev, space: Space, seeds):
    seen: dict[tuple, float] = {}

    def mapper(func, xs):
        xs = [tuple(float(v) for v in x) for x in xs]
        for x, arr in zip(xs, ev.evaluate([space.task(x, seeds) for x in xs], "fit"),
                          strict=True):  # fmt: skip
            seen[x] = float(prior.discrepancy(numbers(arr).mean(axis=0))["rms_log_ratio"])
        return [func(np.array(x)) for x in xs]

    return seen, mapper


def fit(ev, level: Level, space: Space, des: dict) -> dict:
    """Minimise the rms log ratio (seed mean over the level's seeds) by differential evolution
    from ``fit_starts`` starts; re-evaluate the best over ``fit_seeds``."""
    from scipy.optimize import differential_evolution

    d = len(space.names)
    pop = max(5, level.fit_popsize * d)
    best_design = np.argsort(des["rms_log_ratio"], kind="stable")
    starts = []
    for s in range(level.fit_starts):
        seen, mapper = _objective_cache(ev, space, level.seeds)
        init = des["u"][best_design[:pop]] if s == 0 else "latinhypercube"
        res = differential_evolution(lambda x, seen=seen: seen[tuple(float(v) for v in x)],
                                     [(0.0, 1.0)] * d, popsize=max(1, pop // d), init=init,
                                     maxiter=level.fit_maxiter, seed=s, polish=False,
                                     updating="deferred", workers=mapper)  # fmt: skip
        starts.append({"start": s, "init": "best design points" if s == 0 else
                       "latin hypercube", "rms_log_ratio": float(res.fun), "nfev": int(res.nfev),
                       "u": [float(x) for x in res.x],
                       "settings": _jsonable(space.values(res.x))})  # fmt: skip
    best = min(starts, key=lambda r: r["rms_log_ratio"])
    arr = ev.evaluate([space.task(best["u"], level.fit_seeds)], "best fit")[0]
    nums, div = numbers(arr), diverged(arr).any(axis=0)
    mean, sd = nums.mean(axis=0), nums.std(axis=0, ddof=1) if len(nums) > 1 else np.zeros(36)
    sd_eff = np.maximum(sd, des["cv"] * mean)
    tol = prior.tolerance(sd_eff, len(nums))
    lr = prior.log_ratios(mean)
    within = _within(mean, sd_eff, div, len(nums), prior.Z_JOINT)
    within_1 = _within(mean, sd_eff, div, len(nums), prior.Z_SEED)
    residuals = {name: {"paper": float(prior.PAPER[i]), "mean": float(mean[i]),
                        "sd": float(sd[i]), "log_ratio": float(lr[i]),
                        "ratio": float(np.exp(lr[i])), "tolerance": float(tol[i]),
                        "within": bool(within[i]), "within_per_number": bool(within_1[i]),
                        "diverged_seeds": int(diverged(arr)[:, i].sum())}
                 for i, name in enumerate(prior.NUMBER_NAMES)}  # fmt: skip
    return {"settings": best["settings"], "u": best["u"], "varied": list(space.names),
            "rms_log_ratio": float(np.sqrt(np.mean(lr**2))),
            "max_abs_log_ratio": float(np.max(np.abs(lr))),
            "rms_log_ratio_at_design_seeds": best["rms_log_ratio"],
            "best_design_rms_log_ratio": float(des["rms_log_ratio"][best_design[0]]),
            "seeds": list(level.fit_seeds), "n_within": int(within.sum()),
            "n_within_per_number": int(within_1.sum()),
            "feasible": bool(within.all()), "residuals": residuals,
            "per_seed": nums.tolist(), "n_diverged": int(np.sum(arr[..., -1] != 0)),
            "starts": starts, "population": pop, "generations": level.fit_maxiter,
            "optimiser": "scipy.optimize.differential_evolution (deferred updating, no polish), "
                         "seeds as common random numbers"}  # fmt: skip


def _jsonable(v: Mapping) -> dict:
    return {k: (x.item() if hasattr(x, "item") else x) for k, x in v.items()}


def finite(x) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None
