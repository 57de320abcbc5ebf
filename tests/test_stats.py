"""Tests of wmr/stats.py: paired tests over seeds (Wilcoxon, Holm, TOST, bootstrap interval).

Oracles: the exact null distribution of the signed-rank statistic enumerated over all sign
patterns; Holm's adjustment worked by hand; TOST against its definition (two one-sided
``scipy.stats.ttest_1samp`` tests) and against its confidence-interval form; the bootstrap
interval against the normal closed form in a large sample.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats as sps

from wmr import stats as st

# TOST p-values against scipy's one-sided t-tests: the same t distribution reached by another
# code path (ttest_1samp computes its own mean, std and statistic): round-off only.
P_TOL = 1e-12
# Bootstrap quantile vs the normal closed form, in standard errors of the mean: the Monte-Carlo
# error of a 2.5 % quantile from B resamples is sqrt(p (1 - p) / B) / phi(z_p) = 0.019 se at
# B = 20000; 0.1 se is ~5 of those (the sampling skew at n = 400 is far smaller).
BOOT_TOL_SE = 0.1


def _sample(seed, n=20, mean=0.0, std=1e-3):
    rng = np.random.default_rng(seed)
    b = rng.uniform(0.05, 0.2, n)  # an arm's RMSEs [m]
    return b + rng.normal(mean, std, n), b


# ---- Wilcoxon signed-rank ----------------------------------------------------------------------


def _exact_signed_rank_p(d):
    """Two-sided exact p of the signed-rank test by enumerating the 2^n equally likely sign
    patterns of the ranks (no ties, no zeros): 2 min(P(T <= t), P(T >= t)), capped at 1."""
    ranks = sps.rankdata(np.abs(d))
    t = ranks[d > 0].sum()
    sums = np.array([sum(r for r, s in zip(ranks, signs, strict=True) if s)
                     for signs in itertools.product((0, 1), repeat=d.size)])  # fmt: skip
    return min(1.0, 2 * min(np.mean(sums <= t), np.mean(sums >= t)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wilcoxon_is_the_exact_signed_rank_test(seed):
    d = np.random.default_rng(seed).normal(0.3, 1.0, 9)
    assert st.wilcoxon(d) == pytest.approx(_exact_signed_rank_p(d), rel=1e-12)


def test_wilcoxon_by_hand_and_its_conventions():
    # ranks 1..5, the negative one has rank 5: T- = 5; 10 of the 32 sign patterns have a
    # negative-rank sum <= 5 ({}, {1}..{5}, {1,2}, {1,3}, {1,4}, {2,3}): p = 2 * 10/32.
    assert st.wilcoxon([1.0, 2.0, 3.0, 4.0, -5.0]) == pytest.approx(0.625, rel=1e-12)
    # all of one sign: 1/32 one-sided in the right direction, 2/32 two-sided
    d = np.array([0.5, 0.4, 0.6, 0.3, 0.7])
    assert st.wilcoxon(-d, alternative="less") == pytest.approx(1 / 32, rel=1e-12)
    assert st.wilcoxon(d) == pytest.approx(2 / 32, rel=1e-12)
    assert st.wilcoxon(np.zeros(6)) == 1.0 and st.wilcoxon([0.3]) == 1.0  # no evidence
    assert st.paired_differences([1.0, np.nan, 3.0], [0.5, 1.0, np.inf]).tolist() == [0.5]
    with pytest.raises(ValueError, match="same length"):
        st.paired_differences([1.0, 2.0], [1.0])


# ---- Holm ------------------------------------------------------------------------------------


def test_holm_by_hand():
    # sorted 0.01, 0.02, 0.03, 0.04, 0.5 times 5, 4, 3, 2, 1: 0.05, 0.08, 0.09, 0.08 -> 0.09
    # (monotone), 0.5.
    assert st.holm([0.03, 0.5, 0.01, 0.04, 0.02]) == pytest.approx([0.09, 0.5, 0.05, 0.09, 0.08])
    assert st.holm_reject([0.03, 0.5, 0.01, 0.04, 0.02], 0.06) == [False, False, True, False,
                                                                   False]  # fmt: skip
    # step-down: 3*0.001, 2*0.012, 1*0.04 all below 0.05 (Bonferroni, 3*0.04 = 0.12, would keep
    # the last hypothesis)
    assert st.holm([0.001, 0.04, 0.012]) == pytest.approx([0.003, 0.04, 0.024])
    assert st.holm_reject([0.001, 0.04, 0.012]) == [True, True, True]
    assert st.holm([0.6, 0.7]) == [1.0, 1.0]  # capped at 1
    assert st.holm([]) == []


# ---- TOST ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("seed", "mean", "delta"), [(0, 0.0, 1e-3), (1, 2e-4, 5e-4), (2, -8e-4, 1e-3), (3, 0.0, 1e-5)]
)
def test_tost_is_two_one_sided_t_tests(seed, mean, delta):  # fmt: skip
    """H0: mu <= -delta rejected by the upper-tailed test of popmean -delta, H0: mu >= delta by
    the lower-tailed test of popmean +delta; TOST's p is the larger of the two."""
    a, b = _sample(seed, mean=mean)
    r = st.tost(a, b, delta)
    d = a - b
    p_lo = sps.ttest_1samp(d, -delta, alternative="greater").pvalue
    p_hi = sps.ttest_1samp(d, delta, alternative="less").pvalue
    assert r.p_lower == pytest.approx(p_lo, rel=P_TOL, abs=1e-300)
    assert r.p_upper == pytest.approx(p_hi, rel=P_TOL, abs=1e-300)
    assert r.p == max(r.p_lower, r.p_upper)
    assert r.equivalent == (max(p_lo, p_hi) < 0.05)
    assert r.n == d.size and r.mean_diff == pytest.approx(np.mean(d), rel=1e-12)


def test_tost_rejects_exactly_when_the_interval_lies_inside_the_margin():
    """The (1 - 2 alpha) t interval of the mean difference is scipy's; it lies inside
    (-delta, delta) iff TOST rejects, over seeded samples and margins on both sides of the
    boundary; at the margin equal to the interval's farther end, p = alpha."""
    checked = {True: 0, False: 0}
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        a, b = _sample(seed, n=int(rng.integers(3, 30)), mean=rng.normal(0, 5e-4))
        d = a - b
        for alpha in (0.05, 0.1):
            r0 = st.tost(a, b, 1.0, alpha)
            lo, hi = sps.t.interval(1 - 2 * alpha, d.size - 1, loc=np.mean(d), scale=sps.sem(d))
            assert (r0.ci_low, r0.ci_high) == pytest.approx((lo, hi), rel=1e-12)
            edge = max(abs(lo), abs(hi))
            assert st.tost(a, b, edge, alpha).p == pytest.approx(alpha, rel=1e-9)
            for delta in edge * np.array([0.5, 0.9, 0.999, 1.001, 1.1, 2.0]):
                r = st.tost(a, b, delta, alpha)
                assert r.equivalent == (-delta < r.ci_low and r.ci_high < delta), (seed, delta)
                checked[r.equivalent] += 1
    assert min(checked.values()) > 100  # both outcomes exercised


def test_a_synthetic_pair_is_equivalent_at_delta_and_not_at_a_tenth_of_it():
    """Two arms within ~0.5 mm of each other per seed, with differences symmetric about zero by
    construction (20 seeds, pairs +x, -x): the same to within 1 mm, not to within 0.1 mm (the
    90 % interval is wider than 0.2 mm), while the Wilcoxon test sees no difference at all: no
    difference found is not equivalence."""
    rng = np.random.default_rng(7)
    x = rng.normal(0.0, 5e-4, 10)
    b = rng.uniform(0.05, 0.2, 20)
    a = b + np.concatenate((x, -x))
    at_delta, at_tenth = st.tost(a, b, 1e-3), st.tost(a, b, 1e-4)
    assert at_delta.equivalent and at_delta.p < 1e-6
    assert at_tenth.ci_high - at_tenth.ci_low > 2e-4 and not at_tenth.equivalent
    assert st.wilcoxon(a - b) > 0.05
    assert at_delta.to_json()["equivalent"] is True


def test_tost_edge_cases():
    a = np.array([1.0, 2.0, 3.0])
    # every difference exactly 0.5: the interval is that point
    assert st.tost(a + 0.5, a, 1.0).equivalent and st.tost(a + 0.5, a, 1.0).p == 0.0
    assert st.tost(a + 0.5, a, 1.0).ci_low == 0.5
    assert not st.tost(a + 2.0, a, 1.0).equivalent and st.tost(a + 2.0, a, 1.0).p == 1.0
    with pytest.raises(ValueError, match="delta"):
        st.tost(a, a, 0.0)
    with pytest.raises(ValueError, match="alpha"):
        st.tost(a, a, 1.0, alpha=0.5)
    with pytest.raises(ValueError, match="2 finite pairs"):
        st.tost([1.0, np.nan], [1.0, 2.0], 1.0)


# ---- bootstrap ---------------------------------------------------------------------------------


def test_bootstrap_interval_tends_to_the_normal_closed_form():
    """n = 400 normal differences: the percentile interval of the resampled means is
    mean -+ z_0.975 sigma/sqrt(n) (sigma with ddof 0, the bootstrap's own variance)."""
    a, b = _sample(11, n=400, mean=1e-3, std=2e-3)
    d = a - b
    se = np.std(d) / math.sqrt(d.size)
    z = sps.norm.ppf(0.975)
    lo, hi = st.bootstrap_mean_diff_ci(a, b, 0.95, n_resamples=20_000, seed=3)
    assert abs(lo - (np.mean(d) - z * se)) < BOOT_TOL_SE * se
    assert abs(hi - (np.mean(d) + z * se)) < BOOT_TOL_SE * se


def test_bootstrap_is_deterministic_by_seed():
    a, b = _sample(5, n=15)
    first = st.bootstrap_mean_diff_ci(a, b, seed=42, n_resamples=2_500)
    assert st.bootstrap_mean_diff_ci(a, b, seed=42, n_resamples=2_500) == first
    assert st.bootstrap_mean_diff_ci(a, b, seed=np.random.default_rng(42),
                                     n_resamples=2_500) == first  # fmt: skip
    assert st.bootstrap_mean_diff_ci(a, b, seed=43, n_resamples=2_500) != first
    lo, hi = first
    assert lo < np.mean(a - b) < hi
    with pytest.raises(ValueError, match="level"):
        st.bootstrap_mean_diff_ci(a, b, level=1.0)
    with pytest.raises(ValueError, match="finite pair"):
        st.bootstrap_mean_diff_ci([np.nan], [1.0])


# --- Clopper-Pearson ---------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 5, 20, 137])
def test_clopper_pearson_closed_forms_and_scipys_root_finding(n):
    from scipy.stats import binomtest

    assert st.clopper_pearson(0, n) == (0.0, pytest.approx(1 - 0.025 ** (1 / n), rel=1e-12))
    assert st.clopper_pearson(n, n) == (pytest.approx(0.025 ** (1 / n), rel=1e-12), 1.0)
    for k in range(n + 1):
        ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
        assert st.clopper_pearson(k, n) == pytest.approx((ci.low, ci.high), abs=1e-10)
    lo, hi = st.clopper_pearson(n / 2, n, level=0.99)  # a wider level, a non-integer count
    assert lo < 0.5 < hi and st.clopper_pearson(0, 0) == (0.0, 1.0)


def test_clopper_pearson_covers_a_planted_proportion_at_least_nominally():
    rng = np.random.default_rng(7)
    p, n, reps = 0.1, 30, 2000
    k = rng.binomial(n, p, size=reps)
    covered = np.mean([lo <= p <= hi for lo, hi in (st.clopper_pearson(x, n) for x in k)])
    assert covered >= 0.95  # exact intervals are conservative: >= nominal at every p
