"""A search that can find the truth (issue 23 item 2): history-matching waves on a Gaussian-process
emulator, and their recovery of planted truths.

**The emulator** (:class:`Emulator`).  One Gaussian process per number (scikit-learn's
``GaussianProcessRegressor``: a constant times an anisotropic RBF kernel plus white noise,
``normalize_y``) of the seed mean of its log RMSE over the unit cube of the settings varied,
trained on the design points where none of that number's runs diverged.  A training target is
a mean over the design's seeds, so its seed noise (one run's seed variance over their number,
:func:`seed_variance`) is the process's known noise (``alpha``), left out of the predictive
variance (the target of a prediction is the simulator's mean, not another noisy mean; the
implausibility adds the target run's own seed variance); the White kernel is the nugget, the
roughness beyond that noise, and stays in.  The kernel's
hyperparameters are fitted once, on the space-filling design (wave 0); later waves condition
on their new points with those hyperparameters (``optimizer=None``).  Each process's
variance is multiplied by its mean squared standardised leave-one-out error on the design
(:func:`loo_ratio`, at least 1), so that an overconfident process is widened by what the
design itself shows; the planted truths then validate it independently.  A point where a
number's runs diverged is left out of that number's emulator, so a diverging region is
emulated by extrapolation: it is never ruled out for diverging (conservative).

**Validation** (:func:`validate`): the planted truths' runs at the rule's ``K`` seeds (settings
uniform over the prior, never in the design) give each number's mean at ``K`` seeds; the
standardised prediction errors ``(m - E) / sqrt(V + s^2 / K)`` (``s^2`` the seed variance
pooled over the same runs, :func:`seed_variance`) should be about standard normal: the record
gives the share within ±3 and within ±2 (Bastos & O'Hagan 2009's individual standardised
errors) and calls the emulator valid when at least 95 % lie within ±3 *and* its wave-0
implausibility keeps at least 90 % of the planted truths (the maximum over 36 numbers is the
decision, and every number's tail enters it).

**Implausibility** of a point ``x`` for a target ``z`` (the paper's tables or a planted
truth's rounded numbers): ``I_i(x) = |log z_i - E_i(x)| / sqrt(V_i(x) + s_i^2 + (h_i / z_i)^2 /
3 + log(1 + delta)^2)``: the emulator's variance, one run's seed variance (the target is one
run), the printed rounding and the discrepancy of the rule (``analysis.calibration.rule``);
``x`` is not ruled out when ``max_i I_i <= c``, ``c`` the normal Sidak quantile of the rule
(3.19 for 36 numbers at 95 %).

**Waves** (:func:`history_match`): the retained region is estimated on a fixed uniform Monte
Carlo sample of the cube (its share is the retained volume); each wave draws ``per_wave``
points at random from the retained sample, runs them at the design's seeds (through the
store), conditions the emulators on them and cuts the retained sample again (a point once
ruled out stays out: the waves' regions are nested).

**Planted recovery** (:func:`recovery`): for each planted truth the waves run with its numbers
as the target; recovered when the truth's own setting is not ruled out by any wave's
emulators (nested, as the region is); the record gives the recovery rate (Clopper-Pearson)
and the retained volumes.
Wave 0 (the design's emulators alone) is judged for every planted truth at no extra runs; the
later waves for the first ``recovery_truths`` of them.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.calibration import prior, rule, stages
from analysis.calibration.fit import _values as fit_values

__all__ = ["Waves", "Emulator", "validate", "history_match", "recovery", "study", "MC_SEED",
           "VALID_WITHIN_3", "RECOVER", "DIVERGED_TARGET"]

#: An emulator is called valid when at least this share of its standardised errors at the
#: planted truths lies within +-3 (Pukelsheim 1994: >= 95 % for any unimodal distribution).
VALID_WITHIN_3 = 0.95

#: ... and when its wave-0 implausibility keeps at least this share of the planted truths (the
#: maximum over 36 numbers compounds every number's tail: the decision is what is validated).
RECOVER = 0.9

#: The generator of the Monte Carlo sample (and of the waves' draws: ``[MC_SEED, wave, tag]``).
MC_SEED = 29


@dataclass(frozen=True)
class Waves:
    """``waves`` waves after the design of ``per_wave`` points each; the retained volume on
    ``mc`` uniform points; the later waves for the first ``recovery_truths`` planted truths;
    the kernel fitted with ``restarts`` optimiser restarts (0: once, from length scales 0.5),
    the 36 processes over ``jobs`` processes, on the design's first ``train_points`` points
    (None: all; a Sobol design's leading points are themselves space-filling, and an exact GP
    costs O(N^3), its gradient O(N^2 d): 128 s at 256 points)."""

    waves: int
    per_wave: int
    mc: int
    recovery_truths: int
    restarts: int = 0
    jobs: int = 2
    train_points: int | None = None


def _log_means(nums: np.ndarray, diverged: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seed means of log RMSE per point and number (points, 36), and whether they are finite
    (no seed diverged)."""
    y = np.log(np.maximum(nums, 1e-12)).mean(axis=1)
    return y, ~diverged.any(axis=1)


class Emulator:
    """The 36 Gaussian processes (see the module): :meth:`fit` on the design, :meth:`condition`
    on more points with the fitted kernels, :meth:`predict` means and variances."""

    def __init__(self, restarts: int = 0, seed: int = 0, jobs: int = 1):
        self.restarts, self.seed, self.jobs = restarts, seed, jobs
        self.gps: list = []
        self.inflate = np.ones(36)
        self.noise = np.zeros(36)
        self.X = self.Y = self.ok = None

    def _gp(self, y: np.ndarray, i: int, kernel=None, optimizer="fmin_l_bfgs_b"):
        """Number ``i``'s process for targets ``y``: its training noise ``noise[i]`` as the
        known diagonal ``alpha`` (in ``normalize_y``'s units, ``y``'s variance), so that the
        predictive variance leaves it out; the White kernel is the nugget, which stays in."""
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

        if kernel is None:
            d = self.X.shape[1]
            kernel = (ConstantKernel(1.0, (1e-3, 1e3)) * RBF(np.full(d, 0.5), (1e-2, 1e2))
                      + WhiteKernel(0.1, (1e-6, 1e1)))  # fmt: skip
        var = float(np.var(y)) if y.size > 1 else 1.0
        alpha = max(float(self.noise[i]) / var, 1e-10) if var > 0 else 1e-10
        return GaussianProcessRegressor(kernel, alpha=alpha, normalize_y=True,
                                        optimizer=optimizer, n_restarts_optimizer=self.restarts,
                                        random_state=self.seed)  # fmt: skip

    def fit(self, X: np.ndarray, Y: np.ndarray, ok: np.ndarray,
            noise: np.ndarray | None = None) -> Emulator:  # fmt: skip
        """Fit each number's process (kernel hyperparameters too) on the rows where ``ok``,
        ``noise`` (36,) the variance of a training target's seed mean (None: 0), the numbers
        spread over ``jobs`` processes (each process's fit is seeded: the same emulator
        whatever ``jobs``)."""
        from joblib import Parallel, delayed

        self.X, self.Y, self.ok = np.asarray(X), np.asarray(Y), np.asarray(ok)
        self.noise = np.zeros(self.Y.shape[1]) if noise is None else np.asarray(noise, float)
        cols = [self.ok[:, i] for i in range(self.Y.shape[1])]
        self.gps = Parallel(n_jobs=self.jobs)(
            delayed(_fit_one)(self._gp(self.Y[m, i], i), self.X[m], self.Y[m, i])
            for i, m in enumerate(cols))  # fmt: skip
        self.inflate = np.array([max(1.0, loo_ratio(g)) for g in self.gps])
        return self

    def condition(self, X: np.ndarray, Y: np.ndarray, ok: np.ndarray) -> Emulator:
        """A new emulator on these rows and the old ones, with the fitted kernels."""
        out = Emulator(self.restarts, self.seed, self.jobs)
        out.inflate, out.noise = self.inflate, self.noise
        out.X, out.Y = np.vstack([self.X, X]), np.vstack([self.Y, Y])
        out.ok = np.vstack([self.ok, ok])
        out.gps = []
        for i, g in enumerate(self.gps):
            m = out.ok[:, i]
            out.gps.append(out._gp(out.Y[m, i], i, g.kernel_, optimizer=None)
                           .fit(out.X[m], out.Y[m, i]))  # fmt: skip
        return out

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Means and variances (n, 36) of the seed-mean log RMSE at ``X`` (n, d)."""
        mean, var = [], []
        for g in self.gps:
            m, s = g.predict(np.atleast_2d(X), return_std=True)
            mean.append(m)
            var.append(s**2)
        return np.column_stack(mean), np.column_stack(var) * self.inflate

    def kernels(self) -> list[str]:
        return [str(g.kernel_) for g in self.gps]


def _fit_one(gp, X: np.ndarray, y: np.ndarray):
    """One process fitted (its optimiser's warnings of length scales at their bounds kept
    quiet: an inert setting's length scale at the upper bound is the expected answer)."""
    from sklearn.exceptions import ConvergenceWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return gp.fit(X, y)


def loo_ratio(gp) -> float:
    """The mean squared standardised leave-one-out error of a fitted process (its kernel
    fixed; Rasmussen & Williams 2006 eq. 5.12: residual ``[K^-1 y]_i / [K^-1]_ii``, variance
    ``1 / [K^-1]_ii``): about 1 when its variances are right, above 1 when overconfident."""
    from scipy.linalg import cho_solve

    kinv = cho_solve((gp.L_, True), np.eye(gp.L_.shape[0]))
    alpha = gp.alpha_.ravel()
    return float(np.mean(alpha**2 / np.diag(kinv)))


def seed_variance(nums: np.ndarray, diverged: np.ndarray) -> np.ndarray:
    """One run's seed variance of each number's log RMSE, pooled over the points where none of
    its seeds diverged (within-point variance, ``ddof = 1``), shape (36,): in the study, the
    planted truths' ``K`` rule seeds (settings uniform over the prior)."""
    y = np.log(np.maximum(nums, 1e-12))
    ok = ~diverged.any(axis=1)
    v = y.var(axis=1, ddof=1)
    return np.array([v[ok[:, i], i].mean() if ok[:, i].any() else 0.0 for i in range(36)])


def implausibility(mean, var, z, v_seed, delta: float = rule.DELTA) -> np.ndarray:
    """Max over the 36 numbers of the emulator implausibility (see the module) for target
    ``z`` (36,), at points with emulator ``mean``, ``var`` (n, 36): shape (n,).  A number
    whose target diverged (a planted truth's run past the bound, ``prior.DIVERGED_RMSE``) is
    not judged: the emulator of finite runs cannot match it (:data:`DIVERGED_TARGET`)."""
    z = np.asarray(z, dtype=float)
    v = var + v_seed + (prior.ROUNDING / z) ** 2 / 3.0 + np.log1p(delta) ** 2
    i = np.abs(np.log(z) - mean) / np.sqrt(v)
    return np.max(np.where(z < prior.DIVERGED_RMSE, i, 0.0), axis=1)


#: How a diverged target number enters the emulator's implausibility.
DIVERGED_TARGET = ("a number whose target run diverged is not judged by the emulator (it "
                   "models finite runs only): conservative, it never rules a point out")


def validate(em: Emulator, u: np.ndarray, nums: np.ndarray, diverged: np.ndarray,
             v_seed: np.ndarray) -> dict:  # fmt: skip
    """Standardised errors of the emulator at ``u`` (points, d) against the seed means of
    ``nums`` (points, K, 36) (see the module)."""
    y, ok = _log_means(nums, diverged)
    mean, var = em.predict(u)
    k = nums.shape[1]
    e = (y - mean) / np.sqrt(var + v_seed / k)
    e = e[ok]
    per = [float(np.mean(np.abs(((y - mean) / np.sqrt(var + v_seed / k))[ok[:, i], i]) <= 3))
           if ok[:, i].any() else None for i in range(36)]  # fmt: skip
    return {"points": int(u.shape[0]), "seeds": int(k), "values": int(e.size),
            "within_2": float(np.mean(np.abs(e) <= 2)), "within_3": float(np.mean(np.abs(e) <= 3)),
            "rmse_standardised": float(np.sqrt(np.mean(e**2))),
            "per_number_within_3": dict(zip(prior.NUMBER_NAMES, per, strict=True)),
            "errors": [round(float(x), 4) for x in e],
            "errors_valid": bool(np.mean(np.abs(e) <= 3) >= VALID_WITHIN_3),
            "form": "(m - E) / sqrt(V + s^2 / K) at the planted truths' K rule seeds; about "
                    "N(0, 1) for a valid emulator (95 % within 2, 99.7 % within 3)"}  # fmt: skip


def _run(ev, space, U: np.ndarray, seeds: Sequence[int], desc: str):
    res = ev.evaluate([space.task(x, tuple(seeds)) for x in U], desc)
    nums = np.stack([stages.numbers(a) for a in res])
    div = np.stack([stages.diverged(a) for a in res])
    return nums, div


def history_match(ev, space, em0: Emulator, v_seed, z, mc: np.ndarray, cfg: Waves,
                  seeds: Sequence[int], tag: int, waves: int | None = None,
                  truth: np.ndarray | None = None) -> dict:  # fmt: skip
    """The waves for target ``z`` from the design's emulator ``em0``: the retained share of
    ``mc`` after each wave, the new points run, and (``truth``: a planted setting) whether
    it is retained after each wave.  ``tag`` names the target in the draws' generator."""
    c = rule.threshold(len(seeds))  # the normal Sidak quantile (the rule's c)
    em = em0
    keep = implausibility(*em.predict(mc), z, v_seed) <= c
    kept = None if truth is None else bool(implausibility(*em.predict(truth[None]), z,
                                                          v_seed)[0] <= c)  # fmt: skip
    out = {"retained": [float(keep.mean())], "runs": [0],
           "truth_retained": [] if truth is None else [kept]}
    for w in range(1, (cfg.waves if waves is None else waves) + 1):
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            break
        rng = np.random.default_rng([MC_SEED, w, tag])
        pick = rng.choice(idx, size=min(cfg.per_wave, idx.size), replace=False)
        nums, div = _run(ev, space, mc[pick], seeds, f"wave {w}")
        y, ok = _log_means(nums, div)
        em = em.condition(mc[pick], y, ok)
        idx = np.flatnonzero(keep)  # a point once ruled out stays out: predict the rest only
        keep[idx] = implausibility(*em.predict(mc[idx]), z, v_seed) <= c
        out["retained"].append(float(keep.mean()))
        out["runs"].append(int(pick.size * len(seeds) * 12))
        if truth is not None:  # nested as the region is: once ruled out, the truth stays out
            kept = kept and bool(implausibility(*em.predict(truth[None]), z, v_seed)[0] <= c)
            out["truth_retained"].append(kept)
    out["retained_points"] = int(keep.sum())
    if keep.any():
        imp = implausibility(*em.predict(mc[keep]), z, v_seed)
        out["least_implausible_u"] = mc[keep][int(np.argmin(imp))].tolist()
        out["least_implausibility"] = float(imp.min())
    return out


def recovery(ev, space, em0: Emulator, v_seed, targets: Sequence[np.ndarray],
             truths: np.ndarray, mc: np.ndarray, cfg: Waves,
             seeds: Sequence[int]) -> dict:  # fmt: skip
    """The planted truths' recovery (see the module): wave 0 for every truth, the waves for
    the first ``cfg.recovery_truths``."""
    c = rule.threshold(len(seeds))
    mean_t, var_t = em0.predict(truths)
    mean_mc, var_mc = em0.predict(mc)
    w0_in, w0_vol = [], []
    for t, z in enumerate(targets):
        w0_in.append(bool(implausibility(mean_t[t:t + 1], var_t[t:t + 1], z, v_seed)[0] <= c))
        w0_vol.append(float(np.mean(implausibility(mean_mc, var_mc, z, v_seed) <= c)))
    seq = [history_match(ev, space, em0, v_seed, targets[t], mc, cfg, seeds, tag=1 + t,
                         truth=truths[t]) for t in range(min(cfg.recovery_truths, len(truths)))]
    last_in = [s["truth_retained"][-1] for s in seq]
    last_vol = [s["retained"][-1] for s in seq]
    small = [v <= 0.05 for v in last_vol]
    return {"wave0": {"recovered": rule.proportion(sum(w0_in), len(w0_in)),
                      "retained_volume_median": float(np.median(w0_vol)),
                      "retained_volume_q90": float(np.quantile(w0_vol, 0.9)),
                      "retained_volume": w0_vol, "truth_retained": w0_in},
            "waves": {"truths": len(seq), "recovered": rule.proportion(sum(last_in), len(seq)),
                      "retained_volume_median": float(np.median(last_vol)) if seq else None,
                      "volume_at_most_5pc": rule.proportion(sum(small), len(seq)),
                      "recovered_and_small": rule.proportion(
                          sum(a and b for a, b in zip(last_in, small, strict=True)), len(seq)),
                      "per_truth": seq},
            "criterion": "the retained region holds the planted setting for >= 90 % of truths "
                         "while keeping <= 5 % of the prior's volume"}  # fmt: skip


def study(ev, level, space, des: dict, truths_u: Sequence, cfg: Waves) -> dict:
    """The record's ``sequential``: the emulator (fitted on the design, validated on the planted
    truths' rule runs), the waves for the paper's tables, and the planted recovery."""
    seeds = tuple(level.seeds)
    truths = np.asarray(truths_u, dtype=float).reshape(len(truths_u), len(space.names))
    y, ok = _log_means(des["nums"], stages_diverged(des))
    X = des["u"]
    if cfg.train_points is not None:
        X, y, ok = X[: cfg.train_points], y[: cfg.train_points], ok[: cfg.train_points]
    t_nums, t_div = _run(ev, space, truths, level.rule_seeds, "planted truths")
    v_seed = seed_variance(t_nums, t_div)  # K seeds at each of the truths, uniform on the prior
    t0 = time.perf_counter()
    em0 = Emulator(cfg.restarts, jobs=cfg.jobs).fit(X, y, ok, v_seed / len(seeds))
    fit_s = round(time.perf_counter() - t0, 1)
    val = validate(em0, truths, t_nums, t_div, v_seed)
    targets = []
    for t, u in enumerate(truths):  # each truth's "paper": one run, rounded as printed
        n1, _ = _run(ev, space, u[None], (rule.TRUTH_SEED0 + t,), "planted truths")
        targets.append(rule.printed_round(n1[0, 0]))
    mc = np.random.default_rng(MC_SEED).random((cfg.mc, len(space.names)))
    paper = history_match(ev, space, em0, v_seed, prior.PAPER, mc, cfg, seeds, tag=0)
    if "least_implausible_u" in paper:
        paper["least_implausible"] = {n: v for n, v in
                                      fit_values(space, paper["least_implausible_u"]).items()
                                      if n in space.names}  # fmt: skip
        # the emulator's least implausible point run and judged by the rule itself
        (arr,) = ev.evaluate([space.task(np.asarray(paper["least_implausible_u"]),
                                         tuple(level.verdict_seeds))], "least implausible point")
        j = rule.judge(rule.rmse_numbers(arr), len(level.verdict_seeds))["by_delta"]
        paper["least_direct"] = {"seeds": list(level.verdict_seeds),
                                 "max_implausibility": j[f"{rule.DELTA:g}"]["max_implausibility"],
                                 "not_ruled_out": j[f"{rule.DELTA:g}"]["not_ruled_out"]}
    rec = recovery(ev, space, em0, v_seed, targets, truths, mc, cfg, seeds)
    val["recovers_wave0"] = rec["wave0"]["recovered"]["p"] >= RECOVER
    val["valid"] = val["errors_valid"] and val["recovers_wave0"]
    val["criterion"] = (f"valid when >= {100 * VALID_WITHIN_3:.0f} % of the errors lie within "
                        "+-3 (Pukelsheim's 3-sigma rule) and its implausibility at wave 0 keeps "
                        f">= {100 * RECOVER:.0f} % of the planted truths (the 36-number "
                        "maximum is what decides)")
    return {"emulator": {"form": "scikit-learn GaussianProcessRegressor per number: C * RBF "
                                 "(anisotropic) + White (the nugget), normalize_y, the training "
                                 "targets' seed noise (s^2 / the design's seeds) as its known "
                                 "alpha, outside the predictive variance; hyperparameters "
                                 "fitted on the design, then fixed",
                         "trained_on": int(X.shape[0]),
                         "fit_seconds": fit_s, "inflate": em0.inflate.round(3).tolist(),
                         "validation": val},
            "seed_variance": v_seed.tolist(), "threshold": rule.threshold(len(seeds)),
            "delta": rule.DELTA, "diverged_target": DIVERGED_TARGET, "mc_points": cfg.mc,
            "waves": cfg.waves, "per_wave": cfg.per_wave, "seeds": list(seeds), "paper": paper,
            "recovery": rec}


def stages_diverged(des: dict) -> np.ndarray:
    """Whether each seed's number diverged at each design point (points, seeds, 36)."""
    return np.stack([stages.diverged(a) for a in des["results"]])

