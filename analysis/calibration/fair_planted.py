"""The fair tuning's comparison rule on planted truth (DESIGN §7.6; issue 23 item 6): does the
rule of ``analysis.calibration.verdicts`` accept the truth at nominal 95 %, and how large must a
difference be before it names it?

- **From the real runs, not from the interval's own model** (:func:`layout`, :func:`draw`).
  For each comparison the report makes (each matched arm against the candidate best, and the
  paper's arm against the same law on the raw pose), the real held-out runs of the four
  arm-levels it reads (each arm's best and runner-up restart, on the main cells) give, on the
  cells where no level fails to track at any seed, each level's log RMSE residuals about its
  own cell means (its systematic differences removed: every level has the same truth).  A
  synthetic comparison resamples the seeds with replacement, the same seeds for every level
  (a seed bootstrap: the real seed effects, tails, cell-dependent spread and correlation
  between the arms and between one law's two restarts all carried along), and sets each
  run's log RMSE to a common centre plus its residual plus the planted log ratio (in arm a's
  levels only).  The centre keeps every such run well below the tracking threshold, so that
  no planted ratio makes a failure.
- **Failures**: a cell where each arm fails at every seed or at none (at both restarts) is a
  systematic difference, not noise: every level fails there.  In the other cells with a
  failure, each resampled seed's failure rows are exchanged between the arms at random (a
  random permutation per seed): the real failures that vary over the seeds, with no
  difference between the arms in law (the null); their tracked runs carry the planted ratio
  without noise.  Where a failure difference is planted, arm a's runs also fail at an extra
  probability ``f`` (anywhere).
- **Truth and words** (:func:`false_of`): with ``f = 0`` and planted ratio ``rho``, "fails
  more" and "fails less" are false; "higher" and "worse" when ``rho <= 1``, "lower" and
  "better" when ``rho >= 1``, "equivalent" when ``|log rho| >= log 1.05``.  With ``f > 0``
  (at ``rho = 1``) "fails less", "lower", "better", "higher" and "equivalent" (arm a does
  fail more) are false.  "tie", "mixed", "undetermined" and "restart-dependent" claim nothing
  (the report words them so).  The rule **accepts the truth** when the comparison's verdict
  is not false of it; its **power** is the share naming the planted truth ("equivalent"
  inside the margin, else "higher" or "worse" above 1 and "lower" or "better" below; "fails
  more" or "worse" with ``f > 0``); the best/best pairing's 95 % t interval's **coverage**
  of ``log rho`` is beside them (a seed bootstrap shrinks a sample's spread by about
  ``(S - 1) / S``: slightly under 95 % is expected).
- **The best arm** (:func:`best_claims`): every matched arm's two levels, from the same
  real runs (all arms' residuals, the cells where no arm fails, failure rows exchanged
  among all arms per seed); with all arms equal, the share of replicates where a best is
  claimed (each claim false), and with one arm planted better (ratio ``rho`` to the others)
  the share claiming that arm and the share claiming another.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from analysis.calibration import verdicts
from analysis.regimes import coverage as rcov
from analysis.regimes import stats as rstats

__all__ = ["RATIOS", "FAIL_EXTRA", "BEST_RATIOS", "false_of", "layout", "draw", "planted_pair",
           "best_claims", "study", "check", "REPLICATES", "ACCEPT"]  # fmt: skip

#: Planted RMSE ratios of arm a to arm b (1.02 and 0.97: inside the ±5 % margin).
RATIOS = (1.0, 1.02, 0.97, 1.05, 0.95, 1.10, 0.90, 1.20, 0.80, 1.50)
#: Planted extra failure probabilities of arm a's runs (at ratio 1).
FAIL_EXTRA = (0.02, 0.05, 0.10)
#: The planted advantage of one arm in the best-arm study (its RMSE ratio to the others').
BEST_RATIOS = (1.0, 0.90, 0.80)
#: Replicates per condition at the medium and full levels.
REPLICATES = 200
#: The share of replicates the rule must accept the truth in (DESIGN §7.6).
ACCEPT = 0.9
_TAIL = verdicts._TAIL
#: The synthetic runs' largest RMSE, as a share of the tracking threshold.
_HEADROOM = 0.25


def false_of(word: str, rho: float, f: float) -> bool:
    """Whether the verdict ``word`` (a pairing's or the four pairings') is false of a planted
    ratio ``rho`` with planted extra failure ``f`` (see the module)."""
    lr = math.log(rho)
    if f > 0:
        return word in ("fails less", "lower", "better", "higher", "equivalent")
    return ((word in ("fails more", "fails less"))
            or (word in verdicts.WORSE + ("worse",) and lr <= 0)
            or (word in verdicts.BETTER + ("better",) and lr >= 0)
            or (word == "equivalent" and abs(lr) >= verdicts.EQUIV))  # fmt: skip


def _right(word: str, rho: float, f: float) -> bool:
    """Whether ``word`` names the planted truth (the rule's power)."""
    if f > 0:
        return word in ("fails more", "worse")
    if abs(math.log(rho)) < verdicts.EQUIV:
        return word == "equivalent"
    return word in (("higher", "worse") if rho > 1 else ("lower", "better"))


def layout(arms: Sequence[Mapping[str, np.ndarray]]) -> dict | None:
    """The real runs of ``arms`` (each: restart level -> held-out result (seeds, cells,
    metrics), restricted to the compared cells) as the planted comparisons' material (see the
    module): ``resid`` (arms, levels, seeds, cells) log RMSE residuals (zero off ``tracked``),
    ``fails`` the failure masks, the cells ``tracked`` (no level fails at any seed),
    ``systematic`` (each arm fails at every seed or at none) and ``varying`` (the rest), and a
    description of the noise: the first two arms' best/best ``seed_sd`` and ``pair_sd`` (the
    regime study's method of moments) and ``random_failures``, the share of all the levels'
    runs that fail in the varying cells.  None with fewer than 3 seeds or 2 tracked cells."""
    import pandas as pd

    rs = [[verdicts._runs(a[lv]) for lv in verdicts.RESTARTS] for a in arms]
    logr = np.array([[np.log(r) for r, _, _ in lv] for lv in rs])
    fails = np.array([[f for _, _, f in lv] for lv in rs])
    n_arms, _, s, c = fails.shape
    tracked = ~fails.any(axis=(0, 1, 2))
    if s < 3 or tracked.sum() < 2:
        return None
    per_arm = fails.reshape(n_arms, -1, c)
    systematic = ~tracked & (per_arm.all(axis=1) | ~per_arm.any(axis=1)).all(axis=0)
    resid = np.where(tracked, logr - logr.mean(axis=2, keepdims=True), 0.0)
    d = resid[0, 0][:, tracked] - resid[1, 0][:, tracked]
    frame = pd.DataFrame({"mechanism": "pair", "pose": "raw",
                          "trajectory": np.tile(np.arange(d.shape[1]), s),
                          "seed": np.repeat(np.arange(s), d.shape[1]), "delta": d.ravel()})
    varying = ~tracked & ~systematic
    return {"resid": resid, "fails": fails, "tracked": tracked, "systematic": systematic,
            "varying": varying,
            "noise": {**rcov.noise(frame)["pair"],
                      "random_failures": float(fails[..., varying].sum() / fails.size),
                      "seeds": int(s), "cells": int(c), "tracked": int(tracked.sum()),
                      "systematic": int(systematic.sum()),
                      "varying": int(varying.sum())}}  # fmt: skip


def draw(lay: Mapping, log_shift: np.ndarray, f: float, rng: np.random.Generator) -> list:
    """One synthetic set of the layout's arms (see the module): per arm a dict level -> held-out
    result, arm ``i``'s log RMSE shifted by ``log_shift[i]``, the first arm's runs failing at
    an extra probability ``f``."""
    resid, fails = lay["resid"], lay["fails"]
    n_arms, n_lv, s, c = fails.shape
    idx = rng.integers(0, s, s)
    r, fl = resid[:, :, idx], fails[:, :, idx].copy()
    perm = np.argsort(rng.random((s, n_arms)), axis=1)  # a permutation of the arms per seed
    swapped = fl[perm.T, :, np.arange(s)[None, :]].transpose(0, 2, 1, 3)
    fl = np.where(lay["varying"], swapped, fl)
    fl[..., lay["systematic"]] = True
    if f > 0:
        fl[0] |= rng.random(fl[0].shape) < f
    shift = np.asarray(log_shift, float)[:, None, None, None]
    top = float(np.max(np.abs(resid))) + float(np.max(np.abs(log_shift)))
    centre = math.log(_HEADROOM * rstats.TRACKING_M) - top
    logr = centre + shift + np.where(lay["tracked"], r, 0.0)
    out = []
    for i in range(n_arms):
        lv = {}
        for j, name in enumerate(verdicts.RESTARTS):
            arr = np.zeros((s, c, len(verdicts.METRICS) + 1))
            arr[..., _TAIL] = np.exp(logr[i, j])
            arr[..., -1] = fl[i, j]
            lv[name] = arr
        out.append(lv)
    return out


def _share(k: int, n: int) -> dict:
    if n == 0:
        return {"k": 0, "n": 0, "share": None, "ci_low": None, "ci_high": None}
    d = rstats.divergence(np.arange(n) < k)
    return {"k": int(k), "n": int(n), **{x: d[x] for x in ("share", "ci_low", "ci_high")}}


def planted_pair(lay: Mapping, rho: float, f: float, replicates: int,
                 rng: np.random.Generator) -> dict:  # fmt: skip
    """The rule (``verdicts.across``) on ``replicates`` synthetic comparisons of a two-arm
    :func:`layout` at one planted truth: the verdicts' shares, acceptance of the truth (the
    four pairings' verdict; the best/best pairing's word beside it), power, and the best/best
    t interval's coverage of the planted log ratio (with ``f = 0``, where it has one)."""
    words: dict[str, int] = {}
    accepts = accepts_tuned = right = covered = with_ci = 0
    lr = math.log(rho)
    for _ in range(replicates):
        a, b = draw(lay, np.array([lr, 0.0]), f, rng)
        v = verdicts.across(a, b)
        w = v["verdict"]
        words[w] = words.get(w, 0) + 1
        accepts += not false_of(w, rho, f)
        accepts_tuned += not false_of(v["tuned"]["word"], rho, f)
        right += _right(w, rho, f)
        if f == 0 and v["tuned"]["ci"] is not None:
            with_ci += 1
            covered += v["tuned"]["ci"][0] <= lr <= v["tuned"]["ci"][1]
    return {"rho": rho, "f": f, "verdicts": {k: words[k] / replicates for k in sorted(words)},
            "accepts": _share(accepts, replicates),
            "accepts_best_pairing": _share(accepts_tuned, replicates),
            "power": _share(right, replicates),
            "coverage": _share(covered, with_ci) if f == 0 else None}  # fmt: skip


def best_claims(lay: Mapping, names: list[str], rho: float, replicates: int,
                rng: np.random.Generator) -> dict:  # fmt: skip
    """The best-arm claim (``verdicts.compare``) on ``replicates`` synthetic sets of the arms
    ``names`` (their :func:`layout`, in that order), the first planted at ratio ``rho`` to the
    others (1: all equal): the share of replicates claiming a best (``claims``), claiming the
    planted one (``right``; only below 1) and claiming another (``wrong``)."""
    claims = right = 0
    shift = np.zeros(len(names))
    shift[0] = math.log(rho)
    cols = np.ones(lay["fails"].shape[-1], bool)
    for _ in range(replicates):
        runs = dict(zip(names, draw(lay, shift, 0.0, rng), strict=True))
        c = verdicts.compare(runs, names, cols)
        claims += c["best_determined"]
        right += c["best_determined"] and rho < 1 and c["best"] == names[0]
    return {"rho": rho, "arms": len(names), "claims": _share(claims, replicates),
            "right": _share(right, replicates),
            "wrong": _share(claims - right, replicates)}  # fmt: skip


def _conditions() -> list[tuple[float, float]]:
    return [(r, 0.0) for r in RATIOS] + [(1.0, f) for f in FAIL_EXTRA]


def study(runs: Mapping[str, Mapping[str, np.ndarray]], comparisons: Mapping[str, tuple],
          main: np.ndarray, matched: list[str], replicates: int = REPLICATES,
          seed: int = 23) -> dict:  # fmt: skip
    """The rule on planted truth for the record's ``comparisons`` (label -> (a, b): arm names
    of ``runs``, level -> held-out result (seeds, cells, metrics)) on the cells ``main`` (see
    the module), and the best-arm claim over ``matched``.  The summary: the least acceptance
    over the comparisons and truths (with its interval), and per planted truth the least
    power and coverage."""
    def levels(n: str) -> dict:
        return {lv: runs[n][lv][:, main] for lv in verdicts.RESTARTS}

    out: dict = {"replicates": replicates, "seed": seed, "ratios": list(RATIOS),
                 "fail_extra": list(FAIL_EXTRA), "accept_target": ACCEPT,
                 "comparisons": {}}  # fmt: skip
    for k, (label, (a, b)) in enumerate(comparisons.items()):
        lay = layout([levels(a), levels(b)])
        entry: dict = {"arms": [a, b], "noise": None if lay is None else lay["noise"]}
        if lay is not None:
            entry["truths"] = [planted_pair(lay, r, f, replicates,
                                            np.random.default_rng([seed, k, i]))
                               for i, (r, f) in enumerate(_conditions())]  # fmt: skip
        out["comparisons"][label] = entry
    out.update(summarise(out))
    lay = layout([levels(n) for n in matched]) if len(matched) > 1 else None
    out["best"] = None if lay is None else {
        "noise": lay["noise"], "arms": list(matched),
        "by_rho": [best_claims(lay, list(matched), r, replicates,
                               np.random.default_rng([seed, 10**6, i]))
                   for i, r in enumerate(BEST_RATIOS)]}  # fmt: skip
    return out


def summarise(pl: Mapping) -> dict:
    """The summary of the planted comparisons ``pl["comparisons"]``: the least acceptance (and
    where), whether every truth is accepted at :data:`ACCEPT`, and per planted truth the least
    power and the least coverage over the comparisons (empty without a planted comparison)."""
    done = [c for c in pl["comparisons"].values() if c["noise"] is not None]
    if not done:
        return {}
    rows = [(label, r) for label, c in pl["comparisons"].items() if c["noise"] is not None
            for r in c["truths"]]  # fmt: skip
    label, least = min(rows, key=lambda x: x[1]["accepts"]["share"])
    conds = _conditions()

    def key(r: float, f: float) -> str:
        return f"{r:g}" if f == 0 else f"{r:g}+f{f:g}"

    return {"least_accepts": {**least["accepts"], "rho": least["rho"], "f": least["f"],
                              "comparison": label},
            "accepts_at_target": all(r["accepts"]["share"] >= ACCEPT for _, r in rows),
            "least_power": {key(r, f): min(c["truths"][i]["power"]["share"] for c in done)
                            for i, (r, f) in enumerate(conds)},
            "least_coverage": {key(r, f): min(c["truths"][i]["coverage"]["share"]
                                              for c in done)
                               for i, (r, f) in enumerate(conds)
                               if f == 0 and all(c["truths"][i]["coverage"]["n"]
                                                 for c in done)}}  # fmt: skip


def check(pl: Mapping) -> None:
    """The record's planted-truth part is whole and its summary follows from its rows; the
    rule accepts the truth in at least :data:`ACCEPT` of every planted comparison (DESIGN
    §7.6).  The rows themselves need the runs: ``study`` on the stores recomputes them."""
    assert pl["ratios"] == list(RATIOS) and pl["fail_extra"] == list(FAIL_EXTRA), pl["ratios"]
    conds = _conditions()
    for label, c in pl["comparisons"].items():
        if c["noise"] is None:
            assert "truths" not in c, label
            continue
        assert [(r["rho"], r["f"]) for r in c["truths"]] == conds, label
        for r in c["truths"]:
            for k in ("accepts", "accepts_best_pairing", "power"):
                x = r[k]
                assert x["n"] == pl["replicates"] and 0 <= x["k"] <= x["n"], (label, k, r)
                assert math.isclose(x["share"], x["k"] / x["n"]), (label, k, r)
                assert x["ci_low"] <= x["share"] <= x["ci_high"], (label, k, r)
            assert math.isclose(sum(r["verdicts"].values()), 1.0), (label, r)
            assert (r["coverage"] is None) == (r["f"] > 0), (label, r)
            want = sum(v for w, v in r["verdicts"].items() if not false_of(w, r["rho"], r["f"]))
            assert math.isclose(r["accepts"]["share"], want, abs_tol=1e-9), (label, r)
            want = sum(v for w, v in r["verdicts"].items() if _right(w, r["rho"], r["f"]))
            assert math.isclose(r["power"]["share"], want, abs_tol=1e-9), (label, r)
    summary = summarise(pl)
    assert {k: pl.get(k) for k in summary} == summary, "the planted summary is not its rows'"
    if summary:
        assert pl["accepts_at_target"], f"the rule rejects planted truth: {pl['least_accepts']}"
    if pl.get("best"):
        for b in pl["best"]["by_rho"]:
            assert b["claims"]["k"] == b["right"]["k"] + b["wrong"]["k"], b
            assert b["rho"] < 1 or b["right"]["k"] == 0, b
