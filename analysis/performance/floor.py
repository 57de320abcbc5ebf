"""The benchmark's floor: the cheapest correct weight-EKF update we could write (a reference).

The performance study (``analysis.performance``) judges the closed-loop step of
``iapid-nn-dekf`` against :func:`floor_update`, a standard-form EKF update of the same size,
written with hand-made loops and timed inside a jitted loop like the closed loop, and times the
library's ``wmr.estimation.ekf.weight_update`` the same way beside it.  Nothing here is used by the
loop: it is a measuring stick, checked against the dense textbook update (``wmr.estimation.ekf``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from analysis.performance.bench import clocks, per_step
from wmr import controllers
from wmr._borrow import borrowed
from wmr._jit import njit
from wmr.controllers import iapid_nn_dekf
from wmr.estimation import nn

# the Cholesky helpers of the library's weight update, shared so the floor uses the same ones
from wmr.estimation.ekf import cholesky, cholesky_solve_rows, weight_update, weight_update_reference

__all__ = [
    "SUBJECT",
    "floor_update",
    "floor_loop",
    "library_weight_update_loop",
    "filter_problem",
    "time_floor",
    "check_floor",
]

#: The controller whose weight filter the floor stands for.
SUBJECT = "iapid-nn-dekf"


@njit
def floor_update(theta, P, H, innovation, q_diag, R, work, specialise=True):
    """The floor: a minimal EKF weight update (identity model), in place.

    ``P <- P + diag(q_diag)``; ``HP = H P`` (m, n) (= ``(P H^T)^T`` for symmetric ``P``);
    ``S = HP H^T + R``; ``K^T = S^-1 HP`` (Cholesky of the m x m ``S``); ``theta += K nu``;
    ``P <- P - K (H P)`` — the standard (non-Joseph) form.  Laid out by rows so every inner loop
    runs along a row of ``P`` and vectorises without reassociation: ``2 n^2 m`` multiply-adds.
    With ``specialise`` and ``m == 3`` (the network's outputs) the three output rows are fused
    into one pass, and two rows of ``P`` are taken per pass (the same blocking as the library's
    ``wmr.estimation.ekf`` kernels, so the floor stays the best we know); otherwise one pass per
    output.

    Parameters
    ----------
    theta : ndarray, shape (n,)
    P : ndarray, shape (n, n), symmetric
    H : ndarray, shape (m, n)
    innovation : ndarray, shape (m,)
    q_diag : ndarray, shape (n,)
    R : ndarray, shape (m, m)
    work : ndarray, shape (2, m, n)
        Scratch (``H P`` and ``K^T``), overwritten.
    specialise : bool
        Use the fused ``m == 3`` passes when ``m == 3``.
    """
    n = theta.size
    m = innovation.size
    HP = work[0]
    Kt = work[1]
    for i in range(n):
        P[i, i] += q_diag[i]
    HP[:, :] = 0.0
    fused = specialise and m == 3
    paired = n - n % 2 if fused else 0  # rows taken two at a time by the fused passes
    if fused:
        h0, h1, h2 = HP[0], HP[1], HP[2]
        for i in range(0, paired, 2):  # rows i and i + 1 of P in one pass over HP
            Pi, Pk = P[i], P[i + 1]
            a0, a1, a2 = H[0, i], H[1, i], H[2, i]
            b0, b1, b2 = H[0, i + 1], H[1, i + 1], H[2, i + 1]
            for j in range(n):
                p = Pi[j]
                r = Pk[j]
                h0[j] += a0 * p + b0 * r
                h1[j] += a1 * p + b1 * r
                h2[j] += a2 * p + b2 * r
    for i in range(paired, n):  # the rest, one output at a time
        Pi = P[i]
        for a in range(m):
            h = H[a, i]
            ha = HP[a]
            for j in range(n):
                ha[j] += h * Pi[j]
    S = R.copy()
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for j in range(n):
                acc += HP[a, j] * H[b, j]
            S[a, b] += acc
    L = np.zeros((m, m))
    cholesky(S, L)
    cholesky_solve_rows(L, HP, Kt)  # K^T = S^-1 H P
    for a in range(m):
        g = innovation[a]
        for j in range(n):
            theta[j] += Kt[a, j] * g
    if fused:
        k0r, k1r, k2r = Kt[0], Kt[1], Kt[2]
        h0, h1, h2 = HP[0], HP[1], HP[2]
        for i in range(0, paired, 2):  # rows i and i + 1 share the loads of HP
            Pi, Pk = P[i], P[i + 1]
            c0, c1, c2 = k0r[i], k1r[i], k2r[i]
            d0, d1, d2 = k0r[i + 1], k1r[i + 1], k2r[i + 1]
            for j in range(n):
                x0, x1, x2 = h0[j], h1[j], h2[j]
                Pi[j] -= c0 * x0 + c1 * x1 + c2 * x2
                Pk[j] -= d0 * x0 + d1 * x1 + d2 * x2
    for i in range(paired, n):
        Pi = P[i]
        for a in range(m):
            k = Kt[a, i]
            ha = HP[a]
            for j in range(n):
                Pi[j] -= k * ha[j]


@njit
def floor_loop(steps, theta, P, H, innovation, q_diag, R, work, specialise=True):
    """``steps`` calls of :func:`floor_update` inside one jitted loop (no Python call overhead),
    the arrays borrowed as the closed loop borrows them (``wmr._borrow``: no reference counts)."""
    theta, P, H, innovation, q_diag, R, work = borrowed((theta, P, H, innovation, q_diag, R, work))
    for _ in range(steps):
        floor_update(theta, P, H, innovation, q_diag, R, work, specialise)


@njit
def library_weight_update_loop(steps, theta, P, H, innovation, q_diag, R, work):
    """``steps`` calls of the library's ``wmr.estimation.ekf.weight_update`` inside one jitted
    loop, the arrays borrowed as in :func:`floor_loop`."""
    theta, P, H, innovation, q_diag, R, work = borrowed((theta, P, H, innovation, q_diag, R, work))
    for _ in range(steps):
        weight_update(theta, P, H, innovation, q_diag, R, work)


def filter_problem(hidden: int, scenario) -> dict:
    """A realistic weight-filter problem of ``iapid-nn-dekf`` with ``hidden`` units.

    ``theta`` and ``P`` its initial weights and covariance (initialised from
    ``default_rng(0)``), ``q`` and ``R`` its filter's noise, ``H`` the weight Jacobian at those
    weights for the identifier input ``(v, w, theta) = (0.3, 0.2, 1.0)``, ``nu`` a fixed
    innovation.
    """
    ctrl = controllers.get(SUBJECT)
    st = dataclasses.replace(scenario.settings(SUBJECT), hidden=hidden)
    p, _, theta, P = ctrl.pack(st, scenario, np.random.default_rng(0))
    x = iapid_nn_dekf.identifier_input(np.array([0.3, 0.2]), 1.0)
    _, h = nn.forward(theta, x, hidden, iapid_nn_dekf.N_OUT)
    H = np.zeros((iapid_nn_dekf.N_OUT, theta.size))
    nn.weight_jacobian(theta, x, hidden, iapid_nn_dekf.N_OUT, h, H)
    return {"theta": theta, "P": P, "H": H, "nu": np.array([1e-3, -2e-3, 5e-4]),
            "q": p.q_diag, "R": p.R}  # fmt: skip


def time_floor(prob: dict, steps: int, kind: str) -> tuple[float, float]:
    """(wall, CPU) seconds per update of the floor (``kind`` = ``"floor"``, or ``"generic"``:
    without the fused ``m == 3`` passes) or of the library's update (``"library"``).

    Raises ``AssertionError`` if the updates left non-finite or subnormal covariance entries
    (subnormal arithmetic would make the timing meaningless).
    """
    theta, P = prob["theta"].copy(), prob["P"].copy()
    n, m = theta.size, prob["nu"].size
    t0 = clocks()
    if kind == "library":
        library_weight_update_loop(steps, theta, P, prob["H"], prob["nu"], prob["q"], prob["R"],
                                   np.zeros((3, m, n)))  # fmt: skip
    else:
        floor_loop(steps, theta, P, prob["H"], prob["nu"], prob["q"], prob["R"],
                   np.zeros((2, m, n)), kind == "floor")  # fmt: skip
    elapsed = per_step(t0, steps)
    if not np.all(np.isfinite(P)) or np.any((P != 0) & (np.abs(P) < np.finfo(float).tiny)):
        raise AssertionError(f"{kind} update left non-finite or subnormal covariance entries")
    return elapsed


def check_floor(prob: dict) -> float:
    """Max relative difference of one floor update against the dense textbook update
    (``wmr.estimation.ekf.weight_update_reference``) from a random well-conditioned covariance."""
    rng = np.random.default_rng(1)
    n = prob["theta"].size
    A = rng.standard_normal((n, n))
    P0 = A @ A.T / n + np.eye(n)
    theta, P = prob["theta"].copy(), P0.copy()
    nu = rng.standard_normal(3)
    floor_update(theta, P, prob["H"], nu, prob["q"], prob["R"], np.zeros((2, 3, n)))
    t_ref, P_ref = weight_update_reference(prob["theta"], P0, prob["H"], nu, prob["q"], prob["R"])
    return max(float(np.max(np.abs(theta - t_ref)) / max(np.max(np.abs(t_ref)), 1e-300)),
               float(np.max(np.abs(P - P_ref)) / np.max(np.abs(P_ref))))  # fmt: skip
