"""Moment-independent sensitivity on the design's own sample: PAWN indices (issue 23, item 4).

PAWN (Pianosi & Wagener 2015, 2018; ``SALib.analyze.pawn``): for setting ``i``, the design's
points are cut into ``S`` equal-count slices of ``x_i``; in each slice the Kolmogorov-Smirnov
distance between the conditional and the unconditional distribution of the output; the index
is their median over the slices.  It depends on the output only through its ranks (bounded in
[0, 1], insensitive to the heavy tails and the divergence placeholder that broke the Sobol
estimators), needs no extra runs (the design is the sample), and a setting that does nothing
scores the sampling floor -- measured here by **dummy** settings (independent uniform columns,
Khorashadizadeh et al. 2017): a setting is above the floor when its index exceeds the 95th
percentile of theirs (a permutation-type test).

Intervals: bias-corrected percentile bootstrap over the design's rows (seeded).  Settings are
**tied** when their intervals overlap: :func:`ties` groups the ranking into such runs.  The
implementation is vectorised (searchsorted); a test checks it against ``SALib.analyze.pawn``
exactly.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["SLICES", "RESAMPLES", "pawn_median", "pawn", "ties"]

SLICES = 10
RESAMPLES = 200


def _ks(sel: np.ndarray, all_sorted: np.ndarray) -> float:
    """Two-sample KS statistic of ``sel`` against the sorted sample ``all_sorted``."""
    if sel.size == 0:
        return np.nan
    s = np.sort(sel)
    grid = np.concatenate([s, all_sorted])
    f1 = np.searchsorted(s, grid, side="right") / s.size
    f2 = np.searchsorted(all_sorted, grid, side="right") / all_sorted.size
    return float(np.max(np.abs(f1 - f2)))


def pawn_median(X: np.ndarray, y: np.ndarray, slices: int = SLICES) -> np.ndarray:
    """The median-KS PAWN index of each column of ``X`` (n, d) for output ``y`` (n,), with
    SALib's slicing (``x_q[s] <= x < x_q[s+1]`` at the quantiles of each column)."""
    all_sorted = np.sort(y)
    step = 1.0 / slices
    out = np.empty(X.shape[1])
    for j in range(X.shape[1]):
        x = X[:, j]
        q = np.nanquantile(x, np.arange(0, 1 + step, step))
        ks = [_ks(y[(x >= q[s]) & (x < q[s + 1])], all_sorted) for s in range(slices)]
        out[j] = np.nanmedian(ks)
    return out


def pawn(X: np.ndarray, Y: np.ndarray, names, outputs, seed: int = 0,
         resamples: int = RESAMPLES, level: float = 0.95) -> dict:  # fmt: skip
    """PAWN indices of every output (columns of ``Y``, (n, s)) for the settings ``names``
    (columns of ``X``) and a dummy, with bootstrap intervals and ties.  Each output is
    analysed on its finite rows (their number is its ``n``; NaN marks a value that is not
    defined, such as a tracking error of a diverged run); ``None`` when it has fewer than
    ``2 x SLICES`` of them or they are constant.  The dummy column is drawn from ``seed``;
    output o's bootstrap and null from ``[seed, crc32(o)]``."""
    Xall = np.column_stack([X, np.random.default_rng(seed).random(X.shape[0])])
    q = [(1 - level) / 2, (1 + level) / 2]
    out = {}
    for k, o in enumerate(outputs):
        # each output's own generator, keyed by its name: adding, dropping or reordering the
        # other outputs does not move it
        rng = np.random.default_rng([seed, zlib.crc32(str(o).encode())])
        ok = np.isfinite(Y[:, k])
        y, Xd, n = Y[ok, k], Xall[ok], int(ok.sum())
        if n < 2 * SLICES or np.ptp(y) == 0:
            out[o] = None
            continue
        est = pawn_median(Xd, y)
        boot = np.array([pawn_median(Xd[idx], y[idx]) for idx in
                         (rng.integers(0, n, n) for _ in range(resamples))])  # fmt: skip
        # the bootstrap of a KS statistic is biased upward (resampled rows tie): the
        # percentile interval shifted by the bootstrap's bias (Efron & Tibshirani 1993 §10)
        bias = boot.mean(axis=0) - est
        lo, hi = np.quantile(boot, q, axis=0) - bias
        # the floor: the index of independent uniform columns (an inert setting), its 95th
        # percentile over ``resamples`` such columns
        null = pawn_median(rng.random((n, resamples)), y)
        ix = {nm: {"index": float(est[i]), "low": float(lo[i]), "high": float(hi[i])}
              for i, nm in enumerate([*names, "dummy"])}  # fmt: skip
        floor = float(np.quantile(null, 0.95))
        out[o] = {"n": n, "indices": ix, "dummy_high": floor,
                  "above_dummy": [nm for nm in names if ix[nm]["index"] > floor],
                  "ties": ties(ix)}  # fmt: skip
    return out


def ties(ix: dict) -> list[list[str]]:
    """The settings ranked by index, grouped: a setting joins the current group when its
    interval overlaps the interval of the group's leader (its highest index), so that no two
    settings whose intervals are apart end in one group through a chain of overlaps."""
    order = sorted(ix, key=lambda k: -ix[k]["index"])
    groups: list[list[str]] = []
    for k in order:
        if groups and ix[k]["high"] >= ix[groups[-1][0]]["low"]:
            groups[-1].append(k)
        else:
            groups.append([k])
    return groups
