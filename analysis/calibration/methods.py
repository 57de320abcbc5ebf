"""The calibration study's methods: Morris screening, the Sobol design and indices, the ranking
statistics and the seeded bootstrap (issue 15, steps 3 and 5).  Pure numpy/scipy, no runs.

- :func:`morris_design` / :func:`morris_effects`: elementary effects (Morris 1991) on a
  ``p``-level grid of the unit cube with the jump ``delta = p / (2 (p - 1))``; ``mu*`` (mean of
  ``|EE|``, Campolongo et al. 2007) ranks the settings, ``sigma`` flags interactions or
  nonlinearity.
- :func:`sobol_design`: ``A`` and ``B`` (``n`` x ``d`` each) as the two halves of a scrambled
  Sobol sequence in ``2 d`` dimensions (as ``scipy.stats.sobol_indices`` draws them), and
  :func:`ab_matrices`, the ``A_B^(i)`` (``A`` with column ``i`` from ``B``).
- :func:`sobol_indices`: first-order (Saltelli et al. 2010) and total (Jansen 1999) indices, the
  estimators of ``scipy.stats.sobol_indices`` (the tests check the two agree), with percentile
  bootstrap intervals over the rows from a seeded generator (scipy's own bootstrap draws from
  the global state).
- :func:`kendall_tau`, :func:`order_stats`: how our order of the four controllers compares with
  the paper's per (scenario, axis), with a cluster bootstrap over design points.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

__all__ = ["morris_design", "morris_effects", "sobol_design", "ab_matrices", "saltelli_2010",
           "sobol_indices", "kendall_tau", "paper_orders", "order_stats", "bootstrap_mean",
           "BOOTSTRAP"]  # fmt: skip

#: Bootstrap resamples of every interval of this study.
BOOTSTRAP = 2000


def morris_design(k: int, r: int, levels: int = 4, seed: int = 0):
    """``r`` Morris trajectories through the ``levels``-level grid of ``[0, 1]^k``.

    Returns
    -------
    u : ndarray, shape (r, k + 1, k)
        The points of each trajectory; point ``j + 1`` differs from point ``j`` in setting
        ``order[t, j]`` only, by ``+delta`` (``up``) or ``-delta``.
    order : ndarray of int, shape (r, k)
    up : ndarray of bool, shape (r, k)
        Direction of each setting's jump, by setting.
    delta : float
        ``levels / (2 (levels - 1))`` (2/3 for 4 levels).
    """
    rng = np.random.default_rng(seed)
    delta = levels / (2.0 * (levels - 1))
    grid = np.arange(levels) / (levels - 1)
    low = grid[grid <= 1.0 - delta + 1e-12]  # a base from which +delta stays in the cube
    u = np.empty((r, k + 1, k))
    order = np.empty((r, k), dtype=int)
    up = np.empty((r, k), dtype=bool)
    for t in range(r):
        base = rng.choice(low, size=k)
        up[t] = rng.random(k) < 0.5
        cur = np.where(up[t], base, base + delta)
        order[t] = rng.permutation(k)
        u[t, 0] = cur
        for j, i in enumerate(order[t]):
            cur = cur.copy()
            cur[i] += delta if up[t, i] else -delta
            u[t, j + 1] = cur
    return u, order, up, delta


def morris_effects(y: np.ndarray, order: np.ndarray, up: np.ndarray, delta: float) -> dict:
    """Elementary effects of outputs ``y`` (shape ``(r, k + 1, s)``) along the trajectories.

    Returns ``{"ee": (r, k, s), "mu": (k, s), "mu_star": (k, s), "sigma": (k, s)}``; an effect
    is ``(y_{j+1} - y_j) / (+-delta)`` for the setting moved at step ``j``.
    """
    r, k1, s = y.shape
    k = k1 - 1
    ee = np.empty((r, k, s))
    for t in range(r):
        for j, i in enumerate(order[t]):
            step = delta if up[t, i] else -delta
            ee[t, i] = (y[t, j + 1] - y[t, j]) / step
    return {"ee": ee, "mu": ee.mean(axis=0), "mu_star": np.abs(ee).mean(axis=0),
            "sigma": ee.std(axis=0, ddof=1) if r > 1 else np.zeros((k, s))}  # fmt: skip


def sobol_design(d: int, m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``A``, ``B``: ``2**m`` x ``d`` each, the two halves of a scrambled Sobol sequence in
    ``2 d`` dimensions (``scipy.stats.qmc.Sobol``, seeded)."""
    from scipy.stats import qmc

    x = qmc.Sobol(2 * d, scramble=True, seed=seed).random_base2(m)
    return x[:, :d], x[:, d:]


def ab_matrices(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A_B^(i)`` for each setting ``i``: shape ``(d, n, d)``."""
    d = A.shape[1]
    out = np.repeat(A[None], d, axis=0)
    for i in range(d):
        out[i, :, i] = B[:, i]
    return out


def saltelli_2010(f_A: np.ndarray, f_B: np.ndarray, f_AB: np.ndarray):
    """First-order (Saltelli et al. 2010) and total (Jansen 1999) indices.

    ``f_A``, ``f_B``: ``(s, n)``; ``f_AB``: ``(d, s, n)``.  Returns ``(S1, ST)``, each
    ``(s, d)``: ``S1_i = mean(f_B (f_AB_i - f_A)) / V``, ``ST_i = mean((f_A - f_AB_i)^2) / (2 V)``,
    ``V`` the variance of ``f_A`` and ``f_B`` pooled.
    """
    var = np.var(np.stack([f_A, f_B]), axis=(0, -1))
    s1 = np.mean(f_B * (f_AB - f_A), axis=-1) / var
    st = 0.5 * np.mean((f_A - f_AB) ** 2, axis=-1) / var
    return s1.T, st.T


def sobol_indices(f_A, f_B, f_AB, level: float = 0.95, n_resamples: int = BOOTSTRAP,
                  seed: int = 0) -> dict:  # fmt: skip
    """Indices of :func:`saltelli_2010` with percentile bootstrap intervals over the rows.

    As ``scipy.stats.sobol_indices``, the outputs are first centred by the mean of ``f_A`` and
    ``f_B`` (Sobol' & Levitan 1999: it lowers the first-order estimator's variance).

    Returns ``{"first", "first_low", "first_high", "total", "total_low", "total_high"}``, each
    ``(s, d)``.
    """
    f_A, f_B, f_AB = (np.array(f, dtype=float) for f in (f_A, f_B, f_AB))
    mean = np.mean([f_A, f_B], axis=(0, -1))[:, None]
    f_A, f_B, f_AB = f_A - mean, f_B - mean, f_AB - mean
    s1, st = saltelli_2010(f_A, f_B, f_AB)
    rng = np.random.default_rng(seed)
    n = f_A.shape[-1]
    b1 = np.empty((n_resamples, *s1.shape))
    bt = np.empty_like(b1)
    for b in range(n_resamples):
        idx = rng.integers(0, n, n)
        b1[b], bt[b] = saltelli_2010(f_A[:, idx], f_B[:, idx], f_AB[..., idx])
    q = [(1 - level) / 2, (1 + level) / 2]
    l1, h1 = np.quantile(b1, q, axis=0)
    lt, ht = np.quantile(bt, q, axis=0)
    return {"first": s1, "first_low": l1, "first_high": h1, "total": st, "total_low": lt,
            "total_high": ht}  # fmt: skip


def kendall_tau(ours: np.ndarray, paper: np.ndarray) -> np.ndarray:
    """Kendall's tau between the orders of ``ours`` (..., m) and ``paper`` (m,): ``(concordant -
    discordant) / (m (m - 1) / 2)`` over the pairs (ties in ours count as neither)."""
    m = paper.shape[-1]
    total = np.zeros(ours.shape[:-1])
    for i, j in itertools.combinations(range(m), 2):
        total += np.sign(ours[..., i] - ours[..., j]) * np.sign(paper[i] - paper[j])
    return total / (m * (m - 1) / 2)


def paper_orders(paper: np.ndarray) -> np.ndarray:
    """The paper's values as (scenario, controller, axis) -> shape (3, 4, 3)."""
    return np.asarray(paper).reshape(3, 4, 3)


def bootstrap_mean(x: np.ndarray, level: float = 0.95, n_resamples: int = BOOTSTRAP,
                   seed: int = 0) -> tuple[float, float]:  # fmt: skip
    """Percentile bootstrap interval of the mean of ``x`` over its first axis (clusters: a
    point's seeds stay together when ``x`` is the per-point mean)."""
    x = np.asarray(x, dtype=float)
    rng = np.random.default_rng(seed)
    n = len(x)
    idx = rng.integers(0, n, (n_resamples, n))
    means = x[idx].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def order_stats(numbers: np.ndarray, paper: np.ndarray, names: Sequence[str],
                scenarios: Sequence[str], axes: Sequence[str], seed: int = 0) -> dict:  # fmt: skip
    """How often the paper's order holds over design points x seeds.

    Parameters
    ----------
    numbers : ndarray, shape (n_points, n_seeds, 36)
        Per run, the 36 RMSEs (scenario, controller, axis order; diverged as a large value).
    paper : ndarray, shape (36,)
    names : the 4 controllers, in the numbers' order.

    Returns
    -------
    dict
        ``all_nine`` (P that all 9 (scenario, axis) orders are the paper's), ``per_table`` (P per
        (scenario, axis)), ``iapid_first_all`` (P IAPID is lowest on all 9), ``kendall_tau``
        (mean tau per (scenario, axis) and overall), ``pairwise`` (P that A < B, over the 9
        (scenario, axis) pairs pooled, for each ordered pair, with the paper's own share), each
        probability with its exact (Clopper-Pearson) 95 % interval over the points (a zero
        count: ``[0, upper]``); the Kendall tau with a cluster-bootstrap interval.
    """
    n_p, n_s = numbers.shape[:2]
    x = numbers.reshape(n_p, n_s, 3, 4, 3)  # point, seed, scenario, controller, axis
    pp = paper_orders(paper)
    same = np.empty((n_p, n_s, 3, 3), dtype=bool)
    tau = np.empty((n_p, n_s, 3, 3))
    for si, ai in itertools.product(range(3), range(3)):
        ours = x[:, :, si, :, ai]
        # the paper's order holds when ours increase strictly along it (a tie is no order)
        along = ours[..., np.argsort(pp[si, :, ai])]
        same[:, :, si, ai] = np.all(np.diff(along, axis=-1) > 0, axis=-1)
        tau[:, :, si, ai] = kendall_tau(ours, pp[si, :, ai])
    # (p, s, scenario, axis): IAPID (index 0) strictly below every other (a tie is not first)
    first = x[:, :, :, 0, :] < x[:, :, :, 1:, :].min(axis=3)

    def prob(ind):  # ind: (n_p, n_s) -> p and its exact interval over the points
        from analysis.calibration.rule import clopper_pearson

        per_point = ind.reshape(n_p, -1).mean(axis=1)
        p = float(per_point.mean())
        # Clopper-Pearson with the points as the independent draws (Korn & Graubard 1998:
        # effective count p n_p of n_p; a point's seeds are not independent of each other)
        lo, hi = clopper_pearson(p * n_p, n_p)
        return {"p": p, "ci_low": lo, "ci_high": hi, "k_runs": int(ind.sum()),
                "n_runs": int(ind.size), "n_points": int(n_p)}

    out = {"n_points": int(n_p), "n_seeds": int(n_s), "runs_per_point": int(n_s),
           "all_nine": prob(np.all(same, axis=(2, 3))),
           "iapid_first_all": prob(np.all(first, axis=(2, 3))),
           "iapid_first_any": prob(np.any(first, axis=(2, 3))),
           "per_table": {f"{scenarios[si]}/{axes[ai]}": prob(same[:, :, si, ai])
                         for si, ai in itertools.product(range(3), range(3))},
           "kendall_tau": {"mean": float(tau.mean()), "ci": list(bootstrap_mean(
               tau.reshape(n_p, -1).mean(axis=1), seed=seed)),
               "per_table": {f"{scenarios[si]}/{axes[ai]}": float(tau[:, :, si, ai].mean())
                             for si, ai in itertools.product(range(3), range(3))}},
           "pairwise": {}}  # fmt: skip
    for a, b in itertools.permutations(range(4), 2):
        wins = x[:, :, :, a, :] < x[:, :, :, b, :]  # (p, s, scenario, axis)
        paper_share = float(np.mean(pp[:, a, :] < pp[:, b, :]))
        out["pairwise"][f"{names[a]} < {names[b]}"] = {**prob(wins.reshape(n_p, n_s, -1).mean(
            axis=-1)), "paper": paper_share}  # fmt: skip
    return out
