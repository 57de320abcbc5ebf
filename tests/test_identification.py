"""Tests of ``wmr/estimation/identification.py``: the quality metrics of the Jacobian a run used.

Oracles: hand cases of the relative error; ``adaptive-pid``, which logs the exact ZOH Jacobian
of the nominal plant, scores zero error and full agreement against the default true Jacobian
(this checks the time indices); true Jacobians that differ from the logged one in a known way
(a scale, a flipped column, a flipped sign) give the metrics in closed form.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.estimation.identification import (
    QUALITY_KEYS,
    JacobianQuality,
    jacobian_quality,
    nominal_jacobian,
    rel_error,
)
from wmr.model import kinematics as kin

# Identical formulas evaluated twice differ by nothing; rounding-level agreement is a few ulp.
ROUNDING = 1e-14


@pytest.fixture(scope="module")
def lemniscate_short():
    sc = scn.load(scn.builtin("lemniscate"))
    return dataclasses.replace(sc, duration=4.0)


@pytest.fixture(scope="module")
def apid_run(lemniscate_short):
    return simulate(lemniscate_short, "adaptive-pid", seed=0)


# ---------------------------------------------------------------------------------------------
# rel_error
# ---------------------------------------------------------------------------------------------


def test_rel_error_hand_cases():
    B = np.array([[3.0, 0.0], [0.0, 4.0]])  # ||B||_F = 5
    assert rel_error(B, B) == 0.0
    assert rel_error(B + [[0.0, 5.0], [0.0, 0.0]], B) == pytest.approx(1.0, rel=1e-15)
    assert rel_error(np.zeros((2, 2)), B) == pytest.approx(1.0, rel=1e-15)  # J = 0 scores 1
    assert rel_error(2 * B, B) == pytest.approx(1.0, rel=1e-15)
    assert rel_error(np.zeros((3, 2)), np.zeros((3, 2))) == 0.0  # both zero: no 0/0
    assert rel_error(np.ones((1, 1)), np.zeros((1, 1))) > 1e300  # B = 0, A != 0: huge
    assert rel_error([3.0, 4.0], [0.0, 0.0]) > 1e300  # 1-D: one row


def test_rel_error_is_batched_over_leading_axes():
    rng = np.random.default_rng(0)
    A, B = rng.standard_normal((7, 3, 2)), rng.standard_normal((7, 3, 2))
    r = rel_error(A, B)
    assert r.shape == (7,)
    for i in range(7):
        assert r[i] == pytest.approx(np.linalg.norm(A[i] - B[i]) / np.linalg.norm(B[i]), rel=1e-14)


def test_rel_error_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="shapes differ"):
        rel_error(np.zeros((3, 2)), np.zeros((2, 3)))


# ---------------------------------------------------------------------------------------------
# The nominal true Jacobian
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", ["exact", "euler", "rk4"])
def test_nominal_jacobian_is_the_zoh_step_input_jacobian(integrator):
    q, u, dt = np.array([0.3, -1.2, 2.0]), np.array([0.7, -1.3]), 0.05
    G = nominal_jacobian(integrator)(17, q, u, dt)
    assert_array_equal(G, kin.step_jacobians(q, u, dt, kin.integrator_code(integrator))[1])
    with pytest.raises(ValueError, match="unknown integrator"):
        nominal_jacobian("midpoint")


# ---------------------------------------------------------------------------------------------
# jacobian_quality
# ---------------------------------------------------------------------------------------------


def test_the_adaptive_pid_scores_exactly(apid_run, lemniscate_short):
    """``adaptive-pid`` logs the exact ZOH Jacobian at (q_hat_{k-1}, u_{k-1}): zero error and
    full agreement, which checks the time indices (J_{k-1} against the true Jacobian of the same
    step); off by one step, the same logs no longer match."""
    r = apid_run
    d = jacobian_quality(r)
    assert len(d.t) == lemniscate_short.n_steps - 1
    assert_array_equal(d.t, r.t[1 : len(r.u)])
    assert np.max(d.rel_error) < ROUNDING
    assert np.max(d.rel_error_v) < ROUNDING and np.max(d.rel_error_w) < ROUNDING
    assert_allclose(d.norm_ratio, 1.0, rtol=0, atol=ROUNDING)
    assert_allclose(d.matrix_cosine, 1.0, rtol=0, atol=ROUNDING)
    assert np.nanmin(d.cosine) > 1 - ROUNDING
    assert np.nanmin(d.sign_v) == 1.0 and np.nanmin(d.sign_w) == 1.0
    shifted = dataclasses.replace(r, q_hat=np.roll(r.q_hat, 1, axis=0))
    assert np.median(jacobian_quality(shifted).rel_error) > 1e-3


def test_the_true_jacobian_follows_the_integrator(lemniscate_short):
    """With an Euler plant, the adaptive-pid's logged Euler Jacobian is matched exactly by the
    nominal Euler Jacobian, and not by the exact arc's."""
    sc = dataclasses.replace(lemniscate_short, integrator="euler")
    r = simulate(sc, "adaptive-pid", seed=0)
    assert np.max(jacobian_quality(r, integrator="euler").rel_error) < ROUNDING
    assert np.median(jacobian_quality(r, integrator="exact").rel_error) > 1e-6


def test_the_true_jacobian_is_called_per_step_with_the_step_index(apid_run):
    r = apid_run
    calls = []
    nominal = nominal_jacobian("exact")

    def true_jacobian(k, q, u, dt):
        calls.append((k, q.copy(), u.copy(), dt))
        return nominal(k, q, u, dt)

    jacobian_quality(r, true_jacobian)
    assert [c[0] for c in calls] == list(range(len(r.u) - 1))
    k, q, u, dt = calls[10]
    assert_array_equal(q, r.q_hat[k]) and assert_array_equal(u, r.u[k])
    assert dt == r.dt


def test_metrics_against_known_true_jacobians(apid_run):
    """The logged J against 2 J, -J and J with its w column flipped: closed-form metrics."""
    r = apid_run
    nominal = nominal_jacobian("exact")
    twice = jacobian_quality(r, lambda k, q, u, dt: 2.0 * nominal(k, q, u, dt))
    assert_allclose(twice.rel_error, 0.5, rtol=ROUNDING)  # ||J - 2J|| / ||2J||
    assert_allclose(twice.norm_ratio, 0.5, rtol=ROUNDING)
    assert_allclose(twice.matrix_cosine, 1.0, rtol=ROUNDING)
    assert np.nanmin(twice.cosine) > 1 - ROUNDING
    assert np.nanmin(twice.sign_v) == 1.0 and np.nanmin(twice.sign_w) == 1.0

    neg = jacobian_quality(r, lambda k, q, u, dt: -nominal(k, q, u, dt))
    assert_allclose(neg.rel_error, 2.0, rtol=ROUNDING)
    assert_allclose(neg.matrix_cosine, -1.0, rtol=ROUNDING)
    assert np.nanmax(neg.cosine) < -1 + ROUNDING
    assert np.nanmax(neg.sign_v) == 0.0 and np.nanmax(neg.sign_w) == 0.0

    def w_flipped(k, q, u, dt):
        G = nominal(k, q, u, dt).copy()
        G[:, 1] *= -1.0
        return G

    flip = jacobian_quality(r, w_flipped)
    assert np.max(flip.rel_error_v) < ROUNDING
    assert_allclose(flip.rel_error_w, 2.0, rtol=ROUNDING)
    assert_allclose(flip.norm_ratio, 1.0, rtol=ROUNDING)
    assert np.nanmin(flip.sign_v) == 1.0 and np.nanmax(flip.sign_w) == 0.0


def test_signs_and_cosine_are_nan_where_the_direction_vanishes(apid_run):
    """A zero true Jacobian: no direction to agree with (NaN), relative error infinite-like."""
    d = jacobian_quality(apid_run, lambda k, q, u, dt: np.zeros((3, 2)))
    assert np.all(np.isnan(d.cosine))
    assert np.all(np.isnan(d.sign_v)) and np.all(np.isnan(d.sign_w))
    assert np.all(d.rel_error > 1e300) and np.all(np.isinf(d.norm_ratio))


def test_tail_means(apid_run):
    d = jacobian_quality(apid_run)
    x = d.rel_error_v.copy()
    assert d.tail_mean("rel_error_v") == float(np.nanmean(x[len(x) // 2 :]))
    assert d.tail_mean("rel_error_v", start=0.0) == float(np.nanmean(x))
    means = d.tail_means()
    assert tuple(means) == QUALITY_KEYS
    assert means["sign_w"] == 1.0
    assert tuple(d.as_dict()) == ("t", *QUALITY_KEYS)
    assert tuple(f.name for f in dataclasses.fields(JacobianQuality)) == ("t", *QUALITY_KEYS)


def test_a_controller_without_a_plant_jacobian_is_refused(lemniscate_short):
    r = simulate(lemniscate_short, "backstepping", seed=0)
    with pytest.raises(KeyError, match="plant Jacobian"):
        jacobian_quality(r)


# --- The true robot's Jacobian and the oracle arm (issue 14) ---------------------------------


def _with_plant(name, section):
    from wmr import scenario as scn_

    return scn_.loads(scn_.builtin(name).read_text() + section)


def test_plant_jacobian_of_an_input_map_is_the_nominal_at_the_applied_input_times_the_map():
    """dq+/du = G(q, M u) M for a plant that only maps the command (exact arc with v_s = 0)."""
    from wmr.estimation import identification as idf

    sc = _with_plant("lemniscate", "[plant]\nv_gain = 0.8\nw_gain = 1.1\nw_from_v = 0.2\n")
    run = simulate(sc, "adaptive-pid", 0)
    J = idf.plant_jacobian(sc, run)
    M = np.array([[0.8, 0.0], [0.2, 1.1]])
    for k in (0, 17, 2500):
        G = kin.step_jacobians(run.q_hat[k], M @ run.u[k], sc.dt, kin.EXACT)[1]
        # central differences of a pose ~1 m with h = 1e-6: rounding ~1e-16 / 1e-6 = 1e-10
        assert_allclose(J(k, run.q_hat[k], run.u[k], sc.dt), G @ M, rtol=1e-7, atol=1e-9)


def test_plant_jacobian_is_zero_with_a_delay_and_nominal_for_the_ideal_plant():
    from wmr import scenario as scn_
    from wmr.estimation import identification as idf

    sc = _with_plant("lemniscate", "[plant]\ndelay_steps = 1\n")
    run = simulate(sc, "pid", 0)
    assert np.all(idf.plant_jacobian(sc, run)(5, run.q_hat[5], run.u[5], sc.dt) == 0.0)
    ideal = scn_.load(scn_.builtin("lemniscate"))
    r = simulate(ideal, "pid", 0)
    assert r.plant_velocity is None and run.plant_velocity.shape == (ideal.n_steps, 2)
    J = idf.plant_jacobian(ideal, r)(9, r.q_hat[9], r.u[9], ideal.dt)
    assert np.array_equal(J, kin.step_jacobians(r.q_hat[9], r.u[9], ideal.dt, kin.EXACT)[1])


def test_the_oracle_is_iapid_when_the_estimate_is_the_truth():
    """Without measurement noise and acting on the raw measurement, the estimate is the true
    pose: the oracle arm (identifier on the true poses) is IAPID-NN-DEKF bit for bit; with
    noise its identifier's innovation is far smaller."""
    import dataclasses

    from wmr import scenario as scn_

    sc = scn_.load(scn_.builtin("lemniscate"))
    clean = dataclasses.replace(sc, noise=scn_.Noise((0.0, 0.0, 0.0)),
                                estimator=scn_.Estimator(pose_source="raw"))  # fmt: skip
    a, b = simulate(clean, "iapid-nn-dekf", 3), simulate(clean, "iapid-oracle", 3)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.state, b.state)
    noisy_a, noisy_b = simulate(sc, "iapid-nn-dekf", 3), simulate(sc, "iapid-oracle", 3)
    rms = [np.sqrt(np.mean(r.signal("nn_error")[1:] ** 2)) for r in (noisy_a, noisy_b)]
    assert rms[1] < 0.3 * rms[0], rms
    assert np.array_equal(noisy_a.q_hat[0], noisy_b.q_hat[0])  # the same estimate, same noise
