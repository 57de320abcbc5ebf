"""Stochastic-stability quantities of the discrete EKF (§3.4.1-3.4.2; Reif et al. 1999).

The paper's Assumption 1 and Lemma 2, in the corrected reading of errata E10, written in the
*two-step* form of the filter (``K_k`` without ``A``)::

    P_{k|k-1} = A_k P_{k-1|k-1} A_k^T + Q_k                                    (28)
    K_k       = P_{k|k-1} H_k^T (H_k P_{k|k-1} H_k^T + R_k)^-1                    (29)
    P_{k|k}   = (I - K_k H_k) P_{k|k-1} (I - K_k H_k)^T + K_k R_k K_k^T   (Joseph, = 31)
    e_{k+1|k} = A_k (I - K_k H_k) e_{k|k-1} + r_k + s_k                       (39, E10)

The Lyapunov function of the proof (eq. 52) is ``V_k = e_{k|k-1}^T Pi_k e_{k|k-1}`` with
``Pi_k = P_{k|k-1}^-1``: in the two-step form the ``P_k`` of Assumption 1 and Lemma 2 is the
*prior* covariance ``P_{k|k-1}`` (Reif's ``P_k`` is the one-step, i.e. prior, covariance).

**Assumption 1 (eq. 43, E10).** ``||A_k|| <= a_bar``, ``||H_k|| <= c_bar``,
``p_min I <= P_{k|k-1} <= p_max I``, ``q_min I <= Q_k``, ``r_min I <= R_k`` (R is m x m).

**Lemma 2 (eq. 48, E10).** With ``M_k = A_k (I - K_k H_k)``::

    M_k^T Pi_{k+1} M_k <= (1 - alpha) Pi_k,
    1 - alpha = 1 / (1 + q_min / (p_max (a_bar + a_bar p_max c_bar^2 / r_min)^2)).

Proof sketch in the two-step form (why the formula holds and what it loses):
``P_{k+1|k} = M P M^T + A K R K^T A^T + Q >= B B^T + G`` with ``P = P_{k|k-1}``,
``B = M P^{1/2}`` and ``G = A K R K^T A^T + Q``.  By the push-through identity
``B^T (B B^T + G)^-1 B = I - (I + B^T G^-1 B)^-1``, so the largest generalised eigenvalue of
``(M^T Pi_{k+1} M, Pi_k)`` is exactly ``1 - 1 / (1 + y)`` with ``y = lambda_max(B^T G^-1 B)``:
the *achieved* contraction is ``alpha_k = 1 / (1 + y)``, computed here without the cancellation
of ``1 - lambda``.  Bounding ``y <= ||M||^2 p_max / q_min`` and
``||M|| <= a_bar (1 + p_max c_bar^2 / r_min)`` (``||K|| <= p_max c_bar / r_min``) gives Lemma 2's
``alpha``; so (48) with Lemma 2's ``alpha`` must hold at every step of an exact Kalman filter whose
constants are those of the run — a check of the lemma, and ``alpha_k / alpha`` says how much the
bound gives away.

All functions are plain numpy (analysis-time; the closed loop never calls them).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import scipy.linalg as sla
from scipy import stats

__all__ = [
    "lemma2_alpha",
    "step_bounds",
    "constants_from_bounds",
    "assumption1_constants",
    "kalman_gain",
    "contraction_direct",
    "kalman_contraction",
    "ineq48_holds",
    "noise_term",
    "noise_term_parts",
    "noise_term_from_parts",
    "theorem1_bound",
    "chi2_band",
    "random_walk_consistency",
    "random_walk_increment_noise",
    "CONSTANT_NAMES",
]

#: Keys of Assumption 1's constants, in the order of eq. (43).
CONSTANT_NAMES = ("a_bar", "c_bar", "p_min", "p_max", "q_min", "r_min")


def lemma2_alpha(a_bar: float, c_bar: float, p_max: float, q_min: float, r_min: float) -> float:
    """Lemma 2's ``alpha`` (errata E10): ``1 - alpha = 1 / (1 + x)``, ``alpha = x / (1 + x)``,

    with ``x = q_min / (p_max (a_bar + a_bar p_max c_bar^2 / r_min)^2)``.

    Parameters
    ----------
    a_bar, c_bar : float
        Bounds on ``||A_k||`` and ``||H_k||`` (spectral norms), ``> 0``.
    p_max : float
        Upper bound on the prior covariance, ``P_{k|k-1} <= p_max I``, ``> 0``.
    q_min, r_min : float
        Lower bounds ``q_min I <= Q_k``, ``r_min I <= R_k``, ``> 0``.

    Returns
    -------
    float
        ``alpha`` in (0, 1).  Written as ``x / (1 + x)`` so a tiny ``alpha`` (~1e-12) keeps its
        relative precision (``1 - 1/(1 + x)`` would cancel).
    """
    for name, v in (("a_bar", a_bar), ("c_bar", c_bar), ("p_max", p_max), ("q_min", q_min),
                    ("r_min", r_min)):  # fmt: skip
        if not (v > 0 and math.isfinite(v)):
            raise ValueError(f"lemma2_alpha: {name} = {v!r} must be a finite number > 0")
    m = a_bar + a_bar * p_max * c_bar**2 / r_min
    x = q_min / (p_max * m * m)
    return x / (1.0 + x)


def step_bounds(A: np.ndarray, H: np.ndarray, P: np.ndarray, Q: np.ndarray, R: np.ndarray):
    """The six per-step quantities of Assumption 1 for one step.

    Returns ``(||A||_2, ||H||_2, lambda_min(P), lambda_max(P), lambda_min(Q), lambda_min(R))``;
    ``P``, ``Q``, ``R`` symmetric (their symmetric part is used).
    """
    lp = np.linalg.eigvalsh(_sym(P))
    return (
        float(np.linalg.norm(np.atleast_2d(A), 2)),
        float(np.linalg.norm(np.atleast_2d(H), 2)),
        float(lp[0]),
        float(lp[-1]),
        float(np.linalg.eigvalsh(_sym(Q))[0]),
        float(np.linalg.eigvalsh(_sym(R))[0]),
    )


def constants_from_bounds(bounds: Sequence[Sequence[float]] | np.ndarray) -> dict[str, float]:
    """Reduce per-step :func:`step_bounds` rows (N, 6) to Assumption 1's constants over a run:

    ``a_bar = max ||A||``, ``c_bar = max ||H||``, ``p_min = min lambda_min(P)``,
    ``p_max = max lambda_max(P)``, ``q_min = min lambda_min(Q)``, ``r_min = min lambda_min(R)``.
    """
    b = np.asarray(bounds, dtype=float).reshape(-1, 6)
    if b.shape[0] == 0:
        raise ValueError("constants_from_bounds: no steps")
    return {
        "a_bar": float(b[:, 0].max()),
        "c_bar": float(b[:, 1].max()),
        "p_min": float(b[:, 2].min()),
        "p_max": float(b[:, 3].max()),
        "q_min": float(b[:, 4].min()),
        "r_min": float(b[:, 5].min()),
    }


def assumption1_constants(A: Iterable, H: Iterable, P: Iterable, Q: Iterable,
                          R: Iterable) -> dict[str, float]:  # fmt: skip
    """Assumption 1's constants (eq. 43, E10) of a sequence of filter matrices.

    Parameters
    ----------
    A, H, P, Q, R : iterables of ndarray
        Per-step ``A_k`` (n, n), ``H_k`` (m, n), prior ``P_{k|k-1}`` (n, n), ``Q_k`` (n, n),
        ``R_k`` (m, m), of equal length.

    Returns
    -------
    dict
        ``{"a_bar", "c_bar", "p_min", "p_max", "q_min", "r_min"}``.
    """
    rows = [step_bounds(*m) for m in zip(A, H, P, Q, R, strict=True)]
    return constants_from_bounds(rows)


def kalman_gain(P_prior: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``K = P H^T (H P H^T + R)^-1`` (eq. 29), shape (n, m), by a Cholesky solve."""
    PHt = P_prior @ H.T
    S = _sym(H @ PHt + R)
    return sla.cho_solve(sla.cho_factor(S, lower=True), PHt.T).T


def contraction_direct(M: np.ndarray, P_k: np.ndarray, P_next: np.ndarray) -> float:
    """Largest generalised eigenvalue of ``(M^T Pi_{k+1} M, Pi_k)``, ``Pi = P^-1``.

    ``lambda = ||L_{k+1}^-1 M L_k||_2^2`` with Cholesky factors ``P_k = L_k L_k^T``,
    ``P_next = L_{k+1} L_{k+1}^T``: (48) holds with ``alpha`` iff ``lambda <= 1 - alpha``.
    Works for any ``M`` and any pair of covariances (no Riccati structure assumed).  Near
    ``lambda = 1`` its absolute error is ~eps times a condition number; for Kalman steps use
    :func:`kalman_contraction`, which returns ``1 - lambda`` without cancellation.
    """
    Lk = np.linalg.cholesky(_sym(P_k))
    Ln = np.linalg.cholesky(_sym(P_next))
    C = sla.solve_triangular(Ln, M @ Lk, lower=True)
    return float(np.linalg.eigvalsh(C.T @ C)[-1])


def kalman_contraction(P_prior: np.ndarray, H: np.ndarray, R: np.ndarray, Q: np.ndarray,
                       A: np.ndarray | None = None,
                       K: np.ndarray | None = None) -> dict:  # fmt: skip
    """The contraction of (48) achieved by one exact Kalman step (two-step form).

    With ``P = P_{k|k-1}``, ``K`` of eq. (29) (or the one given), ``M = A (I - K H)`` and the
    next prior ``P_{k+1|k} = M P M^T + A K R K^T A^T + Q`` (Joseph; ``A = I`` by default), returns
    the achieved ``alpha_k = 1 - lambda_max(M^T Pi_{k+1} M, Pi_k) = 1 / (1 + y)``,
    ``y = lambda_max(M P M^T, G)``, ``G = A K R K^T A^T + Q`` (module docstring).

    Returns
    -------
    dict
        ``alpha`` (achieved, no cancellation), ``y``, ``norm_M`` (``||M||_2``), ``K`` (n, m),
        ``P_next`` (the next prior).
    """
    n = P_prior.shape[0]
    A = np.eye(n) if A is None else A
    K = kalman_gain(P_prior, H, R) if K is None else K
    IKH = np.eye(n) - K @ H
    M = A @ IKH
    MPMt = _sym(M @ P_prior @ M.T)
    AK = A @ K
    G = _sym(AK @ R @ AK.T + Q)
    y = float(sla.eigh(MPMt, G, eigvals_only=True, subset_by_index=[n - 1, n - 1])[0])
    return {
        "alpha": 1.0 / (1.0 + y),
        "y": y,
        "norm_M": _norm_identity_minus(K, H) if A is None else float(np.linalg.norm(M, 2)),
        "K": K,
        "P_next": MPMt + G,
    }


def ineq48_holds(alpha_achieved: np.ndarray | float, alpha: float) -> np.ndarray | bool:
    """(48) holds with ``alpha`` at the steps whose achieved contraction is ``>= alpha``."""
    return np.asarray(alpha_achieved) >= alpha


def noise_term(P_next: np.ndarray, K: np.ndarray, q_diag: np.ndarray, R: np.ndarray) -> float:
    """Theorem 1's noise term of one step, ``mu_k = E[s_k^T Pi_{k+1} s_k]`` (E10).

    With ``s_k = w_k - A K_k v_k`` (``A = I``: the weights are a random walk), ``w ~ N(0, Q)``,
    ``v ~ N(0, R)`` independent (the filter's own noise model)::

        mu_k = tr(Pi_{k+1} (Q + K R K^T)),   Pi_{k+1} = P_{k+1|k}^-1,

    evaluated as ``sum (L^-1)_ij^2 q_j + ||L^-1 K C||_F^2`` with ``P_{k+1|k} = L L^T`` and
    ``R = C C^T`` (Cholesky; no explicit inverse of ``P``).

    Parameters
    ----------
    P_next : ndarray, shape (n, n)
        The next prior ``P_{k+1|k}`` (SPD).
    K : ndarray, shape (n, m)
        The Kalman gain of eq. (29).
    q_diag : ndarray, shape (n,)
        The diagonal of ``Q`` (diagonal process noise).
    R : ndarray, shape (m, m)
        Measurement-noise covariance (SPD).
    """
    L = np.linalg.cholesky(P_next)
    Linv = sla.solve_triangular(L, np.eye(L.shape[0]), lower=True)
    LK = Linv @ K @ np.linalg.cholesky(R)
    return float(np.sum(Linv**2 * np.asarray(q_diag)[None, :]) + np.sum(LK**2))


def noise_term_parts(P_next: np.ndarray, K: np.ndarray, q_diag: np.ndarray
                     ) -> tuple[float, np.ndarray]:  # fmt: skip
    """Theorem 1's noise term of one step split by noise source, for any measurement noise.

    ``mu_k = tr(Pi_{k+1} Q_w) + tr(Pi_{k+1} K R_v K^T)`` (:func:`noise_term`) is linear in the
    measurement-noise covariance ``R_v``: ``tr(Pi K R_v K^T) = sum_ij (R_v)_ij (K^T Pi K)_ij``
    (both symmetric).  So one step's ``(tr(Pi_{k+1} Q_w), K^T Pi_{k+1} K)`` gives ``mu_k`` for
    the filter's own ``R`` and for a measured noise covariance alike
    (:func:`noise_term_from_parts`).

    Parameters
    ----------
    P_next : ndarray, shape (n, n)
        The next prior ``P_{k+1|k}`` (SPD).
    K : ndarray, shape (n, m)
        The Kalman gain of eq. (29).
    q_diag : ndarray, shape (n,)
        The diagonal of the process-noise covariance ``Q_w``.

    Returns
    -------
    tuple
        ``tr(Pi_{k+1} Q_w)`` (float) and ``K^T Pi_{k+1} K`` (ndarray, shape (m, m)).
    """
    L = np.linalg.cholesky(P_next)
    Linv = sla.solve_triangular(L, np.eye(L.shape[0]), lower=True)
    LK = Linv @ K
    return float(np.sum(Linv**2 * np.asarray(q_diag)[None, :])), LK.T @ LK


def noise_term_from_parts(tr_pi_q: float | np.ndarray, ktpik: np.ndarray,
                          R: np.ndarray) -> float | np.ndarray:  # fmt: skip
    """``mu_k = tr(Pi Q_w) + sum_ij R_ij (K^T Pi K)_ij`` from :func:`noise_term_parts`.

    ``tr_pi_q`` scalar or shape (N,), ``ktpik`` shape (m, m) or (N, m, m), ``R`` (m, m): the
    measurement-noise covariance the expectation is taken with.
    """
    return tr_pi_q + np.sum(np.asarray(ktpik) * np.asarray(R), axis=(-2, -1))


def theorem1_bound(alpha: float, p_min: float, p_max: float, mu: float, e0_sq: float,
                   k: np.ndarray | float) -> dict:  # fmt: skip
    """The mean-square bound that Theorem 1's proof gives once (59) holds (E10 reading).

    From ``E V_{k+1} <= (1 - alpha/2) V_k + mu`` (eq. 59, ``mu = kappa_noise delta``) and
    ``||e||^2 / p_max <= V <= ||e||^2 / p_min`` (eq. 53)::

        E ||e_{k|k-1}||^2 <= (p_max / p_min) ||e_0||^2 (1 - alpha/2)^k + 2 p_max mu / alpha.

    Valid only inside the region ``||e|| <= eps = min(eps', alpha / (2 p_max kappa_max))``
    (eq. 57), whose size needs Assumption 2's ``kappa`` (not computable without a true weight
    vector).  Returns the bound at ``k`` and its parts: ``transient_gain = p_max / p_min``,
    ``noise_floor = 2 p_max mu / alpha``, ``decay_steps = 2 / alpha`` (e-folding of the
    transient) and ``eps_times_kappa = alpha / (2 p_max)``.
    """
    k = np.asarray(k, dtype=float)
    decay = np.exp(k * np.log1p(-0.5 * alpha))
    floor = 2.0 * p_max * mu / alpha
    return {
        "bound_sq": (p_max / p_min) * e0_sq * decay + floor,
        "transient_gain": p_max / p_min,
        "noise_floor": floor,
        "decay_steps": 2.0 / alpha,
        "eps_times_kappa": alpha / (2.0 * p_max),
    }


def chi2_band(dof: int, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` band of the average of ``runs`` independent chi^2(dof) values.

    ``runs * mean ~ chi^2(runs dof)``, so the band is ``chi2.ppf((1 -+ level)/2, runs dof)/runs``
    (Bar-Shalom, Li & Kirubarajan 2001, §5.4).
    """
    if dof < 1 or runs < 1 or not 0 < level < 1:
        raise ValueError(f"chi2_band: need dof >= 1, runs >= 1, 0 < level < 1; got "
                         f"{dof}, {runs}, {level}")  # fmt: skip
    lo = stats.chi2.ppf(0.5 * (1 - level), dof * runs) / runs
    hi = stats.chi2.ppf(0.5 * (1 + level), dof * runs) / runs
    return float(lo), float(hi)


def random_walk_consistency(q: float, r: float) -> tuple[float, float]:
    """Steady-state expected NEES and NIS of a scalar random-walk Kalman filter whose true state
    has *no* process noise (the pose filter's situation, per axis, when its model is exact).

    Filter model ``x_{k+1} = x_k + w``, ``w ~ N(0, q)``; measurement ``z = x + v``,
    ``v ~ N(0, r)``.  In units of ``r`` with ``rho = q / r``, the steady posterior variance ``p``
    solves ``p = (p + rho) / (p + rho + 1)``, i.e. ``p^2 + rho p - rho = 0``, and the gain is
    ``K = (p + rho)/(p + rho + 1) = p``.  The true error obeys ``e+ = (1 - K) e- + K v`` with
    ``e-`` the previous ``e+`` (no true process noise), so its variance is ``K / (2 - K)`` and::

        NEES = (K / (2 - K)) / p = 1 / (2 - K),
        NIS  = (K / (2 - K) + 1) / (p + rho + 1) = 2 (1 - K) / (2 - K).

    Both are below 1 (the value of a consistent filter) for every ``q > 0``.  Returns
    ``(NEES, NIS)`` per axis.
    """
    if not (q >= 0 and r > 0):
        raise ValueError(f"random_walk_consistency: need q >= 0 and r > 0, got {q}, {r}")
    rho = q / r
    K = 0.5 * (-rho + math.sqrt(rho * rho + 4.0 * rho))
    return 1.0 / (2.0 - K), 2.0 * (1.0 - K) / (2.0 - K)


def random_walk_increment_noise(q: float, r: float) -> tuple[float, float]:
    """Steady-state variance and lag-1 autocorrelation of the *increment* of a scalar
    random-walk Kalman filter's error, when the true state has no process noise.

    The filter of :func:`random_walk_consistency` (model ``x+ = x + w``, ``w ~ N(0, q)``,
    measurement ``z = x + v``, ``v ~ N(0, r)``; steady gain ``K``, ``rho = q/r``,
    ``K = (-rho + sqrt(rho^2 + 4 rho))/2``) has posterior error ``e_k = (1 - K) e_{k-1} + K v_k``
    with variance ``s2 = r K / (2 - K)``.  Its increment ``d_k = e_k - e_{k-1} = -K e_{k-1} +
    K v_k`` (what differencing the estimate adds to the true increment) has::

        Var d = K^2 (s2 + r),
        Cov(d_k, d_{k+1}) = K^2 ((1 - K) s2 - K r),
        corr_1 = ((1 - K) s2 - K r) / (s2 + r).

    Returns ``(Var d / r, corr_1)``: the variance in units of ``r`` and the lag-1
    autocorrelation (negative: a differenced filter error is not white).
    """
    if not (q > 0 and r > 0):
        raise ValueError(f"random_walk_increment_noise: need q > 0 and r > 0, got {q}, {r}")
    rho = q / r
    K = 0.5 * (-rho + math.sqrt(rho * rho + 4.0 * rho))
    s2 = K / (2.0 - K)  # in units of r
    return K * K * (s2 + 1.0), ((1.0 - K) * s2 - K) / (s2 + 1.0)


def _norm_identity_minus(K: np.ndarray, H: np.ndarray) -> float:
    """``||I - K H||_2`` for ``K`` (n, m), ``H`` (m, n) in O(n m^2).

    With ``U`` an orthonormal basis of ``span(H^T, K)`` (``r <= 2m`` columns), ``I - K H`` is the
    identity on ``U``'s orthogonal complement and maps ``span U`` into itself, so its norm is
    ``max(1, ||I_r - U^T K H U||)`` (the 1 only when the complement is not empty).
    """
    n = K.shape[0]
    U, sv, _ = np.linalg.svd(np.hstack((H.T, K)), full_matrices=False)
    U = U[:, sv > sv[0] * n * np.finfo(float).eps]
    r = U.shape[1]
    inner = float(np.linalg.norm(np.eye(r) - (U.T @ K) @ (H @ U), 2))
    return max(1.0, inner) if r < n else inner


def _sym(X: np.ndarray) -> np.ndarray:
    X = np.atleast_2d(np.asarray(X, dtype=float))
    return 0.5 * (X + X.T)
