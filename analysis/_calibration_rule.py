"""The calibration's decision rule, its planted-truth coverage and power, and exact intervals
(issue 23, items 1 and 5).

**The rule** (history matching's implausibility: Craig, Goldstein, Seheult & Smith 1997;
Vernon, Goldstein & Bower 2010, eq. 6).  For a candidate setting ``x`` run at ``K`` seeds the
rule never shares with "the paper", each of the 36 numbers ``z_i`` (one run, rounded as
printed) is compared on the log scale (RMSEs are positive and right-skewed) with the predictive
distribution of one run at ``x``::

    I_i(x) = |log z_i - m_i(x)| / sqrt(s_i(x)^2 (1 + 1/K) + V_round,i + V_md)

``m_i``, ``s_i``: the mean and standard deviation of ``log`` RMSE over the ``K`` seeds
(a diverged run counts as ``prior.DIVERGED_RMSE``); ``s^2 (1 + 1/K)`` is the variance of one
new run about a ``K``-seed mean; ``V_round,i = (h_i / z_i)^2 / 3`` the printed rounding (half a
unit ``h_i`` in the last printed place, uniform, on the log scale); ``V_md = log(1 + delta)^2``
the model discrepancy (the paper's code is not ours: ``delta`` a relative discrepancy, a
judgement stated with the record; ``delta = 0`` for planted truths, which the suite itself
made).  ``x`` is *not ruled out* when ``max_i I_i(x) <= c``, ``c`` the Sidak quantile of
Student's t with ``K - 1`` degrees of freedom: each number at ``0.95**(1/36)``, so for Gaussian
log RMSE the truth passes all 36 at once with probability >= 95 % (the 36 are positively
correlated: conservative).

**Coverage and power** (:func:`planted`): settings drawn uniformly from the prior (unit cube of
the settings varied), their 36 numbers made by the suite as the paper's were (one run at a seed
of :data:`TRUTH_SEED0` + t, rounded to the printed digits); the rule at the truth (coverage) and
at points at unit-cube distances :data:`DISTANCES` in random directions (power: the share
ruled out).

**Exact intervals** (:func:`clopper_pearson`): every proportion of the study; a zero count's
interval is ``[0, upper]``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

from analysis import _calibration_prior as prior

__all__ = ["LEVEL", "DISTANCES", "TRUTH_SEED0", "PLANT_SEED", "DELTAS", "DELTA",
           "threshold", "implausibility", "CAP", "capped", "printed_round", "clopper_pearson",
           "proportion", "planted", "judge"]  # fmt: skip

#: The rule's nominal joint level over the 36 numbers.
LEVEL = 0.95
#: Distances in the unit cube of the varied settings at which the power is measured.
DISTANCES = (0.1, 0.2, 0.3)
#: Planted truths' "paper" runs use seeds TRUTH_SEED0 + t (never a rule seed: those are < 1000).
TRUTH_SEED0 = 100_000
#: The generator of the planted settings and directions.
PLANT_SEED = 23
#: The model discrepancy (relative) of the verdict, and the values it is also shown at.
DELTA = 0.1
DELTAS = (0.0, 0.05, 0.1, 0.25)
DELTA_SOURCE = (
    "history matching's model discrepancy (Vernon et al. 2010 §3.2; Craig et al. 1997): a "
    "variance for what the simulator does not share with the system -- here the paper's "
    "unpublished code against ours (its integrator, noise generator, filter details).  No "
    "measurement fixes it: delta = 0.1 (10 % of each number, log(1.1)^2 on the log scale) is a "
    "judgement of the size of such implementation differences; the verdict is also shown at "
    "0, 0.05 and 0.25.  Planted truths come from the suite itself: their coverage is measured "
    "at delta = 0 (the rule at delta > 0 is wider, so covers at least as often)")


@functools.lru_cache(maxsize=256)
def threshold(k: int, level: float = LEVEL, n: int = 36) -> float:
    """``c``: the two-sided Student-t (``k - 1`` d.o.f.) quantile at the Sidak per-number level
    ``level**(1/n)``."""
    per = level ** (1.0 / n)
    return float(stats.t.ppf(0.5 + 0.5 * per, k - 1))


def printed_round(values: np.ndarray) -> np.ndarray:
    """``values`` (..., 36) rounded to the decimals the paper prints each number with (and not
    below half a unit, so that its log exists)."""
    dec = np.round(-np.log10(2.0 * prior.ROUNDING)).astype(int)
    out = np.array([np.round(v, d) for v, d in zip(np.moveaxis(np.asarray(values), -1, 0), dec,
                                                   strict=True)])  # fmt: skip
    return np.maximum(np.moveaxis(out, 0, -1), prior.ROUNDING)


def implausibility(nums: np.ndarray, z: np.ndarray, delta: float = 0.0) -> np.ndarray:
    """``I_i`` of the module's formula: ``nums`` (K, 36) the candidate's runs [m, rad]
    (diverged = ``DIVERGED_RMSE``), ``z`` (36,) the target's printed numbers; shape (36,).

    A diverged run is no RMSE: ``m_i`` and ``s_i`` are over the seeds where number ``i`` did
    not diverge (``n_i`` of them), and ``I_i`` is scaled by ``c(K) / c(n_i)`` so that one
    threshold ``c(K)`` applies (:func:`threshold`); fewer than 3 such seeds rule the number
    out (``inf``).  A diverged target (a planted truth's run) is matched (``I_i = 0``) when
    some of the candidate's seeds diverged too, else ruled out."""
    x = np.asarray(nums, dtype=float)
    z = np.asarray(z, dtype=float)
    k = x.shape[0]
    fin = x < prior.DIVERGED_RMSE
    n = fin.sum(axis=0)
    y = np.where(fin, np.log(np.maximum(x, 1e-12)), np.nan)
    out = np.full(x.shape[1], np.inf)
    ok = (n >= 3) & (z < prior.DIVERGED_RMSE)
    if ok.any():
        m = np.nanmean(y[:, ok], axis=0)
        s = np.nanstd(y[:, ok], axis=0, ddof=1)
        nk = n[ok]
        var = (s**2 * (1.0 + 1.0 / nk) + (prior.ROUNDING[ok] / z[ok]) ** 2 / 3.0
               + math.log1p(delta) ** 2)  # fmt: skip
        scale = threshold(k) / np.array([threshold(int(j)) for j in nk])
        out[ok] = np.abs(np.log(z[ok]) - m) / np.sqrt(np.maximum(var, 1e-300)) * scale
    div_t = z >= prior.DIVERGED_RMSE
    out[div_t] = np.where(n[div_t] < k, 0.0, np.inf)
    return out


#: How an infinite implausibility (a number ruled out by divergence) is written in the record.
CAP = 1e6


def capped(i: np.ndarray) -> np.ndarray:
    """Implausibilities with ``inf`` written as :data:`CAP` (JSON has no infinity)."""
    return np.minimum(np.asarray(i, dtype=float), CAP)


def clopper_pearson(k: float, n: float, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a proportion ``k / n``; ``[0, upper]`` for
    ``k = 0``.  A non-integer ``k`` (an effective count, Korn & Graubard 1998) is allowed."""
    if n <= 0:
        return 0.0, 1.0
    a = 1.0 - level
    lo = 0.0 if k <= 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k >= n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def proportion(k: float, n: float, level: float = 0.95) -> dict:
    """``{"k", "n", "p", "ci_low", "ci_high", "method"}`` (Clopper-Pearson)."""
    lo, hi = clopper_pearson(k, n, level)
    return {"k": float(k), "n": float(n), "p": float(k / n) if n else None, "ci_low": lo,
            "ci_high": hi, "method": "Clopper-Pearson (exact), 95 %"}  # fmt: skip


def _away(rng, u: np.ndarray, d: float) -> tuple[np.ndarray, float]:
    """A point at distance ``d`` from ``u`` in a random direction, reflected into the cube;
    its actual distance (reflection can shorten it)."""
    w = rng.standard_normal(len(u))
    v = u + d * w / np.linalg.norm(w)
    v = np.abs(v)
    v = np.where(v > 1.0, 2.0 - v, v)
    v = np.clip(v, 0.0, 1.0 - 1e-12)
    return v, float(np.linalg.norm(v - u))


def _nums(arr: np.ndarray) -> np.ndarray:
    x = arr[:, :, :3]
    return np.where(np.isfinite(x), x, prior.DIVERGED_RMSE).reshape(arr.shape[0], 36)


def planted(ev, space, n_truths: int, rule_seeds: Sequence[int],
            distances: Sequence[float] = DISTANCES, seed: int = PLANT_SEED) -> dict:
    """The rule's coverage and power on ``n_truths`` planted truths in ``space``
    (``_calibration_stages.Space``), the rule's runs at ``rule_seeds``."""
    rng = np.random.default_rng(seed)
    d = len(space.names)
    truths = rng.random((n_truths, d))
    away = [[_away(rng, u, r) for r in distances] for u in truths]
    tasks = []
    for t, u in enumerate(truths):
        tasks.append(space.task(u, (TRUTH_SEED0 + t,)))
        tasks.append(space.task(u, tuple(rule_seeds)))
        tasks += [space.task(v, tuple(rule_seeds)) for v, _ in away[t]]
    res = ev.evaluate(tasks, "planted truths")
    per = 2 + len(distances)
    c = threshold(len(rule_seeds))
    at = {dl: _planted_at(res, per, n_truths, distances, away, c, dl) for dl in DELTAS}
    head = at[DELTA]  # the verdict's discrepancy: the rule as it is applied
    return {"n_truths": n_truths, "rule_seeds": list(rule_seeds), "threshold": c,
            "truth_seeds": [TRUTH_SEED0, TRUTH_SEED0 + n_truths - 1], "generator_seed": seed,
            "delta": DELTA, "nominal": LEVEL, **head,
            "by_delta": {f"{dl:g}": {k: v for k, v in r.items()
                                     if k in ("coverage", "power", "too_loose")}
                         for dl, r in at.items()},
            "truths_u": truths.tolist()}  # fmt: skip


def _planted_at(res, per, n_truths, distances, away, c, delta) -> dict:
    """Coverage and power of the rule at discrepancy ``delta`` from the planted runs."""
    imax_truth, imax_away, which = [], [], []
    for t in range(n_truths):
        z = printed_round(_nums(res[per * t])[0])
        i_t = capped(implausibility(_nums(res[per * t + 1]), z, delta))
        imax_truth.append(float(i_t.max()))
        which.append(int(np.argmax(i_t)))
        imax_away.append([float(capped(implausibility(_nums(res[per * t + 2 + j]), z,
                                                      delta)).max())
                          for j in range(len(distances))])  # fmt: skip
    it, ia = np.array(imax_truth), np.array(imax_away).reshape(n_truths, len(distances))
    acc = int(np.sum(it <= c))
    power = {}
    for j, r in enumerate(distances):
        k = int(np.sum(ia[:, j] > c))
        dist = [a[j][1] for a in away]
        power[f"{r:g}"] = {**proportion(k, n_truths), "distance": r,
                           "actual_distance_median": float(np.median(dist)),
                           "median_max_implausibility": float(np.median(ia[:, j]))}
    worst = np.bincount(which, minlength=36)
    return {"coverage": proportion(acc, n_truths), "power": power,
            "too_loose": bool(power[f"{max(distances):g}"]["p"] < 0.9),
            "max_implausibility_at_truth": {"median": float(np.median(it)),
                                            "q90": float(np.quantile(it, 0.9)),
                                            "max": float(it.max())},
            "max_implausibility_truth": it.tolist(), "max_implausibility_away": ia.tolist(),
            "largest_at_truth": {prior.NUMBER_NAMES[i]: int(n) for i, n in enumerate(worst)
                                 if n}}  # fmt: skip


def judge(nums: np.ndarray, k_seeds: int, deltas: Sequence[float] = DELTAS) -> dict:
    """The rule against the paper's Tables 1-3 for one candidate's runs ``nums`` (K, 36): its
    implausibilities and verdict at each discrepancy of ``deltas``."""
    c = threshold(k_seeds)
    out = {}
    for delta in deltas:
        i = capped(implausibility(nums, prior.PAPER, delta))
        order = np.argsort(-i)
        out[f"{delta:g}"] = {"max_implausibility": float(i.max()),
                             "not_ruled_out": bool(i.max() <= c),
                             "n_within": int(np.sum(i <= c)),
                             "worst": [prior.NUMBER_NAMES[j] for j in order[:3]],
                             "implausibility": [float(x) for x in i]}  # fmt: skip
    return {"threshold": c, "seeds": k_seeds, "by_delta": out}
