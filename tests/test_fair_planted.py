"""The fair tuning's comparison rule on planted truth (analysis.calibration.fair_planted):
truth tables, the noise decomposition against planted variances, the t interval's coverage,
a rule made too loose caught by the acceptance it measures, and the record's check."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from analysis.calibration import fair_planted as fp
from analysis.calibration import verdicts
from analysis.calibration.store import METRICS


def _held(rmse: np.ndarray, failed: np.ndarray | None = None) -> np.ndarray:
    """A held-out result (seeds, cells, metrics + status) with the tail RMSE ``rmse``."""
    arr = np.zeros((*rmse.shape, len(METRICS) + 1))
    arr[..., METRICS.index("tail_position")] = rmse
    if failed is not None:
        arr[..., -1] = failed.astype(float)
    return arr


def _base(seeds: int = 8, cells: int = 6, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return _held(np.exp(rng.normal(-4.0, 0.5, (1, cells)) + rng.normal(0, 0.05, (seeds, cells))))


def test_false_of_is_the_truth_table():
    """Each word against a planted ratio, with and without a planted failure difference."""
    f = fp.false_of
    assert not any(f(w, 1.0, 0.0) for w in ("equivalent", "tie", "mixed", "undetermined",
                                           "restart-dependent"))  # fmt: skip
    assert all(f(w, 1.0, 0.0) for w in ("higher", "lower", "worse", "better", "fails more",
                                        "fails less"))  # fmt: skip
    assert f("lower", 1.1, 0.0) and f("better", 1.1, 0.0) and not f("higher", 1.1, 0.0)
    assert f("higher", 0.9, 0.0) and f("worse", 0.9, 0.0) and not f("lower", 0.9, 0.0)
    assert f("equivalent", 1.05, 0.0) and f("equivalent", 1 / 1.05, 0.0)  # the margin's edge
    assert not f("equivalent", 1.049, 0.0) and not f("higher", 1.02, 0.0)
    assert not f("fails more", 1.0, 0.05) and not f("worse", 1.0, 0.05)
    assert all(f(w, 1.0, 0.05) for w in ("fails less", "lower", "better", "higher"))


def test_pair_noise_recovers_planted_variances_and_sets_systematic_failures_apart():
    """A seed effect of sd 0.05 and a run's noise of sd 0.1 on 60 seeds x 20 cells (cell
    means arbitrary) come back within 20 %; a cell where a fails at every seed is systematic,
    one where it fails at 5 seeds is the random part."""
    rng = np.random.default_rng(1)
    s, c = 60, 20
    rb = np.exp(rng.normal(-4.0, 0.5, (1, c)) + rng.normal(0, 0.2, (s, c)))
    lr = rng.normal(0, 0.3, (1, c)) + rng.normal(0, 0.05, (s, 1)) + rng.normal(0, 0.1, (s, c))
    fa = np.zeros((s, c), bool)
    fa[:, 0] = True
    fa[:5, 1] = True
    sd = fp.pair_noise(_held(rb * np.exp(lr), fa), _held(rb))
    assert sd["cells"] == c - 2 and sd["seeds"] == s
    assert sd["seed_sd"] == pytest.approx(0.05, rel=0.2)
    assert sd["pair_sd"] == pytest.approx(0.1, rel=0.2)
    assert sd["systematic"] == s and sd["discordance"] == pytest.approx(5 / (s * c))
    assert sd["discordance_all"] == pytest.approx((s + 5) / (s * c))
    assert fp.pair_noise(_held(rb[:2]), _held(rb[:2])) is None  # 2 seeds: no variance split


def test_the_rule_accepts_planted_truth_and_its_interval_covers():
    """At the record's kind of layout (8 seeds, 6 cells) and no random failures: the best/best
    t interval covers the planted log ratio about 95 % of the time (300 replicates: 285
    expected), the rule accepts the truth at 1, 1.02 and 1.2, and names 1.5x every time."""
    sd = {"seed_sd": 0.02, "pair_sd": 0.05, "discordance": 0.0}
    base = _base()
    for k, rho in enumerate((1.0, 1.02, 1.2)):
        r = fp.planted_pair(base, sd, rho, 0.0, 300, np.random.default_rng([2, k]))
        assert r["accepts"]["share"] >= fp.ACCEPT, r
        assert 0.91 <= r["coverage"]["share"] <= 0.985, r["coverage"]
    r = fp.planted_pair(base, sd, 1.5, 0.0, 50, np.random.default_rng(3))
    assert r["power"]["share"] == 1.0 and r["verdicts"] == {"higher": 1.0}
    # a planted failure difference of 30 % per run is named "fails more" nearly always
    r = fp.planted_pair(base, sd, 1.0, 0.3, 50, np.random.default_rng(4))
    assert r["power"]["share"] >= 0.9 and r["accepts"]["share"] == 1.0


def test_a_rule_that_calls_a_tie_equivalent_is_caught(monkeypatch):
    """The measurement can fail: a rule that calls every difference it cannot separate
    'equivalent' (absence of evidence as evidence of sameness) says so of a planted 1.15x at
    a noisy 3-seed layout, and its acceptance of that truth falls below 90 %; the rule as
    written calls it a tie and accepts it.  A z quantile in place of t at 3 seeds drops the
    interval's coverage below 90 %."""
    sd = {"seed_sd": 0.1, "pair_sd": 0.1, "discordance": 0.0}
    three = _base(seeds=3)
    ok = fp.planted_pair(three, sd, 1.15, 0.0, 100, np.random.default_rng(5))
    word = verdicts.word
    monkeypatch.setattr(verdicts, "word", lambda p: "equivalent" if p["tie"] else word(p))
    bad = fp.planted_pair(three, sd, 1.15, 0.0, 100, np.random.default_rng(5))
    assert ok["accepts"]["share"] >= fp.ACCEPT > bad["accepts"]["share"], (ok, bad)
    monkeypatch.undo()
    from scipy import stats

    ppf = stats.t.ppf
    sd = {"seed_sd": 0.02, "pair_sd": 0.05, "discordance": 0.0}
    ok = fp.planted_pair(three, sd, 1.0, 0.0, 300, np.random.default_rng(6))
    monkeypatch.setattr(stats.t, "ppf", lambda q, df: stats.norm.ppf(q))
    z = fp.planted_pair(three, sd, 1.0, 0.0, 300, np.random.default_rng(6))
    assert ok["coverage"]["share"] >= 0.91 > z["coverage"]["share"], (ok, z)
    assert ppf is not stats.t.ppf


def test_best_claims_never_name_a_best_among_equals_and_find_a_planted_one():
    sd = {"seed_sd": 0.02, "pair_sd": 0.05, "discordance": 0.0}
    base, names = _base(), ["a", "b", "c", "d"]
    eq = fp.best_claims(base, sd, names, 1.0, 60, np.random.default_rng(7))
    assert eq["claims"]["k"] <= 3 and eq["right"]["k"] == 0  # 5 % of 60 at most
    bet = fp.best_claims(base, sd, names, 0.8, 60, np.random.default_rng(8))
    assert bet["right"]["share"] >= 0.9 and bet["wrong"]["k"] == 0


def test_study_summary_checks_and_a_tampered_one_does_not():
    """The record's planted part on synthetic arms: ``check`` passes, a changed summary or a
    rule that rejects planted truth fails it; the report states the least acceptance."""
    from analysis.calibration import fair_report

    rng = np.random.default_rng(9)
    base = _base(seeds=6, cells=5)
    tail = METRICS.index("tail_position")
    runs = {}
    for i, n in enumerate(("x@raw", "y@raw", "z@raw")):
        lv = {}
        for level in verdicts.RESTARTS:
            arr = base.copy()
            arr[..., tail] *= np.exp(0.1 * i + rng.normal(0, 0.03, arr.shape[:2]))
            lv[level] = arr
        runs[n] = lv
    main = np.ones(5, bool)
    pl = fp.study(runs, {"y@raw vs x@raw": ("y@raw", "x@raw"),
                         "z@raw vs x@raw": ("z@raw", "x@raw")}, main,
                  ["x@raw", "y@raw", "z@raw"], replicates=20)  # fmt: skip
    fp.check(pl)
    text = fair_report.planted({"planted": pl, "ranking": ["x@raw", "y@raw", "z@raw"]})[0]
    assert f"accepts the truth in at least {100 * pl['least_accepts']['share']:.0f} %" in text
    bad = copy.deepcopy(pl)
    bad["least_power"]["1.1"] += 0.05
    with pytest.raises(AssertionError):
        fp.check(bad)
    bad = copy.deepcopy(pl)
    row = bad["comparisons"]["y@raw vs x@raw"]["truths"][0]
    row["accepts"].update(k=10, share=0.5)
    bad["least_accepts"]["share"] = 0.5
    bad["accepts_at_target"] = False
    with pytest.raises(AssertionError, match="rejects planted truth"):
        fp.check(bad)
