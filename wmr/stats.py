"""Statistics of paired samples over seeds: is one arm better, worse, or "the same"?

Runs of two arms on the same seeds (common random numbers) give paired samples ``a``, ``b``
(shape ``(n,)``, e.g. RMSEs in metres); every function here works on the differences
``d = a - b`` of the finite pairs (:func:`paired_differences`: a diverged run is NaN and leaves
its pair out).

- :func:`wilcoxon`: the paired Wilcoxon signed-rank test (scipy, exact for small ``n``): is the
  difference's distribution centred on zero?  A small p says "different"; a large p does **not**
  say "the same".
- :func:`holm`: Holm's step-down adjustment of a family of p-values (family-wise error ``alpha``).
- :func:`tost`: the paired-t **two one-sided tests** of equivalence at a stated margin ``delta``
  (Schuirmann 1987): ``H0: |mean d| >= delta`` against ``H1: |mean d| < delta``.  Equivalence is
  claimed when both one-sided tests reject at ``alpha``; equivalently, when the ``(1 - 2 alpha)``
  confidence interval of the mean difference lies inside ``(-delta, delta)``.  This is the test
  that can support "A is the same as B" (to within ``delta``).
- :func:`bootstrap_mean_diff_ci`: a seeded percentile-bootstrap interval of the mean difference
  (resampling the pairs), which does not lean on the normality the t interval assumes.
- :func:`clopper_pearson`: the exact interval of a proportion (a divergence rate, a coverage),
  the one implementation every study uses.

Randomness only through the ``seed`` argument (a ``numpy.random.Generator`` is made from it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as _st

__all__ = [
    "BOOTSTRAP_RESAMPLES",
    "paired_differences",
    "wilcoxon",
    "holm",
    "holm_reject",
    "Tost",
    "tost",
    "bootstrap_mean_diff_ci",
    "clopper_pearson",
]

#: Default number of bootstrap resamples: the Monte-Carlo error of a 2.5 % quantile is then
#: ~2 % of the interval's half-width (``sqrt(p (1 - p) / B) / phi(z_p)`` in standard errors).
BOOTSTRAP_RESAMPLES = 10_000
#: Resamples drawn per block (memory ``O(block n)``); fixed, so a seed gives one interval.
_BLOCK = 1_000


def paired_differences(a, b) -> np.ndarray:
    """``a - b`` over the pairs where both are finite, shape ``(m,)``, ``m <= n``.

    Parameters
    ----------
    a, b : array_like, shape (n,)
        Paired samples (the same seeds in the same order); NaN marks a missing value.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"a and b must be 1-D of the same length, got {a.shape} and {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    return a[ok] - b[ok]


def wilcoxon(d, alternative: str = "two-sided") -> float:
    """p-value of the Wilcoxon signed-rank test of the paired differences ``d`` (shape (n,)).

    ``scipy.stats.wilcoxon(d)`` with its defaults (zero differences dropped; scipy 1.17's
    ``method="auto"``: the exact null distribution for up to 50 differences without ties or
    zeros, the exact permutation distribution for up to 13 with them, the normal approximation
    otherwise).  With fewer than two differences, or all of them zero, there is no evidence of a
    difference: 1.0.  ``alternative``: ``"two-sided"``, ``"less"`` (``d`` centred below 0) or
    ``"greater"``.
    """
    d = np.asarray(d, dtype=float)
    if d.size > 1 and np.any(d != 0):
        return float(_st.wilcoxon(d, alternative=alternative).pvalue)
    return 1.0


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values (step-down, monotone), in the input order.

    Sorted ascending, the ``i``-th smallest (``i = 0 .. m-1``) is multiplied by ``m - i``,
    capped at 1, and made non-decreasing along the sorted order; rejecting where the adjusted
    p is below ``alpha`` controls the family-wise error rate at ``alpha`` (Holm 1979).
    """
    m = len(pvalues)
    order = sorted(range(m), key=lambda i: pvalues[i])
    adjusted = [1.0] * m
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * pvalues[i]))
        adjusted[i] = running
    return adjusted


def holm_reject(pvalues: Sequence[float], alpha: float = 0.05) -> list[bool]:
    """Which hypotheses of the family Holm's procedure rejects at family-wise error ``alpha``."""
    return [q < alpha for q in holm(pvalues)]


@dataclass(frozen=True)
class Tost:
    """The paired-t two one-sided tests of equivalence (:func:`tost`).

    Attributes
    ----------
    n : int
        Number of finite pairs.
    mean_diff, std_diff : float
        Mean and std (ddof 1) of ``d = a - b`` [units of the samples].
    delta, alpha : float
        The equivalence margin (> 0) and the level of each one-sided test.
    p_lower, p_upper : float
        p-values of ``H0: mean d <= -delta`` (vs ``> -delta``) and of ``H0: mean d >= delta``
        (vs ``< delta``).
    p : float
        ``max(p_lower, p_upper)``: the TOST p-value.
    ci_low, ci_high : float
        The ``(1 - 2 alpha)`` t confidence interval of the mean difference.
    equivalent : bool
        ``p < alpha``: both one-sided tests reject; equivalently ``-delta < ci_low`` and
        ``ci_high < delta``.
    """

    n: int
    mean_diff: float
    std_diff: float
    delta: float
    alpha: float
    p_lower: float
    p_upper: float
    p: float
    ci_low: float
    ci_high: float
    equivalent: bool

    def to_json(self) -> dict:
        """The fields as a JSON-able dict."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def tost(a, b, delta: float, alpha: float = 0.05) -> Tost:
    """Paired-t TOST: is the mean of ``a - b`` within ``(-delta, delta)``?

    With ``d`` the finite paired differences (:func:`paired_differences`), ``n`` of them, mean
    ``m``, std ``s`` (ddof 1), standard error ``se = s/sqrt(n)`` and ``n - 1`` degrees of freedom:

    - lower test, ``H0: mu_d <= -delta``: ``t_L = (m + delta)/se``, ``p_L = P(T > t_L)``;
    - upper test, ``H0: mu_d >= delta``: ``t_U = (m - delta)/se``, ``p_U = P(T < t_U)``;
    - equivalent at level ``alpha`` iff ``max(p_L, p_U) < alpha``.

    The ``(1 - 2 alpha)`` interval ``m -+ t_{1-alpha, n-1} se`` lies inside ``(-delta, delta)``
    exactly when both tests reject (``p_L < alpha`` iff ``m - t_{1-alpha} se > -delta``).  When
    every difference is the same (``s = 0``) the interval is that point, and the tests are
    decided by it (p = 0 inside the margin, 1 outside).

    Parameters
    ----------
    a, b : array_like, shape (n,)
        Paired samples (NaN: a missing value, its pair left out); at least two finite pairs.
    delta : float
        The equivalence margin, > 0, in the samples' units (e.g. 1e-3 m).
    alpha : float
        Level of each one-sided test, in (0, 0.5).
    """
    if not (math.isfinite(delta) and delta > 0):
        raise ValueError(f"delta must be finite and > 0, got {delta!r}")
    if not 0 < alpha < 0.5:
        raise ValueError(f"alpha must lie in (0, 0.5), got {alpha!r}")
    d = paired_differences(a, b)
    n = d.size
    if n < 2:
        raise ValueError(f"TOST needs at least 2 finite pairs, got {n}")
    m, s = float(np.mean(d)), float(np.std(d, ddof=1))
    se = s / math.sqrt(n)
    if se > 0:
        t_dist = _st.t(n - 1)
        p_lo = float(t_dist.sf((m + delta) / se))
        p_hi = float(t_dist.cdf((m - delta) / se))
        half = float(t_dist.ppf(1.0 - alpha)) * se
    else:
        p_lo = 0.0 if m > -delta else 1.0
        p_hi = 0.0 if m < delta else 1.0
        half = 0.0
    p = max(p_lo, p_hi)
    return Tost(n, m, s, float(delta), float(alpha), p_lo, p_hi, p, m - half, m + half,
                bool(p < alpha))  # fmt: skip


def bootstrap_mean_diff_ci(a, b, level: float = 0.95, n_resamples: int = BOOTSTRAP_RESAMPLES,
                           seed=0) -> tuple[float, float]:  # fmt: skip
    """Percentile-bootstrap interval of the mean paired difference ``mean(a - b)``.

    The ``n`` finite pairs are resampled with replacement ``n_resamples`` times (the pairing
    kept: the differences are resampled); the interval is the ``(1 - level)/2`` and
    ``(1 + level)/2`` quantiles of the resampled means (linear interpolation).  For large ``n``
    it tends to ``mean -+ z_{(1+level)/2} sigma/sqrt(n)`` (``sigma`` the std with ddof 0).

    Parameters
    ----------
    a, b : array_like, shape (n,)
        Paired samples (NaN: missing); at least one finite pair.
    level : float
        Coverage, in (0, 1).
    n_resamples : int
        Bootstrap resamples, >= 1.
    seed : int, numpy.random.SeedSequence or numpy.random.Generator
        The randomness (``numpy.random.default_rng(seed)``): the same seed gives the same interval.

    Returns
    -------
    tuple of float
        ``(low, high)`` in the samples' units.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    if int(n_resamples) != n_resamples or n_resamples < 1:
        raise ValueError(f"n_resamples must be an integer >= 1, got {n_resamples!r}")
    d = paired_differences(a, b)
    if d.size == 0:
        raise ValueError("the bootstrap needs at least one finite pair")
    rng = np.random.default_rng(seed)
    means = np.empty(int(n_resamples))
    for start in range(0, means.size, _BLOCK):
        stop = min(start + _BLOCK, means.size)
        idx = rng.integers(0, d.size, size=(stop - start, d.size))
        means[start:stop] = d[idx].mean(axis=1)
    lo, hi = np.quantile(means, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return float(lo), float(hi)


def clopper_pearson(k: float, n: float, level: float = 0.95) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a proportion ``k / n``.

    ``(beta.ppf(a/2; k, n-k+1), beta.ppf(1-a/2; k+1, n-k))`` with ``a = 1 - level``; ``[0,
    upper]`` for ``k = 0`` (then ``upper = 1 - (a/2)^(1/n)``), ``[lower, 1]`` for ``k = n``, and
    ``(0, 1)`` for ``n = 0`` (no information).  A non-integer ``k`` (an effective count, Korn &
    Graubard 1998) is allowed.  scipy's ``binomtest(k, n).proportion_ci(method="exact")`` finds
    the same bounds by root-finding, to about 1e-12; this is the closed form.
    """
    if n <= 0:
        return 0.0, 1.0
    a = 1.0 - level
    lo = 0.0 if k <= 0 else float(_st.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k >= n else float(_st.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi
