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
from wmr.model.kinematics import step_into, step_jacobians_into, wrap_angle

__all__ = [
    "weight_update",
    "weight_update_reference",
    "joseph_update",
    "joseph_identity3",
    "innovation_covariance",
    "repair_covariance",
    "is_positive_definite",
    "pose_predict",
    "pose_update",
    "pose_work",
    "POSE_WORK",
    "nees",
    "cholesky",
    "cholesky_solve_rows",
]


@njit
def joseph_update(x, P, H, innovation, R, work, small=None):
    """Kalman measurement update in Joseph form, O(n^2 m), in place.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Prior state estimate; updated in place to ``x + K innovation``.
    P : ndarray, shape (n, n)
        Prior covariance, exactly symmetric (as every function of this module leaves it);
        overwritten with the posterior covariance, again exactly symmetric.
    H : ndarray, shape (m, n)
        Measurement Jacobian at the prior estimate.
    innovation : ndarray, shape (m,)
        Measurement residual ``z - h(x)`` (angles already wrapped by the caller).
    R : ndarray, shape (m, m)
        Measurement noise covariance, symmetric positive definite.
    work : ndarray, shape (3, m, n)
        Scratch, overwritten: ``work[0] = H P``, ``work[1] = K^T``,
        ``work[2] = (K S / 2 - P H^T)^T``.
    small : ndarray, shape (3, m, m), optional
        Scratch for ``S``, its Cholesky factor and the NIS solve (``small[0]``, ``small[1]``,
        ``small[2, 0]``), overwritten; without it they are allocated (the loop passes it: no
        allocation in the step).

    Returns
    -------
    float
        Normalised innovation squared ``NIS = innovation^T S^{-1} innovation`` with
        ``S = H P H^T + R``; ``nan`` if ``S`` is not numerically positive definite (only possible
        when ``P`` or ``R`` is not PSD or not finite), in which case ``x`` and ``P`` are left
        unchanged and the caller must treat the filter as failed.

    Notes
    -----
    Joseph form ``P+ = (I - K H) P (I - K H)^T + K R K^T`` because it keeps ``P`` symmetric PSD
    under round-off and for any (even suboptimal) gain ``K``; the plain ``(I - K H) P`` does not.
    For symmetric ``P`` with ``M = P H^T`` (n, m), ``S = H M + R`` and ``K = M S^{-1}`` it expands
    exactly to::

        P+ = P + C,   C = - K M^T - M K^T + K S K^T,

    a rank-2m correction costing O(n^2 m) instead of the O(n^3) of the literal products.  ``K S``
    is evaluated, not replaced by ``M`` (which would collapse ``C`` to the plain ``-K M^T`` and
    lose the Joseph form's first-order insensitivity to errors in ``K``).  The correction is
    symmetrised, ``(C + C^T)/2 = D K^T + K D^T`` with ``D = K S / 2 - M``; for symmetric ``P``
    this is ``(P+ + P+^T)/2``.  Each entry ``D_a . K_b + K_a . D_b`` is the same IEEE sum for
    ``(a, b)`` and ``(b, a)`` (products and a two-term sum commute exactly; no FMA contraction,
    ``fastmath=False``), so ``P+`` comes out exactly symmetric without a transpose pass.
    ``S`` is factored by Cholesky (m x m) and ``K`` obtained by triangular solves, no inverse.
    ``M``, ``K`` and ``D`` are held transposed, (m, n), so every inner loop runs along contiguous
    memory and vectorises.
    """
    n = x.size
    m = innovation.size
    if (P.shape != (n, n) or H.shape != (m, n) or R.shape != (m, m)
            or work.shape[0] < 3 or work.shape[1] != m or work.shape[2] != n):  # fmt: skip
        # O(1); without it a wrongly shaped scratch would be written out of bounds
        raise ValueError("joseph_update: need P (n, n), H (m, n), R (m, m), work (3, m, n)")
    HP = work[0]
    Kt = work[1]
    Dt = work[2]
    if small is None:
        S = np.empty((m, m))
        L = np.empty((m, m))
        y = np.empty(m)
    else:
        S = small[0]
        L = small[1]  # only its lower triangle is written and read
        y = small[2, 0]
    # M^T = H P (= (P H^T)^T for symmetric P)
    _h_times_p(H, P, HP)
    innovation_covariance(HP, H, R, S)
    _symmetrise(S)
    if not cholesky(S, L):
        return np.nan
    # K^T = S^{-1} H P, by forward and back substitution with L L^T = S
    cholesky_solve_rows(L, HP, Kt)
    # D^T = (S K^T) / 2 - H P; S K^T equals H P only up to round-off, and that is the point
    _d_matrix(S, Kt, HP, Dt)
    nis = _normalised_square(L, innovation, y)
    _add_gain_times(x, Kt, innovation)
    _symmetric_rank_update(P, Kt, Dt)
    return nis


@njit
def innovation_covariance(HP, H, R, S):
    """``S = (H P) H^T + R`` (m, m), each entry the sum over ``b = 0 .. n-1`` in that order.

    For ``m = 3`` the nine sums run in one pass over ``b``: nine independent chains of additions
    in flight instead of one at a time (a sum's order is fixed, so it cannot be vectorised; its
    additions wait on each other).  Same sums, same order: bit-identical (test_ekf).
    """
    m, n = HP.shape
    if m == 3:
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        h0, h1, h2 = HP[0], HP[1], HP[2]
        g0, g1, g2 = H[0], H[1], H[2]
        for b in range(n):
            x0, x1, x2, y0, y1, y2 = h0[b], h1[b], h2[b], g0[b], g1[b], g2[b]
            a00 += x0 * y0
            a01 += x0 * y1
            a02 += x0 * y2
            a10 += x1 * y0
            a11 += x1 * y1
            a12 += x1 * y2
            a20 += x2 * y0
            a21 += x2 * y1
            a22 += x2 * y2
        S[0, 0], S[0, 1], S[0, 2] = a00 + R[0, 0], a01 + R[0, 1], a02 + R[0, 2]
        S[1, 0], S[1, 1], S[1, 2] = a10 + R[1, 0], a11 + R[1, 1], a12 + R[1, 2]
        S[2, 0], S[2, 1], S[2, 2] = a20 + R[2, 0], a21 + R[2, 1], a22 + R[2, 2]
        return
    for r in range(m):
        for s in range(m):
            acc = 0.0
            for b in range(n):
                acc += HP[r, b] * H[s, b]
            S[r, s] = acc + R[r, s]


@njit
def _symmetrise(S):
    """``S = (S + S^T) / 2`` in place, each pair averaged once (a square matrix)."""
    for r in range(S.shape[0]):
        for s in range(r):
            v = 0.5 * (S[r, s] + S[s, r])
            S[r, s] = v
            S[s, r] = v


@njit
def _d_matrix(S, Kt, HP, Dt):
    """``D^T = (S K^T) / 2 - H P`` (m, n): entry ``(r, b)`` is ``-HP[r, b] + c_0 K[b, 0] + c_1
    K[b, 1] + ...`` (left to right, ``c_s = S[r, s] / 2``), one pass over ``b`` per row when
    ``m = 3`` (the same sums as a pass per term: bit-identical)."""
    m, n = Kt.shape
    for r in range(m):
        out = Dt[r]
        hp = HP[r]
        if m == 3:
            c0, c1, c2 = 0.5 * S[r, 0], 0.5 * S[r, 1], 0.5 * S[r, 2]
            K0, K1, K2 = Kt[0], Kt[1], Kt[2]
            for b in range(n):
                out[b] = -hp[b] + c0 * K0[b] + c1 * K1[b] + c2 * K2[b]
            continue
        for b in range(n):
            out[b] = -hp[b]
        for s in range(m):
            c = 0.5 * S[r, s]
            Ks = Kt[s]
            for b in range(n):
                out[b] += c * Ks[b]


@njit
def _add_gain_times(x, Kt, innovation):
    """``x += K innovation`` in place: ``x[b] + K[b, 0] nu_0 + K[b, 1] nu_1 + ...`` left to right,
    one pass when ``m = 3`` (bit-identical to a pass per output)."""
    m, n = Kt.shape
    if m == 3:
        c0, c1, c2 = innovation[0], innovation[1], innovation[2]
        K0, K1, K2 = Kt[0], Kt[1], Kt[2]
        for b in range(n):
            x[b] = x[b] + K0[b] * c0 + K1[b] * c1 + K2[b] * c2
        return
    for r in range(m):
        c = innovation[r]
        Kr = Kt[r]
        for b in range(n):
            x[b] += Kr[b] * c


@njit
def _h_times_p(H, P, HP):
    """``HP = H P``, (m, n), as axpys of the contiguous rows of ``P``, in place.

    Each ``HP[r, b]`` is the sum over ``a = 0 .. n-1`` in that order of ``H[r, a] P[a, b]``,
    skipping the zero ``H[r, a]`` (the network's ``H`` is block-sparse in its output layer).  For
    ``m = 3``, where two consecutive columns of ``H`` have no zero, the three outputs take both
    rows of ``P`` in one pass over ``HP`` (same sums, same order: bit-identical, test_ekf).
    """
    m, n = HP.shape
    HP[:, :] = 0.0
    a = 0
    while a < n:
        if (m == 3 and a + 1 < n and H[0, a] != 0.0 and H[1, a] != 0.0 and H[2, a] != 0.0
                and H[0, a + 1] != 0.0 and H[1, a + 1] != 0.0 and H[2, a + 1] != 0.0):  # fmt: skip
            c0, c1, c2 = H[0, a], H[1, a], H[2, a]
            g0, g1, g2 = H[0, a + 1], H[1, a + 1], H[2, a + 1]
            p1, p2 = P[a], P[a + 1]
            h0, h1, h2 = HP[0], HP[1], HP[2]
            for b in range(n):
                v = p1[b]
                w = p2[b]
                h0[b] = h0[b] + c0 * v + g0 * w
                h1[b] = h1[b] + c1 * v + g1 * w
                h2[b] = h2[b] + c2 * v + g2 * w
            a += 2
            continue
        row = P[a]
        for r in range(m):
            c = H[r, a]
            if c != 0.0:
                out = HP[r]
                for b in range(n):
                    out[b] += c * row[b]
        a += 1


@njit
def _symmetric_rank_update(P, Kt, Dt):
    """``P += D K^T + K D^T`` in place, ``Kt``, ``Dt`` of shape (m, n), ``m`` small.

    Entry ``(a, b)`` becomes ``P[a, b] + t_0 + t_1 + ...`` (left to right) with
    ``t_r = D[a, r] K[b, r] + K[a, r] D[b, r]``; ``t_r`` is the same IEEE number at ``(b, a)``, so
    a symmetric ``P`` stays exactly symmetric.  Full rows, not the upper triangle: mirroring a
    triangle costs more in strided stores than the multiplications it saves (measured).  The
    ``m = 3`` case is written out, one row per pass with the three terms fused: one row stored per
    loop keeps the loop's possible overlaps few enough for LLVM to vectorise it behind its
    run-time checks (two rows per pass were not vectorised: measured 10-25 % slower).  The
    arithmetic is the same, so the result is bit-identical (test_ekf).
    """
    m, n = Kt.shape
    if m == 3:
        K0, K1, K2 = Kt[0], Kt[1], Kt[2]
        D0, D1, D2 = Dt[0], Dt[1], Dt[2]
        for a in range(n):
            row = P[a]
            d0, d1, d2, k0, k1, k2 = D0[a], D1[a], D2[a], K0[a], K1[a], K2[a]
            for b in range(n):
                row[b] = (row[b] + (d0 * K0[b] + k0 * D0[b]) + (d1 * K1[b] + k1 * D1[b])
                          + (d2 * K2[b] + k2 * D2[b]))  # fmt: skip
        return
    for i in range(n):
        row = P[i]
        for r in range(m):
            d_a = Dt[r, i]
            k_a = Kt[r, i]
            Kr = Kt[r]
            Dr = Dt[r]
            for b in range(n):
                row[b] += d_a * Kr[b] + k_a * Dr[b]


@njit
def cholesky(A, L):
    """Write the lower Cholesky factor of ``A`` (lower triangle read) into ``L``.

    Returns False (with ``L`` partly written) if a pivot is not positive or not finite.
    """
    n = A.shape[0]
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0 or not math.isfinite(d):
            return False
        ljj = math.sqrt(d)
        L[j, j] = ljj
        for i in range(j + 1, n):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / ljj
    return True


@njit
def cholesky_solve_rows(L, B, X):
    """``X = (L L^T)^{-1} B`` for ``B`` (m, n), by row-wise forward then back substitution."""
    m, n = B.shape
    for r in range(m):
        for b in range(n):
            X[r, b] = B[r, b]
        for s in range(r):
            c = L[r, s]
            for b in range(n):
                X[r, b] -= c * X[s, b]
        inv = 1.0 / L[r, r]
        for b in range(n):
            X[r, b] *= inv
    for r in range(m - 1, -1, -1):
        for s in range(r + 1, m):
            c = L[s, r]
            for b in range(n):
                X[r, b] -= c * X[s, b]
        inv = 1.0 / L[r, r]
        for b in range(n):
            X[r, b] *= inv


@njit
def _normalised_square(L, e, y):
    """``e^T (L L^T)^{-1} e = |L^{-1} e|^2`` by forward substitution; ``L`` lower (m, m), ``y``
    (m,) scratch."""
    m = e.size
    out = 0.0
    for r in range(m):
        acc = e[r]
        for s in range(r):
            acc -= L[r, s] * y[s]
        y[r] = acc / L[r, r]
        out += y[r] * y[r]
    return out


@njit
def weight_update(theta, P, H, innovation, q_diag, R, work, small=None):
    """One step of the weight filter, eqs. (27)-(31) with errata E8, in place.

    Predict with ``f = identity``: ``P <- P + diag(q_diag)``; then the Joseph update of
    :func:`joseph_update` with ``H = dz/dtheta`` at the current input and the innovation
    ``d_k - h(theta, x_k)``.  ``work`` is scratch of shape (3, m, n), ``small`` (3, m, m)
    optional scratch (:func:`joseph_update`).  Returns the NIS.
    """
    for i in range(theta.size):
        P[i, i] += q_diag[i]
    return joseph_update(theta, P, H, innovation, R, work, small)


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


#: Slices of the pose filter's scratch (:func:`pose_work`, shape (POSE_WORK, 3, 3)): the Joseph
#: update's ``work`` (3 slices) and ``small`` (3), the measurement matrix, ``F``, ``F P``, ``G``
#: and the innovation.
_W_JOSEPH, _W_SMALL, _W_H, _W_F, _W_FP, _W_G, _W_NU = 0, 3, 6, 7, 8, 9, 10
POSE_WORK = 11


@njit
def pose_work():
    """Scratch for :func:`pose_predict` and :func:`pose_update`, shape (POSE_WORK, 3, 3)
    (overwritten by each call), so that the loop's pose filter allocates nothing per step."""
    return np.zeros((POSE_WORK, 3, 3))


@njit
def pose_predict(q_hat, P, u, dt, integrator, Qp, work=None):
    """Pose-filter prediction, in place: ``q_hat <- step(q_hat, u)``, ``P <- F P F^T + Qp``.

    ``work``: optional scratch of :func:`pose_work` (none allocated then)."""
    if work is None:
        work = np.zeros((POSE_WORK, 3, 3))
    F = work[_W_F]
    G = work[_W_G].reshape(9)[0:6].reshape((3, 2))
    FP = work[_W_FP]
    step_jacobians_into(q_hat, u, dt, integrator, F, G)
    step_into(q_hat, u, dt, integrator, q_hat)
    # written out: a 3 x 3 product needs no BLAS call, whose rounding would depend on the
    # machine's BLAS kernel; the upper triangle is mirrored, so P stays exactly symmetric
    for i in range(3):
        for j in range(3):
            FP[i, j] = F[i, 0] * P[0, j] + F[i, 1] * P[1, j] + F[i, 2] * P[2, j]
    for i in range(3):
        for j in range(i, 3):
            v = FP[i, 0] * F[j, 0] + FP[i, 1] * F[j, 1] + FP[i, 2] * F[j, 2] + Qp[i, j]
            P[i, j] = v
            P[j, i] = v


@njit
def pose_update(q_hat, P, z, Rp, work=None):
    """Pose-filter update with the measured pose ``z`` (``H = I_3``), in place; returns the NIS.

    The heading innovation is wrapped to (-pi, pi]; the estimate's heading stays continuous.
    ``work``: optional scratch of :func:`pose_work` (none allocated then).
    """
    if work is None:
        work = np.zeros((POSE_WORK, 3, 3))
    nu = work[_W_NU, 0]
    for i in range(3):
        nu[i] = z[i] - q_hat[i]
    nu[2] = wrap_angle(nu[2])
    return joseph_identity3(q_hat, P, nu, Rp, work[_W_JOSEPH : _W_JOSEPH + 3],
                            work[_W_SMALL : _W_SMALL + 3])  # fmt: skip


@njit
def joseph_identity3(x, P, innovation, R, work, small):
    """:func:`joseph_update` with ``H = I_3`` and ``n = m = 3`` (the pose filter), written out.

    Every operation of the general update, in its order, on the same values -- the products with
    the identity's ones and zeros included (IEEE arithmetic may not drop them: ``-0``, ``inf``) --
    so the result is the general update's bit for bit (test_ekf); what is left out is the
    general update's loops sized at run time, whose set-up cost a 3 x 3 update several times its
    arithmetic.  ``work`` (3, 3, 3) and ``small`` (3, 3, 3) are scratch as there.
    """
    HP, Kt, Dt = work[0], work[1], work[2]
    S, L, y = small[0], small[1], small[2, 0]
    for a in range(3):  # H P: row a of P added once, with the factor 1, to a zero row
        for b in range(3):
            HP[a, b] = 0.0 + 1.0 * P[a, b]
    for r in range(3):  # S = (H P) H^T + R, each entry summed over b in order
        for s in range(3):
            acc = 0.0
            for b in range(3):
                acc += HP[r, b] * (1.0 if s == b else 0.0)
            S[r, s] = acc + R[r, s]
    _symmetrise(S)
    if not cholesky(S, L):
        return np.nan
    for r in range(3):  # K^T = S^{-1} H P: forward, then back substitution (cholesky_solve_rows)
        for b in range(3):
            Kt[r, b] = HP[r, b]
        for s in range(r):
            for b in range(3):
                Kt[r, b] -= L[r, s] * Kt[s, b]
        inv = 1.0 / L[r, r]
        for b in range(3):
            Kt[r, b] *= inv
    for r in range(2, -1, -1):
        for s in range(r + 1, 3):
            for b in range(3):
                Kt[r, b] -= L[s, r] * Kt[s, b]
        inv = 1.0 / L[r, r]
        for b in range(3):
            Kt[r, b] *= inv
    for r in range(3):  # D^T = (S K^T) / 2 - H P (_d_matrix)
        for b in range(3):
            Dt[r, b] = (-HP[r, b] + 0.5 * S[r, 0] * Kt[0, b] + 0.5 * S[r, 1] * Kt[1, b]
                        + 0.5 * S[r, 2] * Kt[2, b])  # fmt: skip
    nis = _normalised_square(L, innovation, y)
    for b in range(3):  # x += K innovation (_add_gain_times)
        x[b] = x[b] + Kt[0, b] * innovation[0] + Kt[1, b] * innovation[1] + Kt[2, b] * innovation[2]
    for a in range(3):  # P += D K^T + K D^T (_symmetric_rank_update)
        for b in range(3):
            P[a, b] = (P[a, b] + (Dt[0, a] * Kt[0, b] + Kt[0, a] * Dt[0, b])
                       + (Dt[1, a] * Kt[1, b] + Kt[1, a] * Dt[1, b])
                       + (Dt[2, a] * Kt[2, b] + Kt[2, a] * Dt[2, b]))  # fmt: skip
    return nis


@njit
def nees(q_true, q_hat, P):
    """Normalised estimation error squared ``e^T P^-1 e`` (heading error wrapped)."""
    e = q_true - q_hat
    e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(P, e))
