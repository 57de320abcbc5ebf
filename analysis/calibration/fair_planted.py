"""The fair tuning's comparison rule on planted truth (DESIGN §7.6; issue 23 item 6): does the
rule of ``analysis.calibration.verdicts`` accept the truth at nominal 95 %, and how large must a
difference be before it names it?

- **Layout**: the record's.  For each comparison the report makes (each matched arm against the
  candidate best, and the paper's arm against the same law on the raw pose), the reference
  arm's real held-out runs at its best restart (``b``'s ``tuned`` level on the main cells: its
  seeds, cells and the runs that fail to track) are the **base**.  Each of the four arm-levels
  a comparison reads (a's and b's best and runner-up restarts) is the base with its position
  RMSE multiplied by ``exp(planted + seed effect + own noise)``; the planted log ratio is in
  arm a's two levels only, so every pairing has the same truth.
- **Noise at the record's levels**: the real pair's per-run log ratios ``log r_a - log r_b`` on
  the cells where both track at every seed, decomposed over the seeds into a seed effect and a
  run's own noise (``analysis.regimes.coverage.noise``, the regime study's method of moments);
  each arm-level gets half of each variance, so that the difference of two levels has the real
  pair's.  Tracking failures: the base's are every level's; beyond them each level's runs fail
  independently at half the real pair's discordance that varies over the seeds (so two levels
  disagree at about that rate; a null difference in failures: a cell where one arm fails at
  every seed is a systematic difference, left out), and where a failure difference is
  planted, arm a's levels fail at an extra probability ``f``.  Real failures cluster by plant;
  independent ones are a simplification, said in the record.
- **Truth and words** (:func:`false_of`): with ``f = 0`` and planted ratio ``rho``, "fails more"
  and "fails less" are false; "higher" and "worse" are false when ``rho <= 1``, "lower" and
  "better" when ``rho >= 1``, "equivalent" when ``|log rho| >= log 1.05``.  With ``f > 0`` (at
  ``rho = 1``) "fails less", "lower", "better" and "higher" are false ("equivalent" is true of
  the accuracy).  "tie", "mixed", "undetermined" and "restart-dependent" claim nothing.  The
  rule **accepts the truth** when the comparison's verdict is not false of it; its **power** is
  the share naming the planted truth ("equivalent" inside the margin, else "higher" or "worse"
  above 1, "lower" or "better" below; "fails more" or "worse" with ``f > 0``).
- **The best arm** (:func:`best_claims`): all the matched arms on the pooled noise (the pairs'
  median standard deviations and discordance), each arm's levels independently noisy; with all
  arms equal, the share of replicates where a best is claimed (every claim is false), and with
  one arm planted better (each other arm's ratio to it ``1 / rho``) the share where the rule
  claims that arm, and where it claims another.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from analysis.calibration import verdicts
from analysis.regimes import coverage as rcov
from analysis.regimes import stats as rstats

__all__ = ["RATIOS", "FAIL_EXTRA", "BEST_RATIOS", "false_of", "pair_noise", "planted_pair",
           "best_claims", "study", "check", "REPLICATES", "ACCEPT"]  # fmt: skip

#: Planted RMSE ratios of arm a to arm b (1.02 and 0.97: inside the ±5 % margin).
RATIOS = (1.0, 1.02, 0.97, 1.05, 1.10, 0.90, 1.20, 1.50)
#: Planted extra failure probabilities of arm a's runs (at ratio 1).
FAIL_EXTRA = (0.02, 0.05, 0.10)
#: The planted advantage of one arm in the best-arm study (its RMSE ratio to the others').
BEST_RATIOS = (1.0, 0.90, 0.80)
#: Replicates per condition at the medium and full levels.
REPLICATES = 200
#: The share of replicates the rule must accept the truth in (DESIGN §7.6).
ACCEPT = 0.9
_TAIL = verdicts._TAIL


def false_of(word: str, rho: float, f: float) -> bool:
    """Whether the verdict ``word`` (a pairing's or the four pairings') is false of a planted
    ratio ``rho`` with planted extra failure ``f`` (see the module)."""
    lr = math.log(rho)
    if f > 0:
        return word in ("fails less", "lower", "better", "higher")
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


def pair_noise(arr_a: np.ndarray, arr_b: np.ndarray) -> dict | None:
    """The real pair's noise (see the module): ``seed_sd``, ``pair_sd`` [log units], the
    failure discordance (``discordance_all``: the share of runs where exactly one arm fails
    to track) and its part that varies over the seeds (``discordance``: the discordant runs
    of the cells where the arms disagree at some seeds but not at all, a share of all runs;
    a cell where one arm
    fails at every seed and the other at none is a systematic difference, not noise,
    ``systematic`` counts its runs); None with fewer than 3 seeds or 2 cells where both track
    at every seed."""
    import pandas as pd

    ra, _, fa = verdicts._runs(arr_a)
    rb, _, fb = verdicts._runs(arr_b)
    common = (~fa & ~fb).all(axis=0)
    s, c = ra.shape[0], int(common.sum())
    if s < 3 or c < 2:
        return None
    lr = np.log(ra[:, common] / rb[:, common])
    frame = pd.DataFrame({"mechanism": "pair", "pose": "raw",
                          "trajectory": np.tile(np.arange(c), s),
                          "seed": np.repeat(np.arange(s), c), "delta": lr.ravel()})  # fmt: skip
    sd = rcov.noise(frame)["pair"]
    dis = fa ^ fb
    always = dis.all(axis=0)
    return {**sd, "discordance": float(dis[:, ~always].sum() / dis.size),
            "discordance_all": float(dis.mean()), "systematic": int(dis[:, always].sum()),
            "cells": c, "seeds": s}  # fmt: skip


def _level(base: np.ndarray, shift: float, sd: Mapping, f: float,
           rng: np.random.Generator) -> np.ndarray:  # fmt: skip
    """One synthetic arm-level: the base's RMSE times ``exp(shift + seed effect + own noise)``
    (half the pair's variances), failures at half the discordance plus ``f``."""
    s, c = base.shape[:2]
    h = math.sqrt(0.5)
    eff = (shift + rng.normal(0.0, h * sd["seed_sd"], s)[:, None]
           + rng.normal(0.0, h * sd["pair_sd"], (s, c)))  # fmt: skip
    arr = base.copy()
    arr[..., _TAIL] = base[..., _TAIL] * np.exp(eff)
    fails = rng.random((s, c)) < 0.5 * sd["discordance"] + f
    arr[..., -1] = np.where(fails, 1.0, base[..., -1])
    return arr


def _share(k: int, n: int) -> dict:
    return {"k": int(k), "n": int(n), **{x: rstats.divergence(np.arange(n) < k)[x]
                                         for x in ("share", "ci_low", "ci_high")}}  # fmt: skip


def planted_pair(base: np.ndarray, sd: Mapping, rho: float, f: float, replicates: int,
                 rng: np.random.Generator) -> dict:  # fmt: skip
    """The rule (``verdicts.across``) on ``replicates`` synthetic comparisons of one planted
    truth: the verdicts' shares, acceptance of the truth (the four pairings' verdict and the
    best/best pairing's word), power, and the best/best t interval's coverage of the planted
    log ratio (where it has one)."""
    words: dict[str, int] = {}
    accepts = accepts_tuned = right = covered = with_ci = 0
    lr = math.log(rho)
    for _ in range(replicates):
        a = {lv: _level(base, lr, sd, f, rng) for lv in verdicts.RESTARTS}
        b = {lv: _level(base, 0.0, sd, 0.0, rng) for lv in verdicts.RESTARTS}
        v = verdicts.across(a, b)
        w = v["verdict"]
        words[w] = words.get(w, 0) + 1
        accepts += not false_of(w, rho, f)
        accepts_tuned += not false_of(v["tuned"]["word"], rho, f)
        right += _right(w, rho, f)
        if v["tuned"]["ci"] is not None:
            with_ci += 1
            covered += v["tuned"]["ci"][0] <= lr <= v["tuned"]["ci"][1]
    return {"rho": rho, "f": f, "verdicts": {k: words[k] / replicates for k in sorted(words)},
            "accepts": _share(accepts, replicates),
            "accepts_best_pairing": _share(accepts_tuned, replicates),
            "power": _share(right, replicates),
            "coverage": _share(covered, with_ci) if f == 0 and with_ci else None}  # fmt: skip


def best_claims(base: np.ndarray, sd: Mapping, names: list[str], rho: float, replicates: int,
                rng: np.random.Generator) -> dict:  # fmt: skip
    """The best-arm claim (``verdicts.compare``) on ``replicates`` synthetic sets of the arms
    ``names``, the first planted at ratio ``rho`` to the others (1: all equal): the share of
    replicates claiming a best (``claims``), claiming the planted one (``right``; only below
    1) and claiming another (``wrong``: every claim at ``rho = 1``)."""
    claims = right = 0
    for _ in range(replicates):
        runs = {n: {lv: _level(base, math.log(rho) if i == 0 else 0.0, sd, 0.0, rng)
                    for lv in verdicts.RESTARTS} for i, n in enumerate(names)}  # fmt: skip
        c = verdicts.compare(runs, names, np.ones(base.shape[1], bool))
        claims += c["best_determined"]
        right += c["best_determined"] and rho < 1 and c["best"] == names[0]
    return {"rho": rho, "arms": len(names), "claims": _share(claims, replicates),
            "right": _share(right, replicates),
            "wrong": _share(claims - right, replicates)}  # fmt: skip


def study(runs: Mapping[str, Mapping[str, np.ndarray]], comparisons: Mapping[str, tuple],
          main: np.ndarray, matched: list[str], replicates: int = REPLICATES,
          seed: int = 23) -> dict:  # fmt: skip
    """The rule on planted truth for the record's ``comparisons`` (label -> (a, b): arm names
    of ``runs``, level -> held-out result (seeds, cells, metrics)) on the cells ``main`` (see
    the module); each comparison's noise from its real best/best pair, its base b's best
    runs.  The summary: the least acceptance over the comparisons and truths with its interval,
    and per planted ratio the least power."""
    out: dict = {"replicates": replicates, "seed": seed, "ratios": list(RATIOS),
                 "fail_extra": list(FAIL_EXTRA), "accept_target": ACCEPT,
                 "comparisons": {}}  # fmt: skip
    noises = []
    for k, (label, (a, b)) in enumerate(comparisons.items()):
        base = runs[b]["tuned"][:, main]
        sd = pair_noise(runs[a]["tuned"][:, main], base)
        if sd is None:
            out["comparisons"][label] = {"arms": [a, b], "noise": None}
            continue
        noises.append(sd)
        conds = [(r, 0.0) for r in RATIOS] + [(1.0, f) for f in FAIL_EXTRA]
        rows = [planted_pair(base, sd, r, f, replicates, np.random.default_rng([seed, k, i]))
                for i, (r, f) in enumerate(conds)]  # fmt: skip
        out["comparisons"][label] = {"arms": [a, b], "noise": sd, "truths": rows}
    done = [c for c in out["comparisons"].values() if c["noise"] is not None]
    rows = [r for c in done for r in c["truths"]]
    if rows:
        least = min(rows, key=lambda r: r["accepts"]["share"])
        out["least_accepts"] = {**least["accepts"], "rho": least["rho"], "f": least["f"]}
        out["accepts_at_target"] = all(r["accepts"]["share"] >= ACCEPT for r in rows)
        out["least_power"] = {f"{r:g}": min(c["truths"][i]["power"]["share"] for c in done)
                              for i, r in enumerate(RATIOS)}  # fmt: skip
        out["least_power_fail"] = {f"{f:g}": min(c["truths"][len(RATIOS) + i]["power"]["share"]
                                                 for c in done)
                                   for i, f in enumerate(FAIL_EXTRA)}  # fmt: skip
    if noises and len(matched) > 1:
        pooled = {k: float(np.median([n[k] for n in noises]))
                  for k in ("seed_sd", "pair_sd", "discordance")}  # fmt: skip
        ref = out["comparisons"][next(iter(comparisons))]["arms"][1]
        base = runs[ref]["tuned"][:, main]
        out["best"] = {"noise": pooled, "base": ref,
                       "by_rho": [best_claims(base, pooled, list(matched), r, replicates,
                                              np.random.default_rng([seed, 99, i]))
                                  for i, r in enumerate(BEST_RATIOS)]}  # fmt: skip
    return out


def check(pl: Mapping) -> None:
    """The record's planted-truth summary follows from its rows, and the rule accepts the
    truth in at least :data:`ACCEPT` of every planted comparison (DESIGN §7.6)."""
    done = [c for c in pl["comparisons"].values() if c["noise"] is not None]
    rows = [r for c in done for r in c["truths"]]
    for r in rows:
        for k in ("accepts", "accepts_best_pairing", "power"):
            assert r[k]["n"] == pl["replicates"] and 0 <= r[k]["k"] <= r[k]["n"], (k, r)
            assert math.isclose(r[k]["share"], r[k]["k"] / r[k]["n"]), (k, r)
        assert math.isclose(sum(r["verdicts"].values()), 1.0), r
    if not rows:
        assert "least_accepts" not in pl
        return
    least = min(r["accepts"]["share"] for r in rows)
    assert math.isclose(pl["least_accepts"]["share"], least), (pl["least_accepts"], least)
    assert pl["accepts_at_target"] == (least >= pl["accept_target"])
    assert pl["accepts_at_target"], f"the rule rejects planted truth: {pl['least_accepts']}"
    for i, rho in enumerate(pl["ratios"]):
        want = min(c["truths"][i]["power"]["share"] for c in done)
        assert all(c["truths"][i]["rho"] == rho for c in done)
        assert math.isclose(pl["least_power"][f"{rho:g}"], want), (rho, want)
