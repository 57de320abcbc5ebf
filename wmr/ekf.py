"""Discrete extended Kalman filters as pure functions (Joseph form, symmetrised).

Two filters share these updates:

- the **weight filter** of eqs. (25)-(31), corrected as in errata E8: the network weights are the
  state with the identity as process model (``A_k = I``, ``P_{k|k-1} = P + Q``), and the
  innovation is ``d_k - h(theta, x_k)`` at the *current* network input (not ``h(theta, 0)``);
- the **pose filter** for localisation (errata E9, reading A): the unicycle ZOH step as process
  model and the measured pose as measurement (``H = I_3``), heading innovation wrapped.

The covariance update is Joseph's ``P+ = (I - K H) P (I - K H)^T + K R K^T``: it keeps ``P``
symmetric positive semi-definite under round-off and for any gain.  For symmetric ``P`` and
``S = H P H^T + R`` it expands exactly to ``P - K (P H^T)^T - (P H^T) K^T + K S K^T``, which
costs O(n^2 m) instead of O(n^3) (DESIGN §6).
"""

from __future__ import annotations

import math

import numpy as np

from wmr._jit import njit
from wmr.kinematics import step, step_jacobians, wrap_angle

__all__ = [
    "weight_update",
    "weight_update_reference",
    "joseph_update",
    "repair_covariance",
    "is_positive_definite",
    "pose_predict",
    "pose_update",
    "nees",
]


@njit
def _cholesky_solve_rows(L, B, X):
    """Solve ``S X[i] = B[i]`` for every row ``i`` of ``B`` (n, m), with ``S = L L^T`` (m, m)."""
    m = L.shape[0]
    y = np.empty(m)
    for i in range(B.shape[0]):
        for a in range(m):
            acc = B[i, a]
            for b in range(a):
                acc -= L[a, b] * y[b]
            y[a] = acc / L[a, a]
        for a in range(m - 1, -1, -1):
            acc = y[a]
            for b in range(a + 1, m):
                acc -= L[b, a] * X[i, b]
            X[i, a] = acc / L[a, a]


@njit
def _small_cholesky(S):
    """Lower Cholesky factor of a small SPD matrix; NaNs if it is not positive definite."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        L[j, j] = math.sqrt(d) if d > 0.0 else math.nan
        for i in range(j + 1, m):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    return L


@njit(fastmath={"reassoc", "contract"})  # lets the O(n^2 m) sums vectorise; ~1e-16 changes
def joseph_update(x, P, H, innovation, R, work):
    """Kalman measurement update of ``x`` (n,) and ``P`` (n, n), in place, in O(n^2 m).

    Parameters
    ----------
    x, P : ndarray
        State and symmetric covariance, updated in place.
    H : ndarray, shape (m, n)
        Measurement Jacobian.
    innovation : ndarray, shape (m,)
        ``z - h(x)`` (angles already wrapped by the caller).
    R : ndarray, shape (m, m)
        Measurement noise covariance.
    work : ndarray, shape (3, n, m)
        Scratch space (``P H^T``, the gain ``K`` and ``M``), overwritten.

    Returns
    -------
    float
        The normalised innovation squared ``nu^T S^-1 nu`` (NIS); NaN if ``S`` is not positive
        definite (then nothing is updated).

    Notes
    -----
    With ``M = K S / 2 - P H^T`` the Joseph form is ``P + K M^T + M K^T``: symmetric by
    construction, 2 m multiply-adds per entry of the upper triangle.
    """
    n = x.size
    m = innovation.size
    PHt = work[0]
    K = work[1]
    M = work[2]
    for i in range(n):
        for a in range(m):
            acc = 0.0
            for j in range(n):
                acc += P[i, j] * H[a, j]
            PHt[i, a] = acc
    S = R.copy()
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for j in range(n):
                acc += H[a, j] * PHt[j, b]
            S[a, b] += acc
    for a in range(m):  # symmetrise S against round-off
        for b in range(a + 1, m):
            v = 0.5 * (S[a, b] + S[b, a])
            S[a, b] = v
            S[b, a] = v
    L = _small_cholesky(S)
    if not math.isfinite(L[m - 1, m - 1]):
        return math.nan
    _cholesky_solve_rows(L, PHt, K)  # K = P H^T S^-1
    nu = np.empty((1, m))
    nu[0, :] = innovation
    Sinv_nu = np.empty((1, m))
    _cholesky_solve_rows(L, nu, Sinv_nu)
    nis = 0.0
    for a in range(m):
        nis += innovation[a] * Sinv_nu[0, a]
    for i in range(n):
        acc = 0.0
        for a in range(m):
            acc += K[i, a] * innovation[a]
        x[i] += acc
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += K[i, b] * S[b, a]
            M[i, a] = 0.5 * acc - PHt[i, a]
    for i in range(n):
        for j in range(i, n):
            acc = P[i, j]
            for a in range(m):
                acc += K[i, a] * M[j, a] + M[i, a] * K[j, a]
            P[i, j] = acc
            P[j, i] = acc
    return nis


@njit
def weight_update(theta, P, H, innovation, q_diag, R, work):
    """One step of the weight filter, eqs. (27)-(31) with errata E8, in place.

    Predict with ``f = identity``: ``P <- P + diag(q_diag)``; then the Joseph update of
    :func:`joseph_update` with ``H = dz/dtheta`` at the current input and the innovation
    ``d_k - h(theta, x_k)``.  ``work`` is scratch of shape (3, n, m).  Returns the NIS.
    """
    for i in range(theta.size):
        P[i, i] += q_diag[i]
    return joseph_update(theta, P, H, innovation, R, work)


def weight_update_reference(theta, P, H, innovation, q_diag, R):
    """The same step written literally with dense matrices (test oracle; O(n^3))."""
    theta = np.array(theta, dtype=float)
    P = np.array(P, dtype=float) + np.diag(q_diag)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    IKH = np.eye(theta.size) - K @ H
    return theta + K @ innovation, IKH @ P @ IKH.T + K @ R @ K.T


@njit
def is_positive_definite(P):
    """True when ``P`` is symmetric positive definite (a Cholesky factorisation succeeds)."""
    n = P.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = P[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            acc = P[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    return True


@njit
def repair_covariance(P, floor):
    """Cheap guard run every step: returns True (and repairs) if a diagonal entry of ``P`` is not
    above ``floor`` or not finite, by symmetrising and lifting the diagonal to ``floor``.

    A full check (:func:`is_positive_definite`, O(n^3)) is left to the analyses, which run it
    along whole runs; the diagonal check costs O(n).
    """
    bad = False
    for i in range(P.shape[0]):
        if not P[i, i] > floor:
            bad = True
            break
    if bad:
        n = P.shape[0]
        for i in range(n):
            for j in range(i + 1, n):
                v = 0.5 * (P[i, j] + P[j, i])
                P[i, j] = v
                P[j, i] = v
            if not P[i, i] > floor:
                P[i, i] = floor
    return bad


@njit
def pose_predict(q_hat, P, u, dt, integrator, Qp):
    """Pose-filter prediction, in place: ``q_hat <- step(q_hat, u)``, ``P <- F P F^T + Qp``."""
    F, _ = step_jacobians(q_hat, u, dt, integrator)
    q_hat[:] = step(q_hat, u, dt, integrator)
    P[:, :] = F @ P @ F.T + Qp


@njit
def pose_update(q_hat, P, z, Rp):
    """Pose-filter update with the measured pose ``z`` (``H = I_3``), in place; returns the NIS.

    The heading innovation is wrapped to (-pi, pi]; the estimate's heading stays continuous.
    """
    nu = z - q_hat
    nu[2] = wrap_angle(nu[2])
    return joseph_update(q_hat, P, np.eye(3), nu, Rp, np.empty((3, 3, 3)))


@njit
def nees(q_true, q_hat, P):
    """Normalised estimation error squared ``e^T P^-1 e`` (heading error wrapped)."""
    e = q_true - q_hat
    e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(P, e))
