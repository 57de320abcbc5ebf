"""Tests of wmr.estimation.stability (Assumption 1, Lemma 2, eq. 48, Theorem 1) and of the
boundedness study (analysis/boundedness/); the probes it observes runs with are tested in
test_probes.py."""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis import boundedness as bd
from analysis import common
from wmr import scenario as scn
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate
from wmr.estimation import stability as stab
from wmr.scenario import Disturbance

#: Round-off on closed-form arithmetic of a few operations.
EXACT_RTOL = 1e-14
#: Relative agreement of two O(n^3) computations of the same eigenvalue (n <= 10).
EIG_RTOL = 1e-10
#: Monte-Carlo tolerance on a mean of ~6000 chi^2-like values (std of the mean ~2 %).
MC_RTOL = 0.06


# --- Lemma 2's alpha ------------------------------------------------------------------------


def test_lemma2_alpha_by_hand():
    # a_bar = 1, c_bar = 1, p_max = 2, q_min = 1, r_min = 2:
    #   a_bar + a_bar p_max c_bar^2 / r_min = 1 + 1 * 2 * 1 / 2 = 2,  squared = 4,
    #   x = q_min / (p_max * 4) = 1 / 8,
    #   1 - alpha = 1 / (1 + 1/8) = 8/9,  alpha = 1/9.
    assert_allclose(stab.lemma2_alpha(1.0, 1.0, 2.0, 1.0, 2.0), 1.0 / 9.0, rtol=EXACT_RTOL)


def test_lemma2_alpha_paper_tuning_matches_e10_closed_form():
    # The paper's eq. (63): p_max = 1000, q_min = 1e-5, r_min = 1000; A = I so a_bar = 1.
    # With c_bar = 2: 1 + 1000 * 4 / 1000 = 5, x = 1e-5 / (1000 * 25) = 4e-10,
    # alpha = 4e-10 / (1 + 4e-10), and E10's 1e-8 / (1 + c_bar^2)^2 = 1e-8 / 25 = 4e-10.
    alpha = stab.lemma2_alpha(1.0, 2.0, 1000.0, 1e-5, 1000.0)
    assert_allclose(alpha, 4e-10 / (1 + 4e-10), rtol=EXACT_RTOL)
    for c in (0.5, 1.0, 3.0, 8.0):
        assert_allclose(
            stab.lemma2_alpha(1.0, c, 1000.0, 1e-5, 1000.0),
            1e-8 / (1 + c * c) ** 2,
            rtol=1.1e-8,  # E10's form drops x in 1 + x: relative change x <= 1e-8
        )


@pytest.mark.parametrize("bad", ["a_bar", "c_bar", "p_max", "q_min", "r_min"])
def test_lemma2_alpha_rejects_nonpositive(bad):
    args = dict(a_bar=1.0, c_bar=1.0, p_max=1.0, q_min=1.0, r_min=1.0)
    args[bad] = 0.0
    with pytest.raises(ValueError, match=bad):
        stab.lemma2_alpha(**args)


# --- Assumption 1's constants ---------------------------------------------------------------


def test_assumption1_constants_hand_made_sequence():
    A = [np.eye(2), np.array([[2.0, 0.0], [0.0, 1.0]])]  # norms 1, 2
    H = [np.array([[3.0, 4.0]]), np.array([[0.0, 1.0]])]  # norms 5, 1
    P = [np.diag([1.0, 4.0]), np.array([[2.0, 1.0], [1.0, 2.0]])]  # eigs {1, 4}, {1, 3}
    Q = [np.diag([0.5, 0.25]), np.diag([0.1, 1.0])]  # min eigs 0.25, 0.1
    R = [np.array([[2.0]]), np.array([[3.0]])]
    const = stab.assumption1_constants(A, H, P, Q, R)
    expected = dict(a_bar=2.0, c_bar=5.0, p_min=1.0, p_max=4.0, q_min=0.1, r_min=2.0)
    assert const.keys() == expected.keys()
    for k, v in expected.items():
        assert_allclose(const[k], v, rtol=EXACT_RTOL, err_msg=k)


def test_assumption1_constants_length_mismatch():
    with pytest.raises(ValueError):
        stab.assumption1_constants([np.eye(1)], [], [np.eye(1)], [np.eye(1)], [np.eye(1)])


# --- Inequality (48) ------------------------------------------------------------------------


def _kalman_run(A, H, Q, R, P0, steps):
    """Priors P_{k|k-1}, gains and next priors of a linear Kalman filter (two-step form)."""
    P = P0
    out = []
    for _ in range(steps):
        K = stab.kalman_gain(P, H, R)
        IKH = np.eye(len(P)) - K @ H
        P_post = IKH @ P @ IKH.T + K @ R @ K.T
        P_next = A @ P_post @ A.T + Q
        out.append((P, K, P_next))
        P = P_next
    return out


def test_ineq48_scalar_random_walk_steady_state_by_hand():
    # x+ = x + w, z = x + v, q = r = 1.  Steady prior P = phi = (1 + sqrt 5)/2 (P = P/(P+1) + 1),
    # K = phi / (phi + 1) = 1/phi, and M^T Pi+ M / Pi = (1 - K)^2 = phi^-4: achieved alpha
    # = 1 - phi^-4 ~ 0.854.  Lemma 2: 1 + phi * 1 / 1 = phi^2, x = 1 / (phi * phi^4) = phi^-5,
    # alpha = phi^-5 / (1 + phi^-5) ~ 0.0827 <= 0.854: (48) holds.
    phi = (1 + math.sqrt(5)) / 2
    one = np.eye(1)
    c = stab.kalman_contraction(phi * one, one, one, one)
    assert_allclose(c["alpha"], 1 - phi**-4, rtol=EIG_RTOL)
    assert_allclose(c["P_next"], phi * one, rtol=EIG_RTOL)
    lam = stab.contraction_direct(one - c["K"], phi * one, c["P_next"])
    assert_allclose(lam, phi**-4, rtol=EIG_RTOL)
    alpha = stab.lemma2_alpha(1.0, 1.0, phi, 1.0, 1.0)
    assert_allclose(alpha, phi**-5 / (1 + phi**-5), rtol=EXACT_RTOL)
    assert stab.ineq48_holds(c["alpha"], alpha)
    assert not stab.ineq48_holds(c["alpha"], 0.9)  # more contraction than the filter achieves


def test_ineq48_holds_along_linear_kalman_filter():
    # Constant-velocity model, position measured: (48) with Lemma 2's alpha (constants of the
    # run) must hold at every step of the exact filter, in both computations.
    dt = 0.1
    A = np.array([[1.0, dt], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    Q = np.diag([1e-3, 1e-2])
    R = np.array([[0.5]])
    run = _kalman_run(A, H, Q, R, 10.0 * np.eye(2), 300)
    const = stab.assumption1_constants(
        [A] * len(run), [H] * len(run), [P for P, _, _ in run], [Q] * len(run), [R] * len(run)
    )
    alpha = stab.lemma2_alpha(*(const[k] for k in ("a_bar", "c_bar", "p_max", "q_min", "r_min")))
    assert 0 < alpha < 1
    for P, K, P_next in run:
        c = stab.kalman_contraction(P, H, R, Q, A=A)
        lam = stab.contraction_direct(A @ (np.eye(2) - K @ H), P, P_next)
        assert_allclose(1 - lam, c["alpha"], rtol=1e-8)  # 1 - lam cancels: looser
        assert_allclose(c["P_next"], P_next, rtol=EIG_RTOL)
        assert c["norm_M"] <= const["a_bar"] * (
            1 + const["p_max"] * const["c_bar"] ** 2 / const["r_min"]
        )
        assert stab.ineq48_holds(c["alpha"], alpha)
        assert lam <= 1 - alpha


def test_ineq48_fails_without_riccati_covariance():
    # Unstable scalar system, no correction (K = 0) and a covariance that is *not* propagated
    # (P_{k+1} = P_k = 1): M^T Pi+ M = a^2 = 1.44 > 1 - alpha for every alpha > 0.
    a = 1.2
    lam = stab.contraction_direct(np.array([[a]]), np.eye(1), np.eye(1))
    assert_allclose(lam, a * a, rtol=EXACT_RTOL)
    assert not lam <= 1 - stab.lemma2_alpha(a, 1.0, 1.0, 1.0, 1.0)
    # An overconfident covariance (half the propagated one) breaks (48) for a stable system too.
    P, H, R, Q = np.eye(2), np.array([[1.0, 0.0]]), np.eye(1), 1e-4 * np.eye(2)
    c = stab.kalman_contraction(P, H, R, Q)
    lam = stab.contraction_direct(np.eye(2) - c["K"] @ H, P, 0.5 * c["P_next"])
    assert lam > 1.0


def test_kalman_contraction_unexcited_direction_without_cancellation():
    # The weight filter's situation: H sees one of two directions, P = diag(1, 1000), q = 1e-5.
    # The unseen direction keeps M = 1 and P -> P + q, so the achieved contraction is exactly
    # q / (1000 + q) ~ 1e-8, which 1 - lambda would only give to ~1e-8 relative precision.
    q = 1e-5
    c = stab.kalman_contraction(
        np.diag([1.0, 1000.0]), np.array([[1.0, 0.0]]), np.eye(1), q * np.eye(2)
    )
    assert_allclose(c["alpha"], q / (1000.0 + q), rtol=EIG_RTOL)


def _random_filter(seed, n=6, m=2):
    """A random filter step: prior ``P`` (n, n), ``H`` (m, n), ``R`` (m, m), ``Q`` (n, n), ``A``."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, n))
    P = X @ X.T + 0.1 * np.eye(n)
    H = rng.standard_normal((m, n))
    R = np.diag(rng.uniform(0.5, 2.0, m))
    Q = np.diag(rng.uniform(0.05, 0.2, n))
    return P, H, R, Q, np.eye(n) + 0.1 * rng.standard_normal((n, n))


@pytest.mark.parametrize("seed", range(5))
def test_kalman_contraction_matches_direct_on_random_filters(seed):
    n = 6
    P, H, R, Q, A = _random_filter(seed, n)
    c = stab.kalman_contraction(P, H, R, Q, A=A)
    M = A @ (np.eye(n) - c["K"] @ H)
    assert_allclose(1 - stab.contraction_direct(M, P, c["P_next"]), c["alpha"], rtol=1e-9)
    c_identity = stab.kalman_contraction(P, H, R, Q)  # A = I: the low-rank ||I - K H||
    assert_allclose(
        c_identity["norm_M"], np.linalg.norm(np.eye(n) - c_identity["K"] @ H, 2), rtol=EIG_RTOL
    )


# --- Theorem 1, chi^2 bands, exact-model consistency ----------------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_noise_term_is_the_trace_formula(seed):
    # Oracle: tr(P_next^-1 (Q + K R K^T)) with an explicit inverse, on a random filter step.
    P, H, R, Q, _ = _random_filter(seed, n=7, m=3)
    c = stab.kalman_contraction(P, H, R, Q)
    K, P_next = c["K"], c["P_next"]
    want = np.trace(np.linalg.inv(P_next) @ (Q + K @ R @ K.T))
    assert_allclose(stab.noise_term(P_next, K, np.diag(Q), R), want, rtol=EIG_RTOL)


@pytest.mark.parametrize("seed", range(3))
def test_noise_term_parts_give_the_noise_term_for_any_measurement_noise(seed):
    # Oracle: noise_term (its own Cholesky evaluation) with the filter's R and with another R.
    P, H, R, Q, _ = _random_filter(seed, n=7, m=3)
    c = stab.kalman_contraction(P, H, R, Q)
    tr_q, ktpik = stab.noise_term_parts(c["P_next"], c["K"], np.diag(Q))
    assert ktpik.shape == (3, 3)
    assert_allclose(ktpik, ktpik.T, rtol=EXACT_RTOL, atol=0)
    for R_v in (R, np.diag([0.5, 0.2, 0.1]), np.zeros((3, 3))):
        want = np.trace(np.linalg.inv(c["P_next"]) @ (Q + c["K"] @ R_v @ c["K"].T))
        assert_allclose(stab.noise_term_from_parts(tr_q, ktpik, R_v), want, rtol=EIG_RTOL)
    assert_allclose(stab.noise_term_from_parts(tr_q, ktpik, R),
                    stab.noise_term(c["P_next"], c["K"], np.diag(Q), R), rtol=EIG_RTOL)


def test_theorem1_bound_arithmetic():
    # alpha = 0.5, p in [1, 4], mu = 0.25, ||e0||^2 = 2: transient 4 * 2 * 0.75^k, floor
    # 2 * 4 * 0.25 / 0.5 = 4.
    b = stab.theorem1_bound(0.5, 1.0, 4.0, 0.25, 2.0, np.array([0.0, 1.0, 2.0]))
    assert_allclose(b["bound_sq"], [8 + 4, 6 + 4, 4.5 + 4], rtol=EXACT_RTOL)
    assert b["transient_gain"] == 4.0 and b["noise_floor"] == 4.0 and b["decay_steps"] == 4.0


def test_chi2_band_known_values():
    lo, hi = stab.chi2_band(3, 1)
    assert_allclose((lo, hi), (0.215795, 9.348404), rtol=1e-5)  # chi^2_3 2.5 % / 97.5 % points
    lo, hi = stab.chi2_band(3, 50)
    assert lo < 3 < hi and hi - lo < 1.5


def test_random_walk_consistency_against_simulation():
    # Scalar random-walk filter (q = r = 1e-4) on a constant true state, 60 seeded runs.
    q, r, runs, steps = 1e-4, 1e-4, 60, 200
    rng = np.random.default_rng(7)
    nees, nis = [], []
    for _ in range(runs):
        x_hat, P = 0.0, r
        noise = rng.standard_normal(steps) * math.sqrt(r)
        for k in range(steps):
            P_prior = P + q
            S = P_prior + r
            nu = noise[k] - x_hat
            K = P_prior / S
            x_hat += K * nu
            P = (1 - K) * P_prior
            if k >= 100:  # steady state
                nees.append(x_hat**2 / P)
                nis.append(nu**2 / S)
    e_nees, e_nis = stab.random_walk_consistency(q, r)
    assert_allclose(e_nees, 1 / (2 - (math.sqrt(5) - 1) / 2), rtol=EXACT_RTOL)  # K = 1/phi
    assert_allclose(np.mean(nees), e_nees, rtol=MC_RTOL)
    assert_allclose(np.mean(nis), e_nis, rtol=MC_RTOL)


def test_random_walk_increment_noise_against_simulation():
    # Oracle: the scalar filter of the previous test, its error differenced; q = r = 1e-4 gives
    # K = 1/phi, Var d / r = K^2 (K/(2-K) + 1) and corr_1 = -1/(2 phi) (by hand: -0.309).
    q, r, runs, steps = 1e-4, 1e-4, 60, 300
    rng = np.random.default_rng(11)
    d = []
    for _ in range(runs):
        x_hat, P, e = 0.0, r, []
        for z in rng.standard_normal(steps) * math.sqrt(r):
            K = (P + q) / (P + q + r)
            x_hat += K * (z - x_hat)
            P = (1 - K) * (P + q)
            e.append(x_hat)  # the true state is 0: x_hat is the error
        d.append(np.diff(e[100:]))  # steady state
    d = np.array(d)
    var, corr = stab.random_walk_increment_noise(q, r)
    K = (math.sqrt(5) - 1) / 2
    assert_allclose(var, K * K * (K / (2 - K) + 1), rtol=EXACT_RTOL)
    assert_allclose(corr, -K / 2, rtol=1e-12)  # (1-K) K/(2-K) - K = -K (s2 + 1)/2 with K^2=1-K
    assert_allclose(np.mean(d**2) / r, var, rtol=MC_RTOL)
    lag1 = np.mean(d[:, 1:] * d[:, :-1]) / np.mean(d**2)
    assert lag1 == pytest.approx(corr, abs=0.03)  # ~12000 products: std ~0.01


# --- The study ------------------------------------------------------------------------------

COMMITTED = Path(__file__).resolve().parents[1] / "paper"


def _short(name, duration=2.0, **changes):
    sc = scn.load(scn.builtin(name))
    return dataclasses.replace(sc, duration=duration, **changes)


def test_analyse_weight_filter_short_run():
    sc = _short(
        "sinusoid-perturbed", duration=1.0, disturbances=(Disturbance(0.3, 0.6, (0.1, 0.3)),)
    )
    rec, series = bd.analyse_weight_filter(sc, seed=1)
    assert rec["replay_equals_simulate"] and rec["long_run_prefix_identical"]
    assert rec["filter_updates"] == sc.n_steps - 1
    assert rec["P_spd_every_step"] and rec["covariance_repairs"] == 0
    assert rec["a_bar"] == 1.0 and rec["q_min"] == 1e-5 and rec["r_min"] == 1000.0
    assert rec["ineq48_fraction"] == 1.0 and rec["alpha_actual_min"] >= rec["alpha"]
    assert_allclose(
        rec["alpha"], stab.lemma2_alpha(1.0, rec["c_bar"], rec["p_max"], 1e-5, 1000.0), rtol=0
    )
    assert rec["innovation_recomputed_max_rel_diff"] < bd.INNOVATION_RTOL
    assert rec["direct_vs_cancellation_free_max_abs"] < bd.DIRECT_ATOL
    assert series["alpha_k"].shape == (sc.n_steps,) and np.isnan(series["alpha_k"][0])
    # the measured target noise: the targets minus the true increments, over the filter updates
    res = simulate(sc, "iapid-nn-dekf", 1)
    v = (np.diff(res.q_hat, axis=0) - np.diff(res.q[: sc.n_steps], axis=0)) / sc.dt
    assert rec["target_noise_steps"] == sc.n_steps - 1
    assert_allclose(rec["target_noise_cov"], v.T @ v / len(v), rtol=1e-9)  # no heading seam here
    assert_allclose(rec["target_noise_std"], v.std(axis=0), rtol=1e-9)
    assert rec["weight_error_theorem1_mu_parts_max_rel_diff"] < bd.NOISE_PARTS_RTOL
    # the real noise is ~1e3 times smaller than R = 1000 I: a smaller noise term and bound
    assert rec["filter_r_over_target_noise"] > 100
    assert rec["weight_error_theorem1_mu_q_part"] <= rec["weight_error_theorem1_mu_measured_noise"]
    assert rec["weight_error_theorem1_mu_measured_noise"] < rec["weight_error_theorem1_mu"]
    assert (rec["weight_error_theorem1_bound_final_measured_noise"]
            < rec["weight_error_theorem1_bound_final"])  # fmt: skip
    assert series["bound_measured"].shape == (sc.n_steps,)
    # the proxy theta* is the end of a run twice as long: the error starts at ||theta_0 - theta*||
    theta_star = simulate(dataclasses.replace(sc, duration=2.0), "iapid-nn-dekf", 1).final.theta
    theta_0 = loop.prepare(sc, "iapid-nn-dekf", 1).theta
    assert_allclose(rec["weight_error_initial"], np.linalg.norm(theta_0 - theta_star),
                    rtol=EXACT_RTOL)  # fmt: skip


def test_pose_consistency_windows_and_bands():
    sc = _short(
        "sinusoid-perturbed", duration=1.0, disturbances=(Disturbance(0.4, 0.7, (0.1, 0.3)),)
    )
    names = [w[0] for w in bd.windows(sc)]
    assert names == ["all", "0-0.4 s", "0.4-0.7 s (disturbance)", "0.7-1 s"]
    runs = [bd.pose_run(sc, seed) for seed in range(4)]
    rec, series = bd.pose_consistency(sc, runs)
    assert rec["nees_bounds"] == list(stab.chi2_band(3, 4))
    assert rec["consistency_spd_failures"] == 0 and rec["consistency_diverged_runs"] == 0
    assert np.isnan(series["nis"][0]) and np.all(np.isfinite(series["nees"]))
    for w in rec["consistency_windows"].values():
        assert_allclose(w["nees_in_band"] + w["nees_below_band"] + w["nees_above_band"], 1.0)


@pytest.fixture(scope="module")
def committed():
    record = common.load_record(COMMITTED, bd.STEM)
    if record is None:
        pytest.skip("no committed paper/results/boundedness.json")
    return record


def test_check_holds_on_the_committed_record(committed):
    bd.check(committed)


@pytest.mark.parametrize(
    "key, value",
    [("ineq48_fraction", 0.999), ("replay_equals_simulate", False), ("alpha", 1e-3),
     ("covariance_repairs", 1), ("nees_mean", 3.0), ("target_noise_std", [1.3, 0.74, 0.74]),
     ("weight_error_theorem1_mu_parts_max_rel_diff", 1e-6)],
)  # fmt: skip
def test_check_rejects_a_broken_claim(committed, key, value):
    record = copy.deepcopy(committed)
    record["sinusoid"][key] = value
    with pytest.raises(AssertionError, match="sinusoid"):
        bd.check(record)


def test_the_check_names_ineq48_a_consistency_check(committed):
    record = copy.deepcopy(committed)
    record["sinusoid"]["ineq48_fraction"] = 0.999
    with pytest.raises(AssertionError, match="sinusoid: consistency check failed: \\(48\\)"):
        bd.check(record)


def test_render_calls_ineq48_a_consistency_check_and_gives_both_bounds(committed):
    text = bd.render(committed)
    assert "(48) fraction with Lemma 2 alpha (consistency check)" in text
    if "target_noise_cov" in committed["sinusoid"]:  # a record with the measured noise
        assert "is a *consistency check*, not evidence" in text
        assert "Theorem 1 bound, end (measured target noise)" in text
        for rec in committed.values():
            assert any("Consistency check, not evidence" in n for n in rec["notes"])


def test_render_is_the_committed_report_section(committed):
    report = (COMMITTED / "report.md").read_text()
    table = (COMMITTED / "tables" / "boundedness.md").read_text()
    assert bd.table(committed) == table
    section = bd.render(committed)
    assert section.startswith(f"## {bd.TITLE}\n\n")
    assert section in report
    for name in committed:
        assert f"![boundedness_{name}.png](figures/boundedness_{name}.png)" in section


@pytest.mark.slow
def test_quick_run_writes_and_checks(tmp_path):
    record = bd.run(tmp_path, quick=True, workers=2)
    bd.check(record)
    assert common.load_record(tmp_path, bd.STEM) == record
    bd.check(common.load_record(tmp_path, bd.STEM))
    assert (tmp_path / "tables" / "boundedness.md").read_text() == bd.table(record)
    for name in bd.figure_names(record):
        assert (tmp_path / "figures" / name).stat().st_size > 0
    first = next(iter(record.values()))
    assert first["instrumented_every"] == bd.QUICK_EVERY
    assert first["consistency_runs"] == bd.QUICK_SEEDS
