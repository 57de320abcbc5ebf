"""EKF: the O(n^2 m) Joseph update vs the literal form, bit-exact fused kernels, linear-KF
equivalence, pose-filter NEES/NIS."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from wmr.estimation import ekf
from wmr.model import kinematics as kin

REL_TOL = 1e-12  # the expanded Joseph form sums in another order: a few ulps of ||P||


def _spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + np.eye(n))


@pytest.mark.parametrize("n", [1, 5, 63, 83, 123], ids=lambda n: f"n={n}")
def test_fast_weight_update_equals_the_literal_joseph_form(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        P = _spd(rng, n, 10.0)
        H = rng.normal(size=(3, n))
        theta = rng.normal(size=n)
        nu = rng.normal(size=3)
        q = rng.uniform(0, 1e-3, size=n)
        R = _spd(rng, 3)
        theta_ref, P_ref = ekf.weight_update_reference(theta, P, H, nu, q, R)
        ekf.weight_update(theta, P, H, nu, q, R, np.empty((3, 3, n)))
        np.testing.assert_allclose(theta, theta_ref, rtol=REL_TOL,
                                   atol=REL_TOL * np.abs(theta_ref).max())
        np.testing.assert_allclose(P, P_ref, atol=REL_TOL * np.abs(P_ref).max())
        np.testing.assert_array_equal(P, P.T)


def _network_like_H(rng, m, n):
    """A measurement matrix with the block structure of the network's ``H``: dense columns,
    then columns with a single non-zero row (output weights and biases)."""
    H = rng.normal(size=(m, n))
    for a in range(n // 2, n):
        keep = a % m
        H[np.arange(m) != keep, a] = 0.0
    return H


@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("n", [1, 2, 7, 82, 83])
def test_h_times_p_is_bit_identical_to_the_sequential_axpys(m, n):
    """Oracle: the same sums in the same order in numpy (``H[r, a] P[a]`` added for a = 0..n-1,
    zero ``H[r, a]`` skipped); the fused two-row m = 3 path must not change a single bit."""
    rng = np.random.default_rng(10 * n + m)
    P = _spd(rng, n)
    H = _network_like_H(rng, m, n)
    expected = np.zeros((m, n))
    for a in range(n):
        for r in range(m):
            if H[r, a] != 0.0:
                expected[r] = expected[r] + H[r, a] * P[a]
    out = np.full((m, n), np.nan)
    ekf._h_times_p(H, P, out)
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("n", [1, 2, 7, 82, 83])
def test_symmetric_rank_update_is_bit_identical_and_exactly_symmetric(m, n):
    """Oracle: ``P + t_0 + t_1 + ...`` with ``t_r = outer(D_r, K_r) + outer(K_r, D_r)`` in numpy
    (elementwise products and sums round like the kernel's, no FMA)."""
    rng = np.random.default_rng(10 * n + m)
    P = _spd(rng, n)
    Kt, Dt = rng.normal(size=(m, n)), rng.normal(size=(m, n))
    expected = P.copy()
    for r in range(m):
        expected = expected + (np.outer(Dt[r], Kt[r]) + np.outer(Kt[r], Dt[r]))
    ekf._symmetric_rank_update(P, Kt, Dt)
    np.testing.assert_array_equal(P, expected)
    np.testing.assert_array_equal(P, P.T)


@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("n", [1, 2, 7, 83])
def test_s_d_and_state_correction_are_bit_identical_to_their_sequential_sums(m, n):
    """Oracles in numpy, summed in the documented order (each entry a left-to-right sum, no
    FMA): ``S = (H P) H^T + R`` over ``b = 0 .. n-1``, ``D^T = -H P + sum_s (S_rs / 2) K_s`` and
    ``x + sum_r K_r nu_r``; the fused m = 3 passes must not change a single bit."""
    rng = np.random.default_rng(100 * n + m)
    HP, H, Kt = rng.normal(size=(m, n)), rng.normal(size=(m, n)), rng.normal(size=(m, n))
    R = _spd(rng, m)
    S_expected = np.empty((m, m))
    for r in range(m):
        for s in range(m):
            acc = 0.0
            for b in range(n):
                acc = acc + HP[r, b] * H[s, b]
            S_expected[r, s] = acc + R[r, s]
    S = np.full((m, m), np.nan)
    ekf.innovation_covariance(HP, H, R, S)
    np.testing.assert_array_equal(S, S_expected)
    D_expected = -HP
    for s in range(m):
        D_expected = D_expected + (0.5 * S[:, s])[:, None] * Kt[s][None, :]
    Dt = np.full((m, n), np.nan)
    ekf._d_matrix(S, Kt, HP, Dt)
    np.testing.assert_array_equal(Dt, D_expected)
    x, nu = rng.normal(size=n), rng.normal(size=m)
    x_expected = x.copy()
    for r in range(m):
        x_expected = x_expected + Kt[r] * nu[r]
    ekf._add_gain_times(x, Kt, nu)
    np.testing.assert_array_equal(x, x_expected)


def _pose_cases():
    """Pose-filter updates: random SPD covariances and innovations over several scales, then
    the edges where IEEE arithmetic keeps what an identity would drop (a -0 entry, inf, NaN)
    and a covariance that is not positive definite."""
    rng = np.random.default_rng(3)
    for scale in (1e-8, 1e-4, 1.0, 1e4):
        for _ in range(50):
            yield _spd(rng, 3, scale), rng.normal(size=3) * scale**0.5, _spd(rng, 3, scale)
    P = _spd(rng, 3)
    for i, j, v in ((0, 1, -0.0), (2, 2, np.inf), (1, 0, np.nan), (0, 0, -1.0)):
        Q = P.copy()
        Q[i, j] = v
        yield Q, rng.normal(size=3), _spd(rng, 3)


def test_pose_update_written_out_is_the_general_update_bit_for_bit():
    """Oracle: ``joseph_update`` with ``H = I_3`` (the general O(n^2 m) update)."""
    for P, nu, R in _pose_cases():
        x1, P1 = np.arange(3.0), P.copy()
        x2, P2 = np.arange(3.0), P.copy()
        nis1 = ekf.joseph_update(x1, P1, np.eye(3), nu, R, np.empty((3, 3, 3)))
        nis2 = ekf.joseph_identity3(x2, P2, nu, R, np.empty((3, 3, 3)), np.empty((3, 3, 3)))
        np.testing.assert_array_equal(np.array([nis2]), np.array([nis1]))
        np.testing.assert_array_equal(x2, x1)
        np.testing.assert_array_equal(P2, P1)
        assert np.array_equal(np.signbit(P2), np.signbit(P1))


@pytest.mark.parametrize("integrator", [kin.EXACT, kin.EULER, kin.RK4])
def test_pose_predict_is_the_congruence_and_stays_exactly_symmetric(integrator):
    rng = np.random.default_rng(integrator)
    for _ in range(20):
        q = rng.normal(size=3)
        u = np.array([rng.uniform(-1, 1), rng.uniform(-2, 2)])
        P = _spd(rng, 3, 1e-3)
        Qp = np.diag(rng.uniform(1e-6, 1e-4, size=3))
        F, _ = kin.step_jacobians(q, u, 0.05, integrator)
        expected = F @ P @ F.T + Qp
        q_hat = q.copy()
        ekf.pose_predict(q_hat, P, u, 0.05, integrator, Qp)
        np.testing.assert_allclose(P, expected, rtol=1e-14, atol=1e-18)
        np.testing.assert_array_equal(P, P.T)
        np.testing.assert_array_equal(q_hat, kin.step(q, u, 0.05, integrator))


def test_weight_filter_equals_a_linear_kalman_filter():
    """With an output linear in the weights (z = H_k theta) the EKF is the linear KF."""
    rng = np.random.default_rng(0)
    n, m, steps = 12, 3, 200
    theta_true = rng.normal(size=n)
    Q = np.full(n, 1e-4)
    R = 0.1 * np.eye(m)
    x_ekf = np.zeros(n)
    P_ekf = 100.0 * np.eye(n)
    x_kf, P_kf = x_ekf.copy(), P_ekf.copy()
    work = np.empty((3, m, n))
    for _ in range(steps):
        H = rng.normal(size=(m, n))
        z = H @ theta_true + rng.normal(size=m) * 0.3
        ekf.weight_update(x_ekf, P_ekf, H, z - H @ x_ekf, Q, R, work)
        # textbook linear KF, random-walk model
        P_pred = P_kf + np.diag(Q)
        K = P_pred @ H.T @ np.linalg.inv(H @ P_pred @ H.T + R)
        x_kf = x_kf + K @ (z - H @ x_kf)
        P_kf = (np.eye(n) - K @ H) @ P_pred
    np.testing.assert_allclose(x_ekf, x_kf, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P_ekf, P_kf, rtol=1e-8, atol=1e-12)


def test_paper_tuning_keeps_P_symmetric_positive_definite():
    """P0 = 1000 I, Q = 1e-5 I, R = 1000 I3 (eq. 63) over many updates with network-like H."""
    rng = np.random.default_rng(5)
    n = 83
    P = 1000.0 * np.eye(n)
    theta = np.zeros(n)
    R = 1000.0 * np.eye(3)
    work = np.empty((3, 3, n))
    for _ in range(2000):
        H = rng.normal(size=(3, n)) * rng.uniform(0.01, 1.0)
        ekf.weight_update(theta, P, H, rng.normal(size=3), np.full(n, 1e-5), R, work)
    np.testing.assert_array_equal(P, P.T)
    assert ekf.is_positive_definite(P)
    assert np.linalg.eigvalsh(P).min() > 0


def test_not_positive_definite_innovation_covariance_leaves_the_state_untouched():
    P = np.eye(2)
    x = np.ones(2)
    nis = ekf.joseph_update(x, P, np.zeros((1, 2)), np.ones(1), -np.eye(1), np.empty((3, 1, 2)))
    assert np.isnan(nis)
    np.testing.assert_array_equal(x, 1.0)


def test_repair_covariance_counts_and_fixes_a_bad_diagonal():
    P = np.array([[1.0, 0.2], [0.1, -1e-3]])
    assert ekf.repair_covariance(P, 1e-9)
    assert P[1, 1] == 1e-9 and P[0, 1] == P[1, 0]
    assert not ekf.repair_covariance(np.eye(2), 1e-9)


def test_pose_update_wraps_the_heading_innovation():
    q = np.array([0.0, 0.0, np.pi - 0.01])
    P = np.eye(3) * 0.01
    ekf.pose_update(q, P, np.array([0.0, 0.0, -np.pi + 0.01]), np.eye(3) * 0.01)
    assert q[2] > np.pi - 0.01  # moved the short way, across the seam, not back through 0


def test_pose_ekf_is_consistent_nees_and_nis_within_chi2_bounds():
    """Monte-Carlo over seeded runs with the filter's own noise model: the run-averaged NEES and
    NIS lie in the two-sided 95 % chi-square band (3 dof, averaged over runs)."""
    runs, steps, dt = 30, 200, 0.05
    Qp = np.diag([1e-4, 1e-4, 4e-4])
    Rp = np.diag([0.02, 0.02, 0.01]) ** 2
    nees_avg = np.zeros(steps)
    nis_avg = np.zeros(steps)
    for r in range(runs):
        rng = np.random.default_rng(1000 + r)
        q = np.array([0.0, 0.0, 0.3])
        P = Rp.copy()
        q_hat = q + rng.multivariate_normal(np.zeros(3), Rp)
        for k in range(steps):
            u = np.array([0.5 + 0.2 * np.sin(0.1 * k), 0.4 * np.cos(0.05 * k)])
            q = kin.step(q, u, dt, kin.EXACT) + rng.multivariate_normal(np.zeros(3), Qp)
            ekf.pose_predict(q_hat, P, u, dt, kin.EXACT, Qp)
            z = q + rng.multivariate_normal(np.zeros(3), Rp)
            nis_avg[k] += ekf.pose_update(q_hat, P, z, Rp) / runs
            nees_avg[k] += ekf.nees(q, q_hat, P) / runs
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * runs) / runs
    # averaged over time too: the whole-run mean must sit in the band of the run average
    assert lo < nees_avg.mean() < hi
    assert lo < nis_avg.mean() < hi
    assert np.mean((nees_avg > lo) & (nees_avg < hi)) > 0.85  # ~95 % of instants expected
