"""The reproduction study's statistics on hand-made rows: means, stds, ranking, paired tests
(``analysis.reproduction.stats`` and ``analysis.reproduction.summarise``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import reproduction as rep
from analysis.reproduction import stats as st
from wmr.closedloop.result import Row


def _row(controller, seed, pos, scenario="lemniscate", diverged=False):
    value = math.nan if diverged else pos
    return Row(scenario, controller, "default", seed, value, value, value, value, diverged,
               tail_x=value, tail_y=value, tail_theta=value, tail_position=value)  # fmt: skip


def test_paired_difference_wins_and_wilcoxon():
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    b = a + np.array([0.5, 0.4, 0.6, 0.3, 0.7])  # a better on every seed
    r = st.paired(a, b)
    assert r["n"] == 5 and r["wins"] == 5
    assert r["mean_diff"] == pytest.approx(-0.5)
    assert r["std_diff"] == pytest.approx(np.std(a - b, ddof=1))
    assert r["wilcoxon_p"] == pytest.approx(0.0625)  # exact two-sided, n = 5, all one sign: 2/2^5
    assert st.paired(a, a)["wilcoxon_p"] == 1.0  # no difference at all
    nan_b = b.copy()
    nan_b[0] = np.nan
    assert st.paired(a, nan_b)["n"] == 4  # a diverged seed is left out of the pairing


def test_summarise_statistics_and_rankings():
    rows = [_row(c, s, base + 0.01 * s) for c, base in
            (("backstepping", 0.1), ("iapid-nn-dekf", 0.3), ("adaptive-pid", 0.2),
             ("adaptive-nn", 0.4)) for s in range(3)]  # fmt: skip
    out = rep.summarise(rows)["scenarios"]["lemniscate"]
    rec = out["runs"]["adaptive-pid"]["default"]["position"]
    assert rec["mean"] == pytest.approx(0.21) and rec["std"] == pytest.approx(0.01)  # ddof = 1
    assert rec["n"] == 3
    assert out["ranking"]["default"]["x"] == ["backstepping", "adaptive-pid", "iapid-nn-dekf",
                                              "adaptive-nn"]  # fmt: skip
    # the paper's order (IAPID < APID < DA-NN < BSC) is not this one
    assert out["paper_ranking_reproduced"] == {"x": False, "y": False, "theta": False}


def test_a_diverging_controller_ranks_last_and_is_counted():
    rows = [_row("backstepping", s, 0.1) for s in range(3)]
    rows += [_row("iapid-nn-dekf", s, 0.05, diverged=(s == 1)) for s in range(3)]
    rows += [_row(c, s, 0.2) for c in ("adaptive-pid", "adaptive-nn") for s in range(3)]
    out = rep.summarise(rows)["scenarios"]["lemniscate"]
    assert out["ranking"]["default"]["position"][-1] == "iapid-nn-dekf"
    assert out["runs"]["iapid-nn-dekf"]["default"]["n_diverged"] == 1
    assert out["runs"]["iapid-nn-dekf"]["default"]["position"]["n"] == 2


def test_holm_adjustment_matches_the_step_down_definition():
    p = [0.01, 0.04, 0.03, 0.005]
    # sorted 0.005, 0.01, 0.03, 0.04 -> 4*0.005, 3*0.01, 2*0.03, 1*0.04, made monotone
    assert st.holm(p) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert st.holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])  # capped at 1


def test_tie_aware_check_ignores_noise_and_flags_significant_reversals():
    """Paper order IAPID < APID < DA-NN < BSC.  Here BSC is clearly best on every seed (a
    significant reversal of three pairs), while IAPID and APID swap by pure noise."""
    rng = np.random.default_rng(0)
    seeds = range(20)
    noise = {s: rng.normal(0, 0.01) for s in seeds}
    rows = [_row("iapid-nn-dekf", s, 0.30 + noise[s] + rng.normal(0, 0.02)) for s in seeds]
    rows += [_row("adaptive-pid", s, 0.30 + noise[s] + rng.normal(0, 0.02)) for s in seeds]
    rows += [_row("adaptive-nn", s, 0.40 + noise[s]) for s in seeds]
    rows += [_row("backstepping", s, 0.10 + noise[s]) for s in seeds]
    out = rep.summarise(rows)["scenarios"]["lemniscate"]
    contra = out["paper_ranking_contradicted"]["x"]
    flagged = {(c["paper_worse"], c["paper_better"]) for c in contra}
    assert flagged == {("backstepping", "iapid-nn-dekf"), ("backstepping", "adaptive-pid"),
                       ("backstepping", "adaptive-nn")}  # fmt: skip
    assert all(c["p_holm"] < st.ALPHA and c["mean_diff"] > 0
               for c in out["paper_ranking_contradicted"]["x"])  # fmt: skip


# --- "the same controller": equivalence tests; the best controller with a variant --------------


def _rows(controller, values, scenario="lemniscate", variant="default"):
    return [Row(scenario, controller, variant, s, v, v, v, v, False, tail_x=v, tail_y=v,
                tail_theta=v, tail_position=v) for s, v in enumerate(values)]  # fmt: skip


def test_equivalence_is_the_tost_and_wilcoxon_of_wmr_stats_with_holm_over_the_family():
    """Oracle: ``wmr.stats.tost``/``wilcoxon``/``holm`` called directly on the same per-seed
    numbers.  IAPID and APID differ by +0.2 mm +- noise (equivalent at 1 mm, and detectable),
    APID and the fixed PID by 3 mm (not equivalent)."""
    from wmr import stats

    rng = np.random.default_rng(3)
    base = 0.05 + rng.normal(0, 1e-3, 20)
    arms = {"iapid-nn-dekf": base + 2e-4 + rng.normal(0, 5e-5, 20), "adaptive-pid": base,
            "pid": base + 3e-3 + rng.normal(0, 5e-5, 20)}  # fmt: skip
    rows = [r for sc in ("lemniscate", "sinusoid") for c, v in arms.items()
            for r in _rows(c, v, scenario=sc)]  # fmt: skip
    eq = st.equivalence(st.by_run(rows), ["lemniscate", "sinusoid"], metrics=("position",))
    got = eq["lemniscate"]["iapid-nn-dekf vs adaptive-pid"]["position"]
    want = stats.tost(arms["iapid-nn-dekf"], arms["adaptive-pid"], st.MARGIN, st.ALPHA).to_json()
    assert {k: got[k] for k in want} == want
    d_a = arms["iapid-nn-dekf"] - arms["adaptive-pid"]
    d_b = arms["adaptive-pid"] - arms["pid"]
    assert got["wilcoxon_p"] == stats.wilcoxon(d_a)
    # the family: 2 pairs x 2 scenarios, in (scenario, pair) order
    family = [stats.wilcoxon(d) for d in (d_a, d_b, d_a, d_b)]
    assert got["p_holm"] == stats.holm(family)[0]
    assert got["equivalent"] and got["different"]
    other = eq["sinusoid"]["adaptive-pid vs pid"]["position"]
    assert not other["equivalent"] and other["different"]
    assert other["ci_high"] < -st.MARGIN  # the 90 % interval lies below -1 mm


def test_equivalence_leaves_out_a_pair_with_fewer_than_two_runs():
    rows = _rows("adaptive-pid", [0.05]) + _rows("pid", [0.051])
    assert st.equivalence(st.by_run(rows), ["lemniscate"]) == {}


def test_lowest_mean_takes_the_variant_runs_where_a_controller_has_them():
    """Feed-forward halves the PID's error: without it backstepping is best, with it the PID."""
    rows = _rows("backstepping", [0.030, 0.032]) + _rows("pid", [0.050, 0.052])
    rows += _rows("pid", [0.020, 0.022], variant="feed-forward")
    table = st.by_run(rows)
    names = ["backstepping", "pid"]
    without = st.lowest_mean(table, "lemniscate", names)
    with_ff = st.lowest_mean(table, "lemniscate", names, "feed-forward")
    assert without["best"] == "backstepping" and without["mean"] == pytest.approx(0.031)
    assert without["on_variant"] == names  # the default runs are the "variant" here
    assert with_ff["best"] == "pid" and with_ff["mean"] == pytest.approx(0.021)
    assert with_ff["on_variant"] == ["pid"]
    assert with_ff["means"]["backstepping"] == pytest.approx(0.031)  # its default runs


def test_a_diverged_controller_is_never_the_lowest_mean():
    rows = _rows("backstepping", [0.030, 0.032]) + _rows("pid", [0.001, math.nan])
    best = st.lowest_mean(st.by_run(rows), "lemniscate", ["backstepping", "pid"])
    assert best["best"] == "backstepping" and best["means"]["pid"] is None
