"""The fair tuning's comparison rule on planted truth (analysis.calibration.fair_planted):
the truth table, the layout against planted variances and failure patterns, the synthetic
draws (planted shift, no threshold crossing, exchanged failures), the t interval's coverage,
rules made wrong caught by the acceptance the study measures, and the record's check."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from analysis.calibration import fair_planted as fp
from analysis.calibration import verdicts
from analysis.calibration.store import METRICS
from analysis.regimes import stats as rstats

TAIL = METRICS.index("tail_position")


def _held(rmse: np.ndarray, failed: np.ndarray | None = None) -> np.ndarray:
    """A held-out result (seeds, cells, metrics + status) with the tail RMSE ``rmse``."""
    arr = np.zeros((*rmse.shape, len(METRICS) + 1))
    arr[..., TAIL] = rmse
    if failed is not None:
        arr[..., -1] = failed.astype(float)
    return arr


def _arms(n_arms=2, seeds=10, cells=6, seed_sd=0.02, run_sd=0.05, seed=0, fails=None):
    """``n_arms`` arms (level -> result), each level with cell means of its own, a seed effect
    shared by every arm and level of a seed plus each arm's own, and a run's own noise;
    ``fails``: (arm, level) -> failure mask."""
    rng = np.random.default_rng(seed)
    shared = rng.normal(0, seed_sd, (seeds, 1))
    out = []
    for i in range(n_arms):
        own = rng.normal(0, seed_sd, (seeds, 1))
        lv = {}
        for j, name in enumerate(verdicts.RESTARTS):
            lr = (np.log(0.02) + rng.normal(0, 0.5, (1, cells)) + shared + own
                  + rng.normal(0, run_sd, (seeds, cells)))  # fmt: skip
            lv[name] = _held(np.exp(lr), None if fails is None else fails.get((i, j)))
        out.append(lv)
    return out


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
    assert all(f(w, 1.0, 0.05) for w in ("fails less", "lower", "better", "higher",
                                         "equivalent"))  # fmt: skip


def test_layout_recovers_planted_variances_and_sorts_the_failing_cells():
    """The best/best pair's seed effect (each arm's own, sd 0.05: the difference's sd 0.071)
    and a run's noise (sd 0.1 per arm: 0.141) come back within 20 % on 60 seeds x 20 cells;
    a cell where a fails at every seed is fixed, one where the arms take turns (a at seeds
    0-4, b at 5-9) varies, and so does one where only a's runner-up fails at a few; a cell
    where only one level fails, at every seed, is fixed too."""
    s, c = 60, 20
    fa, fb, fo = (np.zeros((s, c), bool) for _ in range(3))
    fa[:, 0] = True
    fa[:5, 1] = True
    fb[5:10, 1] = True
    fo[:3, 2] = True
    fb1 = fb.copy()
    fb[:, 3] = True  # b's best restart fails there at every seed, its runner-up never
    arms = _arms(seeds=s, cells=c, seed_sd=0.05, run_sd=0.1, seed=1,
                 fails={(0, 0): fa, (0, 1): fa | fo, (1, 0): fb, (1, 1): fb1})
    lay = fp.layout(arms)
    n = lay["noise"]
    assert n["tracked"] == c - 4 and n["fixed"] == 2 and n["varying"] == 2
    assert lay["fixed"][0] and lay["fixed"][3] and lay["varying"][1] and lay["varying"][2]
    assert n["seed_sd"] == pytest.approx(0.05 * math.sqrt(2), rel=0.2)
    assert n["pair_sd"] == pytest.approx(0.1 * math.sqrt(2), rel=0.2)
    assert n["random_failures"] == pytest.approx((5 + 5 + 5 + 3 + 5) / (4 * s * c))
    # the offsets are each level's cell means less its arm's
    assert np.allclose(lay["offset"].sum(axis=1), 0.0)
    # the residuals are each level's, about its own cell means
    assert np.allclose(lay["resid"][..., lay["tracked"]].mean(axis=2), 0.0)
    assert fp.layout(_arms(seeds=2)) is None  # 2 seeds: no variance to resample


def test_draws_plant_the_shift_keep_below_the_threshold_and_exchange_failures():
    """Over many draws: the best/best mean log ratio on the tracked cells averages the planted
    log 1.2 (a bootstrap's mean is unbiased); no tracked run comes near the tracking threshold;
    the varying cell's failures (arm a's, at 3 seeds) are shared equally by the four levels,
    each seed's on a level of its own drawing (permuted per seed, not per draw); the fixed
    cell fails everywhere; a planted extra failure lands on the first arm only."""
    s, c = 10, 6
    fa = np.zeros((s, c), bool)
    fa[:, 0] = True
    fa[:3, 1] = True
    arms = _arms(seeds=s, cells=c, fails={(0, 0): fa})  # a's best restart only
    lay = fp.layout(arms)
    rng = np.random.default_rng(2)
    means, fails_a, fails_b, spread = [], 0, 0, []
    for _ in range(400):
        a, b = fp.draw(lay, np.array([math.log(1.2), 0.0]), 0.0, rng)
        t = lay["tracked"]
        means.append(np.mean(np.log(a["tuned"][:, t, TAIL] / b["tuned"][:, t, TAIL])))
        for arr in (*a.values(), *b.values()):
            ok = arr[..., -1] == 0
            assert np.all(arr[ok][:, TAIL] <= 0.25 * rstats.TRACKING_M + 1e-12)
            assert np.all(arr[:, 0, -1] == 1)  # the systematic cell
        fails_a += sum(int(x[:, 1, -1].sum()) for x in a.values())
        fails_b += sum(int(x[:, 1, -1].sum()) for x in b.values())
        per_level = [int(x[:, 1, -1].sum()) for x in (*a.values(), *b.values())]
        if sum(per_level) >= 3:  # at least three failing seeds drawn (one level each)
            spread.append(sum(k > 0 for k in per_level) > 1)
    assert np.mean(means) == pytest.approx(math.log(1.2), abs=0.01)
    assert abs(fails_a - fails_b) < 0.15 * (fails_a + fails_b)
    assert np.mean(spread) > 0.8  # one level for all of a draw's seeds: 1/16 at 3 seeds
    a, b = fp.draw(lay, np.zeros(2), 0.5, np.random.default_rng(3))
    tracked_a = sum(int(x[:, lay["tracked"], -1].sum()) for x in a.values())
    tracked_b = sum(int(x[:, lay["tracked"], -1].sum()) for x in b.values())
    assert tracked_a > 0 and tracked_b == 0


def test_the_rule_accepts_planted_truth_and_its_interval_covers():
    """Without failures at 10 seeds: the best/best t interval covers the planted log ratio
    in about 95 % x (S - 1) / S of the bootstrap draws (300: 0.88-0.98 accepted), the rule
    accepts the truth at 1, 1.02 and 1.2, and names 1.5x every time."""
    lay = fp.layout(_arms(seed=4))
    for k, rho in enumerate((1.0, 1.02, 1.2)):
        r = fp.planted_pair(lay, rho, 0.0, 300, np.random.default_rng([5, k]))
        assert r["accepts"]["share"] >= fp.ACCEPT, r
        assert 0.88 <= r["coverage"]["share"] <= 0.98, r["coverage"]
    r = fp.planted_pair(lay, 1.5, 0.0, 50, np.random.default_rng(6))
    assert r["power"]["share"] == 1.0 and r["verdicts"] == {"higher": 1.0}
    r = fp.planted_pair(lay, 1.0, 0.3, 50, np.random.default_rng(7))
    assert r["power"]["share"] >= 0.9 and r["accepts"]["share"] == 1.0 and r["coverage"] is None


def test_random_failures_in_one_runner_up_cost_the_power_not_the_acceptance():
    """One level failing at random in two cells (4 of 10 seeds) leaves acceptance at or
    above 90 % but makes the four pairings disagree: the power at 1.5x falls below the
    failure-free layout's (the exchange puts those failures on either arm)."""
    fo = np.zeros((10, 6), bool)
    fo[:4, :2] = True
    clean = fp.planted_pair(fp.layout(_arms(seed=8)), 1.5, 0.0, 60, np.random.default_rng(9))
    lay = fp.layout(_arms(seed=8, fails={(1, 1): fo}))
    noisy = fp.planted_pair(lay, 1.5, 0.0, 60, np.random.default_rng(9))
    assert noisy["accepts"]["share"] >= fp.ACCEPT
    assert noisy["power"]["share"] < clean["power"]["share"] == 1.0
    assert noisy["verdicts"].get("restart-dependent", 0) > 0


def test_wrong_rules_are_caught_by_the_acceptance(monkeypatch):
    """The measurement can fail: a rule that calls every difference it cannot separate
    'equivalent' says so of a planted 1.15x at a noisy 3-seed layout, and its acceptance
    falls below 90 % (the rule as written calls it a tie); a z quantile in place of t at 3
    seeds drops the interval's coverage."""
    from scipy import stats

    lay = fp.layout(_arms(seeds=3, seed_sd=0.1, run_sd=0.1, seed=10))
    ok = fp.planted_pair(lay, 1.15, 0.0, 100, np.random.default_rng(11))
    word = verdicts.word
    monkeypatch.setattr(verdicts, "word", lambda p: "equivalent" if p["tie"] else word(p))
    bad = fp.planted_pair(lay, 1.15, 0.0, 100, np.random.default_rng(11))
    assert ok["accepts"]["share"] >= fp.ACCEPT > bad["accepts"]["share"], (ok, bad)
    monkeypatch.undo()
    lay = fp.layout(_arms(seeds=3, seed=12))
    t = fp.planted_pair(lay, 1.0, 0.0, 200, np.random.default_rng(13))
    monkeypatch.setattr(stats.t, "ppf", lambda q, df: stats.norm.ppf(q))
    z = fp.planted_pair(lay, 1.0, 0.0, 200, np.random.default_rng(13))
    assert z["coverage"]["share"] < t["coverage"]["share"] - 0.1, (t, z)


def test_best_claims_never_name_a_best_among_equals_and_find_a_planted_one():
    lay = fp.layout(_arms(n_arms=4, seed=14))
    names = ["a", "b", "c", "d"]
    eq = fp.best_claims(lay, names, 1.0, 40, np.random.default_rng(15))
    assert eq["claims"]["k"] <= 2 and eq["right"]["k"] == 0  # 5 % of 40 at most
    bet = fp.best_claims(lay, names, 0.8, 40, np.random.default_rng(16))
    assert bet["right"]["share"] >= 0.9 and bet["wrong"]["k"] == 0


def test_best_claims_find_the_arm_that_fails_less_and_no_other():
    """Every other arm failing in an extra 40 % of its runs (at equal accuracy): the seed
    sign-flip test tells each apart at 10 seeds x 6 cells, so the arm that fails less is
    claimed in most replicates and another never; at 0 % none is claimed; the extra failures
    land on the other arms only."""
    lay = fp.layout(_arms(n_arms=3, seed=18))
    names = ["a", "b", "c"]
    more = fp.best_claims(lay, names, 1.0, 40, np.random.default_rng(19), f=0.4)
    assert more["right"]["share"] >= 0.8 and more["wrong"]["k"] == 0, more
    none = fp.best_claims(lay, names, 1.0, 40, np.random.default_rng(19), f=0.0)
    assert none["claims"]["k"] <= 2 and none["right"]["k"] == 0
    a, b, c = fp.draw(lay, np.zeros(3), [0.0, 0.4, 0.4], np.random.default_rng(20))
    assert not any(x[..., -1].any() for x in a.values())
    assert all(x[..., -1].any() for x in (*b.values(), *c.values()))


def test_study_checks_and_a_tampered_record_does_not():
    """The record's planted part on synthetic arms: ``check`` passes; a changed summary, a
    verdict share that does not give the acceptance, a missing truth or a rule that rejects
    planted truth fails it; the report states the least acceptance."""
    from analysis.calibration import fair_report

    names = ["x@raw", "y@raw", "z@raw"]
    runs = dict(zip(names, _arms(n_arms=3, seeds=6, cells=5, seed=17), strict=True))
    pl = fp.study(runs, {"y@raw vs x@raw": ("y@raw", "x@raw"),
                         "z@raw vs x@raw": ("z@raw", "x@raw")}, np.ones(5, bool), names,
                  replicates=10)  # fmt: skip
    text = fair_report.planted({"planted": pl, "ranking": names})[0]
    assert f"accepts the truth in at least {100 * pl['least_accepts']['share']:.0f} %" in text
    right = "/".join(str(b["right"]["k"]) for b in pl["best"]["by_fail"])
    assert f"claims the arm that fails less in {right} of 10" in text

    def broken(edit) -> None:
        bad = copy.deepcopy(pl)
        edit(bad)
        with pytest.raises(AssertionError):
            fp.check(bad, labels)

    labels = ["y@raw vs x@raw", "z@raw vs x@raw"]
    fp.check(pl, labels)
    first = ("comparisons", "y@raw vs x@raw", "truths")
    broken(lambda b: b["truths"]["least_power"].update(
        {"1.1": b["truths"]["least_power"]["1.1"] + 0.05}))  # fmt: skip
    broken(lambda b: b["least_accepts"].update(k=b["least_accepts"]["k"] - 1))
    broken(lambda b: b["as_run"]["least_coverage"].update({"1": 0.5}))
    broken(lambda b: b["best"]["by_rho"][1]["right"].update(k=0, share=0.0))
    broken(lambda b: b["best"]["by_fail"].pop())
    broken(lambda b: b["best"]["by_fail"][0]["wrong"].update(
        k=b["best"]["by_fail"][0]["wrong"]["k"] + 1))  # fmt: skip
    broken(lambda b: b["comparisons"].pop("z@raw vs x@raw"))
    broken(lambda b: b[first[0]][first[1]][first[2]].pop())
    broken(lambda b: b[first[0]][first[1]][first[2]][0]["verdicts"].update(
        {"equivalent": 0.0, "higher": 1.0}))  # fmt: skip
    i = fp.RATIOS.index(1.5)  # a row whose power and shares say otherwise, counts consistent
    broken(lambda b: b[first[0]][first[1]][first[2]][i]["power"].update(
        k=(k := 1 - b[first[0]][first[1]][first[2]][i]["power"]["k"] // 10), share=k / 10))

    def rejects(b):
        row = b[first[0]][first[1]][first[2]][0]
        row["verdicts"] = {"higher": 0.5, "equivalent": 0.5}
        row["accepts"].update(k=5, share=0.5, ci_low=0.2, ci_high=0.8)
        row["power"].update(k=5, share=0.5, ci_low=0.2, ci_high=0.8)
        row["definite"].update(k=10, share=1.0, ci_low=0.7, ci_high=1.0)
        row["false_among_definite"].update(k=5, n=10, share=0.5, ci_low=0.2, ci_high=0.8)
        b.update(fp.summarise(b))

    bad = copy.deepcopy(pl)
    rejects(bad)
    with pytest.raises(AssertionError, match="rejects planted truth"):
        fp.check(bad)


def test_restarts_as_run_keep_every_pairings_truth_in_the_cells_whose_failures_vary():
    """With no run noise, each level a fixed cell-by-cell offset and a cell where arm a's best
    restart fails at a few seeds: in every as-run draw, each pairing's mean log ratio over
    the cells its two levels share is exactly its truth (planted ratio plus the tracked
    cells' mean offset difference), whether or not the varying cell is among them (an offset
    of zero there, as before, pulls it toward the planted ratio alone)."""
    s, c = 8, 6
    rng = np.random.default_rng(11)
    fa = np.zeros((s, c), bool)
    fa[:2, 1] = True
    arms = []
    for i in range(2):
        lv = {}
        for j, name in enumerate(verdicts.RESTARTS):
            cells = np.log(0.02) + rng.normal(0, 0.3, c)
            fails = fa if (i, j) == (0, 0) else None
            lv[name] = _held(np.exp(np.tile(cells, (s, 1))), fails)
        arms.append(lv)
    lay = fp.layout(arms)
    assert lay["varying"][1] and lay["noise"]["varying"] == 1
    rho = 1.3
    truths = fp.pairing_truths(lay, math.log(rho), True)
    assert len(set(np.round(truths, 9))) == len(truths)  # the restarts' offsets differ
    with_varying = 0
    draws = np.random.default_rng(12)
    for _ in range(60):
        a, b = fp.draw(lay, np.array([math.log(rho), 0.0]), 0.0, draws, as_run=True)
        v = verdicts.across(a, b)
        for (la, lb), t in zip(verdicts.PAIRINGS, truths, strict=True):
            p = v["tuned"] if (la, lb) == verdicts.PAIRINGS[0] else v["by"][f"{la} / {lb}"]
            assert p["mean_log_ratio"] == pytest.approx(t, abs=1e-9), (la, lb)
            with_varying += p["common_cells"] == int(lay["tracked"].sum()) + 1
    assert with_varying > 0  # the varying cell was shared in some draws


def test_a_varying_cells_tracked_runs_take_a_tracked_cells_residuals():
    """A cell where one level fails at a few seeds has no cell mean of its own to resample
    about: its tracked runs take the residuals of a tracked cell drawn at random, so they vary
    over the seeds as the tracked cells' runs do (not a constant)."""
    s, c = 10, 6
    fa = np.zeros((s, c), bool)
    fa[:2, 1] = True
    lay = fp.layout(_arms(seeds=s, cells=c, run_sd=0.1, fails={(0, 0): fa}))
    assert lay["varying"][1]
    rng = np.random.default_rng(21)
    spread = []
    for _ in range(50):
        a, _ = fp.draw(lay, np.zeros(2), 0.0, rng)
        x = a["tuned-other"]  # a level that tracks the varying cell at every seed unless moved
        ok = x[:, 1, -1] == 0
        if ok.sum() > 2:
            spread.append(np.std(np.log(x[ok, 1, TAIL])))
    assert spread and np.median(spread) > 0.02, spread
