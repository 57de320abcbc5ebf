"""The calibration study's stages, each run through the engine (``_calibration_store``).

1. :func:`screening`: Morris elementary effects of every setting of the prior on the
   discrepancy, each controller's (log) position RMSE per scenario and the ranking margins;
   settings whose ``mu*`` stays below ``screen_fraction`` of the largest for every output are
   fixed at the suite's default.
2. :func:`design`: a scrambled Sobol design over the settings kept (``A`` and ``B`` of
   ``methods.sobol_design``, stacked), each point over the level's seeds (common random
   numbers): the 36 numbers per point, their discrepancy, the range each number spans.
3. :func:`sensitivity`: PAWN indices (``_calibration_pawn``) of :data:`OUTPUTS` and of the
   share of diverged runs on the design's own points; :func:`ranking`: P(the paper's order)
   over the design with exact intervals.
4. The rule, its planted truths and the verdict (``_calibration_rule``), the fit
   (``_calibration_fit``): ``analysis.calibration.compute`` calls them.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.calibration import fit as fitmod
from analysis.calibration import methods, prior
from analysis.calibration.fair import Budget
from analysis.calibration.store import Task, task_key
from analysis.calibration.waves import Waves
from wmr.engine.sweep import Factor

__all__ = ["Level", "FULL", "MEDIUM", "QUICK", "LEVELS", "Space", "OUTPUTS", "numbers",
           "run_outputs", "screening", "design", "coverage", "sensitivity", "ranking",
           "MORRIS_SEED", "DESIGN_SEED", "TIMED"]  # fmt: skip

MORRIS_SEED = 0
DESIGN_SEED = 0
#: Outputs of the sensitivity analysis, per run: each controller's log position RMSE (mean over
#: the three scenarios), the ranking margins (log RMSE of X minus IAPID's: > 0 = IAPID better),
#: the rms log ratio to the paper and the mean Kendall tau against the paper's 9 orders.
OUTPUTS = tuple([f"log_rmse:{c}" for c in prior.CONTROLLERS]
                + [f"margin:{c}" for c in prior.CONTROLLERS[1:]]
                + ["rms_log_ratio", "kendall_tau"])  # fmt: skip
#: The outputs with a clear worse end (larger is worse: a law's log RMSE, the rms log ratio):
#: the ones the sensitivity also analyses on every point, a left-out point ranked worst.
WORSE_END = tuple(o for o in OUTPUTS if o.startswith("log_rmse:") or o == "rms_log_ratio")
#: Screening outputs: OUTPUTS and the log position RMSE of each (scenario, controller).
SCREEN_OUTPUTS = OUTPUTS + tuple(f"log_rmse:{s}/{c}" for s in prior.SCENARIOS
                                 for c in prior.CONTROLLERS)  # fmt: skip


@dataclass(frozen=True)
class Level:
    """How much of the study to run (``QUICK`` for tests, ``MEDIUM`` the committed record and
    what ``make calibration`` runs (about 105 minutes on 2 workers), ``FULL`` a larger study for a
    machine with more cores: see :data:`TIMED`)."""

    name: str
    seeds: tuple[int, ...]  # the design's seeds (common random numbers; the fit's objective)
    morris_r: int
    design_m: int  # A and B: 2**design_m rows each (the design: twice that)
    rule_seeds: tuple[int, ...]  # K seeds of every candidate the rule judges
    n_truths: int  # planted truths (coverage and power)
    verdict_top: int  # design points judged by the rule (the closest by rms log ratio)
    cma_restarts: int
    cma_popsize: int
    cma_maxfevals: int  # per restart
    fair: Budget
    factors: Mapping[str, Factor] = field(default_factory=dict)  # prior overrides
    base: Mapping[str, object] = field(default_factory=dict)  # default overrides
    screen_fraction: float = 0.1
    pawn_resamples: int = 100
    #: the seeds at which the verdict judges its candidates (K of them, like ``rule_seeds``):
    #: disjoint from ``seeds``, on which the candidates were selected (the design's ranking and
    #: the fit's objective), so their judgement is not the selection's own noise
    verdict_seeds: tuple[int, ...] = ()
    #: the sequential design (history-matching waves) and its planted recovery
    waves: Waves = Waves(waves=1, per_wave=3, mc=500, recovery_truths=2)

    def __post_init__(self):
        if len(self.verdict_seeds) != len(self.rule_seeds):
            raise ValueError(f"level {self.name}: {len(self.verdict_seeds)} verdict seeds, "
                             f"{len(self.rule_seeds)} rule seeds (the rule's K must be one)")
        if set(self.verdict_seeds) & set(self.seeds):
            raise ValueError(f"level {self.name}: verdict seeds {self.verdict_seeds} share "
                             f"seeds with the selection's {self.seeds}")


#: The fair tuning of the medium and full levels: the regime study's full-level budget and
#: training (so the two studies share one tuning), ten held-out seeds.
_FAIR = Budget(per_setting=30, train_seeds=(100, 101), test_seeds=tuple(range(200, 210)))
#: A larger study than the 90-minute budget allows on 2 workers of this machine (~2x slower per
#: step than the one the earlier records came from; :data:`TIMED`): 2 x 1,024 design points
#: (N >= 1,024 for the sensitivity indices), 5 CMA-ES restarts of popsize 12 and 1,000
#: evaluations, 30 recovery truths, the emulator on the design's first 512 points.
FULL = Level("full", (0, 1), morris_r=20, design_m=10, rule_seeds=tuple(range(10)),
             n_truths=100, verdict_top=20, cma_restarts=5, cma_popsize=12, cma_maxfevals=1000,
             fair=_FAIR,
             verdict_seeds=tuple(range(2, 12)),
             waves=Waves(waves=2, per_wave=32, mc=10_000, recovery_truths=30,
                         train_points=512))  # fmt: skip
MEDIUM = Level("medium", (0, 1), morris_r=8, design_m=7, rule_seeds=tuple(range(10)),
               n_truths=100, verdict_top=5, cma_restarts=5, cma_popsize=8, cma_maxfevals=1000,
               fair=_FAIR,
               verdict_seeds=tuple(range(2, 12)),
               waves=Waves(waves=2, per_wave=24, mc=4000, recovery_truths=20))  # fmt: skip
QUICK = Level("quick", (0,), morris_r=2, design_m=3, rule_seeds=(0, 1, 2), n_truths=3,
              verdict_top=2, cma_restarts=2, cma_popsize=4, cma_maxfevals=4,
              fair=Budget(per_setting=1, train_seeds=(100,), test_seeds=(200,),
                          train_duration=3.0, training=1, duration=21.0,
                          plants=("slip", "mujoco")),
              factors={"duration": Factor("duration", levels=(21.0,)),
                       "dt": Factor("dt", levels=(0.05,))},
              base={"duration": 21.0, "dt": 0.05}, screen_fraction=0.3,
              pawn_resamples=10, verdict_seeds=(1, 2, 3))  # fmt: skip
LEVELS = {lv.name: lv for lv in (QUICK, MEDIUM, FULL)}
#: Measured wall times from an empty store (`python -m analysis.calibration --level L
#: --workers 2`, a 2-core machine, 2026-12-07; the log of the full level's stages is summarised
#: here).  MEDIUM is what ``make calibration`` runs.
TIMED = {
    "medium": "about 6,300 s from an empty store on 2 workers (274,716 runs). 4,860 s were "
              "measured from an empty store and tuning cache before the 100 fresh planted "
              "truths, whose 49,200 runs added 851 s and the 24,000 of their longer distances "
              "(0.4, 0.5) 616 s: over the 90-minute budget by ~15 min here",
    "full": "screening and design 15 min, planted truths 15 min, the emulator, its waves and "
            "30 recovery truths 27 min. The fit then took ~9 s per generation of 12 points: its "
            "5 x 84 generations ~63 min: over 2 h in all before the verdict and the fair "
            "tuning (stopped in the fit's first restart; never completed)",
}


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


def _log_position(arr: np.ndarray) -> np.ndarray:
    p = arr[:, :, 3]
    return np.log(np.where(np.isfinite(p), p, prior.DIVERGED_RMSE)).reshape(-1, 3, 4)


def run_outputs(arr: np.ndarray, screen: bool = False) -> np.ndarray:
    """Per seed, the values of :data:`OUTPUTS` (or :data:`SCREEN_OUTPUTS`), shape (n_seeds, s);
    a diverged run enters as ``prior.DIVERGED_RMSE``.  Only the screening uses these values as
    they are: there a setting that drives runs out of bounds must not look inert, and the
    placeholder gives it a large effect.  The sensitivity indices use :func:`tracked_outputs`."""
    lp = _log_position(arr)
    per = lp.mean(axis=1)
    nums = numbers(arr)
    tau = _tau(nums)
    cols = [per, per[:, 1:] - per[:, :1], prior.discrepancy(nums)["rms_log_ratio"][:, None],
            tau[:, None]]  # fmt: skip
    if screen:
        cols.append(lp.reshape(-1, 12))
    return np.column_stack(cols)


def tracked_outputs(arr: np.ndarray) -> np.ndarray:
    """:func:`run_outputs` with NaN wherever a diverged run enters a value (divergence is its
    own output, ``diverged_share``, never a number averaged into the others; DESIGN §7): a
    controller's mean log RMSE needs its three runs, a margin its own and IAPID-NN-DEKF's, the rms
    log ratio and the Kendall tau all 12 runs."""
    y = run_outputs(arr)
    dpos = ~np.isfinite(arr[:, :, :4]).all(axis=2).reshape(-1, 3, 4)  # (seed, scenario, law)
    dc = dpos.any(axis=1)
    every = dc.any(axis=1, keepdims=True)
    mask = np.column_stack([dc, dc[:, 1:] | dc[:, :1], every, every])
    return np.where(mask, np.nan, y)


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


def _summary(nums: np.ndarray, div: np.ndarray) -> dict:
    """Per point: the seed mean of the 36 numbers, NaN where a seed diverged (the placeholder
    is never averaged in), and whether any seed diverged (p, 36)."""
    anyd = div.any(axis=1)
    return {"mean": np.where(anyd, np.nan, nums.mean(axis=1)), "any_diverged": anyd}


def design(ev, level: Level, space: Space) -> dict:
    """Run the Sobol design over ``space``; return its arrays (``u``, ``nums``, ``status``,
    ``A``, ``B``, the seed means, the discrepancy) for the later stages and the record."""
    d = len(space.names)
    A, B = methods.sobol_design(d, level.design_m, seed=DESIGN_SEED)
    U = np.vstack([A, B])
    res = ev.evaluate([space.task(x, level.seeds) for x in U], "design")
    nums = np.stack([numbers(a) for a in res])
    status = np.stack([a[..., -1] for a in res])
    feas = _summary(nums, np.stack([diverged(a) for a in res]))
    # a point with a diverged run has no discrepancy (NaN; its runs are in ``n_diverged``)
    tracked = ~feas["any_diverged"].any(axis=1)
    disc = {k: np.where(tracked, v, np.nan)
            for k, v in prior.discrepancy(feas["mean"]).items()}  # fmt: skip
    obj = np.array([fitmod.objective(x) for x in nums])  # the fit's: selects its candidates
    return {"u": U, "A": A, "B": B, "results": res, "nums": nums, "status": status, **feas,
            **disc, "objective": obj}  # fmt: skip


def coverage(des: dict) -> dict:
    """Per number: the range its seed mean spans over the design (points where none of its
    seeds diverged) against the paper's value (descriptive: a number outside the range is
    not reached by this design, which does not rule the region out)."""
    mean = des["mean"]
    out = {}
    for i, name in enumerate(prior.NUMBER_NAMES):
        m = mean[~des["any_diverged"][:, i], i]
        m = m if m.size else np.array([np.nan])
        q = np.quantile(m, [0.05, 0.5, 0.95])
        out[name] = {"paper": float(prior.PAPER[i]), "min": float(m.min()),
                     "max": float(m.max()), "q05": float(q[0]), "median": float(q[1]),
                     "q95": float(q[2]), "spanned": bool(m.min() <= prior.PAPER[i] <= m.max()),
                     "n_diverged": int(des["any_diverged"][:, i].sum())}  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# 3. Sensitivity and the ranking's robustness


def sensitivity(level: Level, space: Space, des: dict) -> dict:
    """PAWN indices (``_calibration_pawn``) of :data:`OUTPUTS` (seed means per design point,
    each on the points where no run it needs diverged: :func:`tracked_outputs`) and of the
    share of diverged runs (every point), on the design's own points (no extra runs)."""
    from analysis.calibration import pawn

    Y = np.stack([tracked_outputs(a).mean(axis=0) for a in des["results"]])
    div = np.mean(des["status"] != 0, axis=(1, 2))
    outputs = [*OUTPUTS, "diverged_share"]
    ix = pawn.pawn(des["u"], np.column_stack([Y, div]), list(space.names), outputs,
                   seed=DESIGN_SEED, resamples=level.pawn_resamples)  # fmt: skip
    # beside it, every point, a point the tracked analysis leaves out placed past the worst
    # tracked value (censored: PAWN reads only ranks, so this ranks it worst), for the outputs
    # whose worse end is clear (a law's log RMSE, the rms log ratio: larger is worse)
    worse = [OUTPUTS.index(o) for o in WORSE_END]
    Yc = Y[:, worse].copy()
    for j in range(Yc.shape[1]):
        gone = ~np.isfinite(Yc[:, j])
        Yc[gone, j] = np.nanmax(Yc[:, j]) + 1.0 if (~gone).any() else 0.0
    cen = pawn.pawn(des["u"], Yc, list(space.names), list(WORSE_END), seed=DESIGN_SEED,
                    resamples=level.pawn_resamples)  # fmt: skip
    return {"method": "PAWN (Pianosi & Wagener 2015; SALib.analyze.pawn's slicing, "
                      f"{pawn.SLICES} slices, median KS), a dummy setting as the floor, "
                      f"{level.pawn_resamples} bootstrap resamples of the design's rows "
                      "(95 % percentile); settings whose intervals overlap are tied; each "
                      "tracking output on the points where none of the runs it needs "
                      "diverged (its n), the diverged share on every point",
            "n": int(len(des["u"])), "outputs": outputs, "factors": list(space.names),
            "indices": ix,
            "every_point": {"note": "a law's log RMSE and the rms log ratio on every point, a "
                                    "point with a diverged run it needs placed past the worst "
                                    "tracked value (+1 on the log scale: ranked worst); the "
                                    "margins and the tau have no worse end and are left out",
                            "outputs": cen}}  # fmt: skip


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
