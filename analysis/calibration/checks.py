"""The consistency checks of the calibration record's planted-truth and sensitivity blocks
(``analysis.calibration.check`` calls them): each count, proportion and decision recomputed
from the per-truth values and the design's points it summarises."""

from __future__ import annotations

import math

import numpy as np

from analysis.calibration import pawn as pawnmod
from analysis.calibration import rule, stages

__all__ = ["proportion", "planted", "pawn"]


def proportion(x: dict) -> None:
    """A proportion of the record is its count's: p = k / n and the Clopper-Pearson interval."""
    assert x["p"] == (x["k"] / x["n"] if x["n"] else None), x
    lo, hi = rule.clopper_pearson(x["k"], x["n"])
    assert math.isclose(x["ci_low"], lo, abs_tol=1e-9), x
    assert math.isclose(x["ci_high"], hi, abs_tol=1e-9), x


def planted(pl: dict, distances) -> None:
    """A planted-truth block's counts, proportions and decisions follow from its per-truth
    maximum implausibilities and moves."""
    c, it, ia = pl["threshold"], pl["max_implausibility_truth"], pl["max_implausibility_away"]
    assert pl["nominal"] == rule.LEVEL
    assert pl["coverage"]["n"] == pl["n_truths"] == len(it) == len(ia)
    assert pl["coverage"]["k"] == sum(i <= c for i in it)
    assert set(pl["power"]) == {f"{d:g}" for d in distances}, pl["power"]
    acc = [i <= c for i in it]
    fin = pl["truth_all_finite"]
    assert len(fin) == len(it)
    cf = pl["coverage_all_finite"]
    assert (cf["n"], cf["k"]) == (sum(fin), sum(a and f for a, f in zip(acc, fin, strict=True)))
    n_fin = cf["n"]
    for j, key in enumerate(pl["power"]):
        assert pl["power"][key]["k"] == sum(r[j] > c for r in ia), key
        sel = [t for t, kept in enumerate(pl["discrete_kept"]) if kept[j]]
        cont = pl["power_continuous_only"][key]  # the moves that kept every discrete level
        assert (cont["n"], cont["k"]) == (len(sel), sum(ia[t][j] > c for t in sel)), key
        given = pl["power_given_accepted"][key]  # around the accepted truths
        assert given["n"] == sum(acc), (key, given)
        assert given["k"] == sum(a and r[j] > c for a, r in zip(acc, ia, strict=True)), key
        pf = pl["power_all_finite"][key]
        assert (pf["n"], pf["k"]) == (n_fin, sum(f and r[j] > c for f, r in
                                                 zip(fin, ia, strict=True))), key
        med = float(np.median([d[j] for d in pl["actual_distance"]]))
        assert math.isclose(pl["power"][key]["actual_distance_median"], med), key
        for block in ("power", "power_continuous_only", "power_given_accepted",
                      "power_all_finite"):  # fmt: skip
            proportion(pl[block][key])
    for x in (pl["coverage"], pl["coverage_all_finite"]):
        proportion(x)
    # the same runs at other discrepancies and at the earlier threshold: each proportion is its
    # count's (the counts themselves are not recounted: the per-truth values are recorded at
    # the verdict's discrepancy only)
    earlier = {k: v for k, v in pl.get("by_delta_earlier_threshold", {}).items()
               if isinstance(v, dict)}  # fmt: skip
    for block in [*pl["by_delta"].values(), *earlier.values()]:
        for x in (block["coverage"], *block["power"].values()):
            proportion(x)
    if "added_after_seen" in pl:  # the fresh block: the distances added once it was seen
        assert pl["added_after_seen"] == list(rule.ADDED_AFTER_SEEN), pl["added_after_seen"]
        assert {f"{d:g}" for d in pl["added_after_seen"]} <= set(pl["power"])
    power = pl["power"]
    assert pl["too_loose"] == (power[f"{rule.DECIDE_AT:g}"]["p"] < 0.9)
    reach = [float(d) for d, pw in power.items() if pw["p"] >= 0.9]
    whole = [float(d) for d, pw in power.items() if pw["ci_low"] >= 0.9]
    assert pl["resolves_at"] == {"target": 0.9, "point": min(reach) if reach else None,
                                 "interval": min(whole) if whole else None}, pl["resolves_at"]


def pawn(record: dict) -> None:
    """Each PAWN output's rows: every point for the diverged share, the tracked points for
    the discrepancy and the tau; its settings above the dummy are those whose index exceeds
    the dummy's bound; its tied groups partition the settings and the dummy."""
    sen, pts = record["sensitivity"]["pawn"], record["points"]
    tracked = pts["n"] - pts["n_diverged_points"]
    want = {"diverged_share": pts["n"], "rms_log_ratio": tracked, "kendall_tau": tracked}
    for o, x in sen["indices"].items():
        if x is None:
            continue
        if o in want:
            assert x["n"] == want[o], (o, x["n"], want[o])
        else:
            assert tracked <= x["n"] <= pts["n"], (o, x["n"])
        _pawn_entry(x, o)
    # the every-point analysis: exactly the outputs with a worse end (a law's log RMSE, the
    # discrepancy) whose tracked analysis exists; the report's clear/near split reads it
    every = sen["every_point"]["outputs"]
    worse = [o for o in stages.WORSE_END if sen["indices"].get(o) is not None]
    assert sorted(o for o, x in every.items() if x is not None) == sorted(worse), list(every)
    for o, x in every.items():
        if x is not None:
            assert x["n"] == pts["n"], (o, x["n"])
            _pawn_entry(x, o)


def _pawn_entry(x: dict, o: str) -> None:
    """One output's PAWN entry: the settings above the inert floor (``dummy_high``, the null's
    95th percentile) are those whose index exceeds it; the tied groups are :func:`pawn.ties` of
    the indices.  The indices, intervals and floor themselves are not recomputed (the design's
    outputs are not in the record)."""
    names = [n for n in x["indices"] if n != "dummy"]
    assert x["above_dummy"] == [n for n in names
                                if x["indices"][n]["index"] > x["dummy_high"]], o
    assert x["ties"] == pawnmod.ties(x["indices"]), o
