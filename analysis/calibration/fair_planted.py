"""The fair tuning's comparison rule on planted truth (DESIGN §7.6; issue 23 item 6): does the
rule of ``analysis.calibration.verdicts`` accept the truth at nominal 95 %, and how large must a
difference be before it names it?

- **From the real runs, not from the interval's own model** (:func:`layout`, :func:`draw`).
  For each comparison the report makes (each matched arm against the candidate best, and the
  paper's arm against the same law on the raw pose), the real held-out runs of the four
  arm-levels it reads (each arm's best and runner-up restart, on the main cells) give, on the
  cells where no level fails to track at any seed, each level's log RMSE residuals about its
  own cell means.  A synthetic comparison resamples the seeds with replacement, the same
  seeds for every level (a seed bootstrap: the real seed effects, tails, cell-dependent
  spread and correlations between the arms and between one law's two restarts carried
  along), and sets each run's log RMSE to a common centre plus its residual plus the planted
  log ratio (in arm a's levels only).  The centre keeps every run at a quarter of the
  tracking threshold, so that no planted ratio makes a failure.
- **Two modes**.  *Same restarts* (``truths``): the levels' own cell means are removed, so
  every pairing has the planted truth; this isolates the law's noise.  *Restarts as run*
  (``as_run``): each level keeps its offset from its arm's mean over the two restarts (cell
  by cell; in a cell where failures vary, its mean offset over the tracked cells), so a
  pairing's truth is the planted log ratio plus the mean over the tracked cells of the two
  levels' offsets (:func:`pairing_truths`), whichever varying cells a draw's pairing has in
  common; the restarts' real differences are then part of the truth.
- **Failures**: a cell where every level fails at every seed or at none is a fixed
  difference, not noise: in the synthetic data every level fails there.  In the cells where
  some level's failures vary over the seeds, each resampled seed's failure rows are permuted
  at random among the four levels (a null in failures for every pairing, with the real
  failure pattern), and the runs that track there take the residuals of a tracked cell drawn
  at random.  Where a failure difference is planted, arm a's runs in the cells that can track
  also fail at an extra probability ``f``, independently (real failures cluster by plant:
  a simplification).
- **Truth and words** (:func:`false_of`): with ``f = 0``, "fails more" and "fails less" are
  false; "higher" and "worse" are false when some pairing's truth is ``<= 0`` (log ratio),
  "lower" and "better" when some is ``>= 0``, "equivalent" when some is outside ``±log
  1.05``.  With ``f > 0`` (at ratio 1) "fails less", "lower", "better", "higher" and
  "equivalent" (arm a does fail more) are false.  "tie", "mixed", "undetermined" and
  "restart-dependent" claim nothing (the report words them so).  The rule **accepts the
  truth** when the comparison's verdict is not false of it (each pairing's word against its
  own truth is recorded too); its **power** is the share naming the truth ("equivalent" when
  every pairing is inside the margin, the direction when every pairing is beyond it on one
  side, "restart-dependent" when they straddle; "fails more" with ``f > 0``).  Beside them:
  the share of definite verdicts and how many of those are false, and the best/best
  pairing's 95 % t interval's coverage (a seed bootstrap of few seeds narrows the interval:
  the coverage is measured, not assumed).
- **The best arm** (:func:`best_claims`): every matched arm's two levels from the same real
  runs (same restarts; failures permuted among all the levels); with all arms equal, the
  share of replicates where a best is claimed (each claim false), and with one arm planted
  better (ratio ``rho`` to the others, or every other arm failing at an extra probability
  ``f``) the share claiming that arm and claiming another.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from analysis.calibration import verdicts
from analysis.regimes import coverage as rcov
from analysis.regimes import stats as rstats

__all__ = ["RATIOS", "FAIL_EXTRA", "RUN_RATIOS", "BEST_RATIOS", "MODES", "false_of", "layout",
           "pairing_truths", "draw", "planted_pair", "best_claims", "study", "summarise",
           "check", "label", "comparisons", "REPLICATES", "ACCEPT", "DEFINITE"]  # fmt: skip

#: Planted RMSE ratios of arm a to arm b (1.02 and 0.97: inside the ±5 % margin).
RATIOS = (1.0, 1.02, 0.97, 1.05, 0.95, 1.10, 0.90, 1.20, 0.80, 1.50, 0.67)
#: Planted extra failure probabilities of arm a's runs (at ratio 1).
FAIL_EXTRA = (0.02, 0.05, 0.10)
#: Planted ratios with the restarts as run.
RUN_RATIOS = (1.0, 1.10, 0.90, 1.50, 0.67)
#: The planted advantage of one arm in the best-arm study (its RMSE ratio to the others').
BEST_RATIOS = (1.0, 0.90, 0.80)
#: Replicates per condition at the medium and full levels.
REPLICATES = 200
#: The share of replicates the rule must accept the truth in (DESIGN §7.6).
ACCEPT = 0.9
#: The verdicts that claim something (the others claim nothing).
DEFINITE = ("higher", "lower", "equivalent", "fails more", "fails less", "worse", "better")
_TAIL = verdicts._TAIL
#: The synthetic runs' largest RMSE, as a share of the tracking threshold.
_HEADROOM = 0.25


def false_of(word: str, truth, f: float = 0.0) -> bool:
    """Whether the verdict ``word`` (a pairing's or the four pairings') is false of the planted
    truth: ``truth`` a ratio (every pairing's) or a sequence of the pairings' log ratios, ``f``
    the planted extra failure (see the module)."""
    lrs = [math.log(truth)] if np.isscalar(truth) else list(truth)
    if f > 0:
        return word in ("fails less", "lower", "better", "higher", "equivalent")
    return ((word in ("fails more", "fails less"))
            or (word in verdicts.WORSE + ("worse",) and min(lrs) <= 0)
            or (word in verdicts.BETTER + ("better",) and max(lrs) >= 0)
            or (word == "equivalent" and max(abs(x) for x in lrs) >= verdicts.EQUIV))  # fmt: skip


def _right(word: str, truth, f: float = 0.0) -> bool:
    """Whether ``word`` names the planted truth (the rule's power; see the module)."""
    if f > 0:
        return word == "fails more"
    lrs = [math.log(truth)] if np.isscalar(truth) else list(truth)
    if max(abs(x) for x in lrs) < verdicts.EQUIV:
        return word == "equivalent"
    if min(lrs) >= verdicts.EQUIV:
        return word in ("higher", "worse")
    if max(lrs) <= -verdicts.EQUIV:
        return word in ("lower", "better")
    return word == "restart-dependent"


def layout(arms: Sequence[Mapping[str, np.ndarray]]) -> dict | None:
    """The real runs of ``arms`` (each: restart level -> held-out result (seeds, cells,
    metrics), restricted to the compared cells) as the planted comparisons' material (see the
    module): ``resid`` (arms, levels, seeds, cells) log RMSE residuals about each level's
    cell means and ``offset`` (arms, levels, cells) those means less their arm's (in a
    ``varying`` cell the level's mean over ``tracked``; zero in a ``fixed`` one), ``fails``
    the failure masks; the cells ``tracked`` (no level fails at any
    seed), ``fixed`` (every level fails at every seed or at none) and ``varying`` (the rest);
    and a description of the noise: the first two arms' best/best ``seed_sd`` and ``pair_sd``
    (the regime study's method of moments), ``random_failures`` (the share of all the levels'
    runs that fail in the varying cells) and each arm's ``restart_offset`` (its runner-up's
    mean log ratio to its best over the tracked cells).  None with fewer than 3 seeds or 2
    tracked cells."""
    import pandas as pd

    rs = [[verdicts._runs(a[lv]) for lv in verdicts.RESTARTS] for a in arms]
    fails = np.array([[f for _, _, f in lv] for lv in rs])
    _, _, s, c = fails.shape
    tracked = ~fails.any(axis=(0, 1, 2))
    if s < 3 or tracked.sum() < 2:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        logr = np.where(tracked, np.log(np.array([[r for r, _, _ in lv] for lv in rs])), 0.0)
    fixed = ~tracked & (fails.all(axis=2) | ~fails.any(axis=2)).all(axis=(0, 1))
    varying = ~tracked & ~fixed
    mu = logr.mean(axis=2)
    offset = mu - mu.mean(axis=1, keepdims=True)
    # a varying cell's tracked runs enter a pairing's common cells with a donor's residuals:
    # each level's mean offset there keeps every pairing's truth that of the tracked cells
    offset[..., varying] = offset[..., tracked].mean(axis=-1, keepdims=True)
    resid = logr - mu[:, :, None, :]
    d = resid[0, 0][:, tracked] - resid[1, 0][:, tracked]
    frame = pd.DataFrame({"mechanism": "pair", "pose": "raw",
                          "trajectory": np.tile(np.arange(d.shape[1]), s),
                          "seed": np.repeat(np.arange(s), d.shape[1]), "delta": d.ravel()})
    return {"resid": resid, "offset": offset, "fails": fails, "tracked": tracked,
            "fixed": fixed, "varying": varying,
            "noise": {**rcov.noise(frame)["pair"],
                      "random_failures": float(fails[..., varying].sum() / fails.size),
                      "restart_offset": [float(np.mean(o[1, tracked] - o[0, tracked]))
                                         for o in offset],
                      "seeds": int(s), "cells": int(c), "tracked": int(tracked.sum()),
                      "fixed": int(fixed.sum()), "varying": int(varying.sum())}}  # fmt: skip


def pairing_truths(lay: Mapping, log_rho: float, as_run: bool) -> list[float]:
    """Each pairing's true log ratio (``verdicts.PAIRINGS`` order) of a two-arm layout at a
    planted ``log_rho``: with the restarts as run, plus the mean over the tracked cells of the
    two levels' offsets."""
    if not as_run:
        return [log_rho] * len(verdicts.PAIRINGS)
    t, o = lay["tracked"], lay["offset"]
    ix = {lv: i for i, lv in enumerate(verdicts.RESTARTS)}
    return [log_rho + float(np.mean(o[0, ix[la], t] - o[1, ix[lb], t]))
            for la, lb in verdicts.PAIRINGS]  # fmt: skip


def draw(lay: Mapping, log_shift: np.ndarray, f: float | Sequence[float],
         rng: np.random.Generator, as_run: bool = False) -> list:  # fmt: skip
    """One synthetic set of the layout's arms (see the module): per arm a dict level -> held-out
    result, arm ``i``'s log RMSE shifted by ``log_shift[i]``, the levels' offsets kept
    (``as_run``) or not, the first arm's runs failing at an extra probability ``f`` (or arm
    ``i``'s at ``f[i]``) in the cells that can track."""
    resid, fails, varying = lay["resid"], lay["fails"], lay["varying"]
    n_arms, n_lv, s, c = fails.shape
    idx = rng.integers(0, s, s)
    r, fl = resid[:, :, idx].copy(), fails[:, :, idx].copy()
    if varying.any():
        rows = fl.reshape(n_arms * n_lv, s, c)
        perm = np.argsort(rng.random((s, n_arms * n_lv)), axis=1)  # per seed, among levels
        moved = rows[perm.T, np.arange(s)[None, :]].reshape(fl.shape)
        fl = np.where(varying, moved, fl)
        donors = rng.choice(np.flatnonzero(lay["tracked"]), int(varying.sum()))
        r[..., varying] = r[..., donors]
    fl[..., lay["fixed"]] = True
    for i, fi in enumerate([f] if np.isscalar(f) else f):  # draws only where one is planted
        if fi > 0:
            fl[i] |= (rng.random(fl[i].shape) < fi) & ~lay["fixed"]
    shift = np.asarray(log_shift, float)[:, None, None, None]
    off = lay["offset"][:, :, None, :] if as_run else 0.0
    top = (float(np.max(np.abs(resid))) + float(np.max(np.abs(log_shift)))
           + (float(np.max(np.abs(lay["offset"]))) if as_run else 0.0))  # fmt: skip
    logr = math.log(_HEADROOM * rstats.TRACKING_M) - top + shift + r + off
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


def label(a: str, b: str) -> str:
    """A planted comparison's name in the record: arm ``a`` against arm ``b``."""
    return f"{a} vs {b}"


def comparisons(ranking: Sequence[str], best: str, paper: str, raw: str) -> dict:
    """The comparisons the fair-tuning record reports (label -> (a, b)): each ranked arm after
    the first against the candidate best, and the paper's arm against its law on the raw
    pose."""
    return {label(a, b): (a, b) for a, b in [*((n, best) for n in ranking[1:]), (paper, raw)]}


def _share(k: int, n: int) -> dict:
    if n == 0:
        return {"k": 0, "n": 0, "share": None, "ci_low": None, "ci_high": None}
    d = rstats.divergence(np.arange(n) < k)
    return {"k": int(k), "n": int(n), **{x: d[x] for x in ("share", "ci_low", "ci_high")}}


def planted_pair(lay: Mapping, rho: float, f: float, replicates: int,
                 rng: np.random.Generator, as_run: bool = False) -> dict:  # fmt: skip
    """The rule (``verdicts.across``) on ``replicates`` synthetic comparisons of a two-arm
    :func:`layout` at one planted truth (see the module): the verdicts' shares, acceptance of
    the truth (the four pairings' verdict; each pairing's word against its own truth beside
    it), power, the definite verdicts and the false ones among them, and the best/best t
    interval's coverage of its truth (with ``f = 0``, where it has one)."""
    words: dict[str, int] = {}
    accepts = right = definite = wrong = covered = with_ci = 0
    by_pairing = dict.fromkeys(verdicts.PAIRINGS, 0)
    truths = pairing_truths(lay, math.log(rho), as_run)
    for _ in range(replicates):
        a, b = draw(lay, np.array([math.log(rho), 0.0]), f, rng, as_run)
        v = verdicts.across(a, b)
        w = v["verdict"]
        words[w] = words.get(w, 0) + 1
        bad = false_of(w, truths, f)
        accepts += not bad
        definite += w in DEFINITE
        wrong += bad
        right += _right(w, truths, f)
        for (la, lb), t in zip(verdicts.PAIRINGS, truths, strict=True):
            p = v["tuned"] if (la, lb) == verdicts.PAIRINGS[0] else v["by"][f"{la} / {lb}"]
            by_pairing[(la, lb)] += not false_of(p["word"], [t], f)
        ci = v["tuned"]["ci"]
        if f == 0 and ci is not None:
            with_ci += 1
            covered += ci[0] <= truths[0] <= ci[1]
    return {"rho": rho, "f": f, "truths": truths,
            "verdicts": {k: words[k] / replicates for k in sorted(words)},
            "accepts": _share(accepts, replicates),
            "accepts_by_pairing": {f"{la} / {lb}": _share(k, replicates)
                                   for (la, lb), k in by_pairing.items()},
            "power": _share(right, replicates), "definite": _share(definite, replicates),
            "false_among_definite": _share(wrong, definite),
            "coverage": _share(covered, with_ci) if f == 0 else None}  # fmt: skip


def best_claims(lay: Mapping, names: list[str], rho: float, replicates: int,
                rng: np.random.Generator, f: float = 0.0) -> dict:  # fmt: skip
    """The best-arm claim (``verdicts.compare``) on ``replicates`` synthetic sets of the arms
    ``names`` (their :func:`layout`, in that order; same restarts), the first planted better:
    at ratio ``rho`` to the others, or failing less (every other arm's runs fail at an extra
    probability ``f`` in the cells that can track); all equal at ``rho = 1, f = 0``.  The
    share of replicates claiming a best (``claims``), claiming the planted one (``right``;
    only where one is planted) and claiming another (``wrong``)."""
    claims = right = 0
    shift = np.zeros(len(names))
    shift[0] = math.log(rho)
    extra = [0.0] + [f] * (len(names) - 1)
    planted = rho < 1 or f > 0
    cols = np.ones(lay["fails"].shape[-1], bool)
    for _ in range(replicates):
        runs = dict(zip(names, draw(lay, shift, extra, rng), strict=True))
        c = verdicts.compare(runs, names, cols)
        claims += c["best_determined"]
        right += c["best_determined"] and planted and c["best"] == names[0]
    return {"rho": rho, "f": f, "arms": len(names), "claims": _share(claims, replicates),
            "right": _share(right, replicates),
            "wrong": _share(claims - right, replicates)}  # fmt: skip


def _conditions(mode: str) -> list[tuple[float, float]]:
    if mode == "as_run":
        return [(r, 0.0) for r in RUN_RATIOS]
    return [(r, 0.0) for r in RATIOS] + [(1.0, f) for f in FAIL_EXTRA]


#: The record's keys of the two modes (see the module).
MODES = ("truths", "as_run")


def study(runs: Mapping[str, Mapping[str, np.ndarray]], comparisons: Mapping[str, tuple],
          main: np.ndarray, matched: list[str], replicates: int = REPLICATES,
          seed: int = 23) -> dict:  # fmt: skip
    """The rule on planted truth for the record's ``comparisons`` (label -> (a, b): arm names
    of ``runs``, level -> held-out result (seeds, cells, metrics)) on the cells ``main`` in
    both modes (see the module), and the best-arm claim over ``matched``; with the summary
    (:func:`summarise`)."""
    def levels(n: str) -> dict:
        return {lv: runs[n][lv][:, main] for lv in verdicts.RESTARTS}

    out: dict = {"replicates": replicates, "seed": seed, "ratios": list(RATIOS),
                 "run_ratios": list(RUN_RATIOS), "fail_extra": list(FAIL_EXTRA),
                 "best_ratios": list(BEST_RATIOS), "accept_target": ACCEPT,
                 "comparisons": {}}  # fmt: skip
    for k, (label, (a, b)) in enumerate(comparisons.items()):
        lay = layout([levels(a), levels(b)])
        entry: dict = {"arms": [a, b], "noise": None if lay is None else lay["noise"]}
        for m, mode in enumerate(MODES if lay is not None else ()):
            entry[mode] = [planted_pair(lay, r, f, replicates,
                                        np.random.default_rng([seed, k, m, i]),
                                        as_run=mode == "as_run")
                           for i, (r, f) in enumerate(_conditions(mode))]  # fmt: skip
        out["comparisons"][label] = entry
    out.update(summarise(out))
    lay = layout([levels(n) for n in matched]) if len(matched) > 1 else None
    out["best"] = None if lay is None else {
        "noise": lay["noise"], "arms": list(matched),
        "by_rho": [best_claims(lay, list(matched), r, replicates,
                               np.random.default_rng([seed, 10**6, i]))
                   for i, r in enumerate(BEST_RATIOS)],
        "by_fail": [best_claims(lay, list(matched), 1.0, replicates,
                                np.random.default_rng([seed, 10**6 + 1, i]), fx)
                    for i, fx in enumerate(FAIL_EXTRA)]}  # fmt: skip
    return out


def _key(r: float, f: float) -> str:
    return f"{r:g}" if f == 0 else f"{r:g}+f{f:g}"


def summarise(pl: Mapping) -> dict:
    """The summary of the planted comparisons: the least acceptance over both modes (and
    where), whether every truth is accepted at :data:`ACCEPT`, and per mode and planted truth
    the least power and the least best/best coverage over the comparisons (empty without a
    planted comparison)."""
    done = {k: c for k, c in pl["comparisons"].items() if c["noise"] is not None}
    if not done:
        return {}
    rows = [(label, mode, r) for label, c in done.items() for mode in MODES for r in c[mode]]
    label, mode, least = min(rows, key=lambda x: x[2]["accepts"]["share"])
    out = {"least_accepts": {**least["accepts"], "rho": least["rho"], "f": least["f"],
                             "comparison": label, "mode": mode},
           "accepts_at_target": all(r["accepts"]["share"] >= ACCEPT for *_, r in rows)}
    for mode in MODES:
        conds = _conditions(mode)
        out[mode] = {
            "least_power": {_key(r, f): min(c[mode][i]["power"]["share"]
                                            for c in done.values())
                            for i, (r, f) in enumerate(conds)},
            "least_coverage": {_key(r, f): min(c[mode][i]["coverage"]["share"]
                                               for c in done.values())
                               for i, (r, f) in enumerate(conds)
                               if f == 0 and all(c[mode][i]["coverage"]["n"]
                                                 for c in done.values())}}  # fmt: skip
    return out


def check(pl: Mapping, labels: Sequence[str] | None = None) -> None:
    """The record's planted-truth part is whole (its comparisons ``labels`` where given, every
    condition of both modes, the best-arm rows) and its summary follows from its rows; each
    row's acceptance, power and definite shares follow from its verdict shares; the rule
    accepts the truth in at least :data:`ACCEPT` of every planted comparison (DESIGN §7.6).
    The rows themselves need the runs: ``study`` on the stores recomputes them."""
    assert pl["ratios"] == list(RATIOS) and pl["fail_extra"] == list(FAIL_EXTRA), pl["ratios"]
    assert pl["run_ratios"] == list(RUN_RATIOS) and pl["best_ratios"] == list(BEST_RATIOS)
    n = pl["replicates"]
    if labels is not None:
        assert list(pl["comparisons"]) == list(labels), (list(pl["comparisons"]), labels)
    for label, c in pl["comparisons"].items():
        if c["noise"] is None:
            assert not any(m in c for m in MODES), label
            continue
        for mode in MODES:
            assert [(r["rho"], r["f"]) for r in c[mode]] == _conditions(mode), (label, mode)
            for r in c[mode]:
                _check_row(r, n, label)
    summary = summarise(pl)
    assert {k: pl.get(k) for k in summary} == summary, "the planted summary is not its rows'"
    if summary:
        assert pl["accepts_at_target"], f"the rule rejects planted truth: {pl['least_accepts']}"
    if pl.get("best"):
        assert [b["rho"] for b in pl["best"]["by_rho"]] == list(BEST_RATIOS)
        assert [b["f"] for b in pl["best"]["by_fail"]] == list(FAIL_EXTRA)
        for b in [*pl["best"]["by_rho"], *pl["best"]["by_fail"]]:
            for k in ("claims", "right", "wrong"):
                _check_share(b[k], n, b)
            assert b["claims"]["k"] == b["right"]["k"] + b["wrong"]["k"], b
            assert b["rho"] < 1 or b["f"] > 0 or b["right"]["k"] == 0, b


def _check_share(x: Mapping, n: int | None, where) -> None:
    assert n is None or x["n"] == n, (where, x)
    assert 0 <= x["k"] <= x["n"], (where, x)
    if x["n"]:
        assert math.isclose(x["share"], x["k"] / x["n"]), (where, x)
        assert x["ci_low"] <= x["share"] <= x["ci_high"], (where, x)


def _check_row(r: Mapping, n: int, label: str) -> None:
    """One planted truth's row: its counts, and its acceptance, power and definite shares
    from its verdict shares against its truths."""
    for k in ("accepts", "power", "definite", *(["coverage"] if r["coverage"] else [])):
        _check_share(r[k], n if k != "coverage" else None, (label, k))
    _check_share(r["false_among_definite"], r["definite"]["k"], (label, "false"))
    assert (r["coverage"] is None) == (r["f"] > 0), (label, r)
    v = r["verdicts"]
    assert math.isclose(sum(v.values()), 1.0), (label, r)
    for key, pick in (("accepts", lambda w: not false_of(w, r["truths"], r["f"])),
                      ("power", lambda w: _right(w, r["truths"], r["f"])),
                      ("definite", lambda w: w in DEFINITE)):  # fmt: skip
        want = sum(x for w, x in v.items() if pick(w))
        assert math.isclose(r[key]["share"], want, abs_tol=1e-9), (label, key, r)
    wrong = round(n * sum(x for w, x in v.items() if false_of(w, r["truths"], r["f"])))
    assert r["false_among_definite"]["k"] == wrong, (label, r)
