"""Checks of the helpers of ``analysis/jacobians.py`` (the study itself checks its claims in main).

Small and fast: the relative error on hand cases, the batched CasADi evaluation against single
calls, the point comparisons at ~50 points with the study's own thresholds, the printed network
Jacobian failing at every size, and the learned-vs-true bookkeeping against a run whose logged
Jacobian is the true one (``adaptive-pid`` logs the exact ZOH Jacobian in the same slots).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from analysis import jacobians as jac
from wmr import kinematics as kin
from wmr import scenario as scn
from wmr import symbolic as sym
from wmr.sim import simulate

SMALL = 50  # random points per check in these tests
# Identical formulas evaluated twice differ by nothing; rounding-level agreement is a few ulp.
ROUNDING = 1e-14


@pytest.fixture(scope="module")
def small_study():
    return jac.point_study(points=SMALL, seed=1)


@pytest.fixture(scope="module")
def lemniscate_short():
    sc = scn.load(scn.builtin("lemniscate"))
    return dataclasses.replace(sc, duration=4.0)


# ---------------------------------------------------------------------------------------------
# rel_error
# ---------------------------------------------------------------------------------------------


def test_rel_error_hand_cases():
    B = np.array([[3.0, 0.0], [0.0, 4.0]])  # ||B||_F = 5
    assert jac.rel_error(B, B) == 0.0
    assert jac.rel_error(B + [[0.0, 5.0], [0.0, 0.0]], B) == pytest.approx(1.0, rel=1e-15)
    assert jac.rel_error(np.zeros((2, 2)), B) == pytest.approx(1.0, rel=1e-15)  # J = 0 scores 1
    assert jac.rel_error(2 * B, B) == pytest.approx(1.0, rel=1e-15)
    assert jac.rel_error(np.zeros((3, 2)), np.zeros((3, 2))) == 0.0  # both zero: no 0/0
    assert jac.rel_error(np.ones((1, 1)), np.zeros((1, 1))) > 1e300  # B = 0, A != 0: huge
    assert jac.rel_error([3.0, 4.0], [0.0, 0.0]) > 1e300  # 1-D: one row


def test_rel_error_is_batched_over_leading_axes():
    rng = np.random.default_rng(0)
    A, B = rng.standard_normal((7, 3, 2)), rng.standard_normal((7, 3, 2))
    r = jac.rel_error(A, B)
    assert r.shape == (7,)
    for i in range(7):
        assert r[i] == pytest.approx(np.linalg.norm(A[i] - B[i]) / np.linalg.norm(B[i]), rel=1e-14)


def test_rel_error_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="shapes differ"):
        jac.rel_error(np.zeros((3, 2)), np.zeros((2, 3)))


# ---------------------------------------------------------------------------------------------
# Batched CasADi evaluation and the sampled points
# ---------------------------------------------------------------------------------------------


def test_ad_batch_equals_single_calls():
    rng = np.random.default_rng(1)
    pts = jac.unicycle_points(rng, 5, edges=False)
    F, G = jac._ad_batch(sym.step_jacobian_function("rk4"), pts.q, pts.u, pts.dt)
    assert F.shape == (5, 3, 3) and G.shape == (5, 3, 2)
    f = sym.step_jacobian_function("rk4")
    for i in range(5):
        Fi, Gi = f(pts.q[i], pts.u[i], pts.dt[i])
        assert_array_equal(F[i], Fi.full())
        assert_array_equal(G[i], Gi.full())
    net = jac.network_points(rng, 4, 5, 3, edges=False)
    (H,) = jac._ad_batch(sym.network_weight_jacobian_function(4, 5, 3), net.theta, net.x)
    h = sym.network_weight_jacobian_function(4, 5, 3)
    for i in range(3):
        assert_array_equal(H[i], h(net.theta[i], net.x[i]).full())


def test_points_are_seeded_and_include_the_edges():
    a = jac.unicycle_points(np.random.default_rng(3), 10)
    b = jac.unicycle_points(np.random.default_rng(3), 10)
    assert_array_equal(a.q, b.q)
    assert_array_equal(a.u, b.u)
    assert len(a) > 10
    assert np.any(a.u[:, 0] == 0.0) and np.any(a.u[:, 1] == 0.0)
    assert np.any(a.q[:, 2] == np.pi) and np.any(a.q[:, 2] == -np.pi)
    assert set(np.unique(a.dt)) == set(jac.DTS)


# ---------------------------------------------------------------------------------------------
# The point comparisons at a few points, with the study's own thresholds
# ---------------------------------------------------------------------------------------------


def test_closed_forms_match_ad(small_study):
    summary, _ = small_study
    for name, e in summary["unicycle_step"].items():
        assert e["max_rel_error"] < jac.CLOSED_FORM_TOL, name
    assert summary["network_input"]["corrected_max_rel_error"] < jac.CLOSED_FORM_TOL
    assert summary["network_weights"]["max_rel_error"] < jac.CLOSED_FORM_TOL


def test_printed_network_jacobian_fails(small_study):
    summary, _ = small_study
    ni = summary["network_input"]
    assert ni["printed_median_rel_error"] > jac.PRINTED_MIN_ERROR
    assert ni["printed_max_rel_error"] > jac.PRINTED_MIN_ERROR
    for size, d in ni["by_size"].items():
        assert d["printed_median_rel_error"] > jac.PRINTED_MIN_ERROR, size


def test_rotation_and_error_dynamics(small_study):
    rot = small_study[0]["rotation"]
    assert rot["printed_det"] == "(sq(cos(theta))-sq(sin(theta)))"
    assert rot["corrected_det"] == "1"
    assert rot["max_abs_det_minus_cos_2theta"] < jac.DET_TOL
    assert rot["error_dynamics_max_residual"]["corrected"] < jac.IDENTITY_TOL
    assert rot["error_dynamics_median_residual"]["printed"] > jac.PRINTED_MIN_RESIDUAL


def test_check_claims_passes_and_fails_loudly(small_study):
    summary = small_study[0]
    jac.check_claims(summary)
    broken = {
        **summary,
        "network_input": {**summary["network_input"], "printed_median_rel_error": 0.01},
    }
    with pytest.raises(AssertionError, match="printed eqs. 22-24"):
        jac.check_claims(broken)
    broken = {**summary, "unicycle_step": {"rk4": {"max_rel_error": 1e-6}}}
    with pytest.raises(AssertionError, match="step rk4"):
        jac.check_claims(broken)


def test_printed_network_jacobian_is_zero_only_where_the_network_is_constant():
    """All-zero weights: both Jacobians are exactly zero, so the printed form 'agrees' there."""
    pts = jac.network_points(np.random.default_rng(2), 4, 5, 0)
    errs = jac.network_errors(pts)
    zero = np.all(pts.theta == 0.0, axis=1)
    assert zero.sum() == 1
    assert errs["input_printed"][zero] == 0.0
    assert np.all(errs["input_printed"][~zero] > jac.PRINTED_MIN_ERROR)


def test_hidden_units_from_weight_count():
    assert jac._hidden_units(83) == 10  # 10 (4 + 1 + 3) + 3
    with pytest.raises(ValueError, match="do not fit"):
        jac._hidden_units(84)


def test_rolling_mean_has_no_zero_padding_and_skips_nan():
    x = np.full(20, 0.7)
    x[5] = np.nan
    assert_allclose(jac._rolling_mean(x, 7), 0.7, rtol=0, atol=ROUNDING)


# ---------------------------------------------------------------------------------------------
# Along runs and the learned-vs-true bookkeeping
# ---------------------------------------------------------------------------------------------


def test_learned_vs_true_is_exact_for_the_adaptive_pid(lemniscate_short):
    """``adaptive-pid`` logs the exact ZOH Jacobian at (q_hat_{k-1}, u_{k-1}) in the same slots:
    fed to :func:`learned_vs_true` it must score zero error and perfect agreement, which checks
    the time indices (J_{k-1} against the true Jacobian of the same step)."""
    sc = lemniscate_short
    r = simulate(sc, "adaptive-pid", seed=0)
    d = jac.learned_vs_true(r, sc, sc.settings("adaptive-pid"))
    assert len(d["t"]) == sc.n_steps - 1
    assert np.max(d["rel_error"]) < ROUNDING
    assert_allclose(d["norm_ratio"], 1.0, rtol=0, atol=ROUNDING)
    assert np.nanmin(d["cosine"]) > 1 - ROUNDING
    assert np.nanmin(d["sign_v"]) == 1.0 and np.nanmin(d["sign_w"]) == 1.0
    # off by one step, the same logs no longer match
    shifted = dataclasses.replace(r, q_hat=np.roll(r.q_hat, 1, axis=0))
    assert (
        np.median(jac.learned_vs_true(shifted, sc, sc.settings("adaptive-pid"))["rel_error"]) > 1e-3
    )


def test_along_run_and_learned_summary(lemniscate_short):
    sc = lemniscate_short
    r = simulate(sc, jac.CONTROLLER, seed=0)
    a = jac.along_run(r, max_points=100)
    assert a["steps"] == 100
    for e in a["unicycle_step"].values():
        assert e["max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["network_input"]["corrected_max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["network_weights"]["max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["error_dynamics_max_residual"]["corrected"] < jac.IDENTITY_TOL
    s = jac.summarise_learned([jac.learned_vs_true(r, sc)])
    assert s["seeds"] == 1
    assert set(jac.LEARNED_KEYS) <= set(s)
    assert np.isfinite(s["rel_error"]["mean"]) and np.isfinite(s["rel_error_whole_run"]["mean"])
    assert -1.0 <= s["cosine"]["mean"] <= 1.0
    assert 0.0 <= s["sign_w"]["mean"] <= 1.0


def test_without_noise_zeroes_only_the_noise():
    sc = scn.load(scn.builtin("sinusoid"))
    q = jac.without_noise(sc)
    assert q.noise.pose_std == (0.0, 0.0, 0.0)
    assert q.reference == sc.reference and q.dt == sc.dt


def test_true_jacobian_uses_the_scenario_integrator(lemniscate_short):
    """With an Euler plant, the adaptive-pid's logged Euler Jacobian is still matched exactly."""
    sc = dataclasses.replace(lemniscate_short, integrator="euler")
    r = simulate(sc, "adaptive-pid", seed=0)
    d = jac.learned_vs_true(r, sc, sc.settings("adaptive-pid"))
    assert np.max(d["rel_error"]) < ROUNDING
    assert kin.integrator_code(sc.integrator) == kin.EULER
